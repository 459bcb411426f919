"""Issue 23: the holes an outside sweep found, each a regression test that failed before its fix."""

from contextlib import contextmanager

import numpy as np
import pytest
from test_arkit_csv import HEADER, row, write_take

from faceanim.cli import main
from faceanim.errors import FaceAnimError
from faceanim.io.arkit_csv import read_arkit_csv
from faceanim.standards.arkit import ARKIT_NAMES


def run(argv, capsys) -> tuple[int, str, str]:
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def _rows():
    w = np.zeros(52)
    w[ARKIT_NAMES.index("JawOpen")] = 0.5
    return [row("00:00:00:00.000"), row("00:00:00:06.000", w), row("00:00:00:12.000")]


# --------------------------------------------------------------------- 10: a BOM is accepted
def test_a_live_link_csv_with_a_byte_order_mark_reads_as_without(tmp_path):
    plain = write_take(tmp_path / "plain.csv", _rows())
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    a, b = read_arkit_csv(plain), read_arkit_csv(bom)
    assert np.array_equal(a.weights, b.weights) and np.array_equal(a.times, b.times)
    assert b.weights[1, ARKIT_NAMES.index("JawOpen")] == 0.5


# ------------------------------------------------- 6: a cell with no column is refused, not dropped
def test_a_live_link_row_with_a_cell_more_than_the_header_is_refused(tmp_path, capsys):
    rows = _rows()
    rows[1] = rows[1] + ["0.7"]
    take = write_take(tmp_path / "extra.csv", rows)
    with pytest.raises(FaceAnimError, match=r"line 3: 64 cells for 63 columns \(a cell with no column"):
        read_arkit_csv(take)
    rc, out, err = run(["arkit", "play", take, "-o", tmp_path / "x.csv"], capsys)
    assert rc == 2 and len(err.strip().splitlines()) == 1 and not (tmp_path / "x.csv").exists()
    # an empty cell after the last column (a trailing comma, as spreadsheets write) is no data
    rows[1][-1] = ""
    assert read_arkit_csv(write_take(tmp_path / "trailing.csv", rows)).weights.shape == (3, 52)
    assert len(HEADER) == 63


# ------------------------------------------------- 4: a tiny frame rate overflowed the glTF times
def test_a_fap_file_with_a_tiny_frame_rate_is_one_line_and_exit_2(tmp_path, capsys):
    values = " ".join(["0"] * 68)
    for fps in ("1e-30", "1e-5"):
        fap = tmp_path / "tiny.fap"
        fap.write_text(f"2.1 tiny {fps} 2\n{values}\n0\n{values}\n1\n")
        rc, out, err = run(["fap", "play", fap, "-o", tmp_path / "x.glb"], capsys)
        assert rc == 2, err
        assert "more than faceanim's limit of 3600 s; check the frame rate" in err and len(err.splitlines()) == 1
        assert not (tmp_path / "x.glb").exists()


def test_the_gltf_writer_refuses_times_beyond_float32(tmp_path):
    from faceanim.face.mesh import Mesh
    from faceanim.io.gltf import write_gltf

    mesh = Mesh(np.eye(3), np.array([[0, 1, 2]]))
    with pytest.raises(FaceAnimError, match="finite 32-bit numbers"):
        write_gltf(tmp_path / "x.glb", mesh, {"a": np.ones((3, 3))}, times=np.array([0.0, 1e39]),
                   weights=np.array([[0.0], [1.0]]))
    assert not (tmp_path / "x.glb").exists()


# -------------------------------------------------------------- 1, 9: the viewer serves what it was given
def _animated_glb(folder, sound_name="voice.wav"):
    from faceanim.face.mesh import Mesh
    from faceanim.io.gltf import write_gltf

    mesh = Mesh(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    return write_gltf(folder / "m.glb", mesh, {"a": np.full((3, 3), 0.1)}, times=np.array([0.0, 1.0]),
                      weights=np.array([[0.0], [1.0]]), extras={"audio": sound_name})


@contextmanager
def _serving(viewer):
    """``viewer`` served on a free port in a thread; yields get(path) -> (status, body)."""
    import http.client
    import threading

    from faceanim.viewer import server as srv

    server = srv.ViewerServer(viewer, 0)
    threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.1}, daemon=True).start()
    port = server.server_address[1]

    def get(path):
        c = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
        c.request("GET", path, headers={"Host": f"127.0.0.1:{port}"})
        r = c.getresponse()
        return r.status, r.read()

    try:
        yield get
    finally:
        server.shutdown()
        server.server_close()


