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
    others = [k for k, n in enumerate(names) if n not in BROWS and not n.startswith("eyeBlink")]
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
    a, head_a = with_prosody(mouth, names, x, RATE, 50.0)
    b, head_b = with_prosody(mouth, names, x.copy(), RATE, 50.0)
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
