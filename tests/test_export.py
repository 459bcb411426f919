"""The one export type and suffix -> writer registry (faceanim/export.py): every animation command
and the live file sink write through it, read their suffixes from it, and make only what the asked
format needs."""

import json

import numpy as np
import pytest
from gltf_reader import accessor
from test_languages_and_cues import read_rhubarb_json, read_rhubarb_tsv

from faceanim.cli import build_parser, main
from faceanim.drivers.cues import arkit_cues
from faceanim.export import WRITERS, Animation, head_quaternions, suffixes, write
from faceanim.io.arkit_csv import read_arkit_csv
from faceanim.io.rhubarb import tidy_cues
from faceanim.standards.arkit import ARKIT_NAMES, apple_name


def _choices(argv):
    """The suffixes a command's -o accepts, asked of the parser itself."""
    parser = build_parser()
    ok = []
    for suffix in (*WRITERS, ".vrm", ".obj", ".png"):
        try:
            parser.parse_args([*argv, "-o", f"x{suffix}"])
            ok.append(suffix)
        except SystemExit:
            pass
    return ok


def test_commands_accept_what_the_registry_writes(capsys):
    assert _choices(["say", "hi"]) == list(WRITERS)
    assert _choices(["perform", "v.mp4"]) == [*suffixes(".fap"), ".vrm"]
    assert _choices(["arkit", "play", "t.csv"]) == [*suffixes(".fap"), ".vrm"]
    assert _choices(["fap", "play", "a.fap"]) == [".glb", ".mp4", ".csv"]
    assert _choices(["direct", "s.json"]) == [".glb", ".mp4", ".csv", ".fap"]
    capsys.readouterr()


def _curves(n=60, fps=30.0):
    """A jaw opening and closing twice, a blink, a head turn: (F, 52) Live Link order, (F, 3)."""
    t = np.arange(n) / fps
    w = np.zeros((n, 52))
    w[:, ARKIT_NAMES.index("JawOpen")] = np.clip(np.sin(2 * np.pi * t / (n / fps / 2)), 0, 1)
    w[:, ARKIT_NAMES.index("EyeBlinkLeft")] = (t > 1.0) * 1.0
    head = np.c_[0.3 * t / t[-1], np.zeros(n), np.zeros(n)]
    return w, head


def test_curves_only_writers_need_no_face_and_round_trip(tmp_path):
    w, head = _curves()
    a = Animation(30.0, arkit=w, head=head)
    [csv] = write(tmp_path / "a.csv", a)
    take = read_arkit_csv(csv)
    np.testing.assert_allclose(take.weights, w, atol=1e-6)
    np.testing.assert_allclose(take.head, head, atol=1e-6)
    [tsv] = write(tmp_path / "a.tsv", a)
    rows = read_rhubarb_tsv(tsv.read_text())
    # the cues are the curves' (the classifier), tidied to Rhubarb's 0.01 s over the 2 s of frames
    expected = tidy_cues(arkit_cues(w, list(ARKIT_NAMES), 30.0), 2.0)
    assert rows[:-1] == [(a / 100, shape) for a, _, shape in expected] and rows[-1] == (2.0, "X")
    assert {"X", "A"} < {shape for _, shape in rows} and len({shape for _, shape in rows}) >= 3
    for suffix in (".glb", ".mp4"):
        with pytest.raises(Exception, match="shows the face"):
            write(tmp_path / f"a{suffix}", a)
    assert not (tmp_path / "a.glb").exists() and not (tmp_path / "a.mp4").exists()


def test_glb_carries_the_faces_arkit_shapes_curves_and_head(tmp_path):
    from pygltflib import GLTF2

    from faceanim.face.face import Face
    from faceanim.rig.arkit import arkit_shapes

    face = Face.load("default")
    w, head = _curves(30)
    [glb] = write(tmp_path / "a.glb", Animation(30.0, arkit=w, head=head, face=face, name="take"))
    g = GLTF2().load(str(glb))
    names = g.meshes[0].extras["targetNames"]
    made = arkit_shapes(face)[0]
    assert names == list(made)  # every made shape is a target, in the made order
    anim = g.animations[0]
    weights = rot = None
    for ch in anim.channels:
        sampler = anim.samplers[ch.sampler]
        if ch.target.path == "weights":
            weights = accessor(g, sampler.output).reshape(30, len(names))
        if ch.target.path == "rotation":
            rot = accessor(g, sampler.output).reshape(30, 4)
    column = {apple_name(n): k for k, n in enumerate(ARKIT_NAMES)}
    np.testing.assert_allclose(weights, w[:, [column[n] for n in names]], atol=1e-6)
    q = head_quaternions(head, face.frame.rotation)
    np.testing.assert_allclose(np.abs(np.sum(rot * q, axis=1)), 1.0, atol=1e-5)  # the same rotations
    # a still head (a take whose angles are all zero) still gets its head node, turned by nothing
    [still] = write(tmp_path / "still.glb", Animation(30.0, arkit=w, head=np.zeros_like(head), face=face))
    g = GLTF2().load(str(still))
    paths = {ch.target.path for ch in g.animations[0].channels}
    assert paths == {"weights", "rotation"} and any(n.name == "head" for n in g.nodes)


