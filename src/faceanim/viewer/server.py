"""The viewer's local web server: the page, three.js, one model, its sound, the photos; nothing else.

Bound to 127.0.0.1 only. It serves, by fixed routes and never by a path from the request:

- ``/`` the page and ``/app/NAME`` its own files (a fixed list);
- ``/vendor/PATH`` files of the npm packages installed beside the page (``static/node_modules``,
  three.js and three-vrm), only inside that folder, only ``.js``/``.wasm`` files;
- ``/model`` the one model file, ``/sound`` the sound its scene extras name (a ``.wav`` beside it),
  ``/photo/N`` the photos given with ``--photo``;
- ``/api/info`` what the page needs to know (slider groups, sound, photos, point names) and
  ``POST /api/points`` the picked points, checked as the commands read them and written to the
  ``--save-points`` file (the only file it writes).

Requests whose ``Host`` is not this server's own address (DNS rebinding) and posts from another
origin are refused. A file is served only if it is what was given: the sound must be a regular
WAV file in the model's own folder, never a symbolic link (its name comes from the model file, so
a link could point anywhere), and it is opened without following one. Each connection waits at
most :data:`REQUEST_SECONDS` for a request (a client that trickles headers is cut off) and for
each part of an answer to be taken (a client that reads slowly is cut off), at most
:data:`MAX_CLIENTS` are served at once (a new one cuts the connection that has waited longest for
its request or, with none waiting, the one that has been answered longest: a flood of idle or
slow-reading sockets cannot keep a browser out), and a stop (Ctrl-C) never waits for a client.
"""

from __future__ import annotations

import json
import mimetypes
import os
import shutil
import sys
import threading
from dataclasses import dataclass, field
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import unquote, urlsplit

from faceanim.errors import FaceAnimError, shown

STATIC = Path(__file__).resolve().parent / "static"
VENDOR = STATIC / "node_modules"
APP_FILES = ("index.html", "viewer.js", "viewer.css")
VENDOR_SUFFIXES = (".js", ".wasm")
MODEL_SUFFIXES = (".glb", ".vrm")
PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png")
MAX_PHOTOS = len(("front", "side", "side2"))
MAX_MODEL_BYTES = 2 << 30
MAX_POST_BYTES = 8 << 20
HOST = "127.0.0.1"
DEFAULT_PORT = 8760
REQUEST_SECONDS = 10.0  # a connection's socket timeout: an idle or slow client is let go after this
MAX_CLIENTS = 64  # connections served at once; a new one past this cuts the longest-waiting one
PATH_SHOWN = 80


class ViewerError(FaceAnimError):
    """The viewer cannot start: its model, photos, packages or port."""


def install_hint() -> str:
    return f"npm install --prefix {STATIC}"


def check_vendor(vrm: bool = False) -> None:
    """three.js (and for a VRM three-vrm) must be installed beside the page."""
    need = ["three/build/three.module.js"] + (["@pixiv/three-vrm/lib/three-vrm.module.js"] if vrm else [])
    missing = [n.split("/lib/")[0].split("/build/")[0] for n in need if not (VENDOR / n).is_file()]
    if missing:
        raise ViewerError(f"the viewer's browser packages ({', '.join(missing)}) are not installed; run "
                          f"'{install_hint()}' (bash scripts/setup.sh does it when npm is there)")


@dataclass
class Model:
    """A model file checked for serving: its path, kind (``glb`` or ``vrm``), glTF JSON and sound;
    ``served``: the file the path named when checked (links resolved then), opened at each request
    without following a link (a link put in its place later is refused)."""

    path: Path
    kind: str
    doc: dict
    sound: Path | None = None
    extras: dict = field(default_factory=dict)
    served: Path | None = None

    def __post_init__(self):
        if self.served is None:
            self.served = self.path.resolve()


def _named(path) -> str:
    return shown(path, PATH_SHOWN, tail=True)


