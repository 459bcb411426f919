"""The faceanim command: outputs match the library, bad input exits non-zero with no output."""

import json
import subprocess
import sys

import numpy as np
import pytest

from faceanim.cli import main
from faceanim.deform import bind_rbf
from faceanim.io.meshio import load_mesh, save_mesh


@pytest.fixture
def mesh_file(tmp_path, base_face):
    path = tmp_path / "face.obj"
    save_mesh(base_face, path)
    return path


def _write(tmp_path, name, data):
    p = tmp_path / name
    p.write_text(json.dumps(data) if not isinstance(data, str) else data)
    return p


def test_deform_rbf_matches_the_library(tmp_path, mesh_file, base_face):
    handles = base_face.vertices[[1, 61, 291, 152, 10, 234, 454]]
    offsets = np.zeros_like(handles)
    offsets[3] = [0, -0.01, 0]
    spec = _write(tmp_path, "h.json", {"method": "rbf", "kernel": "thin_plate_spline", "smoothing": 0.0,
                                       "handles": handles.tolist(), "offsets": offsets.tolist()})
    assert main(["deform", str(mesh_file), "--handles", str(spec), "-o", str(tmp_path / "out.obj")]) == 0
    out = load_mesh(tmp_path / "out.obj")
    expected = bind_rbf(base_face.vertices, handles, "thin_plate_spline", 0.0).apply(offsets)
    np.testing.assert_allclose(out.vertices, expected, atol=1e-8)
    assert out.n_vertices == base_face.n_vertices and out.texture is not None


def test_deform_gde_to_glb(tmp_path, mesh_file, base_face):
    spec = _write(tmp_path, "g.json", {"method": "gde", "elements": [
        {"control": base_face.vertices[152].tolist(), "offset": [0, -0.01, 0], "metric": "edges", "extent": 3}]})
    assert main(["deform", str(mesh_file), "--handles", str(spec), "-o", str(tmp_path / "out.glb")]) == 0
    out = load_mesh(tmp_path / "out.glb")
    assert out.vertices[152, 1] < base_face.vertices[152, 1] - 0.005


