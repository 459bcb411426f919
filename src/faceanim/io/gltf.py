"""Binary glTF 2.0 (GLB) export: mesh, texture, morph targets and their animation.

Every blendshape becomes a morph target (names in ``mesh.extras.targetNames``, the convention
Blender, three.js and Babylon read); a target that moves less than half of the vertices is
stored as a sparse accessor (only the moving rows). An animation drives the morph weights with
linear interpolation. glTF stores one UV per vertex, so vertices on UV seams are duplicated; the
first V vertices are the source mesh's, in its order, and the seam copies follow
(``primitive.extras.sourceVertex`` maps every glTF vertex back to the source vertex).

``quantize=True`` writes a compact file with KHR_mesh_quantization (declared used and required):

- positions and morph-target position deltas are normalised int16 (SHORT) in one local frame:
  ``world = s * local + t`` with ``t`` the bounding-box centre and the uniform ``s`` the largest
  of the mesh's half-extents and of the deltas' components, stored as the node's ``scale`` and
  ``translation``. glTF adds the deltas to the positions before the node transform, so both share
  the one scale: a morph accessor cannot carry its own. The worst error of any coordinate,
  position or delta, is half a step, ``s / 32767 / 2`` (2.5 micrometres on the default head,
  5.4e-6 of its 47 cm bounding-box diagonal; see :func:`quantization_frame`). The scale is
  uniform so the normals need no correction for a non-uniform node scale;
- normals are normalised int8 (BYTE), texture coordinates normalised uint16 (when all lie in
  [0, 1]; otherwise they stay float), triangle indices uint16 when the mesh has fewer than 65535
  vertices;
- a morph target keeps only the rows whose quantised delta is non-zero, as a sparse accessor
  with uint16 row indices whenever that is smaller than the dense, 8-byte-aligned rows;
- the animation's times and weights stay float (they are small and weights may leave [0, 1]).

Viewers that implement the extension (three.js's GLTFLoader, Babylon.js) read these files as
they are; a reader that ignores accessor normalisation (trimesh 5.2's glTF loader, and so
:func:`faceanim.io.meshio.load_mesh`) gets the raw integers and a mesh thousands of times too
large: keep ``quantize`` for delivery, and the plain file for round trips.
"""

from __future__ import annotations

import io
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pygltflib as g

from faceanim.errors import FaceAnimError, shown
from faceanim.face.mesh import Mesh, vertex_normals
from faceanim.io.files import atomic_output

SKIN_FACTOR = [0.87, 0.72, 0.62, 1.0]
QUANTIZATION_EXTENSION = "KHR_mesh_quantization"
_COMPONENT = {np.dtype(np.float32): g.FLOAT, np.dtype(np.uint32): g.UNSIGNED_INT,
              np.dtype(np.uint16): g.UNSIGNED_SHORT, np.dtype(np.int16): g.SHORT,
              np.dtype(np.uint8): g.UNSIGNED_BYTE, np.dtype(np.int8): g.BYTE}


