"""Dirichlet free-form deformation, DFFD (Lee, Escher, Sannier & Magnenat Thalmann 1999, section
2.1.2; Moccozet & Magnenat Thalmann 1997; Farin 1990; Sibson 1980).

Control points ``p_i`` (the paper's feature points plus 27 points around the head, see
:func:`enclosing_points`) move by offsets ``d_i``; every point ``x`` inside their convex hull is
written once in its **Sibson natural-neighbour coordinates** ``lambda_i(x)`` and moves with them:

    x' = x + sum_i lambda_i(x) d_i                                                        (DFFD)

    lambda_i(x) = vol(V(x) ∩ V_i) / vol(V(x))                                          (Sibson)

where ``V_i`` is the Voronoi cell of ``p_i`` among the control points and ``V(x)`` the cell ``x``
would have if it were inserted as one more point: ``lambda_i`` is the share of the new cell that
``x`` steals from ``p_i``. The coordinates are local (nonzero only for the natural neighbours of
``x``: the vertices of the Delaunay tetrahedra whose circumsphere contains ``x``), non-negative,
sum to 1, interpolate (``lambda_i(p_j) = delta_ij``) and reproduce linear functions exactly:
``sum_i lambda_i(x) p_i = x``, so an affine motion of all control points moves every point by the
same affine map. The map from offsets to displacements is linear, so a DFFD compiles to the one
deformation core: ``LinearDeformer(rest=x, weights=W)`` with ``W[v, i] = lambda_i(x_v)`` sparse.

How the volumes are computed (no halfspace intersection): the piece ``P_k = V(x) ∩ V_k`` is the
convex polytope bounded by the bisector plane of ``x`` and ``p_k`` and by the old Voronoi facets
between ``p_k`` and its Delaunay neighbours ``p_m``. Its volume is a sum of signed cones from the
apex ``r_k = (x + p_k) / 2``, which lies on the bisector of ``x`` and ``p_k`` (that facet adds
nothing), over the facets on the bisectors of ``p_k`` and ``p_m``, each fanned from the midpoint
``(p_k + p_m) / 2``:

    6 vol(P_k) = sum over the edges (u, v) of each facet, turning counter-clockwise seen from
                 outside, of det((p_k + p_m) / 2 - r_k, u - r_k, v - r_k)

The edges of the facet on the bisector of ``p_k`` and ``p_m`` lie on old Voronoi edges, dual to
the Delaunay triangles (k, m, w) around the edge (k, m): they run from the circumcentre ``c_T`` of
one tetrahedron of the cavity (those whose circumsphere contains ``x``; Bowyer-Watson) to the
next, or, where a triangle bounds the cavity, to the circumcentre ``g_f`` of ``x`` and that
triangle (a vertex of the new cell), and from there along the line equidistant from ``x``,
``p_k`` and ``p_m`` (split at the circumcentre ``z_km`` of the triangle x, p_k, p_m) to the next
bounding triangle. Every piece is then a term of one (tetrahedron, k, triangle, m) of the cavity,
and its orientation is the sign of ``det(p_m - p_k, p_n - p_k, p_m' - p_k)`` (``n`` the vertex
across the triangle, ``m'`` its third vertex). A Voronoi edge between two cavity tetrahedra is split
at the midpoint of their circumcentres (the split point is free: the two halves are collinear).
All points are taken relative to ``x``; a query at a control point gets that point's unit row.

The cavities are found by walking out from the tetrahedron holding each point, with an in-sphere
determinant (a tie, the point on a circumsphere, counts as outside, as it does exactly), and all
the points of a block are processed at once in numpy. Degenerate (cospherical) control points,
such as the 27 grid points, make qhull's triangulation contain flat tetrahedra: 4 points on one
circle get that circle's centre as circumcentre (any point of the circle's axis keeps every sum
exact) and the orientation that agrees with their neighbours; they join a cavity with the
neighbour they are reached from. Other flat ones (collinear points on a flat piece of the hull)
never do.

API, as in :mod:`faceanim.deform.rbf` (a system on fixed centres, and a bind function):

- :class:`DirichletFFD` ``(sites)``: the control points, triangulated once;
  ``.coordinates(points)`` (sparse Sibson coordinates), ``.deformer(vertices, names=None)``
  (a bound :class:`LinearDeformer`), ``ffd(points, offsets)`` (moved points);
- :func:`dirichlet_ffd` ``(sites, vertices, names=None)``: bind in one call;
- :func:`sibson_coordinates` ``(sites, queries)``: the coordinates alone;
- :func:`enclosing_points` ``(points, margin=0.25)``: the paper's 27 extra control points.

Speed: 25,000 vertices of a face against 550 control points bind in about 1 s on 2 cores
(``benchmarks/bench_ffd.py``).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from scipy.spatial import Delaunay, QhullError, cKDTree

from faceanim.deform.base import LinearDeformer, one_blas_thread
from faceanim.deform.rbf import check_number, check_points
from faceanim.errors import DeformError

MIN_SITES = 5  # fewer points cannot enclose a volume with any point strictly inside
MAX_SITES = 200_000  # control points of one DFFD (the paper uses a few hundred)
MAX_QUERIES = 5_000_000  # points expressed at once (a full head has ~25,000 vertices)
FLAT = 1e-10  # |det| / longest edge^3 below which a Delaunay tetrahedron is treated as flat
CIRCLE = 1e-6  # spread of a flat tetrahedron's face circumcentres (times its longest edge) on one circle
COPLANAR = 1e-8  # smallest / largest singular value of the centred sites below which they are planar
# tolerances in units of the sites' bounding-box diagonal (coordinates are scaled to it, within 2x)
DUPLICATE = 1e-9  # sites closer than this are the same point
AT_SITE = 1e-12  # a query this close to a site gets that site's unit row
HULL_MARGIN = 1e-9  # queries must be this far inside the convex hull (the new cell grows as 1/distance)
TIE = 1e-12  # in-sphere determinants below this times the size of their terms are ties (outside)
_CHUNK_BYTES = 16 * 2**20  # cavity bookkeeping (queries x tetrahedra, one byte each) per block
_CHUNK_QUERIES = 512  # queries per block: ~25 cavity tetrahedra x 12 terms each, cache-sized arrays

# the face of a tetrahedron across its vertex j (scipy: ``neighbors[:, j]`` is across vertex j)
_FACES = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])
_EDGES = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]


def _parity(p) -> int:
    """+1 for an even permutation of 0..n-1, -1 for an odd one."""
    p, s = list(p), 1
    for i in range(len(p)):
        for j in range(i + 1, len(p)):
            if p[i] > p[j]:
                s = -s
    return s


def _terms():
    """The 12 (k, n) vertex pairs of a tetrahedron with the other two (m1, m2) ordered so that
    (k, m1, n, m2) is an even permutation of the tetrahedron's vertices."""
    k_, n_, m1_, m2_ = [], [], [], []
    for k in range(4):
        for n in range(4):
            if n == k:
                continue
            m1, m2 = (i for i in range(4) if i not in (k, n))
            if _parity((k, m1, n, m2)) < 0:
                m1, m2 = m2, m1
            k_.append(k)
            n_.append(n)
            m1_.append(m1)
            m2_.append(m2)
    return tuple(np.array(a) for a in (k_, n_, m1_, m2_))


