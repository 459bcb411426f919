"""Apple ARKit's 52 blendshapes on any face, for ``faceanim rig`` and for playing Live Link Face
recordings.

The generic head (ICT FaceKit) carries artist-made shapes for 51 of ARKit's 52 blendshapes, and a
``tongueOut`` faceanim makes from the tongue's geometry (``scripts/build_generic_head.py``): the
mouth opened, the tongue out over the lower lip, as Apple's reference shows it. A mesh with no
tongue gets the opening alone (:func:`shows_tongue` tells).
:func:`arkit_rig` moves them onto any face with the retargeting of :mod:`faceanim.rig.retarget`
(the face's registration: dense correspondence part by part, motion carried by its similarity:
Chai et al. 2003, section 5, applied to named shapes, as Noh and Neumann's expression cloning
does), and names them as Apple does (``eyeBlinkLeft`` ... ; Left and
Right are the subject's own sides). ICT splits ``browInnerUp`` and ``cheekPuff`` in halves: their
sum is the ARKit shape.

Each displacement is rebuilt on the face's own surface from the patterns of ICT's artist-made
shapes (learned, not copied: a face that is not ICT's gets its own). :func:`arkit_shapes` adds
what ICT's shapes lack: the ``eyeLook*`` shapes also turn the eyeballs, by the angles a real Live
Link Face take records at weight 1 (:data:`~faceanim.standards.arkit.LOOK_ANGLES`). ``faceanim
rig`` and ``faceanim arkit play`` both use it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from faceanim.errors import FaceAnimError, shown
from faceanim.face.face import Face
from faceanim.face.generic_head import generic_head
from faceanim.rig.mpeg4 import EYEBALL_OPEN as OPEN_EYE, boundary_share
from faceanim.rig.retarget import retarget
from faceanim.rig.rig import Rig
from faceanim.standards.arkit import LOOK_ANGLES, apple_name


def arkit_rig(face: Face) -> tuple[Rig, list[str]]:
    """The face's ARKit rig: one control per ARKit blendshape the generic head has (all 52; Apple's
    names, in Live Link Face's column order), and the names it lacks (none with the shipped head)."""
    from faceanim.standards.arkit import ARKIT_NAMES, ict_name

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
            closed = boundary_share(face.mesh, rows) < OPEN_EYE
            centre = ball.mean(axis=0) if closed else \
                face.mesh.vertices[rows].mean(axis=0) - radius * face.frame.rotation[2]
            out[side] = (rows, centre)
    return out


def face_eyes(face: Face, fap_eyes: dict | None = None) -> dict:
    """Every eye piece of ``face``: :func:`registered_eyes` (balls and plates found through the
    registration) with the FAP rig's eyeballs over them (``fap_eyes``,
    :attr:`FapRig.eyes <faceanim.rig.mpeg4.FapRig>`; built when not given). Side -> (rows, centre)."""
    if fap_eyes is None:
        from faceanim.rig.mpeg4 import FapRig

        fap_eyes = FapRig.build(face).eyes
    return {**registered_eyes(face), **{s: e for s, e in fap_eyes.items() if e is not None}}


LID_REACH = 0.6  # the closure correction fades out this far above the upper lid's margin (slit widths)
LID_STRETCH = 1.2  # the upper lid's band that stretches is at least this many times the largest gap tall
LID_MEET = 0.75  # the share of the gap the upper lid travels; the lower lid rises the rest
OPENING_COLUMNS = 24  # columns across an eye in which its opening is found
OPENING_ROWS = 120  # rays per column, over +-0.8 slit widths about the eye's centre


@dataclass
class EyeOpening:
    """Where a face's eye is open, seen from the front (:func:`eye_opening`), per column across
    the eye: ``x`` (along the slit, face frame), the upper and lower lid margins (3D points on the
    skin just above and below the opening, their triangles) and the opening's height (mesh units,
    0 where the column is shut)."""

    x: np.ndarray
    upper: np.ndarray
    upper_tri: np.ndarray
    lower: np.ndarray
    lower_tri: np.ndarray
    height: np.ndarray

    @property
    def area(self) -> float:
        """The opening's area in the front view (mesh units squared)."""
        return float(np.sum(self.height) * (self.x[1] - self.x[0])) if len(self.x) > 1 else 0.0


