"""Every command, every kind of bad output path: one line on stderr, exit 2, nothing written, and
no work done first (each case returns before a face is loaded, so the sweep takes seconds).
Also the numbers that would exhaust memory, refused by the parser before anything is allocated."""

import json
import os

import numpy as np
import pytest

from faceanim.cli import main


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, base_face):
    """Small valid inputs for every command (never reached in the bad-output cases)."""
    from faceanim.io.meshio import save_mesh

    d = tmp_path_factory.mktemp("inputs")
    save_mesh(base_face, d / "face.obj")
    (d / "h.json").write_text(json.dumps({"method": "rbf", "handles": [[0, 0, 0], [0, 1, 0], [1, 0, 0], [0, 0, 1]],
                                          "offsets": [[0, 0, 0]] * 4}))
    (d / "w.wires.json").write_text("{}")
    (d / "a.fap").write_text("2.1 a 25 1\n0 0 1\n")
    (d / "scene.yaml").write_text("events:\n  - expression: joy\n    at: 0\n    duration: 1\n")
    (d / "t.txt").write_text("hello")
    return d


def commands(i):
    """(name, argv without the output, the output option, a suffix it accepts)."""
    face = str(i / "face.obj")
    return [
        ("landmarks", ["landmarks", face], "-o", ".json"),
        ("landmarks --image", ["landmarks", face, "-o", str(i / "never.json")], "--image", ".png"),
        ("deform", ["deform", face, "--handles", str(i / "h.json")], "-o", ".obj"),
        ("render", ["render", face], "-o", ".png"),
        ("preprocess", ["preprocess", face], "-o", ".obj"),
        ("au", ["au", "--au", "12"], "-o", ".glb"),
        ("transfer", ["transfer", "--source-neutral", face, "--source-expressive", face], "-o", ".obj"),
        ("wires extract", ["wires", "extract", "--base", face, "--template", face], "-o", ".json"),
        ("wires apply", ["wires", "apply", "--base", face, "--wires", str(i / "w.wires.json")], "-o", ".obj"),
        ("wires blend", ["wires", "blend", "--base", face, "--from", str(i / "w.wires.json"), "--to",
                         str(i / "w.wires.json")], "-o", ".mp4"),
        ("say", ["say", "hello"], "-o", ".fap"),
        ("say --audio", ["say", "--audio", str(i / "t.txt"), "--transcript", str(i / "t.txt")], "-o", ".mp4"),
        ("fap play", ["fap", "play", str(i / "a.fap")], "-o", ".glb"),
        ("fap write", ["fap", "write", "--expression", "joy"], "-o", ".fap"),
        ("direct", ["direct", str(i / "scene.yaml")], "-o", ".mp4"),
    ]


def bad_outputs(tmp_path, suffix):
    (tmp_path / "a_file").write_text("keep")
    (tmp_path / f"folder{suffix}").mkdir()
    return {
        "missing folder": tmp_path / "missing" / f"out{suffix}",
        "parent is a file": tmp_path / "a_file" / f"out{suffix}",
        "output is a folder": tmp_path / f"folder{suffix}",
    }


CASES = ["missing folder", "parent is a file", "output is a folder"]


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("index", range(15), ids=lambda k: f"cmd{k}")
def test_every_command_refuses_a_bad_output_path(tmp_path, inputs, capsys, index, case):
    name, argv, option, suffix = commands(inputs)[index]
    work = tmp_path / "work"
    work.mkdir()
    out = bad_outputs(work, suffix)[case]
    before = sorted(os.listdir(work)) + sorted(os.listdir(inputs))
    assert main(argv + [option, str(out)]) == 2, name
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("faceanim ") and "Traceback" not in err, err
    expected = {"missing folder": "does not exist; create it first", "parent is a file": "is not a folder",
                "output is a folder": "is a folder"}[case]
    assert expected in err, err
    assert sorted(os.listdir(work)) + sorted(os.listdir(inputs)) == before  # nothing written anywhere
    assert (work / "a_file").read_text() == "keep"


