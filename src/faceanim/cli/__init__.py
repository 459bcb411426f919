"""The ``faceanim`` command: parses arguments, calls the library, reports.

One small module per command group (:mod:`.mesh`, :mod:`.facs`, :mod:`.wires`, :mod:`.mpeg4`, ...)
registers its parsers; :mod:`.common` holds what they share. :data:`.commands.COMMANDS` names each
command's module and help line: a command's module is imported only when that command runs (or
its help is asked for), so ``faceanim --help`` loads none. Every user error becomes one line on
stderr and exit code 2; outputs are checked before any work and written atomically, so no partial
file is left.
"""

from __future__ import annotations

import argparse
import re
import sys

from faceanim.cli.commands import COMMANDS
from faceanim.errors import FaceAnimError


class _Help(argparse.HelpFormatter):
    """Help that states each option's default where it has a meaningful one."""

    def _get_help_string(self, action):
        text = action.help or ""
        if action.default not in (None, False, argparse.SUPPRESS) and "%(default)" not in text \
                and action.option_strings:
            text += " (default: %(default)s)"
        return text


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors that name the command's --help."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _version() -> str:
    from faceanim.version import __version__

    return __version__


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The whole parser (``command`` None: every command's module imported), or the parser with
    ``command``'s module registered and the other commands listed by name and help only (``""``:
    none registered, for ``faceanim --help``)."""
    import importlib

    fmt = _Help
    p = _Parser(prog="faceanim", formatter_class=fmt,
                description="3D facial animation from the papers: make a head from photos, rig any face mesh, animate "
                            "it with FACS action units, MPEG-4 FAPs, wires, speech, scene scripts and tracked video, "
                            "export glTF/OBJ/.fap/PNG/MP4.")
    p.add_argument("--version", action="version", version=f"faceanim {_version()}")
    p.add_argument("--verbose", action="store_true", help="show MediaPipe's log and Python tracebacks")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)

    wanted = list(dict.fromkeys(m for m, _ in COMMANDS.values())) if command is None else \
        ([COMMANDS[command][0]] if command in COMMANDS else [])
    for name, (module, text) in COMMANDS.items():  # in the table's order
        if module in wanted:
            importlib.import_module(f"faceanim.cli.{module}").register(sub)
            wanted.remove(module)
        elif name not in sub.choices:
            sub.add_parser(name, help=text)  # listed only: its module is not loaded
    sub.metavar = "{" + ",".join(sub.choices) + "}"  # the commands, each once (not their aliases)
    for action in sub.choices.values():
        _defaults_everywhere(action, fmt)
    return p


def _defaults_everywhere(parser: argparse.ArgumentParser, fmt) -> None:
    parser.formatter_class = fmt
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for child in a.choices.values():
                _defaults_everywhere(child, fmt)


_AXIS = re.compile(r"^[+-]?[xyzXYZ]$")


def _join_axis_values(argv: list[str]) -> list[str]:
    """``--forward -z`` as ``--forward=-z``: argparse takes a lone ``-z`` for an option."""
    out, k = [], 0
    while k < len(argv):
        if argv[k] in ("--forward", "--up") and k + 1 < len(argv) and _AXIS.match(argv[k + 1]):
            out.append(f"{argv[k]}={argv[k + 1]}")
            k += 2
        else:
            out.append(argv[k])
            k += 1
    return out


def _raise_interrupted(signum, frame) -> None:
    from faceanim.errors import STOPS, Interrupted

    STOPS.append(signum)
    raise Interrupted(signum)


def _stop_signals() -> dict:
    """SIGINT, SIGTERM and SIGHUP are recorded and raise :class:`~faceanim.errors.Interrupted` (in the
    main thread, unless ignored on purpose, as nohup and a shell's background jobs do); returns the
    handlers to put back."""
    import signal
    import threading

    previous = {}
    if threading.current_thread() is not threading.main_thread():
        return previous
    for sig in (signal.SIGINT, getattr(signal, "SIGTERM", None), getattr(signal, "SIGHUP", None)):
        if sig is None:
            continue
        current = signal.getsignal(sig)
        if current in (signal.SIG_DFL, signal.default_int_handler):
            previous[sig] = signal.signal(sig, _raise_interrupted)
    return previous


def main(argv: list[str] | None = None, final: bool = False) -> int:
    """Run one command; its exit code. ``final``: the process ends with it (the ``faceanim``
    program): a stop that comes once the command is over is ignored, not a silent death by signal
    on the way out (its output is whole by then)."""
    import signal

    from faceanim.errors import STOPS, Interrupted

    STOPS.clear()
    previous = _stop_signals()
    unraisable = sys.unraisablehook
    sys.unraisablehook = _quiet_stops(unraisable)
    try:
        try:
            return _main(argv, final)
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, signal.SIG_IGN if final else handler)
            STOPS.clear()  # this command's stops are said; a caller in the same process goes on
            if not final:
                sys.unraisablehook = unraisable
    except Interrupted as exc:  # it came as the command returned, before its handlers were put back
        return _interrupted(exc.signum)


def _quiet_stops(previous):
    """An unraisable-exception hook that says nothing of a stop: the stop handler raises where the
    program is, also inside a finaliser (tqdm's ``__del__``), where Python can only print it with a
    traceback; the stop is recorded (``errors.STOPS``) and said once, in one line, by the command."""
    from faceanim.errors import Interrupted

    def hook(unraisable) -> None:
        if isinstance(unraisable.exc_value, Interrupted):
            return
        previous(unraisable)

    return hook


def run() -> None:
    """The ``faceanim`` program: :func:`main` on the command line, then exit with its code."""
    sys.exit(main(final=True))


def _main(argv: list[str] | None = None, final: bool = False) -> int:
    from faceanim.errors import STOPS

    argv = _join_axis_values(list(sys.argv[1:] if argv is None else argv))
    command = next((a for a in argv if not a.startswith("-")), "")
    args = build_parser(command).parse_args(argv)
    from faceanim.cli.common import outputs_are_not_inputs, quiet_native_logs

    quiet_native_logs(args.verbose, whole_process=final)
    name = " ".join(x for x in (args.command, getattr(args, "wires_command", None),
                                getattr(args, "fap_command", None), getattr(args, "mocap_command", None),
                                getattr(args, "arkit_command", None)) if x)
    try:
        _no_empty_values(argv)
        outputs_are_not_inputs(args)
        args.func(args)
    except FaceAnimError as exc:
        if STOPS:  # the stop made a step fail (ffmpeg killed mid-file): it is the stop that is said
            return _interrupted(STOPS[0])
        # printable characters only: a file name's escape codes must not reach the terminal
        message = "".join(c if c.isprintable() else "?" for c in str(exc))
        print(f"faceanim {name}: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:  # Ctrl-C (SIGINT), SIGTERM, SIGHUP: exit 128 + the signal's number
        import signal

        return _interrupted(getattr(exc, "signum", signal.SIGINT))
    except MemoryError:
        print(f"faceanim {name}: error: out of memory; try a smaller input, --size or --frames", file=sys.stderr)
        return 2
    except Exception as exc:  # a bug, not bad input: one line, the traceback with --verbose
        if STOPS:  # a stop that a library turned into another error on its way up (an interrupted import)
            return _interrupted(STOPS[0])
        if args.verbose:
            raise
        print(f"faceanim {name}: internal error ({type(exc).__name__}); please report it with the command "
              "line (run with --verbose for the traceback)", file=sys.stderr)
        return 1
    if STOPS:  # a stop swallowed on its way up (printed by a finaliser): the command did not finish
        return _interrupted(STOPS[0])
    return 0


def _no_empty_values(argv: list[str]) -> None:
    """An option given an empty value (``--face ''``, ``--out ' '``, ``--out=``) is refused: taken as
    given it meant the default face or the current folder, never what the user typed. (An empty
    positional argument, a path or a text, is refused by its command, which names what it is.)"""
    from faceanim.cli.common import CommandError

    for k, token in enumerate(argv):
        if token.startswith("--") and token.endswith("=") and len(token) > 3:
            raise CommandError(f"{token[:-1]} is empty; give it a value or leave it out")
        if not token.strip() and k and argv[k - 1].startswith("-") and len(argv[k - 1]) > 1:
            raise CommandError(f"{argv[k - 1]} is empty; give it a value or leave it out")


def _interrupted(signum: int) -> int:
    import signal

    print(f"faceanim: interrupted ({signal.Signals(signum).name})", file=sys.stderr)
    return 128 + int(signum)


if __name__ == "__main__":
    sys.exit(main())
