"""``faceanim batch JOBS.yaml -o OUTDIR``: one faceanim command over every combination of its
inputs, on Dask (:mod:`faceanim.batch`). Each task is the command itself, called in the worker's
process with its face already bound (not a shell-out)."""

from __future__ import annotations

import contextlib
import io
import os
import sys
import time
from functools import lru_cache
from pathlib import Path

from faceanim.cli.commands import HELP
from faceanim.cli import build_parser
from faceanim.cli.common import CommandError
from faceanim.errors import FaceAnimError, shown

# the operations a batch may run: name -> the command's words; and those that bind a face
OPERATIONS = {"rig": ("rig",), "au": ("au",), "transfer": ("transfer",), "wires extract": ("wires", "extract"),
              "wires apply": ("wires", "apply"), "say": ("say",), "fap play": ("fap", "play"),
              "perform": ("perform",), "photo": ("photo",), "render": ("render",)}
FACE_OPERATIONS = {"rig", "au", "transfer", "wires extract", "wires apply", "say", "fap play", "perform"}
# other faces an operation reads, bound like its face: (mesh argument, its landmarks argument)
OTHER_FACES = {"transfer": (("source_neutral", "source_neutral_landmarks"),
                            ("source_expressive", "source_expressive_landmarks"))}
MAX_WORKERS = 256
MAX_RETRIES = 10


@lru_cache(maxsize=1)
def _parser():
    return build_parser()


def _subparser(words):
    import argparse

    p = _parser()
    for w in words:
        sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
        p = sub.choices[w]
    return p


def _arguments(words) -> dict[str, tuple[str, object]]:
    """name (underscored) -> ("option", its long flag) or ("positional", action), for a command's
    arguments other than the output and help."""
    import argparse

    out: dict[str, tuple[str, object]] = {}
    for a in _subparser(words)._actions:
        if isinstance(a, argparse._HelpAction) or a.dest in ("output", "func"):
            continue
        if a.option_strings:
            for flag in a.option_strings:
                if flag.startswith("--"):
                    out.setdefault(flag[2:].replace("-", "_"), ("option", flag, a))
        elif a.dest == "face_positional":
            continue  # the face is --face
        else:
            out[a.dest] = ("positional", a.dest, a)
    return out


def _argv_part(name: str, value, spec, where: str) -> list[str]:
    import argparse

    kind, flag, action = spec
    if kind == "positional":
        return [str(value)]
    if isinstance(action, (argparse._StoreTrueAction, argparse._StoreFalseAction)):
        if not isinstance(value, bool):
            raise CommandError(f"option '{name}' ({where}) is a switch: give true or false")
        return [flag] if value else []
    if isinstance(value, bool):
        raise CommandError(f"option '{name}' ({where}) takes a value, not {str(value).lower()}")
    if value is None:
        return []
    values = value if isinstance(value, list) else [value]
    if len(values) > 1 and not isinstance(action, argparse._AppendAction) and action.nargs not in ("+", "*"):
        raise CommandError(f"option '{name}' ({where}) takes one value, not a list")
    if isinstance(action, argparse._AppendAction):
        return [x for v in values for x in (flag, str(v))]
    return [flag, *[str(v) for v in values]]


NOT_FILES = {"say": ("text",)}  # positional arguments that are words, not files: options, not inputs
FILE_METAVARS = {"MESH", "JSON", "SOUND", "TXT", "IMAGE", "MOTION.npz"}  # options that name files


def faceanim_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("faceanim")
    except PackageNotFoundError:
        return "unknown"


def _where_refused(job, known: dict, message: str) -> str:
    """The job file's key (and line) an argparse refusal is about: the option or input whose flag
    it names, or the output."""
    import re

    named = re.match(r"argument ([^:]+):", message)
    flags = [f.strip() for f in named.group(1).split("/")] if named else []
    if "--output" in flags or "-o" in flags:
        return f"output ({job.where('output')})"
    for name, (_, flag, _) in known.items():
        if flag in flags or name in flags:
            group = "inputs" if name in job.inputs else "options"
            return f"{group[:-1]} '{name}' ({job.where(f'{group}.{name}')})"
    return job.source