class _Buffer:
    def __init__(self):
        self.data = bytearray()
        self.views: list[g.BufferView] = []
        self.accessors: list[g.Accessor] = []

    def _view(self, raw: bytes, target: int | None = None, stride: int | None = None) -> int:
        while len(self.data) % 4:
            self.data.append(0)
        self.views.append(g.BufferView(buffer=0, byteOffset=len(self.data), byteLength=len(raw), target=target,
                                       byteStride=stride))
        self.data.extend(raw)
        return len(self.views) - 1

    def add(self, array: np.ndarray, component: int, kind: str, target: int | None = None,
            minmax: bool = False, normalized: bool = False) -> int:
        array = np.ascontiguousarray(array)
        count = array.shape[0]
        a = array.reshape(count, -1)
        stride = None
        if target == g.ARRAY_BUFFER and (a.shape[1] * a.itemsize) % 4:
            # a vertex attribute's elements must start on 4-byte boundaries: pad each row
            pad = (4 - (a.shape[1] * a.itemsize) % 4) // a.itemsize
            padded = np.zeros((count, a.shape[1] + pad), dtype=a.dtype)
            padded[:, :a.shape[1]] = a
            raw, stride = padded.tobytes(), padded.shape[1] * a.itemsize
        else:
            raw = array.tobytes()
        acc = g.Accessor(bufferView=self._view(raw, target, stride), componentType=component, count=count, type=kind)
        if normalized:
            acc.normalized = True
        if minmax:
            acc.min = _bounds(a.min(0))
            acc.max = _bounds(a.max(0))
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def add_sparse(self, array: np.ndarray, rows: np.ndarray, index_dtype=np.uint32, normalized: bool = False) -> int:
        """A VEC3 accessor of ``array``'s dtype that is zero except at ``rows`` (glTF sparse accessor;
        with no rows, a plain all-zero accessor without buffer views, which may not be empty)."""
        views = [self._view(np.ascontiguousarray(part).tobytes())
                 for part in (rows.astype(index_dtype), array[rows])] if rows.size else []
        acc = g.Accessor(componentType=_COMPONENT[array.dtype], count=array.shape[0], type=g.VEC3,
                         min=_bounds(array.min(0)), max=_bounds(array.max(0)))
        if normalized:
            acc.normalized = True
        acc.byteOffset = None  # no bufferView: the base values are zeros
        if rows.size:
            acc.sparse = g.Sparse(count=int(rows.size),
                                  indices=g.AccessorSparseIndices(bufferView=views[0],
                                                                  componentType=_COMPONENT[np.dtype(index_dtype)]),
                                  values=g.AccessorSparseValues(bufferView=views[1]))
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def add_image(self, png: bytes) -> int:
        return self._view(png)


def _bounds(values: np.ndarray) -> list:
    """Accessor min/max: the stored values (before any normalisation), as JSON numbers."""
    return [float(x) for x in values]


def quantization_frame(vertices: np.ndarray, deltas=()) -> tuple[np.ndarray, float]:
    """The node translation ``t`` and uniform scale ``s`` that ``quantize=True`` uses for these
    positions and morph deltas, in the mesh's units: stored int16 ``q`` means ``s * q / 32767``
    (plus ``t`` for positions), so no coordinate is off by more than ``s / 32767 / 2``."""
    v = np.asarray(vertices, dtype=np.float64)
    lo, hi = v.min(0), v.max(0)
    centre = (lo + hi) / 2
    scale = float(np.max(hi - lo)) / 2
    for d in deltas:
        scale = max(scale, float(np.max(np.abs(d), initial=0.0)))
    if not scale > 0:
        scale = 1.0  # a single point and no deltas: any scale is exact
    return centre, scale


def _quantize_signed(x: np.ndarray, dtype) -> np.ndarray:
    top = np.iinfo(dtype).max
    return np.clip(np.rint(x * top), -top, top).astype(dtype)


def _check_extras(extras: Any) -> dict:
    if not isinstance(extras, dict):
        raise FaceAnimError(f"extras must be a dict of JSON values, not {type(extras).__name__}")
    try:
        same = json.loads(json.dumps(extras, allow_nan=False)) == extras
    except (TypeError, ValueError) as e:
        raise FaceAnimError(f"extras must hold JSON values only (str keys; str, finite numbers, bools, None, "
                            f"lists, dicts): {e}") from None
    if not same:
        raise FaceAnimError("extras must hold JSON values only (str keys; lists, not tuples; plain Python types)")
    return extras


def write_gltf(path: str | os.PathLike, mesh: Mesh, blendshapes: Mapping[str, np.ndarray] | None = None,
               times: np.ndarray | None = None, weights: np.ndarray | None = None,
               animation_name: str = "expressions", *, quantize: bool = False,
               extras: dict | None = None, rotations: np.ndarray | None = None,
               pivot: np.ndarray | None = None) -> Path:
    """Write ``mesh`` as GLB with optional morph targets and a morph-weight animation.

    The parameters are :func:`build_gltf`'s; the file is written atomically (see
    :func:`faceanim.io.files.atomic_output`)."""
    gltf = build_gltf(mesh, blendshapes, times, weights, animation_name, quantize=quantize, extras=extras,
                      rotations=rotations, pivot=pivot)
    return save_glb(gltf, path)


def save_glb(gltf: g.GLTF2, path: str | os.PathLike) -> Path:
    """Write a document made by :func:`build_gltf` (its binary blob set) to ``path`` atomically."""
    path = Path(path)
    with atomic_output(path) as tmp:
        gltf.save_binary(str(tmp))
    return path


