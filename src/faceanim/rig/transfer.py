"""Landmark-driven expression transfer between faces (Erdogdu 2010, sections 5.5.3 and 5.6).

1. *Learn* (5.5.3): the control points of the neutral source face are found on the expressive
   scan of the same person, and their displacement vectors ``v_i = P'_i - P_i`` (eq. 5.6) are
   kept. With the same topology (a registered scan) the points are followed exactly through
   their triangles; otherwise by the thesis' landmark thin-plate spline from the neutral to the
   expressive landmarks plus snapping to the nearest surface point.
2. *Animate* (5.6): the control points are placed on the target from its landmarks, each one
   moves by ``v_i * m`` (upper face) or ``v_i * m * s_t / s_s`` (lower face, the mouth-width
   ratio, eq. 5.8), and each face half is warped with its own interpolant, masked to its half.

Displacements are stored in the source face's own frame (x to the subject's left eye, y up,
z forward) and divided by its inter-ocular distance (upper face) or mouth width (lower face),
so they rotate and scale onto any target.

Interpolants: ``tps`` is the thesis' 3D thin-plate spline ``f(x) = [1 x y z] A + sum w_i
U(|P_i - x|)`` (eq. 4.19) over the half's control points, faded out beyond the face outline;
``surface`` (default) is faceanim's biharmonic interpolation along the skin
(:mod:`faceanim.deform.surface`) with a few fixed anchors at the top of the forehead, which does
not couple the lips across the mouth or the lids across the eye.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from faceanim.deform.rbf import RadialBasis, landmark_tps
from faceanim.deform.surface import bind_surface
from faceanim.errors import DeformError, LandmarkError, MeshError
from faceanim.face.face import Face
from faceanim.face.frame import FaceFrame, face_frame, rigid_align
from faceanim.face.landmarks import STABLE_LANDMARKS
from faceanim.face.mesh import Mesh
from faceanim.face.regions import FREE_MARGIN, free_region, skin
from faceanim.rig.facs import (
    MAX_SNAP,
    MIN_SPACING,
    ActionUnitError,
    ActionUnitLibrary,
    ControlPoints,
    default_library,
    place_control_points,
    region_weights,
)
from faceanim.rig.rig import Rig

METHODS = ("surface", "tps")


SUBNASALE = 2  # MediaPipe point below the nose: the skull is what lies above it
CUTOFF = 1e-4  # blendshape displacements below this many inter-ocular distances are zero


def skull_vertices(mesh: Mesh, lm478: np.ndarray, frame: FaceFrame) -> np.ndarray:
    """Vertices for rigid alignment of two scans: the skull above the mouth, outside the
    region expressions move (none on a face mask: then stable landmarks are used)."""
    free = free_region(mesh, lm478, frame)
    above = frame.to_local(mesh.vertices)[:, 1] > frame.to_local(np.asarray(lm478)[SUBNASALE])[1]
    out = np.flatnonzero(~free & above)
    return out if len(out) >= 50 else np.zeros(0, dtype=np.int64)


@dataclass
class ExpressionSample:
    """Displacements of the control points learned from one neutral/expressive pair, in the
    source's normalised frame (see module docstring)."""

    names: list[str]
    displacements: np.ndarray  # (N, 3), units: IOD (upper) or mouth width (lower)
    source: str = ""
    method: str = "correspondence"

    def subset(self, names) -> ExpressionSample:
        where = {n: k for k, n in enumerate(self.names)}
        return ExpressionSample(list(names), self.displacements[[where[n] for n in names]], self.source, self.method)

    def to_dict(self) -> dict:
        return {"source": self.source, "method": self.method,
                "points": {n: [round(float(x), 6) for x in d] for n, d in zip(self.names, self.displacements)}}

    @classmethod
    def from_dict(cls, d: dict) -> ExpressionSample:
        names = list(d["points"])
        return cls(names, np.array([d["points"][n] for n in names], dtype=np.float64).reshape(-1, 3),
                   d.get("source", ""), d.get("method", ""))


def _normaliser(names, library: ActionUnitLibrary, frame: FaceFrame) -> np.ndarray:
    return np.array([frame.iod if library.control_points[n].region == "upper" else frame.mouth_width
                     for n in names])


