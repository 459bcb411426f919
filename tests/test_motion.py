"""Motion capture markers from ARKit takes played on the generic head (Chai et al. 2003, s. 3)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from faceanim.build.motion import (
    FEATURE_LANDMARKS,
    N_MARKERS,
    head_rotation,
    marker_vertices,
    play_take,
)
from faceanim.drivers.video.tracking import FEATURE_NAMES, FEATURES
from faceanim.errors import FaceAnimError
from faceanim.face.generic_head import generic_head


def test_markers_are_the_tracked_features_and_spread_over_the_face():
    head = generic_head()
    m = marker_vertices(head)
    assert len(m) == N_MARKERS == len(set(m.tolist()))
    assert np.isin(m, head.parts["skin"]).all()
    # the first 19 are the video analysis's features, in its order, each within 3 mm of its landmark
    assert FEATURE_LANDMARKS == tuple(FEATURES[n] for n in FEATURE_NAMES)
    lm = head.landmarks()
    d = np.linalg.norm(head.mesh.vertices[m[:19]] - lm[list(FEATURE_LANDMARKS)], axis=1)
    assert d.max() < 0.003
    v = head.mesh.vertices[m]
    gaps = np.linalg.norm(v[:, None] - v[None], axis=2) + np.eye(len(v))
    assert gaps.min() > 0.005  # no two markers on one spot
    # they cover the face: from brow to chin and cheek to cheek
    assert np.ptp(v[:, 1]) > 0.12 and np.ptp(v[:, 0]) > 0.12
    np.testing.assert_array_equal(marker_vertices(head), m)  # deterministic


def test_play_take_is_the_weighted_shapes_turned_about_the_pivot():
    head = generic_head()
    m = marker_vertices(head)
    names = ["jawOpen", "mouthSmile_L"]
    curves = np.array([[0.0, 0.0], [1.0, 0.0], [0.3, 0.5]])
    pos = play_take(head, names, curves, m)
    np.testing.assert_allclose(pos[0], head.mesh.vertices[m])
    want = head.mesh.vertices[m] + 0.3 * head.shape("jawOpen")[m] + 0.5 * head.shape("mouthSmile_L")[m]
    np.testing.assert_allclose(pos[2], want, atol=1e-12)
    lower_lip = list(FEATURE_LANDMARKS).index(17)
    assert pos[1, lower_lip, 1] < pos[0, lower_lip, 1] - 0.005  # the jaw opens: the lower lip goes down
    rot = head_rotation(np.radians([0.0, 30.0, -20.0]), np.radians([0.0, 10.0, 0.0]), np.radians([0.0, 0.0, 5.0]))
    turned = play_take(head, names, curves, m, rot)
    np.testing.assert_allclose(turned[0], pos[0])  # no rotation in frame 0
    for f in (1, 2):  # a rigid turn: the distances between markers are kept
        a = np.linalg.norm(turned[f][:, None] - turned[f][None], axis=2)
        b = np.linalg.norm(pos[f][:, None] - pos[f][None], axis=2)
        np.testing.assert_allclose(a, b, atol=1e-12)
    with pytest.raises(FaceAnimError, match="no shape"):
        play_take(head, ["cheekRaiser_L"], np.zeros((1, 1)), m)  # in ICT's source, not among its 53


def test_head_rotation_angles():
    r = head_rotation(np.radians(90.0), 0.0, 0.0)[0]
    np.testing.assert_allclose(r @ [0, 0, 1], [1, 0, 0], atol=1e-12)  # yaw: the nose to the head's left
    r = head_rotation(0.0, np.radians(90.0), 0.0)[0]
    np.testing.assert_allclose(r @ [0, 0, 1], [0, -1, 0], atol=1e-12)  # pitch: the nose down
    r = head_rotation(0.0, 0.0, np.radians(90.0))[0]
    np.testing.assert_allclose(r @ [0, 1, 0], [-1, 0, 0], atol=1e-12)  # roll: the top to the head's right
    from faceanim.drivers.video.tracking import euler_degrees

    r = head_rotation(np.radians(25.0), np.radians(-12.0), np.radians(7.0))[0]
    np.testing.assert_allclose(euler_degrees(r), (25.0, -12.0, 7.0), atol=1e-9)  # the tracker's angles


def _rotation_errors(rot, truth):
    """Angles (degrees) between recovered and true rotations after the best global rotation (the
    factorisation's gauge is free)."""
    u, _, vt = np.linalg.svd(np.einsum("fji,fjk->ik", rot, truth))
    w = u @ vt
    return np.degrees(np.arccos(np.clip((np.einsum("fij,fij->f", rot @ w, truth) - 1) / 2, -1, 1)))


def test_factorisation_recovers_pose_and_bases_of_synthetic_data():
    """X_f = R_f sum_k c_fk S_k + T_f with 3 random bases: the rank-3L factorisation with rotation
    and basis constraints finds L = 3, the rotations exactly (up to the free global one), unit
    coefficients at its basis frames, and rebuilds every frame."""
    from faceanim.build.motion import factorise

    rng = np.random.default_rng(0)
    n_l, p_count, f_count = 3, 30, 200
    shapes = rng.normal(size=(n_l, 3, p_count))
    coeff = rng.normal(size=(f_count, n_l)) + np.array([2.0, 0.0, 0.0])
    rot = head_rotation(rng.uniform(-0.5, 0.5, f_count), rng.uniform(-0.3, 0.3, f_count), rng.uniform(-0.2, 0.2, f_count))
    x = np.einsum("fij,fkjp->fpi", rot, coeff[:, :, None, None] * shapes[None]) + rng.normal(size=(f_count, 1, 3))
    fa = factorise(x, energy=0.999999)
    assert fa.n_bases == 3
    assert _rotation_errors(fa.rotations, rot).max() < 1e-4
    np.testing.assert_allclose(fa.coefficients[fa.basis_frames], np.eye(3), atol=1e-8)
    rebuilt = np.einsum("fij,fpj->fpi", fa.rotations, fa.expression) + fa.translations[:, None]
    np.testing.assert_allclose(rebuilt, x, atol=1e-9)
    with pytest.raises(FaceAnimError, match="markers must be finite"):
        factorise(np.full((3, 5, 3), np.nan))


TAKE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "arkit-curves" / "alex_rom_3.csv"


def _turned_take():
    """The real take at 10 fps played on the markers and turned by a known smooth head sweep (yaw
    +-20, pitch +-10, roll +-8 degrees): (head, markers, take, rotations, marker positions)."""
    from faceanim.io.arkit_csv import read_arkit_csv

    head = generic_head()
    m = marker_vertices(head)
    take = read_arkit_csv(TAKE).resample(10.0)
    names, curves = take.ict_curves()
    t = take.times
    rot = head_rotation(np.radians(20) * np.sin(t / 7), np.radians(10) * np.sin(t / 5 + 1), np.radians(8) * np.sin(t / 3))
    return head, m, take, rot, play_take(head, names, curves, m, rot)


@pytest.mark.skipif(not TAKE.is_file(), reason="../shared/data/arkit-curves is not here")
def test_factorisation_separates_real_motion_from_a_known_head_motion():
    """The real ARKit take played on the markers, turned by a known head motion (a smooth sweep of
    yaw +-20, pitch +-10, roll +-8 degrees): the recovered rotations are within 1.5 degrees
    (median) of the applied ones, closer than a rigid Procrustes fit of each frame to one frame."""
    from faceanim.build.motion import factorise
    from faceanim.face.frame import similarity

    _, _, _, rot, x = _turned_take()
    fa = factorise(x)
    err = _rotation_errors(fa.rotations, rot)
    rigid = np.stack([similarity(x[0], x[f], scale=False)[1] for f in range(len(x))])
    base = _rotation_errors(rigid, rot)
    assert np.median(err) < 1.5 and np.median(err) < np.median(base) and np.percentile(err, 95) < np.percentile(base, 95)


@pytest.mark.skipif(not TAKE.is_file(), reason="../shared/data/arkit-curves is not here")
def test_stable_registration_beats_the_factorisation_on_real_motion():
    """Registration weighted towards the stillest markers (learnt from the data, no face model)
    recovers the known head motion of the real take within 0.4 degrees (median), at least three
    times closer than the factorisation, and its pose-free markers are within 1 mm of the markers
    played without any turn."""
    from faceanim.build.motion import factorise, rotation_error, stable_registration

    head, m, take, rot, x = _turned_take()
    rest = head.mesh.vertices[m]
    r, t, w = stable_registration(x, rest)
    err = rotation_error(r, rot)
    np.testing.assert_allclose(err, _rotation_errors(r, rot), atol=1e-9)  # one definition
    fact = rotation_error(factorise(x).rotations, rot)
    assert np.median(err) < 0.4 and np.median(err) * 3 < np.median(fact)
    names, curves = take.ict_curves()
    still = play_take(head, names, curves, m)
    y = np.einsum("fji,fpj->fpi", r, x - t[:, None])
    assert np.linalg.norm(y - still, axis=2).mean() < 1e-3
    # the heaviest markers are ones the expressions hardly move (the forehead, the nose bridge)
    most = np.max([np.linalg.norm(head.shape(n)[m], axis=1) for n in head.shape_names], axis=0)
    assert np.median(most[np.argsort(w)[-8:]]) < np.median(most)


@pytest.mark.skipif(not TAKE.is_file(), reason="../shared/data/arkit-curves is not here")
def test_control_parameters_of_the_markers_follow_the_recorded_curves():
    """The 15 control parameters read off the pose-free markers (the head turning all the while)
    follow what the performer did: the mouth opening is explained by the recorded mouth and jaw
    curves and not by the brows', the eye opening by the eye curves, the brow height by the brow
    curves (R^2 of linear fits over the take)."""
    from faceanim.build.motion import marker_controls, stable_registration
    from faceanim.face.controls import CONTROL_NAMES
    from faceanim.standards.arkit import ARKIT_NAMES

    head, m, take, _, x = _turned_take()
    rest = head.mesh.vertices[m]
    r, t, _ = stable_registration(x, rest)
    _, z, neutral = marker_controls(np.einsum("fji,fpj->fpi", r, x - t[:, None]))
    # measured from the typical face: the brows' and eyes' medians are 0, the closed mouth's too
    assert z.shape == (take.n_samples, 15) and 0 <= neutral < take.n_samples
    assert np.abs(np.median(z[:, [CONTROL_NAMES.index(n) for n in ("eye_open_L", "brow_raise_L")]], axis=0)).max() < 1e-9

    def explained(control, arkit):  # R^2 of a linear fit of the control to those curves
        a = z[:, CONTROL_NAMES.index(control)]
        x = np.c_[np.ones(len(a)), take.weights[:, [ARKIT_NAMES.index(n) for n in arkit]]]
        coef, *_ = np.linalg.lstsq(x, a, rcond=None)
        return 1 - (a - x @ coef).var() / a.var()

    mouth = ["JawOpen", "MouthClose", "MouthLowerDownLeft", "MouthLowerDownRight", "MouthUpperUpLeft",
             "MouthUpperUpRight", "MouthFunnel", "MouthPucker", "MouthRollLower", "MouthRollUpper",
             "MouthShrugLower", "MouthShrugUpper"]
    eye = ["EyeBlinkLeft", "EyeSquintLeft", "EyeWideLeft", "EyeLookDownLeft", "EyeLookUpLeft", "CheekSquintLeft"]
    brow = ["BrowDownLeft", "BrowOuterUpLeft", "BrowInnerUp"]
    for control, own, other in (("mouth_open", mouth, brow), ("eye_open_L", eye, mouth), ("brow_raise_L", brow, mouth)):
        assert explained(control, own) > 0.8 and explained(control, own) > explained(control, other) + 0.4, control


def _small_take(tmp_path):
    """A short synthetic take (jaw opening and closing, a blink) written as a Live Link Face CSV."""
    from faceanim.io.arkit_csv import read_arkit_csv
    from faceanim.standards.arkit import ARKIT_NAMES, EYE_NAMES, HEAD_NAMES

    rows = [",".join(["Timecode", "BlendShapeCount", *ARKIT_NAMES, *HEAD_NAMES, *EYE_NAMES])]
    for i in range(40):
        w = np.zeros(52)
        w[ARKIT_NAMES.index("JawOpen")] = 0.5 - 0.5 * np.cos(2 * np.pi * i / 40)
        w[ARKIT_NAMES.index("EyeBlinkLeft")] = 1.0 if 18 <= i <= 22 else 0.0
        head = [0.3 * np.sin(i / 6), 0.1 * np.cos(i / 5), 0.05 * np.sin(i / 4)]  # radians
        rows.append(",".join([f"00:00:{i // 30:02d}:{(2 * i) % 60:02d}.000", "61", *[f"{x:.5f}" for x in w],
                              *[f"{h:.5f}" for h in head], *["0"] * 6]))
    p = tmp_path / "take.csv"
    p.write_text("\n".join(rows) + "\n")
    return read_arkit_csv(p)


def test_database_of_a_take_with_its_recorded_head_motion(tmp_path):
    """build_database plays the take with its recorded head rotation, finds it again, and its
    controls show the jaw and the blink; save and load give the same database back."""
    from faceanim.build.motion import build_database, load_database
    from faceanim.face.controls import CONTROL_NAMES

    db = build_database([("take", _small_take(tmp_path))], fps=30.0)
    assert db.n_frames == 40 and db.markers.shape == (40, N_MARKERS, 3)
    # the recorded turns (up to 17 degrees) recovered within a degree
    assert np.percentile(db.rotation_error, 95) < 1.0
    mouth = db.controls[:, CONTROL_NAMES.index("mouth_open")]
    assert np.argmax(mouth) in range(17, 24) and mouth.max() > 0.3  # the jaw wide open mid-take
    eye = db.controls[:, CONTROL_NAMES.index("eye_open_L")]
    assert eye[20] < eye[10] - 0.2  # the blink
    db.save(tmp_path / "db.npz")
    back = load_database(tmp_path / "db.npz")
    np.testing.assert_allclose(back.controls, db.controls)
    np.testing.assert_allclose(back.markers, db.markers, atol=2e-5)  # motion stored as float16
    np.testing.assert_allclose(back.basis_curves, db.basis_curves)
    assert back.take_names == ("take",) and back.neutral == db.neutral
    # the deformation bases: orthonormal; the weights rebuild the motion; the bases written as the
    # head's shapes give back the recorded curves (the jaw and the blink)
    b = db.bases.reshape(db.n_bases, -1)
    np.testing.assert_allclose(b @ b.T, np.eye(db.n_bases), atol=1e-9)
    np.testing.assert_allclose(db.basis_weights(db.markers), db.weights, atol=1e-12)
    rebuilt = db.rest + np.einsum("fl,lpd->fpd", db.weights, db.bases)
    assert np.linalg.norm(rebuilt - db.markers, axis=2).mean() < 2e-4
    curves = db.weights @ db.basis_curves
    jaw = curves[:, db.curve_names.index("jawOpen")]
    blink = curves[:, db.curve_names.index("eyeBlink_L")]
    assert np.argmax(jaw) in range(18, 23) and jaw.max() > 0.9 and blink[20] > 0.9 and abs(blink[5]) < 0.1


def test_load_database_refuses_other_files(tmp_path):
    from faceanim.build.motion import load_database
    from faceanim.errors import InputFileError

    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(InputFileError, match="not a faceanim motion database"):
        load_database(tmp_path / "other.npz")
    with pytest.raises(InputFileError, match="does not exist"):
        load_database(tmp_path / "none.npz")
    (tmp_path / "bad.npz").write_bytes(b"PK\x03\x04 broken")
    with pytest.raises(InputFileError, match="not a readable .npz"):
        load_database(tmp_path / "bad.npz")


def test_a_database_for_other_control_parameters_is_refused(tmp_path):
    from faceanim.build.motion import build_database, load_database
    from faceanim.errors import InputFileError

    db = build_database([("take", _small_take(tmp_path))], fps=30.0)
    db.control_names = tuple(f"other_{k}" for k in range(15))
    db.save(tmp_path / "db.npz")
    with pytest.raises(InputFileError, match="built for other control parameters"):
        load_database(tmp_path / "db.npz")


def test_mocap_build_command(tmp_path, capsys):
    from faceanim.build.motion import load_database
    from faceanim.cli import main

    _small_take(tmp_path)
    out = tmp_path / "db.npz"
    assert main(["mocap", "build", str(tmp_path / "take.csv"), "-o", str(out)]) == 0
    assert "40 frames from 1 take(s)" in capsys.readouterr().out
    assert load_database(out).n_frames == 40
    before = sorted(tmp_path.iterdir())
    bad = tmp_path / "bad.csv"
    bad.write_text("Timecode,EyeBlinkLeft\n")
    assert main(["mocap", "build", str(bad), "-o", str(tmp_path / "x.npz")]) == 2
    assert "lacks the column" in capsys.readouterr().err
    assert sorted(tmp_path.iterdir()) == sorted([*before, bad])


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.binary(max_size=300))
def test_database_reader_takes_any_bytes(tmp_path, blob):
    from faceanim.build.motion import load_database

    p = tmp_path / "x.npz"
    p.write_bytes(blob)
    with pytest.raises(FaceAnimError) as exc:
        load_database(p)
    assert "\n" not in str(exc.value)
