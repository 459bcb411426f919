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
2. **Dense surface correspondence**: the target's vertices are carried into the source's space
   by the landmark thin-plate spline (the volume morph; landmarks on both faces) and projected
   onto the source surface (closest point), each on its own side: skin onto skin, the rest
   (eyeballs, teeth) onto the rest, a lower lip or lid onto a lower one, the lower teeth and
   tongue onto the lower ones. A face made from the
   generic head (the default face, ``faceanim photo``) corresponds vertex for vertex.
3. **Motion vector transfer** (eqs. 5-6): ``delta x_t = Jf(x_s) delta x_s``, ``f`` the thin-plate
   spline from the source's landmarks to the target's, its Jacobian by central differences.
4. **Target motion synthesis** (eq. 7): the L target bases become the columns of a :class:`Rig`
   (one :class:`~faceanim.deform.base.LinearDeformer`, like every rig here); a frame is L weights.
"""

from __future__ import annotations

import numpy as np

from faceanim.deform.rbf import landmark_tps
from faceanim.errors import FaceAnimError
from faceanim.face.face import Face
from faceanim.face.generic_head import GenericHead, generic_head
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


SMOOTHING = 1.0  # landmark spline smoothing: on the ICT head (an oracle) 0 gave 56% error, 1.0 gives 7%
NEAR_SLIT = 0.75  # a vertex keeps to its side of a slit within this many slit widths of its centre
SLIT_NAMES = ("eye_L", "eye_R", "mouth")  # the columns of _sides


def _sides(mesh, lm478: np.ndarray, skin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per vertex: (sides (V, S) bool, True below slit s of :data:`SLIT_NAMES` (for what is not
    skin, below the mouth: the lower teeth; False for the eyes), near (V, S) bool, within
    :data:`NEAR_SLIT` slit widths of the slit's centre)."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    from faceanim.face.frame import face_frame
    from faceanim.face.landmarks import SLITS
    from faceanim.face.regions import slit_sides

    lm = np.asarray(lm478, dtype=np.float64)
    lower = slit_sides(mesh, lm)
    y = face_frame(lm).to_local(mesh.vertices)[:, 1]
    mouth_y = face_frame(lm).to_local(lm[list(SLITS["mouth"]["corners"])])[:, 1].mean()
    # what is not skin goes by whole shells (a lower tooth row whose crowns rise above the lips'
    # line is still lower): each connected piece by its mean height
    f = mesh.faces
    keep = ~skin[f].any(axis=1)
    rows = np.concatenate([f[keep, 0], f[keep, 1], f[keep, 2]])
    cols = np.concatenate([f[keep, 1], f[keep, 2], f[keep, 0]])
    n = mesh.n_vertices
    _, piece = connected_components(sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)), directed=False)
    piece_y = np.bincount(piece, weights=y, minlength=piece.max() + 1) / np.bincount(piece, minlength=piece.max() + 1)
    below_mouth = piece_y[piece] < mouth_y
    sides = np.zeros((mesh.n_vertices, len(SLIT_NAMES)), bool)
    near = np.zeros_like(sides)
    for k, name in enumerate(SLIT_NAMES):
        c = lm[list(SLITS[name]["corners"])]
        width = float(np.linalg.norm(c[1] - c[0]))
        sides[:, k] = np.where(skin, np.asarray(lower[name], dtype=bool), below_mouth & (name == "mouth"))
        near[:, k] = np.linalg.norm(mesh.vertices - c.mean(axis=0), axis=1) < NEAR_SLIT * width
    return sides, near


def _closest_on(mesh_v: np.ndarray, tris: np.ndarray, points: np.ndarray):
    """Closest points of ``points`` on the triangles ``tris`` (T, 3) of vertices ``mesh_v``:
    (triangle index into tris, barycentric (N, 3))."""
    import trimesh

    tm = trimesh.Trimesh(mesh_v, tris, process=False)
    closest, _, tri = trimesh.proximity.closest_point(tm, points)
    bary = trimesh.triangles.points_to_barycentric(mesh_v[tris[tri]], closest)
    bary = np.clip(bary, 0.0, None)
    return tri, bary / np.maximum(bary.sum(axis=1, keepdims=True), 1e-12)


def correspondence(face: Face, head: GenericHead | None = None,
                   smoothing: float = SMOOTHING) -> tuple[np.ndarray, np.ndarray]:
    """The dense correspondence from the target ``face`` to the generic head: per target vertex,
    the source triangle (rows of ``head.mesh.faces``) and barycentric coordinates of the source
    point ``x_s`` it corresponds to (stage 2 of the module docstring)."""
    head = head or generic_head()
    src = head.mesh
    if head.landmarks_on(face.mesh) is not None:  # made from the generic head: vertex for vertex
        first = np.full(src.n_vertices, -1, dtype=np.int64)
        corner = np.full(src.n_vertices, -1, dtype=np.int64)
        for c in range(3):  # any triangle that has the vertex, with its corner
            unset = first[src.faces[:, c]] < 0
            first[src.faces[unset, c]] = np.flatnonzero(unset)
            corner[src.faces[unset, c]] = c
        loose = first < 0
        if loose.any():
            raise FaceAnimError("the generic head has vertices outside every triangle")
        bary = np.zeros((src.n_vertices, 3))
        bary[np.arange(src.n_vertices), corner] = 1.0
        return first, bary
    src_lm = head.landmarks()
    morph = landmark_tps(face.landmarks, src_lm, "landmarks", merge_repeated=True, smoothing=smoothing)
    moved = morph(face.mesh.vertices)
    src_skin = np.zeros(src.n_vertices, bool)
    src_skin[head.parts["skin"]] = True
    tgt_skin = np.asarray(face.skin, dtype=bool)
    src_sides, _ = _sides(src, src_lm, src_skin)
    tgt_sides, tgt_near = _sides(face.mesh, face.landmarks, tgt_skin)
    # a source triangle's kind: skin or not, and its side of each slit (all three corners agree)
    t_skin = src_skin[src.faces].all(axis=1)
    t_other = (~src_skin[src.faces]).all(axis=1)
    t_side = src_sides[src.faces]  # (T, 3, S)
    t_lower, t_upper = t_side.all(axis=1), (~t_side).all(axis=1)
    # each target vertex's constraint: skin or not; below (1) / above (2) / free (0) per slit
    near = tgt_near | ~tgt_skin[:, None]  # what is not skin keeps to its side of the mouth always
    key = np.where(near, np.where(tgt_sides, 1, 2), 0)
    eyes = [k for k, name in enumerate(SLIT_NAMES) if name != "mouth"]
    key[np.ix_(~tgt_skin, eyes)] = 0  # (the eyes' sides mean nothing off the skin)
    key = np.column_stack([tgt_skin, key])
    uniq, group = np.unique(key, axis=0, return_inverse=True)
    tri = np.empty(face.mesh.n_vertices, dtype=np.int64)
    bary = np.empty((face.mesh.n_vertices, 3))
    for g, k in enumerate(uniq):
        ok = t_skin.copy() if k[0] else t_other.copy()
        for s, want in enumerate(k[1:]):
            if want == 1:
                ok &= t_lower[:, s]
            elif want == 2:
                ok &= t_upper[:, s]
        pool = np.flatnonzero(ok)
        if len(pool) == 0:  # no such side on the generic head: the whole surface
            pool = np.arange(len(src.faces))
        mine = np.flatnonzero(group.ravel() == g)
        t, b = _closest_on(src.vertices, src.faces[pool], moved[mine])
        tri[mine], bary[mine] = pool[t], b
    # a separate piece (eyelashes, a lid's tear line, one tooth) onto its own piece: the closest
    # point alone lands an eyelash on the eyeball just under it, which does not blink
    scale = float(np.linalg.norm(src_lm[LEFT_EYE_CORNERS].mean(0) - src_lm[RIGHT_EYE_CORNERS].mean(0)))
    matched, unmatched = _matching_shells(face.mesh, moved, ~tgt_skin, src, ~src_skin, SHELL_MATCH * scale)
    for mine, pool in matched:
        t, b = _closest_on(src.vertices, src.faces[pool], moved[mine])
        tri[mine], bary[mine] = pool[t], b
    # a piece the generic head has no counterpart for, at an eye and not round (eyelashes, a tear
    # line): it rides on its lid, the skin on its side of the slit, as it is fixed to it
    from faceanim.face.frame import face_frame
    from faceanim.face.landmarks import SLITS

    up = face_frame(src_lm).rotation[1]  # the generic head's up (the pieces are in its space now)
    for mine in unmatched:
        centre = moved[mine].mean(0)
        for k, name in enumerate(SLIT_NAMES):
            if name == "mouth":
                continue
            corners = src_lm[list(SLITS[name]["corners"])]
            width = float(np.linalg.norm(corners[1] - corners[0]))
            d = np.linalg.norm(moved[mine] - centre, axis=1)
            round_ = d.std() < ROUND * d.mean()
            if np.linalg.norm(centre - corners.mean(0)) > NEAR_EYE * width or round_:
                continue
            upper = (centre - corners.mean(0)) @ up > 0
            pool = np.flatnonzero(t_skin & (t_upper[:, k] if upper else t_lower[:, k]))
            if len(pool):
                t, b = _closest_on(src.vertices, src.faces[pool], moved[mine])
                tri[mine], bary[mine] = pool[t], b
            break
    return tri, bary


SHELL_MATCH = 0.05  # a target piece matches a source piece within this (IODs): centre distance + size difference
NEAR_EYE = 1.0  # an unmatched piece this near an eye (slit widths, centre to centre) rides on its lid...
ROUND = 0.2  # ...unless it is round (its points' distances from its centre vary less than this share)
LEFT_EYE_CORNERS, RIGHT_EYE_CORNERS = [263, 362], [33, 133]  # MediaPipe's eye corners


def _shells(mesh, vertices: np.ndarray, off_skin: np.ndarray):
    """The connected pieces made only of off-skin triangles: (triangles per piece, vertices per
    piece, centre (P, 3), RMS radius (P,)) with ``vertices`` as the positions."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    f = mesh.faces
    keep = np.flatnonzero(off_skin[f].all(axis=1))
    n = mesh.n_vertices
    rows = np.concatenate([f[keep, 0], f[keep, 1]])
    cols = np.concatenate([f[keep, 1], f[keep, 2]])
    _, label = connected_components(sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)), directed=False)
    tri_label = label[f[keep, 0]]
    pieces = np.unique(tri_label)
    tris = [keep[tri_label == p] for p in pieces]
    verts = [np.unique(f[t]) for t in tris]
    centre = np.array([vertices[v].mean(0) for v in verts]).reshape(-1, 3)
    radius = np.array([np.sqrt(np.mean(np.sum((vertices[v] - c) ** 2, axis=1))) for v, c in zip(verts, centre)])
    return tris, verts, centre, radius