def plan(job, out_dir: Path, progress=None):
    """The job's tasks as :class:`~faceanim.batch.runner.PlannedTask` (checked: operation,
    input and option names, and each task's command line as the command itself parses it).
    ``progress(done, total)`` is called as tasks are planned (a big job takes a while: every
    command line is parsed and every input file hashed)."""
    from faceanim.batch.jobs import expand
    from faceanim.batch.manifest import file_hash, signature
    from faceanim.batch.runner import PlannedTask
    from faceanim.cli.common import face_key, key_of

    words = OPERATIONS.get(job.operation)
    if words is None:
        raise CommandError(f"unknown operation '{shown(job.operation)}' ({job.where('operation')}); choose one of: "
                           f"{', '.join(OPERATIONS)}")
    known = _arguments(words)
    for group, names in (("inputs", job.inputs), ("options", job.options)):
        for name in names:
            if name not in known:
                raise CommandError(f"unknown {group[:-1]} '{shown(name)}' for {job.operation} "
                                   f"({job.where(f'{group}.{name}')}); it takes: {', '.join(sorted(known))}")
    for name in NOT_FILES.get(job.operation, ()):
        if name in job.inputs:
            raise CommandError(f"input '{name}' ({job.where(f'inputs.{name}')}) is words, not a file: give it "
                               "under options")
    for name, spec in known.items():
        action = spec[2]
        if getattr(action, "required", False) and name not in job.inputs and name not in job.options:
            raise CommandError(f"{job.operation} needs '{name}' ({job.where('inputs')}); add it to inputs or options")
    tasks = expand(job)
    hashes: dict = {}
    option_argv: list[str] = []
    option_files: dict[str, str] = {}  # options naming files (a landmarks JSON, photo points): by content too
    for name, value in job.options.items():
        where = job.where(f"options.{name}")
        if getattr(known[name][2], "metavar", None) in FILE_METAVARS and value is not None:
            # a file given as an option is relative to the job file, like the inputs, and must exist
            values = value if isinstance(value, list) else [value]
            resolved = []
            for v in values:
                path = Path(os.path.normpath(job.base / str(v)))
                if not path.is_file():
                    raise CommandError(f"option '{name}' ({where}): '{shown(v, 80)}' is not a file")
                resolved.append(str(path))
            value = resolved if isinstance(value, list) else resolved[0]
            option_files.update({f"{name}[{k}]": p for k, p in enumerate(resolved)})
        option_argv += _argv_part(name, value, known[name], where)
    # the files a task reads, which no task may write (a batch writing into its inputs' folder)
    read = {str(Path(p).resolve()) for t in tasks for _, p in t.inputs} | \
        {str(Path(p).resolve()) for p in option_files.values()}
    parser = _parser()
    planned = []
    version = faceanim_version()
    for k, t in enumerate(tasks):
        if progress is not None and k % 100 == 0:
            progress(k, len(tasks))
        out = out_dir / t.output
        if str(out.resolve()) in read:
            raise CommandError(f"output ({job.where('output')}) '{shown(t.output, 80)}' would overwrite an input of "
                               "the job; choose another output folder or pattern")

        def command(paths) -> list[str]:
            argv, positional = list(words), []
            for name, path in paths:
                part = _argv_part(name, path, known[name], job.where(f"inputs.{name}"))
                (positional if known[name][0] == "positional" else argv).extend(part)
            return argv[:len(words)] + positional + argv[len(words):] + option_argv

        argv = command(t.inputs) + ["-o", str(out)]
        # what the result depends on, wherever the data and OUTDIR are: the inputs by name (their
        # content is hashed), the options, the output's place, faceanim's version
        recorded = command([(name, f"{{{name}}}") for name, _ in t.inputs]) + [t.output, version]
        err = io.StringIO()
        try:
            with contextlib.redirect_stderr(err):
                args = parser.parse_args(argv)
        except SystemExit:
            message = err.getvalue().strip().splitlines()[-1] if err.getvalue().strip() else "bad arguments"
            message = message.split(": error: ", 1)[-1]
            raise CommandError(f"{_where_refused(job, known, message)}: {job.operation} would refuse it: "
                               f"{shown(message, 300)}") from None
        faces = [face_key(args)] if job.operation in FACE_OPERATIONS else []
        faces += [key_of(getattr(args, mesh), getattr(args, lms)) for mesh, lms in OTHER_FACES.get(job.operation, ())]
        try:
            inputs = {name: file_hash(path, hashes) for name, path in [*t.inputs, *option_files.items()]}
        except OSError:
            raise CommandError(f"an input of task '{shown(t.output, 80)}' cannot be read; check its permissions") \
                from None
        planned.append(PlannedTask(t.output, argv, tuple(dict.fromkeys(faces)),
                                   signature(job.operation, recorded, inputs)))
    return planned


