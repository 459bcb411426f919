"""The deformation core: every method binds once to a rest pose and compiles to one
:class:`LinearDeformer` (``positions = rest + W @ handle offsets``)."""

from faceanim.deform.base import LinearDeformer
from faceanim.deform.gde import (
    BoundElement,
    GeometryDeformationElement,
    bind_element,
    bind_gdes,
)
from faceanim.deform.rbf import KERNELS, RadialBasis, bind_rbf

__all__ = [
    "KERNELS",
    "BoundElement",
    "GeometryDeformationElement",
    "LinearDeformer",
    "RadialBasis",
    "bind_element",
    "bind_gdes",
    "bind_rbf",
]
