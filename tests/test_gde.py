"""Geometry deformation elements: region search, anchors, locality, the paper's algorithm."""

import numpy as np
import pytest
from scipy.sparse import csgraph

from faceanim.deform import GeometryDeformationElement as GDE
from faceanim.deform import bind_gdes, element_influence
from faceanim.errors import DeformError


def test_edge_metric_region_is_the_bfs_ball(face, face_landmarks):
    root = int(face.kdtree.query(face_landmarks["mouth_corner_left"])[1])  # the head's vertex at a mouth corner
    b = element_influence(face, GDE(tuple(face.vertices[root]), 6, "edges"))
    # oracle: hop distances from scipy's breadth-first search
    hops = csgraph.shortest_path(face.adjacency.astype(float), unweighted=True, indices=root)
    np.testing.assert_array_equal(b.region, np.flatnonzero(hops <= 6))
    np.testing.assert_array_equal(np.sort(b.boundary), np.flatnonzero(hops == 6))
    assert b.root == root


def test_euclidean_metric_region_is_connected_ball(face, face_landmarks):
    c = face_landmarks["brow_inner_left"]
    b = element_influence(face, GDE(tuple(c), 0.015, "euclidean"))
    d = np.linalg.norm(face.vertices[b.region] - c, axis=1)
    assert d.max() <= 0.015
    # every vertex of the ball that is connected to the root inside the ball is found
    inside = np.flatnonzero(np.linalg.norm(face.vertices - c, axis=1) <= 0.015)
    sub = face.adjacency[inside][:, inside]
    _, labels = csgraph.connected_components(sub, directed=False)
    root_label = labels[np.searchsorted(inside, b.root)]
    np.testing.assert_array_equal(b.region, inside[labels == root_label])


def test_locality_outside_regions_is_bit_identical_and_anchors_fixed(face, face_landmarks):
    elements = [GDE(tuple(face_landmarks["mouth_corner_left"]), 0.02, "euclidean"),
                GDE(tuple(face_landmarks["brow_inner_right"]), 8, "edges")]
    deformer = bind_gdes(face, elements)
    out = deformer.apply(np.array([[0.004, 0.006, -0.002], [0.0, 0.005, 0.0]]))
    bound = [element_influence(face, e) for e in elements]
    region = np.unique(np.concatenate([b.region for b in bound]))
    outside = np.setdiff1d(np.arange(face.n_vertices), region)
    assert np.array_equal(out[outside], face.vertices[outside])  # bit-identical
    fixed = np.concatenate([b.boundary for b in bound])
    assert np.array_equal(out[fixed], face.vertices[fixed])  # every anchor stays put
    for b in bound:
        assert len(b.anchors) <= 20
        assert np.abs(out[b.moving] - face.vertices[b.moving]).max() > 1e-3


def test_control_point_moves_by_its_offset(face, face_landmarks):
    # a control point on a vertex (the head's vertex nearest the chin landmark, which lies inside a
    # triangle): the vertex is where the interpolant is exact
    root = int(face.kdtree.query(face_landmarks["chin"])[1])
    c = face.vertices[root]
    off = np.array([0.0, -0.01, 0.0])
    exact = bind_gdes(face, [GDE(tuple(c), 0.03, "euclidean", smoothing=0.0)])
    assert element_influence(face, GDE(tuple(c), 0.03, "euclidean")).root == root
    np.testing.assert_allclose(exact.apply(off[None])[root] - face.vertices[root], off, atol=1e-12)
    # with the paper's lambda = 0.01 the control point is approximated, not matched
    smooth = bind_gdes(face, [GDE(tuple(c), 0.03, "euclidean")])
    moved = smooth.apply(off[None])[root] - face.vertices[root]
    assert 0.5 < moved[1] / off[1] < 1.0


def test_control_point_off_the_vertices(face):
    """A control point inside a triangle (paper step 1) binds to its nearest vertex."""
    tri = face.faces[1000]
    p = face.vertices[tri].mean(0)
    b = element_influence(face, GDE(tuple(p), 5, "edges"))
    assert b.root in tri
    assert b.moving.size > 10