def check_model(path: str | os.PathLike) -> Model:
    """The model file, refused with one line when it cannot be served: missing, a folder,
    unreadable, not a ``.glb``/``.vrm``, not a GLB (damaged, truncated), a GLB that refers to
    other files, a ``.vrm`` without a VRM extension."""
    from faceanim.io.files import check_input_file
    from faceanim.io.gltf import glb_json
    from faceanim.viewer.groups import scene_extras

    p = check_input_file(path, "model", "a .glb or .vrm file")
    name = _named(p)
    if p.suffix.lower() not in MODEL_SUFFIXES:
        raise ViewerError(f"model '{name}' is not a .glb or .vrm file; give one (OBJ, PLY and glTF: convert "
                          "with faceanim deform or another tool to .glb first)")
    try:
        size = p.stat().st_size
        with open(p, "rb") as fh:
            head = fh.read(12)
    except OSError as exc:
        raise ViewerError(f"cannot read model '{name}': {exc.strerror or exc}; check its permissions") from None
    if size > MAX_MODEL_BYTES:
        raise ViewerError(f"model '{name}' is {size / 2**30:.1f} GB; the viewer takes files up to "
                          f"{MAX_MODEL_BYTES >> 30} GB")
    doc = glb_json(p)
    if doc is None or len(head) < 12 or int.from_bytes(head[8:12], "little") != size:
        raise ViewerError(f"model '{name}' is not a valid GLB file (damaged, truncated or another format); "
                          "export it again as .glb")
    for key in ("buffers", "images"):
        for item in doc.get(key) or []:
            uri = item.get("uri") if isinstance(item, dict) else None
            if isinstance(uri, str) and not uri.startswith("data:"):
                raise ViewerError(f"model '{name}' refers to another file ({key}: '{shown(uri)}'); the viewer "
                                  "serves the one file: give a self-contained .glb")
    extensions = doc.get("extensionsUsed") or []
    vrm = isinstance(extensions, list) and ("VRMC_vrm" in extensions or "VRM" in extensions) \
        or isinstance(doc.get("extensions"), dict) and ({"VRMC_vrm", "VRM"} & set(doc["extensions"]))
    if p.suffix.lower() == ".vrm" and not vrm:
        raise ViewerError(f"model '{name}' has no VRM extension (VRMC_vrm or VRM); give a VRM file, or a "
                          "glTF binary named .glb")
    _check_data(p, name)
    extras = scene_extras(doc)
    return Model(p, "vrm" if vrm else "glb", doc, _sound(p, extras), extras)


def _check_data(path: Path, name: str) -> None:
    """Refuse a model whose data break glTF's rules (accessors past their buffers, triangles naming
    missing vertices, NaN positions), as every other command does; a valid file that uses what
    faceanim does not edit (quantised or compressed meshes) is the browser's to show."""
    from faceanim.errors import MeshError
    from faceanim.io.scene import DamagedGltf, read_scene

    try:
        scene = read_scene(path)
        for k in range(len(scene.meshes())):
            scene.mesh_geometry(k)
    except DamagedGltf:
        raise ViewerError(f"model '{name}' is damaged (its data break the glTF rules); export it again") from None
    except MeshError:
        return


def _sound(model: Path, extras: dict) -> Path | None:
    """The sound an animated GLB names in its scene extras: a regular ``.wav`` file (RIFF/WAVE)
    beside it, not a symbolic link, or None."""
    named = extras.get("audio")
    if not isinstance(named, str) or Path(named).name != named or not named.lower().endswith(".wav"):
        return None
    wav = model.with_name(named)
    if wav.is_symlink() or not wav.is_file():
        return None
    try:
        with open_no_link(wav) as fh:
            head = fh.read(12)
    except OSError:
        return None
    return wav if head[:4] == b"RIFF" and head[8:12] == b"WAVE" else None


def open_no_link(path: Path):
    """``path`` opened for reading, refused (OSError) if it is a symbolic link or not a regular file."""
    import stat

    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise OSError("not a regular file")
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


@dataclass
class Photo:
    """A photo to pick points on; ``served`` as for :class:`Model`."""

    path: Path
    width: int
    height: int
    served: Path | None = None

    def __post_init__(self):
        if self.served is None:
            self.served = self.path.resolve()


def check_photo(path: str | os.PathLike) -> Photo:
    """A photo to pick points on: a JPEG or PNG the photo command reads; its upright size."""
    from faceanim.build.photo import read_photo

    p = Path(path)
    if p.suffix.lower() not in PHOTO_SUFFIXES:
        raise ViewerError(f"photo '{_named(p)}' is not a .jpg or .png file; give the photo you pass to "
                          "faceanim photo")
    rgb = read_photo(p, "photo")
    return Photo(p, int(rgb.shape[1]), int(rgb.shape[0]))


