"""Shared helpers of the benchmark scripts: timing, memory, BLAS threads and tables.

- :func:`best`: best-of-N wall time after a warm-up (the steady state of an animation loop);
  :func:`once`: one timed call (cold measurements: a bind, a first frame);
- :func:`traced`: a call under ``tracemalloc``: bytes it leaves allocated and its peak. numpy
  (1.22+) reports its array buffers to tracemalloc, so arrays, scipy.sparse matrices and Python
  objects are counted; memory that C libraries allocate themselves (SuperLU's L and U factors,
  OpenBLAS work buffers) is not;
- :func:`blas_threads` and :func:`blas_line`: the BLAS thread count, set with threadpoolctl and
  printed in every script's header, so a table says what it was measured with;
- :class:`Row` and :func:`speed_table`: timings grouped by case with the ratio to the fastest
  baseline of the same case and group (measured in the same run); :func:`table` prints any
  other table.

Timings on a shared machine are noisy: compare the ratio columns (baseline and method measured
moments apart in one process), not absolute times between runs.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import ctypes.util
import gc
import os
import platform
import sys
import time
import tracemalloc
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

import numpy as np
import scipy
import scipy.linalg  # (loads scipy's own OpenBLAS, so the thread limit reaches it too)
import scipy.sparse.linalg
from threadpoolctl import threadpool_info, threadpool_limits


# ---------------------------------------------------------------------------------- timing
def best(fn, repeat: int = 5, number: int = 1, warmup: int = 1, warmup_seconds: float = 0.0) -> float:
    """Best mean time (seconds) of ``number`` calls over ``repeat`` runs.

    ``fn`` is first called ``warmup`` times and for at least ``warmup_seconds``: right after a
    large solve OpenBLAS's threads can slow small products for a while, and first calls build
    caches and fault fresh memory in, none of which is the steady state.
    """
    end = time.perf_counter() + warmup_seconds
    calls = 0
    while calls < warmup or time.perf_counter() < end:
        fn()
        calls += 1
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        for _ in range(number):
            fn()
        times.append((time.perf_counter() - t) / number)
    return min(times)


def interleaved(fns: dict, repeat: int = 5, warmup: int = 1, warmup_seconds: float = 0.0) -> dict:
    """Best time (seconds) of each of ``fns`` (name -> callable), calling them in turn: round
    ``k`` times every function once, so a change in the machine's load (other people's tests)
    hits the baseline and the method alike. Each is first called ``warmup`` times and the set
    for at least ``warmup_seconds``; a function's result is dropped before the next call."""
    end = time.perf_counter() + warmup_seconds
    calls = 0
    while calls < warmup or time.perf_counter() < end:
        for fn in fns.values():
            fn()
        calls += 1
    times = {name: np.inf for name in fns}
    for _ in range(repeat):
        for name, fn in fns.items():
            t = time.perf_counter()
            fn()
            times[name] = min(times[name], time.perf_counter() - t)
    return times


def once(fn):
    """One timed call: (seconds, result)."""
    t = time.perf_counter()
    out = fn()
    return time.perf_counter() - t, out


def best_fresh(fn, repeat: int = 3):
    """Best of ``repeat`` calls with no warm-up, each doing all its work again (a cold bind
    repeated from scratch): (seconds, result of the last call)."""
    times, out = [], None
    for _ in range(repeat):
        out = None
        gc.collect()
        t, out = once(fn)
        times.append(t)
    return min(times), out


class Stopwatch:
    """Elapsed wall time of a script's parts: ``lap(name)`` records the time since the last lap."""

    def __init__(self):
        self.start = self.last = time.perf_counter()
        self.laps: list[tuple[str, float]] = []

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.laps.append((name, now - self.last))
        self.last = now

    def line(self) -> str:
        total = time.perf_counter() - self.start
        return f"run time {total:.0f} s (" + ", ".join(f"{n} {t:.0f} s" for n, t in self.laps) + ")"


