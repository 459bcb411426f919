"""Performance-driven animation (Chai et al. 2003): retargeting (s. 5) against exact answers and the
ICT head's own shapes, synthesis driven by the database's own controls, the perform command's
three outputs and its bad input."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pygltflib
import pytest
from gltf_reader import accessor

from faceanim.cli import main
from faceanim.face.face import Face
from faceanim.face.generic_head import generic_head
from faceanim.face.mesh import Mesh

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
VIDEOS = DATA / "talking-head-videos"
ICT = DATA / "ict-facekit"
needs_videos = pytest.mark.skipif(not VIDEOS.is_dir(), reason="../shared/data/talking-head-videos is not here")


def run(args) -> int:
    try:
        return main([str(a) for a in args])
    except SystemExit as exc:
        return exc.code


@pytest.fixture(scope="module")
def db():
    from faceanim.perform import default_database

    return default_database()


def _turned(angle_deg: float, scale: float, shift) -> tuple[np.ndarray, np.ndarray]:
    a = np.radians(angle_deg)
    r = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    return scale * r, np.asarray(shift, dtype=np.float64)


def test_retargeting_onto_a_moved_copy_is_the_jacobian_times_the_source(db):
    """The generic head scaled by 100, turned by 30 degrees and moved: the landmark spline is that
    similarity (its Jacobian s R everywhere), so every retargeted basis is exactly s R times the
    source basis (eq. 5), vertex for vertex."""
    from faceanim.rig.retarget import retarget, source_bases

    head = generic_head()
    a, t = _turned(30.0, 100.0, [5.0, -3.0, 2.0])
    mesh = Mesh(head.mesh.vertices @ a.T + t, head.mesh.faces, name="moved")
    face = Face(mesh, head.landmarks() @ a.T + t)
    rig = retarget(face, db.basis_curves[:3], db.curve_names)
    src = source_bases(db.basis_curves[:3], db.curve_names)
    for i, name in enumerate(rig.controls):
        np.testing.assert_allclose(rig.blendshape(name), src[i] @ a.T, atol=1e-6 * np.abs(src[i] @ a.T).max())


def test_source_bases_at_the_markers_are_the_database_bases(db):
    """Each basis written as the generic head's shapes reproduces the database's marker basis
    (the bases are orthonormal, so the misfit is a fraction of a unit vector) for the strongest
    bases, which carry almost all of the motion."""
    from faceanim.rig.retarget import source_bases

    dense = source_bases(db.basis_curves, db.curve_names)[:, db.marker_vertices]
    misfit = np.linalg.norm(dense - db.bases, axis=(1, 2))
    energy = (db.weights ** 2).sum(axis=0) / (db.weights ** 2).sum()
    assert misfit[0] < 0.15 and float(energy @ misfit) < 0.2


def _obj_vertices(path: Path) -> np.ndarray:
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as fh:
        return np.array([ln.split()[1:4] for ln in fh if ln.startswith("v ")], dtype=np.float64)


@pytest.mark.skipif(not ICT.is_dir(), reason="../shared/data/ict-facekit is not here")
def test_retargeting_onto_the_ict_head_matches_its_own_shapes(db):
    """The ICT head from its files (another mesh: 26,719 vertices, centimetres, landmarks detected
    on a render) has its own 53 ARKit shapes: each basis written with them is the right answer.
    The retargeted bases are within 15% of it on the skin (by the landmark spline's smoothing; an
    exact spline through the detected landmarks was 56% off); the teeth within 10%."""
    from faceanim.rig.retarget import retarget

    face = Face.load(ICT / "generic_neutral_mesh.obj")
    n0 = face.mesh.vertices
    truth = np.zeros((db.n_bases,) + n0.shape)
    for c, name in enumerate(db.curve_names):
        p = ICT / f"{name}.obj"
        delta = _obj_vertices(p if p.is_file() else ICT / f"{name}.obj.gz") - n0
        truth += db.basis_curves[:, c, None, None] * delta[None]
    rig = retarget(face, db.basis_curves, db.curve_names)
    got = np.stack([rig.blendshape(n) for n in rig.controls])
    skin = np.asarray(face.skin)

    def error(where):
        return np.linalg.norm(got - truth, axis=2)[:, where].sum() / np.linalg.norm(truth, axis=2)[:, where].sum()

    assert error(skin) < 0.15
    # the teeth (the ICT head is the generic head in centimetres): each row with its own jaw
    from scipy.spatial import cKDTree

    head = generic_head()
    d, near = cKDTree(head.mesh.vertices).query(n0 / 100.0)
    teeth = np.isin(near, head.parts["teeth"]) & (d < 1e-4)
    assert teeth.sum() > 4000 and error(teeth) < 0.1


def test_synthesis_driven_by_the_database_own_controls_gives_its_motion_back(db):
    """A tracking made of a stretch of the database's own controls: the paper's synthesis returns
    that stretch's basis weights within 35% of their size (K = 30 neighbours are blended, so not
    exactly); the direct mapping is a least-squares fit to these very frames (in-sample), so it
    is checked only to be near them too."""
    from faceanim.drivers.video.tracking import Tracking
    from faceanim.perform import perform

    a, b = 1000, 1300
    n = b - a
    tr = Tracking(30.0, np.ones(n, bool), np.zeros((n, 6)), np.zeros((n, 19, 2)), db.raw[a:b], db.controls[a:b], 0)
    synth = perform(tr, db, whole_face=True, window=20, overlap=5)
    direct = perform(tr, db, raw=True)
    truth = db.weights[a:b]
    n_l = db.n_bases
    np.testing.assert_array_equal(synth.weights[:, :n_l], synth.weights[:, n_l:2 * n_l])  # one search: both halves
    synth.weights, direct.weights = synth.weights[:, :n_l], direct.weights[:, :n_l]
    scale = np.linalg.norm(truth, axis=1).mean()
    e_synth = np.linalg.norm(synth.weights - truth, axis=1).mean()
    e_direct = np.linalg.norm(direct.weights - truth, axis=1).mean()
    assert e_synth < 0.35 * scale and e_direct < 0.35 * scale


def test_blinks_are_read_off_the_lids_in_the_performers_own_range(db):
    """The lids' opening of a known clip: open (1.0, a little noise) with two blinks down to the
    performer's closed lid (0.08) for four frames, the left eye also squinting to 0.6 once. The
    blink curve is 0 at rest (the dead zone swallows the noise), 1 through each blink, about
    (1 - 0.6) / (1 - 0.08) past the dead zone in the squint; and the ARKit export's EyeBlink columns
    are these curves. A performer who never closes the eyes (lids down to 0.85 at most) gets a
    curve under 0.2: the closed lid is then taken as a tenth of the open one, not the shallowest dip."""
    from faceanim.drivers.video.tracking import Tracking
    from faceanim.face.controls import CONTROL_NAMES
    from faceanim.standards.arkit import ARKIT_NAMES
    from faceanim.perform import BLINK_DEAD, arkit_curves, blink_curves, perform

    n = 200
    rng = np.random.default_rng(3)
    raw = np.tile(db.raw[1000], (n, 1))
    lids = 1.0 + 0.02 * rng.standard_normal((n, 2))
    for a in (50, 140):
        lids[a:a + 4] = 0.08
    lids[100:106, 0] = 0.6  # the left eye squints
    li, ri = CONTROL_NAMES.index("eye_open_L"), CONTROL_NAMES.index("eye_open_R")
    raw[:, li], raw[:, ri] = 0.01 * lids[:, 0], 0.01 * lids[:, 1]
    tr = Tracking(30.0, np.ones(n, bool), np.zeros((n, 6)), np.zeros((n, 19, 2)), raw, np.tile(db.controls[1000], (n, 1)), 0)
    b = blink_curves(tr)
    rest = np.ones(n, bool)
    rest[45:60] = rest[95:111] = rest[135:150] = False
    assert np.abs(b[rest]).max() == 0.0
    for a in (50, 140):
        np.testing.assert_allclose(b[a + 1:a + 3], 1.0)
    squint = ((1.0 - 0.6) / (1.0 - 0.08) - BLINK_DEAD) / (1.0 - BLINK_DEAD)
    assert abs(b[102, 0] - squint) < 0.05 and b[102, 1] == 0.0
    perf = perform(tr, db)
    np.testing.assert_array_equal(perf.weights[:, 2 * db.n_bases:2 * db.n_bases + 2], b)
    curves = arkit_curves(perf, db)
    np.testing.assert_allclose(curves[:, ARKIT_NAMES.index("EyeBlinkLeft")], b[:, 0])
    np.testing.assert_allclose(curves[:, ARKIT_NAMES.index("EyeBlinkRight")], b[:, 1])
    raw[:, li] = raw[:, ri] = 0.01 * np.where(np.arange(n) % 50 < 3, 0.85, 1.0)
    assert blink_curves(tr).max() < 0.2


def test_gaze_is_read_off_the_irises(db):
    """Known iris offsets (eye widths, x to the subject's left): both irises at the clip's median
    (looking at the camera), then 0.1 to the subject's left for 20 frames, then 0.08 down. Looking
    left is the left eye's Out and the right eye's In, by the angle asin(0.1 / IRIS_RADIUS) over the
    take's angle at weight 1; looking down is Down on both; nothing else moves; through a blink (the
    iris unseen, its offset thrown off) the gaze holds; the ARKit export carries the curves."""
    from faceanim.drivers.video.tracking import Tracking
    from faceanim.face.controls import CONTROL_NAMES
    from faceanim.standards.arkit import ARKIT_NAMES
    from faceanim.perform import EYE_CONTROLS, IRIS_RADIUS, arkit_curves, perform
    from faceanim.standards.arkit import LOOK_ANGLES

    n = 120
    gaze = np.zeros((n, 4))
    gaze[40:60, [0, 2]] = 0.1
    gaze[80:100, [1, 3]] = -0.08
    raw = np.tile(db.raw[1000], (n, 1))
    lids = np.ones(n)
    lids[50:54] = 0.08  # a blink while looking left: the irises' offsets are junk then
    gaze[50:54] = [[-0.3, 0.2, -0.3, 0.2]] * 4
    for name in ("eye_open_L", "eye_open_R"):
        raw[:, CONTROL_NAMES.index(name)] = 0.01 * lids
    tr = Tracking(30.0, np.ones(n, bool), np.zeros((n, 6)), np.zeros((n, 19, 2)), raw, np.tile(db.controls[1000], (n, 1)),
                  0, gaze)
    perf = perform(tr, db)
    w = dict(zip(EYE_CONTROLS, perf.weights[:, 2 * db.n_bases:].T))
    left = np.arcsin(0.1 / IRIS_RADIUS)
    down = np.arcsin(0.08 / IRIS_RADIUS)
    np.testing.assert_allclose(w["eyeLookOutLeft"][42:58], left / LOOK_ANGLES["Out"])
    np.testing.assert_allclose(w["eyeLookInRight"][42:58], left / LOOK_ANGLES["In"])
    np.testing.assert_allclose(w["eyeLookDownLeft"][82:98], down / LOOK_ANGLES["Down"])
    np.testing.assert_allclose(w["eyeLookDownRight"][82:98], down / LOOK_ANGLES["Down"])
    for name in ("eyeLookInLeft", "eyeLookOutRight", "eyeLookUpLeft", "eyeLookUpRight"):
        assert np.abs(w[name]).max() == 0.0, name
    assert np.abs(w["eyeLookOutLeft"][:38]).max() == 0.0 and np.abs(w["eyeLookDownLeft"][:78]).max() == 0.0
    curves = arkit_curves(perf, db)
    np.testing.assert_allclose(curves[:, ARKIT_NAMES.index("EyeLookOutLeft")], w["eyeLookOutLeft"])
    np.testing.assert_allclose(curves[:, ARKIT_NAMES.index("EyeLookDownRight")], w["eyeLookDownRight"])


def test_untracked_frames_hold_the_last_tracked_values():
    from faceanim.errors import FaceAnimError
    from faceanim.perform import hold_untracked

    v = np.array([[np.nan], [1.0], [np.nan], [np.nan], [4.0], [np.nan]])
    got = hold_untracked(v, ~np.isnan(v[:, 0]))
    np.testing.assert_array_equal(got[:, 0], [1.0, 1.0, 1.0, 1.0, 4.0, 4.0])
    with pytest.raises(FaceAnimError, match="no face was found"):
        hold_untracked(v, np.zeros(6, bool))


def test_arkit_csv_round_trip(tmp_path):
    from faceanim.io.arkit_csv import read_arkit_csv, write_arkit_csv

    rng = np.random.default_rng(0)
    w, h = rng.uniform(0, 1, (90, 52)), rng.normal(0, 0.2, (90, 3))
    write_arkit_csv(tmp_path / "t.csv", w, 30.0, h)
    take = read_arkit_csv(tmp_path / "t.csv")
    np.testing.assert_allclose(take.weights, w, atol=1e-6)
    np.testing.assert_allclose(take.head, h, atol=1e-6)
    np.testing.assert_allclose(take.times, np.arange(90) / 30.0, atol=1e-9)


@needs_videos
def test_perform_command_writes_glb_csv_and_mp4(tmp_path, db):
    """d0.mp4 (78 frames): the glTF has one morph target per basis, their weights and the head's
    rotation animated per frame, the mesh's own vertices untouched; the CSV reads back as a Live
    Link Face take whose jaw opens with the performer's mouth; the MP4 is the video beside the
    face with the video's sound."""
    import subprocess

    import imageio_ffmpeg

    from faceanim.drivers.video.tracking import track_video
    from faceanim.face.controls import CONTROL_NAMES
    from faceanim.io.arkit_csv import read_arkit_csv
    from faceanim.standards.arkit import ARKIT_NAMES
    from faceanim.io.gltf import glb_json
    from faceanim.io.video import video_info
    from faceanim.perform import EYE_CONTROLS

    video = VIDEOS / "d0.mp4"
    glb, out_csv, mp4 = tmp_path / "p.glb", tmp_path / "p.csv", tmp_path / "p.mp4"
    assert run(["perform", video, "--quiet", "--bases", "-o", glb]) == 0  # --bases: Chai et al.'s synthesis
    doc = glb_json(glb)
    targets = doc["meshes"][0]["extras"]["targetNames"]
    assert targets == [f"{r}_{k + 1:02d}" for r in ("lower", "upper") for k in range(db.n_bases)] + list(EYE_CONTROLS)
    # by default: the face's ARKit targets, Apple's names, weights in 0..1, the CSV's curves
    arkit_glb = tmp_path / "a.glb"
    assert run(["perform", video, "--quiet", "-o", arkit_glb]) == 0
    adoc = glb_json(arkit_glb)
    names = adoc["meshes"][0]["extras"]["targetNames"]
    assert names == [n[0].lower() + n[1:] for n in ARKIT_NAMES]
    gltf = pygltflib.GLTF2().load_binary(str(arkit_glb))
    w = accessor(gltf, adoc["animations"][0]["samplers"][0]["output"]).reshape(78, len(names))
    assert w.min() >= 0.0 and w.max() <= 1.0 and w[:, names.index("jawOpen")].max() > 0.15  # d0 opens its lips
    anim = doc["animations"][0]
    assert [c["target"]["path"] for c in anim["channels"]] == ["weights", "rotation"]
    assert doc["accessors"][anim["samplers"][0]["input"]]["count"] == 78
    assert doc["accessors"][anim["samplers"][1]["output"]]["count"] == 78
    assert [n["name"] for n in doc["nodes"]][1:] == ["head_offset", "head"]
    import json
    import shutil

    validator = Path(__file__).resolve().parents[1] / "tools" / "validate_gltf.js"
    if shutil.which("node") and (validator.parent / "node_modules" / "gltf-validator").exists():
        report = json.loads(subprocess.run(["node", str(validator), str(glb)], capture_output=True, text=True,
                                           check=True).stdout)
        assert report["numErrors"] == 0 and report["numWarnings"] == 0, report

    assert run(["perform", video, "--quiet", "-o", out_csv]) == 0
    take = read_arkit_csv(out_csv)
    assert take.n_samples == 78
    np.testing.assert_allclose(w, take.weights, atol=2e-6)  # the glb plays the CSV's curves
    tr = track_video(video)
    mouth = tr.raw[:, CONTROL_NAMES.index("mouth_open")]
    jaw = take.weights[:, ARKIT_NAMES.index("JawOpen")]
    assert np.corrcoef(mouth[tr.tracked], jaw[tr.tracked])[0, 1] > 0.5
    from faceanim.perform import perform

    smoothed = perform(tr, db).pose[:, 0]  # the tracked yaw, smoothed by the One-Euro filter
    np.testing.assert_allclose(np.degrees(take.head[:, 0]), smoothed, atol=1e-3)
    # close to the tracked yaw, with less frame-to-frame trembling (the second differences: 0.23 of
    # the tracked yaw's measured; the Face Landmarker's yaw is steady enough that first differences,
    # which also hold the head's real turns, drop only to 0.62)
    assert np.abs(smoothed - tr.pose[:, 0]).max() < 3.0
    assert np.abs(np.diff(smoothed, 2)).mean() < 0.5 * np.abs(np.diff(tr.pose[:, 0], 2)).mean()

    assert run(["perform", video, "--quiet", "--size", "256", "-o", mp4]) == 0
    info = video_info(mp4)
    assert info.frames_expected == 78 and info.size[1] == 256 and info.size[0] > 256
    probe = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(mp4)],
                           capture_output=True, text=True, check=False).stderr
    has_sound = "Audio:" in subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(video)],
                                           capture_output=True, text=True, check=False).stderr
    assert ("Audio: aac" in probe) == has_sound


