"""What every command shares: the face options, output paths, numbers in range, progress, writing a pose."""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from pathlib import Path

from faceanim.errors import FaceAnimError, shown
from faceanim.limits import (
    MAX_DURATION,
    MAX_FPS,
    MAX_FRAMES,
    MAX_GRID,
    MAX_IMAGE_SIZE,
    MIN_IMAGE_SIZE,
    LimitError,
    check_range,
)

DEFAULT_SIZE = 512  # pixels per side of PNG and MP4 output


class CommandError(FaceAnimError):
    """Options that do not go together."""


def _arg_type(name: str, low: float, high: float, integer: bool = False, low_inclusive: bool = True):
    def parse(text: str):
        try:
            return check_range(text, name, low, high, integer=integer, low_inclusive=low_inclusive)
        except LimitError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    parse.__name__ = name.lstrip("-")
    return parse


_SIZE_RANGE = _arg_type("--size", MIN_IMAGE_SIZE, MAX_IMAGE_SIZE, integer=True)


def _even_size(text: str) -> int:
    """Pixels per side: a whole, even number (H.264 video needs even sizes) in range."""
    size = _SIZE_RANGE(text)
    if size % 2:
        raise argparse.ArgumentTypeError(f"--size must be even (video needs even sizes), got {size}")
    return size


_even_size.__name__ = "size"
FPS = _arg_type("--fps", 0.0, MAX_FPS, low_inclusive=False)
SIZE = _even_size
FRAMES = _arg_type("--frames", 2, MAX_FRAMES, integer=True)
GRID = _arg_type("--grid", 8, MAX_GRID, integer=True)
DURATION = _arg_type("--duration", 0.0, MAX_DURATION, low_inclusive=False)
INTENSITY = _arg_type("--intensity", 0.0, 2.0)
ANGLE = _arg_type("angle", -180.0, 180.0)


def output_type(suffixes):
    """An argparse type accepting paths that end in one of ``suffixes``."""
    def check(value: str) -> str:
        if Path(value).suffix.lower() not in suffixes:
            raise argparse.ArgumentTypeError(f"'{shown(value, 80)}' must end in one of: {', '.join(suffixes)}")
        return value
    return check


def add_output(p, suffixes, flag: str = "-o", long: str = "--output", required: bool = True, help: str = ""):
    p.add_argument(flag, long, required=required, type=output_type(suffixes), metavar="OUT",
                   help=(help + " " if help else "") + f"({' '.join(suffixes)})")


def add_face(p, aliases: tuple[str, ...] = (), positional: bool = True, landmarks: bool = True,
             default_help: str = "the embedded default face"):
    """The face, given the same way everywhere: ``--face MESH`` (or the positional MESH, or an
    older alias such as ``--target``/``--base``), and ``--landmarks JSON`` instead of detection."""
    if positional:
        p.add_argument("face_positional", nargs="?", metavar="MESH", help="the face mesh (same as --face)")
    p.add_argument("--face", *aliases, dest="face", metavar="MESH",
                   help=f"the face mesh: .obj, .ply, .glb, .gltf (default: {default_help})")
    if landmarks:
        p.add_argument("--landmarks", metavar="JSON",
                       help="the face's landmarks (478 MediaPipe points or the basic 22) instead of detection")


def face_path(args, required: bool = False):
    given = [v for v in (getattr(args, "face_positional", None), getattr(args, "face", None)) if v]
    if len(given) == 2 and given[0] != given[1]:
        raise CommandError(f"two faces given ('{given[0]}' and --face '{given[1]}'); give one")
    if not given and required:
        raise CommandError("give the face mesh (--face MESH" + (", or MESH first)" if hasattr(args, "face_positional")
                                                                 else ")"))
    return given[0] if given else None


# faces already bound, by (mesh path, landmarks path, forward, up): ``faceanim batch`` sets this in
# a worker so the tasks on one face share one bound Face (None: load every time)
BOUND_FACES: dict | None = None
# the files a command reported writing (``faceanim batch`` collects them; None: not collected)
REPORTED: list | None = None


def key_of(path, landmarks=None, forward: str = "+z", up: str = "+y") -> tuple:
    """What a face is loaded from: (mesh path or None for the default, landmarks, forward, up)."""
    path = None if path in (None, "default") else str(Path(path).resolve())
    return (path, str(Path(landmarks).resolve()) if landmarks else None, forward, up)


