"""Bad input of every kind: a clean FaceAnimError (one line), no output file, no temp file, and
never a file the user did not name overwritten."""

import json
import os
import re
import signal
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from faceanim.errors import (
    DeformError,
    FaceAnimError,
    InputFileError,
    LandmarkError,
    MeshError,
)
from faceanim.io.files import (
    OutputError,
    atomic_output,
    check_output_path,
    remove_stale_temps,
)
from faceanim.io.meshio import load_mesh, save_mesh

SRC = str(Path(__file__).resolve().parents[1] / "src")


def listing(folder) -> list[str]:
    return sorted(os.listdir(folder))


def one_line(exc) -> str:
    msg = str(exc.value)
    assert "\n" not in msg and "Traceback" not in msg
    return msg


# ====================================================================== check_output_path
def test_missing_folder_is_refused_not_created(tmp_path):
    with pytest.raises(OutputError, match=r"folder '.*nope/deeper' does not exist; create it first") as exc:
        check_output_path(tmp_path / "nope" / "deeper" / "out.obj")
    one_line(exc)
    with pytest.raises(OutputError, match="does not exist; create it first"):
        check_output_path(tmp_path / "nope" / "out.obj")
    assert listing(tmp_path) == []


def test_parent_that_is_a_file_or_path_that_is_a_folder(tmp_path):
    (tmp_path / "file.txt").write_text("keep")
    with pytest.raises(OutputError, match="is not a folder"):
        check_output_path(tmp_path / "file.txt" / "out.obj")
    (tmp_path / "dir.obj").mkdir()
    with pytest.raises(OutputError, match="is a folder; give a file name"):
        check_output_path(tmp_path / "dir.obj")
    with pytest.raises(OutputError, match="no output path"):
        check_output_path("")
    assert listing(tmp_path) == ["dir.obj", "file.txt"] and listing(tmp_path / "dir.obj") == []
    assert (tmp_path / "file.txt").read_text() == "keep"


def test_special_file_is_not_replaced(tmp_path):
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    with pytest.raises(OutputError, match="not a regular file"):
        check_output_path(fifo)
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


def test_unwritable_folder_is_refused(tmp_path):
    if os.geteuid() == 0:
        # root writes through permission bits; /sys refuses new files even to root
        folder = Path("/sys/kernel")
        if not folder.is_dir():
            pytest.skip("no /sys/kernel to test a folder that refuses root")
    else:
        folder = tmp_path / "ro"
        folder.mkdir()
        folder.chmod(0o555)
    before = listing(folder)
    with pytest.raises(OutputError, match="is not writable") as exc:
        check_output_path(folder / "out.json")
    one_line(exc)
    assert listing(folder) == before


def test_read_only_existing_file_is_kept(tmp_path):
    if os.geteuid() == 0:
        pytest.skip("root may replace read-only files")
    p = tmp_path / "keep.json"
    p.write_text("mine")
    p.chmod(0o444)
    with pytest.raises(OutputError, match="read-only"):
        check_output_path(p)
    assert p.read_text() == "mine"


def test_a_good_path_passes_and_leaves_nothing(tmp_path):
    (tmp_path / "old.obj").write_text("old")
    assert check_output_path(tmp_path / "new.obj") == tmp_path / "new.obj"
    assert check_output_path(tmp_path / "old.obj") == tmp_path / "old.obj"
    assert listing(tmp_path) == ["old.obj"] and (tmp_path / "old.obj").read_text() == "old"


# ====================================================================== atomic_output
TEMP = re.compile(r"^\.out\.faceanim-(\d+)-[A-Za-z0-9_]+\.json$")


def test_temp_name_carries_our_pid_and_success_renames(tmp_path):
    out = tmp_path / "out.json"
    with atomic_output(out) as tmp:
        m = TEMP.match(tmp.name)
        assert m and int(m.group(1)) == os.getpid() and tmp.parent == tmp_path
        tmp.write_text("new")
    assert listing(tmp_path) == ["out.json"] and out.read_text() == "new"
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(out.stat().st_mode) == 0o666 & ~umask


@pytest.mark.parametrize("error", [RuntimeError("boom"), KeyboardInterrupt(), MeshError("bad mesh")])
def test_failure_leaves_the_old_output_and_no_temp(tmp_path, error):
    out = tmp_path / "out.json"
    out.write_bytes(b"old contents")
    with pytest.raises(type(error)), atomic_output(out) as tmp:
        tmp.write_text("partial")
        raise error
    assert listing(tmp_path) == ["out.json"] and out.read_bytes() == b"old contents"


