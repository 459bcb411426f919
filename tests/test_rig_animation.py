"""Expressions as GDE sets driven by d, mixtures, and key-frame interpolation."""

import numpy as np
import pytest

from faceanim.deform import bind_gdes
from faceanim.demo import demo_expressions
from faceanim.drivers.keyframes import KeyframeAnimation, expression_tour
from faceanim.errors import DeformError, FaceAnimError
from faceanim.rig.expressions import expression_rig
from faceanim.rig.rig import Rig, RigidPart


@pytest.fixture(scope="module")
def rig(face, face_landmarks):
    return expression_rig(face, demo_expressions(face_landmarks))


def test_expression_blendshape_is_its_gdes_at_full_offset(rig, face, face_landmarks):
    smile = demo_expressions(face_landmarks)[0]
    direct = bind_gdes(face, smile.elements).apply(smile.offsets)
    np.testing.assert_allclose(rig.pose({"smile": 1.0}), direct, atol=1e-12)
    np.testing.assert_allclose(rig.pose({"smile": 0.0}), face.vertices, atol=0)
    half = rig.pose({"smile": 0.5}) - face.vertices
    np.testing.assert_allclose(half, 0.5 * (direct - face.vertices), atol=1e-12)


def test_mixture_adds_blendshapes(rig, face):
    mix = rig.pose({"smile": 0.7, "A": 0.4}) - face.vertices
    parts = 0.7 * (rig.pose({"smile": 1}) - face.vertices) + 0.4 * (rig.pose({"A": 1}) - face.vertices)
    np.testing.assert_allclose(mix, parts, atol=1e-12)


def test_expressions_move_what_they_should(rig, face, face_landmarks):
    # the landmarks lie inside triangles of the head: followed onto each pose
    rest = face_landmarks.positions
    smile = face_landmarks.on(rig.pose({"smile": 1.0}), face.faces)
    assert smile[61, 1] > rest[61, 1] + 0.004 and smile[291, 1] > rest[291, 1] + 0.004  # mouth corners
    a_pose = rig.pose({"A": 1.0})
    a = face_landmarks.on(a_pose, face.faces)
    assert a[152, 1] < rest[152, 1] - 0.01  # the chin drops
    assert np.array_equal(a[10], rest[10])  # the forehead does not move
    top = face.faces[face_landmarks.triangles[10]]  # nor do the vertices around it
    assert np.array_equal(a_pose[top], face.vertices[top])


def test_evaluate_matches_pose_per_frame(rig):
    tour = expression_tour(rig.names)
    t, w = tour.sample(10)
    frames = rig.evaluate(w)
    for f in [0, len(t) // 3, len(t) - 1]:
        np.testing.assert_allclose(frames[f], rig.pose(w[f]), atol=1e-12)


def test_keyframes_pass_through_keys_and_stay_in_range():
    anim = KeyframeAnimation.from_keys(["a", "b"], [(0, {}), (1, {"a": 1}), (2, {"a": 0.2, "b": 1}), (3, {})])
    np.testing.assert_allclose(anim.at([0, 1, 2, 3]), [[0, 0], [1, 0], [0.2, 1], [0, 0]], atol=1e-12)
    t, w = anim.sample(100)
    assert w.min() >= -1e-12 and w.max() <= 1 + 1e-12  # monotone cubic: no overshoot
    lin = KeyframeAnimation.from_keys(["a"], [(0, {}), (2, {"a": 1})], "linear")
    np.testing.assert_allclose(lin.at([0.5, 1.0]), [[0.25], [0.5]])


def test_bad_controls(rig):
    with pytest.raises(DeformError, match="unknown control"):
        rig.pose({"grin": 1})
    with pytest.raises(FaceAnimError, match="strictly increasing"):
        KeyframeAnimation.from_keys(["a"], [(1, {}), (0, {})])


def test_rig_evaluate_is_the_sum_of_blendshapes(face):
    """Oracle: rest + sum_c w_c B_c, summed directly with numpy, dense and sparse rigs alike."""
    rng = np.random.default_rng(3)
    v = face.n_vertices
    shapes = {f"s{k}": np.where(rng.random((v, 1)) < 0.1, rng.normal(size=(v, 3)), 0.0) for k in range(4)}
    curves = rng.uniform(-1, 1, size=(7, 4))
    want = face.vertices[None] + np.einsum("fc,cvd->fvd", curves, np.stack(list(shapes.values())))
    for sparse in (True, False):
        rig = Rig.from_blendshapes(face, shapes, sparse=sparse)
        np.testing.assert_allclose(rig.evaluate(curves), want, atol=1e-12)
        # the same operator through the general handle form: offsets[f, 3c + a, a] = w[f, c]
        off = np.zeros((7, 12, 3))
        for a in range(3):
            off[:, a::3, a] = curves
        np.testing.assert_allclose(rig.deformer.apply(off), want, atol=1e-12)


def test_rigid_part_turns_exactly_and_linearises_to_its_derivative(face):
    """A rigid part's rotation matches scipy's Rotation, and Rig.linearised is the finite
    difference of the true motion at the neutral pose."""
    from scipy.spatial.transform import Rotation

    rows = np.flatnonzero(face.vertices[:, 1] < np.median(face.vertices[:, 1]))
    pivot = face.vertices[rows].mean(0)
    part = RigidPart("lower", rows, np.ones(len(rows)), pivot, np.eye(3),
                     rotations=[("turn", 1, 0.01), ("nod", 0, 0.02)], translations=[("shift", np.array([0, 0, 0.001]))])
    rig = Rig.from_blendshapes(face, {}, controls=["turn", "nod", "shift"], rigid_parts=[part])
    got = rig.pose({"turn": 30.0, "nod": -10.0, "shift": 5.0})
    r = Rotation.from_euler("YX", [0.3, -0.2]).as_matrix()  # intrinsic: yaw, then pitch in the turned frame
    want = (face.vertices[rows] - pivot) @ r.T + pivot + [0, 0, 0.005]
    np.testing.assert_allclose(got[rows], want, atol=1e-12)
    others = np.setdiff1d(np.arange(face.n_vertices), rows)
    assert np.array_equal(got[others], face.vertices[others])
    for name in ("turn", "nod", "shift"):
        h = 1e-4
        fd = (rig.pose({name: h}) - rig.pose({name: -h})) / (2 * h)
        np.testing.assert_allclose(rig.linearised(name), fd, atol=1e-7)
