"""`faceanim rig AVATAR.glb|.vrm` (faceanim.avatar): a whole skinned multi-mesh avatar rigged in place.

The real VRoid sample (../shared/data/avatars, skipped without it) is rigged with and without
--replace; a small synthetic avatar is built here with pygltflib (a skinned cube body, faceanim's
default face as a skinned 'Wolf3D_Head' and an 'EyeLeft' companion on a node of its own) and
rigged end to end; bad avatars and flags are refused with one line on stderr, exit code 2 and
nothing written. Accessors of the written files are decoded by hand (from the glTF spec), not with
the module under test.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pygltflib as g
import pytest

from faceanim.autorig import viseme_mixes
from faceanim.cli import main
from faceanim.standards.arkit import ARKIT_NAMES
from faceanim.io.scene import read_scene
from faceanim.standards.arkit import apple_name
from test_scene import decode, glb_parts  # the GLB read by hand, independently of io/scene.py

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
VROID = DATA / "avatars" / "vroid-sample.glb"
needs_vroid = pytest.mark.skipif(not VROID.is_file(), reason="../shared/data/avatars/vroid-sample.glb is not here")

APPLE_52 = [apple_name(n) for n in ARKIT_NAMES]  # Apple's names in Live Link Face's order
OCULUS = [f"viseme_{v['oculus']}" for v in viseme_mixes()]


def run(args) -> int:
    try:
        return main([str(a) for a in args])
    except SystemExit as exc:
        return exc.code


def refused(capsys, args, phrase: str, folder: Path, left: list[str]) -> str:
    """``faceanim rig ARGS``: exit 2, one stderr line holding ``phrase``, no traceback, and
    ``folder`` holding only ``left`` afterwards."""
    assert run(["rig", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0, err
    assert "Traceback" not in err and "internal error" not in err and phrase in err, err
    assert sorted(os.listdir(folder)) == sorted(left), os.listdir(folder)
    return err


# ====================================================================== GLB decoded by hand (the spec)
def mesh_accessors(doc: dict, mi: int) -> list[int]:
    """Every accessor a mesh's primitives use (attributes, indices, targets)."""
    out = []
    for prim in doc["meshes"][mi]["primitives"]:
        out += list(prim["attributes"].values()) + ([prim["indices"]] if "indices" in prim else [])
        out += [a for t in prim.get("targets", []) for a in t.values()]
    return out


def assert_mesh_unchanged(before, after, mi: int):
    """Mesh ``mi``'s JSON and the decoded data of every accessor it uses are as they were."""
    (d0, b0), (d1, b1) = before, after
    assert d1["meshes"][mi] == d0["meshes"][mi]
    for k in mesh_accessors(d0, mi):
        assert d1["accessors"][k] == d0["accessors"][k]
        a0, a1 = decode(d0, b0, k), decode(d1, b1, k)
        assert a0.dtype == a1.dtype and a0.tobytes() == a1.tobytes(), (mi, k)


def assert_rest_unchanged(before, after):
    """Nodes (but their weights), skins, animations, materials, extensions as they were; every
    original accessor's decoded data the same."""
    (d0, b0), (d1, b1) = before, after
    assert len(d1["nodes"]) == len(d0["nodes"])
    for n0, n1 in zip(d0["nodes"], d1["nodes"]):
        assert {k: v for k, v in n1.items() if k != "weights"} == {k: v for k, v in n0.items() if k != "weights"}
    for key in ("skins", "animations", "materials", "textures", "images", "scenes", "extensionsUsed"):
        assert d1.get(key) == d0.get(key), key
    assert len(d1["meshes"]) == len(d0["meshes"])
    for k in range(len(d0["accessors"])):
        assert decode(d0, b0, k).tobytes() == decode(d1, b1, k).tobytes(), k


# ====================================================================== the synthetic avatar
HEAD_AT = np.array([0.0, 1.6, 0.0])  # the head joint, world (the default face is centred near 0)
HIPS_AT = np.array([0.0, 1.0, 0.0])
EYE_NODE = np.array([0.03, 0.03, 0.05])  # the EyeLeft node's translation under the head joint


