"""The ``faceanim`` command: parses arguments, calls the library, reports.

Every user error becomes one line on stderr and exit code 2; no partial output is left.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from .errors import FaceAnimError, InputFileError


def _cmd_demo(args) -> None:
    from .demo import run_demo

    written = run_demo(args.out, fps=args.fps, size=args.size, quiet=args.quiet)
    print(f"wrote {len(written)} files to {Path(args.out)}/:")
    for p in written:
        print(f"  {p}  ({p.stat().st_size / 1024:.0f} KiB)")


def _cmd_landmarks(args) -> None:
    from .landmarks import Landmarks, detect_landmarks
    from .mesh import load_mesh
    from .render import save_png

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
    from .deform import bind_gdes, bind_rbf
    from .deform.gde import GeometryDeformationElement
    from .deform.rbf import check_points
    from .fileio import read_json
    from .mesh import load_mesh, save_mesh

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
                from .landmarks import pick_surface_points

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
        from .render import render_png

        render_png(mesh, args.image, deformed)
        print(f"wrote {args.image}")


def _cmd_render(args) -> None:
    from .mesh import load_mesh
    from .render import render_png

    mesh = load_mesh(args.mesh)
    render_png(mesh, args.output, size=(args.size, args.size), yaw=args.yaw, pitch=args.pitch)
    print(f"wrote {args.output}")


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
