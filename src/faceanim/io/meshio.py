"""Mesh files in and out (OBJ, PLY, glTF/GLB) keeping vertex order, UVs and texture.

A user's mesh comes back as it went in: the same vertex count and order, UVs and texture kept.
OBJ is read and written here (trimesh splits vertices along UV seams on load, which would renumber
them); PLY, glTF and GLB are read with trimesh, whose loaders keep the stored vertex order. Polygons
are triangulated as fans; OBJ output writes the original polygons back (a polygon a UV seam runs
through, whose triangles give one corner two UVs, as its triangles). UV seams: a PLY keeps the
vertices and gives each triangle its corners' UVs (the face list ``texcoord``, read back as such);
glTF adds seam copies after the mesh's own vertices and names their sources in
``primitive.extras.sourceVertex``, which reading uses to give the mesh back as it was written.

Reading refuses damaged files with a :class:`MeshError` that names the file (and for OBJ the line):
non-numbers, NaN or infinite or absurd coordinates, faces of fewer than 3 corners, indices that are
0, before the first vertex or past the last, binary data in an OBJ, PLY headers that promise more
than the file holds, textures that are corrupt or larger than Pillow's decompression-bomb limit.

Writing an OBJ with a texture also writes two companions, a material file and the texture image.
They never replace a file the user did not name: each gets a free name beside the OBJ
(``face.mtl`` or ``face-1.mtl`` ..., ``face.texture.png`` or ``face.texture-1.png`` ...) that is
neither an existing file nor one of the paths in ``avoid`` (the other files named on the same
command). Only companions that faceanim itself wrote for the same OBJ (the OBJ being replaced names
its ``.mtl``, which carries faceanim's mark for that OBJ) are replaced in place.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import re
import warnings
from pathlib import Path

import numpy as np

from faceanim.errors import FaceAnimError, MeshError, shown
from faceanim.face.mesh import Mesh
from faceanim.io.files import OutputError, atomic_output, check_output_path
from faceanim.limits import MAX_MESH_VERTICES

MESH_SUFFIXES = (".obj", ".ply", ".glb", ".gltf")
# coordinates beyond this (in any unit) are a broken file, and their squares would overflow later
MAX_COORDINATE = 1e12
MAX_INDEX = 1 << 40
MAX_PLY_ELEMENTS = 1 << 31

_OBJ_MARK = "# written by faceanim"


# ====================================================================== reading
def load_mesh(path: str | os.PathLike) -> Mesh:
    """Read an OBJ, PLY, glTF or GLB file into a :class:`Mesh`, keeping the stored vertex order."""
    path = Path(path)
    if not path.is_file():
        if path.is_dir():
            raise MeshError(f"mesh '{path}' is a folder; give a mesh file (.obj, .ply, .glb, .gltf)")
        if path.exists():
            raise MeshError(f"mesh '{path}' is not a regular file (a device, pipe or socket); give a mesh file")
        raise MeshError(f"mesh file '{path}' does not exist; check the path")
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise MeshError(f"cannot read '{path}': unsupported format '{suffix}' (use {', '.join(MESH_SUFFIXES)})")
    try:
        mesh = _load_obj(path) if suffix == ".obj" else _load_with_trimesh(path)
    except FaceAnimError:
        raise
    except MemoryError:
        raise MeshError(f"mesh '{path}' is too large to read into memory") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise MeshError(f"cannot read mesh '{path}': {getattr(exc, 'strerror', None) or 'read error'}") from None
    if mesh.n_vertices > MAX_MESH_VERTICES:
        raise MeshError(f"mesh '{path}' has {mesh.n_vertices:,} vertices; faceanim reads meshes of up to "
                        f"{MAX_MESH_VERTICES:,}: decimate it and try again")
    big = np.abs(mesh.vertices) > MAX_COORDINATE
    if big.any():
        i = int(np.flatnonzero(big.any(1))[0])
        raise MeshError(f"mesh '{path}' has an absurd coordinate (beyond {MAX_COORDINATE:g}) at vertex index {i}; "
                        "repair or re-export the mesh")
    a, b, c = (mesh.vertices[mesh.faces[:, k]] for k in range(3))
    if not np.any(np.linalg.norm(np.cross(b - a, c - a), axis=1) > 0):
        raise MeshError(f"mesh '{path}' has no area: every triangle is degenerate (repeated or collinear corners); "
                        "give a surface mesh")
    return mesh


def _obj_error(path, line_no, msg) -> MeshError:
    return MeshError(f"mesh '{path}' line {line_no}: {msg}")


def _floats(parts, path, line_no, what, low, high) -> list[float]:
    """``low``..``high`` numbers of an OBJ line (extra ones ignored, as OBJ allows)."""
    if len(parts) < low:
        raise _obj_error(path, line_no, f"malformed {what} line (needs {low} numbers, got {len(parts)})")
    try:
        return [float(t) for t in parts[:high]]
    except ValueError:
        raise _obj_error(path, line_no, f"malformed {what} line (its numbers are not all numbers)") from None


def _index(token: str, count: int, path, line_no, what: str) -> int:
    """A 0-based index from an OBJ index (1-based; negative: relative to the ``count`` read so far)."""
    try:
        i = int(token)
    except ValueError:
        raise _obj_error(path, line_no, f"malformed face: {what} index is not a whole number") from None
    if i == 0:
        raise _obj_error(path, line_no, f"{what} index 0 in a face (OBJ counts from 1)")
    if i < 0:
        if -i > count:
            raise _obj_error(path, line_no, f"relative {what} index {i} points before the first {what} "
                                            f"(only {count} so far)")
        return count + i
    if i > MAX_INDEX:
        raise _obj_error(path, line_no, f"{what} index {i} is absurdly large; the face indexes missing vertices")
    return i - 1


def _load_obj(path: Path) -> Mesh:
    verts, v_line, uvs, t_line = [], [], [], []
    corner_v, corner_t, sizes, f_line = [], [], [], []
    mtllib = None
    material = None
    all_t = True
    with open(path, "rb") as fh:
        for line_no, raw in enumerate(fh, 1):
            if b"\0" in raw:
                raise _obj_error(path, line_no, "binary data in a text OBJ file; give a text OBJ "
                                                "(or a .ply/.glb for binary meshes)")
            line = raw.decode("utf-8", errors="replace")
            parts = line.split()
            if not parts or parts[0][0] == "#":
                continue
            key = parts[0]
            if key == "v":
                if len(verts) >= MAX_MESH_VERTICES:
                    raise _obj_error(path, line_no, f"more than {MAX_MESH_VERTICES:,} vertices; faceanim reads "
                                                    "meshes up to that size: decimate it and try again")
                verts.append(_floats(parts[1:], path, line_no, "vertex ('v x y z')", 3, 3))
                v_line.append(line_no)
            elif key == "vt":
                uv = _floats(parts[1:], path, line_no, "texture coordinate ('vt u v')", 1, 2)
                uvs.append(uv if len(uv) == 2 else uv + [0.0])
                t_line.append(line_no)
            elif key == "f":
                if len(parts) < 4:
                    raise _obj_error(path, line_no, f"a face needs at least 3 corners, got {len(parts) - 1}")
                nv, nt = len(verts), len(uvs)
                for p in parts[1:]:
                    idx = p.split("/")
                    if len(idx) > 3 or not idx[0]:
                        raise _obj_error(path, line_no, "malformed face corner ('v', 'v/t', 'v//n' or 'v/t/n')")
                    corner_v.append(_index(idx[0], nv, path, line_no, "vertex"))
                    if len(idx) > 1 and idx[1]:
                        corner_t.append(_index(idx[1], nt, path, line_no, "texture coordinate"))
                    else:
                        corner_t.append(-1)
                        all_t = False
                sizes.append(len(parts) - 1)
                f_line.append(line_no)
            elif key == "mtllib" and mtllib is None and len(parts) > 1:
                mtllib = line.split(None, 1)[1].strip()
            elif key == "usemtl" and material is None and len(parts) > 1:
                material = line.split(None, 1)[1].strip()
    if not verts or not sizes:
        raise MeshError(f"mesh '{path}' is empty (no vertices or no faces); give a surface mesh")
    v = np.array(verts, dtype=np.float64)
    bad = ~np.isfinite(v).all(1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise _obj_error(path, v_line[i], f"NaN or infinite coordinates at vertex index {i}; repair or "
                                          "re-export the mesh")
    sizes = np.array(sizes, dtype=np.int64)
    ends = np.cumsum(sizes)  # corner k belongs to polygon searchsorted(ends, k, "right"): its f line

    cv = np.array(corner_v, dtype=np.int64)
    out = cv >= len(v)
    if out.any():
        k = int(np.flatnonzero(out)[0])
        face = int(np.searchsorted(ends, k, side="right"))
        raise _obj_error(path, f_line[face], f"a face indexes missing vertices (vertex {cv[k] + 1}; the file "
                                             f"has {len(v)}, 1..{len(v)})")
    if not uvs and corner_t and max(corner_t) >= 0:
        k = int(np.flatnonzero(np.array(corner_t) >= 0)[0])
        face = int(np.searchsorted(ends, k, side="right"))
        raise _obj_error(path, f_line[face], "a face indexes texture coordinates (f v/vt) but the file has no vt "
                                             "lines; repair or re-export the mesh")
    has_uv = bool(uvs) and all_t
    faces = _fan(cv, sizes)
    uv = face_uv = None
    if has_uv:
        uv = np.array(uvs, dtype=np.float64)
        bad = ~np.isfinite(uv).all(1)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise _obj_error(path, t_line[i], f"NaN or infinite texture coordinate (vt {i + 1}); repair or "
                                              "re-export the mesh")
        ct = np.array(corner_t, dtype=np.int64)
        out = ct >= len(uv)
        if out.any():
            k = int(np.flatnonzero(out)[0])
            face = int(np.searchsorted(ends, k, side="right"))
            raise _obj_error(path, f_line[face], f"a face indexes missing texture coordinates (vt {ct[k] + 1}; "
                                                 f"the file has {len(uv)})")
        face_uv = _fan(ct, sizes)
    texture = _read_mtl_texture(path, path.parent / mtllib, material) if (mtllib and has_uv) else None
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


_MAX_MTL_BYTES = 16 << 20


def _read_mtl_texture(obj: Path, mtl: Path, material: str | None) -> np.ndarray | None:
    """The diffuse texture the material file names (None when there is none or it is missing)."""
    try:
        if not mtl.is_file():
            return None
        if mtl.stat().st_size > _MAX_MTL_BYTES:
            raise MeshError(f"material file '{mtl}' of '{obj}' is too large to be a material file")
        data = mtl.read_bytes()
    except OSError:
        return None
    if b"\0" in data:
        raise MeshError(f"material file '{mtl}' of '{obj}' is not a text file; fix its mtllib line")
    current, maps = None, {}
    for line in data.decode("utf-8", errors="replace").splitlines():
        parts = line.split(None, 1)
        if not parts:
            continue
        if parts[0] == "newmtl" and len(parts) > 1:
            current = parts[1].strip()
        elif parts[0] == "map_Kd" and len(parts) > 1:
            rest = parts[1].strip()
            # options (-s 1 1 1 ...) come before the name; a name may hold spaces
            name = rest if (mtl.parent / rest).is_file() else rest.split()[-1]
            maps.setdefault(current, name)
    name = maps.get(material) or next(iter(maps.values()), None)
    if name is None:
        return None
    image = mtl.parent / name
    if not image.is_file():
        return None
    return _read_image(image, f"texture '{shown(name)}' of mesh '{obj}'")


def _read_image(path: Path, what: str = "image") -> np.ndarray:
    from PIL import Image

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with Image.open(path) as im:
                im = im.convert("RGBA" if im.mode in ("RGBA", "LA", "P", "PA") else "RGB")
                return np.asarray(im).copy()
    except (Image.DecompressionBombError, Image.DecompressionBombWarning):
        raise MeshError(f"{what} is larger than {Image.MAX_IMAGE_PIXELS} pixels (Pillow's limit against "
                        "decompression bombs); shrink the texture") from None
    except MemoryError:
        raise MeshError(f"{what} is too large to read into memory; shrink the texture") from None
    except Exception:  # noqa: BLE001 -- any failure of an image decoder on a damaged file
        raise MeshError(f"{what} cannot be read (damaged or not an image); re-save it as PNG or JPEG, or "
                        "remove the map_Kd line") from None


_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
              "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8,
              "float64": 8}


def _check_ply_header(path: Path) -> None:
    """Refuse a PLY file whose header is missing or promises more elements than the file can hold
    (before any reader allocates arrays of the promised size)."""
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(65536)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        raise MeshError(f"mesh '{path}' is not a PLY file (no 'ply' ... 'end_header' header)")
    lines = head[:end].decode("ascii", errors="replace").splitlines()
    fmt, elements = None, []
    for n, line in enumerate(lines, 1):
        t = line.split()
        if not t:
            continue
        if t[0] == "format" and len(t) > 1:
            fmt = t[1]
        elif t[0] == "element":
            if len(t) != 3 or not t[2].isdigit():
                raise MeshError(f"mesh '{path}' line {n}: malformed PLY element line ('element NAME COUNT')")
            count = int(t[2])
            if count > MAX_PLY_ELEMENTS:
                raise MeshError(f"mesh '{path}' line {n}: absurd element count {count}")
            elements.append([count, 0])
        elif t[0] == "property" and elements:
            if fmt == "ascii":
                elements[-1][1] += 2  # at least a digit and a separator
            elif len(t) >= 5 and t[1] == "list":
                elements[-1][1] += _PLY_SIZES.get(t[2], 1)
            else:
                elements[-1][1] += _PLY_SIZES.get(t[1] if len(t) > 1 else "", 1)
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise MeshError(f"mesh '{path}' has no valid PLY format line (ascii or binary)")
    need = sum(count * max(row, 1) for count, row in elements)
    if need > size - end:
        raise MeshError(f"mesh '{path}' is truncated: its PLY header promises more elements than the file holds")


def _check_gltf(path: Path) -> dict:
    """What trimesh would read without asking: a GLB whose header disagrees with the file's size,
    JSON nested too deep, quantized data it misreads, and files referenced outside the glTF's
    folder (``uri: /etc/passwd``); all refused before it reads anything."""
    damaged = MeshError(f"mesh '{path}' is not a valid {path.suffix[1:].upper()} file (damaged header or JSON); "
                        "export it again")
    try:
        if path.suffix.lower() == ".glb":
            with open(path, "rb") as fh:
                head = fh.read(12)
            if len(head) < 12 or head[:4] != b"glTF" or int.from_bytes(head[8:12], "little") != path.stat().st_size:
                raise damaged
            from faceanim.io.gltf import glb_json

            doc = glb_json(path)
        else:
            if path.stat().st_size > 64 << 20:
                raise MeshError(f"mesh '{path}' has more than 64 MB of glTF JSON; give a .glb")
            doc = json.loads(path.read_text(encoding="utf-8"))
    except (RecursionError, ValueError, UnicodeDecodeError):
        raise damaged from None
    if not isinstance(doc, dict):
        raise damaged
    if "KHR_mesh_quantization" in (doc.get("extensionsRequired") or []):
        raise MeshError(f"mesh '{path}' is quantized (KHR_mesh_quantization, e.g. written with --compact); "
                        "faceanim reads plain glTF: give the file written without --compact")
    folder = path.resolve().parent
    for key in ("buffers", "images"):
        for item in doc.get(key) or []:
            uri = item.get("uri") if isinstance(item, dict) else None
            if not isinstance(uri, str) or uri.startswith("data:"):
                continue
            target = (folder / uri).resolve()
            if "://" in uri or target.parent != folder and folder not in target.parents:
                raise MeshError(f"mesh '{path}' refers to a file outside its folder ({key}); faceanim reads only "
                                "files beside a glTF")
    return doc


def _load_with_trimesh(path: Path) -> Mesh:
    import trimesh
    from PIL import Image

    if path.suffix.lower() == ".ply":
        _check_ply_header(path)
    doc = _check_gltf(path) if path.suffix.lower() in (".glb", ".gltf") else None
    log = logging.getLogger("trimesh")
    level = log.level
    log.setLevel(logging.CRITICAL + 1)  # its warnings would add lines to the one-line error rule
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            # a PLY's per-corner UVs ('texcoord') are read below; trimesh would split the vertices
            extra = {"fix_texture": False} if path.suffix.lower() == ".ply" else {}
            loaded = trimesh.load(str(path), process=False, maintain_order=True, **extra)
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
                if not np.isfinite(uv).all():
                    raise MeshError(f"mesh '{path}' has NaN or infinite texture coordinates; repair or re-export it")
                mat = getattr(visual, "material", None)
                img = getattr(mat, "baseColorTexture", None) or getattr(mat, "image", None)
                if img is not None:
                    texture = np.asarray(img.convert("RGBA" if img.mode in ("RGBA", "LA", "P") else "RGB")).copy()
            vertices, faces = np.asarray(m.vertices), np.asarray(m.faces)
            face_uv = None
            if path.suffix.lower() == ".ply":
                corner_uv = _ply_corner_uv(m, len(faces))
                if corner_uv is not None:
                    if not np.isfinite(corner_uv).all():
                        raise MeshError(f"mesh '{path}' has NaN or infinite texture coordinates; repair or "
                                        "re-export it")
                    uv, inverse = np.unique(corner_uv.reshape(-1, 2), axis=0, return_inverse=True)
                    face_uv = inverse.reshape(-1, 3)
    except FaceAnimError:
        raise
    except (Image.DecompressionBombError, Image.DecompressionBombWarning):
        raise MeshError(f"mesh '{path}' has a texture larger than {Image.MAX_IMAGE_PIXELS} pixels (Pillow's "
                        "limit against decompression bombs); shrink the texture") from None
    except MemoryError:
        raise MeshError(f"mesh '{path}' is too large to read into memory") from None
    except Exception:  # noqa: BLE001 -- any failure of a third-party reader on a damaged file
        kind = {".ply": "PLY", ".glb": "GLB", ".gltf": "glTF"}[path.suffix.lower()]
        raise MeshError(f"cannot read mesh '{path}': damaged or not a valid {kind} file; re-export it") from None
    finally:
        log.setLevel(level)
    if vertices.ndim != 2 or vertices.shape[1:] != (3,) or faces.ndim != 2 or faces.shape[1:] != (3,):
        raise MeshError(f"mesh '{path}' is not a triangle mesh; re-export it")
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise MeshError(f"mesh '{path}' has triangles that name vertices it does not have (damaged); re-export it")
    if doc and doc.get("images") and doc.get("textures") and uv is not None and texture is None:
        raise MeshError(f"mesh '{path}' names a texture that cannot be read (damaged or not an image); "
                        "re-export it, or remove the texture")
    source = _gltf_source_vertex(doc, vertices) if doc else None
    if source is not None:
        # the seam copies faceanim's glTF writer added go back onto their vertices; each corner
        # keeps its own UV
        n = int(source.max()) + 1
        face_uv = faces if uv is not None else None
        vertices, faces = vertices[:n], source[faces]
    return Mesh(vertices, faces, uv, face_uv, texture, name=path.stem, source=str(path))


def _ply_corner_uv(m, n_faces: int) -> np.ndarray | None:
    """(T, 6) UVs of each triangle's corners from a PLY face list 'texcoord' (None without one)."""
    raw = (getattr(m, "metadata", None) or {}).get("_ply_raw") or {}
    data = (raw.get("face") or {}).get("data")
    try:
        tc = data["texcoord"]
        tc = tc["f1"] if getattr(tc, "dtype", None) is not None and tc.dtype.names else tc
        tc = np.asarray(tc, dtype=np.float64)
    except (KeyError, IndexError, TypeError, ValueError):
        return None
    return tc if tc.shape == (n_faces, 6) else None