def test_oserror_while_writing_becomes_one_line_output_error(tmp_path):
    out = tmp_path / "out.json"
    with pytest.raises(OutputError) as exc, atomic_output(out) as tmp:
        tmp.write_text("partial")
        raise OSError(28, "No space left on device")
    assert one_line(exc) == f"cannot write output '{out}': No space left on device"
    assert listing(tmp_path) == []


def test_rename_failure_becomes_output_error_and_removes_the_temp(tmp_path, monkeypatch):
    out = tmp_path / "out.json"

    def fail(src, dst):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OutputError, match="Permission denied"), atomic_output(out) as tmp:
        tmp.write_text("done")
    assert listing(tmp_path) == []


def test_signal_handlers_only_while_writing(tmp_path):
    before = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGHUP)}
    with atomic_output(tmp_path / "out.json") as tmp:
        tmp.write_text("x")
        during = signal.getsignal(signal.SIGTERM)
    assert during is not before[signal.SIGTERM]
    assert {s: signal.getsignal(s) for s in before} == before


WRITER = textwrap.dedent("""
    import sys, time
    from faceanim.io.files import atomic_output
    with atomic_output(sys.argv[1]) as tmp:
        with open(tmp, "w") as fh:
            fh.write("partial" * 1000)
            fh.flush()
            print(tmp.name, flush=True)
            time.sleep(60)
""")


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_kill_during_a_write_leaves_no_temp_file(tmp_path, sig):
    out = tmp_path / "out.json"
    env = {**os.environ, "PYTHONPATH": SRC}
    # the signal at its default in the writer, however the tests were started (under nohup,
    # SIGHUP comes ignored, and a write rightly leaves an ignored signal ignored)
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env,
                            preexec_fn=lambda: signal.signal(sig, signal.SIG_DFL))
    try:
        tmp_name = proc.stdout.readline().strip()
        assert TEMP.match(tmp_name) and listing(tmp_path) == [tmp_name]
        proc.send_signal(sig)
        code = proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert code == 128 + sig
    assert "Traceback" not in proc.stderr.read()
    assert listing(tmp_path) == []


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_stale_temps_of_dead_processes_are_removed_live_ones_kept(tmp_path):
    dead = _dead_pid()
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        stale = f".out.faceanim-{dead}-abcd1234.json"
        other_stale = f".face.faceanim-{dead}-zz9_y8x7.obj"
        alive = f".out.faceanim-{live.pid}-efgh5678.json"
        keep = [".out-abcd1234.json", ".hidden.json", "faceanim-1-abcd.json", "notes.txt"]
        for name in [stale, other_stale, alive, *keep]:
            (tmp_path / name).write_text(name)
        with atomic_output(tmp_path / "out.json") as tmp:
            tmp.write_text("new")
        assert listing(tmp_path) == sorted([alive, *keep, "out.json"])
        for name in [alive, *keep]:
            assert (tmp_path / name).read_text() == name
        assert remove_stale_temps(tmp_path) == []
    finally:
        live.kill()
        live.wait()
    # once its process is gone, the live one is stale too
    assert remove_stale_temps(tmp_path) == [tmp_path / alive]


# ====================================================================== data loss: OBJ companions
def test_writing_face_obj_keeps_the_users_face_png_and_mtl(tmp_path, base_face):
    user_png = b"\x89PNG not really, but the user's bytes"
    user_mtl = b"newmtl mine\nmap_Kd face.png\n"
    (tmp_path / "face.png").write_bytes(user_png)
    (tmp_path / "face.mtl").write_bytes(user_mtl)
    written = save_mesh(base_face, tmp_path / "face.obj")
    assert written == [tmp_path / "face.obj", tmp_path / "face-1.mtl", tmp_path / "face.texture.png"]
    assert (tmp_path / "face.png").read_bytes() == user_png
    assert (tmp_path / "face.mtl").read_bytes() == user_mtl
    assert listing(tmp_path) == ["face-1.mtl", "face.mtl", "face.obj", "face.png", "face.texture.png"]
    back = load_mesh(tmp_path / "face.obj")
    assert np.array_equal(back.texture, base_face.texture)


