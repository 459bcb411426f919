"""Live Link Face's UDP packets: what Epic's iPhone app sends to Unreal's Live Link (port 11111).

One datagram per frame, big-endian: a version byte (6), the device's id and the subject's name
(each an int32 byte count and UTF-8), the frame time (int32 frame number, float32 sub-frame, int32
frame rate numerator and denominator), a byte with the number of values (61) and then 61 float32:
the 52 ARKit blendshapes, the head's yaw, pitch and roll and each eye's yaw, pitch and roll
(radians), in the order of Unreal's ``EARFaceBlendShape``
(:data:`faceanim.standards.arkit.LIVE_LINK_ORDER`; the app's CSV has another column order,
:data:`~faceanim.standards.arkit.ARKIT_NAMES`: values are matched by name).

:func:`encode_packet` builds a packet and :func:`decode_packet` reads one back (the tests' receiver,
and anyone checking what a sender sent), refusing anything that is not a whole, finite packet.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

import numpy as np

from faceanim.errors import InputFileError
from faceanim.standards.arkit import LIVE_LINK_ORDER

VERSION = 6
DEFAULT_PORT = 11111


MAX_TEXT = 256  # bytes of a device id or subject name (the app's are a UUID and a short name)


@dataclass
class LiveLinkFrame:
    """One packet: ``device`` id, ``subject`` name, ``frame`` number, ``subframe`` (0..1),
    ``rate`` (numerator, denominator) and ``values`` {name: value} in
    :data:`~faceanim.standards.arkit.LIVE_LINK_ORDER`."""

    device: str
    subject: str
    frame: int
    subframe: float
    rate: tuple[int, int]
    values: dict[str, float]


def _text(s: str, what: str) -> bytes:
    b = s.encode("utf-8")
    if not b or len(b) > MAX_TEXT:
        raise ValueError(f"the Live Link {what} must be 1 to {MAX_TEXT} bytes of UTF-8")
    return struct.pack(">i", len(b)) + b


def encode_packet(values: dict[str, float], frame: int, fps: float, subject: str, device: str,
                  subframe: float = 0.0) -> bytes:
    """The packet of one frame: ``values`` by name (missing names are 0; weights as given, angles in
    radians), ``frame`` the frame number at ``fps`` (sent as a rational: 30 -> 30/1, 29.97 ->
    30000/1001)."""
    rate = (int(round(fps)), 1) if abs(fps - round(fps)) < 1e-6 else (int(round(fps * 1001)), 1001)
    row = np.array([float(values.get(n, 0.0)) for n in LIVE_LINK_ORDER], dtype=">f4")
    return (struct.pack(">B", VERSION) + _text(device, "device id") + _text(subject, "subject name")
            + struct.pack(">ifii", int(frame) & 0x7FFFFFFF, float(subframe), *rate)
            + struct.pack(">B", len(LIVE_LINK_ORDER)) + row.tobytes())


def decode_packet(data: bytes) -> LiveLinkFrame:
    """Read one packet (:func:`encode_packet`'s or the app's); a packet that is cut short, too long,
    of another version or carries a non-finite value is refused with an :class:`InputFileError`."""
    pos = 0

    def take(n: int) -> bytes:
        nonlocal pos
        if n < 0 or pos + n > len(data):
            raise InputFileError("a Live Link packet is cut short")
        out = data[pos:pos + n]
        pos += n
        return out

    (version,) = struct.unpack(">B", take(1))
    if version != VERSION:
        raise InputFileError(f"a Live Link packet of version {version}; faceanim reads version {VERSION}")
    texts = []
    for what in ("device id", "subject name"):
        (n,) = struct.unpack(">i", take(4))
        if not 0 <= n <= MAX_TEXT:
            raise InputFileError(f"a Live Link packet's {what} claims {n} bytes")
        try:
            texts.append(take(n).decode("utf-8"))
        except UnicodeDecodeError:
            raise InputFileError(f"a Live Link packet's {what} is not UTF-8") from None
    frame, subframe, num, den = struct.unpack(">ifii", take(16))
    (count,) = struct.unpack(">B", take(1))
    if count > len(LIVE_LINK_ORDER):
        raise InputFileError(f"a Live Link packet with {count} values; at most {len(LIVE_LINK_ORDER)}")
    row = np.frombuffer(take(4 * count), dtype=">f4").astype(np.float64)
    if pos != len(data):
        raise InputFileError("a Live Link packet has bytes after its last value")
    if not (np.all(np.isfinite(row)) and math.isfinite(subframe)):
        raise InputFileError("a Live Link packet carries a value that is not a finite number")
    return LiveLinkFrame(texts[0], texts[1], frame, subframe, (num, den),
                         {n: float(v) for n, v in zip(LIVE_LINK_ORDER, row)})