def bind(face):
    """A bound face for ``face_key`` (mesh path, landmarks, forward, up): loaded, landmarks
    found, its frame and regions computed once."""
    from faceanim.face.face import Face

    path, landmarks, forward, up = face
    f = Face.load(path, landmarks, forward, up)
    for part in ("frame", "skin", "face_region"):  # cached properties: computed here, shipped with it
        getattr(f, part, None)
    return f


def work(argv, out_dir, bound: dict) -> dict:
    """Run one task (a command line the job's check already parsed) in this process: the
    command's own function, its faces the bound ones (``bound``: face key -> Face), its printing
    (stdout and stderr) kept from the terminal."""
    from faceanim.cli import common

    from faceanim.cli.common import outputs_are_not_inputs

    args = _parser().parse_args(argv)
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    common.BOUND_FACES = dict(bound) if bound else None
    common.REPORTED = []
    start = time.perf_counter()
    try:
        # the command's report and notes (e.g. rig's shapes not made) stay out of the terminal:
        # a thousand tasks would print a thousand of them
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            outputs_are_not_inputs(args)  # as the command line checks it (the plan checks it too)
            args.func(args)
        written = common.REPORTED or [str(out)]
        root = Path(out_dir).resolve()
        outputs = sorted({str(Path(p).resolve().relative_to(root)) for p in written
                          if Path(p).resolve().is_relative_to(root)})
        return {"state": "done", "outputs": outputs, "error": "", "seconds": time.perf_counter() - start}
    except FaceAnimError as exc:
        message = "".join(c if c.isprintable() else "?" for c in str(exc))
        return {"state": "failed", "outputs": [], "error": message, "seconds": time.perf_counter() - start}
    except Exception as exc:  # noqa: BLE001 -- a bug: one line for the summary, not a retried traceback
        return {"state": "failed", "outputs": [], "seconds": time.perf_counter() - start,
                "error": f"internal error ({type(exc).__name__}); please report it with the job file"}
    finally:
        common.BOUND_FACES = None
        common.REPORTED = None


