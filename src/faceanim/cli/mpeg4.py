"""faceanim say, fap play, fap write, direct: MPEG-4 FAPs, lip sync and scene scripts (Lee et al. 1999)."""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

from faceanim.cli.commands import HELP
from faceanim.cli.common import (
    DEFAULT_SIZE,
    DURATION,
    FPS,
    INTENSITY,
    SIZE,
    CommandError,
    add_face,
    add_output,
    check_outputs,
    load_face,
    note_written,
    own_targets,
    play_own,
    progress,
)
from faceanim.limits import DEFAULT_FPS
from faceanim.export import WRITERS, suffixes
from faceanim.standards.rhubarb import CUE_SUFFIXES


def _write(args, rig, stream, face, audio: Path | None) -> list[Path]:
    """A FAP stream written by the suffix of ``-o`` (:data:`faceanim.export.WRITERS`): .fap, .glb (the
    face's ARKit shapes driven by curves fitted to the stream on this face, weights 0..1, and the
    head's rotation, or with ``--faps`` one target per FAP, signed weights; its sound as .wav beside,
    named in the glb's extras), .mp4 (rendered, with the sound) or .csv (Live Link Face: the fitted
    ARKit curves)."""
    import numpy as np

    from faceanim.export import write
    from faceanim.player import stream_animation

    out = Path(args.output)
    a = stream_animation(face, rig, stream, getattr(args, "faps", False), sound=audio, quantize=args.compact,
                         size=args.size)
    if out.suffix.lower() in (".glb", ".csv") and a.targets is None:
        if not (np.any(a.need("arkit", "")) or np.any(a.need("head", ""))):
            raise CommandError("the stream sets no FAP this face can show (as ARKit curves); give FAPs of the "
                               "face, brows, eyes, mouth or head")
    with progress(stream.n_frames if out.suffix.lower() == ".mp4" else 0, f"rendering {out.name}",
                  args.quiet or out.suffix.lower() != ".mp4") as bar:
        return write(out, a, bar)


def _say_phones(args, voice, tmp: Path) -> tuple[list, Path]:
    """The timed phones of ``say``'s input and the sound they go with."""
    from faceanim.drivers.speech import align, say_timed

    if args.audio:
        from faceanim.io.files import read_text

        wav = Path(args.audio)
        if args.transcript:
            return align(wav, read_text(args.transcript, "transcript")), wav
        from faceanim.drivers.speech import recognise_phones  # no transcript: the phones as heard

        return recognise_phones(wav), wav
    wav = tmp / "speech.wav"
    return say_timed(args.text, wav, voice=voice), wav


def _say_animation(args, face, phones, wav):
    """``say`` as an :class:`~faceanim.export.Animation`: ARKit curves of the lip sync
    (:mod:`faceanim.drivers.speech.lipsync`) with the brows and blinks of the voice's prosody
    (:mod:`faceanim.drivers.speech.prosody`) and ``--emotion`` phrase by phrase, Rhubarb cues of the
    phones, MPEG-4's visemes with the same prosody and emotion as FAPs (Lee et al.; made only for a
    .fap), the sound (written beside a .glb or cue file, or the recording named)."""
    from faceanim.drivers.cues import phone_cues
    from faceanim.drivers.speech.lipsync import lipsync_curves
    from faceanim.drivers.speech.prosody import with_prosody
    from faceanim.export import Animation
    from faceanim.io.audio import read_audio
    from faceanim.perform import EYE_CONTROLS, eye_angles
    from faceanim.standards.arkit import APPLE_NAMES

    names = list(APPLE_NAMES)  # Live Link Face's order
    curves, head, prosody = with_prosody(lipsync_curves(phones, names, args.fps), names, *read_audio(wav), args.fps,
                                         args.expression, args.intensity)

    def fap_stream():
        from faceanim.drivers.speech.prosody import emotion_actions, prosody_actions
        from faceanim.drivers.speech.visemes import speech_stream

        extra = prosody_actions(prosody)
        if args.expression:
            extra += emotion_actions(prosody, args.expression, args.intensity, max(p.end for p in phones))
        # a .fap file is for any face: MPEG-4's neutral face has closed lips, so no gap to close
        return speech_stream(0.0, phones, args.fps, extra, name=Path(args.output).stem)

    eyes = eye_angles(curves[:, [names.index(n) for n in EYE_CONTROLS[2:]]])  # the looks away, as a CSV's angles
    out = Path(args.output)
    return Animation(args.fps, arkit=curves, head=head, eyes=eyes, face=face, fap=fap_stream, cues=phone_cues(phones),
                     sound=wav, sound_name=str(Path(args.audio).resolve()) if args.audio else "", name=out.stem,
                     quantize=args.compact, size=args.size, view=face.view() if face is not None else None)