def test_rewriting_reuses_its_own_companions_only(tmp_path, base_face):
    first = save_mesh(base_face, tmp_path / "face.obj")
    second = save_mesh(base_face, tmp_path / "face.obj", base_face.vertices + 0.001)
    assert first == second == [tmp_path / "face.obj", tmp_path / "face.mtl", tmp_path / "face.texture.png"]
    assert listing(tmp_path) == ["face.mtl", "face.obj", "face.texture.png"]
    # a material edited by hand to name the user's own image: that image is never written
    (tmp_path / "skin.png").write_bytes(b"user skin")
    mtl = (tmp_path / "face.mtl").read_text().replace("map_Kd face.texture.png", "map_Kd skin.png")
    (tmp_path / "face.mtl").write_text(mtl)
    third = save_mesh(base_face, tmp_path / "face.obj")
    assert (tmp_path / "skin.png").read_bytes() == b"user skin"
    assert third[0] == tmp_path / "face.obj" and tmp_path / "skin.png" not in third


def test_companions_avoid_other_named_paths(tmp_path, base_face):
    avoid = [tmp_path / "out.texture.png", tmp_path / "out.mtl"]
    written = save_mesh(base_face, tmp_path / "out.obj", avoid=avoid)
    assert written == [tmp_path / "out.obj", tmp_path / "out-1.mtl", tmp_path / "out.texture-1.png"]
    assert listing(tmp_path) == ["out-1.mtl", "out.obj", "out.texture-1.png"]


def test_failed_mesh_write_leaves_no_companions(tmp_path, base_face):
    bad = base_face.vertices.copy()
    bad[3] = np.nan
    with pytest.raises(MeshError, match="NaN"):
        save_mesh(base_face, tmp_path / "out.obj", bad)
    with pytest.raises(OutputError, match="does not exist"):
        save_mesh(base_face, tmp_path / "missing" / "out.obj")
    assert listing(tmp_path) == []


@pytest.mark.parametrize("image", ["out.png", "out.texture.png"])
def test_deform_image_never_overwrites_the_texture(tmp_path, base_face, image):
    from faceanim.cli import main

    mesh = tmp_path / "in.obj"
    save_mesh(base_face, mesh)
    inputs = listing(tmp_path)
    before = {n: (tmp_path / n).read_bytes() for n in inputs}
    handles = base_face.vertices[[1, 61, 291, 152, 10]]
    offsets = np.zeros_like(handles)
    offsets[3] = [0, -0.01, 0]
    spec = tmp_path / "h.json"
    spec.write_text(json.dumps({"handles": handles.tolist(), "offsets": offsets.tolist()}))
    out, png = tmp_path / "out.obj", tmp_path / image
    assert main(["deform", str(mesh), "--handles", str(spec), "-o", str(out), "--image", str(png)]) == 0
    back = load_mesh(out)
    assert np.array_equal(back.texture, base_face.texture)  # the .mtl still names the texture, not the render
    from PIL import Image

    with Image.open(png) as im:
        assert im.size != base_face.texture.shape[1::-1] or not np.array_equal(np.asarray(im), base_face.texture)
    for n, data in before.items():
        assert (tmp_path / n).read_bytes() == data
    new = sorted(set(listing(tmp_path)) - set(inputs) - {"h.json"})
    expected_tex = "out.texture-1.png" if image == "out.texture.png" else "out.texture.png"
    assert new == sorted({"out.obj", "out.mtl", expected_tex, image})


