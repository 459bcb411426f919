"""faceanim track, faceanim mocap: performance from video (Chai et al. 2003): tracking, motion databases."""

from __future__ import annotations

import sys
from pathlib import Path

from faceanim.cli.commands import HELP
from faceanim.cli.common import (
    CommandError,
    own_targets,
    play_own,
    _arg_type,
    add_face,
    add_output,
    check_outputs,
    load_face,
    progress,
    report,
)

from faceanim.export import WRITERS, suffixes
from faceanim.limits import MAX_FRAMES


TRACKER_HELP = ("what turns the tracked landmarks into ARKit's 52 curves: solve (default: the generic head's own "
                "ARKit shapes fitted to each frame's 478 landmarks, with the performer's neutral from the clip), "
                "synthesis (Chai et al.'s motion database synthesis, the paper's method) or mediapipe (MediaPipe's "
                "own 52 blendshape scores, unchanged: the baseline)")


def add_tracker(p, synthesis_options: bool = False) -> None:
    p.add_argument("--tracker", choices=("solve", "synthesis", "mediapipe"), default=None if synthesis_options else "solve",
                   help=TRACKER_HELP + ("; an option of the synthesis (--db, --window, --k, --overlap, --raw, "
                                        "--whole-face, --bases) chooses it" if synthesis_options else ""))


def _even(name: str, low: int, high: int):
    """An argparse type: a whole, even number in [low, high] (H.264 needs even frame sizes)."""
    import argparse

    base = _arg_type(name, low, high, integer=True)

    def parse(text: str) -> int:
        value = base(text)
        if value % 2:
            raise argparse.ArgumentTypeError(f"{name} must be even (video needs even sizes), got {value}")
        return value

    parse.__name__ = name.lstrip("-")
    return parse


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
    import numpy as np

    from faceanim.drivers.video.tracking import CONTROL_NAMES, POSE_NAMES, track_frames
    from faceanim.io.curves import write_curves_csv
    from faceanim.io.video import video_frames, video_info

    if (args.video is None) == (args.camera is None):
        raise CommandError("give a video file or --camera N (one of them)")
    out = Path(args.output)
    check_outputs(args.output)
    if args.video is not None:
        info = video_info(args.video)
        frames, fps, total = video_frames(info), info.fps, info.frames_expected
    else:
        frames, fps = _camera_frames(args.camera, args.frames)
        total = args.frames
    with progress(total, "tracking", args.quiet) as bar:
        tr = track_frames(frames, fps, args.neutral_frame, bar)
    if args.tracker == "synthesis":  # the paper's video analysis: its 15 control parameters
        names = [f"head_{n}" for n in POSE_NAMES] + list(CONTROL_NAMES)
        values = np.hstack([tr.pose, tr.controls])
        what = f"the 15 control parameters against neutral frame {tr.neutral}"
    else:  # ARKit's 52 curves per frame, as tracked (NaN where no face was found)
        from faceanim.perform import mediapipe_performance, solve_performance
        from faceanim.standards.arkit import APPLE_NAMES

        if not tr.tracked.any():
            raise CommandError("no face was found in any frame; give a video where the face is seen")
        perf = solve_performance(tr, smooth_head=False) if args.tracker == "solve" else \
            mediapipe_performance(tr, smooth_head=False)
        curves = np.where(tr.tracked[:, None], perf.weights, np.nan)
        names = [f"head_{n}" for n in POSE_NAMES] + list(APPLE_NAMES)
        values = np.hstack([tr.pose, curves])
        what = "ARKit's 52 curves " + ("solved per frame" if args.tracker == "solve" else "as MediaPipe scores them")
    written = write_curves_csv(out, names, values, tr.fps, tr.tracked)
    print(f"tracked {int(tr.tracked.sum())} of {tr.n_frames} frames at {tr.fps:g} fps; {what}")
    report([written])


def _cmd_mocap_build(args) -> None:
    import numpy as np

    from faceanim.build.motion import build_database
    from faceanim.drivers.video.tracking import track_video
    from faceanim.io.arkit_csv import read_arkit_csv

    out = Path(args.output)
    check_outputs(args.output)
    takes = [(Path(p).stem, read_arkit_csv(p)) for p in args.takes]
    motion = None
    if args.head_motion:
        tr = track_video(args.head_motion)
        pose = tr.pose[tr.tracked, :3]
        motion = pose - np.median(pose, axis=0)  # turns about the performer's usual pose
    db = build_database(takes, args.fps, motion, pose=args.pose)
    db.save(out)
    err = db.rotation_error
    note = (f"; head rotation recovered within {np.median(err):.2f} degrees (median), {np.percentile(err, 95):.2f} "
            "(95th percentile) of the applied one" if np.isfinite(err).all() else "")
    print(f"{db.n_frames} frames from {len(takes)} take(s) at {db.fps:g} fps, {len(db.marker_vertices)} markers, "
          f"{db.n_bases} deformation bases{note}")
    report([out])


