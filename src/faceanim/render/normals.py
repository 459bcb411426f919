"""Smooth vertex normals of a deforming mesh, fast enough to recompute every frame.

The triangle list is fixed while the vertices move, so the sum of the (area-weighted) normals of
the triangles around each vertex is one product with a sparse vertex x triangle incidence
matrix built once: per frame there are three gathers, one cross product and one sparse
matrix product, all vectorised (no ``np.add.at``), into work arrays allocated once (fresh
megabyte-sized arrays every frame cost page faults that can double the time).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

try:  # the sparse product into a preallocated output; scipy's public @ allocates its result
    from scipy.sparse._sparsetools import csr_matvecs as _csr_matvecs
except ImportError:  # pragma: no cover - a scipy that moved it
    _csr_matvecs = None


class VertexNormals:
    """Area-weighted vertex normals for a fixed triangle list.

    ``rows`` (optional, (S,) vertex indices) asks for the normals of those vertices in that
    order, e.g. the seam-split vertices of :meth:`Mesh.per_vertex_uv`, straight from the one
    sparse product.
    """

    def __init__(self, faces: np.ndarray, n_vertices: int, rows: np.ndarray | None = None):
        faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        n_tri = len(faces)
        self.n_vertices = int(n_vertices)
        if n_tri and (faces.min() < 0 or faces.max() >= self.n_vertices):
            raise ValueError("triangle vertex indices out of range")
        self._corners = [np.ascontiguousarray(faces[:, k]) for k in range(3)]
        incidence = sp.csr_matrix(
            (np.ones(3 * n_tri, dtype=np.float32), (faces.ravel(), np.repeat(np.arange(n_tri), 3))),
            shape=(self.n_vertices, n_tri))
        if rows is not None:
            incidence = incidence[np.asarray(rows, dtype=np.int64)]
        incidence = incidence.tocsr()
        incidence.sum_duplicates()
        self.incidence = incidence
        self._a = np.empty((n_tri, 3), dtype=np.float32)
        self._e1 = np.empty_like(self._a)
        self._e2 = np.empty_like(self._a)
        self._fn = np.empty_like(self._a)
        self._tmp = np.empty(n_tri, dtype=np.float32)

    def __call__(self, vertices: np.ndarray, normalise: bool = True) -> np.ndarray:
        """(S, 3) float32 normals (a new array); unit length when ``normalise`` (zero for vertices
        on no triangle or only on degenerate ones), else the sums of twice the triangle areas
        times their unit normals."""
        v = np.ascontiguousarray(vertices, dtype=np.float32)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) != self.n_vertices:
            raise ValueError(f"expected ({self.n_vertices}, 3) vertices, got shape {v.shape}")
        a, e1, e2, fn, tmp = self._a, self._e1, self._e2, self._fn, self._tmp
        np.take(v, self._corners[0], axis=0, out=a)  # np.take: several times faster than v[idx]
        np.take(v, self._corners[1], axis=0, out=e1)
        np.take(v, self._corners[2], axis=0, out=e2)
        e1 -= a
        e2 -= a
        for k, (i, j) in enumerate(((1, 2), (2, 0), (0, 1))):  # the cross product written out
            np.multiply(e1[:, i], e2[:, j], out=fn[:, k])
            np.multiply(e1[:, j], e2[:, i], out=tmp)
            fn[:, k] -= tmp
        m = self.incidence
        if _csr_matvecs is not None:
            n = np.zeros((m.shape[0], 3), dtype=np.float32)
            _csr_matvecs(m.shape[0], m.shape[1], 3, m.indptr, m.indices, m.data, fn.ravel(), n.ravel())
        else:  # pragma: no cover
            n = np.asarray(m @ fn, dtype=np.float32)
        if normalise:
            length = np.sqrt(np.einsum("ij,ij->i", n, n))[:, None]
            n /= np.where(length > 0, length, 1.0)
        return n
