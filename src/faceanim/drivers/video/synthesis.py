"""Data-driven filtering and expression synthesis (Chai, Xiao & Hodgins 2003, sections 4.2-4.3).

The control signal from video is noisy and low-dimensional (15 numbers); the motion database
holds what real faces do. Both steps work on **segments** of W frames (the paper: 20), so that
the mapping from controls to motion is disambiguated by the frames around:

- **Filtering (4.2)**: the K segments of the database nearest the query segment (Euclidean in
  the W x 15 space of control parameters) span a local linear model: their mean and the
  principal directions keeping 99% of their variance. The query is projected onto it: what
  the database cannot produce (noise) is removed.
- **Synthesis (4.3)**: the filtered query is written as a combination of the K neighbours in
  the same local subspace; their marker segments, weighted alike (weights from the distances in
  the subspace, normalised), give the synthesised markers.
- **Blending**: each output frame is covered by several overlapping segments; their estimates
  are blended with the paper's ``alpha = 0.5 cos(beta pi) + 0.5`` (beta from 0 for the newest
  segment to 1), over ``overlap`` frames, which sets the delay: a frame is final once the newest
  segment covering it has been seen.

The K nearest segments come from the paper's **neighbourhood graph** (4.4, :class:`NeighbourhoodGraph`:
segments linked to their nearest neighbours; a query starts from the nearest of the previous
query's neighbours and walks the graph best-first, using the temporal coherence of the control
signal), from scipy's k-d tree, or by brute force (``search=``).
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np

from faceanim.errors import FaceAnimError


@dataclass
class SegmentDatabase:
    """The database's segments: ``controls`` (S, W*15) and, per segment, the index of its last
    frame (``ends``); markers are looked up from the frames."""

    window: int
    controls: np.ndarray
    ends: np.ndarray


def segments(controls: np.ndarray, window: int, take_starts=(0,)) -> SegmentDatabase:
    """Every run of ``window`` consecutive frames of (F, 15) ``controls`` that stays inside one
    take (``take_starts``: the first frame of each)."""
    c = np.asarray(controls, dtype=np.float64)
    if not 1 <= window <= len(c):
        raise FaceAnimError(f"the segment window must be 1 to {len(c)} frames, got {window}")
    starts = sorted({int(s) for s in take_starts} | {0})
    bounds = starts[1:] + [len(c)]
    ends = np.concatenate([np.arange(s + window - 1, b) for s, b in zip(starts, bounds)]).astype(np.int64)
    if not len(ends):
        raise FaceAnimError(f"no take is {window} frames long; give a shorter window")
    idx = ends[:, None] - np.arange(window - 1, -1, -1)[None]
    return SegmentDatabase(window, c[idx].reshape(len(ends), -1), ends)


class NeighbourhoodGraph:
    """The paper's data structure (4.4): every segment linked to its ``degree`` nearest segments
    (both ways); K-nearest queries walk it best-first from the nearest of the previous query's
    neighbours, visiting at most ``budget`` segments, so a query costs about O(K) whatever the
    database's size. The first query (or after :meth:`reset`) is answered exactly."""

    def __init__(self, points: np.ndarray, degree: int = 12, budget: int = 4):
        from scipy.spatial import cKDTree

        self.points = np.asarray(points, dtype=np.float64)
        n = len(self.points)
        degree = int(min(max(degree, 1), n - 1)) if n > 1 else 0
        self.tree = cKDTree(self.points)
        if degree:
            _, nn = self.tree.query(self.points, k=degree + 1)
            pairs = np.c_[np.repeat(np.arange(n), degree), nn[:, 1:].reshape(-1)]
            pairs = np.unique(np.sort(np.vstack([pairs, pairs[:, ::-1]]), axis=1), axis=0)
            both = np.vstack([pairs, pairs[:, ::-1]])
            order = np.lexsort((both[:, 1], both[:, 0]))
            both = both[order]
            self.starts = np.searchsorted(both[:, 0], np.arange(n + 1))
            self.links = both[:, 1]
        else:
            self.starts, self.links = np.zeros(n + 1, np.int64), np.zeros(0, np.int64)
        self.budget = int(budget)
        self.last: np.ndarray | None = None
        self.visited_total = 0

    def reset(self) -> None:
        self.last = None

    def query(self, q: np.ndarray, k: int) -> np.ndarray:
        """Indices of (about) the ``k`` nearest points to ``q``, nearest first."""
        if self.last is None:
            _, nn = self.tree.query(q, k=k)
            self.last = np.atleast_1d(nn)
            return self.last
        dist = {}

        def d(i):
            if i not in dist:
                dist[i] = float(np.sum((self.points[i] - q) ** 2))
            return dist[i]

        seeds = [int(i) for i in self.last]
        start = min(seeds, key=d)
        heap = [(d(start), start)]
        seen = {start}
        done = []
        limit = self.budget * k
        while heap and len(done) < limit:
            dd, i = heapq.heappop(heap)
            done.append((dd, i))
            for j in self.links[self.starts[i]:self.starts[i + 1]]:
                j = int(j)
                if j not in seen:
                    seen.add(j)
                    heapq.heappush(heap, (d(j), j))
        self.visited_total += len(dist)
        best = sorted(done)[:k]
        self.last = np.array([i for _, i in best], dtype=np.int64)
        return self.last


