"""The voice's prosody moving the upper face: brows on pitch accents, blinks at pauses.

People who talk raise their brows on the syllables they stress and blink when they pause
(Cavé et al. 1996 on brows and F0 rises; Ekman 1979 on brows as "batons"; blinks cluster at
pauses and phrase ends). :func:`analyse` reads that from the sound alone, whatever produced it
(espeak-ng for ``say TEXT``, a recording for ``say --audio``):

- the voice's pitch (F0) with Praat's autocorrelation tracker (``praat-parselmouth``), 10 ms steps;
- its level (RMS in 25 ms windows, dB) and the pauses: silences of at least :data:`PAUSE_MIN`, the
  level under the loud speech's by more than :data:`SILENCE_DB` or nearer the recording's noise
  floor than :data:`SILENCE_SHARE` of the way up;
- phrases (speech between pauses) and their pitch accents: peaks of the smoothed pitch in
  semitones at least :data:`ACCENT_ST` above the phrase's median, at least :data:`ACCENT_GAP`
  apart, voiced and no more than :data:`ACCENT_QUIET` under the phrase's median level.

:func:`prosody_curves` turns them into ARKit curves in 0..1: ``browInnerUp`` and
``browOuterUpLeft/Right`` rise before each accent and fall after it, higher for a bigger rise
(:data:`BROW_PER_ST` per semitone up to :data:`BROW_MAX`); both ``eyeBlink`` close once at the
start of each pause of :data:`BLINK_PAUSE` or more, and once in any run of speech longer than
:data:`BLINK_MAX_GAP` without one (at its quietest moment). :func:`prosody_head` moves the head
with the phrases: a rise with the voice's pitch, a nod at each phrase's last accent, a lean over
each phrase. The same sound gives the same curves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

STEP = 0.01  # seconds between pitch and level samples
PITCH_FLOOR, PITCH_CEILING = 75.0, 500.0  # Hz: Praat's range for speech
WINDOW = 0.025  # seconds of sound in each level sample
SILENCE_DB = 30.0  # a sample this far under the loud speech (its 95th percentile) is silence,
SILENCE_SHARE = 0.35  # or this share of the way from the noise floor (2nd percentile) up to it
PAUSE_MIN = 0.2  # seconds of silence that part two phrases
ACCENT_ST = 1.5  # semitones over the phrase's median pitch that make a pitch accent
ACCENT_GAP = 0.35  # seconds between two accents at least
ACCENT_QUIET = 6.0  # dB an accent may lie under the phrase's median level
SMOOTH = 0.05  # seconds: the pitch's smoothing (a Gaussian's sigma) before its peaks are taken
BROW_LEAD, BROW_FALL = 0.15, 0.35  # seconds the brows rise before an accent's peak and fall after it
BROW_PER_ST, BROW_MAX = 0.1, 0.6  # brow raise per semitone of the accent, and at most
BLINK_PAUSE = 0.3  # seconds: a pause this long gets a blink at its start
BLINK_MAX_GAP = 5.0  # seconds of speech without a blink at most
BLINK_CLOSE, BLINK_OPEN = 0.08, 0.17  # seconds a blink takes to close and to open again
BLINK_DELAY = 0.05  # seconds after the pause starts


@dataclass
class Prosody:
    """The prosody of one sound (:func:`analyse`): per sample ``times`` (s), ``pitch`` (Hz, NaN
    where unvoiced) and ``level`` (dB), ``speaking`` (bool); ``pauses`` (start, end) in seconds
    (the silences before the first and after the last speech included), ``accents`` (time,
    semitones over the phrase's median) and the sound's ``duration``."""

    times: np.ndarray
    pitch: np.ndarray
    level: np.ndarray
    speaking: np.ndarray
    pauses: list[tuple[float, float]]
    accents: list[tuple[float, float]]
    duration: float


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, end) index pairs (end exclusive) of the runs of True in ``mask``."""
    edges = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist()))


