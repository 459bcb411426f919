"""The mesh: vertices, triangles, UVs and texture, with file exchange that keeps vertex order.

A user's mesh comes back as it went in: the same vertex count and order, UVs and texture kept,
so that deformed meshes and morph targets line up with the original asset in Blender, Maya or
an engine. OBJ is read and written here (trimesh splits vertices along UV seams on load, which
would renumber them); PLY, glTF and GLB are read with trimesh, whose loaders keep the stored
vertex order. Polygons are triangulated as fans; OBJ output writes the original polygons back.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from faceanim.errors import MeshError


@dataclass(eq=False)
class Mesh:
    """A triangle mesh with optional texture coordinates and texture image.

    Attributes
    ----------
    vertices : (V, 3) float64
    faces : (T, 3) int64, triangles indexing ``vertices``
    uv : (U, 2) float64 or None, texture coordinates (v up, as in OBJ and glTF's flipped v)
    face_uv : (T, 3) int64 or None, the UV index of each triangle corner (OBJ style; equal to
        ``faces`` when UVs are per vertex)
    texture : (H, W, 3 or 4) uint8 or None
    polygon_sizes : (P,) int or None, corner counts of the original polygons (fan-triangulated
        into ``faces`` in order), used to write the original polygons back to OBJ
    name : str
    """

    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None = None
    face_uv: np.ndarray | None = None
    texture: np.ndarray | None = None
    polygon_sizes: np.ndarray | None = None
    name: str = "mesh"
    source: str | None = field(default=None, repr=False)

    def __post_init__(self):
        v = np.asarray(self.vertices, dtype=np.float64)
        f = np.asarray(self.faces, dtype=np.int64)
        label = self.source or self.name
        if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] == 0:
            raise MeshError(f"mesh '{label}' has no vertices; give a mesh with at least one triangle")
        if f.ndim != 2 or f.shape[1] != 3 or f.shape[0] == 0:
            raise MeshError(f"mesh '{label}' has no triangles; give a surface mesh, not a point cloud")
        bad = ~np.all(np.isfinite(v), axis=1)
        if bad.any():
            idx = np.flatnonzero(bad)
            raise MeshError(
                f"mesh '{label}' has NaN or infinite coordinates at {idx.size} vertex(es), first at "
                f"index {idx[0]}; repair or re-export the mesh"
            )
        if f.min() < 0 or f.max() >= v.shape[0]:
            raise MeshError(f"mesh '{label}' has faces that index missing vertices (0..{v.shape[0] - 1})")
        self.vertices, self.faces = v, f
        if self.uv is not None:
            self.uv = np.asarray(self.uv, dtype=np.float64)
            if self.face_uv is None:
                if self.uv.shape[0] != v.shape[0]:
                    raise MeshError("per-vertex uv must have one row per vertex")
                self.face_uv = f
            self.face_uv = np.asarray(self.face_uv, dtype=np.int64)
            if self.face_uv.shape != f.shape or self.face_uv.min() < 0 or self.face_uv.max() >= len(self.uv):
                raise MeshError(f"mesh '{label}' has texture-coordinate indices out of range")
        else:
            self.face_uv = None

    # ------------------------------------------------------------------ derived, cached
    @property
    def n_vertices(self) -> int:
        return self.vertices.shape[0]

    @property
    def n_faces(self) -> int:
        return self.faces.shape[0]

    def __getstate__(self) -> dict:
        # a pickled mesh (e.g. a bound face sent to a batch worker) leaves its trimesh copy behind:
        # its spatial index (rtree) does not survive pickling and answers later queries wrongly
        state = self.__dict__.copy()
        state.pop("trimesh", None)
        state.pop("_query_vertices", None)  # remade on demand
        return state

    @cached_property
    def edges(self) -> np.ndarray:
        """(E, 2) unique undirected edges, smaller index first."""
        f = self.faces
        e = np.vstack([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        e.sort(axis=1)
        return np.unique(e, axis=0)

    @cached_property
    def adjacency(self) -> sp.csr_matrix:
        """(V, V) symmetric vertex adjacency over mesh edges (CSR, boolean)."""
        e = self.edges
        n = self.n_vertices
        data = np.ones(2 * len(e), dtype=bool)
        a = sp.csr_matrix((data, (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n))
        a.sort_indices()
        return a

    @cached_property
    def bounding_box_diagonal(self) -> float:
        return float(np.linalg.norm(self.vertices.max(0) - self.vertices.min(0)))

    @cached_property
    def mean_edge_length(self) -> float:
        e = self.edges
        return float(np.linalg.norm(self.vertices[e[:, 0]] - self.vertices[e[:, 1]], axis=1).mean())

    @cached_property
    def kdtree(self) -> cKDTree:
        return cKDTree(self.vertices)

    @cached_property
    def trimesh(self):
        """The geometry as a ``trimesh.Trimesh`` (same vertex order) for ray and proximity queries."""
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False, validate=False)

    def vertex_normals(self, vertices: np.ndarray | None = None) -> np.ndarray:
        """Area-weighted unit vertex normals, for the rest pose or for ``vertices``."""
        return vertex_normals(self.vertices if vertices is None else vertices, self.faces, self.face_incidence)

    @cached_property
    def face_incidence(self) -> sp.csr_matrix:
        """(V, T) sparse: 1 where vertex v is a corner of triangle t (sums over each vertex's fan)."""
        return face_incidence(self.faces, self.n_vertices)

    # ------------------------------------------------------------------ queries
    def closest_points(self, points, triangles=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest surface points: (positions (N, 3), distances (N,), triangle ids (N,)).

        ``triangles`` (indices or a boolean mask) restricts the search to part of the surface,
        e.g. the skin of a head that also holds eyeballs and teeth.

        The search runs in the mesh's :attr:`_query_frame` (edges about 1 long), by libigl's AABB
        tree (built per call: a few dozen points on a 50k-triangle skin take milliseconds, where
        trimesh's tree took a second to build). The frame matters to any search with absolute
        tolerances: trimesh's misplaced points inside millimetre triangles of a mesh in metres (up
        to 0.17 mm on the default head, a point on the surface snapped beside itself).
        """
        import igl

        centre, scale = self._query_frame
        pts = (np.atleast_2d(np.asarray(points, dtype=np.float64)) - centre) * scale
        allowed = None
        if triangles is not None:
            allowed = np.asarray(triangles)
            allowed = np.flatnonzero(allowed) if allowed.dtype == bool else allowed.astype(np.int64)
            if allowed.size == 0:
                raise MeshError(f"no triangles of '{self.name}' to search for closest points")
            if allowed.size == self.n_faces:
                allowed = None
        faces = self.faces if allowed is None else self.faces[allowed]
        d2, tri, closest = igl.point_mesh_squared_distance(np.ascontiguousarray(pts, dtype=np.float64),
                                                           self._query_vertices,
                                                           np.ascontiguousarray(faces, dtype=np.int64))
        tri = np.asarray(tri, dtype=np.int64).reshape(-1)
        dist = np.sqrt(np.maximum(np.asarray(d2, dtype=np.float64).reshape(-1), 0.0))
        closest = np.asarray(closest, dtype=np.float64).reshape(-1, 3)
        return closest / scale + centre, dist / scale, (tri if allowed is None else allowed[tri])

    @cached_property
    def _query_frame(self) -> tuple[np.ndarray, float]:
        """(centre, scale) of the frame closest-point queries run in: the bounding-box centre at the
        origin, the mean edge scaled to 1."""
        lo, hi = self.vertices.min(0), self.vertices.max(0)
        edge = self.mean_edge_length
        return (lo + hi) / 2, (1.0 / edge if np.isfinite(edge) and edge > 0 else 1.0)

    @cached_property
    def _query_vertices(self) -> np.ndarray:
        """The vertices in :attr:`_query_frame` (contiguous float64, as libigl takes them)."""
        centre, scale = self._query_frame
        return np.ascontiguousarray((self.vertices - centre) * scale, dtype=np.float64)

    @cached_property
    def vertex_triangle(self) -> np.ndarray:
        """One triangle that uses each vertex (the first in face order; -1 for a loose vertex)."""
        vt = np.full(self.n_vertices, -1, dtype=np.int64)
        vt[self.faces.ravel()[::-1]] = np.repeat(np.arange(self.n_faces), 3)[::-1]
        return vt

    @cached_property
    def vertex_components(self) -> np.ndarray:
        """Connected-component label of each vertex (shells such as eyeballs or teeth)."""
        from scipy.sparse.csgraph import connected_components

        return connected_components(self.adjacency, directed=False)[1]

    def barycentric(self, points, triangles) -> np.ndarray:
        """Barycentric coordinates of ``points`` in ``triangles`` (N, 3)."""
        import trimesh

        tri = self.vertices[self.faces[np.asarray(triangles)]]
        return trimesh.triangles.points_to_barycentric(tri, np.atleast_2d(points))

    def cast_rays(self, origins, directions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """First hit of each ray: (hit mask (N,), positions (N, 3), triangle ids (N,), -1 on a miss).
        Rays that all go one way (a front view) are cast by :meth:`cast_parallel`."""
        origins = np.atleast_2d(np.asarray(origins, dtype=np.float64))
        directions = np.atleast_2d(np.asarray(directions, dtype=np.float64))
        n = len(origins)
        if n and np.ptp(directions / np.linalg.norm(directions, axis=1, keepdims=True), axis=0).max() < 1e-12:
            return self.cast_parallel(origins, directions[0])
        locs, ray_idx, tri_idx = self.trimesh.ray.intersects_location(origins, directions, multiple_hits=True)
        hit = np.zeros(n, dtype=bool)
        pos = np.full((n, 3), np.nan)
        tri = np.full(n, -1, dtype=np.int64)
        if len(ray_idx):
            t = ((locs - origins[ray_idx]) * directions[ray_idx]).sum(1)
            order = np.lexsort((t, ray_idx))
            first = order[np.r_[True, np.diff(ray_idx[order]) != 0]]
            hit[ray_idx[first]] = True
            pos[ray_idx[first]] = locs[first]
            tri[ray_idx[first]] = tri_idx[first]
        return hit, pos, tri

    def cast_parallel(self, origins, direction, chunk: int = 100_000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`cast_rays` for rays that all go along ``direction`` (3,): in the plane across
        it each triangle covers the rays whose points lie inside it; the nearest such triangle
        ahead of a ray's origin is its first hit. Tens of times faster than a ray-triangle search
        for a front view (the triangles near the rays are found with a k-d tree of the rays)."""
        from scipy.spatial import cKDTree

        o = np.atleast_2d(np.asarray(origins, dtype=np.float64))
        d = np.asarray(direction, dtype=np.float64).reshape(3)
        d = d / np.linalg.norm(d)
        n = len(o)
        hit, pos, tri = np.zeros(n, dtype=bool), np.full((n, 3), np.nan), np.full(n, -1, dtype=np.int64)
        if not n or not len(self.faces):
            return hit, pos, tri
        side = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
        side /= np.linalg.norm(side)
        plane = np.column_stack([side, np.cross(d, side)])  # (3, 2): across the rays
        v2, vt = self.vertices @ plane, self.vertices @ d
        o2, ot = o @ plane, o @ d
        lo, hi = o2.min(axis=0), o2.max(axis=0)
        corners2 = v2[self.faces]  # (T, 3, 2)
        tmin, tmax = corners2.min(axis=1), corners2.max(axis=1)
        near = np.flatnonzero(np.all(tmax >= lo, axis=1) & np.all(tmin <= hi, axis=1)
                              & (vt[self.faces].max(axis=1) >= ot.min()))
        rays = cKDTree(o2)
        best = np.full(n, np.inf)
        for a in range(0, len(near), chunk):
            t_ids = near[a:a + chunk]
            centre = 0.5 * (tmin[t_ids] + tmax[t_ids])
            radius = 0.5 * np.linalg.norm(tmax[t_ids] - tmin[t_ids], axis=1) * (1 + 1e-9) + 1e-12
            lists = rays.query_ball_point(centre, radius, return_sorted=False)
            counts = np.fromiter((len(x) for x in lists), dtype=np.int64, count=len(lists))
            if not counts.sum():
                continue
            t_of = np.repeat(t_ids, counts)
            r_of = np.concatenate([np.asarray(x, dtype=np.int64) for x in lists if len(x)])
            c = self.faces[t_of]
            p0, e1, e2 = v2[c[:, 0]], v2[c[:, 1]] - v2[c[:, 0]], v2[c[:, 2]] - v2[c[:, 0]]
            q = o2[r_of] - p0
            den = e1[:, 0] * e2[:, 1] - e2[:, 0] * e1[:, 1]
            ok = np.abs(den) > 1e-300
            den = np.where(ok, den, 1.0)
            s = (q[:, 0] * e2[:, 1] - e2[:, 0] * q[:, 1]) / den
            t = (e1[:, 0] * q[:, 1] - q[:, 0] * e1[:, 1]) / den
            eps = 1e-9
            ok &= (s >= -eps) & (t >= -eps) & (s + t <= 1 + eps)
            depth = vt[c[:, 0]] + s * (vt[c[:, 1]] - vt[c[:, 0]]) + t * (vt[c[:, 2]] - vt[c[:, 0]]) - ot[r_of]
            ok &= depth >= 0
            t_of, r_of, depth = t_of[ok], r_of[ok], depth[ok]
            order = np.lexsort((t_of, depth, r_of))  # per ray the nearest (ties: the lower triangle id)
            first = order[np.r_[True, np.diff(r_of[order]) != 0]] if len(order) else order
            better = depth[first] < best[r_of[first]]
            r_new = r_of[first][better]
            best[r_new] = depth[first][better]
            tri[r_new] = t_of[first][better]
        hit = np.isfinite(best)
        pos[hit] = o[hit] + best[hit, None] * d
        return hit, pos, tri

    # ------------------------------------------------------------------ variants
    def with_vertices(self, vertices) -> Mesh:
        """The same mesh (faces, UVs, texture) with other vertex positions."""
        return Mesh(vertices, self.faces, self.uv, self.face_uv, self.texture, self.polygon_sizes,
                    self.name, self.source)

    def faceted(self) -> Mesh:
        """The same surface with every triangle on vertices of its own (3T vertices): its vertex
        normals are the face normals, so it renders flat-shaded (sharper creases for landmark
        detection)."""
        t = len(self.faces)
        corners = np.arange(3 * t).reshape(t, 3)
        uv = face_uv = None
        if self.uv is not None:
            uv, face_uv = self.uv[self.face_uv].reshape(-1, 2), corners
        return Mesh(self.vertices[self.faces].reshape(-1, 3), corners, uv, face_uv, self.texture,
                    name=self.name, source=self.source)

    def per_vertex_uv(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Split vertices along UV seams for formats with one UV per vertex (glTF, renderers).

        Returns ``(source_vertex (S,), faces (T, 3), uv (S, 2) or None)``. The first V entries of
        ``source_vertex`` are 0..V-1 in order (each vertex with the UV of its first corner);
        seam copies follow, so the original vertex order is kept as a prefix.
        """
        if self.uv is None:
            return np.arange(self.n_vertices), self.faces, None
        v = self.faces.ravel()
        t = self.face_uv.ravel()
        nv = self.n_vertices
        first_uv = np.full(nv, -1, dtype=np.int64)
        # first corner of each vertex decides its primary uv
        order = np.arange(v.size)[::-1]
        first_uv[v[order]] = t[order]
        primary = first_uv[v] == t
        source = [np.arange(nv)]
        uv_index = first_uv.copy()
        unused = uv_index < 0
        uv_index[unused] = 0  # vertices not used by any face keep uv 0
        new_corner = np.empty(v.size, dtype=np.int64)
        new_corner[primary] = v[primary]
        if (~primary).any():
            pairs = np.stack([v[~primary], t[~primary]], axis=1)
            uniq, inv = np.unique(pairs, axis=0, return_inverse=True)
            new_corner[~primary] = nv + inv.ravel()
            source.append(uniq[:, 0])
            uv_index = np.r_[uv_index, uniq[:, 1]]
        return np.concatenate(source), new_corner.reshape(-1, 3), self.uv[uv_index]


def face_incidence(faces: np.ndarray, n_vertices: int) -> sp.csr_matrix:
    """(V, T) sparse vertex x triangle incidence (1 per corner; a triangle that names a vertex
    twice counts it twice)."""
    faces = np.asarray(faces, dtype=np.int64)
    t = len(faces)
    m = sp.csr_matrix((np.ones(3 * t), (faces.ravel(), np.repeat(np.arange(t), 3))), shape=(n_vertices, t))
    m.sum_duplicates()
    return m


def vertex_normals(vertices: np.ndarray, faces: np.ndarray, incidence: sp.csr_matrix | None = None) -> np.ndarray:
    """Area-weighted unit vertex normals: the sum of the adjacent triangles' (unnormalised) normals,
    one sparse product with the vertex x triangle incidence (pass ``incidence`` to reuse it)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    fn = np.cross(b - a, c - a)
    if incidence is None:
        incidence = face_incidence(faces, len(vertices))
    n = np.asarray(incidence @ fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(length > 0, length, 1.0)
