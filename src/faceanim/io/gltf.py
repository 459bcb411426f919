"""Binary glTF 2.0 (GLB) export: mesh, texture, morph targets and their animation.

Every blendshape becomes a morph target (names in ``mesh.extras.targetNames``, the convention
Blender, three.js and Babylon read); a target that moves less than half of the vertices is
stored as a sparse accessor (only the moving rows). An animation drives the morph weights with
linear interpolation. glTF stores one UV per vertex, so vertices on UV seams are duplicated; the
first V vertices are the source mesh's, in its order, and the seam copies follow
(``primitive.extras.sourceVertex`` maps every glTF vertex back to the source vertex).
"""

from __future__ import annotations

import io
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pygltflib as g

from faceanim.errors import FaceAnimError
from faceanim.face.mesh import Mesh, vertex_normals
from faceanim.io.files import atomic_output

SKIN_FACTOR = [0.87, 0.72, 0.62, 1.0]


class _Buffer:
    def __init__(self):
        self.data = bytearray()
        self.views: list[g.BufferView] = []
        self.accessors: list[g.Accessor] = []

    def add(self, array: np.ndarray, component: int, kind: str, target: int | None = None,
            minmax: bool = False) -> int:
        while len(self.data) % 4:
            self.data.append(0)
        raw = np.ascontiguousarray(array).tobytes()
        self.views.append(g.BufferView(buffer=0, byteOffset=len(self.data), byteLength=len(raw), target=target))
        self.data.extend(raw)
        count = array.shape[0]
        acc = g.Accessor(bufferView=len(self.views) - 1, componentType=component, count=count, type=kind)
        if minmax:
            a = array.reshape(count, -1)
            acc.min = [float(x) for x in a.min(0)]
            acc.max = [float(x) for x in a.max(0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def add_sparse(self, array: np.ndarray, rows: np.ndarray) -> int:
        """A VEC3 float accessor that is zero except at ``rows`` (glTF sparse accessor)."""
        views = []
        for part in (rows.astype(np.uint32), np.ascontiguousarray(array[rows], dtype=np.float32)):
            while len(self.data) % 4:
                self.data.append(0)
            raw = part.tobytes()
            self.views.append(g.BufferView(buffer=0, byteOffset=len(self.data), byteLength=len(raw)))
            self.data.extend(raw)
            views.append(len(self.views) - 1)
        acc = g.Accessor(componentType=g.FLOAT, count=array.shape[0], type=g.VEC3,
                         min=[float(x) for x in array.min(0)], max=[float(x) for x in array.max(0)])
        acc.byteOffset = None  # no bufferView: the base values are zeros
        if rows.size:
            acc.sparse = g.Sparse(count=int(rows.size),
                                  indices=g.AccessorSparseIndices(bufferView=views[0], componentType=g.UNSIGNED_INT),
                                  values=g.AccessorSparseValues(bufferView=views[1]))
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def add_image(self, png: bytes) -> int:
        while len(self.data) % 4:
            self.data.append(0)
        self.views.append(g.BufferView(buffer=0, byteOffset=len(self.data), byteLength=len(png)))
        self.data.extend(png)
        return len(self.views) - 1


def write_gltf(path: str | os.PathLike, mesh: Mesh, blendshapes: Mapping[str, np.ndarray] | None = None,
               times: np.ndarray | None = None, weights: np.ndarray | None = None,
               animation_name: str = "expressions") -> Path:
    """Write ``mesh`` as GLB with optional morph targets and a morph-weight animation.

    Parameters
    ----------
    blendshapes : name -> (V, 3) vertex displacement
    times : (F,) seconds, increasing; with ``weights`` (F, C), one column per blendshape
    """
    path = Path(path)
    blendshapes = dict(blendshapes or {})
    names = list(blendshapes)
    for name, d in blendshapes.items():
        d = np.asarray(d)
        if d.shape != mesh.vertices.shape or not np.all(np.isfinite(d)):
            raise FaceAnimError(f"blendshape '{name}' must be a finite ({mesh.n_vertices}, 3) array")
    if (times is None) != (weights is None):
        raise FaceAnimError("give both times and weights for an animation, or neither")

    source, faces, uv = mesh.per_vertex_uv()
    buf = _Buffer()
    pos = mesh.vertices[source].astype(np.float32)
    attrs = g.Attributes(POSITION=buf.add(pos, g.FLOAT, g.VEC3, g.ARRAY_BUFFER, minmax=True))
    attrs.NORMAL = buf.add(vertex_normals(mesh.vertices, mesh.faces)[source].astype(np.float32),
                           g.FLOAT, g.VEC3, g.ARRAY_BUFFER)
    if uv is not None:
        tex = uv.astype(np.float32).copy()
        tex[:, 1] = 1.0 - tex[:, 1]  # glTF's v runs downwards
        attrs.TEXCOORD_0 = buf.add(tex, g.FLOAT, g.VEC2, g.ARRAY_BUFFER)
    idx = buf.add(faces.astype(np.uint32).ravel(), g.UNSIGNED_INT, g.SCALAR, g.ELEMENT_ARRAY_BUFFER, minmax=True)
    targets = []
    for name in names:
        d = np.asarray(blendshapes[name], dtype=np.float32)[source]
        moved = np.flatnonzero(np.any(d != 0, axis=1))
        if moved.size < 0.5 * len(d):
            # local expressions (GDEs) move a small part of the face: store only those rows
            targets.append(g.Attributes(POSITION=buf.add_sparse(d, moved)))
        else:
            targets.append(g.Attributes(POSITION=buf.add(d, g.FLOAT, g.VEC3, g.ARRAY_BUFFER, minmax=True)))

    gltf = g.GLTF2(asset=g.Asset(generator="faceanim", version="2.0"))
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
    gltf.nodes = [g.Node(name=mesh.name, mesh=0)]
    gltf.scenes = [g.Scene(nodes=[0])]
    gltf.scene = 0

    if times is not None:
        t = np.asarray(times, dtype=np.float32)
        w = np.asarray(weights, dtype=np.float32)
        if not names:
            raise FaceAnimError("an animation needs blendshapes to drive")
        if t.ndim != 1 or w.shape != (t.size, len(names)):
            raise FaceAnimError(f"weights must have shape ({t.size}, {len(names)}) for {t.size} times")
        if t.size < 1 or np.any(np.diff(t) <= 0) or t[0] < 0:
            raise FaceAnimError("animation times must be >= 0 and strictly increasing")
        ti = buf.add(t, g.FLOAT, g.SCALAR, minmax=True)
        wo = buf.add(w.ravel(), g.FLOAT, g.SCALAR)
        gltf.animations = [g.Animation(
            name=animation_name,
            samplers=[g.AnimationSampler(input=ti, output=wo, interpolation="LINEAR")],
            channels=[g.AnimationChannel(sampler=0, target=g.AnimationChannelTarget(node=0, path="weights"))],
        )]

    while len(buf.data) % 4:
        buf.data.append(0)
    gltf.buffers = [g.Buffer(byteLength=len(buf.data))]
    gltf.bufferViews = buf.views
    gltf.accessors = buf.accessors
    gltf.set_binary_blob(bytes(buf.data))
    with atomic_output(path) as tmp:
        gltf.save_binary(str(tmp))
    return path
