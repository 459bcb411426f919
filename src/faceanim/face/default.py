"""faceanim's embedded default face: a whole head built from a real photograph.

``scripts/build_default_face.py`` made it from scikit-image's ``astronaut`` photo with faceanim's
own photo pipeline (:mod:`faceanim.build.photo`, Lee et al. 1999): the generic head
(:mod:`faceanim.face.generic_head`, the ICT FaceKit head) fitted to the photo's face, with skin,
eyeballs, teeth, gums, tongue and mouth cavity as parts of one mesh, a neutral mouth (the photo's
smile fitted, then taken off, the corners lowered by the script's ``NEUTRAL_MOUTH``) and one
texture atlas. The asset stores the vertices and texture
coordinates; triangles, parts and the 478 landmarks (on triangles) are the generic head's. Units
are metres; the face looks along +z with +y up.
"""

from __future__ import annotations

from functools import lru_cache
from importlib import resources

import numpy as np

from faceanim.face.generic_head import generic_head
from faceanim.face.landmarks import SCHEMES, Landmarks
from faceanim.face.mesh import Mesh


def _asset(name: str):
    return resources.files("faceanim").joinpath("assets", name)


@lru_cache(maxsize=1)
def _default_arrays() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    from PIL import Image

    with _asset("default_head.npz").open("rb") as fh:
        data = dict(np.load(fh))
    with _asset("default_head.png").open("rb") as fh:
        texture = np.asarray(Image.open(fh).convert("RGB")).copy()
    return (data["vertices"].astype(np.float64), data["uv"].astype(np.float64),
            data["face_uv"].astype(np.int64), texture)


def default_face() -> Mesh:
    """The default face: a textured full head (24,591 vertices, the generic head's topology)."""
    head = generic_head()
    vertices, uv, face_uv, texture = _default_arrays()
    return Mesh(vertices.copy(), head.mesh.faces.copy(), uv.copy(), face_uv.copy(), texture.copy(),
                head.mesh.polygon_sizes.copy(), name="default_face", source="faceanim:default_face")


def default_shapes(prefix: str = "") -> dict[str, np.ndarray]:
    """The generic head's 53 expression shapes (ARKit names) carried onto the default face."""
    with _asset("default_head.npz").open("rb") as fh:
        affine = np.load(fh)["affine"]
    return generic_head().carried_shapes(affine[:, :3], prefix)


def default_parts() -> dict[str, np.ndarray]:
    """Part name -> vertex indices of the default face (skin, gums_tongue, teeth, eyeballs)."""
    return {k: v.copy() for k, v in generic_head().parts.items()}


def default_landmarks(mesh: Mesh | None = None, scheme: str = "mediapipe478") -> Landmarks:
    """The default face's own landmarks (on its triangles; on ``mesh``'s vertices when given, a
    deformed copy of the default face)."""
    head = generic_head()
    vertices = _default_arrays()[0] if mesh is None else mesh.vertices
    pos = head.landmarks(vertices)
    pairs = SCHEMES[scheme]
    idx = np.array([i for _, i in pairs])
    return Landmarks(scheme, [n for n, _ in pairs], idx, pos[idx], head.landmark_triangles[idx].copy(),
                     head.landmark_barycentric[idx].copy(), "faceanim:default_face")