@needs_videos
def test_raw_warns_that_it_is_the_baseline(tmp_path, capsys):
    """--raw writes its CSV and says on stderr, in one line, that it is the per-frame baseline."""
    out = tmp_path / "raw.csv"
    assert run(["perform", VIDEOS / "d0.mp4", "--raw", "--quiet", "-o", out]) == 0 and out.is_file()
    err = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert len(err) == 1 and "--raw is the per-frame baseline" in err[0]
    assert run(["perform", VIDEOS / "d0.mp4", "--quiet", "-o", tmp_path / "s.csv"]) == 0
    assert "warning" not in capsys.readouterr().err


def test_perform_bad_input(tmp_path, capsys, db):
    from faceanim.render.video import write_video

    blank = tmp_path / "blank.mp4"
    write_video(blank, [np.full((64, 64, 3), 80, np.uint8)] * 5, fps=25)
    other = tmp_path / "other.npz"
    np.savez(other, a=np.zeros(3))
    foreign = tmp_path / "foreign.npz"
    data = dict(np.load(Path(__file__).resolve().parents[1] / "src" / "faceanim" / "assets" / "motion_default.npz"))
    data["control_names"] = np.array([f"other_{k}" for k in range(15)])
    np.savez(foreign, **data)
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    out = tmp_path / "o.glb"
    for args, match in [
        (["perform", blank, "-o", out], "no face was found in any frame"),
        (["perform", tmp_path / "none.mp4", "-o", out], "does not exist"),
        (["perform", blank, "--db", other, "-o", out], "not a faceanim motion database"),
        (["perform", blank, "--db", foreign, "-o", out], "built for other control parameters"),
        (["perform", blank, "--face", text, "-o", out], ""),
        (["perform", blank, "--window", "0", "-o", out], "--window"),
        (["perform", blank, "--window", "5", "--overlap", "9", "-o", out], "--overlap"),
        (["perform", blank, "-o", tmp_path / "o.txt"], ""),
        (["perform", blank, "-o", blank], "also an input"),
    ]:
        before = sorted(tmp_path.iterdir())
        assert run(args) == 2, args
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and match in err, (args, err)
        assert sorted(tmp_path.iterdir()) == before


