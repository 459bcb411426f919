"""Small file helpers shared by every writer: checked, atomic output and JSON/text reading.

Every file faceanim writes goes through :func:`atomic_output`:

- :func:`check_output_path` runs first (and the CLI runs it for every output path before any
  work starts): the folder must exist (it is never created: a typo in ``-o out/x.glb`` would
  otherwise make a tree of folders), be a folder and be writable; the path must not be a folder
  or a special file, and an existing file must be replaceable.
- The data goes to a hidden temporary file beside the output, ``.{stem}.faceanim-{pid}-<random>{suffix}``,
  which is renamed onto the output only when the writer succeeded. On every failure (an
  exception, Ctrl-C, SIGTERM or SIGHUP) the temporary file is removed, so a failed or killed write
  leaves neither a partial output nor a hidden file. An OSError while writing or renaming becomes
  an :class:`OutputError` (one line: the path and the system's reason).
- While a write is under way, SIGTERM and SIGHUP remove the live temporary files and exit with
  status 128 + signal number (handlers are installed from the main thread only, and the previous
  handlers are restored when the last write ends).
- At the start of a write, temporary files of this pattern beside the output whose process is no
  longer alive (a power cut, ``kill -9``) are removed. Only files of faceanim's own pattern, and only
  those of dead processes, are touched.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import stat
import sys
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

from faceanim.errors import FaceAnimError, InputFileError


class OutputError(FaceAnimError):
    """An output path that cannot be written (missing folder, read-only, a folder, disk full)."""


# the hidden temporary file beside an output: .{stem}.faceanim-{pid}-{random}{suffix}
_TEMP_MARK = ".faceanim-"
_TEMP_RE = re.compile(r"^\..*\.faceanim-(\d{1,7})-[A-Za-z0-9_]{4,16}(\.[^.]*)?$")
_MAX_TEMP_STEM = 80  # characters of the output's stem kept in the temporary name
_MAX_PID = 1 << 22  # Linux's pid_max ceiling


def _reason(exc: OSError) -> str:
    """The system's one-line reason (strerror); never the text of a tool's error (ffmpeg output)."""
    return exc.strerror or "the write failed"


def check_output_path(path: str | os.PathLike, what: str = "output") -> Path:
    """Raise :class:`OutputError` unless ``path`` can be written as an output file; returns it.

    Refused: an empty path; a missing folder (it is not created: make it first); a parent that is
    not a folder or is not writable (checked by creating and removing a probe file, which also
    catches read-only file systems); a path that is an existing folder or a special file (device,
    pipe, socket); an existing file that is read-only (the user protected it) or cannot be
    replaced. Nothing is left behind.
    """
    if path is None or str(path) == "":
        raise OutputError(f"no {what} path given; name the file to write")
    from faceanim.errors import shown

    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    sp, sparent = shown(p, 120, tail=True), shown(parent, 120, tail=True)  # printable, one line
    if p.name in ("", ".", ".."):
        raise OutputError(f"{what} '{sp}' is a folder; give a file name inside it")
    try:
        st = os.stat(parent)
    except FileNotFoundError:
        raise OutputError(f"cannot write {what} '{sp}': folder '{sparent}' does not exist; create it first "
                          f"(mkdir -p '{sparent}')") from None
    except NotADirectoryError:
        raise OutputError(f"cannot write {what} '{sp}': '{sparent}' is not a folder; choose another path") from None
    except OSError as exc:
        raise OutputError(f"cannot write {what} '{sp}': folder '{sparent}': {_reason(exc)}") from None
    if not stat.S_ISDIR(st.st_mode):
        raise OutputError(f"cannot write {what} '{sp}': '{sparent}' is not a folder; choose another path")
    try:
        lst = os.lstat(p)
    except FileNotFoundError:
        lst = None
    except OSError as exc:
        raise OutputError(f"cannot write {what} '{sp}': {_reason(exc)}; choose another path") from None
    if lst is not None:
        try:
            target = os.stat(p)
        except OSError:
            target = lst  # a dangling symlink: replacing it writes a new file
        if stat.S_ISDIR(target.st_mode):
            raise OutputError(f"{what} '{sp}' is a folder; give a file name (e.g. '{shown(p / ('out' + p.suffix), 120, tail=True)}')")
        if not stat.S_ISREG(target.st_mode):
            raise OutputError(f"{what} '{sp}' exists and is not a regular file (a device, pipe or socket); "
                              "choose another path")
        # no write bit at all is the user's protection even for root, whom os.access lets through
        if not os.access(p, os.W_OK) or not p.stat().st_mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH):
            raise OutputError(f"{what} '{sp}' exists and is read-only; remove it or choose another path")
        euid = os.geteuid() if hasattr(os, "geteuid") else None
        if (euid not in (None, 0) and st.st_mode & stat.S_ISVTX and lst.st_uid != euid
                and st.st_uid != euid):
            raise OutputError(f"{what} '{sp}' belongs to another user in a shared folder and cannot be "
                              "replaced; choose another path")
    if len(p.name.encode("utf-8", "surrogateescape")) > 255:
        raise OutputError(f"cannot write {what} '{sp}': the file name is longer than 255 bytes; use a shorter name")
    # the only sure test of a writable folder (read-only mounts, ACLs, root on /sys): try it, with
    # Ctrl-C, SIGTERM and SIGHUP held until the probe is gone (a stop in between would leave it)
    with signals_held():
        try:
            fd, probe = tempfile.mkstemp(prefix=f".probe{_TEMP_MARK}{os.getpid()}-", suffix=".tmp", dir=parent)
        except OSError as exc:
            raise OutputError(f"cannot write {what} '{sp}': folder '{sparent}' is not writable ({_reason(exc)}); "
                              "choose another folder") from None
        os.close(fd)
        with contextlib.suppress(OSError):
            os.unlink(probe)
    return p


_HELD = tuple(s for s in (getattr(signal, "SIGINT", None), getattr(signal, "SIGTERM", None),
                          getattr(signal, "SIGHUP", None)) if s is not None)


@contextlib.contextmanager
def signals_held():
    """Hold SIGINT, SIGTERM and SIGHUP in this thread for the block (a few system calls that must
    not be cut between them); one that came in is handled as the block ends."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, _HELD)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