def analyse(samples: np.ndarray, rate: int) -> Prosody:
    """The pitch, level, pauses and pitch accents of mono ``samples`` at ``rate`` Hz (module
    docstring)."""
    import parselmouth
    from scipy.ndimage import gaussian_filter1d

    x = np.asarray(samples, dtype=np.float64).ravel()
    x = np.where(np.isfinite(x), x, 0.0)
    duration = len(x) / float(rate)
    n = max(int(np.floor(duration / STEP)), 1)
    times = (np.arange(n) + 0.5) * STEP
    # level: RMS over WINDOW about each sample time
    half = max(int(WINDOW * rate / 2), 1)
    power = np.r_[0.0, np.cumsum(x * x)]
    centre = np.clip((times * rate).astype(np.int64), 0, len(x))
    lo, hi = np.clip(centre - half, 0, len(x)), np.clip(centre + half, 0, len(x))
    rms = np.sqrt((power[hi] - power[lo]) / np.maximum(hi - lo, 1))
    level = 20.0 * np.log10(np.maximum(rms, 1e-10))
    loud, floor = np.percentile(level, 95), np.percentile(level, 2)
    speaking = (level > max(loud - SILENCE_DB, floor + SILENCE_SHARE * (loud - floor))) & (rms > 1e-5)
    # silences shorter than PAUSE_MIN are inside a phrase (a stop's closure, a breath between words)
    for a, b in _runs(~speaking):
        if 0 < a and b < n and (b - a) * STEP < PAUSE_MIN:
            speaking[a:b] = True
    pauses = [(a * STEP, b * STEP) for a, b in _runs(~speaking) if (b - a) * STEP >= PAUSE_MIN or a == 0 or b == n]
    pitch = np.full(n, np.nan)
    if duration > 3 / PITCH_FLOOR and np.any(speaking):
        track = parselmouth.Sound(x, sampling_frequency=float(rate)).to_pitch(
            time_step=STEP, pitch_floor=PITCH_FLOOR, pitch_ceiling=PITCH_CEILING)
        f0 = track.selected_array["frequency"]
        pitch = np.interp(times, track.xs(), np.where(f0 > 0, f0, np.nan), left=np.nan, right=np.nan)
        # interp across NaN gives NaN near them: unvoiced stays unvoiced
        voiced_at = np.interp(times, track.xs(), (f0 > 0).astype(float), left=0.0, right=0.0) > 0.5
        pitch[~voiced_at] = np.nan
    accents = []
    for a, b in _runs(speaking):
        seg = pitch[a:b]
        voiced = np.isfinite(seg)
        if voiced.sum() < 5:
            continue
        st = 12.0 * np.log2(seg / np.nanmedian(seg))
        filled = np.interp(np.arange(len(st)), np.flatnonzero(voiced), st[voiced])
        smooth = gaussian_filter1d(filled, SMOOTH / STEP, mode="nearest")
        floor = np.median(level[a:b])
        peaks = [i for i in range(1, len(smooth) - 1)
                 if smooth[i] >= smooth[i - 1] and smooth[i] > smooth[i + 1] and smooth[i] >= ACCENT_ST
                 and voiced[i] and level[a + i] >= floor - ACCENT_QUIET]
        # the biggest first; a peak closer than ACCENT_GAP to a bigger one is part of it
        kept: list[int] = []
        for i in sorted(peaks, key=lambda i: (-smooth[i], i)):
            if all(abs(i - j) * STEP >= ACCENT_GAP for j in kept):
                kept.append(i)
        accents += [(float(times[a + i]), float(smooth[i])) for i in sorted(kept)]
    return Prosody(times, pitch, level, speaking, pauses, accents, duration)


def blink_times(prosody: Prosody) -> list[float]:
    """When the eyes close (module docstring): at the start of each pause of ``BLINK_PAUSE`` or more
    (the silence before the first speech counts from its start), and in each run of speech longer
    than ``BLINK_MAX_GAP`` without one, at its quietest moment, until none is."""
    t, level = prosody.times, prosody.level
    out = sorted(a + BLINK_DELAY for a, b in prosody.pauses if b - a >= BLINK_PAUSE)
    end = prosody.duration
    while True:
        marks = [0.0, *out, end]
        gaps = [(b - a, a, b) for a, b in zip(marks[:-1], marks[1:]) if b - a > BLINK_MAX_GAP]
        if not gaps:
            return out
        _, a, b = max(gaps)
        inside = np.flatnonzero((t > a + 1.0) & (t < b - 1.0))  # not right after or before another
        if not len(inside):
            inside = np.flatnonzero((t > a) & (t < b))
        out = sorted([*out, float(t[inside[np.argmin(level[inside])]])])


