"""Mesh exchange: vertex count and order kept, UVs and texture kept, bad files refused."""

import numpy as np
import pytest
from conftest import FACEWAREHOUSE, ICT, need

from faceanim.errors import MeshError
from faceanim.face.mesh import Mesh
from faceanim.io.meshio import load_mesh, save_mesh


def _raw_obj_vertices(path):
    return np.array([l.split()[1:4] for l in open(path) if l.startswith("v ")], dtype=float)


@pytest.mark.parametrize("name", ["pose_0.obj"])
def test_real_quad_obj_with_uv_seams_round_trips(tmp_path, name):
    src = need(FACEWAREHOUSE / name)
    m = load_mesh(src)
    raw = _raw_obj_vertices(src)
    assert m.n_vertices == 11510 and np.array_equal(m.vertices, raw)  # order and count as stored
    assert m.n_faces == 2 * 11400  # quads triangulated
    assert len(m.uv) == 11558  # more UVs than vertices: seams
    moved = m.vertices + 0.01
    save_mesh(m, tmp_path / "out.obj", moved)
    back = load_mesh(tmp_path / "out.obj")
    np.testing.assert_allclose(back.vertices, moved, atol=1e-7)
    np.testing.assert_array_equal(back.faces, m.faces)
    np.testing.assert_allclose(back.uv, m.uv, atol=1e-7)
    np.testing.assert_array_equal(back.face_uv, m.face_uv)
    assert back.polygon_sizes is not None and (back.polygon_sizes == 4).all()  # quads written back


def test_textured_obj_round_trip_keeps_texture(tmp_path, base_face):
    written = save_mesh(base_face, tmp_path / "face.obj")
    assert {p.name for p in written} == {"face.obj", "face.mtl", "face.texture.png"}
    back = load_mesh(tmp_path / "face.obj")
    assert np.array_equal(back.texture, base_face.texture)
    np.testing.assert_allclose(back.uv, base_face.uv, atol=1e-7)


@pytest.mark.parametrize("suffix", [".ply", ".glb"])
def test_ply_and_glb_keep_vertex_order(tmp_path, base_face, suffix):
    save_mesh(base_face, tmp_path / f"face{suffix}")
    back = load_mesh(tmp_path / f"face{suffix}")
    assert back.n_vertices >= base_face.n_vertices
    np.testing.assert_allclose(back.vertices[: base_face.n_vertices], base_face.vertices, atol=1e-6)
    np.testing.assert_allclose(back.uv[: base_face.n_vertices], base_face.uv, atol=1e-6)
    if suffix == ".glb":
        assert back.texture is not None and back.texture.shape[:2] == base_face.texture.shape[:2]


def test_glb_with_seams_keeps_the_original_vertices_first(tmp_path):
    m = load_mesh(need(ICT / "generic_neutral_mesh.obj"))
    source, faces, uv = m.per_vertex_uv()
    assert np.array_equal(source[: m.n_vertices], np.arange(m.n_vertices))
    # every triangle corner keeps its position and its own UV
    np.testing.assert_array_equal(source[faces], m.faces)
    np.testing.assert_allclose(uv[faces], m.uv[m.face_uv])


BAD_FILES = {
    "empty.obj": ("# nothing\n", "empty"),
    "nan.obj": ("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n", "NaN or infinite coordinates.*index 1"),
    "broken.obj": ("v 0 0 zero\nf 1 2 3\n", "malformed"),
    "range.obj": ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "missing vertices"),
    "x.stl": ("solid\n", "unsupported format"),
}


@pytest.mark.parametrize("name", list(BAD_FILES))
def test_bad_mesh_files(tmp_path, name):
    text, message = BAD_FILES[name]
    (tmp_path / name).write_text(text)
    with pytest.raises(MeshError, match=message):
        load_mesh(tmp_path / name)


def test_missing_file_and_point_cloud(tmp_path):
    with pytest.raises(MeshError, match="does not exist"):
        load_mesh(tmp_path / "missing.obj")
    with pytest.raises(MeshError, match="no triangles"):
        Mesh(np.zeros((3, 3)), np.zeros((0, 3), dtype=int))
