"""faceanim's glb files in Blender: imported with Blender's own glTF importer (PyPI's ``bpy``), the
shape keys are the file's morph targets by name and in order, the animation is an action with one
fcurve per animated target (and the head's rotation an object action), the keys' values at whole
frames are the file's weights, and every shape key moves the vertices as its morph target does
(after Blender's Y-up to Z-up axis change).

``bpy`` 5.0.1 is 0.8 GB and wants Python 3.11 exactly, so it lives in its own venv,
``.venv-blender`` (``scripts/setup.sh`` makes it when it can); ``FACEANIM_BLENDER_PYTHON`` names
another interpreter that has it. Without one, these tests skip. Blender runs in a subprocess
(``scripts/check_blender.py``), which reports Blender's side as JSON and arrays; the file's side is
read here with the spec's own decoding (``tests/gltf_reader.py``)."""

from __future__ import annotations

import functools
import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pygltflib
import pytest
from conftest import DATA, ROOT
from gltf_reader import accessor

SCRIPT = ROOT / "scripts" / "check_blender.py"
TAKE = DATA / "arkit-curves" / "alex_rom_3.csv"
VIDEO = DATA / "talking-head-videos" / "d0.mp4"
AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # glTF (x, y, z) -> Blender (x, -z, y)
FPS = 25


@functools.lru_cache(maxsize=1)
def _blender_python() -> tuple[str | None, str]:
    """An interpreter that imports bpy, and why not when there is none."""
    candidates = []
    if os.environ.get("FACEANIM_BLENDER_PYTHON"):
        candidates.append(os.environ["FACEANIM_BLENDER_PYTHON"])
    candidates.append(str(ROOT / ".venv-blender" / "bin" / "python"))
    if importlib.util.find_spec("bpy") is not None:
        candidates.append(sys.executable)
    tried = []
    for py in candidates:
        if not Path(py).exists():
            tried.append(f"{py}: not found")
            continue
        try:
            run = subprocess.run([py, "-c", "import bpy; print(bpy.app.version_string)"], check=False,
                                 capture_output=True, text=True, timeout=300)
        except (OSError, subprocess.TimeoutExpired) as exc:
            tried.append(f"{py}: {exc}")
            continue
        if run.returncode == 0:
            return py, run.stdout.strip()
        tried.append(f"{py}: {(run.stderr.strip().splitlines() or ['import bpy failed'])[-1]}")
    return None, "; ".join(tried)


@pytest.fixture(scope="module")
def blender():
    py, why = _blender_python()
    if py is None:
        pytest.skip("Blender's Python module bpy is not importable (bash scripts/setup.sh makes .venv-blender "
                    f"with PyPI's bpy, or set FACEANIM_BLENDER_PYTHON): {why}")
    return py


def check(blender, glb: Path, *options) -> tuple[dict, dict]:
    """Run scripts/check_blender.py on one file: its report and Blender's arrays."""
    out, dump = glb.with_suffix(".blender.json"), glb.with_suffix(".blender.npz")
    run = subprocess.run([blender, str(SCRIPT), str(glb), "--json", str(out), "--dump", str(dump),
                          "--fps", str(FPS), *map(str, options)], check=False, capture_output=True, text=True,
                         timeout=900)
    assert run.returncode in (0, 1), run.stdout + run.stderr
    report = json.loads(out.read_text())["files"][0]
    with np.load(dump) as z:
        arrays = {k: z[k] for k in z.files}
    return report, arrays


def file_side(glb: Path) -> dict:
    """The file read with tests/gltf_reader.py: the mesh node, names, positions, targets (in its
    node's units, dequantised), the node's uniform scale, the weight channel."""
    g = pygltflib.GLTF2().load(str(glb))
    ni = next(i for i, n in enumerate(g.nodes) if n.mesh is not None)
    node, mesh = g.nodes[ni], g.meshes[g.nodes[ni].mesh]
    prim = mesh.primitives[0]
    anim = g.animations[0]
    by_path = {c.target.path: anim.samplers[c.sampler] for c in anim.channels}
    names = mesh.extras["targetNames"]
    times = accessor(g, by_path["weights"].input)
    weights = accessor(g, by_path["weights"].output).reshape(len(times), len(names))
    rotation = None
    if "rotation" in by_path:
        rotation = (accessor(g, by_path["rotation"].input), accessor(g, by_path["rotation"].output))
    return {"node": node, "names": names, "positions": accessor(g, prim.attributes.POSITION),
            "targets": [accessor(g, t["POSITION"] if isinstance(t, dict) else t.POSITION) for t in prim.targets], "scale": (node.scale or [1.0])[0],
            "times": times, "weights": weights, "rotation": rotation,
            "nodes": [n.name for n in g.nodes], "quantized": "KHR_mesh_quantization" in (g.extensionsUsed or [])}


