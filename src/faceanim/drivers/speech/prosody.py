"""The voice's prosody moving the rest of the face: brows on pitch accents, blinks at pauses, the
eyes looking away and back, the head nodding and leaning with the phrases, an emotion phrase by
phrase.

People who talk raise their brows on the syllables they stress and blink when they pause
(Cavé et al. 1996 on brows and F0 rises; Ekman 1979 on brows as "batons"; blinks cluster at
pauses and phrase ends), look away as they begin a long turn and back as they end it (Kendon
1967), and move the head with the voice's pitch (Yehia et al. 2002). :func:`analyse` reads the
sound alone, whatever produced it (espeak-ng for ``say TEXT``, a recording for ``say --audio``):

- the voice's pitch (F0) with Praat's autocorrelation tracker (``praat-parselmouth``), 10 ms steps,
  in two passes (the second in the speaker's own range);
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
:data:`BLINK_MAX_GAP` without one (at its quietest moment); the ``eyeLook`` curves look aside
early in each long phrase (:func:`gaze_aversions`). :func:`prosody_head` moves the head with the
phrases: a rise with the voice's pitch, a nod at each phrase's last accent, a lean over each
phrase. :func:`emotion_intensity` and :func:`emotion_actions` carry an emotion phrase by phrase
(stronger in livelier phrases); :func:`prosody_actions` is all of it as MPEG-4 actions (the
director, ``.fap`` files); :class:`LiveProsody` hears it as the sound comes (``live --audio``).
The same sound gives the same curves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

STEP = 0.01  # seconds between pitch and level samples
PITCH_FLOOR, PITCH_CEILING = 75.0, 500.0  # Hz: Praat's range for speech, the first pass
RANGE_FLOOR, RANGE_CEILING = 0.75, 1.5  # the second pass's range: these times the first's quartiles
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
        sound = parselmouth.Sound(x, sampling_frequency=float(rate))
        track = sound.to_pitch(time_step=STEP, pitch_floor=PITCH_FLOOR, pitch_ceiling=PITCH_CEILING)
        f0 = track.selected_array["frequency"]
        if np.sum(f0 > 0) >= 20:  # a second pass in this speaker's own range: no octave errors
            q1, q3 = np.percentile(f0[f0 > 0], [25, 75])
            floor_hz = max(PITCH_FLOOR / 2, RANGE_FLOOR * q1)
            track = sound.to_pitch(time_step=STEP, pitch_floor=floor_hz,
                                   pitch_ceiling=max(RANGE_CEILING * q3, 2 * floor_hz))
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


GAZE_AWAY = 0.3  # ARKit look weight of a look away (about 0.17 rad: perform.eye_angles)
GAZE_UP = 0.5  # of that, upwards as well (people look up and aside as they think what to say)
GAZE_PHRASE = 1.0  # seconds a phrase lasts at least for its speaker to look away in it
GAZE_START, GAZE_SHARE, GAZE_LONGEST = 0.1, 0.4, 1.5  # seconds into the phrase; the share of it, at most seconds
GAZE_TURN = 0.2  # seconds the eyes take to go and to come back
LOOK_LEFT = ("eyeLookOutLeft", "eyeLookInRight")  # the eyes to the speaker's left
LOOK_RIGHT = ("eyeLookInLeft", "eyeLookOutRight")
LOOK_UP = ("eyeLookUpLeft", "eyeLookUpRight")
LOOKS = LOOK_LEFT + LOOK_RIGHT + LOOK_UP


def gaze_aversions(prosody: Prosody) -> list[tuple[float, float, int]]:
    """(start, end, side) of each look away: speakers look away as a long phrase begins and back
    to the listener before it ends (Kendon 1967; Argyle and Cook 1976): in each phrase of
    :data:`GAZE_PHRASE` or more, from :data:`GAZE_START` into it, for :data:`GAZE_SHARE` of it (at
    most :data:`GAZE_LONGEST`), to the left (side +1) and right (-1) phrase by phrase."""
    out = []
    for start, end in phrases(prosody):
        if end - start >= GAZE_PHRASE:
            out.append((start + GAZE_START, start + GAZE_START + min(GAZE_SHARE * (end - start), GAZE_LONGEST),
                        1 if len(out) % 2 == 0 else -1))
    return out


def _held(t: np.ndarray, start: float, end: float, turn: float) -> np.ndarray:
    """0..1: rising over ``turn`` seconds from ``start``, held, falling over ``turn`` to ``end``."""
    up = np.clip((t - start) / turn, 0.0, 1.0)
    down = np.clip((end - t) / turn, 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * np.minimum(up, down))


def prosody_curves(prosody: Prosody, names: list[str], fps: float, n_frames: int) -> np.ndarray:
    """(n_frames, len(names)) ARKit weights in 0..1 of the brows, blinks and looks away of
    ``prosody`` (module docstring), sampled at ``fps`` from 0 s; columns other than :data:`BROWS`,
    :data:`BLINKS` and :data:`LOOKS` are 0."""
    t = np.arange(int(n_frames)) / float(fps)
    brow = np.zeros(len(t))
    for at, semitones in prosody.accents:
        brow = np.maximum(brow, min(BROW_MAX, BROW_PER_ST * semitones) * _bump(t, at, BROW_LEAD, BROW_FALL))
    blink = np.zeros(len(t))
    for at in blink_times(prosody):
        blink = np.maximum(blink, _bump(t, at + BLINK_CLOSE, BLINK_CLOSE, BLINK_OPEN))
    left, right = np.zeros(len(t)), np.zeros(len(t))
    for start, end, side in gaze_aversions(prosody):
        away = GAZE_AWAY * _held(t, start, end, GAZE_TURN)
        left, right = (np.maximum(left, away), right) if side > 0 else (left, np.maximum(right, away))
    columns = {**{n: brow for n in BROWS}, **{n: blink for n in BLINKS}, **{n: left for n in LOOK_LEFT},
               **{n: right for n in LOOK_RIGHT}, **{n: GAZE_UP * np.maximum(left, right) for n in LOOK_UP}}
    out = np.zeros((len(t), len(names)))
    for k, name in enumerate(names):
        if name in columns:
            out[:, k] = columns[name]
    return np.clip(out, 0.0, 1.0)


HEAD_PER_ST = 0.006  # radians the head rises per semitone of the voice over its median (Yehia et al. 2002)
HEAD_SMOOTH = 0.15  # seconds: the smoothing (Gaussian sigma) of that rise
NOD, NOD_DOWN, NOD_UP = 0.05, 0.15, 0.35  # a nod at a phrase's last accent: radians down, seconds down and back
TILT = 0.03  # radians the head leans over a phrase, to alternate sides phrase by phrase


def head_rise(prosody: Prosody, t: np.ndarray) -> np.ndarray:
    """The head's pitch (radians, faceanim's sign: negative is up) at times ``t`` from the voice's
    pitch alone: :data:`HEAD_PER_ST` per semitone over its median, smoothed over
    :data:`HEAD_SMOOTH`; 0 where nobody speaks (:func:`prosody_head`'s slow rise)."""
    from scipy.ndimage import gaussian_filter1d

    voiced = np.isfinite(prosody.pitch)
    if voiced.sum() < 5:
        return np.zeros(len(t))
    st = 12.0 * np.log2(prosody.pitch / np.nanmedian(prosody.pitch))
    st = np.where(voiced & prosody.speaking, st, 0.0)
    rise = gaussian_filter1d(st, HEAD_SMOOTH / STEP, mode="constant")
    return -HEAD_PER_ST * np.interp(t, prosody.times, rise, left=0.0, right=0.0)


def prosody_head(prosody: Prosody, fps: float, n_frames: int) -> np.ndarray:
    """(n_frames, 3) the head's yaw, pitch, roll in radians (faceanim's signs: pitch nods down,
    roll tilts to the head's right) that ``prosody`` shows, sampled at ``fps`` from 0 s: the head
    rises a little with the voice's pitch over its median (:data:`HEAD_PER_ST`), nods down
    :data:`NOD` at each phrase's last accent (or its end, if it has none), and leans :data:`TILT`
    to one side over each phrase, the other over the next; still where nobody speaks."""
    t = np.arange(int(n_frames)) / float(fps)
    out = np.zeros((len(t), 3))
    out[:, 1] = head_rise(prosody, t)
    for k, (a, b) in enumerate(_runs(prosody.speaking)):
        start, end = a * STEP, b * STEP
        last = [at for at, _ in prosody.accents if start <= at <= end]
        out[:, 1] += NOD * _bump(t, (last[-1] if last else end) + NOD_DOWN, NOD_DOWN, NOD_UP)
        span = max(end - start, 2 * STEP)
        lean = np.clip((t - start) / span, 0.0, 1.0)
        out[:, 2] += (TILT if k % 2 == 0 else -TILT) * np.sin(np.pi * lean) ** 2
    return out


def phrases(prosody: Prosody) -> list[tuple[float, float]]:
    """(start, end) seconds of each phrase: the speech between two pauses."""
    return [(a * STEP, b * STEP) for a, b in _runs(prosody.speaking)]


EMOTION_SPREAD = 0.35  # an emotion's intensity per phrase: 1 + this x the phrase's arousal (z-score),
EMOTION_RANGE = (0.5, 1.5)  # within these times the intensity asked for
EMOTION_RAMP = 0.3  # seconds the intensity takes to change between phrases (and to rise at the start)


def phrase_arousal(prosody: Prosody) -> list[float]:
    """Each phrase's arousal as a z-score over the sound's phrases: its mean level (dB) plus its
    pitch range (semitones, 10th to 90th percentile), each standardised; 0 for a lone phrase."""
    rows = []
    for start, end in phrases(prosody):
        inside = (prosody.times >= start) & (prosody.times < end)
        level = float(np.mean(prosody.level[inside])) if inside.any() else 0.0
        voiced = prosody.pitch[inside & np.isfinite(prosody.pitch)]
        spread = float(np.diff(12.0 * np.log2(np.percentile(voiced, [10, 90]))).item()) if len(voiced) >= 5 else 0.0
        rows.append((level, spread))
    if len(rows) < 2:
        return [0.0] * len(rows)
    r = np.array(rows)
    sd = r.std(axis=0)
    z = np.where(sd > 1e-9, (r - r.mean(axis=0)) / np.where(sd > 1e-9, sd, 1.0), 0.0)
    return (z.mean(axis=1)).tolist()


def emotion_intensity(prosody: Prosody, intensity: float, fps: float, n_frames: int) -> np.ndarray:
    """(n_frames,) an emotion's intensity over the speech, phrase by phrase: ``intensity`` times
    1 + :data:`EMOTION_SPREAD` x the phrase's :func:`phrase_arousal` (within :data:`EMOTION_RANGE`),
    a louder, livelier phrase showing more of it; held through the pause after a phrase, changing
    over :data:`EMOTION_RAMP` seconds, rising from 0 at the start and falling to 0 at the end."""
    t = np.arange(int(n_frames)) / float(fps)
    spans, arousal = phrases(prosody), phrase_arousal(prosody)
    level = np.full(len(t), float(intensity))
    lo, hi = EMOTION_RANGE
    for (start, _), z in zip(spans, arousal):
        level[t >= start - EMOTION_RAMP / 2] = intensity * float(np.clip(1.0 + EMOTION_SPREAD * z, lo, hi))
    k = max(int(round(EMOTION_RAMP * fps)), 1)
    level = np.convolve(np.r_[np.full(k, level[0]), level, np.full(k, level[-1])], np.ones(k) / k, "same")[k:-k]
    end = max(t[-1], 1e-9) if len(t) else 1e-9
    return level * np.clip(np.minimum(t, end - t) / EMOTION_RAMP, 0.0, 1.0)


BROW_FAP = 400.0  # ENS of MPEG-4's eyebrow raises for an ARKit brow weight of 1 (surprise: 250)
BLINK_FAPS = {"close_t_l_eyelid": 1024, "close_t_r_eyelid": 1024, "close_b_l_eyelid": 150, "close_b_r_eyelid": 150}
ANGLE_UNIT = 1e-5  # radians per MPEG-4 angle unit (AU): head_pitch, head_roll
RISE_STEP = 0.05  # seconds between the keys of the head's slow rise as FAP actions


def prosody_actions(prosody: Prosody, offset: float = 0.0) -> list:
    """The same brows, blinks, looks away, nods and leans as :func:`prosody_curves` and
    :func:`prosody_head`, as MPEG-4 actions (Lee et al.'s director and ``.fap`` files): the eyebrow
    raises (``raise_*_eyebrow``, :data:`BROW_FAP` per unit of brow), eyelid closures, the eyeballs'
    yaw and pitch, ``head_pitch`` nods and ``head_roll`` leans, starting ``offset`` seconds into
    the timeline; the slow rise of the head with the pitch (:func:`head_rise`) as an additive layer
    on ``head_pitch``: keys every :data:`RISE_STEP`, each a linear hat over its neighbours' (their
    sum is the rise interpolated linearly between the keys), added over the nods."""
    from faceanim.drivers.mpeg4 import Action, fap_set

    brow_faps = ("raise_l_i_eyebrow", "raise_r_i_eyebrow", "raise_l_m_eyebrow", "raise_r_m_eyebrow",
                 "raise_l_o_eyebrow", "raise_r_o_eyebrow")
    out = []
    for at, semitones in prosody.accents:
        raise_ = min(BROW_MAX, BROW_PER_ST * semitones) * BROW_FAP
        start = max(at - BROW_LEAD, 0.0)
        rise = (at - start) / (at + BROW_FALL - start)
        out.append(Action("brow raise", fap_set({f: raise_ for f in brow_faps}), offset + start, at + BROW_FALL - start,
                          1.0, "smooth", rise, 1.0 - rise))
    blink = fap_set(BLINK_FAPS)
    for at in blink_times(prosody):
        out.append(Action("blink", blink, offset + at, BLINK_CLOSE + BLINK_OPEN, 1.0, "smooth",
                          BLINK_CLOSE / (BLINK_CLOSE + BLINK_OPEN), 1.0 - BLINK_CLOSE / (BLINK_CLOSE + BLINK_OPEN),
                          weight=3.0))
    from faceanim.standards.arkit import LOOK_ANGLES

    for start, end, side in gaze_aversions(prosody):  # the eyeballs turned as the eyeLook curves turn them
        outward, inward = GAZE_AWAY * LOOK_ANGLES["Out"], GAZE_AWAY * LOOK_ANGLES["In"]
        yaw_l, yaw_r = (outward, inward) if side > 0 else (-inward, -outward)
        turn = min(GAZE_TURN / (end - start), 0.5)
        out.append(Action("look away", fap_set({"yaw_l_eyeball": yaw_l / ANGLE_UNIT, "yaw_r_eyeball": yaw_r / ANGLE_UNIT,
                                                "pitch_l_eyeball": -GAZE_UP * GAZE_AWAY * LOOK_ANGLES["Up"] / ANGLE_UNIT,
                                                "pitch_r_eyeball": -GAZE_UP * GAZE_AWAY * LOOK_ANGLES["Up"] / ANGLE_UNIT}),
                          offset + start, end - start, 1.0, "smooth", turn, turn))
    for k, (start, end) in enumerate(phrases(prosody)):
        last = [at for at, _ in prosody.accents if start <= at <= end]
        at = last[-1] if last else end
        out.append(Action("nod", fap_set({"head_pitch": NOD / ANGLE_UNIT}), offset + at, NOD_DOWN + NOD_UP, 1.0,
                          "smooth", NOD_DOWN / (NOD_DOWN + NOD_UP), 1.0 - NOD_DOWN / (NOD_DOWN + NOD_UP)))
        lean = TILT if k % 2 == 0 else -TILT
        out.append(Action("lean", fap_set({"head_roll": lean / ANGLE_UNIT}), offset + start,
                          max(end - start, 2 * STEP), 1.0, "smooth", 0.5, 0.5))
    keys = np.arange(0.0, prosody.duration + RISE_STEP, RISE_STEP)
    pitch = fap_set({"head_pitch": 1.0})
    for at, value in zip(keys, head_rise(prosody, keys)):
        if abs(value) >= ANGLE_UNIT:  # under one unit of the .fap: nothing
            out.append(Action("head rise", {k: value / ANGLE_UNIT for k in pitch}, offset + at - RISE_STEP,
                              2 * RISE_STEP, 1.0, "linear", 0.5, 0.5, additive=True))
    return out


def emotion_actions(prosody: Prosody, emotion: str, intensity: float, end: float, offset: float = 0.0) -> list:
    """``emotion`` (an MPEG-4 expression's name) as one action per phrase of the voice, at
    ``intensity`` times the phrase's factor (as :func:`emotion_intensity`), each running on to the
    next phrase's start so the face keeps it through the pauses; the last ends 0.2 s after ``end``
    (the speech's end, seconds); ``offset`` seconds into the timeline."""
    from faceanim.drivers.mpeg4 import Action, expression_faps

    faps = expression_faps(emotion)
    spans = phrases(prosody) or [(0.0, end)]
    arousal = phrase_arousal(prosody) or [0.0]
    lo, hi = EMOTION_RANGE
    out = []
    for k, ((start, stop), z) in enumerate(zip(spans, arousal)):
        last = k + 1 == len(spans)
        begin = max(start - EMOTION_RAMP / 2, 0.0) if k else 0.0
        until = max(end, stop) + 0.2 if last else spans[k + 1][0] + EMOTION_RAMP / 2
        level = intensity * float(np.clip(1.0 + EMOTION_SPREAD * z, lo, hi))
        duration = max(until - begin, 0.1)
        ramp = min(EMOTION_RAMP / duration, 0.5)
        out.append(Action(emotion, faps, offset + begin, duration, level, "linear", ramp, ramp, 0.3))
    return out


def with_prosody(curves: np.ndarray, names: list[str], samples: np.ndarray, rate: int, fps: float,
                 emotion: str | None = None, intensity: float = 0.6) -> tuple[np.ndarray, np.ndarray, Prosody]:
    """The speech's ARKit ``curves`` (F, len(names)) with the brows and blinks of its sound's prosody
    laid over them (the larger of the two in each of those columns) and ``emotion`` (an
    expression's name) added at ``intensity`` phrase by phrase (:func:`emotion_intensity`); the
    head's (F, 3) yaw, pitch, roll (:func:`prosody_head`); and the prosody itself."""
    from faceanim.drivers.speech.lipsync import expression_curves

    prosody = analyse(samples, rate)
    n = len(curves)
    out = np.maximum(np.asarray(curves, dtype=np.float64), prosody_curves(prosody, names, fps, n))
    if emotion:
        out = np.clip(out + expression_curves(emotion, names, n, fps, emotion_intensity(prosody, intensity, fps, n)),
                      0.0, 1.0)
    return out, prosody_head(prosody, fps, n), prosody


LIVE_HOP = 0.1  # seconds of sound between two pitch readings of a live stream
LIVE_CONTEXT = 0.34  # seconds of sound each reading looks at (its newest pitch sample is 20 ms old)
LIVE_HISTORY = 20.0  # seconds of levels the loud speech and the noise floor are judged on
LIVE_KEEP = 5.0  # seconds of past events kept (a bump lasts under one)
LIVE_LEAN = 0.5  # seconds a lean takes to come and to go
LIVE_GAZE_AFTER = 0.5  # seconds a phrase has lasted when the eyes look away (a short one never does)
LIVE_QUIET = -60.0  # dBFS: quieter is never speech
LIVE_RANGE = 10.0  # dB: the loud speech over the noise floor at least, for any sound to be speech
LIVE_PHRASES = 20  # past phrases a live phrase's arousal is judged against


class LiveProsody:
    """The brows, blinks and head of :func:`prosody_curves` and :func:`prosody_head` as the sound
    comes (``live --audio``): :meth:`feed` chunks of mono samples, then :meth:`curves` and
    :meth:`head` are the face now. Everything is decided from the sound heard so far:

    - pitch: Praat's tracker on the last :data:`LIVE_CONTEXT` seconds every :data:`LIVE_HOP`,
      in semitones over the phrase's median so far;
    - a brow raise starts when the pitch rises :data:`ACCENT_ST` over that median (its height
      following the rise, :data:`BROW_PER_ST`) and falls over :data:`BROW_FALL` from the moment
      the pitch turns down;
    - the eyes blink once a pause has lasted :data:`BLINK_PAUSE` (the offline blink comes at the
      pause's start), or when :data:`BLINK_MAX_GAP` has passed without one, speech or not;
    - a pause of :data:`PAUSE_MIN` ends a phrase: the head nods then, and the lean of the phrase
      (to alternate sides, phrase by phrase) eases back; the head rises with the pitch;
    - once a phrase has lasted :data:`LIVE_GAZE_AFTER` the eyes look away (sides alternating), for
      at most :data:`GAZE_LONGEST`, and come back when it ends;
    - :attr:`emotion_level`, an emotion's intensity multiplier phrase by phrase, as
      :func:`emotion_intensity`'s: 1 + :data:`EMOTION_SPREAD` x the phrase's arousal so far (its
      mean level and pitch range so far, standardised over it and the last :data:`LIVE_PHRASES`
      phrases), within :data:`EMOTION_RANGE`, held through the pause after it, rising from 0 at
      the first phrase over :data:`EMOTION_RAMP`.

    Memory stays bounded however long the stream: levels of the last :data:`LIVE_HISTORY` seconds
    and events of the last :data:`LIVE_KEEP`. The same samples in the same chunks give the same face.
    """

    def __init__(self, rate: int):
        self.rate = int(rate)
        self.tail = np.zeros(0)  # the last LIVE_CONTEXT seconds of sound
        self.heard = 0  # samples fed
        self.read_to = 0.0  # seconds: pitch and level known up to here
        self.pending = np.zeros(0)  # samples not yet in a 10 ms level step
        self.levels = np.full(int(LIVE_HISTORY / STEP), np.nan)  # a ring of 10 ms levels (dB)
        self.n_levels = 0
        self.speaking = False
        self.silent_for = 0.0  # seconds of silence so far (within speech: not yet a pause)
        self.phrase: tuple[float, float | None] | None = None  # (start, end) of the phrase being heard
        self.phrase_pitch: list[float] = []  # semitones re 100 Hz of this phrase's voiced samples
        self.phrase_index = -1
        self.smooth_st = np.nan  # the pitch over the phrase's median, smoothed (semitones)
        self.rise = 0.0  # the head's rise with the pitch (semitones, smoothed)
        self.accent: list | None = None  # [onset, height, turned-down time or None] of the rise being heard
        self.accents: list[list] = []  # past raises [onset, height, turned]
        self.blinks: list[float] = []
        self.last_blink = 0.0
        self.blinked_this_pause = False
        self.nods: list[float] = []
        self.leans: list[tuple[float, float | None, float]] = []  # (start, end, signed tilt)
        self.looks: list[list] = []  # [start, end, side] of the looks away
        self.phrase_level = [0.0, 0]  # this phrase's summed level (dB) and 10 ms steps
        self.phrase_spread = 0.0  # its pitch range so far (semitones, 10th to 90th percentile)
        self.past_phrases: list[tuple[float, float]] = []  # (mean level, pitch range) of the last ones
        self.emotion_target = 1.0
        self.emotion_now = 0.0  # the multiplier, eased to its target (0 before the first phrase)

    @property
    def time(self) -> float:
        return self.heard / self.rate

    def feed(self, samples: np.ndarray) -> None:
        x = np.asarray(samples, dtype=np.float64).ravel()
        x = np.where(np.isfinite(x), x, 0.0)
        if not len(x):
            return
        self.heard += len(x)
        keep = int(LIVE_CONTEXT * self.rate)
        self.tail = np.r_[self.tail, x][-keep:]
        self.pending = np.r_[self.pending, x]
        step = max(int(STEP * self.rate), 1)
        while len(self.pending) >= step:
            self._level_step(self.pending[:step])
            self.pending = self.pending[step:]
        if self.time - self.read_to >= LIVE_HOP:
            self._pitch_step()

    def _level_step(self, part: np.ndarray) -> None:
        rms = float(np.sqrt(np.mean(part * part)))
        level = 20.0 * np.log10(max(rms, 1e-10))
        self.levels[self.n_levels % len(self.levels)] = level
        self.n_levels += 1
        known = self.levels[np.isfinite(self.levels)]
        loud, floor = np.percentile(known, 95), np.percentile(known, 2)
        # until a second is heard the percentiles know nothing: a fixed bar (-50 dBFS) then; and a
        # room's steady noise, whose levels lie within LIVE_RANGE of each other, is never speech
        threshold = max(loud - SILENCE_DB, floor + SILENCE_SHARE * (loud - floor)) if len(known) >= 100 else -50.0
        now = self.n_levels * STEP
        sound = level > max(threshold, LIVE_QUIET) and (loud - floor >= LIVE_RANGE or len(known) < 100)
        if sound:
            self.silent_for = 0.0
            self.blinked_this_pause = False
            if self.phrase is None:  # a phrase begins
                self.phrase_index += 1
                self.phrase = (now - STEP, None)
                self.phrase_pitch = []
                self.phrase_level, self.phrase_spread = [0.0, 0], 0.0
                self.leans.append((now - STEP, None, TILT if self.phrase_index % 2 == 0 else -TILT))
            self.phrase_level[0] += level
            self.phrase_level[1] += 1
        else:
            self.silent_for += STEP
            if self.phrase is not None and self.silent_for >= PAUSE_MIN:  # the phrase is over
                end = now - self.silent_for
                self.phrase = None
                self.past_phrases = [*self.past_phrases, self._phrase_row()][-LIVE_PHRASES:]
                self.nods.append(now)
                if self.leans and self.leans[-1][1] is None:
                    self.leans[-1] = (self.leans[-1][0], end, self.leans[-1][2])
                self._turn_down(now)
            if self.silent_for >= BLINK_PAUSE and not self.blinked_this_pause:
                self._blink(now)
                self.blinked_this_pause = True
        self.speaking = self.phrase is not None
        if self.speaking:
            begun = self.phrase[0]
            if now - begun >= LIVE_GAZE_AFTER and not (self.looks and self.looks[-1][0] >= begun):
                self.looks.append([now, now + GAZE_LONGEST, 1 if len(self.looks) % 2 == 0 else -1])
                self.looks = self.looks[-2:]
        elif self.looks and self.looks[-1][1] > now:  # the phrase is over: the eyes come back
            self.looks[-1][1] = now
        if now - self.last_blink >= BLINK_MAX_GAP:
            self._blink(now)
        self._emotion_step()

    def _phrase_row(self) -> tuple[float, float]:
        total, steps = self.phrase_level
        return (total / max(steps, 1), self.phrase_spread)

    def _emotion_step(self) -> None:
        if self.speaking:  # in a pause the last phrase's is held
            rows = np.array([*self.past_phrases, self._phrase_row()])
            z = 0.0
            if len(rows) >= 2:
                sd = rows.std(axis=0)
                z = float(np.mean(np.where(sd > 1e-9, (rows[-1] - rows.mean(axis=0)) / np.where(sd > 1e-9, sd, 1.0), 0.0)))
            lo, hi = EMOTION_RANGE
            self.emotion_target = float(np.clip(1.0 + EMOTION_SPREAD * z, lo, hi))
        if self.phrase_index < 0:
            return
        ease = min(STEP / EMOTION_RAMP, 1.0)  # per step: 0 to 1 (the first rise) over EMOTION_RAMP
        self.emotion_now += float(np.clip(self.emotion_target - self.emotion_now, -ease, ease))

    @property
    def emotion_level(self) -> float:
        """An emotion's intensity multiplier now (class docstring): 0 before anyone speaks, then
        within :data:`EMOTION_RANGE`."""
        return self.emotion_now

    def _blink(self, now: float) -> None:
        self.blinks.append(now)
        self.last_blink = now

    def _turn_down(self, now: float) -> None:
        if self.accent is not None:
            self.accent[2] = now
            self.accents.append(self.accent)
            self.accent = None

    def _pitch_step(self) -> None:
        import parselmouth

        start = self.time - len(self.tail) / self.rate
        frames = np.zeros(0)
        times = np.zeros(0)
        if len(self.tail) / self.rate > 3 / PITCH_FLOOR:
            track = parselmouth.Sound(self.tail, sampling_frequency=float(self.rate)).to_pitch(
                time_step=STEP, pitch_floor=PITCH_FLOOR, pitch_ceiling=PITCH_CEILING)
            times, frames = start + track.xs(), track.selected_array["frequency"]
        new = times > self.read_to
        alpha = 1.0 - np.exp(-STEP / SMOOTH)
        head_alpha = 1.0 - np.exp(-STEP / HEAD_SMOOTH)
        for t, f0 in zip(times[new], frames[new]):
            voiced = f0 > 0 and self.speaking
            if voiced:
                self.phrase_pitch.append(12.0 * np.log2(f0 / 100.0))
                if len(self.phrase_pitch) >= 5 and len(self.phrase_pitch) % 10 == 5:
                    q10, q90 = np.percentile(self.phrase_pitch, [10, 90])
                    self.phrase_spread = float(q90 - q10)
            if voiced and len(self.phrase_pitch) >= 5:
                st = self.phrase_pitch[-1] - float(np.median(self.phrase_pitch))
                self.smooth_st = st if not np.isfinite(self.smooth_st) else self.smooth_st + alpha * (st - self.smooth_st)
                self.rise += head_alpha * (self.smooth_st - self.rise)
                self._accent_step(float(t))
            else:
                self.rise += head_alpha * (0.0 - self.rise)
                if not voiced:
                    self.smooth_st = np.nan
        self.read_to = self.time - 0.02
        # what is long past is forgotten
        old = self.time - LIVE_KEEP
        self.accents = [a for a in self.accents if a[2] is None or a[2] > old]
        self.blinks = [b for b in self.blinks if b > old]
        self.nods = [n for n in self.nods if n > old]
        self.leans = [le for le in self.leans if le[1] is None or le[1] > old]

    def _accent_step(self, t: float) -> None:
        st = self.smooth_st
        if self.accent is None:
            last = max([a[0] for a in self.accents], default=-np.inf)
            if st >= ACCENT_ST and t - last >= ACCENT_GAP:
                self.accent = [t, st, None]
        elif st > self.accent[1]:
            self.accent[1] = st
        elif st < self.accent[1] - 0.5:  # turned down: the peak is past
            self._turn_down(t)

    def curves(self, names: list[str], now: float | None = None) -> np.ndarray:
        """(len(names),) ARKit weights in 0..1 of the brows, blinks and looks now (0 in other columns)."""
        t = self.time if now is None else float(now)
        brow = 0.0
        for onset, height, turned in [*self.accents, *([self.accent] if self.accent else [])]:
            up = min(BROW_MAX, BROW_PER_ST * height)
            if turned is None or t < turned:
                e = 0.5 - 0.5 * np.cos(np.pi * np.clip((t - onset) / BROW_LEAD, 0.0, 1.0))
            else:
                e = 0.5 + 0.5 * np.cos(np.pi * np.clip((t - turned) / BROW_FALL, 0.0, 1.0))
                e *= 0.5 - 0.5 * np.cos(np.pi * np.clip((turned - onset) / BROW_LEAD, 0.0, 1.0))
            brow = max(brow, up * float(e))
        blink = max([float(_bump(np.array([t]), b + BLINK_CLOSE, BLINK_CLOSE, BLINK_OPEN)[0]) for b in self.blinks],
                    default=0.0)
        left = right = 0.0
        for start, end, side in self.looks:
            away = GAZE_AWAY * float(_held(np.array([t]), start, max(end, start + 2 * GAZE_TURN), GAZE_TURN)[0])
            left, right = (max(left, away), right) if side > 0 else (left, max(right, away))
        columns = {**{n: brow for n in BROWS}, **{n: blink for n in BLINKS}, **{n: left for n in LOOK_LEFT},
                   **{n: right for n in LOOK_RIGHT}, **{n: GAZE_UP * max(left, right) for n in LOOK_UP}}
        return np.clip(np.array([columns.get(name, 0.0) for name in names]), 0.0, 1.0)

    def head(self, now: float | None = None) -> np.ndarray:
        """(3,) the head's yaw, pitch, roll in radians now (faceanim's signs, as :func:`prosody_head`)."""
        t = self.time if now is None else float(now)
        pitch = -HEAD_PER_ST * self.rise
        pitch += sum(NOD * float(_bump(np.array([t]), n + NOD_DOWN, NOD_DOWN, NOD_UP)[0]) for n in self.nods)
        roll = 0.0
        for start, end, tilt in self.leans:
            come = 0.5 - 0.5 * np.cos(np.pi * np.clip((t - start) / LIVE_LEAN, 0.0, 1.0))
            go = 1.0 if end is None else 0.5 + 0.5 * np.cos(np.pi * np.clip((t - end) / LIVE_LEAN, 0.0, 1.0))
            roll += tilt * come * go
        return np.array([0.0, pitch, roll])
