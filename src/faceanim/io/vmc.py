"""The VMC protocol (Virtual Motion Capture, OSC over UDP): what VSeeFace, VNyan, Warudo and
VMagicMirror receive from a face tracker.

A frame is one OSC bundle (python-osc builds and parses it): ``/VMC/Ext/OK 1`` (a model is loaded),
``/VMC/Ext/T`` (the sender's time, seconds), ``/VMC/Ext/Bone/Pos "Head" px py pz qx qy qz qw``
(the head's rotation as a quaternion in Unity's left-handed frame: x right, y up, z forward, the
avatar facing +z), then ``/VMC/Ext/Blend/Val name value`` for every curve and
``/VMC/Ext/Blend/Apply``, which makes the receiver show the values together. The blend names are
ARKit's 52 as "perfect sync" avatars name their clips (``EyeBlinkLeft`` ... ``TongueOut``).
Receivers listen on port 39539 by default.

:func:`encode_frame` builds a frame's datagram, :func:`decode_frame` reads one back (the tests'
receiver, and a check of what a sender sent).
"""

from __future__ import annotations

import math
import struct

import numpy as np

from faceanim.errors import InputFileError

DEFAULT_PORT = 39539
MAX_BLENDS = 512  # blend values a frame may carry (ARKit's 52 and a VRM's presets are far fewer)


def head_quaternion(yaw: float, pitch: float, roll: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of the head's rotation in Unity's frame from faceanim's angles (radians; yaw
    turns the head to its own left, pitch nods it down, roll tilts it to its right): Unity's
    rotations about y, x and z applied as its ``Quaternion.Euler`` does (z, then x, then y),
    with the signs of its left-handed frame (a turn to the avatar's own left is negative about y,
    a nod down positive about x, a tilt to its right negative about z)."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_euler("YXZ", [-yaw, pitch, -roll]).as_quat()
    return tuple(float(x) for x in q)


def encode_frame(blends: dict[str, float], head: tuple[float, float, float], time: float) -> bytes:
    """One frame's datagram: ``blends`` {name: value} (in the given order), ``head`` (yaw, pitch,
    roll, radians), ``time`` in seconds."""
    from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
    from pythonosc.osc_message_builder import OscMessageBuilder

    def message(address: str, *args) -> object:
        m = OscMessageBuilder(address=address)
        for a in args:
            m.add_arg(a)
        return m.build()

    b = OscBundleBuilder(IMMEDIATELY)
    b.add_content(message("/VMC/Ext/OK", 1))
    b.add_content(message("/VMC/Ext/T", float(time)))
    b.add_content(message("/VMC/Ext/Bone/Pos", "Head", 0.0, 0.0, 0.0, *head_quaternion(*head)))
    for name, value in blends.items():
        b.add_content(message("/VMC/Ext/Blend/Val", str(name), float(value)))
    b.add_content(message("/VMC/Ext/Blend/Apply"))
    return b.build().dgram


def decode_frame(data: bytes) -> dict:
    """Read one datagram: {"ok": int, "time": float, "bones": {name: (7,)}, "blends": {name:
    value} in the order sent, "applied": bool (an Apply came after the values)}. Anything that is
    not an OSC packet, a VMC message with the wrong arguments or a non-finite number is refused
    with an :class:`InputFileError`."""
    from pythonosc import osc_bundle, osc_message
    from pythonosc.osc_bundle import OscBundle
    from pythonosc.osc_message import OscMessage
    from pythonosc.parsing import osc_types

    broken = (osc_types.ParseError, osc_message.ParseError, osc_bundle.ParseError, IndexError, ValueError, TypeError,
              struct.error, UnicodeDecodeError, OverflowError)

    out = {"ok": None, "time": None, "bones": {}, "blends": {}, "applied": False}
    try:
        if OscBundle.dgram_is_bundle(data):
            contents = list(OscBundle(data))
        else:
            contents = [OscMessage(data)]
    except broken:
        raise InputFileError("a VMC datagram that is not an OSC packet") from None
    messages = []
    for c in contents:
        if isinstance(c, OscBundle):
            messages.extend(m for m in c if isinstance(m, OscMessage))
        else:
            messages.append(c)
    if len(messages) > MAX_BLENDS + 8:
        raise InputFileError(f"a VMC datagram with {len(messages)} messages; at most {MAX_BLENDS + 8}")
    for m in messages:
        a = list(m.params)
        numbers = [x for x in a if isinstance(x, float)]
        if any(not math.isfinite(x) for x in numbers):
            raise InputFileError("a VMC message carries a number that is not finite")
        if m.address == "/VMC/Ext/OK" and a and isinstance(a[0], int):
            out["ok"] = a[0]
        elif m.address == "/VMC/Ext/T" and len(a) == 1 and isinstance(a[0], float):
            out["time"] = a[0]
        elif m.address == "/VMC/Ext/Bone/Pos" and len(a) == 8 and isinstance(a[0], str) \
                and all(isinstance(x, float) for x in a[1:]):
            out["bones"][a[0]] = np.array(a[1:])
        elif m.address == "/VMC/Ext/Blend/Val" and len(a) == 2 and isinstance(a[0], str) and isinstance(a[1], float):
            out["blends"][a[0]] = a[1]
            out["applied"] = False
        elif m.address == "/VMC/Ext/Blend/Apply":
            out["applied"] = True
        elif m.address.startswith("/VMC/"):
            raise InputFileError("a VMC message with unexpected arguments")
    return out
