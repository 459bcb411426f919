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

from faceanim.errors import FaceAnimError, LandmarkError, shown
from faceanim.face.frame import FaceFrame, face_frame
from faceanim.face.landmarks import SLITS
from faceanim.face.mesh import Mesh
from faceanim.face.regions import skin, slit_sides, smoothstep

REGIONS = ("upper", "lower")


SIDES = ("both", "R", "L")


# a control point farther than this (IODs) from the skin is missing on that face; two closer
# than MIN_SPACING are one
MAX_SNAP = 0.25


MIN_SPACING = 0.01


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
        self.slits = SLITS
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
        items = text.replace(" ", "").split(",")
        if not text or "" in items:
            raise ActionUnitError("give action units as a comma list such as 1,2 or 'all' (no empty item)")
        numbers = [self.action_unit(t).number for t in items]
        twice = sorted({n for n in numbers if numbers.count(n) > 1})
        if twice:
            raise ActionUnitError(f"AU{twice[0]} is given twice in the action unit list; give each once")
        return numbers

    def intensity(self, value) -> float:
        """A FACS intensity letter (A-E) or a number in [0, 1] to the magnitude m."""
        if isinstance(value, str) and value.strip().upper() in self.intensity_scale:
            return self.intensity_scale[value.strip().upper()]
        try:
            m = float(value)
        except (TypeError, ValueError):
            raise ActionUnitError(f"intensity must be A-E or a number in [0, 1], got '{shown(value)}'") from None
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


def _named_point(lm478, library, name) -> np.ndarray:
    if isinstance(name, int):
        return np.asarray(lm478)[name]
    return np.asarray(lm478)[list(library.control_points[name].at)].mean(0)


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
        sides = sides if sides is not None else slit_sides(mesh, lm478)
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
