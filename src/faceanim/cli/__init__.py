"""The ``faceanim`` command: parses arguments, calls the library, reports.

Every user error becomes one line on stderr and exit code 2; no partial output is left.
"""

from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path

import numpy as np

from faceanim.errors import FaceAnimError, InputFileError


def _cmd_demo(args) -> None:
    from faceanim.demo import run_demo

    written = run_demo(args.out, fps=args.fps, size=args.size, quiet=args.quiet)
    print(f"wrote {len(written)} files to {Path(args.out)}/:")
    for p in written:
        print(f"  {p}  ({p.stat().st_size / 1024:.0f} KiB)")


def _cmd_landmarks(args) -> None:
    from faceanim.face.landmarks import Landmarks, detect_landmarks
    from faceanim.io.meshio import load_mesh
    from faceanim.render import save_png

    mesh = load_mesh(args.mesh)
    if args.given:
        # landmarks from a file override detection: snap them onto this mesh
        lms, image = Landmarks.load(args.given).attached_to(mesh), None
        if args.image:
            raise FaceAnimError("--image shows the detection render; it does not apply with --from")
    else:
        lms, image = detect_landmarks(mesh, scheme=args.scheme, forward=args.forward, up=args.up,
                                      return_image=True)
    lms.save(args.output)
    print(f"wrote {len(lms)} '{lms.scheme}' landmarks to {args.output}")
    if args.image:
        save_png(args.image, image)
        print(f"wrote the render used for detection to {args.image}")


def _cmd_deform(args) -> None:
    from faceanim.deform import bind_gdes, bind_rbf
    from faceanim.deform.gde import GeometryDeformationElement
    from faceanim.deform.rbf import check_points
    from faceanim.io.files import read_json
    from faceanim.io.meshio import load_mesh, save_mesh

    spec = read_json(args.handles, "handle file")
    if not isinstance(spec, dict):
        raise InputFileError(f"handle file '{args.handles}' must hold a JSON object with a 'method'")
    method = spec.get("method", "rbf")
    mesh = load_mesh(args.mesh)
    if method == "rbf":
        for key in ("handles", "offsets"):
            if key not in spec:
                raise InputFileError(f"handle file '{args.handles}': method 'rbf' needs '{key}'")
        handles = check_points(spec["handles"], "handles")
        offsets = check_points(spec["offsets"], "offsets")
        if offsets.shape != handles.shape:
            raise InputFileError(
                f"handle file '{args.handles}': {len(handles)} handles but {len(offsets)} offsets")
        deformer = bind_rbf(mesh.vertices, handles, kernel=spec.get("kernel", "multiquadric"),
                            smoothing=spec.get("smoothing", 0.01), stiffness=spec.get("stiffness"),
                            degree=spec.get("degree"))
    elif method == "gde":
        elements = spec.get("elements")
        if not isinstance(elements, list) or not elements:
            raise InputFileError(f"handle file '{args.handles}': method 'gde' needs a non-empty 'elements' list")
        gdes, offsets = [], []
        for k, e in enumerate(elements):
            if not isinstance(e, dict) or "offset" not in e:
                raise InputFileError(f"handle file '{args.handles}': element {k} needs an 'offset' [dx, dy, dz]")
            if "pick" in e and "control" not in e:
                # a 2D pick in the front view, converted to a surface point by ray casting
                from faceanim.face.landmarks import pick_surface_points

                e = {**{k2: v for k2, v in e.items() if k2 != "pick"},
                     "control": pick_surface_points(mesh, [e["pick"]], args.forward, args.up)[0][0].tolist()}
            gdes.append(GeometryDeformationElement.from_dict(e, k))
            offsets.append(check_points(e["offset"], f"element {k} offset")[0])
        deformer = bind_gdes(mesh, gdes)
        offsets = np.array(offsets)
    else:
        raise InputFileError(f"handle file '{args.handles}': unknown method '{method}' (use 'rbf' or 'gde')")
    deformed = deformer.apply(offsets)
    written = save_mesh(mesh, args.output, deformed)
    moved = int((np.abs(deformed - mesh.vertices).max(1) > 0).sum())
    print(f"deformed {moved} of {mesh.n_vertices} vertices; wrote {', '.join(map(str, written))}")
    if args.image:
        from faceanim.render import render_png

        render_png(mesh, args.image, deformed)
        print(f"wrote {args.image}")


