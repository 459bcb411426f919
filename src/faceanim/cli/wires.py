"""faceanim wires extract, apply, blend: wire curves (Pyun, Shin & Shin 2001)."""

from __future__ import annotations

from pathlib import Path

from faceanim.cli.commands import HELP
from faceanim.cli.common import (
    DEFAULT_SIZE,
    FPS,
    FRAMES,
    SIZE,
    CommandError,
    add_face,
    add_output,
    check_outputs,
    load_face,
    note_written,
    progress,
    report,
    write_pose,
)
from faceanim.limits import DEFAULT_FPS


def _cmd_extract(args) -> None:
    import numpy as np

    from faceanim.face.regions import face_region
    from faceanim.io.meshio import load_mesh
    from faceanim.rig.wires import align_template, default_wires, extract_template

    check_outputs(args.output)
    face = load_face(args)
    base, lm = face.mesh, face.landmarks
    wireset = default_wires(lm)
    template = load_mesh(args.template)
    if not args.no_align:
        template = align_template(base, template, lm)
    bound = wireset.influence(base, lm)
    t = extract_template(base, template, wireset, bound)
    region = face_region(base, lm)
    moved = np.linalg.norm((template.vertices - base.vertices)[region])
    err = np.linalg.norm((t.rebuild(base, bound) - template.vertices)[region]) / moved if moved > 0 else 0.0
    t.save(args.output)
    note_written([args.output])
    print(f"wrote {args.output}: {len(wireset.wires)} wires, {t.n_numbers} numbers for the template's "
          f"{3 * template.n_vertices} ({3 * template.n_vertices / t.n_numbers:.0f}x smaller); rebuild error "
          f"{err:.3f} of the template's motion over the face")


def _cmd_apply(args) -> None:
    from faceanim.io.files import read_json
    from faceanim.rig.wires import WireTemplate, edit_template, parse_edits

    check_outputs(args.output)
    face = load_face(args)
    t = WireTemplate.load(args.wires)
    if args.edit:
        moves, scales = parse_edits(read_json(args.edit, "edit file"), t.wireset)
        t = edit_template(t, moves, scales)
    delta = t.rebuild(face.mesh, lm478=face.landmarks) - face.mesh.vertices
    report(write_pose(args, face, {"expression": delta}, "expression", 1.0))


def _cmd_blend(args) -> None:
    from faceanim.player import render_curves, write_rig_gltf
    from faceanim.rig.wires import WireTemplate, blend_chain

    functions = {"eyes": args.eyes, "mouth": args.mouth}
    for item in args.group or []:
        if "=" not in item:
            raise CommandError(f"--group takes NAME=FUNCTION, got '{item}'")
        k, v = item.split("=", 1)
        functions[k] = v
    if Path(args.output).suffix.lower() == ".mp4":
        from faceanim.limits import check_video

        check_video(args.frames * len(args.to), args.size, args.size)
    check_outputs(args.output)
    face = load_face(args)
    templates = [WireTemplate.load(p) for p in [args.source] + list(args.to)]
    rig, curves = blend_chain(face.mesh, face.landmarks, templates, functions, args.frames)
    if Path(args.output).suffix.lower() == ".glb":
        write_rig_gltf(rig, curves, args.output, args.fps, "blend", names=rig.controls)
    else:
        with progress(len(curves), "rendering", args.quiet) as bar:
            render_curves(rig, curves, args.output, args.fps, face.view(), args.size, progress=bar)
    n_seg = len(templates) - 1
    note_written([args.output])
    print(f"wrote {args.output} ({len(curves)} frames, {n_seg} blend{'s' if n_seg > 1 else ''})")


def register(sub) -> None:
    w = sub.add_parser("wires", help=HELP["wires"])
    wsub = w.add_subparsers(dest="wires_command", required=True, metavar="{extract,apply,blend}")
    we = wsub.add_parser("extract", help="fit the default wires of a base face to an expression template")
    add_face(we, aliases=("--base",), positional=False)
    we.add_argument("--template", required=True, metavar="MESH", help="the expression, same topology as the base")
    we.add_argument("--no-align", action="store_true",
                    help="keep the template's pose (by default it is aligned rigidly on the skull first)")
    add_output(we, [".json"])
    we.set_defaults(func=_cmd_extract)

    wa = wsub.add_parser("apply", help="rebuild an expression from its wires on the base face")
    add_face(wa, aliases=("--base",), positional=False)
    wa.add_argument("--wires", required=True, metavar="JSON", help="a .wires.json from `faceanim wires extract`")
    wa.add_argument("--edit", metavar="JSON",
                    help='edits: {"edits": [{"wire": "upper_lip", "control": 3, "offset": [0, 0.002, 0]}]}')
    add_output(wa, [".obj", ".ply", ".glb", ".png"])
    wa.add_argument("--size", type=SIZE, default=DEFAULT_SIZE, help="PNG pixels per side")
    wa.set_defaults(func=_cmd_apply)

    wb = wsub.add_parser("blend", help="blend templates through their wires, feature by feature")
    add_face(wb, aliases=("--base",), positional=False)
    wb.add_argument("--from", dest="source", required=True, metavar="JSON", help="template at t = 0")
    wb.add_argument("--to", required=True, action="append", metavar="JSON",
                    help="template at t = 1; repeat to blend on through more templates (a -> b -> c)")
    wb.add_argument("--eyes", default="linear", help="blending function of the eye wires (linear, sqrt, cubic, ...)")
    wb.add_argument("--mouth", default="linear", help="blending function of the mouth wires")
    wb.add_argument("--group", action="append", metavar="NAME=FUNCTION",
                    help="blending function of another wire group (brows, cheeks, nose), or samples 0,0.2,1")
    wb.add_argument("--frames", type=FRAMES, default=60, help="frames per blend (2..200000)")
    wb.add_argument("--fps", type=FPS, default=DEFAULT_FPS, help="frames per second (up to 240)")
    add_output(wb, [".glb", ".mp4"])
    wb.add_argument("--size", type=SIZE, default=DEFAULT_SIZE, help="MP4 pixels per side")
    wb.add_argument("--quiet", action="store_true", help="no progress bar")
    wb.set_defaults(func=_cmd_blend)
