"""faceanim live: the causal performance, the VMC and Live Link packets, the sinks and the command.

Oracles: the offline perform path on the same clip (the live curves must agree with it and with
the video's own lip gap), python-osc's own server and dispatcher as the VMC receiver, and Live Link
packets built byte by byte with struct from the layout Unreal reads.
"""

from __future__ import annotations

import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from faceanim.errors import FaceAnimError, InputFileError
from faceanim.face.face import Face
from faceanim.io.arkit_csv import read_arkit_csv
from faceanim.standards.arkit import ARKIT_NAMES
from faceanim.io.livelink import decode_packet, encode_packet
from faceanim.standards.arkit import LIVE_LINK_ORDER
from faceanim.io.vmc import decode_frame, encode_frame, head_quaternion

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
CLIPS = DATA / "talking-head-videos"
needs_clips = pytest.mark.skipif(not (CLIPS / "d18.mp4").exists(), reason="needs ../shared/data/talking-head-videos")


# -- Live Link packets -----------------------------------------------------------------------------
def test_livelink_packet_matches_the_layout_built_by_hand():
    values = {n: (k + 1) / 100.0 for k, n in enumerate(LIVE_LINK_ORDER)}
    got = encode_packet(values, frame=1234, fps=30, subject="Face", device="ABC", subframe=0.25)
    want = (b"\x06" + struct.pack(">i", 3) + b"ABC" + struct.pack(">i", 4) + b"Face"
            + struct.pack(">i", 1234) + struct.pack(">f", 0.25) + struct.pack(">ii", 30, 1) + bytes([61])
            + b"".join(struct.pack(">f", (k + 1) / 100.0) for k in range(61)))
    assert got == want
    back = decode_packet(got)
    assert (back.device, back.subject, back.frame, back.rate) == ("ABC", "Face", 1234, (30, 1))
    assert back.values["JawOpen"] == pytest.approx(values["JawOpen"])
    assert list(back.values) == list(LIVE_LINK_ORDER)
    # Unreal's enum: jaw left before right, unlike the app's CSV columns
    assert LIVE_LINK_ORDER.index("JawLeft") < LIVE_LINK_ORDER.index("JawRight")
    assert set(LIVE_LINK_ORDER[:52]) == set(ARKIT_NAMES)


UNREAL_ENUM = """EyeBlinkLeft EyeLookDownLeft EyeLookInLeft EyeLookOutLeft EyeLookUpLeft EyeSquintLeft EyeWideLeft
EyeBlinkRight EyeLookDownRight EyeLookInRight EyeLookOutRight EyeLookUpRight EyeSquintRight EyeWideRight JawForward
JawLeft JawRight JawOpen MouthClose MouthFunnel MouthPucker MouthLeft MouthRight MouthSmileLeft MouthSmileRight
MouthFrownLeft MouthFrownRight MouthDimpleLeft MouthDimpleRight MouthStretchLeft MouthStretchRight MouthRollLower
MouthRollUpper MouthShrugLower MouthShrugUpper MouthPressLeft MouthPressRight MouthLowerDownLeft MouthLowerDownRight
MouthUpperUpLeft MouthUpperUpRight BrowDownLeft BrowDownRight BrowInnerUp BrowOuterUpLeft BrowOuterUpRight CheekPuff
CheekSquintLeft CheekSquintRight NoseSneerLeft NoseSneerRight TongueOut HeadYaw HeadPitch HeadRoll LeftEyeYaw
LeftEyePitch LeftEyeRoll RightEyeYaw RightEyePitch RightEyeRoll""".split()  # Unreal's EARFaceBlendShape


def test_livelink_packet_order_is_unreals_enum():
    assert LIVE_LINK_ORDER == tuple(UNREAL_ENUM)


def test_livelink_ntsc_rate_is_a_rational():
    assert decode_packet(encode_packet({}, 0, 29.97, "s", "d")).rate == (30000, 1001)


@pytest.mark.parametrize("cut", [b"", b"\x05", "short", "long", "nan"])
def test_livelink_decode_refuses_broken_packets(cut):
    good = encode_packet({"JawOpen": 0.5}, 1, 30, "s", "d")
    data = {"short": good[:-3], "long": good + b"\x00", "nan": good[:-4] + struct.pack(">f", float("nan"))}.get(cut, cut)
    if cut == b"\x05":
        data = b"\x05" + good[1:]
    with pytest.raises(InputFileError):
        decode_packet(data)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=800))
def test_livelink_decode_fuzz(data):
    try:
        decode_packet(data)
    except InputFileError:
        pass


# -- VMC ---------------------------------------------------------------------------------------------
def _rotate(q, v):
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(q).apply(v)


