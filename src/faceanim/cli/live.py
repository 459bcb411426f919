"""faceanim live: a camera or a clip drives ARKit curves in real time, sent to VMC apps, Unreal's
Live Link and a Live Link Face CSV (:mod:`faceanim.live`)."""

from __future__ import annotations

import signal
import sys
from pathlib import Path

from faceanim.cli.commands import HELP
from faceanim.cli.common import INTENSITY, CommandError, _arg_type, check_outputs
from faceanim.errors import shown


def _cmd_live(args) -> None:
    from faceanim.live.pipeline import run_live
    from faceanim.live.sinks import FileSink, parse_sinks
    from faceanim.live.sources import CameraSource, ClipSource

    if args.video is not None and args.camera is not None:
        raise CommandError("give --video FILE or --camera N, not both")
    if args.audio is not None and args.mic is not None:
        raise CommandError("give --audio FILE or --mic, not both (one sound drives the mouth)")
    heard = args.audio is not None or args.mic is not None
    if args.video is None and args.camera is None and not heard:
        raise CommandError("give a source: --camera N, --video FILE and/or --audio FILE or --mic [DEVICE]")
    picture = args.video is not None or args.camera is not None
    if args.mouth is not None and not (picture and heard):
        raise CommandError("--mouth chooses between a video's mouth and a sound's; give --audio or --mic with "
                           "--video or --camera")
    if args.intensity is not None and args.emotion is None:
        raise CommandError("--intensity is --emotion's; give --emotion NAME too")
    if args.emotion is not None:
        if not heard or picture:
            raise CommandError("--emotion colours a face the voice drives alone; give --audio or --mic without "
                               "--video or --camera (a performer's face shows their own)")
        from faceanim.drivers.speech.lipsync import expression_mix

        expression_mix(args.emotion)  # an unknown name is refused before anything is opened
    if heard:
        from faceanim.extras import require

        require("pocketsphinx", "live lip sync (--audio, --mic)")
    # every sink checked before the source is opened (a camera light should not flash for a typo)
    views = [t for t in args.to if t == "viewer" or t.startswith("viewer:")]
    if args.face is not None and not views:
        raise CommandError("--face is the avatar the viewer shows; give --to viewer too")
    if args.face is not None:
        from faceanim.live.viewer import driven_curves
        from faceanim.viewer.server import check_model

        model = check_model(args.face)
        if not driven_curves(model.doc):
            raise CommandError(f"'{shown(model.path.name, 60)}' has no morph target or VRM expression named by "
                               "ARKit (jawOpen, eyeBlinkLeft ... in any spelling) nor VRM blink/aa presets; rig it "
                               "first with faceanim rig")
    if len(views) > 1:
        raise CommandError("give --to viewer once (one page serves any number of browsers)")
    if views:
        from faceanim.live.viewer import viewer_port

        viewer_port(views[0])
    others = [t for t in args.to if t not in views]
    sinks = parse_sinks(others, 30.0, args.subject) if others else []
    files = [s.path for s in sinks if isinstance(s, FileSink)]
    if len({p.resolve() for p in files}) < len(files):
        raise CommandError("two --to file: sinks name the same file; give each its own")
    inputs = [Path(p).resolve() for p in (args.video, args.audio) if p is not None]
    if any(p.resolve() in inputs for p in files):
        raise CommandError("a --to file: output is an input; give the take its own path")
    check_outputs(*files)
    sound = None
    if args.audio is not None:
        from faceanim.live.audio import AudioFeed, read_sound

        sound = AudioFeed(read_sound(args.audio), args.seconds, Path(args.audio).name)
    elif args.mic is not None:
        from faceanim.live.mic import MicFeed, find_input

        sound = MicFeed(find_input(args.mic))  # opened now: a device that cannot record is refused here
    if args.emotion is not None:
        sound.carry(args.emotion, 0.6 if args.intensity is None else args.intensity)
    if not picture:
        from faceanim.live.audio import AudioSource

        source, sound = AudioSource(sound, seconds=args.seconds), None
    else:
        source = ClipSource(args.video, seconds=args.seconds) if args.video is not None else \
            CameraSource(args.camera, seconds=args.seconds)
    for s in sinks:  # the rate now known
        s.fps = source.fps
        if isinstance(s, FileSink) and (args.audio or args.video):
            s.sound_name = str(Path(args.audio or args.video).resolve())  # what cue files name as the sound
    if views:
        from faceanim.live.viewer import ViewerSink

        sinks.append(ViewerSink(views[0], args.face))  # its servers start here
    print(f"faceanim live: {source.name} ({source.fps:g} fps) -> {', '.join(s.label for s in sinks)}"
          + (f" with the sound of {sound.name} ({args.mouth or 'both'} mouth)" if sound else "")
          + ("" if args.camera is None and args.mic is None else "; Ctrl-C stops"), file=sys.stderr, flush=True)
    page = next((s.url for s in sinks if hasattr(s, "url")), None)
    if page and not args.no_browser:
        import threading
        import webbrowser

        threading.Thread(target=webbrowser.open, args=(page,), daemon=True).start()
    previous = signal.signal(signal.SIGTERM, signal.default_int_handler)  # SIGTERM stops as Ctrl-C does
    try:
        from faceanim.live.performer import live_tracker

        performer = live_tracker(args.tracker) if picture else None
        report = run_live(source, sinks, performer, notice=lambda text: print(f"faceanim live: {text}", file=sys.stderr),
                          sound=sound, mouth=args.mouth or "both")
    finally:
        signal.signal(signal.SIGTERM, previous)
    from faceanim.errors import STOPS

    STOPS.clear()  # a stop is how a live run ends (its report says so): exit 0
    if report.error:
        print(f"faceanim live: {report.error}; stopped", file=sys.stderr)
    print(("stopped: " if report.interrupted else "") + report.summary())
    for p in report.written:
        print(f"wrote {p}")