# ---------------------------------------------------------------------------------- memory
def traced(fn):
    """Call ``fn`` under tracemalloc: (result, retained bytes, peak bytes).

    Retained: what is still allocated when ``fn`` returns (the result kept alive), relative to
    before the call; peak: the highest allocation during the call, relative to before.
    """
    gc.collect()
    started = not tracemalloc.is_tracing()
    if started:
        tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        out = fn()
        current, peak = tracemalloc.get_traced_memory()
    finally:
        if started:
            tracemalloc.stop()
    return out, current - before, peak - before


def keep_freed_memory() -> bool:
    """Ask glibc to keep freed memory in the process (no mmap for large blocks, never trim), so
    a batch output reuses pages an earlier one touched instead of faulting in fresh ones.

    On this kind of virtual machine fresh pages were seen to cost up to 10 s per GiB (the host
    backs them page by page, and memory handed back is reclaimed), against ~0.07 s per GiB for
    reused ones: without this, a 2.6 GiB batch measured the machine's memory, not the method.
    Every method measured gets the same treatment. Returns False where mallopt is unavailable."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        m_trim_threshold, m_mmap_max = -1, -4
        return bool(libc.mallopt(m_mmap_max, 0)) and bool(libc.mallopt(m_trim_threshold, -1))
    except (OSError, AttributeError):
        return False


def prefault(nbytes: int) -> float:
    """Write ``nbytes`` of fresh memory once and free it; returns the seconds it took.

    With :func:`keep_freed_memory` the pages stay with the process, so the first measurement
    that needs a large batch output does not pay for the machine's first touch (seconds per GiB
    here), which says nothing about the method measured."""
    t = time.perf_counter()
    a = np.empty(nbytes // 8)
    a.fill(1.0)
    del a
    return time.perf_counter() - t


def size_of(*arrays) -> int:
    """Bytes held by numpy arrays and scipy sparse matrices."""
    n = 0
    for a in arrays:
        if a is None:
            continue
        if scipy.sparse.issparse(a):
            a = a.tocsr() if a.format not in ("csr", "csc") else a
            n += a.data.nbytes + a.indices.nbytes + a.indptr.nbytes
        else:
            n += np.asarray(a).nbytes
    return n


# ---------------------------------------------------------------------------------- BLAS threads
def blas_threads(n: int | None):
    """Context limiting every loaded BLAS (numpy's and scipy's OpenBLAS) to ``n`` threads;
    ``None`` leaves them as they are (one per core by default)."""
    return contextlib.nullcontext() if n is None else threadpool_limits(limits=n, user_api="blas")


def blas_line() -> str:
    """The BLAS libraries in use: kernel, version and current thread count."""
    libs = [f"{i['internal_api']} {i.get('version')} ({i.get('architecture')} kernel, "
            f"{i['num_threads']} thread{'s' if i['num_threads'] != 1 else ''}) for "
            f"{'scipy' if 'scipy' in Path(i['filepath']).name else 'numpy'}"
            for i in threadpool_info() if i["user_api"] == "blas"]
    env = {k: os.environ[k] for k in ("OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE", "OPENBLAS_NUM_THREADS",
                                     "OMP_NUM_THREADS") if k in os.environ}
    return "; ".join(libs) + (f"; env {env}" if env else "; no OPENBLAS_*/OMP_* set")


def arguments(doc: str, data: str | None = None, extra=()) -> argparse.Namespace:
    """The options every benchmark takes: ``--blas-threads`` and an optional data folder; ``extra``:
    (flag, add_argument keywords) of a script's own."""
    p = argparse.ArgumentParser(description=doc.strip().splitlines()[0])
    if data:
        p.add_argument("data", nargs="?", type=Path, help=data)
    for flag, kw in extra:
        p.add_argument(flag, **kw)
    p.add_argument("--blas-threads", type=int, default=None,
                   help="limit BLAS to this many threads for the whole run (default: leave as is)")
    return p.parse_args()


def header(title: str, touch: int = 0) -> None:
    """The first lines of every benchmark: what ran, on what, with how many BLAS threads; with
    ``touch``, that many bytes are pre-faulted first (:func:`prefault`)."""
    print(f"# {title}")
    print(f"python {platform.python_version()}, numpy {np.__version__}, scipy {scipy.__version__}, "
          f"{os.cpu_count()} cores, load average {', '.join(f'{x:.1f}' for x in os.getloadavg())}")
    print(f"BLAS: {blas_line()}")
    kept = keep_freed_memory()
    print("memory: " + ("glibc keeps freed memory (mallopt), so batch outputs reuse touched pages"
                        if kept else "mallopt unavailable: large outputs fault in fresh pages")
          + (f"; {fmt_bytes(touch)} pre-faulted in {prefault(touch):.1f} s" if touch else ""))
    print()


