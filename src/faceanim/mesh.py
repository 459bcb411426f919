"""The mesh: vertices, triangles, UVs and texture, with file exchange that keeps vertex order.

A user's mesh comes back as it went in: the same vertex count and order, UVs and texture kept,
so that deformed meshes and morph targets line up with the original asset in Blender, Maya or
an engine. OBJ is read and written here (trimesh splits vertices along UV seams on load, which
would renumber them); PLY, glTF and GLB are read with trimesh, whose loaders keep the stored
vertex order. Polygons are triangulated as fans; OBJ output writes the original polygons back.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from .errors import MeshError
from .fileio import atomic_output

MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf")


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
        return vertex_normals(self.vertices if vertices is None else vertices, self.faces)

    # ------------------------------------------------------------------ queries
    def closest_points(self, points, triangles=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Closest surface points: (positions (N, 3), distances (N,), triangle ids (N,)).

        ``triangles`` (indices or a boolean mask) restricts the search to part of the surface,
        e.g. the skin of a head that also holds eyeballs and teeth.
        """
        import trimesh

        pts = np.atleast_2d(np.asarray(points, dtype=np.float64))
        if triangles is None:
            closest, dist, tri = trimesh.proximity.closest_point(self.trimesh, pts)
            return closest, dist, tri
        allowed = np.asarray(triangles)
        allowed = np.flatnonzero(allowed) if allowed.dtype == bool else allowed.astype(np.int64)
        if allowed.size == 0:
            raise MeshError(f"no triangles of '{self.name}' to search for closest points")
        if allowed.size == self.n_faces:
            closest, dist, tri = trimesh.proximity.closest_point(self.trimesh, pts)
            return closest, dist, tri
        # the part's search tree is kept: a rig asks about the same part (the skin) many times
        key = hashlib.sha1(allowed.tobytes()).hexdigest()
        part = self._parts.get(key)
        if part is None:
            part = self._parts[key] = trimesh.Trimesh(self.vertices, self.faces[allowed], process=False,
                                                      validate=False)
        closest, dist, tri = trimesh.proximity.closest_point(part, pts)
        return closest, dist, allowed[np.asarray(tri)]

    @cached_property
    def _parts(self) -> dict:
        return {}

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
        """First hit of each ray: (hit mask (N,), positions (N, 3), triangle ids (N,), -1 on a miss)."""
        origins = np.atleast_2d(np.asarray(origins, dtype=np.float64))
        directions = np.atleast_2d(np.asarray(directions, dtype=np.float64))
        n = len(origins)
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

    # ------------------------------------------------------------------ variants
    def with_vertices(self, vertices) -> Mesh:
        """The same mesh (faces, UVs, texture) with other vertex positions."""
        return Mesh(vertices, self.faces, self.uv, self.face_uv, self.texture, self.polygon_sizes,
                    self.name, self.source)

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


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals."""
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    fn = np.cross(b - a, c - a)
    n = np.zeros_like(vertices)
    for i in range(3):
        np.add.at(n, faces[:, i], fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(length > 0, length, 1.0)


# ====================================================================== reading
def load_mesh(path: str | os.PathLike) -> Mesh:
    """Read an OBJ, PLY, glTF or GLB file into a :class:`Mesh`, keeping the stored vertex order."""
    path = Path(path)
    if not path.is_file():
        raise MeshError(f"mesh file '{path}' does not exist; check the path")
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise MeshError(f"cannot read '{path}': unsupported format '{suffix}' (use {', '.join(MESH_SUFFIXES)})")
    try:
        if suffix == ".obj":
            return _load_obj(path)
        return _load_with_trimesh(path)
    except MeshError:
        raise
    except (OSError, ValueError, IndexError, KeyError, TypeError, UnicodeDecodeError) as exc:
        raise MeshError(f"cannot read mesh '{path}': {exc}") from None


def _load_obj(path: Path) -> Mesh:
    verts, uvs = [], []
    corner_v, corner_t, sizes = [], [], []
    mtllib = None
    material = None
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line_no, line in enumerate(fh, 1):
            if not line or line[0] == "#":
                continue
            parts = line.split()
            if not parts:
                continue
            key = parts[0]
            if key == "v":
                verts.append(parts[1:4])
            elif key == "vt":
                uvs.append(parts[1:3])
            elif key == "f":
                if len(parts) < 4:
                    raise MeshError(f"'{path}' line {line_no}: a face needs at least 3 corners")
                for p in parts[1:]:
                    idx = p.split("/")
                    corner_v.append(idx[0])
                    corner_t.append(idx[1] if len(idx) > 1 and idx[1] else "")
                sizes.append(len(parts) - 1)
            elif key == "mtllib" and mtllib is None:
                mtllib = line.split(None, 1)[1].strip()
            elif key == "usemtl" and material is None:
                material = line.split(None, 1)[1].strip()
    try:
        v = np.array(verts, dtype=np.float64).reshape(-1, 3)
    except ValueError:
        raise MeshError(f"'{path}' has a malformed vertex line ('v x y z' expected)") from None
    if len(v) == 0 or not sizes:
        raise MeshError(f"mesh '{path}' is empty (no vertices or no faces); give a surface mesh")
    cv = np.array(corner_v, dtype=np.int64)
    cv = np.where(cv < 0, len(v) + cv, cv - 1)
    has_uv = uvs and all(corner_t)
    sizes = np.array(sizes, dtype=np.int64)
    faces = _fan(cv, sizes)
    uv = face_uv = None
    if has_uv:
        uv = np.array(uvs, dtype=np.float64).reshape(-1, 2)
        ct = np.array(corner_t, dtype=np.int64)
        ct = np.where(ct < 0, len(uv) + ct, ct - 1)
        face_uv = _fan(ct, sizes)
    texture = _read_mtl_texture(path.parent / mtllib, material) if (mtllib and has_uv) else None
    return Mesh(v, faces, uv, face_uv, texture, sizes if (sizes != 3).any() else None,
                name=path.stem, source=str(path))


def _fan(corners: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """Fan-triangulate polygons given as flat corner lists."""
    starts = np.r_[0, np.cumsum(sizes)[:-1]]
    ntri = sizes - 2
    poly = np.repeat(np.arange(len(sizes)), ntri)
    k = np.arange(ntri.sum()) - np.repeat(np.cumsum(ntri) - ntri, ntri)
    s = starts[poly]
    return np.stack([corners[s], corners[s + k + 1], corners[s + k + 2]], axis=1)


def _read_mtl_texture(mtl: Path, material: str | None) -> np.ndarray | None:
    if not mtl.is_file():
        return None
    current, maps = None, {}
    with open(mtl, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            parts = line.split(None, 1)
            if not parts:
                continue
            if parts[0] == "newmtl":
                current = parts[1].strip()
            elif parts[0] == "map_Kd" and len(parts) > 1:
                maps.setdefault(current, parts[1].strip().split()[-1])
    name = maps.get(material) or next(iter(maps.values()), None)
    if name is None:
        return None
    image = mtl.parent / name
    if not image.is_file():
        return None
    return _read_image(image)


def _read_image(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        im = im.convert("RGBA" if im.mode in ("RGBA", "LA", "P") else "RGB")
        return np.asarray(im).copy()


def _load_with_trimesh(path: Path) -> Mesh:
    import trimesh

    loaded = trimesh.load(str(path), process=False, maintain_order=True)
    if isinstance(loaded, trimesh.Scene):
        geoms = [g for g in loaded.dump(concatenate=False) if isinstance(g, trimesh.Trimesh)]
        if not geoms:
            raise MeshError(f"mesh '{path}' contains no triangle mesh")
        m = geoms[0] if len(geoms) == 1 else trimesh.util.concatenate(geoms)
    else:
        m = loaded
    if not isinstance(m, trimesh.Trimesh) or len(m.faces) == 0:
        raise MeshError(f"mesh '{path}' is empty (no triangles); give a surface mesh, not a point cloud")
    uv = texture = None
    visual = getattr(m, "visual", None)
    if visual is not None and getattr(visual, "kind", None) == "texture" and visual.uv is not None \
            and len(visual.uv) == len(m.vertices):
        uv = np.asarray(visual.uv, dtype=np.float64)
        mat = getattr(visual, "material", None)
        img = getattr(mat, "baseColorTexture", None) or getattr(mat, "image", None)
        if img is not None:
            texture = np.asarray(img.convert("RGBA" if img.mode in ("RGBA", "LA", "P") else "RGB")).copy()
    return Mesh(np.asarray(m.vertices), np.asarray(m.faces), uv, None, texture,
                name=path.stem, source=str(path))


# ====================================================================== writing
def save_mesh(mesh: Mesh, path: str | os.PathLike, vertices: np.ndarray | None = None) -> list[Path]:
    """Write ``mesh`` (optionally with other ``vertices``) as OBJ, PLY or GLB; returns files written.

    Vertex count and order are those of ``mesh``. OBJ writes the original polygons, UVs and a
    material with the texture beside it; GLB goes through :mod:`faceanim.export.gltf`.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    m = mesh if vertices is None else mesh.with_vertices(vertices)
    if suffix == ".obj":
        return _save_obj(m, path)
    if suffix == ".ply":
        return _save_ply(m, path)
    if suffix in (".glb", ".gltf"):
        from .export.gltf import write_gltf

        if suffix == ".gltf":
            raise MeshError("write binary glTF: use the .glb suffix")
        write_gltf(path, m)
        return [path]
    raise MeshError(f"cannot write '{path}': unsupported format '{suffix}' (use .obj, .ply or .glb)")


