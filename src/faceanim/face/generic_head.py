"""The generic head that photos deform: the ICT FaceKit neutral head (MIT licence).

Lee et al. (1999, 2.1.2) start every person from "a previously constructed, animation-ready
generic model" with eyeballs and teeth, deformed onto the feature points found in the photos.
faceanim ships the ICT Face Model's generic neutral head (``assets/generic_head.npz``, built by
``scripts/build_generic_head.py``; licence notice ``assets/LICENSE-ICT-FaceKit.txt``): 24,591
vertices in metres (+z forward, +y up, +x the subject's left) with the parts

    skin (head, neck, mouth socket, eye sockets), gums_tongue, teeth, eyeball_L, eyeball_R

as separate shells of one mesh, its 478 MediaPipe landmarks attached to its triangles, and its
53 expression blendshapes (ARKit names, ``_L``/``_R`` halves) as deltas, and ICT's 100 PCA identity
modes: a morphable head, ``neutral + sum_i w_i mode_i`` with a standard normal prior on ``w``
(:meth:`GenericHead.identity_basis`; how they are stored: the build script's docstring).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from importlib import resources

import numpy as np
import scipy.sparse as sp

from faceanim.face.mesh import Mesh


@dataclass(frozen=True, eq=False)
class GenericHead:
    """The generic head: mesh, parts, landmarks and expression blendshapes.

    Attributes
    ----------
    mesh : Mesh (no UVs: a head from photos gets its own atlas)
    parts : part name -> (n,) vertex indices
    landmark_triangles, landmark_barycentric : (478,), (478, 3): MediaPipe landmark ``i`` on the
        surface (use :meth:`landmarks` for positions on any deformed copy)
    shapes : expression name -> (V, 3) sparse-stored delta, see :meth:`shape`
    """

    mesh: Mesh
    parts: dict
    landmark_triangles: np.ndarray
    landmark_barycentric: np.ndarray
    shape_names: tuple
    _shapes: dict
    _identity: tuple = (np.zeros((0, 0, 3), np.int8), np.zeros(0, np.float32))

    @property
    def n_identity(self) -> int:
        """How many identity modes the head has."""
        return len(self._identity[1])

    def identity_basis(self, count: int | None = None) -> np.ndarray:
        """(K, V, 3) float32: the first ``count`` (all by default) identity modes, each the
        displacement of one standard deviation of head shape (metres)."""
        q, scale = self._identity
        k = len(scale) if count is None else int(count)
        return q[:k].astype(np.float32) * scale[:k, None, None]

    def identity(self, weights) -> np.ndarray:
        """(V, 3) the neutral head of identity ``weights`` (K,) (the first K modes)."""
        w = np.asarray(weights, dtype=np.float64).ravel()
        q, scale = self._identity
        out = self.mesh.vertices.copy()
        for k in np.flatnonzero(w):
            out += (w[k] * float(scale[k])) * q[k]
        return out

    def landmarks(self, vertices: np.ndarray | None = None) -> np.ndarray:
        """(478, 3) landmark positions on the head (or on ``vertices``, a deformed copy)."""
        v = self.mesh.vertices if vertices is None else np.asarray(vertices, dtype=np.float64)
        corners = v[self.mesh.faces[self.landmark_triangles]]  # (478, 3, 3)
        return np.einsum("lk,lkd->ld", self.landmark_barycentric, corners)

    def landmarks_on(self, mesh: Mesh) -> np.ndarray | None:
        """(478, 3) landmarks of ``mesh`` if it has this head's topology (a head fitted from it:
        same vertex count and triangles), else None."""
        if mesh.n_vertices != self.mesh.n_vertices or mesh.faces.shape != self.mesh.faces.shape:
            return None
        if not np.array_equal(mesh.faces, self.mesh.faces):
            return None
        return self.landmarks(mesh.vertices)

    def landmark_matrix(self) -> sp.csr_matrix:
        """(478, V) sparse matrix with ``landmarks(v) == L @ v``."""
        rows = np.repeat(np.arange(478), 3)
        cols = self.mesh.faces[self.landmark_triangles].ravel()
        return sp.csr_matrix((self.landmark_barycentric.ravel(), (rows, cols)), shape=(478, self.mesh.n_vertices))

    def shape(self, name: str) -> np.ndarray:
        """(V, 3) delta of one expression blendshape (e.g. ``jawOpen``, ``mouthSmile_L``)."""
        rows, delta = self._shapes[name]
        out = np.zeros((self.mesh.n_vertices, 3))
        out[rows] = delta
        return out

    def sparse_shape(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """One expression blendshape as stored: (rows (n,), deltas (n, 3)) of the vertices it moves."""
        return self._shapes[name]

    def carried_shapes(self, linear: np.ndarray | None = None, prefix: str = "") -> dict[str, np.ndarray]:
        """All expression shapes carried onto a head fitted from this one: each delta turned by the
        fit's linear part ``linear`` (3, 3) (the global affine of the fit; identity if None)."""
        lin = np.eye(3) if linear is None else np.asarray(linear, dtype=np.float64)
        return {f"{prefix}{n}": self.shape(n) @ lin.T for n in self.shape_names}


@lru_cache(maxsize=1)
def generic_head() -> GenericHead:
    """The shipped generic head (loaded once per process; treat it as read-only)."""
    with resources.files("faceanim").joinpath("assets", "generic_head.npz").open("rb") as fh:
        data = dict(np.load(fh))
    mesh = Mesh(data["vertices"].astype(np.float64), data["faces"].astype(np.int64),
                polygon_sizes=data["polygon_sizes"].astype(np.int64), name="generic_head",
                source="faceanim:generic_head")
    parts = {str(n): np.arange(a, b) for n, (a, b) in zip(data["part_names"], data["part_ranges"])}
    names = tuple(str(n) for n in data["shape_names"])
    shapes = {n: (data[f"shape_rows_{n}"].astype(np.int64), data[f"shape_delta_{n}"].astype(np.float64))
              for n in names}
    bary = data["landmark_barycentric"].astype(np.float64)
    bary /= bary.sum(axis=1, keepdims=True)  # stored as float32: sum exactly to 1 again
    identity = (data["identity_modes"], data["identity_scale"].astype(np.float32))
    return GenericHead(mesh, parts, data["landmark_triangles"].astype(np.int64), bary, names, shapes, identity)
