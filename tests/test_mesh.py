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
    # every triangle corner keeps its own UV (the head has UV seams, some through its quads)
    np.testing.assert_array_equal(back.faces, base_face.faces)
    np.testing.assert_array_equal(back.face_uv, base_face.face_uv)


def test_obj_writes_a_quad_split_by_a_uv_seam_as_its_triangles(tmp_path):
    """A quad whose two triangles give its diagonal's corners different UVs (an atlas seam along
    the diagonal) cannot be one OBJ polygon: it is written as two triangles, every corner's UV
    kept; the quad beside it stays a quad."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]], dtype=float)
    faces = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]])
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5], [0.6, 0.6], [2, 0], [2, 1]], dtype=float)
    face_uv = np.array([[0, 1, 2], [4, 5, 3], [1, 6, 7], [1, 7, 2]])  # triangle 1: corners 0, 2 elsewhere
    m = Mesh(v, faces, uv, face_uv, polygon_sizes=np.array([4, 4]))
    save_mesh(m, tmp_path / "seam.obj")
    back = load_mesh(tmp_path / "seam.obj")
    np.testing.assert_array_equal(back.faces, faces)
    np.testing.assert_allclose(back.uv[back.face_uv], uv[face_uv], atol=1e-9)
    np.testing.assert_array_equal(back.polygon_sizes, [3, 3, 4])


@pytest.mark.parametrize("suffix", [".ply", ".glb"])
def test_ply_and_glb_keep_vertex_order(tmp_path, base_face, suffix):
    """The head has UV seams: PLY keeps the vertices as they are and gives each triangle its corners'
    UVs; glTF adds seam copies after them, which reading maps back (``extras.sourceVertex``). Either
    way the mesh read back is the one written: its vertices in order, its triangles, every
    corner's UV."""
    assert len(base_face.uv) > base_face.n_vertices  # seams
    save_mesh(base_face, tmp_path / f"face{suffix}")
    back = load_mesh(tmp_path / f"face{suffix}")
    assert back.n_vertices == base_face.n_vertices
    np.testing.assert_allclose(back.vertices, base_face.vertices, atol=1e-6)
    np.testing.assert_array_equal(back.faces, base_face.faces)
    np.testing.assert_allclose(back.uv[back.face_uv], base_face.uv[base_face.face_uv], atol=1e-6)
    if suffix == ".glb":
        assert back.texture is not None and back.texture.shape[:2] == base_face.texture.shape[:2]


def test_a_glb_source_vertex_map_that_does_not_fit_is_not_applied(tmp_path):
    """Reading maps seam copies back only when ``sourceVertex`` is the writer's layout (the mesh's
    vertices first, in order; copies at their vertices' positions); otherwise the file is read as
    stored."""
    import pygltflib

    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5]], dtype=float)
    m = Mesh(v, np.array([[0, 1, 2], [0, 2, 3]]), uv, np.array([[0, 1, 2], [4, 2, 3]]))
    save_mesh(m, tmp_path / "s.glb")
    gltf = pygltflib.GLTF2().load(str(tmp_path / "s.glb"))
    assert gltf.meshes[0].primitives[0].extras == {"sourceVertex": [0, 1, 2, 3, 0]}
    assert load_mesh(tmp_path / "s.glb").n_vertices == 4
    for wrong in ([0, 1, 2, 3, 1], [1, 0, 2, 3, 0], [0, 1, 2, 3], [0, 1, 2, 3, "0"], [0, 1, 2, 3, -1]):
        gltf.meshes[0].primitives[0].extras = {"sourceVertex": wrong}
        gltf.save_binary(str(tmp_path / "w.glb"))
        back = load_mesh(tmp_path / "w.glb")
        assert back.n_vertices == 5, wrong
        np.testing.assert_allclose(back.vertices[back.faces], v[m.faces], atol=1e-6)


