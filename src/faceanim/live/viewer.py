"""``--to viewer[:PORT]``: the ``faceanim view`` page shows the avatar moving live.

The viewer's HTTP server (:mod:`faceanim.viewer.server`, 127.0.0.1 only) serves the avatar (the
``--face`` .glb/.vrm, or the default face with ARKit's shapes made for it) and tells the page in
``/api/info`` where the live stream is: a WebSocket server (the ``websockets`` library) on another
free port of 127.0.0.1 that takes connections from the viewer's own page only (its Origin), at most
:data:`MAX_CLIENTS` of them. Each frame goes to every page as one JSON message: the capture time
(milliseconds since the epoch), the 52 ARKit curves (Live Link order, the names sent once in
``/api/info``), the head's yaw, pitch and roll and the eyes' angles. A page that reads slowly is
sent only the newest frame (one pending per page): it never holds the run back. The page applies
the curves to the avatar's morph targets by name (ARKit's, case and ``_L``/``Left`` spellings
alike) and turns the head.
"""

from __future__ import annotations

import json
import queue
import tempfile
import threading
import time
from pathlib import Path

from faceanim.errors import FaceAnimError
from faceanim.standards.arkit import APPLE_NAMES
from faceanim.live.performer import LiveSample
from faceanim.live.sinks import Sink

MAX_CLIENTS = 16
MAX_MESSAGE = 4096  # bytes a page may send (it sends nothing; anything is read and dropped)



def default_avatar(folder: Path) -> Path:
    """The default face with its ARKit shapes (as ``faceanim rig`` makes them), written to
    ``folder``/default_face_arkit.glb."""
    from faceanim.face.face import Face
    from faceanim.io.gltf import write_gltf
    from faceanim.rig.arkit import arkit_shapes

    face = Face.default()
    shapes, _ = arkit_shapes(face)
    return write_gltf(folder / "default_face_arkit.glb", face.mesh, shapes,
                      extras={"morph_sets": {"arkit": list(shapes)}})


def viewer_port(spec: str) -> int:
    """The port of ``viewer`` or ``viewer:PORT`` (the viewer's default, 8760; 0 for any free port)."""
    from faceanim.viewer.server import DEFAULT_PORT

    rest = spec[len("viewer"):]
    if not spec.startswith("viewer") or rest and not (rest.startswith(":") and rest[1:].isdigit()
                                                      and 0 <= int(rest[1:]) <= 65535):
        raise FaceAnimError("--to viewer takes an optional port: viewer or viewer:8760 (0: any free port)")
    return int(rest[1:]) if rest else DEFAULT_PORT


VRM_PRESETS = {"eyeBlinkLeft": "blinkLeft", "eyeBlinkRight": "blinkRight", "jawOpen": "aa"}  # as the page maps them


def driven_curves(doc: dict) -> list[str]:
    """The ARKit curves (Apple's names) a model's page can drive: morph targets or VRM expressions
    named by ARKit in any spelling, or a VRM's blink and aa presets (as ``viewer.js`` matches)."""
    from faceanim.standards.arkit import name_key

    names = []
    for mesh in doc.get("meshes") or []:
        for extras in (mesh.get("extras"), *((p or {}).get("extras") for p in mesh.get("primitives") or [])):
            if isinstance(extras, dict) and isinstance(extras.get("targetNames"), list):
                names += [n for n in extras["targetNames"] if isinstance(n, str)]
    ext = doc.get("extensions") or {}
    vrm1 = (ext.get("VRMC_vrm") or {}).get("expressions") or {}
    for group in ("preset", "custom"):
        if isinstance(vrm1.get(group), dict):
            names += [n for n in vrm1[group] if isinstance(n, str)]
    vrm0 = ((ext.get("VRM") or {}).get("blendShapeMaster") or {}).get("blendShapeGroups") or []
    names += [g.get("presetName") or g.get("name") for g in vrm0 if isinstance(g, dict)]
    keys = {name_key(n) for n in names if isinstance(n, str)}
    return [a for a in APPLE_NAMES if name_key(a) in keys or name_key(VRM_PRESETS.get(a, a)) in keys]