def eye_opening(face: Face, slit: str, eyes: dict, vertices: np.ndarray | None = None) -> EyeOpening | None:
    """The opening of one eye as the front view shows it: rays along the face's -z over the eye,
    each classed by the first thing it meets (the skin from outside; an eye piece, the inside of
    the head or nothing: the opening; anything else, such as lashes or an eyeline plate: the lid).
    In each column the opening is the run of opening rays nearest the eye's centre; its margins
    are the skin met first above and below it. MediaPipe's lid points cannot serve here: on an
    anime face they sit inside the painted eye, a third of the way to the real lids. ``vertices``:
    the face deformed (a blink, to see whether it closes). None when the front view shows no
    opening (a closed eye, painted eyes)."""
    from faceanim.face.landmarks import EYE_LEFT, EYE_RIGHT

    mesh = face.mesh if vertices is None else face.mesh.with_vertices(vertices)
    fr = face.frame
    lm = fr.to_local(face.landmarks)
    contour = lm[list(EYE_LEFT if slit == "eye_L" else EYE_RIGHT)]
    width = float(np.ptp(contour[:, 0]))
    centre = contour.mean(axis=0)
    # a little wider than MediaPipe's contour (on an anime face it lies inside the painted eye)
    xs = centre[0] + np.linspace(-0.65, 0.65, OPENING_COLUMNS) * width
    ys = centre[1] + np.linspace(-0.8, 0.8, OPENING_ROWS) * width
    gx, gy = np.meshgrid(xs, ys, indexing="ij")  # (columns, rows)
    local = fr.to_local(mesh.vertices)
    start = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, local[:, 2].max() + width)])
    origins = start @ fr.rotation + fr.origin
    dirs = np.broadcast_to(-fr.rotation[2], origins.shape)
    hit, pos, tri = mesh.cast_rays(origins, dirs)
    skin = np.asarray(face.skin, dtype=bool)
    eye_rows = np.zeros(mesh.n_vertices, bool)
    for part in (eyes or {}).values():
        if part is not None:
            eye_rows[part[0]] = True
    corners = mesh.faces[np.maximum(tri, 0)]
    fv = mesh.vertices[corners]
    front = np.einsum("ij,ij->i", np.cross(fv[:, 1] - fv[:, 0], fv[:, 2] - fv[:, 0]), dirs) < 0
    on_skin = hit & front & skin[corners].all(axis=1)
    opening = ~hit | ~front | eye_rows[corners].any(axis=1)
    on_skin, opening = on_skin.reshape(gx.shape), opening.reshape(gx.shape)
    pos, tri = pos.reshape(gx.shape + (3,)), tri.reshape(gx.shape)
    mid = int(np.argmin(np.abs(ys - centre[1])))
    out = {k: [] for k in ("x", "upper", "upper_tri", "lower", "lower_tri", "height")}
    for j in range(len(xs)):
        rows = np.flatnonzero(opening[j])
        if rows.size:
            # the run of opening rays nearest the centre row
            runs = np.split(rows, np.flatnonzero(np.diff(rows) > 1) + 1)
            run = min(runs, key=lambda r: 0 if r[0] <= mid <= r[-1] else min(abs(r[0] - mid), abs(r[-1] - mid)))
            below = np.flatnonzero(on_skin[j, :run[0]])
            above = np.flatnonzero(on_skin[j, run[-1] + 1:]) + run[-1] + 1
            if below.size and above.size and abs(run[0] + run[-1] - 2 * mid) < OPENING_ROWS // 2:
                lo, up = below[-1], above[0]
                out["x"].append(xs[j])
                out["upper"].append(pos[j, up])
                out["upper_tri"].append(tri[j, up])
                out["lower"].append(pos[j, lo])
                out["lower_tri"].append(tri[j, lo])
                out["height"].append((run[-1] - run[0] + 1) * (ys[1] - ys[0]))
                continue
        out["x"].append(xs[j])
        for k in ("upper", "lower"):
            out[k].append(np.full(3, np.nan))
            out[f"{k}_tri"].append(-1)
        out["height"].append(0.0)
    res = EyeOpening(*(np.asarray(out[k]) for k in ("x", "upper", "upper_tri", "lower", "lower_tri", "height")))
    return res if res.height.any() else None