def _cmd_render(args) -> None:
    from faceanim.io.meshio import load_mesh
    from faceanim.render import render_png

    mesh = load_mesh(args.mesh)
    render_png(mesh, args.output, size=(args.size, args.size), yaw=args.yaw, pitch=args.pitch)
    print(f"wrote {args.output}")


def _face_and_landmarks(path, landmarks_file):
    from faceanim.face.default import default_face
    from faceanim.face.face import landmarks_478
    from faceanim.face.landmarks import Landmarks, detect_landmarks
    from faceanim.io.meshio import load_mesh

    if path in (None, "default"):
        mesh = default_face()
    else:
        mesh = load_mesh(path)
    if landmarks_file:
        lms = Landmarks.load(landmarks_file).attached_to(mesh)
    else:
        lms = detect_landmarks(mesh)
    return mesh, landmarks_478(mesh, lms)


def _write_expression(args, mesh, lm478, shapes, pose: str, weight: float) -> None:
    """The face posed with blendshape ``pose`` at ``weight`` as OBJ/PLY or a PNG render; GLB:
    the rest mesh with every blendshape as a morph target and a short animation of ``pose``
    from 0 to ``weight`` and back."""
    from faceanim.io.gltf import write_gltf
    from faceanim.io.meshio import save_mesh
    from faceanim.render import render_png

    suffix = Path(args.output).suffix.lower()
    pose_delta = shapes[pose] * weight
    if suffix == ".png":
        from faceanim.face.landmarks import FACE_OVAL

        render_png(mesh, args.output, vertices=mesh.vertices + pose_delta, size=(args.size, args.size), yaw=12,
                   pitch=3, frame_vertices=np.asarray(lm478)[list(FACE_OVAL)], margin=1.25)
    elif suffix == ".glb":
        names = list(shapes)
        times = np.array([0.0, 1.0, 2.0])
        w = np.zeros((3, len(names)))
        w[1, names.index(pose)] = weight
        write_gltf(args.output, mesh, shapes, times=times, weights=w, animation_name="expression")
    else:
        save_mesh(mesh, args.output, vertices=mesh.vertices + pose_delta)
    print(f"wrote {args.output}")


def _cmd_au(args) -> None:
    from faceanim.rig.facs import default_library
    from faceanim.rig.transfer import CUTOFF, ExpressionTransfer, default_model

    lib = default_library()
    if args.emotion and args.au:
        raise FaceAnimError("give --au or --emotion, not both")
    if not args.emotion and not args.au:
        raise FaceAnimError("give --au (e.g. 12 or 1,2 or all) or --emotion (e.g. joy)")
    m = lib.intensity(args.magnitude)
    mix = lib.emotion(args.emotion) if args.emotion else {au: 1.0 for au in lib.parse_action_units(args.au)}
    model = default_model()
    mesh, lm = _face_and_landmarks(args.target, args.landmarks)
    xf = ExpressionTransfer(mesh, lm, lib, method=args.method)
    pose = xf.mixture_delta(model, {au: w * m for au, w in mix.items()}, side=args.side)
    shapes = {"pose": pose}
    if Path(args.output).suffix.lower() == ".glb":
        shapes.update(xf.rig(model, sides=args.halves).blendshape_dict())
        shapes["pose"] = pose * (np.linalg.norm(pose, axis=1) >= CUTOFF * xf.frame.iod)[:, None]
    _write_expression(args, mesh, lm, shapes, "pose", 1.0)


