"""Chai, Xiao & Hodgins' performance, causally: one tracked frame in, one frame of curves out.

:func:`faceanim.perform.perform` sees the whole clip before it decides anything: the performer's
neutral face, open and closed eyes, gaze straight ahead and mouth at rest are medians and
percentiles over every frame. Live, only the past is known, so :class:`LivePerformer` keeps the
last :data:`HISTORY` seconds of tracked frames and recomputes the same statistics from them (every
frame during the first second, then every :data:`REFRESH` seconds): after a few seconds of a
performer's face it behaves as the offline path on the same frames. The synthesis is the same
segment search (:class:`~faceanim.drivers.video.synthesis.SynthesisStream`, lower and upper face
apart, the mouth held to the performer's), run at the database's frame rate on the query
interpolated between the frames that arrive (a frame dropped upstream is bridged, not shifted);
``overlap`` 1 (the default live) gives the newest frame's own estimate, no delay.

Each :meth:`LivePerformer.step` returns a :class:`LiveSample`: the performance weights, ARKit's 52
curves (Live Link order, 0..1), the head's yaw, pitch and roll and the eyes' angles (radians). A
face lost holds its expression for :data:`~faceanim.perform.LOST_HOLD` seconds, then eases to rest;
when it comes back the expression eases in over :data:`~faceanim.perform.LOST_EASE` seconds.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from faceanim.build.motion import MotionDatabase
from faceanim.drivers.video.filters import OneEuro
from faceanim.drivers.video.synthesis import SynthesisStream, Synthesiser
from faceanim.drivers.video.tracking import pose_and_features, rigid_landmarks
from faceanim.face.controls import CONTROL_NAMES, control_parameters, find_neutral, normalise, typical_controls
from faceanim.face.generic_head import generic_head
from faceanim.perform import (
    GAZE_HOLD,
    HEAD_BETA,
    HEAD_MIN_CUTOFF,
    LOST_EASE,
    LOST_HOLD,
    LOWER_FACE,
    MOUTH_MEASURES,
    UPPER_FACE,
    WINDOW,
    K,
    arkit_matrix,
    arkit_weights,
    blink_closure,
    blink_dead_zone,
    database_mouth,
    default_database,
    eye_angles,
    feature_mouth,
    look_weights,
    neutral_mouth,
    rest_frames,
)

def _eye_columns() -> list[int]:
    from faceanim.perform import _eye_columns as columns

    return columns()


_EYE_COLUMNS = _eye_columns()  # ARKit columns of the blinks, then the looks (EYE_CONTROLS order)
HISTORY = 20.0  # seconds of tracked frames the running statistics are taken over
REFRESH = 0.5  # seconds between two updates of the statistics (after the first second: every frame)
SETTLE = 1.0  # seconds from the first tracked frame during which the statistics follow every frame



@dataclass
class LiveSample:
    """One frame out of :class:`LivePerformer`: ``time`` (seconds of the source), ``tracked``,
    ``weights`` (2L + 10,) as :attr:`faceanim.perform.Performance.weights`, ``arkit`` (52,) in
    :data:`~faceanim.standards.arkit.ARKIT_NAMES` order, ``head`` (3,) yaw, pitch, roll and ``eyes``
    (6,) the eyes' yaw, pitch, roll (radians, :func:`~faceanim.perform.eye_angles`); ``capture``:
    when its frame was captured (seconds since the epoch; set by the pipeline)."""

    time: float
    tracked: bool
    weights: np.ndarray
    arkit: np.ndarray
    head: np.ndarray
    eyes: np.ndarray
    capture: float = 0.0


class LiveFace:
    """What every live tracker does with a frame (see the module docstring): the head's pose and
    its One-Euro filter, the running statistics of the lids, the gaze and the mouth, the blinks
    and the gaze read off, and a lost face held and eased to rest. Subclasses make the rest of
    the expression (:meth:`_expression`) and say how a frame's weights become ARKit's curves
    (:meth:`_compose`, :meth:`_arkit`)."""

    n_weights = 0

    def _start(self) -> None:
        self.reference = generic_head().landmarks()
        self.rigid = rigid_landmarks()
        self.head_filter = OneEuro(HEAD_MIN_CUTOFF, HEAD_BETA)
        self.history: deque = deque()  # (time, raw, pose, features, gaze, mouth, eyes open, landmarks) of tracked frames
        self.first_tracked: float | None = None
        self.refreshed = -np.inf
        self.stats: dict = {}
        self.look_hold = np.zeros(8)
        self.expression = np.zeros(self.n_weights)
        self.head = np.zeros(3)
        self.last_tracked: float | None = None
        self.fade = 1.0
        self.last_time: float | None = None
        self.scores: np.ndarray | None = None  # MediaPipe's scores of the newest frame, when given


class LivePerformer(LiveFace):
    """The perform path one frame at a time (see the module docstring): ``step(landmarks, time)``
    with a frame's 478 MediaPipe landmarks in pixels (None where no face was found) and its time in
    seconds (increasing) -> :class:`LiveSample`."""

    def __init__(self, db: MotionDatabase | None = None, window: int = WINDOW, k: int = K, overlap: int = 1,
                 follow_mouth: bool = True, search: str = "kdtree"):
        self.db = db = db or default_database()
        self.n_weights = 2 * db.n_bases + 10
        self.scale = np.maximum(db.controls.std(axis=0), 1e-9)
        self.lo, self.hi = np.percentile(db.controls, [0.5, 99.5], axis=0)
        known = db.controls / self.scale
        self.lower_cols = [CONTROL_NAMES.index(n) for n in LOWER_FACE]
        self.upper_cols = [CONTROL_NAMES.index(n) for n in UPPER_FACE]
        self.follow = bool(follow_mouth)
        markers = db.weights
        if self.follow:
            known_mouth = database_mouth(db)
            self.spread = np.maximum(known_mouth.std(axis=0), 1e-12)
            self.lo_m, self.hi_m = np.percentile(known_mouth, [0.5, 99.5], axis=0)
            along, *_ = np.linalg.lstsq(np.c_[known_mouth / self.spread, np.ones(db.n_frames)], db.weights, rcond=None)
            self.along = along[:-1]
            markers = np.hstack([db.weights, known_mouth / self.spread])
            self.rest_mouth = neutral_mouth()
        k = min(int(k), db.n_frames - int(window) + 1)
        self.lower = SynthesisStream(Synthesiser(known[:, self.lower_cols], markers, window, k, 0.99, overlap,
                                                 db.take_starts, search))
        self.upper = SynthesisStream(Synthesiser(known[:, self.upper_cols], db.weights, window, k, 0.99, overlap,
                                                 db.take_starts, search))
        self.delay = (int(overlap) - 1) / db.fps
        self.arkit = arkit_matrix(db)
        self.last_query: tuple[float, np.ndarray] | None = None
        self.synth: tuple[np.ndarray, np.ndarray] | None = None  # the newest lower and upper output
        self._start()

    # -- running statistics (LiveFace) -----------------------------------------------------------
    def _refresh(self) -> None:
        times = np.array([h[0] for h in self.history])
        raw = np.array([h[1] for h in self.history])
        pose = np.array([h[2] for h in self.history])
        ok = np.ones(len(raw), dtype=bool)
        neutral = find_neutral(raw, pose, ok)
        st = {"typical": typical_controls(raw, pose, ok), "neutral_features": self.history[neutral][3]}
        for name in ("eye_open_L", "eye_open_R"):
            o = raw[:, CONTROL_NAMES.index(name)]
            st[name] = (float(np.median(o)), float(np.percentile(o, 1)))
        gaze = np.array([h[4] for h in self.history])
        open_eyes = np.array([h[6] for h in self.history])  # both closures under GAZE_HOLD
        st["gaze"] = np.median(gaze[open_eyes], axis=0) if open_eyes.any() else np.median(gaze, axis=0)
        mouth = np.array([h[5] for h in self.history])
        st["mouth_rest"] = np.median(mouth[rest_frames(mouth)], axis=0)
        self.stats = st
        self.refreshed = float(times[-1])

    # -- one frame -------------------------------------------------------------------------------
    def step(self, landmarks: np.ndarray | None, time: float) -> LiveSample:
        time = float(time)
        if self.last_time is not None and time <= self.last_time:
            time = self.last_time + 1e-6  # a source's clock must not go backwards
        dt = 0.0 if self.last_time is None else time - self.last_time
        self.last_time = time
        if landmarks is not None:
            self._tracked(np.asarray(landmarks, dtype=np.float64), time)
            self.fade = min(1.0, self.fade + dt / LOST_EASE) if self.last_tracked is not None else 1.0
            self.last_tracked = time
        elif self.last_tracked is not None:
            beyond = np.clip((time - self.last_tracked - LOST_HOLD) / LOST_EASE, 0.0, 1.0)
            self.fade = min(self.fade, 0.5 * (1.0 + np.cos(np.pi * beyond)))
        weights = self.expression * self.fade
        arkit = self._arkit(weights)
        return LiveSample(time, landmarks is not None, weights, arkit, self.head.copy(),
                          eye_angles(arkit[_EYE_COLUMNS[2:]]))

    def _tracked(self, landmarks: np.ndarray, time: float) -> None:
        pose, feats, gaze, gap = pose_and_features(landmarks, self.rigid, self.reference, eyes_and_lips=True)
        raw = control_parameters(feats)
        mouth = feature_mouth(feats[None])[0]
        if self.first_tracked is None:
            self.first_tracked = time
        # closures of the eyes as the statistics stand (the gaze is not taken while a lid is shut)
        st = self.stats
        closing = [float(blink_closure(raw[CONTROL_NAMES.index(n)], *st[n])) if st else 0.0
                   for n in ("eye_open_L", "eye_open_R")]
        eyes_open = max(closing) < GAZE_HOLD
        self.history.append((time, raw, pose, feats, gaze, mouth, eyes_open, self._kept(landmarks)))
        while self.history and self.history[0][0] < time - HISTORY:
            self.history.popleft()
        if time - self.first_tracked < SETTLE or time - self.refreshed >= REFRESH:
            self._refresh()
            st = self.stats
        self.head = np.radians(self.head_filter(pose[:3], time))
        face = self._expression(landmarks, raw, feats, mouth, gap, time)
        # the lids and the gaze, read off directly: no filter on the gaze (offline's centred 3-frame
        # median, made causal, put every saccade a frame late: gaze x r on the tuning clips d3, d9 went
        # from 0.92, 0.79 to 0.95, 0.88 without it, offline 0.96, 0.90; a One-Euro filter did worse)
        blinks = blink_dead_zone(np.array([blink_closure(raw[CONTROL_NAMES.index(n)], *st[n])
                                           for n in ("eye_open_L", "eye_open_R")]))
        for e, outward in ((0, 1.0), (1, -1.0)):
            if blinks[e] < GAZE_HOLD:
                self.look_hold[4 * e:4 * e + 4] = look_weights(gaze[2 * e:2 * e + 2] - st["gaze"][2 * e:2 * e + 2],
                                                               outward)
        self.expression = self._compose(face, blinks, self.look_hold.copy())

    # -- what a subclass makes ------------------------------------------------------------------
    def _kept(self, landmarks: np.ndarray):
        """What the history keeps of a frame's landmarks (nothing here)."""
        return None

    def _expression(self, landmarks, raw, feats, mouth, gap, time) -> np.ndarray:
        """The expression but the eyes: the lower and the upper face's synthesised weights."""
        st = self.stats
        # the controls, as the offline path has them, then the synthesis at the database's rate
        query = np.clip(normalise(raw, st["typical"], st["neutral_features"]), self.lo, self.hi) / self.scale
        self._synthesise(query, time)
        n_l = self.db.n_bases
        lower, upper = self.synth
        if self.follow:
            target = self.rest_mouth + mouth - st["mouth_rest"]  # as perform.performer_mouth
            target[0] = gap
            target = np.clip(target, self.lo_m, self.hi_m) / self.spread
            got = lower[n_l:n_l + len(MOUTH_MEASURES)]
            lower = lower[:n_l] + (target - got) @ self.along
        return np.r_[lower, upper]

    def _compose(self, face: np.ndarray, blinks: np.ndarray, looks: np.ndarray) -> np.ndarray:
        return np.r_[face, blinks, looks]

    def _arkit(self, weights: np.ndarray) -> np.ndarray:
        return arkit_weights(weights[None], self.db, self.arkit)[0]

    def _synthesise(self, query: np.ndarray, time: float) -> None:
        """Push the database-rate samples between the previous query and this one (at most a
        window of them: after a long gap the segment restarts from this frame)."""
        step = 1.0 / self.db.fps
        if self.last_query is None or time - self.last_query[0] > self.lower.s.window * step:
            samples = [query]
            self.next_sample = time + step
        else:
            t0, q0 = self.last_query
            samples = []
            while self.next_sample <= time + 1e-9:
                a = (self.next_sample - t0) / (time - t0)
                samples.append(q0 + a * (query - q0))
                self.next_sample += step
        self.last_query = (time, query)
        for q in samples:
            lo = self.lower.push(q[self.lower_cols])
            up = self.upper.push(q[self.upper_cols])
            if lo is not None:
                self.synth = (lo, up)
        if self.synth is None:  # the first frames of a delayed (overlap > 1) synthesis
            self.synth = (self.lower.s.markers.mean(axis=0), self.upper.s.markers.mean(axis=0))


