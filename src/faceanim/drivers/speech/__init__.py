"""Speech: timed phonemes from text (synthesized with espeak-ng) or from recorded speech and its
transcript (forced alignment with pocketsphinx) or from recorded speech alone (pocketsphinx's
phone recognition), and co-articulated visemes. Audio files are read
and written by :mod:`faceanim.io.audio`."""

from faceanim.drivers.speech.phonemes import (
    Phone,
    SpeechError,
    align,
    check_text,
    check_voice,
    espeak_voices,
    recognise_phones,
    say_timed,
    synthesize,
)
from faceanim.drivers.speech.visemes import phone_viseme, viseme_actions

__all__ = ["Phone", "SpeechError", "align", "check_text", "check_voice", "espeak_voices", "phone_viseme",
           "recognise_phones", "say_timed", "synthesize", "viseme_actions"]
