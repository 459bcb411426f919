"""The deformation core: every method binds once to a rest pose and compiles to one
:class:`LinearDeformer` (``positions = rest + W @ handle offsets``)."""

from faceanim.deform.base import LinearDeformer
from faceanim.deform.gde import (
    ElementInfluence,
    GeometryDeformationElement,
    bind_gdes,
    element_influence,
)
from faceanim.deform.rbf import KERNELS, RadialBasis, bind_rbf

__all__ = [
    "KERNELS",
    "ElementInfluence",
    "GeometryDeformationElement",
    "LinearDeformer",
    "RadialBasis",
    "element_influence",
    "bind_gdes",
    "bind_rbf",
]