def _say_own(args, face, phones, wav) -> tuple[list[Path], int, float]:
    """``say`` onto the --face avatar's own ARKit-named targets: the same avatar with the speech as one
    more animation, the sound beside it (named in the scene's extras)."""
    from faceanim.drivers.speech.lipsync import lipsync_curves
    from faceanim.drivers.speech.prosody import with_prosody
    from faceanim.export import sound_beside
    from faceanim.io.audio import read_audio
    from faceanim.io.gltf import sound_companion
    from faceanim.standards.arkit import APPLE_NAMES

    names = list(APPLE_NAMES)
    curves, head, _ = with_prosody(lipsync_curves(phones, names, args.fps), names, *read_audio(wav), args.fps,
                                   args.expression, args.intensity)
    out = Path(args.output)
    companion = sound_companion(out)
    play_own(args, out, curves, args.fps, out.stem, {"audio": companion.name, "fps": args.fps}, head=head)
    return sound_beside(out, companion, *read_audio(wav)), len(curves), args.fps


def _cmd_say(args) -> None:
    if (args.text is None) == (args.audio is None):
        raise CommandError("give the text to say, or --audio clip.wav (with --transcript clip.txt if you have it)")
    if args.transcript and args.audio is None:
        raise CommandError("--transcript names the words of an --audio recording; give --audio too, or say the text "
                           "itself without --transcript")
    voice = None
    if args.text is not None:
        from faceanim.drivers.speech import check_text, check_voice

        check_text(args.text)
        voice = check_voice(args.voice)
    if args.expression:
        from faceanim.drivers.speech.lipsync import expression_mix

        expression_mix(args.expression)  # an unknown name is refused before any work
    check_video_size(args)
    check_outputs(args.output)
    if args.audio:
        from faceanim.io.audio import read_audio

        read_audio(args.audio, "recorded speech")
    suffix = Path(args.output).suffix.lower()
    if suffix in CUE_SUFFIXES and args.expression:
        raise CommandError("mouth cues (.tsv, .json) show the mouth's shapes only; leave out --emotion")
    if not WRITERS[suffix].shows_face and (args.face or args.landmarks):
        raise CommandError(f"a {suffix} output holds {WRITERS[suffix].holds.split(' (')[0]}, not a face: drop "
                           "--face/--landmarks, or write .glb or .mp4")
    own = own_targets(args, suffix)
    face = load_face(args) if WRITERS[suffix].shows_face and not own else None
    with tempfile.TemporaryDirectory() as tmp:
        phones, wav = _say_phones(args, voice, Path(tmp))
        if own:
            written, n_frames, fps = _say_own(args, face, phones, wav)
        else:
            from faceanim.export import write

            a = _say_animation(args, face, phones, wav)
            with progress(a.n_frames if suffix == ".mp4" else 0, f"rendering {Path(args.output).name}",
                          args.quiet or suffix != ".mp4") as bar:
                written = write(args.output, a, bar)
            n_frames, fps = (a.fap.n_frames, a.fap.fps) if suffix == ".fap" else (a.n_frames, a.fps)
    note_written(written)
    if suffix in CUE_SUFFIXES:
        from faceanim.io.rhubarb import tidy_cues

        print(f"wrote {', '.join(map(str, written))} ({len(tidy_cues(a.cues, n_frames / fps))} mouth cues, "
              f"{len(phones)} phones)")
        return
    print(f"wrote {', '.join(map(str, written))} ({n_frames} frames, {len(phones)} phones, {n_frames / fps:.1f} s)")