def _save_obj(m: Mesh, path: Path) -> list[Path]:
    written = []
    lines = [f"# written by faceanim: {m.n_vertices} vertices, {m.n_faces} triangles\n"]
    tex_name = f"{path.stem}.png"
    mtl_name = f"{path.stem}.mtl"
    if m.uv is not None and m.texture is not None:
        lines.append(f"mtllib {mtl_name}\nusemtl faceanim_skin\n")
    lines.append("".join(f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in m.vertices))
    if m.uv is not None:
        lines.append("".join(f"vt {u:.9g} {v:.9g}\n" for u, v in m.uv))
    if m.polygon_sizes is not None:
        polys_v = _unfan(m.faces, m.polygon_sizes)
        polys_t = _unfan(m.face_uv, m.polygon_sizes) if m.uv is not None else None
    else:
        polys_v = list(m.faces)
        polys_t = list(m.face_uv) if m.uv is not None else None
    if polys_t is None:
        lines.append("".join("f " + " ".join(str(i + 1) for i in p) + "\n" for p in polys_v))
    else:
        lines.append("".join(
            "f " + " ".join(f"{i + 1}/{j + 1}" for i, j in zip(p, q)) + "\n" for p, q in zip(polys_v, polys_t)))
    if m.uv is not None and m.texture is not None:
        from PIL import Image

        with atomic_output(path.parent / tex_name) as tmp:
            Image.fromarray(m.texture).save(tmp, format="PNG")
        written.append(path.parent / tex_name)
        with atomic_output(path.parent / mtl_name) as tmp:
            tmp.write_text(f"newmtl faceanim_skin\nKd 1 1 1\nmap_Kd {tex_name}\n")
        written.append(path.parent / mtl_name)
    with atomic_output(path) as tmp:
        tmp.write_text("".join(lines))
    return [path] + written


def _unfan(faces: np.ndarray, sizes: np.ndarray) -> list[np.ndarray]:
    out, t = [], 0
    for n in sizes:
        k = n - 2
        tris = faces[t:t + k]
        out.append(np.r_[tris[0], tris[1:, 2]] if k > 1 else tris[0])
        t += k
    return out


def _save_ply(m: Mesh, path: Path) -> list[Path]:
    import trimesh

    visual = None
    if m.uv is not None and np.array_equal(m.face_uv, m.faces):
        # one UV per vertex (no seams): PLY carries it as the s, t vertex properties
        visual = trimesh.visual.TextureVisuals(uv=m.uv)
    tm = trimesh.Trimesh(m.vertices, m.faces, process=False, validate=False, visual=visual)
    with atomic_output(path) as tmp:
        tm.export(str(tmp), file_type="ply")
    return [path]
