"""faceanim au, transfer: FACS action units and expression transfer (Erdogdu 2010)."""

from __future__ import annotations

from pathlib import Path

from faceanim.cli.commands import HELP
from faceanim.cli.common import (
    DEFAULT_SIZE,
    SIZE,
    CommandError,
    add_face,
    add_output,
    check_outputs,
    face_at,
    load_face,
    report,
    write_pose,
)

SUFFIXES = [".glb", ".png", ".obj", ".ply"]


def _cmd_au(args) -> None:
    import numpy as np

    from faceanim.rig.facs import default_library
    from faceanim.rig.transfer import CUTOFF, ExpressionTransfer, default_model

    lib = default_library()
    if args.emotion and args.au:
        raise CommandError("give --au or --emotion, not both")
    if not args.emotion and not args.au:
        raise CommandError("give --au (e.g. 12 or 1,2 or all) or --emotion (e.g. joy)")
    m = lib.intensity(args.magnitude)
    mix = lib.emotion(args.emotion) if args.emotion else {au: 1.0 for au in lib.parse_action_units(args.au)}
    check_outputs(args.output)
    face = load_face(args)
    xf = ExpressionTransfer(face, lib, method=args.method)
    model = default_model()
    pose = xf.mixture_delta(model, {au: w * m for au, w in mix.items()}, side=args.side)
    shapes = {"pose": pose}
    if Path(args.output).suffix.lower() == ".glb":
        shapes.update(xf.rig(model, sides=args.halves).blendshape_dict())
        shapes["pose"] = pose * (np.linalg.norm(pose, axis=1) >= CUTOFF * xf.frame.iod)[:, None]
    report(write_pose(args, face, shapes, "pose", 1.0))


def _cmd_transfer(args) -> None:
    from faceanim.rig.facs import default_library
    from faceanim.rig.transfer import ExpressionTransfer, learn_expression

    lib = default_library()
    m = lib.intensity(args.magnitude)
    aus = lib.parse_action_units(args.au)
    check_outputs(args.output)
    s0 = face_at(args.source_neutral, args.source_neutral_landmarks)
    s1 = face_at(args.source_expressive, args.source_expressive_landmarks)
    sample = learn_expression(s0.mesh, s1.mesh, s0.landmarks, s1.landmarks, lib)
    face = load_face(args)
    xf = ExpressionTransfer(face, lib, method=args.method)
    full = xf.points_delta(sample, aus, 1.0, side=args.side)
    report(write_pose(args, face, {"expression": full}, "expression", m))


def register(sub) -> None:
    a = sub.add_parser("au", help=HELP["au"])
    add_face(a, aliases=("--target",))
    a.add_argument("--au", help="action units: 12, 1,2 or all")
    a.add_argument("--emotion", help="joy, sadness, surprise, fear, anger or disgust")
    a.add_argument("--magnitude", default="1.0", help="m in [0, 1] or a FACS intensity A-E")
    a.add_argument("--side", default="both", choices=["both", "L", "R"], help="one-sided action (subject's side)")
    a.add_argument("--method", default="surface", choices=["surface", "tps"], help="warp interpolant")
    a.add_argument("--halves", action="store_true", help="GLB: also one-sided AUn_L / AUn_R morph targets")
    a.add_argument("--compact", action="store_true", help="GLB: quantized (KHR_mesh_quantization), several times smaller")
    add_output(a, SUFFIXES)
    a.add_argument("--size", type=SIZE, default=DEFAULT_SIZE, help="PNG pixels per side (16..4096)")
    a.set_defaults(func=_cmd_au)

    t = sub.add_parser("transfer", help=HELP["transfer"])
    t.add_argument("--source-neutral", required=True, metavar="MESH")
    t.add_argument("--source-expressive", required=True, metavar="MESH")
    t.add_argument("--source-neutral-landmarks", metavar="JSON", help="landmarks of the neutral scan (else detected)")
    t.add_argument("--source-expressive-landmarks", metavar="JSON",
                   help="landmarks of the expressive scan; for scans of another topology, hand-marked landmarks "
                        "learn far better than detected ones")
    add_face(t, aliases=("--target",), positional=False)
    t.add_argument("--au", default="all", help="action units whose control points move: 12, 1,2 or all")
    t.add_argument("--magnitude", default="1.0", help="m in [0, 1] or a FACS intensity A-E")
    t.add_argument("--side", default="both", choices=["both", "L", "R"])
    t.add_argument("--method", default="surface", choices=["surface", "tps"])
    t.add_argument("--compact", action="store_true", help="GLB: quantized (KHR_mesh_quantization)")
    add_output(t, SUFFIXES)
    t.add_argument("--size", type=SIZE, default=DEFAULT_SIZE, help="PNG pixels per side")
    t.set_defaults(func=_cmd_transfer)
