"""ASCII .fap files: read and write FAP streams.

    # comment lines start with '#'
    2.1 <name> <fps> <number of frames>
    <mask line: 68 integers 0/1, one per FAP>
    <value line: frame number, then the values of the FAPs whose mask bit is 1, in FAP order>
    ... one mask line and one value line per frame ...

FAP 1 (viseme) contributes 4 numbers and FAP 2 (expression) 6 to a value line when set; every
other FAP one integer. The reader takes real-world files: comments and blank lines anywhere,
trailing spaces, Windows line ends, a name with spaces (a path), frames that set only some FAPs.
A malformed file is refused with its line number. Values are written as whole FAPU units, as the
format has them; writing then reading a stream of whole values gives the same stream.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

import numpy as np

from faceanim.errors import FaceAnimError, InputFileError
from faceanim.face.faps import FapStream
from faceanim.standards.mpeg4 import N_FAPS
from faceanim.io.files import atomic_output
from faceanim.limits import MAX_DURATION, MAX_FPS, MAX_FRAMES

VERSION = "2.1"


# a FAP value is a whole number of FAPU units; the largest real ones are head rotations
# (2 pi rad = 628318 angle units). Anything beyond this is a broken file, not an animation.
MAX_FAP_VALUE = 1e7
# frame numbers and the integer fields of FAPs 1 and 2 (viseme, expression) are stored as int64
MAX_FIELD = 2**31 - 1
MAX_FAP_BYTES = 1 << 30  # 1 GiB: far above MAX_FRAMES frames of 68 values


def _show(token: str) -> str:
    """A token of the file as an error message names it (with a leading space): only when written as a number
    (short, digits, sign, point, exponent); anything else is described, never shown (a file that is
    no .fap at all may hold anything, and its content is not echoed)."""
    if len(token) <= 24 and re.fullmatch(r"[0-9eE.+-]+|[+-]?(?i:nan|inf|infinity)", token):
        return f" '{token}'"
    return ""


def _number(token: str, path, line_no: int, what: str) -> float:
    try:
        value = float(token)
    except ValueError:
        raise InputFileError(f"{path}:{line_no}: {what}{_show(token)} is not a number") from None
    if not math.isfinite(value):
        raise InputFileError(f"{path}:{line_no}: {what}{_show(token)} is not a finite number")
    return value


def _whole(value: float, token: str, path, line_no: int, what: str, low: float, high: float) -> int:
    if value != int(value) or not low <= value <= high:
        raise InputFileError(f"{path}:{line_no}: {what}{_show(token)} must be a whole number from "
                             f"{int(low)} to {int(high)}")
    return int(value)


def parse_fap(text: str, path: str = "<fap>") -> FapStream:
    """A FAP stream from the text of an ASCII .fap file.

    Refused with the line number: a missing or short header; a frame rate that is not a number,
    not above 0 or above ``limits.MAX_FPS``; a frame count that is not whole, below 1 or above
    ``limits.MAX_FRAMES`` (checked before anything is allocated); NUL bytes; bad mask lines;
    values that are not finite numbers or beyond ``MAX_FAP_VALUE``; frame numbers and FAP 1/2
    fields that are not whole numbers in int32 range.
    """
    nul = text.find("\0")
    if nul >= 0:
        raise InputFileError(f"{path}:{text.count(chr(10), 0, nul) + 1}: NUL byte: this is not a text .fap "
                             "file")
    lines = [(n, raw.strip()) for n, raw in enumerate(text.split("\n"), start=1)]
    lines = [(n, s) for n, s in lines if s and not s.startswith("#")]
    if not lines:
        raise InputFileError(f"{path}: no header; a .fap file starts with '2.1 <name> <fps> <frames>'")
    n0, header = lines[0]
    tokens = header.split()
    if len(tokens) < 4:
        raise InputFileError(f"{path}:{n0}: the header needs '<version> <name> <fps> <frames>', "
                             f"got {len(tokens)} field(s)")
    fps = _number(tokens[-2], path, n0, "the frame rate")
    count = _number(tokens[-1], path, n0, "the frame count")
    if fps <= 0:
        raise InputFileError(f"{path}:{n0}: the frame rate must be positive, got{_show(tokens[-2])}")
    if fps > MAX_FPS:
        raise InputFileError(f"{path}:{n0}: the frame rate {fps:g} is above faceanim's limit of {MAX_FPS:g} fps")
    if count != int(count) or count < 0:
        raise InputFileError(f"{path}:{n0}: the frame count must be a whole number, got{_show(tokens[-1])}")
    if count > MAX_FRAMES:
        raise InputFileError(f"{path}:{n0}: the header promises {count:g} frames, more than faceanim's limit "
                             f"of {MAX_FRAMES}")
    if count / fps > MAX_DURATION:
        raise InputFileError(f"{path}:{n0}: {count:g} frames at {fps:g} fps last {count / fps:.3g} s, more than "
                             f"faceanim's limit of {MAX_DURATION:g} s; check the frame rate in the header")
    count = int(count)
    name = " ".join(tokens[1:-2])
    body = lines[1:]
    if count == 0 and not body:
        raise InputFileError(f"{path}:{n0}: the file has no frames; a .fap file needs at least one")
    if len(body) % 2:
        n, _ = body[-1]
        raise InputFileError(f"{path}:{n}: a mask line without its value line (each frame has both)")
    frames = len(body) // 2
    if frames != count:
        where = body[-1][0] if body else n0
        raise InputFileError(f"{path}:{where}: the header promises {count} frames but the file has {frames}")
    values = np.zeros((count, N_FAPS))
    mask = np.zeros((count, N_FAPS), dtype=bool)
    viseme = np.zeros((count, 4), dtype=np.int64)
    expression = np.zeros((count, 6), dtype=np.int64)
    numbers = np.zeros(count, dtype=np.int64)
    for k in range(count):
        (nm, mask_line), (nv, value_line) = body[2 * k], body[2 * k + 1]
        bits = mask_line.split()
        if len(bits) != N_FAPS:
            raise InputFileError(f"{path}:{nm}: a mask line needs {N_FAPS} bits (one per FAP), got {len(bits)}")
        if any(b not in ("0", "1") for b in bits):
            raise InputFileError(f"{path}:{nm}: mask bits must be 0 or 1")
        m = np.array([b == "1" for b in bits])
        tokens = value_line.split()
        expected = 1 + int(m.sum()) + (3 if m[0] else 0) + (5 if m[1] else 0)
        if len(tokens) != expected:
            raise InputFileError(f"{path}:{nv}: the mask on line {nm} sets {int(m.sum())} FAPs, so this line "
                                 f"needs {expected} numbers (frame number first), got {len(tokens)}")
        nums = [_number(t, path, nv, "value") for t in tokens]
        numbers[k] = _whole(nums[0], tokens[0], path, nv, "the frame number", 0, MAX_FIELD)
        pos = 1
        if m[0]:
            viseme[k] = [_whole(x, t, path, nv, "a viseme field", 0, MAX_FIELD)
                         for x, t in zip(nums[pos:pos + 4], tokens[pos:pos + 4])]
            pos += 4
        if m[1]:
            expression[k] = [_whole(x, t, path, nv, "an expression field", 0, MAX_FIELD)
                             for x, t in zip(nums[pos:pos + 6], tokens[pos:pos + 6])]
            pos += 6
        for x, t in zip(nums[pos:], tokens[pos:]):
            if abs(x) > MAX_FAP_VALUE:
                raise InputFileError(f"{path}:{nv}: value{_show(t)} is beyond +-{MAX_FAP_VALUE:g} FAPU units; "
                                     "check the file")
        rest = np.flatnonzero(m[2:]) + 2
        values[k, rest] = nums[pos:]
        mask[k] = m
    try:
        return FapStream(values, mask, fps, name, viseme, expression, numbers)
    except FaceAnimError as exc:
        raise InputFileError(f"{path}: {exc}") from None


def read_fap(path: str | os.PathLike) -> FapStream:
    """Read an ASCII .fap file (UTF-8 text; see :func:`parse_fap` for what is refused)."""
    p = Path(path)
    if not p.is_file():
        if p.is_dir():
            raise InputFileError(f".fap file '{p}' is a folder; give a .fap file")
        raise InputFileError(f".fap file '{p}' does not exist; check the path")
    try:
        if p.stat().st_size > MAX_FAP_BYTES:
            raise InputFileError(f".fap file '{p}' is larger than {MAX_FAP_BYTES >> 20} MiB; that is not a "
                                 "FAP animation faceanim can play")
        data = p.read_bytes()
    except OSError as exc:
        raise InputFileError(f"cannot read '{p}': {exc.strerror or 'read error'}") from None
    nul = data.find(b"\0")
    if nul >= 0:
        line = data.count(b"\n", 0, nul) + 1
        raise InputFileError(f"{p}:{line}: NUL byte: this is not a text .fap file")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise InputFileError(f"{p}:{line}: not UTF-8 text; save the .fap file as UTF-8 (or ASCII)") from None
    text = text.removeprefix("\ufeff")  # a byte-order mark from a Windows editor
    return parse_fap(text, str(p))


def _fmt(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else repr(float(x))


def format_fap(stream: FapStream, integers: bool = True) -> str:
    """The text of an ASCII .fap file for ``stream``: FAP values rounded to whole FAPU units as
    the format has them (``integers=False`` keeps fractions, which only faceanim reads back)."""
    name = stream.name.strip() or "faceanim"
    out = [f"{VERSION} {name} {_fmt(stream.fps)} {stream.n_frames}"]
    for k in range(stream.n_frames):
        m = stream.mask[k]
        out.append(" ".join("1" if b else "0" for b in m))
        nums = [str(int(stream.frame_numbers[k]))]
        if m[0]:
            nums += [str(int(x)) for x in stream.viseme[k]]
        if m[1]:
            nums += [str(int(x)) for x in stream.expression[k]]
        values = stream.values[k, np.flatnonzero(m[2:]) + 2]
        nums += [_fmt(x) for x in (np.rint(values) if integers else values)]
        out.append(" ".join(nums))
    return "\n".join(out) + "\n"


def write_fap(path: str | os.PathLike, stream: FapStream, integers: bool = True) -> Path:
    """Write ``stream`` as an ASCII .fap file (atomically); see :func:`format_fap`."""
    with atomic_output(path) as tmp:
        Path(tmp).write_text(format_fap(stream, integers), encoding="utf-8")
    return Path(path)
