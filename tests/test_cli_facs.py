"""faceanim au / transfer / preprocess: outputs match the library; bad input exits 2, no output."""

import json

import numpy as np
import pytest
from conftest import FACEWAREHOUSE, need
from gltf_reader import accessor

from faceanim.cli import main
from faceanim.face.face import Face, landmarks_478
from faceanim.face.landmarks import BASIC22, Landmarks
from faceanim.io.meshio import load_mesh, save_mesh
from faceanim.rig.transfer import ExpressionTransfer, default_model


@pytest.fixture(scope="module")
def base_lms(base_face):
    """The default face's 478 landmarks (on its triangles: they are not vertices of the head)."""
    from faceanim.face.default import default_landmarks

    return default_landmarks(base_face)


@pytest.fixture
def lm478(base_lms):
    """(478, 3) landmark positions of the default face, by MediaPipe index."""
    return base_lms.positions


@pytest.fixture
def face_files(tmp_path, base_face, lm478):
    mesh = tmp_path / "face.obj"
    save_mesh(base_face, mesh)
    path = tmp_path / "face.landmarks.json"
    path.write_text(json.dumps({"scheme": "mediapipe478", "points": [
        {"index": i, "position": lm478[i].tolist()} for i in range(478)]}))
    return mesh, path


def _at_landmarks(base_lms, base_face, values):
    """Per-vertex ``values`` (V, 3) at the landmarks (interpolated in their triangles)."""
    return base_lms.on(values, base_face.faces)


def _run(args, capsys=None):
    return main([str(a) for a in args])


def test_au_matches_the_library(tmp_path, face_files, base_face, base_lms, lm478):
    mesh, lm = face_files
    out = tmp_path / "au12.obj"
    assert _run(["au", mesh, "--au", "12", "--magnitude", "0.5", "--landmarks", lm, "-o", out]) == 0
    got = load_mesh(out)
    lms = landmarks_478(base_face, Landmarks.load(lm).attached_to(base_face))
    # the file's points are on the surface: kept as given (to 10 nm: the head's landmark
    # barycentrics are stored as float32, summing to 1 within 5e-8, so a landmark may sit 4 nm off
    # its triangle's plane and the snap puts it on the plane)
    np.testing.assert_allclose(lms, lm478, atol=1e-8)
    xf = ExpressionTransfer(Face(base_face, lms))
    want = base_face.vertices + xf.action_unit_delta(default_model(), 12, 0.5)
    np.testing.assert_allclose(got.vertices, want, atol=1e-7)
    assert got.n_vertices == base_face.n_vertices and got.texture is not None
    # independent of the library: AU12 (lip corner puller) raises and widens the mouth corners and
    # leaves the brows and forehead where they were (the landmarks lie inside triangles of the
    # head: their motion is the vertices' motion interpolated there)
    d, iod = got.vertices - base_face.vertices, np.linalg.norm(lm478[263] - lm478[33])
    d_lm = _at_landmarks(base_lms, base_face, d)
    up = xf.frame.rotation[1]
    assert d_lm[61] @ up > 0.01 * iod and d_lm[291] @ up > 0.01 * iod
    right_left = lm478[291] - lm478[61]
    assert (d_lm[291] - d_lm[61]) @ right_left > 0
    assert np.abs(d_lm[[10, 105, 334]]).max() < 1e-3 * iod  # forehead top, brows


