import numpy as np
import pytest
from conftest import FACEWAREHOUSE, need
from scipy.interpolate import RBFInterpolator

from faceanim.deform.rbf import landmark_tps
from faceanim.deform.surface import bind_surface, cotangent_laplacian
from faceanim.errors import FaceAnimError, LandmarkError
from faceanim.face.face import Face, landmarks_478
from faceanim.face.mesh import Mesh
from faceanim.face.regions import face_region
from faceanim.rig.facs import ActionUnitError, default_library, region_weights
from faceanim.rig.transfer import ExpressionTransfer, default_model


def grid_mesh(n=21):
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    v = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, 1:].ravel(), i[1:, :-1].ravel()
    return Mesh(v, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]))


def test_cotangent_laplacian_is_zero_on_linear_functions_inside():
    m = grid_mesh()
    lap, area = cotangent_laplacian(m.vertices, m.faces)
    f = 2 * m.vertices[:, 0] - 3 * m.vertices[:, 1]
    inner = (m.vertices[:, :2] > 0.01).all(1) & (m.vertices[:, :2] < 0.99).all(1)
    assert np.abs(lap @ f)[inner].max() < 1e-10
    assert np.isclose(area.sum(), 1.0)  # the unit square


def test_surface_deformer_hits_handles_and_keeps_fixed_vertices():
    m = grid_mesh()
    free = (np.abs(m.vertices[:, :2] - 0.5) < 0.4).all(1)
    tri = np.array([210, 172, 610])  # cells in the free middle
    bary = np.array([[0.2, 0.3, 0.5], [1, 0, 0], [0.1, 0.1, 0.8]])
    op = bind_surface(m.vertices, m.faces, tri, bary, free)
    d = np.array([[0, 0, 0.1], [0, 0.05, 0], [0.02, 0, -0.03]])
    moved = op.apply(d)
    got = np.einsum("nk,nkd->nd", bary, moved[m.faces[tri]])
    want = np.einsum("nk,nkd->nd", bary, m.vertices[m.faces[tri]]) + d
    assert np.allclose(got, want, atol=1e-9)
    assert np.array_equal(moved[~free], m.vertices[~free])
    # linear in the offsets
    assert np.allclose(op.displacements(2 * d), 2 * op.displacements(d))


def test_landmark_tps_matches_scipy_and_refuses_coplanar(rng):
    src = rng.normal(size=(22, 3))
    dst = src + 0.1 * rng.normal(size=(22, 3))
    warp = landmark_tps(src, dst)
    q = rng.normal(size=(50, 3))
    ref = RBFInterpolator(src, dst - src, kernel="thin_plate_spline", degree=1)(q) + q
    assert np.allclose(warp(q), ref, atol=1e-8)
    assert np.allclose(warp(src), dst, atol=1e-9)
    flat = src.copy()
    flat[:, 2] = 0
    with pytest.raises(LandmarkError, match="coplanar"):
        landmark_tps(flat, dst)
    with pytest.raises(FaceAnimError):
        landmark_tps(np.vstack([src, src[:1]]), np.vstack([dst, dst[:1]]))


def test_library_parsing_and_errors():
    lib = default_library()
    assert len(lib.point_names) <= 60
    for au in (1, 2, 4, 5, 6, 7, 9, 10, 12, 14, 15, 16, 17, 20, 23, 25, 26):
        unit = lib.action_unit(au)
        assert unit.region in ("upper", "lower") and unit.muscle and unit.points
    assert lib.parse_action_units("AU1, 2") == [1, 2]
    for sloppy in ("12,", ",12", "1,,2", "", " , "):  # an empty item is a typo, never dropped
        with pytest.raises(ActionUnitError, match="no empty item"):
            lib.parse_action_units(sloppy)
    with pytest.raises(ActionUnitError, match="AU12 is given twice"):
        lib.parse_action_units("12,AU12")
    assert lib.intensity("E") == 1.0 and lib.intensity("0.5") == 0.5
    assert lib.emotion("happiness") == lib.emotion("joy")
    with pytest.raises(ActionUnitError, match="AU3"):
        lib.action_unit(3)
    with pytest.raises(ActionUnitError, match=r"\[0, 1\]"):
        lib.intensity(1.2)
    with pytest.raises(ActionUnitError, match="emotion"):
        lib.emotion("boredom")
    assert lib.action_unit(12).points_on("R") and not any(p.endswith("_L") for p in lib.action_unit(12).points_on("R"))


@pytest.fixture(scope="module")
def transfer(face, face_landmarks):
    lm = landmarks_478(face, face_landmarks)
    return ExpressionTransfer(Face(face, lm))


def test_brow_action_never_moves_the_mouth_and_the_reverse(transfer, face, face_landmarks):
    model = default_model()
    lm = transfer.lm
    w = region_weights(face.vertices, lm, default_library())
    brow = np.linalg.norm(transfer.action_unit_delta(model, 4), axis=1)
    smile = np.linalg.norm(transfer.action_unit_delta(model, 12), axis=1)
    mouth = w["upper"] == 0
    eyes = w["lower"] == 0
    assert mouth.sum() > 100 and eyes.sum() > 100
    assert brow.max() > 0.05 * transfer.frame.iod and smile.max() > 0.05 * transfer.frame.mouth_width
    assert brow[mouth].max() == 0 and smile[eyes].max() == 0