def test_view_never_serves_a_file_a_sound_link_points_at(tmp_path):
    from faceanim.io.audio import write_wav
    from faceanim.viewer import server as srv

    secret = tmp_path / "secret.txt"
    secret.write_text("a private key")
    glb = _animated_glb(tmp_path)
    (tmp_path / "voice.wav").symlink_to(secret)
    assert srv.check_model(glb).sound is None  # a link named by the file is not the model's sound
    (tmp_path / "voice.wav").unlink()
    (tmp_path / "voice.wav").write_text("not a wav at all")
    assert srv.check_model(glb).sound is None  # nor is a file that is not a WAV
    write_wav(tmp_path / "voice.wav", np.zeros(1600), 16000)
    model = srv.check_model(glb)
    assert model.sound == tmp_path / "voice.wav"
    with _serving(srv.Viewer(model)) as get:
        status, body = get("/sound")
        assert status == 200 and body[:4] == b"RIFF"
        # swapped for a link while the viewer runs: refused at the request, not only at start
        (tmp_path / "voice.wav").unlink()
        (tmp_path / "voice.wav").symlink_to(secret)
        status, body = get("/sound")
        assert status == 404 and b"private" not in body


def test_view_never_serves_a_link_put_in_place_of_its_model_or_photo(tmp_path):
    """The model and photo given at start (through a link if the user gave one) are served; a link
    swapped in for either while the viewer runs is refused (the sweep read /etc/passwd so)."""
    import shutil

    from PIL import Image

    from faceanim.viewer import server as srv

    secret = tmp_path / "secret.txt"
    secret.write_text("a private key")
    real = _animated_glb(tmp_path)
    glb = tmp_path / "given.glb"
    glb.symlink_to(real)  # a link given by the user is followed once, at start
    photo = tmp_path / "p.png"
    Image.fromarray(np.full((64, 64, 3), 128, np.uint8)).save(photo)
    with _serving(srv.Viewer(srv.check_model(glb), [srv.Photo(photo, 64, 64)])) as get:
        assert get("/model") == (200, real.read_bytes())
        assert get("/photo/0") == (200, photo.read_bytes())
        kept = tmp_path / "kept.glb"
        shutil.move(real, kept)
        real.symlink_to(secret)
        photo.unlink()
        photo.symlink_to(secret)
        for path in ("/model", "/photo/0"):
            status, body = get(path)
            assert status == 404 and b"private" not in body, (path, status)
        status, body = get("/api/info")
        assert status == 200 and b'"size": 0' in body  # the link's target is not even measured
        real.unlink()
        shutil.move(kept, real)  # a model exported again (a regular file) is served as it is now
        assert get("/model") == (200, real.read_bytes())


def _a_browser_is_answered_then_ctrl_c_stops(p, port: int, within: float) -> None:
    """/api/info answered within ``within`` seconds, then SIGINT ends the viewer in a second, exit 0."""
    import signal
    import socket
    import time

    start = time.monotonic()
    c = socket.create_connection(("127.0.0.1", port), timeout=10)
    c.sendall(b"GET /api/info HTTP/1.1\r\nHost: 127.0.0.1:%d\r\nConnection: close\r\n\r\n" % port)
    reply = b""
    while chunk := c.recv(65536):
        reply += chunk
    c.close()
    assert reply.startswith(b"HTTP/1.1 200") and b'"sound"' in reply
    assert time.monotonic() - start < within, time.monotonic() - start
    p.send_signal(signal.SIGINT)
    start = time.monotonic()
    code = p.wait(timeout=10)
    assert time.monotonic() - start < 1.0 and code == 0


