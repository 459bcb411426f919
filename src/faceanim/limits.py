"""Ranges every input is checked against before anything is allocated.

A few small numbers on a command line (``--fps 1e9``, ``--size 100000``, a scene that repeats a
blink every 0.3 s for 1e9 s) would otherwise ask for terabytes. Each limit is far above what a
real use needs and far below what exhausts a machine of a few GB; the CLI's help states them.
"""

from __future__ import annotations

import math

from faceanim.errors import FaceAnimError

DEFAULT_FPS = 25.0  # the one default frame rate of every animation (MPEG-4's usual 25 fps)
MAX_FPS = 240.0  # frames per second of any animation or video
MIN_IMAGE_SIZE = 16  # pixels per side of a render
MAX_IMAGE_SIZE = 4096
MAX_DURATION = 3600.0  # seconds of animation (one hour)
MAX_FRAMES = 200_000  # frames of one animation (an hour at 55 fps; a glTF of a 30k face at 200k frames
#                       is already ~24 MB of weights alone)
MAX_GRID = 500  # vertices per side of a resampling grid (250,000 vertices; the thesis uses 150)
MAX_VIDEO_SIZE = 2048  # pixels per side of an MP4 (PNGs may be up to MAX_IMAGE_SIZE)
MAX_VIDEO_PIXELS = 6e10  # frames x width x height of one video (512 x 512 for 200,000 frames, 4096 x 4096
#                          for 3,500): past this an MP4 takes many hours to render
MAX_ACTIONS = 100_000  # actions on one timeline (visemes, blinks, expressions)
MAX_NESTING = 8  # groups inside groups in a scene script
MAX_TEXT = 10_000  # characters of text to speak
MAX_FACE_VERTICES = 1_000_000  # vertices of a face to rig or animate: memory grows about 10 kB per
#                                vertex (rig of every set: 0.9 GB at 46k, 2.3 GB at 183k, 4.2 GB at
#                                400k; benchmarks/bench_rig_scale.py)
MAX_MESH_VERTICES = 5_000_000  # vertices of any mesh read (an OBJ parses into Python lists first)
MAX_SAMPLE_RATE = 192_000  # samples per second of audio in or out (the highest common studio rate;
#                             an hour of it is 2.8 GB of float32 mono)


class LimitError(FaceAnimError):
    """A number outside the range faceanim accepts."""


def check_range(value, name: str, low: float, high: float, *, integer: bool = False,
                low_inclusive: bool = True) -> float:
    """``value`` as a float (or int) if it is finite and within [low, high]; else a LimitError
    that names the option and the range."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise LimitError(f"{name} must be a number, got '{value}'") from None
    if not math.isfinite(v):
        raise LimitError(f"{name} must be a finite number, got {value}")
    below = v < low if low_inclusive else v <= low
    if below or v > high:
        lo = f"at least {low:g}" if low_inclusive else f"more than {low:g}"
        raise LimitError(f"{name} must be {lo} and at most {high:g}, got {v:g}")
    if integer:
        if v != int(v):
            raise LimitError(f"{name} must be a whole number, got {v:g}")
        return int(v)
    return v


def check_fps(fps, name: str = "--fps") -> float:
    return check_range(fps, name, 0.0, MAX_FPS, low_inclusive=False)


def check_size(size, name: str = "--size") -> int:
    return check_range(size, name, MIN_IMAGE_SIZE, MAX_IMAGE_SIZE, integer=True)


def check_frames(n, name: str = "frames") -> int:
    return check_range(n, name, 1, MAX_FRAMES, integer=True)


def check_video(frames: int, width: int, height: int) -> None:
    """Refuse a video larger than ``MAX_VIDEO_SIZE`` per side (H.264 at 4096 px takes ffmpeg
    3.5 GB) or whose frames x pixels would take many hours (``MAX_VIDEO_PIXELS``)."""
    if max(width, height) > MAX_VIDEO_SIZE:
        raise LimitError(f"a video frame of {width}x{height} pixels is larger than faceanim encodes "
                         f"({MAX_VIDEO_SIZE} per side); lower --size")
    if frames * width * height > MAX_VIDEO_PIXELS:
        raise LimitError(f"{frames} frames of {width}x{height} pixels is more video than faceanim renders in one go "
                         f"({MAX_VIDEO_PIXELS:.0e} frame pixels); lower --size or the number of frames")