def test_vmc_head_quaternion_signs():
    # Unity: x right (from the avatar's view), y up, z forward (the avatar faces +z)
    assert _rotate(head_quaternion(0.3, 0, 0), [0, 0, 1])[0] < -0.25  # a turn to its own left
    assert _rotate(head_quaternion(0, 0.3, 0), [0, 0, 1])[1] < -0.25  # a nod down
    assert _rotate(head_quaternion(0, 0, 0.3), [0, 1, 0])[0] > 0.25  # a tilt to its right
    assert np.allclose(head_quaternion(0, 0, 0), (0, 0, 0, 1))


def test_vmc_frame_read_by_python_osc_dispatcher():
    """python-osc's own dispatcher (what a VMC receiver built on it sees), not our decoder."""
    from pythonosc.dispatcher import Dispatcher
    from pythonosc.osc_server import BlockingOSCUDPServer

    seen = []
    d = Dispatcher()
    d.set_default_handler(lambda address, *args: seen.append((address, args)))
    server = BlockingOSCUDPServer(("127.0.0.1", 0), d)
    port = server.server_address[1]
    blends = {"JawOpen": 0.5, "EyeBlinkLeft": 1.0, "MouthSmileRight": 0.0}
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.sendto(encode_frame(blends, (0.1, 0.0, 0.0), 1.5), ("127.0.0.1", port))
    server.timeout = 5
    server.handle_request()
    server.server_close()
    addresses = [a for a, _ in seen]
    assert addresses[0] == "/VMC/Ext/OK" and addresses[-1] == "/VMC/Ext/Blend/Apply"
    vals = [args for a, args in seen if a == "/VMC/Ext/Blend/Val"]
    assert [v[0] for v in vals] == list(blends) and [v[1] for v in vals] == pytest.approx(list(blends.values()))
    bone = [args for a, args in seen if a == "/VMC/Ext/Bone/Pos"][0]
    assert bone[0] == "Head" and len(bone) == 8
    assert np.allclose(bone[4:], head_quaternion(0.1, 0, 0), atol=1e-6)
    ours = decode_frame(encode_frame(blends, (0.1, 0.0, 0.0), 1.5))
    assert ours["applied"] and ours["blends"] == pytest.approx(blends) and ours["time"] == pytest.approx(1.5)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=600))
def test_vmc_decode_fuzz(data):
    try:
        decode_frame(data)
    except InputFileError:
        pass


# -- the causal synthesis ----------------------------------------------------------------------------
@pytest.mark.parametrize("overlap", [1, 2, 4])
def test_synthesis_stream_gives_the_offline_frames(overlap):
    from faceanim.drivers.video.synthesis import SynthesisStream, Synthesiser

    rng = np.random.default_rng(3)
    controls = np.cumsum(rng.normal(size=(300, 3)), axis=0)
    markers = rng.normal(size=(300, 5))
    query = controls[40:110] + 0.1 * rng.normal(size=(70, 3))
    offline = Synthesiser(controls, markers, 5, 12, 0.99, overlap).synthesise(query)
    stream = SynthesisStream(Synthesiser(controls, markers, 5, 12, 0.99, overlap))
    out = [stream.push(q) for q in query]
    assert all(o is None for o in out[:overlap - 1])
    got = np.array(out[overlap - 1:])
    assert np.allclose(got, offline[:len(got)], atol=1e-12)
    assert stream.delay == overlap - 1


# -- the live performer against the offline path, on a real clip ------------------------------------
@pytest.fixture(scope="module", params=["solve", "synthesis"])
def d18_live_and_offline(request):
    """d18 live (each frame tracked and stepped as it comes) and offline, by the ARKit solve
    (:class:`LiveSolver`, :func:`solve_performance`) and by Chai et al.'s synthesis
    (:class:`LivePerformer`, :func:`perform`)."""
    from faceanim.drivers.video.tracking import FaceTracker, track_video
    from faceanim.io.video import video_frames, video_info
    from faceanim.live.performer import LivePerformer, LiveSolver
    from faceanim.perform import arkit_curves, default_database, perform, solve_performance

    clip = CLIPS / "d18.mp4"
    if not clip.is_file():
        pytest.skip("../shared/data/talking-head-videos is not here")
    info = video_info(clip)
    samples = []
    with FaceTracker() as tracker:
        if request.param == "solve":
            lp = LiveSolver()
            for i, f in enumerate(video_frames(info)):
                found = tracker.detect(f, i / info.fps)
                samples.append(lp.step(None if found is None else found.landmarks, i / info.fps,
                                       None if found is None else found.blendshapes))
        else:
            lp = LivePerformer()
            samples = [lp.step(tracker(f, i / info.fps), i / info.fps) for i, f in enumerate(video_frames(info))]
    tracking = track_video(clip)
    offline = solve_performance(tracking) if request.param == "solve" else perform(tracking)
    return samples, tracking, arkit_curves(offline, default_database())