def _cmd_transfer(args) -> None:
    from faceanim.rig.facs import default_library
    from faceanim.rig.transfer import ExpressionTransfer, learn_expression

    lib = default_library()
    m = lib.intensity(args.magnitude)
    aus = lib.parse_action_units(args.au)
    s0, lm0 = _face_and_landmarks(args.source_neutral, args.source_neutral_landmarks)
    s1, lm1 = _face_and_landmarks(args.source_expressive, args.source_expressive_landmarks)
    sample = learn_expression(s0, s1, lm0, lm1, lib)
    mesh, lm = _face_and_landmarks(args.target, args.landmarks)
    xf = ExpressionTransfer(mesh, lm, lib, method=args.method)
    full = xf.points_delta(sample, aus, 1.0, side=args.side)
    _write_expression(args, mesh, lm, {"expression": full}, "expression", m)


def _cmd_preprocess(args) -> None:
    from faceanim.build.preprocess import AverageFace, preprocess, resample_to_grid
    from faceanim.io.files import write_json
    from faceanim.io.meshio import save_mesh

    mesh, lm = _face_and_landmarks(args.scan, args.landmarks)
    if args.no_normalise:
        grid = resample_to_grid(mesh, lm, args.grid, args.crop)
    else:
        ref = AverageFace.load(args.reference) if args.reference else None
        grid = preprocess(mesh, lm, ref, args.grid, args.crop)
    lm_path = Path(args.output).with_suffix(".landmarks.json")
    save_mesh(grid.mesh, args.output)
    write_json(lm_path, {"scheme": "mediapipe478", "points": [
        {"index": i, "position": [float(x) for x in p]} for i, p in enumerate(grid.landmarks)]})
    print(f"wrote {args.output} ({grid.mesh.n_vertices} grid vertices of {args.grid}x{args.grid}) and {lm_path}")


def _wire_base(args):
    from faceanim.rig.wires import default_wires

    mesh, lm = _face_and_landmarks(args.base, args.landmarks)
    return mesh, lm, default_wires(lm)


def _cmd_wires_extract(args) -> None:
    from faceanim.face.regions import face_region
    from faceanim.io.meshio import load_mesh
    from faceanim.rig.wires import align_template, extract_template

    base, lm, wireset = _wire_base(args)
    template = load_mesh(args.template)
    if not args.no_align:
        template = align_template(base, template, lm)
    bound = wireset.bind(base, lm)
    t = extract_template(base, template, wireset, bound)
    face = face_region(base, lm)
    moved = np.linalg.norm((template.vertices - base.vertices)[face])
    err = np.linalg.norm((t.rebuild(base, bound) - template.vertices)[face]) / moved if moved > 0 else 0.0
    t.save(args.output)
    print(f"wrote {args.output}: {len(wireset.wires)} wires, {t.n_numbers} numbers for the template's "
          f"{3 * template.n_vertices} ({3 * template.n_vertices / t.n_numbers:.0f}x smaller); rebuild error "
          f"{err:.3f} of the template's motion over the face")


def _cmd_wires_apply(args) -> None:
    from faceanim.io.files import read_json
    from faceanim.rig.wires import WireTemplate, edit_template, parse_edits

    base, lm, _ = _wire_base(args)
    t = WireTemplate.load(args.wires)
    if args.edit:
        moves, scales = parse_edits(read_json(args.edit, "edit file"), t.wireset)
        t = edit_template(t, moves, scales)
    delta = t.rebuild(base, lm478=lm) - base.vertices
    _write_expression(args, base, lm, {"expression": delta}, "expression", 1.0)