def test_view_outlives_a_flood_of_idle_slow_and_oversized_clients_and_stops_at_once(tmp_path):
    import socket

    from test_viewer import _start, needs_vendor

    if needs_vendor.args[0]:
        pytest.skip(needs_vendor.kwargs["reason"])
    p, url, port = _start([_animated_glb(tmp_path), "--port", "0"])
    socks = []
    try:
        for _ in range(300):  # idle: connect, say nothing
            socks.append(socket.create_connection(("127.0.0.1", port), timeout=5))
        for _ in range(3):  # slowloris: a byte of a request now and then
            s = socket.create_connection(("127.0.0.1", port), timeout=5)
            s.sendall(b"GET / HTTP/1.1\r\nHost: ")
            socks.append(s)
        for size in (70_000, 1 << 20):  # a header line and a body far over the limits
            s = socket.create_connection(("127.0.0.1", port), timeout=5)
            try:
                s.sendall(b"GET /api/info HTTP/1.1\r\nHost: 127.0.0.1:%d\r\nX: " % port + b"a" * size + b"\r\n\r\n")
            except OSError:
                pass  # cut off mid-send: refused
            socks.append(s)
        # a browser still gets its answer, promptly, and Ctrl-C stops it within a second: exit 0
        _a_browser_is_answered_then_ctrl_c_stops(p, port, 5)
    finally:
        for s in socks:
            s.close()
        if p.poll() is None:
            p.kill()
            p.wait()


def test_view_slow_readers_cannot_keep_a_browser_out_or_hold_the_stop(tmp_path):
    """More slow readers than the viewer serves at once (each asks for a large file again and again
    and never reads: the server's writes block), then a browser: it is answered promptly (the
    oldest answer is cut for it), and Ctrl-C stops the viewer within a second."""
    import socket
    import time

    from faceanim.viewer.server import MAX_CLIENTS
    from test_viewer import _start, needs_vendor

    if needs_vendor.args[0]:
        pytest.skip(needs_vendor.kwargs["reason"])
    p, url, port = _start([_animated_glb(tmp_path), "--port", "0"])
    ask = b"GET /vendor/three/build/three.core.js HTTP/1.1\r\nHost: 127.0.0.1:%d\r\n\r\n" % port
    socks = []
    try:
        for _ in range(MAX_CLIENTS + 6):
            s = socket.socket()
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            s.settimeout(5)
            s.connect(("127.0.0.1", port))
            s.sendall(ask * 30)  # ~44 MB of answers asked for, none read
            socks.append(s)
        time.sleep(1.0)  # their answers have filled the buffers: every one of these threads is blocked
        _a_browser_is_answered_then_ctrl_c_stops(p, port, 3)
    finally:
        for s in socks:
            s.close()
        if p.poll() is None:
            p.kill()
            p.wait()


# ------------------------------------------ 5: a detector fooled by a ball is caught by the one check
@pytest.fixture
def fooled_detector(monkeypatch):
    """MediaPipe 'finding' a face on any render: the points it finds on the default face's."""
    import faceanim.face.landmarks as lmod
    from faceanim.face.default import default_face

    with lmod.detection_view(default_face(), "+z", "+y", 768) as r:
        found = lmod.detect_landmarks_in_image(r.render(), agreement=True)
    real_detect, real_in_image = lmod.detect_landmarks, lmod.detect_landmarks_in_image

    def detect(mesh, *a, **k):  # fooled on the ball only (a transfer's source scans are real faces)
        if mesh.name != "ball":
            return real_detect(mesh, *a, **k)
        monkeypatch.setattr(lmod, "detect_landmarks_in_image", lambda img, agreement=False, **kw:
                            found if agreement else found[0])
        try:
            return real_detect(mesh, *a, **k)
        finally:
            monkeypatch.setattr(lmod, "detect_landmarks_in_image", real_in_image)

    monkeypatch.setattr(lmod, "detect_landmarks", detect)
    return found


@pytest.fixture(scope="module")
def ball(tmp_path_factory):
    import trimesh

    path = tmp_path_factory.mktemp("ball") / "ball.obj"
    trimesh.creation.icosphere(subdivisions=4, radius=0.1).export(path)
    return path


