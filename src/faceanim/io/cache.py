"""A user cache of arrays faceanim computes from a face, keyed by content.

Work that depends only on a mesh and faceanim's own code (a face's ARKit shapes: 3 s on the
default face) is kept as an ``.npz`` under ``$FACEANIM_CACHE`` (default ``$XDG_CACHE_HOME/faceanim``
or ``~/.cache/faceanim``) and read back the next time the same input comes. The key is a SHA-256
of the input's bytes and of faceanim itself (every ``.py`` and data file of the installed package:
:func:`code_fingerprint`), so an edited or upgraded faceanim never reads another version's
results. Files are written atomically, read without pickles, at most :data:`KEEP` per kind are
kept (the least recently used go first); a cache that cannot be read or written is skipped (the
work is done as if there were none). ``FACEANIM_CACHE=off`` turns it off.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path

import numpy as np

from faceanim.io.files import npz_bytes

log = logging.getLogger(__name__)

KEEP = 8  # entries kept per kind
MAX_BYTES = 512 << 20  # an entry larger than this is not kept


def cache_dir() -> Path | None:
    """Where the cache lives, or None when it is off."""
    setting = os.environ.get("FACEANIM_CACHE", "")
    if setting.lower() in ("off", "0", "no", "false"):
        return None
    if setting:
        return Path(setting)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "faceanim"


@lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """SHA-256 over faceanim's own source and data files (paths and contents, in sorted order)."""
    root = Path(__file__).resolve().parents[1]
    files = []
    for folder, dirs, names in os.walk(root):
        dirs[:] = [d for d in dirs if d not in ("node_modules", "__pycache__")]  # the viewer's npm tree
        files += [Path(folder) / n for n in names if n.endswith((".py", ".json", ".npz"))]
    h = hashlib.sha256()
    for path in sorted(files):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def content_key(*parts) -> str:
    """A key from arrays, strings and numbers (arrays by dtype, shape and bytes)."""
    h = hashlib.sha256(code_fingerprint().encode())
    for part in parts:
        if isinstance(part, np.ndarray):
            a = np.ascontiguousarray(part)
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
        else:
            h.update(json.dumps(part, sort_keys=True, default=str).encode())
    return h.hexdigest()


def cached_arrays(kind: str, key: str, compute: Callable[[], tuple[dict[str, np.ndarray], dict]]
                  ) -> tuple[dict[str, np.ndarray], dict]:
    """``compute()``'s (named arrays, JSON-safe notes), from the cache when ``kind``/``key`` is there,
    else computed and kept. Arrays come back in the order they were computed in."""
    folder = cache_dir()
    path = None if folder is None else folder / kind / f"{key}.npz"
    if path is not None and path.is_file():
        try:
            with np.load(path, allow_pickle=False) as data:
                names = json.loads(str(data["__names__"]))
                notes = json.loads(str(data["__notes__"]))
                arrays = {n: _unpack(data, f"a{k}") for k, n in enumerate(names)}
            os.utime(path)  # recently used
            return arrays, notes
        except (OSError, ValueError, KeyError) as exc:
            log.debug("cache entry %s unreadable (%s): computed again", path, exc)
    arrays, notes = compute()
    if path is not None and sum(a.nbytes for a in arrays.values()) <= MAX_BYTES:
        _keep(path, arrays, notes)
    return arrays, notes


def _keep(path: Path, arrays: dict[str, np.ndarray], notes: dict) -> None:
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.npz")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        payload = {}
        for k, a in enumerate(arrays.values()):
            payload.update(_pack(np.asarray(a), f"a{k}"))
        blob = npz_bytes(False, __names__=json.dumps(list(arrays)), __notes__=json.dumps(notes), **payload)
        with open(tmp, "wb") as fh:
            fh.write(blob)
        os.replace(tmp, path)
        entries = sorted(path.parent.glob("*.npz"), key=lambda p: p.stat().st_mtime, reverse=True)
        for old in entries[KEEP:]:
            old.unlink(missing_ok=True)
    except OSError as exc:
        log.debug("cache entry %s not written (%s)", path, exc)
        tmp.unlink(missing_ok=True)


def _pack(a: np.ndarray, name: str) -> dict[str, np.ndarray]:
    """An array as stored: a 2-D one whose rows are mostly zero (a shape moving part of a face) as
    its shape, the nonzero rows' indices and those rows (exact); any other as it is."""
    if a.ndim == 2 and a.shape[0] > 64:
        rows = np.flatnonzero(np.any(a != 0, axis=1))
        if len(rows) < 0.5 * a.shape[0]:
            return {f"{name}_shape": np.array(a.shape), f"{name}_rows": rows, f"{name}_values": a[rows]}
    return {name: a}


def _unpack(data, name: str) -> np.ndarray:
    if f"{name}_shape" in data.files:
        values = data[f"{name}_values"]
        out = np.zeros(tuple(data[f"{name}_shape"]), dtype=values.dtype)
        out[data[f"{name}_rows"]] = values
        return out
    return data[name]