def checked_blendshapes(mesh: Mesh, blendshapes: Mapping[str, np.ndarray] | None) -> dict[str, np.ndarray]:
    """``blendshapes`` as a dict, each checked to be a finite (V, 3) array for ``mesh``."""
    out = dict(blendshapes or {})
    for name, d in out.items():
        d = np.asarray(d)
        if d.shape != mesh.vertices.shape or not np.all(np.isfinite(d)):
            raise FaceAnimError(f"blendshape '{shown(name)}' must be a finite ({mesh.n_vertices}, 3) array")
    return out


def build_gltf(mesh: Mesh, blendshapes: Mapping[str, np.ndarray] | None = None,
               times: np.ndarray | None = None, weights: np.ndarray | None = None,
               animation_name: str = "expressions", *, quantize: bool = False,
               extras: dict | None = None, rotations: np.ndarray | None = None,
               pivot: np.ndarray | None = None) -> g.GLTF2:
    """The glTF document :func:`write_gltf` writes, with its binary blob set: node 0 holds mesh 0
    (one primitive), the scene's root is node 0 (or, with ``rotations``, the ``head`` node
    above it); writers of glTF-based formats (:mod:`faceanim.io.vrm`) add their nodes and
    extensions to it and write it with :func:`save_glb`.

    Parameters
    ----------
    blendshapes : name -> (V, 3) vertex displacement
    times : (F,) seconds, increasing; with ``weights`` (F, C), one column per blendshape
    quantize : compact output with KHR_mesh_quantization (see the module docstring for the
        layout and its error bound); off by default
    extras : JSON-safe metadata stored as the scene's ``extras`` (three.js: ``gltf.scene.userData``;
        Blender: the scene's custom properties), e.g. ``{"audio": "speech.wav"}``
    rotations : (F, 4) unit quaternions (x, y, z, w) at ``times``: the head turning about ``pivot``
        (3,), animated on a parent node ``head`` at the pivot (the mesh keeps its coordinates: a
        child node takes the pivot off again)
    """
    blendshapes = checked_blendshapes(mesh, blendshapes)
    names = list(blendshapes)
    if (times is None) != (weights is None):
        raise FaceAnimError("give both times and weights for an animation, or neither")
    if extras is not None:
        extras = _check_extras(extras)

    source, faces, uv = mesh.per_vertex_uv()
    buf = _Buffer()
    normals = vertex_normals(mesh.vertices, mesh.faces)[source]
    tex = None
    if uv is not None:
        tex = uv.astype(np.float32).copy()
        tex[:, 1] = 1.0 - tex[:, 1]  # glTF's v runs downwards
    node = g.Node(name=mesh.name, mesh=0)
    targets = []
    if not quantize:
        pos = mesh.vertices[source].astype(np.float32)
        attrs = g.Attributes(POSITION=buf.add(pos, g.FLOAT, g.VEC3, g.ARRAY_BUFFER, minmax=True))
        attrs.NORMAL = buf.add(normals.astype(np.float32), g.FLOAT, g.VEC3, g.ARRAY_BUFFER)
        if tex is not None:
            attrs.TEXCOORD_0 = buf.add(tex, g.FLOAT, g.VEC2, g.ARRAY_BUFFER)
        idx = buf.add(faces.astype(np.uint32).ravel(), g.UNSIGNED_INT, g.SCALAR, g.ELEMENT_ARRAY_BUFFER,
                      minmax=True)
        for name in names:
            d = np.asarray(blendshapes[name], dtype=np.float32)[source]
            moved = np.flatnonzero(np.any(d != 0, axis=1))
            if moved.size < 0.5 * len(d):
                # local expressions (GDEs) move a small part of the face: store only those rows
                targets.append(g.Attributes(POSITION=buf.add_sparse(d, moved)))
            else:
                targets.append(g.Attributes(POSITION=buf.add(d, g.FLOAT, g.VEC3, g.ARRAY_BUFFER, minmax=True)))
    else:
        n_out = len(source)
        small = n_out < 65535  # 65535 is the primitive-restart value, never a valid uint16 index
        centre, scale = quantization_frame(mesh.vertices, [np.asarray(d) for d in blendshapes.values()])
        node.translation = [float(x) for x in centre]
        node.scale = [scale] * 3
        qpos = _quantize_signed((np.asarray(mesh.vertices, dtype=np.float64)[source] - centre) / scale, np.int16)
        attrs = g.Attributes(POSITION=buf.add(qpos, g.SHORT, g.VEC3, g.ARRAY_BUFFER, minmax=True,
                                              normalized=True))
        attrs.NORMAL = buf.add(_quantize_signed(normals, np.int8), g.BYTE, g.VEC3, g.ARRAY_BUFFER, normalized=True)
        if tex is not None:
            if np.all((tex >= 0) & (tex <= 1)):
                qtex = np.rint(tex.astype(np.float64) * 65535).astype(np.uint16)
                attrs.TEXCOORD_0 = buf.add(qtex, g.UNSIGNED_SHORT, g.VEC2, g.ARRAY_BUFFER, normalized=True)
            else:  # normalised unsigned values cover [0, 1] only
                attrs.TEXCOORD_0 = buf.add(tex, g.FLOAT, g.VEC2, g.ARRAY_BUFFER)
        fdtype, fcomp = (np.uint16, g.UNSIGNED_SHORT) if small else (np.uint32, g.UNSIGNED_INT)
        idx = buf.add(faces.astype(fdtype).ravel(), fcomp, g.SCALAR, g.ELEMENT_ARRAY_BUFFER, minmax=True)
        rdtype = np.uint16 if small else np.uint32
        for name in names:
            q = _quantize_signed(np.asarray(blendshapes[name], dtype=np.float64)[source] / scale, np.int16)
            moved = np.flatnonzero(np.any(q != 0, axis=1))
            # dense rows are padded to 8 bytes; a sparse row costs its index and 6 bytes
            if moved.size * (np.dtype(rdtype).itemsize + 6) < n_out * 8:
                targets.append(g.Attributes(POSITION=buf.add_sparse(q, moved, rdtype, normalized=True)))
            else:
                targets.append(g.Attributes(POSITION=buf.add(q, g.SHORT, g.VEC3, g.ARRAY_BUFFER, minmax=True,
                                                             normalized=True)))

    gltf = g.GLTF2(asset=g.Asset(generator="faceanim", version="2.0"))
    if quantize:
        gltf.extensionsUsed = [QUANTIZATION_EXTENSION]
        gltf.extensionsRequired = [QUANTIZATION_EXTENSION]
    material = g.Material(name="skin", doubleSided=True,
                          pbrMetallicRoughness=g.PbrMetallicRoughness(metallicFactor=0.0, roughnessFactor=0.7))
    if uv is not None and mesh.texture is not None:
        from PIL import Image

        png = io.BytesIO()
        Image.fromarray(mesh.texture).save(png, format="PNG")
        view = buf.add_image(png.getvalue())
        gltf.images = [g.Image(bufferView=view, mimeType="image/png")]
        gltf.samplers = [g.Sampler(magFilter=g.LINEAR, minFilter=g.LINEAR_MIPMAP_LINEAR)]
        gltf.textures = [g.Texture(sampler=0, source=0)]
        material.pbrMetallicRoughness.baseColorTexture = g.TextureInfo(index=0)
    else:
        material.pbrMetallicRoughness.baseColorFactor = SKIN_FACTOR
    gltf.materials = [material]
    prim = g.Primitive(attributes=attrs, indices=idx, material=0, mode=g.TRIANGLES)
    if targets:
        prim.targets = targets
    if len(source) > mesh.n_vertices:
        prim.extras = {"sourceVertex": source.tolist()}
    gm = g.Mesh(name=mesh.name, primitives=[prim])
    if names:
        gm.weights = [0.0] * len(names)
        gm.extras = {"targetNames": names}
    gltf.meshes = [gm]
    gltf.nodes = [node]
    gltf.scenes = [g.Scene(nodes=[0])]
    head = None
    if rotations is not None:
        q = np.asarray(rotations, dtype=np.float64)
        pv = np.zeros(3) if pivot is None else np.asarray(pivot, dtype=np.float64)
        if times is None or q.shape != (len(times), 4) or not np.all(np.isfinite(q)) or pv.shape != (3,) \
                or not np.all(np.isfinite(pv)) or np.any(np.abs(np.linalg.norm(q, axis=1) - 1) > 1e-3):
            raise FaceAnimError("head rotations must be (F, 4) unit quaternions at the F animation times, "
                                "about a finite (3,) pivot")
        offset = g.Node(name="head_offset", translation=[float(-x) for x in pv], children=[0])
        head = g.Node(name="head", translation=[float(x) for x in pv], children=[1])
        gltf.nodes = [node, offset, head]
        gltf.scenes = [g.Scene(nodes=[2])]
    if extras:
        gltf.scenes[0].extras = extras
    gltf.scene = 0

    if times is not None:
        with np.errstate(over="ignore", invalid="ignore"):  # out of float32's range: refused below
            t = np.asarray(times, dtype=np.float32)
            w = np.asarray(weights, dtype=np.float32)
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(w))):
            raise FaceAnimError("animation times and weights must be finite 32-bit numbers (a frame rate far too "
                                "small makes the times overflow); check the frame rate")
        if not names:
            raise FaceAnimError("an animation needs blendshapes to drive")
        if t.ndim != 1 or w.shape != (t.size, len(names)):
            raise FaceAnimError(f"weights must have shape ({t.size}, {len(names)}) for {t.size} times")
        if t.size < 1 or np.any(np.diff(t) <= 0) or t[0] < 0:
            raise FaceAnimError("animation times must be >= 0 and strictly increasing")
        ti = buf.add(t, g.FLOAT, g.SCALAR, minmax=True)
        wo = buf.add(w.ravel(), g.FLOAT, g.SCALAR)
        samplers = [g.AnimationSampler(input=ti, output=wo, interpolation="LINEAR")]
        channels = [g.AnimationChannel(sampler=0, target=g.AnimationChannelTarget(node=0, path="weights"))]
        if head is not None:
            qo = buf.add(np.asarray(rotations, dtype=np.float32), g.FLOAT, g.VEC4)
            samplers.append(g.AnimationSampler(input=ti, output=qo, interpolation="LINEAR"))
            channels.append(g.AnimationChannel(sampler=1, target=g.AnimationChannelTarget(node=2, path="rotation")))
        gltf.animations = [g.Animation(name=animation_name, samplers=samplers, channels=channels)]

    while len(buf.data) % 4:
        buf.data.append(0)
    gltf.buffers = [g.Buffer(byteLength=len(buf.data))]
    gltf.bufferViews = buf.views
    gltf.accessors = buf.accessors
    gltf.set_binary_blob(bytes(buf.data))
    return gltf