def _bump(t: np.ndarray, peak: float, rise: float, fall: float) -> np.ndarray:
    """0..1: a raised cosine rising over ``rise`` seconds to 1 at ``peak`` and falling over ``fall``."""
    u = np.where(t < peak, (t - peak) / rise, (t - peak) / fall)
    return np.where(np.abs(u) < 1.0, 0.5 * (1.0 + np.cos(np.pi * u)), 0.0)


BROWS = ("browInnerUp", "browOuterUpLeft", "browOuterUpRight")
BLINKS = ("eyeBlinkLeft", "eyeBlinkRight")


def prosody_curves(prosody: Prosody, names: list[str], fps: float, n_frames: int) -> np.ndarray:
    """(n_frames, len(names)) ARKit weights in 0..1 of the brows and blinks of ``prosody`` (module
    docstring), sampled at ``fps`` from 0 s; columns other than :data:`BROWS` and :data:`BLINKS` are 0."""
    t = np.arange(int(n_frames)) / float(fps)
    brow = np.zeros(len(t))
    for at, semitones in prosody.accents:
        brow = np.maximum(brow, min(BROW_MAX, BROW_PER_ST * semitones) * _bump(t, at, BROW_LEAD, BROW_FALL))
    blink = np.zeros(len(t))
    for at in blink_times(prosody):
        blink = np.maximum(blink, _bump(t, at + BLINK_CLOSE, BLINK_CLOSE, BLINK_OPEN))
    out = np.zeros((len(t), len(names)))
    for k, name in enumerate(names):
        if name in BROWS:
            out[:, k] = brow
        elif name in BLINKS:
            out[:, k] = blink
    return np.clip(out, 0.0, 1.0)


HEAD_PER_ST = 0.006  # radians the head rises per semitone of the voice over its median (Yehia et al. 2002)
HEAD_SMOOTH = 0.15  # seconds: the smoothing (Gaussian sigma) of that rise
NOD, NOD_DOWN, NOD_UP = 0.05, 0.15, 0.35  # a nod at a phrase's last accent: radians down, seconds down and back
TILT = 0.03  # radians the head leans over a phrase, to alternate sides phrase by phrase


def prosody_head(prosody: Prosody, fps: float, n_frames: int) -> np.ndarray:
    """(n_frames, 3) the head's yaw, pitch, roll in radians (faceanim's signs: pitch nods down,
    roll tilts to the head's right) that ``prosody`` shows, sampled at ``fps`` from 0 s: the head
    rises a little with the voice's pitch over its median (:data:`HEAD_PER_ST`), nods down
    :data:`NOD` at each phrase's last accent (or its end, if it has none), and leans :data:`TILT`
    to one side over each phrase, the other over the next; still where nobody speaks."""
    from scipy.ndimage import gaussian_filter1d

    t = np.arange(int(n_frames)) / float(fps)
    out = np.zeros((len(t), 3))
    voiced = np.isfinite(prosody.pitch)
    if voiced.sum() >= 5:
        st = 12.0 * np.log2(prosody.pitch / np.nanmedian(prosody.pitch))
        st = np.where(voiced & prosody.speaking, st, 0.0)
        rise = gaussian_filter1d(st, HEAD_SMOOTH / STEP, mode="constant")
        out[:, 1] -= HEAD_PER_ST * np.interp(t, prosody.times, rise, left=0.0, right=0.0)
    for k, (a, b) in enumerate(_runs(prosody.speaking)):
        start, end = a * STEP, b * STEP
        last = [at for at, _ in prosody.accents if start <= at <= end]
        out[:, 1] += NOD * _bump(t, (last[-1] if last else end) + NOD_DOWN, NOD_DOWN, NOD_UP)
        span = max(end - start, 2 * STEP)
        lean = np.clip((t - start) / span, 0.0, 1.0)
        out[:, 2] += (TILT if k % 2 == 0 else -TILT) * np.sin(np.pi * lean) ** 2
    return out


def with_prosody(curves: np.ndarray, names: list[str], samples: np.ndarray, rate: int, fps: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The speech's ARKit ``curves`` (F, len(names)) with the brows and blinks of its sound's prosody
    laid over them (the larger of the two in each of those columns), and the head's (F, 3) yaw,
    pitch, roll (:func:`prosody_head`)."""
    prosody = analyse(samples, rate)
    upper = prosody_curves(prosody, names, fps, len(curves))
    return np.maximum(np.asarray(curves, dtype=np.float64), upper), prosody_head(prosody, fps, len(curves))