def _cmd_wires_blend(args) -> None:
    from faceanim.io.gltf import write_gltf
    from faceanim.render import OffscreenRenderer, write_video
    from faceanim.rig.wires import WireTemplate, blend_blendshapes, blending_function

    base, lm, _ = _wire_base(args)
    paths = [args.source] + list(args.to)
    templates = [WireTemplate.load(p) for p in paths]
    for t, name in zip(templates, paths):
        if t.n_vertices != base.n_vertices:
            raise FaceAnimError(f"'{name}' was extracted on a base with {t.n_vertices} vertices, "
                                f"'{args.base}' has {base.n_vertices}")
    if args.frames < 2:
        raise FaceAnimError("--frames must be at least 2")
    functions = {"eyes": args.eyes, "mouth": args.mouth}
    for item in args.group or []:
        if "=" not in item:
            raise FaceAnimError(f"--group takes NAME=FUNCTION, got '{item}'")
        k, v = item.split("=", 1)
        functions[k] = v
    groups = set(templates[0].wireset.groups)
    if set(functions) - groups - {"eyes", "mouth"}:
        raise FaceAnimError(f"no wire group {', '.join(sorted(set(functions) - groups))}; the groups are "
                            f"{', '.join(sorted(groups))}")
    curves = {g: blending_function(f) for g, f in functions.items()}
    bound = templates[0].wireset.bind(base, lm)
    # a chain a -> b -> c ...: segment i adds its per-group share of (next - this), weighted by the
    # group's blending function over the segment and held at its end value after it
    shapes, columns = {}, []
    for i, (a, b) in enumerate(itertools.pairwise(templates)):
        seg = blend_blendshapes(a, b, bound)
        if i == 0:
            shapes["from"] = seg["from"]
            columns.append(("from", None, None))
        for g, d in seg.items():
            if g != "from":
                name = g if len(templates) == 2 else f"{g}@{i + 1}"
                shapes[name] = d
                columns.append((name, i, curves.get(g, blending_function("linear"))))
    n_seg = len(templates) - 1
    ts = np.linspace(0.0, float(n_seg), args.frames * n_seg)
    weights = np.zeros((len(ts), len(columns)))
    for c, (_, seg_i, curve) in enumerate(columns):
        weights[:, c] = 1.0 if seg_i is None else curve(np.clip(ts - seg_i, 0.0, 1.0))
    times = np.arange(len(ts)) / args.fps
    if Path(args.output).suffix.lower() == ".glb":
        write_gltf(args.output, base, shapes, times=times, weights=weights, animation_name="blend")
    else:
        from faceanim.face.landmarks import FACE_OVAL
        from faceanim.rig.rig import Rig

        frames = Rig(base, shapes).evaluate(weights)
        with OffscreenRenderer(base, size=(args.size, args.size), yaw=12, pitch=3,
                               frame_vertices=np.asarray(lm)[list(FACE_OVAL)], margin=1.25) as r:
            write_video(args.output, (r.render(v) for v in frames), fps=args.fps)
    print(f"wrote {args.output} ({len(ts)} frames, {n_seg} blend{'s' if n_seg > 1 else ''})")


def _cmd_say(args) -> None:
    import tempfile

    from faceanim.drivers.mpeg4 import Action, expression_faps
    from faceanim.drivers.speech import align, say_timed
    from faceanim.io.fapfile import write_fap
    from faceanim.player import gltf_stream, render_stream, speech_stream
    from faceanim.rig.mpeg4 import FapRig

    if (args.text is None) == (args.audio is None):
        raise FaceAnimError('give the text to say, or --audio clip.wav with --transcript clip.txt')
    suffix = Path(args.output).suffix.lower()
    mesh, lm = _face_and_landmarks(args.face, args.landmarks)
    rig = FapRig.build(mesh, lm)
    with tempfile.TemporaryDirectory() as tmp:
        if args.audio:
            if not args.transcript:
                raise FaceAnimError("--audio needs --transcript (the words spoken in it)")
            from faceanim.io.files import read_text

            text = read_text(args.transcript, "transcript")
            wav = Path(args.audio)
            phones = align(wav, text)
        else:
            wav = Path(tmp) / "speech.wav"
            phones = say_timed(args.text, wav, voice=args.voice)
        extra = []
        if args.expression:
            end = max(p.end for p in phones)
            extra.append(Action(args.expression, expression_faps(args.expression), 0.0, end + 0.2,
                                args.intensity, "linear", 0.1, 0.1, 0.3))
        stream = speech_stream(rig.lip_gap, phones, args.fps, extra, name=Path(args.output).stem)
        if suffix == ".fap":
            write_fap(args.output, stream)
        elif suffix == ".glb":
            gltf_stream(rig, stream, args.output)
        else:
            render_stream(rig, stream, args.output, lm, size=args.size, audio=wav)
    print(f"wrote {args.output} ({stream.n_frames} frames, {len(phones)} phones, "
          f"{stream.n_frames / stream.fps:.1f} s)")