def _matching_shells(target, moved: np.ndarray, tgt_off: np.ndarray, src, src_off: np.ndarray, tolerance: float):
    """The target's pieces off the skin, matched to the source's: (pairs (target vertices, source
    triangles) for each piece whose centre (carried into the source's space, ``moved``) distance
    plus size difference to one source piece is under ``tolerance`` (many target pieces may match
    one source piece), the vertices of each piece that matches none)."""
    _, t_verts, t_centre, t_radius = _shells(target, moved, tgt_off)
    s_tris, _, s_centre, s_radius = _shells(src, src.vertices, src_off)
    if not len(t_verts) or not len(s_tris):
        return [], list(t_verts)
    score = np.linalg.norm(t_centre[:, None] - s_centre[None], axis=2) + np.abs(t_radius[:, None] - s_radius[None])
    best = np.argmin(score, axis=1)
    ok = score[np.arange(len(t_verts)), best] < tolerance
    return ([(t_verts[k], s_tris[best[k]]) for k in np.flatnonzero(ok)],
            [t_verts[k] for k in np.flatnonzero(~ok)])


def jacobians(f, points: np.ndarray, step: float) -> np.ndarray:
    """(N, 3, 3) Jacobians of the map ``f`` at ``points`` by central differences (eq. 6):
    ``J[n, i, j] = d f_i / d x_j``."""
    p = np.asarray(points, dtype=np.float64)
    out = np.empty((len(p), 3, 3))
    for j in range(3):
        e = np.zeros(3)
        e[j] = step
        out[:, :, j] = (f(p + e) - f(p - e)) / (2 * step)
    return out


