"""MPEG-4 Face and Body Animation's tables (ISO/IEC 14496-2, ``docs/mpeg4-fba.md`` of the shared docs):
the 68 face animation parameters (``data/faps.json``: number, name, FAPU unit, bidirectional, positive
direction in the face's own frame, group, the feature points each moves, the pivot for rotations,
quantiser step), the high-level FAPs' fields (visemes, expressions), the FAPU names and the feature
points' definitions (``data/fdp.json``: faceanim's mapping from MediaPipe's 478 landmarks). Plain
tables, read once; what they do to a face is :mod:`faceanim.face.faps` and :mod:`faceanim.face.fdp`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

from typing import TYPE_CHECKING

from faceanim.errors import FaceAnimError

if TYPE_CHECKING:
    import numpy as np

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
    import numpy as np

    return np.asarray(_table()[0]["direction_vectors"][f.direction], dtype=np.float64)



@lru_cache(maxsize=1)
def fdp_spec() -> dict:
    """The feature points' definitions (``data/fdp.json``): each point's landmarks, the missing ones."""
    return json.loads(resources.files("faceanim").joinpath("data", "fdp.json").read_text())
