"""Apple ARKit's 52 blendshapes on any face, for ``faceanim rig`` and for playing Live Link Face
recordings.

The generic head (ICT FaceKit) carries artist-made shapes for 51 of ARKit's 52 blendshapes, and a
``tongueOut`` faceanim makes from the tongue's geometry (``scripts/build_generic_head.py``).
:func:`arkit_rig` moves them onto any face with the retargeting of :mod:`faceanim.rig.performance`
(the face's registration: dense correspondence part by part, motion carried by its similarity:
Chai et al. 2003, section 5, applied to named shapes, as Noh and Neumann's expression cloning
does), and names them as Apple does (``eyeBlinkLeft`` ... ; Left and
Right are the subject's own sides). ICT splits ``browInnerUp`` and ``cheekPuff`` in halves: their
sum is the ARKit shape.

Each displacement is rebuilt on the face's own surface from the patterns of ICT's artist-made
shapes (learned, not copied: a face that is not ICT's gets its own). :func:`arkit_shapes` adds
what ICT's shapes lack: the ``eyeLook*`` shapes also turn the eyeballs, by the angles a real Live
Link Face take records at weight 1 (:data:`LOOK_ANGLES`). ``faceanim rig`` and ``faceanim arkit
play`` both use it.
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
    """The face's ARKit rig: one control per ARKit blendshape the generic head has (all 52; Apple's
    names, in Live Link Face's column order), and the names it lacks (none with the shipped head)."""
    from faceanim.io.arkit_csv import ARKIT_NAMES, ict_name

    head = generic_head()
    names = list(head.shape_names)
    ict = retarget(face, np.eye(len(names)), names, names=names)
    shapes, missing = {}, []
    for column in ARKIT_NAMES:
        # ICT's own names, else the head's own shape by Apple's name (tongueOut, made by faceanim)
        parts = [n for n in ict_name(column) or (apple_name(column),) if n in head.shape_names]
        if not parts:
            missing.append(apple_name(column))
            continue
        shapes[apple_name(column)] = sum(ict.blendshape(n) for n in parts)
    return Rig.from_blendshapes(face.mesh, shapes), missing


# radians an eyeball turns at look weight 1: the Live Link Face take in ../shared/data/arkit-curves,
# its eye yaw/pitch regressed on the look curves (r = 0.999 yaw, 0.996 pitch; both eyes agree to 0.01)
LOOK_ANGLES = {"Out": 0.58, "In": 0.63, "Up": 0.45, "Down": 0.62}


