"""faceanim's embedded default face, built from a real photograph.

``scripts/build_default_face.py`` made the asset from scikit-image's ``astronaut`` photo with the
MediaPipe face mesh (see that script). Here it is turned into a :class:`Mesh`: the 479-vertex
face-mesh topology, or a smooth ~30k-vertex version by three Loop subdivisions. Texture
coordinates are the projection of each vertex into the photo, so they stay exact on the
subdivided mesh. Vertex ``i`` < 478 of either version is MediaPipe landmark ``i``. Units are
metres; the face looks along +z with +y up.
"""

from __future__ import annotations

from importlib import resources

import numpy as np

from faceanim.face.landmarks import SCHEMES, Landmarks
from faceanim.face.mesh import Mesh

SUBDIVISIONS = 3


def _asset(name: str):
    return resources.files("faceanim").joinpath("assets", name)


def default_face(dense: bool = True) -> Mesh:
    """The default face: dense (~30k vertices, three Loop subdivisions) or the 479-vertex base."""
    from PIL import Image
    from trimesh.remesh import subdivide_loop

    with _asset("default_face.npz").open("rb") as fh:
        data = dict(np.load(fh))
    with _asset("default_face.png").open("rb") as fh:
        texture = np.asarray(Image.open(fh).convert("RGB")).copy()
    pix = data["image_vertices"]
    faces = data["faces"].astype(np.int64)
    if dense:
        pix, faces = subdivide_loop(pix, faces, SUBDIVISIONS)
    ox, oy = data["crop_origin"]
    cw, ch = data["crop_size"]
    uv = np.stack([(pix[:, 0] - ox) / cw, 1.0 - ((-pix[:, 1]) - oy) / ch], axis=1)
    t = data["transform"]
    vertices = pix @ t[:3, :3].T + t[:3, 3]
    name = "default_face" if dense else "default_face_base"
    return Mesh(vertices, faces, uv, None, texture, name=name, source=f"faceanim:{name}")


def default_landmarks(mesh: Mesh, scheme: str = "mediapipe478") -> Landmarks:
    """The default face's own landmarks (vertex ``i`` is MediaPipe point ``i``)."""
    pairs = SCHEMES[scheme]
    idx = np.array([i for _, i in pairs])
    tri = np.full(mesh.n_vertices, -1, dtype=np.int64)
    corner = np.full(mesh.n_vertices, 0, dtype=np.int64)
    for k in range(3):
        tri[mesh.faces[::-1, k]] = np.arange(mesh.n_faces)[::-1]
    for k in range(3):
        corner[idx[mesh.faces[tri[idx], k] == idx]] = k
    bary = np.zeros((len(idx), 3))
    bary[np.arange(len(idx)), corner[idx]] = 1.0
    return Landmarks(scheme, [n for n, _ in pairs], idx, mesh.vertices[idx].copy(), tri[idx], bary, mesh.source)
