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

from faceanim.errors import FaceAnimError, InputFileError

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


def resample(x: np.ndarray, rate: int, to: int = SAMPLE_RATE) -> np.ndarray:
    """Samples at ``rate`` resampled to ``to`` (polyphase filter)."""
    if rate == to:
        return np.asarray(x, dtype=np.float64)
    from math import gcd

    from scipy.signal import resample_poly

    g = gcd(rate, to)
    return resample_poly(x, to // g, rate // g)


def _pcm16(x: np.ndarray) -> bytes:
    return (np.clip(x, -1, 1) * 32767).astype("<i2").tobytes()


def _to_16k(x: np.ndarray, rate: int) -> bytes:
    return _pcm16(resample(x, rate))


def write_wav(path, samples: np.ndarray, rate: int = SAMPLE_RATE) -> Path:
    """Mono float samples in [-1, 1] as a 16-bit PCM WAV file."""
    out = Path(path)
    with wave.open(str(out), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(_pcm16(samples))
    return out


def _decoder():
    from pocketsphinx import Decoder

    return Decoder(samprate=SAMPLE_RATE, loglevel="FATAL")


def align(audio, transcript: str, rate: int | None = None, decoder=None) -> list[Phone]:
    """Timed phones of ``transcript`` in ``audio`` (a WAV path, or samples with ``rate``);
    ``decoder`` reuses a pocketsphinx decoder (loading the model takes ~0.3 s)."""
    if isinstance(audio, (str, Path)):
        x, rate = load_wav(audio)
    else:
        x = np.asarray(audio, dtype=np.float64)
        if rate is None:
            raise SpeechError("give the sample rate of the audio samples")
    words = words_of(transcript)
    dec = decoder or _decoder()
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
    spoken = [p for p in phones if p.phone != "SIL"]
    if not spoken:
        raise SpeechError("the audio could not be aligned with its transcript; does the audio match it?")
    # a transcript forced onto audio that says something else squeezes most phones to the
    # aligner's minimum of 3 frames
    squeezed = np.mean([p.end - p.start <= 3.01 * FRAME for p in spoken])
    if len(spoken) >= 8 and squeezed > 0.5:
        raise SpeechError(f"{squeezed:.0%} of the phones got the shortest possible duration: the audio "
                          "does not seem to match its transcript")
    return phones


def synthesize(text: str, wav_path, voice: str = "en-us", speed: int = 160) -> Path:
    """Speak ``text`` with espeak-ng into a 16-bit WAV file."""
    words_of(text)  # refuse text with nothing to say before starting a process
    exe = _espeak()
    out = Path(wav_path)
    result = subprocess.run([exe, "-v", voice, "-s", str(int(speed)), "-w", str(out), str(text)],
                            capture_output=True, text=True, check=False)
    if result.returncode != 0 or not out.is_file():
        raise SpeechError(f"espeak-ng failed: {result.stderr.strip() or result.returncode}")
    return out


def _espeak() -> str:
    exe = shutil.which("espeak-ng")
    if exe is None:
        raise SpeechError("espeak-ng is not installed; run scripts/setup.sh (it installs Debian's espeak-ng)")
    return exe


PAUSES = {",": 0.2, ";": 0.25, ":": 0.25, ".": 0.4, "?": 0.4, "!": 0.4}
WORD_GAP = 0.02


def say_timed(text: str, wav_path, voice: str = "en-us", speed: int = 175) -> list[Phone]:
    """Speak ``text`` word by word with espeak-ng into one 16 kHz WAV and return its timed phones.

    Each word is synthesized alone and aligned alone (short and therefore robust: aligning a whole
    synthesized sentence fails on the robotic voice), then the words are joined with short gaps and
    pauses at punctuation, so every phone's time is known by construction.
    """
    import tempfile

    tokens = re.findall(r"[A-Za-z0-9']+|[,;:.?!]", str(text))
    words = [t for t in tokens if t not in PAUSES]
    words_of(" ".join(words) or text)  # nothing to say -> a clear error
    exe = _espeak()
    dec = _decoder()
    pieces, phones, clock = [], [], 0.0

    def silence(seconds: float) -> np.ndarray:
        return np.zeros(round(seconds * SAMPLE_RATE))

    with tempfile.TemporaryDirectory() as tmp:
        for token in tokens:
            if token in PAUSES:
                pieces.append(silence(PAUSES[token]))
                phones.append(Phone("SIL", clock, clock + PAUSES[token]))
                clock += PAUSES[token]
                continue
            word = token.lower().strip("'")
            if dec.lookup_word(word) is None:
                raise SpeechError(f"the pronunciation dictionary does not know '{word}'; "
                                  "spell numbers and abbreviations out as words")
            path = Path(tmp) / "w.wav"
            result = subprocess.run([exe, "-v", voice, "-s", str(int(speed)), "-w", str(path), token],
                                    capture_output=True, text=True, check=False)
            if result.returncode != 0:
                raise SpeechError(f"espeak-ng failed on '{token}': {result.stderr.strip()}")
            x, rate = load_wav(path)
            x = resample(x, rate)
            loud = np.flatnonzero(np.abs(x) > 0.02)
            x = x[max(loud[0] - 160, 0):loud[-1] + 160] if len(loud) else x
            try:
                word_phones = [p for p in align(x, word, SAMPLE_RATE, dec) if p.phone != "SIL"]
            except SpeechError:
                word_phones = []
            if not word_phones:  # spread the dictionary pronunciation evenly over the word
                pron = dec.lookup_word(word).split()
                step = len(x) / SAMPLE_RATE / len(pron)
                word_phones = [Phone(ph, k * step, (k + 1) * step, word) for k, ph in enumerate(pron)]
            phones += [Phone(p.phone, clock + p.start, clock + p.end, word) for p in word_phones]
            pieces.append(x)
            clock += len(x) / SAMPLE_RATE
            pieces.append(silence(WORD_GAP))
            clock += WORD_GAP
    write_wav(wav_path, np.concatenate(pieces))
    return phones