def _cmd_fap_play(args) -> None:
    from faceanim.io.fapfile import read_fap
    from faceanim.player import gltf_stream, render_stream
    from faceanim.rig.mpeg4 import FapRig

    stream = read_fap(args.fap)
    mesh, lm = _face_and_landmarks(args.face, args.landmarks)
    rig = FapRig.build(mesh, lm)
    for warning in rig.check(stream):
        print(f"faceanim fap play: warning: {warning}", file=sys.stderr)
    if Path(args.output).suffix.lower() == ".glb":
        gltf_stream(rig, stream, args.output)
    else:
        render_stream(rig, stream, args.output, lm, size=args.size, audio=args.audio)
    print(f"wrote {args.output} ({stream.n_frames} frames at {stream.fps:g} fps)")


def _cmd_fap_write(args) -> None:
    import tempfile
    from types import SimpleNamespace

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
                raise FaceAnimError(f"--fap takes NAME=VALUE (e.g. open_jaw=300), got '{item}'")
            k, v = item.split("=", 1)
            faps[k] = v
        events.append({"faps": faps, "at": 0.0, "duration": args.duration, "envelope": args.envelope})
    if args.say:
        events.append({"say": args.say, "at": 0.2})
    if not events:
        raise FaceAnimError("give --expression, --fap NAME=VALUE and/or --say TEXT")
    with tempfile.TemporaryDirectory() as tmp:
        # MPEG-4's neutral face has closed lips: no gap to close
        scene = build_scene({"fps": args.fps, "events": events}, SimpleNamespace(lip_gap=0.0), Path(tmp))
        stream = scene_stream(scene, Path(args.output).stem)
        write_fap(args.output, stream)
    print(f"wrote {args.output} ({stream.n_frames} frames at {stream.fps:g} fps)")


def _cmd_direct(args) -> None:
    import tempfile

    from faceanim.drivers.director import (
        build_scene,
        load_script,
        mix_speech,
        scene_stream,
    )
    from faceanim.io.fapfile import write_fap
    from faceanim.player import gltf_stream, render_stream
    from faceanim.rig.mpeg4 import FapRig

    script = load_script(args.script)
    face = args.face or script.get("face", "default")
    mesh, lm = _face_and_landmarks(face, args.landmarks)
    rig = FapRig.build(mesh, lm)
    with tempfile.TemporaryDirectory() as tmp:
        scene = build_scene(script, rig, Path(tmp))
        stream = scene_stream(scene, Path(args.output).stem)
        suffix = Path(args.output).suffix.lower()
        if suffix == ".fap":
            write_fap(args.output, stream)
        elif suffix == ".glb":
            gltf_stream(rig, stream, args.output)
        else:
            audio = mix_speech(scene, Path(tmp) / "track.wav")
            render_stream(rig, stream, args.output, lm, size=args.size, audio=audio)
    print(f"wrote {args.output} ({stream.n_frames} frames, {len(scene.actions)} actions, {scene.duration:.1f} s)")