def register(sub) -> None:
    p = sub.add_parser("live", help=HELP["live"],
                       description="Track a face live (a camera, or a clip played at its own frame rate), run the "
                                   "ARKit solve of `faceanim perform` causally (and/or lip sync a sound "
                                   "played in real time, --audio, or a microphone, --mic), and send ARKit's 52 curves "
                                   "with the head's and eyes' angles to each --to: vmc://HOST:PORT (VSeeFace, VNyan, "
                                   "Warudo, VMagicMirror; port 39539), livelink://HOST:PORT (Unreal's Live Link, "
                                   "port 11111), file:PATH (the run written when it stops: a Live Link Face CSV, Rhubarb "
                                   "mouth cues .tsv/.json, or the default face animated .glb; csv:PATH is a .csv), "
                                   "viewer[:PORT] (the faceanim view page with the avatar moving). "
                                   "Frames the compute cannot keep up with are dropped, and counted.")
    p.add_argument("--video", metavar="FILE", help="a clip, played in real time; the run ends with it")
    p.add_argument("--camera", type=_arg_type("--camera", 0, 63, integer=True), metavar="N", help="camera N")
    p.add_argument("--audio", metavar="FILE", help="a sound (WAV, FLAC, OGG, ...) played in real time: live lip sync "
                                                   "(phones recognised as they come); alone it drives the whole face "
                                                   "(the brows on the voice's accents, blinks at its pauses, the "
                                                   "head nodding and leaning phrase by phrase), with a video its "
                                                   "mouth")
    p.add_argument("--mic", nargs="?", const="", metavar="DEVICE",
                   help="a microphone, heard live as --audio plays a file (PortAudio): the default input device, "
                        "or DEVICE, an index or a part of a name (--mic pulse: PulseAudio or PipeWire through "
                        "ALSA); runs until --seconds or Ctrl-C")
    p.add_argument("--mouth", choices=("audio", "video", "both"),
                   help="with --audio or --mic and a video or camera: whose mouth the avatar has (default: both, "
                        "averaged; the lips shut when either shuts them)")
    p.add_argument("--emotion", metavar="EMOTION",
                   help="with --audio or --mic alone: an emotion carried while speaking (joy, sadness, surprise, "
                        "fear, anger, disgust), phrase by phrase as it is heard: a louder, livelier phrase shows "
                        "more of it")
    p.add_argument("--intensity", type=INTENSITY, metavar="I",
                   help="intensity of --emotion (0..2, default 0.6), the mean over the phrases")
    p.add_argument("--to", action="append", metavar="SINK", required=True,
                   help="where the curves go (repeatable): vmc://HOST:PORT, livelink://HOST:PORT, file:PATH "
                        "(.csv .tsv .json .glb) or viewer[:PORT] (the faceanim view page, 8760 by default)")
    p.add_argument("--tracker", choices=("solve", "synthesis", "mediapipe"), default="solve",
                   help="with a video or camera: what turns the landmarks into ARKit's curves: solve (default: the "
                        "generic head's ARKit shapes fitted to each frame, the performer's neutral from the frames "
                        "so far), synthesis (Chai et al.'s motion database, causally) or mediapipe (MediaPipe's "
                        "own 52 scores)")
    p.add_argument("--subject", default="faceanim", help="the Live Link subject name")
    p.add_argument("--face", metavar="MODEL", help="the avatar --to viewer shows, a .glb or .vrm whose morph targets "
                                                  "(or VRM expressions) carry ARKit's names (default: the default "
                                                  "face with ARKit's shapes)")
    p.add_argument("--no-browser", action="store_true", help="with --to viewer: do not open the page")
    p.add_argument("--seconds", type=_arg_type("--seconds", 0.1, 86400.0), metavar="S",
                   help="stop after S seconds (default: the clip's or the sound's end, or Ctrl-C)")
    p.set_defaults(func=_cmd_live)
