"""Run planned tasks in this process or on a ``dask.distributed`` cluster.

A cluster costs seconds to start (about 4 s for a LocalCluster of two workers here) and each of its
workers binds the faces again, so a small batch runs faster as a plain loop. Without a scheduler
address or a worker count the tasks start here, one after another; once the measured time per task
says the work left would pay a cluster's start-up (:func:`cluster_pays`), the rest moves to a
:class:`~distributed.LocalCluster` on this machine (one single-threaded worker process per core).
``--scheduler`` or ``--workers N`` (N > 1) start on the cluster; ``--workers 1`` stays here. Binding a face (landmarks, regions, rigs) is
the expensive part of most tasks, so each distinct face is bound once, by a task of its own, and
the tasks on that face take the bound face as an argument: Dask runs them where it lives and
copies it to any other worker that steals work, rather than each task binding it again. A task
that raises is retried (``retries``); a worker that dies has its tasks, and the bound faces it
held, redone on the others (Dask's lineage). A task that fails on bad input returns its one-line
error and the batch goes on. Only this process writes the manifest.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from contextlib import ExitStack, contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path

from faceanim.batch.manifest import NAME as MANIFEST_NAME
from faceanim.batch.manifest import Manifest
from faceanim.errors import FaceAnimError, shown

CONNECT_TIMEOUT = "10s"


@dataclass
class PlannedTask:
    """A task ready to run: its output (relative to the output folder), the argv the task
    function takes, the faces it binds (keys for ``bind``; none: nothing to bind) and its
    manifest signature."""

    output: str
    argv: list[str]
    faces: tuple
    signature: str


@dataclass
class Summary:
    done: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0
    workers: int = 0
    dashboard: str | None = None
    task_seconds: list[float] = field(default_factory=list)
    bind_seconds: list[float] = field(default_factory=list)
    here: int = 0  # tasks run in this process (before any cluster)


CLUSTER_START = 5.0  # seconds a LocalCluster takes to be ready, a little over what it takes here


def cluster_pays(task_seconds: float, bind_seconds: float, left: int, workers: int) -> bool:
    """Whether ``left`` tasks of ``task_seconds`` each finish sooner on a local cluster of ``workers``
    processes than here: the time the cluster saves (``left * task_seconds * (1 - 1/workers)``)
    against its start-up and each worker binding a face again."""
    if workers < 2 or left < 2:
        return False
    return left * task_seconds * (1.0 - 1.0 / workers) > CLUSTER_START + bind_seconds


def _client(scheduler: str | None, workers: int | None):
    from faceanim.extras import require

    distributed = require("distributed", "faceanim batch")
    Client, LocalCluster = distributed.Client, distributed.LocalCluster

    if scheduler:
        try:
            return Client(scheduler, timeout=CONNECT_TIMEOUT, set_as_default=False)
        except (OSError, TimeoutError, ValueError, TypeError):
            raise FaceAnimError(f"cannot reach the Dask scheduler at '{shown(scheduler, 80)}' within "
                                f"{CONNECT_TIMEOUT}; check the address and that 'dask scheduler' runs there") from None
    try:
        import bokeh  # noqa: F401  -- the dashboard needs it
        dashboard = ":0"
    except ImportError:
        dashboard = None
    n = workers or max(1, min(os.cpu_count() or 1, 8))
    # the worker processes start with Ctrl-C ignored: a terminal sends it to the whole process group,
    # and this process stops the batch (and its workers) itself; each worker would print a traceback
    with _sigint_ignored():
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=dashboard,
                               silence_logs=logging.CRITICAL)
    return Client(cluster, set_as_default=False)


@contextmanager
def _sigint_ignored():
    """SIGINT ignored while the block starts processes (they inherit it), then as it was (a Ctrl-C
    in those few seconds is ignored too; the next one stops the batch)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@contextmanager
def _dask_quiet():
    """Dask's, Tornado's and asyncio's loggers silent in this process while the cluster runs and
    closes (a worker's connection closing as the cluster stops is logged with a traceback)."""
    names = ("distributed", "tornado", "asyncio", "bokeh")
    levels = {n: logging.getLogger(n).level for n in names}
    for n in names:
        logging.getLogger(n).setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for n, level in levels.items():
            logging.getLogger(n).setLevel(level)


IN_FLIGHT_PER_WORKER = 4  # tasks handed to the scheduler at once, per worker (a dataset may have 10^5)...
IN_FLIGHT_MIN = 64  # ...and at least this many (a cluster that grows with the work starts with few)


