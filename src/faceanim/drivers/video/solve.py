"""An ARKit solve per frame: the performer's expression as the generic head's own ARKit shapes,
fitted to each frame's 478 MediaPipe landmarks.

The generic head (ICT FaceKit) is a linear model at the landmarks: a neutral face plus its
expression shapes' deltas (``landmarks = n + D e``). Per frame, with the head's similarity
(scale, rotation, translation) taken out, the weights ``e`` of the :data:`SOLVED` shapes solve

    min_e  sum_i c_i |D_i e - (y_i - n_i)|^2 / sigma^2  +  prior |e|^2  +  temporal |e - e_prev|^2,   0 <= e <= 1

over MediaPipe's 468 face points ``y`` (the irises are the eyeballs', not the skin's), each axis
weighted (depth counts :data:`Z_WEIGHT` as much: MediaPipe's depth is regressed, not seen). Two
passes: the pose from the landmarks no expression moves against the neutral, then the weights
solved together with a small change of pose (linearised: a brow raise moves the forehead points
the first pose was fitted on); the pose again from all points against the solved face, and the
weights with the pose's change again.

- **Bounded 0..1** as ARKit's curves are, so a shape is never used backwards to fit noise.
- **Prior** (ridge, :data:`PRIOR`): among shapes that move the landmarks alike (``jawOpen`` and
  ``mouthLowerDown``, the brows' halves) the solve takes the smallest weights, and a shape the
  landmarks barely see stays at 0.
- **Temporal term** (:data:`TEMPORAL`): a pull to the previous frame's weights, causal, so it
  works the same offline and live; it is small against the data (about a frame of lag on the
  mouth, measured by ``scripts/eval_motion.py``) and steadies the shapes that trade with each
  other from frame to frame.
- **The performer's neutral** (:func:`calibrate`): each tracked frame in the generic head's frame
  (a similarity onto its landmarks no expression moves); the median of the frames most like a
  face at rest (:func:`rest_frames`: eyes open, lips together, MediaPipe's scores low) is the
  neutral, the person's own shape with MediaPipe's bias on it, so the performer at rest solves to
  about zero. Offline the whole clip calibrates; live, the frames so far, refreshed as they come
  (:class:`~faceanim.live.performer.LiveSolver`).
- **Blinks and gaze** are read off the lids and irises per performer as before
  (:func:`~faceanim.perform.blink_curves`, :func:`~faceanim.perform.look_curves`): MediaPipe's
  lids never close on a closed eye, so a geometric solve alone would leave every blink part open;
  the solve's own ``eyeBlink`` is kept where it is larger (the small closures under the blinks'
  dead zone: on the tuning clip d3 the eye opening's r went from 0.91 to 0.95, the brows' from
  0.85 to 0.92).
- **MediaPipe's own scores** fill what the landmarks cannot see: ``cheekPuff`` (the cheeks'
  bulge is in depth, which MediaPipe's mesh hardly moves). ``tongueOut`` has neither: 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from faceanim.face.frame import similarity
from faceanim.face.generic_head import GenericHead, generic_head

FACE_POINTS = np.arange(468)
# the generic head's shapes the solve fits: all but the eyes' turns (the irises give the gaze) and
# the tongue (no landmark on it)
UNSOLVED = ("eyeLook", "tongueOut")
SIGMA = 1e-3  # metres on the generic head: MediaPipe's frame-to-frame jitter at the landmarks
Z_WEIGHT = 0.2  # depth's weight against x and y
CONTOUR_WEIGHT = 0.2  # the face oval's weight (its points slide along the silhouette)
LIP_WEIGHT = 10.0  # the lips' inner line's weight: whether the lips touch is what a viewer sees first
PRIOR = 20.0  # ridge on the weights: a weight of 1 costs as much as 20 landmark axes off by SIGMA
TEMPORAL = 20.0  # pull to the previous frame's weights, in the same units
FROM_SCORES = ("cheekPuff_L", "cheekPuff_R")  # taken from MediaPipe's scores (cheekPuff)
REST_SHARE = 0.2  # the performer's face at rest: the fifth of the frames most like it
LIPS_APART = 1e-3  # a neutral whose inner lips are further apart than this (metres) gets them shut
# MediaPipe's face oval (the silhouette ring)
FACE_OVAL = (10, 338, 297, 332, 284, 251, 389, 356, 454, 323, 361, 288, 397, 365, 379, 378, 400, 377, 152,
             148, 176, 149, 150, 136, 172, 58, 132, 93, 234, 127, 162, 21, 54, 103, 67, 109)


def solved_shapes(head: GenericHead | None = None) -> tuple[str, ...]:
    """The generic head's shape names the solve fits (head order)."""
    head = head or generic_head()
    return tuple(n for n in head.shape_names if not n.startswith(UNSOLVED))