@needs_clips
def test_live_mouth_follows_the_video_as_offline_does(d18_live_and_offline):
    samples, tracking, offline = d18_live_and_offline
    live = np.array([s.arkit for s in samples])
    assert live.shape == offline.shape and np.all((live >= 0) & (live <= 1))
    j, c = ARKIT_NAMES.index("JawOpen"), ARKIT_NAMES.index("MouthClose")
    gap = tracking.inner_gap
    ok = np.isfinite(gap)
    r_live = np.corrcoef((live[:, j] - live[:, c])[ok], gap[ok])[0, 1]
    r_off = np.corrcoef((offline[:, j] - offline[:, c])[ok], gap[ok])[0, 1]
    assert r_live >= 0.85 and r_live >= r_off - 0.03, (r_live, r_off)


@needs_clips
def test_live_blinks_close_and_head_turns_as_tracked(d18_live_and_offline):
    samples, tracking, offline = d18_live_and_offline
    live = np.array([s.arkit for s in samples])
    b = ARKIT_NAMES.index("EyeBlinkLeft")
    assert live[:, b].max() > 0.9  # d18 yawns with the eyes shut
    assert np.corrcoef(live[:, b], offline[:, b])[0, 1] > 0.8
    head = np.degrees(np.array([s.head for s in samples]))
    ok = tracking.tracked
    for k in range(3):  # the live One-Euro against the raw tracked angles
        assert np.abs(head[ok, k] - tracking.pose[ok, k]).max() < 5.0


def test_live_performer_holds_then_eases_a_lost_face():
    from faceanim.face.generic_head import generic_head
    from faceanim.live.performer import LivePerformer
    from faceanim.perform import LOST_EASE, LOST_HOLD

    # the generic head's own landmarks, seen by a camera: an open jaw
    head = generic_head()
    v = head.mesh.vertices + 1.0 * head.shape("jawOpen")
    lm = head.landmarks(v)
    px = np.c_[lm[:, 0] * 2000 + 256, -lm[:, 1] * 2000 + 256, -lm[:, 2] * 2000]
    rest = head.landmarks()
    px_rest = np.c_[rest[:, 0] * 2000 + 256, -rest[:, 1] * 2000 + 256, -rest[:, 2] * 2000]
    lp = LivePerformer()
    fps = 30.0
    t = 0.0
    for i in range(60):  # two seconds at rest, then open
        lp.step(px_rest if i < 45 else px, t)
        t += 1 / fps
    jaw = ARKIT_NAMES.index("JawOpen")
    opened = lp.step(px, t).arkit[jaw]
    assert opened > 0.2
    out = []
    for i in range(int((LOST_HOLD + LOST_EASE + 0.5) * fps)):
        t += 1 / fps
        out.append(lp.step(None, t))
    held = [s.arkit[jaw] for s in out if s.time - out[0].time < LOST_HOLD - 0.05]
    assert np.allclose(held, opened)
    assert out[-1].arkit[jaw] == pytest.approx(0.0, abs=1e-9)
    assert not any(s.tracked for s in out)


# -- the pipeline with a clip, receivers on 127.0.0.1 ---------------------------------------------
@needs_clips
def test_pipeline_sends_every_frame_to_vmc_livelink_and_csv(tmp_path):
    from pythonosc.dispatcher import Dispatcher
    from pythonosc.osc_server import ThreadingOSCUDPServer

    from faceanim.live.pipeline import run_live
    from faceanim.live.sinks import parse_sinks
    from faceanim.live.sources import ClipSource

    frames = []
    current = {}

    def on_val(address, name, value):
        current[name] = value

    def on_apply(address, *args):
        frames.append(dict(current))
        current.clear()

    d = Dispatcher()
    d.map("/VMC/Ext/Blend/Val", on_val)
    d.map("/VMC/Ext/Blend/Apply", on_apply)
    vmc = ThreadingOSCUDPServer(("127.0.0.1", 0), d)
    threading.Thread(target=vmc.serve_forever, daemon=True).start()
    ll = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    ll.bind(("127.0.0.1", 0))
    ll.settimeout(0.5)
    packets = []

    def listen():
        while True:
            try:
                packets.append(decode_packet(ll.recv(4096)))
            except (socket.timeout, OSError):
                if stop.is_set():
                    return

    stop = threading.Event()
    th = threading.Thread(target=listen, daemon=True)
    th.start()
    csv = tmp_path / "take.csv"
    sinks = parse_sinks([f"vmc://127.0.0.1:{vmc.server_address[1]}", f"livelink://127.0.0.1:{ll.getsockname()[1]}",
                         f"csv:{csv}"], 25.0, "Me")
    source = ClipSource(CLIPS / "d0.mp4", realtime=False)
    report = run_live(source, sinks, keep_samples=True)
    time.sleep(0.5)
    stop.set()
    th.join()
    vmc.shutdown()
    vmc.server_close()
    ll.close()
    n = 78  # d0's frames
    assert report.processed == n and report.dropped == 0 and report.written == [csv]
    assert len(frames) == n and len(packets) == n
    assert all(list(f) == list(ARKIT_NAMES) for f in frames)  # every curve, every frame, in order
    assert all(0.0 <= v <= 1.0 for f in frames for v in f.values())
    assert [p.frame for p in packets] == list(range(n)) and {p.subject for p in packets} == {"Me"}
    sent = np.array([[f[k] for k in ARKIT_NAMES] for f in frames])
    want = np.array([s.arkit for s in report.samples])
    assert np.allclose(sent, want, atol=1e-6)
    assert np.allclose([[p.values[k] for k in ARKIT_NAMES] for p in packets], want, atol=1e-6)
    take = read_arkit_csv(csv)
    assert take.n_samples == n and np.allclose(take.weights, np.round(want, 6), atol=2e-6)
    assert np.allclose(take.head, np.round([s.head for s in report.samples], 6), atol=2e-6)
    smile = ARKIT_NAMES.index("MouthSmileLeft")
    assert want[:, smile].max() > 0.3  # d0's broad grin


