"""Expressions as sets of geometry deformation elements (Noh, Fidaleo & Neumann 2000), compiled to a Rig.

An *expression* (seed paper section 2.5) is a set of geometry deformation elements driven by one
parameter ``d`` in [0, 1]: ``d = 0`` is the neutral face, ``d = 1`` puts every control point of
the set at its full offset. Because the GDE deformer is linear in the control offsets, each
expression compiles to one blendshape (a (V, 3) displacement) and any mixture of expressions is
a weighted sum of blendshapes: ``pose = rest + sum_k d_k B_k``. For many frames this is one
matrix product, ``(F, C) @ (C, 3V)``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from faceanim.deform.gde import GeometryDeformationElement, bind_gdes
from faceanim.deform.rbf import check_points
from faceanim.errors import DeformError
from faceanim.rig.rig import Rig


@dataclass
class Expression:
    """A named set of GDEs with the control-point offsets reached at ``d = 1``."""

    name: str
    elements: list[GeometryDeformationElement]
    offsets: np.ndarray  # (G, 3)

    def __post_init__(self):
        self.offsets = check_points(self.offsets, f"expression '{self.name}' offsets")
        if len(self.offsets) != len(self.elements):
            raise DeformError(
                f"expression '{self.name}' has {len(self.elements)} elements but {len(self.offsets)} offsets"
            )

    @classmethod
    def from_dict(cls, d: Mapping, index: int = 0) -> Expression:
        if not isinstance(d, Mapping) or not isinstance(d.get("elements"), list) or not d["elements"]:
            raise DeformError(f"expression {index} needs a non-empty 'elements' list")
        name = str(d.get("name", f"expression{index}"))
        elements, offsets = [], []
        for k, e in enumerate(d["elements"]):
            if not isinstance(e, Mapping) or "offset" not in e:
                raise DeformError(f"expression '{name}' element {k} needs an 'offset' [dx, dy, dz]")
            elements.append(GeometryDeformationElement.from_dict(
                {**e, "name": e.get("name", f"{name}.{k}")}, k))
            offsets.append(check_points(e["offset"], f"expression '{name}' element {k} offset")[0])
        return cls(name, elements, np.array(offsets))


def expression_rig(mesh, expressions: Sequence[Expression]) -> Rig:
    """Bind every expression's GDEs once (one deformer, one handle per element) and compile each
    expression to a blendshape: the rig's control ``name`` is the expression's ``d``."""
    names = [e.name for e in expressions]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise DeformError(f"expression names must be unique; repeated: {', '.join(dup)}")
    deformer = bind_gdes(mesh, [el for e in expressions for el in e.elements])
    shapes, start = {}, 0
    for e in expressions:
        off = np.zeros((deformer.n_handles, 3))
        off[start:start + len(e.elements)] = e.offsets
        shapes[e.name] = deformer.displacements(off)
        start += len(e.elements)
    return Rig.from_blendshapes(mesh, shapes)