def _lid_frame(face: Face, op: EyeOpening, eyes: dict, reach: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per vertex of ``face``, for the eye opening ``op``: its height down the face (face frame),
    the upper and lower margins' heights in its column (interpolated across the eye), and whether
    it is a lid's: within the open columns, less than ``reach`` behind the upper margin (not the
    back of the head behind the eye), not an eye piece."""
    fr = face.frame
    open_ = op.height > 0
    x = op.x[open_]
    local = fr.to_local(face.mesh.vertices)
    xv = local[:, 0]
    upper = np.interp(xv, x, fr.to_local(op.upper[open_])[:, 1])
    lower = np.interp(xv, x, fr.to_local(op.lower[open_])[:, 1])
    depth = np.interp(xv, x, fr.to_local(op.upper[open_])[:, 2])
    near = (xv > x.min()) & (xv < x.max()) & (local[:, 2] > depth - reach)
    for part in (eyes or {}).values():
        if part is not None:
            near[part[0]] = False
    return local[:, 1], upper, lower, near


def _lid_closure(face: Face, blink: np.ndarray, slit: str, eyes: dict, reach: tuple | None = None) -> np.ndarray:
    """The correction that makes a carried blink close the eye: ICT's lids travel ICT's eye
    opening, which on another face leaves a slit (40% of it on the default face; half an anime
    eye). The opening is found in the front view (:func:`eye_opening`), at rest and as the carried
    blink leaves it; in each column where the lids still part, the upper lid comes down
    :data:`LID_MEET` of the gap and the lower lid rises the rest, so they meet on a line between
    their arcs (meeting on the lower arc draws the closed lid into a sagging V). Each lid (the
    skin on its side of the eye's middle and what rides on it, such as lashes or an eyeline
    plate; not the eyes) moves by its column's share, interpolated across the eye:
    fully up to its margin, fading to nothing above (below) it over :data:`LID_REACH` slit widths
    (the upper lid) or a third of that (the lower): a sheet drawn over the eye, no lumps. The
    lids move down the face only, at the depth the carried blink leaves them: the whole 3D gap
    would draw an overhanging anime lid back into the head. ``reach``: (upper, lower) fade
    heights instead (a stylised lid's short sheet, :func:`_lid_sheet`)."""
    from faceanim.face.regions import smoothstep

    op = eye_opening(face, slit, eyes)
    if op is None:
        return np.zeros_like(blink)
    mesh = face.mesh
    fr = face.frame
    # what the carried blink leaves open, column by column, in the front view
    left = eye_opening(face, slit, eyes, mesh.vertices + blink)
    if left is None:
        return np.zeros_like(blink)
    open_ = op.height > 0
    gap = np.where(open_, left.height, 0.0)  # how far the lids still part, down the face
    width = float(op.x[-1] - op.x[0])
    yv, upper_margin, lower_margin, near = _lid_frame(face, op, eyes, 0.5 * width)
    # per vertex: its column's gap (0 past the corners), interpolated across
    g = np.interp(face.frame.to_local(mesh.vertices)[:, 0], op.x, gap, left=0.0, right=0.0)
    middle = 0.5 * (upper_margin + lower_margin)
    if reach is None:
        tall = max(LID_REACH * width, LID_STRETCH * float(gap.max()))
        reach = (tall, tall / 3)
    up = near & (yv > middle)
    lo = near & (yv <= middle)
    fade_up = np.where(yv <= upper_margin, 1.0, smoothstep(1.0 - (yv - upper_margin) / reach[0]))
    fade_lo = np.where(yv >= lower_margin, 1.0, smoothstep(1.0 - (lower_margin - yv) / reach[1]))
    dy = np.where(up, -LID_MEET * g * fade_up, 0.0) + np.where(lo, (1.0 - LID_MEET) * g * fade_lo, 0.0)
    return dy[:, None] * fr.rotation[1]


STYLES = ("realistic", "stylised")
# a stylised lid (a game or anime avatar's) is a short sheet: its margin travels, the skin above it
# barely; these are its heights over the upper (under the lower) margin, in tallest openings
LID_SHEET, LID_SHEET_LOWER = 0.4, 0.2


def _lid_sheet(face: Face, blink: np.ndarray, slit: str, eyes: dict) -> np.ndarray:
    """``blink`` with its motion down the face over the lids replaced by a stylised lid's: each
    lid's margin goes to the line where the lids meet (:data:`LID_MEET` of the opening down from
    the upper margin), the skin above (below) following less and less over :data:`LID_SHEET`
    (:data:`LID_SHEET_LOWER`) of the tallest opening; its motion along and into the face is kept.
    Measured on Ready Player Me's avatar, its artist's blink moves the upper lid's skin a third of
    the opening above the margin by a tenth of the margin's travel; ICT's real lid (and the
    carried blink) moves a band as tall as the opening."""
    from faceanim.face.regions import smoothstep

    op = eye_opening(face, slit, eyes)
    if op is None:
        return blink
    open_ = op.height > 0
    yv, upper, lower, near = _lid_frame(face, op, eyes, 0.5 * float(np.ptp(op.x[open_])))
    tallest = float(np.max(face.frame.to_local(op.upper[open_])[:, 1] - face.frame.to_local(op.lower[open_])[:, 1]))
    meet = lower + (1.0 - LID_MEET) * (upper - lower)
    middle = 0.5 * (upper + lower)
    up, lo = near & (yv > middle), near & (yv <= middle)
    fade_up = np.where(yv <= upper, 1.0, smoothstep(1.0 - (yv - upper) / (LID_SHEET * tallest)))
    fade_lo = np.where(yv >= lower, 1.0, smoothstep(1.0 - (lower - yv) / (LID_SHEET_LOWER * tallest)))
    target = np.where(up, (meet - upper) * fade_up, 0.0) + np.where(lo, (meet - lower) * fade_lo, 0.0)
    down = face.frame.rotation[1]
    return blink + ((target - blink @ down) * (up | lo))[:, None] * down


LID_PASSES = 2  # closures at most: a second closes what the first left, if the first did close
LID_SHUT = 0.02  # an eye showing less than this share of its opening is shut


def closed_blink(face: Face, blink: np.ndarray, slit: str, eyes: dict, style: str = "realistic") -> np.ndarray:
    """A carried blink with its lids closed by :func:`_lid_closure`, then, while an eye still shows
    more than :data:`LID_SHUT` of its opening and the pass before at least halved what was left,
    again (up to :data:`LID_PASSES`): one pass can leave a tenth of an anime eye open where the
    lids' meeting line is off by a ray's spacing. A pass that hardly closes anything (the opening
    measure sees through a mesh's transparent eye overlays) is not repeated. ``style``
    "stylised": the lids first drawn as a short sheet (:func:`_lid_sheet`), what it leaves open
    closed the same way within the sheet."""
    if style not in STYLES:
        raise FaceAnimError(f"unknown style '{shown(style)}'; use one of {', '.join(STYLES)}")
    rest = eye_opening(face, slit, eyes)
    if rest is None or rest.area <= 0:
        return blink
    reach = None
    if style == "stylised":
        blink = _lid_sheet(face, blink, slit, eyes)
        tallest = float(np.max(rest.height))
        reach = (LID_SHEET * tallest, LID_SHEET_LOWER * tallest)
    area = lambda d: getattr(eye_opening(face, slit, eyes, face.mesh.vertices + d), "area", 0.0)  # noqa: E731
    before = area(blink)
    if before <= LID_SHUT * rest.area:
        return blink
    for k in range(LID_PASSES):
        blink = blink + _lid_closure(face, blink, slit, eyes, reach)
        if k + 1 == LID_PASSES:
            break
        after = area(blink)
        if after <= LID_SHUT * rest.area or after > 0.5 * before:
            break
        before = after
    return blink


def blink_shapes(face: Face, eyes: dict | None = None, style: str = "realistic") -> dict[str, np.ndarray]:
    """``eyeBlinkLeft`` and ``eyeBlinkRight`` alone, as :func:`arkit_shapes` makes them (ICT's
    blinks carried, then closed by :func:`_lid_closure`), for drivers that need only the lids.
    ``eyes``: the eye pieces (:func:`face_eyes` when not given); ``style``: :func:`closed_blink`'s."""
    names = ["eyeBlink_L", "eyeBlink_R"]
    ict = retarget(face, np.eye(2), names, names=names)
    eyes = face_eyes(face) if eyes is None else eyes
    out = {}
    for slit, ict_name_, name in (("eye_L", "eyeBlink_L", "eyeBlinkLeft"), ("eye_R", "eyeBlink_R", "eyeBlinkRight")):
        out[name] = closed_blink(face, ict.blendshape(ict_name_), slit, eyes, style)
    return out


def look_shapes(face: Face, eyes: dict | None = None) -> dict[str, np.ndarray]:
    """The eight ``eyeLook*`` shapes alone, as :func:`arkit_shapes` makes them (ICT's carried,
    the lids following, plus the eyeballs turned), for drivers that need only the gaze."""
    from faceanim.standards.arkit import ARKIT_NAMES, ict_name

    columns = [c for c in ARKIT_NAMES if c.startswith("EyeLook")]
    names = [n for c in columns for n in ict_name(c)]
    ict = retarget(face, np.eye(len(names)), names, names=names)
    out = {apple_name(c): sum(ict.blendshape(n) for n in ict_name(c)) for c in columns}
    for name, d in _look_shapes(face, face_eyes(face) if eyes is None else eyes).items():
        out[name] = out[name] + d
    return out


def arkit_shapes(face: Face, eyes: dict | None = None, style: str = "realistic"
                 ) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """ARKit's shapes on ``face``: :func:`arkit_rig`'s, with the ``eyeLook*`` shapes also turning
    the eyeballs ``eyes`` (:attr:`FapRig.eyes <faceanim.rig.mpeg4.FapRig>`; found when not given),
    the blinks closed in ``style`` (:func:`closed_blink`), and the names it cannot make, with why.
    Kept in the user cache (:mod:`faceanim.io.cache`): the same mesh, landmarks, eyes and style
    with the same faceanim give them back without the work."""
    from faceanim.io.cache import cached_arrays, content_key

    if style not in STYLES:
        raise FaceAnimError(f"unknown style '{shown(style)}'; use one of {', '.join(STYLES)}")
    eye_parts = [] if eyes is None else [(side, None if e is None else [np.asarray(e[0]), np.asarray(e[1])])
                                         for side, e in sorted(eyes.items())]
    key = content_key(face.mesh.vertices, face.mesh.faces, face.landmarks,
                      *[x for side, e in eye_parts for x in ([side] + (e or [None]))],
                      *([] if style == "realistic" else [style]))
    return cached_arrays("arkit_shapes", key, lambda: _arkit_shapes(face, eyes, style))


def _arkit_shapes(face: Face, eyes: dict | None, style: str) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    eyes = face_eyes(face, eyes)
    rig, missing = arkit_rig(face)
    shapes = {n: rig.blendshape(n) for n in rig.controls}
    for name, d in _look_shapes(face, eyes).items():
        shapes[name] = shapes[name] + d
    for slit, name in (("eye_L", "eyeBlinkLeft"), ("eye_R", "eyeBlinkRight")):
        shapes[name] = closed_blink(face, shapes[name], slit, eyes, style)
    skipped = {n: "no learned pattern: the generic head has no such shape" for n in missing}
    return shapes, skipped


STILL = 1e-3  # motion under this (inter-ocular distances) is no motion
NO_TONGUE = "opens the lips and jaw as Apple's reference does; the mesh has no tongue to put out"


def shows_tongue(shapes: dict[str, np.ndarray], iod: float) -> bool:
    """Whether ``tongueOut`` in ``shapes`` (:func:`arkit_shapes`) puts out a tongue: moves some
    vertex further than ``STILL`` inter-ocular distances beyond what the mouth opening it carries
    (the generic head's ``tongueOut`` opens the mouth by a share of ``jawOpen``) moves it. A scan
    or a mask, nothing inside its mouth, gets only the opening."""
    tongue, jaw = shapes.get("tongueOut"), shapes.get("jawOpen")
    if tongue is None:
        return False
    if jaw is None or not np.any(jaw):
        return bool(np.linalg.norm(tongue, axis=1).max() > STILL * iod)
    share = float(np.sum(tongue * jaw) / np.sum(jaw * jaw))
    return bool(np.linalg.norm(tongue - share * jaw, axis=1).max() > STILL * iod)