def _gltf_source_vertex(doc: dict, vertices: np.ndarray) -> np.ndarray | None:
    """The ``primitive.extras.sourceVertex`` map of a glTF faceanim wrote (one mesh, one primitive):
    glTF vertex -> vertex of the mesh written, the mesh's own vertices first, in order, then seam
    copies at the positions of their vertices. None when the file has no such map or it does not
    fit what was read (the file is then read as stored)."""
    meshes = doc.get("meshes")
    if not isinstance(meshes, list) or len(meshes) != 1 or not isinstance(meshes[0], dict):
        return None
    prims = meshes[0].get("primitives")
    if not isinstance(prims, list) or len(prims) != 1 or not isinstance(prims[0], dict):
        return None
    extras = prims[0].get("extras")
    src = extras.get("sourceVertex") if isinstance(extras, dict) else None
    if not isinstance(src, list) or len(src) != len(vertices) or not all(type(i) is int for i in src):
        return None
    src = np.asarray(src, dtype=np.int64)
    n = int(src.max(initial=-1)) + 1
    if src.min(initial=0) < 0 or n < 1 or not np.array_equal(src[:n], np.arange(n)) \
            or not np.array_equal(vertices[src], vertices):
        return None
    return src


# ====================================================================== writing
def _key(p) -> str:
    return os.path.normcase(os.path.abspath(os.fspath(p)))


