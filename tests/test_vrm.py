"""VRM 1.0 export (faceanim.io.vrm): the default head with ARKit shapes carried over, written as a
VRM avatar, checked by Khronos' validator, read back by hand (the VRMC_vrm extension, the
humanoid, the binds, the vertices in metres facing +Z) and loaded by a real VRM consumer, pixiv's
three-vrm, in Node."""

import json
import shutil
import subprocess

import numpy as np
import pygltflib
import pytest
from conftest import ICT, ROOT, need
from gltf_reader import accessor

from faceanim.errors import FaceAnimError
from faceanim.face.face import Face
from faceanim.face.mesh import Mesh
from faceanim.io.vrm import DEFAULT_META, LICENSE_URL, REQUIRED_BONES, write_vrm
from faceanim.standards.vrm import PRESETS

MODULES = ROOT / "tools" / "node_modules"
# presets bound to the face's ARKit shapes (Apple's Left/Right: the subject's own sides, as VRM's)
BINDS = {
    "happy": {"mouthSmileLeft": 1.0, "mouthSmileRight": 1.0, "cheekSquintLeft": 0.4, "cheekSquintRight": 0.4},
    "sad": {"mouthFrownLeft": 1.0, "mouthFrownRight": 1.0, "browInnerUp": 0.6},
    "surprised": {"browInnerUp": 1.0, "eyeWideLeft": 1.0, "eyeWideRight": 1.0, "jawOpen": 0.3},
    "aa": {"jawOpen": 0.7},
    "ou": {"mouthPucker": 1.0, "mouthFunnel": 0.4, "jawOpen": 0.2},
    "blink": {"eyeBlinkLeft": 1.0, "eyeBlinkRight": 1.0},
    "blinkLeft": {"eyeBlinkLeft": 1.0},
    "blinkRight": {"eyeBlinkRight": 1.0},
    "lookLeft": {"eyeLookOutLeft": 1.0, "eyeLookInRight": 1.0},
    "lookRight": {"eyeLookInLeft": 1.0, "eyeLookOutRight": 1.0},
    "lookUp": {"eyeLookUpLeft": 1.0, "eyeLookUpRight": 1.0},
    "lookDown": {"eyeLookDownLeft": 1.0, "eyeLookDownRight": 1.0},
    "neutral": {},
}
UNUSED = ["mouthClose", "noseSneerLeft"]  # targets no preset binds, between the bound ones


def _pivot_and_eyes(face):
    """The head bone between the ears (the face oval's sides at ear level, MediaPipe 234 and 454)
    and the point between the outer eye corners (33, 263)."""
    lm = face.landmarks
    return (lm[234] + lm[454]) / 2, (lm[33] + lm[263]) / 2


@pytest.fixture(scope="module")
def avatar(tmp_path_factory):
    from faceanim.rig.arkit import arkit_rig

    face = Face.default()
    rig, _ = arkit_rig(face)
    wanted = {t for b in BINDS.values() for t in b} | set(UNUSED)
    shapes = {n: rig.blendshape(n) for n in rig.controls if n in wanted}
    pivot, eyes = _pivot_and_eyes(face)
    path = tmp_path_factory.mktemp("vrm") / "avatar.vrm"
    out = write_vrm(path, face.mesh, shapes, BINDS, head_pivot=pivot, rotation=face.frame.rotation,
                    eyes=eyes, meta={"name": "Default head", "authors": ["faceanim tests"]})
    assert out == path
    return path, face, shapes, pivot, eyes


def _doc(path):
    return pygltflib.GLTF2().load_binary(str(path))


def _world(gltf):
    """Each node's model-space translation (the writer uses translations only: checked here)."""
    parent = {c: p for p, n in enumerate(gltf.nodes) for c in (n.children or [])}
    out = {}
    for i, n in enumerate(gltf.nodes):
        assert n.rotation in (None, [0, 0, 0, 1]) and n.scale in (None, [1, 1, 1]) and n.matrix is None
        pos, j = np.zeros(3), i
        while j is not None:
            pos += np.asarray(gltf.nodes[j].translation or [0, 0, 0], dtype=float)
            j = parent.get(j)
        out[i] = pos
    return out