@pytest.mark.parametrize("suffix", [".ply", ".glb"])
def test_ply_and_glb_keep_per_vertex_uvs(tmp_path, suffix):
    """A mesh without seams: one UV per vertex, read back per vertex, nothing added."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.2]], dtype=float)
    m = Mesh(v, np.array([[0, 1, 2], [0, 2, 3]]), v[:, :2] * 0.5 + 0.1)
    save_mesh(m, tmp_path / f"q{suffix}")
    back = load_mesh(tmp_path / f"q{suffix}")
    np.testing.assert_allclose(back.vertices, v, atol=1e-6)
    np.testing.assert_array_equal(back.faces, m.faces)
    np.testing.assert_allclose(back.uv[back.face_uv], m.uv[m.faces], atol=1e-6)


def test_glb_with_seams_keeps_the_original_vertices_first(tmp_path):
    m = load_mesh(need(ICT / "generic_neutral_mesh.obj"))
    source, faces, uv = m.per_vertex_uv()
    assert np.array_equal(source[: m.n_vertices], np.arange(m.n_vertices))
    # every triangle corner keeps its position and its own UV
    np.testing.assert_array_equal(source[faces], m.faces)
    np.testing.assert_allclose(uv[faces], m.uv[m.face_uv])


def test_closest_points_are_exact_on_millimetre_triangles(base_face):
    """Points on the surface are their own closest points, on a mesh in metres with millimetre
    triangles (the default head; trimesh's absolute tolerances once moved 13% of them up to
    0.17 mm: a landmark file snapped beside itself), for the whole mesh and for a part of it."""
    rng = np.random.default_rng(7)
    tri = rng.integers(0, base_face.n_faces, 2000)
    bary = rng.dirichlet([1, 1, 1], 2000)
    pts = np.einsum("nk,nkd->nd", bary, base_face.vertices[base_face.faces[tri]])
    for allowed in (None, np.unique(tri)):
        pos, dist, got = base_face.closest_points(pts, allowed)
        np.testing.assert_allclose(pos, pts, atol=1e-12)
        assert dist.max() < 1e-12
        # the triangle found holds the point (a neighbour sharing the point's edge or corner may be found)
        b = base_face.barycentric(pts, got)
        assert b.min() > -1e-9 and b.max() < 1 + 1e-9
    # a point off the surface: its distance along the triangle's normal
    a, b, c = base_face.vertices[base_face.faces[tri[0]]]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n)
    pos, dist, _ = base_face.closest_points(pts[0] + 1e-4 * n)
    assert dist[0] <= 1e-4 + 1e-12


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


# ---------------------------------------------------------------------- damaged and hostile OBJ files
TRI = "v 0 0 0\nv 1 0 0\nv 0 1 0\n"
TRI_UV = TRI + "vt 0 0\nvt 1 0\nvt 0 1\n"
BAD_OBJ_LINES = {
    "inf vertex": (TRI + "v 1 1 inf\nf 1 2 4\n", r"line 4: NaN or infinite coordinates at vertex index 3"),
    "overflow vertex": ("v 1e400 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", r"line 1: NaN or infinite coordinates"),
    "nan uv": (TRI_UV.replace("vt 1 0", "vt nan 0") + "f 1/1 2/2 3/3\n", r"line 5: NaN or infinite texture"),
    "inf uv": (TRI_UV.replace("vt 0 1", "vt 0 -inf") + "f 1/1 2/2 3/3\n", r"line 6: NaN or infinite texture"),
    "absurd vertex": ("v 1e200 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", r"absurd coordinate .* vertex index 0"),
    "index 0": (TRI + "f 0 1 2\n", r"line 4: vertex index 0 in a face \(OBJ counts from 1\)"),
    "relative before first": (TRI + "f -1 -2 -4\n", r"line 4: relative vertex index -4 points before the first"),
    "huge index": (TRI + "f 1 2 99999999999999999999999\n", r"line 4: vertex index 9+ is absurdly large"),
    "index past the end": (TRI + "# c\nf 1 2 3\nf 1 2 7\n", r"line 6: a face indexes missing vertices \(vertex 7"),
    "uv index past the end": (TRI_UV + "f 1/1 2/2 3/9\n", r"line 7: a face indexes missing texture coordinates"),
    "face of one vertex": (TRI + "f 1\n", r"line 4: a face needs at least 3 corners, got 1"),
    "face of two": (TRI + "f 1 2\n", r"line 4: a face needs at least 3 corners, got 2"),
    "text index": (TRI + "f 1 2 three\n", r"line 4: malformed face: vertex index is not a whole number"),
    "float index": (TRI + "f 1 2 3.0\n", r"line 4: malformed face"),
    "too many slashes": (TRI + "f 1/1/1/1 2 3\n", r"line 4: malformed face corner"),
    "short vertex": ("v 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", r"line 1: malformed vertex .*needs 3 numbers, got 2"),
    "truncated": (TRI + "f 1 2 3\nv 0.5 0.", r"line 5: malformed vertex .*needs 3 numbers, got 2"),
    "no faces": (TRI, "empty"),
}


@pytest.mark.parametrize("case", list(BAD_OBJ_LINES))
def test_damaged_obj_names_the_line(tmp_path, case):
    text, message = BAD_OBJ_LINES[case]
    (tmp_path / "bad.obj").write_text(text)
    with pytest.raises(MeshError, match=message) as exc:
        load_mesh(tmp_path / "bad.obj")
    assert "\n" not in str(exc.value) and str(tmp_path / "bad.obj") in str(exc.value)


def test_binary_data_in_an_obj(tmp_path):
    (tmp_path / "bin.obj").write_bytes(TRI.encode() + b"f 1 2 3\n\x00\x01\x02garbage")
    with pytest.raises(MeshError, match=r"line 5: binary data in a text OBJ"):
        load_mesh(tmp_path / "bin.obj")
    (tmp_path / "latin1.obj").write_bytes(b"# caf\xe9\n" + TRI.encode() + b"f 1 2 3\n")
    assert load_mesh(tmp_path / "latin1.obj").n_faces == 1  # stray non-UTF-8 bytes in a comment are harmless


def test_relative_indices_count_from_the_current_line(tmp_path):
    # OBJ's negative indices are relative to the vertices read so far, not to the whole file
    (tmp_path / "rel.obj").write_text(TRI + "f -3 -2 -1\nv 5 5 5\nf -4 -3 -1\nvt 0\n")
    m = load_mesh(tmp_path / "rel.obj")
    np.testing.assert_array_equal(m.faces, [[0, 1, 2], [0, 1, 3]])
    assert m.uv is None  # the faces give no texture indices


def _textured_obj(tmp_path, image_bytes: bytes | None = None, size=(8, 8)):
    from PIL import Image

    (tmp_path / "t.obj").write_text("mtllib t.mtl\nusemtl skin\n" + TRI_UV + "f 1/1 2/2 3/3\n")
    (tmp_path / "t.mtl").write_text("newmtl skin\nmap_Kd -s 1 1 1 skin.png\n")
    if image_bytes is None:
        Image.new("RGB", size, (200, 150, 120)).save(tmp_path / "skin.png")
    else:
        (tmp_path / "skin.png").write_bytes(image_bytes)
    return tmp_path / "t.obj"


def test_texture_with_options_is_read(tmp_path):
    m = load_mesh(_textured_obj(tmp_path))
    assert m.texture.shape == (8, 8, 3) and (m.texture[0, 0] == [200, 150, 120]).all()


@pytest.mark.parametrize("data", [b"", b"\x89PNG\r\n\x1a\n" + b"\x00" * 40, b"GIF89a\xff\xff\xff\xff", b"not an image"])
def test_corrupt_texture_is_refused(tmp_path, data):
    with pytest.raises(MeshError, match=r"texture '.*skin.png' of mesh '.*t.obj' cannot be read \(damaged"):
        load_mesh(_textured_obj(tmp_path, data))


@pytest.mark.parametrize("pixels", [144, 1024])  # over the limit (a warning in Pillow) and over twice it (an error)
def test_decompression_bomb_texture_is_refused(tmp_path, monkeypatch, pixels):
    from PIL import Image

    side = int(pixels ** 0.5)
    obj = _textured_obj(tmp_path, size=(side, side))
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 100)
    with pytest.raises(MeshError, match="larger than 100 pixels .*decompression bombs"):
        load_mesh(obj)


def test_ply_header_that_promises_too_much(tmp_path):
    header = ("ply\nformat binary_little_endian 1.0\nelement vertex 1000000000\nproperty float x\n"
              "property float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\n"
              "end_header\n")
    (tmp_path / "big.ply").write_bytes(header.encode() + b"\0" * 64)
    with pytest.raises(MeshError, match="truncated: its PLY header promises more"):
        load_mesh(tmp_path / "big.ply")
    (tmp_path / "junk.ply").write_bytes(b"\x00\x01 not a ply")
    with pytest.raises(MeshError, match="is not a PLY file"):
        load_mesh(tmp_path / "junk.ply")


@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
def test_garbage_gltf_is_refused(tmp_path, suffix):
    (tmp_path / f"x{suffix}").write_bytes(b"glTF\x02\x00\x00\x00garbage" if suffix == ".glb" else b"{\"asset\": 3}")
    with pytest.raises(MeshError, match="damaged or not a valid|not a valid GLB file \\(damaged|empty|no triangle"):
        load_mesh(tmp_path / f"x{suffix}")


def test_a_folder_is_not_a_mesh(tmp_path):
    (tmp_path / "d.obj").mkdir()
    with pytest.raises(MeshError, match="is a folder"):
        load_mesh(tmp_path / "d.obj")


def test_a_pickled_mesh_answers_closest_point_queries_as_before():
    """A mesh sent to another process (faceanim batch ships bound faces to Dask workers) must not
    carry trimesh's spatial index: unpickled, that index finds no triangle (IndexError)."""
    import pickle

    from faceanim.face.face import Face

    face = Face.default()
    mesh = face.mesh
    skin = face.skin[mesh.faces].all(axis=1)
    points = mesh.vertices[::500] + 0.001
    before = mesh.closest_points(points, skin)
    again = pickle.loads(pickle.dumps(mesh)).closest_points(points, skin)
    for a, b in zip(before, again):
        assert np.array_equal(a, b)


