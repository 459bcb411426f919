"""faceanim landmarks, deform, render, preprocess: one mesh in, one file out."""

from __future__ import annotations

from pathlib import Path

from faceanim.cli.commands import HELP
from faceanim.cli.common import (
    ANGLE,
    DEFAULT_SIZE,
    GRID,
    SIZE,
    CommandError,
    add_face,
    add_output,
    check_outputs,
    face_path,
    named_paths,
    outputs_together,
    report,
)
from faceanim.errors import shown


def _cmd_landmarks(args) -> None:
    from faceanim.face.landmarks import Landmarks, detect_landmarks
    from faceanim.render import save_png

    check_outputs(args.output, args.image)
    mesh = load_face_mesh(args)
    if args.given:
        lms, image = Landmarks.load(args.given).attached_to(mesh), None
    else:
        lms, image = detect_landmarks(mesh, scheme=args.scheme, forward=args.forward, up=args.up,
                                      return_image=True)
        from faceanim.face.face import Face, landmarks_478
        from faceanim.face.registration import check_face

        check_face(Face(mesh, landmarks_478(mesh, lms)))  # the one check every command's face passes
    with outputs_together() as written:
        written.append(lms.save(args.output))
        if args.image:
            written.append(save_png(args.image, image))
    print(f"wrote {len(lms)} '{lms.scheme}' landmarks to {args.output}"
          + (f" and the render used for detection to {args.image}" if args.image else ""))


def _cmd_deform(args) -> None:
    import numpy as np

    from faceanim.deform.handles import load_handles
    from faceanim.io.meshio import save_mesh

    check_outputs(args.output, args.image)
    mesh = load_face_mesh(args)
    deformer, offsets = load_handles(args.handles, mesh, args.forward, args.up)
    deformed = deformer.apply(offsets)
    with outputs_together() as written:
        written += save_mesh(mesh, args.output, deformed, avoid=named_paths(args))
        if args.image:
            from faceanim.render import render_png

            written.append(render_png(mesh, args.image, deformed))
    moved = int((np.abs(deformed - mesh.vertices).max(1) > 0).sum())
    print(f"deformed {moved} of {mesh.n_vertices} vertices; wrote {', '.join(map(str, written))}")


def _cmd_render(args) -> None:
    from faceanim.render import render_png

    check_outputs(args.output)
    mesh = load_face_mesh(args)
    report([render_png(mesh, args.output, size=(args.size, args.size), yaw=args.yaw, pitch=args.pitch)])


def _cmd_preprocess(args) -> None:
    from faceanim.build.preprocess import AverageFace, preprocess, resample_to_grid
    from faceanim.cli.common import load_face
    from faceanim.io.files import write_json
    from faceanim.io.meshio import save_mesh

    lm_path = Path(args.output).with_suffix(".landmarks.json")
    if lm_path.exists():
        raise CommandError(f"'{lm_path}' (the grid's landmarks, written beside -o) exists already; move it or "
                           "choose another -o")
    check_outputs(args.output, lm_path)
    face = load_face(args, required=True)
    if args.no_normalise:
        grid = resample_to_grid(face.mesh, face.landmarks, args.grid, args.crop)
    else:
        ref = AverageFace.load(args.reference) if args.reference else None
        grid = preprocess(face.mesh, face.landmarks, ref, args.grid, args.crop)
    with outputs_together() as written:
        written += save_mesh(grid.mesh, args.output, avoid=[lm_path, *named_paths(args)])
        written.append(lm_path)  # removed with the grid if it cannot be written
        write_json(lm_path, {"scheme": "mediapipe478", "points": [
            {"index": i, "position": [float(x) for x in p]} for i, p in enumerate(grid.landmarks)]})
    print(f"wrote {', '.join(map(str, written))} ({grid.mesh.n_vertices} grid vertices of {args.grid}x{args.grid})")


def load_face_mesh(args):
    """The mesh alone (no landmarks needed): the file named, or the embedded default face."""
    from faceanim.face.default import default_face
    from faceanim.io.meshio import load_mesh

    path = face_path(args)
    return default_face() if path in (None, "default") else load_mesh(path)


def _axis(text: str) -> str:
    import argparse
    import re

    if not re.fullmatch(r"[+-]?[xyzXYZ]", text.strip()):
        raise argparse.ArgumentTypeError(f"'{shown(text, 12)}' is not an axis; use one of +x -x +y -y +z -z")
    return text.strip().lower() if text.strip()[0] in "+-" else "+" + text.strip().lower()


def _axes(p) -> None:
    p.add_argument("--forward", default="+z", type=_axis, help="axis the face looks along: +x -x +y -y +z -z")
    p.add_argument("--up", default="+y", type=_axis, help="axis pointing up")


def register(sub) -> None:
    lm = sub.add_parser("landmarks", help=HELP["landmarks"])
    add_face(lm, landmarks=False)
    add_output(lm, [".json"])
    lm.add_argument("--scheme", default="mediapipe478", choices=["mediapipe478", "basic22"])
    _axes(lm)
    src = lm.add_mutually_exclusive_group()
    src.add_argument("--image", type=lambda v: v if v.lower().endswith(".png") else _bad_png(v),
                     help="also save the render used for detection (.png)")
    src.add_argument("--from", dest="given", metavar="JSON",
                     help="take landmarks from this file instead of detecting them (snapped onto the mesh)")
    lm.set_defaults(func=_cmd_landmarks)

    df = sub.add_parser("deform", help=HELP["deform"])
    add_face(df, landmarks=False)
    df.add_argument("--handles", required=True, metavar="JSON", help="method rbf (handles, offsets) or gde (elements)")
    add_output(df, [".obj", ".ply", ".glb"])
    df.add_argument("--image", type=lambda v: v if v.lower().endswith(".png") else _bad_png(v),
                    help="also render the result (.png)")
    _axes(df)
    df.set_defaults(func=_cmd_deform)

    r = sub.add_parser("render", help=HELP["render"])
    add_face(r, landmarks=False)
    add_output(r, [".png"])
    r.add_argument("--size", type=SIZE, default=DEFAULT_SIZE, help="pixels per side (16..4096)")
    r.add_argument("--yaw", type=ANGLE, default=15.0, help="degrees")
    r.add_argument("--pitch", type=ANGLE, default=4.0, help="degrees")
    r.set_defaults(func=_cmd_render)

    pp = sub.add_parser("preprocess", help=HELP["preprocess"])
    add_face(pp, aliases=("--scan",))
    add_output(pp, [".obj", ".ply", ".glb"])
    pp.add_argument("--grid", type=GRID, default=150, help="grid vertices per side (8..500)")
    pp.add_argument("--crop", default="oval", choices=["oval", "radius"],
                    help="inside the landmark face oval, or a radius around the nose tip (raw scans)")
    pp.add_argument("--reference", help="average face model (.npz) to normalise to (default: faceanim's)")
    pp.add_argument("--no-normalise", action="store_true", help="resample only, keep the scan's pose and size")
    pp.set_defaults(func=_cmd_preprocess)


def _bad_png(value):
    import argparse

    raise argparse.ArgumentTypeError(f"'{value}' must end in .png")
