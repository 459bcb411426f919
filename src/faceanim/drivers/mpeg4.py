"""High-level actions and their blending (Lee et al. 1999, sections 3.1-3.2).

An action is a named FAP set (an emotion, a viseme, a user expression) played with an intensity,
a start, a duration and an envelope: ``linear`` (attack, sustain, release as straight ramps),
``smooth`` (the same with cosine ramps) or ``peak`` (no sustain: up to the middle, down again).
Several actions active at once combine per FAP by the paper's weighted blending,

    FAP_final(t) = sum_i w_i(t) I_i FAP_i(t) / sum_i w_i(t),

where FAP_i(t) = envelope_i(t) * FAP_i and the weighting curve w_i(t) = weight_i * envelope_i(t)
is smallest where an action starts and ends, so starting or ending actions never jump. The
weight sets priorities: a plosive's lip closure outweighs a surprised open mouth.

A :class:`FapStream` (the curves every MPEG-4 driver produces) is frames x 68 values with a mask of
which FAPs each frame sets, plus the fields of the two high-level FAPs.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources

import numpy as np

from faceanim.face.faps import N_FAPS, FapError, fap


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


ENVELOPES = ("linear", "smooth", "peak")


@lru_cache(maxsize=1)
def viseme_table() -> dict:
    return json.loads(resources.files("faceanim").joinpath("data", "visemes.json").read_text())


def fap_set(spec: dict) -> dict[int, float]:
    """{FAP name or number: value} -> {FAP number: value}, checked against the FAP table."""
    out = {}
    for key, value in spec.items():
        f = fap(key)
        if f.is_high_level:
            raise FapError(f"FAP {f.number} ({f.name}) cannot be part of an action's FAP set")
        v = float(value)
        if not np.isfinite(v):
            raise FapError(f"FAP {f.name}: value {value!r} is not a finite number")
        out[f.number] = v
    return out


def expression_faps(name: str) -> dict[int, float]:
    """The FAP set of an MPEG-4 expression (joy, sadness, anger, fear, disgust, surprise)."""
    for d in viseme_table()["expressions"].values():
        if d["name"] == name:
            return fap_set(d["faps"])
    names = [d["name"] for d in viseme_table()["expressions"].values()]
    raise FapError(f"unknown expression '{name}'; choose one of: {', '.join(names)}")


@dataclass
class Action:
    """A FAP set played over time."""

    name: str
    faps: dict[int, float]
    start: float
    duration: float
    intensity: float = 1.0
    envelope: str = "smooth"
    attack: float = 0.25  # fraction of the duration spent rising (linear, smooth)
    release: float = 0.25  # fraction spent falling
    weight: float = 1.0
    extra: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.envelope not in ENVELOPES:
            raise FapError(f"action '{self.name}': unknown envelope '{self.envelope}'; choose one of "
                           f"{', '.join(ENVELOPES)}")
        if not np.isfinite(self.duration) or self.duration <= 0:
            raise FapError(f"action '{self.name}': the duration must be positive, got {self.duration}")
        if not (0 <= self.attack <= 1 and 0 <= self.release <= 1 and self.attack + self.release <= 1):
            raise FapError(f"action '{self.name}': attack and release are fractions of the duration "
                           "that add up to at most 1")
        if not np.isfinite(self.intensity) or not np.isfinite(self.weight) or self.weight < 0:
            raise FapError(f"action '{self.name}': intensity must be finite and weight >= 0")

    @property
    def end(self) -> float:
        return self.start + self.duration

    def envelope_at(self, t: np.ndarray) -> np.ndarray:
        """The envelope in [0, 1] at times ``t`` (0 outside the action)."""
        x = (np.asarray(t, dtype=np.float64) - self.start) / self.duration
        inside = (x >= 0) & (x <= 1)
        if self.envelope == "peak":
            up, down = x / 0.5, (1 - x) / 0.5
        else:
            up = x / self.attack if self.attack > 0 else np.ones_like(x)
            down = (1 - x) / self.release if self.release > 0 else np.ones_like(x)
        e = np.clip(np.minimum(up, down), 0.0, 1.0)
        if self.envelope in ("smooth", "peak"):
            e = 0.5 - 0.5 * np.cos(np.pi * e)
        return np.where(inside, e, 0.0)


def blend_actions(actions: list[Action], n_frames: int, fps: float, name: str = "faceanim") -> FapStream:
    """Sample actions to a FAP stream with the paper's weighted blending."""
    if n_frames < 1:
        raise FapError("a FAP stream needs at least one frame")
    t = np.arange(n_frames) / fps
    num = np.zeros((n_frames, N_FAPS))
    den = np.zeros((n_frames, N_FAPS))
    for a in actions:
        env = a.envelope_at(t)
        if not env.any():
            continue
        w = a.weight * env
        for n, v in a.faps.items():
            num[:, n - 1] += w * a.intensity * env * v
            den[:, n - 1] += w
    mask = den > 1e-12
    values = np.divide(num, den, out=np.zeros_like(num), where=mask)
    return FapStream(values, mask, fps, name)
