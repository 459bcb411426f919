"""Whole glTF 2.0 / VRM avatars (``.glb``, ``.vrm``): read, add morph targets to a mesh, write back.

:func:`read_scene` reads a binary glTF (a VRM is the same GLB container) into a :class:`Scene`;
:meth:`Scene.meshes` lists its meshes, :meth:`Scene.mesh_geometry` gives one glTF mesh (all its
primitives) as one faceanim :class:`~faceanim.face.mesh.Mesh` in world space, :meth:`Scene.targets`
its existing morph targets, and :func:`write_scene` writes a copy of the file in which the listed
meshes have gained new morph targets and nothing else has changed.

**World space.** A mesh's vertices are shown as a viewer shows the file without animation:

- a mesh on a node without a skin: positions transformed by the node's global matrix;
- a skinned mesh: the glTF spec ignores the mesh node's transform and places a vertex by its
  joints, ``sum_k w_k * G[j_k] @ IBM[j_k] @ v`` (``G`` a joint node's global matrix,
  ``IBM`` its inverse bind matrix), which is what this module computes (linear-blend skinning at
  the skeleton's stored pose, weights renormalised to sum 1; a vertex without weights takes the mean
  of the skin's ``G @ IBM``). When the skeleton is stored in its bind pose every ``G @ IBM`` is the
  same matrix and this is one affine map of the mesh; often that map is the mesh node's global
  matrix (or the identity), but not always: glTF-Transform's ``quantize`` (the shared VRoid sample)
  leaves the mesh nodes at the identity and bakes a per-mesh scale and offset into the inverse bind
  matrices, so the node matrix alone would leave every mesh in its own unit box.

A mesh used by several nodes is placed by the first of them. Morph deltas follow the linear part of
the same per-vertex map: :meth:`Scene.targets` returns ``A_v @ d`` and :func:`write_scene` stores
``pinv(A_v) @ delta`` (a bone scaled to zero drops the part of a delta it would hide anyway).

**Vertices.** The primitives are merged in order; primitives that share their vertex data (the same
POSITION, TEXCOORD_0, skinning and target accessors, as UniVRM writes submeshes) share one block of
merged vertices, and get one shared accessor per new target. Vertices of different blocks at the
same position stay separate; :func:`weld` joins them for geometry processing.

**Writing** keeps every buffer view, accessor, node, skin, animation, material, texture, image,
other mesh and extension as it was: the JSON is written from the pygltflib document (``Scene.document``,
where the caller may edit ``extensions``), key by key as the file had it: properties pygltflib has no
field for (a node's ``weights``, non-spec keys) are taken from the file, and the defaults pygltflib
fills in are left out (numbers may change form, ``0`` to ``0.0``). New data is appended to the one
binary buffer. Each new target is a POSITION delta in every primitive of the
mesh (glTF requires equal target counts): sparse when it moves fewer than half of a block's
vertices, dense otherwise, and an accessor without a buffer view (all zeros, as the spec defines
it) when it moves none of them; all carry min/max. ``mesh.weights`` (and node ``weights``) grow
with zeros, ``extras.targetNames`` with the names, and an animation of the mesh's weights gets a
widened copy of its output with zeros for the new targets (the old accessor stays in the file,
unused). ``replace=True`` replaces a same-named target: its POSITION delta in every primitive
(its NORMAL/TANGENT deltas, which belonged to the old shape, are dropped); the old accessors stay,
unused.

Refused with one :class:`~faceanim.errors.MeshError` line: files that are not GLB, damaged or
truncated ones, buffers or images stored outside the file (``uri``, also ``data:``), compressed or
quantised geometry (Draco, meshopt, KHR_mesh_quantization), and, when a mesh is used, primitives
that are not triangles or store POSITION as anything but float. Sizes are checked before anything
is allocated (:data:`MAX_SCENE_BYTES`, :data:`MAX_JSON_BYTES`, :data:`MAX_SCENE_VERTICES`).
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pygltflib as g

from faceanim.errors import InputFileError, MeshError, shown
from faceanim.face.mesh import Mesh
from faceanim.io.files import atomic_output, check_output_path
from faceanim.io.meshio import MAX_COORDINATE

SCENE_SUFFIXES = (".glb", ".vrm")
MAX_SCENE_BYTES = 1 << 30  # a GLB file
MAX_JSON_BYTES = 64 << 20  # its JSON chunk
MAX_SCENE_VERTICES = 1 << 24  # POSITION rows over all primitives (distinct vertex blocks)
MAX_ZERO_ELEMENTS = 1 << 24  # components of an accessor without a buffer view (zeros the file does not hold)
MAX_TARGET_ROWS = 1 << 24  # targets x vertices read by one Scene.targets call
WELD_TOLERANCE = 1e-7  # of the bounding-box diagonal

_COMPONENTS = {5120: "<i1", 5121: "<u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_NORMALIZED = {"<i1": 127.0, "<u1": 255.0, "<i2": 32767.0, "<u2": 65535.0}
_COMPRESSION = ("KHR_draco_mesh_compression", "EXT_meshopt_compression", "KHR_mesh_quantization")
_ARRAYS = ("accessors", "animations", "bufferViews", "buffers", "cameras", "images", "materials", "meshes",
           "nodes", "samplers", "scenes", "skins", "textures")
_MODES = {0: "points", 1: "lines", 2: "line loops", 3: "line strips", 4: "triangles", 5: "triangle strips",
          6: "triangle fans"}


class DamagedGltf(MeshError):
    """The file breaks glTF's own rules (indices past their data, NaN positions, ...): no tool
    should show it, unlike a valid file that uses what faceanim does not edit (quantisation)."""


@dataclasses.dataclass(frozen=True)
class MeshInfo:
    """One glTF mesh of a :class:`Scene`, as :meth:`Scene.meshes` lists it.

    ``n_vertices`` counts the vertices :meth:`Scene.mesh_geometry` gives (blocks shared by
    primitives once); ``bbox`` is (2, 3) min and max corners in world space (None when no
    primitive has positions); ``editable`` tells whether :meth:`Scene.mesh_geometry` and
    :func:`write_scene` accept it (triangles with float positions).
    """

    index: int
    name: str
    nodes: tuple[int, ...]
    skinned: bool
    n_vertices: int
    n_primitives: int
    target_names: tuple[str, ...]
    bbox: np.ndarray | None
    editable: bool


@dataclasses.dataclass(frozen=True)
class _Block:
    """Primitives sharing one vertex block: its rows ``offset .. offset + count`` of the merged mesh."""

    prims: tuple[int, ...]
    offset: int
    count: int
    attributes: dict
    targets: tuple


def _is_int(v) -> bool:
    return type(v) is int


def _numbers(v, n: int) -> bool:
    return (isinstance(v, list) and len(v) == n
            and all(type(x) in (int, float) and math.isfinite(x) and abs(x) <= MAX_COORDINATE for x in v))


def _no_constants(token):
    raise ValueError(f"non-JSON constant {token}")


def _finite(token: str) -> float:
    value = float(token)
    if not math.isfinite(value):  # 1e400: valid JSON that no float holds
        raise ValueError("a number too large for a float")
    return value


class Scene:
    """A glTF/VRM avatar read by :func:`read_scene`.

    ``document`` is the pygltflib document; edit its ``extensions`` (e.g. VRM expressions) before
    :func:`write_scene` to have them written. Geometry is always read from the file as it was read.
    """

    def __init__(self, path: Path, document: g.GLTF2, gltf: dict, binary: bytes):
        self.path = path
        self.document = document
        self._json = gltf
        self._bin = binary
        self._label = shown(path, 80, tail=True)
        self._cache: dict = {}
        self._globals = _global_matrices(gltf, self._bad)

    # ------------------------------------------------------------------ public
    def meshes(self) -> list[MeshInfo]:
        """Every glTF mesh with its nodes, skinning, counts, morph target names and world bounding box."""
        out = []
        for mi, mesh in enumerate(self._json.get("meshes", [])):
            blocks = self._blocks(mi)
            bbox = None
            if blocks:
                world = self._world_positions(mi)
                bbox = np.stack([world.min(0), world.max(0)])
            out.append(MeshInfo(index=mi, name=self._mesh_name(mi), nodes=tuple(self._users(mi)),
                                skinned=self._skin(mi) is not None, n_vertices=sum(b.count for b in blocks),
                                n_primitives=len(mesh["primitives"]), target_names=tuple(self._target_names(mi)),
                                bbox=bbox, editable=self._problem(mi) is None))
        return out

    def mesh_geometry(self, mesh_index: int) -> tuple[Mesh, np.ndarray]:
        """All primitives of glTF mesh ``mesh_index`` as one :class:`Mesh` in world space (see the
        module doc), with UVs when every primitive has TEXCOORD_0, and the (V, 2) int64 ``mapping``:
        row i is (primitive index, vertex index in that primitive) of merged vertex i (the first
        primitive of a shared block)."""
        mi = self._check_mesh(mesh_index)
        if ("geometry", mi) in self._cache:
            return self._cache[("geometry", mi)]
        blocks = self._blocks(mi)
        world = self._world_positions(mi)
        faces = []
        for p, prim in enumerate(self._json["meshes"][mi]["primitives"]):
            block = next(b for b in blocks if p in b.prims)
            if "indices" in prim:
                idx = self._ints(prim["indices"], "SCALAR", "triangle indices", mi).ravel()
            else:
                idx = np.arange(block.count, dtype=np.int64)
            if idx.size % 3:
                self._bad(f"mesh {mi} primitive {p} has {idx.size} corners, not whole triangles")
            if idx.size and idx.max() >= block.count:
                self._bad(f"mesh {mi} primitive {p} has triangles indexing missing vertices")
            faces.append(idx.reshape(-1, 3) + block.offset)
        uv = None
        if all("TEXCOORD_0" in b.attributes for b in blocks):
            uv = np.concatenate([self._floats(b.attributes["TEXCOORD_0"], "VEC2", "texture coordinates", mi,
                                              normalized=True) for b in blocks])
            if not np.isfinite(uv).all():
                self._bad(f"mesh {mi} has NaN or infinite texture coordinates")
            uv[:, 1] = 1.0 - uv[:, 1]  # glTF's v runs downwards
        mapping = np.concatenate([np.stack([np.full(b.count, b.prims[0]), np.arange(b.count)], axis=1)
                                  for b in blocks]).astype(np.int64)
        mesh = Mesh(world, np.concatenate(faces), uv=uv, name=self._mesh_name(mi), source=str(self.path))
        self._cache[("geometry", mi)] = (mesh, mapping)
        return mesh, mapping

    def targets(self, mesh_index: int, names=None) -> dict[str, np.ndarray]:
        """The existing morph targets of mesh ``mesh_index`` (all, or those ``names``) as name ->
        (V, 3) world-space POSITION deltas in :meth:`mesh_geometry`'s vertex order."""
        mi = self._check_mesh(mesh_index)
        all_names = self._target_names(mi)
        if names is None:
            wanted = list(dict.fromkeys(all_names))
        else:
            wanted = [names] if isinstance(names, str) else list(names)
            for name in wanted:
                if name not in all_names:
                    raise MeshError(f"mesh '{shown(self._mesh_name(mi))}' of '{self._label}' has no morph target "
                                    f"'{shown(name)}'; see its target names in Scene.meshes()")
        blocks = self._blocks(mi)
        n_vertices = sum(b.count for b in blocks)
        if len(wanted) * n_vertices > MAX_TARGET_ROWS:
            raise MeshError(f"mesh '{shown(self._mesh_name(mi))}' of '{self._label}': {len(wanted)} targets x "
                            f"{n_vertices} vertices is more than faceanim reads at once; ask for fewer names")
        linear, _ = self._frames(mi)
        out = {}
        for name in wanted:
            k = all_names.index(name)
            parts = []
            for b in blocks:
                acc = b.targets[k].get("POSITION") if isinstance(b.targets[k], dict) else None
                if acc is None:
                    parts.append(np.zeros((b.count, 3)))
                    continue
                d = self._floats(acc, "VEC3", "morph target positions", mi)
                if len(d) != b.count:
                    self._bad(f"mesh {mi} has a morph target whose vertex count differs from its positions'")
                parts.append(d)
            local = np.concatenate(parts)
            if not np.isfinite(local).all():
                self._bad(f"mesh {mi} has NaN or infinite morph target deltas")
            out[name] = _apply(linear, local)
        return out

    # ------------------------------------------------------------------ structure
    def _bad(self, what: str):
        raise DamagedGltf(f"'{self._label}' is not a valid glTF file ({what}); export it again")

    def _mesh_name(self, mi: int) -> str:
        name = self._json["meshes"][mi].get("name")
        return name if isinstance(name, str) and name else f"mesh{mi}"

    def _check_mesh(self, mesh_index) -> int:
        count = len(self._json.get("meshes", []))
        if not _is_int(mesh_index) and not isinstance(mesh_index, np.integer):
            raise MeshError(f"mesh index must be a whole number (0..{count - 1}), not {type(mesh_index).__name__}")
        mi = int(mesh_index)
        if not 0 <= mi < count:
            raise MeshError(f"'{self._label}' has no mesh {mi} (it has {count}: 0..{count - 1}); "
                            "see Scene.meshes()")
        problem = self._problem(mi)
        if problem:
            raise MeshError(f"mesh '{shown(self._mesh_name(mi))}' of '{self._label}' {problem}")
        return mi

    def _problem(self, mi: int) -> str | None:
        """Why mesh ``mi`` cannot be edited (None when it can)."""
        prims = self._json["meshes"][mi]["primitives"]
        accessors = self._json.get("accessors", [])
        for p, prim in enumerate(prims):
            mode = prim.get("mode", 4)
            if mode != 4:
                return (f"primitive {p} is {_MODES[mode]}, not triangles; faceanim edits triangle meshes only "
                        "(pick another mesh)")
            pos = prim["attributes"].get("POSITION")
            if pos is None:
                return f"primitive {p} has no positions; pick another mesh"
            a = accessors[pos]
            if a["type"] != "VEC3" or a["componentType"] != 5126 or a.get("normalized"):
                return (f"primitive {p} stores positions as other than float VEC3 (quantised); export the avatar "
                        "without mesh quantisation")
            if len(prim.get("targets", [])) != len(prims[0].get("targets", [])):
                return "has primitives with different morph target counts (invalid glTF); export it again"
        return None

    def _users(self, mi: int) -> list[int]:
        return [n for n, node in enumerate(self._json.get("nodes", [])) if node.get("mesh") == mi]

    def _skin(self, mi: int) -> int | None:
        users = self._users(mi)
        return self._json["nodes"][users[0]].get("skin") if users else None

    def _blocks(self, mi: int) -> list[_Block]:
        key = ("blocks", mi)
        if key not in self._cache:
            blocks: dict = {}
            accessors = self._json.get("accessors", [])
            for p, prim in enumerate(self._json["meshes"][mi]["primitives"]):
                attrs = prim["attributes"]
                if "POSITION" not in attrs:
                    continue
                skinning = tuple(sorted((k, v) for k, v in attrs.items() if k.startswith(("JOINTS_", "WEIGHTS_"))))
                targets = tuple(tuple(sorted(t.items())) for t in prim.get("targets", []))
                ident = (attrs["POSITION"], attrs.get("TEXCOORD_0"), skinning, targets)
                if ident in blocks:
                    blocks[ident][0].append(p)
                else:
                    blocks[ident] = ([p], attrs, prim.get("targets", []))
            out, offset = [], 0
            for prims, attrs, targets in blocks.values():
                count = accessors[attrs["POSITION"]]["count"]
                out.append(_Block(tuple(prims), offset, count, attrs, tuple(targets)))
                offset += count
            self._cache[key] = out
        return self._cache[key]

    def _target_names(self, mi: int) -> list[str]:
        mesh = self._json["meshes"][mi]
        n = len(mesh["primitives"][0].get("targets", []))
        names = None
        for extras in (mesh.get("extras"), mesh["primitives"][0].get("extras")):
            candidate = extras.get("targetNames") if isinstance(extras, dict) else None
            if isinstance(candidate, list) and all(isinstance(s, str) for s in candidate):
                names = candidate
                break
        names = list(names or [])[:n]
        return names + [f"target_{k}" for k in range(len(names), n)]

    # ------------------------------------------------------------------ data
    def _read(self, index: int) -> np.ndarray:
        """Accessor ``index`` as stored: (count, width) of its component type, sparse values applied."""
        key = ("accessor", index)
        if key in self._cache:
            return self._cache[key]
        a = self._json["accessors"][index]
        dtype = np.dtype(_COMPONENTS[a["componentType"]])
        width = _WIDTH[a["type"]]
        count = a["count"]
        if "bufferView" in a:
            view = self._json["bufferViews"][a["bufferView"]]
            elem = width * dtype.itemsize
            rows = np.ndarray((count, elem), dtype=np.uint8, buffer=self._bin,
                              offset=view.get("byteOffset", 0) + a.get("byteOffset", 0),
                              strides=(view.get("byteStride") or elem, 1))
            out = np.ascontiguousarray(rows).view(dtype).reshape(count, width)
        else:
            out = np.zeros((count, width), dtype=dtype)
        sparse = a.get("sparse")
        if sparse:
            n = sparse["count"]
            ind, val = sparse["indices"], sparse["values"]
            iview, vview = self._json["bufferViews"][ind["bufferView"]], self._json["bufferViews"][val["bufferView"]]
            idx = np.frombuffer(self._bin, dtype=_COMPONENTS[ind["componentType"]], count=n,
                                offset=iview.get("byteOffset", 0) + ind.get("byteOffset", 0)).astype(np.int64)
            values = np.frombuffer(self._bin, dtype=dtype, count=n * width,
                                   offset=vview.get("byteOffset", 0) + val.get("byteOffset", 0))
            if idx.max() >= count:
                self._bad(f"accessor {index} has sparse indices past its count")
            out = out.copy()
            out[idx] = values.reshape(n, width)
        self._cache[key] = out
        return out

    def _floats(self, index: int, kind: str, what: str, mi: int, normalized: bool = False) -> np.ndarray:
        """A float accessor (or, with ``normalized``, normalised integers) as float64 (count, width)."""
        a = self._json["accessors"][index]
        if a["type"] != kind:
            self._bad(f"mesh {mi} has {what} of type {a['type']}, not {kind}")
        raw = self._read(index)
        if a["componentType"] == 5126:
            return raw.astype(np.float64)
        if normalized and a.get("normalized") and raw.dtype.str in _NORMALIZED:
            return np.maximum(raw.astype(np.float64) / _NORMALIZED[raw.dtype.str], -1.0)
        raise MeshError(f"mesh '{shown(self._mesh_name(mi))}' of '{self._label}' stores {what} as integers "
                        "(quantised); export the avatar without mesh quantisation")

    def _ints(self, index: int, kind: str, what: str, mi: int) -> np.ndarray:
        """An unsigned integer accessor of type ``kind`` as int64 (count, width)."""
        a = self._json["accessors"][index]
        if a["componentType"] not in (5121, 5123, 5125) or a.get("normalized") or a["type"] != kind:
            self._bad(f"mesh {mi} has {what} that are not unsigned {kind} integers")
        return self._read(index).astype(np.int64)

    def _local_positions(self, mi: int) -> np.ndarray:
        parts = [self._floats(b.attributes["POSITION"], "VEC3", "positions", mi) for b in self._blocks(mi)]
        v = np.concatenate(parts) if parts else np.zeros((0, 3))
        if not np.isfinite(v).all() or (np.abs(v) > MAX_COORDINATE).any():
            self._bad(f"mesh {mi} has NaN, infinite or absurd positions")
        return v

    def _world_positions(self, mi: int) -> np.ndarray:
        key = ("world", mi)
        if key not in self._cache:
            linear, shift = self._frames(mi)
            world = _apply(linear, self._local_positions(mi)) + shift
            if not np.isfinite(world).all() or (np.abs(world) > MAX_COORDINATE).any():
                self._bad(f"mesh {mi} lands at absurd world positions (node or skin matrices)")
            self._cache[key] = world
        return self._cache[key]

    def _frames(self, mi: int) -> tuple[np.ndarray, np.ndarray]:
        """The map from mesh to world space: (3, 3) and (3,) for all vertices, or (V, 3, 3) and (V, 3)."""
        key = ("frames", mi)
        if key in self._cache:
            return self._cache[key]
        users = self._users(mi)
        skin = self._skin(mi)
        with np.errstate(all="ignore"):
            if skin is None:
                m = self._globals[users[0]] if users else np.eye(4)
                result = (m[:3, :3], m[:3, 3])
            else:
                result = self._skin_frames(mi, skin)
        if not all(np.isfinite(r).all() and (np.abs(r) <= MAX_COORDINATE).all() for r in result):
            self._bad(f"mesh {mi} is placed by absurd node or skin matrices")
        self._cache[key] = result
        return result

    def _skin_frames(self, mi: int, skin_index: int) -> tuple[np.ndarray, np.ndarray]:
        skin = self._json["skins"][skin_index]
        joints = skin["joints"]
        if "inverseBindMatrices" in skin:
            ibm = self._floats(skin["inverseBindMatrices"], "MAT4", "inverse bind matrices", mi)
            if len(ibm) < len(joints) or not np.isfinite(ibm).all():
                self._bad(f"skin {skin_index} has too few or non-finite inverse bind matrices")
            ibm = ibm[:len(joints)].reshape(-1, 4, 4).transpose(0, 2, 1)  # column-major
        else:
            ibm = np.broadcast_to(np.eye(4), (len(joints), 4, 4))
        joint_maps = np.stack([self._globals[j] for j in joints]) @ ibm
        fallback = joint_maps.mean(0)
        out = []
        for b in self._blocks(mi):
            m = np.zeros((b.count, 4, 4))
            total = np.zeros(b.count)
            for k in range(len(b.attributes)):
                jk, wk = b.attributes.get(f"JOINTS_{k}"), b.attributes.get(f"WEIGHTS_{k}")
                if jk is None or wk is None:
                    break
                j = self._ints(jk, "VEC4", "joint indices", mi)
                w = self._floats(wk, "VEC4", "skin weights", mi, normalized=True)
                if j.shape != (b.count, 4) or w.shape != (b.count, 4):
                    self._bad(f"mesh {mi} has joint indices or weights that do not match its vertices")
                if not np.isfinite(w).all() or (w < 0).any():
                    self._bad(f"mesh {mi} has negative or non-finite skin weights")
                used = w > 0
                if (j[used] >= len(joints)).any():
                    self._bad(f"mesh {mi} has joint indices past its skin's joints")
                j = np.where(used, j, 0)
                m += np.einsum("vk,vkij->vij", w, joint_maps[j])
                total += w.sum(1)
            ok = total > 0
            m[ok] /= total[ok, None, None]
            m[~ok] = fallback
            out.append(m)
        m = np.concatenate(out) if out else np.zeros((0, 4, 4))
        return m[:, :3, :3], m[:, :3, 3]