def assert_imports_as_written(report: dict, arrays: dict, glb: Path, check_targets=None):
    """Names, counts, action, values at whole frames and every (or the given) shape key's
    displacement, against the file read independently of the script."""
    f = file_side(glb)
    mesh = report["meshes"][0]
    name = mesh["object"]
    assert mesh["shape_keys"] == f["names"]  # exactly the morph targets, in order
    assert mesh["vertices"] == mesh["file_vertices"] == len(f["positions"])
    # the animation: one action, one fcurve per animated target, on the shape keys
    assert mesh["action"] and mesh["fcurves"] == len(f["names"])
    slots = {s["used_by"]: s for a in report["actions"] for s in a["slots"]}
    assert slots[name]["data_paths"] == sorted(f'key_blocks["{n}"].value' for n in f["names"])
    assert slots[name]["interpolation"] == ["LINEAR"]
    # frame range: seconds * the scene's 25 fps
    frames = report["animation"]["action_frames"]
    assert frames[0] == pytest.approx(f["times"][0] * FPS, abs=1e-3)
    assert frames[1] == pytest.approx(f["times"][-1] * FPS, abs=1e-3)
    # shape key values at whole frames = the file's weights at that time (linear interpolation)
    checked = report["animation"]["frames_checked"]
    assert len(checked) >= 3
    for frame in checked:
        want = np.array([np.interp(frame / FPS, f["times"], f["weights"][:, k]) for k in range(len(f["names"]))])
        np.testing.assert_allclose(arrays[f"{name}/values@{frame}"], want, atol=1e-4)
    # geometry: Basis = positions, each key's displacement = its morph target, after the axes
    unit = f["scale"]
    basis = arrays[f"{name}/basis"].astype(np.float64)
    assert np.abs(basis - f["positions"] @ AXES.T).max() * unit < 1e-5
    deltas = arrays[f"{name}/deltas"]
    for k, target in enumerate(f["targets"]):
        if check_targets is None or f["names"][k] in check_targets:
            err = np.abs(deltas[k] - target @ AXES.T).max() * unit
            assert err < 1e-5, (f["names"][k], err)
    assert report["ok"], report["problems"]


@pytest.fixture(scope="module")
def rig_and_curves():
    from faceanim.face.face import Face
    from faceanim.autorig import full_rig

    rig = full_rig(Face.default())
    frames = 20
    ramp = np.sin(np.linspace(0, np.pi, frames))[:, None]
    curves = ramp * (0.3 + 0.7 * (np.arange(rig.n_controls) % 5) / 4)[None, :]
    return rig, curves


@pytest.mark.parametrize("quantize", [False, True], ids=["float", "quantized"])
def test_full_rig_imports_into_blender(blender, rig_and_curves, tmp_path, quantize):
    """Every control faceanim has on the default face (197 morph targets: ARKit's 52, visemes, Ready
    Player Me's extras, AUs with halves, emotions, FAPs), animated, plain and with
    KHR_mesh_quantization."""
    from faceanim.player import write_rig_gltf

    rig, curves = rig_and_curves
    glb = write_rig_gltf(rig, curves, tmp_path / "rig.glb", fps=FPS, quantize=quantize)
    report, arrays = check(blender, glb)
    assert len(report["meshes"][0]["shape_keys"]) == rig.n_controls == 197
    assert report["extensions"] == (["KHR_mesh_quantization"] if quantize else [])
    assert_imports_as_written(report, arrays, glb)
    # the whole evaluated mesh at the checked frames is the file's (weights applied, node scale)
    assert report["animation"]["world_max_abs"] < 1e-5


