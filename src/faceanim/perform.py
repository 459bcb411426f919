"""Performance-driven animation (Chai, Xiao & Hodgins 2003): a video of a performer drives any face.

The four components, each in its own layer, meet here:

1. video analysis (:mod:`faceanim.drivers.video.tracking`): head pose and 15 control parameters
   per frame;
2. the motion database (:mod:`faceanim.build.motion`; one ships with the package, built from a
   real ARKit recording by ``scripts/build_default_motion.py``);
3. filtering and synthesis (:mod:`faceanim.drivers.video.synthesis`): the noisy controls become
   the database's real motion, as weights of its L deformation bases, feature-wise (the lower
   and the upper face each from its own controls; ``whole_face=True`` is the paper's one search);
   ``raw=True`` maps each frame's controls linearly instead (the baseline a user can compare with);
4. retargeting (:mod:`faceanim.rig.performance`): the bases moved onto the face once; a frame is
   then L weights, whatever the face's vertex count.

:func:`perform` does 3 on a tracking; :func:`performance_rig` does 4; the writers put the result
in glTF (morph targets + weights, head rotation on a node), MP4 (the face beside the video, with
its sound) or Live Link Face CSV (ARKit's 52 curves and the head angles).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from faceanim.build.motion import MotionDatabase, head_rotation, load_database
from faceanim.drivers.video.synthesis import Synthesiser
from faceanim.drivers.video.tracking import Tracking
from faceanim.errors import FaceAnimError
from faceanim.face.controls import CONTROL_NAMES
from faceanim.face.face import Face
from faceanim.rig.performance import basis_names, retarget
from faceanim.rig.rig import Rig

WINDOW, K, OVERLAP = 5, 30, 2  # segment length, neighbours, segments blended (the paper: 20, -, 5)
# Feature-wise synthesis: the lower face is searched on these controls alone, the upper face on
# the others; the lips' and corners' tilts and the mouth's sideways shift are left out of the
# search: tracked, they spread 2-10 times wider than in the database (head roll, noise) and drowned
# the mouth opening (measured by scripts/eval_performance.py)
LOWER_FACE = ("mouth_open", "mouth_width", "mouth_centre_y")
UPPER_FACE = ("nose_width", "nose_height", "eye_open_R", "eye_open_L", "brow_tilt_R", "brow_tilt_L",
              "brow_raise_R", "brow_raise_L", "brow_gap")
REGION_EDGE = 0.02  # metres: the lower and upper face blend over this band at the nose tip


@lru_cache(maxsize=1)
def default_database() -> MotionDatabase:
    """The motion database that ships with faceanim (built from the MIT Live Link Face take by
    ``scripts/build_default_motion.py``)."""
    from importlib import resources

    with resources.as_file(resources.files("faceanim").joinpath("assets", "motion_default.npz")) as p:
        return load_database(p)


@dataclass
class Performance:
    """A performance on a motion database's bases: ``weights`` (F, L) per video frame, the
    tracked head ``pose`` (F, 6; see :data:`~faceanim.drivers.video.tracking.POSE_NAMES`) with
    untracked frames held from the nearest tracked one, ``tracked`` (F,) and ``fps``."""

    fps: float
    weights: np.ndarray
    pose: np.ndarray
    tracked: np.ndarray
    settings: dict | None = None  # the window, K and overlap the synthesis used (None: raw)

    @property
    def n_frames(self) -> int:
        return len(self.weights)

    def rotations(self) -> np.ndarray:
        """(F, 3, 3) the head's rotation per frame (yaw, pitch, roll of the tracking)."""
        a = np.radians(self.pose[:, :3])
        return head_rotation(a[:, 0], a[:, 1], a[:, 2])

    def quaternions(self) -> np.ndarray:
        """(F, 4) the head's rotation as glTF quaternions (x, y, z, w)."""
        from scipy.spatial.transform import Rotation

        return Rotation.from_matrix(self.rotations()).as_quat()


def hold_untracked(values: np.ndarray, tracked: np.ndarray) -> np.ndarray:
    """``values`` (F, n) with each untracked frame given the nearest earlier tracked frame's values
    (the first tracked frame's before it): the avatar holds still while the face is lost."""
    v = np.array(values, dtype=np.float64)
    idx = np.flatnonzero(tracked)
    if not len(idx):
        raise FaceAnimError("no face was found in any frame of the video; give a video where the face is seen")
    src = idx[np.clip(np.searchsorted(idx, np.arange(len(v)), side="right") - 1, 0, None)]
    return v[src]


def direct_mapping(db: MotionDatabase) -> np.ndarray:
    """(16, L) the least-squares linear map from [controls, 1] to basis weights over the
    database's frames: the per-frame baseline (no segments, no filtering)."""
    x = np.c_[db.controls, np.ones(db.n_frames)]
    a, *_ = np.linalg.lstsq(x, db.weights, rcond=None)
    return a


def region_projectors(db: MotionDatabase) -> tuple[np.ndarray, np.ndarray]:
    """(L, L) matrices taking basis weights to the weights of their motion's lower part (markers
    below the nose tip, blended over :data:`REGION_EDGE`) and upper part: ``P_low + P_up = I``
    (the bases are orthonormal), so one motion for the lower face and another for the upper
    face combine into one set of L weights."""
    from faceanim.face.generic_head import generic_head

    nose_y = generic_head().landmarks()[2, 1]  # subnasale
    low = np.clip(0.5 + (nose_y - db.rest[:, 1]) / REGION_EDGE, 0.0, 1.0)
    p_low = np.einsum("lpd,p,kpd->lk", db.bases, low, db.bases)
    p_up = np.einsum("lpd,p,kpd->lk", db.bases, 1.0 - low, db.bases)
    return p_low, p_up