# -- the command ------------------------------------------------------------------------------------
def _live(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "faceanim", "live", *args], capture_output=True, text=True,
                          timeout=timeout)


@pytest.mark.parametrize("to", ["osc://127.0.0.1:9000", "vmc://127.0.0.1:99999", "vmc://no.such.host.invalid:9000",
                                "vmc://", "csv:", "csv:take.txt", "livelink://127.0.0.1:x", "viewer2"])
def test_live_refuses_bad_sinks(tmp_path, to):
    r = _live("--video", str(tmp_path / "none.mp4"), "--to", to)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "--to" in r.stderr
    assert not list(tmp_path.iterdir())


def test_live_refuses_missing_sources_and_outputs(tmp_path):
    r = _live("--camera", "63", "--to", f"csv:{tmp_path / 'x.csv'}")
    assert r.returncode == 2 and "no camera 63" in r.stderr
    r = _live("--video", str(tmp_path / "none.mp4"), "--to", f"csv:{tmp_path / 'x.csv'}")
    assert r.returncode == 2 and "none.mp4" in r.stderr
    r = _live("--to", f"csv:{tmp_path / 'x.csv'}")
    assert r.returncode == 2
    r = _live("--video", "a.mp4", "--to", f"csv:{tmp_path / 'no' / 'x.csv'}")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert not list(tmp_path.iterdir())


