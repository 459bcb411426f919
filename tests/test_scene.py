"""Whole avatars (faceanim.io.scene): read a skinned multi-mesh GLB/VRM, add morph targets to one mesh,
write it back with everything else unchanged.

The synthetic avatar is built here with pygltflib and checked against numpy by hand (node matrices,
linear-blend skinning at the stored pose); the GLB container and the accessors of the written files
are decoded by hand from the glTF spec, not with the module under test.
"""

import json
import math
import os
import shutil
import struct
from pathlib import Path

import numpy as np
import pygltflib as g
import pytest
from conftest import DATA, ROOT, need

from faceanim.errors import FaceAnimError, InputFileError, MeshError
from faceanim.io.files import OutputError
from faceanim.io.scene import read_scene, weld, write_scene

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

VROID = DATA / "avatars" / "vroid-sample.glb"
_DTYPES = {5120: "<i1", 5121: "<u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


# ====================================================================== oracles (by hand, from the spec)
def glb_parts(path) -> tuple[dict, bytes]:
    """The JSON and BIN chunks of a GLB file, read by hand."""
    data = Path(path).read_bytes()
    assert data[:4] == b"glTF" and struct.unpack_from("<I", data, 8)[0] == len(data)
    n = struct.unpack_from("<I", data, 12)[0]
    assert data[16:20] == b"JSON"
    doc = json.loads(data[20:20 + n])
    pos, binary = 20 + n, b""
    if pos < len(data):
        m = struct.unpack_from("<I", data, pos)[0]
        assert data[pos + 4:pos + 8] == b"BIN\0"
        binary = data[pos + 8:pos + 8 + m]
    return doc, binary


def pack_glb(doc: dict, binary: bytes) -> bytes:
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    body = struct.pack("<I", len(text)) + b"JSON" + text
    if binary:
        body += struct.pack("<I", len(binary)) + b"BIN\0" + binary
    return b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body


def decode(doc: dict, binary: bytes, index: int) -> np.ndarray:
    """Accessor ``index`` (dense, strided or sparse) as stored, (count, width)."""
    a = doc["accessors"][index]
    dtype, width = np.dtype(_DTYPES[a["componentType"]]), _WIDTH[a["type"]]
    if "bufferView" in a:
        view = doc["bufferViews"][a["bufferView"]]
        stride = view.get("byteStride") or width * dtype.itemsize
        start = view.get("byteOffset", 0) + a.get("byteOffset", 0)
        rows = start + np.arange(a["count"])[:, None] * stride + np.arange(width * dtype.itemsize)[None, :]
        out = np.frombuffer(binary, np.uint8)[rows].view(dtype)
    else:
        out = np.zeros((a["count"], width), dtype)
    if "sparse" in a:
        sp = a["sparse"]
        iv, vv = doc["bufferViews"][sp["indices"]["bufferView"]], doc["bufferViews"][sp["values"]["bufferView"]]
        idx = np.frombuffer(binary, _DTYPES[sp["indices"]["componentType"]], sp["count"],
                            iv.get("byteOffset", 0) + sp["indices"].get("byteOffset", 0))
        assert np.all(np.diff(idx.astype(np.int64)) > 0)
        out = out.copy()
        out[idx] = np.frombuffer(binary, dtype, sp["count"] * width,
                                 vv.get("byteOffset", 0) + sp["values"].get("byteOffset", 0)).reshape(-1, width)
    return out


def view_bytes(doc: dict, binary: bytes, k: int) -> bytes:
    v = doc["bufferViews"][k]
    return binary[v.get("byteOffset", 0):v.get("byteOffset", 0) + v["byteLength"]]


def assert_originals_kept(before, after):
    """Every buffer view, accessor (JSON and decoded data), node, skin, material, animation, image,
    texture, extension of ``before`` is in ``after`` unchanged (mesh JSON is checked by the tests)."""
    (d0, b0), (d1, b1) = before, after
    for k in range(len(d0.get("bufferViews", []))):
        assert d1["bufferViews"][k] == d0["bufferViews"][k]
        assert view_bytes(d1, b1, k) == view_bytes(d0, b0, k)
    for k in range(len(d0.get("accessors", []))):
        assert d1["accessors"][k] == d0["accessors"][k]
        a0, a1 = decode(d0, b0, k), decode(d1, b1, k)
        assert a0.dtype == a1.dtype and a0.tobytes() == a1.tobytes()
    for key in ("skins", "materials", "textures", "images", "samplers", "scenes", "scene", "asset", "extensions",
                "extensionsUsed", "extensionsRequired", "cameras"):
        assert d1.get(key) == d0.get(key), key
    for k, node in enumerate(d0.get("nodes", [])):
        assert {a: b for a, b in d1["nodes"][k].items() if a != "weights"} == \
            {a: b for a, b in node.items() if a != "weights"}


def trs(t=(0, 0, 0), q=(0, 0, 0, 1), s=(1, 1, 1)) -> np.ndarray:
    x, y, z, w = q
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    m = np.eye(4)
    m[:3, :3] = r * np.asarray(s, float)[None, :]
    m[:3, 3] = t
    return m


def quat(axis, degrees):
    a = np.asarray(axis, float) / np.linalg.norm(axis) * math.sin(math.radians(degrees) / 2)
    return [float(a[0]), float(a[1]), float(a[2]), math.cos(math.radians(degrees) / 2)]


# ====================================================================== the synthetic avatar
ARMATURE = dict(t=[0.5, 0.0, 0.0], q=quat([0, 1, 0], 30))
HIPS = dict(t=[0.0, 1.0, 0.0])
NECK = dict(t=[0.0, 0.5, 0.0], q=quat([0, 0, 1], 20))  # posed: the bind pose has no rotation
HEAD_OFFSET = dict(t=[0.1, 1.6, 0.05], q=quat([1, 0, 0], 10), s=[0.5, 0.6, 0.4])  # a non-uniform scale
HEAD_MATRIX = trs(t=[0.0, 0.1, 0.0], q=quat([0, 1, 0], 90))
QUANT = trs(t=[0.0, 0.9, 0.0], s=[0.8, 0.8, 0.8])  # bind space -> world baked into the IBMs (glTF-Transform)

CUBE = np.array([[x, y, z] for y in (-0.5, 0.5) for z in (-0.5, 0.5) for x in (-0.5, 0.5)], dtype=np.float32)
CUBE_FACES = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                       [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]], dtype=np.uint16)
CUBE_JOINTS = np.array([[0, 0, 0, 0]] * 4 + [[0, 1, 0, 0]] * 4, dtype=np.uint8)
CUBE_WEIGHTS = np.array([[1, 0, 0, 0]] * 4 + [[0.25, 0.75, 0, 0]] * 4, dtype=np.float32)
QUAD = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float32)
QUAD_FACES = np.array([0, 1, 2, 0, 2, 3], dtype=np.uint16)
FAN = np.array([[1, 0, 0], [1, 1, 0], [2, 0.5, 0], [2, 1, 0.2], [1.5, 1.5, 0.3]], dtype=np.float32)
FAN_FACES = np.array([0, 2, 1, 1, 2, 3, 1, 3, 4], dtype=np.uint8)
SMILE = (np.arange(12, dtype=np.float32).reshape(4, 3) / 100, np.arange(15, dtype=np.float32).reshape(5, 3) / 50)
BLINK_ROWS, BLINK_VALUES = np.array([3, 4], dtype=np.uint16), np.array([[0, -0.1, 0], [0, -0.2, 0.05]], np.float32)
VRM_EXTENSION = {"specVersion": "1.0",
                 "meta": {"name": "cube", "authors": ["test"], "licenseUrl": "https://vrm.dev/licenses/1.0/"},
                 "expressions": {"preset": {"happy": {"morphTargetBinds": [{"node": 5, "index": 0, "weight": 1.0}]}}}}


