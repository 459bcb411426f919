"""The voice's prosody on the upper face (drivers/speech/prosody.py): signals whose pitch accents
and pauses are known by construction, and the same sound giving the same curves."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from faceanim.drivers.speech.prosody import (
    BLINK_MAX_GAP,
    BROWS,
    analyse,
    blink_times,
    prosody_curves,
    with_prosody,
)
from faceanim.standards.arkit import APPLE_NAMES

RATE = 16000


def voice(f0, seconds: float) -> np.ndarray:
    """A voiced sound with three harmonics on the pitch contour ``f0(t)`` (Hz)."""
    t = np.arange(int(seconds * RATE)) / RATE
    phase = 2 * np.pi * np.cumsum(f0(t)) / RATE
    return 0.3 * (np.sin(phase) + 0.5 * np.sin(2 * phase) + 0.3 * np.sin(3 * phase))


def silence(seconds: float) -> np.ndarray:
    return np.zeros(int(seconds * RATE))


def rise(at: float, semitones: float):
    return lambda t: 120.0 * 2 ** (semitones / 12 * np.exp(-((t - at) / 0.08) ** 2))


def test_a_pitch_rise_raises_the_brows_and_a_pause_closes_the_eyes():
    """A phrase with a 6-semitone rise at 0.9 s, a 0.6 s pause, a flat phrase: one accent, at the
    rise (within 30 ms), the brows up around it and down in the flat phrase; a blink at the pause's
    start and none in either phrase."""
    x = np.r_[silence(0.4), voice(rise(0.5, 6.0), 1.0), silence(0.6), voice(lambda t: np.full_like(t, 120.0), 1.0),
              silence(0.1)]
    p = analyse(x, RATE)
    [(at, semitones)] = p.accents
    assert at == pytest.approx(0.9, abs=0.03) and 4.0 < semitones < 7.0
    assert any(abs(a - 1.4) < 0.03 and abs(b - 2.0) < 0.03 for a, b in p.pauses)
    blinks = blink_times(p)
    assert any(1.4 < b < 1.6 for b in blinks)
    assert not any(0.45 < b < 1.35 or 2.05 < b < 2.95 for b in blinks)
    names = list(APPLE_NAMES)
    fps = 50.0
    curves = prosody_curves(p, names, fps, int(x.size / RATE * fps))
    brow = curves[:, names.index("browInnerUp")]
    assert int(np.argmax(brow)) == pytest.approx(0.9 * fps, abs=2) and brow.max() > 0.3
    assert np.allclose(curves[:, [names.index(n) for n in BROWS]], brow[:, None])
    assert brow[int(2.1 * fps):int(3.0 * fps)].max() == 0.0
    others = [k for k, n in enumerate(names) if n not in BROWS and not n.startswith(("eyeBlink", "eyeLook"))]
    assert not curves[:, others].any() and curves.min() >= 0.0 and curves.max() <= 1.0


def test_a_bigger_rise_raises_the_brows_higher():
    small = analyse(np.r_[silence(0.3), voice(rise(0.5, 2.5), 1.0), silence(0.3)], RATE)
    big = analyse(np.r_[silence(0.3), voice(rise(0.5, 5.0), 1.0), silence(0.3)], RATE)
    names = list(APPLE_NAMES)
    peak = [prosody_curves(p, names, 50.0, 80)[:, names.index("browInnerUp")].max() for p in (small, big)]
    assert 0 < peak[0] < peak[1]


def test_long_speech_without_a_pause_still_blinks():
    """12 s of speech with no pause: blinks no more than BLINK_MAX_GAP apart, none at the very start."""
    x = voice(lambda t: 120 + 10 * np.sin(2 * np.pi * 0.7 * t), 12.0)
    blinks = blink_times(analyse(x, RATE))
    marks = [0.0, *blinks, 12.0]
    assert blinks and max(np.diff(marks)) <= BLINK_MAX_GAP + 1e-9


def test_the_same_sound_gives_the_same_curves_and_the_mouth_is_kept():
    rng = np.random.default_rng(3)
    x = np.r_[silence(0.3), voice(rise(0.6, 4.0), 1.2) + 0.01 * rng.standard_normal(int(1.2 * RATE)), silence(0.5)]
    names = list(APPLE_NAMES)
    mouth = np.zeros((100, len(names)))
    mouth[:, names.index("jawOpen")] = np.linspace(0, 1, 100)
    a, head_a, _ = with_prosody(mouth, names, x, RATE, 50.0)
    b, head_b, _ = with_prosody(mouth, names, x.copy(), RATE, 50.0)
    assert np.array_equal(a, b) and np.array_equal(head_a, head_b) and head_a.shape == (100, 3)
    assert np.array_equal(a[:, names.index("jawOpen")], mouth[:, names.index("jawOpen")])


@settings(max_examples=25, deadline=None)
@given(st.lists(st.one_of(st.floats(-1e6, 1e6), st.just(float("nan")), st.just(float("inf"))), max_size=4000),
       st.sampled_from([8000, 16000, 44100]))
def test_any_samples_give_curves_in_range(samples, rate):
    """Whatever the samples (empty, NaN, huge, silent), the curves are finite, in 0..1, one row a frame."""
    x = np.asarray(samples, dtype=np.float64)
    names = list(APPLE_NAMES)
    out = prosody_curves(analyse(x, rate), names, 25.0, 7)
    assert out.shape == (7, len(names)) and np.isfinite(out).all() and out.min() >= 0 and out.max() <= 1


def test_the_head_nods_after_a_phrases_last_accent_and_leans_phrase_by_phrase():
    """Two phrases, each with one rise: the head nods down (positive pitch) right after each accent
    (its deepest point within NOD_DOWN + 50 ms after it) and leans to one side over the first phrase,
    to the other over the second; it is still (under 1 mrad) before the first word."""
    from faceanim.drivers.speech.prosody import NOD_DOWN, prosody_head

    x = np.r_[silence(0.4), voice(rise(0.5, 5.0), 1.0), silence(0.6), voice(rise(0.6, 5.0), 1.0), silence(0.4)]
    p = analyse(x, RATE)
    assert len(p.accents) == 2
    fps = 100.0
    head = prosody_head(p, fps, int(x.size / RATE * fps))
    for (at, _), (a, b) in zip(p.accents, [(0.4, 1.4), (2.0, 3.0)]):
        window = slice(int(at * fps), int((at + 0.6) * fps))
        deepest = (int(at * fps) + int(np.argmax(head[window, 1]))) / fps
        assert 0 < deepest - at <= NOD_DOWN + 0.05 and head[window, 1].max() > 0.02
    first, second = head[int(0.9 * fps), 2], head[int(2.5 * fps), 2]
    assert first * second < 0 and min(abs(first), abs(second)) > 0.02
    assert np.abs(head[: int(0.1 * fps)]).max() < 1e-3  # the pitch's smoothing reaches a little before


def two_phrases(loud: float, quiet: float) -> np.ndarray:
    """A lively phrase (``loud`` amplitude, pitch swinging 8 semitones) and a flat one (``quiet``)."""
    lively = voice(lambda t: 120.0 * 2 ** (8 / 12 * (0.5 + 0.5 * np.sin(2 * np.pi * 2 * t))), 1.2)
    flat = voice(lambda t: np.full_like(t, 120.0), 1.2)
    return np.r_[silence(0.3), loud * lively, silence(0.6), quiet * flat, silence(0.3)]


def test_an_emotion_is_stronger_in_the_livelier_louder_phrase():
    """--emotion phrase by phrase: the lively loud phrase's intensity is over the one asked for and
    the flat quiet one's under it (by EMOTION_SPREAD, within EMOTION_RANGE); it is 0 at the clip's
    ends; swapping the phrases swaps the order; the ARKit curves carry exactly that envelope."""
    from faceanim.drivers.speech.lipsync import expression_mix
    from faceanim.drivers.speech.prosody import EMOTION_RANGE, emotion_intensity, phrase_arousal

    fps = 50.0
    x = two_phrases(1.0, 0.3)
    p = analyse(x, RATE)
    assert len(phrase_arousal(p)) == 2
    n = int(x.size / RATE * fps)
    level = emotion_intensity(p, 0.6, fps, n)
    first, second = level[int(0.9 * fps)], level[int(2.7 * fps)]
    assert 0.6 < first <= 0.6 * EMOTION_RANGE[1] + 1e-9 and 0.6 * EMOTION_RANGE[0] - 1e-9 <= second < 0.6
    assert level[0] == 0.0 and level[-1] == pytest.approx(0.0, abs=1e-9)
    swapped = analyse(np.r_[silence(0.3), 0.3 * voice(lambda t: np.full_like(t, 120.0), 1.2), silence(0.6),
                            x[int(0.3 * RATE):int(1.5 * RATE)], silence(0.3)], RATE)
    other = emotion_intensity(swapped, 0.6, fps, n)
    assert other[int(0.9 * fps)] < 0.6 < other[int(2.7 * fps)]
    from faceanim.drivers.speech.prosody import emotion_actions

    lively, flat = emotion_actions(p, "joy", 0.6, x.size / RATE - 0.3)  # the director's and .fap's, per phrase
    assert lively.intensity == pytest.approx(first, rel=1e-6) and flat.intensity == pytest.approx(second, rel=1e-6)
    assert lively.start == 0.0 and flat.start < lively.end
    names = list(APPLE_NAMES)
    curves, _, _ = with_prosody(np.zeros((n, len(names))), names, x, RATE, fps, "joy", 0.6)
    smile = names.index("mouthSmileLeft")
    assert curves[:, smile] == pytest.approx(np.clip(expression_mix("joy")["mouthSmileLeft"] * level, 0, 1))


def test_the_fap_actions_move_the_face_when_the_curves_do():
    """prosody_actions (the director's and .fap's) against prosody_curves/prosody_head of the same
    sound: the eyebrow raise peaks at the accent, the eyelids shut at the blink, head_pitch nods
    down at the phrase's last accent and rises with the pitch as the curve does (within 0.5 mrad),
    head_roll leans one way then the other."""
    from faceanim.drivers.mpeg4 import blend_actions
    from faceanim.drivers.speech.prosody import prosody_actions, prosody_head
    from faceanim.standards.mpeg4 import fap

    x = np.r_[silence(0.4), voice(rise(0.5, 5.0), 1.0), silence(0.6), voice(rise(0.6, 5.0), 1.0), silence(0.4)]
    p = analyse(x, RATE)
    fps = 100.0
    n = int(x.size / RATE * fps)
    stream = blend_actions(prosody_actions(p, 0.0), n, fps)
    names = list(APPLE_NAMES)
    curves, head = prosody_curves(p, names, fps, n), prosody_head(p, fps, n)

    def col(name):
        return stream.values[:, fap(name).number - 1]

    brow = col("raise_l_i_eyebrow")
    for at, _ in p.accents:
        w = slice(int((at - 0.3) * fps), int((at + 0.3) * fps))
        assert abs(np.argmax(brow[w]) - np.argmax(curves[w, names.index("browInnerUp")])) <= 2 and brow[w].max() > 100
    lid, shut = col("close_t_l_eyelid"), curves[:, names.index("eyeBlinkLeft")]
    from faceanim.drivers.speech.prosody import blink_times

    assert blink_times(p)
    for at in blink_times(p):
        w = slice(int(at * fps), int((at + 0.3) * fps))
        assert abs(np.argmax(lid[w]) - np.argmax(shut[w])) <= 1 and lid[w].max() > 1000
    assert lid[int(0.6 * fps):int(1.3 * fps)].max() == 0.0  # not inside the first phrase
    nod = col("head_pitch") * 1e-5
    for at, _ in p.accents:
        w = slice(int(at * fps), int((at + 0.6) * fps))
        assert abs(np.argmax(nod[w]) - np.argmax(head[w, 1])) <= 3 and nod[w].max() > 0.04
    # the nods with the slow rise with the pitch (an additive layer) are the curve's head pitch
    np.testing.assert_allclose(nod, head[:, 1], atol=5e-4)
    roll = col("head_roll")
    assert roll[int(0.9 * fps)] * roll[int(2.5 * fps)] < 0
    assert np.sign(roll[int(0.9 * fps)]) == np.sign(head[int(0.9 * fps), 2])


def _live(x: np.ndarray, chunk: int = 320) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """LiveProsody fed ``x`` in chunks: (times, brow and blink, head) after each chunk."""
    from faceanim.drivers.speech.prosody import LiveProsody

    live, names = LiveProsody(RATE), list(APPLE_NAMES)
    cols = [names.index("browInnerUp"), names.index("eyeBlinkLeft")]
    rows = []
    for k in range(0, len(x), chunk):
        live.feed(x[k:k + chunk])
        rows.append((live.time, live.curves(names)[cols], live.head()))
    t, face, head = zip(*rows)
    return np.array(t), np.array(face), np.array(head)


def test_live_prosody_follows_the_voice_as_it_comes():
    """``live --audio``'s prosody, heard 20 ms at a time: each brow raise peaks within 0.25 s after
    the offline accent, the eyes blink inside each pause (after BLINK_PAUSE of it) and never in a
    phrase, the head nods once each phrase is over and leans one way, then the other."""
    from faceanim.drivers.speech.prosody import BLINK_PAUSE

    x = np.r_[silence(0.4), voice(rise(0.5, 5.0), 1.0), silence(0.6), voice(rise(0.6, 5.0), 1.0), silence(0.5)]
    offline = analyse(x, RATE)
    t, face, head = _live(x)
    for (at, _), (a, b) in zip(offline.accents, [(0.4, 1.45), (2.0, 3.05)]):
        inside = (t > a) & (t < b)
        peak = t[inside][np.argmax(face[inside, 0])]
        assert 0.0 <= peak - at <= 0.25 and face[inside, 0].max() > 0.3
    shut = t[face[:, 1] > 0.5]
    for a, b in [(0.0, 0.4), (1.4, 2.0), (3.0, 3.5)]:  # the pauses
        assert np.any((shut > a + BLINK_PAUSE - 0.02) & (shut < b + 0.2))
    assert not np.any(((shut > 0.5) & (shut < 1.4)) | ((shut > 2.1) & (shut < 3.0)))
    nods = t[1:-1][(head[1:-1, 1] > head[:-2, 1]) & (head[1:-1, 1] >= head[2:, 1]) & (head[1:-1, 1] > 0.03)]
    assert len(nods) == 2 and 1.4 < nods[0] < 2.0 and 3.0 < nods[1] < 3.5
    assert head[np.searchsorted(t, 0.9), 2] * head[np.searchsorted(t, 2.5), 2] < 0
    assert np.abs(head[t < 0.35]).max() == 0.0


def test_live_eyes_look_away_in_a_long_phrase_and_come_back_when_it_ends():
    """Heard as it comes: in each 2 s phrase the eyes look aside LIVE_GAZE_AFTER into it (the
    first to the left, the second to the right) and are back within GAZE_TURN plus the pause's
    PAUSE_MIN after it ends; never in the 0.3 s phrase."""
    from faceanim.drivers.speech.prosody import GAZE_AWAY, LOOK_LEFT, LOOK_RIGHT, LiveProsody

    flat = lambda t: np.full_like(t, 120.0)  # noqa: E731
    x = np.r_[silence(0.4), voice(flat, 2.0), silence(0.6), voice(flat, 2.0), silence(0.6), voice(flat, 0.3),
              silence(0.6)]
    live, names = LiveProsody(RATE), list(APPLE_NAMES)
    rows = []
    for k in range(0, len(x), 320):
        live.feed(x[k:k + 320])
        c = live.curves(names)
        rows.append((live.time, c[names.index(LOOK_LEFT[0])], c[names.index(LOOK_RIGHT[0])]))
    t, left, right = np.array(rows).T
    assert left[(t > 1.2) & (t < 2.0)].min() == pytest.approx(GAZE_AWAY) and right[t < 3.0].max() == 0
    assert right[(t > 3.8) & (t < 4.6)].min() == pytest.approx(GAZE_AWAY) and left[t > 3.0].max() == 0
    assert left[(t > 2.85) & (t < 3.0)].max() == 0 and right[t > 5.45].max() == 0


def test_live_prosody_is_the_same_in_any_chunks_and_stays_small_for_hours():
    """The same sound in 20 ms or 7 ms chunks gives the same face at the same moments (to the
    pitch reading's 10 ms); minutes of silence keep blinking every BLINK_MAX_GAP and keep no
    more than LIVE_KEEP seconds of events."""
    from faceanim.drivers.speech.prosody import LIVE_KEEP, LiveProsody

    x = np.r_[silence(0.3), voice(rise(0.6, 4.0), 1.2), silence(0.5)]
    t1, f1, h1 = _live(x, 320)
    again = _live(x, 320)
    assert np.array_equal(f1, again[1]) and np.array_equal(h1, again[2])
    t2, f2, _ = _live(x, 112)
    for k in np.flatnonzero(np.isin(np.round(t2, 4), np.round(t1, 4)))[:: 5]:
        j = int(np.flatnonzero(np.round(t1, 4) == np.round(t2[k], 4))[0])
        assert np.abs(f2[k] - f1[j]).max() < 0.15
    live = LiveProsody(RATE)
    quiet = 1e-4 * np.random.default_rng(0).standard_normal(RATE)
    for _ in range(180):  # three minutes of a quiet room
        live.feed(quiet)
    assert len(live.blinks) <= LIVE_KEEP / BLINK_MAX_GAP + 1 and live.blinks
    assert live.phrase_index == -1 and not live.nods and not live.leans  # a room's hiss is not speech
    hiss = 0.05 * np.random.default_rng(1).standard_normal(RATE)
    for _ in range(30):  # loud steady noise (a fan by the microphone): heard as one phrase when it
        live.feed(hiss)  # starts, no longer once the last LIVE_HISTORY seconds are all of it
    assert live.phrase_index <= 0 and not live.speaking
    assert live.time - live.last_blink <= BLINK_MAX_GAP
    live.feed(np.full(320, np.nan))  # a broken chunk is silence
    assert np.isfinite(live.head()).all() and np.isfinite(live.curves(list(APPLE_NAMES))).all()


def test_the_eyes_look_away_as_a_long_phrase_begins_and_come_back_before_it_ends():
    """Two phrases of 2 s and a short one of 0.5 s: the eyes look aside (and a little up) early in
    each long phrase, to the left in the first and the right in the second, and are back on the
    listener before each ends; none in the short phrase; the two eyes turn the same way."""
    from faceanim.drivers.speech.prosody import GAZE_AWAY, GAZE_UP, LOOK_LEFT, LOOK_RIGHT, gaze_aversions

    flat = lambda t: np.full_like(t, 120.0)  # noqa: E731
    x = np.r_[silence(0.4), voice(flat, 2.0), silence(0.5), voice(flat, 2.0), silence(0.5), voice(flat, 0.5),
              silence(0.4)]
    p = analyse(x, RATE)
    assert [side for *_, side in gaze_aversions(p)] == [1, -1]
    names, fps = list(APPLE_NAMES), 100.0
    c = prosody_curves(p, names, fps, int(x.size / RATE * fps))
    left = c[:, [names.index(n) for n in LOOK_LEFT]]
    right = c[:, [names.index(n) for n in LOOK_RIGHT]]
    up = c[:, names.index("eyeLookUpLeft")]
    assert np.array_equal(left[:, 0], left[:, 1]) and np.array_equal(right[:, 0], right[:, 1])
    assert left[int(1.0 * fps), 0] == pytest.approx(GAZE_AWAY) and right[int(1.0 * fps)].max() == 0
    assert right[int(3.5 * fps), 0] == pytest.approx(GAZE_AWAY) and left[int(3.5 * fps)].max() == 0
    assert up[int(1.0 * fps)] == pytest.approx(GAZE_UP * GAZE_AWAY)
    for end in (2.4, 4.9):  # back on the listener for the phrase's last half
        assert left[int((end - 0.9) * fps):int(end * fps)].max() == 0
        assert right[int((end - 0.9) * fps):int(end * fps)].max() == 0
    assert c[int(5.3 * fps):, [names.index(n) for n in LOOK_LEFT + LOOK_RIGHT]].max() == 0
    # the .fap's and the director's eyeballs turn as perform.eye_angles reads these curves
    from faceanim.drivers.mpeg4 import blend_actions
    from faceanim.drivers.speech.prosody import prosody_actions
    from faceanim.perform import EYE_CONTROLS, eye_angles
    from faceanim.standards.mpeg4 import fap

    stream = blend_actions(prosody_actions(p), len(c), fps)
    eyes = eye_angles(c[:, [names.index(n) for n in EYE_CONTROLS[2:]]])
    for name, col in (("yaw_l_eyeball", 0), ("pitch_l_eyeball", 1), ("yaw_r_eyeball", 3), ("pitch_r_eyeball", 4)):
        np.testing.assert_allclose(stream.values[:, fap(name).number - 1] * 1e-5, eyes[:, col], atol=2e-3)
    assert eyes[int(1.0 * fps), 0] > 0.1 and eyes[int(3.5 * fps), 0] < -0.1  # to the left, then the right


def test_live_emotion_follows_each_phrase_as_the_offline_intensity_does():
    """``live --emotion``'s intensity multiplier, heard 20 ms at a time on a real voice said loud,
    then quiet, then loud: 0 before anyone speaks; the quiet phrase shows less of the emotion than
    either loud one; and the last phrase, judged against the two before it, ends where the offline
    ``emotion_intensity`` (which knows all three) has it."""
    import soundfile

    from faceanim.drivers.speech.prosody import EMOTION_RANGE, LiveProsody, emotion_intensity, phrases
    from conftest import DATA, need

    path = need(DATA / "speech-librivox" / "clip-0880.wav")
    x, rate = soundfile.read(str(path))
    gap = np.zeros(int(0.6 * rate))
    s = np.concatenate([gap, x, gap, 0.25 * x, gap, x, gap])
    s = s + 1e-4 * np.random.default_rng(0).standard_normal(len(s))  # a quiet room, not digital silence
    p = analyse(s, rate)
    spans = phrases(p)
    assert len(spans) == 3
    offline = emotion_intensity(p, 1.0, 100.0, int(len(s) / rate * 100))
    live, level = LiveProsody(rate), []
    for k in range(0, len(s), 320):
        live.feed(s[k:k + 320])
        level.append(live.emotion_level)
    level = np.array(level)
    at = lambda t: level[int(t / 0.02) - 1]  # noqa: E731 -- after the chunk that ends at t
    assert np.all(level[: int(0.55 / 0.02)] == 0.0)
    ends = [at(b) for _, b in spans]
    assert ends[1] < ends[0] and ends[1] < ends[2]
    assert all(EMOTION_RANGE[0] <= e <= EMOTION_RANGE[1] for e in ends)
    assert ends[2] == pytest.approx(offline[int(spans[2][1] * 100) - 1], abs=0.1)
    assert offline[int(spans[1][1] * 100) - 1] < offline[int(spans[0][1] * 100) - 1]  # the oracle agrees