def test_one_sided_action_moves_one_side(transfer, face):
    d = np.linalg.norm(transfer.action_unit_delta(default_model(), 12, side="L"), axis=1)
    x = transfer.frame.to_local(face.vertices)[:, 0]  # + towards the subject's left
    assert d[x > 0].sum() > 20 * d[x < 0].sum()


def test_magnitude_scales_linearly(transfer):
    m = default_model()
    assert np.allclose(transfer.action_unit_delta(m, 1, 0.3), 0.3 * transfer.action_unit_delta(m, 1, 1.0))


def test_rebuild_real_expression_beats_landmark_tps():
    """The thesis' test on a real scan pair: smile (pose_2) rebuilt from 60 control points."""
    from faceanim.face.frame import rigid_align
    from faceanim.face.landmarks import detect_landmarks
    from faceanim.io.meshio import load_mesh
    from faceanim.rig.transfer import learn_expression, skull_vertices

    n = load_mesh(need(FACEWAREHOUSE / "pose_0.obj"))
    e = load_mesh(FACEWAREHOUSE / "pose_2.obj")
    lm = landmarks_478(n, detect_landmarks(n))
    xf = ExpressionTransfer(Face(n, lm))
    stable = skull_vertices(n, lm, xf.frame)
    r, t = rigid_align(e.vertices[stable], n.vertices[stable])
    real = e.vertices @ r.T + t - n.vertices
    face = face_region(n, lm)
    sample = learn_expression(n, e, lm)
    rebuilt = xf.points_delta(sample, default_library().parse_action_units("all"))
    err = np.linalg.norm((rebuilt - real)[face]) / np.linalg.norm(real[face])
    assert err < 0.4  # measured 0.27; no motion is 1.0, the 22-landmark TPS ~0.5


def test_learning_without_correspondence_recovers_a_known_motion(face, face_landmarks):
    """Thesis 5.5.3 on a synthetic pair: landmark TPS + snapping finds the control points' motion."""
    from faceanim.face.frame import face_frame
    from faceanim.face.landmarks import Landmarks
    from faceanim.rig.transfer import learn_expression

    lm = landmarks_478(face, face_landmarks)
    y = face.vertices[:, 1]
    chin_y, mouth_y = lm[152, 1], lm[14, 1]
    t = np.clip((mouth_y - y) / (mouth_y - chin_y), 0, 1)
    shift = np.array([0.0, -0.006, 0.0])  # 6 mm down, growing from the mouth to the chin
    expressive = face.with_vertices(face.vertices + t[:, None] * shift)
    moved = Landmarks(face_landmarks.scheme, face_landmarks.names, face_landmarks.indices,
                      face_landmarks.on(expressive), face_landmarks.triangles, face_landmarks.barycentric)
    sample = learn_expression(face, expressive, lm, landmarks_478(expressive, moved), method="landmarks")
    frame = face_frame(lm)
    chin = frame.vectors_to_mesh(sample.displacements[sample.names.index("chin")]) * frame.mouth_width
    brow = frame.vectors_to_mesh(sample.displacements[sample.names.index("brow_inner_R")]) * frame.iod
    assert abs(chin[1] - shift[1]) < 0.15 * abs(shift[1])
    assert np.linalg.norm(brow) < 0.1 * abs(shift[1])


def test_target_without_a_face_region_is_refused(base_face, rng):
    from faceanim.face.default import default_landmarks
    from faceanim.face.regions import free_region

    lm = default_landmarks(base_face).positions.copy()
    away = base_face.with_vertices(base_face.vertices + [0.0, 0.0, -1.0])  # the face 1 m behind its landmarks
    with pytest.raises(LandmarkError, match="face outline"):
        free_region(away, lm)


def test_aus_from_one_scan_share_its_measurement(transfer):
    """AU1 and AU2 were both learned from the brow raise: together they rebuild it once, not twice."""
    model = default_model()
    assert model.samples[1].source == model.samples[2].source
    both = transfer.mixture_delta(model, {1: 1.0, 2: 1.0})
    one_scan = model.samples[1]
    names = sorted(set(model.samples[1].names) | set(model.samples[2].names))
    merged = {n: d for s in (model.samples[1], model.samples[2]) for n, d in zip(s.names, s.displacements)}
    from faceanim.rig.transfer import ExpressionSample

    want = transfer.delta(ExpressionSample(names, np.array([merged[n] for n in names]), one_scan.source))
    np.testing.assert_allclose(both, want, atol=1e-12)
    # AUs from different scans add
    mix = transfer.mixture_delta(model, {4: 0.5, 12: 0.7})
    np.testing.assert_allclose(mix, transfer.action_unit_delta(model, 4, 0.5) + transfer.action_unit_delta(model, 12, 0.7),
                               atol=1e-12)