# ---------------------------------------------------------------------- live temporary files
_live: set[str] = set()
_lock = threading.Lock()
_previous: dict[int, object] = {}  # signal -> handler before ours, while ours is installed
_SIGNALS = tuple(s for s in (getattr(signal, "SIGTERM", None), getattr(signal, "SIGHUP", None)) if s is not None)


def _on_signal(signum, frame) -> None:
    """SIGTERM/SIGHUP during a write: hand over to the handler that was there before ours (the
    ``faceanim`` command's raises, so the write unwinds), else exit 128 + signum by SystemExit; either
    way :func:`atomic_output` removes its temporary file as the exception passes (after a writer
    that runs a process, such as ffmpeg, has stopped it: removing the file first would leave the
    process writing into a vanished file)."""
    previous = _previous.get(signum)
    if callable(previous):
        previous(signum, frame)
        return
    raise SystemExit(128 + signum)


def _install_handlers() -> None:
    if threading.current_thread() is not threading.main_thread() or _previous:
        return
    for sig in _SIGNALS:
        try:
            current = signal.getsignal(sig)
            if current in (signal.SIG_IGN, None):
                continue  # ignored on purpose (nohup) or set from C: leave it alone
            signal.signal(sig, _on_signal)
            _previous[sig] = current
        except (ValueError, OSError):
            pass


def _restore_handlers() -> None:
    if threading.current_thread() is not threading.main_thread():
        return
    for sig, handler in list(_previous.items()):
        with contextlib.suppress(ValueError, OSError, TypeError):
            if signal.getsignal(sig) is _on_signal:
                signal.signal(sig, handler)
        del _previous[sig]


def _register(tmp: str) -> None:
    with _lock:
        _live.add(tmp)
    if len(_live) == 1 or not _previous:
        _install_handlers()


def _unregister(tmp: str) -> None:
    with _lock:
        _live.discard(tmp)
        empty = not _live
    if empty:
        _restore_handlers()


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError, OverflowError):
        return True  # exists (another user's) or cannot tell: keep its file
    return True