def retarget(face: Face, basis_curves: np.ndarray, curve_names, head: GenericHead | None = None,
             names=None, smoothing: float = SMOOTHING, regions: dict | None = None) -> Rig:
    """A :class:`Rig` of ``face`` with one control per deformation basis (``basis_curves`` (L, C)
    over the generic head's shapes ``curve_names``, as a motion database stores them): the
    bases moved onto the face by the dense correspondence and the landmark spline's Jacobian
    (stages 1-3 of the module docstring). Weight ``lambda_i`` of control ``i`` moves the face by
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
    tri, bary = correspondence(face, head, smoothing)
    corners = head.mesh.faces[tri]  # (Vt, 3)
    at = np.einsum("vc,lvcd->lvd", bary, bases[:, corners])  # delta x_s,i at each x_s
    x_s = np.einsum("vc,vcd->vd", bary, head.mesh.vertices[corners])
    f = landmark_tps(head.landmarks(), face.landmarks, "landmarks", merge_repeated=True, smoothing=smoothing)
    step = 1e-3 * float(np.ptp(head.landmarks(), axis=0).max())
    moving = np.flatnonzero(np.abs(at).max(axis=(0, 2)) > 0)
    jac = jacobians(f, x_s[moving], step)
    target = np.zeros((len(bases), face.mesh.n_vertices, 3))
    target[:, moving] = np.einsum("vij,lvj->lvi", jac, at[:, moving])
    names = list(names or basis_names(len(bases)))
    if len(names) != len(bases):
        raise FaceAnimError(f"give {len(bases)} control names, got {len(names)}")
    return Rig.from_blendshapes(face.mesh, dict(zip(names, target)))