def test_emotion_glb_carries_named_morph_targets(tmp_path, face_files):
    import pygltflib

    mesh, lm = face_files
    out = tmp_path / "joy.glb"
    assert _run(["au", mesh, "--emotion", "joy", "--landmarks", lm, "-o", out]) == 0
    gltf = pygltflib.GLTF2().load(str(out))
    names = gltf.meshes[0].extras["targetNames"]
    assert {"pose", "AU12", "AU6", "joy", "sadness", "surprise", "fear", "anger", "disgust"} <= set(names)
    # the 'pose' target is joy, and joy is the sum of its action units at their FACS intensities
    prim = gltf.meshes[0].primitives[0]
    target = {n: accessor(gltf, prim.targets[k]["POSITION"]) for k, n in enumerate(names)}
    np.testing.assert_allclose(target["pose"], target["joy"], atol=2e-6)
    from faceanim.rig.facs import default_library

    mix = default_library().emotion("joy")
    np.testing.assert_allclose(target["joy"], sum(w * target[f"AU{au}"] for au, w in mix.items()), atol=2e-5)
    # the animation takes 'pose' from 0 to 1 and back
    weights = accessor(gltf, gltf.animations[0].samplers[0].output).reshape(3, len(names))
    assert weights[:, names.index("pose")].tolist() == [0.0, 1.0, 0.0]


@pytest.mark.parametrize("extra, message", [
    (["--au", "99"], "unknown action unit AU99"),
    (["--au", "12", "--magnitude", "1.5"], "[0, 1]"),
    (["--emotion", "boredom"], "unknown emotion"),
    (["--au", "12", "--emotion", "joy"], "not both"),
    ([], "give --au"),
])
def test_au_bad_arguments(tmp_path, face_files, capsys, extra, message):
    mesh, lm = face_files
    out = tmp_path / "x.obj"
    assert _run(["au", mesh, "--landmarks", lm, "-o", out] + extra) == 2
    assert message in capsys.readouterr().err
    assert not out.exists() and not list(tmp_path.glob(".x*"))


