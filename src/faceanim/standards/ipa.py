"""IPA phones as the mouth sees them: any language's phone -> the ARPAbet phone with the same mouth.

faceanim's mouth targets (``data/visemes_arkit.json``, ``data/visemes.json``) are keyed by ARPAbet,
the US English phone set. A phone of another language (or an English one outside the pronunciation
dictionary) is given the target of the ARPAbet phone made with the same lips, jaw and tongue tip,
from its IPA symbol's place and manner (consonants) or height, backness and rounding (vowels):
German ``ø`` and French ``y`` are rounded like ``AO``/``UW``, Spanish ``β`` closes the lips as ``B``,
a uvular ``ʁ`` or velar ``x`` shows no lips (``HH``), Mandarin ``tɕ`` is ``CH``.

:func:`arpabet` reads one phone as espeak-ng writes it in IPA (``espeak-ng --ipa``, or its phoneme
events with IPA on): the base symbols are matched longest first (affricates, diphthongs); length
marks, stress, tones, nasalisation and other diacritics change no viseme and are dropped. A symbol
not in :data:`IPA_ARPABET` gives None (the caller merges its time into the phone before).
"""

from __future__ import annotations

import unicodedata

# base IPA symbol (or sequence) -> ARPAbet phones (space-separated)
IPA_ARPABET: dict[str, str] = {
    # plosives: the lips shut (bilabial), or the tongue behind (the lips follow the vowels)
    "p": "P", "b": "B", "ɓ": "B", "t": "T", "d": "D", "ɗ": "D", "ʈ": "T", "ɖ": "D", "c": "K", "ɟ": "G",
    "k": "K", "g": "G", "ɡ": "G", "q": "K", "ɢ": "G", "ʔ": "T",
    # nasals
    "m": "M", "ɱ": "M", "n": "N", "ɳ": "N", "ɲ": "N", "ŋ": "NG", "ɴ": "NG",
    # fricatives: bilabial ones nearly close the lips, labiodental tuck the lip under the teeth
    "ɸ": "F", "β": "B", "f": "F", "v": "V", "θ": "TH", "ð": "DH", "s": "S", "z": "Z", "ʃ": "SH", "ʒ": "ZH",
    "ʂ": "SH", "ʐ": "ZH", "ɕ": "SH", "ʑ": "ZH", "ç": "HH", "ʝ": "Y", "x": "HH", "ɣ": "HH", "χ": "HH",
    "ʁ": "HH", "ħ": "HH", "ʕ": "HH", "h": "HH", "ɦ": "HH", "ɬ": "S", "ɮ": "L",
    # affricates
    "tʃ": "CH", "dʒ": "JH", "ts": "T S", "dz": "D Z", "tɕ": "CH", "dʑ": "JH", "tʂ": "CH", "dʐ": "JH",
    "pf": "P F", "tθ": "T TH", "dð": "D DH", "ʧ": "CH", "ʤ": "JH", "ʦ": "T S", "ʣ": "D Z",
    # approximants, trills, taps
    "ʋ": "V", "ɹ": "R", "ɻ": "R", "r": "R", "ɾ": "T", "ɽ": "T", "ʀ": "HH", "ɺ": "L", "j": "Y", "ɰ": "Y",
    "w": "W", "ʍ": "W", "ɥ": "W", "l": "L", "ɫ": "L", "ɭ": "L", "ʎ": "L", "ʟ": "L",
    # vowels, front: spread, then rounded
    "i": "IY", "ɪ": "IH", "e": "EH", "ɛ": "EH", "æ": "AE", "a": "AA", "ɶ": "AO",
    "y": "UW", "ʏ": "UH", "ø": "AO", "œ": "AO",
    # central
    "ɨ": "IH", "ʉ": "UW", "ɘ": "AH", "ɵ": "UH", "ə": "AH", "ɜ": "ER", "ɝ": "ER", "ɚ": "ER", "ɞ": "AO",
    "ɐ": "AH", "ä": "AA", "ᵻ": "IH", "ᵿ": "UH",
    # back: unrounded, then rounded
    "ɯ": "UH", "ɤ": "AH", "ʌ": "AH", "ɑ": "AA", "u": "UW", "ʊ": "UH", "o": "AO", "ɔ": "AO", "ɒ": "AA",
    # diphthongs with an ARPAbet name of their own (a plain e or o above is one mouth, not a glide)
    "aɪ": "AY", "aʊ": "AW", "ɔɪ": "OY", "eɪ": "EY", "oʊ": "OW", "əʊ": "OW",
}

# marks that change no viseme: length, stress, syllable and tone marks, and espeak-ng's own
# (a '-' after a reduced vowel, '#' on some English vowels)
_MARKS = set("ːˑˈˌ.‿|‖-#'’ˀ˞ˤˠʰʱʲʷⁿˡ̚↗↘˥˦˧˨˩0123456789")
_LONGEST = max(len(k) for k in IPA_ARPABET)


_LETTERS = set("".join(IPA_ARPABET))


def _base(phone: str) -> str:
    """The phone's base letters, diacritics and marks dropped ('ɔ̃ː' -> 'ɔ', 'ẽ' -> 'e'); a letter
    that is a symbol of its own here stays whole ('ç', 'ä')."""
    out = []
    for ch in unicodedata.normalize("NFC", phone.strip()):
        if ch not in _LETTERS:
            ch = unicodedata.normalize("NFD", ch)[0]  # a precomposed letter with a diacritic: its base
        if unicodedata.combining(ch) or ch in _MARKS or ch.isspace():
            continue
        out.append(ch)
    return "".join(out)


def arpabet(phone: str) -> list[str] | None:
    """The ARPAbet phones with the same mouth as an IPA phone (one or a few symbols, diacritics
    allowed): ``arpabet("øː") == ["AO"]``, ``arpabet("tʃ") == ["CH"]``, ``arpabet("aɪə") == ["AY",
    "AH"]``; ``[]`` for a phone of marks only, None when a symbol is not IPA that is known here."""
    s = _base(phone)
    out: list[str] = []
    k = 0
    while k < len(s):
        for n in range(min(_LONGEST, len(s) - k), 0, -1):
            hit = IPA_ARPABET.get(s[k:k + n])
            if hit is not None:
                out += hit.split()
                k += n
                break
        else:
            return None
    return out
