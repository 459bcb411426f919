"""Mesh files in and out (OBJ, PLY, glTF/GLB) keeping vertex order, UVs and texture.

A user's mesh comes back as it went in: the same vertex count and order, UVs and texture kept.
OBJ is read and written here (trimesh splits vertices along UV seams on load, which would renumber
them); PLY, glTF and GLB are read with trimesh, whose loaders keep the stored vertex order. Polygons
are triangulated as fans; OBJ output writes the original polygons back.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from faceanim.errors import MeshError
from faceanim.face.mesh import Mesh
from faceanim.io.files import atomic_output

MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf")


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
        from faceanim.io.gltf import write_gltf

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