BAD = {
    "missing mesh": (None, {"method": "rbf"}, "does not exist"),
    "unknown kernel": ("ok", {"method": "rbf", "kernel": "cubic", "handles": [[0, 0, 0], [0.01, 0, 0]],
                              "offsets": [[0, 0, 0], [0, 0, 0]]}, "unknown kernel 'cubic'"),
    "coincident": ("ok", {"method": "rbf", "handles": [[0, 0, 0], [0.01, 0, 0], [0, 0, 0]],
                          "offsets": [[0, 0, 0]] * 3}, "handles 0 and 2 coincide"),
    "nan offsets": ("ok", {"method": "rbf", "handles": [[0, 0, 0], [0.01, 0, 0]],
                           "offsets": [[0, 0, 0], [float("nan"), 0, 0]]}, "NaN"),
    "too few for tps": ("ok", {"method": "rbf", "kernel": "thin_plate_spline", "handles": [[0, 0, 0], [0.01, 0, 0]],
                               "offsets": [[0, 0, 0], [0, 0, 0]]}, "at least 4 handles"),
    "far control": ("ok", {"method": "gde", "elements": [{"control": [0, 0, 5], "offset": [0, 0, 0]}]},
                    "from the surface"),
    "malformed json": ("ok", "{not json", "not valid JSON"),
    "nan mesh": ("nan", {"method": "rbf"}, "NaN or infinite"),
    "empty mesh": ("empty", {"method": "rbf"}, "empty"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_exits_nonzero_without_output(tmp_path, mesh_file, capsys, case):
    mesh_kind, spec, message = BAD[case]
    mesh = {None: tmp_path / "nope.obj", "ok": mesh_file}.get(mesh_kind)
    if mesh_kind == "nan":
        mesh = _write(tmp_path, "nan.obj", "v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n")
    if mesh_kind == "empty":
        mesh = _write(tmp_path, "empty.obj", "")
    h = _write(tmp_path, "h.json", spec)
    out = tmp_path / "result.obj"
    code = main(["deform", str(mesh), "--handles", str(h), "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 2
    assert message in err and err.count("\n") == 1
    assert not out.exists() and not list(tmp_path.glob(".result*"))


def test_landmarks_command_and_no_face(tmp_path, mesh_file):
    out = tmp_path / "lm.json"
    assert main(["landmarks", str(mesh_file), "-o", str(out), "--scheme", "basic22"]) == 0
    data = json.loads(out.read_text())
    assert data["scheme"] == "basic22" and len(data["points"]) == 22
    p = {q["name"]: q for q in data["points"]}["mouth_corner_right"]
    assert p["index"] == 61 and len(p["barycentric"]) == 3
    # a face looking down -x is not found when we claim it looks along +z
    box = _write(tmp_path, "box.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    assert main(["landmarks", str(box), "-o", str(tmp_path / "none.json")]) == 2
    assert not (tmp_path / "none.json").exists()


def test_console_script_runs():
    r = subprocess.run([sys.executable, "-m", "faceanim", "--help"], capture_output=True, text=True)
    assert r.returncode == 0 and "demo" in r.stdout


def test_deform_gde_from_a_2d_pick(tmp_path, mesh_file, base_face):
    from faceanim.face.landmarks import detection_view

    with detection_view(base_face) as view:
        xy = view.project(base_face.vertices[[152]])[0]
    spec = _write(tmp_path, "p.json", {"method": "gde", "elements": [
        {"pick": xy.tolist(), "offset": [0, -0.01, 0], "metric": "edges", "extent": 2, "smoothing": 0}]})
    assert main(["deform", str(mesh_file), "--handles", str(spec), "-o", str(tmp_path / "out.obj")]) == 0
    out = load_mesh(tmp_path / "out.obj")
    moved = np.linalg.norm(out.vertices - base_face.vertices, axis=1)
    assert moved.argmax() == 152 or moved[152] > 0.5 * moved.max()


def test_landmarks_from_a_file_override_detection(tmp_path, mesh_file, base_face):
    given = {"scheme": "custom", "points": [
        {"name": "nose_tip", "index": 4, "position": (base_face.vertices[4] + [0, 0, 0.002]).tolist()},
        {"name": "chin", "position": base_face.vertices[152].tolist()}]}
    src = _write(tmp_path, "given.json", given)
    out = tmp_path / "lm.json"
    assert main(["landmarks", str(mesh_file), "--from", str(src), "-o", str(out)]) == 0
    pts = {p["name"]: p for p in json.loads(out.read_text())["points"]}
    # snapped onto the surface: the nose point moves back onto the skin, the chin stays
    assert np.linalg.norm(np.array(pts["nose_tip"]["position"]) - base_face.vertices[4]) < 0.002
    np.testing.assert_allclose(pts["chin"]["position"], base_face.vertices[152], atol=1e-9)
    tri = base_face.faces[pts["chin"]["triangle"]]
    assert 152 in tri
    far = _write(tmp_path, "far.json", {"points": [{"name": "x", "position": [0, 0, 3]}]})
    assert main(["landmarks", str(mesh_file), "--from", str(far), "-o", str(tmp_path / "f.json")]) == 2
    assert not (tmp_path / "f.json").exists()


def test_help_and_version_load_no_command_and_no_numpy():
    """`faceanim --help` lists every command from the table alone; a command's module (and numpy,
    scipy, MediaPipe...) is loaded only when that command runs or its help is asked for."""
    import subprocess
    import sys

    code = ("import sys\nfrom faceanim.cli import main\n"
            "try:\n    main(sys.argv[1:])\nexcept SystemExit:\n    pass\n"
            "mods = sorted(m for m in sys.modules if m.startswith(('faceanim.cli.', 'numpy')))\n"
            "print(' '.join(mods), file=sys.stderr)\n")
    for argv, loaded in ((["--help"], "faceanim.cli.commands"), (["--version"], "faceanim.cli.commands"),
                         (["say", "--help"], "faceanim.cli.commands faceanim.cli.common faceanim.cli.mpeg4")):
        out = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, check=True)
        assert out.stderr.strip().splitlines()[-1] == loaded, argv
        if argv == ["--help"]:
            from faceanim.cli.commands import COMMANDS

            assert all(name in out.stdout for name in COMMANDS)