def _trimesh_first_hits(mesh, origins, direction):
    """The oracle: trimesh's ray-triangle search, every hit, the nearest ahead of each origin."""
    dirs = np.broadcast_to(direction, origins.shape)
    locs, ray, _ = mesh.trimesh.ray.intersects_location(origins, dirs, multiple_hits=True)
    t = ((locs - origins[ray]) * dirs[ray]).sum(1)
    hit = np.zeros(len(origins), bool)
    pos = np.full(origins.shape, np.nan)
    order = np.lexsort((t, ray))
    first = order[np.r_[True, np.diff(ray[order]) != 0]] if len(order) else order
    hit[ray[first]] = True
    pos[ray[first]] = locs[first]
    return hit, pos


@pytest.mark.parametrize("which", ["default", "sphere"])
def test_parallel_rays_hit_what_trimesh_hits(which):
    """Rays that all go one way (some starting inside the mesh, some beside it) meet the same first
    surface points as trimesh's ray-triangle search, on the default face (open shells: eyes, teeth)
    and on a closed sphere, looking along an oblique direction."""
    import trimesh

    from faceanim.face.face import Face

    mesh = Face.default().mesh if which == "default" else Mesh(*(lambda s: (s.vertices, s.faces))(
        trimesh.creation.icosphere(subdivisions=4)))
    rng = np.random.default_rng(3)
    d = np.array([0.2, -0.3, -1.0])
    d /= np.linalg.norm(d)
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    origins = rng.uniform(lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo), (3000, 3)) - 0.2 * np.ptp(mesh.vertices) * d
    want_hit, want_pos = _trimesh_first_hits(mesh, origins, d)
    hit, pos, tri = mesh.cast_parallel(origins, d)
    assert 500 < hit.sum() < 3000
    np.testing.assert_array_equal(hit, want_hit)
    np.testing.assert_allclose(pos[hit], want_pos[hit], atol=1e-9)
    assert np.all(tri[~hit] == -1) and np.all(tri[hit] >= 0)
    # the hit point lies on the triangle given
    corners = mesh.vertices[mesh.faces[tri[hit]]]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    assert np.abs(np.einsum("ij,ij->i", pos[hit] - corners[:, 0], normal)).max() < 1e-9 * np.ptp(mesh.vertices) ** 2
    # cast_rays takes this path for parallel rays and gives the same
    same = mesh.cast_rays(origins, np.tile(d, (len(origins), 1)))
    np.testing.assert_array_equal(same[2], tri)
