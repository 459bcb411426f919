"""Timed phonemes: forced alignment of speech audio with its transcript, and speech synthesis.

Alignment uses pocketsphinx (its wheel ships a US English acoustic model and dictionary): the
transcript's words are looked up (unknown words are refused by name), the audio is aligned at
10 ms frames, and the ARPAbet phones come back with their start and end times. Synthesis runs
espeak-ng (installed by ``scripts/setup.sh``) to a WAV file; the synthesized audio is then
aligned the same way, so text and recorded speech give timings by one method.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import wave
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import FaceAnimError, InputFileError

SAMPLE_RATE = 16000  # what the pocketsphinx model expects
FRAME = 0.01  # pocketsphinx frame length, seconds


class SpeechError(FaceAnimError):
    """Text with nothing to say, audio that does not match its transcript, a missing synthesizer."""


@dataclass(frozen=True)
class Phone:
    phone: str  # ARPAbet without stress, or SIL
    start: float  # seconds
    end: float
    word: str = ""

    @property
    def centre(self) -> float:
        return 0.5 * (self.start + self.end)


def words_of(text: str) -> list[str]:
    """The speakable words of ``text``, lower case (letters, digits spelled as written, apostrophes)."""
    words = re.findall(r"[a-z0-9']+", str(text).lower())
    words = [w.strip("'") for w in words if w.strip("'")]
    if not words:
        raise SpeechError(f"there are no words to speak in {text!r}")
    return words


def load_wav(path) -> tuple[np.ndarray, int]:
    """Mono float samples in [-1, 1] and the sample rate of a PCM WAV file."""
    p = Path(path)
    if not p.is_file():
        raise InputFileError(f"audio file '{p}' does not exist; check the path")
    try:
        with wave.open(str(p)) as w:
            rate, channels, width = w.getframerate(), w.getnchannels(), w.getsampwidth()
            raw = w.readframes(w.getnframes())
    except (wave.Error, EOFError) as exc:
        raise InputFileError(f"'{p}' is not a PCM WAV file ({exc})") from None
    if width != 2:
        raise InputFileError(f"'{p}': only 16-bit PCM WAV is read, this one has {8 * width}-bit samples")
    x = np.frombuffer(raw, dtype="<i2").astype(np.float64) / 32768.0
    if channels > 1:
        x = x.reshape(-1, channels).mean(1)
    if x.size == 0:
        raise InputFileError(f"'{p}' holds no audio")
    return x, rate


def _to_16k(x: np.ndarray, rate: int) -> bytes:
    if rate != SAMPLE_RATE:
        from math import gcd

        from scipy.signal import resample_poly

        g = gcd(rate, SAMPLE_RATE)
        x = resample_poly(x, SAMPLE_RATE // g, rate // g)
    return (np.clip(x, -1, 1) * 32767).astype("<i2").tobytes()


def align(audio, transcript: str, rate: int | None = None) -> list[Phone]:
    """Timed phones of ``transcript`` in ``audio`` (a WAV path, or samples with ``rate``)."""
    from pocketsphinx import Decoder

    if isinstance(audio, (str, Path)):
        x, rate = load_wav(audio)
    else:
        x = np.asarray(audio, dtype=np.float64)
        if rate is None:
            raise SpeechError("give the sample rate of the audio samples")
    words = words_of(transcript)
    dec = Decoder(samprate=SAMPLE_RATE, loglevel="FATAL")
    unknown = [w for w in dict.fromkeys(words) if dec.lookup_word(w) is None]
    if unknown:
        raise SpeechError(f"the pronunciation dictionary does not know: {', '.join(unknown[:8])}; "
                          "spell numbers and abbreviations out as words")
    raw = _to_16k(x, rate)
    duration = len(raw) / 2 / SAMPLE_RATE
    if duration < 0.1 * len(words):
        raise SpeechError(f"{duration:.2f} s of audio is too short for {len(words)} words; "
                          "does the audio match its transcript?")
    try:
        dec.set_align_text(" ".join(words))
        dec.start_utt()
        dec.process_raw(raw, full_utt=True)
        dec.end_utt()
        dec.set_alignment()
        dec.start_utt()
        dec.process_raw(raw, full_utt=True)
        dec.end_utt()
        alignment = dec.get_alignment()
    except (RuntimeError, ValueError) as exc:
        raise SpeechError(f"the audio could not be aligned with its transcript ({exc}); "
                          "does the audio match its transcript?") from None
    phones = []
    for word in alignment or []:
        for p in word:
            phones.append(Phone(p.name, p.start * FRAME, (p.start + p.duration) * FRAME,
                                "" if word.name.startswith("<") else word.name))
    if not phones or not any(p.phone != "SIL" for p in phones):
        raise SpeechError("the audio could not be aligned with its transcript; does the audio match it?")
    return phones


def synthesize(text: str, wav_path, voice: str = "en-us", speed: int = 160) -> Path:
    """Speak ``text`` with espeak-ng into a 16-bit WAV file."""
    words_of(text)  # refuse text with nothing to say before starting a process
    exe = shutil.which("espeak-ng")
    if exe is None:
        raise SpeechError("espeak-ng is not installed; run scripts/setup.sh (it installs Debian's espeak-ng)")
    out = Path(wav_path)
    result = subprocess.run([exe, "-v", voice, "-s", str(int(speed)), "-w", str(out), str(text)],
                            capture_output=True, text=True, check=False)
    if result.returncode != 0 or not out.is_file():
        raise SpeechError(f"espeak-ng failed: {result.stderr.strip() or result.returncode}")
    return out