def _output(args, csv_is: str) -> tuple[Path, str]:
    """The checked output path of a command that writes .glb, .mp4 or .csv of a face, and its
    suffix: writable (that it is no input is checked for every command before it runs:
    :func:`faceanim.cli.common.outputs_are_not_inputs`); a .csv (which ``csv_is``, not a face) refuses
    --face and --landmarks."""
    out = Path(args.output)
    check_outputs(args.output)
    suffix = out.suffix.lower()
    if suffix in WRITERS and not WRITERS[suffix].shows_face and (args.face or args.landmarks):
        what = csv_is if suffix == ".csv" else "holds mouth cues"
        raise CommandError(f"a {suffix} output {what}, not a face: drop --face/--landmarks, or write .glb or .mp4")
    return out, suffix


def _cmd_perform(args) -> None:
    from faceanim.build.motion import load_database
    from faceanim.drivers.video.tracking import track_frames
    from faceanim.io.video import video_frames, video_info
    from faceanim.perform import default_database, perform, write_performance

    out, suffix = _output(args, "holds ARKit curves")
    synthesis_only(args)
    if args.tracker == "synthesis" and args.overlap > args.window:
        raise CommandError(f"--overlap ({args.overlap}) cannot exceed --window ({args.window})")
    info = video_info(args.video)
    if suffix == ".mp4":
        from faceanim.limits import check_video

        w, h = info.size
        check_video(info.frames_expected, max(2, int(round(w * args.size / h / 2)) * 2) + args.size, args.size)
    db = (load_database(args.db) if args.db else default_database()) if args.tracker == "synthesis" else None
    if args.bases and suffix == ".vrm":
        raise CommandError("--bases writes faceanim's own basis targets to .glb; a .vrm output plays ARKit's curves "
                           "onto a --face VRM avatar (leave out --bases)")
    own = own_targets(args, suffix) and not args.bases
    face = load_face(args) if WRITERS[suffix].shows_face and not own else None
    with progress(info.frames_expected, "tracking", args.quiet) as bar:
        tr = track_frames(video_frames(info), info.fps, args.neutral_frame, bar)
    perf, how = performance_of(tr, args, db)
    print(f"tracked {int(tr.tracked.sum())} of {tr.n_frames} frames at {tr.fps:g} fps; {how}")
    if own:
        import numpy as np

        from faceanim.perform import arkit_curves

        report([play_own(args, out, arkit_curves(perf, db), perf.fps, "performance", head=np.radians(perf.pose[:, :3]))])
        return
    with progress(perf.n_frames if suffix == ".mp4" else 0, "rendering", args.quiet or suffix != ".mp4") as bar:
        written = write_performance(out, perf, db, face, args.video, args.size, bar, bases=args.bases)
    report(written)


# the options of --tracker synthesis alone, and their defaults
SYNTHESIS_OPTIONS = {"db": None, "raw": False, "whole_face": False, "window": 5, "k": 30, "overlap": 2, "bases": False}


def synthesis_only(args) -> None:
    """The options of Chai et al.'s synthesis (--db, --window, ...) choose it when --tracker is not
    given, and are refused with another --tracker; with the synthesis they get their defaults
    (they are None when not given)."""
    given = [f"--{k.replace('_', '-')}" for k in SYNTHESIS_OPTIONS if getattr(args, k, None) not in (None, False)]
    if args.tracker is None:
        args.tracker = "synthesis" if given else "solve"
    if args.tracker != "synthesis":
        if given:
            raise CommandError(f"{', '.join(given)} belong{'s' if len(given) == 1 else ''} to Chai et al.'s motion "
                               f"synthesis: add --tracker synthesis, or leave {'it' if len(given) == 1 else 'them'} out "
                               f"for --tracker {args.tracker}")
        return
    for k, default in SYNTHESIS_OPTIONS.items():
        if getattr(args, k, None) is None:
            setattr(args, k, default)


