"""Speech: timed phonemes from text (synthesized with espeak-ng) or from recorded speech and its
transcript (forced alignment with pocketsphinx), and co-articulated visemes."""

from faceanim.drivers.speech.phonemes import (
    Phone,
    align,
    load_wav,
    say_timed,
    synthesize,
)
from faceanim.drivers.speech.visemes import phone_viseme, viseme_actions

__all__ = ["Phone", "align", "load_wav", "phone_viseme", "say_timed", "synthesize", "viseme_actions"]
