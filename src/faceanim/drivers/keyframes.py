"""Control curves over time: key frames, interpolation and sampling to an (F, C) matrix.

Key-frame interpolation between expressions (seed paper section 3) is done per control with a
monotone cubic (PCHIP): it passes through every key, eases in and out, and never overshoots, so
weights between keys in [0, 1] stay in [0, 1]. ``'linear'`` is available too.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PchipInterpolator

from faceanim.errors import FaceAnimError

INTERPOLATIONS = ("smooth", "linear")


@dataclass
class KeyframeAnimation:
    """Key frames ``(time, {control: weight})``; controls absent from a key are 0 there."""

    controls: list[str]
    times: np.ndarray  # (K,)
    values: np.ndarray  # (K, C)
    interpolation: str = "smooth"

    @classmethod
    def from_keys(cls, controls: Sequence[str], keys: Sequence[tuple[float, Mapping[str, float]]],
                  interpolation: str = "smooth") -> KeyframeAnimation:
        if interpolation not in INTERPOLATIONS:
            raise FaceAnimError(f"unknown interpolation '{interpolation}'; choose {', '.join(INTERPOLATIONS)}")
        if not keys:
            raise FaceAnimError("an animation needs at least one key frame")
        controls = list(controls)
        times = np.array([float(t) for t, _ in keys])
        if not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
            raise FaceAnimError("key frame times must be finite and strictly increasing")
        values = np.zeros((len(keys), len(controls)))
        for k, (_, w) in enumerate(keys):
            unknown = set(w) - set(controls)
            if unknown:
                raise FaceAnimError(f"key {k} names unknown control(s): {', '.join(sorted(unknown))}")
            for c, v in w.items():
                values[k, controls.index(c)] = float(v)
        return cls(controls, times, values, interpolation)

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def at(self, t) -> np.ndarray:
        """Control weights (F, C) at times ``t`` (held constant before the first/after the last key)."""
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=np.float64)), self.times[0], self.times[-1])
        if len(self.times) == 1:
            return np.repeat(self.values, len(t), axis=0)
        if self.interpolation == "linear":
            return np.stack([np.interp(t, self.times, self.values[:, c]) for c in range(len(self.controls))], 1)
        return PchipInterpolator(self.times, self.values, axis=0)(t)

    def sample(self, fps: float) -> tuple[np.ndarray, np.ndarray]:
        """Frame times (F,) from 0 to the last key at ``fps`` and the weights (F, C) there."""
        if not fps > 0:
            raise FaceAnimError(f"fps must be positive, got {fps}")
        n = int(round(self.duration * fps)) + 1
        t = np.arange(n) / fps
        return t, self.at(t)


def expression_tour(controls: Sequence[str], rise: float = 0.6, hold: float = 0.5,
                    fall: float = 0.6, rest: float = 0.3, interpolation: str = "smooth") -> KeyframeAnimation:
    """Neutral -> each expression in turn -> neutral, as key frames."""
    keys: list[tuple[float, dict]] = [(0.0, {})]
    t = rest
    for c in controls:
        keys.append((t, {}))
        keys.append((t + rise, {c: 1.0}))
        keys.append((t + rise + hold, {c: 1.0}))
        t += rise + hold + fall
        keys.append((t, {}))
        t += rest
    keys.append((t, {}))
    return KeyframeAnimation.from_keys(controls, keys, interpolation)
