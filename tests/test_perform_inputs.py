"""Bad input to ``faceanim perform``, ``faceanim mocap build`` and ``faceanim track``: every case
gives exactly one line on stderr that names the fault, exit code 2, and leaves no file behind
(nothing new, changed or removed in the inputs' folder, the output folder or the working
folder). Also: the smallest settings (--window 1 --overlap 1, --k 1, a one-frame video) run.

Inputs are made here: blank videos with faceanim's own writer, takes with its Live Link Face
writer, databases as damaged copies of the shipped one (or of one built from the real ARKit take
in ../shared/data, for the cases that need real data)."""

from __future__ import annotations

import json
import os
import sys
import wave
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from faceanim.cli import main

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
VIDEOS = DATA / "talking-head-videos"
TAKE = DATA / "arkit-curves" / "alex_rom_3.csv"
needs_data = pytest.mark.skipif(not (VIDEOS.is_dir() and TAKE.is_file()),
                                reason="../shared/data (talking-head-videos, arkit-curves) is not here")


def run(args) -> int:
    try:
        return main([str(a) for a in args])
    except SystemExit as exc:
        return exc.code


def snapshot(*folders) -> dict:
    """Every entry under ``folders``: (kind, size, mtime) by path (a file replaced or touched shows)."""
    seen = {}
    for folder in folders:
        for dirpath, dirnames, filenames in os.walk(folder):
            for name in dirnames + filenames:
                p = os.path.join(dirpath, name)
                st = os.lstat(p)
                seen[p] = (st.st_mode, st.st_size, st.st_mtime_ns)
    return seen


def refused(args, phrase: str, capsys, *folders) -> str:
    """Run ``args``; assert exit 2, one stderr line holding ``phrase``, no traceback, no file made,
    changed or removed in ``folders``. Returns the line."""
    capsys.readouterr()
    before = snapshot(*folders)
    code = run(args)
    err = capsys.readouterr().err
    assert code == 2, (args, code, err)
    assert err.count("\n") == 1 and err.endswith("\n"), (args, err)
    assert phrase in err, (args, phrase, err)
    assert "internal error" not in err and "Traceback" not in err, (args, err)
    assert "\x1b" not in err, (args, err)
    assert snapshot(*folders) == before, args
    return err


