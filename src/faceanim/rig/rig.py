"""A rig: named controls over one rest mesh, compiled to blendshapes.

An *expression* (seed paper section 2.5) is a set of geometry deformation elements driven by one
parameter ``d`` in [0, 1]: ``d = 0`` is the neutral face, ``d = 1`` puts every control point of
the set at its full offset. Because the GDE deformer is linear in the control offsets, each
expression compiles to one blendshape (a (V, 3) displacement) and any mixture of expressions is
a weighted sum of blendshapes: ``pose = rest + sum_k d_k B_k``. For many frames this is one
matrix product, ``(F, C) @ (C, 3V)``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from faceanim.deform.base import LinearDeformer
from faceanim.deform.gde import bind_element, deformer_from_bound
from faceanim.errors import DeformError
from faceanim.face.mesh import Mesh
from faceanim.rig.expressions import Expression


class Rig:
    """Named blendshapes over a rest mesh; ``pose`` and ``evaluate`` give deformed vertices."""

    def __init__(self, mesh: Mesh, blendshapes: Mapping[str, np.ndarray]):
        if not blendshapes:
            raise DeformError("a rig needs at least one blendshape")
        self.mesh = mesh
        self.names = list(blendshapes)
        b = np.stack([np.asarray(blendshapes[n], dtype=np.float64) for n in self.names])
        if b.shape[1:] != mesh.vertices.shape:
            raise DeformError(f"blendshapes must have shape ({mesh.n_vertices}, 3)")
        self.blendshapes = b  # (C, V, 3)
        self.deformer: LinearDeformer | None = None

    @classmethod
    def from_expressions(cls, mesh: Mesh, expressions: Sequence[Expression]) -> Rig:
        """Bind every expression's GDEs once and compile each expression to a blendshape."""
        names = [e.name for e in expressions]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise DeformError(f"expression names must be unique; repeated: {', '.join(sorted(dup))}")
        bound = [bind_element(mesh, el) for e in expressions for el in e.elements]
        deformer = deformer_from_bound(mesh, bound)
        shapes = {}
        start = 0
        for e in expressions:
            off = np.zeros((deformer.n_handles, 3))
            off[start:start + len(e.elements)] = e.offsets
            shapes[e.name] = deformer.displacements(off)
            start += len(e.elements)
        rig = cls(mesh, shapes)
        rig.deformer = deformer
        rig.bound_elements = bound
        return rig

    def weights_vector(self, weights: Mapping[str, float] | Sequence[float]) -> np.ndarray:
        if isinstance(weights, Mapping):
            unknown = set(weights) - set(self.names)
            if unknown:
                raise DeformError(
                    f"unknown control(s) {', '.join(sorted(unknown))}; this rig has: {', '.join(self.names)}")
            return np.array([float(weights.get(n, 0.0)) for n in self.names])
        w = np.asarray(weights, dtype=np.float64)
        if w.shape != (len(self.names),):
            raise DeformError(f"expected {len(self.names)} weights, got shape {w.shape}")
        return w

    def pose(self, weights: Mapping[str, float] | Sequence[float]) -> np.ndarray:
        """Vertices for a mixture of controls, e.g. ``{'smile': 0.7, 'A': 0.3}``."""
        w = self.weights_vector(weights)
        return self.mesh.vertices + np.tensordot(w, self.blendshapes, axes=1)

    def evaluate(self, curves: np.ndarray) -> np.ndarray:
        """Vertices (F, V, 3) for control curves sampled to an (F, C) matrix."""
        c = np.asarray(curves, dtype=np.float64)
        if c.ndim != 2 or c.shape[1] != len(self.names):
            raise DeformError(f"curves must have shape (frames, {len(self.names)}), got {c.shape}")
        flat = c @ self.blendshapes.reshape(len(self.names), -1)
        return self.mesh.vertices[None] + flat.reshape(c.shape[0], -1, 3)

    def blendshape_dict(self) -> dict[str, np.ndarray]:
        return {n: self.blendshapes[k] for k, n in enumerate(self.names)}