def test_vrm_passes_the_khronos_validator(avatar):
    if shutil.which("node") is None or not (MODULES / "gltf-validator").exists():
        pytest.skip("node or the gltf-validator npm package is missing (scripts/setup.sh installs it)")
    out = subprocess.run(["node", str(ROOT / "tools" / "validate_gltf.js"), str(avatar[0])],
                         capture_output=True, text=True, check=True)
    report = json.loads(out.stdout)
    assert report["numErrors"] == 0 and report["numWarnings"] == 0, report["messages"]


def test_vrm_extension_meta_humanoid_and_binds(avatar):
    path, face, shapes, _, _ = avatar
    gltf = _doc(path)
    assert "VRMC_vrm" in gltf.extensionsUsed and not gltf.extensionsRequired
    vrm = gltf.extensions["VRMC_vrm"]
    assert vrm["specVersion"] == "1.0"
    assert not gltf.animations  # VRM 1.0 leaves animations unused

    meta = vrm["meta"]
    assert meta["name"] == "Default head" and meta["authors"] == ["faceanim tests"]
    assert meta["licenseUrl"] == LICENSE_URL == "https://vrm.dev/licenses/1.0/"
    # the restrictive defaults, written out
    assert meta["avatarPermission"] == "onlyAuthor" and meta["commercialUsage"] == "personalNonProfit"
    assert meta["creditNotation"] == "required" and meta["modification"] == "prohibited"
    assert meta["allowRedistribution"] is False and meta["allowExcessivelySexualUsage"] is False

    bones = vrm["humanoid"]["humanBones"]
    assert set(REQUIRED_BONES) <= set(bones)
    nodes = [b["node"] for b in bones.values()]
    assert len(set(nodes)) == len(nodes) and all(0 <= i < len(gltf.nodes) for i in nodes)
    # the spec's parent chain: each bone's nearest humanoid ancestor
    parent = {c: p for p, n in enumerate(gltf.nodes) for c in (n.children or [])}
    bone_of = {b["node"]: name for name, b in bones.items()}

    def humanoid_parent(name):
        j = parent.get(bones[name]["node"])
        while j is not None and j not in bone_of:
            j = parent.get(j)
        return bone_of.get(j)

    assert humanoid_parent("hips") is None
    for child, par in [("spine", "hips"), ("chest", "spine"), ("neck", "chest"), ("head", "neck"),
                       ("leftUpperLeg", "hips"), ("leftLowerLeg", "leftUpperLeg"), ("leftFoot", "leftLowerLeg"),
                       ("rightUpperLeg", "hips"), ("rightFoot", "rightLowerLeg"), ("leftUpperArm", "chest"),
                       ("leftHand", "leftLowerArm"), ("rightUpperArm", "chest"), ("rightHand", "rightLowerArm")]:
        assert humanoid_parent(child) == par, child
    # the rest pose: translations only; T pose with the avatar's left at +X, feet above the ground
    world = _world(gltf)
    assert world[bones["leftHand"]["node"]][0] > 0.5 > -0.5 > world[bones["rightHand"]["node"]][0]
    assert 0 < world[bones["leftFoot"]["node"]][1] < 0.2 and world[bones["head"]["node"]][1] > 1.3

    # the mesh hangs under the head bone, every bind names the target asked for
    mesh_node = [i for i, n in enumerate(gltf.nodes) if n.mesh is not None]
    assert len(mesh_node) == 1 and mesh_node[0] in gltf.nodes[bones["head"]["node"]].children
    names = gltf.meshes[0].extras["targetNames"]
    assert names == list(shapes) and len(gltf.meshes[0].primitives[0].targets) == len(names)
    preset = vrm["expressions"]["preset"]
    assert list(preset) == [p for p in PRESETS if p in BINDS]  # the rest are left out
    for name, binds in BINDS.items():
        got = {names[b["index"]]: b["weight"] for b in preset[name].get("morphTargetBinds", [])}
        assert got == binds, name
        assert all(b["node"] == mesh_node[0] for b in preset[name].get("morphTargetBinds", []))
        assert preset[name]["isBinary"] is False
    assert preset["happy"]["overrideBlink"] == "blend" and preset["happy"]["overrideMouth"] == "none"
    assert preset["blink"]["overrideLookAt"] == "blend" and preset["aa"]["overrideBlink"] == "none"
    assert "morphTargetBinds" not in preset["neutral"]  # the schema wants none rather than []

    look = vrm["lookAt"]
    assert look["type"] == "expression"
    assert all(look[k] == {"inputMaxValue": 90.0, "outputScale": 1.0} for k in
               ("rangeMapHorizontalInner", "rangeMapHorizontalOuter", "rangeMapVerticalDown", "rangeMapVerticalUp"))
    assert vrm["firstPerson"]["meshAnnotations"] == [{"node": mesh_node[0], "type": "thirdPersonOnly"}]


