"""The 68 MPEG-4 face animation parameters as data, and FAP streams.

The table (``data/faps.json``) holds, for each FAP, its number, name, FAPU unit, whether it is
bidirectional, its positive direction in the face's own frame, its group, the feature points it
moves (the pivot for rotations) and its quantiser step. A translational FAP moves its feature
point by ``value * FAPU / 1024`` along its direction; a rotational one (unit ``AU``) turns by
``value * 1e-5`` rad.

A :class:`FapStream` is frames x 68 values with a mask of which FAPs each frame sets, plus the
fields of the two high-level FAPs: FAP 1 (viseme_select1, viseme_select2, viseme_blend,
viseme_def) and FAP 2 (expression_select1, expression_intensity1, expression_select2,
expression_intensity2, init_face, expression_def).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources

import numpy as np

from faceanim.errors import FaceAnimError

N_FAPS = 68


VISEME_FIELDS = ("viseme_select1", "viseme_select2", "viseme_blend", "viseme_def")


EXPRESSION_FIELDS = ("expression_select1", "expression_intensity1", "expression_select2",
                     "expression_intensity2", "init_face", "expression_def")


VISEMES = ("none", "p b m", "f v", "T D", "t d", "k g", "tS dZ S", "s z", "n l", "r", "A:", "e", "I", "Q", "U")


EXPRESSIONS = ("neutral", "joy", "sadness", "anger", "fear", "disgust", "surprise")


FAPU_NAMES = ("IRISD", "ES", "ENS", "MNS", "MW", "AU")


ANGLE_UNIT = 1e-5  # radians per AU


class FapError(FaceAnimError):
    """A FAP number, value or stream that breaks the MPEG-4 rules."""


@dataclass(frozen=True)
class Fap:
    number: int
    name: str
    unit: str | None
    bidirectional: bool | None
    direction: str | None
    group: int
    feature_points: tuple[str, ...]
    pivot: bool
    quantiser: int

    @property
    def is_rotation(self) -> bool:
        return self.unit == "AU"

    @property
    def is_high_level(self) -> bool:
        return self.number in (1, 2)


@lru_cache(maxsize=1)
def _table() -> tuple[dict, tuple[Fap, ...]]:
    data = json.loads(resources.files("faceanim").joinpath("data", "faps.json").read_text())
    faps = tuple(Fap(d["number"], d["name"], d["unit"], d["bidirectional"], d["direction"], d["group"],
                     tuple(d["feature_points"]), bool(d["feature_point_is_pivot"]), d["quantiser"])
                 for d in data["faps"])
    if [f.number for f in faps] != list(range(1, N_FAPS + 1)):
        raise FaceAnimError("the FAP table must list FAPs 1..68 in order")
    return data, faps


def faps() -> tuple[Fap, ...]:
    """All 68 FAPs, FAP 1 first."""
    return _table()[1]


def fap(key) -> Fap:
    """A FAP by number (1..68) or name (``open_jaw``)."""
    table = faps()
    if isinstance(key, str) and not key.strip().isdigit():
        for f in table:
            if f.name == key.strip():
                return f
        raise FapError(f"unknown FAP name '{key}'")
    try:
        n = int(key)
    except (TypeError, ValueError):
        raise FapError(f"'{key}' is not a FAP number or name") from None
    if not 1 <= n <= N_FAPS:
        raise FapError(f"unknown FAP number {n}; FAPs are numbered 1 to {N_FAPS}")
    return table[n - 1]


def direction_vector(f: Fap) -> np.ndarray:
    """The positive direction of a translational FAP in the face frame (x = the face's left)."""
    if f.is_rotation or f.direction is None:
        raise FapError(f"FAP {f.number} ({f.name}) is not a translation")
    return np.asarray(_table()[0]["direction_vectors"][f.direction], dtype=np.float64)


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