class LiveSolver(LivePerformer):
    """The ARKit solve (:mod:`faceanim.drivers.video.solve`) one frame at a time: the performer's
    neutral is the median of the frames most like a face at rest among those of the last
    :data:`HISTORY` seconds, its lips shut (:func:`~faceanim.drivers.video.solve.rest_neutral`),
    updated with the other running statistics; each frame is solved against it (the temporal term is causal, as
    offline); blinks, gaze, head and a lost face as :class:`LivePerformer`. ``step`` takes the
    frame's MediaPipe scores too (``cheekPuff``); the sample's weights are ARKit's 52 curves."""

    def __init__(self, settings=None):
        from faceanim.drivers.video.solve import Solver, solved_shapes

        self.n_weights = 52
        self.solver_settings = settings
        self.solver: Solver | None = None
        self.n_solved = len(solved_shapes())
        self._start()

    def step(self, landmarks: np.ndarray | None, time: float, scores: np.ndarray | None = None) -> LiveSample:
        self.scores = scores
        return super().step(landmarks, time)

    def _kept(self, landmarks: np.ndarray):
        from faceanim.drivers.video.solve import head_frame

        frontal = head_frame(landmarks, self.rigid, self.reference).astype(np.float32)
        return frontal, None if self.scores is None else np.asarray(self.scores, dtype=np.float32)

    def _refresh(self) -> None:
        from faceanim.drivers.video.solve import Solver, rest_neutral

        super()._refresh()
        frontal = np.array([h[7][0] for h in self.history], dtype=np.float64)
        scores = None if any(h[7][1] is None for h in self.history) else np.array([h[7][1] for h in self.history])
        neutral, _ = rest_neutral(frontal, scores)
        if self.solver is None:
            self.solver = Solver(neutral, self.solver_settings)
        else:
            self.solver.neutral = neutral

    def _expression(self, landmarks, raw, feats, mouth, gap, time) -> np.ndarray:
        from faceanim.drivers.video.solve import camera_points, to_arkit

        e = self.solver.solve(camera_points(landmarks))
        return to_arkit(e[None], None if self.scores is None else np.asarray(self.scores)[None])[0]

    def _compose(self, face: np.ndarray, blinks: np.ndarray, looks: np.ndarray) -> np.ndarray:
        out = np.array(face, dtype=np.float64)
        # as offline (solve_performance): the solve's own eyeBlink where larger than the lids' closure
        out[_EYE_COLUMNS] = np.r_[np.maximum(blinks, out[_EYE_COLUMNS[:2]]), looks]
        return out

    def _arkit(self, weights: np.ndarray) -> np.ndarray:
        return np.clip(weights, 0.0, 1.0)


