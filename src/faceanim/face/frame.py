"""A face's own frame from its landmarks, and rigid alignment of two point sets."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from faceanim.errors import LandmarkError
from faceanim.face.landmarks import CHIN, EYE_OUTER_CORNERS, MOUTH_CORNERS, NOSE_TIP


# ---------------------------------------------------------------------------- face geometry
@dataclass(frozen=True)
class FaceFrame:
    """A face's own frame from landmarks: origin at the nose tip, x towards the subject's left
    eye, y up, z forward; its inter-ocular distance and mouth width (the thesis' s_t, s_s)."""

    origin: np.ndarray
    rotation: np.ndarray  # rows: x, y, z axes in mesh coordinates
    iod: float
    mouth_width: float

    def to_local(self, points: np.ndarray) -> np.ndarray:
        return (np.asarray(points) - self.origin) @ self.rotation.T

    def vectors_to_local(self, vectors: np.ndarray) -> np.ndarray:
        return np.asarray(vectors) @ self.rotation.T

    def vectors_to_mesh(self, vectors: np.ndarray) -> np.ndarray:
        return np.asarray(vectors) @ self.rotation


def face_frame(lm478: np.ndarray) -> FaceFrame:
    """The frame of a face from its 478 landmarks: origin at the nose tip, x along the outer eye
    corners (to the subject's left), y from the chin up to the eyes (orthogonalised), z = x cross y;
    refused when the landmarks do not have a face's proportions or are mirrored."""
    p = np.asarray(lm478)
    eye_r, eye_l = (p[i] for i in EYE_OUTER_CORNERS)
    mouth_r, mouth_l = (p[i] for i in MOUTH_CORNERS)
    x = eye_l - eye_r
    iod = float(np.linalg.norm(x))
    mouth = float(np.linalg.norm(mouth_l - mouth_r))
    if iod <= 0 or mouth <= 0 or not np.isfinite(iod + mouth):
        raise LandmarkError("the eye corners or mouth corners coincide; the landmarks are broken")
    x = x / iod
    up = (eye_r + eye_l) / 2 - p[CHIN]
    y = up - x * (up @ x)
    height = np.linalg.norm(y)
    if not (0.2 < mouth / iod < 2.0 and 0.5 < height / iod < 4.0):
        raise LandmarkError(
            f"the landmarks do not have a face's proportions (mouth width {mouth / iod:.2f}, eyes to chin "
            f"{height / iod:.2f} inter-ocular distances); they are out of order or not for this face")
    y /= height
    z = np.cross(x, y)
    if (p[NOSE_TIP] - (eye_r + eye_l) / 2) @ z <= 0:
        raise LandmarkError("the nose tip lies behind the eyes in these landmarks: they are mirrored "
                            "(left and right swapped) or out of order")
    return FaceFrame(p[NOSE_TIP].copy(), np.stack([x, y, z]), iod, mouth)


def similarity(src: np.ndarray, dst: np.ndarray, scale: bool = True,
               weights: np.ndarray | None = None) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares ``dst ~ s * R @ src + t`` in any dimension (Umeyama 1991; Kabsch with
    ``scale=False``, s = 1), each point pair counted with its ``weights`` (all 1 by default):
    returns (s, R, t), R a proper rotation."""
    a, b = np.asarray(src, dtype=np.float64), np.asarray(dst, dtype=np.float64)
    c = np.ones(len(a)) if weights is None else np.asarray(weights, dtype=np.float64)
    c = c / c.sum()
    ms, md = c @ a, c @ b
    a, b = a - ms, b - md
    u, sv, vt = np.linalg.svd((b * c[:, None]).T @ a)
    fix = np.ones(a.shape[1])
    fix[-1] = np.sign(np.linalg.det(u @ vt))
    r = (u * fix) @ vt
    s = float((sv * fix).sum() / max(float(c @ (a ** 2).sum(1)), 1e-300)) if scale else 1.0
    return s, r, md - s * r @ ms


def rigid_align(moving: np.ndarray, fixed: np.ndarray, keep: float = 0.5,
                iterations: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R and translation t that best map ``moving`` onto ``fixed`` (Kabsch), robustly:
    after a first fit only the best-fitting ``keep`` fraction of the points is refitted, a few
    times, so skin that did move (a neck dragged by the jaw) does not tilt the skull."""
    a, b = np.asarray(moving, dtype=np.float64), np.asarray(fixed, dtype=np.float64)
    sel = np.arange(len(a))
    for it in range(iterations + 1):
        _, r, t = similarity(a[sel], b[sel], scale=False)
        if it == iterations or len(a) < 8:
            break
        res = np.linalg.norm(a @ r.T + t - b, axis=1)
        sel = np.argsort(res)[: max(4, int(keep * len(a)))]
    return r, t
