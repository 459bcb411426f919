"""The One-Euro filter (Casiez, Roussel & Vogel, CHI 2012): a low-pass filter whose cutoff rises
with the signal's speed, so that a still signal is smoothed hard (no jitter) and a moving one is
followed closely (little lag). Causal: each output uses only the samples before it.

faceanim smooths the tracked head pose with it (the tracker's rotation trembles by a few tenths of
a degree per frame; on a head that is 1 mm at the face) and the evaluation uses it as the
baseline filter the paper's data-driven filtering is measured against.
"""

from __future__ import annotations

import numpy as np

from faceanim.errors import FaceAnimError


def one_euro(x: np.ndarray, fps: float, min_cutoff: float = 1.0, beta: float = 0.007,
             d_cutoff: float = 1.0) -> np.ndarray:
    """Filter (F, ...) samples at ``fps``: cutoff ``min_cutoff + beta * |speed|`` Hz, the speed
    (units per second) itself smoothed at ``d_cutoff`` Hz. The standard parameters are the
    defaults; ``beta`` is in the signal's units (per unit of speed)."""
    x = np.asarray(x, dtype=np.float64)
    if not (np.isfinite(fps) and fps > 0):
        raise FaceAnimError("One-Euro filter: fps and cutoffs must be positive, beta >= 0")
    f = OneEuro(min_cutoff, beta, d_cutoff)
    if len(x) and not np.all(np.isfinite(x)):
        raise FaceAnimError("One-Euro filter: the samples must be finite")
    out = np.empty_like(x)
    for t in range(len(x)):
        out[t] = f(x[t], t / fps)
    return out


class OneEuro:
    """The filter one sample at a time (live input): ``f(sample, time_in_seconds)`` -> the filtered
    sample; samples may come at any (increasing) times."""

    def __init__(self, min_cutoff: float = 1.0, beta: float = 0.007, d_cutoff: float = 1.0):
        if not (min_cutoff > 0 and beta >= 0 and d_cutoff > 0 and np.isfinite([min_cutoff, beta, d_cutoff]).all()):
            raise FaceAnimError("One-Euro filter: fps and cutoffs must be positive, beta >= 0")
        self.min_cutoff, self.beta, self.d_cutoff = float(min_cutoff), float(beta), float(d_cutoff)
        self.last = None
        self.time = 0.0
        self.speed = None

    @staticmethod
    def _alpha(cutoff, dt: float):
        tau = 1.0 / (2 * np.pi * cutoff)
        return 1.0 / (1.0 + tau / dt)

    def __call__(self, sample, time: float) -> np.ndarray:
        x = np.asarray(sample, dtype=np.float64)
        if self.last is None:
            self.last, self.time, self.speed = x.copy(), float(time), np.zeros_like(x)
            return x.copy()
        dt = float(time) - self.time
        if not dt > 0:
            return self.last.copy()
        a_d = self._alpha(self.d_cutoff, dt)
        self.speed = a_d * (x - self.last) / dt + (1 - a_d) * self.speed
        a = self._alpha(self.min_cutoff + self.beta * np.abs(self.speed), dt)
        self.last = a * x + (1 - a) * self.last
        self.time = float(time)
        return self.last.copy()