def test_vrm_vertices_round_trip_in_metres_facing_plus_z(avatar):
    """Positions and deltas come back after undoing the writer's transform (same count and order,
    seam copies mapped by sourceVertex); in model space the face looks along +Z, its left eye
    at +X, the eyes above the chin, the lookAt origin between the eyes."""
    path, face, shapes, pivot, eyes = avatar
    gltf = _doc(path)
    prim = gltf.meshes[0].primitives[0]
    mesh = face.mesh
    r = face.frame.rotation
    pos = accessor(gltf, prim.attributes.POSITION)
    src = np.asarray((prim.extras or {}).get("sourceVertex", np.arange(len(pos))))
    assert len(pos) == len(src) == len(mesh.per_vertex_uv()[0])
    np.testing.assert_array_equal(src[:mesh.n_vertices], np.arange(mesh.n_vertices))
    back = pos @ r + pivot  # rotation rows: left, up, forward; the default head is in metres
    np.testing.assert_allclose(back, mesh.vertices[src], atol=1e-6)
    for k, name in enumerate(gltf.meshes[0].extras["targetNames"]):
        d = accessor(gltf, prim.targets[k]["POSITION"] if isinstance(prim.targets[k], dict)
                     else prim.targets[k].POSITION)
        np.testing.assert_allclose(d @ r, shapes[name][src], atol=1e-6)
    # the texture and its coordinates come along
    assert prim.attributes.TEXCOORD_0 is not None and gltf.images

    world = _world(gltf)
    mesh_node = next(i for i, n in enumerate(gltf.nodes) if n.mesh is not None)

    def model(p):
        return world[mesh_node] + (p - pivot) @ r.T

    lm = face.landmarks
    nose, left_eye, right_eye, chin = (model(lm[i]) for i in (1, 263, 33, 152))
    head = world[mesh_node]
    assert nose[2] > head[2] + 0.05  # the nose is ahead of the head bone
    assert left_eye[0] > 0.02 > -0.02 > right_eye[0]  # the subject's left at +X
    assert left_eye[1] > chin[1] + 0.05 and chin[1] > 1.0  # upright, well above the ground
    offset = gltf.extensions["VRMC_vrm"]["lookAt"]["offsetFromHeadBone"]
    np.testing.assert_allclose(head + offset, model(eyes), atol=1e-9)


def test_a_millimetre_mesh_turned_sideways_gives_the_same_avatar(avatar, tmp_path):
    """The same head in millimetres, turned and moved: with its own frame's rotation and scale
    0.001 the file's positions are those of the head in metres."""
    path, face, shapes, pivot, eyes = avatar
    rng = np.random.default_rng(3)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    shift = np.array([40.0, -300.0, 1200.0])
    m = face.mesh
    turned = Mesh(1000 * m.vertices @ q.T + shift, m.faces, m.uv, m.face_uv, m.texture, name=m.name)
    face2 = Face(turned, 1000 * face.landmarks @ q.T + shift)
    shapes2 = {n: 1000 * d @ q.T for n, d in shapes.items()}
    pivot2, eyes2 = _pivot_and_eyes(face2)
    out = write_vrm(tmp_path / "mm.vrm", turned, shapes2, BINDS, head_pivot=pivot2,
                    rotation=face2.frame.rotation, scale=0.001, eyes=eyes2)
    a, b = _doc(path), _doc(out)
    pa, pb = (accessor(g, g.meshes[0].primitives[0].attributes.POSITION) for g in (a, b))
    np.testing.assert_allclose(pb, pa, atol=2e-6)
    np.testing.assert_allclose(b.extensions["VRMC_vrm"]["lookAt"]["offsetFromHeadBone"],
                               a.extensions["VRMC_vrm"]["lookAt"]["offsetFromHeadBone"], atol=1e-9)
    # with the millimetres taken for metres the mesh is 400 m across: refused, nothing written
    with pytest.raises(FaceAnimError, match="scale") as e:
        write_vrm(tmp_path / "wrong.vrm", turned, shapes2, BINDS, head_pivot=pivot2, rotation=face2.frame.rotation)
    assert "\n" not in str(e.value) and not (tmp_path / "wrong.vrm").exists()