def cube(centre, size) -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[x, y, z] for y in (-0.5, 0.5) for z in (-0.5, 0.5) for x in (-0.5, 0.5)]) * size + centre
    f = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                  [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]])
    return v, f


def ball(centre, radius, n=8) -> tuple[np.ndarray, np.ndarray]:
    """A UV sphere (poles shared)."""
    rows = []
    for i in range(1, n):
        t = np.pi * i / n
        for j in range(2 * n):
            p = 2 * np.pi * j / (2 * n)
            rows.append([np.sin(t) * np.cos(p), np.cos(t), np.sin(t) * np.sin(p)])
    v = np.array([[0, 1, 0], *rows, [0, -1, 0]], float) * radius + centre
    ring = lambda i, j: 1 + (i - 1) * 2 * n + j % (2 * n)  # noqa: E731
    f = [[0, ring(1, j + 1), ring(1, j)] for j in range(2 * n)]
    for i in range(1, n - 1):
        for j in range(2 * n):
            f += [[ring(i, j), ring(i, j + 1), ring(i + 1, j)], [ring(i, j + 1), ring(i + 1, j + 1), ring(i + 1, j)]]
    last = len(v) - 1
    f += [[last, ring(n - 1, j), ring(n - 1, j + 1)] for j in range(2 * n)]
    return v, np.array(f)


class _Buf:
    def __init__(self):
        self.data, self.views, self.accessors = bytearray(), [], []

    def add(self, a, comp, kind, target=None, minmax=False) -> int:
        a = np.ascontiguousarray(a)
        while len(self.data) % 4:
            self.data.append(0)
        self.views.append(g.BufferView(buffer=0, byteOffset=len(self.data), byteLength=a.nbytes, target=target))
        self.data.extend(a.tobytes())
        acc = g.Accessor(bufferView=len(self.views) - 1, componentType=comp, count=len(a), type=kind)
        if minmax:
            acc.min = [float(x) for x in np.atleast_1d(a.min(0))]
            acc.max = [float(x) for x in np.atleast_1d(a.max(0))]
        self.accessors.append(acc)
        return len(self.accessors) - 1