@lru_cache(maxsize=2)
def _deltas(head: GenericHead) -> np.ndarray:
    """(468, 3, E) the :func:`solved_shapes`' deltas at the face points (read-only)."""
    from faceanim.face.registration import _landmark_model

    _, basis = _landmark_model(head)  # identity modes first, then the head's shapes
    names = head.shape_names
    cols = [head.n_identity + names.index(n) for n in solved_shapes(head)]
    out = np.ascontiguousarray(basis[..., cols])
    out.setflags(write=False)
    return out


INNER_LIPS = (78, 191, 80, 81, 82, 13, 312, 311, 310, 415, 308, 95, 88, 178, 87, 14, 317, 402, 318, 324)


def point_weights(z_weight: float = Z_WEIGHT, contour: float = CONTOUR_WEIGHT, lips: float = LIP_WEIGHT) -> np.ndarray:
    """(468, 3) each face point's and axis's weight in the data term."""
    w = np.ones((len(FACE_POINTS), 3))
    w[:, 2] = z_weight
    w[list(FACE_OVAL)] *= contour
    w[list(INNER_LIPS)] *= lips
    return w


@dataclass
class SolverSettings:
    """The solve's weights (module docstring): ``prior``, ``temporal``, ``z_weight``, ``contour``,
    ``lips``."""

    prior: float = PRIOR
    temporal: float = TEMPORAL
    z_weight: float = Z_WEIGHT
    contour: float = CONTOUR_WEIGHT
    lips: float = LIP_WEIGHT


class Solver:
    """The per-frame solve against one neutral (478, 3) in the generic head's frame (metres).

    ``solve(q)`` takes one frame's 478 landmarks in camera coordinates (x right, y up, z towards
    the camera: MediaPipe's pixels with y and z negated) and returns the :func:`solved_shapes`'
    weights (E,); it remembers them for the next frame's temporal term (:meth:`reset` forgets)."""

    def __init__(self, neutral: np.ndarray, settings: SolverSettings | None = None, head: GenericHead | None = None):
        from faceanim.drivers.video.tracking import rigid_landmarks

        self.head = head or generic_head()
        self.settings = settings or SolverSettings()
        self.neutral = np.asarray(neutral, dtype=np.float64)
        self.rigid = rigid_landmarks()
        d = _deltas(self.head)
        self._d = d
        self._sw = np.sqrt(point_weights(self.settings.z_weight, self.settings.contour, self.settings.lips)) / SIGMA  # (468, 3)
        a = (d * self._sw[..., None]).reshape(-1, d.shape[-1])
        self._a = a
        e = d.shape[-1]
        # the data term counts a landmark's axis off by SIGMA as 1: a prior of 1 makes a weight of
        # 1 cost as much as one landmark off by SIGMA along one axis
        gram = a.T @ a + np.eye(e) * (self.settings.prior + self.settings.temporal)
        self._gram = gram
        self._pull = self.settings.temporal
        self._point_w = point_weights(self.settings.z_weight, self.settings.contour, self.settings.lips)[:, 0]
        self.previous = np.zeros(e)

    @property
    def n_shapes(self) -> int:
        return self._d.shape[-1]

    def reset(self) -> None:
        self.previous = np.zeros(self.n_shapes)

    def _joint(self, y: np.ndarray) -> np.ndarray:
        """The weights for frame points ``y`` (head frame) solved together with a small change of
        the pose (a scale, a rotation and a shift, linearised about ``y``): a brow raise is not
        taken for a nod, nor a nod for a brow raise, however the first pose erred."""
        from scipy.linalg import cho_factor, solve_triangular
        from scipy.optimize import lsq_linear

        p = y[FACE_POINTS]
        e_n = self.n_shapes
        # the residual's change per pose parameter: -sigma * y, -omega x y (= [y]x omega), -tau
        cols = np.zeros((len(p), 3, 7))
        cols[..., 0] = -p
        cols[:, 0, 2], cols[:, 0, 3] = p[:, 2], -p[:, 1]  # [y]x: (0, z, -y; -z, 0, x; y, -x, 0)
        cols[:, 1, 1], cols[:, 1, 3] = -p[:, 2], p[:, 0]
        cols[:, 2, 1], cols[:, 2, 2] = p[:, 1], -p[:, 0]
        cols[:, 0, 4], cols[:, 1, 5], cols[:, 2, 6] = -1.0, -1.0, -1.0
        ap = (cols * self._sw[..., None]).reshape(-1, 7)
        b = ((p - self.neutral[FACE_POINTS]) * self._sw).ravel()
        gram = np.empty((e_n + 7, e_n + 7))
        gram[:e_n, :e_n] = self._gram
        gram[:e_n, e_n:] = self._a.T @ ap
        gram[e_n:, :e_n] = gram[:e_n, e_n:].T
        gram[e_n:, e_n:] = ap.T @ ap + 1e-9 * np.eye(7)
        h = np.r_[self._a.T @ b + self._pull * self.previous, ap.T @ b]
        upper = np.triu(cho_factor(gram, lower=False)[0])
        rhs = solve_triangular(upper, h, trans="T")
        x = solve_triangular(upper, rhs)
        if x[:e_n].min() < 0.0 or x[:e_n].max() > 1.0:
            lo, hi = np.r_[np.zeros(e_n), np.full(7, -np.inf)], np.r_[np.ones(e_n), np.full(7, np.inf)]
            x = lsq_linear(upper, rhs, bounds=(lo, hi), method="bvls").x
        return x[:e_n]

    def frontal(self, q: np.ndarray, model: np.ndarray | None = None) -> np.ndarray:
        """``q`` (478, 3) camera coordinates in the generic head's frame: the similarity onto the
        neutral's landmarks no expression moves, or with ``model`` (478, 3, the solved face) onto
        all face points."""
        if model is None:
            s, r, t = similarity(self.neutral[self.rigid], q[self.rigid])
        else:
            s, r, t = similarity(model[FACE_POINTS], q[FACE_POINTS], weights=self._point_w)
        return ((q - t) @ r) / s

    def solve(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, dtype=np.float64)
        e = self._joint(self.frontal(q))
        model = self.neutral.copy()
        model[FACE_POINTS] += self._d @ e
        e = self._joint(self.frontal(q, model))
        e = np.clip(e, 0.0, 1.0)
        self.previous = e
        return e