def _cmd_fap_play(args) -> None:
    from faceanim.io.fapfile import read_fap
    from faceanim.rig.mpeg4 import FapRig

    check_video_size(args)
    check_outputs(args.output)
    stream = read_fap(args.fap)
    if args.audio:
        from faceanim.io.audio import read_audio

        read_audio(args.audio, "sound for the animation")
    face = load_face(args)
    rig = FapRig.build(face)
    for warning in rig.check(stream):
        print(f"faceanim fap play: warning: {warning}", file=sys.stderr)
    written = _write(args, rig, stream, face, Path(args.audio) if args.audio else None)
    note_written(written)
    print(f"wrote {', '.join(map(str, written))} ({stream.n_frames} frames at {stream.fps:g} fps)")


def _cmd_fap_write(args) -> None:
    from faceanim.drivers.director import build_scene, scene_stream
    from faceanim.io.fapfile import write_fap

    events = []
    if args.expression:
        events.append({"expression": args.expression, "at": 0.0, "duration": args.duration,
                       "intensity": args.intensity, "envelope": args.envelope})
    if args.fap:
        faps = {}
        for item in args.fap:
            if "=" not in item:
                raise CommandError(f"--fap takes NAME=VALUE (e.g. open_jaw=300), got '{item}'")
            k, v = item.split("=", 1)
            try:
                faps[k] = float(v)
            except ValueError:
                raise CommandError(f"--fap {k}: the value must be a number of FAPU units, got '{v[:20]}'") from None
        events.append({"faps": faps, "at": 0.0, "duration": args.duration, "envelope": args.envelope})
    if args.say:
        events.append({"say": args.say, "at": 0.2})
    if not events:
        raise CommandError("give --expression, --fap NAME=VALUE and/or --say TEXT")
    from faceanim.limits import MAX_FRAMES

    if args.fps * args.duration > MAX_FRAMES:
        raise CommandError(f"--fps {args.fps:g} x --duration {args.duration:g} s is more than {MAX_FRAMES} frames; "
                           "lower one of them")
    check_outputs(args.output)
    with tempfile.TemporaryDirectory() as tmp:
        # MPEG-4's neutral face has closed lips: no gap to close
        scene = build_scene({"fps": args.fps, "events": events}, 0.0, Path(tmp))
        stream = scene_stream(scene, Path(args.output).stem)
        write_fap(args.output, stream)
    note_written([args.output])
    print(f"wrote {args.output} ({stream.n_frames} frames at {stream.fps:g} fps)")


def _cmd_direct(args) -> None:
    from faceanim.cli.common import face_path
    from faceanim.drivers.director import (
        build_scene,
        load_script,
        mix_speech,
        scene_stream,
    )
    from faceanim.face.face import Face
    from faceanim.rig.mpeg4 import FapRig

    check_video_size(args)
    check_outputs(args.output)
    script = load_script(args.script)
    scripted = script.face
    if scripted and scripted != "default" and not Path(scripted).is_absolute():
        scripted = str(Path(args.script).parent / scripted)  # a script's face is beside the script
    face = Face.load(face_path(args) or scripted or "default", args.landmarks)
    rig = FapRig.build(face)
    lip_gap = 0.0 if Path(args.output).suffix.lower() == ".fap" else rig.lip_gap
    with tempfile.TemporaryDirectory() as tmp:
        scene = build_scene(script, lip_gap, Path(tmp))
        stream = scene_stream(scene, Path(args.output).stem)
        audio = mix_speech(scene, Path(tmp) / "track.wav")
        written = _write(args, rig, stream, face, audio)
    note_written(written)
    print(f"wrote {', '.join(map(str, written))} ({stream.n_frames} frames, {len(scene.actions)} actions, "
          f"{scene.duration:.1f} s)")