def test_bad_landmarks(tmp_path, face_files, lm478, capsys):
    mesh, _ = face_files
    out = tmp_path / "x.obj"
    # too few landmarks
    few = tmp_path / "few.json"
    few.write_text(json.dumps({"points": [{"index": i, "position": lm478[i].tolist()}
                                          for i in (1, 4, 33)]}))
    assert _run(["au", mesh, "--au", "1", "--landmarks", few, "-o", out]) == 2
    assert "missing" in capsys.readouterr().err
    # on the surface but out of order: eye corners where the mouth corners are, chin at the forehead;
    # and mirrored: left and right eye corners, mouth corners and cheeks swapped
    for swaps in (((33, 61), (263, 291), (152, 10)), ((33, 263), (61, 291), (234, 454))):
        idx = np.arange(478)
        for a, b in swaps:
            idx[a], idx[b] = b, a
        bad = tmp_path / "bad_order.json"
        bad.write_text(json.dumps({"points": [{"index": i, "position": lm478[idx[i]].tolist()}
                                              for i in range(478)]}))
        assert _run(["au", mesh, "--au", "1", "--landmarks", bad, "-o", out]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "mirrored (left and right swapped) or out of order" in err
    # landmarks of another mesh (off this surface): 10 cm in front of the face (a head's surface
    # is all around it, so the face turned upside down, as for a face mask, would stay near one)
    far = tmp_path / "far.json"
    v = lm478 + [0.0, 0.0, 0.1]
    far.write_text(json.dumps({"points": [{"index": i, "position": v[i].tolist()} for i in range(478)]}))
    assert _run(["au", mesh, "--au", "1", "--landmarks", far, "-o", out]) == 2
    assert "from the surface" in capsys.readouterr().err
    # the basic 22 on three surface points only (repeated, all in one plane): degenerate TPS
    flat = tmp_path / "flat.json"
    pts = [{"index": i, "position": lm478[(4, 33, 263)[k % 3]].tolist()}
           for k, (_, i) in enumerate(BASIC22)]
    flat.write_text(json.dumps({"points": pts}))
    assert _run(["au", mesh, "--au", "1", "--landmarks", flat, "-o", out]) == 2
    assert "coplanar" in capsys.readouterr().err
    assert not out.exists()


def test_au_from_the_basic22_landmarks(tmp_path, face_files, base_face, lm478):
    """The thesis' path: only 22 landmarks; the rest come from the default face by TPS."""
    mesh, _ = face_files
    lm22 = tmp_path / "lm22.json"
    lm22.write_text(json.dumps({"points": [{"index": i, "name": n, "position": lm478[i].tolist()}
                                           for n, i in BASIC22]}))
    out = tmp_path / "au4.obj"
    assert _run(["au", mesh, "--au", "4", "--landmarks", lm22, "-o", out]) == 0
    moved = np.linalg.norm(load_mesh(out).vertices - base_face.vertices, axis=1)
    brow = lm478[[105, 334], 1].mean()
    assert moved[base_face.vertices[:, 1] > brow - 0.01].max() > moved[base_face.vertices[:, 1] < lm478[2, 1]].max()


def test_preprocess_writes_grid_and_landmarks(tmp_path, face_files):
    mesh, lm = face_files
    out = tmp_path / "grid.obj"
    assert _run(["preprocess", mesh, "--landmarks", lm, "--grid", "40", "-o", out]) == 0
    grid = load_mesh(out)
    assert 0.5 * 1600 < grid.n_vertices <= 1600
    pts = json.loads((tmp_path / "grid.landmarks.json").read_text())["points"]
    assert len(pts) == 478 and np.allclose(pts[4]["position"], 0, atol=0.05)  # nose tip at the origin


def test_transfer_from_a_real_scan_pair(tmp_path, face_files, base_face, base_lms, lm478):
    """A real smile (FaceWarehouse pose 2) transferred onto the default face: the mouth corners
    (AU12's points) rise and widen, the forehead stays, and the GLB's morph target is exactly
    the OBJ's displacement."""
    mesh, lm = face_files
    s0 = need(FACEWAREHOUSE / "pose_0.obj")
    args = ["transfer", "--source-neutral", s0, "--source-expressive", FACEWAREHOUSE / "pose_2.obj",
            "--target", mesh, "--landmarks", lm, "--au", "12", "--magnitude", "0.8"]
    assert _run(args + ["-o", tmp_path / "smile.obj"]) == 0
    assert _run(args + ["-o", tmp_path / "smile.glb"]) == 0
    from faceanim.io.meshio import load_mesh

    posed = load_mesh(tmp_path / "smile.obj").vertices
    d = posed - base_face.vertices
    # the landmarks lie in triangles of the head: followed onto the posed mesh
    rest, moved = lm478, base_lms.on(posed, base_face.faces)
    d_lm = moved - rest
    iod = np.linalg.norm(rest[263] - rest[33])
    right, left = 61, 291  # the mouth corners rise and move apart in a smile
    assert d_lm[right, 1] > 0.02 * iod and d_lm[left, 1] > 0.02 * iod
    width = np.linalg.norm(moved[left] - moved[right]) - np.linalg.norm(rest[left] - rest[right])
    assert width > 0.02 * iod
    assert np.abs(d_lm[10]).max() < 1e-3 * iod  # the top of the forehead does not move
    import pygltflib

    gltf = pygltflib.GLTF2().load(str(tmp_path / "smile.glb"))
    prim = gltf.meshes[0].primitives[0]
    assert gltf.meshes[0].extras["targetNames"] == ["expression"]
    target = accessor(gltf, prim.targets[0]["POSITION"])
    v = base_face.n_vertices  # seam copies of the UV layout follow the mesh's own vertices
    np.testing.assert_allclose(target[:v], d, atol=1e-6)  # the morph target at weight 1 is the pose


def test_preprocess_bad_reference(tmp_path, face_files, capsys):
    mesh, lm = face_files
    out = tmp_path / "grid.obj"
    assert _run(["preprocess", mesh, "--landmarks", lm, "--reference", tmp_path / "nope.npz", "-o", out]) == 2
    assert "does not exist" in capsys.readouterr().err
    bad = tmp_path / "bad.npz"
    bad.write_text("not a model")
    assert _run(["preprocess", mesh, "--landmarks", lm, "--reference", bad, "-o", out]) == 2
    assert "not an average face model" in capsys.readouterr().err
    assert not out.exists()