def perform(tracking: Tracking, db: MotionDatabase | None = None, raw: bool = False, window: int = WINDOW,
            k: int = K, overlap: int = OVERLAP, search: str = "kdtree", whole_face: bool = False) -> Performance:
    """The performance of a tracked video on a motion database (the shipped one by default):
    filtered and synthesised from segments of ``window`` frames, ``k`` neighbours, blended over
    ``overlap`` frames (delay ``overlap - 1`` frames), or mapped frame by frame with ``raw``.

    Synthesis is feature-wise: the lower face from a search on :data:`LOWER_FACE`, the upper face
    from one on :data:`UPPER_FACE`, joined by :func:`region_projectors`; ``whole_face`` makes one
    search on all 15 controls, as the paper does. Controls are compared in units of their spread
    over the database and held to its range (0.5-99.5th percentile). A video at another frame
    rate than the database is resampled to it for the synthesis (segments are W of the
    database's frames) and back."""
    db = db or default_database()
    controls = hold_untracked(tracking.controls, tracking.tracked)
    pose = hold_untracked(tracking.pose, tracking.tracked)
    if raw:
        weights = np.c_[controls, np.ones(len(controls))] @ direct_mapping(db)
    else:
        t_video = np.arange(len(controls)) / tracking.fps
        resample = abs(tracking.fps - db.fps) > 1e-6 * db.fps
        if resample:
            t_db = np.arange(int(np.floor(t_video[-1] * db.fps + 1e-9)) + 1) / db.fps
            controls = np.stack([np.interp(t_db, t_video, c) for c in controls.T], axis=1)
        # controls in units of their spread over the database (they mix mouth widths and degrees),
        # each held to the range the database has (a tracked value beyond it is mostly noise)
        scale = np.maximum(db.controls.std(axis=0), 1e-9)
        lo, hi = np.percentile(db.controls, [0.5, 99.5], axis=0)
        query, known = np.clip(controls, lo, hi) / scale, db.controls / scale
        bounds = np.r_[np.sort(np.unique(np.r_[0, db.take_starts])), db.n_frames]
        lengths = np.diff(bounds)
        if int(window) > lengths.max():
            raise FaceAnimError(f"the motion database's takes are at most {lengths.max()} frames long; give a "
                                f"window (W) of at most {lengths.max()} frames")
        window = int(window)
        if not 1 <= int(overlap) <= window:
            raise FaceAnimError(f"the overlap must be 1 to {window} frames (the window), got {overlap}")
        n_segments = int(np.sum(np.maximum(lengths - window + 1, 0)))
        k = min(int(k), n_segments)  # a small database has fewer segments than K asks

        def synthesise(cols):
            synth = Synthesiser(known[:, cols], db.weights, window, k, 0.99, int(overlap), db.take_starts, search)
            return synth.synthesise(query[:, cols])

        if whole_face:
            weights = synthesise(list(range(len(CONTROL_NAMES))))
        else:
            p_low, p_up = region_projectors(db)
            lower = synthesise([CONTROL_NAMES.index(n) for n in LOWER_FACE])
            upper = synthesise([CONTROL_NAMES.index(n) for n in UPPER_FACE])
            weights = lower @ p_low.T + upper @ p_up.T
        if resample:
            weights = np.stack([np.interp(t_video, t_db, w) for w in weights.T], axis=1)
        return Performance(tracking.fps, weights, pose, tracking.tracked.copy(),
                           {"window": window, "k": k, "overlap": int(overlap)})
    return Performance(tracking.fps, weights, pose, tracking.tracked.copy())


def performance_rig(face: Face, db: MotionDatabase | None = None) -> Rig:
    """The face's rig for a motion database: one control per deformation basis (retargeting)."""
    db = db or default_database()
    return retarget(face, db.basis_curves, db.curve_names, names=basis_names(db.n_bases))


def head_pivot(face: Face) -> np.ndarray:
    """(3,) the point the head turns about: between the ears, at the eyes' height, one
    inter-ocular distance behind the nose bridge's plane (roughly the top of the neck)."""
    fr = face.frame
    lm = face.landmarks
    centre = 0.5 * (lm[234] + lm[454])
    centre = centre + fr.rotation[1] * float((0.5 * (lm[33] + lm[263]) - centre) @ fr.rotation[1])
    return centre - fr.rotation[2] * 0.3 * fr.iod


def arkit_curves(perf: Performance, db: MotionDatabase) -> np.ndarray:
    """(F, 52) ARKit curves (Live Link Face order) of a performance: the bases written as the
    generic head's shapes (ICT names) mapped back to ARKit's names, clamped to [0, 1]."""
    from faceanim.io.arkit_csv import ARKIT_NAMES, ict_name

    ict = perf.weights @ db.basis_curves
    col = {n: i for i, n in enumerate(db.curve_names)}
    out = np.zeros((perf.n_frames, len(ARKIT_NAMES)))
    for a, name in enumerate(ARKIT_NAMES):
        parts = [col[n] for n in ict_name(name) if n in col]
        if parts:
            out[:, a] = ict[:, parts].mean(axis=1)
    return np.clip(out, 0.0, 1.0)


def frames_of(perf: Performance, rig: Rig, pivot: np.ndarray, chunk: int = 64):
    """The face's vertices per frame: the bases blended, then turned by the head's rotation
    about ``pivot``."""
    rot = perf.rotations()
    for a in range(0, perf.n_frames, chunk):
        v = rig.evaluate(perf.weights[a:a + chunk])
        for j, vf in enumerate(v):
            yield (vf - pivot) @ rot[a + j].T + pivot