def test_face_regions_split_each_basis_exactly(db):
    """The lower and upper copies of each retargeted basis add up to the whole basis (its lids left
    out: the blinks are the rig's own two controls), and the jaw's basis lies almost all in the
    lower copy, the brows' in the upper."""
    from faceanim.perform import EYE_CONTROLS, EYE_CURVES, face_regions, performance_rig
    from faceanim.rig.retarget import retarget

    regions = face_regions()
    np.testing.assert_allclose(regions["lower"] + regions["upper"], 1.0)
    face = Face.default()
    rig = performance_rig(face, db)
    curves = db.basis_curves[:2].copy()
    curves[:, [list(db.curve_names).index(c) for c in EYE_CURVES]] = 0.0
    whole = retarget(face, curves, db.curve_names)
    n = db.n_bases
    assert rig.controls[:2] == ["lower_01", "lower_02"] and rig.controls[n] == "upper_01"
    for i in range(2):
        np.testing.assert_allclose(rig.blendshape(rig.controls[i]) + rig.blendshape(rig.controls[n + i]),
                                   whole.blendshape(whole.controls[i]), atol=1e-12)
    jaw = db.weights[np.argmax(db.controls[:, 0])]  # the database's widest mouth opening
    assert rig.controls[2 * n:] == list(EYE_CONTROLS)
    eyes = np.zeros(len(EYE_CONTROLS))
    lower = rig.evaluate(np.r_[jaw, 0 * jaw, eyes][None])[0] - face.mesh.vertices
    upper = rig.evaluate(np.r_[0 * jaw, jaw, eyes][None])[0] - face.mesh.vertices
    assert np.linalg.norm(lower) > 3 * np.linalg.norm(upper)


