"""Dirichlet FFD: Sibson coordinates against independent oracles (qhull's halfspace intersection,
Monte-Carlo volumes, the Delaunay cavity, a symmetric case solved by hand), their defining
properties, the bound deformer, the paper's 27 enclosing points, and bad input."""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial import ConvexHull, Delaunay, HalfspaceIntersection, cKDTree

from faceanim.deform.base import LinearDeformer
from faceanim.deform.ffd import (
    DirichletFFD,
    dirichlet_ffd,
    enclosing_points,
    sibson_coordinates,
)
from faceanim.errors import DeformError


# ---------------------------------------------------------------------------------- oracles
def _cell(points, i, lo, hi, interior):
    """Halfspaces of the Voronoi cell of points[i] among ``points``, clipped to the box [lo, hi]."""
    p, others = points[i], np.delete(points, i, axis=0)
    # |y - p| <= |y - o|  <=>  (o - p) . y - (|o|^2 - |p|^2) / 2 <= 0
    hs = [np.hstack([others - p, -((others**2).sum(1) - p @ p)[:, None] / 2])]
    for d in range(3):
        e = np.eye(3)[d]
        hs.append([np.r_[e, -hi[d]], np.r_[-e, lo[d]]])
    return ConvexHull(HalfspaceIntersection(np.vstack(hs), interior).intersections).volume


def oracle(sites, x):
    """Sibson coordinates by qhull: (volume of each site's old cell - its cell once x is inserted)
    / volume of x's cell, every cell clipped to a box holding x's (bounded) cell."""
    new_cell = HalfspaceIntersection(np.hstack([sites - x, -((sites**2).sum(1) - x @ x)[:, None] / 2]), x)
    corners = np.vstack([new_cell.intersections, sites])
    lo, hi = corners.min(0) - 1, corners.max(0) + 1
    both = np.vstack([sites, x])
    total = ConvexHull(new_cell.intersections).volume
    lam = np.array([_cell(sites, k, lo, hi, sites[k]) - _cell(both, k, lo, hi, sites[k]) for k in range(len(sites))])
    return lam / total, new_cell.intersections


def cavity_vertices(sites, x):
    """Natural neighbours of x, independently: the vertices of the Delaunay tetrahedra whose
    circumsphere holds x (circumcentres solved with numpy)."""
    tri = Delaunay(sites)
    v = sites[tri.simplices]
    a = 2 * (v[:, 1:] - v[:, :1])
    b = (v[:, 1:] ** 2).sum(-1) - (v[:, :1] ** 2).sum(-1)
    c = np.linalg.solve(a, b[..., None])[..., 0]
    r2 = ((v[:, 0] - c) ** 2).sum(-1)
    inside = ((x - c) ** 2).sum(-1) < r2
    return set(tri.simplices[inside].ravel().tolist())


def inside_hull(sites, pts, margin):
    hull = ConvexHull(sites)
    return pts[(pts @ hull.equations[:, :3].T + hull.equations[:, 3]).max(axis=1) < -margin]


def cloud(rng, n=40):
    return rng.normal(size=(n, 3))


# ---------------------------------------------------------------------------------- properties
def test_rows_are_nonnegative_partitions_of_unity_that_reproduce_linear_functions(rng):
    sites = cloud(rng, 80)
    q = inside_hull(sites, rng.normal(size=(3000, 3)), 1e-3)
    w = sibson_coordinates(sites, q)
    assert sp.isspmatrix_csr(w) and w.shape == (len(q), len(sites))
    assert w.data.min() >= 0.0
    np.testing.assert_allclose(np.asarray(w.sum(axis=1)).ravel(), 1.0, rtol=0, atol=1e-14)
    err = np.abs(w @ sites - q).max(axis=1)
    assert err.max() <= 1e-12  # near the hull x's cell is large and its volume cancels more
    deep = np.isin(np.arange(len(q)), np.flatnonzero(np.all(q @ ConvexHull(sites).equations[:, :3].T
                                                               + ConvexHull(sites).equations[:, 3] < -0.1, axis=1)))
    assert err[deep].max() <= 1e-14
    # linear functions, not only the coordinates themselves
    A, t = rng.normal(size=(3, 3)), rng.normal(size=3)
    np.testing.assert_allclose(w @ (sites @ A.T + t), q @ A.T + t, rtol=0, atol=1e-12)
    assert 8 < w.nnz / len(q) < 30  # local: a dozen or so natural neighbours each