def test_cli_refuses_a_missing_output_folder_before_work(tmp_path, base_face, capsys):
    from faceanim.cli import main

    mesh = tmp_path / "in.obj"
    save_mesh(base_face, mesh)
    spec = tmp_path / "h.json"
    spec.write_text(json.dumps({"handles": base_face.vertices[:3].tolist(), "offsets": [[0, 0, 0]] * 3}))
    before = listing(tmp_path)
    assert main(["deform", str(mesh), "--handles", str(spec), "-o", str(tmp_path / "no" / "out.obj")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "does not exist; create it first" in err
    assert listing(tmp_path) == before


# ====================================================================== .fap files
MASK1 = "0 0 1 " + "0 " * 65


@pytest.mark.parametrize("text, message", [
    ("2.1 x 25 1000000000000\n", "bad.fap:1: the header promises 1e+12 frames, more than faceanim's limit of 200000"),
    ("2.1 x 0 1\n", "bad.fap:1: the frame rate must be positive, got '0'"),
    ("2.1 x -3 1\n", "bad.fap:1: the frame rate must be positive, got '-3'"),
    ("2.1 x nan 1\n", "bad.fap:1: the frame rate 'nan' is not a finite number"),
    ("2.1 x 1e9 1\n", "bad.fap:1: the frame rate 1e+09 is above faceanim's limit of 240 fps"),
    ("2.1 x 25 0\n", "bad.fap:1: the file has no frames"),
    ("# c\n2.1 x 25 1\n" + MASK1 + "\n0 1e400\n", "bad.fap:4: value '1e400' is not a finite number"),
    ("2.1 x 25 1\n" + MASK1 + "\n0 1e308\n", "bad.fap:3: value '1e308' is beyond +-1e+07 FAPU units"),
    ("2.1 x 25 1\n" + MASK1 + "\n1e300 5\n", "bad.fap:3: the frame number '1e300' must be a whole number"),
    ("2.1 x 25 1\n" + MASK1 + "\n0 5\x00\n", "bad.fap:3: NUL byte"),
    ("2.1 x 25 1\n" + MASK1 + "\n0 " + "9" * 5000 + "\n", "bad.fap:3: value is not a finite"),
])
def test_bad_fap_text(text, message):
    from faceanim.io.fapfile import parse_fap

    with pytest.raises(InputFileError) as exc:
        parse_fap(text, "bad.fap")
    assert one_line(exc).startswith(message)


def test_bad_fap_bytes(tmp_path):
    from faceanim.io.fapfile import read_fap

    p = tmp_path / "x.fap"
    p.write_bytes(b"2.1 x 25 1\n" + MASK1.encode() + b"\n0 \xff\xfe\n")
    with pytest.raises(InputFileError) as exc:
        read_fap(p)
    assert one_line(exc) == f"{p}:3: not UTF-8 text; save the .fap file as UTF-8 (or ASCII)"
    p.write_bytes(b"2.1 x 25 1\n\x00\x01\x02")
    with pytest.raises(InputFileError, match=r":2: NUL byte"):
        read_fap(p)
    with pytest.raises(InputFileError, match="is a folder"):
        read_fap(tmp_path)


# ====================================================================== handle files
@pytest.fixture(scope="module")
def small_face():
    from faceanim.face.default import default_face

    return default_face()


def _rbf(face, **extra):
    h = face.vertices[[1, 61, 291, 152, 10]].tolist()
    return {"method": "rbf", "handles": h, "offsets": [[0, 0, 0]] * 5, **extra}


def _gde(face, **extra):
    return {"method": "gde", "elements": [{"control": face.vertices[152].tolist(), "offset": [0, -0.01, 0],
                                           **extra}]}


HANDLE_CASES = {
    "not an object": (lambda f: [1, 2], InputFileError, "must hold a JSON object"),
    "unknown method": (lambda f: {"method": "tps"}, DeformError, "unknown method 'tps'"),
    "method not text": (lambda f: {"method": 3}, DeformError, "unknown method a number"),
    "unknown keys": (lambda f: _rbf(f, colour=1, size=2), DeformError, "unknown key(s) 'colour', 'size'"),
    "unknown kernel": (lambda f: _rbf(f, kernel="cubic"), DeformError, "unknown kernel 'cubic'"),
    "smoothing text": (lambda f: _rbf(f, smoothing="0.1"), DeformError, "smoothing must be a number, got text"),
    "smoothing nan": (lambda f: _rbf(f, smoothing=float("nan")), DeformError, "smoothing must be a finite"),
    "smoothing negative": (lambda f: _rbf(f, smoothing=-1), DeformError, "smoothing must be at least 0"),
    "stiffness zero": (lambda f: _rbf(f, stiffness=0), DeformError, "stiffness must be more than 0"),
    "degree bool": (lambda f: _rbf(f, degree=True), DeformError, "degree must be a number, got true/false"),
    "handles text": (lambda f: {**_rbf(f), "handles": [["0", "0", "0"]] * 5}, DeformError, "numbers only, got text"),
    "handles too deep": (lambda f: {**_rbf(f), "handles": [[[0, 0, 0]]] * 5}, DeformError, "nested too deeply"),
    "handles ragged": (lambda f: {**_rbf(f), "handles": [[0, 0], [0, 0, 0]]}, DeformError, "lists of 3 numbers"),
    "huge handle": (lambda f: {**_rbf(f), "handles": [[1e300, 0, 0]] + _rbf(f)["handles"][1:]}, DeformError,
                    "handle 0 is absurdly far"),
    "huge offset": (lambda f: {**_rbf(f), "offsets": [[0, 1e300, 0]] + [[0, 0, 0]] * 4}, DeformError,
                    "offset 0 is absurdly far"),
    "count mismatch": (lambda f: {**_rbf(f), "offsets": [[0, 0, 0]]}, InputFileError, "5 handles but 1 offsets"),
    "missing offsets": (lambda f: {"method": "rbf", "handles": [[0, 0, 0]]}, InputFileError, "needs 'offsets'"),
    "null handles": (lambda f: {**_rbf(f), "handles": None}, DeformError, "'handles' must be a list"),
    "max_anchors 0": (lambda f: _gde(f, max_anchors=0), DeformError, "max_anchors must be at least 1"),
    "max_anchors huge": (lambda f: _gde(f, max_anchors=10**12), DeformError, "at most 1000"),
    "max_anchors negative": (lambda f: _gde(f, max_anchors=-3), DeformError, "max_anchors must be at least 1"),
    "extent negative": (lambda f: _gde(f, extent=-1), DeformError, "extent (edges) must be at least 0"),
    "extent text": (lambda f: _gde(f, extent="4"), DeformError, "extent (edges) must be a number, got text"),
    "extent absurd": (lambda f: _gde(f, extent=1e300, metric="euclidean"), DeformError, "extent 1e+300 is absurd"),
    "metric unknown": (lambda f: _gde(f, metric="geodesic"), DeformError, "unknown metric 'geodesic'"),
    "element kernel": (lambda f: _gde(f, kernel=["x"]), DeformError, "unknown kernel a list"),
    "element unknown key": (lambda f: _gde(f, radius=3), DeformError, "element 0 has unknown key(s) 'radius'"),
    "element smoothing nan": (lambda f: _gde(f, smoothing=float("nan")), DeformError, "smoothing must be a finite"),
    "control and pick": (lambda f: _gde(f, pick=[0.5, 0.5]), DeformError, "both 'control' and 'pick'"),
    "pick outside": (lambda f: {"method": "gde", "elements": [{"pick": [1.5, 0.5], "offset": [0, 0, 0]}]},
                     LandmarkError, "element 0: GDE pick [1.5, 0.5] is outside the image"),
    "pick misses": (lambda f: {"method": "gde", "elements": [{"pick": [0.01, 0.01], "offset": [0, 0, 0]}]},
                    LandmarkError, "element 0: GDE pick [0.01, 0.01] does not hit the face"),
    "pick text": (lambda f: {"method": "gde", "elements": [{"pick": ["a", 0], "offset": [0, 0, 0]}]},
                  DeformError, "pick coordinate must be a number, got text"),
    "element not object": (lambda f: {"method": "gde", "elements": [7]}, DeformError, "got a number"),
    "no elements": (lambda f: {"method": "gde", "elements": []}, InputFileError, "non-empty 'elements'"),
    "far control": (lambda f: {"method": "gde", "elements": [{"control": [0, 0, 5], "offset": [0, 0, 0]}]},
                    DeformError, "from the surface"),
}


@pytest.mark.parametrize("case", list(HANDLE_CASES))
def test_bad_handle_files(tmp_path, small_face, case):
    from faceanim.deform.handles import load_handles

    make, kind, message = HANDLE_CASES[case]
    path = tmp_path / "h.json"
    path.write_text(json.dumps(make(small_face)))
    with pytest.raises(kind) as exc:
        load_handles(path, small_face)
    msg = one_line(exc)
    assert msg.startswith(f"handle file '{path}': ") and message in msg, msg


def test_handle_file_matches_the_library(small_face):
    from faceanim.deform import bind_gdes, bind_rbf
    from faceanim.deform.gde import GeometryDeformationElement
    from faceanim.deform.handles import load_handles

    spec = _rbf(small_face, kernel="thin_plate_spline", smoothing=0.0)
    spec["offsets"][3] = [0, -0.01, 0]
    deformer, offsets = load_handles(spec, small_face)
    expected = bind_rbf(small_face.vertices, spec["handles"], "thin_plate_spline", 0.0).apply(np.array(spec["offsets"]))
    np.testing.assert_array_equal(deformer.apply(offsets), expected)
    spec = _gde(small_face, extent=3, comment="chin down")
    deformer, offsets = load_handles(spec, small_face)
    gde = GeometryDeformationElement(tuple(small_face.vertices[152]), 3, name="gde0")
    np.testing.assert_array_equal(deformer.apply(offsets), bind_gdes(small_face, [gde]).apply(np.array([[0, -0.01, 0]])))


# ====================================================================== landmark files
LANDMARK_CASES = {
    "not an object": ([1], "expected {'scheme'"),
    "no points": ({"points": []}, "'points' is empty"),
    "index float": ({"points": [{"position": [0, 0, 0], "index": 1.5}]}, "point 0: 'index' must be a whole number"),
    "index text": ({"points": [{"position": [0, 0, 0], "index": "4"}]}, "'index' must be a whole number, got text"),
    "index null": ({"points": [{"position": [0, 0, 0], "index": None}]}, "point 0: 'index' is null"),
    "index outside": ({"points": [{"position": [0, 0, 0], "index": 478}]}, "'index' 478 is out of range (0..477)"),
    "not in scheme": ({"scheme": "basic22", "points": [{"position": [0, 0, 0], "index": 5}]},
                      "index 5 is not a landmark of scheme 'basic22'"),
    "duplicate index": ({"points": [{"position": [0, 0, 0], "index": 3}, {"position": [1, 0, 0], "index": 3}]},
                        "point 1: index 3 repeats point 0"),
    "duplicate name": ({"points": [{"position": [0, 0, 0], "name": "a"}, {"position": [1, 0, 0], "name": "a"}]},
                       "point 1: name 'a' repeats point 0"),
    "position text": ({"points": [{"position": [0, "a", 0]}]}, "invalid position: expected 3 numbers, got a list holding text"),
    "position nested": ({"points": [{"position": [[0, 0, 0]]}]}, "invalid position: expected 3 numbers, got 1 value(s)"),
    "position nan": ({"points": [{"position": [0, 0, float("nan")]}]}, "invalid position: NaN, infinite"),
    "position inf": ({"points": [{"position": [0, 0, 1e400]}]}, "invalid position: NaN, infinite"),
    "position bool": ({"points": [{"position": [True, 0, 0]}]}, "got a list holding true/false"),
    "scheme null": ({"scheme": None, "points": [{"position": [0, 0, 0]}]}, "'scheme' must be a name (text), got null"),
    "triangle without bary": ({"points": [{"position": [0, 0, 0], "triangle": 4}]}, "no 'barycentric'"),
    "triangle below -1": ({"points": [{"position": [0, 0, 0], "triangle": -2}]}, "'triangle' -2 is out of range"),
}


@pytest.mark.parametrize("case", list(LANDMARK_CASES))
def test_bad_landmark_files(tmp_path, case):
    from faceanim.face.landmarks import Landmarks

    data, message = LANDMARK_CASES[case]
    path = tmp_path / "lm.json"
    path.write_text(json.dumps(data))
    with pytest.raises(LandmarkError) as exc:
        Landmarks.load(path)
    assert message in one_line(exc)


def test_landmark_json_that_is_not_json(tmp_path):
    from faceanim.face.landmarks import Landmarks

    for name, data in {"deep.json": b"[" * 100000, "bytes.json": b"\xff\xfe{}", "digits.json": b"1" * 5000}.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(InputFileError) as exc:
            Landmarks.load(tmp_path / name)
        one_line(exc)


def test_landmark_triangles_of_another_mesh(small_face):
    from faceanim.face.landmarks import Landmarks

    lm = Landmarks.from_dict({"points": [{"position": [0, 0, 0], "triangle": 10**9, "barycentric": [1, 0, 0]}]})
    with pytest.raises(LandmarkError, match="not a triangle of this mesh"):
        lm.on(small_face)


def test_pick_outside_the_image_is_refused_before_rendering(small_face):
    from faceanim.face.landmarks import pick_surface_points

    with pytest.raises(LandmarkError, match=r"pick \[-0.1, 0.5\] is outside the image"):
        pick_surface_points(small_face, [[-0.1, 0.5]])


def test_all_errors_are_faceanim_errors():
    assert issubclass(OutputError, FaceAnimError)


@pytest.mark.parametrize("z", [5.0, 134217729.0, 1e11])
def test_points_far_from_the_mesh_are_refused_before_the_closest_point_search(small_face, z):
    """trimesh's closest-point query fails (IndexError) on points ~1e8 away: refused before it."""
    from faceanim.deform.gde import GeometryDeformationElement, element_influence
    from faceanim.face.landmarks import Landmarks

    lm = Landmarks.from_dict({"points": [{"index": 152, "position": [0, -1, z]}]})
    with pytest.raises(LandmarkError, match="from the surface of"):
        lm.attached_to(small_face)
    with pytest.raises(DeformError, match="from the surface"):
        element_influence(small_face, GeometryDeformationElement((0.0, -1.0, z)))