def _output_path(suffixes):
    def check(value: str) -> str:
        if Path(value).suffix.lower() not in suffixes:
            raise argparse.ArgumentTypeError(f"'{value}' must end in one of: {', '.join(suffixes)}")
        return value
    return check


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="faceanim", description="3D facial animation from the papers.")
    sub = p.add_subparsers(dest="command", required=True)

    d = sub.add_parser("demo", help="animate the embedded default face: GLB, MP4 and PNGs")
    d.add_argument("--out", default="faceanim-demo", help="output folder (default ./faceanim-demo)")
    d.add_argument("--fps", type=float, default=30.0)
    d.add_argument("--size", type=int, default=512, help="image size in pixels (even)")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=_cmd_demo)

    lm = sub.add_parser("landmarks", help="detect named 3D landmarks on a mesh")
    lm.add_argument("mesh")
    lm.add_argument("-o", "--output", required=True, type=_output_path([".json"]))
    lm.add_argument("--scheme", default="mediapipe478", choices=["mediapipe478", "basic22"])
    lm.add_argument("--forward", default="+z", help="axis the face looks along (default +z)")
    lm.add_argument("--up", default="+y", help="axis pointing up (default +y)")
    lm.add_argument("--image", type=_output_path([".png"]), help="also save the render used for detection")
    lm.add_argument("--from", dest="given", metavar="JSON",
                    help="take landmarks from this file instead of detecting them (snapped onto the mesh)")
    lm.set_defaults(func=_cmd_landmarks)

    df = sub.add_parser("deform", help="deform a mesh with RBF handles or GDEs from a JSON file")
    df.add_argument("mesh")
    df.add_argument("--handles", required=True, help="JSON: method rbf (handles, offsets) or gde (elements)")
    df.add_argument("-o", "--output", required=True, type=_output_path([".obj", ".ply", ".glb"]))
    df.add_argument("--image", type=_output_path([".png"]), help="also render the result to a PNG")
    df.add_argument("--forward", default="+z", help="axis the face looks along, for 2D picks (default +z)")
    df.add_argument("--up", default="+y", help="axis pointing up, for 2D picks (default +y)")
    df.set_defaults(func=_cmd_deform)

    r = sub.add_parser("render", help="render a mesh to PNG")
    r.add_argument("mesh")
    r.add_argument("-o", "--output", required=True, type=_output_path([".png"]))
    r.add_argument("--size", type=int, default=512)
    r.add_argument("--yaw", type=float, default=15.0)
    r.add_argument("--pitch", type=float, default=4.0)
    r.set_defaults(func=_cmd_render)

    a = sub.add_parser("au", help="pose a face with FACS action units or an emotion (built-in AU library)")
    a.add_argument("target", nargs="?", default="default", help="mesh (default: the embedded default face)")
    a.add_argument("--au", help="action units: 12, 1,2 or all")
    a.add_argument("--emotion", help="joy, sadness, surprise, fear, anger or disgust")
    a.add_argument("--magnitude", default="1.0", help="m in [0, 1] or a FACS intensity A-E (default 1)")
    a.add_argument("--side", default="both", choices=["both", "L", "R"], help="one-sided action (subject's side)")
    a.add_argument("--method", default="surface", choices=["surface", "tps"], help="warp interpolant")
    a.add_argument("--landmarks", help="landmark JSON for the target instead of detection")
    a.add_argument("--halves", action="store_true", help="GLB: also one-sided AUn_L / AUn_R morph targets")
    a.add_argument("-o", "--output", required=True, type=_output_path([".glb", ".png", ".obj", ".ply"]))
    a.add_argument("--size", type=int, default=512, help="PNG size")
    a.set_defaults(func=_cmd_au)

    t = sub.add_parser("transfer", help="learn AUs from a neutral/expressive scan pair and apply them to a target")
    t.add_argument("--source-neutral", required=True)
    t.add_argument("--source-expressive", required=True)
    t.add_argument("--source-neutral-landmarks", metavar="JSON", help="landmarks of the neutral scan (else detected)")
    t.add_argument("--source-expressive-landmarks", metavar="JSON",
                   help="landmarks of the expressive scan; for scans of another topology, hand-marked landmarks "
                        "learn far better than detected ones")
    t.add_argument("--target", default="default", help="mesh (default: the embedded default face)")
    t.add_argument("--au", default="all", help="action units whose control points move: 12, 1,2 or all")
    t.add_argument("--magnitude", default="1.0", help="m in [0, 1] or a FACS intensity A-E")
    t.add_argument("--side", default="both", choices=["both", "L", "R"])
    t.add_argument("--method", default="surface", choices=["surface", "tps"])
    t.add_argument("--landmarks", help="landmark JSON for the target instead of detection")
    t.add_argument("-o", "--output", required=True, type=_output_path([".glb", ".png", ".obj", ".ply"]))
    t.add_argument("--size", type=int, default=512)
    t.set_defaults(func=_cmd_transfer)

    pp = sub.add_parser("preprocess", help="crop a scan, resample it on a regular grid, normalise pose and size")
    pp.add_argument("scan")
    pp.add_argument("-o", "--output", required=True, type=_output_path([".obj", ".ply", ".glb"]))
    pp.add_argument("--grid", type=int, default=150, help="grid vertices per side (default 150)")
    pp.add_argument("--crop", default="oval", choices=["oval", "radius"],
                    help="inside the landmark face oval, or a radius around the nose tip (raw scans)")
    pp.add_argument("--landmarks", help="landmark JSON for the scan instead of detection")
    pp.add_argument("--reference", help="average face model (.npz) to normalise to (default: faceanim's)")
    pp.add_argument("--no-normalise", action="store_true", help="resample only, keep the scan's pose and size")
    pp.set_defaults(func=_cmd_preprocess)

    w = sub.add_parser("wires", help="wire curves: extract from expression templates, apply, edit, blend")
    wsub = w.add_subparsers(dest="wires_command", required=True)
    we = wsub.add_parser("extract", help="fit the default wires of a base face to an expression template")
    we.add_argument("--base", required=True, help="neutral face mesh")
    we.add_argument("--template", required=True, help="the expression, same topology as the base")
    we.add_argument("--landmarks", help="landmark JSON for the base instead of detection")
    we.add_argument("--no-align", action="store_true",
                    help="keep the template's pose (by default it is aligned rigidly on the skull first)")
    we.add_argument("-o", "--output", required=True, type=_output_path([".json"]))
    we.set_defaults(func=_cmd_wires_extract)
    wa = wsub.add_parser("apply", help="rebuild an expression from its wires on the base face")
    wa.add_argument("--base", required=True)
    wa.add_argument("--wires", required=True, help="a .wires.json from `faceanim wires extract`")
    wa.add_argument("--edit", help='JSON edits: {"edits": [{"wire": "upper_lip", "control": 3, "offset": [0, 0.002, 0]}]}')
    wa.add_argument("--landmarks", help="landmark JSON for the base instead of detection")
    wa.add_argument("-o", "--output", required=True, type=_output_path([".obj", ".ply", ".glb", ".png"]))
    wa.add_argument("--size", type=int, default=512)
    wa.set_defaults(func=_cmd_wires_apply)
    wb = wsub.add_parser("blend", help="blend two templates through their wires, feature by feature")
    wb.add_argument("--base", required=True)
    wb.add_argument("--from", dest="source", required=True, help="template at t = 0")
    wb.add_argument("--to", required=True, action="append",
                    help="template at t = 1; repeat to blend on through more templates (a -> b -> c)")
    wb.add_argument("--eyes", default="linear", help="blending function of the eye wires (linear, sqrt, cubic, ...)")
    wb.add_argument("--mouth", default="linear", help="blending function of the mouth wires")
    wb.add_argument("--group", action="append", metavar="NAME=FUNCTION",
                    help="blending function of another wire group (brows, cheeks, nose), or samples 0,0.2,1")
    wb.add_argument("--frames", type=int, default=60, help="frames per blend")
    wb.add_argument("--fps", type=float, default=30.0)
    wb.add_argument("--landmarks", help="landmark JSON for the base instead of detection")
    wb.add_argument("-o", "--output", required=True, type=_output_path([".glb", ".mp4"]))
    wb.add_argument("--size", type=int, default=512)
    wb.set_defaults(func=_cmd_wires_blend)

    sy = sub.add_parser("say", help="lip-sync: text (synthesized) or recorded speech + transcript to an animated face")
    sy.add_argument("text", nargs="?", help="what to say (spoken by espeak-ng)")
    sy.add_argument("--audio", help="recorded speech (16-bit WAV) instead of text")
    sy.add_argument("--transcript", help="text file with the words spoken in --audio")
    sy.add_argument("--face", default="default", help="mesh (default: the embedded default face)")
    sy.add_argument("--landmarks", help="landmark JSON for the face instead of detection")
    sy.add_argument("--expression", help="an MPEG-4 expression held while speaking (joy, sadness, ...)")
    sy.add_argument("--intensity", type=float, default=0.6, help="intensity of --expression")
    sy.add_argument("--voice", default="en-us", help="espeak-ng voice")
    sy.add_argument("--fps", type=float, default=25.0)
    sy.add_argument("--size", type=int, default=512)
    sy.add_argument("-o", "--output", required=True, type=_output_path([".mp4", ".glb", ".fap"]))
    sy.set_defaults(func=_cmd_say)

    fp = sub.add_parser("fap", help="MPEG-4 FAP files")
    fsub = fp.add_subparsers(dest="fap_command", required=True)
    fpl = fsub.add_parser("play", help="play a .fap file on a face")
    fpl.add_argument("fap")
    fpl.add_argument("--face", default="default", help="mesh (default: the embedded default face)")
    fpl.add_argument("--landmarks", help="landmark JSON for the face instead of detection")
    fpl.add_argument("--audio", help="WAV to put under the video")
    fpl.add_argument("--size", type=int, default=512)
    fpl.add_argument("-o", "--output", required=True, type=_output_path([".mp4", ".glb"]))
    fpl.set_defaults(func=_cmd_fap_play)
    fw = fsub.add_parser("write", help="write a .fap file from an expression, FAP values or text")
    fw.add_argument("-o", "--output", required=True, type=_output_path([".fap"]))
    fw.add_argument("--expression", help="joy, sadness, anger, fear, disgust or surprise")
    fw.add_argument("--fap", action="append", metavar="NAME=VALUE", help="a FAP value (FAPU units), repeatable")
    fw.add_argument("--say", metavar="TEXT", help="lip-sync visemes for the text (synthesized and aligned)")
    fw.add_argument("--duration", type=float, default=2.0, help="seconds of --expression / --fap")
    fw.add_argument("--intensity", type=float, default=1.0)
    fw.add_argument("--envelope", default="smooth", choices=["linear", "smooth", "peak"])
    fw.add_argument("--fps", type=float, default=25.0)
    fw.set_defaults(func=_cmd_fap_write)

    di = sub.add_parser("direct", help="render a scene script (YAML or JSON): speech, expressions, head motion, blinks")
    di.add_argument("script")
    di.add_argument("--face", help="mesh (default: the script's 'face', else the embedded default face)")
    di.add_argument("--landmarks", help="landmark JSON for the face instead of detection")
    di.add_argument("--size", type=int, default=512)
    di.add_argument("-o", "--output", required=True, type=_output_path([".mp4", ".glb", ".fap"]))
    di.set_defaults(func=_cmd_direct)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except FaceAnimError as exc:
        print(f"faceanim {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("faceanim: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
