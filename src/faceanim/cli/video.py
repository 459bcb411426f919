"""faceanim track: head pose and expression control parameters from a video (Chai et al. 2003)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from faceanim.cli.common import (
    CommandError,
    _arg_type,
    add_output,
    check_outputs,
    progress,
    report,
)
from faceanim.limits import MAX_FRAMES


def _camera_frames(index: int, n_frames: int):
    """Frames from a camera (OpenCV), RGB, at most ``n_frames``; its frame rate (30 if unknown)."""
    import cv2

    from faceanim.io.files import native_stderr_quiet

    with native_stderr_quiet():  # OpenCV logs its failed probes of the camera devices
        cap = cv2.VideoCapture(index)
        opened = cap.isOpened()
    if not opened:
        raise CommandError(f"no camera {index} on this machine; give a video file instead")
    fps = cap.get(cv2.CAP_PROP_FPS) or 30.0

    def frames():
        try:
            for _ in range(n_frames):
                ok, bgr = cap.read()
                if not ok:
                    break
                yield bgr[..., ::-1]
        finally:
            cap.release()

    return frames(), float(fps)


def _cmd_track(args) -> None:
    from faceanim.drivers.video.tracking import CONTROL_NAMES, POSE_NAMES, track_frames
    from faceanim.io.curves import write_curves_csv
    from faceanim.io.video import video_frames, video_info

    if (args.video is None) == (args.camera is None):
        raise CommandError("give a video file or --camera N (one of them)")
    out = Path(args.output)
    if args.video is not None and out.resolve() == Path(args.video).resolve():
        raise CommandError(f"the output '{out}' is the input video; give the output its own path")
    check_outputs(args.output)
    if args.video is not None:
        info = video_info(args.video)
        frames, fps, total = video_frames(info), info.fps, info.frames_expected
    else:
        frames, fps = _camera_frames(args.camera, args.frames)
        total = args.frames
    with progress(total, "tracking", args.quiet) as bar:
        tr = track_frames(frames, fps, args.neutral_frame, bar)
    names = [f"head_{n}" for n in POSE_NAMES] + list(CONTROL_NAMES)
    written = write_curves_csv(out, names, np.hstack([tr.pose, tr.controls]), tr.fps, tr.tracked)
    print(f"tracked {int(tr.tracked.sum())} of {tr.n_frames} frames at {tr.fps:g} fps; neutral frame {tr.neutral}")
    report([written])


def register(sub) -> None:
    t = sub.add_parser("track", help="head pose (6 DOF) and the 15 expression control parameters of a video's face, "
                                     "per frame, as CSV (Chai et al. 2003)",
                       description="Track the face in a video (or a camera) with the MediaPipe face mesh: per frame "
                                   "the head's yaw, pitch, roll (degrees), position (x, y pixels of the nose bridge) "
                                   "and scale (pixels per metre), and the paper's 15 control parameters from 19 "
                                   "features seen fronto-parallel (mouth 6, nose 2, eyes 2, brows 5), normalised "
                                   "against the performer's neutral frame. Frames without a face have tracked=0 "
                                   "and empty cells.")
    t.add_argument("video", nargs="?", metavar="VIDEO", help="a video file (MP4, MOV, MKV, AVI, WebM)")
    t.add_argument("--camera", type=_arg_type("--camera", 0, 63, integer=True), metavar="N",
                   help="track camera N instead of a file")
    t.add_argument("--frames", type=_arg_type("--frames", 1, MAX_FRAMES, integer=True), default=300,
                   help="frames to take from a camera")
    t.add_argument("--neutral-frame", type=_arg_type("--neutral-frame", 0, MAX_FRAMES, integer=True), metavar="N",
                   help="the frame with the performer's neutral face (default: found automatically)")
    t.add_argument("--quiet", action="store_true", help="no progress bar")
    add_output(t, [".csv"])
    t.set_defaults(func=_cmd_track)
