"""Landmarks on untextured real heads, against geometric and data-driven oracles.

Tolerance: 5 % of the inter-ocular distance (outer eye corners). 2D landmark benchmarks count
a face as failed above about 8-10 % of this distance; a mouth corner on a scan is itself only
defined to a few percent, so 5 % is tight enough to catch a wrong point, a flipped side or a
ray that hit the back of the head, and loose enough for the real ambiguity of the anatomy.
"""

import numpy as np
import pytest
from conftest import FACEWAREHOUSE, ICT, need

from faceanim.errors import LandmarkError
from faceanim.face.landmarks import (
    Landmarks,
    detect_landmarks,
    detect_landmarks_in_image,
)
from faceanim.io.meshio import load_mesh

TOL = 0.05


def _nose_oracle(mesh, lm):
    """Pronasale: the most forward vertex between the eye line and the mouth, near the midline."""
    v = mesh.vertices
    iod = np.linalg.norm(lm["eye_outer_right"] - lm["eye_outer_left"])
    mid = (lm["eye_outer_right"] + lm["eye_outer_left"]) / 2
    band = (v[:, 1] < mid[1]) & (v[:, 1] > lm["mouth_corner_right"][1]) & (np.abs(v[:, 0] - mid[0]) < 0.3 * iod)
    return v[np.flatnonzero(band)[v[band, 2].argmax()]], iod


@pytest.fixture(scope="module")
def facewarehouse():
    m = load_mesh(need(FACEWAREHOUSE / "pose_0.obj"))
    m.texture = None  # detect on the shaded, untextured surface
    return m, detect_landmarks(m, scheme="basic22")


@pytest.fixture(scope="module")
def ict():
    m = load_mesh(need(ICT / "generic_neutral_mesh.obj"))
    return m, detect_landmarks(m, scheme="basic22")


@pytest.mark.parametrize("which", ["facewarehouse", "ict"])
def test_nose_tip(request, which):
    mesh, lm = request.getfixturevalue(which)
    nose, iod = _nose_oracle(mesh, lm)
    assert np.linalg.norm(lm["nose_tip"] - nose) < TOL * iod


def test_mouth_corners_facewarehouse(facewarehouse):
    """Oracle: the lateral ends of the scan's mouth opening (its boundary loop): within 0.06 IOD
    (the Face Landmarker's corners measured 0.053 IOD from the loop's ends, the legacy face mesh's
    under 0.05)."""
    mesh, lm = facewarehouse
    import trimesh

    edges = mesh.trimesh.edges_sorted
    loop = np.unique(edges[trimesh.grouping.group_rows(edges, require_count=1)])
    # the mouth opening: boundary vertices near the detected mouth, below the nose
    near = loop[np.linalg.norm(mesh.vertices[loop] - (lm["mouth_corner_left"] + lm["mouth_corner_right"]) / 2,
                               axis=1) < 0.5 * np.linalg.norm(lm["eye_outer_right"] - lm["eye_outer_left"])]
    pts = mesh.vertices[near]
    right, left = pts[pts[:, 0].argmin()], pts[pts[:, 0].argmax()]
    iod = np.linalg.norm(lm["eye_outer_right"] - lm["eye_outer_left"])
    assert np.linalg.norm(lm["mouth_corner_right"] - right) < 0.06 * iod
    assert np.linalg.norm(lm["mouth_corner_left"] - left) < 0.06 * iod


def test_mouth_corners_ict(ict):
    """Oracle: the vertex each one-sided smile blendshape of the ICT model moves most."""
    mesh, lm = ict
    iod = np.linalg.norm(lm["eye_outer_right"] - lm["eye_outer_left"])
    for side, name in [("L", "mouth_corner_left"), ("R", "mouth_corner_right")]:
        smile = load_mesh(ICT / f"mouthSmile_{side}.obj")
        corner = mesh.vertices[np.linalg.norm(smile.vertices - mesh.vertices, axis=1).argmax()]
        assert np.linalg.norm(lm[name] - corner) < TOL * iod


def test_landmarks_sit_on_the_surface_and_follow_it(ict, tmp_path):
    mesh, lm = ict
    _, dist, _ = mesh.closest_points(lm.positions)
    assert dist.max() < 1e-6 * mesh.bounding_box_diagonal
    np.testing.assert_allclose(lm.on(mesh), lm.positions, atol=1e-9)
    shifted = mesh.vertices + np.array([1.0, 2.0, 3.0])
    np.testing.assert_allclose(lm.on(shifted, mesh.faces), lm.positions + [1, 2, 3], atol=1e-9)
    lm.save(tmp_path / "lm.json")
    back = Landmarks.load(tmp_path / "lm.json")
    assert back.names == lm.names and back.indices.tolist() == lm.indices.tolist()
    np.testing.assert_allclose(back.positions, lm.positions)
    assert lm.indices[lm.names.index("mouth_corner_right")] == 61


def test_default_face_landmarks_are_found_again(face, face_landmarks):
    """Detection on the default face's own render recovers its built-in landmarks (found by the
    legacy face mesh when the face was built: the Face Landmarker's median 0.020, worst 0.089 IOD)."""
    lm = detect_landmarks(face, scheme="basic22")
    ref = face_landmarks.subset("basic22")
    iod = np.linalg.norm(ref["eye_outer_right"] - ref["eye_outer_left"])
    err = np.linalg.norm(lm.positions - ref.positions, axis=1) / iod
    assert np.median(err) < 0.03 and err.max() < 0.11


def test_no_face_found():
    noise = np.random.default_rng(0).integers(0, 255, size=(256, 256, 3), dtype=np.uint8)
    with pytest.raises(LandmarkError, match="no face found"):
        detect_landmarks_in_image(noise)


def test_no_face_in_a_mesh_render():
    import trimesh

    from faceanim.face.mesh import Mesh

    box = trimesh.creation.box()
    with pytest.raises(LandmarkError, match="no face found.*--forward"):
        detect_landmarks(Mesh(box.vertices, box.faces, name="box"))


def test_bad_landmark_file(tmp_path):
    (tmp_path / "bad.json").write_text('{"points": [{"name": "x", "position": [0, "a", 0]}]}')
    with pytest.raises(LandmarkError, match="invalid position"):
        Landmarks.load(tmp_path / "bad.json")


def test_2d_picks_ray_cast_onto_the_surface(face):
    """Seed section 2.2: a pick at a vertex's image position lands on that vertex."""
    from faceanim.face.landmarks import detection_view, pick_surface_points

    ids = [4, 61, 152, 334]  # nose tip, mouth corner, chin, brow
    with detection_view(face) as view:
        xy = view.project(face.vertices[ids])
    pos, tri = pick_surface_points(face, xy)
    err = np.linalg.norm(pos - face.vertices[ids], axis=1)
    assert err.max() < 2 * face.mean_edge_length
    for k, i in enumerate(ids):
        assert np.linalg.norm(face.vertices[face.faces[tri[k]]] - face.vertices[i], axis=1).min() < 3 * face.mean_edge_length