def performance_of(tr, args, db):
    """The performance of a tracking by ``args.tracker``, and a line saying how it was made."""
    from faceanim.perform import mediapipe_performance, perform, solve_performance

    if args.tracker == "solve":
        perf = solve_performance(tr)
        return perf, ("ARKit's 52 curves solved per frame on the generic head's shapes (neutral from the clip's "
                      "face at rest)")
    if args.tracker == "mediapipe":
        return mediapipe_performance(tr), "MediaPipe's own 52 blendshape scores (--tracker mediapipe)"
    perf = perform(tr, db, raw=args.raw, window=args.window, k=args.k, overlap=args.overlap,
                   whole_face=args.whole_face)
    if args.raw:
        how = "mapped frame by frame (--raw)"
        print("faceanim perform: warning: --raw is the per-frame baseline the synthesis is measured against: "
              "expect exposed gums, smears on head turns and unsteady eyes; leave it out for the synthesised "
              "motion", file=sys.stderr)
    else:
        used = perf.settings
        how = (f"filtered and synthesised {'on the whole face' if args.whole_face else 'feature-wise'} from "
               f"{db.n_frames} database frames (W={used['window']}, K={used['k']}, "
               f"delay {1000 * used['delay']:.0f} ms)")
    return perf, f"{how}; {db.n_bases} deformation bases"


def _cmd_arkit_play(args) -> None:
    from faceanim.io.arkit_csv import read_arkit_csv
    from faceanim.perform import write_take

    out, suffix = _output(args, "is the take itself")
    take = read_arkit_csv(args.take)
    n = int(take.duration * args.fps) + 1
    if n > MAX_FRAMES:
        raise CommandError(f"the take lasts {take.duration:.0f} s: {n} frames at {args.fps:g} fps, more than "
                           f"{MAX_FRAMES}; lower --fps or cut the take")
    if suffix == ".mp4":
        from faceanim.limits import check_video

        check_video(n, args.size, args.size)
    if own_targets(args, suffix):
        print(f"{n} frames ({take.duration:.1f} s) of the take at {args.fps:g} fps")
        played = take.resample(args.fps)
        report([play_own(args, out, played.weights, args.fps, "take", head=played.head)])
        return
    face = load_face(args) if WRITERS[suffix].shows_face else None
    with progress(n if suffix == ".mp4" else 0, "rendering", args.quiet or suffix != ".mp4") as bar:
        written = write_take(out, take, face, args.fps, args.size, bar)
    print(f"{n} frames ({take.duration:.1f} s) of the take at {args.fps:g} fps")
    report(written)


