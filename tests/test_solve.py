"""The ARKit solve per frame (faceanim.drivers.video.solve) against oracles: weights put into the
generic head's own landmark model and read back through an unknown similarity, scipy's bounded
least squares on the whole stacked problem, a sampled ICT identity's neutral recovered by the
calibration, and a real clip's lips; the MediaPipe adapter's model check and the --tracker CLI."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from faceanim.drivers.video import solve as S
from faceanim.face.generic_head import generic_head

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
VIDEOS = DATA / "talking-head-videos"


def _rotation(yaw, pitch, roll):
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("yxz", [yaw, pitch, roll], degrees=True).as_matrix()


def _as_mediapipe(points_head: np.ndarray, s: float, r: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Head-frame points (metres) seen by a camera: similarity, then MediaPipe's pixels (y down, z away)."""
    q = s * points_head @ r.T + t
    return q * np.array([1.0, -1.0, -1.0])


def _frame(weights: dict, identity=None):
    """478 landmarks of the generic head (its identity ``identity``) with ``weights`` on its shapes."""
    head = generic_head()
    v = head.identity(identity) if identity is not None else head.mesh.vertices.copy()
    for name, w in weights.items():
        v = v + w * head.shape(name)
    return head.landmarks(v)


def _calibrated(frames):
    """The calibration of frames seen by a camera, each put in the generic head's frame as
    tracking puts them."""
    from faceanim.drivers.video.tracking import rigid_landmarks

    head = generic_head()
    ref, rigid = head.landmarks(), rigid_landmarks()
    return S.calibrate(np.stack([S.head_frame(f, rigid, ref) for f in frames]))


def _neutral_error(neutral, truth) -> float:
    """The largest face point distance between two neutrals once the pose is taken out (metres)."""
    from faceanim.face.frame import similarity

    s, r, t = similarity(neutral[S.FACE_POINTS], truth[S.FACE_POINTS])
    return float(np.linalg.norm(s * neutral[S.FACE_POINTS] @ r.T + t - truth[S.FACE_POINTS], axis=1).max())


def test_weights_put_in_come_back_through_an_unknown_pose():
    """Oracle: the model itself. Landmarks made from known weights, turned, scaled and moved as a
    camera would see them, solve back to those weights (within 0.03; the prior shrinks them a
    little), every other shape near 0."""
    head = generic_head()
    names = S.solved_shapes(head)
    truth = {"jawOpen": 0.45, "mouthSmile_L": 0.6, "mouthSmile_R": 0.55, "browInnerUp_L": 0.5, "browInnerUp_R": 0.5,
             "eyeBlink_R": 0.7}
    neutral = head.landmarks()
    solver = S.Solver(neutral, S.SolverSettings(temporal=0.0, prior=1.0))
    q = _as_mediapipe(_frame(truth), 2400.0, _rotation(14, -6, 4), np.array([300.0, -250.0, -40.0]))
    e = solver.solve(S.camera_points(q))
    got = dict(zip(names, e))
    for name, w in truth.items():
        assert abs(got[name] - w) < 0.03, (name, got[name], w)
    others = [n for n in names if n not in truth]
    assert max(got[n] for n in others) < 0.05, sorted(((got[n], n) for n in others), reverse=True)[:3]
    # the performer at rest: all zero
    assert np.abs(solver.solve(S.camera_points(_as_mediapipe(neutral, 2400.0, _rotation(-20, 5, 0),
                                                             np.zeros(3))))).max() < 1e-6