def _owned_companions(path: Path) -> set[str]:
    """Companions faceanim wrote for the OBJ at ``path`` earlier: the material file its mtllib
    names, if that carries faceanim's mark for this OBJ, and the texture that material names, if
    it has faceanim's companion name. Those may be replaced; nothing else is."""
    owned: set[str] = set()
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096).decode("utf-8", errors="replace").splitlines()
    except OSError:
        return owned
    if not head or not head[0].startswith(_OBJ_MARK):
        return owned
    for line in head[1:4]:
        if not line.startswith("mtllib "):
            continue
        name = line[7:].strip()
        if not name or os.sep in name or "/" in name:
            return owned
        mtl = path.parent / name
        try:
            with open(mtl, "rb") as fh:
                lines = fh.read(4096).decode("utf-8", errors="replace").splitlines()
        except OSError:
            return owned
        if not lines or lines[0].strip() != f"{_OBJ_MARK} for {path.name}":
            return owned
        owned.add(_key(mtl))
        stem = _safe_stem(path)
        for ln in lines[1:]:
            if ln.startswith("map_Kd "):
                tex = ln[7:].strip()
                if re.fullmatch(re.escape(stem) + r"\.texture(-\d+)?\.png", tex):
                    owned.add(_key(path.parent / tex))
        return owned
    return owned