def test_signed_weights_are_clamped_by_blenders_importer(blender, rig_and_curves, tmp_path):
    """Weights outside [0, 1] (faceanim's FAP and performance animations have them: say, fap
    play, direct, perform) reach Blender as keyframes unchanged, but Blender clamps a shape key's
    value to its slider range, which its importer widens to the first keyframe's weight only.
    --widen-sliders (the fix a user makes by hand after importing) gives the file's motion back."""
    from faceanim.io.gltf import write_gltf

    rig, curves = rig_and_curves
    names = rig.controls[:4]
    shapes, _ = rig.morph_targets(curves, names)
    ramp = np.sin(np.linspace(0, np.pi, len(curves)))
    # in [0, 1]; down to -1; up to 1.5; a first key outside [0, 1] (the importer widens the
    # slider to it, and only to it) and on below it
    weights = np.stack([ramp, -ramp, 1.5 * ramp, -0.2 - 0.5 * ramp], axis=1)
    glb = write_gltf(tmp_path / "signed.glb", rig.mesh, shapes, times=np.arange(len(ramp)) / FPS, weights=weights)
    report, _ = check(blender, glb)
    assert report["meshes"][0]["shape_keys"] == names
    assert report["meshes"][0]["keyframe_value_max_abs"] < 1e-6  # the keyframes are the file's
    clamped = {k.split("/")[1] for k in report["clamped_keys"]}
    assert clamped == set(names[1:])
    assert report["animation"]["weight_max_abs"] > 0.1 and not report["ok"]

    report, arrays = check(blender, glb, "--widen-sliders")
    assert_imports_as_written(report, arrays, glb)


@pytest.mark.skipif(not TAKE.is_file(), reason="../shared/data/arkit-curves is not here")
def test_arkit_play_imports_with_apples_names(blender, tmp_path):
    """``faceanim arkit play``: 52 shape keys named as Apple names them (eyeBlinkLeft first,
    jawOpen ...), a 134 s take as one action, and the head node's rotation as an object action."""
    from faceanim.cli import main
    from faceanim.standards.arkit import ARKIT_NAMES, apple_name

    glb = tmp_path / "take.glb"
    assert main(["arkit", "play", str(TAKE), "--fps", str(FPS), "-o", str(glb)]) in (0, None)
    report, arrays = check(blender, glb)
    keys = report["meshes"][0]["shape_keys"]
    assert keys == [apple_name(n) for n in ARKIT_NAMES]
    assert keys[0] == "eyeBlinkLeft" and "jawOpen" in keys
    assert_imports_as_written(report, arrays, glb, check_targets={"jawOpen", "eyeBlinkLeft", "mouthSmileLeft"})
    head = [r for r in report["node_animation"] if r["object"] == "head"]
    assert head and head[0]["data_path"] == "rotation_quaternion" and head[0]["fcurves"] == 4


@pytest.mark.skipif(not VIDEO.is_file(), reason="../shared/data/talking-head-videos is not here")
def test_perform_imports_with_the_head_turning(blender, tmp_path):
    """``faceanim perform``: the face's ARKit shapes as shape keys, the head's rotation on the ``head``
    node as an action on Blender's ``head`` empty (parent of ``head_offset``, parent of the mesh),
    and the evaluated mesh at whole frames where the file puts it, the rotation included. Its
    weights stay in [0, 1]: it plays as written with Blender's sliders as they are."""
    from faceanim.cli import main

    glb = tmp_path / "perform.glb"
    assert main(["perform", str(VIDEO), "-o", str(glb)]) in (0, None)
    report, arrays = check(blender, glb)
    assert_imports_as_written(report, arrays, glb)
    parents = {o["name"]: o["parent"] for o in report["objects"]}
    mesh = report["meshes"][0]["object"]
    assert parents[mesh] == "head_offset" and parents["head_offset"] == "head" and parents["head"] is None
    head = [r for r in report["node_animation"] if r["object"] == "head"]
    assert head[0]["data_path"] == "rotation_quaternion" and head[0]["fcurves"] == 4
    assert head[0]["keyframe_max_abs"] < 1e-5 and report["animation"]["rotation_max_abs"] < 1e-4
    slots = {s["used_by"]: s for a in report["actions"] for s in a["slots"]}
    assert slots["head"]["data_paths"] == ["rotation_quaternion"]
    f = file_side(glb)
    turned = np.degrees(2 * np.arccos(np.clip(np.abs(f["rotation"][1][:, 3]), 0, 1))).max()
    assert turned > 1.0  # the head does turn in this clip, and the world positions follow it
    assert report["animation"]["world_max_abs"] < 1e-5


AVATAR = DATA / "avatars" / "vroid-sample.glb"
AVATAR_SCRIPT = ROOT / "scripts" / "check_avatar_blender.py"