def learn_expression(neutral: Mesh, expressive: Mesh, neutral_lm478: np.ndarray,
                     expressive_lm478: np.ndarray | None = None, library: ActionUnitLibrary | None = None,
                     method: str = "auto") -> ExpressionSample:
    """Displacements of every control point from a neutral scan to an expressive scan of the
    same person (thesis 5.5.3).

    ``method``: ``correspondence`` (same topology: follow the points' triangles after rigid
    alignment on the skull), ``landmarks`` (the thesis: landmark TPS neutral -> expressive and
    snapping to the expressive surface; needs ``expressive_lm478``), or ``auto``.
    """
    library = library or default_library()
    frame = face_frame(neutral_lm478)
    points = place_control_points(neutral, neutral_lm478, library)
    same = neutral.n_vertices == expressive.n_vertices and np.array_equal(neutral.faces, expressive.faces)
    if method == "auto":
        method = "correspondence" if same else "landmarks"
    if method == "correspondence":
        if not same:
            raise MeshError(f"'{expressive.name}' has another topology than '{neutral.name}' "
                            f"({expressive.n_vertices} vs {neutral.n_vertices} vertices); use method 'landmarks'")
        stable = skull_vertices(neutral, neutral_lm478, frame)
        if len(stable):
            r, t = rigid_align(expressive.vertices[stable], neutral.vertices[stable])
        else:
            idx = list(STABLE_LANDMARKS)
            r, t = rigid_align(points_on_landmarks(expressive, neutral, neutral_lm478)[idx],
                               np.asarray(neutral_lm478)[idx])
        moved = points.on(expressive.vertices @ r.T + t, neutral.faces)
    elif method == "landmarks":
        if expressive_lm478 is None:
            raise LandmarkError("learning without a shared topology needs the expressive scan's landmarks")
        idx = list(STABLE_LANDMARKS)
        r, t = rigid_align(np.asarray(expressive_lm478)[idx], np.asarray(neutral_lm478)[idx])
        exp_lm = np.asarray(expressive_lm478) @ r.T + t
        # the face's 468 points (the irises lie on the eyeballs); detection can put two on one spot
        warp = landmark_tps(np.asarray(neutral_lm478)[:468], exp_lm[:468], merge_repeated=True)
        aligned = expressive.with_vertices(expressive.vertices @ r.T + t)
        on_skin = skin(expressive, expressive_lm478)
        moved, _, _ = aligned.closest_points(warp(points.positions), on_skin[expressive.faces].all(axis=1))
    else:
        raise DeformError(f"unknown learning method '{method}'; choose correspondence, landmarks or auto")
    d = frame.vectors_to_local(moved - points.positions) / _normaliser(points.names, library, frame)[:, None]
    return ExpressionSample(points.names, d, f"{neutral.name} -> {expressive.name}", method)


def points_on_landmarks(expressive: Mesh, neutral: Mesh, lm478: np.ndarray) -> np.ndarray:
    """The neutral landmarks followed onto a same-topology expressive mesh."""
    pos, _, tri = neutral.closest_points(lm478)
    bary = neutral.barycentric(pos, tri)
    return np.einsum("nk,nkd->nd", bary, expressive.vertices[neutral.faces[tri]])


@dataclass
class ActionUnitModel:
    """Learned displacements per action unit: AU number -> sample over that AU's points."""

    samples: dict[int, ExpressionSample] = field(default_factory=dict)
    about: str = ""

    def to_dict(self) -> dict:
        return {"about": self.about, "action_units": {str(k): s.to_dict() for k, s in sorted(self.samples.items())}}

    @classmethod
    def from_dict(cls, d: dict) -> ActionUnitModel:
        return cls({int(k): ExpressionSample.from_dict(v) for k, v in d["action_units"].items()}, d.get("about", ""))


def default_model() -> ActionUnitModel:
    """The built-in AU displacements (learned from real scans by scripts/learn_au_library.py)."""
    import json
    from importlib import resources

    return ActionUnitModel.from_dict(json.loads(
        resources.files("faceanim").joinpath("data", "au_displacements.json").read_text()))


# a control point whose triangle lies outside the face's free region (under the chin of a dense
# scan, where the front view's depth test calls the skin hidden) frees the skin within this many
# inter-ocular distances around it (graph distance), so that it can move what it should
POINT_REACH = 0.15


