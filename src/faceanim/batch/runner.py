"""Run planned tasks on a ``dask.distributed`` cluster.

Without a scheduler address a :class:`~distributed.LocalCluster` starts on this machine (one
single-threaded worker process per core by default). Binding a face (landmarks, regions, rigs) is
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
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from pathlib import Path

from faceanim.batch.manifest import Manifest
from faceanim.errors import FaceAnimError, shown

CONNECT_TIMEOUT = "10s"


@dataclass
class PlannedTask:
    """A task ready to run: its output (relative to the output folder), the argv the task
    function takes, the face it binds (None: nothing to bind) and its manifest signature."""

    output: str
    argv: list[str]
    face: Hashable | None
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


def _client(scheduler: str | None, workers: int | None):
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            return Client(scheduler, timeout=CONNECT_TIMEOUT, set_as_default=False)
        except (OSError, TimeoutError, ValueError):
            raise FaceAnimError(f"cannot reach the Dask scheduler at '{shown(scheduler, 80)}' within "
                                f"{CONNECT_TIMEOUT}; check the address and that dask-scheduler runs there") from None
    try:
        import bokeh  # noqa: F401  -- the dashboard needs it
        dashboard = ":0"
    except ImportError:
        dashboard = None
    n = workers or max(1, min(os.cpu_count() or 1, 8))
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=dashboard,
                           silence_logs=logging.ERROR)
    return Client(cluster, set_as_default=False)


def run(tasks: list[PlannedTask], out_dir, bind: Callable, work: Callable, *, scheduler: str | None = None,
        workers: int | None = None, retries: int = 2, bind_faces: bool = True, progress: Callable | None = None,
        on_start: Callable | None = None) -> Summary:
    """Run ``tasks`` not already done (by the manifest in ``out_dir``). ``bind(face)`` makes the
    bound face; ``work(argv, out_dir, bound)`` runs one task and returns ``{"state": "done" |
    "failed", "outputs": [...], "error": str, "seconds": float}``. ``bind_faces=False`` binds in
    every task instead (to measure what binding once saves). ``progress(n)`` is called with the
    number of tasks finished; ``on_start(summary)`` once the cluster is up."""
    out_dir = Path(out_dir)
    manifest = Manifest(out_dir)
    summary = Summary()
    start = time.perf_counter()
    try:
        todo = []
        for t in tasks:
            if manifest.is_done(t.output, t.signature, out_dir):
                summary.skipped.append(t.output)
            else:
                todo.append(t)
        if not todo:
            return summary
        client = _client(scheduler, workers)
        try:
            info = client.scheduler_info()
            summary.workers = len(info.get("workers", {}))
            summary.dashboard = client.dashboard_link if "dashboard" in info.get("services", {}) else None
            if on_start is not None:
                on_start(summary)
            summary.seconds = 0.0
            futures = {}
            bound = {}
            if bind_faces:
                for face in dict.fromkeys(t.face for t in todo if t.face is not None):
                    bound[face] = client.submit(_timed_bind, bind, face, retries=retries, pure=False)
            for t in todo:
                b = bound.get(t.face) if bind_faces else None
                fut = client.submit(_run_one, work, bind, t.argv, str(out_dir), b, t.face, not bind_faces,
                                    retries=retries, pure=False)
                futures[fut] = t
            from distributed import as_completed

            finished = 0
            with client.as_current():
                for fut in as_completed(list(futures)):
                    t = futures[fut]
                    try:
                        result = fut.result()
                    except Exception as exc:  # noqa: BLE001 -- a task that kept crashing its workers, or a bug
                        result = {"state": "failed", "outputs": [], "seconds": 0.0,
                                  "error": f"the task failed {retries + 1} times ({type(exc).__name__}); rerun the "
                                           "batch to retry it"}
                    if result["state"] == "done":
                        summary.done.append(t.output)
                        summary.task_seconds.append(result["seconds"])
                        manifest.record(t.output, t.signature, "done", result["outputs"], "", result["seconds"])
                    else:
                        summary.failed[t.output] = result["error"]
                        manifest.record(t.output, t.signature, "failed", [], result["error"], result["seconds"])
                    if result.get("bind_seconds") is not None:
                        summary.bind_seconds.append(result["bind_seconds"])
                    finished += 1
                    if progress is not None:
                        progress(finished)
            for fut in bound.values():
                try:
                    summary.bind_seconds.append(fut.result()[1])
                except Exception:  # noqa: BLE001 -- its tasks already say why
                    pass
        finally:
            cluster = client.cluster
            client.close()
            if cluster is not None and not scheduler:
                cluster.close()
    finally:
        manifest.close()
        summary.seconds = time.perf_counter() - start
    return summary


def _timed_bind(bind: Callable, face):
    start = time.perf_counter()
    try:
        return bind(face), time.perf_counter() - start
    except FaceAnimError as exc:  # bad input: its tasks report it, not a retry
        return exc, time.perf_counter() - start


def _run_one(work: Callable, bind: Callable, argv, out_dir: str, bound, face, bind_here: bool) -> dict:
    bind_seconds = None
    if bind_here and face is not None:
        bound = _timed_bind(bind, face)
        bind_seconds = bound[1]
    if bound is not None:
        bound = bound[0]
        if isinstance(bound, FaceAnimError):
            return {"state": "failed", "outputs": [], "error": str(bound), "seconds": 0.0, "bind_seconds": bind_seconds}
    result = work(argv, out_dir, bound)
    result["bind_seconds"] = bind_seconds
    return result