def test_interpolates_at_the_sites_with_unit_rows(rng):
    sites = cloud(rng, 30)
    w = sibson_coordinates(sites, sites[::-1])
    assert np.array_equal(w.toarray(), np.eye(30)[::-1])


def test_near_a_site_the_coordinates_tend_to_its_unit_row(rng):
    sites = cloud(rng, 40)
    k = int(np.argmin(np.linalg.norm(sites, axis=1)))
    for d in (1e-3, 1e-6, 1e-9):
        x = sites[k] + d * np.array([0.6, 0.0, 0.8])
        w = sibson_coordinates(sites, x[None]).toarray()[0]
        assert 1 - w[k] <= 50 * d
        assert np.abs(w @ sites - x).max() <= 1e-15


def test_matches_qhull_halfspace_volumes(rng):
    sites = cloud(rng, 30)
    q = inside_hull(sites, 0.6 * rng.normal(size=(12, 3)), 1e-2)[:6]
    w = sibson_coordinates(sites, q).toarray()
    for x, row in zip(q, w):
        ref, _ = oracle(sites, x)
        np.testing.assert_allclose(row, ref, rtol=0, atol=1e-12)


def test_only_natural_neighbours_are_nonzero(rng):
    sites = cloud(rng, 50)
    q = inside_hull(sites, 0.7 * rng.normal(size=(200, 3)), 1e-3)
    w = sibson_coordinates(sites, q)
    for i, x in enumerate(q):
        assert set(w.indices[w.indptr[i]:w.indptr[i + 1]].tolist()) == cavity_vertices(sites, x)


def test_monte_carlo_estimate_of_the_stolen_volumes(rng):
    """Sample x's new cell uniformly (rejection from its bounding box: keep points nearer to x
    than to every site), give each sample to its nearest old site: the shares are the
    coordinates, to within the Monte-Carlo error."""
    sites = cloud(rng, 25)
    q = inside_hull(sites, 0.5 * rng.normal(size=(10, 3)), 1e-2)[:3]
    w = sibson_coordinates(sites, q).toarray()
    tree = cKDTree(sites)
    mc = np.random.default_rng(7)
    for x, row in zip(q, w):
        corners = HalfspaceIntersection(np.hstack([sites - x, -((sites**2).sum(1) - x @ x)[:, None] / 2]),
                                        x).intersections
        y = mc.uniform(corners.min(0), corners.max(0), size=(400_000, 3))
        d_old, owner = tree.query(y)
        kept = np.linalg.norm(y - x, axis=1) < d_old
        n = kept.sum()
        assert n > 50_000
        share = np.bincount(owner[kept], minlength=len(sites)) / n
        sigma = np.sqrt(np.maximum(row * (1 - row), 1e-6) / n)
        assert np.all(np.abs(share - row) <= 5 * sigma), np.abs(share - row).max()


def test_symmetric_case_solved_by_hand():
    """Sites: the cube (+-1, +-1, +-1) and the octahedron (+-2, 0, 0)...; x at the centre. x's cell
    is |y_i| <= 1 cut by |y_1| + |y_2| + |y_3| <= 3/2: volume 8 - 8 * 1/2 = 4. The octahedron
    vertex (2, 0, 0) was nearest where y_1 >= 1/2 + |y_2| + |y_3| (and y_1 <= 1): with
    s = |y_2| + |y_3| (area element 4 s ds), its share is int_0^1/2 (1/2 - s) 4 s ds = 1/12, so
    lambda = 1/48 for each octahedron vertex and (1 - 6/48) / 8 = 7/64 for each cube vertex.
    The 14 sites are highly degenerate (the cube's 8 and each square + apex are cospherical)."""
    cube = np.array(np.meshgrid([-1.0, 1], [-1.0, 1], [-1.0, 1])).reshape(3, -1).T
    sites = np.vstack([cube, 2 * np.eye(3), -2 * np.eye(3)])
    w = sibson_coordinates(sites, np.zeros((1, 3))).toarray()[0]
    np.testing.assert_allclose(w[:8], 7 / 64, rtol=0, atol=1e-15)
    np.testing.assert_allclose(w[8:], 1 / 48, rtol=0, atol=1e-15)