def _commands(ball, d):
    fw = __import__("conftest").DATA / "facewarehouse-tester1"
    video = __import__("conftest").DATA / "talking-head-videos" / "d0.mp4"
    fap = d / "one.fap"
    fap.write_text("2.1 one 25 1\n" + " ".join(["0"] * 68) + "\n0\n")
    take = write_take(d / "take.csv", _rows())
    return {
        "landmarks": ["landmarks", ball, "-o", d / "x.json"],
        "transfer": ["transfer", "--source-neutral", fw / "pose_0.obj", "--source-expressive", fw / "pose_1.obj",
                     "--target", ball, "-o", d / "x.obj"],
        "preprocess": ["preprocess", ball, "-o", d / "x.obj"],
        "wires extract": ["wires", "extract", "--face", ball, "--template", "default", "-o", d / "x.json"],
        "fap play": ["fap", "play", fap, "--face", ball, "-o", d / "x.glb"],
        "arkit play": ["arkit", "play", take, "--face", ball, "-o", d / "x.glb"],
        "perform": ["perform", video, "--face", ball, "-o", d / "x.glb"],
        "rig": ["rig", ball, "-o", d / "x.glb"],
        "say": ["say", "hi", "--face", ball, "-o", d / "x.glb"],
        "au": ["au", "--face", ball, "--au", "12", "-o", d / "x.png"],
    }


@pytest.mark.parametrize("command", ["landmarks", "transfer", "preprocess", "wires extract", "fap play", "arkit play",
                                     "perform", "rig", "say", "au"])
def test_every_command_that_takes_a_face_refuses_a_ball(command, ball, fooled_detector, tmp_path, capsys):
    argv = _commands(ball, tmp_path)[command]
    if any(isinstance(a, __import__("pathlib").Path) and not a.exists() and a.suffix in (".obj", ".mp4")
           and a.parent != tmp_path for a in argv):
        pytest.skip("the shared data is not here")
    if command == "say" and not __import__("shutil").which("espeak-ng"):
        pytest.skip("espeak-ng is not installed")
    rc, out, err = run(argv, capsys)
    assert rc == 2, (out, err)
    assert "no face found in 'ball': its landmarks have no nose" in err and len(err.strip().splitlines()) == 1
    assert not any(p.name.startswith("x.") for p in tmp_path.iterdir())


# --------------------------------------------- 8, 11: a batch on a cluster stops and fails in one line
def _render_job(folder, n: int, bad: bool = False):
    import trimesh

    for k in range(n):
        trimesh.creation.box(extents=(1, 1 + k / n, 1)).export(folder / f"m{k:03d}.obj")
    if bad:
        (folder / "m999.obj").write_bytes(b"")
    job = folder / "job.yaml"
    job.write_text("operation: render\ninputs:\n  face: 'm*.obj'\noptions: {size: 128}\noutput: '{face}.png'\n")
    return job