def face_key(args, required: bool = False) -> tuple:
    """:func:`key_of` the command's face (``--face``/MESH, ``--landmarks``, ``--forward``, ``--up``)."""
    return key_of(face_path(args, required), getattr(args, "landmarks", None), getattr(args, "forward", "+z"),
                  getattr(args, "up", "+y"))


def face_at(path, landmarks=None, forward: str = "+z", up: str = "+y"):
    """``Face.load`` of another face a command reads (e.g. a transfer's source scans), or the one
    already bound for it."""
    from faceanim.face.face import Face

    if BOUND_FACES is not None:
        bound = BOUND_FACES.get(key_of(path, landmarks, forward, up))
        if bound is not None:
            return bound
    return Face.load(path, landmarks, forward, up)


def load_face(args, required: bool = False):
    from faceanim.face.face import Face

    if BOUND_FACES is not None:
        bound = BOUND_FACES.get(face_key(args, required))
        if bound is not None:
            return bound
    return Face.load(face_path(args, required), getattr(args, "landmarks", None),
                     getattr(args, "forward", "+z"), getattr(args, "up", "+y"))


def check_outputs(*paths) -> None:
    """Refuse before any work: outputs that cannot be written, or one path named twice."""
    from faceanim.io.files import check_output_path

    named = [Path(p) for p in paths if p]
    resolved = [p.resolve() for p in named]
    for k, p in enumerate(resolved):
        if p in resolved[:k]:
            raise CommandError(f"'{named[k]}' is named as two outputs; give each output its own path")
    for p in named:
        check_output_path(p)


def progress(total: int, desc: str, quiet: bool = False):
    """A progress bar on a terminal (tqdm), nothing when piped or quiet."""
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="frame", disable=quiet or not sys.stderr.isatty(), leave=False)


@contextlib.contextmanager
def stages(desc: str, total: int, quiet: bool = False):
    """Progress through ``total`` named steps on a terminal (nothing when piped or quiet): yields a
    callable taking each step's name as it starts (the library's ``progress`` hooks)."""
    from tqdm import tqdm

    bar = tqdm(total=total, desc=desc, unit="step", disable=quiet or not sys.stderr.isatty(), leave=False,
               bar_format="{desc} [{elapsed}]")
    started = [0]

    def step(name: str) -> None:
        started[0] += 1
        bar.set_description_str(f"{desc}: {min(started[0], total)}/{total} {name}")

    try:
        yield step
    finally:
        bar.close()


def write_pose(args, face, shapes: dict, pose: str, weight: float) -> list[Path]:
    """The face posed with blendshape ``pose`` at ``weight`` as OBJ/PLY or a PNG render; GLB:
    the rest mesh with every blendshape as a morph target and a short animation of ``pose``
    from 0 to ``weight`` and back."""
    import numpy as np

    from faceanim.io.meshio import save_mesh
    from faceanim.player import write_rig_gltf
    from faceanim.render import render_png
    from faceanim.rig.rig import Rig

    rig = Rig.from_blendshapes(face.mesh, shapes)
    out = Path(args.output)
    suffix = out.suffix.lower()
    if suffix == ".png":
        render_png(face.mesh, out, vertices=rig.pose({pose: weight}), size=(args.size, args.size), **face.view())
        return [out]
    if suffix == ".glb":
        curves = np.zeros((3, rig.n_controls))
        curves[1, rig.index(pose)] = weight
        return [write_rig_gltf(rig, curves, out, fps=1.0, name="expression", names=rig.controls,
                               quantize=getattr(args, "compact", False))]
    return save_mesh(face.mesh, out, vertices=rig.pose({pose: weight}), avoid=named_paths(args))


def named_paths(args) -> list[str]:
    """Every path-like value given on the command line but the output: files a format's
    companions (an OBJ's .mtl and texture) must never take."""
    out = []
    for key, value in vars(args).items():
        if key == "output" or key == "func":
            continue
        for v in value if isinstance(value, list) else [value]:
            if isinstance(v, str) and v:
                out.append(v)
    return out


@contextlib.contextmanager
def outputs_together():
    """For commands that write several files: yields a list to append each written path to; if
    anything fails after the first is written, the ones already written are removed (a command
    leaves all its outputs or none)."""
    written: list = []
    try:
        yield written
    except BaseException:
        for p in written:
            Path(p).unlink(missing_ok=True)
        raise