def _free_around_points(face: Face, points: ControlPoints) -> np.ndarray:
    """The face's free region, grown around control points it leaves with no free corner."""
    from faceanim.face.regions import graph_distance

    free = face.free_region
    stuck = ~free[face.mesh.faces[points.triangles]].any(axis=1)
    if not stuck.any():
        return free
    seeds = np.unique(face.mesh.faces[points.triangles[stuck]])
    near = np.isfinite(graph_distance(face.mesh, seeds, limit=POINT_REACH * face.frame.iod))
    return free | (near & face.skin)


class ExpressionTransfer:
    """A target face rigged with control points: turns learned displacements into blendshapes.

    Binding (placement, region weights, the interpolants) happens once; every AU, side, emotion
    or whole learned expression then costs one matrix product.
    """

    def __init__(self, face: Face, library: ActionUnitLibrary | None = None, method: str = "surface", names=None):
        if method not in METHODS:
            raise DeformError(f"unknown transfer method '{method}'; choose one of: {', '.join(METHODS)}")
        self.face = face
        self.mesh = target = face.mesh
        self.library = library or default_library()
        self.lm = face.landmarks
        self.frame = face.frame
        self.method = method
        self.points: ControlPoints = place_control_points(target, self.lm, self.library, names, sides=face.slits)
        self.free = _free_around_points(face, self.points)
        self.region = region_weights(target.vertices, self.lm, self.library, self.frame)
        self.scale = _normaliser(self.points.names, self.library, self.frame)
        self._regions = {r: np.array([self.library.control_points[n].region == r for n in self.points.names])
                         for r in ("upper", "lower")}
        self._bind()

    def _bind(self):
        names = self.points.names
        self._n_anchors = 0
        if self.method == "surface":
            # fixed anchors at the top of the forehead (the paper's anchors): the skin at the
            # hairline stays put, also on a face mask that ends there
            ids = list(self.library.anchors)
            on_skin = self.face.skin
            pos, dist, tri = self.mesh.closest_points(self.lm[ids], on_skin[self.mesh.faces].all(axis=1))
            near = np.linalg.norm(pos[:, None] - self.points.positions[None], axis=2).min(1)
            ok = (dist < MAX_SNAP * self.frame.iod) & (near > MIN_SPACING * self.frame.iod)
            # an anchor on fixed vertices only is held already (a dense mesh's free region ends
            # farther from the hairline than a coarse one's triangles reach)
            ok &= self.free[self.mesh.faces[np.asarray(tri)]].any(axis=1)
            tri, bary = np.asarray(tri)[ok], self.mesh.barycentric(pos[ok], np.asarray(tri)[ok])
            self._n_anchors = int(ok.sum())
            deformer = bind_surface(self.mesh.vertices, self.mesh.faces,
                                    np.concatenate([self.points.triangles, tri]),
                                    np.concatenate([self.points.barycentric, bary]), self.free,
                                    handle_names=names + [f"anchor{i}" for i in np.asarray(ids)[ok]])
            self._operators = {r: deformer for r in ("upper", "lower")}
            return
        # the thesis (5.6.2): one TPS per face half over that half's control points (eq. 4.19),
        # evaluated on the face; beyond the face outline the warp fades out over the margin of
        # the free region instead of extrapolating (the thesis' faces were cropped there)
        from faceanim.deform.base import LinearDeformer
        from faceanim.face.regions import graph_distance as _graph_distance
        from faceanim.face.regions import smoothstep

        dist = _graph_distance(self.mesh, np.flatnonzero(self.face.face_region), limit=FREE_MARGIN * self.frame.iod)
        fade = np.where(np.isfinite(dist), smoothstep(1.0 - dist / (FREE_MARGIN * self.frame.iod)), 0.0)
        rows = np.flatnonzero(self.free & (fade > 0))
        self._operators = {}
        for r, sel in self._regions.items():
            system = RadialBasis(self.points.positions[sel], "thin_plate_spline", smoothing=0.0)
            full = np.zeros((len(rows), len(names)))
            full[:, np.flatnonzero(sel)] = system.weights(self.mesh.vertices[rows]) * fade[rows, None]
            self._operators[r] = LinearDeformer(self.mesh.vertices, full, rows, handle_names=names)

    def offsets(self, sample: ExpressionSample, magnitude: float = 1.0) -> np.ndarray:
        """Handle offsets (N, 3) in mesh units for a sample (points it lacks stay still)."""
        where = {n: k for k, n in enumerate(sample.names)}
        d = np.zeros((len(self.points.names), 3))
        for k, n in enumerate(self.points.names):
            if n in where:
                d[k] = sample.displacements[where[n]]
        return self.frame.vectors_to_mesh(d * self.scale[:, None]) * magnitude

    def delta(self, sample: ExpressionSample, magnitude: float = 1.0) -> np.ndarray:
        """(V, 3) vertex displacement of the target for one sample at magnitude m."""
        d = self.offsets(sample, magnitude)
        out = np.zeros_like(self.mesh.vertices)
        for r in ("upper", "lower"):
            dr = np.where(self._regions[r][:, None], d, 0.0)
            if not dr.any():
                continue
            dr = np.vstack([dr, np.zeros((self._n_anchors, 3))])
            op = self._operators[r]
            out += op.displacements(dr) * self.region[r][:, None]
        return out

    def points_delta(self, sample: ExpressionSample, aus, magnitude: float = 1.0,
                     side: str = "both") -> np.ndarray:
        """One learned expression restricted to the union of the listed AUs' control points
        (each point moves once): how a whole real expression is rebuilt with ``aus='all'``."""
        keep = set()
        for au in aus:
            keep.update(self.library.action_unit(au).points_on(side))
        return self.delta(sample.subset([n for n in sample.names if n in keep]), magnitude)

    def action_unit_delta(self, model: ActionUnitModel, au: int, magnitude: float = 1.0,
                          side: str = "both") -> np.ndarray:
        unit = self.library.action_unit(au)
        if unit.number not in model.samples:
            raise ActionUnitError(f"AU{unit.number} has no learned displacements in this model")
        sample = model.samples[unit.number]
        keep = [n for n in unit.points_on(side) if n in sample.names]
        return self.delta(sample.subset(keep), magnitude)

    def mixture_delta(self, model: ActionUnitModel, weights: dict[int, float], side: str = "both") -> np.ndarray:
        """Several AUs at once (an emotion, a mix).

        Motions measured on different scans add up. AUs learned from the same scan (AU1 and AU2
        from one brow raise) share that scan's measurement at their common points: it is used
        once there, at the larger of their magnitudes, not once per AU.
        """
        groups: dict[str, dict[str, tuple[float, np.ndarray]]] = {}
        for au, m in weights.items():
            m = self.library.intensity(m)
            unit = self.library.action_unit(au)
            if unit.number not in model.samples:
                raise ActionUnitError(f"AU{unit.number} has no learned displacements in this model")
            sample = model.samples[unit.number]
            where = {n: k for k, n in enumerate(sample.names)}
            group = groups.setdefault(sample.source or f"AU{unit.number}", {})
            for n in unit.points_on(side):
                if n in where and (n not in group or m > group[n][0]):
                    group[n] = (m, sample.displacements[where[n]])
        total: dict[str, np.ndarray] = {}
        for group in groups.values():
            for n, (m, d) in group.items():
                total[n] = total.get(n, 0.0) + m * d
        if not total:
            return np.zeros_like(self.mesh.vertices)
        names = list(total)
        return self.delta(ExpressionSample(names, np.array([total[n] for n in names])))

    def rig(self, model: ActionUnitModel, emotions: bool = True, sides: bool = True) -> Rig:
        """Every AU of the model (and its one-sided halves) and every emotion as named blendshapes."""
        shapes = {}
        for au in sorted(model.samples):
            if au not in self.library.action_units:
                continue
            shapes[f"AU{au}"] = self.action_unit_delta(model, au)
            if sides and any(p.endswith("_R") for p in self.library.action_unit(au).points):
                for s in ("L", "R"):
                    shapes[f"AU{au}_{s}"] = self.action_unit_delta(model, au, side=s)
        if emotions:
            for name in self.library.emotions:
                mix = self.library.emotion(name)
                if all(a in model.samples for a in mix):
                    shapes[name] = self.mixture_delta(model, mix)
        # the interpolant's far tails (under a micrometre on a real face) are set to exactly zero,
        # so each morph target touches only the skin its action moves (sparse in glTF)
        floor = CUTOFF * self.frame.iod
        for d in shapes.values():
            d[np.linalg.norm(d, axis=1) < floor] = 0.0
        return Rig.from_blendshapes(self.mesh, shapes)
