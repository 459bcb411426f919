"""Live Link Face takes played on any face (issue 12, item 3): ARKit's blendshapes retargeted from
the generic head with Apple's names; the take's curves and head angles animated."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pygltflib
import pytest
from gltf_reader import accessor

from faceanim.cli import main
from faceanim.face.face import Face

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
TAKE = DATA / "arkit-curves" / "alex_rom_3.csv"
needs_take = pytest.mark.skipif(not TAKE.is_file(), reason="../shared/data/arkit-curves is not here")


def run(args) -> int:
    try:
        return main([str(a) for a in args])
    except SystemExit as exc:
        return exc.code


def test_arkit_rig_names_and_shapes_on_the_default_face():
    """52 controls with Apple's names in Live Link Face's order (tongueOut made by faceanim); on the
    default face (made from the generic head) the retargeted shapes are within 10% of the shapes
    carried exactly by the fit; browInnerUp is the sum of ICT's halves."""
    from faceanim.face.default import default_shapes
    from faceanim.standards.arkit import ARKIT_NAMES
    from faceanim.rig.arkit import arkit_rig
    from faceanim.standards.arkit import apple_name

    rig, missing = arkit_rig(Face.default())
    assert missing == [] and rig.n_controls == 52
    assert rig.controls == [apple_name(n) for n in ARKIT_NAMES]
    assert rig.controls[0] == "eyeBlinkLeft" and "jawOpen" in rig.controls
    carried = default_shapes()
    for apple, ict in [("jawOpen", ["jawOpen"]), ("eyeBlinkLeft", ["eyeBlink_L"]), ("mouthSmileRight", ["mouthSmile_R"]),
                       ("browInnerUp", ["browInnerUp_L", "browInnerUp_R"])]:
        want = sum(carried[n] for n in ict)
        assert np.linalg.norm(rig.blendshape(apple) - want) < 0.1 * np.linalg.norm(want), apple


def _small_take(path: Path) -> None:
    from faceanim.io.arkit_csv import write_arkit_csv
    from faceanim.standards.arkit import ARKIT_NAMES

    w = np.zeros((20, len(ARKIT_NAMES)))
    w[:, ARKIT_NAMES.index("JawOpen")] = np.linspace(0, 1, 20)
    w[5:9, ARKIT_NAMES.index("EyeBlinkLeft")] = 1.0
    head = np.zeros((20, 3))
    head[:, 0] = np.linspace(0, 0.3, 20)  # yaw, radians
    write_arkit_csv(path, w, 30.0, head)


def test_arkit_play_writes_glb_csv_and_mp4(tmp_path):
    from faceanim.io.arkit_csv import read_arkit_csv
    from faceanim.standards.arkit import ARKIT_NAMES
    from faceanim.io.gltf import glb_json
    from faceanim.standards.arkit import apple_name

    _small_take(tmp_path / "take.csv")
    assert run(["arkit", "play", tmp_path / "take.csv", "-o", tmp_path / "t.glb"]) == 0
    doc = glb_json(tmp_path / "t.glb")
    names = doc["meshes"][0]["extras"]["targetNames"]
    assert names == [apple_name(n) for n in ARKIT_NAMES]  # a whole ARKit rig, Apple's names
    anim = doc["animations"][0]
    assert [c["target"]["path"] for c in anim["channels"]] == ["weights", "rotation"]
    assert doc["accessors"][anim["samplers"][1]["output"]]["count"] == 20
    # the weights as recorded, by name (read with the spec's own decoding)
    gltf = pygltflib.GLTF2().load_binary(str(tmp_path / "t.glb"))
    w = accessor(gltf, anim["samplers"][0]["output"]).reshape(20, len(names))
    np.testing.assert_allclose(w[:, names.index("jawOpen")], np.linspace(0, 1, 20), atol=1e-6)
    np.testing.assert_allclose(w[:, names.index("eyeBlinkLeft")], np.r_[np.zeros(5), np.ones(4), np.zeros(11)])
    assert np.abs(np.delete(w, [names.index("jawOpen"), names.index("eyeBlinkLeft")], axis=1)).max() == 0
    assert run(["arkit", "play", tmp_path / "take.csv", "--fps", "60", "-o", tmp_path / "t.csv"]) == 0
    back = read_arkit_csv(tmp_path / "t.csv")
    assert back.n_samples == 39  # 19 intervals of 1/30 s at 60 fps
    np.testing.assert_allclose(back.weights[::2], read_arkit_csv(tmp_path / "take.csv").weights, atol=1e-5)
    assert run(["arkit", "play", tmp_path / "take.csv", "--size", "128", "--quiet", "-o", tmp_path / "t.mp4"]) == 0
    assert (tmp_path / "t.mp4").stat().st_size > 0