def _turn(points: np.ndarray, centre: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Displacement of ``points`` turned by ``angle`` about the line through ``centre`` along the
    unit ``axis`` (Rodrigues)."""
    from scipy.spatial.transform import Rotation

    r = Rotation.from_rotvec(axis * angle).as_matrix()
    return (points - centre) @ r.T + centre - points


def _look_shapes(face: Face, eyes: dict) -> dict[str, np.ndarray]:
    """The eyeballs' part of the eight ``eyeLook*`` shapes: each eyeball turned about its centre
    in the face's own axes (x to the subject's left, y up, z forward)."""
    right, up, forward = face.frame.rotation
    v = face.mesh.vertices
    out = {}
    for side, word in (("L", "Left"), ("R", "Right")):
        if eyes.get(side) is None:
            continue
        rows, centre = eyes[side]
        outward = right if side == "L" else -right  # the subject's left eye looks out to its left
        # the direction the pupil moves, and the axis that turns forward into it
        for look, towards in (("Out", outward), ("In", -outward), ("Up", up), ("Down", -up)):
            axis = np.cross(forward, towards)
            d = np.zeros_like(v)
            d[rows] = _turn(v[rows], centre, axis / np.linalg.norm(axis), LOOK_ANGLES[look])
            out[f"eyeLook{look}{word}"] = d
    return out


OPEN_EYE = 0.02  # eye pieces with more than this share of boundary edges are plates, not balls


def registered_eyes(face: Face) -> dict:
    """Eyes that are not round shells (an anime face's flat iris and eye-white discs): the face's
    pieces off the skin whose corresponding points lie on the generic head's eyeballs, turned
    about the registered eyeball's centre when they close into a ball, else (an open plate or
    disc with the eye painted on: it has no centre of its own) about a centre one registered
    eyeball radius behind them, so the iris travels as far as a person's eye turning by the
    same angle. Side -> (vertex rows, centre); sides without any left out."""
    head = generic_head()
    tri, _ = face.correspondence
    reg = face.registration
    skin = np.asarray(face.skin, dtype=bool)
    out = {}
    for side in ("L", "R"):
        part = head.parts[f"eyeball_{side}"]
        on_eye = np.isin(head.mesh.faces[tri], part).all(axis=1) & ~skin
        if on_eye.any():
            rows = np.flatnonzero(on_eye)
            ball = reg.vertices[part]
            radius = float(np.linalg.norm(ball - ball.mean(axis=0), axis=1).mean())
            f = face.mesh.faces[np.isin(face.mesh.faces, rows).all(axis=1)]
            edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
            _, count = np.unique(edges, axis=0, return_counts=True)
            closed = len(count) > 0 and np.mean(count == 1) < OPEN_EYE
            centre = ball.mean(axis=0) if closed else \
                face.mesh.vertices[rows].mean(axis=0) - radius * face.frame.rotation[2]
            out[side] = (rows, centre)
    return out


LID_REACH = 0.6  # the closure correction fades out this far from the upper lid's margin (slit widths)


def _lid_closure(face: Face, blink: np.ndarray, slit: str, eyes: dict) -> np.ndarray:
    """The correction that makes a carried blink close the eye: ICT's lids travel ICT's eye
    opening, which on another face leaves a slit (40% of it on the default face) or overshoots.
    Each upper-margin point moves by what still parts it from the lower margin (at the same place
    along the slit, both as the blink leaves them); the upper lid's skin (and what rides on it,
    such as lashes, not the eyeballs) follows by inverse-distance weights, fading to nothing
    :data:`LID_REACH` slit widths from the margin."""
    from scipy.spatial import cKDTree

    from faceanim.face.landmarks import SLITS
    from faceanim.face.regions import slit_sides, smoothstep

    v = face.mesh.vertices
    lm = face.landmarks
    skin = np.flatnonzero(face.skin)
    tree = cKDTree(v[skin])
    spec = SLITS[slit]
    upper = skin[tree.query(lm[list(spec["upper"])])[1]]
    lower = skin[tree.query(lm[list(spec["lower"])])[1]]
    a, b = lm[list(spec["corners"])]
    axis = (b - a) / np.linalg.norm(b - a)
    width = float(np.linalg.norm(b - a))
    # the lower margin as a curve along the slit (through the corners, where the lids meet)
    lower = np.concatenate([lower, skin[tree.query(lm[list(spec["corners"])])[1]]])
    t_low = (v[lower] - a) @ axis
    p_low = v[lower] + blink[lower]
    order = np.argsort(t_low)
    t_up = (v[upper] - a) @ axis
    target = np.column_stack([np.interp(t_up, t_low[order], p_low[order, k]) for k in range(3)])
    gaps = target - (v[upper] + blink[upper])
    # who follows: the upper lid's skin near the margin, and off-skin pieces riding on it
    movable = np.ones(len(v), bool)
    movable[skin[slit_sides(face.mesh, lm)[slit][skin]]] = False  # the lower lid stays as carried,
    movable[lower] = False  # its margin and the corners too (the lids meet there)
    for part in (eyes or {}).values():
        if part is not None:
            movable[part[0]] = False
    d = np.linalg.norm(v[:, None] - v[upper][None], axis=2)  # (V, 5): fine for 5 margin points
    fade = smoothstep(1.0 - d.min(axis=1) / (LID_REACH * width)) * movable
    near = np.flatnonzero(fade > 0)
    w = 1.0 / (d[near] ** 2 + (0.02 * width) ** 2)
    out = np.zeros_like(v)
    out[near] = fade[near, None] * (w @ gaps) / w.sum(axis=1, keepdims=True)
    return out


def arkit_shapes(face: Face, eyes: dict | None = None) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """ARKit's shapes on ``face``: :func:`arkit_rig`'s, with the ``eyeLook*`` shapes also turning
    the eyeballs ``eyes`` (:attr:`FapRig.eyes <faceanim.rig.mpeg4.FapRig>`; found when not given),
    and the names it cannot make, with why."""
    if eyes is None:
        from faceanim.rig.mpeg4 import FapRig

        eyes = FapRig.build(face).eyes
    eyes = {**registered_eyes(face), **{s: e for s, e in eyes.items() if e is not None}}
    rig, missing = arkit_rig(face)
    shapes = {n: rig.blendshape(n) for n in rig.controls}
    for name, d in _look_shapes(face, eyes).items():
        shapes[name] = shapes[name] + d
    for slit, name in (("eye_L", "eyeBlinkLeft"), ("eye_R", "eyeBlinkRight")):
        shapes[name] = shapes[name] + _lid_closure(face, shapes[name], slit, eyes)
    skipped = {n: "no learned pattern: the generic head has no such shape" for n in missing}
    tongue = shapes.get("tongueOut")
    if tongue is not None and np.linalg.norm(tongue, axis=1).max() < STILL * face.frame.iod:
        del shapes["tongueOut"]  # a mesh without a tongue inside its mouth (a scan, a mask)
        skipped["tongueOut"] = "the mesh has no tongue: nothing inside its mouth corresponds to the generic head's"
    return shapes, skipped


STILL = 1e-3  # a shape that moves no vertex further than this (inter-ocular distances) is not made
