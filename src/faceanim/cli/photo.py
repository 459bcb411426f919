"""faceanim photo: a person's animatable full head from front and side photos (Lee et al. 1999)."""

from __future__ import annotations

from pathlib import Path

from faceanim.cli.commands import HELP
from faceanim.cli.common import (
    DEFAULT_SIZE,
    SIZE,
    CommandError,
    add_output,
    check_outputs,
    named_paths,
    report,
    stages,
)


# a textured head: glTF and OBJ carry the texture atlas (PLY has no place for it)
SUFFIXES = [".glb", ".obj", ".png"]


def _cmd_photo(args) -> None:
    import numpy as np

    from faceanim.build.photo import head_from_photos

    out = Path(args.output)
    if args.rig and out.suffix.lower() != ".glb":
        raise CommandError("--rig writes morph targets, which only a .glb holds; give -o HEAD.glb")
    if len(args.side or []) > 2:
        raise CommandError("give --side at most twice (a left and a right view)")
    check_outputs(args.output)
    suffix = out.suffix.lower()
    with stages("photo", 5, args.quiet) as step:
        ph = head_from_photos(args.front, args.side or [], args.points, method=args.method,
                              keep_expression=args.keep_expression, texture_size=args.texture_size, progress=step,
                              fast=args.fast)
        face = ph.face()
        step("rigging and writing" if args.rig else f"writing {out.name}")
        written = _write(args, out, suffix, face, ph)
    rec = ph.reconstruction
    errs = ", ".join(f"{Path(v.name).name} {np.median(e):.3f}" for v, e in zip(ph.views, rec.errors))
    print(f"views: {errs} (median reprojection error, inter-ocular distances; the 3D points come from the front "
          "photo and any profile, so the front's is near 0 by construction)")
    report(written)


def _write(args, out: Path, suffix: str, face, ph) -> list[Path]:
    """The head as the output asks: PNG (three views), GLB (rigged with --rig) or OBJ/PLY."""
    import numpy as np

    from faceanim.face.face import HEAD_MARGIN
    from faceanim.io.meshio import save_mesh

    if suffix == ".png":
        from faceanim.render import OffscreenRenderer, save_png

        views = []
        for yaw in (0.0, 40.0, 90.0):
            view = face.view(margin=HEAD_MARGIN, yaw=yaw, pitch=3.0)
            with OffscreenRenderer(face.mesh, size=(args.size, args.size), **view) as r:
                views.append(r.render())
        written = [save_png(out, np.hstack(views))]
    elif suffix == ".glb":
        if args.rig:  # what faceanim rig writes for the head: every set of the catalogue
            from faceanim.autorig import auto_rig, write_rigged

            written = [write_rigged(out, auto_rig(face))[0]]
        else:
            from faceanim.io.gltf import write_gltf

            written = [write_gltf(out, face.mesh)]
    else:
        written = save_mesh(face.mesh, out, avoid=named_paths(args))
    return written


def register(sub) -> None:
    p = sub.add_parser("photo", help=HELP["photo"],
                       description="A whole head from photos (Lee et al. 1999): the generic head fitted to the "
                                   "feature points of the photos, with one texture atlas. Outputs: .glb (textured; "
                                   "--rig adds every control as a morph target), .obj (with .mtl and "
                                   "OUT.texture.png beside it), .png (the head from the front, at 40 and 90 degrees).")
    p.add_argument("--front", required=True, metavar="IMAGE", help="a frontal photo (JPEG or PNG)")
    p.add_argument("--side", action="append", metavar="IMAGE",
                   help="a profile or three-quarter photo; give it twice for the left and the right side")
    p.add_argument("--points", metavar="JSON",
                   help='corrections of detected points, in pixels (x right, y down): {"front": {"9.3": [x, y]}, '
                        '"side": {"mp:4": [x, y], "head_top": [x, y]}, "side2": {...}}; points are named by MPEG-4 '
                        "FDP (9.3 the nose tip), by MediaPipe landmark as mp:N, or head_top / head_back")
    p.add_argument("--method", default="dffd", choices=["dffd", "rbf"],
                   help="head modification with --fast: Dirichlet free-form deformation (the paper) or the thin-plate "
                        "spline (without --fast the head is not warped)")
    p.add_argument("--keep-expression", action="store_true",
                   help="keep the photo's expression in the rest pose (default: fitted and taken off)")
    p.add_argument("--fast", action="store_true",
                   help="leave out the identity from the photos' shading (about 20 s on 2 cores) and warp the head "
                        "fully onto the landmarks: a head less like the person's")
    p.add_argument("--texture-size", type=int, default=1024,
                   help="texture atlas pixels per side (64..2048; a multiple of 16 keeps the back seam exact)")
    p.add_argument("--quiet", action="store_true", help="no progress on the terminal")
    p.add_argument("--rig", action="store_true",
                   help="GLB: every control as a morph target (AUs, emotions, visemes, FAP expressions, ARKit)")
    add_output(p, SUFFIXES)
    p.add_argument("--size", type=SIZE, default=DEFAULT_SIZE, help="PNG pixels per view (an even number, 16..4096)")
    p.set_defaults(func=_cmd_photo)