def test_arkit_play_bad_input(tmp_path, capsys):
    _small_take(tmp_path / "take.csv")
    (tmp_path / "bad.csv").write_text("Timecode,EyeBlinkLeft\n")
    (tmp_path / "face.obj").write_text("hello\n")
    lines = (tmp_path / "take.csv").read_text().splitlines()
    row = lines[1].split(",")
    long_rows = []
    for i in range(3000):  # a sample every 9 s for 7.5 hours: 810,000 frames at 30 fps
        t = 9 * i
        row[0] = f"{t // 3600:02d}:{t // 60 % 60:02d}:{t % 60:02d}:00.000"
        long_rows.append(",".join(row))
    (tmp_path / "long.csv").write_text("\n".join([lines[0], *long_rows]) + "\n")
    out = tmp_path / "o.glb"
    for args, phrase in [
        (["arkit", "play", tmp_path / "none.csv", "-o", out], "does not exist"),
        (["arkit", "play", tmp_path / "bad.csv", "-o", out], "lacks the column"),
        (["arkit", "play", tmp_path / "long.csv", "-o", out], "lower --fps or cut the take"),
        (["arkit", "play", tmp_path / "take.csv", "--face", tmp_path / "face.obj", "-o", tmp_path / "o.csv"],
         "drop --face"),
        (["arkit", "play", tmp_path / "take.csv", "-o", tmp_path / "take.csv"], "also an input"),
        (["arkit", "play", tmp_path / "take.csv", "--size", "65", "-o", tmp_path / "o.mp4"], "--size must be even"),
    ]:
        before = sorted(tmp_path.iterdir())
        assert run(args) == 2, args
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and phrase in err, (args, err)
        assert sorted(tmp_path.iterdir()) == before


@needs_take
def test_the_real_take_on_another_person(tmp_path):
    """The real take on FaceWarehouse tester 1 (another mesh): at its widest jaw opening the lower
    lip goes down by over a tenth of the eye distance."""
    from faceanim.io.arkit_csv import read_arkit_csv
    from faceanim.standards.arkit import ARKIT_NAMES
    from faceanim.rig.arkit import arkit_rig
    from faceanim.standards.arkit import apple_name

    face = Face.load(DATA / "facewarehouse-tester1" / "pose_0.obj")
    rig, _ = arkit_rig(face)
    take = read_arkit_csv(TAKE).resample(10.0)
    f = int(np.argmax(take.weights[:, ARKIT_NAMES.index("JawOpen")]))
    curves = take.weights[f:f + 1, [[apple_name(n) for n in ARKIT_NAMES].index(c) for c in rig.controls]]
    v = rig.evaluate(curves)[0]
    lower_lip = int(np.argmin(np.linalg.norm(face.mesh.vertices - face.landmarks[17], axis=1)))
    drop = (face.mesh.vertices[lower_lip] - v[lower_lip]) @ face.frame.rotation[1]
    assert drop > 0.1 * face.frame.iod


