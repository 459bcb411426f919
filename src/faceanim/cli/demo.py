"""``faceanim demo``: the embedded default face animated (GLB, MP4, PNGs)."""

from __future__ import annotations

from pathlib import Path

from faceanim.cli.commands import HELP
from faceanim.cli.common import DEFAULT_SIZE, FPS, SIZE, check_outputs, stages
from faceanim.errors import FaceAnimError
from faceanim.limits import DEFAULT_FPS


def _cmd_demo(args) -> None:
    from faceanim.demo import run_demo
    from faceanim.limits import check_video

    check_video(1, args.size, args.size)
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise FaceAnimError(f"--out '{out}' is a file; give a folder")
    if not out.exists():
        check_outputs(out)  # its parent must exist and be writable
    with stages("demo", 4, args.quiet) as step:
        written = run_demo(out, fps=args.fps, size=args.size, quiet=args.quiet, progress=step)
    print(f"wrote {len(written)} files to {out}/:")
    for p in written:
        print(f"  {p}  ({p.stat().st_size / 1024:.0f} KiB)")


def register(sub) -> None:
    d = sub.add_parser("demo", help=HELP["demo"])
    d.add_argument("--out", default="faceanim-demo", help="output folder")
    d.add_argument("--fps", type=FPS, default=DEFAULT_FPS, help="frames per second (up to 240)")
    d.add_argument("--size", type=SIZE, default=DEFAULT_SIZE, help="image pixels per side (16..4096)")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=_cmd_demo)