def avatar_bytes(parts: list[tuple[str, np.ndarray, np.ndarray]], extensions: dict | None = None) -> bytes:
    """An avatar: a skeleton (Hips, Head joints, in their bind pose), a skinned cube 'Body' under
    the head and ``parts`` (name, world vertices, triangles): the first skinned to the Head
    joint, the others unskinned on nodes under the Head joint (their positions stored relative
    to it). The body has two primitives (two materials) sharing its vertex data."""
    buf = _Buf()
    body_v, body_f = cube([0.0, 0.9, 0.0], 1.0)
    body_v = body_v * [0.6, 1.0, 0.3]  # x -0.3..0.3, y 0.4..1.4: under the head
    position = buf.add(body_v.astype(np.float32), g.FLOAT, g.VEC3, g.ARRAY_BUFFER, minmax=True)
    joints = buf.add(np.array([[0, 1, 0, 0]] * 8, np.uint8), g.UNSIGNED_BYTE, g.VEC4, g.ARRAY_BUFFER)
    weights = buf.add(np.array([[1, 0, 0, 0]] * 4 + [[0.5, 0.5, 0, 0]] * 4, np.float32), g.FLOAT, g.VEC4,
                      g.ARRAY_BUFFER)
    attrs = dict(POSITION=position, JOINTS_0=joints, WEIGHTS_0=weights)
    body = g.Mesh(name="Body", primitives=[
        g.Primitive(attributes=g.Attributes(**attrs), material=m,
                    indices=buf.add(half.ravel().astype(np.uint16), g.UNSIGNED_SHORT, g.SCALAR,
                                    g.ELEMENT_ARRAY_BUFFER))
        for m, half in enumerate((body_f[:6], body_f[6:]))])
    meshes, nodes = [body], [g.Node(name="Hips", translation=list(HIPS_AT), children=[1]),
                             g.Node(name="HeadJoint", translation=list(HEAD_AT - HIPS_AT), children=[]),
                             g.Node(name="Body", mesh=0, skin=0)]
    roots = [0, 2]
    for k, (name, v, f) in enumerate(parts):
        skinned = k == 0
        stored = v if skinned else v - HEAD_AT - EYE_NODE
        prim = g.Primitive(attributes=g.Attributes(
            POSITION=buf.add(stored.astype(np.float32), g.FLOAT, g.VEC3, g.ARRAY_BUFFER, minmax=True)),
            indices=buf.add(f.ravel().astype(np.uint32), g.UNSIGNED_INT, g.SCALAR, g.ELEMENT_ARRAY_BUFFER),
            material=0)
        if skinned:
            prim.attributes.JOINTS_0 = buf.add(np.tile(np.array([[1, 0, 0, 0]], np.uint8), (len(v), 1)),
                                               g.UNSIGNED_BYTE, g.VEC4, g.ARRAY_BUFFER)
            prim.attributes.WEIGHTS_0 = buf.add(np.tile(np.array([[1, 0, 0, 0]], np.float32), (len(v), 1)),
                                                g.FLOAT, g.VEC4, g.ARRAY_BUFFER)
        meshes.append(g.Mesh(name=name, primitives=[prim]))
        if skinned:
            nodes.append(g.Node(name=name, mesh=len(meshes) - 1, skin=0))
            roots.append(len(nodes) - 1)
        else:
            nodes.append(g.Node(name=name, mesh=len(meshes) - 1, translation=list(EYE_NODE)))
            nodes[1].children.append(len(nodes) - 1)
    ibm = np.stack([np.eye(4), np.eye(4)])
    ibm[0, :3, 3], ibm[1, :3, 3] = -HIPS_AT, -HEAD_AT  # inverse bind: the joints' globals inverted
    skin = g.Skin(joints=[0, 1], skeleton=0,
                  inverseBindMatrices=buf.add(ibm.transpose(0, 2, 1).reshape(2, 16).astype(np.float32),
                                              g.FLOAT, g.MAT4))
    doc = g.GLTF2(asset=g.Asset(generator="faceanim tests", version="2.0"), scene=0, scenes=[g.Scene(nodes=roots)],
                  nodes=nodes, skins=[skin], meshes=meshes,
                  materials=[g.Material(name="skin"), g.Material(name="cloth")])
    if extensions:
        doc.extensions, doc.extensionsUsed = extensions, list(extensions)
    while len(buf.data) % 4:
        buf.data.append(0)
    doc.buffers = [g.Buffer(byteLength=len(buf.data))]
    doc.bufferViews, doc.accessors = buf.views, buf.accessors
    doc.set_binary_blob(bytes(buf.data))
    return b"".join(doc.save_to_bytes())


@pytest.fixture(scope="module")
def default_face():
    from faceanim.face.face import Face

    return Face.default()


@pytest.fixture(scope="module")
def head_parts(default_face):
    """The default face at the head joint as 'Wolf3D_Head' and a small 'EyeLeft' ball inside its
    left eyeball (world vertices)."""
    mesh = default_face.mesh
    eye = default_face.landmarks[473] - [0.0, 0.0, 0.012]  # the subject's left iris, pushed into the ball
    return [("Wolf3D_Head", mesh.vertices + HEAD_AT, mesh.faces), ("EyeLeft", *ball(eye + HEAD_AT, 0.006))]


