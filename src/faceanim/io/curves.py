"""Control curves as CSV: one row per frame, one column per named curve (empty where unknown)."""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np

from faceanim.errors import FaceAnimError
from faceanim.io.files import atomic_output


def write_curves_csv(path: str | os.PathLike, names, values: np.ndarray, fps: float,
                     tracked: np.ndarray | None = None) -> Path:
    """Write (F, C) ``values`` named by ``names`` with a ``frame`` and a ``time`` (seconds) column
    first and, given ``tracked``, a ``tracked`` column (1/0); NaN is written as an empty cell."""
    values = np.asarray(values, dtype=np.float64)
    names = [str(n) for n in names]
    if values.ndim != 2 or values.shape[1] != len(names):
        raise FaceAnimError(f"curves must be (frames, {len(names)}), got shape {values.shape}")
    header = ["frame", "time"] + (["tracked"] if tracked is not None else []) + names
    with atomic_output(path, "curves") as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for i, row in enumerate(values):
            cells = [str(i), f"{i / fps:.6f}"]
            if tracked is not None:
                cells.append("1" if tracked[i] else "0")
            cells += ["" if not np.isfinite(v) else f"{v:.6g}" for v in row]
            w.writerow(cells)
    return Path(path)