def camera_points(landmarks_px: np.ndarray) -> np.ndarray:
    """MediaPipe's landmarks in pixels (x right, y down, z away) as camera coordinates (y up, z
    towards the camera)."""
    return np.asarray(landmarks_px, dtype=np.float64) * np.array([1.0, -1.0, -1.0])


def head_frame(landmarks_px: np.ndarray, rigid: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(478, 3) one frame's landmarks in the generic head's frame: the similarity onto the head's
    landmarks no expression moves (``reference[rigid]``)."""
    q = camera_points(landmarks_px)
    s, r, t = similarity(reference[rigid], q[rigid])
    return ((q - t) @ r) / s


@dataclass
class Calibration:
    """The performer's neutral (478, 3, generic head frame; :func:`calibrate`), the identity
    fitted (``identity``, the morphable head's weights) and the RMS of what the fitted head left
    over (``fit_error``, metres) over the ``frames`` used."""

    neutral: np.ndarray
    identity: np.ndarray = field(default_factory=lambda: np.zeros(0))
    fit_error: float = float("nan")
    frames: int = 0


REST_EYES = 0.75  # ... among the frames whose lids are at least this share of their median opening apart


def expressiveness(scores: np.ndarray) -> np.ndarray:
    """(F,) how far from rest MediaPipe's own scores (F, 51) put each frame: the sum of its scores
    but the eyes' (blinks and looks: the lids are judged by their opening, the gaze is no
    expression)."""
    from faceanim.face.mediapipe import BLENDSHAPE_NAMES

    keep = [k for k, n in enumerate(BLENDSHAPE_NAMES) if not n.startswith(("eyeBlink", "eyeLook"))]
    return np.nan_to_num(np.asarray(scores, dtype=np.float64)[:, keep]).sum(axis=1)


def rest_frames(frontal: np.ndarray, share: float = REST_SHARE, scores: np.ndarray | None = None) -> np.ndarray:
    """Indices of the frames (F, 478, 3, head frame) most like a face at rest, among the frames
    whose eyes are open (the lids' mean opening at least :data:`REST_EYES` of its median: no
    blink; squints are the scores' to rank): the lowest ``share`` by the lips' gap (the inner
    lips, MediaPipe 13 - 14) or, with MediaPipe's ``scores`` (F, 51), by the sum of the gap's rank
    and the :func:`expressiveness`'s rank (lips together and no smile, no raised brows).
    The eyes are not asked to be among the widest (the 40th percentile was the bar): a performer
    who opens a take at rest and then purses his lips with his eyes wider (d18, held out) had
    his rest frames barred for the first 1.5 s and the pursed mouth taken as live's neutral."""
    f = np.asarray(frontal, dtype=np.float64)
    gap = f[:, 13, 1] - f[:, 14, 1]
    eyes = 0.5 * ((f[:, 159, 1] - f[:, 145, 1]) + (f[:, 386, 1] - f[:, 374, 1]))
    open_eyes = np.flatnonzero(eyes >= REST_EYES * np.median(eyes))
    n = max(1, int(round(share * len(f))))
    key = gap[open_eyes]
    if scores is not None:
        from scipy.stats import rankdata

        key = rankdata(key) + rankdata(expressiveness(np.asarray(scores)[open_eyes]))
    return np.sort(open_eyes[np.argsort(key, kind="stable")[:n]])


def shut_lips(neutral: np.ndarray, head: GenericHead | None = None) -> np.ndarray:
    """The neutral (478, 3, head frame) with its lips together: where its inner lips (13 - 14)
    are more than :data:`LIPS_APART` apart (the generic head's own rest gap is 1.0 mm, ICT's
    identities' -0.1-1.7 mm, MediaPipe's on lips that touch -0.4-0.2 mm), the generic head's
    ``jawOpen`` that brings them to :data:`LIPS_APART` is taken off the face points (at most a
    whole ``jawOpen``). A performer whose lips never meet (d10's rest gap is 3-15 mm) otherwise
    rests at an open mouth: the avatar's lips then shut while the performer's stay apart, and only
    the opening beyond her rest is played."""
    head = head or generic_head()
    n = np.array(neutral, dtype=np.float64)
    gap = n[13, 1] - n[14, 1]
    if gap <= LIPS_APART:
        return n
    jaw = _deltas(head)[..., solved_shapes(head).index("jawOpen")]
    per_unit = jaw[13, 1] - jaw[14, 1]
    if per_unit <= 0:
        return n
    n[FACE_POINTS] -= min((gap - LIPS_APART) / per_unit, 1.0) * jaw
    return n


def rest_neutral(frontal: np.ndarray, scores: np.ndarray | None = None,
                 head: GenericHead | None = None) -> tuple[np.ndarray, int]:
    """(the performer's neutral, the number of frames it is made of): the median per point of the
    :func:`rest_frames`, its lips :func:`shut_lips`."""
    f = np.asarray(frontal, dtype=np.float64)
    rest_idx = rest_frames(f, scores=scores)
    return shut_lips(np.median(f[rest_idx], axis=0), head), len(rest_idx)


def calibrate(frontal: np.ndarray, head: GenericHead | None = None, scores: np.ndarray | None = None) -> Calibration:
    """The performer's neutral face from (F, 478, 3) tracked frames in the generic head's frame
    (``scores``: MediaPipe's (F, 51), to rank the frames by expression too).

    The frames most like a face at rest (:func:`rest_frames`) are averaged (the median per
    point), the lips shut if they are apart (:func:`shut_lips`): that is the neutral, the person's
    own shape with MediaPipe's own bias on it, so a frame like the performer at rest solves to
    about zero. Taking off all that the one registration's landmark fit calls expression in it
    was tried and did not help on the tuning clips (d0, d3, d9), so only the lips' gap is.
    The fit (:func:`~faceanim.face.registration.fit_landmarks`) is kept for the record: the
    identity's weights and what the fitted head left over."""
    from faceanim.face.registration import fit_landmarks

    head = head or generic_head()
    neutral, frames = rest_neutral(frontal, scores, head)
    _, _, _, x, err = fit_landmarks(neutral, head)
    k = head.n_identity
    return Calibration(neutral, x[:k], err, frames)


def to_arkit(weights: np.ndarray, scores: np.ndarray | None, head: GenericHead | None = None) -> np.ndarray:
    """(F, 52) ARKit curves (Live Link order) of (F, E) solved weights: each curve its ICT
    shape's weight (the mean of both halves where ARKit has one curve for two), ``CheekPuff``
    from MediaPipe's ``scores`` (F, 51, :data:`~faceanim.face.mediapipe.BLENDSHAPE_NAMES`) when
    given; the eyes' blinks and looks are left 0 (set by the caller)."""
    from faceanim.face.mediapipe import BLENDSHAPE_NAMES
    from faceanim.standards.arkit import ARKIT_NAMES, apple_name, ict_name

    head = head or generic_head()
    names = solved_shapes(head)
    col = {n: i for i, n in enumerate(names)}
    w = np.atleast_2d(np.asarray(weights, dtype=np.float64))
    out = np.zeros((len(w), len(ARKIT_NAMES)))
    for a, name in enumerate(ARKIT_NAMES):
        parts = [col[n] for n in ict_name(name) if n in col]
        if any(n in FROM_SCORES for n in ict_name(name)) and scores is not None:
            out[:, a] = np.asarray(scores)[:, BLENDSHAPE_NAMES.index(apple_name(name))]
        elif parts:
            out[:, a] = w[:, parts].mean(axis=1)
    return np.clip(out, 0.0, 1.0)