@needs_videos
def test_the_avatar_mouth_follows_the_performer(db):
    """d18 (a man opening his mouth wide, three times): the default face's mouth opening (inner
    lips) under faceanim perform's feature-wise synthesis follows the mouth opening tracked in the
    video (r > 0.85, the issue's goal), and better than the paper's one search on all 15 controls,
    whose distances the tilts of the lips (noisy in video) dominate."""
    from faceanim.drivers.video.tracking import track_video
    from faceanim.face.controls import CONTROL_NAMES
    from faceanim.perform import perform, performance_rig

    tr = track_video(VIDEOS / "d18.mp4")
    face = Face.default()
    rig = performance_rig(face, db)
    head = generic_head()

    def mouth(perf):
        lm = np.stack([head.landmarks(v)[[13, 14]] for v in rig.evaluate(perf.weights)])
        return np.linalg.norm(lm[:, 0] - lm[:, 1], axis=1)

    video = tr.raw[:, CONTROL_NAMES.index("mouth_open")]
    ok = tr.tracked
    ours = np.corrcoef(mouth(perform(tr, db))[ok], video[ok])[0, 1]
    paper = np.corrcoef(mouth(perform(tr, db, whole_face=True, window=20, overlap=5))[ok], video[ok])[0, 1]
    assert ours > 0.85 and ours > paper + 0.1


