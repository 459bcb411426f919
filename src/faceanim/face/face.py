"""The Face: a mesh plus its landmarks."""

from __future__ import annotations

import numpy as np

from faceanim.deform.rbf import landmark_tps
from faceanim.errors import LandmarkError
from faceanim.face.landmarks import BASIC22, Landmarks
from faceanim.face.mesh import Mesh


def landmarks_478(mesh: Mesh, landmarks: Landmarks) -> np.ndarray:
    """All 478 MediaPipe landmark positions on ``mesh``.

    Taken directly when ``landmarks`` has them; from the basic 22 by a landmark thin-plate
    spline from faceanim's default face (thesis 5.6.1) and snapping onto ``mesh`` otherwise.
    """
    where = {int(i): k for k, i in enumerate(landmarks.indices)}
    if all(i in where for i in range(478)):
        return landmarks.positions[[where[i] for i in range(478)]]
    need = [i for _, i in BASIC22]
    missing = [n for n, i in BASIC22 if i not in where]
    if missing:
        raise LandmarkError(
            f"action units need the 478 MediaPipe landmarks or the basic 22; missing: {', '.join(missing[:6])}"
            + (" ..." if len(missing) > 6 else "") + " (run `faceanim landmarks` on the mesh)")
    from faceanim.face.default import default_face

    ref = default_face(dense=False).vertices[:478]
    tps = landmark_tps(ref[need], landmarks.positions[[where[i] for i in need]], "basic 22 landmarks")
    moved = tps(ref)
    pos, _, _ = mesh.closest_points(moved)
    return pos