def check_video_size(args) -> None:
    """An MP4's size is refused before any work (not after the face and rig are built)."""
    if Path(args.output).suffix.lower() == ".mp4":
        from faceanim.limits import check_video

        check_video(1, args.size, args.size)


def _video_options(p, suffixes) -> None:
    add_output(p, suffixes)
    p.add_argument("--size", type=SIZE, default=DEFAULT_SIZE, help="MP4 pixels per side (16..4096)")
    p.add_argument("--compact", action="store_true", help="GLB: quantized (KHR_mesh_quantization)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def register(sub) -> None:
    sy = sub.add_parser("say", help=HELP["say"])
    sy.add_argument("text", nargs="?", help="what to say (spoken by espeak-ng)")
    sy.add_argument("--audio", metavar="SOUND", help="recorded speech (WAV of any sample format, FLAC, OGG) instead of text")
    sy.add_argument("--transcript", metavar="TXT", help="text file with the words spoken in --audio (more exact "
                                                        "timing; without it the phones are recognised from the audio)")
    add_face(sy, positional=False)
    sy.add_argument("--emotion", "--expression", dest="expression", metavar="EMOTION",
                    help="an emotion carried while speaking (joy, sadness, surprise, fear, anger, disgust), phrase "
                         "by phrase: a louder, livelier phrase shows more of it")
    sy.add_argument("--intensity", type=INTENSITY, default=0.6, help="intensity of --emotion (0..2), the mean over "
                                                                      "the phrases")
    sy.add_argument("--voice", default="en-us", help="espeak-ng voice (`espeak-ng --voices` lists them)")
    sy.add_argument("--fps", type=FPS, default=DEFAULT_FPS, help="frames per second (up to 240)")
    _video_options(sy, suffixes())
    sy.set_defaults(func=_cmd_say)

    fp = sub.add_parser("fap", help=HELP["fap"])
    fsub = fp.add_subparsers(dest="fap_command", required=True, metavar="{play,write}")
    fpl = fsub.add_parser("play", help="play a .fap file on a face")
    fpl.add_argument("fap", metavar="FAP", help="the .fap file")
    add_face(fpl, positional=False)
    fpl.add_argument("--audio", metavar="SOUND", help="sound to put under the video (or beside a .glb)")
    _video_options(fpl, suffixes(".fap", *CUE_SUFFIXES))
    fpl.add_argument("--faps", action="store_true", help=".glb: one morph target per FAP (signed weights) instead "
                                                         "of the face's ARKit shapes with fitted curves")
    fpl.set_defaults(func=_cmd_fap_play)

    fw = fsub.add_parser("write", help="write a .fap file from an expression, FAP values or text")
    add_output(fw, [".fap"])
    fw.add_argument("--expression", help="joy, sadness, anger, fear, disgust or surprise")
    fw.add_argument("--fap", action="append", metavar="NAME=VALUE", help="a FAP value (FAPU units), repeatable")
    fw.add_argument("--say", metavar="TEXT", help="lip-sync visemes for the text (synthesized and aligned)")
    fw.add_argument("--duration", type=DURATION, default=2.0, help="seconds of --expression / --fap (up to 3600)")
    fw.add_argument("--intensity", type=INTENSITY, default=1.0, help="0..2")
    fw.add_argument("--envelope", default="smooth", choices=["linear", "smooth", "peak"])
    fw.add_argument("--fps", type=FPS, default=DEFAULT_FPS, help="frames per second (up to 240)")
    fw.set_defaults(func=_cmd_fap_write)

    di = sub.add_parser("direct", help=HELP["direct"])
    di.add_argument("script", metavar="SCRIPT")
    add_face(di, positional=False, default_help="the script's 'face', else the embedded default face")
    _video_options(di, suffixes(*CUE_SUFFIXES))
    di.add_argument("--faps", action="store_true", help=".glb: one morph target per FAP (signed weights) instead "
                                                        "of the face's ARKit shapes with fitted curves")
    di.set_defaults(func=_cmd_direct)