class Viewer:
    """What one ``faceanim view`` serves: the model, its photos, where points are saved."""

    def __init__(self, model: Model, photos: list[Photo] | None = None, save_points: Path | None = None):
        self.model = model
        self.photos = list(photos or [])
        self.save_points = save_points
        self.lock = threading.Lock()
        self.saved = 0
        self.live: dict | None = None  # faceanim live --to viewer: where the page finds the stream

    @property
    def model_size(self) -> int:
        """The served model's size in bytes now (0 if it is gone or no longer a regular file)."""
        import stat

        try:
            st = os.lstat(self.model.served)
        except OSError:
            return 0
        return st.st_size if stat.S_ISREG(st.st_mode) else 0

    def info(self) -> dict:
        from faceanim.viewer.groups import group_targets, target_names
        from faceanim.viewer.points import point_names

        names = target_names(self.model.doc)
        return {
            "model": {"name": self.model.path.name, "kind": self.model.kind, "url": "/model",
                      "size": self.model_size},
            "groups": group_targets(names, self.model.extras.get("morph_sets")),
            "sound": {"name": self.model.sound.name, "url": "/sound"} if self.model.sound else None,
            "photos": [{"name": ph.path.name, "url": f"/photo/{k}", "width": ph.width, "height": ph.height}
                       for k, ph in enumerate(self.photos)],
            "save_points": str(self.save_points) if self.save_points else None,
            "names": point_names(),
            "live": self.live,
        }

    def save(self, body: object) -> dict:
        """Check posted points as the command that reads them does and write them to
        ``--save-points``; returns what the page shows."""
        from faceanim.io.files import write_json
        from faceanim.viewer.points import PHOTO_VIEWS, PointsError, check_landmarks, check_photo_points

        if not isinstance(body, dict) or body.get("kind") not in ("landmarks", "photo"):
            raise PointsError('send {"kind": "landmarks" or "photo", "data": {...}}')
        data = body.get("data")
        if body["kind"] == "landmarks":
            check_landmarks(data)
        else:
            views = body.get("views")  # view name -> photo number
            if not isinstance(views, dict) or not all(
                    k in PHOTO_VIEWS and type(v) is int and 0 <= v < len(self.photos) for k, v in views.items()):
                raise PointsError("each view (front, side, side2) must name one of the photos")
            check_photo_points(data, {k: (self.photos[v].width, self.photos[v].height) for k, v in views.items()})
        if self.save_points is None:
            return {"saved": None, "message": "checked; not written on disk (start faceanim view with "
                                              "--save-points PATH to write it there)"}
        with self.lock:
            write_json(self.save_points, data)
            self.saved += 1
        return {"saved": str(self.save_points), "message": f"saved to {self.save_points}"}