class _Buf:
    def __init__(self):
        self.data, self.views, self.accessors = bytearray(), [], []

    def view(self, raw: bytes, target=None) -> int:
        while len(self.data) % 4:
            self.data.append(0)
        self.views.append(g.BufferView(buffer=0, byteOffset=len(self.data), byteLength=len(raw), target=target))
        self.data.extend(raw)
        return len(self.views) - 1

    def add(self, a, comp, kind, target=None, minmax=False, normalized=False) -> int:
        a = np.ascontiguousarray(a)
        acc = g.Accessor(bufferView=self.view(a.tobytes(), target), componentType=comp, count=len(a), type=kind)
        if minmax:
            acc.min = [float(x) for x in np.atleast_1d(a.min(0))]
            acc.max = [float(x) for x in np.atleast_1d(a.max(0))]
        if normalized:
            acc.normalized = True
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def zeros(self, count, rows=None, values=None) -> int:
        """A VEC3 float accessor without a buffer view (zeros), optionally sparse."""
        full = np.zeros((count, 3), np.float32)
        acc = g.Accessor(componentType=g.FLOAT, count=count, type=g.VEC3, byteOffset=None)
        if rows is not None:
            full[rows] = values
            acc.sparse = g.Sparse(count=len(rows),
                                  indices=g.AccessorSparseIndices(bufferView=self.view(rows.tobytes()),
                                                                  componentType=g.UNSIGNED_SHORT),
                                  values=g.AccessorSparseValues(bufferView=self.view(values.tobytes())))
        acc.min, acc.max = [float(x) for x in full.min(0)], [float(x) for x in full.max(0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1


def bind_inverse(neck_bind_rotation=False):
    """The inverse bind matrices: each joint's bind-pose global inverted, times the bind-space map."""
    arm = trs(ARMATURE["t"], ARMATURE["q"])
    hips = arm @ trs(HIPS["t"])
    neck_bind = hips @ trs(NECK["t"])  # bound before the neck was turned
    return [np.linalg.inv(hips) @ QUANT, np.linalg.inv(neck_bind) @ QUANT]


def globals_by_hand():
    arm = trs(ARMATURE["t"], ARMATURE["q"])
    hips = arm @ trs(HIPS["t"])
    neck = hips @ trs(NECK["t"], NECK["q"])
    head = trs(HEAD_OFFSET["t"], HEAD_OFFSET["q"], HEAD_OFFSET["s"]) @ HEAD_MATRIX
    return {"hips": hips, "neck": neck, "head": head}


def build_avatar(lines=False) -> g.GLTF2:
    """Two meshes: a skinned 'Body' cube (2 joints) and an unskinned 'Head' of two primitives (a quad and
    a fan; two morph targets, one sparse), an animation (a neck rotation and the head's weights), two
    materials and a VRMC_vrm extension."""
    buf = _Buf()
    body_attrs = g.Attributes(POSITION=buf.add(CUBE, g.FLOAT, g.VEC3, g.ARRAY_BUFFER, minmax=True),
                              TEXCOORD_0=buf.add(CUBE[:, :2] + 0.5, g.FLOAT, g.VEC2, g.ARRAY_BUFFER),
                              JOINTS_0=buf.add(CUBE_JOINTS, g.UNSIGNED_BYTE, g.VEC4, g.ARRAY_BUFFER),
                              WEIGHTS_0=buf.add(CUBE_WEIGHTS, g.FLOAT, g.VEC4, g.ARRAY_BUFFER))
    body = g.Primitive(attributes=body_attrs, material=0,
                       indices=buf.add(CUBE_FACES.ravel(), g.UNSIGNED_SHORT, g.SCALAR, g.ELEMENT_ARRAY_BUFFER))
    quad = g.Primitive(attributes=g.Attributes(POSITION=buf.add(QUAD, g.FLOAT, g.VEC3, g.ARRAY_BUFFER, minmax=True),
                                               TEXCOORD_0=buf.add(QUAD[:, :2], g.FLOAT, g.VEC2, g.ARRAY_BUFFER)),
                       indices=buf.add(QUAD_FACES, g.UNSIGNED_SHORT, g.SCALAR, g.ELEMENT_ARRAY_BUFFER), material=1)
    fan_uv = np.rint(np.clip(FAN[:, :2] / 2, 0, 1) * 65535).astype(np.uint16)
    fan = g.Primitive(attributes=g.Attributes(POSITION=buf.add(FAN, g.FLOAT, g.VEC3, g.ARRAY_BUFFER, minmax=True),
                                              TEXCOORD_0=buf.add(fan_uv, g.UNSIGNED_SHORT, g.VEC2, g.ARRAY_BUFFER,
                                                                 normalized=True)),
                      indices=buf.add(FAN_FACES, g.UNSIGNED_BYTE, g.SCALAR, g.ELEMENT_ARRAY_BUFFER), material=0,
                      mode=g.LINES if lines else g.TRIANGLES)
    quad.targets = [{"POSITION": buf.add(SMILE[0], g.FLOAT, g.VEC3, minmax=True)}, {"POSITION": buf.zeros(4)}]
    fan.targets = [{"POSITION": buf.add(SMILE[1], g.FLOAT, g.VEC3, minmax=True)},
                   {"POSITION": buf.zeros(5, BLINK_ROWS, BLINK_VALUES)}]
    ibm = np.stack([m.T for m in bind_inverse()]).astype(np.float32)  # column-major
    skin = g.Skin(joints=[1, 2], inverseBindMatrices=buf.add(ibm.reshape(2, 16), g.FLOAT, g.MAT4), skeleton=1)
    times = buf.add(np.array([0, 1], np.float32), g.FLOAT, g.SCALAR, minmax=True)
    turns = buf.add(np.array([NECK["q"], quat([0, 0, 1], -20)], np.float32), g.FLOAT, g.VEC4)
    weights = buf.add(np.array([0, 0, 1, 0.5], np.float32), g.FLOAT, g.SCALAR)
    animation = g.Animation(name="nod", samplers=[g.AnimationSampler(input=times, output=turns),
                                                  g.AnimationSampler(input=times, output=weights)],
                            channels=[g.AnimationChannel(sampler=s, target=g.AnimationChannelTarget(node=n, path=path))
                                      for s, n, path in ((0, 2, "rotation"), (1, 5, "weights"))])
    nodes = [g.Node(name="Armature", translation=ARMATURE["t"], rotation=ARMATURE["q"], children=[1]),
             g.Node(name="Hips", translation=HIPS["t"], children=[2]),
             g.Node(name="Neck", translation=NECK["t"], rotation=NECK["q"]),
             g.Node(name="Body", mesh=0, skin=0, translation=[5.0, 0.0, 0.0]),  # ignored: the mesh is skinned
             g.Node(name="HeadOffset", translation=HEAD_OFFSET["t"], rotation=HEAD_OFFSET["q"],
                    scale=HEAD_OFFSET["s"], children=[5]),
             g.Node(name="Head", mesh=1, matrix=[float(x) for x in HEAD_MATRIX.T.ravel()])]
    doc = g.GLTF2(asset=g.Asset(generator="faceanim tests", version="2.0"), scene=0,
                  scenes=[g.Scene(nodes=[0, 3, 4])], nodes=nodes, skins=[skin], animations=[animation],
                  meshes=[g.Mesh(name="Body", primitives=[body]),
                          g.Mesh(name="Head", primitives=[quad, fan], weights=[0.25, 0.0],
                                 extras={"targetNames": ["smile", "blink"]})],
                  materials=[g.Material(name="skin", doubleSided=True), g.Material(name="lips")],
                  extensionsUsed=["VRMC_vrm"], extensions={"VRMC_vrm": VRM_EXTENSION})
    while len(buf.data) % 4:
        buf.data.append(0)
    doc.buffers = [g.Buffer(byteLength=len(buf.data))]
    doc.bufferViews, doc.accessors = buf.views, buf.accessors
    doc.set_binary_blob(bytes(buf.data))
    return doc


def avatar_bytes(**kw) -> bytes:
    return b"".join(build_avatar(**kw).save_to_bytes())


@pytest.fixture
def avatar(tmp_path) -> Path:
    path = tmp_path / "avatar.vrm"
    path.write_bytes(avatar_bytes())
    return path


def head_world(v):
    m = globals_by_hand()["head"]
    return v @ m[:3, :3].T + m[:3, 3]


def body_world_by_hand():
    """Linear-blend skinning of the cube at the stored pose, from the spec."""
    glob = globals_by_hand()
    maps = [glob["hips"] @ bind_inverse()[0], glob["neck"] @ bind_inverse()[1]]
    out = []
    for v, j, w in zip(CUBE.astype(float), CUBE_JOINTS, CUBE_WEIGHTS.astype(float)):
        m = sum(w[k] * maps[j[k]] for k in range(4))
        out.append(m[:3, :3] @ v + m[:3, 3])
    return np.array(out), maps


def no_files_but(folder: Path, *names):
    assert sorted(p.name for p in folder.iterdir()) == sorted(names)


# ====================================================================== tests: synthetic avatar
def test_meshes_are_listed(avatar):
    scene = read_scene(avatar)
    body, head = scene.meshes()
    assert (body.index, body.name, body.nodes, body.skinned, body.n_vertices, body.n_primitives) == \
        (0, "Body", (3,), True, 8, 1)
    assert (head.index, head.name, head.nodes, head.skinned, head.n_vertices, head.n_primitives) == \
        (1, "Head", (5,), False, 9, 2)
    assert head.target_names == ("smile", "blink") and body.target_names == ()
    assert body.editable and head.editable
    world = head_world(np.r_[QUAD, FAN].astype(float))
    np.testing.assert_allclose(head.bbox, [world.min(0), world.max(0)], atol=1e-12)
    np.testing.assert_allclose(body.bbox[0], body_world_by_hand()[0].min(0), atol=1e-6)


def test_geometry_is_merged_in_world_space(avatar):
    scene = read_scene(avatar)
    mesh, mapping = scene.mesh_geometry(1)
    np.testing.assert_allclose(mesh.vertices, head_world(np.r_[QUAD, FAN].astype(float)), atol=1e-12)
    np.testing.assert_array_equal(mesh.faces, np.r_[QUAD_FACES.reshape(-1, 3), FAN_FACES.reshape(-1, 3) + 4])
    np.testing.assert_array_equal(mapping, [[0, i] for i in range(4)] + [[1, i] for i in range(5)])
    # UVs: float on the quad, normalised uint16 on the fan; faceanim's v runs up
    uv = np.r_[QUAD[:, :2], np.rint(np.clip(FAN[:, :2] / 2, 0, 1) * 65535) / 65535]
    np.testing.assert_allclose(mesh.uv, np.c_[uv[:, 0], 1 - uv[:, 1]], atol=1e-7)
    # the skinned body: placed by its joints (G @ IBM, one joint posed), not by its node's translation
    body, _ = scene.mesh_geometry(0)
    want, maps = body_world_by_hand()
    assert not np.allclose(maps[0], maps[1])
    np.testing.assert_allclose(body.vertices, want, atol=1e-6)
    # welding joins the two vertices the quad and the fan share (1, 0, 0) and (1, 1, 0)
    welded, index = weld(mesh)
    assert welded.n_vertices == 7 and index[1] == index[4] and index[2] == index[5]
    np.testing.assert_allclose(welded.vertices[index], mesh.vertices, atol=1e-6)
    np.testing.assert_array_equal(welded.face_uv, mesh.faces)  # every corner keeps its own UV
    assert len(np.unique(welded.vertex_components)) == 1 < len(np.unique(mesh.vertex_components))


def test_existing_targets_are_world_deltas(avatar):
    scene = read_scene(avatar)
    targets = scene.targets(1)
    assert list(targets) == ["smile", "blink"]
    lin = globals_by_hand()["head"][:3, :3]
    np.testing.assert_allclose(targets["smile"], np.r_[SMILE].astype(float) @ lin.T, atol=1e-7)
    blink = np.zeros((9, 3))
    blink[4 + BLINK_ROWS] = BLINK_VALUES
    np.testing.assert_allclose(targets["blink"], blink @ lin.T, atol=1e-7)
    assert list(scene.targets(1, ["blink"])) == ["blink"]
    with pytest.raises(MeshError, match="no morph target 'frown'"):
        scene.targets(1, ["frown"])


def test_write_adds_targets_and_keeps_everything_else(avatar, tmp_path):
    scene = read_scene(avatar)
    rng = np.random.default_rng(3)
    jaw = np.zeros((9, 3))
    jaw[1] = [0.0, -0.02, 0.01]  # one quad vertex: sparse there, nothing on the fan (no data)
    wide = rng.normal(scale=0.01, size=(9, 3))  # dense everywhere
    bulge = rng.normal(scale=0.01, size=(8, 3))  # on the skinned body
    out = write_scene(scene, tmp_path / "out.vrm", {1: {"jaw": jaw, "wide": wide}, 0: {"bulge": bulge}})
    before, after = glb_parts(avatar), glb_parts(out)
    assert_originals_kept(before, after)
    d0, d1 = before[0], after[0]
    head0, head1 = d0["meshes"][1], d1["meshes"][1]
    assert head1["extras"]["targetNames"] == ["smile", "blink", "jaw", "wide"]
    assert head1["weights"] == [0.25, 0, 0, 0]
    assert d1["meshes"][0]["extras"]["targetNames"] == ["bulge"] and d1["meshes"][0]["weights"] == [0]
    lin = globals_by_hand()["head"][:3, :3]
    for p, rows in ((0, slice(0, 4)), (1, slice(4, 9))):
        t0, t1 = head0["primitives"][p]["targets"], head1["primitives"][p]["targets"]
        assert t1[:2] == t0 and len(t1) == 4  # the old targets, their accessors untouched
        assert {k: v for k, v in head1["primitives"][p].items() if k != "targets"} == \
            {k: v for k, v in head0["primitives"][p].items() if k != "targets"}
        for k, delta in ((2, jaw), (3, wide)):
            acc = d1["accessors"][t1[k]["POSITION"]]
            local = decode(*after, t1[k]["POSITION"]).astype(float)
            np.testing.assert_allclose(local @ lin.T, delta[rows], atol=1e-7)  # float32 precision
            np.testing.assert_array_equal(acc["min"], local.min(0))
            np.testing.assert_array_equal(acc["max"], local.max(0))
    quad_jaw = d1["accessors"][head1["primitives"][0]["targets"][2]["POSITION"]]
    fan_jaw = d1["accessors"][head1["primitives"][1]["targets"][2]["POSITION"]]
    assert quad_jaw["sparse"]["count"] == 1 and "bufferView" not in quad_jaw
    assert "sparse" not in fan_jaw and "bufferView" not in fan_jaw and fan_jaw["count"] == 5
    assert "sparse" not in d1["accessors"][head1["primitives"][0]["targets"][3]["POSITION"]]
    # the animation of the head's weights is widened with zeros; the neck's rotation is as it was
    s0, s1 = d0["animations"][0]["samplers"], d1["animations"][0]["samplers"]
    assert s1[0] == s0[0] and s1[1]["input"] == s0[1]["input"] and s1[1]["output"] != s0[1]["output"]
    np.testing.assert_array_equal(decode(*after, s1[1]["output"]).reshape(2, 4), [[0, 0, 0, 0], [1, 0.5, 0, 0]])
    assert d1["animations"][0]["channels"] == d0["animations"][0]["channels"]
    # read back: the same world deltas (the skinned body through its per-vertex joint maps)
    again = read_scene(out)
    got = again.targets(1)
    assert list(got) == ["smile", "blink", "jaw", "wide"]
    np.testing.assert_allclose(got["jaw"], jaw, atol=1e-7)
    np.testing.assert_allclose(got["wide"], wide, atol=1e-7)
    np.testing.assert_allclose(got["smile"], scene.targets(1)["smile"], atol=0)
    np.testing.assert_allclose(again.targets(0)["bulge"], bulge, atol=1e-7)
    local = decode(*after, d1["meshes"][0]["primitives"][0]["targets"][0]["POSITION"]).astype(float)
    maps = body_world_by_hand()[1]
    lbs = np.array([sum(w[k] * maps[j[k]][:3, :3] for k in range(4)) for j, w in zip(CUBE_JOINTS, CUBE_WEIGHTS)])
    np.testing.assert_allclose(np.einsum("vij,vj->vi", lbs, local), bulge, atol=1e-7)
    assert [m.target_names for m in again.meshes()] == [("bulge",), ("smile", "blink", "jaw", "wide")]
    g.GLTF2().load_binary(str(out))  # pygltflib reads it


def test_same_name_refused_unless_replace(avatar, tmp_path):
    scene = read_scene(avatar)
    smile = np.full((9, 3), 0.001)
    with pytest.raises(MeshError, match="already has a morph target 'smile'.*replace=True") as err:
        write_scene(scene, tmp_path / "out.glb", {1: {"smile": smile}})
    assert "\n" not in str(err.value)
    no_files_but(tmp_path, "avatar.vrm")
    out = write_scene(scene, tmp_path / "out.glb", {1: {"smile": smile}}, replace=True)
    before, after = glb_parts(avatar), glb_parts(out)
    assert_originals_kept(before, after)
    head = after[0]["meshes"][1]
    assert head["extras"]["targetNames"] == ["smile", "blink"] and head["weights"] == [0.25, 0]
    for p in range(2):
        targets = head["primitives"][p]["targets"]
        assert len(targets) == 2 and targets[1] == before[0]["meshes"][1]["primitives"][p]["targets"][1]
        assert targets[0]["POSITION"] >= len(before[0]["accessors"])
    np.testing.assert_allclose(read_scene(out).targets(1)["smile"], smile, atol=1e-9)
    assert after[0]["animations"] == before[0]["animations"]  # the target count did not change


def test_document_extensions_are_written(avatar, tmp_path):
    scene = read_scene(avatar)
    mesh, _ = scene.mesh_geometry(1)
    scene.document.extensions["VRMC_vrm"]["expressions"]["custom"] = {
        "jaw": {"morphTargetBinds": [{"node": 5, "index": 2, "weight": 1.0}]}}
    out = write_scene(scene, tmp_path / "out.vrm", {1: {"jaw": np.ones((mesh.n_vertices, 3)) * 1e-3}})
    doc = glb_parts(out)[0]
    assert doc["extensions"]["VRMC_vrm"]["expressions"]["custom"]["jaw"]["morphTargetBinds"][0]["index"] == 2
    assert doc["extensions"]["VRMC_vrm"]["meta"] == VRM_EXTENSION["meta"]
    # no additions: a copy with the same JSON (pygltflib's filled-in defaults left out)
    copy = write_scene(read_scene(avatar), tmp_path / "copy.glb", {})
    assert glb_parts(copy)[0] == glb_parts(avatar)[0] and glb_parts(copy)[1] == glb_parts(avatar)[1]


def test_written_avatar_passes_the_khronos_validator(avatar, tmp_path):
    from test_gltf import _validate

    scene = read_scene(avatar)
    out = write_scene(scene, tmp_path / "out.glb", {1: {"jaw": np.eye(9, 3) * 0.01}, 0: {"b": np.ones((8, 3))}})
    before, after = _validate(avatar), _validate(out)
    assert before["numErrors"] == 0, before["messages"]
    assert after["numErrors"] == 0, after["messages"]


# ====================================================================== tests: the real VRoid avatar
@pytest.fixture(scope="module")
def vroid():
    return read_scene(need(VROID))


def test_vroid_meshes(vroid):
    meshes = vroid.meshes()
    assert [m.name.split()[0] for m in meshes] == ["Body", "Face", "Hair001"]
    body, face, hair = meshes
    assert face.n_primitives == 7 and len(face.target_names) == 124 and face.skinned
    assert all(m.editable and m.skinned for m in meshes)
    # the face sits on the body's neck: inside its x/z extent, at the top of its height
    lo, hi = body.bbox
    centre = face.bbox.mean(0)
    assert np.all(lo[[0, 2]] < centre[[0, 2]]) and np.all(centre[[0, 2]] < hi[[0, 2]])
    assert hi[1] - 0.2 * (hi[1] - lo[1]) < centre[1] < hi[1]
    assert 1.5 < hi[1] - lo[1] < 2.0  # an adult in metres
    # the hair crowns the head; it is narrower than the arms' span (the mesh nodes' identity matrices
    # would leave each mesh in its own unit box: the skin's inverse bind matrices place them)
    assert hair.bbox[1, 1] > face.bbox[1, 1] and np.ptp(hair.bbox[:, 0]) < 0.5 * (hi[0] - lo[0])
    mesh, mapping = vroid.mesh_geometry(face.index)
    assert mesh.n_vertices == face.n_vertices == len(mapping) and mesh.uv is not None
    assert sorted(set(mapping[:, 0])) == list(range(7))


def test_vroid_round_trip_keeps_every_accessor(vroid, tmp_path):
    face = vroid.meshes()[1]
    mesh, _ = vroid.mesh_geometry(face.index)
    lips = np.zeros(mesh.vertices.shape)
    low = mesh.vertices[:, 1] < np.percentile(mesh.vertices[:, 1], 20)
    lips[low] = [0.0, -0.002, 0.001]
    out = write_scene(vroid, tmp_path / "vroid-plus.glb", {face.index: {"faceanim_test": lips}})
    before, after = glb_parts(vroid.path), glb_parts(out)
    assert_originals_kept(before, after)
    for p, prim in enumerate(after[0]["meshes"][face.index]["primitives"]):
        assert prim["targets"][:124] == before[0]["meshes"][face.index]["primitives"][p]["targets"]
        assert len(prim["targets"]) == 125
    assert after[0]["meshes"][face.index]["extras"]["targetNames"][-1] == "faceanim_test"
    loaded = g.GLTF2().load(str(out))
    assert len(loaded.meshes[face.index].primitives[0].targets) == 125
    again = read_scene(out)
    np.testing.assert_allclose(again.targets(face.index, ["faceanim_test"])["faceanim_test"], lips, atol=1e-7)
    report = _validator_report(vroid.path, out)
    if report is not None:
        (e0, codes0), (e1, codes1) = report
        assert e1 <= e0 and codes1 <= codes0, codes1 - codes0


def _validator_report(original, written):
    if shutil.which("node") is None or not (ROOT / "tools" / "node_modules" / "gltf-validator").exists():
        return None
    from test_gltf import _validate

    def errors(report):
        return report["numErrors"], {m.split()[1] for m in report["messages"] if m.startswith("0 ")}

    return errors(_validate(original)), errors(_validate(written))


# ====================================================================== tests: bad input
def _one_line(excinfo):
    assert "\n" not in str(excinfo.value)
    return str(excinfo.value)


def test_missing_and_empty_files(tmp_path):
    with pytest.raises(InputFileError, match="does not exist") as e:
        read_scene(tmp_path / "nothing.glb")
    _one_line(e)
    (tmp_path / "empty.glb").write_bytes(b"")
    with pytest.raises(MeshError, match="is empty") as e:
        read_scene(tmp_path / "empty.glb")
    _one_line(e)
    with pytest.raises(InputFileError, match="folder"):
        read_scene(tmp_path)
    (tmp_path / "a.gltf").write_text('{"asset": {"version": "2.0"}}')
    with pytest.raises(MeshError, match="binary glTF"):
        read_scene(tmp_path / "a.gltf")
    (tmp_path / "cut.glb").write_bytes(avatar_bytes()[:-100])
    with pytest.raises(MeshError, match="truncated"):
        read_scene(tmp_path / "cut.glb")


@pytest.mark.parametrize("uri", ["avatar.bin", "data:application/octet-stream;base64,AAAA"])
def test_buffers_outside_the_file_are_refused(tmp_path, uri):
    doc, binary = glb_parts_from_bytes(avatar_bytes())
    doc["buffers"][0]["uri"] = uri
    (tmp_path / "avatar.bin").write_bytes(binary)
    path = tmp_path / "ext.glb"
    path.write_bytes(pack_glb(doc, b""))
    with pytest.raises(MeshError, match="outside its binary chunk") as e:
        read_scene(path)
    _one_line(e)


def glb_parts_from_bytes(data: bytes):
    n = struct.unpack_from("<I", data, 12)[0]
    m = struct.unpack_from("<I", data, 20 + n)[0]
    return json.loads(data[20:20 + n]), data[28 + n:28 + n + m]


def test_non_triangles_and_bad_indices_refused(tmp_path):
    path = tmp_path / "lines.glb"
    path.write_bytes(avatar_bytes(lines=True))
    scene = read_scene(path)
    assert [m.editable for m in scene.meshes()] == [True, False]
    with pytest.raises(MeshError, match="primitive 1 is lines, not triangles") as e:
        scene.mesh_geometry(1)
    _one_line(e)
    with pytest.raises(MeshError, match="not triangles"):
        write_scene(scene, tmp_path / "out.glb", {1: {"x": np.zeros((9, 3))}})
    for bad in (7, -1):
        with pytest.raises(MeshError, match="has no mesh") as e:
            scene.mesh_geometry(bad)
        _one_line(e)
        with pytest.raises(MeshError, match="has no mesh"):
            write_scene(scene, tmp_path / "out.glb", {bad: {"x": np.zeros((9, 3))}})
    with pytest.raises(MeshError, match=r"finite \(8, 3\) array"):
        write_scene(scene, tmp_path / "out.glb", {0: {"x": np.zeros((9, 3))}})
    with pytest.raises(MeshError, match=r"finite \(8, 3\) array"):
        write_scene(scene, tmp_path / "out.glb", {0: {"x": np.full((8, 3), np.nan)}})
    with pytest.raises(MeshError, match=".glb or .vrm"):
        write_scene(scene, tmp_path / "out.obj", {})
    no_files_but(tmp_path, "lines.glb")


def test_unwritable_output(avatar, tmp_path):
    scene = read_scene(avatar)
    add = {1: {"jaw": np.zeros((9, 3))}}
    with pytest.raises(OutputError, match="does not exist") as e:
        write_scene(scene, tmp_path / "missing" / "out.glb", add)
    _one_line(e)
    with pytest.raises(OutputError, match="not a folder"):
        write_scene(scene, avatar / "out.glb", add)
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        if not os.access(locked, os.W_OK):  # root writes into read-only folders: nothing to test then
            with pytest.raises(OutputError, match="not writable"):
                write_scene(scene, locked / "out.glb", add)
        assert list(locked.iterdir()) == []
    finally:
        locked.chmod(0o700)
    no_files_but(tmp_path, "avatar.vrm", "locked")


# ====================================================================== fuzzing
FUZZ = settings(max_examples=60, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.function_scoped_fixture])
VALID = avatar_bytes()
VALID_DOC, VALID_BIN = glb_parts_from_bytes(VALID)
ODD = [-1, 0, 1, 2, 3, 4, 6, 7, 255, 65535, 2**31, 2**40, 1.5, -0.0, 1e300, "x", "", None, True, [], {}, [0] * 16,
       [1e308] * 3, {"uri": "x.bin"}]


def _leaves(value, path=()):
    yield path
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _leaves(v, path + (k,))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from _leaves(v, path + (i,))


PATHS = [p for p in _leaves(VALID_DOC) if p]


def _use(data: bytes, folder: Path):
    """read_scene and everything after it on ``data``: only one-line faceanim errors may come out, and
    a failed write leaves nothing."""
    path = folder / "fuzz.glb"
    path.write_bytes(data)
    out = folder / "out.glb"
    try:
        scene = read_scene(path)
        for info in scene.meshes():
            try:
                mesh, _ = scene.mesh_geometry(info.index)
                scene.targets(info.index)
                weld(mesh)
            except FaceAnimError as exc:
                assert "\n" not in str(exc)
                continue
            try:
                write_scene(scene, out, {info.index: {"fuzz": np.full((mesh.n_vertices, 3), 1e-3)}})
            except FaceAnimError as exc:
                assert "\n" not in str(exc) and not out.exists()
                continue
            again = read_scene(out)  # what faceanim wrote, it reads
            again.targets(info.index, ["fuzz"])
            out.unlink()
    except FaceAnimError as exc:
        assert "\n" not in str(exc)
    assert all(".faceanim-" not in p.name for p in folder.iterdir())


@FUZZ
@given(cut=st.integers(0, len(VALID) - 1))
def test_fuzz_truncated(tmp_path_factory, cut):
    _use(VALID[:cut], tmp_path_factory.mktemp("f"))


@FUZZ
@given(flips=st.lists(st.tuples(st.integers(0, len(VALID) - 1), st.integers(0, 255)), min_size=1, max_size=6))
def test_fuzz_flipped_bytes(tmp_path_factory, flips):
    data = bytearray(VALID)
    for i, b in flips:
        data[i] = b
    _use(bytes(data), tmp_path_factory.mktemp("f"))


@FUZZ
@given(edits=st.lists(st.tuples(st.sampled_from(PATHS), st.sampled_from(ODD)), min_size=1, max_size=3))
def test_fuzz_json_values(tmp_path_factory, edits):
    doc = json.loads(json.dumps(VALID_DOC))
    for path, value in edits:
        node = doc
        try:
            for key in path[:-1]:
                node = node[key]
            node[path[-1]] = value
        except (KeyError, IndexError, TypeError):
            continue
    _use(pack_glb(doc, VALID_BIN), tmp_path_factory.mktemp("f"))


@settings(FUZZ, max_examples=40)  # each example writes and reads back both meshes
@given(flips=st.lists(st.tuples(st.integers(0, len(VALID_BIN) - 1), st.sampled_from([0, 0x7F, 0x80, 0xFF, 0xC0])),
                      min_size=1, max_size=8))
def test_fuzz_binary_data(tmp_path_factory, flips):
    data = bytearray(VALID_BIN)
    for i, b in flips:
        data[i] = b
    _use(pack_glb(VALID_DOC, bytes(data)), tmp_path_factory.mktemp("f"))
