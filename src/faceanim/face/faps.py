"""FAP streams: frames x 68 MPEG-4 face animation parameters, with a mask of which FAPs each frame
sets and the fields of the two high-level FAPs (FAP 1: viseme_select1, viseme_select2,
viseme_blend, viseme_def; FAP 2: expression_select1, expression_intensity1, expression_select2,
expression_intensity2, init_face, expression_def). The standard's FAP table (numbers, names, units,
directions, feature points) is :mod:`faceanim.standards.mpeg4`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from faceanim.standards.mpeg4 import N_FAPS, FapError, fap

@dataclass
class FapStream:
    """A FAP animation: ``values`` (F, 68) in FAPU units (FAP n in column n-1), ``mask`` (F, 68)
    bool (which FAPs a frame sets), ``viseme`` (F, 4) and ``expression`` (F, 6) integer fields of
    FAPs 1 and 2, a frame rate and a name."""

    values: np.ndarray
    mask: np.ndarray
    fps: float = 25.0
    name: str = "faceanim"
    viseme: np.ndarray = field(default=None)
    expression: np.ndarray = field(default=None)
    frame_numbers: np.ndarray = field(default=None)

    def __post_init__(self):
        v = np.asarray(self.values, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != N_FAPS:
            raise FapError(f"FAP values must have shape (frames, {N_FAPS}), got {v.shape}")
        if not np.all(np.isfinite(v)):
            raise FapError("FAP values contain NaN or infinity")
        m = np.asarray(self.mask, dtype=bool)
        if m.shape != v.shape:
            raise FapError(f"the mask must have the shape of the values {v.shape}, got {m.shape}")
        if not np.isfinite(self.fps) or self.fps <= 0:
            raise FapError(f"the frame rate must be positive, got {self.fps}")
        n = len(v)
        self.viseme = np.zeros((n, 4), dtype=np.int64) if self.viseme is None else np.asarray(self.viseme, dtype=np.int64)
        self.expression = (np.zeros((n, 6), dtype=np.int64) if self.expression is None
                           else np.asarray(self.expression, dtype=np.int64))
        self.frame_numbers = (np.arange(n, dtype=np.int64) if self.frame_numbers is None
                              else np.asarray(self.frame_numbers, dtype=np.int64))
        if self.viseme.shape != (n, 4) or self.expression.shape != (n, 6) or self.frame_numbers.shape != (n,):
            raise FapError("viseme (F, 4), expression (F, 6) and frame numbers (F,) must match the frames")
        v = v.copy()
        v[:, :2] = 0.0  # FAPs 1 and 2 carry their fields in ``viseme`` and ``expression``
        self.values, self.mask = v, m

    @property
    def n_frames(self) -> int:
        return len(self.values)

    @property
    def duration(self) -> float:
        return self.n_frames / self.fps

    @classmethod
    def empty(cls, n_frames: int, fps: float = 25.0, name: str = "faceanim") -> FapStream:
        return cls(np.zeros((n_frames, N_FAPS)), np.zeros((n_frames, N_FAPS), dtype=bool), fps, name)

    def set(self, key, values, frames=None) -> None:
        """Set one FAP (number or name) on ``frames`` (default all) and mark it in the mask."""
        f = fap(key)
        if f.is_high_level:
            raise FapError(f"FAP {f.number} ({f.name}) has fields; set stream.viseme / stream.expression")
        sl = slice(None) if frames is None else frames
        self.values[sl, f.number - 1] = values
        self.mask[sl, f.number - 1] = True

    def column(self, key) -> np.ndarray:
        """The values of one FAP over the frames (0 where the mask does not set it)."""
        f = fap(key)
        return np.where(self.mask[:, f.number - 1], self.values[:, f.number - 1], 0.0)