class _Handler(BaseHTTPRequestHandler):
    server_version = "faceanim-view"
    sys_version = ""
    protocol_version = "HTTP/1.1"
    timeout = REQUEST_SECONDS  # socket timeout: a client that sends nothing, or trickles, is let go

    def handle_one_request(self) -> None:
        self.server.waiting(self.connection, True)  # the request's head must come within REQUEST_SECONDS
        try:
            super().handle_one_request()
        finally:
            self.server.waiting(self.connection, False)

    def parse_request(self) -> bool:
        self.server.answering(self.connection)  # the head has come: the reaper lets it be
        return super().parse_request()

    @property
    def viewer(self) -> Viewer:
        return self.server.viewer  # type: ignore[attr-defined]

    def log_message(self, format, *args):  # noqa: A002 -- quiet: the terminal shows the URL only
        pass

    # ------------------------------------------------------------------ helpers
    def _own_host(self) -> bool:
        port = self.server.server_address[1]
        return self.headers.get("Host", "") in (f"{HOST}:{port}", f"localhost:{port}")

    def _send(self, status: int, body: bytes, ctype: str, cache: bool = False, head: bool = False) -> None:
        self.send_response(status)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "max-age=3600" if cache else "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.send_header("Cross-Origin-Resource-Policy", "same-origin")
        self.end_headers()
        if not head:
            self.wfile.write(body)

    def _json(self, status: int, obj) -> None:
        self._send(status, json.dumps(obj).encode(), "application/json")

    def _error(self, status: int, message: str) -> None:
        self._json(status, {"error": message})

    def _file(self, path: Path, ctype: str | None = None, cache: bool = False, head: bool = False,
              no_link: bool = False) -> None:
        """A file, streamed (a model may be large); ``no_link``: refused if it is now a symbolic link."""
        try:
            fh = open_no_link(path) if no_link else open(path, "rb")
        except OSError:
            self._error(HTTPStatus.NOT_FOUND, "not found")
            return
        if ctype is None:
            ctype = {".js": "text/javascript", ".wasm": "application/wasm", ".html": "text/html; charset=utf-8",
                     ".css": "text/css", ".wav": "audio/wav", ".glb": "model/gltf-binary",
                     ".vrm": "model/gltf-binary"}.get(path.suffix.lower()) \
                or mimetypes.guess_type(path.name)[0] or "application/octet-stream"
        with fh:
            size = os.fstat(fh.fileno()).st_size
            self.send_response(HTTPStatus.OK)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(size))
            self.send_header("Cache-Control", "max-age=3600" if cache else "no-store")
            self.send_header("X-Content-Type-Options", "nosniff")
            self.send_header("Cross-Origin-Resource-Policy", "same-origin")
            self.end_headers()
            if not head:
                shutil.copyfileobj(fh, self.wfile, 1 << 20)

    def _vendor_file(self, rel: str) -> Path | None:
        """A file of the installed npm packages, or None: every segment a plain name, the
        resolved file inside the vendor folder, with an allowed suffix."""
        parts = rel.split("/")
        if not rel or any(s in ("", ".", "..") or "\\" in s or "\0" in s or s.startswith(".") for s in parts):
            return None
        root = VENDOR.resolve()
        try:
            target = (root / rel).resolve()
        except (OSError, RuntimeError):
            return None
        if not target.is_relative_to(root) or target.suffix.lower() not in VENDOR_SUFFIXES \
                or not target.is_file():
            return None
        return target

    # ------------------------------------------------------------------ routes
    def do_HEAD(self):  # noqa: N802
        self.do_GET(head=True)

    def do_GET(self, head: bool = False):  # noqa: N802
        if not self._own_host():
            self._error(HTTPStatus.FORBIDDEN, "unknown host")
            return
        raw = urlsplit(self.path).path
        path = unquote(raw)
        v = self.viewer
        if path in ("/", "/index.html"):
            self._file(STATIC / "index.html", head=head)
        elif path.startswith("/app/") and path[5:] in APP_FILES:
            self._file(STATIC / path[5:], head=head)
        elif path.startswith("/vendor/"):
            target = self._vendor_file(path[len("/vendor/"):])
            if target is None:
                self._error(HTTPStatus.NOT_FOUND, "not found")
            else:
                self._file(target, cache=True, head=head)
        elif path == "/model":
            self._file(v.model.served, "model/gltf-binary", head=head, no_link=True)
        elif path == "/sound" and v.model.sound is not None:
            self._file(v.model.sound, "audio/wav", head=head, no_link=True)
        elif path.startswith("/photo/") and path[7:].isdigit() and int(path[7:]) < len(v.photos):
            photo = v.photos[int(path[7:])].served
            self._file(photo, "image/png" if photo.suffix.lower() == ".png" else "image/jpeg", head=head,
                       no_link=True)
        elif path == "/api/info":
            self._json(HTTPStatus.OK, v.info())
        elif path == "/favicon.ico":
            self._send(HTTPStatus.NO_CONTENT, b"", "image/x-icon", head=True)
        else:
            self._error(HTTPStatus.NOT_FOUND, "not found")

    def do_POST(self):  # noqa: N802
        from faceanim.viewer.points import PointsError

        port = self.server.server_address[1]
        origin = self.headers.get("Origin")
        if not self._own_host() or (origin is not None and origin not in (f"http://{HOST}:{port}",
                                                                          f"http://localhost:{port}")):
            self._error(HTTPStatus.FORBIDDEN, "posts come from the viewer's own page only")
            return
        if urlsplit(self.path).path != "/api/points":
            self._error(HTTPStatus.NOT_FOUND, "not found")
            return
        if self.headers.get("Content-Type", "").split(";")[0].strip() != "application/json":
            self._error(HTTPStatus.UNSUPPORTED_MEDIA_TYPE, "send application/json")
            return
        try:
            length = int(self.headers.get("Content-Length", ""))
        except ValueError:
            self._error(HTTPStatus.LENGTH_REQUIRED, "give Content-Length")
            return
        if not 0 < length <= MAX_POST_BYTES:
            self.close_connection = True
            self._error(HTTPStatus.REQUEST_ENTITY_TOO_LARGE, f"send 1..{MAX_POST_BYTES} bytes")
            return
        try:
            body = json.loads(self.rfile.read(length))
        except (ValueError, RecursionError):
            self._error(HTTPStatus.BAD_REQUEST, "the body is not JSON")
            return
        try:
            self._json(HTTPStatus.OK, self.viewer.save(body))
        except PointsError as exc:
            self._error(HTTPStatus.BAD_REQUEST, str(exc))
        except FaceAnimError as exc:  # the file could not be written
            self._error(HTTPStatus.INTERNAL_SERVER_ERROR, str(exc))