def test_a_fap_stream_as_arkit_curves_follows_the_jaw():
    """A FAP stream that opens the jaw, stretches a lip corner and closes a lid, fitted with the
    face's ARKit shapes: jawOpen follows open_jaw (r > 0.95), the stretch lands on the subject's
    left mouth corner, the blink on the left eye, and the fit leaves under half of the motion."""
    from faceanim.face.faps import FapStream
    from faceanim.standards.mpeg4 import N_FAPS, faps
    from faceanim.standards.arkit import ARKIT_NAMES
    from faceanim.player import arkit_from_stream
    from faceanim.rig.mpeg4 import FapRig

    face = Face.default()
    rig = FapRig.build(face)
    idx = {f.name: f.number - 1 for f in faps()}
    n = 30
    values = np.zeros((n, N_FAPS))
    values[:, idx["open_jaw"]] = 600 * np.sin(np.linspace(0, np.pi, n))
    values[10:20, idx["stretch_l_cornerlip"]] = 300
    values[20:, idx["close_t_l_eyelid"]] = 600
    values[20:, idx["close_b_l_eyelid"]] = -150
    stream = FapStream(values, np.ones_like(values, dtype=bool), 30.0)
    w, head, residual = arkit_from_stream(face, rig, stream)
    col = {n: ARKIT_NAMES.index(n) for n in ARKIT_NAMES}
    assert np.corrcoef(w[:, col["JawOpen"]], values[:, idx["open_jaw"]])[0, 1] > 0.95
    assert w[10:20, col["MouthStretchLeft"]].mean() > w[10:20, col["MouthStretchRight"]].mean() + 0.1
    assert w[22:, col["EyeBlinkLeft"]].mean() > w[22:, col["EyeBlinkRight"]].mean() + 0.15
    assert residual < 0.5 and np.all(head == 0)
    assert np.all(np.minimum(w[:, col["JawLeft"]], w[:, col["JawRight"]]) == 0)


@pytest.mark.skipif(__import__("shutil").which("espeak-ng") is None, reason="espeak-ng is not installed")
def test_say_writes_live_link_face_csv(tmp_path):
    from faceanim.io.arkit_csv import read_arkit_csv
    from faceanim.standards.arkit import ARKIT_NAMES

    assert run(["say", "Papa, how are you?", "--quiet", "-o", tmp_path / "s.csv"]) == 0
    take = read_arkit_csv(tmp_path / "s.csv")
    jaw = take.weights[:, ARKIT_NAMES.index("JawOpen")]
    assert take.n_samples > 20 and jaw.max() > 0.2 and jaw.min() < 0.1  # the mouth opens and closes


def test_arkit_play_onto_the_avatars_own_targets(tmp_path):
    """A face rigged with ARKit's shapes, its jawOpen then edited (as in Blender: here doubled) and
    renamed to another spelling (JawOpen): `arkit play --face` plays the take onto the file's own
    targets by name, keeps the edit, and adds one animation whose weights are the take's."""
    from faceanim.standards.arkit import ARKIT_NAMES
    from faceanim.io.gltf import glb_json
    from faceanim.io.scene import read_scene, write_scene

    _small_take(tmp_path / "take.csv")
    rigged, edited, out = tmp_path / "rigged.glb", tmp_path / "edited.glb", tmp_path / "played.glb"
    assert run(["rig", "--set", "arkit", "-o", rigged]) == 0
    scene = read_scene(rigged)
    mi = next(m.index for m in scene.meshes() if "jawOpen" in m.target_names)
    jaw = scene.targets(mi, ["jawOpen"])["jawOpen"]
    write_scene(scene, edited, {mi: {"jawOpen": 2.0 * jaw}}, replace=True)
    doc = glb_json(edited)
    doc_names = doc["meshes"][mi]["extras"]["targetNames"]
    doc_names[doc_names.index("jawOpen")] = "JawOpen"  # another tool's spelling
    from faceanim.io.scene import _glb

    blob = edited.read_bytes()
    json_len = int.from_bytes(blob[12:16], "little")
    import json

    text = json.dumps(doc, separators=(",", ":")).encode("ascii")
    edited.write_bytes(_glb(text, blob[20 + json_len + 8:]))
    before = glb_json(edited)
    assert run(["arkit", "play", tmp_path / "take.csv", "--face", edited, "-o", out]) == 0
    after = glb_json(out)
    assert len(after["animations"]) == len(before.get("animations", [])) + 1
    assert after["meshes"][mi]["extras"]["targetNames"] == before["meshes"][mi]["extras"]["targetNames"]
    played = read_scene(out)
    np.testing.assert_allclose(played.targets(mi, ["JawOpen"])["JawOpen"], 2.0 * jaw, atol=1e-6)  # the edit kept
    gltf = pygltflib.GLTF2().load_binary(str(out))
    anim = after["animations"][-1]
    names = after["meshes"][mi]["extras"]["targetNames"]
    w = accessor(gltf, anim["samplers"][0]["output"]).reshape(20, len(names))
    np.testing.assert_allclose(w[:, names.index("JawOpen")], np.linspace(0, 1, 20), atol=1e-6)
    np.testing.assert_allclose(w[:, names.index("eyeBlinkLeft")], np.r_[np.zeros(5), np.ones(4), np.zeros(11)])
    assert {c["target"]["path"] for c in anim["channels"]} == {"weights"}
    assert len(names) == len(ARKIT_NAMES)


