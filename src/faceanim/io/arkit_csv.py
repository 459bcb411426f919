"""Live Link Face CSV takes: Apple ARKit's 52 blendshape curves with head and eye angles.

Epic's Live Link Face app (iPhone, ARKit face tracking) records one row per sample: a
``Timecode`` (``HH:MM:SS:FF.fff``, FF.fff counting the app's 60 frames per second), a
``BlendShapeCount`` and then named columns: the 52 ARKit blendshape weights (``EyeBlinkLeft`` ..
``TongueOut``, usually in [0, 1]), ``HeadYaw``, ``HeadPitch``, ``HeadRoll`` and the eyes' yaw,
pitch and roll. Columns are found by name, in any order; extra columns are ignored.

:func:`read_arkit_csv` checks the file (missing columns, non-numeric or non-finite cells, time
going backwards, absurd sizes: one line naming the line and column) and returns the take on its
own sample times; :meth:`ArkitTake.resample` puts it on a uniform frame rate. The names, their orders and their
ICT FaceKit counterparts are :mod:`faceanim.standards.arkit`'s.
"""

from __future__ import annotations

import csv
import os
import re
from dataclasses import dataclass

import numpy as np

from faceanim.errors import InputFileError, shown
from faceanim.io.files import check_input_file
from faceanim.limits import MAX_FRAMES
from faceanim.standards.arkit import ARKIT_NAMES, EYE_NAMES, HEAD_NAMES, ict_name

TIMECODE_RATE = 60.0  # the app's timecode frames per second
MAX_BYTES = 512 * 2**20  # a take of this size is hours long: refuse before reading
MAX_GAP = 10.0  # seconds between two samples: more is two recordings in one file
WEIGHT_RANGE = (-1.0, 2.0)  # blendshape weights beyond these are not a face's (within, clamped to [0, 1])
MAX_ANGLE = 360.0  # |head or eye angle| (radians by ARKit's convention; degrees would stay within too)
TIMECODE = re.compile(r"^(\d{1,2}):(\d{2}):(\d{2}):(\d{1,3}(?:\.\d+)?)$")
PATH_SHOWN = 80


@dataclass
class ArkitTake:
    """A recorded take: ``times`` (F,) seconds from the first sample, ``weights`` (F, 52) in
    :data:`ARKIT_NAMES` order (clamped to [0, 1]), ``head`` (F, 3) yaw, pitch, roll and ``eyes``
    (F, 6) as recorded (the app does not state the unit; radians by ARKit's convention)."""

    times: np.ndarray
    weights: np.ndarray
    head: np.ndarray
    eyes: np.ndarray
    source: str = ""

    @property
    def n_samples(self) -> int:
        return len(self.times)

    @property
    def duration(self) -> float:
        return float(self.times[-1] - self.times[0]) if len(self.times) else 0.0

    def resample(self, fps: float) -> ArkitTake:
        """The take on a uniform grid of ``fps`` frames per second (linear interpolation; a
        dropped sample is bridged)."""
        n = int(np.floor(self.duration * fps + 1e-6)) + 1
        t = np.arange(n) / fps

        def lerp(a):
            return np.stack([np.interp(t, self.times, col) for col in a.T], axis=1)

        return ArkitTake(t, lerp(self.weights), lerp(self.head), lerp(self.eyes), self.source)

    def ict_curves(self) -> tuple[list[str], np.ndarray]:
        """The weights as curves of the ICT shape names: (names, (F, 53)); TongueOut is dropped."""
        names, cols = [], []
        for k, a in enumerate(ARKIT_NAMES):
            for n in ict_name(a):
                names.append(n)
                cols.append(self.weights[:, k])
        order = np.argsort(names)
        return [names[i] for i in order], np.stack(cols, axis=1)[:, order]