def run(tasks: list[PlannedTask], out_dir, bind: Callable, work: Callable, *, scheduler: str | None = None,
        workers: int | None = None, retries: int = 2, bind_faces: bool = True, progress: Callable | None = None,
        on_start: Callable | None = None, on_cluster: Callable | None = None) -> Summary:
    """Run ``tasks`` not already done (by the manifest in ``out_dir``, which is made, with the
    folder, only once the work can start: a cluster asked for must answer first). ``bind(face)``
    makes a bound face; ``work(argv, out_dir, {face: bound})`` runs one task and returns
    ``{"state": "done" | "failed", "outputs": [...], "error": str, "seconds": float}``.
    ``bind_faces=False`` binds in every task instead (to measure what binding once saves). Where the
    tasks run: see the module docstring. ``progress(n)`` is called with the number of tasks
    finished; ``on_start(summary)`` once work starts (``summary.workers`` 0: in this process);
    ``on_cluster(summary, left)`` when the tasks left move to a cluster."""
    out_dir = Path(out_dir)
    summary = Summary()
    start = time.perf_counter()
    existing = Manifest.existing(out_dir)
    try:
        todo = []
        for t in tasks:
            if existing is not None and existing.is_done(t.output, t.signature, out_dir):
                summary.skipped.append(t.output)
            else:
                todo.append(t)
    finally:
        if existing is not None:
            existing.close()
    if not todo:
        summary.seconds = time.perf_counter() - start
        return summary
    # the tasks of one face together, faces in order of first use (a face is let go sooner)
    first = {}
    for k, t in enumerate(todo):
        first.setdefault(t.faces, k)
    todo.sort(key=lambda t: first[t.faces])
    # before the cluster, a second batch on this folder stops here (a first run's manifest is made,
    # and locked, only once the work can start: nothing is written before)
    lock = _lock(out_dir) if (out_dir / MANIFEST_NAME).is_file() else None
    on_cluster_now = scheduler is not None or (workers or 0) > 1
    client = manifest = None
    finished = [0]

    def done_one(t: PlannedTask, result: dict) -> None:
        if result["state"] == "done":
            summary.done.append(t.output)
            summary.task_seconds.append(result["seconds"])
            manifest.record(t.output, t.signature, "done", result["outputs"], "", result["seconds"])
        else:
            summary.failed[t.output] = result["error"]
            manifest.record(t.output, t.signature, "failed", [], result["error"], result["seconds"])
        summary.bind_seconds.extend(result.get("bind_seconds") or [])
        finished[0] += 1
        if progress is not None:
            progress(finished[0])

    quiet = ExitStack()
    try:
        quiet.enter_context(_dask_quiet())
        if on_cluster_now:
            client = _client(scheduler, workers)
        out_dir.mkdir(exist_ok=True)
        planned_unlocked = lock is None
        lock = lock or _lock(out_dir)
        manifest = Manifest(out_dir)
        if planned_unlocked:  # a batch that held the folder between our plan and our lock did these
            left = []
            for t in todo:
                (summary.skipped if manifest.is_done(t.output, t.signature, out_dir) else left).append(t)
            todo = left
        if client is None:
            if on_start is not None:
                on_start(summary)
            n = 1 if workers == 1 else max(1, min(os.cpu_count() or 1, 8))
            todo = _run_here(todo, out_dir, bind, work, bind_faces, done_one, summary, n)
            if todo:
                client = _client(None, workers)
                if on_cluster is not None:
                    on_cluster(summary, len(todo))
        if todo:
            _run_cluster(client, todo, out_dir, bind, work, retries, bind_faces, done_one, summary,
                         on_start if on_cluster_now else None)
    finally:
        if client is not None:
            cluster = client.cluster
            with suppress(Exception):  # a connection closing as the cluster stops is no failure of the batch
                client.close()
            if cluster is not None and not scheduler:
                with suppress(Exception):
                    cluster.close()
        quiet.close()
        if manifest is not None:
            manifest.close()
        if lock is not None:
            lock.close()
        summary.seconds = time.perf_counter() - start
    return summary


def _run_here(todo: list[PlannedTask], out_dir: Path, bind: Callable, work: Callable, bind_faces: bool,
              done_one: Callable, summary: Summary, workers: int) -> list[PlannedTask]:
    """Run tasks one after another in this process (each face bound once, let go after its last
    task) until :func:`cluster_pays` for the rest; returns the tasks left for a cluster."""
    users: dict = {}
    for t in todo:
        for f in t.faces:
            users[f] = users.get(f, 0) + 1
    bound: dict = {}
    spent, binding = 0.0, 0.0
    for k, t in enumerate(todo):
        if k and cluster_pays(spent / k, binding / max(1, len(bound)) if bound else 0.0, len(todo) - k, workers):
            return todo[k:]
        begin = time.perf_counter()
        faces = {}
        if bind_faces:
            for f in t.faces:
                if f not in bound:
                    bound[f] = _timed_bind(bind, f)
                    binding += bound[f][1]
                    summary.bind_seconds.append(bound[f][1])
                faces[f] = bound[f]
        done_one(t, _run_one(work, bind, t.argv, str(out_dir), faces, t.faces))
        summary.here += 1
        for f in t.faces:
            users[f] -= 1
            if users[f] == 0:
                bound.pop(f, None)
        spent += time.perf_counter() - begin
    return []