FW = DATA / "facewarehouse-tester1"


@pytest.mark.skipif(not FW.is_dir(), reason="../shared/data/facewarehouse-tester1 is not here")
def test_retargeted_bases_span_another_persons_real_expressions(db):
    """The 14 bases retargeted onto FaceWarehouse tester 1 (another person, another mesh) explain
    most of the 19 real expressions scanned of that person (each aligned on the back of the head;
    least-squares weights over the face): median over 0.75 of each expression's displacement
    energy."""
    from faceanim.face.frame import similarity
    from faceanim.io.meshio import load_mesh
    from faceanim.rig.retarget import retarget

    face = Face.load(FW / "pose_0.obj")
    v0 = face.mesh.vertices
    region = np.asarray(face.face_region)
    back = face.frame.to_local(v0)[:, 2] < np.percentile(face.frame.to_local(v0)[:, 2], 30)
    shapes = []
    for k in range(1, 20):
        vk = load_mesh(FW / f"pose_{k}.obj").vertices
        s, r, t = similarity(vk[back], v0[back], scale=False)
        shapes.append(((vk @ r.T) * s + t - v0)[region].ravel())

    def explained():
        rig = retarget(face, db.basis_curves, db.curve_names)
        b = np.stack([rig.blendshape(n)[region].ravel() for n in rig.controls], axis=1)
        out = []
        for d in shapes:
            lam, *_ = np.linalg.lstsq(b, d, rcond=None)
            out.append(1 - np.sum((d - b @ lam) ** 2) / np.sum(d ** 2))
        return np.median(out)

    assert explained() > 0.75