@pytest.mark.parametrize("jitter", [0.0, 1e-11])
def test_grid_of_sites_flat_tetrahedra_and_ties(rng, jitter):
    """A 4 x 4 x 4 grid (cospherical cubes: qhull emits flat tetrahedra) with queries on its planes
    and lines and at cell centres (on circumspheres: ties), and the same grid jittered."""
    g = np.array(np.meshgrid(*[np.arange(4.0)] * 3, indexing="ij")).reshape(3, -1).T
    sites = g + jitter * rng.normal(size=g.shape)
    q = rng.uniform(0.1, 2.9, size=(300, 3))
    q[:100, 0] = 1.0
    q[50:100, 1] = 2.0
    q[100:120] = np.floor(q[100:120]) + 0.5
    w = sibson_coordinates(sites, q)
    assert w.data.min() >= 0.0
    np.testing.assert_allclose(np.asarray(w.sum(axis=1)).ravel(), 1.0, rtol=0, atol=1e-14)
    assert np.abs(w @ sites - q).max() <= 1e-14
    dense = w.toarray()
    for i in (0, 60, 110, 200):
        np.testing.assert_allclose(dense[i], oracle(sites, q[i])[0], rtol=0, atol=1e-9)
    if jitter == 0.0:
        centre = sibson_coordinates(sites, np.full((1, 3), 1.5)).toarray()[0]
        corners = np.all(np.isin(sites, [1.0, 2.0]), axis=1)
        np.testing.assert_allclose(centre[corners], 1 / 8, rtol=0, atol=1e-15)  # the cell's 8 corners, by symmetry
        assert np.abs(centre[~corners]).max() == 0.0


def test_ties_on_lattices_with_rounding(rng):
    """Lattice points at a spacing that is not exact in binary, queried at half-lattice points:
    many queries lie exactly on circumspheres (and on circles shared by two tetrahedra), where
    the in-sphere test must call the tie outside however rounding falls, else the query's cell
    gets a vertex at infinity."""
    for _ in range(6):
        pts = np.unique(rng.integers(0, 4, size=(40, 3)), axis=0) * 0.3 + 0.1
        q = inside_hull(pts, rng.integers(0, 7, size=(300, 3)) * 0.15 + 0.1, 1e-6)
        q = q[cKDTree(pts).query(q)[0] > 0]
        w = sibson_coordinates(pts, q)
        assert w.data.min() >= 0.0
        np.testing.assert_allclose(np.asarray(w.sum(axis=1)).ravel(), 1.0, rtol=0, atol=1e-14)
        assert np.abs(w @ pts - q).max() <= 1e-14
    np.testing.assert_allclose(w[:3].toarray(), [oracle(pts, x)[0] for x in q[:3]], rtol=0, atol=1e-12)


# ---------------------------------------------------------------------------------- deformer
def test_dirichlet_ffd_moves_vertices_with_an_affine_motion_of_the_sites(rng):
    verts = rng.uniform(-1, 1, size=(2000, 3)) * [1.0, 1.3, 0.8]
    sites = np.vstack([verts[rng.choice(len(verts), 60, replace=False)], enclosing_points(verts)])
    names = [f"p{i}" for i in range(len(sites))]
    d = dirichlet_ffd(sites, verts, names)
    assert isinstance(d, LinearDeformer) and d.is_sparse and sp.isspmatrix_csr(d.weights)
    assert d.weights.shape == (len(verts), len(sites)) and d.handle_names == names
    A = np.eye(3) + 0.3 * rng.normal(size=(3, 3))
    t = rng.normal(size=3)
    offsets = sites @ A.T + t - sites
    np.testing.assert_allclose(d.apply(offsets), verts @ A.T + t, rtol=0, atol=1e-13)
    frames = np.stack([offsets, 2 * offsets, np.zeros_like(offsets)])
    out = d.apply(frames)
    np.testing.assert_allclose(out[1], verts + 2 * (verts @ A.T + t - verts), rtol=0, atol=1e-13)
    assert np.array_equal(out[2], verts)
    # a vertex at a control point follows it exactly; the class gives the same operator
    ffd = DirichletFFD(sites)
    moved = ffd(sites[:5], offsets)
    np.testing.assert_array_equal(moved, sites[:5] + offsets[:5])
    assert (ffd.deformer(verts).weights != d.weights).nnz == 0


