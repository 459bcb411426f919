"""Where live curves go: one registry of sinks, each named by a scheme in ``--to``.

- ``vmc://HOST[:PORT]``: the VMC protocol over OSC/UDP (:mod:`faceanim.io.vmc`; port 39539), for
  VSeeFace, VNyan, Warudo, VMagicMirror;
- ``livelink://HOST[:PORT]``: Live Link Face's UDP packets (:mod:`faceanim.io.livelink`; port
  11111), for Unreal's Live Link (subject ``--subject``);
- ``file:PATH``: the whole run written (atomically) when it stops, Ctrl-C included, on a uniform
  clock at the source's frame rate, by PATH's suffix through :mod:`faceanim.export`: a Live Link
  Face CSV, Rhubarb mouth cues (.tsv, .json) or the default face animated (.glb); ``csv:PATH``
  is the same for a .csv;
- ``viewer[:PORT]``: the ``faceanim view`` page with the avatar moving live (:mod:`faceanim.live.viewer`).

A sink takes each :class:`~faceanim.live.performer.LiveSample` (``send``) and is closed once
(``close``). Network sinks send to a resolved address and never wait: a datagram that cannot be
sent (no route, nobody listening) is counted and said once on stderr, and the run goes on.
"""

from __future__ import annotations

import socket
from abc import ABC, abstractmethod
import sys
import uuid
from pathlib import Path

import numpy as np

from faceanim.errors import FaceAnimError, shown
from faceanim.standards.arkit import ARKIT_NAMES, EYE_NAMES, HEAD_NAMES
from faceanim.live.performer import LiveSample

SCHEMES = ("vmc", "livelink", "csv", "viewer")
MAX_SUBJECT = 64


class Sink(ABC):
    """A destination of live samples (see the module docstring)."""

    label = "sink"

    @abstractmethod
    def send(self, sample: LiveSample) -> None:
        """Take one frame (never waiting on the receiver)."""

    def close(self) -> Path | None:
        """Finish; a file sink returns the file it wrote."""
        return None


def _address(spec: str, scheme: str, default_port: int) -> tuple[int, tuple]:
    rest = spec[len(scheme) + 3:]
    host, sep, port = rest.rpartition(":") if ":" in rest else (rest, "", "")
    if not sep:
        host, port = rest, str(default_port)
    host = host.strip("[]")
    if not host or "/" in host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise FaceAnimError(f"--to {scheme}:// needs HOST:PORT (port 1-65535), as in "
                            f"{scheme}://127.0.0.1:{default_port}")
    try:
        infos = socket.getaddrinfo(host, int(port), type=socket.SOCK_DGRAM)
    except (socket.gaierror, UnicodeError):
        raise FaceAnimError(f"--to {scheme}://: the host '{shown(host, 60)}' is not known; give an IP address "
                            "or a name this machine can resolve") from None
    family, _, _, _, addr = sorted(infos, key=lambda i: i[0] != socket.AF_INET)[0]  # IPv4 first
    return family, addr