def test_the_bounded_solve_is_scipys_on_the_whole_stacked_problem():
    """Oracle: scipy.optimize.lsq_linear on every row at once: the data's 1,404 rows with the
    expression's 45 columns and the pose change's 7 (scale, rotation, shift about the frame's
    points), the prior's rows and the temporal term's. The solve's weights, found on a 52 x 52
    triangle, are scipy's; some are at their bounds (a shape asked beyond 1, a smile the other
    way)."""
    from scipy.optimize import lsq_linear

    head = generic_head()
    settings = S.SolverSettings(prior=20.0, temporal=20.0)
    neutral = head.landmarks()
    solver = S.Solver(neutral, settings)
    rng = np.random.default_rng(3)
    previous = rng.uniform(0, 0.3, solver.n_shapes)
    solver.previous = previous.copy()
    frame = _frame({"jawOpen": 1.4, "mouthSmile_L": -0.5, "mouthPucker": 0.5}) + rng.normal(0, 4e-4, (478, 3))
    y = S.camera_points(_as_mediapipe(frame, 1.0, _rotation(3, 2, -1), np.array([0.001, 0.0, 0.002])))
    got = solver._joint(y)

    p = y[S.FACE_POINTS]
    w = np.sqrt(S.point_weights(settings.z_weight, settings.contour, settings.lips)) / S.SIGMA
    a = (S._deltas(head) * w[..., None]).reshape(-1, solver.n_shapes)
    cross = np.stack([np.cross(np.eye(3)[k], p) for k in range(3)], axis=-1)  # -(omega x p) per omega axis
    pose = np.concatenate([-p[..., None], -cross, -np.broadcast_to(np.eye(3), (len(p), 3, 3))], axis=-1)
    ap = (pose * w[..., None]).reshape(-1, 7)
    n = solver.n_shapes
    rows = np.vstack([np.hstack([a, ap]),
                      np.hstack([np.sqrt(settings.prior) * np.eye(n), np.zeros((n, 7))]),
                      np.hstack([np.sqrt(settings.temporal) * np.eye(n), np.zeros((n, 7))])])
    rhs = np.r_[((p - neutral[S.FACE_POINTS]) * w).ravel(), np.zeros(n), np.sqrt(settings.temporal) * previous]
    ref = lsq_linear(rows, rhs, bounds=(np.r_[np.zeros(n), np.full(7, -np.inf)], np.r_[np.ones(n), np.full(7, np.inf)]),
                     method="bvls").x[:n]
    names = S.solved_shapes(head)
    assert ref[names.index("jawOpen")] == pytest.approx(1.0) and ref[names.index("mouthSmile_L")] == 0.0
    np.testing.assert_allclose(got, ref, atol=1e-5)


def test_calibration_finds_a_sampled_identitys_neutral():
    """Oracle: a fresh ICT identity (standard normal weights, seed 11) talking: a third of its
    frames at rest, the others with the jaw open and a smile, each seen in another pose. The
    calibration's neutral is that identity's own landmarks (every face point within 0.3 mm once
    the pose is taken out), and the talking frames solve to their jaw and smile."""
    head = generic_head()
    rng = np.random.default_rng(11)
    identity = rng.normal(size=head.n_identity)
    rest = _frame({}, identity)
    frames, truth = [], []
    for k in range(60):
        w = {} if k % 3 == 0 else {"jawOpen": rng.uniform(0.1, 0.5), "mouthSmile_L": rng.uniform(0, 0.6)}
        pose = (1800 + 50 * rng.normal(), _rotation(*rng.normal(0, 8, 3)), rng.normal(0, 30, 3))
        frames.append(_as_mediapipe(_frame(w, identity), *pose))
        truth.append(w)
    cal = _calibrated(frames)
    assert _neutral_error(cal.neutral, rest) < 3e-4
    solver = S.Solver(cal.neutral, S.SolverSettings(temporal=0.0))
    names = S.solved_shapes(head)
    for f, w in zip(frames, truth):
        e = dict(zip(names, solver.solve(S.camera_points(f))))
        assert abs(e["jawOpen"] - w.get("jawOpen", 0.0)) < 0.06
        assert abs(e["mouthSmile_L"] - w.get("mouthSmile_L", 0.0)) < 0.1


def test_a_performer_whose_lips_never_meet_rests_with_them_apart():
    """Oracle: the model. A sampled ICT identity (seed 11) whose rest holds the jaw a quarter open
    (lips about 8 mm apart, never together), talking wider from there: the neutral comes back as
    that identity with its lips LIPS_APART apart (its own landmarks and the jawOpen that opens
    them from its own 0.7 mm, within 0.3 mm), so every frame solves to its own jawOpen less that
    bit; a neutral with the lips together is kept as is."""
    head = generic_head()
    rng = np.random.default_rng(11)
    identity = rng.normal(size=head.n_identity)
    closed = _frame({}, identity)
    own = closed[13, 1] - closed[14, 1]
    assert 0 < own < S.LIPS_APART
    np.testing.assert_array_equal(S.shut_lips(closed, head), closed)
    jaw_delta = head.landmarks(head.mesh.vertices + head.shape("jawOpen")) - head.landmarks()
    rest_jaw = (S.LIPS_APART - own) / (jaw_delta[13, 1] - jaw_delta[14, 1])
    expected = closed + rest_jaw * jaw_delta
    frames, truth = [], []
    for k in range(60):
        jaw = 0.25 if k % 3 == 0 else 0.25 + rng.uniform(0.05, 0.4)
        pose = (1800 + 50 * rng.normal(), _rotation(*rng.normal(0, 8, 3)), rng.normal(0, 30, 3))
        frames.append(_as_mediapipe(_frame({"jawOpen": jaw}, identity), *pose))
        truth.append(jaw)
    cal = _calibrated(frames)
    assert _neutral_error(cal.neutral, expected) < 3e-4
    solver = S.Solver(cal.neutral, S.SolverSettings(temporal=0.0))
    jaw = S.solved_shapes(head).index("jawOpen")
    got = np.array([solver.solve(S.camera_points(f))[jaw] for f in frames])
    assert np.abs(got - (np.array(truth) - rest_jaw)).max() < 0.06


