"""The batch manifest: one SQLite file in the output folder (``faceanim-batch.sqlite``) with a row
per task: its output, a signature (the operation, its arguments and the SHA-256 of every input
file's content), the files it wrote, its state (``done`` / ``failed``), the one-line error of a
failed task and the seconds it took. A rerun skips a task whose signature is unchanged and whose
files are all still there, and redoes the rest (changed inputs or options, deleted outputs,
failures). Only the process that runs the batch writes it (workers return their results)."""

from __future__ import annotations

import hashlib
import json
import sqlite3
import time
from pathlib import Path

from faceanim.errors import FaceAnimError, shown

NAME = "faceanim-batch.sqlite"
CHUNK = 1 << 20


def file_hash(path, cache: dict | None = None) -> str:
    """SHA-256 of a file's bytes (``cache``: path -> (size, mtime_ns, hash), reused while both hold)."""
    p = Path(path)
    st = p.stat()
    key = str(p.resolve())
    if cache is not None and key in cache and cache[key][:2] == (st.st_size, st.st_mtime_ns):
        return cache[key][2]
    h = hashlib.sha256()
    with open(p, "rb") as fh:
        while chunk := fh.read(CHUNK):
            h.update(chunk)
    digest = h.hexdigest()
    if cache is not None:
        cache[key] = (st.st_size, st.st_mtime_ns, digest)
    return digest


def signature(operation: str, argv: list[str], input_hashes: dict[str, str]) -> str:
    """What a task's result depends on, as one hash: the operation, its argv (input paths and
    options as given) and the content hash of every input file."""
    doc = json.dumps({"operation": operation, "argv": argv, "inputs": input_hashes}, sort_keys=True)
    return hashlib.sha256(doc.encode()).hexdigest()


class Manifest:
    """The manifest of an output folder (created on first use)."""

    def __init__(self, folder):
        self.path = Path(folder) / NAME
        try:
            self.db = sqlite3.connect(self.path)
            self.db.execute("CREATE TABLE IF NOT EXISTS tasks (output TEXT PRIMARY KEY, signature TEXT, "
                            "outputs TEXT, state TEXT, error TEXT, seconds REAL, finished REAL)")
            self.db.commit()
        except sqlite3.DatabaseError as exc:
            self._unwritable(exc)
            raise FaceAnimError(f"'{shown(self.path, 80, tail=True)}' is not a faceanim batch manifest (damaged or "
                                "another file); move it away or choose another output folder") from None

    def _unwritable(self, exc: Exception) -> None:
        """A full disk or a failing one, said as such (SQLite's OperationalError)."""
        text = str(exc).lower()
        where = shown(self.path.parent, 80, tail=True)
        if "full" in text:
            raise FaceAnimError(f"the disk holding '{where}' is full; free some space and run the batch again "
                                "(the tasks done are kept)") from None
        if isinstance(exc, sqlite3.OperationalError) and ("i/o" in text or "readonly" in text or "locked" in text):
            raise FaceAnimError(f"the batch manifest in '{where}' cannot be written ({text[:60]}); check the "
                                "folder and run the batch again (the tasks done are kept)") from None

    @classmethod
    def existing(cls, folder) -> Manifest | None:
        """The folder's manifest if there is one (nothing is created)."""
        return cls(folder) if (Path(folder) / NAME).is_file() else None

    def close(self) -> None:
        self.db.close()

    def is_done(self, output: str, sig: str, folder) -> bool:
        row = self.db.execute("SELECT signature, outputs, state FROM tasks WHERE output = ?", (output,)).fetchone()
        if row is None or row[0] != sig or row[2] != "done":
            return False
        try:
            files = json.loads(row[1])
        except ValueError:
            return False
        return bool(files) and all((Path(folder) / f).is_file() for f in files)

    def record(self, output: str, sig: str, state: str, outputs=(), error: str = "", seconds: float = 0.0) -> None:
        try:
            self.db.execute("INSERT OR REPLACE INTO tasks VALUES (?, ?, ?, ?, ?, ?, ?)",
                            (output, sig, json.dumps(list(outputs)), state, error, float(seconds), time.time()))
            self.db.commit()
        except sqlite3.DatabaseError as exc:
            self._unwritable(exc)
            raise FaceAnimError(f"the batch manifest in '{shown(self.path.parent, 80, tail=True)}' cannot be "
                                "written (damaged while the batch ran?); move it away and run the batch again") \
                from None

