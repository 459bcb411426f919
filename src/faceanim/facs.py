"""FACS action units as muscle and wrinkle control points placed from landmarks (Erdogdu 2010, 5.5).

The library (``data/action_units.json``) lists, for each action unit, its FACS name, the muscle it
stands for, the face half it belongs to (FACS upper or lower face) and its muscle and wrinkle
control points. A control point is defined on the MediaPipe face mesh (mean of listed
landmarks), so it can be placed on any face whose landmarks are known: detected (478 points),
or the basic 22 of the thesis, in which case the 478 are carried over from faceanim's default
face by a landmark thin-plate spline (the thesis' own transfer, section 5.6.1).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

from .deform.rbf import RadialBasis, check_points
from .errors import DeformError, FaceAnimError, LandmarkError
from .landmarks import BASIC22, Landmarks
from .mesh import Mesh

REGIONS = ("upper", "lower")
SIDES = ("both", "R", "L")
# the face oval of the MediaPipe face mesh, in order (forehead top, subject's left side, chin, ...)
FACE_OVAL = (10, 338, 297, 332, 284, 251, 389, 356, 454, 323, 361, 288, 397, 365, 379, 378, 400, 377,
             152, 148, 176, 149, 150, 136, 172, 58, 132, 93, 234, 127, 162, 21, 54, 103, 67, 109)
# outer lip contour and the lid margins: what projects inside them and lies behind them is the
# mouth cavity or the eye socket, not visible skin
LIP_OUTER = (61, 185, 40, 39, 37, 0, 267, 269, 270, 409, 291, 375, 321, 405, 314, 17, 84, 181, 91, 146)
EYE_RIGHT = (33, 246, 161, 160, 159, 158, 157, 173, 133, 155, 154, 153, 145, 144, 163, 7)
EYE_LEFT = (263, 466, 388, 387, 386, 385, 384, 398, 362, 382, 381, 380, 374, 373, 390, 249)
# a control point farther than this (IODs) from the skin is missing on that face; two closer
# than MIN_SPACING are one
MAX_SNAP = 0.25
MIN_SPACING = 0.01
# inter-ocular distances of skin around the face outline that expressions may still move
FREE_MARGIN = 0.35
# landmarks on bone that barely move with expressions: rigid alignment of expressive scans
STABLE_LANDMARKS = (168, 6, 197, 195, 133, 362, 33, 263, 234, 454, 10, 151)


class ActionUnitError(FaceAnimError):
    """Unknown action unit or emotion, or an intensity outside [0, 1]."""


@dataclass(frozen=True)
class ActionUnit:
    number: int
    name: str
    muscle: str
    region: str
    muscle_points: tuple[str, ...]
    wrinkle_points: tuple[str, ...]

    @property
    def points(self) -> tuple[str, ...]:
        return self.muscle_points + tuple(p for p in self.wrinkle_points if p not in self.muscle_points)

    def points_on(self, side: str = "both") -> tuple[str, ...]:
        """The control points of one side (``R``/``L``: the subject's own) plus midline points."""
        if side not in SIDES:
            raise ActionUnitError(f"side must be one of {', '.join(SIDES)}, got '{side}'")
        if side == "both":
            return self.points
        other = "_L" if side == "R" else "_R"
        return tuple(p for p in self.points if not p.endswith(other))


@dataclass(frozen=True)
class ControlPointSpec:
    name: str
    at: tuple[int, ...]
    region: str
    side_of: str | None = None  # a slit ('mouth', 'eye_R', 'eye_L') the point borders
    lid: str | None = None  # 'upper' or 'lower' side of that slit
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # from the landmarks, face frame, IOD units


class ActionUnitLibrary:
    """The action units, their control points, the slits and the emotions, from one JSON file."""

    def __init__(self, data: dict):
        self.about = data.get("about", "")
        self.intensity_scale = {k: float(v) for k, v in data["intensity_scale"].items()}
        self.control_points = {
            n: ControlPointSpec(n, tuple(int(i) for i in d["at"]), d["region"], d.get("side_of"), d.get("lid"),
                                tuple(float(x) for x in d.get("offset", (0.0, 0.0, 0.0))))
            for n, d in data["control_points"].items()}
        self.slits = {n: {k: tuple(v) for k, v in d.items()} for n, d in data["slits"].items()}
        self.masks = data["region_masks"]
        self.anchors = tuple(int(i) for i in data.get("anchors", ()))
        self.action_units = {
            int(k): ActionUnit(int(k), d["name"], d["muscle"], d["region"], tuple(d["muscle_points"]),
                               tuple(d["wrinkle_points"]))
            for k, d in data["action_units"].items()}
        self.emotions = {n: {int(k): v for k, v in d.items()} for n, d in data["emotions"].items()}
        for au in self.action_units.values():
            for p in au.points:
                if p not in self.control_points:
                    raise FaceAnimError(f"AU{au.number} names an unknown control point '{p}'")

    @property
    def point_names(self) -> list[str]:
        return list(self.control_points)

    def action_unit(self, number) -> ActionUnit:
        try:
            n = int(str(number).upper().removeprefix("AU"))
        except ValueError:
            raise ActionUnitError(f"'{number}' is not an action unit number (e.g. 12 or AU12)") from None
        if n not in self.action_units:
            raise ActionUnitError(
                f"unknown action unit AU{n}; the library has AU{', AU'.join(map(str, sorted(self.action_units)))}")
        return self.action_units[n]

    def parse_action_units(self, text: str) -> list[int]:
        """'1,2' or 'AU12' or 'all' to a list of AU numbers."""
        text = str(text).strip()
        if text.lower() == "all":
            return sorted(self.action_units)
        items = [t for t in text.replace(" ", "").split(",") if t]
        if not items:
            raise ActionUnitError("give action units as a comma list such as 1,2 or 'all'")
        return [self.action_unit(t).number for t in items]

    def intensity(self, value) -> float:
        """A FACS intensity letter (A-E) or a number in [0, 1] to the magnitude m."""
        if isinstance(value, str) and value.strip().upper() in self.intensity_scale:
            return self.intensity_scale[value.strip().upper()]
        try:
            m = float(value)
        except (TypeError, ValueError):
            raise ActionUnitError(f"intensity must be A-E or a number in [0, 1], got {value!r}") from None
        if not np.isfinite(m) or m < 0 or m > 1:
            raise ActionUnitError(f"magnitude m must be in [0, 1], got {value}")
        return m

    def emotion(self, name: str) -> dict[int, float]:
        """The AU mixture of a basic emotion: {AU number: magnitude}."""
        key = str(name).strip().lower()
        if key == "happiness":
            key = "joy"
        if key not in self.emotions:
            raise ActionUnitError(f"unknown emotion '{name}'; choose one of: {', '.join(self.emotions)}")
        return {au: self.intensity(v) for au, v in self.emotions[key].items()}


@lru_cache(maxsize=1)
def default_library() -> ActionUnitLibrary:
    text = resources.files("faceanim").joinpath("data", "action_units.json").read_text()
    return ActionUnitLibrary(json.loads(text))


# ---------------------------------------------------------------------------- face geometry
@dataclass(frozen=True)
class FaceFrame:
    """A face's own frame from landmarks: origin at the nose tip, x towards the subject's left
    eye, y up, z forward; its inter-ocular distance and mouth width (the thesis' s_t, s_s)."""

    origin: np.ndarray
    rotation: np.ndarray  # rows: x, y, z axes in mesh coordinates
    iod: float
    mouth_width: float

    def to_local(self, points: np.ndarray) -> np.ndarray:
        return (np.asarray(points) - self.origin) @ self.rotation.T

    def vectors_to_local(self, vectors: np.ndarray) -> np.ndarray:
        return np.asarray(vectors) @ self.rotation.T

    def vectors_to_mesh(self, vectors: np.ndarray) -> np.ndarray:
        return np.asarray(vectors) @ self.rotation


def face_frame(lm478: np.ndarray) -> FaceFrame:
    p = np.asarray(lm478)
    x = p[263] - p[33]
    iod = float(np.linalg.norm(x))
    mouth = float(np.linalg.norm(p[291] - p[61]))
    if iod <= 0 or mouth <= 0 or not np.isfinite(iod + mouth):
        raise LandmarkError("the eye corners or mouth corners coincide; the landmarks are broken")
    x = x / iod
    up = (p[33] + p[263]) / 2 - p[152]
    y = up - x * (up @ x)
    height = np.linalg.norm(y)
    if not (0.2 < mouth / iod < 2.0 and 0.5 < height / iod < 4.0):
        raise LandmarkError(
            f"the landmarks do not have a face's proportions (mouth width {mouth / iod:.2f}, eyes to chin "
            f"{height / iod:.2f} inter-ocular distances); they are out of order or not for this face")
    y /= height
    z = np.cross(x, y)
    if (p[4] - (p[33] + p[263]) / 2) @ z <= 0:
        raise LandmarkError("the nose tip lies behind the eyes in these landmarks: they are mirrored "
                            "(left and right swapped) or out of order")
    return FaceFrame(p[4].copy(), np.stack([x, y, z]), iod, mouth)


def landmarks_478(mesh: Mesh, landmarks: Landmarks) -> np.ndarray:
    """All 478 MediaPipe landmark positions on ``mesh``.

    Taken directly when ``landmarks`` has them; from the basic 22 by a landmark thin-plate
    spline from faceanim's default face (thesis 5.6.1) and snapping onto ``mesh`` otherwise.
    """
    where = {int(i): k for k, i in enumerate(landmarks.indices)}
    if all(i in where for i in range(478)):
        return landmarks.positions[[where[i] for i in range(478)]]
    need = [i for _, i in BASIC22]
    missing = [n for n, i in BASIC22 if i not in where]
    if missing:
        raise LandmarkError(
            f"action units need the 478 MediaPipe landmarks or the basic 22; missing: {', '.join(missing[:6])}"
            + (" ..." if len(missing) > 6 else "") + " (run `faceanim landmarks` on the mesh)")
    from .default_face import default_face

    ref = default_face(dense=False).vertices[:478]
    tps = landmark_tps(ref[need], landmarks.positions[[where[i] for i in need]], "basic 22 landmarks")
    moved = tps(ref)
    pos, _, _ = mesh.closest_points(moved)
    return pos


def landmark_tps(source, target, what: str = "landmarks", merge_repeated: bool = False):
    """The thesis' 3D thin-plate spline through landmark pairs (eqs. 4.11-4.19).

    Returns a callable ``f(points)`` mapping points near ``source`` to points near ``target``.
    Repeated or coplanar landmarks make the system singular: refused with a clear error, unless
    ``merge_repeated`` (dense detected sets such as MediaPipe's 478, where two points can land on
    one vertex): then only the first of each repeated source point is kept.
    """
    src = check_points(source, f"source {what}", min_count=5)
    dst = check_points(target, f"target {what}", min_count=5)
    if src.shape != dst.shape:
        raise LandmarkError(f"source and target {what} differ in count: {len(src)} vs {len(dst)}")
    if merge_repeated:
        scale = np.ptp(src, axis=0).max()
        _, first = np.unique(np.round(src / (1e-6 * scale)).astype(np.int64), axis=0, return_index=True)
        first = np.sort(first)
        src, dst = src[first], dst[first]
    for label, pts in (("source", src), ("target", dst)):
        sv = np.linalg.svd(pts - pts.mean(0), compute_uv=False)
        if sv[2] <= 1e-6 * sv[0]:
            raise LandmarkError(f"the {label} {what} are coplanar (or collinear): a 3D thin-plate spline "
                                "needs landmarks off one plane (eyes, nose tip and mouth are not)")
    try:
        system = RadialBasis(src, "thin_plate_spline", smoothing=0.0)
    except DeformError as exc:
        raise LandmarkError(f"{what}: {exc}") from None
    coeff = system.coefficients(dst - src)

    def warp(points):
        p = np.asarray(points, dtype=np.float64)
        return p + system.basis(p) @ coeff

    return warp


def skin(mesh: Mesh, lm478: np.ndarray) -> np.ndarray:
    """Vertices of the face's skin shell: the connected part that carries most landmarks, so
    eyeballs, teeth, gums and tongue modelled as separate shells of one mesh are left out."""
    _, near = mesh.kdtree.query(np.asarray(lm478)[list(FACE_OVAL) + [4, 0, 17, 70, 300]])
    labels = mesh.vertex_components
    main = np.bincount(labels[near]).argmax()
    return labels == main


def depth_behind_front(mesh: Mesh, frame: FaceFrame, cell: float = 0.04) -> np.ndarray:
    """How far (mesh units) each vertex lies behind the front-most surface around its place in
    the frontal view: ~0 on visible skin, large on the inside of the cheeks, the mouth cavity or
    the back of the head. A vertex z-buffer on cells of ``cell`` inter-ocular distances, each
    cell taking the front-most depth of its 3 x 3 neighbourhood (so a cell that only a hidden
    vertex falls into still sees the surface in front of it)."""
    from scipy.ndimage import maximum_filter

    local = frame.to_local(mesh.vertices)
    ij = np.floor(local[:, :2] / (cell * frame.iod)).astype(np.int64)
    ij -= ij.min(0)
    top = np.full(ij.max(0) + 1, -np.inf)
    np.maximum.at(top, (ij[:, 0], ij[:, 1]), local[:, 2])
    top = maximum_filter(top, size=3, mode="constant", cval=-np.inf)
    return top[ij[:, 0], ij[:, 1]] - local[:, 2]


def face_region(mesh: Mesh, lm478: np.ndarray, frame: FaceFrame | None = None) -> np.ndarray:
    """Vertices of the face: skin inside the face oval seen from the front, not behind its rim,
    without the mouth cavity and eye sockets (skin behind the lip contour and lid margins)."""
    from matplotlib.path import Path as PolyPath

    frame = frame or face_frame(lm478)
    local = frame.to_local(mesh.vertices)
    oval = frame.to_local(np.asarray(lm478)[list(FACE_OVAL)])
    inside = PolyPath(oval[:, :2]).contains_points(local[:, :2])
    region = inside & (local[:, 2] > oval[:, 2].min() - 0.1 * frame.iod) & skin(mesh, lm478)
    region &= depth_behind_front(mesh, frame) < 0.15 * frame.iod
    for contour in (LIP_OUTER, EYE_RIGHT, EYE_LEFT):
        c = frame.to_local(np.asarray(lm478)[list(contour)])
        cavity = PolyPath(c[:, :2]).contains_points(local[:, :2]) & (local[:, 2] < c[:, 2].min() - 0.02 * frame.iod)
        region &= ~cavity
    return region


def free_region(mesh: Mesh, lm478: np.ndarray, frame: FaceFrame | None = None) -> np.ndarray:
    """Vertices an expression may move: the face region grown by a margin, and the jaw and
    throat below the mouth (the chin drags them along when the jaw drops)."""
    frame = frame or face_frame(lm478)
    face = face_region(mesh, lm478, frame)
    if not face.any():
        raise LandmarkError(f"no vertices of '{mesh.name}' lie inside the face outline of the landmarks; "
                            "are the landmarks for this mesh?")
    local = frame.to_local(mesh.vertices)
    p = frame.to_local(np.asarray(lm478))
    near = face.copy()
    dist = _graph_distance(mesh, np.flatnonzero(face), limit=FREE_MARGIN * frame.iod)
    near |= np.isfinite(dist)
    jaw = (local[:, 1] < p[13, 1]) & (local[:, 1] > p[152, 1] - 0.9 * frame.iod) & \
          (local[:, 2] > min(p[234, 2], p[454, 2]) + 0.1 * frame.iod)
    # the inside of the cheeks and the mouth cavity stay with the skull (they have no handles
    # and would otherwise swing freely); the inner lips just behind the lip line stay free
    inner = depth_behind_front(mesh, frame) > 0.3 * frame.iod
    return (near | jaw) & skin(mesh, lm478) & ~inner


def region_weights(vertices: np.ndarray, lm478: np.ndarray, library: ActionUnitLibrary,
                   frame: FaceFrame | None = None) -> dict[str, np.ndarray]:
    """Weight (V,) of the upper- and lower-face warps on each vertex (thesis 5.6.2).

    Each face half is warped by its own action units with the other half's control points
    held still, then cut by its mask: an upper-face action is exactly zero from the upper lip
    down and a lower-face action exactly zero from the lower eyelids up (brow actions never
    move the mouth, and the reverse). The masks fade smoothly and overlap around the nose and
    cheeks, where both halves' warps meet, so a whole expression has no seam.
    """
    frame = frame or face_frame(lm478)
    y = frame.to_local(vertices)[:, 1]
    out = {}
    for region, m in library.masks.items():
        if region not in REGIONS:
            continue
        zero = frame.to_local(_named_point(lm478, library, m["zero_at"]))[1]
        full = frame.to_local(_named_point(lm478, library, m["full_at"]))[1]
        if (full - zero) * (1 if region == "upper" else -1) <= 0:
            raise LandmarkError("the eye, nose and mouth landmarks are not in top-to-bottom order: "
                                "the face is upside down or the landmarks are out of order")
        out[region] = smoothstep((y - zero) / (full - zero))
    return out


def smoothstep(t) -> np.ndarray:
    """3t^2 - 2t^3 of ``t`` clipped to [0, 1]: the smooth 0 -> 1 ramp every mask here uses."""
    t = np.clip(np.asarray(t, dtype=np.float64), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def past_corners(x_local: np.ndarray, corner_x: np.ndarray, start: float, width: float) -> np.ndarray:
    """How far (0..1, smooth) points lie past a slit's corners along the face's x axis: 0 within
    ``start`` half-widths of the slit's centre, 1 beyond ``start + width`` half-widths."""
    centre, half = (corner_x[0] + corner_x[1]) / 2, abs(corner_x[1] - corner_x[0]) / 2
    return smoothstep((np.abs(x_local - centre) - start * half) / (width * half))


def _named_point(lm478, library, name) -> np.ndarray:
    if isinstance(name, int):
        return np.asarray(lm478)[name]
    return np.asarray(lm478)[list(library.control_points[name].at)].mean(0)


def _graph_distance(mesh: Mesh, sources: np.ndarray, limit: float | None = None) -> np.ndarray:
    e = sp.triu(mesh.adjacency, 1).tocoo()
    length = np.linalg.norm(mesh.vertices[e.row] - mesh.vertices[e.col], axis=1)
    g = sp.csr_matrix((np.maximum(length, 1e-12), (e.row, e.col)), shape=mesh.adjacency.shape)
    return csgraph.dijkstra(g, directed=False, indices=sources, min_only=True,
                            limit=np.inf if limit is None else limit)


def slit_sides(mesh: Mesh, lm478: np.ndarray, library: ActionUnitLibrary) -> dict[str, np.ndarray]:
    """For each slit (mouth, eyes): True where a vertex is on the lower side (lower lip or lid).

    Decided by distance along the surface from the outer lip or lid margin landmarks, so the
    inner sides of parted lips or open lids land on their own side.
    """
    from scipy.spatial import cKDTree

    on_skin = np.flatnonzero(skin(mesh, lm478))
    tree_v = cKDTree(mesh.vertices[on_skin])
    out = {}
    for name, s in library.slits.items():
        _, up = tree_v.query(np.asarray(lm478)[list(s["upper"])])
        _, lo = tree_v.query(np.asarray(lm478)[list(s["lower"])])
        du = _graph_distance(mesh, np.unique(on_skin[up]))
        dl = _graph_distance(mesh, np.unique(on_skin[lo]))
        out[name] = dl < du
    return out


@dataclass
class ControlPoints:
    """Control points on one face: names, surface attachment (triangle + barycentric), positions."""

    names: list[str]
    triangles: np.ndarray
    barycentric: np.ndarray
    positions: np.ndarray
    missing: list[str] = field(default_factory=list)  # library points this face has no skin for

    def index(self, names) -> np.ndarray:
        where = {n: k for k, n in enumerate(self.names)}
        return np.array([where[n] for n in names], dtype=np.int64)

    def on(self, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """Positions on a mesh of the same topology (e.g. the aligned expressive scan)."""
        return np.einsum("nk,nkd->nd", self.barycentric, np.asarray(vertices)[faces[self.triangles]])


def place_control_points(mesh: Mesh, lm478: np.ndarray, library: ActionUnitLibrary | None = None,
                         names=None, sides: dict[str, np.ndarray] | None = None) -> ControlPoints:
    """Place the library's control points on ``mesh`` from its 478 landmarks and snap them to
    the surface. Points bordering a slit (lips, lids) snap to their own side of it."""
    library = library or default_library()
    names = list(library.control_points) if names is None else list(names)
    specs = [library.control_points[n] for n in names]
    frame = face_frame(lm478)
    target = np.stack([np.asarray(lm478)[list(s.at)].mean(0) + frame.vectors_to_mesh(np.array(s.offset)) * frame.iod
                       for s in specs])
    on_skin = skin(mesh, lm478)
    pos, dist, tri = mesh.closest_points(target, on_skin[mesh.faces].all(axis=1))
    tri = np.asarray(tri).copy()
    pos = np.asarray(pos).copy()
    # a point the face has no skin for (under the chin of a face mask) is left out
    usable = np.asarray(dist) < MAX_SNAP * frame.iod
    if not usable.any():
        raise LandmarkError(f"none of the control points lies on the surface of '{mesh.name}'; "
                            "are the landmarks for this mesh?")
    missing = [n for n, u in zip(names, usable) if not u]
    names = [n for n, u in zip(names, usable) if u]
    specs = [s for s, u in zip(specs, usable) if u]
    target, pos, tri = target[usable], pos[usable], tri[usable]
    if any(s.side_of for s in specs):
        sides = sides if sides is not None else slit_sides(mesh, lm478, library)
        vt = mesh.vertex_triangle
        for k, s in enumerate(specs):
            if not s.side_of:
                continue
            own = (sides[s.side_of] == (s.lid == "lower")) & on_skin
            # keep the projected point if its triangle is entirely on the right side
            if own[mesh.faces[tri[k]]].all():
                continue
            cand = np.flatnonzero(own)
            j = cand[np.argmin(np.linalg.norm(mesh.vertices[cand] - target[k], axis=1))]
            tri[k] = vt[j]
            pos[k] = mesh.vertices[j]
    # two points on one spot would tear the skin: keep the first, unless they sit on the two
    # sides of a closed slit (upper and lower lip of a closed mouth), which move apart freely
    keep = np.ones(len(names), dtype=bool)
    for k in range(1, len(names)):
        close = np.flatnonzero(keep[:k] & (np.linalg.norm(pos[:k] - pos[k], axis=1) < MIN_SPACING * frame.iod))
        for j in close:
            a, b = specs[j], specs[k]
            if not (a.side_of and a.side_of == b.side_of and a.lid != b.lid):
                keep[k] = False
    missing += [n for n, u in zip(names, keep) if not u]
    names = [n for n, u in zip(names, keep) if u]
    pos, tri = pos[keep], tri[keep]
    bary = mesh.barycentric(pos, tri)
    return ControlPoints(names, tri, bary, pos, missing)