def _safe_stem(path: Path) -> str:
    # companions are named in the .obj/.mtl by name; OBJ readers split names at spaces
    return re.sub(r"\s", "_", path.stem) or "mesh"


def companion_name(folder: Path, base: str, ext: str, avoid: set[str], owned: set[str] = frozenset()) -> Path:
    """A name ``base + ext`` (else ``base-1 + ext``, ...) in ``folder`` that is not an existing file
    (unless faceanim wrote it for the same output: ``owned``) and not in ``avoid``."""
    candidates = [folder / (f"{base}{ext}" if k == 0 else f"{base}-{k}{ext}") for k in range(1000)]
    for c in candidates:  # a companion written earlier for this output is reused, not duplicated
        if _key(c) in owned and _key(c) not in avoid:
            return c
    for c in candidates:
        if _key(c) not in avoid and not os.path.lexists(c):
            return c
    raise OutputError(f"no free name for '{folder / (base + ext)}' (tried {base}-1 ... {base}-999); "
                      "clean up the folder or write elsewhere")


def save_mesh(mesh: Mesh, path: str | os.PathLike, vertices: np.ndarray | None = None,
              avoid=()) -> list[Path]:
    """Write ``mesh`` (optionally with other ``vertices``) as OBJ, PLY or GLB; returns the files written.

    Vertex count and order are those of ``mesh``. OBJ writes the original polygons and UVs, and,
    when the mesh has a texture, a material file and the texture as companions with free names
    (see the module doc): ``avoid`` lists the other paths named on the same command (inputs,
    ``--image``, ...), which a companion never takes. The returned list starts with ``path``.
    All files are written to temporary files first and renamed only when every one succeeded.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".gltf":
        raise MeshError("write binary glTF: use the .glb suffix")
    if suffix not in (".obj", ".ply", ".glb"):
        raise MeshError(f"cannot write '{path}': unsupported format '{suffix}' (use .obj, .ply or .glb)")
    check_output_path(path, "mesh output")
    m = mesh if vertices is None else mesh.with_vertices(vertices)
    if suffix == ".obj":
        return _save_obj(m, path, {_key(a) for a in avoid if a is not None and str(a) != ""})
    if suffix == ".ply":
        return _save_ply(m, path)
    from faceanim.io.gltf import write_gltf

    write_gltf(path, m)
    return [path]


def _save_obj(m: Mesh, path: Path, avoid: set[str]) -> list[Path]:
    lines = [f"{_OBJ_MARK}: {m.n_vertices} vertices, {m.n_faces} triangles\n"]
    textured = m.uv is not None and m.texture is not None
    tex = mtl = None
    if textured:
        avoid = avoid | {_key(path)}
        owned = _owned_companions(path)
        stem = _safe_stem(path)
        mtl = companion_name(path.parent, stem, ".mtl", avoid, owned)
        tex = companion_name(path.parent, f"{stem}.texture", ".png", avoid | {_key(mtl)}, owned)
        lines.append(f"mtllib {mtl.name}\nusemtl faceanim_skin\n")
    lines.append("".join(f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in m.vertices))
    if m.uv is not None:
        lines.append("".join(f"vt {u:.9g} {v:.9g}\n" for u, v in m.uv))
    polys_v, polys_t = _polygons(m)
    if polys_t is None:
        lines.append("".join("f " + " ".join(str(i + 1) for i in p) + "\n" for p in polys_v))
    else:
        lines.append("".join(
            "f " + " ".join(f"{i + 1}/{j + 1}" for i, j in zip(p, q)) + "\n" for p, q in zip(polys_v, polys_t)))
    with contextlib.ExitStack() as stack:
        # entered OBJ first, so on leaving the companions are renamed into place before the OBJ
        obj_tmp = stack.enter_context(atomic_output(path, "mesh output"))
        if textured:
            from PIL import Image

            mtl_tmp = stack.enter_context(atomic_output(mtl, "material file"))
            tex_tmp = stack.enter_context(atomic_output(tex, "texture"))
            Image.fromarray(np.asarray(m.texture, dtype=np.uint8)).save(tex_tmp, format="PNG")
            mtl_tmp.write_text(f"{_OBJ_MARK} for {path.name}\nnewmtl faceanim_skin\nKd 1 1 1\nmap_Kd {tex.name}\n",
                               encoding="utf-8")
        obj_tmp.write_text("".join(lines), encoding="utf-8")
    return [path, mtl, tex] if textured else [path]


def _polygons(m: Mesh) -> tuple[list[np.ndarray], list[np.ndarray] | None]:
    """The polygons an OBJ writes: vertex corners and UV corners (None without UVs) of each.

    The original polygons where the triangles are their fans; a polygon whose triangles are not
    the fan of one corner list, in vertices or in UVs (a UV seam through a quad: its two triangles
    give a shared corner two UVs, which one OBJ polygon cannot say), is written as its triangles.
    """
    sizes = m.polygon_sizes
    tris_t = m.face_uv if m.uv is not None else None
    if sizes is None or int(np.sum(sizes - 2)) != m.n_faces or np.any(sizes < 3):
        return list(m.faces), (list(tris_t) if tris_t is not None else None)
    polys_v = _unfan(m.faces, sizes)
    polys_t = _unfan(tris_t, sizes) if tris_t is not None else None
    same = np.all(_fan(np.concatenate(polys_v), sizes) == m.faces, axis=1)
    if polys_t is not None:
        same &= np.all(_fan(np.concatenate(polys_t), sizes) == tris_t, axis=1)
    first = np.cumsum(sizes - 2) - (sizes - 2)  # each polygon's first triangle
    whole = np.logical_and.reduceat(same, first)
    if whole.all():
        return polys_v, polys_t
    out_v, out_t = [], ([] if polys_t is not None else None)
    for k in range(len(sizes)):
        if whole[k]:
            out_v.append(polys_v[k])
            if out_t is not None:
                out_t.append(polys_t[k])
            continue
        rows = range(first[k], first[k] + sizes[k] - 2)
        out_v.extend(m.faces[t] for t in rows)
        if out_t is not None:
            out_t.extend(tris_t[t] for t in rows)
    return out_v, out_t


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

    if m.uv is not None and not np.array_equal(m.face_uv, m.faces):
        # UV seams: each triangle carries its corners' UVs (the 'texcoord' face list MeshLab and
        # trimesh read), so the vertices stay the mesh's own, in its order
        return _save_ply_corner_uv(m, path)
    visual = None
    if m.uv is not None:
        # one UV per vertex (no seams): PLY carries it as the s, t vertex properties
        visual = trimesh.visual.TextureVisuals(uv=m.uv)
    tm = trimesh.Trimesh(m.vertices, m.faces, process=False, validate=False, visual=visual)
    with atomic_output(path, "mesh output") as tmp:
        tm.export(str(tmp), file_type="ply")
    return [path]


def _save_ply_corner_uv(m: Mesh, path: Path) -> list[Path]:
    """Binary PLY with the vertices as they are and each triangle's three corner UVs."""
    header = (f"ply\nformat binary_little_endian 1.0\ncomment {_OBJ_MARK[2:]}\n"
              f"element vertex {m.n_vertices}\nproperty float x\nproperty float y\nproperty float z\n"
              f"element face {m.n_faces}\nproperty list uchar int vertex_indices\n"
              "property list uchar float texcoord\nend_header\n")
    vertex = np.ascontiguousarray(m.vertices, dtype="<f4")
    face = np.zeros(m.n_faces, dtype=[("n", "u1"), ("index", "<i4", 3), ("m", "u1"), ("uv", "<f4", 6)])
    face["n"], face["index"], face["m"] = 3, m.faces, 6
    face["uv"] = m.uv[m.face_uv].reshape(-1, 6)
    with atomic_output(path, "mesh output") as tmp:
        with open(tmp, "wb") as fh:
            fh.write(header.encode("ascii"))
            fh.write(vertex.tobytes())
            fh.write(face.tobytes())
    return [path]