def test_rest_frames_are_the_face_at_rest_whatever_the_lids_drift():
    """0.7 s at rest, then the jaw held open with the lids a hair wider (MediaPipe's smoothing does
    that): the frames taken as rest are the rest frames, by the gap alone and with the scores; a
    blink among them is left out."""
    from faceanim.face.mediapipe import BLENDSHAPE_NAMES

    rest, opened = _frame({}), _frame({"jawOpen": 0.5})
    frames, scores = [], np.zeros((45, len(BLENDSHAPE_NAMES)))
    for k in range(45):
        f = (rest if k < 20 else opened).copy()
        wider = 1.0 + 0.002 * k  # the lids' opening creeps up by 9% over the take
        for top, bottom in ((159, 145), (386, 374)):
            mid = 0.5 * (f[top] + f[bottom])
            f[top], f[bottom] = mid + wider * (f[top] - mid), mid + wider * (f[bottom] - mid)
        if k == 10:  # a blink while at rest
            f[[159, 386]] = f[[145, 374]]
        frames.append(f)
        scores[k, BLENDSHAPE_NAMES.index("jawOpen")] = 0.0 if k < 20 else 0.5
    frames = np.array(frames)
    for sc in (None, scores):
        picked = S.rest_frames(frames, scores=sc)
        assert len(picked) == 9 and picked.max() < 20 and 10 not in picked, picked


def test_rest_frames_stay_at_rest_when_the_next_expression_widens_the_eyes():
    """Half a second at rest, then a pucker held with the lids 20% wider (as d18 opens): the
    frames taken as rest are the first ones, with and without MediaPipe's scores, from the
    first 45 frames as live has them."""
    from faceanim.face.mediapipe import BLENDSHAPE_NAMES

    rest, pursed = _frame({}), _frame({"mouthPucker": 0.6})
    frames, scores = [], np.zeros((45, len(BLENDSHAPE_NAMES)))
    for k in range(45):
        f = (rest if k < 15 else pursed).copy()
        if k >= 15:
            for top, bottom in ((159, 145), (386, 374)):
                mid = 0.5 * (f[top] + f[bottom])
                f[top], f[bottom] = mid + 1.2 * (f[top] - mid), mid + 1.2 * (f[bottom] - mid)
            f[13, 1] += 2e-4  # the pursed lips a hair apart
            scores[k, BLENDSHAPE_NAMES.index("mouthPucker")] = 0.6
        frames.append(f)
    for sc in (None, scores):
        picked = S.rest_frames(np.array(frames), scores=sc)
        assert len(picked) == 9 and picked.max() < 15, picked


def test_to_arkit_names_and_halves():
    """ARKit's one curve for both halves takes their mean; cheekPuff comes from MediaPipe's score."""
    from faceanim.face.mediapipe import BLENDSHAPE_NAMES
    from faceanim.standards.arkit import ARKIT_NAMES

    names = S.solved_shapes()
    e = np.zeros((1, len(names)))
    e[0, names.index("browInnerUp_L")], e[0, names.index("browInnerUp_R")] = 0.2, 0.6
    e[0, names.index("mouthSmile_L")] = 0.7
    e[0, names.index("cheekPuff_L")] = 0.9  # not used: the score is
    scores = np.zeros((1, len(BLENDSHAPE_NAMES)))
    scores[0, BLENDSHAPE_NAMES.index("cheekPuff")] = 0.35
    out = dict(zip(ARKIT_NAMES, S.to_arkit(e, scores)[0]))
    assert out["BrowInnerUp"] == pytest.approx(0.4) and out["MouthSmileLeft"] == pytest.approx(0.7)
    assert out["CheekPuff"] == pytest.approx(0.35) and out["TongueOut"] == 0.0 and out["MouthSmileRight"] == 0.0