def glb_json(path: str | os.PathLike, limit: int = 64 << 20) -> dict | None:
    """The JSON chunk of a GLB file (None when the file is not a readable GLB); only the header
    and that chunk are read; a pipe or device is no GLB (reading it could wait for ever)."""
    try:
        if not Path(path).is_file():
            return None
        with open(path, "rb") as fh:
            head = fh.read(20)
            if len(head) < 20 or head[:4] != b"glTF":
                return None
            length = int.from_bytes(head[12:16], "little")
            if head[16:20] != b"JSON" or not 0 < length <= limit:
                return None
            doc = json.loads(fh.read(length))
        return doc if isinstance(doc, dict) else None
    except (OSError, ValueError, RecursionError):
        return None


def sound_companion(glb: str | os.PathLike) -> Path:
    """Where the sound of an animated GLB goes: the file its earlier version names in the scene's
    ``extras.audio`` (we wrote it: it is replaced with the GLB), else ``OUT.wav``, else
    ``OUT-1.wav``, ... - never a file the user did not name or we did not write."""
    out = Path(glb)
    doc = glb_json(out) if out.is_file() else None
    if doc:
        scenes = doc.get("scenes") or [{}]
        named = (scenes[0].get("extras") or {}).get("audio") if isinstance(scenes[0], dict) else None
        if isinstance(named, str) and Path(named).name == named and named.lower().endswith(".wav"):
            return out.with_name(named)
    candidate, k = out.with_suffix(".wav"), 1
    while os.path.lexists(candidate):  # a dangling link is taken too
        candidate = out.with_name(f"{out.stem}-{k}.wav")
        k += 1
    return candidate