class ViewerServer(ThreadingHTTPServer):
    daemon_threads = True
    block_on_close = False  # a stop never waits for a client's thread
    allow_reuse_address = True  # SO_REUSEADDR: a restart may take a port in TIME_WAIT; a listening port is still refused
    request_queue_size = 128

    def process_request(self, request, client_address) -> None:
        """Serve the connection in a thread of its own. With :data:`MAX_CLIENTS` being served, one
        is cut to make room: the one that has waited longest for its request's head or, if none is
        waiting, the one whose answer started longest ago (a flood of idle, trickling or slow-reading
        sockets cannot keep a browser out: its connections are the newest)."""
        if not self._slots.acquire(blocking=False):
            self._cut_oldest()
            if not self._slots.acquire(timeout=0.2):
                self.shutdown_request(request)
                return
        try:
            super().process_request(request, client_address)
        except BaseException:
            self._slots.release()
            raise

    def process_request_thread(self, request, client_address) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self.waiting(request, False)
            self._slots.release()

    def waiting(self, connection, waiting: bool) -> None:
        """Whether ``connection`` is waiting for a request's head (since now); not waiting: served
        no more (its thread ends, or its request is answered and the next has not begun)."""
        import time

        with self._lock:
            self._answering.pop(connection, None)
            if waiting:
                self._waiting[connection] = time.monotonic()
            else:
                self._waiting.pop(connection, None)

    def answering(self, connection) -> None:
        """``connection``'s request has come; its answer starts now."""
        import time

        with self._lock:
            self._waiting.pop(connection, None)
            self._answering[connection] = time.monotonic()

    def _cut_oldest(self) -> None:
        import socket

        with self._lock:
            pool = self._waiting or self._answering
            oldest = min(pool.items(), key=lambda item: item[1], default=(None, 0))[0]
        if oldest is not None:
            try:
                oldest.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    def _reap(self) -> None:
        """Every half second: cut connections whose request's head has not come within
        :data:`REQUEST_SECONDS` in all (a client trickling a byte at a time keeps each read short)."""
        import socket
        import time

        while not self._closing.wait(0.5):
            now = time.monotonic()
            with self._lock:
                late = [c for c, since in self._waiting.items() if now - since > REQUEST_SECONDS]
            for c in late:
                try:
                    c.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass

    def server_close(self) -> None:
        self._closing.set()
        super().server_close()

    def __init__(self, viewer: Viewer, port: int = DEFAULT_PORT, option: str = "--port"):
        """``option``: how the user gives the port, named in the messages (``--port``, or
        ``--to viewer:`` for faceanim live)."""
        self.viewer = viewer
        self._slots = threading.BoundedSemaphore(MAX_CLIENTS)
        self._lock = threading.Lock()
        self._waiting: dict = {}  # connection -> since when it waits for a request's head
        self._answering: dict = {}  # connection -> since when its answer is being sent
        self._closing = threading.Event()
        sep = "" if option.endswith(":") else " "
        try:
            super().__init__((HOST, port), _Handler)
        except OSError as exc:
            import errno

            if exc.errno == errno.EADDRINUSE:
                raise ViewerError(f"port {port} on {HOST} is in use (another faceanim view or server?); give "
                                  f"another with {option}{sep}P, or {option}{sep}0 for any free port") from None
            if exc.errno == errno.EACCES:
                raise ViewerError(f"port {port} needs special rights here; give a port from 1024 to 65535 "
                                  f"with {option}{sep}P") from None
            raise ViewerError(f"cannot listen on {HOST}:{port} ({exc.strerror or exc}); give another port with "
                              f"{option}{sep}P") from None
        threading.Thread(target=self._reap, name="faceanim-view-reaper", daemon=True).start()

    def handle_error(self, request, client_address) -> None:
        """A browser that goes away mid-answer is no error; anything else: one line, no traceback."""
        exc = sys.exc_info()[1]
        if isinstance(exc, (ConnectionError, TimeoutError)):
            return
        print(f"faceanim view: internal error answering a request ({type(exc).__name__}); the viewer goes on",
              file=sys.stderr, flush=True)

    @property
    def url(self) -> str:
        return f"http://{HOST}:{self.server_address[1]}/"