class LiveScores(LiveSolver):
    """MediaPipe's own 52 blendshape scores, unchanged (``tongueOut`` 0), live: the baseline
    (``--tracker mediapipe``); the head and a lost face as :class:`LivePerformer`."""

    def _refresh(self) -> None:
        LivePerformer._refresh(self)

    def _kept(self, landmarks: np.ndarray):
        return None

    def _expression(self, landmarks, raw, feats, mouth, gap, time) -> np.ndarray:
        from faceanim.face.mediapipe import BLENDSHAPE_NAMES
        from faceanim.standards.arkit import APPLE_NAMES

        out = np.zeros(52)
        if self.scores is not None:
            by = dict(zip(BLENDSHAPE_NAMES, np.asarray(self.scores, dtype=np.float64)))
            out = np.array([by.get(n, 0.0) for n in APPLE_NAMES])
        return out

    def _compose(self, face: np.ndarray, blinks: np.ndarray, looks: np.ndarray) -> np.ndarray:
        return np.array(face, dtype=np.float64)


def live_tracker(name: str = "solve") -> LiveFace:
    """The live counterpart of ``--tracker`` ``name``: solve, synthesis or mediapipe."""
    if name == "solve":
        return LiveSolver()
    if name == "mediapipe":
        return LiveScores()
    return LivePerformer()