def note_written(paths) -> None:
    """Collect the files a command wrote (for ``faceanim batch``), without printing."""
    if REPORTED is not None:
        REPORTED.extend(str(p) for p in paths)


def report(paths) -> None:
    note_written(paths)
    print("wrote " + ", ".join(str(p) for p in paths))


def quiet_native_logs(verbose: bool, whole_process: bool = False) -> None:
    """MediaPipe and TensorFlow Lite log to stderr from C++; keep that quiet unless --verbose.

    ``whole_process`` (the ``faceanim`` program, which ends with its command): file descriptor 2
    goes to /dev/null for the rest of the run and Python's ``sys.stderr`` writes to a private copy
    of the terminal's. MediaPipe's graph threads log when they start, also after the block that
    silenced them was left (a Ctrl-C as a landmarker is made unwinds past it while they run), so
    silencing descriptor 2 block by block can let a line through after the command's last word."""
    if verbose:
        os.environ["FACEANIM_VERBOSE"] = "1"
        return
    os.environ.setdefault("GLOG_minloglevel", "2")
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
    if whole_process:
        _native_stderr_to_devnull()


def _native_stderr_to_devnull() -> None:
    import faulthandler

    try:
        sys.stderr.flush()
        own = os.dup(2)
    except (OSError, AttributeError, ValueError):  # no stderr at all: nothing to keep quiet
        return
    try:
        stream = open(own, "w", encoding=sys.stderr.encoding or "utf-8", errors="backslashreplace",
                      buffering=1, closefd=True)
    except (OSError, LookupError):
        os.close(own)
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 2)
    os.close(devnull)
    sys.stderr = stream
    if faulthandler.is_enabled():  # PYTHONFAULTHANDLER wrote to descriptor 2: keep its dumps visible
        faulthandler.enable(file=stream, all_threads=True)


def own_targets(args, suffix: str) -> bool:
    """Whether the curves go onto the --face avatar's own morph targets by their ARKit names: the face
    is a .glb/.vrm that has such targets and the output is .glb/.vrm. A .vrm output needs one."""
    face = Path(args.face) if args.face else None
    own = vrm = False
    if face is not None and face.suffix.lower() in (".glb", ".vrm") and suffix in (".glb", ".vrm"):
        from faceanim.avatar import arkit_targets
        from faceanim.io.scene import read_scene

        try:
            scene = read_scene(face)
        except FaceAnimError:  # damaged or not an avatar: loading it as a face says what is wrong
            scene = None
        own = scene is not None and bool(arkit_targets(scene))
        vrm = own and bool({"VRMC_vrm", "VRM"} & set(scene.document.extensions or {}))
    if suffix == ".vrm" and not (own and vrm):
        raise CommandError("a .vrm output plays onto a --face VRM avatar whose morph targets carry ARKit's names; "
                           "write .glb, or rig the avatar first with faceanim rig")
    return own


def play_own(args, out: Path, curves, fps: float, name: str, extras: dict | None = None, head=None) -> Path:
    """Play ``curves`` (F, 52, Live Link order) onto the --face avatar's own targets into ``out``,
    and ``head`` ((F, 3) yaw, pitch, roll, radians) onto its head bone if it has one."""
    from faceanim.avatar import play_on_avatar

    played = play_on_avatar(args.face, out, curves, fps, name, extras, head=head)
    for mesh, names in played.driven.items():
        print(f"{len(names)} ARKit curves onto the avatar's own targets of mesh '{shown(mesh, 60)}'")
    if head is not None:
        print(f"the head's motion onto its bone '{shown(played.head_bone, 60)}'" if played.head_bone else
              "no head bone found (a VRM humanoid's head or a joint named Head): the head stays still")
    return out


OUTPUTS = ("output", "image", "save_points")  # the options that name files a command writes


def outputs_are_not_inputs(args) -> None:
    """Refuse an output that is one of the command's input files (it would be replaced by the run)."""
    outputs = [v for v in (getattr(args, n, None) for n in OUTPUTS) if isinstance(v, str) and v]
    inputs = [x for k, v in sorted(vars(args).items()) if k not in OUTPUTS
              for x in (v if isinstance(v, list) else [v]) if isinstance(x, str) and x and os.path.isfile(x)]
    for out in outputs:
        if os.path.isfile(out) and any(os.path.samefile(out, x) for x in inputs):
            raise CommandError(f"the output '{shown(out, 80, tail=True)}' is also an input; give the output its "
                               "own path")