def test_enclosing_points_are_the_papers_27_around_the_bounding_box(rng):
    pts = rng.normal(size=(500, 3)) * [3.0, 1.0, 0.5] + [10.0, -2.0, 0.0]
    g = enclosing_points(pts, margin=0.25)
    assert g.shape == (27, 3)
    lo, hi = pts.min(0), pts.max(0)
    size = hi - lo
    for axis in range(3):
        np.testing.assert_allclose(np.unique(g[:, axis]), [lo[axis] - 0.25 * size[axis],
                                                           (lo[axis] + hi[axis]) / 2,
                                                           hi[axis] + 0.25 * size[axis]])
    assert len(np.unique(g, axis=0)) == 27
    hull = ConvexHull(g)
    assert (pts @ hull.equations[:, :3].T + hull.equations[:, 3]).max() < -0.2 * size.min()
    # the points alone are not enclosed by their own feature points; with the 27 they bind
    flat = np.c_[rng.normal(size=(50, 2)), np.zeros(50)]
    assert np.ptp(enclosing_points(flat), axis=0).min() > 0  # a flat set still gets a volume
    w = sibson_coordinates(np.vstack([pts[:20], g]), pts)
    assert np.abs(w @ np.vstack([pts[:20], g]) - pts).max() < 1e-12


# ---------------------------------------------------------------------------------- bad input
def _one_line(exc):
    msg = str(exc.value)
    assert msg and "\n" not in msg
    return msg


@pytest.mark.parametrize("sites, words", [
    (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]), "at least 5"),
    (np.r_[np.eye(3), [[0, 0, 0], [np.nan, 1, 1]]], "NaN or infinite"),
    (np.r_[np.eye(3), [[0, 0, 0], [np.inf, 1, 1]]], "NaN or infinite"),
    (np.c_[np.random.default_rng(0).normal(size=(20, 2)), np.zeros(20)], "one plane"),
    (np.c_[np.arange(10.0), 2 * np.arange(10.0), np.arange(10.0)], "one plane"),
    (np.r_[np.eye(3), [[0, 0, 0], [1, 1, 1], [1, 0, 0]]], "coincide"),
    (np.zeros((6, 3)), "one place"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], "x"], "numbers"),
    (np.ones((6, 2)), "shape"),
])
def test_degenerate_sites_are_refused_in_one_line(sites, words):
    with pytest.raises(DeformError) as exc:
        DirichletFFD(sites)
    assert words in _one_line(exc)


def test_queries_outside_the_hull_are_counted(rng):
    sites = cloud(rng, 30)
    q = np.r_[np.zeros((3, 3)), [[50.0, 0, 0], [0, -40, 0]]]
    with pytest.raises(DeformError) as exc:
        sibson_coordinates(sites, q)
    msg = _one_line(exc)
    assert "2 of 5 points" in msg and "point 3" in msg and "enclosing_points" in msg
    # on the hull is not strictly inside either
    hull = ConvexHull(sites)
    on = sites[hull.simplices[0]].mean(axis=0)
    with pytest.raises(DeformError, match="1 of 1 points"):
        sibson_coordinates(sites, on[None])


def test_other_bad_arguments(rng):
    sites = cloud(rng, 20)
    ffd = DirichletFFD(sites)
    with pytest.raises(DeformError, match="NaN"):
        ffd.coordinates([[0.0, np.nan, 0.0]])
    with pytest.raises(DeformError, match="one name per control point"):
        ffd.deformer(np.zeros((2, 3)), names=["a", "b"])
    with pytest.raises(DeformError, match="text names"):
        ffd.deformer(np.zeros((2, 3)), names=list(range(20)))
    with pytest.raises(DeformError, match="offsets must have shape"):
        ffd(np.zeros((1, 3)), np.zeros((3, 3)))
    for margin in (0, -1, np.nan, "1"):
        with pytest.raises(DeformError, match="margin"):
            enclosing_points(sites, margin=margin)
    assert sibson_coordinates(sites, np.zeros((0, 3))).shape == (0, 20)