class ViewerSink(Sink):
    """The viewer and its live stream (see the module docstring); ``url`` is the page's address."""

    def __init__(self, spec: str, face=None):
        from faceanim.extras import require

        serve = require("websockets.sync.server", "faceanim live --to viewer").serve

        from faceanim.viewer.server import HOST, Viewer, ViewerServer, check_model, check_vendor

        port = viewer_port(spec)
        # the port first (a port in use is told before the avatar is made), the page's files next
        self.http = ViewerServer(None, port, option="--to viewer:")
        self._tmp = None
        try:
            check_vendor(vrm=face is not None and Path(face).suffix.lower() == ".vrm")
            if face is None:
                self._tmp = tempfile.TemporaryDirectory(prefix="faceanim-live-")
                model = check_model(default_avatar(Path(self._tmp.name)))
            else:
                model = check_model(face)
            check_vendor(vrm=model.kind == "vrm")
            self.clients: dict = {}
            self.lock = threading.Lock()
            self.ws = serve(self._client, HOST, 0, origins=None, max_size=MAX_MESSAGE, compression=None,
                            process_request=self._check_origin)
        except BaseException:
            self.http.server_close()
            if self._tmp is not None:
                self._tmp.cleanup()
            raise
        ws_port = self.ws.socket.getsockname()[1]
        self.http.viewer = Viewer(model)
        from faceanim.avatar import HEAD_BONE_NAMES

        self.http.viewer.live = {"url": f"ws://{HOST}:{ws_port}/", "names": list(APPLE_NAMES),
                                 "headBones": list(HEAD_BONE_NAMES)}  # the page turns the same bone as the files
        self.url = self.http.url
        self.label = f"viewer {self.url}"
        port = self.http.server_address[1]
        self._origins = {f"http://{HOST}:{port}", f"http://localhost:{port}"}
        threading.Thread(target=self.http.serve_forever, kwargs={"poll_interval": 0.2}, daemon=True).start()
        threading.Thread(target=self.ws.serve_forever, daemon=True).start()

    def _check_origin(self, connection, request):
        if request.headers.get("Origin") not in self._origins or len(self.clients) >= MAX_CLIENTS:
            return connection.respond(403, "the live stream is for the viewer's own page\n")
        return None

    def _client(self, connection) -> None:
        pending: queue.Queue = queue.Queue(maxsize=1)
        with self.lock:
            self.clients[connection] = pending
        reader = threading.Thread(target=self._drain, args=(connection,), daemon=True)
        reader.start()
        try:
            while True:
                message = pending.get()
                if message is None:
                    return
                connection.send(message)
        except Exception:  # noqa: BLE001 -- a page closed or gone: drop it, the run goes on
            return
        finally:
            with self.lock:
                self.clients.pop(connection, None)

    @staticmethod
    def _drain(connection) -> None:
        try:
            for _ in connection:  # the page sends nothing; reading sees its close
                pass
        except Exception:  # noqa: BLE001
            pass

    def send(self, sample: LiveSample) -> None:
        message = json.dumps({"c": round(sample.capture * 1000.0, 1), "t": round(sample.time, 4),
                              "w": [round(float(x), 4) for x in sample.arkit],
                              "h": [round(float(x), 4) for x in sample.head],
                              "e": [round(float(x), 4) for x in sample.eyes]}, separators=(",", ":"))
        with self.lock:
            targets = list(self.clients.values())
        for pending in targets:
            try:
                pending.get_nowait()  # an unsent older frame is replaced
            except queue.Empty:
                pass
            try:
                pending.put_nowait(message)
            except queue.Full:
                pass

    def close(self) -> None:
        with self.lock:
            targets = list(self.clients.values())
        for pending in targets:
            try:
                pending.get_nowait()
            except queue.Empty:
                pass
            pending.put_nowait(None)
        deadline = time.monotonic() + 1.0
        while self.clients and time.monotonic() < deadline:
            time.sleep(0.01)
        self.ws.shutdown()
        self.http.shutdown()
        self.http.server_close()
        if self._tmp is not None:
            self._tmp.cleanup()
        return None
