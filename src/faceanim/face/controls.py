"""The expression control parameters of Chai, Xiao & Hodgins (2003, section 2.2) on a face's
fronto-parallel features: the geometry the video analysis (:mod:`faceanim.drivers.video.tracking`)
and the motion database (:mod:`faceanim.build.motion`) share, so that a performer's video and the
motion capture data speak the same 15 numbers.

Features are (19, 2) points in the face's own frame (x the face's left, y up, metres), in the
order of :data:`FEATURE_NAMES`; a control vector is (15,) in the order of :data:`CONTROL_NAMES`.
"""

from __future__ import annotations

import numpy as np

# the 19 tracked features of the paper's figure 3, as MediaPipe landmarks (L/R: the face's own);
# the lips' mid-points are taken on their outer line: on the inner line they meet when the mouth
# closes, and the tilt of the segment between them is then noise
FEATURES = {
    "mouth_corner_R": 61, "mouth_corner_L": 291, "upper_lip": 0, "lower_lip": 17,
    "brow_inner_R": 105, "brow_outer_R": 70, "brow_inner_L": 334, "brow_outer_L": 300,
    "eye_outer_R": 33, "eye_inner_R": 133, "eye_upper_R": 159, "eye_lower_R": 145,
    "eye_outer_L": 263, "eye_inner_L": 362, "eye_upper_L": 386, "eye_lower_L": 374,
    "nose_tip": 4, "nostril_R": 98, "nostril_L": 327,
}
FEATURE_NAMES = tuple(FEATURES)
# the 15 control parameters: name -> the neutral face's length a change of it is measured in
# (4.1: the performer's own mouth, nose, eyes and brows, so that a performer with a small mouth and
# the motion database's subject give the same numbers for the same expression), or "degrees"
CONTROLS = {
    "mouth_open": "mouth_width", "mouth_width": "mouth_width", "mouth_centre_x": "mouth_width",
    "mouth_centre_y": "mouth_width", "lips_tilt": "degrees", "corners_tilt": "degrees",
    "nose_width": "nose_width", "nose_height": "nose_width",
    "eye_open_R": "eye_width_R", "eye_open_L": "eye_width_L",
    "brow_tilt_R": "degrees", "brow_tilt_L": "degrees", "brow_raise_R": "eye_width_R", "brow_raise_L": "eye_width_L",
    "brow_gap": "brow_gap",
}
CONTROL_NAMES = tuple(CONTROLS)


def _angle(v: np.ndarray, reference: np.ndarray) -> float:
    return float(np.degrees(np.arctan2(reference[0] * v[1] - reference[1] * v[0], reference @ v)))


def control_parameters(features: np.ndarray) -> np.ndarray:
    """(15,) control parameters of one frame's fronto-parallel features ((19, 2), x the face's
    left, y up), in the order of :data:`CONTROL_NAMES`."""
    f = {n: features[k] for k, n in enumerate(FEATURE_NAMES)}
    up, left = np.array([0.0, 1.0]), np.array([1.0, 0.0])
    lips = f["upper_lip"] - f["lower_lip"]
    corners = f["mouth_corner_L"] - f["mouth_corner_R"]
    centre = (f["upper_lip"] + f["lower_lip"] + f["mouth_corner_L"] + f["mouth_corner_R"]) / 4
    nostrils = f["nostril_L"] - f["nostril_R"]
    mid = (f["nostril_L"] + f["nostril_R"]) / 2
    nose_dir = nostrils / max(float(np.linalg.norm(nostrils)), 1e-12)
    tip = f["nose_tip"] - mid
    nose_height = abs(tip[0] * nose_dir[1] - tip[1] * nose_dir[0])  # distance to the nostrils' line
    out = [np.linalg.norm(lips), np.linalg.norm(corners), centre[0], centre[1],
           _angle(lips, up), _angle(corners, left),
           np.linalg.norm(nostrils), nose_height,
           np.linalg.norm(f["eye_upper_R"] - f["eye_lower_R"]), np.linalg.norm(f["eye_upper_L"] - f["eye_lower_L"])]
    for side, sign in (("R", -1.0), ("L", 1.0)):  # a brow's tilt: its outer end up is positive
        brow = f[f"brow_outer_{side}"] - f[f"brow_inner_{side}"]
        out.append(_angle(brow * np.array([sign, 1.0]), left))
    for side in ("R", "L"):
        eye = (f[f"eye_upper_{side}"] + f[f"eye_lower_{side}"] + f[f"eye_inner_{side}"] + f[f"eye_outer_{side}"]) / 4
        brow = (f[f"brow_inner_{side}"] + f[f"brow_outer_{side}"]) / 2
        out.append(brow[1] - eye[1])
    out.append(np.linalg.norm(f["brow_inner_L"] - f["brow_inner_R"]))
    return np.array(out, dtype=np.float64)


