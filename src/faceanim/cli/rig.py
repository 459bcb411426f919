"""``faceanim rig``: any face mesh in, a rigged glTF or VRM 1.0 out (every control a named morph
target; :mod:`faceanim.autorig` does the work)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from faceanim.cli.commands import HELP
from faceanim.cli.common import (
    CommandError,
    add_face,
    add_output,
    check_outputs,
    face_path,
    load_face,
    report,
    stages,
)
from faceanim.cli.mesh import _axes
from faceanim.errors import shown

BLINK_STYLES = ("realistic", "stylised")  # faceanim.rig.arkit.STYLES (not imported here: the CLI starts light)

VRM_TEXT_LIMIT = 200  # characters of a VRM meta field given on the command line


def _meta_text(flag: str):
    def parse(text: str) -> str:
        if not text.strip() or len(text) > VRM_TEXT_LIMIT or not text.isprintable():
            raise argparse.ArgumentTypeError(f"{flag} takes 1 to {VRM_TEXT_LIMIT} printable characters")
        return text.strip()
    return parse


def _report_skipped(skipped: dict, notes: dict | None = None) -> None:
    for name, what in (notes or {}).items():
        print(f"{name} on this face: {what}", file=sys.stderr)
    if skipped:
        by_reason: dict[str, list[str]] = {}
        for name, why in skipped.items():
            by_reason.setdefault(why, []).append(name)
        print("not made on this face: " + "; ".join(f"{', '.join(names)} ({why})" for why, names in by_reason.items()),
              file=sys.stderr)


def _cmd_avatar(args, sets, source: Path, out: Path) -> None:
    """A whole avatar (skinned or several meshes) rigged in place: :mod:`faceanim.avatar`."""
    from faceanim.avatar import rig_avatar

    if out.suffix.lower() != source.suffix.lower():
        raise CommandError(f"an avatar is written back as it came: '{shown(source.name, 60, tail=True)}' in, "
                           f"a {source.suffix.lower()} out (give -o NAME{source.suffix.lower()})")
    if args.landmarks:
        raise CommandError("--landmarks is for a single face mesh; an avatar's head is found and its landmarks "
                           "detected (choose the head with --head-mesh NAME)")
    if args.compact:
        raise CommandError("--compact is for a single face mesh; an avatar keeps its own accessors")
    if args.vrm is not None or args.license is not None:
        raise CommandError("--vrm and --license are for a face mesh rigged into a new avatar; a whole avatar keeps "
                           "its own VRM version and licence")
    check_outputs(args.output)
    forward = None if args.forward == "+z" and args.up == "+y" else args.forward
    done = rig_avatar(source, out, sets, head_mesh=args.head_mesh, replace=args.replace, forward=forward, up=args.up,
                      style=args.style)
    rigged = " + ".join([done.head, *done.companions])
    replaced = f" ({len(done.replaced)} replacing its own)" if done.replaced else ""
    print(f"{len(done.written)} morph targets written to {rigged}{replaced}")
    if done.kept:
        print(f"kept the avatar's own targets (--replace to overwrite): {', '.join(done.kept[:12])}"
              + (" ..." if len(done.kept) > 12 else ""), file=sys.stderr)
    _report_skipped(done.skipped, done.notes)
    report([out])


def _licence(text: str) -> dict:
    """``--license``: a preset (:data:`~faceanim.standards.vrm.LICENSE_PRESETS`) or KEY=VALUE,... of
    VRM 1.0 meta fields (their values checked by the writer's own meta check)."""
    from faceanim.standards.vrm import LICENSE_FIELDS, LICENSE_FLAGS, LICENSE_PRESETS

    text = str(text).strip()
    if text.lower() in LICENSE_PRESETS:
        return dict(LICENSE_PRESETS[text.lower()])
    out: dict = {}
    items = [p.strip() for p in text.split(",")]
    if "" in items:
        raise argparse.ArgumentTypeError(f"--license has an empty item; give {', '.join(LICENSE_PRESETS)} or "
                                         "KEY=VALUE,... separated by single commas")
    for item in items:
        key, eq, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not eq or key not in (*LICENSE_FIELDS, *LICENSE_FLAGS):
            raise argparse.ArgumentTypeError(
                f"'{shown(item, 40)}' is not a licence; give {', '.join(LICENSE_PRESETS)} or KEY=VALUE with KEY one of "
                f"{', '.join((*LICENSE_FIELDS, *LICENSE_FLAGS))}")
        if key in LICENSE_FLAGS:
            if value.lower() not in ("true", "false"):
                raise argparse.ArgumentTypeError(f"--license {key} takes true or false, not '{shown(value, 20)}'")
            out[key] = value.lower() == "true"
        elif value not in LICENSE_FIELDS[key]:
            raise argparse.ArgumentTypeError(f"--license {key} takes {', '.join(LICENSE_FIELDS[key])}, "
                                             f"not '{shown(value, 40)}'")
        else:
            out[key] = value
    return out


def _meta(args, face) -> dict:
    return {"name": args.title or shown(face.name, VRM_TEXT_LIMIT), "authors": [args.author], **(args.license or {})}


def _cmd_rig(args) -> None:
    from faceanim.autorig import auto_rig, parse_sets, write_rigged
    from faceanim.avatar import is_avatar

    sets = parse_sets(args.set)
    out = Path(args.output)
    if args.forward.lstrip("+-") == args.up.lstrip("+-"):
        raise CommandError(f"--forward {args.forward} and --up {args.up} lie on one axis: they must be different axes")
    source = face_path(args)
    if source and source != "default" and is_avatar(source):
        return _cmd_avatar(args, sets, Path(source), out)
    if args.head_mesh or args.replace:
        raise CommandError("--head-mesh and --replace are for a whole avatar (.glb/.vrm with a skin or several meshes)")
    if (args.vrm is not None or args.license is not None) and out.suffix.lower() != ".vrm":
        raise CommandError("--vrm and --license are for a .vrm output; give -o NAME.vrm or leave them out")
    if args.compact and out.suffix.lower() == ".vrm":
        raise CommandError("--compact writes KHR_mesh_quantization, which VRM tools do not all read; drop it for a .vrm")
    check_outputs(args.output)
    with stages("rig", len(sets) + 2, args.quiet) as step:
        step("the face and its landmarks")
        face = load_face(args)
        auto = auto_rig(face, sets, progress=step, style=args.style)
        step(f"writing {out.name}")
        written, left_out = write_rigged(out, auto, compact=args.compact, meta=_meta(args, face),
                                         vrm_version=1 if args.vrm is None else args.vrm)
    counts = ", ".join(f"{name} {len(names)}" for name, names in auto.sets.items())
    if left_out:
        print("VRM presets left out: " + "; ".join(f"{p} ({why})" for p, why in left_out.items()), file=sys.stderr)
    print(f"{len(auto.shapes)} morph targets ({counts})")
    _report_skipped(auto.skipped, auto.notes)
    report([written])


def register(sub) -> None:
    from faceanim.catalogue import RIG_SETS

    p = sub.add_parser("rig", help=HELP["rig"],
                       description="Rig a face mesh automatically: landmarks detected (or --landmarks), then every "
                                   "control of the asked sets written as a named morph target on the mesh, vertex "
                                   "order kept. Sets: arkit (Apple ARKit blendshapes, eyeBlinkLeft ... ; Left/Right "
                                   "are the subject's sides), visemes (the 15 Oculus visemes viseme_sil ... "
                                   "viseme_U), rpm (Ready Player Me's mouthOpen, mouthSmile, eyesClosed, eyesLookUp, "
                                   "eyesLookDown), au (FACS action units with one-sided halves), emotions (joy ... "
                                   "disgust), fap (MPEG-4 FAPs by name). A .vrm also binds VRM 1.0's expression "
                                   "presets (happy ... neutral) to them. A whole avatar (a .glb/.vrm with a skin "
                                   "or several meshes) is rigged in place: its head (and eyes, teeth) found, the "
                                   "targets added to them, everything else written back unchanged.")
    add_face(p)
    _axes(p)
    p.add_argument("--set", default="all", metavar="SETS",
                   help=f"comma-separated sets to write: {','.join(RIG_SETS)} or all")
    p.add_argument("--quiet", action="store_true", help="no progress on the terminal")
    p.add_argument("--compact", action="store_true",
                   help="quantised .glb (KHR_mesh_quantization): smaller, for delivery")
    p.add_argument("--style", choices=BLINK_STYLES, default="realistic",
                   help="how the blinks close the lids: realistic (a person's tall upper lid folding down; "
                        "scans, the default face, photo heads) or stylised (a game or anime avatar's short lid "
                        "sheet: the margin travels, the skin above barely) (default: realistic)")
    p.add_argument("--head-mesh", metavar="NAME",
                   help="a whole avatar: the mesh that is the head (default: found by name, else by geometry)")
    p.add_argument("--replace", action="store_true",
                   help="a whole avatar: replace its own targets (and VRM expressions) named as faceanim's "
                        "(default: keep them)")
    p.add_argument("--vrm", type=int, choices=(0, 1), metavar="0|1",
                   help="the VRM version of a .vrm: 1 (VRM 1.0) or 0 (VRM 0.x, for VSeeFace, VMagicMirror and "
                        "other 0.x apps) (default: 1)")
    p.add_argument("--license", type=_licence, metavar="LICENCE",
                   help="a .vrm's licence: private (only the author, no redistribution), cc0, cc-by, or VRM 1.0 "
                        "meta fields as KEY=VALUE,... (avatarPermission, commercialUsage, creditNotation, "
                        "modification, allowRedistribution, allowExcessivelyViolentUsage, ...) (default: private)")
    p.add_argument("--title", type=_meta_text("--title"), help="the avatar's name in a .vrm (default: the mesh's)")
    p.add_argument("--author", type=_meta_text("--author"), default="unknown",
                   help="the author written in a .vrm's meta")
    add_output(p, [".glb", ".vrm"])
    p.set_defaults(func=_cmd_rig)
