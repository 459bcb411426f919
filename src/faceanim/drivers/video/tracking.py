"""Video analysis (Chai, Xiao & Hodgins 2003, section 2): head pose and 15 expression control
parameters per frame of a video of a performer.

The paper tracks the head with a textured cylinder and 19 features with affine optical flow,
both initialised by hand. We track the face with MediaPipe's Face Landmarker (478 landmarks with
depth, the model shipped with faceanim; user-independent, no clicks), and then do what the paper does
with its tracks:

- **Head pose (6 DOF)**: a similarity fit (Umeyama) of the frame's 3D landmarks to the generic
  head's, on the landmarks no expression moves (forehead, nose bridge, temples), gives the
  rotation (yaw, pitch, roll in degrees: yaw positive when the head turns to its own left, pitch
  when it nods down, roll when it tilts to its right, as MPEG-4's head FAPs) and the position (the
  nose bridge in pixels, x right and y down, and the face's scale in pixels per generic-head
  metre, which grows as the head comes nearer).
- **Fronto-parallel features**: the 19 features of figure 3 (mouth corners, upper and lower lip,
  two points on each brow, four on each eye, three on the nose) with the head pose taken out
  (the paper warps the image into the fronto-parallel view; we unrotate the 3D landmarks), in
  units of the generic head (metres).
- **Control parameters (section 2.2)**: mouth 6 (lip distance, mouth width, mouth centre x and
  y, tilt of the lips' line from the vertical, tilt of the corners' line from the horizontal),
  nose 2 (nostril width, nose tip to the nostrils' line), eyes 2 (lid distances), brows 5 (tilt
  of each brow, each brow's height over its eye, distance between the brows).
- **Normalisation (4.1)**: against the performer's neutral frame, found automatically (the
  frame nearest the clip's typical face, looking at the camera) or given: each parameter's change
  from the neutral, in units of the neutral face's own mouth width, nose width, eye width or brow
  gap (the paper scales by the neutral's parameters; a closed mouth's opening is ~0, so ratios to
  it would explode), angles in degrees.

Frames where no face is found are marked (``tracked`` False, NaN values), never invented.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from faceanim.errors import LandmarkError
from faceanim.face.mediapipe import FaceMesh
from faceanim.face.controls import (  # noqa: F401 (find_neutral: part of this module's API)
    CONTROL_NAMES,
    FEATURE_NAMES,
    FEATURES,
    control_parameters,
    find_neutral,
    normalise,
    typical_controls,
)
from faceanim.face.frame import similarity
from faceanim.face.generic_head import generic_head

POSE_NAMES = ("yaw", "pitch", "roll", "x", "y", "scale")
# landmarks the head pose is fitted on: those none of the generic head's 53 expression shapes
# moves by more than this (metres)
RIGID_MOTION = 2e-3


@dataclass
class Tracking:
    """What the video analysis found, per frame (F frames).

    ``tracked`` (F,) bool; ``pose`` (F, 6): yaw, pitch, roll (degrees), x, y (pixels), scale
    (pixels per metre); ``features`` (F, 19, 2) fronto-parallel (metres, x the face's left, y
    up); ``raw`` (F, 15) control parameters as measured; ``controls`` (F, 15) normalised against
    frame ``neutral``. NaN where a frame was not tracked.
    """

    fps: float
    tracked: np.ndarray
    pose: np.ndarray
    features: np.ndarray
    raw: np.ndarray
    controls: np.ndarray
    neutral: int
    gaze: np.ndarray | None = None  # (F, 4): :func:`gaze_offsets` per frame, NaN where untracked
    inner_gap: np.ndarray | None = None  # (F,): :func:`inner_lip_gap` per frame, NaN where untracked
    # (F, 478, 3) float32 MediaPipe's landmarks in pixels (x right, y down, z away) and (F, 51)
    # float32 its blendshape scores (:data:`~faceanim.face.mediapipe.BLENDSHAPE_NAMES`), NaN where untracked
    landmarks: np.ndarray | None = None
    scores: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return len(self.tracked)

    @property
    def times(self) -> np.ndarray:
        return np.arange(self.n_frames) / self.fps


def rigid_landmarks() -> np.ndarray:
    """The landmarks that place the head: those no expression shape of the generic head moves."""
    head = generic_head()
    lmat = head.landmark_matrix()
    moved = np.stack([np.linalg.norm((lmat @ head.shape(n))[:468], axis=1) for n in head.shape_names]).max(0)
    return np.flatnonzero(moved < RIGID_MOTION)


def euler_degrees(r: np.ndarray) -> tuple[float, float, float]:
    """(yaw, pitch, roll) of a head rotation ``r`` = Ry(yaw) Rx(pitch) Rz(roll) in camera
    coordinates (x right, y up, z towards the camera): yaw turns the head to its own left, pitch
    nods it down, roll tilts it to its right."""
    yaw = np.degrees(np.arctan2(r[0, 2], r[2, 2]))
    pitch = np.degrees(np.arcsin(np.clip(-r[1, 2], -1.0, 1.0)))
    roll = np.degrees(np.arctan2(r[1, 0], r[1, 1]))
    return float(yaw), float(pitch), float(roll)


# each eye: (outer corner, inner corner, iris centre), the subject's left eye first
IRIS = ((263, 362, 473), (33, 133, 468))


def gaze_offsets(frontal: np.ndarray) -> np.ndarray:
    """(4,) where each iris sits in its eye, fronto-parallel: the left eye's horizontal and
    vertical offsets, then the right's, from the middle of the eye's corners, in eye widths
    (x to the subject's left, y up)."""
    out = []
    for outer, inner, iris in IRIS:
        mid = 0.5 * (frontal[outer, :2] + frontal[inner, :2])
        width = abs(frontal[outer, 0] - frontal[inner, 0])
        out.extend((frontal[iris, :2] - mid) / max(width, 1e-12))
    return np.array(out)


INNER_LIPS = (13, 14)  # the middle of the upper and the lower lip's inner line


def inner_lip_gap(frontal: np.ndarray) -> float:
    """The opening between the lips' inner lines at their middle, up the face (generic head
    metres, fronto-parallel; about 0 with the lips together): the outer lip points of the 19
    features also move when lips press, roll or pout with the mouth shut."""
    return float(frontal[INNER_LIPS[0], 1] - frontal[INNER_LIPS[1], 1])


def pose_and_features(landmarks_px: np.ndarray, rigid: np.ndarray, reference: np.ndarray, eyes_and_lips: bool = False):
    """Head pose (6,) and fronto-parallel features (19, 2) from one frame's 478 landmarks in
    pixels with depth ((x right, y down, z away from the camera), as MediaPipe reports them
    scaled by the image width); with ``eyes_and_lips``, also the irises' :func:`gaze_offsets` and
    the :func:`inner_lip_gap`."""
    q = landmarks_px * np.array([1.0, -1.0, -1.0])  # camera coordinates: y up, z towards the camera
    s, r, t = similarity(reference[rigid], q[rigid])
    yaw, pitch, roll = euler_degrees(r)
    frontal = ((q - t) @ r) / s  # back into the generic head's frame
    idx = [FEATURES[n] for n in FEATURE_NAMES]
    anchor = landmarks_px[168, :2]  # the nose bridge: where the head is in the picture
    pose = np.array([yaw, pitch, roll, anchor[0], anchor[1], s])
    if eyes_and_lips:
        return pose, frontal[idx, :2], gaze_offsets(frontal), inner_lip_gap(frontal)
    return pose, frontal[idx, :2]


class FaceTracker(FaceMesh):
    """MediaPipe's Face Landmarker in video mode (478 landmarks with the irises), one frame at a
    time: ``tracker(rgb)`` -> (478, 3) landmarks in pixels with depth (x right, y down, z away from
    the camera, scaled by the image width), or None where no face is found; ``tracker.detect(rgb)``
    also gives MediaPipe's 52 blendshape scores. A context manager."""

    def __init__(self):
        super().__init__(video=True, what="video tracking")


def track_frames(frames: Iterable[np.ndarray], fps: float, neutral_frame: int | None = None,
                 progress=None) -> Tracking:
    """Track every frame (RGB arrays) of a clip; see the module docstring."""
    from faceanim.io.files import native_stderr_quiet

    reference = generic_head().landmarks()
    rigid = rigid_landmarks()
    from faceanim.face.mediapipe import BLENDSHAPE_NAMES

    pose, feats, raw, tracked, gaze, gap, marks, scores = [], [], [], [], [], [], [], []
    with native_stderr_quiet(), FaceTracker() as tracker:
        for k, frame in enumerate(frames):
            found = tracker.detect(frame, k / float(fps))
            lm = None if found is None else found.landmarks
            marks.append(np.full((478, 3), np.nan, np.float32) if lm is None else lm.astype(np.float32))
            scores.append(np.full(len(BLENDSHAPE_NAMES), np.nan, np.float32) if found is None
                          else found.blendshapes.astype(np.float32))
            if lm is not None:
                p6, f19, g4, lips = pose_and_features(lm, rigid, reference, eyes_and_lips=True)
                pose.append(p6)
                feats.append(f19)
                gaze.append(g4)
                gap.append(lips)
                raw.append(control_parameters(f19))
                tracked.append(True)
            else:
                pose.append(np.full(6, np.nan))
                feats.append(np.full((19, 2), np.nan))
                raw.append(np.full(15, np.nan))
                gaze.append(np.full(4, np.nan))
                gap.append(np.nan)
                tracked.append(False)
            if progress is not None:
                progress.update(1)
    if not tracked:
        raise LandmarkError("the video has no frames; give a video with at least one frame")
    pose, feats, raw, tracked = np.array(pose), np.array(feats), np.array(raw), np.array(tracked)
    if neutral_frame is None:
        neutral = find_neutral(raw, pose, tracked)
        reference = typical_controls(raw, pose, tracked)
    else:
        neutral = int(neutral_frame)
        if not 0 <= neutral < len(tracked):
            raise LandmarkError(f"--neutral-frame {neutral} is outside the video's {len(tracked)} frames (0..{len(tracked) - 1})")
        if not tracked[neutral]:
            raise LandmarkError(f"no face was found in frame {neutral}; give a frame where the face is seen "
                                "as --neutral-frame")
        reference = raw[neutral]
    return Tracking(float(fps), tracked, pose, feats, raw, normalise(raw, reference, feats[neutral]), neutral,
                    np.array(gaze), np.array(gap), np.array(marks), np.array(scores))


def track_video(path, neutral_frame: int | None = None, progress=None) -> Tracking:
    """Track a video file (see :func:`track_frames`)."""
    from faceanim.io.video import video_frames, video_info

    info = video_info(path)
    return track_frames(video_frames(info), info.fps, neutral_frame, progress)