def test_arkit_play_vrm_output_needs_a_vrm_avatar(tmp_path, capsys):
    _small_take(tmp_path / "take.csv")
    assert run(["arkit", "play", tmp_path / "take.csv", "-o", tmp_path / "x.vrm"]) == 2
    assert "--face VRM avatar" in capsys.readouterr().err and not (tmp_path / "x.vrm").exists()


VROID = DATA / "avatars" / "vroid-sample.glb"


@pytest.mark.skipif(not VROID.exists(), reason="needs ../shared/data/avatars/vroid-sample.glb")
def test_arkit_play_onto_a_whole_vroid_avatar(tmp_path):
    """A skinned, multi-mesh VRoid export whose face mesh carries ARKit-named targets: every node,
    mesh and target kept, one animation added that drives the face mesh's 52; the Khronos validator
    finds no error where it is installed."""
    import json
    import shutil
    import subprocess

    from faceanim.io.gltf import glb_json

    _small_take(tmp_path / "take.csv")
    out = tmp_path / "vroid.glb"
    assert run(["arkit", "play", tmp_path / "take.csv", "--face", VROID, "-o", out]) == 0
    a, b = glb_json(VROID), glb_json(out)
    assert len(b["nodes"]) == len(a["nodes"]) and len(b["meshes"]) == len(a["meshes"])
    assert [m.get("extras", {}).get("targetNames") for m in b["meshes"]] == \
        [m.get("extras", {}).get("targetNames") for m in a["meshes"]]
    assert len(b["animations"]) == len(a.get("animations", [])) + 1
    anim = b["animations"][-1]
    face = {b["nodes"][c["target"]["node"]]["mesh"] for c in anim["channels"] if c["target"]["path"] == "weights"}
    names = b["meshes"][face.pop()]["extras"]["targetNames"]
    gltf = pygltflib.GLTF2().load_binary(str(out))
    w = accessor(gltf, anim["samplers"][0]["output"]).reshape(20, len(names))
    np.testing.assert_allclose(w[:, names.index("jawOpen")], np.linspace(0, 1, 20), atol=1e-6)
    assert np.all(w[:, [k for k, n in enumerate(names) if n.startswith("Fcl_")]] == 0)  # its own presets rest
    validator = Path(__file__).resolve().parents[1] / "tools" / "validate_gltf.js"
    if shutil.which("node") and (validator.parent / "node_modules" / "gltf-validator").exists():
        report = json.loads(subprocess.run(["node", str(validator), str(out)], capture_output=True, text=True,
                                           check=True).stdout)
        assert report["numErrors"] == 0