def _run_cluster(client, todo: list[PlannedTask], out_dir: Path, bind: Callable, work: Callable, retries: int,
                 bind_faces: bool, done_one: Callable, summary: Summary, on_start: Callable | None) -> None:
    """Run tasks on the cluster of ``client``, a window at a time, grouped by face; a bound face
    lives on the workers until its last task is done."""
    info = client.scheduler_info()
    summary.workers = len(info.get("workers", {}))
    threaded = [w for w, n in client.nthreads().items() if n > 1]
    if threaded:  # a task sets process-wide state (its bound faces, its printing): one at a time
        raise FaceAnimError(f"{len(threaded)} of the cluster's workers run several threads; faceanim's tasks "
                            "need single-threaded workers (dask worker --nthreads 1 --nworkers N)")
    summary.dashboard = client.dashboard_link if "dashboard" in info.get("services", {}) else None
    if on_start is not None:
        on_start(summary)
    from distributed import as_completed

    # enough in flight for every worker, and for workers that join later (an adaptive cluster)
    window = max(IN_FLIGHT_MIN, IN_FLIGHT_PER_WORKER * summary.workers)
    users = {}  # face -> tasks not yet finished that use it
    for t in todo:
        for f in t.faces:
            users[f] = users.get(f, 0) + 1
    bound: dict = {}  # face -> future of (bound face, seconds)
    bind_futures = []
    pending = iter(todo)
    running = {}

    def submit_next():  # the next task's future, or False when none is left
        t = next(pending, None)
        if t is None:
            return False
        if bind_faces:
            for f in t.faces:
                if f not in bound:
                    bound[f] = client.submit(_timed_bind, bind, f, retries=retries, pure=False)
                    bind_futures.append(client.submit(_seconds, bound[f], pure=False))
            faces = {f: bound[f] for f in t.faces}
        else:
            faces = {}
        fut = client.submit(_run_one, work, bind, t.argv, str(out_dir), faces, t.faces, retries=retries,
                            pure=False)
        running[fut] = t
        return fut

    with client.as_current():
        flow = as_completed([f for f in (submit_next() for _ in range(window)) if f])
        for fut in flow:
            t = running.pop(fut)
            try:
                result = fut.result()
            except Exception as exc:  # noqa: BLE001 -- a task that kept crashing its workers, or a bug
                result = {"state": "failed", "outputs": [], "seconds": 0.0,
                          "error": f"its worker died or the task crashed {retries + 1} times "
                                   f"({type(exc).__name__}); rerun the batch to try it again"}
            done_one(t, result)
            for f in t.faces:  # a face no task needs any more leaves the workers' memory
                users[f] -= 1
                if users[f] == 0:
                    bound.pop(f, None)
            nxt = submit_next()
            if nxt:
                flow.add(nxt)
        summary.bind_seconds += [b.result() for b in bind_futures]


def _lock(out_dir: Path):
    """An exclusive lock (flock, beside SQLite's own byte-range locks) on the output folder's
    manifest for this batch: two batches on one folder would both redo everything."""
    import fcntl

    fh = open(out_dir / MANIFEST_NAME, "a")  # noqa: SIM115 -- held until the batch ends
    try:
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        fh.close()
        raise FaceAnimError(f"another faceanim batch is writing to '{shown(out_dir, 80, tail=True)}'; wait for it "
                            "or choose another output folder") from None
    return fh


def _timed_bind(bind: Callable, face):
    start = time.perf_counter()
    try:
        return bind(face), time.perf_counter() - start
    except FaceAnimError as exc:  # bad input: its tasks report it, not a retry
        return exc, time.perf_counter() - start
    except Exception as exc:  # noqa: BLE001 -- a bug: one line for its tasks, as work() reports its own
        return FaceAnimError(f"internal error while binding the face ({type(exc).__name__}); please report it "
                             "with the job file"), time.perf_counter() - start


def _seconds(timed) -> float:
    return float(timed[1])


def _run_one(work: Callable, bind: Callable, argv, out_dir: str, faces: dict, keys: tuple) -> dict:
    bind_seconds = []
    if not faces and keys:  # --no-bind: this task binds its own faces
        faces = {}
        for key in keys:
            faces[key] = _timed_bind(bind, key)
            bind_seconds.append(faces[key][1])
    bound = {}
    for key, (face, _) in faces.items():
        if isinstance(face, FaceAnimError):  # bad input (or a bug) while binding: one line for each task
            return {"state": "failed", "outputs": [], "error": str(face), "seconds": 0.0, "bind_seconds": bind_seconds}
        bound[key] = face
    result = work(argv, out_dir, bound)
    result["bind_seconds"] = bind_seconds
    return result