def remove_stale_temps(folder: str | os.PathLike) -> list[Path]:
    """Remove faceanim's temporary files in ``folder`` whose writing process is gone; returns them.

    Only names of faceanim's own pattern (``.{stem}.faceanim-{pid}-<random>{suffix}``) are considered,
    and only those whose pid is not a live process. (Processes in another pid namespace sharing the
    folder look dead from here; their write then fails cleanly at the rename.)
    """
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        if _TEMP_MARK not in entry.name:
            continue
        m = _TEMP_RE.match(entry.name)
        if not m:
            continue
        pid = int(m.group(1))
        if not 0 < pid <= _MAX_PID or _pid_alive(pid):
            continue
        try:
            if entry.is_dir(follow_symlinks=False):  # a staging folder (atomic_folder)
                import shutil

                shutil.rmtree(entry.path)
            elif entry.is_file(follow_symlinks=False):
                os.unlink(entry.path)
            else:
                continue
            removed.append(Path(entry.path))
        except OSError:
            pass
    return removed


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike, what: str = "output") -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` only if the block succeeds.

    The path is checked first (:func:`check_output_path`). A failing writer never leaves a partial
    output or its temporary file behind (exceptions, KeyboardInterrupt, SIGTERM, SIGHUP); an
    OSError raised by the writer or the rename becomes an :class:`OutputError`.
    """
    path = check_output_path(path, what)
    parent = path.parent if str(path.parent) else Path(".")
    remove_stale_temps(parent)
    stem = path.stem[:_MAX_TEMP_STEM]
    suffix = path.suffix if len(path.suffix) <= 16 else ""
    tmp = None
    try:
        with signals_held():  # the temporary file is made and registered with no stop between
            try:
                fd, tmp = tempfile.mkstemp(prefix=f".{stem}{_TEMP_MARK}{os.getpid()}-", suffix=suffix, dir=parent)
            except OSError as exc:
                raise OutputError(f"cannot write {what} '{path}': {_reason(exc)}; choose another path") from None
            os.close(fd)
            _register(tmp)
        tmp_path = Path(tmp)
        try:
            yield tmp_path
        except OSError as exc:
            raise OutputError(f"cannot write {what} '{path}': {_reason(exc)}") from None
        if not os.path.exists(tmp):
            raise OutputError(f"cannot write {what} '{path}': its temporary file vanished while writing")
        from faceanim.errors import STOPS, Interrupted

        if STOPS:  # a stop came while writing and was swallowed on its way up: the output stays as it was
            raise Interrupted(STOPS[0])
        try:
            # mkstemp creates the file private (0600); give the output the usual umask permissions
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp_path, 0o666 & ~umask)
            os.replace(tmp_path, path)
        except OSError as exc:
            raise OutputError(f"cannot write {what} '{path}': {_reason(exc)}") from None
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            _unregister(tmp)


@contextlib.contextmanager
def atomic_folder(folder: str | os.PathLike, what: str = "output folder") -> Iterator[Path]:
    """Yield a hidden staging folder beside ``folder``; only if the block succeeds are its files
    moved into ``folder`` (made if missing), all with no stop between them. A failing or stopped
    block leaves ``folder`` as it was (files it held are kept, a folder it did not have is not
    made) and no staging folder behind (nor does a killed one outlive the next run here)."""
    import shutil

    from faceanim.errors import STOPS, Interrupted

    folder = Path(folder)
    parent = folder.parent if str(folder.parent) else Path(".")
    remove_stale_temps(parent)
    stage = None
    try:
        with signals_held():
            try:
                stage = tempfile.mkdtemp(prefix=f".{folder.name[:_MAX_TEMP_STEM]}{_TEMP_MARK}{os.getpid()}-",
                                         dir=parent)
            except OSError as exc:
                raise OutputError(f"cannot write {what} '{folder}': {_reason(exc)}; choose another folder") from None
            _register(stage)
        yield Path(stage)
        if STOPS:
            raise Interrupted(STOPS[0])
        names = sorted(os.listdir(stage))
        for name in names:  # checked before any is moved: a refusal half-way would leave a mix
            if (folder / name).is_dir() and not (folder / name).is_symlink():
                raise OutputError(f"'{folder / name}' is a folder, where faceanim writes the file {name}; move it away")
        with signals_held():
            try:
                folder.mkdir(exist_ok=True)
                for name in names:
                    os.replace(os.path.join(stage, name), folder / name)
            except OSError as exc:
                raise OutputError(f"cannot write {what} '{folder}': {_reason(exc)}") from None
    finally:
        if stage is not None:
            shutil.rmtree(stage, ignore_errors=True)
            _unregister(stage)


def npz_bytes(compressed: bool = True, **arrays) -> bytes:
    """An ``.npz`` archive of ``arrays`` made in memory. Writing it to the file afterwards keeps a
    failed write (a full disk) one clean error: numpy's zip writer on a file that fails leaves a
    ZipFile whose clean-up reports 'Exception ignored ... seek of closed file' on the terminal."""
    import io

    import numpy as np

    buf = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(buf, **arrays)
    return buf.getvalue()


def check_input_file(path: str | os.PathLike, what: str, give: str) -> Path:
    """The path of an input file that can be read: refused (one :class:`InputFileError` line, the
    path shown by its printable end) when empty, missing, a folder or not a regular file (a device,
    a pipe). ``what`` names the input ("front photo"), ``give`` what to give instead ("a video
    file")."""
    from faceanim.errors import shown

    p = Path(path)
    name = shown(p, 80, tail=True)
    if str(path) == "":
        raise InputFileError(f"{what}: the path is empty; give {give}")
    if not p.exists():
        raise InputFileError(f"{what} '{name}' does not exist; check the path")
    if p.is_dir():
        raise InputFileError(f"{what} '{name}' is a folder; give {give}")
    if not p.is_file():
        raise InputFileError(f"{what} '{name}' is not a regular file; give {give}")
    return p


def read_json(path: str | os.PathLike, what: str = "JSON file") -> object:
    """Read a JSON file, turning every failure into an :class:`InputFileError` naming the file."""
    path = Path(path)
    if not path.is_file():
        if path.is_dir():
            raise InputFileError(f"{what} '{path}' is a folder; give a JSON file")
        raise InputFileError(f"{what} '{path}' does not exist; check the path")
    try:
        with open(path, encoding="utf-8") as fh:
            return json.load(fh)
    except json.JSONDecodeError as exc:
        raise InputFileError(
            f"{what} '{path}' is not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})"
        ) from None
    except UnicodeDecodeError:
        raise InputFileError(f"{what} '{path}' is not UTF-8 text; save it as UTF-8 JSON") from None
    except RecursionError:
        raise InputFileError(f"{what} '{path}' is nested too deeply to be a faceanim JSON file") from None
    except ValueError:
        # e.g. an integer of thousands of digits
        raise InputFileError(f"{what} '{path}' holds a number too long to read; check the file") from None
    except OSError as exc:
        raise InputFileError(f"cannot read {what} '{path}': {_reason(exc)}") from None


def write_json(path: str | os.PathLike, data: object) -> None:
    """Write ``data`` as indented JSON atomically."""
    with atomic_output(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        json.dump(data, fh, indent=1)
        fh.write("\n")


def read_text(path: str | os.PathLike, what: str = "text file") -> str:
    """Read a UTF-8 text file, turning every failure into an :class:`InputFileError` naming the file."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{what} '{path}' does not exist; check the path")
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputFileError(f"{what} '{path}' is not UTF-8 text; save it as UTF-8") from None
    except OSError as exc:
        raise InputFileError(f"cannot read {what} '{path}': {_reason(exc)}") from None


@contextlib.contextmanager
def native_stderr_quiet():
    """Native libraries (MediaPipe's C++, libsndfile's mpg123) log to file descriptor 2 whatever
    Python says; send that to /dev/null while they run, unless FACEANIM_VERBOSE is set
    (``faceanim --verbose``), so an error stays one line."""
    if os.environ.get("FACEANIM_VERBOSE"):
        yield
        return
    sys.stderr.flush()
    saved = os.dup(2)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        os.close(devnull)
