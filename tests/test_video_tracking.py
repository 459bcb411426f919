"""Video analysis (Chai et al. 2003, section 2): head pose against renders of known pose, control
parameters against the events the talking-head videos show, frames without a face, the CSV and
bad input."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from faceanim.cli import main
from faceanim.drivers.video import tracking as T
from faceanim.errors import FaceAnimError, InputFileError, LandmarkError

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
VIDEOS = DATA / "talking-head-videos"
needs_videos = pytest.mark.skipif(not VIDEOS.is_dir(), reason="../shared/data/talking-head-videos is not here")


def run(args) -> int:
    try:
        return main([str(a) for a in args])
    except SystemExit as exc:
        return exc.code


@pytest.fixture(scope="module")
def posed_frames():
    """The default head rendered (textured, perspective) at known camera angles: (frames, camera
    yaws, camera pitches)."""
    from faceanim.face.face import HEAD_MARGIN, Face
    from faceanim.render import OffscreenRenderer

    face = Face.default()
    yaws = [0.0, 25.0, -25.0, 10.0, 0.0, 0.0]
    pitches = [0.0, 0.0, 0.0, 0.0, 15.0, -15.0]
    frames = []
    for yaw, pitch in zip(yaws, pitches):
        with OffscreenRenderer(face.mesh, size=(384, 384), **face.view(margin=HEAD_MARGIN, yaw=yaw, pitch=pitch)) as r:
            frames.append(r.render())
    return frames, np.array(yaws), np.array(pitches)


def test_head_pose_of_renders_at_known_angles(posed_frames):
    """A camera turned to the subject's left by a (yaw) sees a head turned to its own right by a;
    a camera above (pitch) sees a head nodded down: the tracked yaw and pitch follow within 4
    degrees, and the fronto-parallel features stay put while the head turns (they are the same
    face: the control parameters change little)."""
    frames, yaws, pitches = posed_frames
    tr = T.track_frames([f for f in frames for _ in range(4)], 25.0)  # each held for 4 frames
    assert tr.tracked.all()
    rel_yaw = tr.pose[3::4, 0] - tr.pose[3, 0]
    rel_pitch = tr.pose[3::4, 1] - tr.pose[3, 1]
    np.testing.assert_allclose(rel_yaw, -yaws, atol=4.0)
    np.testing.assert_allclose(rel_pitch, pitches, atol=4.0)
    assert np.abs(tr.controls[3:16:4][:, [0, 1, 8, 9]]).max() < 0.12  # mouth and eyes: the same face


def test_a_tilted_picture_is_a_head_roll(posed_frames):
    from PIL import Image

    frame = posed_frames[0][0]
    angles = (0.0, 15.0, -15.0)
    tilted = [np.asarray(Image.fromarray(frame).rotate(a, resample=Image.BILINEAR)) for a in angles]
    # each picture held for 4 frames: the face mesh's video mode follows a jump over a few frames
    tr = T.track_frames([t for t in tilted for _ in range(4)], 25.0)
    roll = tr.pose[3::4, 2] - tr.pose[3, 2]
    # a picture turned counter-clockwise tilts the head to the viewer's left: to its own right
    np.testing.assert_allclose(roll, angles, atol=3.0)


def test_frames_without_a_face_are_marked_and_tracking_recovers(posed_frames):
    frames = list(posed_frames[0][:2])
    blank = np.full_like(frames[0], 60)
    tr = T.track_frames([frames[0], blank, blank, frames[0], frames[1]], 30.0)
    np.testing.assert_array_equal(tr.tracked, [True, False, False, True, True])
    assert np.isnan(tr.controls[1:3]).all() and np.isnan(tr.pose[1:3]).all()
    assert np.isfinite(tr.controls[[0, 3, 4]]).all()
    np.testing.assert_allclose(tr.pose[3, :3], tr.pose[0, :3], atol=1.0)  # the same picture again


def test_control_parameters_of_known_features():
    """The parameters of a hand-made feature set: analytic values."""
    f = {n: np.zeros(2) for n in T.FEATURE_NAMES}
    f.update(mouth_corner_R=np.array([-0.025, -0.05]), mouth_corner_L=np.array([0.025, -0.05]),
             upper_lip=np.array([0.0, -0.04]), lower_lip=np.array([0.0, -0.06]),
             nostril_R=np.array([-0.015, -0.02]), nostril_L=np.array([0.015, -0.02]), nose_tip=np.array([0.0, -0.01]),
             eye_outer_R=np.array([-0.045, 0.03]), eye_inner_R=np.array([-0.015, 0.03]),
             eye_upper_R=np.array([-0.03, 0.036]), eye_lower_R=np.array([-0.03, 0.026]),
             eye_outer_L=np.array([0.045, 0.03]), eye_inner_L=np.array([0.015, 0.03]),
             eye_upper_L=np.array([0.03, 0.034]), eye_lower_L=np.array([0.03, 0.028]),
             brow_inner_R=np.array([-0.012, 0.05]), brow_outer_R=np.array([-0.05, 0.05 + 0.038 * np.tan(np.radians(10))]),
             brow_inner_L=np.array([0.012, 0.05]), brow_outer_L=np.array([0.05, 0.05]))
    z = T.control_parameters(np.stack([f[n] for n in T.FEATURE_NAMES]))
    want = dict(mouth_open=0.02, mouth_width=0.05, mouth_centre_x=0.0, mouth_centre_y=-0.05, lips_tilt=0.0,
                corners_tilt=0.0, nose_width=0.03, nose_height=0.01, eye_open_R=0.01, eye_open_L=0.006,
                brow_tilt_R=10.0, brow_tilt_L=0.0, brow_gap=0.024)
    for name, value in want.items():
        assert z[T.CONTROL_NAMES.index(name)] == pytest.approx(value, abs=1e-9), name
    # normalised against itself: all zero; a mouth opened by half its width reads 0.5
    feats = np.stack([f[n] for n in T.FEATURE_NAMES])
    np.testing.assert_allclose(T.normalise(z[None], z, feats), 0.0, atol=1e-12)
    opened = z.copy()
    opened[0] += 0.025
    assert T.normalise(opened[None], z, feats)[0, 0] == pytest.approx(0.5)


@needs_videos
def test_real_videos_show_their_events():
    """The README's table: frame counts, and what happens in the clips: a jaw drop in d18, a
    one-sided eye closure in d14, a broad smile in d0."""
    d18 = T.track_video(VIDEOS / "d18.mp4")
    assert d18.n_frames == 216 and d18.fps == 30 and d18.tracked.all()
    assert np.nanmax(d18.controls[:, 0]) > 0.6  # the mouth opens by more than half its width
    d14 = T.track_video(VIDEOS / "d14.mp4")
    assert d14.n_frames == 536
    right, left = d14.controls[:, 8], d14.controls[:, 9]
    # looked at: frames 16-20 she shuts both eyes (each lid closes by a third of the eye's width);
    # about frame 390 she half-winks, her left eye closing further than her right (0.20 against 0.11
    # measured with the Face Landmarker; the legacy face mesh read frame 20 as a right-eye wink)
    assert ((right[10:30] < -0.3) & (left[10:30] < -0.3)).any()
    assert ((left[380:400] < -0.15) & (left[380:400] < right[380:400] - 0.06)).any()
    d0 = T.track_video(VIDEOS / "d0.mp4")
    assert d0.n_frames == 78 and d0.fps == 25
    assert np.nanpercentile(d0.controls[:, 1], 95) > 0.25  # the grin widens the mouth by a quarter


@needs_videos
def test_track_command_writes_the_csv(tmp_path):
    """By default the head and ARKit's 52 curves solved per frame (the library's solve on the same
    tracking); --tracker synthesis the paper's 15 control parameters; --tracker mediapipe
    MediaPipe's scores, the same as the library's tracking holds."""
    from faceanim.face.mediapipe import BLENDSHAPE_NAMES
    from faceanim.perform import solve_performance
    from faceanim.standards.arkit import APPLE_NAMES

    lib = T.track_video(VIDEOS / "d0.mp4")
    out = tmp_path / "d0.csv"
    assert run(["track", VIDEOS / "d0.mp4", "--quiet", "-o", out]) == 0
    rows = list(csv.reader(out.open()))
    assert rows[0][:4] == ["frame", "time", "tracked", "head_yaw"] and rows[0][9:] == list(APPLE_NAMES)
    got = np.array([[float(c) for c in r[3:]] for r in rows[1:]])
    np.testing.assert_allclose(got[:, :6], lib.pose, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(got[:, 6:], solve_performance(lib, smooth_head=False).weights, atol=2e-6)
    assert got[:, 6 + APPLE_NAMES.index("jawOpen")].max() > 0.2  # d0 opens its mouth wide

    assert run(["track", VIDEOS / "d0.mp4", "--tracker", "synthesis", "--quiet", "-o", out]) == 0
    rows = list(csv.reader(out.open()))
    assert rows[0][:4] == ["frame", "time", "tracked", "head_yaw"] and rows[0][-1] == "brow_gap"
    assert len(rows) == 79 and len(rows[0]) == 3 + 6 + 15
    got = np.array([[float(c) for c in r[3:]] for r in rows[1:]])
    np.testing.assert_allclose(got[:, 6:], lib.controls, rtol=1e-4, atol=1e-5)

    assert run(["track", VIDEOS / "d0.mp4", "--tracker", "mediapipe", "--quiet", "-o", out]) == 0
    rows = list(csv.reader(out.open()))
    got = np.array([[float(c) for c in r[9:]] for r in rows[1:]])
    for k, name in enumerate(APPLE_NAMES):
        expect = lib.scores[:, BLENDSHAPE_NAMES.index(name)] if name in BLENDSHAPE_NAMES else 0.0
        np.testing.assert_allclose(got[:, k], expect, atol=2e-6)


def test_bad_input(tmp_path, capsys):
    from faceanim.render.video import write_video

    blank = tmp_path / "blank.mp4"
    write_video(blank, [np.full((64, 64, 3), 80, np.uint8)] * 5, fps=25)
    empty = tmp_path / "empty.mp4"
    empty.write_bytes(b"")
    junk = tmp_path / "junk.mp4"
    junk.write_bytes(b"\x00\x00\x00\x18ftypmp42" + b"\x13" * 300)
    clip_csv = tmp_path / "clip.csv"  # a video named like the output: ffmpeg reads it all the same
    clip_csv.write_bytes(blank.read_bytes())
    out = tmp_path / "o.csv"
    for args, match in [
        (["track", blank, "-o", out], "no face was found in any frame"),
        (["track", empty, "-o", out], "is empty"),
        (["track", junk, "-o", out], "not a readable video"),
        (["track", tmp_path / "none.mp4", "-o", out], "does not exist"),
        (["track", "-o", out], "a video file or --camera"),
        (["track", blank, "--camera", "0", "-o", out], "a video file or --camera"),
        (["track", clip_csv, "-o", clip_csv], "is also an input"),
        (["track", blank, "--neutral-frame", "-1", "-o", out], "--neutral-frame"),
    ]:
        before = sorted(tmp_path.iterdir())
        assert run(args) == 2, args
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and match in err, (args, err)
        assert sorted(tmp_path.iterdir()) == before


def test_neutral_frame_outside_the_clip_or_without_a_face(posed_frames):
    frames = [posed_frames[0][0], np.full_like(posed_frames[0][0], 60)]
    with pytest.raises(LandmarkError, match="outside the video's 2 frames"):
        T.track_frames(frames, 25.0, neutral_frame=5)
    with pytest.raises(LandmarkError, match="no face was found in frame 1"):
        T.track_frames(frames, 25.0, neutral_frame=1)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.binary(max_size=400))
def test_video_reader_takes_any_bytes(tmp_path, blob):
    from faceanim.io.video import video_frames, video_info

    p = tmp_path / "x.mp4"
    p.write_bytes(blob)
    try:
        info = video_info(p)
    except FaceAnimError as exc:
        assert "\n" not in str(exc)
        return
    for frame in video_frames(info):
        assert frame.shape == (info.size[1], info.size[0], 3)


def test_an_unreadable_video_is_one_line(tmp_path):
    from faceanim.io.video import video_info

    with pytest.raises(InputFileError, match="is a folder"):
        video_info(tmp_path)


def test_euler_angles_of_known_rotations():
    """Ry(yaw) Rx(pitch) Rz(roll) in camera coordinates back to the three angles; a turn to the
    head's own left sends its nose to the camera's +x."""
    def rot(axis, deg):
        a = np.radians(deg)
        c, s = np.cos(a), np.sin(a)
        return {"y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
                "x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
                "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]

    for yaw, pitch, roll in [(20, 0, 0), (0, 15, 0), (0, 0, -10), (30, -20, 12)]:
        r = rot("y", yaw) @ rot("x", pitch) @ rot("z", roll)
        np.testing.assert_allclose(T.euler_degrees(r), (yaw, pitch, roll), atol=1e-9)
    assert (rot("y", 20) @ [0, 0, 1])[0] > 0  # the nose towards +x: the subject's left
