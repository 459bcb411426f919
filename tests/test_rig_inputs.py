"""`faceanim rig` with bad inputs: broken, hostile or absurd meshes, landmark files, --set,
--forward/--up, --title/--author and output paths. Each is refused with one line on stderr that
says what is wrong, exit code 2 and nothing written (the output folder stays as it was)."""

from __future__ import annotations

import copy
import json
import os
from pathlib import Path

import pytest

from faceanim.cli import main

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
FW = DATA / "facewarehouse-tester1"
needs_fw = pytest.mark.skipif(not (FW / "pose_0.obj").is_file(), reason="../shared/data/facewarehouse-tester1 is not here")


def run(args) -> int:
    try:
        return main([str(a) for a in args])
    except SystemExit as exc:
        return exc.code


def refused(capsys, args, phrase: str, folder: Path, left: list[str] | None = None) -> str:
    """Run ``faceanim rig ARGS``: exit 2, one line holding ``phrase``, no traceback, and ``folder``
    holding only ``left`` afterwards."""
    assert run(["rig", *args]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0, err
    assert "Traceback" not in err and phrase in err, err
    assert sorted(os.listdir(folder)) == sorted(left or []), os.listdir(folder)
    return err


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """The default face as .obj/.ply/.glb and its landmarks, in a folder of their own."""
    from faceanim.face.default import default_face
    from faceanim.io.gltf import write_gltf
    from faceanim.io.meshio import save_mesh

    d = tmp_path_factory.mktemp("rig_inputs")
    face = default_face()
    save_mesh(face, d / "face.obj")
    save_mesh(face, d / "face.ply")
    write_gltf(d / "face.glb", face)
    assert run(["landmarks", "-o", d / "lm.json"]) == 0
    return d


# ---------------------------------------------------------------------------------- the mesh
TRIANGLE = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"


@pytest.mark.parametrize("name, text, phrase", [
    ("empty.obj", "", "is empty"),
    ("nan.obj", "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n", "NaN or infinite coordinates"),
    ("inf.obj", "v 0 0 0\nv 1 inf 0\nv 0 1 0\nf 1 2 3\n", "NaN or infinite coordinates"),
    ("huge.obj", "v 0 0 0\nv 1e30 0 0\nv 0 1e30 0\nf 1 2 3\n", "absurd coordinate"),
    ("index.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99\n", "indexes missing vertices"),
    ("count.ply", "ply\nformat ascii 1.0\nelement vertex 999999999999\nproperty float x\nproperty float y\n"
                  "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n",
     "absurd element count"),
    ("outside.gltf", json.dumps({
        "asset": {"version": "2.0"}, "buffers": [{"uri": "/etc/passwd", "byteLength": 100}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "max": [1, 1, 1], "min": [0, 0, 0]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}], "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}], "scene": 0}), "outside its folder"),
])
def test_broken_or_hostile_meshes(tmp_path, capsys, name, text, phrase):
    src = tmp_path / "in"
    src.mkdir()
    (src / name).write_text(text)
    out = tmp_path / "out"
    out.mkdir()
    err = refused(capsys, [src / name, "-o", out / "o.glb"], phrase, out)
    assert "root:" not in err  # never a file's content


def test_binary_garbage_named_obj(tmp_path, capsys):
    (tmp_path / "garbage.obj").write_bytes(bytes(range(256)) * 80)
    refused(capsys, [tmp_path / "garbage.obj", "-o", tmp_path / "o.glb"], "binary data", tmp_path, ["garbage.obj"])


@pytest.mark.parametrize("suffix, phrase", [
    (".obj", "malformed"), (".glb", "not a valid GLB"), (".ply", "not a valid PLY")])
def test_truncated_meshes(tmp_path, capsys, files, suffix, phrase):
    data = (files / f"face{suffix}").read_bytes()
    (tmp_path / f"cut{suffix}").write_bytes(data[:len(data) // 3])
    refused(capsys, [tmp_path / f"cut{suffix}", "-o", tmp_path / "o.glb"], phrase, tmp_path, [f"cut{suffix}"])


def test_missing_folder_and_unknown_meshes(tmp_path, capsys):
    refused(capsys, [tmp_path / "nope.obj", "-o", tmp_path / "o.glb"], "does not exist", tmp_path)
    refused(capsys, [tmp_path, "-o", tmp_path / "o.glb"], "is a folder", tmp_path)
    (tmp_path / "face.stl").write_text("solid x\nendsolid x\n")
    refused(capsys, [tmp_path / "face.stl", "-o", tmp_path / "o.glb"], "unsupported format", tmp_path, ["face.stl"])
    refused(capsys, [tmp_path / "face.stl", "--face", tmp_path / "other.obj", "-o", tmp_path / "o.glb"],
            "two faces given", tmp_path, ["face.stl"])


def test_a_single_triangle_has_no_face(tmp_path, capsys):
    (tmp_path / "tri.obj").write_text(TRIANGLE)
    refused(capsys, [tmp_path / "tri.obj", "-o", tmp_path / "o.glb"], "no face found", tmp_path, ["tri.obj"])


@needs_fw
def test_a_face_looking_along_minus_z_needs_forward(tmp_path, capsys):
    """FaceWarehouse's head turned half round (not the generic head's topology, so landmarks are
    detected): looked at from +z there is no face, and the message points to --forward."""
    lines = []
    for line in (FW / "pose_0.obj").read_text().splitlines():
        if line.startswith("v "):
            _, x, y, z = line.split()[:4]
            line = f"v {-float(x)} {y} {-float(z)}"
        lines.append(line)
    (tmp_path / "back.obj").write_text("\n".join(lines) + "\n")
    err = refused(capsys, [tmp_path / "back.obj", "-o", tmp_path / "o.glb", "--set", "visemes"], "no face found",
                  tmp_path, ["back.obj"])
    assert "--forward" in err


@needs_fw
def test_forward_and_up_on_one_axis(tmp_path, capsys):
    refused(capsys, [FW / "pose_0.obj", "--forward", "+y", "--up", "+y", "-o", tmp_path / "o.glb"],
            "must be different axes", tmp_path)


def test_forward_not_an_axis(tmp_path, capsys):
    refused(capsys, ["--forward", "+q", "-o", tmp_path / "o.glb"], "is not an axis", tmp_path)


# ----------------------------------------------------------------------------- the landmarks
def _points(doc, fn):
    doc = copy.deepcopy(doc)
    fn(doc)
    return json.dumps(doc)


def _set(i, value):
    def fn(doc):
        doc["points"][i]["position"] = value
    return fn


def _all(fn_point):
    def fn(doc):
        for p in doc["points"]:
            p["position"] = fn_point(p["position"])
    return fn


LANDMARK_CASES = {
    "not json": (lambda doc: "this is {not json", "is not valid JSON"),
    "empty file": (lambda doc: "", "is not valid JSON"),
    "a list": (lambda doc: json.dumps([[0, 0, 0]] * 478), "got a list"),
    "no points": (lambda doc: _points(doc, lambda d: d.update(points=[])), "'points' is empty"),
    "NaN": (lambda doc: _points(doc, _set(5, [float("nan"), 0, 0])), "invalid position"),
    "inf": (lambda doc: _points(doc, _set(5, [0, float("inf"), 0])), "invalid position"),
    "huge": (lambda doc: _points(doc, _set(5, [1e300, 0, 0])), "invalid position"),
    "text": (lambda doc: _points(doc, _set(5, ["a", "b", "c"])), "expected 3 numbers"),
    "index repeated": (lambda doc: _points(doc, lambda d: d["points"][3].update(index=5)), "repeats point"),
    "index absurd": (lambda doc: _points(doc, lambda d: d["points"][3].update(index=10 ** 12)), "out of range"),
    "far from the mesh": (lambda doc: _points(doc, _all(lambda p: [c + 1e5 for c in p])), "from the surface"),
    "all in one place": (lambda doc: _points(doc, _all(lambda p: [0.0, 0.0, 0.1])), "coincide"),
    "too few": (lambda doc: _points(doc, lambda d: d.update(points=d["points"][:100])), "missing:"),
}


@pytest.mark.parametrize("case", list(LANDMARK_CASES))
def test_bad_landmarks(tmp_path, capsys, files, case):
    make, phrase = LANDMARK_CASES[case]
    doc = json.loads((files / "lm.json").read_text())
    src = tmp_path / "in"
    src.mkdir()
    (src / "lm.json").write_text(make(doc))
    out = tmp_path / "out"
    out.mkdir()
    err = refused(capsys, ["--landmarks", src / "lm.json", "-o", out / "o.glb", "--set", "visemes"], phrase, out)
    assert len(err) < 400


def test_missing_landmark_file(tmp_path, capsys):
    refused(capsys, ["--landmarks", tmp_path / "no.json", "-o", tmp_path / "o.glb"], "does not exist", tmp_path)


# ------------------------------------------------------------------------- --set, --title, --author
@pytest.mark.parametrize("args, message", [
    (["--set="], "--set is empty"),
    (["--set", ",,,"], "--set has an empty item"),
    (["--set", "arkit,"], "--set has an empty item"),
    (["--set", "arkit,,visemes"], "--set has an empty item"),
    (["--set", "arkit,ARKIT"], "rig set 'arkit' is given twice"),
    (["--set", "Wings,visemes"], "unknown rig set 'wings'"),
    (["--title", "x" * 10_000], "--title takes 1 to 200 printable characters"),
    (["--title", " "], "--title takes 1 to 200 printable characters"),
    (["--title", "a\x07b"], "--title takes 1 to 200 printable characters"),
    (["--author", "a\nb"], "--author takes 1 to 200 printable characters"),
    (["--author", "\x1b[31mred"], "--author takes 1 to 200 printable characters"),
])
def test_bad_sets_and_meta(tmp_path, capsys, args, message):
    err = refused(capsys, ["-o", tmp_path / "o.vrm", *args], message, tmp_path)
    assert "x" * 300 not in err and "\x1b" not in err


# ------------------------------------------------------------------------------- the output
@pytest.mark.parametrize("name, phrase", [
    ("o.obj", "must end in one of: .glb, .vrm"),
    ("o", "must end in one of: .glb, .vrm"),
    ("no/such/o.glb", "does not exist; create it first"),
])
def test_bad_output_names(tmp_path, capsys, name, phrase):
    refused(capsys, ["-o", tmp_path / name, "--set", "visemes"], phrase, tmp_path)


def test_empty_output(tmp_path, capsys):
    refused(capsys, ["-o", "", "--set", "visemes"], "must end in one of", tmp_path)


def test_output_a_folder(tmp_path, capsys):
    (tmp_path / "adir.glb").mkdir()
    refused(capsys, ["-o", tmp_path / "adir.glb", "--set", "visemes"], "is a folder", tmp_path, ["adir.glb"])
    assert os.listdir(tmp_path / "adir.glb") == []


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="needs Linux's /proc")
def test_output_where_nothing_can_be_written(tmp_path, capsys):
    refused(capsys, ["-o", "/proc/o.glb", "--set", "visemes"], "not writable", tmp_path)


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root writes into read-only folders")
def test_output_in_a_read_only_folder(tmp_path, capsys):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        refused(capsys, ["-o", ro / "o.glb", "--set", "visemes"], "not writable", ro)
    finally:
        ro.chmod(0o755)


def test_output_the_landmark_file(tmp_path, capsys):
    (tmp_path / "lm.glb").write_text("keep")
    refused(capsys, ["--landmarks", tmp_path / "lm.glb", "-o", tmp_path / "lm.glb"], "is also an input",
            tmp_path, ["lm.glb"])
    assert (tmp_path / "lm.glb").read_text() == "keep"


def test_output_a_link_to_the_input(tmp_path, capsys, files):
    (tmp_path / "in.glb").write_bytes((files / "face.glb").read_bytes())
    (tmp_path / "link.glb").symlink_to(tmp_path / "in.glb")
    refused(capsys, [tmp_path / "in.glb", "-o", tmp_path / "link.glb"], "is also an input",
            tmp_path, ["in.glb", "link.glb"])
    assert (tmp_path / "in.glb").read_bytes() == (files / "face.glb").read_bytes()
