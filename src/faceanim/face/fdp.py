"""MPEG-4 feature points (FDP) and face animation parameter units (FAPU) on any face.

The feature points are placed from the face's 478 MediaPipe landmarks (``data/fdp.json``,
faceanim's own mapping) and snapped to its skin; the pivot of head rotation (7.1, the top of the
spine) is estimated inside the head. Points a face mesh cannot have from landmarks (tongue,
teeth, ears, the top and back of the skull) are reported as missing with the reason.

FAPU, measured on the neutral face in its own frame (x the face's left, y up, z forward):
IRISD0 = 3.1.y - 3.3.y, ES0 = 3.5.x - 3.6.x, ENS0 = 3.5.y - 9.15.y, MNS0 = 9.15.y - 2.2.y,
MW0 = 8.3.x - 8.4.x; a FAP value of 1 is FAPU0 / 1024 (translations) or 1e-5 rad (AU).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from faceanim.errors import LandmarkError
from faceanim.standards.mpeg4 import ANGLE_UNIT
from faceanim.face.frame import FaceFrame, face_frame
from faceanim.face.landmarks import CHEEK_EXTREMES
from faceanim.face.mesh import Mesh
from faceanim.face.regions import skin
from faceanim.standards.mpeg4 import fdp_spec


@dataclass
class FeaturePoints:
    """Feature points on a face: name -> position (mesh units), the missing ones with reasons,
    the face frame and the FAPU."""

    positions: dict[str, np.ndarray]
    missing: dict[str, str]
    frame: FaceFrame
    fapu: dict[str, float]

    def __getitem__(self, name: str) -> np.ndarray:
        if name in self.positions:
            return self.positions[name]
        if name in self.missing:
            raise LandmarkError(f"feature point {name} ({self.missing[name]}) is not on this face")
        raise LandmarkError(f"unknown feature point '{name}'")

    def unit(self, name: str) -> float:
        """The size of one FAP value in mesh units (or radians for AU)."""
        key = name.rstrip("0")
        if key == "AU":
            return ANGLE_UNIT
        if key not in self.fapu:
            raise LandmarkError(f"unknown FAPU '{name}'; the units are {', '.join(self.fapu)} and AU")
        return self.fapu[key] / 1024.0


# 7.1 (the top of the spine, the head's pivot) is estimated: this many inter-ocular distances behind
# and below the midpoint of the face's widest points (in front of the ears)
SPINE_BEHIND, SPINE_BELOW = 0.6, 0.9

def feature_points(mesh: Mesh, lm478: np.ndarray) -> FeaturePoints:
    """Place the MPEG-4 feature points on ``mesh`` and measure its FAPU (neutral face assumed)."""
    spec = fdp_spec()
    lm = np.asarray(lm478, dtype=np.float64)
    frame = face_frame(lm)
    names = list(spec["points"])
    target = np.stack([lm[spec["points"][n]].mean(0) for n in names])
    on_skin = skin(mesh, lm)
    pos, _, _ = mesh.closest_points(target, on_skin[mesh.faces].all(axis=1))
    positions = {n: p for n, p in zip(names, pos)}
    # the pupils sit on the eyeballs, not the skin: keep the landmarks themselves
    for n in ("3.5", "3.6"):
        positions[n] = target[names.index(n)]
    # 7.1, the top of the spine: behind the face's outline, below the eyes (an estimate)
    centre = lm[list(CHEEK_EXTREMES)].mean(0)
    positions["7.1"] = centre - frame.rotation[2] * SPINE_BEHIND * frame.iod - frame.rotation[1] * SPINE_BELOW * frame.iod
    missing = dict(spec["not_from_landmarks"])
    loc = {n: frame.to_local(p) for n, p in positions.items()}
    fapu = {
        "IRISD": abs(loc["3.1"][1] - loc["3.3"][1]),
        "ES": abs(loc["3.5"][0] - loc["3.6"][0]),
        "ENS": abs(loc["3.5"][1] - loc["9.15"][1]),
        "MNS": abs(loc["9.15"][1] - loc["2.2"][1]),
        "MW": abs(loc["8.3"][0] - loc["8.4"][0]),
    }
    bad = [k for k, v in fapu.items() if not v > 0]
    if bad:
        raise LandmarkError(f"FAPU {', '.join(bad)} is zero on this face: the landmarks are degenerate "
                            "or the face is not neutral (eyes closed?)")
    return FeaturePoints(positions, missing, frame, fapu)