@pytest.fixture(scope="module")
def cube_avatars(tmp_path_factory) -> Path:
    """Avatars of cubes in a folder of their own: two head-like names ('Head' and 'Face'), no
    head-like name at all; and a plain one-mesh OBJ."""
    d = tmp_path_factory.mktemp("cubes")
    (d / "two.glb").write_bytes(avatar_bytes([("Head", *cube(HEAD_AT, 0.2)),
                                              ("Face", *cube(HEAD_AT + [0, 0, 0.05], 0.1))]))
    (d / "boxes.glb").write_bytes(avatar_bytes([("Box", *cube(HEAD_AT, 0.2)),
                                                ("Lamp", *cube(HEAD_AT + [0, 0, 0.05], 0.1))]))
    (d / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    return d


def turned(v, centre, degrees_about_y):
    a = np.radians(degrees_about_y)
    r = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    return (v - centre) @ r.T + centre


# ====================================================================== 1. the real VRoid avatar
@needs_vroid
def test_vroid_replace_rewrites_its_arkit_and_viseme_targets_in_place(tmp_path, capsys):
    """All 52 ARKit and 15 viseme names are already on VRoid's face (most as empty placeholders):
    --replace rewrites them in place (no target added, the same order), VRoid's own Fcl_* targets,
    the body and the hair are untouched."""
    out = tmp_path / "out.glb"
    assert run(["rig", VROID, "-o", out, "--set", "arkit,visemes", "--replace"]) == 0
    std = capsys.readouterr()
    assert std.out.splitlines()[0] == "67 morph targets written to Face (merged)(Clone) (67 replacing its own)"
    assert "kept" not in std.err and "Traceback" not in std.err
    before, after = glb_parts(VROID), glb_parts(out)
    assert_rest_unchanged(before, after)
    assert_mesh_unchanged(before, after, 0)  # Body (merged)
    assert_mesh_unchanged(before, after, 2)  # Hair001 (merged)
    old, new = read_scene(VROID), read_scene(out)
    assert [m.name for m in new.meshes()] == ["Body (merged)", "Face (merged)(Clone)", "Hair001 (merged)"]
    assert [m.target_names for m in new.meshes()] == [m.target_names for m in old.meshes()]
    assert len(new.meshes()[1].target_names) == 124
    t0, t1 = old.targets(1), new.targets(1)
    ours = set(APPLE_52 + OCULUS)
    unchanged = {n for n in t0 if np.array_equal(t0[n], t1[n])}
    assert unchanged == (set(t0) - ours) | {"viseme_sil"}  # silence moves nothing, before and after
    assert np.abs(t1["viseme_sil"]).max() == 0.0
    assert np.abs(t0["jawOpen"]).max() == 0.0 < 0.01 < np.abs(t1["jawOpen"]).max()  # a placeholder filled
    for p0, p1 in zip(before[0]["meshes"][1]["primitives"], after[0]["meshes"][1]["primitives"]):
        assert {k: v for k, v in p1.items() if k != "targets"} == {k: v for k, v in p0.items() if k != "targets"}
        assert len(p1["targets"]) == len(p0["targets"]) == 124
    assert after[0]["meshes"][1].get("weights") == before[0]["meshes"][1].get("weights")
    g.GLTF2().load_binary(str(out))  # pygltflib reads it


@needs_vroid
def test_vroid_without_replace_keeps_every_target(tmp_path, capsys):
    out = tmp_path / "out.glb"
    assert run(["rig", VROID, "-o", out, "--set", "arkit"]) == 0
    std = capsys.readouterr()
    assert std.out.splitlines()[0] == "0 morph targets written to Face (merged)(Clone)"
    assert std.err.strip().startswith("kept the avatar's own targets (--replace to overwrite): eyeBlinkLeft, "), std.err
    assert std.err.count("\n") == 1
    before, after = glb_parts(VROID), glb_parts(out)
    assert_rest_unchanged(before, after)
    for mi in range(3):
        assert_mesh_unchanged(before, after, mi)
    old, new = read_scene(VROID), read_scene(out)
    t0, t1 = old.targets(1), new.targets(1)
    assert list(t1) == list(t0) and all(np.array_equal(t0[n], t1[n]) for n in t0)


# ====================================================================== 2. a synthetic avatar, end to end
VRMC = {"VRMC_vrm": {"specVersion": "1.0",
                     "meta": {"name": "synthetic", "authors": ["test"], "licenseUrl": "https://vrm.dev/licenses/1.0/"},
                     "humanoid": {"humanBones": {"hips": {"node": 0}, "head": {"node": 1}}},
                     "expressions": {"preset": {}}}}


def test_synthetic_avatar_rigged_in_place(tmp_path, capsys, monkeypatch, head_parts):
    """Ready Player Me-like names: 'Wolf3D_Head' is found by its name, 'EyeLeft' (inside its box) is
    rigged with it as one face; each target in the file is exactly auto_rig's shape on that welded
    face split back to the two meshes; the body is untouched; VRM 1.0 expressions are bound."""
    import faceanim.autorig
    from faceanim.face.mesh import Mesh
    from faceanim.io.scene import weld

    seen = []
    real = faceanim.autorig.auto_rig

    def recording(face, sets, **kw):
        seen.append(real(face, sets, **kw))
        return seen[-1]

    monkeypatch.setattr(faceanim.autorig, "auto_rig", recording)
    src, out = tmp_path / "avatar.vrm", tmp_path / "out.vrm"
    src.write_bytes(avatar_bytes(head_parts, VRMC))
    assert run(["rig", src, "-o", out, "--set", "arkit"]) == 0
    std = capsys.readouterr()
    assert std.out.splitlines()[0] == "52 morph targets written to Wolf3D_Head + EyeLeft", std.out
    assert "Traceback" not in std.err
    (auto,) = seen
    assert list(auto.shapes) == APPLE_52
    # the face that was rigged: the head's and the eye's world vertices (float32 in the file), welded
    rows, offset = [], 0
    for _, v, f in head_parts:
        welded, index = weld(Mesh(v.astype(np.float32).astype(float), f))
        np.testing.assert_allclose(auto.face.mesh.vertices[offset:offset + welded.n_vertices][index],
                                   v.astype(np.float32), atol=1e-6)
        rows.append((offset, welded.n_vertices, index))
        offset += welded.n_vertices
    assert auto.face.mesh.n_vertices == offset
    # each target in the file: the shape on those rows (head skinned at its bind pose, eye on a
    # translated node: stored deltas are world deltas)
    before, after = glb_parts(src), glb_parts(out)
    doc = after[0]
    for mi, (start, count, index) in zip((1, 2), rows):
        mesh = doc["meshes"][mi]
        assert mesh["extras"]["targetNames"] == APPLE_52 and mesh["weights"] == [0] * 52
        (prim,) = mesh["primitives"]
        for k, name in enumerate(APPLE_52):
            stored = decode(*after, prim["targets"][k]["POSITION"])
            np.testing.assert_allclose(stored, auto.shapes[name][start:start + count][index], atol=1e-7)
    jaw = decode(*after, doc["meshes"][1]["primitives"][0]["targets"][APPLE_52.index("jawOpen")]["POSITION"])
    assert np.abs(jaw).max() > 0.01  # the head's jaw opens
    eye = {n: decode(*after, doc["meshes"][2]["primitives"][0]["targets"][k]["POSITION"]) for k, n in
           enumerate(APPLE_52)}
    assert np.abs(eye["eyeLookOutLeft"]).max() > 1e-3 and np.abs(eye["eyeLookOutRight"]).max() == 0
    # the rest as it was: the body, the skeleton, every original accessor
    assert_rest_unchanged(before, after)
    assert_mesh_unchanged(before, after, 0)
    # VRM 1.0: presets and one custom expression per ARKit shape bound on both rigged nodes
    expressions = doc["extensions"]["VRMC_vrm"]["expressions"]
    jaw_at = APPLE_52.index("jawOpen")
    assert expressions["custom"]["jawOpen"]["morphTargetBinds"] == [
        {"node": 3, "index": jaw_at, "weight": 1.0}, {"node": 4, "index": jaw_at, "weight": 1.0}]
    happy = expressions["preset"]["happy"]["morphTargetBinds"]
    assert {b["node"] for b in happy} == {3, 4}
    assert {APPLE_52[b["index"]] for b in happy} >= {"mouthSmileLeft", "mouthSmileRight"}
    assert doc["extensions"]["VRMC_vrm"]["meta"] == VRMC["VRMC_vrm"]["meta"]
    g.GLTF2().load_binary(str(out))


def test_head_found_by_geometry_where_the_face_looks(tmp_path, head_parts):
    """No head-like name: the head is the highest mesh with a face on its render, rendered along
    --forward (here a face turned to look along +x); looked at from +z there is none."""
    from faceanim.avatar import find_head
    from faceanim.errors import FaceAnimError

    centre = HEAD_AT
    parts = [("Mesh_1", turned(head_parts[0][1], centre, 90), head_parts[0][2]),
             ("Mesh_2", turned(head_parts[1][1], centre, 90), head_parts[1][2])]
    (tmp_path / "a.glb").write_bytes(avatar_bytes(parts))
    scene = read_scene(tmp_path / "a.glb")
    assert find_head(scene, forward="+x") == (1, [2])
    with pytest.raises(FaceAnimError, match="no head found among the avatar's 3 meshes"):
        find_head(scene)


# ====================================================================== 3. refused
def test_two_head_candidates(cube_avatars, capsys):
    d = cube_avatars
    err = refused(capsys, [d / "two.glb", "-o", d / "o.glb"], "two meshes could be the head", d,
                  ["two.glb", "boxes.glb", "tri.obj"])
    assert "'Head' and 'Face'" in err and "--head-mesh NAME" in err


@pytest.mark.parametrize("args, phrase", [
    (["--head-mesh", "NOPE"], "no mesh named 'NOPE' in the avatar; its meshes: 'Body', 'Head', 'Face'"),
    (["-o", "{d}/o.vrm"], "an avatar is written back as it came: 'two.glb' in, a .glb out"),
    (["--landmarks", "{d}/x.json"], "--landmarks is for a single face mesh"),
    (["--compact"], "--compact is for a single face mesh"),
    (["-o", "{d}/two.glb"], "is also an input"),
    (["-o", "{d}/missing/o.glb"], "does not exist; create it first"),
])
def test_refused_avatar_flags(cube_avatars, capsys, args, phrase):
    d = cube_avatars
    data = (d / "two.glb").read_bytes()
    args = [a.format(d=d) for a in args]
    out = [] if "-o" in args else ["-o", d / "o.glb"]
    refused(capsys, [d / "two.glb", *out, *args], phrase, d, ["two.glb", "boxes.glb", "tri.obj"])
    assert (d / "two.glb").read_bytes() == data


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs Linux's /proc (a folder even root cannot write)")
def test_output_where_nothing_can_be_written(cube_avatars, capsys):
    d = cube_avatars
    refused(capsys, [d / "two.glb", "-o", "/proc/o.glb"], "not writable", d, ["two.glb", "boxes.glb", "tri.obj"])
    assert not os.path.exists("/proc/o.glb")


def test_no_head_among_cubes(cube_avatars, capsys):
    d = cube_avatars
    err = refused(capsys, [d / "boxes.glb", "-o", d / "o.glb"], "no head found among the avatar's 3 meshes", d,
                  ["two.glb", "boxes.glb", "tri.obj"])
    assert "--head-mesh NAME" in err


def test_a_chosen_head_without_a_face(cube_avatars, capsys):
    """--head-mesh naming a cube: no face on its render, and the advice is what an avatar takes
    (not --landmarks, which is refused for an avatar)."""
    d = cube_avatars
    err = refused(capsys, [d / "two.glb", "-o", d / "o.glb", "--head-mesh", "Body"], "no face found", d,
                  ["two.glb", "boxes.glb", "tri.obj"])
    assert "'Body'" in err and "--head-mesh NAME" in err and "landmarks" not in err.lower()


@pytest.mark.parametrize("flag", [["--head-mesh", "Head"], ["--replace"]])
def test_avatar_flags_on_a_single_mesh(cube_avatars, capsys, flag):
    d = cube_avatars
    refused(capsys, [d / "tri.obj", "-o", d / "o.glb", *flag], "--head-mesh and --replace are for a whole avatar",
            d, ["two.glb", "boxes.glb", "tri.obj"])


@needs_vroid
def test_vroid_blinks_close_its_anime_eyes():
    """The anime avatar's eyes (eye whites and irises painted on open plates, lids that overhang
    them, an eyeline plate): each eyeBlink at 1 leaves less than 10% of the opening seen from the
    front (half of it stayed open before the closure found the opening by rays)."""
    from faceanim.autorig import auto_rig
    from faceanim.avatar import avatar_face, find_head
    from faceanim.io.scene import read_scene
    from faceanim.rig.arkit import eye_opening, face_eyes

    scene = read_scene(VROID)
    head, companions = find_head(scene)
    face, _ = avatar_face(scene, [head] + companions)
    shapes = auto_rig(face, ["arkit"]).shapes
    eyes = face_eyes(face)
    for slit, name in (("eye_L", "eyeBlinkLeft"), ("eye_R", "eyeBlinkRight")):
        rest = eye_opening(face, slit, eyes).area
        shut = eye_opening(face, slit, eyes, face.mesh.vertices + shapes[name])
        assert (shut.area if shut else 0.0) < 0.1 * rest, name