@pytest.mark.skipif(not VROID.exists(), reason="needs ../shared/data/avatars/vroid-sample.glb")
@pytest.mark.skipif(not shutil.which("espeak-ng"), reason="espeak-ng is not installed (scripts/setup.sh installs it)")
def test_say_onto_an_avatars_own_targets(tmp_path):
    """say --face avatar.glb with ARKit-named targets: the avatar with the speech as one more
    animation on its own jawOpen (p, b, m shut: mouthClose reaches jawOpen), its head bone turned
    by the voice's nods and leans, the sound beside it."""
    from faceanim.io.gltf import glb_json
    from faceanim.io.scene import read_scene

    out = tmp_path / "say.glb"
    assert run(["say", "Peter Piper picked a peck", "--face", VROID, "-o", out]) == 0
    doc = glb_json(out)
    anim = doc["animations"][-1]
    mi = doc["nodes"][anim["channels"][0]["target"]["node"]]["mesh"]
    names = doc["meshes"][mi]["extras"]["targetNames"]
    w = accessor(pygltflib.GLTF2().load_binary(str(out)), anim["samplers"][0]["output"]).reshape(-1, len(names))
    jaw, close = w[:, names.index("jawOpen")], w[:, names.index("mouthClose")]
    assert jaw.max() > 0.2 and np.any((close > 0.1) & (np.abs(close - jaw) < 0.02))
    assert doc["scenes"][doc.get("scene", 0)]["extras"]["audio"] == "say.wav" and (tmp_path / "say.wav").is_file()
    assert len(read_scene(out).meshes()) == len(read_scene(VROID).meshes())
    # and the voice's head motion (a nod at the phrase's end, a lean) turns its Head bone from rest
    from scipy.spatial.transform import Rotation

    turn = next(c for c in anim["channels"] if c["target"]["path"] == "rotation")
    assert doc["nodes"][turn["target"]["node"]]["name"] == "Head"
    q = accessor(pygltflib.GLTF2().load_binary(str(out)), anim["samplers"][turn["sampler"]]["output"])
    rest = Rotation.from_quat(doc["nodes"][turn["target"]["node"]]["rotation"])
    away = (rest.inv() * Rotation.from_quat(q)).magnitude()
    assert away[0] < 1e-3 and 0.03 < away.max() < 0.15