def reference_lengths(features: np.ndarray) -> dict[str, float]:
    """The lengths of a (neutral) face that its control parameters are measured in."""
    f = {n: features[k] for k, n in enumerate(FEATURE_NAMES)}
    return {"mouth_width": float(np.linalg.norm(f["mouth_corner_L"] - f["mouth_corner_R"])),
            "nose_width": float(np.linalg.norm(f["nostril_L"] - f["nostril_R"])),
            "eye_width_R": float(np.linalg.norm(f["eye_outer_R"] - f["eye_inner_R"])),
            "eye_width_L": float(np.linalg.norm(f["eye_outer_L"] - f["eye_inner_L"])),
            "brow_gap": float(np.linalg.norm(f["brow_inner_L"] - f["brow_inner_R"]))}


def normalise(raw: np.ndarray, neutral_raw: np.ndarray, neutral_features: np.ndarray) -> np.ndarray:
    """Section 4.1: each control parameter's change from the neutral frame, in units of the neutral
    face's own length for it (its mouth width, nose width, eye width, brow gap; degrees for
    angles). 0 is the neutral face; ``mouth_open`` 0.5 is a mouth opened by half its width."""
    ref = reference_lengths(neutral_features)
    scale = np.array([1.0 if CONTROLS[n] == "degrees" else max(ref[CONTROLS[n]], 1e-12) for n in CONTROL_NAMES])
    return (raw - neutral_raw) / scale


# the neutral face (4.1), found the same way in a video and in a motion database: the frames that
# look at the camera (within this many degrees of yaw and pitch) ...
NEUTRAL_MAX_TURN = 15.0
# ... with the mouth among this fraction of the most closed
NEUTRAL_CLOSED_QUANTILE = 0.3


def _neutral_rows(raw: np.ndarray, pose: np.ndarray, usable: np.ndarray):
    ok = usable & (np.abs(pose[:, 0]) < NEUTRAL_MAX_TURN) & (np.abs(pose[:, 1]) < NEUTRAL_MAX_TURN)
    if not ok.any():
        ok = usable
    if not ok.any():
        from faceanim.errors import LandmarkError

        raise LandmarkError("no face was found in any frame; give a video where the face is lit, sharp and large")
    rows = np.flatnonzero(ok)
    typical = np.median(raw[rows], axis=0)  # eyes, brows, nose: as the clip usually has them
    spread = np.median(np.abs(raw[rows] - typical), axis=0) + 1e-9
    opening = raw[rows, 0] / np.maximum(raw[rows, 1], 1e-12)
    closed = rows[opening <= np.quantile(opening, NEUTRAL_CLOSED_QUANTILE)]
    mouth = [CONTROL_NAMES.index(n) for n in CONTROL_NAMES if n.startswith(("mouth", "lips", "corners"))]
    typical[mouth] = np.median(raw[closed][:, mouth], axis=0)  # the mouth: as it is when closed
    return closed, typical, spread


def typical_controls(raw: np.ndarray, pose: np.ndarray, usable: np.ndarray) -> np.ndarray:
    """(15,) the performer's typical face, the reference the controls are measured from: each raw
    control's median over the usable frames that look at the camera, the mouth's over those among
    them with the mouth most closed (a clip may smile or talk most of the time). A median over the
    clip is steadier than any one frame (a neutral frame caught mid-blink or with the head bowed
    would offset every frame of the eyes)."""
    return _neutral_rows(raw, pose, usable)[1]


def find_neutral(raw: np.ndarray, pose: np.ndarray, usable: np.ndarray) -> int:
    """The neutral frame: among the usable frames looking at the camera (all usable frames if
    none does) with the mouth among the most closed, the one nearest the typical face
    (:func:`typical_controls`; scaled by the spread). Its features give the lengths the controls
    are measured in."""
    closed, typical, spread = _neutral_rows(raw, pose, usable)
    return int(closed[np.argmin((((raw[closed] - typical) / spread) ** 2).sum(axis=1))])
