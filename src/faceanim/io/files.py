"""Small file helpers shared by every writer: atomic output and JSON reading."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from faceanim.errors import InputFileError


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it to ``path`` only if the block succeeds.

    A failing writer therefore never leaves a partial output file behind.
    """
    path = Path(path)
    if path.parent and not path.parent.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}-", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        # mkstemp creates the file private (0600); give the output the usual umask permissions
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp_path, 0o666 & ~umask)
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def read_json(path: str | os.PathLike, what: str = "JSON file") -> object:
    """Read a JSON file, turning every failure into an :class:`InputFileError` naming the file."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{what} '{path}' does not exist; check the path")
    try:
        with open(path, encoding="utf-8") as fh:
            return json.load(fh)
    except json.JSONDecodeError as exc:
        raise InputFileError(
            f"{what} '{path}' is not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})"
        ) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(f"cannot read {what} '{path}': {exc}") from None


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
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(f"cannot read {what} '{path}': {exc}") from None
