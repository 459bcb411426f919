"""Geometry deformation elements (Noh, Fidaleo & Neumann 2000, section 2).

A GDE is a control point on or near the surface, the influence region around it found by a
breadth-first search over mesh edges from the control point's nearest vertex, stationary
anchors on the region's boundary, and one RBF system (control point + anchors as centres) that
moves the vertices inside the region. Following the paper's algorithm summary:

1. a control point anywhere on or near the surface (2D picks are ray-cast onto it first);
2. its nearest vertex is the root of the search;
3. BFS over mesh edges collects the vertices within ``extent``: at most ``extent`` edges away
   (``metric='edges'``) or within Euclidean distance ``extent`` of the control point and
   connected to the root through such vertices (``metric='euclidean'``);
4. the leaves of the search (region vertices with a neighbour outside the region) are the
   anchors; at most ``max_anchors`` (20) of them, sampled evenly by angle around the control
   point, become RBF centres together with the control point.

We interpolate *displacements* (control point: its offset, anchors: zero), so a zero offset
reproduces the rest mesh exactly. Every boundary vertex stays fixed, not only the sampled
anchors, so the region's edge never moves; vertices outside every region are untouched
(bit-identical).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

from faceanim.deform.base import LinearDeformer
from faceanim.deform.rbf import (
    DEFAULT_SMOOTHING,
    KERNELS,
    RadialBasis,
    _describe,
    check_number,
    check_points,
)
from faceanim.errors import DeformError

METRICS = ("edges", "euclidean")
MAX_ANCHORS = 20
MAX_ANCHORS_LIMIT = 1000  # anchors of one element are RBF centres: a dense system of this size
MAX_EDGE_EXTENT = 100_000  # edges from the control point (more than any mesh's diameter)
MAX_SMOOTHING = 1e6
# a control point farther from the surface than this fraction of the mesh's bounding-box
# diagonal is taken for a mistake (the paper allows points "on or near" the surface)
MAX_SURFACE_DISTANCE = 0.05


@dataclass(frozen=True)
class GeometryDeformationElement:
    """A GDE specification: where it sits and how far it reaches.

    Parameters
    ----------
    control : (3,) point on or near the surface
    extent : int edges for ``metric='edges'``, distance in mesh units for ``'euclidean'``
    metric : 'edges' or 'euclidean'
    kernel, smoothing, stiffness : the RBF system (paper: multiquadric, lambda 0.01, eq. 3)
    max_anchors : anchors used as RBF centres (paper: 20)
    name : label used in reports and as the handle name
    """

    control: tuple
    extent: float = 4
    metric: str = "edges"
    kernel: str = "multiquadric"
    smoothing: float = DEFAULT_SMOOTHING
    stiffness: float | None = None
    max_anchors: int = MAX_ANCHORS
    name: str = ""

    @classmethod
    def from_dict(cls, d: dict, index: int = 0) -> GeometryDeformationElement:
        """An element from a JSON object; every field is checked (types, ranges, unknown keys)."""
        if not isinstance(d, dict) or "control" not in d:
            raise DeformError(f"element {index} needs a 'control' point [x, y, z]")
        known = {"control", "offset", "extent", "metric", "kernel", "smoothing", "stiffness",
                 "max_anchors", "name"}
        unknown = [k for k in d if k not in known]
        if unknown:
            shown = ", ".join(_show_key(k) for k in sorted(map(str, unknown))[:5])
            raise DeformError(f"element {index} has unknown key(s): {shown}{' ...' if len(unknown) > 5 else ''} "
                              f"(known: {', '.join(sorted(known))})")
        c = check_points(d["control"], f"element {index} control")
        if len(c) != 1:
            raise DeformError(f"element {index} control must be one point [x, y, z], got {len(c)}")
        metric = d.get("metric", "edges")
        if not isinstance(metric, str) or metric not in METRICS:
            raise DeformError(f"element {index}: unknown metric {_show_key(metric)}; choose one of: "
                              f"{', '.join(METRICS)}")
        kernel = d.get("kernel", "multiquadric")
        if not isinstance(kernel, str) or kernel not in KERNELS:
            raise DeformError(f"element {index}: unknown kernel {_show_key(kernel)}; choose one of: "
                              f"{', '.join(KERNELS)}")
        if metric == "edges":
            extent = check_number(d.get("extent", 4), f"element {index} extent (edges)", 0, MAX_EDGE_EXTENT,
                                  integer=True)
        else:
            extent = check_number(d.get("extent", 4), f"element {index} extent", 0)
        smoothing = check_number(d.get("smoothing", DEFAULT_SMOOTHING), f"element {index} smoothing", 0.0,
                                 MAX_SMOOTHING)
        stiffness = d.get("stiffness")
        if stiffness is not None:
            stiffness = check_number(stiffness, f"element {index} stiffness", 0.0, low_inclusive=False)
        max_anchors = check_number(d.get("max_anchors", MAX_ANCHORS), f"element {index} max_anchors", 1,
                                   MAX_ANCHORS_LIMIT, integer=True)
        name = d.get("name", f"gde{index}")
        if not isinstance(name, str):
            raise DeformError(f"element {index} name must be text, got {_describe(name)}")
        return cls(tuple(c[0]), extent, metric, kernel, smoothing, stiffness, max_anchors, name[:200])


def _show_key(key) -> str:
    """A key or name from a file, quoted for an error message (shortened, control characters escaped)."""
    if not isinstance(key, str):
        return _describe(key)
    text = key[:40].encode("unicode_escape").decode("ascii")
    return f"'{text}'" + ("..." if len(key) > 40 else "")


@dataclass
class ElementInfluence:
    """Where one GDE acts on a mesh: its influence region, anchors and the weight of the control
    offset on each moving vertex (:meth:`deformer` turns it into a bound operator)."""

    element: GeometryDeformationElement
    root: int                 # nearest vertex to the control point (BFS root)
    region: np.ndarray        # all vertices of the influence region
    boundary: np.ndarray      # region vertices with a neighbour outside (fixed)
    anchors: np.ndarray       # boundary vertices used as RBF centres (<= max_anchors)
    moving: np.ndarray        # region minus boundary: the vertices that move
    weights: np.ndarray       # (len(moving),) displacement per unit control offset

    def deformer(self, rest: np.ndarray) -> LinearDeformer:
        """This element alone as a bound operator with one handle (its control offset)."""
        w = sp.csr_matrix(self.weights.astype(rest.dtype)[:, None])
        return LinearDeformer(rest, w, self.moving, [self.element.name or "gde"])


def influence_region(mesh, root: int, control: np.ndarray, extent: float,
                     metric: str) -> tuple[np.ndarray, np.ndarray]:
    """Breadth-first search from ``root`` over mesh edges; returns (region, boundary vertices).

    ``edges``: every vertex at most ``extent`` edges from the root. ``euclidean``: every vertex
    the search reaches through vertices within distance ``extent`` of the control point, i.e.
    the root's connected component in the graph of that ball (found in one step from the
    k-d tree's ball query, which is faster than walking the search level by level).
    The boundary (the search tree's leaves) is the region's vertices with a neighbour outside.
    """
    if metric not in METRICS:
        raise DeformError(f"unknown metric '{metric}'; choose one of: {', '.join(METRICS)}")
    adjacency = mesh.adjacency
    degree = np.diff(adjacency.indptr)
    if metric == "euclidean":
        ball = np.asarray(mesh.kdtree.query_ball_point(control, float(extent)), dtype=np.int64)
        ball = np.union1d(ball, [root])
        sub = adjacency[ball][:, ball]
        _, label = csgraph.connected_components(sub, directed=False)
        keep = label == label[np.searchsorted(ball, root)]
        region = ball[keep]
        # a region vertex's neighbours inside the ball are in its component, so its degree in
        # the ball graph counts exactly its neighbours inside the region
        return region, region[np.diff(sub.indptr)[keep] < degree[region]]

    n = adjacency.shape[0]
    indptr, indices = adjacency.indptr, adjacency.indices
    seen = np.zeros(n, dtype=bool)
    seen[root] = True
    stamp = np.empty(n, dtype=np.int64)
    frontier = np.array([root])
    for _ in range(int(extent)):
        starts, stops = indptr[frontier], indptr[frontier + 1]
        counts = stops - starts
        idx = np.repeat(starts - np.r_[0, np.cumsum(counts)[:-1]], counts) + np.arange(counts.sum())
        nb = indices[idx]
        nb = nb[~seen[nb]]
        # drop repeats without sorting: keep the occurrence whose position the stamp kept
        stamp[nb] = np.arange(nb.size)
        nb = nb[stamp[nb] == np.arange(nb.size)]
        if not nb.size:
            break
        seen[nb] = True
        frontier = nb
    region = np.flatnonzero(seen)
    sub = adjacency[region]
    inside = sub.astype(np.int32) @ seen.astype(np.int32)
    return region, region[inside < degree[region]]


def sample_anchors(vertices: np.ndarray, boundary: np.ndarray, region: np.ndarray, control: np.ndarray,
                   count: int) -> np.ndarray:
    """At most ``count`` boundary vertices, evenly spaced by angle around the control point."""
    if boundary.size <= count:
        return boundary
    pts = vertices[region] - vertices[region].mean(0)
    # tangent plane of the region: its two main directions
    _, _, vt = np.linalg.svd(pts, full_matrices=False)
    rel = vertices[boundary] - control
    angle = np.arctan2(rel @ vt[1], rel @ vt[0])
    order = boundary[np.argsort(angle, kind="stable")]
    pick = np.floor(np.arange(count) * (order.size / count)).astype(int)
    return order[pick]


def element_influence(mesh, element: GeometryDeformationElement) -> ElementInfluence:
    """One GDE's influence on ``mesh``: the region found by BFS, the anchors and the RBF solve."""
    e = element
    if e.metric not in METRICS:
        raise DeformError(f"unknown metric '{e.metric}'; choose one of: {', '.join(METRICS)}")
    if e.kernel not in KERNELS:
        raise DeformError(f"unknown kernel '{e.kernel}'; choose one of: {', '.join(KERNELS)}")
    try:
        extent = float(e.extent)
    except (TypeError, ValueError):
        raise DeformError(f"GDE '{e.name}': extent must be a number, got {e.extent!r}") from None
    if not np.isfinite(extent) or extent < 0:
        raise DeformError(f"GDE '{e.name}': extent must be >= 0, got {e.extent}")
    if e.metric == "edges" and extent != int(extent):
        raise DeformError(f"GDE '{e.name}': the edges metric needs a whole number of edges, got {e.extent}")
    max_anchors = check_number(e.max_anchors, f"GDE '{e.name}': max_anchors", 1, MAX_ANCHORS_LIMIT, integer=True)
    control = check_points(e.control, f"GDE '{e.name}' control")[0]
    dist, root = mesh.kdtree.query(control)
    limit = MAX_SURFACE_DISTANCE * mesh.bounding_box_diagonal
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    box = float(np.linalg.norm(np.maximum(np.maximum(lo - control, control - hi), 0.0)))
    if box > limit:  # far outside the mesh's box: refused before the closest-point search
        raise DeformError(
            f"GDE '{e.name}': control point {np.round(control, 6).tolist()} is {box:.4g} or more from the "
            f"surface (more than {limit:.4g}); put control points on or near the mesh"
        )
    if dist > limit:
        _, sdist, _ = mesh.closest_points(control[None])
        if sdist[0] > limit:
            raise DeformError(
                f"GDE '{e.name}': control point {np.round(control, 6).tolist()} is {sdist[0]:.4g} from the "
                f"surface (more than {limit:.4g}); put control points on or near the mesh"
            )
    root = int(root)
    region, boundary = influence_region(mesh, root, control, extent, e.metric)
    boundary = boundary[boundary != root]
    if region.size == 1 or boundary.size == 0:
        # no anchors: the element reduces to moving its vertices rigidly (vertex manipulation)
        moving = region
        return ElementInfluence(e, root, region, boundary, boundary, moving, np.ones(moving.size))
    anchors = sample_anchors(mesh.vertices, boundary, region, control, max_anchors)
    moving = np.setdiff1d(region, boundary, assume_unique=True)
    centres = np.vstack([control, mesh.vertices[anchors]])
    system = RadialBasis(centres, e.kernel, e.smoothing, e.stiffness)
    with np.errstate(over="ignore", invalid="ignore"):
        w = system.weights(mesh.vertices[moving], column=0)
    if not np.all(np.isfinite(w)):
        raise DeformError(f"GDE '{e.name}': the RBF solve gave non-finite weights; use smoothing > 0 or "
                          "another extent")
    return ElementInfluence(e, root, region, boundary, anchors, moving, w)


def bind_gdes(mesh, elements, dtype=np.float64) -> LinearDeformer:
    """Bind several GDEs into one sparse deformer with one handle (the control offset) each.

    Where influence regions overlap, displacements add.
    """
    elements = list(elements)
    if not elements:
        raise DeformError("give at least one geometry deformation element")
    rest = np.asarray(mesh.vertices, dtype=dtype)
    return LinearDeformer.stack([element_influence(mesh, e).deformer(rest) for e in elements])