def _timecode(text: str, where: str) -> float:
    m = TIMECODE.match(text.strip())
    if not m:  # shown only if written with a timecode's characters (a file's other content is not echoed)
        said = f" '{text.strip()}'" if re.fullmatch(r"[0-9:.]{1,24}", text.strip()) else ""
        raise InputFileError(f"{where}: the timecode{said} is not HH:MM:SS:FF.fff")
    h, mi, s = int(m.group(1)), int(m.group(2)), int(m.group(3))
    frames = float(m.group(4))
    if mi > 59 or s > 59 or frames >= TIMECODE_RATE:
        raise InputFileError(f"{where}: timecode '{shown(text)}' is out of range")
    return h * 3600 + mi * 60 + s + frames / TIMECODE_RATE


def read_arkit_csv(path: str | os.PathLike) -> ArkitTake:
    """Read a Live Link Face CSV take (see the module docstring)."""
    p = check_input_file(path, "ARKit take", "a Live Link Face CSV")
    name = shown(p, PATH_SHOWN, tail=True)
    if p.stat().st_size > MAX_BYTES:
        raise InputFileError(f"ARKit take '{name}' is {p.stat().st_size / 2**20:.0f} MiB; give at most "
                             f"{MAX_BYTES // 2**20} MiB (split the take)")
    try:
        with open(p, newline="", encoding="utf-8-sig") as fh:  # a BOM (Excel, the app on Windows) is skipped
            rows = csv.reader(fh)
            header = next(rows, None)
            if not header:
                raise InputFileError(f"ARKit take '{name}' is empty; give a Live Link Face CSV")
            header = [h.strip() for h in header]
            need = ("Timecode", *ARKIT_NAMES, *HEAD_NAMES, *EYE_NAMES)
            missing = [n for n in need if n not in header]
            if missing:
                raise InputFileError(f"ARKit take '{name}' lacks the column(s) {', '.join(missing[:4])}"
                                     + (" ..." if len(missing) > 4 else "") + "; give a Live Link Face CSV")
            col = {n: header.index(n) for n in need}
            numeric = [col[n] for n in (*ARKIT_NAMES, *HEAD_NAMES, *EYE_NAMES)]
            times, values = [], []
            for line, row in enumerate(rows, start=2):
                if not row or all(not c.strip() for c in row):
                    continue
                if len(times) >= MAX_FRAMES:
                    raise InputFileError(f"ARKit take '{name}' has more than {MAX_FRAMES} samples; split the take")
                where = f"ARKit take '{name}' line {line}"
                if len(row) < len(header):
                    raise InputFileError(f"{where}: {len(row)} cells for {len(header)} columns (a truncated row)")
                if len(row) > len(header) and any(c.strip() for c in row[len(header):]):
                    raise InputFileError(f"{where}: {len(row)} cells for {len(header)} columns (a cell with no "
                                         "column: a damaged or hand-edited row); fix the row or re-export the take")
                times.append(_timecode(row[col["Timecode"]], where))
                try:
                    v = [float(row[i]) for i in numeric]
                except ValueError:
                    bad = next(header[i] for i in numeric if not _is_float(row[i]))
                    raise InputFileError(f"{where}: column {shown(bad)} is not a number") from None
                if not np.all(np.isfinite(v)):
                    raise InputFileError(f"{where}: NaN or infinite value")
                nb = len(ARKIT_NAMES)
                lo, hi = WEIGHT_RANGE
                bad = next((i for i in range(len(v)) if (not lo <= v[i] <= hi if i < nb else abs(v[i]) > MAX_ANGLE)),
                           None)
                if bad is not None:
                    column = header[numeric[bad]]
                    limit = f"{lo:g} to {hi:g}" if bad < nb else f"-{MAX_ANGLE:g} to {MAX_ANGLE:g}"
                    raise InputFileError(f"{where}: column {shown(column)} is {v[bad]:.3g}, outside {limit}")
                values.append(v)
    except UnicodeDecodeError:
        raise InputFileError(f"ARKit take '{name}' is not text (UTF-8); give a Live Link Face CSV") from None
    except csv.Error:
        raise InputFileError(f"ARKit take '{name}' is not a readable CSV file") from None
    if len(times) < 2:
        raise InputFileError(f"ARKit take '{name}' has {len(times)} sample(s); give at least 2")
    t = np.array(times)
    t = np.where(t < t[0] - 12 * 3600, t + 24 * 3600, t)  # a take running past midnight
    if np.any(np.diff(t) < 0):
        k = int(np.flatnonzero(np.diff(t) < 0)[0])
        raise InputFileError(f"ARKit take '{name}': time goes backwards after sample {k + 1}; is it two takes?")
    if np.any(np.diff(t) > MAX_GAP):
        k = int(np.flatnonzero(np.diff(t) > MAX_GAP)[0])
        raise InputFileError(f"ARKit take '{name}': time jumps {np.diff(t)[k]:.0f} s after sample {k + 1}; is it "
                             "two takes? (split it)")
    # repeated timecodes (the app writes its first sample twice): keep the first
    keep = np.r_[True, np.diff(t) > 0]
    v = np.array(values)[keep]
    t = t[keep] - t[keep][0]
    if len(t) < 2:
        raise InputFileError(f"ARKit take '{name}' has all its samples at one time; give a recording")
    nb = len(ARKIT_NAMES)
    return ArkitTake(t, np.clip(v[:, :nb], 0.0, 1.0), v[:, nb:nb + 3], v[:, nb + 3:], str(p))


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def write_arkit_csv(path: str | os.PathLike, weights: np.ndarray, fps: float, head: np.ndarray | None = None,
                    eyes: np.ndarray | None = None):
    """Write a take as Live Link Face CSV (what :func:`read_arkit_csv`, Unreal's importer and
    spreadsheet users read): ``weights`` (F, 52) in :data:`ARKIT_NAMES` order, ``head`` (F, 3)
    yaw, pitch, roll in radians (zeros if None), ``eyes`` (F, 6) the left and the right eye's yaw,
    pitch, roll in radians (zeros if None), timecodes from 00:00:00:00."""
    from pathlib import Path

    from faceanim.errors import FaceAnimError
    from faceanim.io.files import atomic_output

    w = np.asarray(weights, dtype=np.float64)
    h = np.zeros((len(w), 3)) if head is None else np.asarray(head, dtype=np.float64)
    e = np.zeros((len(w), 6)) if eyes is None else np.asarray(eyes, dtype=np.float64)
    if w.ndim != 2 or w.shape[1] != len(ARKIT_NAMES) or h.shape != (len(w), 3) or e.shape != (len(w), 6) \
            or len(w) < 1:
        raise FaceAnimError(f"an ARKit take needs (F, {len(ARKIT_NAMES)}) weights, (F, 3) head and (F, 6) eye angles")
    if not (np.all(np.isfinite(w)) and np.all(np.isfinite(h)) and np.all(np.isfinite(e)) and 0 < fps <= 1000):
        raise FaceAnimError("an ARKit take needs finite weights and head angles and a frame rate in (0, 1000]")
    # as written (6 decimals), with no negative zeros: a weight of -1e-17 from a solver's last bit
    # would print as -0.000000 on one machine and 0.000000 on another
    w, h, e = np.round(w, 6) + 0.0, np.round(h, 6) + 0.0, np.round(e, 6) + 0.0
    with atomic_output(path, "ARKit take") as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        out = csv.writer(fh, lineterminator="\n")  # LF, as the app writes its takes
        out.writerow(["Timecode", "BlendShapeCount", *ARKIT_NAMES, *HEAD_NAMES, *EYE_NAMES])
        for i in range(len(w)):
            t = i / fps
            s = int(np.floor(t + 1e-9))
            frames = (t - s) * TIMECODE_RATE
            code = f"{s // 3600:02d}:{s // 60 % 60:02d}:{s % 60:02d}:{frames:06.3f}"
            out.writerow([code, str(len(ARKIT_NAMES) + len(HEAD_NAMES) + len(EYE_NAMES)),
                          *[f"{x:.6f}" for x in w[i]], *[f"{x:.6f}" for x in h[i]],
                          *(f"{x:.6f}" if x else "0" for x in e[i])])
    return Path(path)