def test_a_costly_field_is_made_only_for_a_format_that_needs_it(tmp_path, monkeypatch):
    import faceanim.player as player
    from faceanim.face.face import Face
    from faceanim.face.faps import FapStream
    from faceanim.standards.mpeg4 import fap
    from faceanim.rig.mpeg4 import FapRig

    face = Face.load("default")
    rig = FapRig.build(face)
    values = np.zeros((10, 68))
    mask = np.zeros((10, 68), dtype=bool)
    k = fap("open_jaw").number - 1
    values[:, k] = np.linspace(0, 400, 10)
    mask[:, k] = True
    stream = FapStream(values, mask, 25.0, name="jaw")
    calls = []
    real = player.arkit_from_stream
    monkeypatch.setattr(player, "arkit_from_stream", lambda *a: calls.append(1) or real(*a))
    write(tmp_path / "a.fap", player.stream_animation(face, rig, stream))
    assert not calls  # a .fap holds the stream: no ARKit fit
    [csv] = write(tmp_path / "a.csv", player.stream_animation(face, rig, stream))
    assert len(calls) == 1  # curves and head from one fit
    jaw = read_arkit_csv(csv).weights[:, ARKIT_NAMES.index("JawOpen")]
    assert jaw[0] < 0.05 and jaw[-1] > 0.3 and np.all(np.diff(jaw) > -1e-3)


def test_arkit_play_writes_mouth_cues_of_the_take(tmp_path):
    from test_arkit_csv import row, write_take

    rows = [row(f"00:00:00:{f:02d}.000", np.eye(52)[ARKIT_NAMES.index("JawOpen")] * (0.8 if 10 <= f < 20 else 0.0))
            for f in range(30)]
    take = write_take(tmp_path / "t.csv", rows)
    main(["arkit", "play", str(take), "-o", str(tmp_path / "c.json"), "--fps", "30"])
    doc = read_rhubarb_json((tmp_path / "c.json").read_text())
    assert doc["metadata"]["soundFile"] == ""  # a take has no sound
    opened = [c for c in doc["mouthCues"] if c["value"] not in "XA"]
    assert opened and opened[0]["start"] == pytest.approx(10 / 60, abs=0.04)  # timecode frames are 1/60 s
    assert opened[-1]["end"] == pytest.approx(20 / 60, abs=0.04)


def test_live_file_sink_writes_the_run_through_the_registry(tmp_path):
    from faceanim.live.performer import LiveSample
    from faceanim.live.sinks import parse_sinks

    w, head = _curves(45)
    with pytest.raises(Exception, match="file:PATH needs a path ending in"):
        parse_sinks([f"file:{tmp_path / 'x.mp4'}"], 30.0, "s")
    sinks = parse_sinks([f"file:{tmp_path / 'run.json'}", f"file:{tmp_path / 'run.glb'}",
                         f"csv:{tmp_path / 'run.csv'}"], 30.0, "s")
    for s in sinks:
        s.sound_name = "/clips/me.wav"
        for f in range(45):
            s.send(LiveSample(0.5 + f / 30.0, True, np.zeros(4), w[f], head[f], np.zeros(6)))
    written = [s.close() for s in sinks]
    assert [p.name for p in written] == ["run.json", "run.glb", "run.csv"]
    assert read_rhubarb_json((tmp_path / "run.json").read_text())["metadata"]["soundFile"] == "/clips/me.wav"
    np.testing.assert_allclose(read_arkit_csv(tmp_path / "run.csv").weights, w, atol=1e-6)
    doc = json.loads((tmp_path / "run.glb").read_bytes()[20:20 + int.from_bytes(
        (tmp_path / "run.glb").read_bytes()[12:16], "little")])
    assert doc["animations"][0]["name"] == "live" and "JawOpen".lower() in {
        n.lower() for n in doc["meshes"][0]["extras"]["targetNames"]}


def test_an_mp4_of_a_fap_stream_turns_the_head_once_and_fits_nothing(monkeypatch):
    """The FAP rig turns the head itself: the frames an MP4 shows are the rig's own evaluation (no
    second turn by fitted head angles), and no ARKit fit is made for them."""
    import faceanim.player as player
    from faceanim.export import face_frames
    from faceanim.face.face import Face
    from faceanim.face.faps import FapStream
    from faceanim.standards.mpeg4 import fap
    from faceanim.rig.mpeg4 import FapRig

    face = Face.load("default")
    rig = FapRig.build(face)
    values = np.zeros((6, 68))
    mask = np.zeros((6, 68), dtype=bool)
    for name, peak in (("head_yaw", 20000.0), ("open_jaw", 300.0)):
        k = fap(name).number - 1
        values[:, k] = np.linspace(0, peak, 6)
        mask[:, k] = True
    stream = FapStream(values, mask, 25.0, name="turn")
    monkeypatch.setattr(player, "arkit_from_stream", lambda *a: (_ for _ in ()).throw(AssertionError("fitted")))
    a = player.stream_animation(face, rig, stream)
    frames = np.array(list(face_frames(a)))
    expected = rig.evaluate(rig.stream_curves(stream))
    np.testing.assert_allclose(frames, expected, atol=1e-12)
    assert np.abs(frames[-1] - face.mesh.vertices).max() > 0.05 * face.frame.iod  # it did turn
    b = player.stream_animation(face, rig, stream, faps_as_targets=True)
    assert b.head is None and "head_yaw" in b.targets
