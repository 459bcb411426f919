"""FAPs deform a face: a FaceDefTable built automatically for any face (MPEG-4, section 4).

For every translational FAP whose feature point the face has, the table holds the vertices it
moves and one displacement per unit of the FAP's value: the FAP direction times FAPU / 1024 times
a weight that is 1 near the feature point and falls off along the skin (a raised cosine of the
surface distance, the falloff an open MPEG-4 player uses) within a radius set by the FAP's group.
Lip and eyelid FAPs keep to their own side of the mouth or eye (a raised lower lip never lifts the
upper one). The table is linear in the values, so each of these FAPs compiles to a blendshape and
a FAP stream to one sparse product per frame (:class:`FapRig.evaluate`).

Rotations are kept as rotations: the jaw (open_jaw turns the jaw about a hinge in front of the
ears so that the chin, 2.1, drops by the FAP's amount; thrust_jaw and shift_jaw translate it),
and the head (pitch, yaw, roll about 7.1). Eyeball rotations need eyeballs: a face mask without
them reports these FAPs as unsupported.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from faceanim.face.face import Face
from faceanim.standards.mpeg4 import ANGLE_UNIT, N_FAPS, FapError, direction_vector, fap, faps
from faceanim.face.fdp import FeaturePoints
from faceanim.face.landmarks import CHEEK_EXTREMES, MOUTH_CORNERS
from faceanim.face.mesh import Mesh
from faceanim.face.regions import (
    graph_distance,
    past_corners,
    smoothstep,
)
from faceanim.rig.rig import Rig, RigidPart

# influence radius of a FAP's feature point by FAP group: (factor, FAPU); within PLATEAU of the
# radius the weight is 1 (a lid or brow moves as a piece), then it falls off as a raised cosine
# (the brows reach over the forehead: frontalis and corrugator move skin far above the brow)
RADIUS = {2: (0.45, "MW"), 3: (0.4, "ES"), 4: (0.7, "ES"), 5: (0.35, "ES"), 8: (0.45, "MW"),
          9: (0.25, "ES"), 10: (0.25, "ES")}
PLATEAU = 0.3
# feature points on one side of a slit: (slit, lower side?)
SIDE = {"2.2": ("mouth", False), "2.6": ("mouth", False), "2.7": ("mouth", False), "8.1": ("mouth", False),
        "8.5": ("mouth", False), "8.6": ("mouth", False), "8.9": ("mouth", False), "8.10": ("mouth", False),
        "2.3": ("mouth", True), "2.8": ("mouth", True), "2.9": ("mouth", True), "8.2": ("mouth", True),
        "8.7": ("mouth", True), "8.8": ("mouth", True),
        "3.1": ("eye_L", False), "3.3": ("eye_L", True), "3.2": ("eye_R", False), "3.4": ("eye_R", True)}
# feature points along one lip contour or brow: a FAP at one of them falls off to zero at its
# neighbours along the chain (a smooth hat over the chain's polyline), so neighbouring FAPs share
# the skin between them and each feature point moves by its own FAP alone (_chain_weight)
CHAINS = (("2.5", "2.7", "2.2", "2.6", "2.4"), ("2.5", "2.9", "2.3", "2.8", "2.4"),
          ("8.4", "8.6", "8.1", "8.5", "8.3"), ("8.4", "8.8", "8.2", "8.7", "8.3"),
          ("4.1", "4.3", "4.5"), ("4.2", "4.4", "4.6"))
# values beyond these are clamped (and reported by check): past 4 FAPU a face folds over itself,
# past half a turn a rotation means nothing new
LIMIT_TRANSLATION = 4096.0
LIMIT_ROTATION = 314159.0  # pi rad in AU
# eyelid feature points: (brow above the eye, inner and outer eye corners). A lid moves as a
# band along the eye (full between the corners' mid-height, fading out past the corners) and
# not up into the brow
LIDS = {"3.1": ("4.3", "3.11", "3.7"), "3.3": ("4.3", "3.11", "3.7"),
        "3.2": ("4.4", "3.8", "3.12"), "3.4": ("4.4", "3.8", "3.12")}
# FAP numbers of the rotations and rigid motions (data/faps.json has their names)
OPEN_JAW, THRUST_JAW, SHIFT_JAW = 3, 14, 15
JAW_FAPS = (OPEN_JAW, THRUST_JAW, SHIFT_JAW)
HEAD_PITCH, HEAD_YAW, HEAD_ROLL = 48, 49, 50
HEAD_FAPS = (HEAD_PITCH, HEAD_YAW, HEAD_ROLL)
EYEBALL_TURNS = {"L": (23, 25), "R": (24, 26)}  # (yaw, pitch) of each eyeball
EYEBALL_FAPS = (23, 24, 25, 26, 27, 28, 29, 30)  # with thrust and pupil dilation
# an eyeball modelled as a part of the mesh: a shell that is not skin, of at least
# EYEBALL_MIN_VERTICES, round, centred within EYEBALL_NEAR_PUPIL and no larger than
# EYEBALL_MAX_RADIUS inter-ocular distances. Round: a closed shell (under EYEBALL_OPEN of its
# edges on a boundary: sclera, cornea, iris) whose least-squares sphere leaves a spread of
# distances under EYEBALL_SPHERE of its radius (a game avatar's low-poly eyeball, its vertices
# crowded at the iris: their mean lies 0.6 radii in front of its centre); or any shell whose
# spread of distances from its vertices' mean is under EYEBALL_ROUNDNESS of their mean (lashes
# and occlusion shells are neither). A shell round about its vertices' mean turns about that mean
# (ICT's, 0.28 radii in front of its sphere's centre: the gaze calibration of the video drivers is
# measured on it), one found by its sphere about the sphere's centre.
EYEBALL_MIN_VERTICES = 20
EYEBALL_ROUNDNESS = 0.25
EYEBALL_SPHERE = 0.15
EYEBALL_OPEN = 0.02  # a shell with more than this share of boundary edges is open (a plate, not a ball)
EYEBALL_NEAR_PUPIL = 0.35
EYEBALL_MAX_RADIUS = 0.4
# the jaw region: between the mouth corners the lower side of the mouth slit; from JAW_BAND_START
# half mouth-widths past the corners (over JAW_BAND_WIDTH more) a band below the mouth level,
# JAW_BAND_HEIGHT inter-ocular distances soft; fading out over JAW_EAR_FADE towards the ears
JAW_BAND_START, JAW_BAND_WIDTH = 0.6, 0.8
JAW_BAND_HEIGHT = 0.35
JAW_EAR_FADE = 0.35
WEIGHT_FLOOR = 1e-6  # FaceDefTable weights below this are dropped (sparse blendshapes)
BROW_GROUP = 4  # the FAP group of the eyebrows


def boundary_share(mesh: Mesh, rows: np.ndarray) -> float:
    """The share of the edges of the triangles among ``rows`` that only one triangle has (0: a
    closed shell; 1 when there are no such triangles)."""
    f = mesh.faces[np.isin(mesh.faces, rows).all(axis=1)]
    if not len(f):
        return 1.0
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, count = np.unique(edges, axis=0, return_counts=True)
    return float(np.mean(count == 1))


def fit_sphere(points: np.ndarray) -> tuple[np.ndarray, float]:
    """(centre, radius) of the least-squares sphere through ``points`` (the algebraic fit:
    |p|^2 = 2 p.c + r^2 - |c|^2 is linear in c and r^2 - |c|^2)."""
    a = np.column_stack([2.0 * points, np.ones(len(points))])
    x, *_ = np.linalg.lstsq(a, np.einsum("ij,ij->i", points, points), rcond=None)
    centre = x[:3]
    return centre, float(np.sqrt(max(x[3] + centre @ centre, 0.0)))


def _find_eyeballs(mesh: Mesh, fp: FeaturePoints, on_skin: np.ndarray) -> dict:
    """Eyeballs modelled as separate parts: the round shells (not skin) around each pupil, turned
    about the centre of the largest one. None for a face that has no eyeball there."""
    labels = mesh.vertex_components
    iod = fp.frame.iod
    eyes = {}
    for side, pupil in (("L", fp["3.5"]), ("R", fp["3.6"])):
        rows, best, best_size = [], None, 0
        for c in np.unique(labels[~on_skin]):
            part = np.flatnonzero(labels == c)
            if len(part) < EYEBALL_MIN_VERTICES:
                continue
            p = mesh.vertices[part]
            centre = p.mean(0)
            dist = np.linalg.norm(p - centre, axis=1)
            round_ = dist.std() < EYEBALL_ROUNDNESS * dist.mean()
            if not round_ and boundary_share(mesh, part) < EYEBALL_OPEN:
                ball, radius = fit_sphere(p)
                spread = np.linalg.norm(p - ball, axis=1)
                if spread.std() < EYEBALL_SPHERE * radius:
                    round_, centre, dist = True, ball, spread
            if round_ and np.linalg.norm(centre - pupil) < EYEBALL_NEAR_PUPIL * iod \
                    and dist.max() < EYEBALL_MAX_RADIUS * iod:
                rows.append(part)
                if len(part) > best_size:
                    best, best_size = centre, len(part)
        eyes[side] = (np.concatenate(rows), best) if rows else None
    return eyes


def _limits() -> np.ndarray:
    """(2, 68) lowest and highest value of each FAP: +-4 FAPU or half a turn, and no negative
    values for the unidirectional FAPs (open_jaw cannot push the jaw up into the skull)."""
    high = np.array([LIMIT_ROTATION if f.is_rotation else LIMIT_TRANSLATION for f in faps()])
    low = np.array([0.0 if f.bidirectional is False else -h for f, h in zip(faps(), high)])
    return np.stack([low, high])


def _falloff(d: np.ndarray, radius: float, plateau: float = PLATEAU) -> np.ndarray:
    """1 within ``plateau`` * radius, then a raised cosine to 0 at the radius."""
    t = np.clip((d / radius - plateau) / (1.0 - plateau), 0.0, 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * t))


def _lid_band(mesh: Mesh, fp: FeaturePoints, lid: str, refs: tuple[str, str, str]) -> np.ndarray:
    """Weight (V,) of the skin an eyelid FAP may move: along the eye between its corners, from
    the lid up to halfway to the brow (upper lids) or as far below (lower lids)."""
    frame = fp.frame
    local = frame.to_local(mesh.vertices)
    brow, inner, outer = (frame.to_local(fp[r]) for r in refs)
    centre = frame.to_local(fp[lid])
    along = 1 - past_corners(local[:, 0], np.array([inner[0], outer[0]]), 0.8, 0.5)
    across = 1 - smoothstep(np.abs(local[:, 1] - centre[1]) / (0.5 * abs(brow[1] - centre[1])))
    return along * across


def _chain_weight(p: str, points: dict, gaps: dict[str, float], radius: float, distance,
                  vertices: np.ndarray) -> np.ndarray:
    """Weight (V,) of chain point ``p``: its share of the chain times one envelope of the whole
    chain. The share comes from where a vertex projects onto the chain's polyline: a smooth hat
    along it (1 at ``p``, 0 at its neighbours, neighbouring shares summing to 1); the envelope is a
    raised cosine over ``radius`` from the nearest chain point along the skin. The chain moves as a
    smooth band that fades over the FAP's radius across the face, not over the small gap between
    its points, and each feature point still moves by its own FAP alone."""
    chain = next(c for c in CHAINS if p in c and all(q in gaps for q in c))
    d = np.stack([distance(q, radius) for q in chain])  # (n, V), inf beyond the radius
    nearest = d.min(axis=0)
    envelope = np.where(np.isfinite(nearest), _falloff(nearest, radius, PLATEAU), 0.0)
    rows = np.flatnonzero(envelope > 0)
    x = vertices[rows]
    nodes = np.stack([points[q] for q in chain])
    best = np.full(len(rows), np.inf)
    share = np.zeros(len(rows))
    k = chain.index(p)
    for j in range(len(chain) - 1):  # segment j runs from node j to node j + 1
        a, b = nodes[j], nodes[j + 1]
        t = np.clip((x - a) @ (b - a) / max(float((b - a) @ (b - a)), 1e-18), 0.0, 1.0)
        dist = np.linalg.norm(x - (a + t[:, None] * (b - a)), axis=1)
        closer = dist < best
        best[closer] = dist[closer]
        value = np.zeros(len(rows))
        if k == j:
            value = 1.0 - smoothstep(t)
        elif k == j + 1:
            value = smoothstep(t)
        share[closer] = value[closer]
    out = np.zeros(len(vertices))
    out[rows] = share * envelope[rows]
    return out


def _chain_gaps(fp: FeaturePoints) -> dict[str, float]:
    """For each feature point on a chain, the distance to its nearest chain neighbour."""
    gaps: dict[str, float] = {}
    for chain in CHAINS:
        if any(p not in fp.positions for p in chain):
            continue
        for k, p in enumerate(chain):
            near = [chain[j] for j in (k - 1, k + 1) if 0 <= j < len(chain)]
            d = min(float(np.linalg.norm(fp.positions[p] - fp.positions[q])) for q in near)
            gaps[p] = min(gaps.get(p, np.inf), d)
    return gaps


class FapRig(Rig):
    """A face rigged for MPEG-4 FAPs: a :class:`Rig` whose 68 controls are the FAPs by name
    (values in FAPU units; FAPs 1 and 2 and those this face cannot show drive nothing), with
    the jaw, the eyeballs and the head as rigid parts. ``evaluate`` takes an (F, 68) matrix or a
    FAP stream (values where its mask is set)."""

    points: FeaturePoints = None
    supported: np.ndarray = None  # (68,) bool
    unsupported: dict = None  # FAP number -> why this face cannot show it
    jaw_weight: np.ndarray = None
    jaw_pivot: np.ndarray = None
    eyes: dict = None  # 'L'/'R' -> (vertex rows, centre of rotation), None where no eyeball

    @classmethod
    def build(cls, face: Face) -> FapRig:
        """Build the FaceDefTable of a face: the FAP blendshapes and rigid parts."""
        mesh, lm478 = face.mesh, face.landmarks
        fp = face.feature_points
        frame = fp.frame
        on_skin = face.skin
        sides = face.slits
        eyes = _find_eyeballs(mesh, fp, on_skin)
        rows, cols, vals = [], [], []
        supported = np.zeros(N_FAPS, dtype=bool)
        unsupported: dict[int, str] = {}
        # each feature point's nearest *skin* vertex: the FAPs move skin only (a lid's point can
        # lie nearer the eyeball under it, whose shell the distances along the skin never reach)
        from scipy.spatial import cKDTree

        skin_rows = np.flatnonzero(on_skin)
        _, near = cKDTree(mesh.vertices[skin_rows]).query(np.stack([p for p in fp.positions.values()]))
        vertex_of = dict(zip(fp.positions, skin_rows[near]))
        gaps = _chain_gaps(fp)
        # the brows move the forehead, fading out from the brow down to the eyes' midline (the
        # eyelids have FAPs of their own)
        local_y = frame.to_local(mesh.vertices)[:, 1]
        eye_y = np.mean([frame.to_local(fp[p])[1] for p in ("3.5", "3.6")])
        brow_y = np.mean([frame.to_local(fp[p])[1] for p in ("4.3", "4.4")])
        above_eyes = smoothstep((local_y - eye_y) / max(brow_y - eye_y, 1e-9))
        cache: dict = {}

        def distance(p: str, limit: float) -> np.ndarray:
            key = (p, limit)
            if key not in cache:
                cache[key] = graph_distance(mesh, np.array([vertex_of[p]]), limit=limit)
            return cache[key]

        for f in faps():
            n = f.number
            if f.is_high_level:
                supported[n - 1] = True  # visemes and expressions expand to low-level FAPs
                continue
            if n in HEAD_FAPS or n in JAW_FAPS:
                supported[n - 1] = True
                continue
            if n in EYEBALL_FAPS or f.is_rotation:
                side = next((k for k, turns in EYEBALL_TURNS.items() if n in turns), None)
                if side is not None and eyes.get(side) is not None:
                    supported[n - 1] = True
                elif side is not None:
                    unsupported[n] = "needs the eyeball modelled as a part of the mesh"
                else:  # thrusting an eyeball, dilating a pupil, rolling the tongue
                    unsupported[n] = "not implemented by faceanim's FAP rig"
                continue
            missing = [p for p in f.feature_points if p in fp.missing]
            if missing:
                unsupported[n] = f"feature point {missing[0]} ({fp.missing[missing[0]]}) is not on this face"
                continue
            unit = fp.unit(f.unit)
            factor, unit_name = RADIUS.get(f.group, (0.3, "ES"))
            radius = factor * fp.fapu[unit_name]
            d = direction_vector(f) @ frame.rotation  # face frame -> mesh
            for p in f.feature_points:
                if p in gaps:
                    w = _chain_weight(p, fp.positions, gaps, radius, distance, mesh.vertices) * on_skin
                else:
                    dist = distance(p, radius)
                    w = np.where(np.isfinite(dist), _falloff(dist, radius, PLATEAU), 0.0) * on_skin
                if p in SIDE:
                    slit, lower = SIDE[p]
                    w = w * (sides[slit] == lower)
                if p in LIDS:
                    w = w * _lid_band(mesh, fp, p, LIDS[p])
                if f.group == BROW_GROUP:
                    w = w * above_eyes
                idx = np.flatnonzero(w > WEIGHT_FLOOR)
                for axis in range(3):
                    rows.append(np.full(len(idx), n - 1))
                    cols.append(3 * idx + axis)
                    vals.append(w[idx] * d[axis] * unit)
            supported[n - 1] = True
        shapes = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                               shape=(N_FAPS, 3 * mesh.n_vertices))
        # the jaw: between the mouth corners, the skin on the lower side of the mouth slit; past
        # the corners, a smooth band across the level of the mouth (no seam across the cheeks);
        # fading out towards the ears. Hinge in front of the ears, at the level of the nose tip.
        local = frame.to_local(mesh.vertices)
        lm = np.asarray(lm478)
        corners = frame.to_local(lm[list(MOUTH_CORNERS)])
        y_mouth = corners[:, 1].mean()
        past = past_corners(local[:, 0], corners[:, 0], JAW_BAND_START, JAW_BAND_WIDTH)
        below = smoothstep((y_mouth - local[:, 1]) / (JAW_BAND_HEIGHT * frame.iod) + 0.5)
        inside = sides["mouth"].astype(float)
        ear_x = abs(frame.to_local(lm[list(CHEEK_EXTREMES)])[:, 0]).mean()
        fade_side = np.clip((ear_x - np.abs(local[:, 0])) / (JAW_EAR_FADE * frame.iod), 0.0, 1.0)
        jaw = ((1 - past) * inside + past * below) * fade_side * on_skin
        pivot_local = np.array([0.0, 0.0, frame.to_local(lm[list(CHEEK_EXTREMES)])[:, 2].mean()])
        pivot = frame.origin + pivot_local @ frame.rotation
        chin = frame.to_local(fp["2.1"]) - pivot_local
        mns, mw = fp.unit("MNS"), fp.unit("MW")
        table = faps()
        name = {f.number: f.name for f in table}
        jaw_rows = np.flatnonzero(jaw > 0)
        parts = [RigidPart("jaw", jaw_rows, jaw[jaw_rows], pivot, frame.rotation,
                           rotations=[(name[OPEN_JAW], 0, mns)],
                           translations=[(name[THRUST_JAW], frame.rotation[2] * mns),  # forward
                                         (name[SHIFT_JAW], -frame.rotation[0] * mw)],  # to the face's right
                           from_rest=True, hinge=chin)]
        for side, (yaw_fap, pitch_fap) in EYEBALL_TURNS.items():
            if eyes.get(side) is not None:
                rows, centre = eyes[side]
                parts.append(RigidPart(f"eyeball_{side}", rows, np.ones(len(rows)), centre, frame.rotation,
                                       rotations=[(name[yaw_fap], 1, ANGLE_UNIT), (name[pitch_fap], 0, ANGLE_UNIT)]))
        # the head about 7.1 (face frame: x left, y up, z forward): a turn to the face's left (+yaw)
        # about +y, then a nod down (+pitch) about +x, then a roll to its right (+roll) about +z
        parts.append(RigidPart("head", np.arange(mesh.n_vertices), np.ones(mesh.n_vertices), fp["7.1"].copy(),
                               frame.rotation, rotations=[(name[HEAD_YAW], 1, ANGLE_UNIT), (name[HEAD_PITCH], 0, ANGLE_UNIT),
                                                          (name[HEAD_ROLL], 2, ANGLE_UNIT)]))
        base = Rig.from_blendshapes(mesh, shapes, controls=[f.name for f in table], rigid_parts=parts,
                                    limits=_limits())
        return cls(base.mesh, base.controls, base.deformer, base.rigid_parts, base.limits, points=fp,
                   supported=supported, unsupported=unsupported, jaw_weight=jaw, jaw_pivot=pivot, eyes=eyes)

    def __init__(self, mesh, controls, deformer, rigid_parts=(), limits=None, *, points=None, supported=None,
                 unsupported=None, jaw_weight=None, jaw_pivot=None, eyes=None):
        super().__init__(mesh, controls, deformer, list(rigid_parts), limits)
        self.points, self.supported, self.unsupported = points, supported, dict(unsupported or {})
        self.jaw_weight, self.jaw_pivot, self.eyes = jaw_weight, jaw_pivot, dict(eyes or {})

    @property
    def lip_gap(self) -> float:
        """The neutral face's gap between the inner lips (2.2 to 2.3) in MNS units (0 when closed)."""
        fp = self.points
        gap = fp.frame.to_local(fp["2.2"])[1] - fp.frame.to_local(fp["2.3"])[1]
        return max(float(gap), 0.0) / fp.unit("MNS")

    @staticmethod
    def stream_curves(stream) -> np.ndarray:
        """A FAP stream's (F, 68) control curves: its values where its mask is set, 0 elsewhere."""
        return np.where(stream.mask, stream.values, 0.0)

    def check(self, stream) -> list[str]:
        """Warnings: FAPs the stream sets that this face cannot show, values that will be clamped."""
        used = np.flatnonzero(stream.mask.any(axis=0)) + 1
        out = [f"FAP {n} ({faps()[n - 1].name}): {self.unsupported[n]}" for n in used if n in self.unsupported]
        vals = self.stream_curves(stream)
        low, high = self.limits
        over = np.flatnonzero(((vals < low) | (vals > high)).any(axis=0))
        for idx in over:
            f = faps()[idx]
            out.append(f"FAP {f.number} ({f.name}): values from {vals[:, idx].min():g} to {vals[:, idx].max():g} "
                       f"are clamped to [{low[idx]:g}, {high[idx]:g}]")
        return out

    def evaluate(self, curves) -> np.ndarray:
        """Vertices (F, V, 3) for a FAP stream or (F, 68) FAP values."""
        if hasattr(curves, "mask"):
            curves = self.stream_curves(curves)
        return super().evaluate(curves)

    def blendshape(self, key) -> np.ndarray:
        """(V, 3) displacement per unit value of a linear FAP."""
        f = fap(key)
        if f.number in JAW_FAPS or f.number in HEAD_FAPS or f.is_high_level:
            raise FapError(f"FAP {f.number} ({f.name}) is a rotation or a high-level FAP, not a blendshape")
        return super().blendshape(f.name)
