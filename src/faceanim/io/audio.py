"""Audio in and out through libsndfile (the ``soundfile`` package): one reader, one writer, one
resampler for the whole toolkit.

:func:`read_audio` reads what libsndfile reads - WAV of any sample format (8/16/24/32-bit PCM,
32/64-bit float), FLAC, OGG Vorbis, AIFF, MP3, ... - as float32 mono samples (channels averaged)
and the sample rate. It refuses, each with one line saying what is wrong and what to do: a missing
or empty file, a file that is not audio, a file whose header promises more samples than it holds
(truncated), NaN or infinite float samples, and a file longer than :data:`~faceanim.limits.MAX_DURATION`
or with a sample rate above :data:`~faceanim.limits.MAX_SAMPLE_RATE` (checked from the header,
before any sample is read). libsndfile's own messages are never shown (they are logged at debug).
"""

from __future__ import annotations

import logging
import os
import re
from pathlib import Path

import numpy as np

from faceanim.errors import InputFileError
from faceanim.io.files import atomic_output, native_stderr_quiet
from faceanim.limits import MAX_DURATION, MAX_SAMPLE_RATE

log = logging.getLogger(__name__)

#: a WAV written to a pipe cannot know its length and declares about 2^31 or 2^32 bytes of data;
#: a declared size at least this large means "unknown length", not "truncated"
_STREAMING_SIZE = 0x7FFF0000
_BLOCK_SAMPLES = 1 << 20  # samples (frames x channels) read at once while mixing to mono


class AudioError(InputFileError):
    """An audio file that is missing, empty, not audio, truncated, or out of range."""


def check_rate(rate, name: str = "sample rate") -> int:
    if isinstance(rate, bool) or not isinstance(rate, (int, np.integer)) or not 1 <= rate <= MAX_SAMPLE_RATE:
        raise AudioError(f"the {name} must be a whole number of Hz from 1 to {MAX_SAMPLE_RATE}, got {rate!r}")
    return int(rate)


def _declared_beyond_end(extra_info: str) -> bool:
    """Whether libsndfile's header log says the data chunk is longer than the file (truncated)."""
    for declared, actual in re.findall(r"^data\s*:\s*(\d+)\s*\(should be (\d+)\)", extra_info, re.MULTILINE):
        if int(actual) < int(declared) < _STREAMING_SIZE:
            return True
    return False


def read_audio(path: str | os.PathLike, what: str = "audio file") -> tuple[np.ndarray, int]:
    """``(samples, rate)``: float32 mono samples (channels averaged; PCM scaled to [-1, 1)) and the
    sample rate in Hz of the audio file ``path``. Every failure is an :class:`AudioError`."""
    import soundfile as sf

    p = Path(path)
    if p.exists() and not p.is_file():
        raise AudioError(f"{what} '{p}' is not a regular file (a folder or a device); give an audio file")
    if not p.is_file():
        raise AudioError(f"{what} '{p}' does not exist; check the path")
    if p.stat().st_size == 0:
        raise AudioError(f"{what} '{p}' is empty; give a WAV, FLAC or OGG file with sound in it")
    not_audio = (f"{what} '{p}' is not audio that faceanim can read (WAV, FLAC, OGG, AIFF, MP3); "
                 "check the file, or convert it to WAV (e.g. `sox IN OUT.wav`)")
    truncated = (f"{what} '{p}' is truncated or damaged (its header promises more audio than the file "
                 "holds, or its data does not decode); record or copy it again")
    try:
        with native_stderr_quiet():  # libsndfile's decoders (mpg123) print their own warnings
            info = sf.info(str(p))
    except (RuntimeError, ValueError, TypeError, OSError) as exc:
        log.debug("libsndfile cannot open %s: %s", p, exc)
        code = getattr(exc, "code", None)  # libsndfile's SF_ERR_*: 2 system, 3 malformed, 4 encoding
        if code == 2:
            raise AudioError(f"cannot read {what} '{p}'; check that it is readable") from None
        if code == 3:
            raise AudioError(truncated) from None
        if code == 4:
            raise AudioError(f"{what} '{p}' uses an audio encoding faceanim cannot decode; convert it to WAV "
                             "(e.g. `sox IN OUT.wav`)") from None
        raise AudioError(not_audio) from None
    rate, frames, channels = int(info.samplerate), int(info.frames), int(info.channels)
    if not 1 <= rate <= MAX_SAMPLE_RATE:
        raise AudioError(f"{what} '{p}' has a sample rate of {rate} Hz; faceanim reads 1 to {MAX_SAMPLE_RATE} Hz: "
                         "resample it (e.g. `sox IN -r 48000 OUT.wav`)")
    if channels < 1:
        raise AudioError(not_audio)
    if frames <= 0:
        raise AudioError(f"{what} '{p}' holds no audio samples; give a recording with sound in it")
    if frames / rate > MAX_DURATION:
        raise AudioError(f"{what} '{p}' is {frames / rate:.0f} s long; faceanim reads at most {MAX_DURATION:g} s "
                         "of audio: cut it into shorter pieces")
    if _declared_beyond_end(info.extra_info):
        raise AudioError(truncated)
    out = np.empty(frames, dtype=np.float32)
    n = 0
    block = max(1, _BLOCK_SAMPLES // channels)
    try:
        with native_stderr_quiet(), sf.SoundFile(str(p)) as f:
            while n < frames:
                chunk = f.read(min(block, frames - n), dtype="float32", always_2d=True)
                if len(chunk) == 0:
                    break
                if not np.all(np.isfinite(chunk)):
                    raise AudioError(f"{what} '{p}' holds NaN or infinite samples; export it again as PCM "
                                     "(e.g. `sox IN -b 16 OUT.wav`)")
                out[n:n + len(chunk)] = chunk[:, 0] if channels == 1 else chunk.mean(axis=1)
                n += len(chunk)
    except (RuntimeError, ValueError, TypeError, OSError) as exc:
        log.debug("libsndfile failed reading %s: %s", p, exc)
        raise AudioError(truncated) from None
    if n < frames:
        raise AudioError(truncated)
    return out, rate


def write_wav(path: str | os.PathLike, samples, rate: int, subtype: str = "PCM_16") -> Path:
    """Mono samples (float, clipped to [-1, 1]) as a WAV file (16-bit PCM unless ``subtype`` says
    otherwise, e.g. ``"PCM_24"`` or ``"FLOAT"``), written atomically: a failure leaves no file."""
    import soundfile as sf

    rate = check_rate(rate)
    x = np.asarray(samples, dtype=np.float64)
    if x.ndim != 1 or x.size == 0:
        raise AudioError(f"audio to write must be a non-empty 1-D array of samples, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise AudioError("audio to write holds NaN or infinite samples")
    out = Path(path)
    with atomic_output(out) as tmp:
        sf.write(str(tmp), np.clip(x, -1.0, 1.0), rate, subtype=subtype, format="WAV")
    return out


def resample(x, rate: int, to: int) -> np.ndarray:
    """Samples at ``rate`` Hz resampled to ``to`` Hz (libsoxr's high-quality resampler through
    python-soxr; scipy.signal, which did this before, takes 1.5-2 s to import), as float32."""
    import soxr

    rate, to = check_rate(rate, "source sample rate"), check_rate(to, "target sample rate")
    x = np.asarray(x, dtype=np.float32)
    if x.ndim != 1:
        raise AudioError(f"audio to resample must be 1-D, got shape {x.shape}")
    if rate == to or x.size == 0:
        return x.copy()
    return soxr.resample(x, rate, to, quality="HQ").astype(np.float32, copy=False)