_K, _N, _M1, _M2 = _terms()


def _dot(a, b):
    return np.einsum("...i,...i->...", a, b)


def _cross(a, b):
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


def _circumcentre_tet(a, b, c):
    """Circumcentre of the tetrahedron (0, a, b, c) and ``det(a, b, c)`` (6 x signed volume)."""
    bc, ca, ab = _cross(b, c), _cross(c, a), _cross(a, b)
    det = _dot(a, bc)
    num = _dot(a, a)[..., None] * bc + _dot(b, b)[..., None] * ca + _dot(c, c)[..., None] * ab
    with np.errstate(divide="ignore", invalid="ignore"):
        return num / (2.0 * det[..., None]), det


def _circumcentre_tri(a, b):
    """Circumcentre of the triangle (0, a, b) in 3-D."""
    n = _cross(a, b)
    with np.errstate(divide="ignore", invalid="ignore"):
        return _cross(_dot(a, a)[..., None] * b - _dot(b, b)[..., None] * a, n) / (2.0 * _dot(n, n)[..., None])


def _count(points) -> int:
    """How many points a sequence holds, before anything is converted or allocated."""
    try:
        return len(points)
    except TypeError:
        return 0


class DirichletFFD:
    """A Dirichlet free-form deformation on fixed control points (sites), triangulated once.

    The analogue of :class:`faceanim.deform.rbf.RadialBasis` (a system on fixed centres, built
    once): :meth:`coordinates` gives the sparse Sibson coordinates of any points strictly inside
    the control points' convex hull, and :meth:`deformer` binds a mesh, a :class:`LinearDeformer`
    with one handle per control point (``apply(offsets)`` with offsets (H, 3)). The function
    :func:`dirichlet_ffd` does both in one call, as :func:`faceanim.deform.rbf.bind_rbf` does
    for RBFs.

    Parameters
    ----------
    sites : (H, 3) array
        Control points: at least 5, finite, not all in one plane, no two at one place.

    Raises
    ------
    DeformError
        NaN or infinite coordinates, fewer than 5 control points, all in one plane (or on a line),
        two of them at one place, or more than ``MAX_SITES``.
    """

    def __init__(self, sites):
        if _count(sites) > MAX_SITES:
            raise DeformError(f"{_count(sites)} control points is more than a DFFD takes ({MAX_SITES}); "
                              "use fewer")
        p = check_points(sites, "control points", min_count=MIN_SITES)
        lo, hi = p.min(axis=0), p.max(axis=0)
        with np.errstate(over="ignore", invalid="ignore"):
            span = float(np.linalg.norm(hi - lo))
        if not math.isfinite(span):
            raise DeformError("the control points are too far apart (coordinates near the float limit); "
                              "check their units")
        if span == 0.0:
            raise DeformError(f"all {len(p)} control points are at one place; spread them out")
        # all geometry is computed about the sites' centre in units of their diagonal (rounded
        # up to a power of 2): no overflow or underflow (volumes are cubes of lengths), the same
        # tolerances at any scale
        self.sites = p
        self.span = span
        self._origin = (lo + hi) / 2.0
        self._scale = 2.0 ** math.ceil(math.log2(span))  # a power of 2: grid coordinates stay exact
        self._p = (p - self._origin) / self._scale
        pairs = sorted(cKDTree(self._p).query_pairs(DUPLICATE))
        if pairs:
            i, j = pairs[0]
            more = f" (and {len(pairs) - 1} more pair(s))" if len(pairs) > 1 else ""
            raise DeformError(f"control points {i} and {j} coincide at {np.round(p[i], 9).tolist()}{more}; "
                              "remove the duplicate or move it apart")
        with one_blas_thread():
            sv = np.linalg.svd(self._p - self._p.mean(axis=0), compute_uv=False)
        if sv[2] <= COPLANAR * sv[0]:
            raise DeformError(f"the {len(p)} control points lie in one plane (or on a line); a DFFD needs "
                              "points around a volume (add enclosing_points(vertices) to them)")
        try:
            tri = Delaunay(self._p)
        except (QhullError, ValueError) as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise DeformError(f"the control points could not be triangulated ({first[:120]}); "
                              "check for nearly coplanar or coinciding points") from None
        if len(tri.coplanar):
            i = int(tri.coplanar[0, 0])
            raise DeformError(f"control point {i} is too close to another one to be triangulated; move it apart")
        self._tri = tri
        self._simp = tri.simplices.astype(np.int64)
        self._nb = tri.neighbors.astype(np.int64)
        self._geometry()
        self._hull_planes()

    # ------------------------------------------------------------------ properties
    @property
    def n_sites(self) -> int:
        return len(self.sites)

    @property
    def n_tetrahedra(self) -> int:
        return len(self._simp)

    # ------------------------------------------------------------------ triangulation geometry
    def _geometry(self) -> None:
        """Circumcentres, orientations and kinds of the Delaunay tetrahedra.

        A tetrahedron is *flat* when its volume is negligible (``|det| <= FLAT * longest^3``):
        qhull emits such ones for cospherical points (a grid). A flat one whose 4 points lie on
        one circle gets the circle's centre as circumcentre (the Voronoi edges of its triangles
        all lie on the circle's axis, and any point of that axis keeps the sums exact) and joins
        a cavity when a neighbour it is reached from is in it; any other flat one (collinear or
        coplanar points on a flat piece of the hull) has no circumsphere a query strictly inside
        the hull could enter, and never joins a cavity."""
        v = self._p[self._simp]  # (T, 4, 3)
        rel = v[:, 1:] - v[:, :1]
        centre, det = _circumcentre_tet(rel[:, 0], rel[:, 1], rel[:, 2])
        edges = np.stack([v[:, b] - v[:, a] for a, b in _EDGES], axis=1)
        longest = np.sqrt(_dot(edges, edges).max(axis=1))
        flat = np.abs(det) <= FLAT * longest**3
        cc = v[:, 0] + np.where(flat[:, None], 0.0, centre)
        sigma = np.sign(det)
        kind = np.zeros(len(v), dtype=np.int8)  # 0 proper, 1 flat on a circle, 2 other flat
        if flat.any():
            f = np.flatnonzero(flat)
            fv = v[f][:, _FACES]  # (F, 4, 3, 3): the 4 triangles of each flat tetrahedron
            a, b = fv[:, :, 1] - fv[:, :, 0], fv[:, :, 2] - fv[:, :, 0]
            centres = fv[:, :, 0] + _circumcentre_tri(a, b)  # (F, 4, 3)
            with np.errstate(invalid="ignore"):
                spread = np.ptp(centres, axis=1).max(axis=1)
            circle = np.isfinite(spread) & (spread <= CIRCLE * longest[f])
            cc[f[circle]] = centres[circle].mean(axis=1)
            kind[f] = np.where(circle, 1, 2)
            sigma[f] = 0.0
            sigma = self._orient_flat(sigma, f)
        if not np.all(np.isfinite(cc[~flat])):
            raise DeformError("the control points are nearly degenerate (a Delaunay tetrahedron has no finite "
                              "circumsphere); move nearly coplanar points apart")
        self._cc, self._sigma, self._kind = cc, sigma, kind

    def _orient_flat(self, sigma: np.ndarray, flat: np.ndarray) -> np.ndarray:
        """Give flat tetrahedra the orientation coherent with their neighbours': a triangle shared
        by two tetrahedra is oriented oppositely by them (the triangulation is orientable)."""
        todo = [int(t) for t in flat]
        while todo:
            left = []
            for t in todo:
                for j in range(4):
                    u = int(self._nb[t, j])
                    if u < 0 or sigma[u] == 0:
                        continue
                    face = [int(self._simp[t, i]) for i in _FACES[j]]
                    ju = next(i for i in range(4) if int(self._simp[u, i]) not in face)
                    other = [int(self._simp[u, i]) for i in _FACES[ju]]
                    sigma[t] = -sigma[u] * (-1) ** (j + ju) * _parity([other.index(i) for i in face])
                    break
                else:
                    left.append(t)
            if len(left) == len(todo):  # no oriented neighbour at all: any sign is coherent
                sigma[left[0]] = 1.0
                left = left[1:]
            todo = left
        return sigma

    def _hull_planes(self) -> None:
        """Outward unit normals and offsets of the convex hull's triangles (degenerate ones, three
        collinear points on a flat piece of the hull, have no plane and are skipped)."""
        hull = self._tri.convex_hull
        a, b, c = (self._p[hull[:, i]] for i in range(3))
        n = _cross(b - a, c - a)
        size = np.linalg.norm(n, axis=1)
        longest = np.max([_dot(b - a, b - a), _dot(c - b, c - b), _dot(a - c, a - c)], axis=0)
        keep = size > FLAT * longest
        a, n = a[keep], n[keep] / size[keep, None]
        n[_dot(self._p.mean(axis=0) - a, n) > 0] *= -1.0
        self._hull_n, self._hull_d = n, _dot(n, a)

    # ------------------------------------------------------------------ coordinates
    def coordinates(self, points) -> sp.csr_matrix:
        """Sibson coordinates of ``points`` (Q, 3): a CSR matrix (Q, H) whose row q holds
        ``lambda_i(points[q])`` for the natural neighbours ``i`` of that point (>= 0, summing to
        1, ``W @ sites == points``).

        Every point must lie strictly inside the convex hull of the control points (else a
        DeformError says how many do not); a point at a control point gets its unit row."""
        if _count(points) > MAX_QUERIES:
            raise DeformError(f"{_count(points)} points is more than a DFFD binds at once ({MAX_QUERIES}); "
                              "split the mesh")
        x = (check_points(points, "points", min_count=0) - self._origin) / self._scale
        h = self.n_sites
        if len(x) == 0:
            return sp.csr_matrix((0, h))
        dist, nearest = cKDTree(self._p).query(x)
        at_site = dist <= AT_SITE
        free = np.flatnonzero(~at_site)
        with one_blas_thread():  # the few small products here run faster on one BLAS thread
            loc = self._locate(x[free], len(x), free)
        rows, cols, vals = [np.flatnonzero(at_site)], [nearest[at_site]], [np.ones(int(at_site.sum()))]
        block = max(1, min(_CHUNK_QUERIES, _CHUNK_BYTES // self.n_tetrahedra))
        for a in range(0, free.size, block):
            idx = free[a:a + block]
            r, c, v = self._block(x[idx], loc[a:a + block])
            rows.append(idx[r])
            cols.append(c)
            vals.append(v)
        w = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(len(x), h))
        w.sum_duplicates()
        return w

    def _locate(self, x: np.ndarray, total: int, index: np.ndarray) -> np.ndarray:
        """A tetrahedron whose circumsphere contains each point (the one holding it), after
        checking that every point lies strictly inside the hull."""
        if not len(x):
            return np.zeros(0, dtype=np.int64)
        margin = np.full(len(x), -np.inf)
        for a in range(0, len(x), 65536):  # (points x hull triangles) in blocks
            margin[a:a + 65536] = (x[a:a + 65536] @ self._hull_n.T - self._hull_d).max(axis=1)
        loc = self._tri.find_simplex(x).astype(np.int64)
        outside = np.flatnonzero((loc < 0) | (margin > -HULL_MARGIN))
        if outside.size:
            raise DeformError(
                f"{outside.size} of {total} points lie outside (or on) the convex hull of the {self.n_sites} "
                f"control points (the first is point {index[outside[0]]}); add control points around "
                "them, e.g. enclosing_points(points) (faceanim.deform.ffd)")
        # find_simplex decides within a rounding tolerance: a point it places in a tetrahedron
        # whose sphere misses it (on a face, to rounding) or in a flat one starts instead from
        # the first proper tetrahedron whose sphere holds it (any one: a cavity is connected)
        wrong = np.flatnonzero(~self._in_sphere(x, loc) | (self._kind[loc] != 0))
        for i in wrong:
            proper = np.flatnonzero(self._kind == 0)
            hit = proper[self._in_sphere(np.repeat(x[i:i + 1], proper.size, axis=0), proper)]
            if not hit.size:
                raise DeformError(f"point {index[i]} could not be located among the control points (degenerate "
                                  "control points around it); move the control points near it apart")
            loc[i] = hit[0]
        return loc

    def _in_sphere(self, x: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Whether each point ``x`` lies strictly inside the circumsphere of tetrahedron ``t``: the
        sign of the lifted determinant of the vertices relative to ``x`` (no circumradius is
        subtracted, so thin tetrahedra with huge circumspheres are decided as well as any).
        A point on the sphere, to rounding (``TIE`` times the size of the determinant's terms),
        is outside, as it is exactly: a tie (a grid of control points and a query on one of its
        planes) must not put one of two tetrahedra that share a circle through the query inside
        and the other outside, which would ask for the circumcentre of the query and their
        triangle, a point in its plane. Flat tetrahedra on a circle are inside (they follow the
        neighbour they are reached from), other flat ones outside."""
        r = self._p[self._simp[t]] - x[:, None]  # (n, 4, 3)
        a, b, c, d = r[:, 0], r[:, 1], r[:, 2], r[:, 3]
        cd = _cross(c, d)
        terms = np.stack([_dot(a, a) * _dot(b, cd), -_dot(b, b) * _dot(a, cd),
                          _dot(c, c) * _dot(a, _cross(b, d)), -_dot(d, d) * _dot(a, _cross(b, c))])
        lifted, size = terms.sum(axis=0), np.abs(terms).sum(axis=0)
        kind = self._kind[t]
        return np.where(kind == 0, self._sigma[t] * lifted > TIE * size, kind == 1)

    def _cavities(self, x: np.ndarray, start: np.ndarray):
        """The Bowyer-Watson cavities: (query, tetrahedron) pairs whose circumsphere contains the
        query, found by walking out from a tetrahedron holding each query through the faces of
        tetrahedra found inside (a cavity is connected), and the (queries, tetrahedra) state
        table (1: in the cavity, 2: tested, outside)."""
        nq, nt = len(x), self.n_tetrahedra
        state = np.zeros((nq, nt), dtype=np.int8)
        q = np.arange(nq, dtype=np.int64)
        state[q, start] = 1
        found_q, found_t = [q], [start]
        fq, ft = q, start
        while fq.size:
            cq, ct = np.repeat(fq, 4), self._nb[ft].ravel()
            keep = ct >= 0
            cq, ct = cq[keep], ct[keep]
            keep = state[cq, ct] == 0
            key = np.unique(cq[keep] * nt + ct[keep])
            cq, ct = key // nt, key % nt
            inside = self._in_sphere(x[cq], ct)
            state[cq, ct] = np.where(inside, 1, 2)
            fq, ft = cq[inside], ct[inside]
            found_q.append(fq)
            found_t.append(ft)
        return np.concatenate(found_q), np.concatenate(found_t), state

    def _block(self, x: np.ndarray, start: np.ndarray):
        """Sibson coordinates of a block of points (none at a site): (rows, columns, values)."""
        q, t, state = self._cavities(x, start)
        xq = x[q]
        vr = self._p[self._simp[t]] - xq[:, None]  # (P, 4, 3) cavity tetrahedra's vertices, relative to x
        cr = self._cc[t] - xq  # their circumcentres
        nb = self._nb[t]
        inner = (nb >= 0) & (state[q[:, None], np.maximum(nb, 0)] == 1)  # the neighbour too is in the cavity
        # a point on the Voronoi edge dual to each triangle: the midpoint of the two circumcentres
        # inside the cavity; on its boundary the new cell's vertex, the circumcentre of x and the triangle
        e = (self._cc[t][:, None] + self._cc[np.maximum(nb, 0)]) / 2.0 - xq[:, None]
        bq, bf = np.nonzero(~inner)
        fv = vr[bq[:, None], _FACES[bf]]  # (B, 3, 3)
        e[bq, bf] = _circumcentre_tet(fv[:, 0], fv[:, 1], fv[:, 2])[0]
        # term (k, n): the Voronoi-edge pieces of the triangle across n on the facets between k and
        # its two other vertices m1, m2, as cones from the apex (x + p_k) / 2 fanned from (p_k + p_m) / 2
        apex = vr[:, _K] / 2.0
        u = cr[:, None] - apex
        v = e[:, _N] - apex
        terms = _dot((vr[:, _M1] - vr[:, _M2]) / 2.0, _cross(u, v))  # (P, 12)
        # and where the triangle bounds the cavity, the new cell's edges on the lines equidistant
        # from x, p_k and p_m, split at the circumcentre z_km of the triangle (x, p_k, p_m)
        bp, bt = np.nonzero(~inner[:, _N])
        if bp.size:
            vb, at = vr[bp], np.arange(bp.size)
            pk, pm1, pm2 = vb[at, _K[bt]], vb[at, _M1[bt]], vb[at, _M2[bt]]
            vv = v[bp, bt]
            z1 = _circumcentre_tri(pk, pm1) - pk / 2.0
            z2 = _circumcentre_tri(pk, pm2) - pk / 2.0
            terms[bp, bt] += _dot(pm1 / 2.0, _cross(vv, z1)) - _dot(pm2 / 2.0, _cross(vv, z2))
        # (P, 4): 6 x the volume stolen from each vertex k (the terms come k-major, 3 per k)
        vol = (terms * self._sigma[t][:, None]).reshape(-1, 4, 3).sum(axis=2)
        stolen = sp.csr_matrix((vol.ravel(), (np.repeat(q, 4), self._simp[t].ravel())), shape=(len(x), self.n_sites))
        stolen.sum_duplicates()
        stolen.data[stolen.data < 0] = 0.0  # rounding only: every natural neighbour loses a volume > 0
        total = np.asarray(stolen.sum(axis=1)).ravel()  # 6 x volume of the new cell
        bad = ~np.isfinite(total) | (total <= 0)
        if bad.any():
            raise DeformError("the Sibson coordinates of a point could not be computed (degenerate control points "
                              "around it); move the control points near it apart")
        stolen.data /= np.repeat(total, np.diff(stolen.indptr))
        stolen.eliminate_zeros()
        coo = stolen.tocoo()
        return coo.row, coo.col, coo.data

    def deformer(self, vertices, names=None) -> LinearDeformer:
        """Bind ``vertices`` (V, 3): the :class:`LinearDeformer` with ``W = coordinates(vertices)``
        (sparse CSR), one handle per control point, named by ``names`` (one per control point)."""
        if names is not None:
            if isinstance(names, str) or not all(isinstance(n, str) for n in names):
                raise DeformError("names must be a list of text names, one per control point")
            names = list(names)
            if len(names) != self.n_sites:
                raise DeformError(f"names must give one name per control point ({self.n_sites}), got {len(names)}")
        if _count(vertices) > MAX_QUERIES:
            raise DeformError(f"{_count(vertices)} vertices is more than a DFFD binds at once ({MAX_QUERIES})")
        rest = check_points(vertices, "mesh vertices")
        return LinearDeformer(rest, self.coordinates(rest), handle_names=names)

    def __call__(self, points, offsets) -> np.ndarray:
        """``points`` (Q, 3) moved by the control points' ``offsets`` (H, 3): x + sum_i lambda_i(x) d_i."""
        d = check_points(offsets, "offsets")
        if d.shape != self.sites.shape:
            raise DeformError(f"offsets must have shape {self.sites.shape}, got {d.shape}")
        x = check_points(points, "points")
        return x + self.coordinates(x) @ d


def sibson_coordinates(sites, queries) -> sp.csr_matrix:
    """Sibson natural-neighbour coordinates (Sibson 1980) of ``queries`` (Q, 3) with respect to
    ``sites`` (H, 3): the CSR matrix (Q, H) of ``lambda_i(x) = vol(V(x) ∩ V_i) / vol(V(x))``.

    Rows are >= 0, sum to 1 and reproduce linear functions (``lambda @ sites == queries``); a query
    at a site gets that site's unit row. Queries must lie strictly inside the sites' convex hull."""
    return DirichletFFD(sites).coordinates(queries)


def dirichlet_ffd(sites, vertices, names=None) -> LinearDeformer:
    """Bind a Dirichlet free-form deformation (Lee et al. 1999, section 2.1.2): control points
    ``sites`` (H, 3) move the mesh ``vertices`` (V, 3) by ``x' = x + sum_i lambda_i(x) d_i``.

    Returns a :class:`LinearDeformer` with the Sibson coordinates as its sparse (V, H) weights, so
    ``apply(offsets)`` takes the (H, 3) control-point offsets. Every vertex must lie inside the
    control points' convex hull: add the paper's 27 points around the mesh,
    ``sites = np.vstack([feature_points, enclosing_points(vertices)])`` (give them zero offsets to
    hold the space around the head still, or move them with the head)."""
    return DirichletFFD(sites).deformer(vertices, names)


def enclosing_points(points, margin: float = 0.25) -> np.ndarray:
    """The paper's 27 extra control points: the 3 x 3 x 3 grid (corners, edge and face centres and
    the centre) of the bounding box of ``points`` enlarged by ``margin`` times its size on every
    side, so every point lies strictly inside their convex hull. An extent under 1/1000 of the
    largest (points in one plane) is given the largest, so the grid always spans a volume."""
    p = check_points(points, "points")
    m = check_number(margin, "margin", 0.0, 1e6, low_inclusive=False)
    lo, hi = p.min(axis=0), p.max(axis=0)
    size = hi - lo
    largest = float(size.max())
    if largest == 0.0:
        largest = max(1.0, float(np.abs(p).max()))
    size = np.where(size >= 1e-3 * largest, size, largest)
    centre = (lo + hi) / 2.0
    half = size / 2.0 + m * size
    axes = [centre[i] + half[i] * np.array([-1.0, 0.0, 1.0]) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    if not np.all(np.isfinite(grid)):
        raise DeformError("the points are too far apart to enclose (coordinates near the float limit); check their units")
    return grid
