"""Expression retargeting (Chai, Xiao & Hodgins 2003, section 5): a motion database's deformation
bases moved onto any face, precomputed once, so that a performance drives the face by blending L
bases, whatever its vertex count.

The four stages of the paper, with what we do at each:

1. **Motion vector interpolation**: the paper spreads each basis from the markers over the
   source surface by barycentric coordinates on a mesh of the markers. Our source is the generic
   head, whose ARKit shapes made the database's markers: each basis is already written as a
   combination of those shapes (:attr:`MotionDatabase.basis_curves
   <faceanim.build.motion.MotionDatabase>`), so it is known on every source vertex, inside the
   lips and lids too, where markers cannot be.
2. **Dense surface correspondence**: the face's one registration (:mod:`faceanim.face.registration`:
   the generic head's morphable model fitted to the face, then non-rigid ICP onto its surface);
   each target vertex is projected onto the registered head part by part (skin onto skin, a
   lower lip or lid onto a lower one, eyeballs, teeth and lashes onto their own pieces). A face
   made from the generic head (the default face, ``faceanim photo``) corresponds vertex for
   vertex.
3. **Motion vector transfer** (eqs. 5-6): ``delta x_t = J delta x_s``. The paper's ``J`` is the
   Jacobian of the map between the two faces. Once the identity is fitted, that map is the
   registration's similarity plus the person's own shape, and ICT's model adds an expression's
   displacement to any identity unchanged: so ``J = s R``, with ``s`` the face's size against
   the generic head (:attr:`Registration.size_scale <faceanim.face.registration.Registration>`:
   the similarity's scale and the fitted identity's size together, which a fit can trade one
   for the other). Measured on remeshed ICT identities (``scripts/eval_registration.py``, tuning
   seeds 0-1): median relative error 0.153 with it, 0.161 with the similarity's scale alone,
   0.17 with the landmark spline's Jacobian and 0.24 with the registration's own local
   deformation gradient (which carries the person's shape into the motion).
4. **Target motion synthesis** (eq. 7): the L target bases become the columns of a :class:`Rig`
   (one :class:`~faceanim.deform.base.LinearDeformer`, like every rig here); a frame is L weights.
"""

from __future__ import annotations

import numpy as np

from faceanim.errors import FaceAnimError
from faceanim.face.face import Face
from faceanim.face.generic_head import GenericHead, generic_head
from faceanim.face.registration import face_to_head, register
from faceanim.rig.rig import Rig

BASIS_PREFIX = "basis_"


def basis_names(n: int) -> list[str]:
    """The rig's control names: ``basis_01`` ... (the database's deformation bases, in order)."""
    return [f"{BASIS_PREFIX}{k + 1:02d}" for k in range(n)]


def source_bases(basis_curves: np.ndarray, curve_names, head: GenericHead | None = None) -> np.ndarray:
    """(L, V, 3) the deformation bases on every vertex of the generic head: each basis's
    combination (``basis_curves`` (L, C)) of the head's shapes ``curve_names``."""
    head = head or generic_head()
    k = np.asarray(basis_curves, dtype=np.float64)
    out = np.zeros((len(k), head.mesh.n_vertices, 3))
    for c, name in enumerate(curve_names):
        used = np.flatnonzero(k[:, c])  # the bases this shape is part of (one each for named shapes)
        if len(used):
            rows, delta = head.sparse_shape(name)
            out[np.ix_(used, rows)] += k[used, c, None, None] * delta[None]
    return out


def retarget(face: Face, basis_curves: np.ndarray, curve_names, head: GenericHead | None = None,
             names=None, regions: dict | None = None) -> Rig:
    """A :class:`Rig` of ``face`` with one control per deformation basis (``basis_curves`` (L, C)
    over the generic head's shapes ``curve_names``, as a motion database stores them): the
    bases moved onto the face by the registration's dense correspondence and the Jacobian of its
    map (stages 1-3 of the module docstring). Weight ``lambda_i`` of control ``i`` moves the face by
    ``lambda_i delta x_t,i`` (eq. 7).

    ``regions``: name -> (V,) weights on the generic head's vertices summing to 1 over the regions
    (e.g. the lower and upper face): then each basis is split into one copy per region, controls
    ``{region}_{01..}``, so that each region can follow its own weights and the same weights on
    all of them give the whole basis back."""
    head = head or generic_head()
    k = np.asarray(basis_curves, dtype=np.float64)
    if k.ndim != 2 or k.shape[1] != len(curve_names) or not np.all(np.isfinite(k)):
        raise FaceAnimError(f"basis curves must be finite (L, {len(curve_names)})")
    unknown = [n for n in curve_names if n not in head.shape_names]
    if unknown:
        raise FaceAnimError(f"the generic head has no shape '{unknown[0]}'")
    bases = source_bases(k, curve_names, head)  # (L, Vs, 3)
    if regions:
        parts = [np.asarray(w, dtype=np.float64) for w in regions.values()]
        if any(w.shape != (head.mesh.n_vertices,) for w in parts) or not np.allclose(sum(parts), 1.0):
            raise FaceAnimError("region weights must be (V,) per region on the generic head, summing to 1")
        bases = np.concatenate([bases * w[None, :, None] for w in parts])
        names = names or [f"{r}_{i + 1:02d}" for r in regions for i in range(len(k))]
    if head is generic_head():
        reg = face.registration
        tri, bary = face.correspondence
    else:
        reg = register(face, head)
        tri, bary = face_to_head(face, reg)
    corners = head.mesh.faces[tri]  # (Vt, 3)
    at = np.einsum("vc,lvcd->lvd", bary, bases[:, corners])  # delta x_s,i at each x_s
    moving = np.flatnonzero(np.abs(at).max(axis=(0, 2)) > 0)
    jac = reg.size_scale * reg.rotation  # eq. 6 (module docstring: why a similarity)
    target = np.zeros((len(bases), face.mesh.n_vertices, 3))
    target[:, moving] = at[:, moving] @ jac.T
    names = list(names or basis_names(len(bases)))
    if len(names) != len(bases):
        raise FaceAnimError(f"give {len(bases)} control names, got {len(names)}")
    return Rig.from_blendshapes(face.mesh, dict(zip(names, target)))