class UdpSink(Sink):
    """Datagrams to one address; failures counted and said once."""

    def __init__(self, family, addr, label: str):
        self.addr, self.label = addr, label
        self.sock = socket.socket(family, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        self.sent = self.failed = 0

    def _send(self, data: bytes) -> None:
        try:
            self.sock.sendto(data, self.addr)
            self.sent += 1
        except OSError as exc:  # no route, the receiver gone (ICMP refused), a full buffer
            if not self.failed:
                reason = exc.strerror or type(exc).__name__
                print(f"faceanim live: {self.label}: cannot send ({reason.lower()}); going on", file=sys.stderr)
            self.failed += 1

    def close(self) -> None:
        self.sock.close()


class VmcSink(UdpSink):
    """``vmc://HOST:PORT``: one OSC bundle per frame (:func:`faceanim.io.vmc.encode_frame`), the
    52 curves by their perfect-sync names."""

    def __init__(self, spec: str):
        from faceanim.extras import require
        from faceanim.io.vmc import DEFAULT_PORT

        require("pythonosc", "faceanim live --to vmc://")
        family, addr = _address(spec, "vmc", DEFAULT_PORT)
        super().__init__(family, addr, f"vmc://{addr[0]}:{addr[1]}")

    def send(self, sample: LiveSample) -> None:
        from faceanim.io.vmc import encode_frame

        self._send(encode_frame(dict(zip(ARKIT_NAMES, sample.arkit.tolist())), tuple(sample.head), sample.time))


class LiveLinkSink(UdpSink):
    """``livelink://HOST:PORT``: one Live Link Face packet per frame, subject ``subject``, frame
    numbers at the source's ``fps``."""

    def __init__(self, spec: str, subject: str, fps: float):
        from faceanim.io.livelink import DEFAULT_PORT

        family, addr = _address(spec, "livelink", DEFAULT_PORT)
        super().__init__(family, addr, f"livelink://{addr[0]}:{addr[1]}")
        self.subject, self.fps = subject, float(fps)
        self.device = str(uuid.uuid5(uuid.NAMESPACE_URL, f"faceanim:{subject}")).upper()  # stable per subject

    def send(self, sample: LiveSample) -> None:
        from faceanim.io.livelink import encode_packet

        values = dict(zip(ARKIT_NAMES, sample.arkit.tolist()))
        values.update(zip(HEAD_NAMES, sample.head.tolist()))
        values.update(zip(EYE_NAMES, sample.eyes.tolist()))
        f = sample.time * self.fps
        self._send(encode_packet(values, int(np.floor(f + 1e-9)), self.fps, self.subject, self.device,
                                 float(f - np.floor(f + 1e-9))))


FILE_SUFFIXES = (".csv", ".tsv", ".json", ".glb")  # what a run is written to (faceanim.export.WRITERS)


class FileSink(Sink):
    """``file:PATH`` (or ``csv:PATH``): every sample kept; on close, resampled to ``fps`` on the
    samples' own times and written by PATH's suffix through the export registry
    (:data:`faceanim.export.WRITERS`): .csv a Live Link Face CSV, .tsv/.json Rhubarb Lip Sync's
    mouth cues (naming ``sound_name``, the run's clip or sound, when set), .glb the default face with
    its ARKit shapes, the curves and the head animated."""

    def __init__(self, spec: str, fps: float):
        scheme, _, rest = spec.partition(":")
        self.path = Path(rest)
        self.label = f"{scheme.lower()}:{shown(self.path, 60, tail=True)}"
        suffix = self.path.suffix.lower()
        if scheme.lower() == "csv" and (not rest or suffix != ".csv"):
            raise FaceAnimError("--to csv:PATH needs a .csv path, as in csv:take.csv")
        if not rest or suffix not in FILE_SUFFIXES:
            raise FaceAnimError(f"--to file:PATH needs a path ending in {', '.join(FILE_SUFFIXES)}, as in "
                                "file:take.glb")
        self.fps = float(fps)
        self.sound_name = ""
        self.times, self.rows = [], []

    def send(self, sample: LiveSample) -> None:
        self.times.append(sample.time)
        self.rows.append(np.r_[sample.arkit, sample.head, sample.eyes])

    def close(self) -> Path | None:
        from faceanim.export import Animation, write

        if not self.rows:
            return None
        t, rows = np.array(self.times), np.array(self.rows)
        grid = np.arange(int(np.floor((t[-1] - t[0]) * self.fps + 1e-9)) + 1) / self.fps + t[0]
        r = np.stack([np.interp(grid, t, c) for c in rows.T], axis=1)
        n = len(ARKIT_NAMES)
        face = None
        if self.path.suffix.lower() == ".glb":
            from faceanim.face.face import Face

            face = Face.load("default")
        a = Animation(self.fps, arkit=np.clip(r[:, :n], 0.0, 1.0), head=r[:, n:n + 3], eyes=r[:, n + 3:], face=face,
                      name="live", sound_name=self.sound_name)
        return write(self.path, a)[0]


KINDS = "vmc://HOST:PORT, livelink://HOST:PORT, file:PATH (.csv .tsv .json .glb) or viewer[:PORT]"


def parse_sinks(specs: list[str], fps: float, subject: str, face=None) -> list[Sink]:
    """The sinks of ``--to`` values (each checked before anything starts: scheme, address, path;
    the viewer, which starts its servers, last). ``face``: the avatar the viewer shows (a .glb or
    .vrm; the default face with ARKit's shapes if None)."""
    if not specs:
        raise FaceAnimError(f"give at least one --to ({KINDS})")
    if not subject or len(subject.encode("utf-8")) > MAX_SUBJECT or not subject.isprintable():
        raise FaceAnimError(f"--subject must be 1 to {MAX_SUBJECT} printable characters")
    sinks, viewers = [], []
    for spec in specs:
        scheme = spec.split(":", 1)[0].lower() if ":" in spec else spec.lower()
        if scheme == "vmc" and spec.lower().startswith("vmc://"):
            sinks.append(VmcSink(spec))
        elif scheme == "livelink" and spec.lower().startswith("livelink://"):
            sinks.append(LiveLinkSink(spec, subject, fps))
        elif scheme in ("csv", "file") and not spec.lower().startswith(("csv://", "file://")):
            sinks.append(FileSink(spec, fps))
        elif scheme == "viewer" and (spec == "viewer" or spec[6:7] == ":"):
            viewers.append(spec)
        else:
            raise FaceAnimError(f"--to '{shown(spec, 60)}' is not a sink; give {KINDS}")
    if len(viewers) > 1:
        raise FaceAnimError("give --to viewer once (one page serves any number of browsers)")
    if viewers:
        from faceanim.live.viewer import ViewerSink

        sinks.append(ViewerSink(viewers[0], face))
    return sinks
