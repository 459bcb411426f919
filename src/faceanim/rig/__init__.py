"""Rigs: every method builds a :class:`~faceanim.rig.rig.Rig` (named controls over one bound
linear deformer, plus rigid parts).

``from faceanim.rig import Rig, RigidPart``. Builders: ``expressions.expression_rig`` (GDE sets),
``transfer.ExpressionTransfer(face).rig`` (FACS action units), ``mpeg4.FapRig.build`` (MPEG-4
FAPs), ``wires.blend_chain`` (wire template blends).
"""

from faceanim.rig.rig import Rig, RigidPart

__all__ = ["Rig", "RigidPart"]
