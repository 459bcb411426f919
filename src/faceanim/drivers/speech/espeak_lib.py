"""espeak-ng's C library through ctypes: speech with its phoneme events, run as its own process.

:func:`faceanim.drivers.speech.phonemes.espeak_phones` runs this file with the Python in use
(``python espeak_lib.py OUT.raw`` with ``{"text", "voice", "rate", "ipa"}`` as JSON on stdin): it
speaks the text in one go, writes the sound to OUT.raw (16-bit mono at the library's rate) and
prints, as JSON, the rate and the events: each phoneme's name (espeak-ng's mnemonic, or its IPA
with ``"ipa": true``) and where its sound starts (ms), and each word's place in the text. A
fresh process per text because the library keeps state between texts (a second text in one
process comes out a few samples different) and can hang when re-initialised; nothing of faceanim
is imported here. Exit code 3: the library is not there.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import json
import sys

PHONEME_EVENTS, PHONEME_IPA, DONT_EXIT = 0x0001, 0x0002, 0x8000  # espeak_Initialize options
SYNCHRONOUS = 2  # AUDIO_OUTPUT_SYNCHRONOUS
EVENT_END_OF_LIST, EVENT_WORD, EVENT_PHONEME = 0, 1, 7
RATE_PARAMETER = 1  # espeakRATE
CHARS_UTF8 = 1  # the text is plain UTF-8: never read as SSML or as phoneme input


class _Id(ctypes.Union):
    _fields_ = [("number", ctypes.c_int), ("name", ctypes.c_char_p), ("string", ctypes.c_char * 8)]


class _Event(ctypes.Structure):
    _fields_ = [("type", ctypes.c_int), ("unique_identifier", ctypes.c_uint), ("text_position", ctypes.c_int),
                ("length", ctypes.c_int), ("audio_position", ctypes.c_int), ("sample", ctypes.c_int),
                ("user_data", ctypes.c_void_p), ("id", _Id)]


def speak(text: str, voice: str, rate: int, out_path: str, ipa: bool = False) -> dict:
    name = ctypes.util.find_library("espeak-ng") or "libespeak-ng.so.1"
    try:
        lib = ctypes.CDLL(name)
    except OSError:
        sys.exit(3)
    options = PHONEME_EVENTS | (PHONEME_IPA if ipa else 0) | DONT_EXIT
    sample_rate = int(lib.espeak_Initialize(SYNCHRONOUS, 0, None, options))
    if sample_rate <= 0:
        sys.exit(3)
    events = []
    with open(out_path, "wb") as out:

        def on_sound(wav, n, ev):
            if n > 0:
                out.write(ctypes.string_at(wav, 2 * n))
            k = 0
            while ev[k].type != EVENT_END_OF_LIST:
                e = ev[k]
                if e.type == EVENT_PHONEME:
                    events.append(["phoneme", e.id.string.decode("utf-8", "replace"), e.audio_position])
                elif e.type == EVENT_WORD:
                    events.append(["word", [e.text_position, e.length], e.audio_position])
                k += 1
            return 0

        callback = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(ctypes.c_short), ctypes.c_int,
                                    ctypes.POINTER(_Event))(on_sound)
        lib.espeak_SetSynthCallback(callback)
        lib.espeak_SetVoiceByName.argtypes = [ctypes.c_char_p]
        if lib.espeak_SetVoiceByName(voice.encode("utf-8")) != 0:
            sys.exit(4)
        lib.espeak_SetParameter(RATE_PARAMETER, int(rate), 0)
        data = text.encode("utf-8")
        lib.espeak_Synth.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_uint, ctypes.c_int, ctypes.c_uint,
                                     ctypes.c_uint, ctypes.c_void_p, ctypes.c_void_p]
        if lib.espeak_Synth(data, len(data) + 1, 0, 0, 0, CHARS_UTF8, None, None) != 0:
            sys.exit(5)
        lib.espeak_Synchronize()
    return {"rate": sample_rate, "events": events}


if __name__ == "__main__":
    request = json.loads(sys.stdin.read())
    print(json.dumps(speak(str(request["text"]), str(request["voice"]), int(request["rate"]), sys.argv[1],
                           bool(request.get("ipa", False)))))