# ---------------------------------------------------------------------------------- formatting
def fmt_time(seconds: float | None) -> str:
    if seconds is None or not np.isfinite(seconds):
        return "-"
    if seconds >= 1:
        return f"{seconds:.2f} s"
    if seconds >= 1e-3:
        return f"{seconds * 1e3:.2f} ms"
    return f"{seconds * 1e6:.0f} us"


def fmt_bytes(n: float | None) -> str:
    if n is None:
        return "-"
    n = float(n)
    for unit, size in (("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if abs(n) >= size:
            return f"{n / size:.1f} {unit}"
    return f"{n:.0f} B"


def fmt_ratio(r: float | None) -> str:
    if r is None or not np.isfinite(r):
        return "-"
    if r >= 100:
        return f"{r:.0f}x"
    if r >= 10:
        return f"{r:.1f}x"
    return f"{r:.2f}x"


def table(rows, header, title: str | None = None, notes=()) -> None:
    """Print rows as an aligned Markdown table (numbers and units right-aligned)."""
    cells = [[str(c) for c in r] for r in rows]
    widths = [max(len(r[i]) for r in cells + [list(header)]) for i in range(len(header))]
    numeric = [all(r[i][:1].isdigit() or r[i][:1] in "-<~" for r in cells) for i in range(len(header))]
    if title:
        print(title)
        print()

    def line(cols):
        return "| " + " | ".join(c.rjust(w) if num else c.ljust(w) for c, w, num in zip(cols, widths, numeric)) + " |"

    print(line(list(header)))
    print("|" + "|".join(("-" * (w + 1) + ":") if num else ("-" * (w + 2)) for w, num in zip(widths, numeric)) + "|")
    for r in cells:
        print(line(r))
    for n in notes:
        print(n)
    print()


@dataclass
class Row:
    """One timing: ``case`` (what is computed, e.g. '1 frame, warm'), ``method``, seconds for
    ``frames`` frames; baselines set ``baseline``. The ratio compares rows of one case and one
    ``group`` (e.g. the same float type): fastest baseline time / this time (above 1: faster)."""

    case: str
    method: str
    seconds: float | None
    frames: int = 1
    baseline: bool = False
    group: str = ""
    note: str = ""


def speed_table(rows: list[Row], title: str | None = None, notes=()) -> None:
    """Timings grouped by case, with per-frame time and the ratio to the best baseline."""
    # cases and groups in order of first appearance, baselines first within a group
    cases = {c: k for k, c in enumerate(dict.fromkeys(r.case for r in rows))}
    groups = {g: k for k, g in enumerate(dict.fromkeys(r.group for r in rows))}
    rows = sorted(rows, key=lambda r: (cases[r.case], groups[r.group], not r.baseline))
    refs: dict[tuple[str, str], float] = {}
    for r in rows:
        if r.baseline and r.seconds is not None:
            key = (r.case, r.group)
            refs[key] = min(refs.get(key, np.inf), r.seconds)
    out, last = [], None
    for r in rows:
        ref = refs.get((r.case, r.group))
        ratio = ref / r.seconds if ref is not None and r.seconds else None
        per = r.seconds / r.frames if r.seconds is not None and r.frames > 1 else None
        label = ("baseline: " if r.baseline else "") + r.method
        out.append([r.case if r.case != last else "", label, fmt_time(r.seconds), fmt_time(per),
                    fmt_ratio(ratio) + (" (ref)" if r.baseline and ref == r.seconds else ""), r.note])
        last = r.case
    table(out, ["case", "method", "time", "per frame", "vs best baseline", "note"], title,
          ["ratio = time of the fastest baseline of the same case"
           + (" and group" if any(r.group for r in rows) else "") + " / this time (above 1x: faster)"]
          + list(notes))