def test_the_head_turns_in_the_face_own_frame_whatever_the_mesh_axes(db):
    """A face given lying on its back (its mesh turned -90 degrees about x, as a z-up file would
    be): the head's yaw, pitch and roll turn it about its own axes, so every frame is the upright
    face's frame turned the same way (not a turn about the mesh's y axis)."""
    from faceanim.perform import Performance, performance_frames, performance_rig

    face = Face.default()
    q = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])  # -90 degrees about x
    lying = Face(Mesh(face.mesh.vertices @ q.T, face.mesh.faces, name="lying"), face.landmarks @ q.T)
    pose = np.zeros((3, 6))
    pose[:, :3] = [[20.0, 0, 0], [0, 15.0, 0], [0, 0, 10.0]]
    perf = Performance(30.0, np.zeros((3, 2 * db.n_bases + 10)), pose, np.ones(3, bool))
    up = list(performance_frames(perf, performance_rig(face, db), face))
    down = list(performance_frames(perf, performance_rig(lying, db), lying))
    for a, b in zip(up, down):
        np.testing.assert_allclose(b, a @ q.T, atol=1e-9)
    assert np.linalg.norm(up[0] - face.mesh.vertices, axis=1).max() > 0.02  # a real turn


def test_a_rendered_gaze_is_read_back():
    """The loop as an oracle: the default face rendered looking to its left (eyeLookOutLeft and
    eyeLookInRight at 0.8, its own shapes turning its eyeballs) between neutral frames, tracked
    from the renders: the gaze curves give the two looks back (their mean within 0.1, each within
    0.2: MediaPipe reads one iris of a render further in than the other) and leave the other six
    near 0 (under 0.1)."""
    from faceanim.drivers.video.tracking import track_frames
    from faceanim.perform import EYE_CONTROLS, blink_curves, look_curves
    from faceanim.render import OffscreenRenderer
    from faceanim.rig.arkit import look_shapes

    face = Face.default()
    shapes = look_shapes(face)
    v0 = face.mesh.vertices
    with OffscreenRenderer(face.mesh, size=(512, 512), **face.view(yaw=0.0, pitch=0.0)) as r:
        rest, look = r.render(v0), r.render(v0 + 0.8 * (shapes["eyeLookOutLeft"] + shapes["eyeLookInRight"]))
    tr = track_frames([rest] * 30 + [look] * 20 + [rest] * 30, 30.0)
    curves = dict(zip(EYE_CONTROLS[2:], look_curves(tr, blink_curves(tr))[35:45].mean(axis=0)))
    out_left, in_right = curves.pop("eyeLookOutLeft"), curves.pop("eyeLookInRight")
    assert abs(0.5 * (out_left + in_right) - 0.8) < 0.1 and abs(out_left - 0.8) < 0.2 and abs(in_right - 0.8) < 0.2
    assert max(curves.values()) < 0.1, curves


