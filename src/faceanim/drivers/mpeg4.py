"""High-level actions and their blending (Lee et al. 1999, sections 3.1-3.2).

An action is a named FAP set (an emotion, a viseme, a user expression) played with an intensity,
a start, a duration and an envelope: ``linear`` (attack, sustain, release as straight ramps),
``smooth`` (the same with cosine ramps) or ``peak`` (no sustain: up to the middle, down again).
Several actions active at once combine per FAP by the paper's weighted blending,

    FAP_final(t) = sum_i w_i(t) I_i FAP_i(t) / sum_i w_i(t),

where FAP_i(t) = envelope_i(t) * FAP_i and the weighting curve w_i(t) = weight_i * envelope_i(t)
is smallest where an action starts and ends, so starting or ending actions never jump. The
weight sets priorities: a plosive's lip closure outweighs a surprised open mouth.

Every MPEG-4 driver produces a :class:`~faceanim.face.faps.FapStream`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources

import numpy as np

from faceanim.face.faps import FapStream
from faceanim.standards.mpeg4 import N_FAPS, FapError, fap

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
    additive: bool = False  # added over the weighted blend of the others (a layer), not blended with them

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
    """Sample actions to a FAP stream with the paper's weighted blending; ``additive`` actions (a
    layer such as the voice's slow head rise) are added over the blend of the others."""
    if n_frames < 1:
        raise FapError("a FAP stream needs at least one frame")
    num = np.zeros((n_frames, N_FAPS))
    den = np.zeros((n_frames, N_FAPS))
    layer = np.zeros((n_frames, N_FAPS))  # additive actions' sum
    layered = np.zeros((n_frames, N_FAPS), dtype=bool)
    for a in actions:
        # only the frames inside the action (its envelope is 0 elsewhere): time ~ total action length
        lo = max(0, int(np.floor(a.start * fps)))
        hi = min(n_frames, int(np.ceil(a.end * fps)) + 1)
        if hi <= lo:
            continue
        env = a.envelope_at(np.arange(lo, hi) / fps)
        if not env.any():
            continue
        cols = np.array([n - 1 for n in a.faps], dtype=np.int64)
        vals = np.array(list(a.faps.values()), dtype=np.float64)
        if a.additive:
            layer[lo:hi, cols] += (a.intensity * env)[:, None] * vals[None]
            layered[lo:hi, cols] |= (env > 0)[:, None]
            continue
        w = a.weight * env
        num[lo:hi, cols] += (w * a.intensity * env)[:, None] * vals[None]
        den[lo:hi, cols] += w[:, None]
    blended = den > 1e-12
    values = np.divide(num, den, out=np.zeros_like(num), where=blended) + layer
    return FapStream(values, blended | layered, fps, name)