def _batch(job, out, *extra):
    import subprocess
    import sys

    return subprocess.Popen([sys.executable, "-m", "faceanim", "batch", str(job), "-o", str(out), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: __import__("signal").signal(__import__("signal").SIGINT,
                                                                            __import__("signal").SIG_DFL))


def test_a_failing_task_on_a_cluster_is_its_one_line_and_nothing_else(tmp_path):
    job = _render_job(tmp_path, 3, bad=True)
    p = _batch(job, tmp_path / "out", "--workers", "2", "--quiet")
    out, err = p.communicate(timeout=300)
    assert p.returncode == 1, err
    assert err.splitlines() == ["failed: m999.png: mesh '" + str(tmp_path / "m999.obj") + "' is empty (no vertices "
                                "or no faces); give a surface mesh"], err
    assert "3 done, 0 skipped (done before), 1 failed" in out


def test_ctrl_c_on_a_cluster_batch_is_one_line_and_keeps_what_is_done(tmp_path):
    import signal
    import sqlite3
    import time

    job = _render_job(tmp_path, 60)
    p = _batch(job, tmp_path / "out", "--workers", "2", "--quiet")
    first = p.stdout.readline()
    assert "on a local cluster of 2 worker processes" in first, first
    manifest = tmp_path / "out" / "faceanim-batch.sqlite"
    deadline = time.monotonic() + 120

    def recorded() -> int:  # tasks the manifest holds as done (a PNG on disk may not be recorded yet)
        if not manifest.is_file():
            return 0
        db = sqlite3.connect(f"file:{manifest}?mode=ro", uri=True, timeout=5)
        try:
            return db.execute("SELECT COUNT(*) FROM tasks WHERE state = 'done'").fetchone()[0]
        except sqlite3.OperationalError:  # the table not made yet, or the writer holds the lock
            return 0
        finally:
            db.close()

    while time.monotonic() < deadline:  # stop once some tasks are done and recorded
        time.sleep(0.2)
        if recorded() >= 2:
            break
    __import__("os").killpg(p.pid, signal.SIGINT)  # a terminal's Ctrl-C: the whole process group
    out, err = p.communicate(timeout=120)
    assert p.returncode == 130, err
    assert err.strip() == "faceanim: interrupted (SIGINT)", err
    db = sqlite3.connect(manifest)
    done = {r[0] for r in db.execute("SELECT output FROM tasks WHERE state = 'done'")}
    db.close()
    assert done and done <= {f.name for f in (tmp_path / "out").glob("*.png")}


def test_planning_a_big_batch_says_how_far_it_is(tmp_path):
    from faceanim.batch.jobs import read_job
    from faceanim.cli.batch import plan

    job = _render_job(tmp_path, 250)
    seen = []
    tasks = plan(read_job(job), (tmp_path / "out").resolve(), lambda done, total: seen.append((done, total)))
    assert len(tasks) == 250 and seen == [(0, 250), (100, 250), (200, 250)]


# ------------------------------------------------------ the outside sweep of this session's change
def test_landmark_detection_prints_nothing_on_stderr(tmp_path):
    """MediaPipe's native threads log (TensorFlow Lite's delegate, absl) whenever they please: the
    detector's whole life runs with those logs off, so a command's stderr is its one line or nothing."""
    import os
    import subprocess
    import sys

    from conftest import DATA

    scan = DATA / "facewarehouse-tester1" / "pose_0.obj"
    if not scan.is_file():
        pytest.skip("../shared/data is not here")
    env = dict(os.environ, FACEANIM_CACHE="off")
    r = subprocess.run([sys.executable, "-m", "faceanim", "landmarks", str(scan), "-o", str(tmp_path / "l.json")],
                       capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    (tmp_path / "empty.obj").write_text("")
    r = subprocess.run([sys.executable, "-m", "faceanim", "wires", "extract", "--face", str(scan), "--template",
                        str(tmp_path / "empty.obj"), "-o", str(tmp_path / "w.json")],
                       capture_output=True, text=True, env=env, timeout=300)
    assert r.returncode == 2 and len(r.stderr.splitlines()) == 1, r.stderr


@pytest.mark.parametrize("argv", [
    ["au", "{m}", "--au", "12", "-o", "{m}"],
    ["landmarks", "{m}", "--from", "{j}", "-o", "{j}"],
    ["transfer", "--source-neutral", "{m}", "--source-expressive", "{m2}", "--target", "{m2}", "-o", "{m}"],
])
def test_an_output_that_is_an_input_is_refused_and_left_as_it_is(argv, tmp_path, capsys):
    import shutil

    from conftest import DATA

    scan = DATA / "facewarehouse-tester1" / "pose_0.obj"
    if not scan.is_file():
        pytest.skip("../shared/data is not here")
    m, m2, j = tmp_path / "in.obj", tmp_path / "in2.obj", tmp_path / "in.json"
    shutil.copy(scan, m)
    shutil.copy(DATA / "facewarehouse-tester1" / "pose_1.obj", m2)
    j.write_text('{"scheme": "basic22", "points": {}}')
    before = {p: p.read_bytes() for p in (m, m2, j)}
    rc, out, err = run([a.format(m=m, m2=m2, j=j) for a in argv], capsys)
    assert rc == 2 and "is also an input; give the output its own path" in err and err.count("\n") == 1
    assert all(p.read_bytes() == b for p, b in before.items())


def test_a_stop_swallowed_on_its_way_up_still_stops_the_command(tmp_path, capsys, monkeypatch):
    """A stop signal raised inside a finaliser is only printed by Python and the code goes on: the
    stop is recorded, so the output is not put in place and the command exits 128 + n."""
    import signal

    import faceanim.cli.mesh as mesh_cli
    from faceanim.errors import STOPS, Interrupted
    from faceanim.io.files import atomic_output

    out = tmp_path / "x.png"
    out.write_bytes(b"before")

    def render_and_swallow(args):
        try:  # what a finaliser does with an exception: prints it and goes on
            STOPS.append(signal.SIGTERM)
            raise Interrupted(signal.SIGTERM)
        except Interrupted:
            pass
        with atomic_output(args.output) as tmp:
            tmp.write_bytes(b"after")

    monkeypatch.setattr(mesh_cli, "_cmd_render", render_and_swallow)
    rc, _, err = run(["render", "-o", out], capsys)
    assert rc == 128 + signal.SIGTERM and err.strip() == "faceanim: interrupted (SIGTERM)"
    assert out.read_bytes() == b"before" and [p.name for p in tmp_path.iterdir()] == ["x.png"]
    assert STOPS == []  # said and forgotten: a caller in the same process writes its files again
    with atomic_output(tmp_path / "y.png") as tmp:
        tmp.write_bytes(b"y")
    assert (tmp_path / "y.png").read_bytes() == b"y"


# ------------------------- a line-oriented file's tokens are named, not echoed (the sweep's canaries)
def test_a_token_of_a_fap_or_take_that_is_not_a_number_is_not_echoed(tmp_path, capsys):
    secret = "password=hunter2"
    values = " ".join(["0"] * 68)
    fap = tmp_path / "canary.fap"
    fap.write_text(f"2.1 x 25 {secret}\n{values}\n0\n")
    rc, _, err = run(["fap", "play", fap, "-o", tmp_path / "x.csv"], capsys)
    assert rc == 2 and err.count("\n") == 1 and "canary.fap:1: the frame count is not a number" in err, err
    assert secret not in err
    fap.write_text(f"2.1 x 25 1.5.3\n{values}\n0\n")  # a number's characters, wrongly: shown, it helps
    rc, _, err = run(["fap", "play", fap, "-o", tmp_path / "x.csv"], capsys)
    assert rc == 2 and "the frame count '1.5.3' is not a number" in err, err
    rows = _rows()
    rows[1][0] = secret
    take = write_take(tmp_path / "canary.csv", rows)
    rc, _, err = run(["arkit", "play", take, "-o", tmp_path / "x.csv"], capsys)
    assert rc == 2 and err.count("\n") == 1 and "line 3: the timecode is not HH:MM:SS:FF.fff" in err, err
    assert secret not in err
    rows[1][0] = "00:00:61:00.000"  # a timecode's characters, out of range: shown
    rc, _, err = run(["arkit", "play", write_take(tmp_path / "range.csv", rows), "-o", tmp_path / "x.csv"], capsys)
    assert rc == 2 and "timecode '00:00:61:00.000' is out of range" in err, err
    assert not (tmp_path / "x.csv").exists()


# ------------------------------------------------ the second sweep: a GLB's triangles, a FIFO named .glb
def _patched_glb(src, dst):
    """``src`` with its first triangle's first index pointing past the vertices."""
    import pygltflib

    g = pygltflib.GLTF2().load(str(src))
    blob = bytearray(g.binary_blob())
    prim = g.meshes[0].primitives[0]
    acc = g.accessors[prim.indices]
    view = g.bufferViews[acc.bufferView]
    width = {5121: 1, 5123: 2, 5125: 4}[acc.componentType]
    at = (view.byteOffset or 0) + (acc.byteOffset or 0)
    blob[at:at + width] = (2 ** (8 * width) - 1).to_bytes(width, "little")
    g.set_binary_blob(bytes(blob))
    g.save_binary(str(dst))
    return dst


@pytest.mark.parametrize("writer", ["faceanim", "trimesh"])
def test_a_glb_whose_triangles_name_missing_vertices_is_refused(tmp_path, capsys, writer):
    import trimesh

    from faceanim.face.default import default_face
    from faceanim.io.meshio import save_mesh

    src = tmp_path / "src.glb"
    if writer == "faceanim":
        save_mesh(default_face(), src)
    else:
        trimesh.creation.box().export(src)
    bad = _patched_glb(src, tmp_path / "bad.glb")
    for argv in (["render", bad, "-o", tmp_path / "x.png", "--size", "64"],
                 ["au", bad, "--au", "12", "-o", tmp_path / "x.obj"]):
        rc, _, err = run(argv, capsys)
        assert rc == 2 and err.count("\n") == 1, err
        assert "has triangles that name vertices it does not have" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.glb", "src.glb"]


def test_rig_of_a_pipe_named_glb_is_refused_at_once(tmp_path):
    import os
    import subprocess
    import sys

    fifo = tmp_path / "pipe.glb"
    os.mkfifo(fifo)
    r = subprocess.run([sys.executable, "-m", "faceanim", "rig", str(fifo), "-o", str(tmp_path / "o.glb"), "--quiet"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "is not a regular file" in r.stderr, r.stderr
    assert not (tmp_path / "o.glb").exists()


# ------------------------------------------- the second sweep: empty values, options that go together
@pytest.mark.parametrize("argv, phrase", [
    (["au", "--face", "", "--au", "12", "-o", "{d}/x.obj"], "--face is empty"),
    (["demo", "--out", "", "--size", "64", "--quiet"], "--out is empty"),
    (["demo", "--out=", "--size", "64", "--quiet"], "--out is empty"),
    (["au", "--emotion", " ", "-o", "{d}/x.obj"], "--emotion is empty"),
    (["say", "", "-o", "{d}/x.csv"], "the text to say is empty"),
    (["say", "hello", "--transcript", "{d}/words.txt", "-o", "{d}/x.csv"], "--transcript names the words of an --audio"),
])
def test_an_empty_value_or_a_transcript_without_audio_is_refused(argv, phrase, tmp_path, capsys, monkeypatch):
    """Empty values meant the default face or the current folder (demo --out '' wrote fifteen files
    into it); a transcript without a recording was dropped without a word."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "words.txt").write_text("hello")
    rc, _, err = run([a.replace("{d}", str(tmp_path)) for a in argv], capsys)
    assert rc == 2 and err.count("\n") == 1 and phrase in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["words.txt"]


def test_a_job_file_that_is_a_pipe_or_a_device_is_refused_at_once(tmp_path):
    """A FIFO named job.yaml hung the batch; a link to /dev/zero read until the machine ran out of
    memory (the third sweep)."""
    import os
    import subprocess
    import sys

    os.mkfifo(tmp_path / "pipe.yaml")
    (tmp_path / "zero.yaml").symlink_to("/dev/zero")
    for job in ("pipe.yaml", "zero.yaml"):
        r = subprocess.run([sys.executable, "-m", "faceanim", "batch", str(tmp_path / job), "-o", str(tmp_path / "out"),
                            "--workers", "1"], capture_output=True, text=True, timeout=120)
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and "is not a regular file" in r.stderr, r.stderr
    assert not (tmp_path / "out").exists()


def test_view_refuses_a_damaged_glb_and_still_shows_a_quantised_one(tmp_path, capsys):
    """view checked only a GLB's container: six damaged files every other command refuses were
    served (the third sweep). A valid file that faceanim does not edit (--compact's quantised
    positions) is still the browser's to show."""
    from faceanim.face.default import default_face
    from faceanim.io.meshio import save_mesh
    from faceanim.viewer.server import ViewerError, check_model

    src = tmp_path / "src.glb"
    save_mesh(default_face(), src)
    bad = _patched_glb(src, tmp_path / "bad.glb")
    with pytest.raises(ViewerError, match="is damaged"):
        check_model(bad)
    rc, _, err = run(["au", "--au", "12", "--compact", "-o", tmp_path / "compact.glb"], capsys)
    assert rc == 0, err
    assert check_model(tmp_path / "compact.glb").kind == "glb"
    assert check_model(src).kind == "glb"
