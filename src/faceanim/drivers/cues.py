"""Mouth cues (Rhubarb Lip Sync's shapes A-H, X) from timed phones or from ARKit curves.

From phones (``say``): each phone's shape from :data:`~faceanim.standards.rhubarb.PHONE_SHAPES`
over its time, as Rhubarb itself maps the phones it hears.

From ARKit curves (``perform``: a performer's mouth on video), frame by frame, by what the curves
show: the lips' opening (``jawOpen - mouthClose``) and rounding (``mouthFunnel``, ``mouthPucker``
above the take's own at rest):
shut -> A (X when shut for :data:`REST_AFTER` seconds or more: a pause), rounded -> F when nearly
closed, E when open; else by the opening: B, C, D (:data:`OPEN_C`, :data:`OPEN_D`). G (teeth on
lip) and H (tongue) are not given from video: the tracked landmarks show neither teeth nor tongue.
"""

from __future__ import annotations

import numpy as np

from faceanim.errors import FaceAnimError
from faceanim.standards.rhubarb import FIRST_PART, PHONE_SHAPES

SHUT = 0.06  # jawOpen - mouthClose under this: the lips are together
# chosen on say's own curves of five English sentences against their phones' shapes
# (scripts/eval_cues.py: 67% of 10 ms steps agree there, 69% on five other sentences)
OPEN_C, OPEN_D = 0.22, 0.30  # openings from which the mouth is open (C) and wide open (D)
ROUNDED = 0.4  # rounding above the take's own at rest (its 10th percentile) from which the lips are rounded
PUCKERED_BELOW = 0.2  # a rounded mouth opened less than this is puckered (F), more slightly rounded (E)
REST_AFTER = 0.3  # seconds: a closed mouth held this long is at rest (X), shorter it is a closure (A)


def phone_cues(phones) -> list[tuple[float, str]]:
    """(start seconds, shape) per phone (a diphthong's two shapes), in time order."""
    cues = []
    for p in sorted(phones, key=lambda p: p.start):
        shapes = PHONE_SHAPES.get(p.phone.upper().rstrip("012"), "B")  # an unknown sound: a consonant's mouth
        cues.append((p.start, shapes[0]))
        if len(shapes) > 1:
            cues.append((p.start + FIRST_PART * (p.end - p.start), shapes[1]))
    return cues


def arkit_cues(curves: np.ndarray, names: list[str], fps: float) -> list[tuple[float, str]]:
    """(start seconds, shape) per frame of ARKit ``curves`` (frames x names; Apple's names, any
    case), classified as the module says."""
    key = {n.lower(): k for k, n in enumerate(names)}
    missing = [n for n in ("jawopen", "mouthclose", "mouthfunnel", "mouthpucker") if n not in key]
    if missing:
        raise FaceAnimError(f"the curves have no {', '.join(missing)}; mouth cues need ARKit's mouth curves")
    c = np.asarray(curves, dtype=np.float64)
    opening = c[:, key["jawopen"]] - c[:, key["mouthclose"]]
    rounding = np.maximum(c[:, key["mouthfunnel"]], c[:, key["mouthpucker"]])
    rounding = rounding - np.percentile(rounding, 10)  # a performer's lips at rest may be pursed a little
    shape = np.where(opening >= OPEN_D, "D", np.where(opening >= OPEN_C, "C", "B")).astype(object)
    rounded = rounding >= ROUNDED
    shape[rounded] = np.where(opening[rounded] < PUCKERED_BELOW, "F", "E")
    shut = opening < SHUT
    shape[shut] = "A"
    run_start = 0
    for k in range(1, len(c) + 1):  # long closures are rest
        if k == len(c) or shut[k] != shut[run_start]:
            if shut[run_start] and (k - run_start) / fps >= REST_AFTER:
                shape[run_start:k] = "X"
            run_start = k
    return [(k / fps, str(s)) for k, s in enumerate(shape)]