# ------------------------------------------------------------------------------------ the inputs
def _wav(path: Path) -> None:
    with wave.open(str(path), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(16000)
        w.writeframes((np.sin(np.arange(16000) * 0.05) * 8000).astype("<i2").tobytes())


def _obj(path: Path, vertices, faces) -> None:
    with open(path, "w") as fh:
        fh.writelines("v {!r} {!r} {!r}\n".format(*(float(c) for c in v)) for v in vertices)
        fh.writelines("f {} {} {}\n".format(*(i + 1 for i in f)) for f in faces)


def _plane(n: int = 12):
    xs, ys = np.meshgrid(np.linspace(-0.1, 0.1, n), np.linspace(-0.1, 0.1, n))
    v = np.c_[xs.ravel(), ys.ravel(), np.zeros(n * n)]
    f = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            f += [(a, a + 1, a + n), (a + 1, a + n + 1, a + n)]
    return v, f


def _take_lines(path: Path) -> list[str]:
    return path.read_text(encoding="utf-8").splitlines()


def _set_cell(line: str, header: list[str], column: str, value: str) -> str:
    cells = line.split(",")
    cells[header.index(column)] = value
    return ",".join(cells)


@pytest.fixture(scope="module")
def inp(tmp_path_factory) -> Path:
    """A folder of bad (and a few good) inputs; tests only read it."""
    from faceanim.face.face import Face
    from faceanim.io.arkit_csv import write_arkit_csv
    from faceanim.standards.arkit import ARKIT_NAMES
    from faceanim.render.video import write_video

    d = tmp_path_factory.mktemp("inputs")
    # videos
    write_video(d / "blank.mp4", [np.full((64, 64, 3), 80, np.uint8)] * 5, fps=25)
    write_video(d / "blank1.mp4", [np.full((64, 64, 3), 80, np.uint8)], fps=25)
    write_video(d / "tiny.mp4", [np.full((8, 8, 3), 80, np.uint8)] * 3, fps=25)
    raw = (d / "blank.mp4").read_bytes()
    (d / "cut.mp4").write_bytes(raw[:300])
    (d / "empty.mp4").write_bytes(b"")
    (d / "junk.mp4").write_bytes(bytes(range(256)) * 20)
    (d / "text.mp4").write_text("this is not a video\n")
    (d / "folder.mp4").mkdir()
    _wav(d / "sound.mp4")
    if hasattr(os, "mkfifo"):
        os.mkfifo(d / "fifo.mp4")
    # takes: a synthetic Live Link Face recording of 30 frames, then damaged copies
    rng = np.random.default_rng(0)
    write_arkit_csv(d / "take.csv", rng.uniform(0, 0.6, (30, len(ARKIT_NAMES))), 30.0,
                    rng.uniform(-0.1, 0.1, (30, 3)))
    lines = _take_lines(d / "take.csv")
    head, rows = lines[0], lines[1:]
    cols = head.split(",")

    def take(name, body):
        (d / name).write_text("\n".join(body) + "\n", encoding="utf-8")

    take("one_row.csv", [head, rows[0]])
    take("header_only.csv", [head])
    (d / "empty.csv").write_text("")
    jaw = cols.index("JawOpen")
    take("no_jaw.csv", [",".join(c for k, c in enumerate(r.split(",")) if k != jaw) for r in lines])
    take("word.csv", [head, *rows[:10], _set_cell(rows[10], cols, "JawOpen", "abc"), *rows[11:]])
    take("nan.csv", [head, *rows[:10], _set_cell(rows[10], cols, "JawOpen", "nan"), *rows[11:]])
    take("inf.csv", [head, *rows[:10], _set_cell(rows[10], cols, "HeadYaw", "-inf"), *rows[11:]])
    text = "\n".join(lines)
    (d / "cut.csv").write_text(text[: len(text) - 150], encoding="utf-8")
    take("backwards.csv", [head, rows[5], rows[0], *rows[6:]])
    take("same_time.csv", [head, rows[0], rows[0]])
    take("escape.csv", [head, rows[0], _set_cell(rows[1], cols, "Timecode", "\x1b[31mEVIL")])
    (d / "binary.csv").write_bytes(bytes(range(256)) * 8)
    (d / "utf16.csv").write_bytes(text.encode("utf-16"))
    (d / "huge_field.csv").write_text(head + "\n" + "x" * 300_000 + "\n")
    take("semicolons.csv", [r.replace(",", ";") for r in lines])
    (d / "take_folder.csv").mkdir()
    (d / "take.npz").write_bytes((d / "take.csv").read_bytes())  # a take named like the output
    # databases: damaged copies of the shipped one
    with resources.as_file(resources.files("faceanim").joinpath("assets", "motion_default.npz")) as p:
        db_bytes = Path(p).read_bytes()
        db = dict(np.load(p))
    (d / "db.npz").write_bytes(db_bytes)

    def save(name, **changes):
        np.savez(d / name, **{**db, **changes})

    n = len(db["controls"])
    np.savez(d / "other.npz", a=np.zeros(3))
    (d / "db_cut100.npz").write_bytes(db_bytes[:100])
    (d / "db_cuthalf.npz").write_bytes(db_bytes[: len(db_bytes) // 2])
    (d / "db_cuttail.npz").write_bytes(db_bytes[:-50])
    (d / "db_empty.npz").write_bytes(b"")
    (d / "db_text.npz").write_text("hello")
    (d / "db_folder.npz").mkdir()
    save("db_shape.npz", controls=db["controls"][:, :14])
    bad = db["controls"].copy()
    bad[3, 2] = np.nan
    save("db_nan_controls.npz", controls=bad)
    bad = db["weights"].astype(np.float64)
    bad[3, 0] = np.inf
    save("db_inf_weights.npz", weights=bad)
    save("db_fps_nan.npz", fps=np.array(np.nan))
    save("db_fps_negative.npz", fps=np.array(-30.0))
    save("db_neutral.npz", neutral=np.array(n + 5))
    save("db_starts_float.npz", take_starts=np.array([0.5]))
    save("db_no_bases.npz", bases=db["bases"][:0], weights=db["weights"][:, :0], basis_curves=db["basis_curves"][:0])
    save("db_markers.npz", marker_vertices=db["marker_vertices"] + 10**8)
    save("db_curve_names.npz", curve_names=np.array(["noSuchShape"] * len(db["curve_names"])))
    objects = np.empty(2, dtype=object)
    objects[:] = [1, "a"]
    save("db_pickled.npz", controls=objects)
    save("db_other_controls.npz", control_names=np.array([f"other_{k}" for k in range(15)]))
    save("db_old.npz", format=np.array("faceanim motion database 1"))
    save("db_format_number.npz", format=np.array(5))
    import zipfile

    with zipfile.ZipFile(d / "db_zip.npz", "w") as z:
        z.writestr("readme.txt", "hello")
    # faces
    (d / "text.obj").write_text("hello world\n")
    (d / "empty.obj").write_text("")
    pv, pf = _plane()
    _obj(d / "plane.obj", pv, pf)
    nan_v = pv.copy()
    nan_v[5] = np.nan
    _obj(d / "nan.obj", nan_v, pf)
    _obj(d / "huge.obj", pv * 1e300, pf)
    _obj(d / "bad_index.obj", pv, pf + [(0, 1, 99_999)])
    (d / "junk.glb").write_bytes(bytes(range(256)) * 8)
    (d / "face_folder.obj").mkdir()
    (d / "picture.png").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(64))
    # landmarks: the default face's 478, then damaged copies
    lm = Face.default().landmarks
    points = [{"index": i, "position": [float(c) for c in lm[i]]} for i in range(len(lm))]

    def landmarks(name, pts):
        (d / name).write_text(json.dumps({"scheme": "mediapipe478", "points": pts}, allow_nan=True))

    landmarks("lm.json", points)
    landmarks("lm_nan.json", [*points[:7], {"index": 7, "position": [float("nan"), 0.0, 0.0]}, *points[8:]])
    landmarks("lm_index.json", [*points[:3], {"index": 9999, "position": points[3]["position"]}, *points[4:]])
    (d / "lm_junk.json").write_text("{not json")
    (d / "lm_list.json").write_text(json.dumps(lm.tolist()))
    (d / "lm.csv").write_text((d / "lm.json").read_text())  # landmarks named like an output
    # output targets that are not plain new files
    (d / "out_folder.glb").mkdir()
    (d / "a_file").write_text("x")
    if os.path.exists("/dev/null"):
        os.symlink("/dev/null", d / "null.glb")
    os.symlink(d / "blank.mp4", d / "link_to_video.mp4")
    return d


@pytest.fixture
def at(tmp_path, monkeypatch):
    """The output folder, also the working folder (a stray file there would show)."""
    monkeypatch.chdir(tmp_path)
    return tmp_path


# ------------------------------------------------------------------------------------ perform
PERFORM_VIDEO = [
    ("blank.mp4", "no face was found in any frame"),
    ("blank1.mp4", "no face was found in any frame"),
    ("empty.mp4", "is empty"),
    ("junk.mp4", "not a readable video"),
    ("cut.mp4", "not a readable video"),
    ("text.mp4", "not a readable video"),
    ("sound.mp4", "not a readable video"),
    ("tiny.mp4", "has frames of 8x8 pixels"),
    ("folder.mp4", "is a folder"),
    ("fifo.mp4", "is not a regular file"),
    ("none.mp4", "does not exist"),
    ("db.npz", "not a readable video"),
    ("take.csv", "not a readable video"),
]


@pytest.mark.parametrize("name,phrase", PERFORM_VIDEO, ids=[c[0] for c in PERFORM_VIDEO])
def test_perform_refuses_the_video(inp, at, capsys, name, phrase):
    if name == "fifo.mp4" and not (inp / name).exists():
        pytest.skip("no FIFOs here")
    refused(["perform", inp / name, "--quiet", "-o", at / "o.glb"], phrase, capsys, inp, at)


def test_perform_refuses_an_empty_video_path(inp, at, capsys):
    refused(["perform", "", "-o", at / "o.csv"], "the path is empty", capsys, inp, at)


PERFORM_DB = [
    ("other.npz", "is not a faceanim motion database"),
    ("db_zip.npz", "is not a faceanim motion database"),
    ("db_format_number.npz", "is not a faceanim motion database"),
    ("db_cut100.npz", "not a readable .npz file"),
    ("db_cuthalf.npz", "not a readable .npz file"),
    ("db_cuttail.npz", "not a readable .npz file"),
    ("db_empty.npz", "not a readable .npz file"),
    ("db_text.npz", "not a readable .npz file"),
    ("db_pickled.npz", "is damaged"),
    ("blank.mp4", "not a readable .npz file"),
    ("db_folder.npz", "is a folder"),
    ("none.npz", "does not exist"),
    ("db_shape.npz", "is damaged"),
    ("db_nan_controls.npz", "is damaged"),
    ("db_inf_weights.npz", "is damaged"),
    ("db_fps_nan.npz", "is damaged"),
    ("db_fps_negative.npz", "is damaged"),
    ("db_neutral.npz", "is damaged"),
    ("db_starts_float.npz", "is damaged"),
    ("db_no_bases.npz", "is damaged"),
    ("db_markers.npz", "is damaged"),
    ("db_curve_names.npz", "is damaged"),
    ("db_other_controls.npz", "built for other control parameters"),
    ("db_old.npz", "older format"),
]


@pytest.mark.parametrize("name,phrase", PERFORM_DB, ids=[c[0] for c in PERFORM_DB])
def test_perform_refuses_the_database(inp, at, capsys, name, phrase):
    """Refused on reading, before any tracking (the video has no face: it is never reached)."""
    for out in ("o.glb", "o.csv"):
        refused(["perform", inp / "blank.mp4", "--db", inp / name, "--quiet", "-o", at / out], phrase, capsys, inp, at)


PERFORM_FACE = [
    (["--face", "text.obj"], "is empty"),
    (["--face", "empty.obj"], "is empty"),
    (["--face", "nan.obj"], "NaN or infinite"),
    (["--face", "huge.obj"], "absurd coordinate"),
    (["--face", "bad_index.obj"], "indexes missing vertices"),
    (["--face", "plane.obj"], "no face found"),
    (["--face", "junk.glb"], "not a valid GLB"),
    (["--face", "face_folder.obj"], "is a folder"),
    (["--face", "none.obj"], "does not exist"),
    (["--face", "picture.png"], "unsupported format"),
    (["--face", "take.csv"], "unsupported format"),
    (["--landmarks", "lm_junk.json"], "not valid JSON"),
    (["--landmarks", "lm_list.json"], "expected {'scheme'"),
    (["--landmarks", "lm_nan.json"], "invalid position"),
    (["--landmarks", "lm_index.json"], "out of range"),
    (["--landmarks", "none.json"], "does not exist"),
    (["--face", "plane.obj", "--landmarks", "lm.json"], "from the surface"),
]


@pytest.mark.parametrize("opts,phrase", PERFORM_FACE, ids=["-".join(c[0]) for c in PERFORM_FACE])
def test_perform_refuses_the_face(inp, at, capsys, opts, phrase):
    """The face is read before tracking; .glb and .mp4 alike."""
    args = [inp / o if k % 2 else o for k, o in enumerate(opts)]
    outs = ("o.glb", "o.mp4") if opts[-1] in ("text.obj", "nan.obj") else ("o.glb",)
    for out in outs:
        refused(["perform", inp / "blank.mp4", *args, "--quiet", "-o", at / out], phrase, capsys, inp, at)


PERFORM_NUMBERS = [
    (["--window", "0"], "--window"),
    (["--window", "121"], "--window"),
    (["--window", "nan"], "--window"),
    (["--window", "1.5"], "--window"),
    (["--window", "abc"], "--window"),
    (["--k", "0"], "--k"),
    (["--k", "501"], "--k"),
    (["--k", "inf"], "--k"),
    (["--overlap", "0"], "--overlap"),
    (["--overlap", "121"], "--overlap"),
    (["--window", "5", "--overlap", "6"], "cannot exceed --window"),
    (["--window", "1", "--overlap", "2"], "cannot exceed --window"),
    (["--neutral-frame", "-1"], "--neutral-frame"),
    (["--neutral-frame", "1e9"], "--neutral-frame"),
    (["--neutral-frame", "99"], "outside the video's 5 frames"),
    (["--size", "0"], "--size"),
    (["--size", "63"], "--size"),
    (["--size", "1025"], "--size"),
    (["--size", "99999999999"], "--size"),
    (["--size", "nan"], "--size"),
]


@pytest.mark.parametrize("opts,phrase", PERFORM_NUMBERS, ids=["".join(c[0]) for c in PERFORM_NUMBERS])
def test_perform_refuses_the_numbers(inp, at, capsys, opts, phrase):
    refused(["perform", inp / "blank.mp4", *opts, "--quiet", "-o", at / "o.mp4"], phrase, capsys, inp, at)


def test_perform_refuses_the_output(inp, at, capsys):
    video = inp / "blank.mp4"
    for out, phrase in [
        (at / "missing" / "o.glb", "does not exist; create it first"),
        (inp / "a_file" / "o.glb", "is not a folder"),
        (inp / "out_folder.glb", "is a folder"),
        (at / ("x" * 300 + ".glb"), "cannot write output"),  # the name is too long
        (at / "o.txt", "must end in one of"),
        (at / "o", "must end in one of"),
        (video, "is also an input"),
        (inp / "link_to_video.mp4", "is also an input"),
    ]:
        refused(["perform", video, "--quiet", "-o", out], phrase, capsys, inp, at)
    if (inp / "null.glb").is_symlink():
        refused(["perform", video, "-o", inp / "null.glb"], "not a regular file", capsys, inp, at)
    if sys.platform.startswith("linux") and os.path.isdir("/proc/self"):
        refused(["perform", video, "-o", "/proc/o.glb"], "not writable", capsys, inp, at)
    # the output named like another input: the database, the face, the landmarks
    refused(["perform", video, "--db", inp / "take.csv", "-o", inp / "take.csv"], "is also an input", capsys, inp, at)
    refused(["perform", video, "--face", inp / "junk.glb", "-o", inp / "junk.glb"], "is also an input", capsys, inp, at)
    refused(["perform", video, "--landmarks", inp / "lm.csv", "-o", inp / "lm.csv"], "is also an input", capsys,
            inp, at)


# ------------------------------------------------------------------------------------ mocap build
MOCAP_TAKES = [
    ("one_row.csv", "has 1 sample(s)"),
    ("header_only.csv", "has 0 sample(s)"),
    ("empty.csv", "is empty"),
    ("no_jaw.csv", "lacks the column(s) JawOpen"),
    ("semicolons.csv", "lacks the column(s)"),
    ("word.csv", "column JawOpen is not a number"),
    ("nan.csv", "NaN or infinite"),
    ("inf.csv", "NaN or infinite"),
    ("cut.csv", "a truncated row"),
    ("backwards.csv", "time goes backwards"),
    ("same_time.csv", "all its samples at one time"),
    ("escape.csv", "is not HH:MM:SS:FF.fff"),
    ("binary.csv", "is not text"),
    ("utf16.csv", "is not text"),
    ("huge_field.csv", "not a readable CSV"),
    ("db.npz", "is not text"),
    ("blank.mp4", "is not text"),
    ("take_folder.csv", "is a folder"),
    ("none.csv", "does not exist"),
]


@pytest.mark.parametrize("name,phrase", MOCAP_TAKES, ids=[c[0] for c in MOCAP_TAKES])
def test_mocap_build_refuses_the_take(inp, at, capsys, name, phrase):
    refused(["mocap", "build", inp / name, "-o", at / "m.npz"], phrase, capsys, inp, at)


def test_mocap_build_names_the_bad_one_of_several_takes(inp, at, capsys):
    err = refused(["mocap", "build", inp / "take.csv", inp / "nan.csv", "-o", at / "m.npz"], "NaN or infinite",
                  capsys, inp, at)
    assert "nan.csv" in err


def test_mocap_build_refuses_options_and_outputs(inp, at, capsys):
    take = inp / "take.csv"
    for opts, phrase in [
        (["--fps", "0"], "--fps"),
        (["--fps", "nan"], "--fps"),
        (["--fps", "241"], "--fps"),
        (["--fps", "abc"], "--fps"),
        (["--pose", "bogus"], "invalid choice"),
        (["--head-motion", inp / "blank.mp4"], "no face was found in any frame"),
        (["--head-motion", inp / "junk.mp4"], "not a readable video"),
        (["--head-motion", inp / "empty.mp4"], "is empty"),
        (["--head-motion", inp / "none.mp4"], "does not exist"),
    ]:
        refused(["mocap", "build", take, *opts, "-o", at / "m.npz"], phrase, capsys, inp, at)
    for out, phrase in [
        (at / "missing" / "m.npz", "does not exist; create it first"),
        (inp / "a_file" / "m.npz", "is not a folder"),
        (at / "m.csv", "must end in one of"),
        (inp / "take.npz", "is also an input"),
    ]:
        args = [inp / "take.npz"] if out == inp / "take.npz" else [take]
        refused(["mocap", "build", *args, "-o", out], phrase, capsys, inp, at)
    (at / "m_folder.npz").mkdir()
    refused(["mocap", "build", take, "-o", at / "m_folder.npz"], "is a folder", capsys, inp, at)
    refused(["mocap", "build", "", "-o", at / "m.npz"], "the path is empty", capsys, inp, at)
    refused(["mocap", "build", "-o", at / "m.npz"], "required: TAKE.csv", capsys, inp, at)
    refused(["mocap", "build", take, "--head-motion", inp / "db.npz", "-o", inp / "db.npz"], "is also an input",
            capsys, inp, at)


# ------------------------------------------------------------------------------------ track
TRACK_VIDEO = [
    ("blank.mp4", "no face was found in any frame"),
    ("blank1.mp4", "no face was found in any frame"),
    ("empty.mp4", "is empty"),
    ("junk.mp4", "not a readable video"),
    ("cut.mp4", "not a readable video"),
    ("sound.mp4", "not a readable video"),
    ("tiny.mp4", "has frames of 8x8 pixels"),
    ("folder.mp4", "is a folder"),
    ("none.mp4", "does not exist"),
]


@pytest.mark.parametrize("name,phrase", TRACK_VIDEO, ids=[c[0] for c in TRACK_VIDEO])
def test_track_refuses_the_video(inp, at, capsys, name, phrase):
    refused(["track", inp / name, "--quiet", "-o", at / "c.csv"], phrase, capsys, inp, at)


def test_track_refuses_options_and_outputs(inp, at, capsys):
    video = inp / "blank.mp4"
    for args, phrase in [
        (["--neutral-frame", "7"], "outside the video's 5 frames"),
        (["--neutral-frame", "-1"], "--neutral-frame"),
        (["-o", at / "missing" / "c.csv"], "does not exist; create it first"),
        (["-o", at / "c.glb"], "must end in one of"),
        (["-o", inp / "take.csv"], "no face was found in any frame"),  # a named file is kept on failure
    ]:
        if args[0] != "-o":
            args = [*args, "-o", at / "c.csv"]
        refused(["track", video, "--quiet", *args], phrase, capsys, inp, at)
    (at / "c_folder.csv").mkdir()
    refused(["track", video, "-o", at / "c_folder.csv"], "is a folder", capsys, inp, at)
    refused(["track", inp / "take.csv", "-o", inp / "take.csv"], "is also an input", capsys, inp, at)


# ------------------------------------------------------------------------------------ with real data
@pytest.fixture(scope="module")
def real(tmp_path_factory):
    """A 10-frame and a 1-frame clip of d0.mp4 and a database built from the real ARKit take."""
    from faceanim.io.video import video_frames, video_info
    from faceanim.render.video import write_video

    if not (VIDEOS.is_dir() and TAKE.is_file()):
        pytest.skip("../shared/data is not here")
    d = tmp_path_factory.mktemp("real")
    info = video_info(VIDEOS / "d0.mp4")
    frames = []
    for f in video_frames(info):
        frames.append(f)
        if len(frames) == 10:
            break
    write_video(d / "face10.mp4", frames, fps=info.fps)
    write_video(d / "face1.mp4", frames[:1], fps=info.fps)
    assert run(["mocap", "build", TAKE, "-o", d / "db.npz"]) == 0
    raw = (d / "db.npz").read_bytes()
    for name, cut in [("cut100", 100), ("cut_half", len(raw) // 2), ("cut_tail", len(raw) - 10)]:
        (d / f"db_{name}.npz").write_bytes(raw[:cut])
    db = dict(np.load(d / "db.npz"))
    starts = np.arange(0, len(db["controls"]), 2)
    np.savez(d / "db_short_takes.npz", **{**db, "take_starts": starts,
                                          "take_names": np.array([f"t{k}" for k in range(len(starts))])})
    return d


@needs_data
def test_a_truncated_real_database_is_refused(real, at, capsys):
    for name in ("db_cut100.npz", "db_cut_half.npz", "db_cut_tail.npz"):
        refused(["perform", real / "face1.mp4", "--db", real / name, "--quiet", "-o", at / "o.glb"],
                "not a readable .npz file", capsys, real, at)


@needs_data
def test_real_clip_with_bad_settings(real, at, capsys):
    video = real / "face10.mp4"
    refused(["perform", video, "--neutral-frame", "10", "--quiet", "-o", at / "o.csv"],
            "outside the video's 10 frames", capsys, real, at)
    refused(["track", video, "--neutral-frame", "10", "--quiet", "-o", at / "o.csv"],
            "outside the video's 10 frames", capsys, real, at)
    # every take of the database shorter than the window (2 frames each)
    refused(["perform", video, "--db", real / "db_short_takes.npz", "--window", "5", "--overlap", "2", "--quiet",
             "-o", at / "o.csv"], "takes are at most 2 frames long", capsys, real, at)


@needs_data
def test_smallest_settings_run(real, at):
    """--window 1 --overlap 1, --k 1 (with the shipped and the built database) and a one-frame
    video: each writes its one output and nothing else."""
    video = real / "face10.mp4"
    for k, (args, out) in enumerate([
        (["--window", "1", "--overlap", "1"], "w1.csv"),
        (["--k", "1"], "k1.csv"),
        (["--window", "1", "--overlap", "1", "--k", "1", "--db", real / "db.npz"], "all1.glb"),
    ]):
        assert run(["perform", video, *args, "--quiet", "-o", at / out]) == 0, args
        assert sorted(p.name for p in at.iterdir()) == sorted(
            ["w1.csv", "k1.csv", "all1.glb"][: k + 1]), args
    rows = (at / "w1.csv").read_text().splitlines()
    assert len(rows) == 1 + 10
    assert run(["perform", real / "face1.mp4", "--quiet", "-o", at / "one.csv"]) == 0
    assert len((at / "one.csv").read_text().splitlines()) == 2


# ------------------------------------------------------------------------------------ found by the sweep
@pytest.fixture(scope="module")
def more(tmp_path_factory) -> Path:
    """Damaged databases with values out of range, takes with absurd numbers or gaps, a picture
    named as a video, a truncated video (made by faceanim's writer, index at the front)."""
    from faceanim.io.arkit_csv import write_arkit_csv
    from faceanim.standards.arkit import ARKIT_NAMES
    from faceanim.render.video import write_video

    d = tmp_path_factory.mktemp("more")
    with resources.as_file(resources.files("faceanim").joinpath("assets", "motion_default.npz")) as p:
        db = dict(np.load(p))
    for name, change in [("fps_huge", {"fps": np.array(1e300)}), ("fps_inf", {"fps": np.array(np.inf)}),
                         ("fps_tiny", {"fps": np.array(1e-300)}),
                         ("weights_huge", {"weights": db["weights"] * np.float32(1e30)}),
                         ("curves_huge", {"basis_curves": db["basis_curves"] * 1e300}),
                         ("controls_huge", {"controls": db["controls"] * 1e300}),
                         ("starts_negative", {"take_starts": np.array([-50])}),
                         ("starts_beyond", {"take_starts": np.array([0, 10**12]), "take_names": np.array(["a", "b"])}),
                         ("curves_repeated", {"curve_names": np.array([db["curve_names"][0]] * len(db["curve_names"]))}),
                         ("bases_scaled", {"bases": db["bases"] * 2.0})]:
        np.savez(d / f"db_{name}.npz", **{**db, **change})
    # a database whose header claims a (100M, 15) array: refused before anything is loaded
    import io
    import zipfile

    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (10**8, 15)})
    with zipfile.ZipFile(d / "db_claims_huge.npz", "w") as z:
        for key, value in db.items():
            if key != "controls":
                buf = io.BytesIO()
                np.lib.format.write_array(buf, value)
                z.writestr(f"{key}.npy", buf.getvalue())
        z.writestr("controls.npy", np.lib.format.magic(1, 0) + header.getvalue()[8:] + b"\0" * 64)
    rng = np.random.default_rng(1)
    w, h = rng.uniform(0, 0.6, (30, len(ARKIT_NAMES))), rng.uniform(-0.1, 0.1, (30, 3))
    write_arkit_csv(d / "take.csv", w, 30.0, h)
    lines = _take_lines(d / "take.csv")
    cols = lines[0].split(",")
    (d / "jaw_huge.csv").write_text("\n".join([lines[0], _set_cell(lines[1], cols, "JawOpen", "1e300"), *lines[2:]]) + "\n")
    (d / "yaw_huge.csv").write_text("\n".join([lines[0], *[_set_cell(r, cols, "HeadYaw", "1e300") for r in lines[1:]]]) + "\n")
    gap = lines[1].split(",")
    gap[0] = "01:00:00:00.000"
    (d / "gap.csv").write_text("\n".join([lines[0], *lines[1:3], ",".join(gap)]) + "\n")
    write_arkit_csv(d / "still.csv", np.zeros((30, len(ARKIT_NAMES))), 30.0)
    # a truncated video and a picture named .mp4
    noise = np.random.default_rng(0)  # (frames of noise: every frame takes its share of the file)
    write_video(d / "whole.mp4", [noise.integers(0, 255, (64, 64, 3), dtype=np.uint8) for _ in range(30)], fps=30)
    raw = (d / "whole.mp4").read_bytes()
    (d / "half.mp4").write_bytes(raw[: len(raw) * 6 // 10])
    with resources.as_file(resources.files("faceanim").joinpath("assets", "default_head.png")) as p:
        (d / "picture.mp4").write_bytes(p.read_bytes())
    return d


DAMAGED = ["fps_huge", "fps_inf", "fps_tiny", "weights_huge", "curves_huge", "controls_huge", "starts_negative",
           "starts_beyond", "curves_repeated", "bases_scaled", "claims_huge"]


@pytest.mark.parametrize("name", DAMAGED)
def test_perform_refuses_a_database_with_values_out_of_range(inp, more, at, capsys, name):
    refused(["perform", inp / "blank.mp4", "--db", more / f"db_{name}.npz", "-o", at / "o.csv"], "is damaged",
            capsys, more, at)


@pytest.mark.parametrize("name,phrase", [("jaw_huge.csv", "outside -1 to 2"), ("yaw_huge.csv", "outside -360 to 360"),
                                         ("gap.csv", "time jumps"), ("still.csv", "no facial motion")])
def test_mocap_build_refuses_absurd_takes(more, at, capsys, name, phrase):
    refused(["mocap", "build", more / name, "-o", at / "db.npz"], phrase, capsys, more, at)


def test_truncated_video_and_picture_are_refused(more, at, capsys):
    refused(["track", more / "half.mp4", "-o", at / "o.csv"], "ends after", capsys, more, at)
    refused(["perform", more / "half.mp4", "-o", at / "o.csv"], "ends after", capsys, more, at)
    refused(["perform", more / "picture.mp4", "-o", at / "o.csv"], "is a picture, not a video", capsys, more, at)


def test_perform_refuses_a_face_for_csv_an_odd_size_and_shows_paths_on_one_line(inp, at, capsys):
    refused(["perform", inp / "blank.mp4", "--face", inp / "text.obj", "-o", at / "o.csv"], "drop --face",
            capsys, inp, at)
    refused(["perform", inp / "blank.mp4", "--size", "65", "-o", at / "o.mp4"], "--size must be even",
            capsys, inp, at)
    for command in (["perform", inp / "blank.mp4"], ["track", inp / "blank.mp4"]):
        err = refused([*command, "-o", at / "no\nsuch" / "o.csv"], "does not exist", capsys, inp, at)
        assert "no?such" in err