def _head_mouth(db, weights) -> np.ndarray:
    """The mouth measures of basis weights (F, L) played on the whole generic head mesh (the
    shapes summed on every vertex, the landmarks read off the moved mesh)."""
    from faceanim.perform import MOUTH_LANDMARKS, mouth_measures

    head = generic_head()
    curves = np.asarray(weights) @ db.basis_curves
    out = []
    for c in curves:
        v = head.mesh.vertices + sum(w * head.shape(n) for w, n in zip(c, db.curve_names))
        out.append(mouth_measures(head.landmarks(v)[list(MOUTH_LANDMARKS)]))
    return np.array(out)


REST = 40  # frames of the head at rest before a tracking's motion


def _mouth_tracking(db, frames):
    """A tracking (fronto-parallel, in the generic head's units, as tracking makes them) of the
    generic head's own mouth at rest for :data:`REST` frames, then doing what it does in
    ``frames`` of the database; its controls are the database's."""
    from faceanim.drivers.video.tracking import Tracking
    from faceanim.face.controls import FEATURE_NAMES, FEATURES

    head = generic_head()
    curves = np.r_[np.zeros((REST, db.basis_curves.shape[1])), db.weights[frames] @ db.basis_curves]
    lm = np.stack([head.landmarks(head.mesh.vertices + sum(w * head.shape(n) for w, n in zip(c, db.curve_names)))
                   for c in curves])
    n = len(curves)
    feats = lm[:, [FEATURES[k] for k in FEATURE_NAMES], :2]
    rest = np.repeat(db.controls[db.neutral][None], REST, axis=0)
    return Tracking(30.0, np.ones(n, bool), np.zeros((n, 6)), feats, np.r_[rest, db.raw[frames]],
                    np.r_[rest, db.controls[frames]], 0, np.zeros((n, 4)), lm[:, 13, 1] - lm[:, 14, 1])


def test_database_mouth_is_the_head_played(db):
    """The database's mouth measures per frame (read off the landmarks' share of each shape) are
    those of the whole head mesh played with the frame's weights."""
    from faceanim.perform import database_mouth

    frames = [0, 700, 1500, 2300, db.n_frames - 1]
    np.testing.assert_allclose(database_mouth(db)[frames], _head_mouth(db, db.weights[frames]), atol=1e-9)


def test_performer_mouth_in_the_heads_units(db):
    """A performer whose mouth rests, then does what the generic head's does in some database
    frames: their mouth measures come back as the head's own in those frames (the width and smile
    from the mouth at rest, found by its stillness; the gap whole), with or without the inner gap
    tracked (without: from the outer lips' change)."""
    from faceanim.perform import database_mouth, performer_mouth, rest_frames

    frames = [300, 900, 1500, 2100, 2101, 2102, 2103, 2104, 2105, 2106]
    tr = _mouth_tracking(db, frames)
    assert set(rest_frames(performer_mouth(tr))) <= set(range(REST))
    want = database_mouth(db)[frames]
    np.testing.assert_allclose(performer_mouth(tr)[REST:], want, atol=1e-9)
    tr.inner_gap = None
    outer = performer_mouth(tr)
    np.testing.assert_allclose(outer[REST:, 1:], want[:, 1:], atol=1e-9)
    assert np.corrcoef(outer[REST:, 0], want[:, 0])[0, 1] > 0.9