def register(sub) -> None:
    t = sub.add_parser("track", help=HELP["track"],
                       description="Track the face in a video (or a camera) with MediaPipe's Face Landmarker: per "
                                   "frame the head's yaw, pitch, roll (degrees), position (x, y pixels of the nose "
                                   "bridge) and scale (pixels per metre), then ARKit's 52 curves (Apple's names, 0..1: "
                                   "the solve, or MediaPipe's scores with --tracker mediapipe) or, with --tracker "
                                   "synthesis, the paper's 15 control parameters from 19 features seen "
                                   "fronto-parallel (mouth 6, nose 2, eyes 2, brows 5), normalised against the "
                                   "performer's neutral frame. Frames without a face have tracked=0 and empty cells.")
    t.add_argument("video", nargs="?", metavar="VIDEO", help="a video file (MP4, MOV, MKV, AVI, WebM)")
    t.add_argument("--camera", type=_arg_type("--camera", 0, 63, integer=True), metavar="N",
                   help="track camera N instead of a file")
    t.add_argument("--frames", type=_arg_type("--frames", 1, MAX_FRAMES, integer=True), default=300,
                   help="frames to take from a camera")
    t.add_argument("--neutral-frame", type=_arg_type("--neutral-frame", 0, MAX_FRAMES, integer=True), metavar="N",
                   help="--tracker synthesis: the frame with the performer's neutral face (default: found "
                        "automatically)")
    add_tracker(t)
    t.add_argument("--quiet", action="store_true", help="no progress bar")
    add_output(t, [".csv"])
    t.set_defaults(func=_cmd_track)

    m = sub.add_parser("mocap", help=HELP["mocap"])
    msub = m.add_subparsers(dest="mocap_command", required=True, metavar="{build}")
    b = msub.add_parser("build", help="a motion database from Live Link Face CSV takes played on the generic head",
                        description="Play each take (ARKit's 52 curves) on the generic head (ICT FaceKit, all ARKit "
                                    "shapes), read 76 markers, turn them by the take's head rotation (or by the head "
                                    "motion tracked in --head-motion VIDEO), separate the pose again (--pose) and store "
                                    "the pose-free markers with their 15 control parameters and the deformation "
                                    "bases that retarget them (.npz; the format is in "
                                    "faceanim.build.motion.MotionDatabase).")
    b.add_argument("takes", nargs="+", metavar="TAKE.csv", help="Live Link Face CSV recordings")
    b.add_argument("--fps", type=_arg_type("--fps", 1, 240), default=30.0, help="frames per second of the database")
    b.add_argument("--head-motion", metavar="VIDEO",
                   help="turn the markers by the head motion tracked in this video (looped): the takes were "
                        "recorded with a still head; the factorisation's error against it is reported")
    b.add_argument("--pose", choices=("stable", "factorisation"), default="stable",
                   help="how the head pose is taken out of the markers: rigid registration weighted towards the "
                        "stillest markers (default, the more accurate) or the paper's rank-3L factorisation")
    add_output(b, [".npz"])
    b.set_defaults(func=_cmd_mocap_build)

    p = sub.add_parser("perform", help=HELP["perform"],
                       description="Track the performer in VIDEO, turn the 15 control parameters into real motion "
                                   "from a motion database (filtering and synthesis on segments; the shipped "
                                   "database unless --db), retarget its deformation bases onto the face (the "
                                   "default face unless --face) and write .glb (the face's ARKit blendshapes as "
                                   "morph targets, Apple's names, weights 0..1, and the head's rotation animated; "
                                   "--bases: one target per deformation basis instead), .mp4 (the video and the face "
                                   "side by side, with the video's sound), .csv (Live Link Face: ARKit's 52 curves "
                                   "and the head angles) or .tsv/.json (Rhubarb Lip Sync's mouth cues). A --face "
                                   ".glb/.vrm avatar whose morph targets carry ARKit's names (any spelling) is played "
                                   "by name instead: the same avatar with the performance as one more animation.")
    p.add_argument("video", metavar="VIDEO", help="a video file of a performer (MP4, MOV, MKV, AVI, WebM)")
    add_face(p, positional=False)
    add_tracker(p, synthesis_options=True)
    p.add_argument("--db", metavar="MOTION.npz", help="--tracker synthesis: a motion database from faceanim mocap "
                                                      "build (default: the shipped one)")
    p.add_argument("--raw", action="store_true", default=None,
                   help="--tracker synthesis: map each frame's controls directly (no filtering or synthesis), to "
                        "compare")
    p.add_argument("--whole-face", action="store_true", default=None,
                   help="--tracker synthesis: one search on all 15 controls, as the paper (default: the lower and "
                        "upper face each from its own controls, which follows the mouth far better)")
    p.add_argument("--window", type=_arg_type("--window", 1, 120, integer=True),
                   help="--tracker synthesis: segment length W in frames (default 5; the paper: 20)")
    p.add_argument("--k", type=_arg_type("--k", 1, 500, integer=True), help="--tracker synthesis: nearest segments K "
                                                                            "(default 30)")
    p.add_argument("--overlap", type=_arg_type("--overlap", 1, 120, integer=True),
                   help="--tracker synthesis: segments blended per frame (default 2; the delay is overlap - 1 "
                        "frames; the paper: 5)")
    p.add_argument("--neutral-frame", type=_arg_type("--neutral-frame", 0, MAX_FRAMES, integer=True), metavar="N",
                   help="the frame with the performer's neutral face (default: found automatically)")
    p.add_argument("--size", type=_even("--size", 64, 1024), default=512,
                   help="MP4 height in pixels (even)")
    p.add_argument("--bases", action="store_true", default=None,
                   help="--tracker synthesis, .glb: one morph target per deformation basis (lower_01 ..., upper_01 "
                        "..., weights about -1..1) instead of ARKit's 52")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    add_output(p, (*suffixes(".fap"), ".vrm"),
               help=".tsv/.json: Rhubarb Lip Sync's mouth cues of the performer's mouth")
    p.set_defaults(func=_cmd_perform)

    a = sub.add_parser("arkit", help=HELP["arkit"])
    asub = a.add_subparsers(dest="arkit_command", required=True, metavar="{play}")
    ap = asub.add_parser("play", help="play a Live Link Face CSV take on a face: glTF, MP4 or CSV",
                         description="Play a recorded take (ARKit's 52 blendshape curves and the head's angles, as "
                                     "Live Link Face writes them) on the face (the default face unless --face): the "
                                     "generic head's ARKit shapes are retargeted onto it (Apple's names) and driven by the recorded curves. .glb: morph targets, weights "
                                     "and head rotation animated; .mp4: rendered; .csv: the take resampled; .tsv/.json: its mouth cues. A --face "
                                     ".glb/.vrm avatar whose morph targets already carry ARKit's names (any spelling) "
                                     "is played by name instead: the same avatar with one more animation (.glb/.vrm).")
    ap.add_argument("take", metavar="TAKE.csv", help="a Live Link Face CSV recording")
    add_face(ap, positional=False)
    ap.add_argument("--fps", type=_arg_type("--fps", 1, 240), default=30.0, help="frames per second of the output")
    ap.add_argument("--size", type=_even("--size", 64, 1024), default=512, help="MP4 pixels per side (even)")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    add_output(ap, (*suffixes(".fap"), ".vrm"),
               help=".tsv/.json: Rhubarb Lip Sync's mouth cues of the take's mouth")
    ap.set_defaults(func=_cmd_arkit_play)