@pytest.mark.skipif(not (VIDEOS / "d18.mp4").is_file(), reason="../shared/data/talking-head-videos is not here")
def test_a_real_jaw_drop_and_closed_lips():
    """d18 (216 frames, a yawn): the solved jawOpen follows the performer's inner lip gap (r > 0.95,
    MediaPipe's own jawOpen score 0.9 or less on the same frames), and the frames with the lips
    together (gap under 1 mm) have the jaw nearly shut."""
    from faceanim.drivers.video.tracking import track_video
    from faceanim.face.mediapipe import BLENDSHAPE_NAMES
    from faceanim.perform import solve_performance
    from faceanim.standards.arkit import ARKIT_NAMES

    tr = track_video(VIDEOS / "d18.mp4")
    perf = solve_performance(tr)
    jaw = perf.weights[:, ARKIT_NAMES.index("JawOpen")] - perf.weights[:, ARKIT_NAMES.index("MouthClose")]
    gap = tr.inner_gap
    r_solve = np.corrcoef(jaw, gap)[0, 1]
    r_scores = np.corrcoef(tr.scores[:, BLENDSHAPE_NAMES.index("jawOpen")], gap)[0, 1]
    assert r_solve > 0.95 and r_solve > r_scores, (r_solve, r_scores)
    shut = gap < 1e-3
    assert shut.sum() > 20 and np.median(jaw[shut]) < 0.1
    assert perf.weights.min() >= 0.0 and perf.weights.max() <= 1.0


@pytest.mark.parametrize("video", [False, True])
def test_a_landmarker_left_open_exits_without_a_traceback(video):
    """A library user who never closes a FaceMesh: the interpreter exits with nothing on stderr
    (MediaPipe's own finaliser, run during teardown, printed a traceback)."""
    import subprocess
    import sys

    code = ("import numpy as np\nfrom faceanim.face.mediapipe import FaceMesh\n"
            f"m = FaceMesh(video={video})\nprint(m(np.zeros((64, 64, 3), np.uint8)))\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and r.stdout.strip() == "None" and r.stderr == "", r.stderr[-400:]


def test_a_damaged_model_is_one_line(monkeypatch):
    """A shipped model whose bytes do not match its SHA-256 is refused naming the file and the fix."""
    from faceanim.errors import LandmarkError
    from faceanim.face import mediapipe as M

    M.model_bytes.cache_clear()
    monkeypatch.setitem(M.MODELS, "face_landmarker.task", "0" * 64)
    try:
        with pytest.raises(LandmarkError, match="face_landmarker.task is missing or damaged; reinstall faceanim"):
            M.FaceMesh()
    finally:
        M.model_bytes.cache_clear()


@pytest.mark.skipif(not (VIDEOS / "d0.mp4").is_file(), reason="../shared/data/talking-head-videos is not here")
def test_tracker_options(tmp_path, capsys):
    """--tracker mediapipe writes MediaPipe's scores as the take; an option of the synthesis with
    another tracker is one line, exit 2, no file."""
    from faceanim.cli import main
    from faceanim.drivers.video.tracking import track_video
    from faceanim.face.mediapipe import BLENDSHAPE_NAMES
    from faceanim.io.arkit_csv import read_arkit_csv
    from faceanim.standards.arkit import ARKIT_NAMES

    out = tmp_path / "mp.csv"
    assert main(["perform", str(VIDEOS / "d0.mp4"), "--tracker", "mediapipe", "--quiet", "-o", str(out)]) == 0
    take = read_arkit_csv(out)
    tr = track_video(VIDEOS / "d0.mp4")
    k = ARKIT_NAMES.index("JawOpen")
    np.testing.assert_allclose(take.weights[:, k], tr.scores[:, BLENDSHAPE_NAMES.index("jawOpen")], atol=1e-5)
    capsys.readouterr()
    bad = tmp_path / "bad.csv"
    assert main(["perform", str(VIDEOS / "d0.mp4"), "--tracker", "solve", "--window", "5", "-o", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--window belongs to Chai et al.'s motion synthesis" in err[0] and not bad.exists()