def test_three_vrm_loads_the_avatar(avatar):
    """pixiv's three-vrm (a VRM 1.0 consumer) in Node: meta, bones, every preset moving exactly its
    morph targets, gaze to the avatar's left and up driving lookLeft and lookUp, the mesh under
    the head at 1.5 m, first person, no warnings."""
    if shutil.which("node") is None or not (MODULES / "@pixiv" / "three-vrm").exists() \
            or not (MODULES / "three").exists():
        pytest.skip("node or three/@pixiv/three-vrm are missing in tools/ (scripts/setup.sh installs them)")
    path, face, shapes, _, _ = avatar
    out = subprocess.run(["node", str(ROOT / "tools" / "check_vrm.mjs"), str(path)],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    assert got["vrm"] and got["warnings"] == []
    assert got["meta"]["metaVersion"] == "1" and got["meta"]["name"] == "Default head"
    assert got["meta"]["licenseUrl"] == LICENSE_URL
    assert set(REQUIRED_BONES) <= set(got["humanBones"])
    (mesh,) = got["meshes"]
    names = list(shapes)
    assert mesh["targets"] == len(names) and mesh["parentIsHead"] and mesh["textured"]
    assert mesh["morphTargetDictionary"] == {n: i for i, n in enumerate(names)}
    assert got["expressions"] == [p for p in PRESETS if p in BINDS]
    for name, binds in BINDS.items():
        (effect,) = got["effects"][name]
        assert {names[int(i)]: w for i, w in effect.items()} == pytest.approx(binds), name
    assert got["lookAt"]["type"] == "expression"
    left, up = got["gaze"]["left"], got["gaze"]["up"]
    assert left["lookLeft"] > 0.3 and left["lookRight"] == 0
    assert up["lookUp"] > 0.3 and up["lookDown"] == 0
    assert got["firstPerson"] == [{"type": "thirdPersonOnly", "meshes": 1}]
    assert got["headWorld"] == pytest.approx([0.0, 1.5, 0.0])
    assert got["meshBox"]["min"][1] > 1.0 and got["meshBox"]["max"][2] > 0.05


def test_three_vrm_plays_happy_on_an_untextured_mesh(tmp_path):
    """Without a texture (nothing for Node to decode) three-vrm loads the avatar as it is, and
    setting happy moves the mesh's morph target."""
    if shutil.which("node") is None or not (MODULES / "@pixiv" / "three-vrm").exists():
        pytest.skip("node or @pixiv/three-vrm is missing in tools/ (scripts/setup.sh installs it)")
    m = Face.default().mesh
    plain = Mesh(m.vertices, m.faces, name="plain")
    smile = np.zeros_like(m.vertices)
    smile[:500, 1] = 0.004
    path = write_vrm(tmp_path / "plain.vrm", plain, {"smile": smile}, {"happy": {"smile": 0.8}},
                     head_pivot=m.vertices.mean(0))
    out = subprocess.run(["node", str(ROOT / "tools" / "check_vrm.mjs"), str(path)],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    got = json.loads(out.stdout)
    assert got["meshes"][0]["textured"] is False and got["effects"]["happy"] == [{"0": 0.8}]
    assert got["lookAt"] is None  # no look presets, no eyes: no lookAt written


def test_meta_overrides_and_refusals(avatar, tmp_path):
    _, face, shapes, pivot, _ = avatar
    args = dict(head_pivot=pivot, rotation=face.frame.rotation)
    out = write_vrm(tmp_path / "open.vrm", face.mesh, shapes, {"blink": {"eyeBlinkLeft": 1}}, **args,
                    meta={"authors": ["A", "B"], "version": "2", "avatarPermission": "everyone",
                          "commercialUsage": "corporation", "allowRedistribution": True,
                          "modification": "allowModificationRedistribution", "creditNotation": "unnecessary"})
    vrm = _doc(out).extensions["VRMC_vrm"]
    meta = vrm["meta"]
    assert meta["name"] == face.mesh.name and meta["authors"] == ["A", "B"] and meta["version"] == "2"
    assert meta["avatarPermission"] == "everyone" and meta["allowRedistribution"] is True
    assert meta["allowExcessivelyViolentUsage"] is False  # untouched defaults stay restrictive
    assert DEFAULT_META["authors"] == ["unknown"]
    assert "lookAt" not in vrm  # no look preset and no eyes

    bad = [
        ({"meta": {"avatarPermission": "anyone"}}, "avatarPermission"),
        ({"meta": {"licenseUrl": "https://example.com/cc-by"}}, "licenseUrl"),
        ({"meta": {"authors": []}}, "authors"),
        ({"meta": {"authors": "me"}}, "authors"),
        ({"meta": {"allowRedistribution": "yes"}}, "allowRedistribution"),
        ({"meta": {"licence": "mine"}}, "unknown VRM meta field 'licence'"),
        ({"look_at": {"rangeMapHorizontalOuter": {"inputMaxValue": 200}}}, "0..180"),
        ({"rotation": np.diag([-1.0, 1.0, 1.0])}, "proper rotation"),
        ({"head_pivot": [0.0, np.nan, 0.0]}, "head_pivot"),
        ({"scale": -1.0}, "positive"),
        ({"eyes": [0.0, 1.0]}, "eyes"),
    ]
    for change, phrase in bad:
        kw = {**args, **change}
        with pytest.raises(FaceAnimError) as e:
            write_vrm(tmp_path / "bad.vrm", face.mesh, shapes, {"blink": {"eyeBlinkLeft": 1}}, **kw)
        assert phrase in str(e.value) and "\n" not in str(e.value), (change, str(e.value))
    assert not (tmp_path / "bad.vrm").exists()


@pytest.mark.parametrize("expressions, phrase", [
    ({"joy": {"mouthSmileLeft": 1}}, "unknown VRM expression preset 'joy'"),
    ({"Happy": {"mouthSmileLeft": 1}}, "unknown VRM expression preset 'Happy'"),
    ({"happy": {"smile": 1}}, "binds morph target 'smile', which is not one of the"),
    ({"happy": {"mouthSmileLeft": 1.5}}, "in 0..1"),
    ({"happy": {"mouthSmileLeft": float("nan")}}, "in 0..1"),
    ({"happy": {}}, "binds no morph target"),
    ({"happy": ["mouthSmileLeft"]}, "must map morph target names to weights"),
])
def test_bad_expressions_are_refused_with_one_line_and_no_file(avatar, tmp_path, expressions, phrase):
    _, face, shapes, pivot, _ = avatar
    with pytest.raises(FaceAnimError) as e:
        write_vrm(tmp_path / "x.vrm", face.mesh, shapes, expressions, head_pivot=pivot, rotation=face.frame.rotation)
    assert phrase in str(e.value) and "\n" not in str(e.value)
    assert list(tmp_path.iterdir()) == []


def test_bad_output_paths_are_refused_before_any_work_and_leave_nothing(avatar, tmp_path):
    _, face, shapes, pivot, _ = avatar
    for target in (tmp_path / "missing" / "a.vrm", tmp_path):
        with pytest.raises(FaceAnimError) as e:
            write_vrm(target, face.mesh, shapes, BINDS, head_pivot=pivot, rotation=face.frame.rotation)
        assert "\n" not in str(e.value)
    assert list(tmp_path.iterdir()) == []


def test_the_ict_head_in_centimetres(tmp_path):
    """A second real head: the ICT generic head (centimetres, UV seams, no texture) with five of its
    own artist-made shapes, written with scale 0.01: validator-clean, the seam copies mapped back,
    positions in metres, and three-vrm plays its presets."""
    from faceanim.io.meshio import load_mesh

    folder = need(ICT)
    face = Face.load(folder / "generic_neutral_mesh.obj")
    mesh = face.mesh
    files = {"eyeBlinkLeft": "eyeBlink_L", "eyeBlinkRight": "eyeBlink_R", "jawOpen": "jawOpen",
             "mouthSmileLeft": "mouthSmile_L", "mouthSmileRight": "mouthSmile_R"}
    shapes = {n: load_mesh(folder / f"{f}.obj").vertices - mesh.vertices for n, f in files.items()}
    binds = {"blink": {"eyeBlinkLeft": 1.0, "eyeBlinkRight": 1.0}, "blinkLeft": {"eyeBlinkLeft": 1.0},
             "blinkRight": {"eyeBlinkRight": 1.0}, "aa": {"jawOpen": 0.6},
             "happy": {"mouthSmileLeft": 1.0, "mouthSmileRight": 1.0}}
    pivot, eyes = _pivot_and_eyes(face)
    path = write_vrm(tmp_path / "ict.vrm", mesh, shapes, binds, head_pivot=pivot, rotation=face.frame.rotation,
                     scale=0.01, eyes=eyes, meta={"authors": ["ICT-VGL (ICT FaceKit, MIT)"]})
    gltf = _doc(path)
    prim = gltf.meshes[0].primitives[0]
    src = np.asarray(prim.extras["sourceVertex"])
    assert len(src) == len(mesh.per_vertex_uv()[0]) > mesh.n_vertices  # seam copies after the mesh's own
    np.testing.assert_array_equal(src[:mesh.n_vertices], np.arange(mesh.n_vertices))
    pos = accessor(gltf, prim.attributes.POSITION)
    np.testing.assert_allclose(pos @ face.frame.rotation / 0.01 + pivot, mesh.vertices[src], atol=1e-4)
    assert 0.2 < np.linalg.norm(pos.max(0) - pos.min(0)) < 0.6  # a head in metres
    offset = gltf.extensions["VRMC_vrm"]["lookAt"]["offsetFromHeadBone"]
    assert offset[2] > 0.03 and abs(offset[0]) < 0.01  # the eyes ahead of the head bone, on the midline

    if shutil.which("node") is None:
        pytest.skip("node is missing")
    if (MODULES / "gltf-validator").exists():
        out = subprocess.run(["node", str(ROOT / "tools" / "validate_gltf.js"), str(path)],
                             capture_output=True, text=True, check=True)
        report = json.loads(out.stdout)
        assert report["numErrors"] == 0 and report["numWarnings"] == 0, report["messages"]
    if (MODULES / "@pixiv" / "three-vrm").exists():
        out = subprocess.run(["node", str(ROOT / "tools" / "check_vrm.mjs"), str(path)],
                             capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stderr
        got = json.loads(out.stdout)
        names = list(shapes)
        assert got["warnings"] == [] and got["meshes"][0]["textured"] is False
        for name, b in binds.items():
            assert {names[int(i)]: w for i, w in got["effects"][name][0].items()} == pytest.approx(b)


# ------------------------------------------------------------------------------------- VRM 0.x


def _three_vrm(path):
    if shutil.which("node") is None or not (MODULES / "@pixiv" / "three-vrm").exists() \
            or not (MODULES / "three").exists():
        pytest.skip("node or three/@pixiv/three-vrm are missing in tools/ (scripts/setup.sh installs them)")
    out = subprocess.run(["node", str(ROOT / "tools" / "check_vrm.mjs"), str(path)],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


@pytest.fixture(scope="module")
def avatar0(avatar, tmp_path_factory):
    """The same head written as VRM 0.x, with a thumbnail and an open licence."""
    import io

    from PIL import Image

    _, face, shapes, pivot, eyes = avatar
    png = io.BytesIO()
    Image.fromarray(np.full((64, 64, 3), 200, dtype=np.uint8)).save(png, format="PNG")
    path = tmp_path_factory.mktemp("vrm0") / "avatar0.vrm"
    write_vrm(path, face.mesh, shapes, BINDS, head_pivot=pivot, rotation=face.frame.rotation, eyes=eyes,
              meta={"name": "Default head", "authors": ["faceanim tests"], "avatarPermission": "everyone",
                    "commercialUsage": "corporation", "modification": "allowModificationRedistribution",
                    "allowRedistribution": True, "creditNotation": "required"},
              custom={"jawOpen": {"jawOpen": 1.0}}, version=0, thumbnail=png.getvalue())
    return path, png.getvalue()


def test_vrm0_extension_by_hand(avatar0):
    path, png = avatar0
    gltf = _doc(path)
    assert gltf.extensionsUsed == ["VRM"] and "VRMC_vrm" not in (gltf.extensions or {})
    ext = gltf.extensions["VRM"]
    assert ext["specVersion"] == "0.0"
    meta = ext["meta"]
    assert meta["title"] == "Default head" and meta["author"] == "faceanim tests"
    assert meta["allowedUserName"] == "Everyone" and meta["commercialUssageName"] == "Allow"
    assert meta["licenseName"] == "CC_BY" and meta["violentUssageName"] == "Disallow"
    image = gltf.images[gltf.textures[meta["texture"]].source]
    view = gltf.bufferViews[image.bufferView]
    blob = gltf.binary_blob()
    assert blob[view.byteOffset:view.byteOffset + view.byteLength] == png  # the thumbnail, as given
    assert {b["bone"] for b in ext["humanoid"]["humanBones"]} >= set(REQUIRED_BONES)
    groups = {g["name"]: g for g in ext["blendShapeMaster"]["blendShapeGroups"]}
    assert groups["A"]["presetName"] == "a" and groups["Blink_L"]["presetName"] == "blink_l"
    assert groups["Joy"]["presetName"] == "joy" and groups["Surprised"]["presetName"] == "unknown"
    assert groups["JawOpen"]["presetName"] == "unknown"  # a custom expression: perfect-sync spelling
    names = gltf.meshes[0].extras["targetNames"]
    assert {names[b["index"]]: b["weight"] for b in groups["A"]["binds"]} == pytest.approx({"jawOpen": 70.0})
    assert ext["firstPerson"]["meshAnnotations"] == [{"mesh": 0, "firstPersonFlag": "ThirdPersonOnly"}]
    # facing -Z: the nose tip (MediaPipe 1) in front of the head bone is at negative z
    v = accessor(gltf, gltf.meshes[0].primitives[0].attributes.POSITION)
    assert v[1, 2] < -0.05


def test_three_vrm_reads_vrm0_as_it_reads_the_same_avatar_in_vrm1(avatar, avatar0):
    """pixiv's three-vrm, a 0.x consumer as well: the 0.x file (turned to face +Z as its users do,
    VRMUtils.rotateVRM0) gives the 1.0 file's expressions (0.x's preset names mapped back), gaze,
    mesh box, head and eye offset (mirrored: 0.x faces the other way), and its licence and
    thumbnail."""
    one, zero = _three_vrm(avatar[0]), _three_vrm(avatar0[0])
    assert zero["vrm"] and zero["warnings"] == [] and zero["meta"]["metaVersion"] == "0"
    assert zero["meta"]["licenseName"] == "CC_BY" and zero["meta"]["allowedUserName"] == "Everyone"
    for name, effect in one["effects"].items():
        key = "Surprised" if name == "surprised" else name
        assert [set(e) for e in zero["effects"][key]] == [set(e) for e in effect], name
        for a, b in zip(zero["effects"][key], effect):
            assert a == pytest.approx(b, abs=1e-9), name  # 0.x's weights are hundredths
    assert zero["effects"]["JawOpen"] != [{}]
    for way in ("left", "up"):
        assert zero["gaze"][way] == pytest.approx(one["gaze"][way], abs=1e-6)
    for end in ("min", "max"):
        assert zero["meshBox"][end] == pytest.approx(one["meshBox"][end], abs=1e-5)
    assert zero["headWorld"] == one["headWorld"]
    x, y, z = one["lookAt"]["offsetFromHeadBone"]
    assert zero["lookAt"]["offsetFromHeadBone"] == pytest.approx([-x, y, -z], abs=1e-6)
    assert zero["firstPerson"] == one["firstPerson"]


def _run(argv) -> int:
    from faceanim.cli import main

    try:
        return main(argv)
    except SystemExit as exc:  # argparse's refusals
        return exc.code


def test_rig_writes_vrm0_with_a_licence_and_refuses_bad_ones(tmp_path, capsys):
    main = _run

    out = tmp_path / "a.vrm"
    assert main(["rig", "-o", str(out), "--set", "arkit", "--vrm", "0", "--license", "cc0"]) == 0
    ext = _doc(out).extensions["VRM"]
    assert ext["meta"]["licenseName"] == "CC0"
    groups = {g["name"] for g in ext["blendShapeMaster"]["blendShapeGroups"]}
    assert {"Blink", "Blink_L", "LookUp", "EyeBlinkLeft", "TongueOut"} <= groups
    from PIL import Image

    gltf = _doc(out)
    view = gltf.bufferViews[gltf.images[gltf.textures[ext["meta"]["texture"]].source].bufferView]
    import io

    thumb = Image.open(io.BytesIO(gltf.binary_blob()[view.byteOffset:view.byteOffset + view.byteLength]))
    assert thumb.size == (512, 512) and np.asarray(thumb).std() > 10  # a rendered face, not a blank
    for bad, phrase in ((["--license", "avatarPermission=all"], "avatarPermission takes"),
                        (["--license", "colour=red"], "is not a licence"), (["--vrm", "2"], "invalid choice"),
                        (["--license", "avatarPermission=everyone,"], "--license has an empty item")):
        assert main(["rig", "-o", str(tmp_path / "b.vrm"), "--set", "arkit", *bad]) == 2
        assert phrase in capsys.readouterr().err
    assert main(["rig", "-o", str(tmp_path / "c.glb"), "--vrm", "0"]) == 2
    assert "for a .vrm output" in capsys.readouterr().err
    assert not any((tmp_path / n).exists() for n in ("b.vrm", "c.glb"))
    one = tmp_path / "one.vrm"
    assert main(["rig", "-o", str(one), "--set", "arkit", "--license",
                 "avatarPermission=everyone,allowRedistribution=true"]) == 0
    meta = _doc(one).extensions["VRMC_vrm"]["meta"]
    assert meta["avatarPermission"] == "everyone" and meta["allowRedistribution"] is True
    assert meta["commercialUsage"] == "personalNonProfit" and "thumbnailImage" in meta


def test_vrm0_passes_the_khronos_validator_but_for_its_extension_name(avatar0):
    """0 errors; the one warning is the name VRM 0.x's extension has had since 2018 ("VRM", not
    PREFIX_name), which every 0.x file carries."""
    if shutil.which("node") is None or not (MODULES / "gltf-validator").exists():
        pytest.skip("node or the gltf-validator npm package is missing (scripts/setup.sh installs it)")
    out = subprocess.run(["node", str(ROOT / "tools" / "validate_gltf.js"), str(avatar0[0])],
                         capture_output=True, text=True, check=True)
    report = json.loads(out.stdout)
    assert report["numErrors"] == 0 and report["numWarnings"] == 1
    assert [m for m in report["messages"] if m.startswith("1 ")] == [
        "1 INVALID_EXTENSION_NAME_FORMAT /extensionsUsed/0 Extension name has invalid format."]


def test_a_nod_turns_the_humanoid_head_forward_in_vrm1_and_vrm0(avatar, avatar0, tmp_path):
    """play_on_avatar's head motion on VRM 1.0 (facing +Z) and VRM 0.x (facing -Z) of the same head:
    the humanoid's head bone is the one turned, the forward found from the face is +Z and -Z, and a
    nod down of 0.3 rad takes the eyes down (skinned by the spec's joint matrices) by the same
    amount in both."""
    from test_arkit_play import _posed_eyes

    from faceanim.avatar import face_axes, head_bone, play_on_avatar
    from faceanim.io.scene import read_scene
    from faceanim.standards.arkit import ARKIT_NAMES

    head = np.zeros((2, 3))
    head[1, 1] = 0.3
    drops = []
    for path, forward in ((avatar[0], 1.0), (avatar0[0], -1.0)):
        scene = read_scene(path)
        bone = head_bone(scene)
        ext = scene._json["extensions"]
        vrm_head = ext["VRMC_vrm"]["humanoid"]["humanBones"]["head"]["node"] if "VRMC_vrm" in ext else \
            next(b["node"] for b in ext["VRM"]["humanoid"]["humanBones"] if b["bone"] == "head")
        assert bone == vrm_head
        np.testing.assert_allclose(face_axes(scene, bone)[2], [0.0, 0.0, forward], atol=1e-9)
        out = tmp_path / f"nod{path.suffix}{forward:+.0f}.vrm"
        played = play_on_avatar(path, out, np.zeros((2, len(ARKIT_NAMES))), 30.0, head=head)
        assert played.head_bone is not None
        rest, _, pivot = _posed_eyes(out, 0)
        down, _, _ = _posed_eyes(out, 1)
        assert down[1] < rest[1] - 1e-3
        drops.append(rest[1] - down[1])
    assert drops[0] == pytest.approx(drops[1], rel=1e-3)