def avatar_report(blender, glb: Path, keys) -> dict:
    out = glb.with_suffix(".avatar.json")
    run = subprocess.run([blender, str(AVATAR_SCRIPT), str(glb), "--mesh", "Face", "--keys", ",".join(keys),
                          "--json", str(out)], check=False, capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stdout + run.stderr
    return json.loads(out.read_text())


@pytest.mark.skipif(not AVATAR.is_file(), reason="../shared/data/avatars/vroid-sample.glb is not here")
def test_a_rigged_avatar_still_poses_and_each_new_key_moves_in_blender(blender, tmp_path):
    """The VRoid avatar rigged in place (``faceanim rig avatar.glb --replace``), imported by
    Blender next to the original: the same mesh objects with the same vertex counts, the face still
    deformed by the armature and moving with its head bone exactly as the original's does (same
    bone, same distances), every original shape key kept, and each new key moving the evaluated
    face by what its shape key stores (more than a millimetre)."""
    from faceanim.cli import main

    keys = ["eyeBlinkLeft", "eyeBlinkRight", "jawOpen", "mouthFunnel", "tongueOut", "browInnerUp", "AU12", "viseme_aa"]
    glb = tmp_path / "rigged.glb"
    assert main(["rig", str(AVATAR), "--replace", "-o", str(glb)]) in (0, None)
    before = avatar_report(blender, AVATAR, keys)
    after = avatar_report(blender, glb, keys)
    assert {k: v["vertices"] for k, v in after["meshes"].items()} == {k: v["vertices"] for k, v in before["meshes"].items()}
    face_before, face_after = before["meshes"][before["head_object"]], after["meshes"][after["head_object"]]
    assert face_after["armature"] and set(face_before["shape_keys"]) <= set(face_after["shape_keys"])
    assert after["pose"]["bone"] == before["pose"]["bone"] and after["pose"]["max"] > 0.02
    assert after["pose"]["max"] == pytest.approx(before["pose"]["max"], abs=1e-6)
    assert after["pose"]["median"] == pytest.approx(before["pose"]["median"], abs=1e-6)
    for name in keys:
        r = after["keys"][name]
        assert r is not None, name
        assert r["stored"] > 1e-3 and r["moved"] == pytest.approx(r["stored"], abs=1e-6), name


@pytest.mark.skipif(not AVATAR.is_file(), reason="../shared/data/avatars/vroid-sample.glb is not here")
def test_a_takes_head_turns_the_avatars_head_bone_in_blender(blender, tmp_path):
    """``arkit play --face`` the VRoid avatar with a take that nods down, turns to the avatar's left
    and tilts to its right by 0.3 rad each: Blender's importer puts the head's turn on the Head
    bone's action, and its armature, at each key, takes the eyes (the vertices the eyeBlink keys
    move) 0.3 rad about the bone's pivot downward (Blender's Z), towards the left eye's side, and
    the right eye under the left."""
    from faceanim.cli import main
    from faceanim.io.arkit_csv import write_arkit_csv
    from faceanim.standards.arkit import ARKIT_NAMES

    head = np.zeros((4, 3))
    head[1, 1], head[2, 0], head[3, 2] = 0.3, 0.3, 0.3
    write_arkit_csv(tmp_path / "take.csv", np.zeros((4, len(ARKIT_NAMES))), 30.0, head)
    glb = tmp_path / "turned.glb"
    assert main(["arkit", "play", str(tmp_path / "take.csv"), "--face", str(AVATAR), "--fps", "30", "-o", str(glb)]) in (0, None)
    out = tmp_path / "turned.json"
    run = subprocess.run([blender, str(AVATAR_SCRIPT), str(glb), "--mesh", "Face (merged)(Clone)", "--head-bone", "Head",
                          "--json", str(out)], check=False, capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stdout + run.stderr
    keys = json.loads(out.read_text())["head_keys"]
    assert len(keys) == 4
    eyes = [(np.array(k["eyeBlinkLeft"]), np.array(k["eyeBlinkRight"]), np.array(k["pivot"])) for k in keys]
    left0, right0, pivot = eyes[0]
    mid = 0.5 * (left0 + right0) - pivot
    side = left0 - right0
    side[2] = 0.0
    side /= np.linalg.norm(side)
    nod = 0.5 * (eyes[1][0] + eyes[1][1]) - pivot
    angle = np.arccos(np.clip(nod @ mid / np.linalg.norm(nod) / np.linalg.norm(mid), -1, 1))
    assert angle == pytest.approx(0.3, abs=0.01) and nod[2] < mid[2] - 0.01 and abs((nod - mid) @ side) < 1e-3
    assert (0.5 * (eyes[2][0] + eyes[2][1]) - pivot - mid) @ side > 0.01
    assert eyes[3][1][2] < eyes[3][0][2] - 0.01
