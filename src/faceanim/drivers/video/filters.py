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
    if not (np.isfinite(fps) and fps > 0 and min_cutoff > 0 and beta >= 0 and d_cutoff > 0):
        raise FaceAnimError("One-Euro filter: fps and cutoffs must be positive, beta >= 0")
    if len(x) == 0:
        return x.copy()
    if not np.all(np.isfinite(x)):
        raise FaceAnimError("One-Euro filter: the samples must be finite")

    def alpha(cutoff):
        tau = 1.0 / (2 * np.pi * cutoff)
        return 1.0 / (1.0 + tau * fps)

    out = np.empty_like(x)
    out[0] = x[0]
    speed = np.zeros_like(x[0])
    a_d = alpha(d_cutoff)
    for t in range(1, len(x)):
        speed = a_d * (x[t] - out[t - 1]) * fps + (1 - a_d) * speed
        a = alpha(min_cutoff + beta * np.abs(speed))
        out[t] = a * x[t] + (1 - a) * out[t - 1]
    return out
