"""K-nearest segment search for filtering and synthesis (Chai, Xiao & Hodgins 2003, 4.4): the
paper's neighbourhood graph against scipy's k-d tree and brute force, at the motion database's
size and at ten times it.

    .venv/bin/python benchmarks/bench_knn.py ../shared/data [--blas-threads 1]    (about two minutes)

Databases: the shipped one (the MIT Live Link Face take, 4,032 frames at 30 fps) and one ten
times its size: the same take played ten times with smooth time warps (the playing speed swaying
by up to +-15% with a different period and phase per copy, so no two copies line up), built by
``build_database`` like any other. Segments of W = 20 frames (300 numbers), K = 30.

Queries: the control signals tracked in two real talking-head videos (d3, d14), one segment per
frame in order, as ``faceanim perform`` asks them (the graph walks from the previous query's
neighbours: that is the temporal coherence it exploits). Per method: time per query (warm, the
whole clip), recall (the fraction of the exact K nearest it returns; k-d tree and brute force are
exact), the mean distance of the K it returns over the exact K's (1 = as near; near-copies of a
motion in the 10x database make recall strict: another copy is as good for synthesis) and, for
the graph, the segments it measured per query. Build: time to make the index.

Compare ratios; wall-clock times depend on the machine's load and are never asserted.
"""

from __future__ import annotations

import time

import numpy as np
from _timing import arguments, blas_threads, fmt_time, header, table

from faceanim.build.motion import build_database
from faceanim.drivers.video.synthesis import NeighbourhoodGraph, segments
from faceanim.drivers.video.tracking import track_video
from faceanim.io.arkit_csv import ArkitTake, read_arkit_csv
from faceanim.perform import default_database, hold_untracked

W, K = 20, 30


def warped(take: ArkitTake, seed: int, depth: float = 0.15) -> ArkitTake:
    """The take played with its speed swaying by up to ``depth`` (a smooth time warp)."""
    rng = np.random.default_rng(seed)
    period, phase = rng.uniform(4.0, 12.0), rng.uniform(0, 2 * np.pi)
    dt = 1.0 / 60.0
    t = np.arange(0.0, take.duration, dt)
    speed = 1.0 + depth * np.sin(2 * np.pi * t / period + phase)
    tau = np.concatenate([[0.0], np.cumsum(speed[:-1]) * dt])
    tau = tau[tau <= take.times[-1]]
    t = t[: len(tau)]

    def at(a):
        return np.stack([np.interp(tau, take.times, c) for c in a.T], axis=1)

    return ArkitTake(t, at(take.weights), at(take.head), at(take.eyes), f"{take.source}#warp{seed}")


def queries(videos) -> list[np.ndarray]:
    out = []
    for v in videos:
        tr = track_video(v)
        c = hold_untracked(tr.controls, tr.tracked)
        padded = np.vstack([np.repeat(c[:1], W - 1, axis=0), c])
        out.append(np.stack([padded[t:t + W].reshape(-1) for t in range(len(c))]))
    return out


def measure(points: np.ndarray, ends: np.ndarray, qs: list[np.ndarray]):
    from scipy.spatial import cKDTree

    t0 = time.perf_counter()
    tree = cKDTree(points)
    t_tree = time.perf_counter() - t0
    t0 = time.perf_counter()
    nxt = np.arange(len(ends)) + 1
    nxt[-1] = len(ends) - 1
    same = np.r_[ends[1:] == ends[:-1] + 1, False]
    graph = NeighbourhoodGraph(points, successor=np.where(same, nxt, np.arange(len(ends))))
    t_graph = time.perf_counter() - t0
    exact, exact_d, rows = [], [], {}
    n_q = sum(len(q) for q in qs)
    t0 = time.perf_counter()
    for q in qs:
        for x in q:
            d = np.einsum("ij,ij->i", points - x, points - x)
            nn = np.argpartition(d, K - 1)[:K]
            exact.append(set(nn.tolist()))
            exact_d.append(np.sqrt(d[nn]).mean())
    rows["brute force"] = ((time.perf_counter() - t0) / n_q, 1.0, None, 0.0, 1.0)
    t0 = time.perf_counter()
    for q in qs:
        tree.query(q[0], k=K)
        for x in q:
            tree.query(x, k=K)
    rows["k-d tree (scipy)"] = ((time.perf_counter() - t0) / (n_q + len(qs)), 1.0, None, t_tree, 1.0)
    found, visited = [], 0
    t0 = time.perf_counter()
    graph.visited_total = 0
    for q in qs:
        graph.reset()
        for x in q:
            found.append(set(graph.query(x, K).tolist()))
    t_q = (time.perf_counter() - t0) / n_q
    recall = float(np.mean([len(a & b) / K for a, b in zip(found, exact)]))
    visited = graph.visited_total / n_q
    allq = np.vstack(qs)
    found_d = [np.linalg.norm(points[sorted(f)] - x, axis=1).mean() for f, x in zip(found, allq)]
    ratio = float(np.mean(np.array(found_d) / np.maximum(exact_d, 1e-12)))
    rows["neighbourhood graph (4.4)"] = (t_q, recall, visited, t_graph, ratio)
    return rows


def main() -> None:
    args = arguments(__doc__, "the shared data folder (../shared/data)")
    blas_threads(args.blas_threads)
    header("K-nearest segment search: neighbourhood graph, k-d tree, brute force")
    data = args.data
    qs = queries([data / "talking-head-videos" / f"{v}.mp4" for v in ("d3", "d14")])
    small = default_database()
    take = read_arkit_csv(data / "arkit-curves" / "alex_rom_3.csv")
    t0 = time.perf_counter()
    big = build_database([("alex_rom_3", take)] + [(f"warp{s}", warped(take, s)) for s in range(1, 10)], fps=30.0)
    t_build = time.perf_counter() - t0
    rows = []
    for label, db in (("1x", small), ("10x (time warps)", big)):
        seg = segments(db.controls, W, db.take_starts)
        res = measure(seg.controls, seg.ends, qs)
        base = res["brute force"][0]
        for name, (t_q, recall, visited, t_build_index, ratio) in res.items():
            rows.append([label, f"{len(seg.ends):,}", name, fmt_time(t_q), f"{base / t_q:.1f}x", f"{recall:.2f}",
                         f"{ratio:.3f}",
                         "-" if visited is None else f"{visited:.0f}", fmt_time(t_build_index) if t_build_index else "-"])
    table(rows, ["database", "segments", "search", "per query", "speed vs brute", "recall@30",
                 "mean distance / exact", "segments measured",
                 "index build"],
          title=f"\nW = {W}, K = {K}; {sum(len(q) for q in qs)} queries from d3 and d14 in order",
          notes=[f"the 10x database: {big.n_frames:,} frames, built in {t_build:.1f} s"])


if __name__ == "__main__":
    main()
