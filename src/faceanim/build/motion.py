"""Facial motion capture from recorded ARKit takes (Chai, Xiao & Hodgins 2003, section 3): markers.

The paper records 76 reflective markers on a real face. We have real facial motion as ARKit
curves (Live Link Face takes, :mod:`faceanim.io.arkit_csv`) and a head that has all of ARKit's
shapes (the generic head, ICT FaceKit): playing a take on the head and reading the positions of
76 marker vertices spread over its face gives marker trajectories driven by real motion, which the
rest of the paper's pipeline takes like real markers.

- :func:`marker_vertices`: the paper's 19 tracked features (so that the control parameters of
  the video analysis can be read off the markers) and more skin vertices of the face chosen by
  farthest-point sampling, 76 in all, deterministic.
- :func:`play_take`: (F, 76, 3) marker positions of a take on the head: rest + the ICT shapes
  weighted by the curves, turned by the recorded (or a given) head rotation about the head's pivot.
"""

from __future__ import annotations

import numpy as np

from faceanim.errors import FaceAnimError
from faceanim.face.generic_head import GenericHead
from faceanim.face.regions import face_region

N_MARKERS = 76  # as the paper's motion capture
# the 19 features of the video analysis (drivers.video.tracking.FEATURES), as MediaPipe landmarks:
# copied here as data because build may not import drivers; tests check they agree
FEATURE_LANDMARKS = (61, 291, 0, 17, 105, 70, 334, 300, 33, 133, 159, 145, 263, 362, 386, 374, 4, 98, 327)


def marker_vertices(head: GenericHead, n: int = N_MARKERS) -> np.ndarray:
    """(n,) skin vertices of the head's face used as motion capture markers: the vertices at the
    19 tracked features first, then farthest-point samples of the face region."""
    if not len(FEATURE_LANDMARKS) <= n <= 2000:
        raise FaceAnimError(f"markers: give {len(FEATURE_LANDMARKS)} to 2000, got {n}")
    mesh = head.mesh
    lm = head.landmarks()
    skin = np.zeros(mesh.n_vertices, bool)
    skin[head.parts["skin"]] = True
    region = face_region(mesh, lm) & skin
    cand = np.flatnonzero(region)
    chosen = []
    for i in FEATURE_LANDMARKS:
        corners = mesh.faces[head.landmark_triangles[i]]
        chosen.append(int(corners[np.argmax(head.landmark_barycentric[i])]))
    chosen = list(dict.fromkeys(chosen))  # in order, no repeats
    d = np.min(np.linalg.norm(mesh.vertices[cand][:, None] - mesh.vertices[chosen][None], axis=2), axis=1)
    while len(chosen) < n:
        k = int(np.argmax(d))
        chosen.append(int(cand[k]))
        d = np.minimum(d, np.linalg.norm(mesh.vertices[cand] - mesh.vertices[cand[k]], axis=1))
    return np.array(chosen, dtype=np.int64)


def head_rotation(yaw, pitch, roll) -> np.ndarray:
    """(F, 3, 3) head rotations Ry(yaw) Rx(pitch) Rz(roll) (radians; head coordinates: x the
    head's left, y up, z forward): yaw turns the head to its own left, pitch nods it down, roll
    tilts it to its right (the video analysis uses the same angles)."""
    yaw, pitch, roll = (np.atleast_1d(np.asarray(a, dtype=np.float64)) for a in (yaw, pitch, roll))
    cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    z, o = np.zeros_like(yaw), np.ones_like(yaw)
    ry = np.stack([np.stack([cy, z, sy], -1), np.stack([z, o, z], -1), np.stack([-sy, z, cy], -1)], -2)
    rx = np.stack([np.stack([o, z, z], -1), np.stack([z, cp, -sp], -1), np.stack([z, sp, cp], -1)], -2)
    rz = np.stack([np.stack([cr, -sr, z], -1), np.stack([sr, cr, z], -1), np.stack([z, z, o], -1)], -2)
    return ry @ rx @ rz


def play_take(head: GenericHead, names: list[str], curves: np.ndarray, markers: np.ndarray,
              rotation: np.ndarray | None = None, pivot: np.ndarray | None = None) -> np.ndarray:
    """(F, P, 3) marker positions: the head's rest + sum of its shapes ``names`` weighted by
    ``curves`` (F, C), then turned by ``rotation`` (F, 3, 3) about ``pivot`` (default: the
    midpoint between the ears at the eyes' height, behind the face)."""
    curves = np.asarray(curves, dtype=np.float64)
    unknown = [n for n in names if n not in head.shape_names]
    if unknown:
        raise FaceAnimError(f"the head has no shape {unknown[0]}; its shapes are ARKit's (ICT names)")
    if curves.ndim != 2 or curves.shape[1] != len(names) or not np.all(np.isfinite(curves)):
        raise FaceAnimError(f"curves must be finite (frames, {len(names)}), got shape {curves.shape}")
    rest = head.mesh.vertices[markers]
    basis = np.stack([head.shape(n)[markers] for n in names])  # (C, P, 3)
    pos = rest[None] + np.einsum("fc,cpd->fpd", curves, basis)
    if rotation is not None:
        if pivot is None:
            lm = head.landmarks()
            pivot = np.array([0.0, lm[[33, 263], 1].mean(), head.mesh.vertices[head.parts["skin"], 2].mean()])
        pos = np.einsum("fij,fpj->fpi", rotation, pos - pivot) + pivot
    return pos