class Synthesiser:
    """Filtering and synthesis against one motion database (see the module docstring).

    ``controls`` (F, 15) and ``markers`` (F, ...) of the database: marker positions (F, P, 3) or
    any per-frame motion, such as its weights in the deformation bases (F, L); ``window`` W, ``k``
    K neighbours, ``variance`` kept by the local model, ``overlap`` segments blended per frame.
    """

    def __init__(self, controls, markers, window: int = 20, k: int = 30, variance: float = 0.99,
                 overlap: int = 5, take_starts=(0,), search: str = "kdtree"):
        from scipy.spatial import cKDTree

        self.markers = np.asarray(markers, dtype=np.float64)
        self.db = segments(controls, int(window), take_starts)
        if not 1 <= k <= len(self.db.ends):
            raise FaceAnimError(f"K must be 1 to {len(self.db.ends)} segments, got {k}")
        if not 0 < variance <= 1:
            raise FaceAnimError(f"the variance kept must be in (0, 1], got {variance}")
        if not 1 <= overlap <= window:
            raise FaceAnimError(f"the overlap must be 1 to {window} frames, got {overlap}")
        if search not in ("graph", "kdtree", "brute"):
            raise FaceAnimError(f"unknown search '{search}'; choose graph, kdtree or brute")
        self.window, self.k, self.variance, self.overlap = int(window), int(k), float(variance), int(overlap)
        self.search = search
        self.tree = cKDTree(self.db.controls)
        self.graph = NeighbourhoodGraph(self.db.controls) if search == "graph" else None

    def nearest(self, query: np.ndarray) -> np.ndarray:
        """The K nearest database segments of a (W*15,) query segment."""
        if self.search == "graph":
            return self.graph.query(query, self.k)
        if self.search == "kdtree":
            return np.atleast_1d(self.tree.query(query, k=self.k)[1])
        d = np.sum((self.db.controls - query) ** 2, axis=1)
        nn = np.argpartition(d, self.k - 1)[: self.k]
        return nn[np.argsort(d[nn])]

    def _local(self, query: np.ndarray):
        """The K nearest segments, the filtered query and the neighbours' weights."""
        nn = self.nearest(query)
        x = self.db.controls[nn]
        mean = x.mean(axis=0)
        _, s, vt = np.linalg.svd(x - mean, full_matrices=False)
        energy = np.cumsum(s ** 2) / max(float((s ** 2).sum()), 1e-300)
        r = int(np.searchsorted(energy, self.variance) + 1) if s.sum() > 0 else 0
        basis = vt[:r]
        coords = (query - mean) @ basis.T  # the query in the local subspace
        filtered = mean + coords @ basis
        d = np.linalg.norm((x - mean) @ basis.T - coords, axis=1)  # distances in the subspace
        sigma = max(float(np.median(d)), 1e-12)
        w = np.exp(-((d / sigma) ** 2))
        return nn, filtered, w / w.sum()

    def synthesise(self, controls: np.ndarray) -> np.ndarray:
        """(F, ...) motion (as the database's ``markers``) for (F, 15) query controls (frames before
        the first full window reuse it; the output frame t is final after frame t + overlap - 1)."""
        q = np.asarray(controls, dtype=np.float64)
        if q.ndim != 2 or q.shape[1] != self.db.controls.shape[1] // self.window or not np.all(np.isfinite(q)):
            raise FaceAnimError(f"query controls must be finite (frames, {self.db.controls.shape[1] // self.window})")
        f_count, w_len = len(q), self.window
        if self.graph is not None:
            self.graph.reset()
        padded = np.vstack([np.repeat(q[:1], w_len - 1, axis=0), q])
        out = np.zeros((f_count,) + self.markers.shape[1:])
        weight = np.zeros(f_count)
        offsets = np.arange(w_len - 1, -1, -1)
        for t in range(f_count):
            seg = padded[t:t + w_len].reshape(-1)  # frames t - W + 1 .. t
            nn, _, wts = self._local(seg)
            frames = self.db.ends[nn][:, None] - offsets[None]  # (K, W) database frames
            est = np.tensordot(wts, self.markers[frames], axes=1)  # the synthesised segment
            # this segment's estimates of frames t - overlap + 1 .. t, blended by alpha(beta)
            for j in range(self.overlap):
                f = t - j
                if f < 0:
                    break
                beta = j / self.overlap
                a = 0.5 * np.cos(beta * np.pi) + 0.5
                out[f] += a * est[w_len - 1 - j]
                weight[f] += a
        return out / weight.reshape((-1,) + (1,) * (out.ndim - 1))

    def filter(self, controls: np.ndarray) -> np.ndarray:
        """(F, 15) the query controls projected on the local models (each frame taken from the
        segment that ends at it)."""
        q = np.asarray(controls, dtype=np.float64)
        w_len, m = self.window, q.shape[1]
        if self.graph is not None:
            self.graph.reset()
        padded = np.vstack([np.repeat(q[:1], w_len - 1, axis=0), q])
        out = np.empty_like(q)
        for t in range(len(q)):
            _, filtered, _ = self._local(padded[t:t + w_len].reshape(-1))
            out[t] = filtered.reshape(w_len, m)[-1]
        return out
