"""Biharmonic interpolation on the surface: handle offsets spread along the skin.

The thin-plate spline of the TPS papers minimises bending energy in the *space* around the
face, so it measures distance straight through the air: a handle on the upper lip pulls the
lower lip (a few millimetres away across the mouth slit) as strongly as its own lip, and an
upper-eyelid handle drags the lower lid. Minimising the same bending energy on the *surface*
removes that coupling wherever the mesh is open (mouth slit, eye openings), because there the
surface distance is long:

    minimise  x^T (L^T M^-1 L) x   over the free vertices,
    subject to  C x = d  (each handle's barycentric point reaches its offset)
                x = 0    on the fixed vertices

with ``L`` the cotangent Laplacian and ``M`` the lumped (barycentric) vertex areas. The
minimiser is linear in ``d``, so the bound operator is one dense ``W`` over the free vertices:
one sparse LU of the KKT system, solved once for all handles (an identity right-hand side).

A tiny area-weighted term ``eps * x^T M x`` keeps the system definite on free parts that no
handle or fixed vertex reaches (eyeballs, teeth: they stay put).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spl

from faceanim.deform.base import LinearDeformer, one_blas_thread
from faceanim.errors import DeformError

_COT_CLAMP = 1e3  # bounds cot(angle) on degenerate triangles of raw scans


def cotangent_laplacian(vertices: np.ndarray, faces: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """Cotangent Laplacian ``L`` (V, V; negative semi-definite) and lumped vertex areas (V,)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    n = len(v)
    rows, cols, vals = [], [], []
    area = np.zeros(n)
    for i in range(3):
        a, b, c = f[:, i], f[:, (i + 1) % 3], f[:, (i + 2) % 3]
        e1, e2 = v[b] - v[a], v[c] - v[a]
        cross = np.linalg.norm(np.cross(e1, e2), axis=1)
        cot = np.clip((e1 * e2).sum(1) / np.maximum(cross, 1e-300), -_COT_CLAMP, _COT_CLAMP)
        rows += [b, c]
        cols += [c, b]
        vals += [0.5 * cot, 0.5 * cot]
        np.add.at(area, a, cross / 6.0)
    w = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    lap = w - sp.diags(np.asarray(w.sum(1)).ravel())
    return lap.tocsr(), area


def bind_surface(rest, faces, handle_triangles, handle_barycentric, free=None,
                 handle_names=None, regularisation: float = 1e-8, order: int = 2) -> LinearDeformer:
    """Bind a surface-biharmonic deformer.

    Parameters
    ----------
    rest : (V, 3) rest vertex positions
    faces : (T, 3) triangles
    handle_triangles : (H,) triangle of each handle
    handle_barycentric : (H, 3) barycentric coordinates of each handle in its triangle
    free : (V,) bool, vertices that may move (default all); the others are fixed anchors
    regularisation : ``eps`` of the definiteness term, relative to the energy's scale

    Returns a :class:`LinearDeformer` over the free vertices.
    """
    rest = np.asarray(rest, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    tri = np.asarray(handle_triangles, dtype=np.int64).ravel()
    bary = np.asarray(handle_barycentric, dtype=np.float64).reshape(-1, 3)
    n, h = len(rest), len(tri)
    if h == 0:
        raise DeformError("the surface deformer needs at least one handle")
    if tri.min() < 0 or tri.max() >= len(faces):
        raise DeformError("a handle's triangle index is outside the mesh")
    free = np.ones(n, dtype=bool) if free is None else np.asarray(free, dtype=bool)
    if free.shape != (n,):
        raise DeformError(f"free must be a boolean mask of the {n} vertices")
    lap, area = cotangent_laplacian(rest, faces)
    area = np.maximum(area, area[area > 0].mean() * 1e-6 if (area > 0).any() else 1.0)
    minv = sp.diags(1.0 / area)
    if order == 2:
        energy = (lap.T @ minv @ lap).tocsr()
    elif order == 3:
        energy = (lap.T @ minv @ lap @ minv @ lap).tocsr()
        energy = 0.5 * (energy + energy.T)
    elif order == 1:
        energy = -lap
    else:
        raise DeformError(f"order must be 1 (harmonic), 2 (biharmonic) or 3 (triharmonic), got {order}")
    fr = np.flatnonzero(free)
    index = np.full(n, -1)
    index[fr] = np.arange(len(fr))
    q = energy[fr][:, fr]
    scale = abs(q.diagonal()).mean() / area[fr].mean() if len(fr) else 1.0
    q = q + sp.diags(regularisation * scale * area[fr])
    # constraint rows: barycentric combination of the handle triangle's free corners
    corner = faces[tri]
    cf = index[corner]
    keep = cf >= 0
    if not keep.any(axis=1).all():
        k = int(np.flatnonzero(~keep.any(axis=1))[0])
        raise DeformError(f"handle {k} lies on fixed vertices only; it cannot move anything")
    r = np.repeat(np.arange(h), 3)[keep.ravel()]
    c = cf.ravel()[keep.ravel()]
    con = sp.csr_matrix((bary.ravel()[keep.ravel()], (r, c)), shape=(h, len(fr)))
    kkt = sp.bmat([[q, con.T], [con, None]]).tocsc()
    # SuperLU calls BLAS on small dense blocks: two OpenBLAS threads on a busy 2-core machine
    # slow the factorisation 2-8x, so the solve runs with one (benchmarks/bench_facs.py)
    with one_blas_thread():
        try:
            lu = spl.splu(kkt)
        except RuntimeError:
            raise DeformError("the surface system is singular: two handles coincide or share one "
                              "vertex; remove the duplicate or move it apart") from None
        rhs = np.zeros((len(fr) + h, h))
        rhs[len(fr):] = np.eye(h)
        w = lu.solve(rhs)[: len(fr)]
    if not np.all(np.isfinite(w)):
        raise DeformError("the surface system is singular: two handles coincide; move them apart")
    return LinearDeformer(rest, w, fr, handle_names=handle_names)