def test_demo_refuses_an_out_folder_that_is_a_file(tmp_path, capsys):
    (tmp_path / "x").write_text("keep")
    assert main(["demo", "--out", str(tmp_path / "x")]) == 2
    assert "is a file" in capsys.readouterr().err
    assert main(["demo", "--out", str(tmp_path / "no" / "deeper")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert sorted(os.listdir(tmp_path)) == ["x"] and (tmp_path / "x").read_text() == "keep"


@pytest.mark.parametrize("argv, message", [
    (["fap", "write", "--expression", "joy", "--fps", "1e9"], "--fps must be more than 0 and at most 240"),
    (["fap", "write", "--expression", "joy", "--fps", "nan"], "--fps must be a finite number"),
    (["fap", "write", "--expression", "joy", "--duration", "1e9"], "--duration must be more than 0 and at most 3600"),
    (["render", "--size", "-64"], "--size must be at least 16 and at most 4096"),
    (["render", "--size", "100000"], "--size must be at least 16 and at most 4096"),
    (["demo", "--size", "0"], "--size must be at least 16"),
    (["wires", "blend", "--base", "b.obj", "--from", "a", "--to", "b", "--frames", "1e9"],
     "--frames must be at least 2 and at most 200000"),
    (["preprocess", "scan.obj", "--grid", "100000"], "--grid must be at least 8 and at most 500"),
    (["say", "hi", "--intensity", "inf"], "--intensity must be a finite number"),
])
def test_absurd_numbers_are_refused_before_anything_is_allocated(tmp_path, capsys, argv, message):
    out = {"fap": "o.fap", "render": "o.png", "demo": None, "wires": "o.mp4", "preprocess": "o.obj", "say": "o.mp4"}
    target = out[argv[0]]
    args = argv + (["-o", str(tmp_path / target)] if target else ["--out", str(tmp_path / "d")])
    with pytest.raises(SystemExit) as exc:
        main(args)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and message in err, err
    assert os.listdir(tmp_path) == []


def test_forward_minus_z_is_an_axis_not_an_option(tmp_path, inputs, capsys):
    """``--forward -z`` reaches the command (it used to be taken for an option): a face looking
    along -z is rendered from behind, so detection finds no face there - a clean error, not usage."""
    from faceanim.cli import _join_axis_values

    assert _join_axis_values(["landmarks", "m.obj", "--forward", "-z", "--up", "+y"]) == \
        ["landmarks", "m.obj", "--forward=-z", "--up=+y"]
    assert _join_axis_values(["say", "--forward", "-zebra"]) == ["say", "--forward", "-zebra"]


def test_version_and_help(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out.startswith("faceanim ")
    with pytest.raises(SystemExit):
        main(["say", "--help"])
    text = capsys.readouterr().out
    from faceanim.export import WRITERS

    assert "(default: 25.0)" in text and " ".join(WRITERS) in text and "--face MESH" in text


def test_say_to_glb_writes_its_sound_beside_and_names_morphs_by_arkit(tmp_path, capsys):
    import shutil

    import pygltflib
    import soundfile

    if not shutil.which("espeak-ng"):
        pytest.skip("espeak-ng is not installed (scripts/setup.sh installs it)")
    (tmp_path / "h.wav").write_bytes(b"the user's own file")
    assert main(["say", "Hello, how are you?", "-o", str(tmp_path / "h.glb")]) == 0
    assert (tmp_path / "h.wav").read_bytes() == b"the user's own file"  # never replaced
    gltf = pygltflib.GLTF2().load(str(tmp_path / "h.glb"))
    assert gltf.scenes[gltf.scene or 0].extras["audio"] == "h-1.wav"
    info = soundfile.info(str(tmp_path / "h-1.wav"))
    names = gltf.meshes[0].extras["targetNames"]
    # the face's own ARKit shapes, by Apple's names, the mouth's among them
    assert {"jawOpen", "mouthFunnel", "mouthPucker", "mouthStretchLeft"} <= set(names)
    assert all(n[0].islower() and not n.startswith(("fap", "open_")) for n in names)
    # the animation and the sound are the same length (to a frame)
    times = gltf.accessors[gltf.animations[0].samplers[0].input]
    assert abs(times.max[0] - info.duration) < 0.1
    # written again: the glb's own sound file is replaced, no new one piles up
    assert main(["say", "Hello, how are you?", "-o", str(tmp_path / "h.glb")]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["h-1.wav", "h.glb", "h.wav"]
    assert (tmp_path / "h.wav").read_bytes() == b"the user's own file"


def test_a_failed_glb_leaves_no_sound_beside(tmp_path, capsys):
    """A stream with only FAPs the default face cannot show (the tongue): nothing is written."""
    import soundfile

    soundfile.write(str(tmp_path / "s.wav"), np.zeros(8000, dtype=np.float32), 16000)
    from faceanim.face.faps import FapStream
    from faceanim.io.fapfile import write_fap

    tongue = FapStream.empty(2, 25.0, "t")
    tongue.set("raise_tongue_tip", 300.0)
    write_fap(tmp_path / "t.fap", tongue)
    assert main(["fap", "play", str(tmp_path / "t.fap"), "--audio", str(tmp_path / "s.wav"),
                 "-o", str(tmp_path / "t.glb")]) == 2
    assert "no FAP this face can show" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.wav", "t.fap"]


def test_say_to_fap_is_for_any_face(tmp_path):
    """A .fap file assumes MPEG-4's neutral face (closed lips): the same visemes as `fap write
    --say`, whatever the face's own lip gap."""
    import shutil

    from faceanim.io.fapfile import read_fap

    if not shutil.which("espeak-ng"):
        pytest.skip("espeak-ng is not installed (scripts/setup.sh installs it)")
    assert main(["say", "hello bob", "-o", str(tmp_path / "a.fap")]) == 0
    assert main(["fap", "write", "--say", "hello bob", "-o", str(tmp_path / "b.fap")]) == 0
    a, b = read_fap(tmp_path / "a.fap"), read_fap(tmp_path / "b.fap")
    lips = [3, 4, 7, 8]  # lower_t_midlip, raise_b_midlip, stretch and raise corners: columns FAP - 1
    assert np.abs(a.values[:, lips]).max() > 0
    np.testing.assert_allclose(np.abs(a.values[:, lips]).max(0), np.abs(b.values[:, lips]).max(0), rtol=0.25)


def test_fap_play_glb_is_arkit_unless_faps(tmp_path):
    """fap play -o x.glb: the face's ARKit shapes (Apple's names) with curves fitted to the stream,
    weights in 0..1 (a smile for joy) and the head's rotation; --faps keeps one target per FAP."""
    import pygltflib
    from gltf_reader import accessor

    from faceanim.face.faps import FapStream
    from faceanim.standards.arkit import ARKIT_NAMES
    from faceanim.io.fapfile import write_fap
    from faceanim.io.gltf import glb_json

    s = FapStream.empty(10, 25.0, "smile")
    for name in ("stretch_l_cornerlip", "stretch_r_cornerlip", "raise_l_cornerlip", "raise_r_cornerlip"):
        s.set(name, 300.0)
    s.set("head_yaw", 20000.0)
    write_fap(tmp_path / "s.fap", s)
    assert main(["fap", "play", str(tmp_path / "s.fap"), "-o", str(tmp_path / "a.glb")]) == 0
    doc = glb_json(tmp_path / "a.glb")
    names = doc["meshes"][0]["extras"]["targetNames"]
    assert names == [n[0].lower() + n[1:] for n in ARKIT_NAMES]
    anim = doc["animations"][0]
    assert [c["target"]["path"] for c in anim["channels"]] == ["weights", "rotation"]
    w = accessor(pygltflib.GLTF2().load_binary(str(tmp_path / "a.glb")), anim["samplers"][0]["output"])
    w = w.reshape(10, len(names))
    assert w.min() >= 0 and w.max() <= 1 and w[:, names.index("mouthSmileLeft")].min() > 0.1
    assert main(["fap", "play", str(tmp_path / "s.fap"), "--faps", "-o", str(tmp_path / "f.glb")]) == 0
    faps = glb_json(tmp_path / "f.glb")["meshes"][0]["extras"]["targetNames"]
    assert "stretch_l_cornerlip" in faps and "jawOpen" not in faps
