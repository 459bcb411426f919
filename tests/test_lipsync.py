"""Lip sync on ARKit shapes (faceanim say): targets reached, co-articulation (dominance), closures,
vowel classes told apart on the default face's mesh, emotions, and the command's CSV."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from faceanim.drivers.speech.lipsync import (
    expression_curves,
    expression_mix,
    lipsync_curves,
    phone_target,
    speech_targets,
)
from faceanim.drivers.speech.phonemes import Phone
from faceanim.errors import FaceAnimError

FPS = 100.0
NAMES = ["jawOpen", "mouthClose", "mouthFunnel", "mouthPucker", "mouthStretchLeft", "mouthPressLeft",
         "mouthLowerDownLeft", "mouthRollLower", "mouthSmileLeft"]


def _at(curves, t, name):
    return curves[int(round(t * FPS)), NAMES.index(name)]


def _phones(spec):
    """[(phone, ms), ...] -> back-to-back Phones from 0.2 s."""
    out, t = [], 0.2
    for p, ms in spec:
        out.append(Phone(p, t, t + ms / 1000.0))
        t += ms / 1000.0
    return out


def test_a_held_vowel_reaches_its_target_and_the_mouth_rests_around_it():
    """A lone AA of 400 ms: in its middle every shape is AA's own (the jaw opened further for a
    vowel longer than its inherent 240 ms, at most by 15%); before and well after, rest."""
    curves = lipsync_curves(_phones([("AA", 400)]), NAMES, FPS, frames=int(1.2 * FPS))
    aa = phone_target("AA")["arkit"]
    assert _at(curves, 0.4, "jawOpen") == pytest.approx(min(1.0, aa["jawOpen"] * 1.15), abs=5e-3)
    assert _at(curves, 0.4, "mouthLowerDownLeft") == pytest.approx(aa["mouthLowerDownLeft"], abs=1e-3)
    assert _at(curves, 0.4, "mouthPucker") == 0.0
    assert np.abs(curves[0]).max() < 0.05 and np.abs(curves[-1]).max() < 0.05
    short = lipsync_curves(_phones([("AA", 120)]), NAMES, FPS)  # unstressed: a little less open
    assert short[:, 0].max() < 0.8 * curves[:, 0].max()


def test_a_bilabial_shuts_the_lips_whatever_the_jaw():
    """AA B AA: over the b, mouthClose equals jawOpen (ARKit's lips-together over an open jaw) and
    lets go in the vowels; on the default face's mesh the lips meet in the b and part in the vowels."""
    from faceanim.face.face import Face
    from faceanim.face.generic_head import generic_head
    from faceanim.rig.arkit import arkit_shapes
    from faceanim.rig.rig import Rig

    phones = _phones([("AA", 200), ("B", 80), ("AA", 200)])
    curves = lipsync_curves(phones, NAMES, FPS)
    mid_b = phones[1].centre
    assert _at(curves, mid_b, "mouthClose") == pytest.approx(_at(curves, mid_b, "jawOpen"))
    assert _at(curves, phones[0].centre, "mouthClose") < 0.01
    face = Face.default()
    shapes, _ = arkit_shapes(face)
    rig = Rig.from_blendshapes(face.mesh, {n: shapes[n] for n in NAMES})
    head = generic_head()

    def gap(t):
        v = rig.evaluate(curves[int(round(t * FPS))][None])[0]
        lm = head.landmarks(v) @ face.frame.rotation.T
        return (lm[13, 1] - lm[14, 1]) / face.frame.iod

    open_gap = gap(phones[0].centre)
    assert open_gap > 0.1  # a tenth of the eyes' distance
    assert gap(mid_b) < 0.1 * open_gap


def test_the_lips_keep_the_vowels_rounding_over_a_tongue_consonant():
    """UW T UW: the t barely rules the lips (the tongue makes it), so in its middle the lips stay
    rounded (pucker over 60% of UW's), while the same t between two IY is unrounded."""
    rounded = _phones([("UW", 200), ("T", 70), ("UW", 200)])
    spread = _phones([("IY", 200), ("T", 70), ("IY", 200)])
    c_r = lipsync_curves(rounded, NAMES, FPS)
    c_s = lipsync_curves(spread, NAMES, FPS)
    pucker = phone_target("UW")["arkit"]["mouthPucker"]
    assert _at(c_r, rounded[1].centre, "mouthPucker") > 0.6 * pucker
    assert _at(c_s, spread[1].centre, "mouthPucker") == 0.0
    assert _at(c_s, spread[1].centre, "mouthStretchLeft") > 0.6 * phone_target("IY")["arkit"]["mouthStretchLeft"]


def test_the_mouth_keeps_moving_across_a_gap_between_words():
    """'how now' with 100 ms between the words and no phone in it: the jaw never goes back to rest
    in the gap (no snapping shut between words); a pause (SIL) of 300 ms does bring it to rest."""
    gap = [Phone("HH", 0.2, 0.28), Phone("AW", 0.28, 0.5), Phone("N", 0.6, 0.66), Phone("AW", 0.66, 0.9)]
    curves = lipsync_curves(gap, NAMES, FPS)
    between = curves[int(0.5 * FPS):int(0.6 * FPS) + 1, 0]
    assert between.min() > 0.1
    pause = [Phone("AA", 0.2, 0.45), Phone("SIL", 0.45, 0.75), Phone("AA", 0.75, 1.0)]
    assert lipsync_curves(pause, NAMES, FPS)[int(0.6 * FPS), 0] < 0.05 * phone_target("AA")["arkit"]["jawOpen"]


def test_diphthongs_move_from_their_first_vowel_to_their_second():
    """AW is AA then UW: the jaw opens first, the lips round at the end."""
    phones = _phones([("AW", 300)])
    curves = lipsync_curves(phones, NAMES, FPS)
    early, late = phones[0].start + 0.06, phones[0].end - 0.06
    assert _at(curves, early, "jawOpen") > 2 * _at(curves, late, "jawOpen")
    assert _at(curves, late, "mouthPucker") > 0.5 and _at(curves, early, "mouthPucker") < 0.25
    assert [name for *_, name in speech_targets(phones)] == ["SIL", "AA", "UW", "SIL"]


def test_vowel_classes_differ_on_the_default_faces_mouth():
    """Held vowels of each class on the default face (its own ARKit shapes, the mouth measured on
    the mesh at MediaPipe's lip points): the lips part most for AA, then EH, then IY; IY's mouth is
    the widest and UW's the narrowest; AO's mouth is narrower than AA's and its inner lips rounder
    (width over height)."""
    from faceanim.face.face import Face
    from faceanim.face.generic_head import generic_head
    from faceanim.rig.arkit import arkit_shapes
    from faceanim.rig.rig import Rig

    face = Face.default()
    shapes, _ = arkit_shapes(face)
    rig = Rig.from_blendshapes(face.mesh, shapes)
    names = list(rig.controls)
    head = generic_head()
    m = {}
    for vowel in ("AA", "EH", "IY", "UW", "AO"):
        phones = _phones([(vowel, 250)])
        c = lipsync_curves(phones, names, FPS)[int(round(phones[0].centre * FPS))]
        lm = head.landmarks(rig.evaluate(c[None])[0]) @ face.frame.rotation.T
        gap = lm[13, 1] - lm[14, 1]
        m[vowel] = (gap, abs(lm[291, 0] - lm[61, 0]), abs(lm[308, 0] - lm[78, 0]) / max(gap, 1e-9))
    assert m["AA"][0] > 1.3 * m["EH"][0] > 1.3 * 1.3 * m["IY"][0] > 0
    assert m["IY"][1] > m["AA"][1] > m["UW"][1]
    assert m["IY"][1] > 1.1 * m["UW"][1]
    assert m["AO"][1] < 0.92 * m["AA"][1] and m["AO"][2] < 0.95 * m["AA"][2]


def test_emotions_as_arkit_mixes():
    joy = expression_mix("joy")
    assert joy["mouthSmileLeft"] > 0.5 and joy["cheekSquintRight"] > 0.3
    c = expression_curves("joy", NAMES, 101, FPS, intensity=0.5, ramp=0.1)
    k = NAMES.index("mouthSmileLeft")
    assert c[0, k] == 0.0 and c[50, k] == pytest.approx(0.5 * joy["mouthSmileLeft"]) and c[-1, k] == 0.0
    assert c[5, k] == pytest.approx(0.5 * c[50, k])  # half way up the ramp
    with pytest.raises(FaceAnimError, match="unknown expression 'glee'; choose one of: joy"):
        expression_mix("glee")


def test_nothing_to_say_is_refused():
    with pytest.raises(FaceAnimError, match="no speech"):
        lipsync_curves([], NAMES, FPS)


@pytest.mark.skipif(not shutil.which("espeak-ng"), reason="espeak-ng is not installed (scripts/setup.sh installs it)")
def test_say_writes_live_link_face_curves(tmp_path):
    """`say "bob" -o bob.csv`: the jaw opens for the vowel, the lips close for both b's
    (mouthClose up with the jaw), at Live Link Face's 52 columns."""
    from faceanim.cli import main
    from faceanim.io.arkit_csv import read_arkit_csv
    from faceanim.standards.arkit import ARKIT_NAMES

    out = tmp_path / "bob.csv"
    assert main(["say", "bob", "-o", str(out), "--fps", "60"]) == 0
    w = read_arkit_csv(out).weights
    jaw, close = w[:, ARKIT_NAMES.index("JawOpen")], w[:, ARKIT_NAMES.index("MouthClose")]
    assert w.shape[1] == 52
    assert jaw.max() > 0.3
    peak = int(np.argmax(jaw))
    assert close[:peak].max() > 0.05 and close[peak:].max() > 0.05  # a b before and after the vowel
    assert close[peak] < 0.2 * jaw[peak]
