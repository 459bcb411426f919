"""The bound linear deformer every method compiles to.

    positions (F, V, 3) = rest (V, 3) + W (V, H) @ handle offsets (F, H, 3)

A method (RBF, thin-plate spline, geometry deformation elements, ...) does its expensive work
once when it is *bound* to a rest pose and produces the weight matrix ``W``; *applying* it to
any number of frames is then a matrix product. ``W`` is stored only for the rows of vertices
that some handle can move (``rows``); every other vertex is copied from the rest pose, so it
stays bit-identical.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.sparse as sp

from faceanim.errors import DeformError

SMALL_SYSTEM = 2000  # dense solves up to this many unknowns run on one BLAS thread (see one_blas_thread)


@functools.lru_cache(maxsize=1)
def _threadpools():
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def one_blas_thread():
    """A context in which BLAS (OpenBLAS) uses one thread. On a busy 2-core machine two BLAS
    threads slow sparse factorisations and small dense solves 2-30x (they wait for each other);
    the controller is found once per process, so entering this costs microseconds."""
    return _threadpools().limit(limits=1, user_api="blas")


# frames per block in batched dense evaluation: enough rows for BLAS to run near peak
_FRAME_BLOCK = 64
_THREADS = max(1, min(8, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1))


def _over_frames(n: int, run) -> None:
    """``run(lo, hi)`` over frames 0..n, split over threads for long batches (scipy's sparse
    kernels and numpy's ufuncs release the GIL)."""
    workers = min(_THREADS, max(1, n // _FRAME_BLOCK))
    if workers == 1:
        run(0, n)
        return
    cuts = np.linspace(0, n, workers + 1).astype(int)
    with ThreadPoolExecutor(workers) as pool:
        list(pool.map(run, cuts[:-1], cuts[1:]))


class LinearDeformer:
    """A deformer bound to a rest pose: ``apply(offsets)`` returns deformed vertex positions.

    Parameters
    ----------
    rest : (V, 3) array
        Rest-pose vertex positions.
    weights : (A, H) array or scipy sparse matrix
        Weight of each handle on each movable vertex.
    rows : (A,) int array, optional
        Vertex indices of the rows of ``weights``; ``None`` means every vertex (A == V).
    handle_names : sequence of str, optional
        One name per handle (column), for reporting.
    """

    def __init__(self, rest, weights, rows=None, handle_names: Sequence[str] | None = None):
        rest = np.asarray(rest)
        if rest.ndim != 2 or rest.shape[1] != 3:
            raise DeformError(f"rest must have shape (V, 3), got {rest.shape}")
        if sp.issparse(weights):
            weights = sp.csr_matrix(weights)
        else:
            weights = np.ascontiguousarray(weights)
        if weights.ndim != 2:
            raise DeformError(f"weights must be 2-D (A, H), got shape {weights.shape}")
        if rows is None:
            if weights.shape[0] != rest.shape[0]:
                raise DeformError(
                    f"weights has {weights.shape[0]} rows but the rest pose has {rest.shape[0]} vertices"
                )
        else:
            rows = np.asarray(rows, dtype=np.int64)
            if rows.shape != (weights.shape[0],):
                raise DeformError(f"rows must have shape ({weights.shape[0]},), got {rows.shape}")
            if rows.size == rest.shape[0] and np.array_equal(rows, np.arange(rest.shape[0])):
                rows = None
        self.rest = rest
        self.weights = weights
        self.rows = rows
        self._full = self._mask = None  # full-height CSC for sparse evaluation, built on first use
        self._axis_ops = None  # the blendshape matrix for apply_blendshapes, built on first use
        self.handle_names = list(handle_names) if handle_names is not None else None
        if self.handle_names is not None and len(self.handle_names) != weights.shape[1]:
            raise DeformError("handle_names must give one name per handle")

    # ------------------------------------------------------------------ properties
    @property
    def n_vertices(self) -> int:
        return self.rest.shape[0]

    @property
    def n_handles(self) -> int:
        return self.weights.shape[1]

    @property
    def dtype(self):
        return self.rest.dtype

    @property
    def moving_vertices(self) -> np.ndarray:
        """Indices of the vertices some handle can move."""
        return np.arange(self.n_vertices) if self.rows is None else self.rows

    @property
    def is_sparse(self) -> bool:
        return sp.issparse(self.weights)

    def nbytes(self) -> int:
        """Memory held by the operator, in bytes: the weights and the evaluation forms built on
        first use (the full-height sparse copy and its mask, the blendshape matrix)."""
        def size(a) -> int:
            if a is None:
                return 0
            if sp.issparse(a):
                a = a.tocsr() if a.format not in ("csr", "csc") else a
                return a.data.nbytes + a.indices.nbytes + a.indptr.nbytes
            return a.nbytes

        n = size(self.weights) + (0 if self.rows is None else self.rows.nbytes)
        if self._full is not None and self._full is not self.weights:
            n += size(self._full) + size(self._mask)
        return n + size(self._axis_ops)

    def dense_weights(self) -> np.ndarray:
        """The full (V, H) weight matrix, zeros on rows no handle moves."""
        w = self.weights.toarray() if sp.issparse(self.weights) else self.weights
        if self.rows is None:
            return np.array(w)
        full = np.zeros((self.n_vertices, self.n_handles), dtype=w.dtype)
        full[self.rows] = w
        return full

    # ------------------------------------------------------------------ conversions
    def astype(self, dtype) -> LinearDeformer:
        """The same deformer evaluated in another float type (float32 is the fast path)."""
        w = self.weights.astype(dtype)
        return LinearDeformer(self.rest.astype(dtype), w, self.rows, self.handle_names)

    def to_dense(self) -> LinearDeformer:
        w = self.weights.toarray() if sp.issparse(self.weights) else self.weights
        return LinearDeformer(self.rest, w, self.rows, self.handle_names)

    # ------------------------------------------------------------------ evaluation
    def _check_offsets(self, offsets) -> np.ndarray:
        off = np.asarray(offsets, dtype=self.rest.dtype)
        if off.ndim not in (2, 3) or off.shape[-2:] != (self.n_handles, 3):
            raise DeformError(
                f"offsets must have shape ({self.n_handles}, 3) or (frames, {self.n_handles}, 3), "
                f"got {off.shape}"
            )
        if not np.all(np.isfinite(off)):
            raise DeformError("offsets contain NaN or infinite values")
        return off

    def displacements(self, offsets) -> np.ndarray:
        """Vertex displacements ``W @ offsets``: (V, 3) for (H, 3), (F, V, 3) for (F, H, 3)."""
        off = self._check_offsets(offsets)
        zero = np.zeros_like(self.rest)
        return self._evaluate(zero, off)

    def weight_columns(self, start: int, stop: int) -> np.ndarray:
        """(V, stop - start) the weights of handles ``start..stop`` over all vertices (zero where
        nothing moves): the displacements of unit offsets at those handles, read off ``W``
        without the product over every handle (a rig's blendshape is three such columns)."""
        if not 0 <= start <= stop <= self.n_handles:
            raise DeformError(f"handle columns {start}..{stop} are outside the {self.n_handles} handles")
        if sp.issparse(self.weights):
            full, _ = self._sparse_full_rows()
            return full[:, start:stop].toarray()
        cols = np.asarray(self.weights[:, start:stop], dtype=self.rest.dtype)
        if self.rows is None:
            return cols.copy()
        out = np.zeros((self.n_vertices, stop - start), dtype=self.rest.dtype)
        out[self.rows] = cols
        return out

    def apply(self, offsets) -> np.ndarray:
        """Deformed positions ``rest + W @ offsets``: (V, 3) for (H, 3), (F, V, 3) for (F, H, 3)."""
        return self._evaluate(self.rest, self._check_offsets(offsets))

    __call__ = apply

    def _sparse_full_rows(self):
        """The weights over all V rows (empty where nothing moves) and the (V, 3) movable mask.

        Scattering a product into ``out[rows]`` by fancy indexing costs more than the product
        itself; a full-height operator gives a contiguous (V, 3) result that is added only where
        ``mask`` is set, so unmoved vertices keep their exact bits (even -0.0).
        """
        if self._full is None:
            w = self.weights
            if self.rows is None:
                full = w
                mask = np.ones((self.n_vertices, 3), dtype=bool)
            else:
                counts = np.diff(w.indptr)
                indptr = np.zeros(self.n_vertices + 1, dtype=w.indptr.dtype)
                np.add.at(indptr, self.rows + 1, counts)
                full = sp.csr_matrix((w.data, w.indices, np.cumsum(indptr)), shape=(self.n_vertices, self.n_handles))
                mask = np.zeros((self.n_vertices, 3), dtype=bool)
                mask[self.rows] = True
            # column-major: scipy's CSC product walks each handle's rows in order, about 30 %
            # faster here than the CSR product for a few handles per vertex
            self._full, self._mask = sp.csc_matrix(full), mask
        return self._full, self._mask

    def _evaluate(self, base: np.ndarray, off: np.ndarray) -> np.ndarray:
        w, rows = self.weights, self.rows
        single = off.ndim == 2
        if single and rows is None and not sp.issparse(w):
            return base + w @ off
        frames = off[None] if single else off
        out = np.empty((frames.shape[0],) + base.shape, dtype=base.dtype)
        if sp.issparse(w):
            # sparse: one product per frame, added in place where vertices can move; scipy's
            # sparse kernels and numpy's ufuncs release the GIL, so long batches use threads
            full, mask = self._sparse_full_rows()

            # rows nothing moves get + 0.0, which keeps every bit except the sign of -0.0:
            # restore those few coordinates afterwards instead of masking every add
            flat_base = base.reshape(-1)
            negzero = np.flatnonzero((flat_base == 0) & np.signbit(flat_base) & ~mask.reshape(-1))

            def run(lo: int, hi: int) -> None:
                for f in range(lo, hi):
                    np.add(base, full @ frames[f], out=out[f])
                    if negzero.size:
                        out[f].reshape(-1)[negzero] = -0.0

            _over_frames(frames.shape[0], run)
        elif rows is None:
            # dense: per coordinate, (frames, H) @ (H, V) with contiguous operands for BLAS
            wt = w.T
            for start in range(0, frames.shape[0], _FRAME_BLOCK):
                stop = min(start + _FRAME_BLOCK, frames.shape[0])
                for c in range(3):
                    d = np.ascontiguousarray(frames[start:stop, :, c]) @ wt
                    np.add(d, base[:, c], out=out[start:stop, :, c])
        else:
            for f in range(frames.shape[0]):
                out[f] = base
                out[f, rows] += w @ frames[f]
        return out[0] if single else out

    def apply_blendshapes(self, curves) -> np.ndarray:
        """Positions (F, V, 3) when the handles come in threes, one (x, y, z) triple per blendshape,
        and handle ``3c + a`` moves along axis ``a`` by ``curves[:, c]``: the same ``rest + W @
        offsets`` as :meth:`apply` with those offsets, evaluated without multiplying the zeros, as
        ``rest + B @ curves[f]`` with the blendshape matrix ``B[3v + a, c] = W[v, 3c + a]`` (one
        sparse product per frame, contiguous output; one BLAS product for all frames when dense).
        This is how a rig's blendshape columns are evaluated (:class:`faceanim.rig.rig.Rig`)."""
        c = np.asarray(curves, dtype=self.rest.dtype)
        if c.ndim != 2 or 3 * c.shape[1] != self.n_handles:
            raise DeformError(f"blendshape curves must have shape (frames, {self.n_handles // 3}), got {c.shape}")
        if self._axis_ops is None:
            n_v, n_c = self.n_vertices, self.n_handles // 3
            if sp.issparse(self.weights):
                w = sp.coo_matrix(self.weights)
                v = w.row if self.rows is None else self.rows[w.row]
                self._axis_ops = sp.csr_matrix((w.data, (3 * v + w.col % 3, w.col // 3)), shape=(3 * n_v, n_c))
            else:
                full = self.dense_weights()  # (V, 3C)
                self._axis_ops = np.ascontiguousarray(
                    full.reshape(n_v, n_c, 3).transpose(1, 0, 2).reshape(n_c, 3 * n_v))  # B^T (C, 3V)
        op = self._axis_ops
        rest = self.rest.reshape(-1)
        out = np.empty((c.shape[0], rest.size), dtype=self.rest.dtype)
        if sp.issparse(op):
            def run(lo: int, hi: int) -> None:
                for f in range(lo, hi):
                    np.add(rest, op @ c[f], out=out[f])

            _over_frames(c.shape[0], run)
        else:
            np.matmul(c, op, out=out)  # no temporary the size of the output
            out += rest
        return out.reshape(c.shape[0], -1, 3)

    # ------------------------------------------------------------------ composition
    @staticmethod
    def stack(deformers: Sequence[LinearDeformer]) -> LinearDeformer:
        """One deformer driving the handles of several, side by side (their effects add)."""
        if not deformers:
            raise DeformError("stack needs at least one deformer")
        rest = deformers[0].rest
        for d in deformers[1:]:
            if d.rest.shape != rest.shape or not np.array_equal(d.rest, rest):
                raise DeformError("deformers stacked together must share one rest pose")
        rows = np.unique(np.concatenate([d.moving_vertices for d in deformers]))
        position = np.full(rest.shape[0], -1, dtype=np.int64)
        position[rows] = np.arange(rows.size)
        blocks = []
        for d in deformers:
            w = sp.coo_matrix(d.weights)
            r = position[d.moving_vertices][w.row]
            blocks.append((r, w.col, w.data, d.n_handles))
        offset = 0
        rr, cc, vv = [], [], []
        for r, c, v, h in blocks:
            rr.append(r)
            cc.append(c + offset)
            vv.append(v)
            offset += h
        w = sp.csr_matrix(
            (np.concatenate(vv), (np.concatenate(rr), np.concatenate(cc))), shape=(rows.size, offset)
        )
        names = None
        if all(d.handle_names is not None for d in deformers):
            names = [n for d in deformers for n in d.handle_names]
        out = LinearDeformer(rest, w, rows, names)
        if not all(d.is_sparse for d in deformers) and w.nnz > 0.25 * rows.size * max(offset, 1):
            out = out.to_dense()
        return out