def _posed_eyes(path: Path, frame: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(left eye, right eye, head pivot) in world space at ``frame`` of the file's last animation:
    its rotation channel decoded by hand (gltf_reader), put on the node, and the face mesh skinned
    by the glTF spec's joint matrices (faceanim.io.scene's skinning of the bind pose, with the
    posed node matrices); each eye: the centroid of what its eyeBlink target moves."""
    from faceanim.io.gltf import glb_json
    from faceanim.io.scene import _global_matrices, read_scene

    doc = glb_json(path)
    anim = doc["animations"][-1]
    turn = [c for c in anim["channels"] if c["target"]["path"] == "rotation"]
    assert len(turn) == 1
    q = accessor(pygltflib.GLTF2().load_binary(str(path)), anim["samplers"][turn[0]["sampler"]]["output"])
    scene = read_scene(path)
    node = turn[0]["target"]["node"]
    scene._json["nodes"][node] = {**scene._json["nodes"][node], "rotation": [float(x) for x in q[frame]]}
    scene._globals = _global_matrices(scene._json, scene._bad)
    scene._cache.clear()
    mi = next(m.index for m in scene.meshes() if "eyeBlinkLeft" in m.target_names)
    world = scene._world_positions(mi)
    blink = scene.targets(mi, ["eyeBlinkLeft", "eyeBlinkRight"])
    left, right = (world[np.linalg.norm(blink[k], axis=1) > 1e-6].mean(0) for k in ("eyeBlinkLeft", "eyeBlinkRight"))
    return left, right, scene._globals[node][:3, 3]


@pytest.mark.skipif(not VROID.exists(), reason="needs ../shared/data/avatars/vroid-sample.glb")
def test_the_takes_head_turns_a_vroid_avatars_head_bone(tmp_path):
    """arkit play --face VROID: the take's head angles turn the avatar's Head bone about its pivot,
    as seen on the skinned face (an oracle that knows nothing of the avatar's facing: its own
    eyes): rest at 0; a nod down of 0.3 rad turns the eyes 0.3 rad about the pivot, downward and
    not sideways; a turn to the avatar's left takes both eyes towards its left eye's side; a tilt
    to its right puts its right eye lower than its left."""
    from faceanim.io.arkit_csv import write_arkit_csv
    from faceanim.io.scene import read_scene
    from faceanim.standards.arkit import ARKIT_NAMES

    head = np.zeros((4, 3))
    head[1, 1], head[2, 0], head[3, 2] = 0.3, 0.3, 0.3  # a nod down, a turn to its left, a tilt to its right
    write_arkit_csv(tmp_path / "take.csv", np.zeros((4, len(ARKIT_NAMES))), 30.0, head)
    out = tmp_path / "vroid.glb"
    assert run(["arkit", "play", tmp_path / "take.csv", "--face", VROID, "--fps", "30", "-o", out]) == 0
    rest_l, rest_r, pivot = _posed_eyes(out, 0)
    bind = read_scene(VROID)
    mi = next(m.index for m in bind.meshes() if "eyeBlinkLeft" in m.target_names)
    blink = bind.targets(mi, ["eyeBlinkLeft"])["eyeBlinkLeft"]
    np.testing.assert_allclose(rest_l, bind._world_positions(mi)[np.linalg.norm(blink, axis=1) > 1e-6].mean(0),
                               atol=1e-6)  # frame 0: the bind pose
    mid = 0.5 * (rest_l + rest_r) - pivot
    side = rest_l - rest_r  # towards the avatar's left
    side[1] = 0.0
    side /= np.linalg.norm(side)
    left, right, _ = _posed_eyes(out, 1)
    nod = 0.5 * (left + right) - pivot
    angle = np.arccos(np.clip(nod @ mid / np.linalg.norm(nod) / np.linalg.norm(mid), -1, 1))
    assert angle == pytest.approx(0.3, abs=0.01) and nod[1] < mid[1] - 0.01
    assert abs((nod - mid) @ side) < 1e-3
    left, right, _ = _posed_eyes(out, 2)
    assert (0.5 * (left + right) - pivot - mid) @ side > 0.01
    left, right, _ = _posed_eyes(out, 3)
    assert right[1] < left[1] - 0.01


@pytest.mark.skipif(not VROID.exists(), reason="needs ../shared/data/avatars/vroid-sample.glb")
def test_a_rotation_channel_is_refused_on_a_node_it_cannot_turn(tmp_path):
    """write_scene's rotation channels: a node that is not there, quaternions that are not unit or
    not one per key: refused, one line, nothing written; the avatar's head bone is VRoid's Head."""
    import re

    from faceanim.avatar import head_bone
    from faceanim.errors import MeshError
    from faceanim.io.scene import read_scene, write_scene

    scene = read_scene(VROID)
    bone = head_bone(scene)
    assert scene._json["nodes"][bone]["name"] == "Head"
    unit = np.tile([0.0, 0.0, 0.0, 1.0], (3, 1))
    for rotations, phrase in (({10_000: unit}, "node"), ({bone: 2 * unit}, "unit"), ({bone: unit[:2]}, "(3, 4)"),
                              ({bone: np.full((3, 4), np.nan)}, "unit")):
        with pytest.raises(MeshError, match=re.escape(phrase)):
            write_scene(scene, tmp_path / "x.glb", {}, animation={"times": np.arange(3) / 30.0, "weights": {},
                                                                  "rotations": rotations})
    assert not (tmp_path / "x.glb").exists()