def _apply(linear: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``linear @ v`` row by row (one (3, 3) matrix or one per row)."""
    return v @ linear.T if linear.ndim == 2 else np.einsum("vij,vj->vi", linear, v)


def _local_matrix(node: dict) -> np.ndarray:
    if "matrix" in node:
        return np.asarray(node["matrix"], dtype=np.float64).reshape(4, 4).T  # column-major
    m = np.eye(4)
    if "rotation" in node:
        x, y, z, w = np.asarray(node["rotation"], dtype=np.float64) / np.linalg.norm(node["rotation"])
        m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    if "scale" in node:
        m[:3, :3] = m[:3, :3] * np.asarray(node["scale"], dtype=np.float64)[None, :]
    if "translation" in node:
        m[:3, 3] = node["translation"]
    return m


def _global_matrices(gltf: dict, bad) -> list[np.ndarray]:
    """Every node's global matrix; refuses a node with two parents or a cycle."""
    nodes = gltf.get("nodes", [])
    parent = [-1] * len(nodes)
    for n, node in enumerate(nodes):
        for c in node.get("children", []):
            if parent[c] != -1 or c == n:
                bad(f"node {c} has more than one parent or is its own child")
            parent[c] = n
    out: list = [None] * len(nodes)
    stack = [(n, np.eye(4)) for n in range(len(nodes)) if parent[n] == -1]
    while stack:
        n, above = stack.pop()
        out[n] = above @ _local_matrix(nodes[n])
        stack.extend((c, out[n]) for c in nodes[n].get("children", []))
    if any(m is None for m in out):
        bad("its node hierarchy has a cycle")
    return out


# ====================================================================== reading
def read_scene(path: str | os.PathLike) -> Scene:
    """Read a binary glTF 2.0 or VRM avatar (``.glb``/``.vrm``) into a :class:`Scene`, checking the
    container, its JSON and every accessor's bounds before anything is decoded."""
    path = Path(path)
    label = shown(path, 80, tail=True)
    if str(path) == "" or not path.exists():
        raise InputFileError(f"avatar file '{label}' does not exist; check the path")
    if path.is_dir():
        raise InputFileError(f"avatar '{label}' is a folder; give a .glb or .vrm file")
    if not path.is_file():
        raise InputFileError(f"avatar '{label}' is not a regular file; give a .glb or .vrm file")
    damaged = MeshError(f"'{label}' is not a binary glTF (GLB/VRM) file or is damaged; give a .glb or .vrm "
                        "exported again")
    try:
        size = path.stat().st_size
        if size == 0:
            raise MeshError(f"avatar '{label}' is empty; give a .glb or .vrm file")
        if size > MAX_SCENE_BYTES:
            raise MeshError(f"avatar '{label}' is larger than {MAX_SCENE_BYTES >> 20} MB; faceanim edits "
                            "avatars up to that size")
        with open(path, "rb") as fh:
            head = fh.read(12)
            if head[:1] == b"{":
                raise MeshError(f"'{label}' is glTF JSON; faceanim edits binary glTF: convert it to .glb "
                                "(e.g. with gltf-transform copy)")
            if len(head) < 12 or head[:4] != b"glTF":
                raise damaged
            if int.from_bytes(head[4:8], "little") != 2:
                raise MeshError(f"'{label}' is not glTF 2.0 (GLB version {int.from_bytes(head[4:8], 'little')}); "
                                "convert it to glTF 2.0")
            if int.from_bytes(head[8:12], "little") != size:
                raise MeshError(f"'{label}' is truncated or damaged (its header gives another length than the "
                                "file's); export it again")
            data = fh.read()
    except OSError as exc:
        raise InputFileError(f"cannot read avatar '{label}': {exc.strerror or 'read error'}") from None
    text, binary = _chunks(data, label, damaged)
    try:
        # some exporters pad the JSON chunk with zeros instead of spaces
        gltf = json.loads(text.rstrip(b"\0 ").decode("utf-8"), parse_constant=_no_constants, parse_float=_finite)
    except (ValueError, UnicodeDecodeError, RecursionError):
        raise damaged from None
    if not isinstance(gltf, dict):
        raise damaged
    _check_document(gltf, len(binary), label)
    try:
        document = g.GLTF2.from_json(json.dumps(gltf))
    except Exception:  # noqa: BLE001 -- any failure of pygltflib on a damaged document
        raise damaged from None
    return Scene(path, document, gltf, binary)


def _chunks(data: bytes, label: str, damaged: MeshError) -> tuple[bytes, bytes]:
    """The JSON and BIN chunks after the 12-byte GLB header (other chunk types are skipped)."""
    pos, text, binary = 0, None, None
    while pos + 8 <= len(data):
        length = int.from_bytes(data[pos:pos + 4], "little")
        kind = data[pos + 4:pos + 8]
        if pos + 8 + length > len(data):
            raise MeshError(f"'{label}' is truncated (a chunk runs past the end of the file); export it again")
        if text is None:
            if kind != b"JSON":
                raise damaged
            if length > MAX_JSON_BYTES:
                raise MeshError(f"'{label}' has more than {MAX_JSON_BYTES >> 20} MB of glTF JSON; faceanim edits "
                                "avatars up to that size")
            text = data[pos + 8:pos + 8 + length]
        elif kind == b"BIN\0" and binary is None:
            binary = data[pos + 8:pos + 8 + length]
        pos += 8 + length
    if text is None:
        raise damaged
    return text, binary if binary is not None else b""


def _check_document(gltf: dict, bin_len: int, label: str) -> None:
    """Refuse (one MeshError) every structure this module would trip on: wrong types, indices out of
    range, accessors past their buffer views, views past the binary chunk, outside data, compression."""

    def bad(what):
        raise DamagedGltf(f"'{label}' is not a valid glTF file ({what}); export it again")

    asset = gltf.get("asset")
    if not isinstance(asset, dict) or not isinstance(asset.get("version"), str) \
            or not asset["version"].startswith("2."):
        raise MeshError(f"'{label}' is not glTF 2.0 (its asset version is missing or another); convert it to "
                        "glTF 2.0")
    for key in _ARRAYS:
        if key in gltf and not (isinstance(gltf[key], list) and all(isinstance(x, dict) for x in gltf[key])):
            bad(f"'{key}' is not a list of objects")
    for key in ("extensionsUsed", "extensionsRequired"):
        if key in gltf and not (isinstance(gltf[key], list) and all(isinstance(x, str) for x in gltf[key])):
            bad(f"'{key}' is not a list of names")
    for ext in _COMPRESSION:
        if ext in gltf.get("extensionsUsed", []) + gltf.get("extensionsRequired", []):
            raise MeshError(f"'{label}' has compressed or quantised geometry ({ext}); export the avatar "
                            "without mesh compression")
    n = {key: len(gltf.get(key, [])) for key in _ARRAYS}

    def index(value, key, what):
        if not (_is_int(value) and 0 <= value < n[key]):
            bad(f"{what} is not an index into {key}")
        return value

    buffers = gltf.get("buffers", [])
    for k, item in enumerate(buffers + gltf.get("images", [])):
        if "uri" in item:
            where = "a buffer" if k < len(buffers) else "an image"
            raise MeshError(f"'{label}' keeps {where} outside its binary chunk (a uri: an external file or a "
                            "data: URI); pack it into one .glb (e.g. gltf-transform copy) and try again")
    if len(buffers) > 1:
        bad("more than one buffer")
    for b in buffers:
        if not _is_int(b.get("byteLength")) or b["byteLength"] < 1:
            bad("a buffer has no valid byteLength")
        if b["byteLength"] > bin_len:
            raise MeshError(f"'{label}' is truncated (its binary chunk is shorter than its buffer); export it again")
    views = gltf.get("bufferViews", [])
    for k, v in enumerate(views):
        index(v.get("buffer"), "buffers", f"bufferView {k}'s buffer")
        off, length, stride = v.get("byteOffset", 0), v.get("byteLength"), v.get("byteStride")
        if not (_is_int(off) and off >= 0 and _is_int(length) and length >= 1):
            bad(f"bufferView {k} has an invalid offset or length")
        if off + length > buffers[v["buffer"]]["byteLength"]:
            bad(f"bufferView {k} runs past its buffer")
        if stride is not None and not (_is_int(stride) and 4 <= stride <= 252):
            bad(f"bufferView {k} has an invalid byteStride")
    for k, a in enumerate(gltf.get("accessors", [])):
        ct, kind, count = a.get("componentType"), a.get("type"), a.get("count")
        if not (_is_int(ct) and ct in _COMPONENTS and isinstance(kind, str) and kind in _WIDTH
                and _is_int(count) and count >= 1):
            bad(f"accessor {k} has an invalid component type, type or count")
        off = a.get("byteOffset", 0)
        if not (_is_int(off) and off >= 0) or not isinstance(a.get("normalized", False), bool):
            bad(f"accessor {k} has an invalid byteOffset or normalized flag")
        size = np.dtype(_COMPONENTS[ct]).itemsize
        elem = _WIDTH[kind] * size
        if kind in ("MAT2", "MAT3") and size < 4:  # matrix columns start on 4-byte boundaries
            elem = {("MAT2", 1): 8, ("MAT3", 1): 12, ("MAT3", 2): 24}.get((kind, size), elem)
        if "bufferView" in a:
            view = views[index(a["bufferView"], "bufferViews", f"accessor {k}'s bufferView")]
            stride = view.get("byteStride") or elem
            if off + stride * (count - 1) + elem > view["byteLength"]:
                bad(f"accessor {k} runs past its bufferView")
        elif count * _WIDTH[kind] > MAX_ZERO_ELEMENTS:
            raise MeshError(f"'{label}': accessor {k} asks for {count} zero elements; faceanim reads accessors up "
                            f"to {MAX_ZERO_ELEMENTS} elements without data")
        sparse = a.get("sparse")
        if sparse is None:
            continue
        if not isinstance(sparse, dict) or not (_is_int(sparse.get("count")) and 1 <= sparse["count"] <= count):
            bad(f"accessor {k} has an invalid sparse count")
        for part, item_size in (("indices", None), ("values", elem)):
            p = sparse.get(part)
            if not isinstance(p, dict):
                bad(f"accessor {k} has no sparse {part}")
            if part == "indices":
                if p.get("componentType") not in (5121, 5123, 5125):
                    bad(f"accessor {k} has sparse indices of an invalid type")
                item_size = np.dtype(_COMPONENTS[p["componentType"]]).itemsize
            view = views[index(p.get("bufferView"), "bufferViews", f"accessor {k}'s sparse {part}")]
            poff = p.get("byteOffset", 0)
            if not (_is_int(poff) and poff >= 0) or poff + sparse["count"] * item_size > view["byteLength"]:
                bad(f"accessor {k}'s sparse {part} run past their bufferView")
    for k, node in enumerate(gltf.get("nodes", [])):
        for c in node.get("children", []) if isinstance(node.get("children", []), list) else [None]:
            index(c, "nodes", f"a child of node {k}")
        for key, target in (("mesh", "meshes"), ("skin", "skins"), ("camera", "cameras")):
            if key in node:
                index(node[key], target, f"node {k}'s {key}")
        for key, size in (("matrix", 16), ("translation", 3), ("rotation", 4), ("scale", 3)):
            if key in node and not _numbers(node[key], size):
                bad(f"node {k} has an invalid {key}")
        if "rotation" in node and not np.linalg.norm(node["rotation"]) > 1e-6:
            bad(f"node {k} has a zero rotation quaternion")
        if "weights" in node and not (isinstance(node["weights"], list)
                                      and all(type(w) in (int, float) for w in node["weights"])):
            bad(f"node {k} has invalid morph weights")
    total = 0
    for k, mesh in enumerate(gltf.get("meshes", [])):
        prims = mesh.get("primitives")
        if not isinstance(prims, list) or not prims or not all(isinstance(p, dict) for p in prims):
            bad(f"mesh {k} has no primitives")
        if "weights" in mesh and not (isinstance(mesh["weights"], list)
                                      and all(type(w) in (int, float) for w in mesh["weights"])):
            bad(f"mesh {k} has invalid morph weights")
        seen = set()
        for p, prim in enumerate(prims):
            attrs = prim.get("attributes")
            if not isinstance(attrs, dict):
                bad(f"mesh {k} primitive {p} has no attributes")
            for name, acc in attrs.items():
                index(acc, "accessors", f"mesh {k} primitive {p} attribute")
            if "indices" in prim:
                index(prim["indices"], "accessors", f"mesh {k} primitive {p} indices")
            if "material" in prim:
                index(prim["material"], "materials", f"mesh {k} primitive {p} material")
            if not (_is_int(prim.get("mode", 4)) and prim.get("mode", 4) in _MODES):
                bad(f"mesh {k} primitive {p} has an invalid mode")
            targets = prim.get("targets", [])
            if not isinstance(targets, list) or not all(isinstance(t, dict) for t in targets):
                bad(f"mesh {k} primitive {p} has invalid morph targets")
            for t in targets:
                for acc in t.values():
                    index(acc, "accessors", f"mesh {k} primitive {p} morph target")
            if "POSITION" in attrs and attrs["POSITION"] not in seen:
                seen.add(attrs["POSITION"])
                total += gltf["accessors"][attrs["POSITION"]]["count"]
    if total > MAX_SCENE_VERTICES:
        raise MeshError(f"'{label}' has more than {MAX_SCENE_VERTICES} vertices; faceanim edits avatars up to "
                        "that size")
    for k, skin in enumerate(gltf.get("skins", [])):
        joints = skin.get("joints")
        if not isinstance(joints, list) or not joints:
            bad(f"skin {k} has no joints")
        for j in joints:
            index(j, "nodes", f"a joint of skin {k}")
        for key, target in (("inverseBindMatrices", "accessors"), ("skeleton", "nodes")):
            if key in skin:
                index(skin[key], target, f"skin {k}'s {key}")
    for k, scene in enumerate(gltf.get("scenes", [])):
        for node in scene.get("nodes", []) if isinstance(scene.get("nodes", []), list) else [None]:
            index(node, "nodes", f"a root of scene {k}")
    if "scene" in gltf:
        index(gltf["scene"], "scenes", "the default scene")
    for k, anim in enumerate(gltf.get("animations", [])):
        samplers, channels = anim.get("samplers"), anim.get("channels")
        if not (isinstance(samplers, list) and isinstance(channels, list)
                and all(isinstance(x, dict) for x in samplers + channels)):
            bad(f"animation {k} has invalid samplers or channels")
        for s in samplers:
            index(s.get("input"), "accessors", f"animation {k}'s sampler input")
            index(s.get("output"), "accessors", f"animation {k}'s sampler output")
        for c in channels:
            if not (_is_int(c.get("sampler")) and 0 <= c["sampler"] < len(samplers)) \
                    or not isinstance(c.get("target"), dict):
                bad(f"animation {k} has an invalid channel")
            if "node" in c["target"]:
                index(c["target"]["node"], "nodes", f"animation {k}'s channel target")


# ====================================================================== welding
def weld(mesh: Mesh, tolerance: float = WELD_TOLERANCE) -> tuple[Mesh, np.ndarray]:
    """Join vertices at the same position (closer than ``tolerance`` times the bounding-box diagonal)
    so that a mesh split into primitives (lips, eyes, skin) is one surface; returns the welded Mesh
    and the (V,) index of each input vertex's welded vertex (``welded_delta[index]`` gives a delta
    back in the input's order). Welded vertices keep the first joined vertex's position, in order of
    first appearance; UVs are kept per triangle corner (``face_uv``)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    v = mesh.vertices
    radius = tolerance * mesh.bounding_box_diagonal
    if not radius > 0:  # all vertices at one point (or no tolerance): weld exact copies only
        labels = np.unique(v, axis=0, return_inverse=True)[1].ravel()
    else:
        pairs = cKDTree(v).query_pairs(radius, output_type="ndarray")
        n = len(v)
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        labels = connected_components(graph, directed=False)[1]
    # number the groups by their first vertex, keeping the input order
    first = np.full(labels.max() + 1, len(v))
    np.minimum.at(first, labels, np.arange(len(v)))
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    index = rank[labels]
    welded = Mesh(v[np.sort(first)], index[mesh.faces], uv=mesh.uv, face_uv=mesh.face_uv, texture=mesh.texture,
                  name=mesh.name, source=mesh.source)
    return welded, index


# ====================================================================== writing
class _Appender:
    """New buffer views and accessors appended after the original binary data."""

    def __init__(self, binary: bytes, n_views: int, n_accessors: int):
        self.data = bytearray(binary)
        self.views: list[g.BufferView] = []
        self.accessors: list[g.Accessor] = []
        self.n_views, self.n_accessors = n_views, n_accessors

    def _view(self, raw: bytes, target: int | None = None) -> int:
        while len(self.data) % 4:
            self.data.append(0)
        self.views.append(g.BufferView(buffer=0, byteOffset=len(self.data), byteLength=len(raw), target=target))
        self.data.extend(raw)
        return self.n_views + len(self.views) - 1

    def _accessor(self, acc: g.Accessor) -> int:
        self.accessors.append(acc)
        return self.n_accessors + len(self.accessors) - 1

    def delta(self, d: np.ndarray) -> int:
        """A float32 VEC3 morph delta: no data when all zero, sparse under half the rows, else dense."""
        d = np.ascontiguousarray(d, dtype=np.float32)
        bounds = dict(min=[float(x) for x in d.min(0)], max=[float(x) for x in d.max(0)])
        moved = np.flatnonzero(np.any(d != 0, axis=1))
        if moved.size == 0:
            return self._accessor(g.Accessor(componentType=g.FLOAT, count=len(d), type=g.VEC3, byteOffset=None,
                                             **bounds))
        if moved.size < 0.5 * len(d):
            itype, icomp = (np.uint16, g.UNSIGNED_SHORT) if len(d) <= 65536 else (np.uint32, g.UNSIGNED_INT)
            iview = self._view(moved.astype(itype).tobytes())
            vview = self._view(d[moved].tobytes())
            sparse = g.Sparse(count=int(moved.size), indices=g.AccessorSparseIndices(bufferView=iview,
                                                                                     componentType=icomp),
                              values=g.AccessorSparseValues(bufferView=vview))
            return self._accessor(g.Accessor(componentType=g.FLOAT, count=len(d), type=g.VEC3, byteOffset=None,
                                             sparse=sparse, **bounds))
        view = self._view(d.tobytes(), g.ARRAY_BUFFER)
        return self._accessor(g.Accessor(bufferView=view, componentType=g.FLOAT, count=len(d), type=g.VEC3,
                                         **bounds))

    def quaternions(self, values: np.ndarray) -> int:
        """(F, 4) float32 quaternions (x, y, z, w): a rotation channel's output."""
        v = np.ascontiguousarray(values, dtype=np.float32)
        view = self._view(v.tobytes())
        return self._accessor(g.Accessor(bufferView=view, componentType=g.FLOAT, count=len(v), type=g.VEC4))

    def scalars(self, values: np.ndarray, bounds: bool = False) -> int:
        """Float32 scalars; with ``bounds``, their min and max (an animation's key times need them)."""
        v = np.ascontiguousarray(values, dtype=np.float32)
        view = self._view(v.tobytes())
        extra = dict(min=[float(v.min())], max=[float(v.max())]) if bounds and len(v) else {}
        return self._accessor(g.Accessor(bufferView=view, componentType=g.FLOAT, count=len(v), type=g.SCALAR, **extra))


def write_scene(scene: Scene, path: str | os.PathLike, additions: Mapping, replace: bool = False,
                animation: dict | None = None) -> Path:
    """Write ``scene`` to ``path`` (``.glb`` or ``.vrm``, the same GLB container) atomically, with the
    morph targets ``additions`` = {mesh index: {name: (V, 3) world-space delta in
    :meth:`Scene.mesh_geometry`'s vertex order}} added to those meshes; everything else as it was read
    (see the module doc). A name the mesh already has is refused unless ``replace``.

    ``animation``: a new animation to add, ``{"name": str, "times": (F,) seconds, "weights": {mesh
    index: (F, n) weights of that mesh's n targets (after the additions)}}``: one linear sampler per
    mesh, one ``weights`` channel per node that shows the mesh; and ``"rotations": {node index: (F,
    4) unit quaternions (x, y, z, w)}``, that node's local rotation (a node with a ``matrix`` cannot
    be animated: refused)."""
    path = Path(path)
    if path.suffix.lower() not in SCENE_SUFFIXES:
        raise MeshError(f"cannot write avatar '{shown(path, 80, tail=True)}': use the .glb or .vrm suffix")
    check_output_path(path, "avatar output")
    if not isinstance(additions, Mapping):
        raise MeshError("additions must map mesh indices to {target name: (V, 3) delta}")
    plan = []
    for mesh_index, shapes in additions.items():
        mi = scene._check_mesh(mesh_index)
        label = f"mesh '{shown(scene._mesh_name(mi))}'"
        if not isinstance(shapes, Mapping):
            raise MeshError(f"additions for {label} must map target names to (V, 3) deltas")
        n_vertices = sum(b.count for b in scene._blocks(mi))
        names = scene._target_names(mi)
        checked = {}
        for name, delta in shapes.items():
            if not isinstance(name, str) or not name:
                raise MeshError(f"morph target names for {label} must be non-empty text")
            if name in names and not replace:
                raise MeshError(f"{label} already has a morph target '{shown(name)}'; choose another name or "
                                "pass replace=True to replace it")
            try:
                d = np.asarray(delta, dtype=np.float64)
            except (TypeError, ValueError):
                d = np.zeros(0)
            if d.shape != (n_vertices, 3) or not np.isfinite(d).all() or (np.abs(d) > MAX_COORDINATE).any():
                raise MeshError(f"morph target '{shown(name)}' of {label} must be a finite ({n_vertices}, 3) array")
            checked[name] = d
        plan.append((mi, checked))

    doc = copy.deepcopy(scene.document)
    buffer_length = scene._json["buffers"][0]["byteLength"] if scene._json.get("buffers") else 0
    out = _Appender(scene._bin[:buffer_length], len(doc.bufferViews), len(doc.accessors))
    widened: set = set()
    for mi, shapes in plan:
        _add_targets(scene, doc, out, mi, shapes, widened)
    if animation is not None:
        _add_animation(scene, doc, out, animation)
    if out.views:
        while len(out.data) % 4:
            out.data.append(0)
        if doc.buffers:
            doc.buffers[0].byteLength = len(out.data)
        else:
            doc.buffers = [g.Buffer(byteLength=len(out.data))]
        doc.bufferViews = list(doc.bufferViews) + out.views
    doc.accessors = list(doc.accessors) + out.accessors
    try:
        text = json.dumps(_plain(doc, scene._json), allow_nan=False, separators=(",", ":"))
    except (TypeError, ValueError):
        raise MeshError("the scene's document holds values JSON cannot store (NaN, infinity or objects); "
                        "check what was edited in scene.document") from None
    blob = _glb(text.encode("ascii"), bytes(out.data))
    if len(blob) >= 1 << 32:
        raise MeshError("the avatar would be larger than the 4 GB a GLB file can hold; add fewer targets")
    with atomic_output(path, "avatar output") as tmp:
        tmp.write_bytes(blob)
    return path


def _add_targets(scene: Scene, doc: g.GLTF2, out: _Appender, mi: int, shapes: dict, widened: set) -> None:
    """Append (or replace) the targets ``shapes`` of mesh ``mi`` in ``doc``."""
    if not shapes:
        return
    blocks = scene._blocks(mi)
    linear, _ = scene._frames(mi)
    inverse = np.linalg.pinv(linear)
    names = scene._target_names(mi)
    n_old = len(names)
    mesh = doc.meshes[mi]
    for prim in mesh.primitives:
        prim.targets = list(prim.targets or [])
    for name, world in shapes.items():
        local = _apply(inverse, world)
        k = names.index(name) if name in names else None
        for b in blocks:
            acc = out.delta(local[b.offset:b.offset + b.count])
            for p in b.prims:
                if k is None:
                    mesh.primitives[p].targets.append({"POSITION": acc})
                else:
                    mesh.primitives[p].targets[k] = {"POSITION": acc}
        if k is None:
            names.append(name)
    n_new = len(names)
    if n_new == n_old:
        return
    if mesh.extras is None:
        mesh.extras = {}
    if not isinstance(mesh.extras, dict):
        raise MeshError(f"mesh '{shown(scene._mesh_name(mi))}' has extras that are not an object; the target "
                        "names cannot be recorded (fix the mesh's extras)")
    mesh.extras["targetNames"] = list(names)
    for prim in mesh.primitives:  # UniVRM (VRM 0.x) keeps the names on the primitives
        if isinstance(prim.extras, dict) and isinstance(prim.extras.get("targetNames"), list):
            prim.extras["targetNames"] = list(names)
    pad = [0.0] * (n_new - n_old)
    mesh.weights = (list(mesh.weights or []) + [0.0] * n_old)[:n_old] + pad
    users = scene._users(mi)
    for n in users:  # pygltflib has no field for a node's weights: _plain writes this attribute
        weights = scene._json["nodes"][n].get("weights")
        if weights:
            doc.nodes[n].weights = (list(weights) + [0.0] * n_old)[:n_old] + pad
    for a, anim in enumerate(doc.animations):
        for channel in anim.channels:
            if channel.target is None or channel.target.path != "weights" or channel.target.node not in users:
                continue
            if (a, channel.sampler) in widened:
                continue
            widened.add((a, channel.sampler))
            sampler = anim.samplers[channel.sampler]
            values = scene._floats(scene._json["animations"][a]["samplers"][channel.sampler]["output"], "SCALAR",
                                   "animated morph weights", mi, normalized=True).ravel()
            if n_old == 0 or values.size % n_old:
                scene._bad(f"animation {a} animates a number of weights that does not fit mesh {mi}'s targets")
            rows = values.reshape(-1, n_old)
            sampler.output = out.scalars(np.hstack([rows, np.zeros((len(rows), n_new - n_old))]).ravel())


def _add_animation(scene: Scene, doc: g.GLTF2, out: _Appender, animation: dict) -> None:
    times = np.asarray(animation.get("times"), dtype=np.float64).ravel()
    if times.size < 1 or not np.isfinite(times).all() or (np.diff(times) <= 0).any() or times[0] < 0:
        raise MeshError("an animation's key times must be finite, from 0 and increasing")
    channels, samplers = [], []
    time_acc = out.scalars(times, bounds=True)
    for mesh_index, weights in sorted(animation.get("weights", {}).items()):
        mi = scene._check_mesh(mesh_index)
        n = len(doc.meshes[mi].primitives[0].targets or [])
        w = np.asarray(weights, dtype=np.float64)
        if w.shape != (len(times), n) or not np.isfinite(w).all():
            raise MeshError(f"the animation of mesh '{shown(scene._mesh_name(mi))}' needs ({len(times)}, {n}) finite "
                            "weights")
        samplers.append(g.AnimationSampler(input=time_acc, output=out.scalars(w.ravel()), interpolation="LINEAR"))
        for node in scene._users(mi):
            channels.append(g.AnimationChannel(sampler=len(samplers) - 1,
                                               target=g.AnimationChannelTarget(node=node, path="weights")))
    nodes = scene._json.get("nodes", [])
    for node, q in sorted(animation.get("rotations", {}).items()):
        if not _is_int(node) or not 0 <= node < len(nodes) or "matrix" in nodes[node]:
            raise MeshError(f"the animation's rotation channel needs a node without a matrix, got node {shown(node)}")
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (len(times), 4) or not np.isfinite(q).all() or np.abs(np.linalg.norm(q, axis=1) - 1).max() > 1e-3:
            raise MeshError(f"the rotation of node {node} needs ({len(times)}, 4) unit quaternions")
        samplers.append(g.AnimationSampler(input=time_acc, output=out.quaternions(q), interpolation="LINEAR"))
        channels.append(g.AnimationChannel(sampler=len(samplers) - 1,
                                           target=g.AnimationChannelTarget(node=int(node), path="rotation")))
    if not channels:
        raise MeshError("the animation drives no mesh shown by a node")
    doc.animations = list(doc.animations or []) + [g.Animation(name=str(animation.get("name", "animation")),
                                                               samplers=samplers, channels=channels)]


def _plain(obj, raw):
    """``obj`` (a pygltflib object) as JSON data: the keys of the original (``raw``) kept, also those
    pygltflib has no field for, pygltflib's defaults for keys the original did not have left out, new
    values kept; ``extensions`` and ``extras`` are written as they are."""
    if dataclasses.is_dataclass(obj):
        out = {}
        for f in dataclasses.fields(obj):
            value = getattr(obj, f.name)
            known = isinstance(raw, dict) and f.name in raw
            if value is None:
                continue
            if not known:
                if f.default is not dataclasses.MISSING:
                    default = f.default
                elif f.default_factory is not dataclasses.MISSING:
                    default = f.default_factory()
                else:
                    default = dataclasses.MISSING
                if value == default or (isinstance(value, (list, dict, str)) and len(value) == 0):
                    continue
            if f.name in ("extensions", "extras"):
                out[f.name] = value
            else:
                out[f.name] = _plain(value, raw[f.name] if known else None)
        if isinstance(raw, dict):  # properties pygltflib has no field for (node weights, unknown ones)
            names = {f.name for f in dataclasses.fields(obj)}
            out.update((k, getattr(obj, k, v)) for k, v in raw.items() if k not in names)
        return out
    if isinstance(obj, g.Attributes):
        return {k: v for k, v in vars(obj).items() if v is not None}
    if isinstance(obj, list):
        return [_plain(x, raw[i] if isinstance(raw, list) and i < len(raw) else None) for i, x in enumerate(obj)]
    if isinstance(obj, dict):
        return {k: _plain(v, raw.get(k) if isinstance(raw, dict) else None) for k, v in obj.items()}
    return obj


def _glb(text: bytes, binary: bytes) -> bytes:
    """A GLB container: header, JSON chunk (space-padded), BIN chunk (zero-padded) when there is data."""
    text = text + b" " * (-len(text) % 4)
    binary = binary + b"\0" * (-len(binary) % 4)
    chunks = len(text).to_bytes(4, "little") + b"JSON" + text
    if binary:
        chunks += len(binary).to_bytes(4, "little") + b"BIN\0" + binary
    return b"glTF" + (2).to_bytes(4, "little") + (12 + len(chunks)).to_bytes(4, "little") + chunks
