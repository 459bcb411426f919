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
segments linked to diverse near neighbours and to their successors in time; a query starts from
the previous query's neighbours and their successors, using the temporal coherence of the control
signal, and walks the graph as a beam), from scipy's k-d tree, or by brute force (``search=``).
"""

from __future__ import annotations

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
    """The paper's data structure (4.4): every segment linked to its nearest segments and to the
    next segment of its take; a K-nearest query starts from the previous query's neighbours and
    their successors (the temporal coherence of the control signal: if segment i was near the
    last query, segment i + 1 is likely near this one) and walks the graph as a beam of
    ``budget * K`` segments, expanding the whole beam's links at once, until its K best stop
    changing. The links are chosen diverse (a candidate is skipped when it is nearer to an
    already chosen link than to the segment: the rule of HNSW graphs), so that near-copies of a
    motion do not use up all the links and trap the walk. The first query (or after
    :meth:`reset`) is answered exactly.

    ``points`` (S, D) segments; ``successor`` (S,) the next segment of the same take (itself at a
    take's end; default: the next row)."""

    def __init__(self, points: np.ndarray, degree: int = 12, budget: int = 4, successor: np.ndarray | None = None,
                 max_steps: int = 8):
        from scipy.spatial import cKDTree

        self.points = np.asarray(points, dtype=np.float64)
        n = len(self.points)
        self.tree = cKDTree(self.points)
        self.successor = (np.minimum(np.arange(n) + 1, n - 1) if successor is None
                          else np.asarray(successor, dtype=np.int64))
        links = [[] for _ in range(n)]
        degree = int(min(max(degree, 1), n - 1)) if n > 1 else 0
        if degree:
            cand_k = min(3 * degree + 1, n)
            dist, nn = self.tree.query(self.points, k=cand_k)
            for i in range(n):
                chosen: list[int] = []
                for dj, j in zip(dist[i, 1:], nn[i, 1:]):
                    if len(chosen) >= degree:
                        break
                    if chosen:
                        dc = np.linalg.norm(self.points[chosen] - self.points[j], axis=1)
                        if dc.min() < dj:  # nearer to a chosen link than to i: reached through it
                            continue
                    chosen.append(int(j))
                links[i].extend(chosen)
                for j in chosen:
                    links[j].append(i)
        for i in range(n):
            if self.successor[i] != i:
                links[i].append(int(self.successor[i]))
                links[int(self.successor[i])].append(i)
        lists = [np.unique(np.array(lk, dtype=np.int64)) for lk in links]
        self.starts = np.concatenate([[0], np.cumsum([len(lk) for lk in lists])]).astype(np.int64)
        self.links = np.concatenate(lists) if lists else np.zeros(0, np.int64)
        self.budget, self.max_steps = int(budget), int(max_steps)
        self.last: np.ndarray | None = None
        self.visited_total = 0
        self._seen = np.zeros(n, dtype=bool)

    def reset(self) -> None:
        self.last = None

    def _neighbours(self, idx: np.ndarray) -> np.ndarray:
        if not len(idx):
            return idx
        lo, hi = self.starts[idx], self.starts[idx + 1]
        take = hi - lo
        rows = np.repeat(lo, take) + (np.arange(take.sum()) - np.repeat(np.cumsum(take) - take, take))
        return self.links[rows]

    def query(self, q: np.ndarray, k: int) -> np.ndarray:
        """Indices of (about) the ``k`` nearest points to ``q``, nearest first."""
        if self.last is None:
            _, nn = self.tree.query(q, k=k)
            self.last = np.atleast_1d(nn)
            return self.last
        seen = self._seen
        beam = np.unique(np.concatenate([self.last, self.successor[self.last]]))
        seen[beam] = True
        touched = [beam]
        diff = self.points[beam] - q
        dist = np.einsum("ij,ij->i", diff, diff)
        ef = max(self.budget * k, k)
        expanded = np.zeros(0, dtype=np.int64)
        best = None
        for _ in range(self.max_steps):
            order = np.argsort(dist)[:ef]
            beam, dist = beam[order], dist[order]
            top = beam[:k]
            if best is not None and np.array_equal(top, best):
                break
            best = top
            fresh = beam[~np.isin(beam, expanded)]
            expanded = np.concatenate([expanded, fresh])
            nb = self._neighbours(fresh)
            nb = np.unique(nb[~seen[nb]])
            if not len(nb):
                break
            seen[nb] = True
            touched.append(nb)
            diff = self.points[nb] - q
            beam = np.concatenate([beam, nb])
            dist = np.concatenate([dist, np.einsum("ij,ij->i", diff, diff)])
        for t in touched:
            seen[t] = False
        self.visited_total += int(sum(len(t) for t in touched))
        self.last = beam[np.argsort(dist)[:k]]
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
        if search == "graph":
            ends = self.db.ends
            nxt = np.arange(len(ends)) + 1
            nxt[-1] = len(ends) - 1
            same = np.r_[ends[1:] == ends[:-1] + 1, False]
            self.graph = NeighbourhoodGraph(self.db.controls, successor=np.where(same, nxt, np.arange(len(ends))))
        else:
            self.graph = None

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


class SynthesisStream:
    """:meth:`Synthesiser.synthesise` one frame at a time, for live input: :meth:`push` a query
    frame, get back the newest *final* frame of motion, ``overlap - 1`` frames behind (None until
    there is one). With ``overlap`` 1 there is no delay: each frame is the estimate of the segment
    ending at it. The frames out are exactly those of :meth:`Synthesiser.synthesise` on the same
    queries."""

    def __init__(self, synthesiser: Synthesiser):
        self.s = synthesiser
        if self.s.graph is not None:
            self.s.graph.reset()
        self.recent: np.ndarray | None = None  # the last W query frames
        self.pending: list[list] = []  # [sum of alpha * estimate, sum of alpha] of frames not yet final
        self._offsets = np.arange(self.s.window - 1, -1, -1)

    @property
    def delay(self) -> int:
        """Frames between a query pushed and its motion out."""
        return self.s.overlap - 1

    def push(self, query: np.ndarray) -> np.ndarray | None:
        q = np.asarray(query, dtype=np.float64).reshape(-1)
        m = self.s.db.controls.shape[1] // self.s.window
        if q.shape != (m,) or not np.all(np.isfinite(q)):
            raise FaceAnimError(f"a query frame must be {m} finite controls")
        w_len, overlap = self.s.window, self.s.overlap
        self.recent = np.repeat(q[None], w_len, axis=0) if self.recent is None else np.vstack([self.recent[1:], q])
        nn, _, wts = self.s._local(self.recent.reshape(-1))
        frames = self.s.db.ends[nn][:, None] - self._offsets[None]
        est = np.tensordot(wts, self.s.markers[frames], axes=1)
        self.pending.append([np.zeros(self.s.markers.shape[1:]), 0.0])
        for j in range(min(overlap, len(self.pending))):
            a = 0.5 * np.cos(j / overlap * np.pi) + 0.5
            slot = self.pending[-1 - j]
            slot[0] = slot[0] + a * est[w_len - 1 - j]
            slot[1] += a
        if len(self.pending) < overlap:
            return None
        total, weight = self.pending.pop(0)
        return total / weight