def test_the_synthesised_mouth_is_held_to_the_performers(db):
    """A stretch of the database's own motion as a tracking (its controls, and the head's mouth in
    those frames): with the mouth followed, the lower face's mouth measures (played on the whole
    head) come within a tenth of their spread of the truth, several times nearer than the K
    blended neighbours alone."""
    from faceanim.perform import database_mouth, perform

    frames = np.arange(1000, 1120)
    tr = _mouth_tracking(db, frames)
    truth = database_mouth(db)[frames]
    spread = database_mouth(db).std(axis=0)
    n_l = db.n_bases
    held = _head_mouth(db, perform(tr, db).weights[REST:, :n_l])
    free = _head_mouth(db, perform(tr, db, follow_mouth=False).weights[REST:, :n_l])
    e_held = np.abs(held - truth).mean(axis=0) / spread
    e_free = np.abs(free - truth).mean(axis=0) / spread
    assert np.all(e_held < 0.1), e_held
    assert np.all(e_held < 0.5 * e_free), (e_held, e_free)


@needs_videos
def test_the_avatar_lips_open_as_the_performers_on_a_held_out_clip(db):
    """d14 (held out from the tuning; a woman talking): the default face's inner lip gap under
    perform follows the gap tracked in the video (r > 0.85; 0.48 before the mouth was followed)
    with a p5-p95 range 0.8-1.25 of the performer's (the issue's goals), both in the generic head's
    units (the face's scaled by its eyes' distance over the head's)."""
    from faceanim.drivers.video.tracking import track_video
    from faceanim.perform import MOUTH_LANDMARKS, mouth_measures, perform, performance_rig, performer_mouth

    tr = track_video(VIDEOS / "d14.mp4")
    face = Face.default()
    rig = performance_rig(face, db)
    head = generic_head()
    frame = face.frame.rotation  # rows: the face's left, up, forward

    def mouth(vertices):
        return mouth_measures(head.landmarks(vertices)[list(MOUTH_LANDMARKS)] @ frame.T)

    lm = head.landmarks()
    scale = np.linalg.norm(lm[33] - lm[263]) / face.frame.iod
    avatar = np.array([mouth(v)[0] for v in rig.evaluate(perform(tr, db).weights)]) * scale
    video = performer_mouth(tr)[:, 0]
    ok = tr.tracked
    r = np.corrcoef(avatar[ok], video[ok])[0, 1]
    span = np.subtract(*np.percentile(avatar[ok], [95, 5])) / np.subtract(*np.percentile(video[ok], [95, 5]))
    assert r > 0.85 and 0.8 < span < 1.25, (r, span)


def test_a_lost_face_holds_then_eases_to_rest(db):
    """A face lost for 3 s in the middle of a take: the expression holds for half a second after the
    last tracked frame (and before the face comes back), is at rest (all weights 0) in the middle of
    the gap, and eases by a half cosine in between; a face lost for less than a second never fades."""
    from faceanim.drivers.video.tracking import Tracking
    from faceanim.perform import lost_face_fade, perform

    fade = lost_face_fade(np.r_[np.ones(30, bool), np.zeros(90, bool), np.ones(30, bool)], 30.0)
    np.testing.assert_array_equal(fade[:45], 1.0)
    np.testing.assert_array_equal(fade[105:], 1.0)
    assert fade[75] == 0.0
    assert fade[52] == pytest.approx(0.5 * (1 + np.cos(np.pi * (23 / 30 - 0.5) / 0.5)))  # 23 frames past the last seen
    assert np.all(np.diff(fade[30:75]) <= 0) and np.all(np.diff(fade[75:120]) >= 0)
    short = np.r_[np.ones(5, bool), np.zeros(25, bool), np.ones(5, bool)]
    np.testing.assert_array_equal(lost_face_fade(short, 30.0), 1.0)
    a, n = 1000, 150
    tracked = np.r_[np.ones(30, bool), np.zeros(90, bool), np.ones(30, bool)]
    nan = np.where(tracked[:, None], 1.0, np.nan)
    tr = Tracking(30.0, tracked, np.zeros((n, 6)) * nan, np.zeros((n, 19, 2)) * nan[:, :, None],
                  db.raw[a:a + n] * nan, db.controls[a:a + n] * nan, 0)
    w = perform(tr, db, follow_mouth=False).weights
    assert np.abs(w[29]).max() > 0 and np.abs(w[75]).max() == 0.0
    # once the synthesis window holds only the held frame, the expression is that held one, faded
    np.testing.assert_allclose(w[36:60], np.repeat(w[36:37], 24, axis=0) * fade[36:60, None], atol=1e-12)
