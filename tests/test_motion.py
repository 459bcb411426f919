"""Motion capture markers from ARKit takes played on the generic head (Chai et al. 2003, s. 3)."""

from __future__ import annotations

import numpy as np
import pytest

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
        play_take(head, ["tongueOut"], np.zeros((1, 1)), m)


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