def test_anchors_sampled_evenly_around_the_control_point(face, face_landmarks):
    c = face_landmarks["cheek_left"]
    b = element_influence(face, GDE(tuple(c), 0.02, "euclidean"))
    assert b.boundary.size > 20 and b.anchors.size == 20
    rel = face.vertices[b.anchors] - c
    normal = face.vertex_normals()[b.root]
    u = np.cross(normal, [0, 1, 0]); u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    angles = np.sort(np.arctan2(rel @ v, rel @ u))
    gaps = np.diff(np.r_[angles, angles[0] + 2 * np.pi])
    assert gaps.max() < 3 * (2 * np.pi / 20)  # no large sector without an anchor


def test_zero_extent_is_vertex_manipulation(face):
    v = 5000
    d = bind_gdes(face, [GDE(tuple(face.vertices[v]), 0, "edges")])
    out = d.apply(np.array([[0.001, 0.002, 0.003]]))
    moved = np.flatnonzero(np.any(out != face.vertices, axis=1))
    assert moved.tolist() == [v]
    np.testing.assert_allclose(out[v] - face.vertices[v], [0.001, 0.002, 0.003])


def test_edge_metric_keeps_the_upper_lip_still(face, face_landmarks):
    """The paper's figure 3: an edge-metric element on the lower lip leaves the upper lip."""
    d = bind_gdes(face, [GDE(tuple(face_landmarks["lower_lip_inner"]), 12, "edges")])
    out = d.apply(np.array([[0.0, -0.008, 0.0]]))
    upper = [0, 13, 37, 267, 82, 312]  # upper-lip landmarks, each inside a triangle of the upper lip
    corners = np.unique(face.faces[face_landmarks.triangles[upper]])
    assert np.array_equal(out[corners], face.vertices[corners])
    moved = face_landmarks.on(out, face.faces)
    assert np.array_equal(moved[upper], face_landmarks.positions[upper])
    assert moved[14, 1] < face_landmarks.positions[14, 1] - 0.004  # the lower lip's middle goes down


def test_bad_elements(face):
    with pytest.raises(DeformError, match="from the surface"):
        element_influence(face, GDE((0.0, 0.0, 1.0), 4))
    with pytest.raises(DeformError, match="unknown metric"):
        element_influence(face, GDE(tuple(face.vertices[0]), 4, "geodesic"))
    with pytest.raises(DeformError, match="whole number"):
        element_influence(face, GDE(tuple(face.vertices[0]), 2.5, "edges"))
    with pytest.raises(DeformError, match="NaN"):
        element_influence(face, GDE((np.nan, 0.0, 0.0), 4))


def test_sparse_batch_equals_frame_by_frame(face, face_landmarks, rng):
    """Long batches run on threads; every frame must equal its own single-frame result."""
    names = ["mouth_corner_left", "mouth_corner_right", "chin", "brow_inner_left"]
    d = bind_gdes(face, [GDE(tuple(face_landmarks[n]), 0.02, "euclidean") for n in names])
    frames = rng.normal(scale=0.003, size=(300, 4, 3))
    batch = d.apply(frames)
    for f in [0, 149, 150, 299]:
        assert np.array_equal(batch[f], d.apply(frames[f]))


def test_unmoved_vertices_keep_their_bits_even_negative_zero(face, face_landmarks):
    rest = face.vertices.copy()
    far = np.flatnonzero(np.linalg.norm(rest - face_landmarks["chin"], axis=1) > 0.05)[:10]
    rest[far, 0] = -0.0
    from faceanim.face.mesh import Mesh

    m = Mesh(rest, face.faces)
    d = bind_gdes(m, [GDE(tuple(face_landmarks["chin"]), 0.02, "euclidean")])
    for out in (d.apply(np.array([[0, -0.01, 0]])), d.apply(np.zeros((200, 1, 3)) + [0, -0.01, 0])[150]):
        assert np.array_equal(out[far].view(np.uint64), rest[far].view(np.uint64))