def _cmd_batch(args) -> None:
    from faceanim.batch.jobs import read_job
    from faceanim.batch.runner import run
    from faceanim.io.files import check_output_path

    if args.workers is not None and args.scheduler:
        raise CommandError("--workers starts a local cluster; with --scheduler the cluster has its own workers")
    if args.scheduler is not None:
        import re

        if not re.fullmatch(r"(tcp|tls|ws|wss)://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9.-]+):\d{1,5}", args.scheduler):
            raise CommandError(f"'{shown(args.scheduler, 80)}' is not a scheduler address such as tcp://host:8786")
    job = read_job(args.job)
    out_dir = Path(args.output)
    if out_dir.exists() and not out_dir.is_dir():
        raise CommandError(f"the output '{shown(out_dir, 80, tail=True)}' is a file; give a folder for the outputs")
    if not out_dir.parent.is_dir():
        raise CommandError(f"the output folder's parent '{shown(out_dir.parent, 80, tail=True)}' does not exist; "
                           "create it first")
    from tqdm import tqdm

    planning = tqdm(desc="planning (each task's command checked, its inputs hashed)", unit="task",
                    disable=args.quiet or not sys.stderr.isatty(), leave=False)

    def planned(done: int, total: int) -> None:
        planning.total = total
        planning.update(done - planning.n)

    try:
        tasks = plan(job, out_dir.resolve(), planned)
    finally:
        planning.close()
    # writable, checked before any work; the folder and its manifest are made once the cluster is up
    check_output_path(out_dir / "faceanim-batch.sqlite" if out_dir.is_dir() else out_dir)

    bar = tqdm(total=len(tasks), desc="tasks", unit="task", disable=args.quiet or not sys.stderr.isatty(),
               leave=False)

    def started(summary) -> None:
        bar.total = len(tasks) - len(summary.skipped)
        bar.refresh()
        where = (args.scheduler or f"a local cluster of {summary.workers} worker processes" if summary.workers
                 else "this process (moving to a local cluster if the work proves long enough to pay its start-up)"
                 if args.workers is None else "this process")
        print(f"{len(tasks)} tasks ({len(summary.skipped)} done before) on {shown(where, 120)}"
              + (f"; dashboard {summary.dashboard}" if summary.dashboard else ""), flush=True)

    def moved(summary, left: int) -> None:
        print(f"{summary.here} tasks done here in {sum(summary.task_seconds):.1f} s; the {left} left go to a local "
              "cluster", flush=True)

    try:
        summary = run(tasks, out_dir, bind, work, scheduler=args.scheduler, workers=args.workers,
                      retries=args.retries, bind_faces=not args.no_bind,
                      progress=lambda n: bar.update(n - bar.n), on_start=started, on_cluster=moved)
    finally:
        bar.close()
    print(f"{len(summary.done)} done, {len(summary.skipped)} skipped (done before), {len(summary.failed)} failed "
          f"in {summary.seconds:.1f} s")
    order = {t.output: k for k, t in enumerate(tasks)}
    for output, error in sorted(summary.failed.items(), key=lambda kv: order[kv[0]]):  # in task order
        print(f"failed: {shown(output, 120)}: {error}", file=sys.stderr)
    if summary.failed:
        raise SystemExit(1)


def register(sub) -> None:
    from faceanim.cli.common import _arg_type

    p = sub.add_parser("batch", help=HELP["batch"],
                       description="Run one faceanim command over every combination of its inputs: in this "
                                   "process while the work is small, on a Dask LocalCluster on this machine once "
                                   "the work left pays its start-up (or at once with --workers N), or on the "
                                   "cluster at --scheduler. The job file "
                                   "(YAML or JSON) has operation, inputs (each input by its CLI name: a path, a "
                                   "glob, a list, or a pattern on an earlier input such as clips/{audio}.txt), "
                                   "options, and output (a file-name pattern under OUTDIR with {name} the stem of "
                                   "each input). A manifest in OUTDIR records every task: a rerun skips what is "
                                   "done and redoes what changed. Exit 1 if any task failed.")
    p.add_argument("job", metavar="JOBS.yaml", help="the job file (.yaml, .yml or .json)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="a running Dask scheduler, e.g. tcp://host:8786 "
                                                          "(default: start a local cluster)")
    p.add_argument("--workers", type=_arg_type("--workers", 1, MAX_WORKERS, integer=True),
                   help="worker processes of a local cluster started at once (1: every task in this process; "
                        "default: this process first, then one worker per core if the work is long)")
    p.add_argument("--retries", type=_arg_type("--retries", 0, MAX_RETRIES, integer=True), default=2,
                   help="times a task that crashes is tried again")
    p.add_argument("--no-bind", action="store_true", help="bind the face in every task instead of once per face "
                                                          "(to measure what binding once saves)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="the output folder (made if missing)")
    p.set_defaults(func=_cmd_batch)