@needs_clips
def test_live_command_stops_on_ctrl_c_with_the_csv_whole_and_survives_a_gone_receiver(tmp_path):
    closed = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    closed.bind(("127.0.0.1", 0))
    port = closed.getsockname()[1]
    closed.close()  # nobody listens: the kernel answers each datagram with "port unreachable"
    csv = tmp_path / "take.csv"
    p = subprocess.Popen([sys.executable, "-m", "faceanim", "live", "--video", str(CLIPS / "d10.mp4"), "--to",
                          f"vmc://127.0.0.1:{port}", "--to", f"csv:{csv}"], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    first = p.stderr.readline()  # the run's own line: the sinks are open, the clip about to play
    assert first.startswith("faceanim live: "), first
    time.sleep(5.0)  # a third of the clip: Ctrl-C comes while it plays, however slow the start was
    p.send_signal(signal.SIGINT)
    out, err = p.communicate(timeout=60)
    err = first + err
    assert p.returncode == 0, err
    assert out.startswith("stopped: "), out
    take = read_arkit_csv(csv)
    processed = int(out.split("stopped: ")[1].split(" frames")[0])
    assert processed > 30 and processed <= take.n_samples <= 15 * 30 + 1  # the clip's span, every frame on it
    assert sum("cannot send" in line for line in err.splitlines()) <= 1
    assert not [f for f in tmp_path.iterdir() if f.name != "take.csv"]


def test_parse_sinks_checks_the_subject():
    from faceanim.live.sinks import parse_sinks

    with pytest.raises(FaceAnimError):
        parse_sinks(["livelink://127.0.0.1"], 30.0, "x" * 100)
    assert parse_sinks(["livelink://127.0.0.1"], 30.0, "Face")[0].addr == ("127.0.0.1", 11111)
    assert parse_sinks(["vmc://localhost"], 30.0, "Face")[0].addr[1] == 39539


# -- the viewer, in headless Chromium ----------------------------------------------------------------
AVATAR = DATA / "avatars" / "vroid-sample.glb"


def _live_page(browser, args, seconds=30.0):
    """Start faceanim live with --to viewer:0 and open its page; returns (process, page)."""
    p = subprocess.Popen([sys.executable, "-m", "faceanim", "live", *map(str, args), "--to", "viewer:0",
                          "--no-browser"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = p.stderr.readline()
    assert "http://127.0.0.1:" in line, line + p.stderr.read()
    url = line.split("viewer ")[1].split()[0]
    page = browser.new_page(viewport={"width": 640, "height": 480})
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url)
    page.wait_for_function("window.viewer && (window.viewer.ready || window.viewer.error)", timeout=120_000)
    assert page.evaluate("viewer.error") is None and not errors
    return p, page


def _finish(proc) -> int:
    """Wait for a live run to end with its clip (Ctrl-C if it has not within 30 s): its exit code."""
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=60)
    return proc.returncode


def _watch(page, name: str, seconds: float) -> list[float]:
    """The page's weight of morph target ``name`` at every frame it draws, until the stream ends (the
    clip is over) or for at most ``seconds`` (a slow machine draws few frames: polling from here
    could miss the jaw's peaks)."""
    page.evaluate(f"window.__seen = []; viewer.onFrame.push(() => __seen.push(viewer.weight({name!r})))")
    page.wait_for_function("faceanimLive.closed", timeout=seconds * 1000, polling=200)
    return page.evaluate("__seen")


@needs_clips
def test_viewer_page_moves_the_default_face_live(browser):
    proc, page = _live_page(browser, ["--video", CLIPS / "d18.mp4"])
    try:
        page.wait_for_function("faceanimLive.messages > 20", timeout=60_000)
        assert page.evaluate("faceanimLive.matched") >= 50  # the default face's ARKit shapes, by name
        jaw = _watch(page, "jawOpen", 30.0)
        assert max(jaw) > 0.2 and len(set(jaw)) >= 3  # d18 opens its jaw; the weight moves
        lat = page.evaluate("faceanimLive.latencies")
        assert len(lat) >= 3 and all(x > -50 for x in lat)  # capture times on the page's clock, in ms (newest frames only)
    finally:
        page.close()
        code = _finish(proc)
    assert code == 0


@needs_clips
@pytest.mark.skipif(not AVATAR.exists(), reason="needs ../shared/data/avatars/vroid-sample.glb")
def test_viewer_page_moves_a_whole_avatar_by_its_arkit_names(browser):
    """The VRoid avatar (a skinned, multi-mesh glb exported from VRoid) has ARKit-named targets on its
    face mesh: they move with the clip; the performer's head turns its Head bone (not the whole
    body)."""
    proc, page = _live_page(browser, ["--video", CLIPS / "d18.mp4", "--face", AVATAR])
    try:
        page.wait_for_function("faceanimLive.messages > 20", timeout=60_000)
        assert page.evaluate("faceanimLive.matched") >= 50
        assert page.evaluate("faceanimLive.turned") == "Head"
        page.evaluate("window.__turns = []; viewer.onFrame.push(() => __turns.push(faceanimLive.headTurn))")
        jaw = _watch(page, "jawOpen", 30.0)
        assert max(jaw) > 0.2
        assert max(page.evaluate("__turns")) > 0.02  # the Head bone turned from its rest
    finally:
        page.close()
        code = _finish(proc)
    assert code == 0


@needs_clips
def test_viewer_page_moves_a_vrm_and_three_vrm_keeps_the_weights(browser, tmp_path):
    """A .vrm (the default face rigged with ARKit's shapes as VRM 1.0 custom expressions): the curves
    reach its expressions by name, and a morph weight set directly survives three-vrm's expression
    manager, which used to set it back to 0 on its next update."""
    vrm = tmp_path / "face.vrm"
    r = subprocess.run([sys.executable, "-m", "faceanim", "rig", "--set", "arkit", "-o", str(vrm)], capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    proc, page = _live_page(browser, ["--video", CLIPS / "d18.mp4", "--face", vrm])
    try:
        page.wait_for_function("faceanimLive.messages > 20", timeout=60_000)
        assert page.evaluate("faceanimLive.matched") >= 50
        jaw = _watch(page, "jawOpen", 30.0)
        assert max(jaw) > 0.2  # the expression manager sets the morph from the jawOpen expression
        assert _finish(proc) == 0
        page.wait_for_function("faceanimLive.closed", timeout=30_000)
        # a morph weight set directly (a slider) is set again after each of three-vrm's updates
        page.evaluate("viewer.setWeight('jawOpen', 1.0)")
        n = page.evaluate("viewer.renders")
        page.wait_for_function(f"viewer.renders > {n + 10}", timeout=30_000)
        assert page.evaluate("viewer.weight('jawOpen')") == 1.0
    finally:
        page.close()
        code = _finish(proc)
    assert code == 0


def test_viewer_stream_refuses_other_origins():
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    from faceanim.live.viewer import ViewerSink
    from faceanim.viewer.server import ViewerError

    try:
        sink = ViewerSink("viewer:0")
    except ViewerError as exc:  # three.js not installed beside the page
        pytest.skip(str(exc))
    try:
        url = sink.http.viewer.live["url"]
        with pytest.raises(InvalidStatus):
            connect(url, origin="http://evil.example", open_timeout=5).close()
        port = sink.http.server_address[1]
        with connect(url, origin=f"http://127.0.0.1:{port}", open_timeout=5) as ws:
            deadline = time.monotonic() + 2
            while not sink.clients and time.monotonic() < deadline:
                time.sleep(0.01)
            from faceanim.live.performer import LiveSample

            sink.send(LiveSample(0.5, True, np.zeros(38), np.full(52, 0.25), np.zeros(3), np.zeros(6), 1.0))
            import json

            m = json.loads(ws.recv(timeout=5))
            assert m["w"] == [0.25] * 52 and m["c"] == 1000.0 and m["t"] == 0.5
    finally:
        sink.close()


# -- live lip sync ----------------------------------------------------------------------------------
SPEECH = DATA / "speech-librivox"
needs_speech = pytest.mark.skipif(not (SPEECH / "clip-0870.wav").exists(), reason="needs ../shared/data/speech-librivox")
VISEMES = {"closed": "P B M", "labiodental": "F V", "rounded": "UW OW AO W UH OY R ER", "open": "AA AE AH AW AY",
           "spread": "IY IH EH EY Y", "dental": "TH DH", "post": "SH ZH CH JH"}


def _stream_clip(path, chunk_s=0.02):
    """A sound fed to LiveLipSync in 20 ms chunks (as AudioFeed does, without the clock): per
    chunk, the stream's time, the mouth's ARKit curves then and the phone being heard."""
    from faceanim.drivers.speech.phonemes import SAMPLE_RATE
    from faceanim.drivers.speech.stream import LiveLipSync
    from faceanim.live.audio import APPLE, read_sound

    x = read_sound(path)
    ls = LiveLipSync(APPLE)
    n = int(chunk_s * SAMPLE_RATE)
    times, curves, heard = [], [], []
    for k in range(0, len(x), n):
        ls.feed(x[k:k + n])
        times.append(ls.stream.time)
        curves.append(ls.curves())
        heard.append(ls.current_phone().rstrip("012"))
    return np.array(times), np.array(curves), heard


@needs_speech
def test_live_lip_sync_against_the_offline_alignment():
    """The oracle: each clip aligned offline with its transcript (pocketsphinx's forced alignment).
    Streamed: a viseme's class shows up within 150 ms of the aligned phone's start (median), and
    most p, b, m shut the lips (mouthClose reaches jawOpen) within 150 ms of the phone's end."""
    from faceanim.drivers.speech.phonemes import align

    cls = {p: k for k, v in VISEMES.items() for p in v.split()}
    j, c = ARKIT_NAMES.index("JawOpen"), ARKIT_NAMES.index("MouthClose")
    latencies, shut, closures = [], 0, 0
    for wav in sorted(SPEECH.glob("clip-*.wav")):
        times, curves, heard = _stream_clip(wav)
        ref = align(wav, wav.with_suffix(".txt").read_text())
        prev = None
        for p in ref:
            k = cls.get(p.phone.rstrip("012"))
            if k is not None and k != prev:
                sel = np.flatnonzero((times >= p.start - 0.02) & (times <= p.end + 0.3))
                hit = [times[i] for i in sel if cls.get(heard[i]) == k]
                if hit:
                    latencies.append(hit[0] - p.start)
            prev = k
            if p.phone in ("P", "B", "M"):
                closures += 1
                sel = (times >= p.start - 0.03) & (times <= p.end + 0.15)
                shut += bool(sel.any() and (curves[sel, j] - curves[sel, c]).min() < 0.03)
    assert len(latencies) > 100 and np.median(latencies) <= 0.15, np.median(latencies)
    assert closures > 20 and shut / closures >= 0.7, (shut, closures)


@needs_speech
def test_quiet_phones_are_silence_but_a_quiet_closure_stays_shut():
    """The lip sync's quiet gate: a phone heard where every block under it was quiet (room hiss the
    decoder takes for f or v) is silence, but a quiet p, b or m keeps its name (a stop's closure
    is silent by nature: the lips shut); loud phones are themselves."""
    from types import SimpleNamespace

    from faceanim.drivers.speech.stream import PhoneStream

    seg = lambda word, a, b: SimpleNamespace(word=word, start_frame=a, end_frame=b)  # noqa: E731
    stream = PhoneStream()
    stream.dec = SimpleNamespace(seg=lambda: [seg("F", 0, 9), seg("M", 10, 19), seg("AA", 20, 29), seg("B", 30, 39),
                                              seg("V", 40, 49), seg("+NSN+", 50, 59)])
    stream.levels = bytearray([0] * 20 + [1] * 20 + [0] * 20)  # frames 20-39 loud, the rest quiet
    assert [p.phone for p in stream._path()] == ["SIL", "M", "AA", "B", "SIL", "SIL"]


def test_live_lip_sync_is_deterministic_and_restarts_at_pauses():
    from faceanim.drivers.speech.phonemes import SAMPLE_RATE
    from faceanim.drivers.speech.stream import MIN_UTTERANCE, PAUSE, LiveLipSync
    from faceanim.live.audio import APPLE, read_sound

    a, b = (read_sound(SPEECH / f"clip-{n}.wav") for n in ("0870", "0880"))
    x = np.r_[a, np.zeros(int(2 * PAUSE * SAMPLE_RATE), np.float32), b]
    runs = []
    for _ in range(2):
        ls = LiveLipSync(APPLE)
        restarts, out = 0, []
        for k in range(0, len(x), 320):
            before = ls.stream.offset
            ls.feed(x[k:k + 320])
            restarts += ls.stream.offset != before
            out.append(ls.curves())
        runs.append(np.array(out))
    assert np.array_equal(runs[0], runs[1])  # same sound, same curves
    assert restarts >= 1 and len(a) / SAMPLE_RATE > MIN_UTTERANCE
    second = [p for p in ls.stream.phones if p.phone != "SIL"]
    assert second and second[-1].end > len(a) / SAMPLE_RATE + PAUSE  # the second clip heard after the restart
    jaw = runs[0][:, APPLE.index("jawOpen")]
    assert jaw[len(a) // 320 + 10:].max() > 0.2


def test_idle_face_sways():
    from faceanim.live.audio import HEAD_SWAY, IdleFace

    t = np.arange(0, 60, 1 / 30)
    head = np.array([IdleFace().at(x) for x in t])
    assert np.all(np.abs(np.degrees(head)) <= np.array([a for _, a in HEAD_SWAY]) + 1e-9)
    assert np.all(np.degrees(np.ptp(head, axis=0)) > np.array([a for _, a in HEAD_SWAY]))  # it moves
    assert np.array_equal(head, np.array([IdleFace().at(x) for x in t]))  # the same every run


def test_merge_mouth():
    from faceanim.live.audio import CLOSE, MOUTH, merge_mouth
    from faceanim.live.performer import LiveSample

    video = np.full(52, 0.2)
    sound = np.zeros(52)
    sound[MOUTH] = 0.6
    sound[CLOSE] = 0.9
    for how, jaw, close, blink in (("audio", 0.6, 0.9, 0.2), ("video", 0.2, 0.2, 0.2), ("both", 0.4, 0.9, 0.2)):
        s = LiveSample(0.0, True, np.zeros(0), video.copy(), np.zeros(3), np.zeros(6))
        merge_mouth(s, sound, how)
        assert s.arkit[ARKIT_NAMES.index("JawOpen")] == pytest.approx(jaw)
        assert s.arkit[CLOSE] == pytest.approx(close)
        assert s.arkit[ARKIT_NAMES.index("EyeBlinkLeft")] == pytest.approx(blink)  # the eyes stay the video's


@needs_speech
def test_live_command_with_sound_alone(tmp_path):
    csv = tmp_path / "talk.csv"
    r = _live("--audio", str(SPEECH / "clip-0870.wav"), "--to", f"csv:{csv}")
    assert r.returncode == 0, r.stderr
    take = read_arkit_csv(csv)
    assert 6.5 * 30 <= take.n_samples <= 7.5 * 30  # the clip's 7 s at 30 ticks a second
    jaw = take.weights[:, ARKIT_NAMES.index("JawOpen")]
    assert jaw.max() > 0.3 and (jaw > 0.05).mean() > 0.3  # it talks
    # and the voice moves the rest of the face: a blink, the brows on its accents, a nod
    assert take.weights[:, ARKIT_NAMES.index("EyeBlinkLeft")].max() > 0.9
    assert take.weights[:, ARKIT_NAMES.index("BrowInnerUp")].max() > 0.1
    assert np.ptp(take.head[:, 1]) > 0.04
    silent = tmp_path / "silent.wav"
    import soundfile

    soundfile.write(str(silent), np.zeros(16000, np.float32), 16000)
    for args, phrase in ((["--audio", str(silent)], "silent"), (["--audio", str(tmp_path / "none.wav")], "none.wav"),
                         (["--audio", str(silent), "--mouth", "audio"], "--mouth")):
        r = _live(*args, "--to", f"csv:{tmp_path / 'x.csv'}")
        assert r.returncode == 2 and phrase in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "x.csv").exists()


@needs_speech
def test_live_command_carries_an_emotion_phrase_by_phrase(tmp_path):
    """``live --audio --emotion joy``: the smile of joy's ARKit mix at 0.6 x the phrase's multiplier
    (0.5..1.5) while the voice speaks, rising from 0 as it begins; the mouth's own curves and the brows stay the
    voice's. Refused before anything is written: an unknown emotion, --emotion with a video,
    --intensity alone."""
    from faceanim.drivers.speech.lipsync import expression_mix
    from faceanim.drivers.speech.prosody import EMOTION_RANGE

    csv = tmp_path / "joy.csv"
    r = _live("--audio", str(SPEECH / "clip-0870.wav"), "--emotion", "joy", "--to", f"csv:{csv}")
    assert r.returncode == 0, r.stderr
    take = read_arkit_csv(csv)
    smile = take.weights[:, ARKIT_NAMES.index("MouthSmileLeft")]
    mix = expression_mix("joy")["mouthSmileLeft"] * 0.6
    assert smile[0] < 0.2 * mix and np.all(np.diff(smile[:6]) >= 0)  # it rises from 0 as the voice begins
    held = smile[int(1.0 * 30):]
    assert held.min() >= EMOTION_RANGE[0] * mix - 1e-3 and held.max() <= EMOTION_RANGE[1] * mix + 1e-3
    assert np.ptp(held) > 0.1 * mix  # it changes phrase by phrase
    assert take.weights[:, ARKIT_NAMES.index("JawOpen")].max() > 0.3
    assert take.weights[:, ARKIT_NAMES.index("EyeBlinkLeft")].max() > 0.9
    for args, phrase in ((["--audio", str(SPEECH / "clip-0870.wav"), "--emotion", "glee"], "glee"),
                         (["--video", str(tmp_path / "a.mp4"), "--audio", str(SPEECH / "clip-0870.wav"),
                           "--emotion", "joy"], "--emotion"),
                         (["--audio", str(SPEECH / "clip-0870.wav"), "--intensity", "1"], "--intensity"),
                         (["--audio", str(SPEECH / "clip-0870.wav"), "--emotion", "joy", "--intensity", "nan"],
                          "--intensity")):
        r = _live(*args, "--to", f"csv:{tmp_path / 'x.csv'}")
        assert r.returncode == 2 and phrase in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "x.csv").exists()


def test_live_refuses_an_avatar_without_arkit_names(tmp_path):
    from faceanim.io.gltf import write_gltf

    face = Face.default()
    glb = tmp_path / "smile.glb"
    write_gltf(glb, face.mesh, {"smile_a": np.zeros_like(face.mesh.vertices) + 1e-3})
    r = _live("--video", str(tmp_path / "none.mp4"), "--to", "viewer:0", "--face", str(glb), "--no-browser")
    assert r.returncode == 2 and "named by ARKit" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = _live("--video", str(tmp_path / "none.mp4"), "--to", f"csv:{tmp_path / 'x.csv'}", "--face", str(glb))
    assert r.returncode == 2 and "--to viewer" in r.stderr


def test_live_command_eases_a_lost_face_to_rest_and_says_so_once(tmp_path):
    """A clip whose face is seen for 1.5 s (the default face rendered with its jaw open), then
    gone for 2.5 s: one notice on stderr; the take holds the open jaw, then is at rest."""
    from faceanim.perform import LOST_EASE, LOST_HOLD
    from faceanim.render import OffscreenRenderer
    from faceanim.render.video import write_video
    from faceanim.rig.arkit import arkit_shapes

    face = Face.default()
    shapes, _ = arkit_shapes(face)
    with OffscreenRenderer(face.mesh, size=(256, 256), **face.view(yaw=0.0, pitch=0.0)) as r:
        rest = r.render(face.mesh.vertices)
        open_jaw = r.render(face.mesh.vertices + 0.7 * shapes["jawOpen"])
    blank = np.full_like(rest, 40)
    clip = tmp_path / "lost.mp4"
    write_video(clip, [rest] * 20 + [open_jaw] * 25 + [blank] * 75, fps=30)
    csv = tmp_path / "take.csv"
    r = _live("--video", str(clip), "--to", f"csv:{csv}")
    assert r.returncode == 0, r.stderr
    assert sum("no face in view" in line for line in r.stderr.splitlines()) == 1
    take = read_arkit_csv(csv)
    jaw = take.weights[:, ARKIT_NAMES.index("JawOpen")]
    t = np.arange(take.n_samples) / 30.0
    seen_until = 45 / 30.0
    held = jaw[(t > seen_until + 0.05) & (t < seen_until + LOST_HOLD - 0.05)]
    assert held.min() > 0.1  # held while the face is just lost
    assert np.all(jaw[t > seen_until + LOST_HOLD + LOST_EASE + 0.1] < 1e-6)  # then at rest


def test_live_viewer_port_in_use(tmp_path):
    from faceanim.viewer.server import ViewerError

    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen(1)
    port = busy.getsockname()[1]
    try:
        from faceanim.live.viewer import ViewerSink

        with pytest.raises(ViewerError, match=f"port {port} .* in use.*--to viewer:P"):
            ViewerSink(f"viewer:{port}")
    finally:
        busy.close()
