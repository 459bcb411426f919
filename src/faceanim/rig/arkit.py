"""Apple ARKit's 52 blendshapes on any face, for playing Live Link Face recordings.

The generic head (ICT FaceKit) carries artist-made shapes for 51 of ARKit's 52 blendshapes
(``tongueOut`` has none). :func:`arkit_rig` moves them onto any face with the retargeting of
:mod:`faceanim.rig.performance` (dense correspondence through the landmarks, motion vectors turned
by the landmark spline's Jacobian: Chai et al. 2003, section 5, applied to named shapes, as Noh and
Neumann's expression cloning does), and names them as Apple does (``eyeBlinkLeft`` ... ; Left and
Right are the subject's own sides). ICT splits ``browInnerUp`` and ``cheekPuff`` in halves: their
sum is the ARKit shape.

This is playback of recorded curves on a face: the shapes are the generic head's, carried over,
not a rig generated from the face's own geometry.
"""

from __future__ import annotations

import numpy as np

from faceanim.face.face import Face
from faceanim.face.generic_head import generic_head
from faceanim.rig.performance import retarget
from faceanim.rig.rig import Rig


def apple_name(live_link: str) -> str:
    """Apple's name of an ARKit blendshape from Live Link Face's column name (``EyeBlinkLeft`` ->
    ``eyeBlinkLeft``)."""
    return live_link[0].lower() + live_link[1:]


def arkit_rig(face: Face) -> tuple[Rig, list[str]]:
    """The face's ARKit rig: one control per ARKit blendshape the generic head has (51; Apple's
    names, in Live Link Face's column order), and the names it lacks (``tongueOut``)."""
    from faceanim.io.arkit_csv import ARKIT_NAMES, ict_name

    head = generic_head()
    names = list(head.shape_names)
    ict = retarget(face, np.eye(len(names)), names, names=names)
    shapes, missing = {}, []
    for column in ARKIT_NAMES:
        parts = [n for n in ict_name(column) if n in head.shape_names]
        if not parts:
            missing.append(apple_name(column))
            continue
        shapes[apple_name(column)] = sum(ict.blendshape(n) for n in parts)
    return Rig.from_blendshapes(face.mesh, shapes), missing
