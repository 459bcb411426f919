"""Wire curves on a face: the default set placed from landmarks, and expression templates.

The default set (``data/wires.json``, 15 wires: brows, eyelids, lips, nasolabial folds,
forehead, cheeks, chin, nose) follows Pyun, Shin & Shin's Figure 1: each reference curve is a
cubic B-spline fitted by least squares through landmarks of the MediaPipe face mesh, with a
range in inter-ocular distances, so it sits on any face whose landmarks are known.

A *template* is an expression stored as its wires (wire control points, radial scales) over the
reference curves of a base face: ``extract`` (eqs. 9-13) and ``rebuild`` are inverse of each other.
"""

from __future__ import annotations

import itertools
import json
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources

import numpy as np

from faceanim.deform.rbf import check_number, check_points
from faceanim.deform.wires import (
    Curve,
    Wire,
    WireInfluence,
    clamped_knots,
    extract_wires,
    wire_influence,
)
from faceanim.errors import DeformError, InputFileError, shown
from faceanim.face.frame import face_frame
from faceanim.face.landmarks import SLITS
from faceanim.face.mesh import Mesh
from faceanim.face.regions import past_corners, smoothstep
from faceanim.io.files import read_json, write_json
from faceanim.limits import check_frames
from faceanim.rig.rig import Rig

WIRE_FORMAT = "faceanim wires 1"  # the wire template file's format tag
MAX_WIRES = 200  # wires in one template file
MAX_WIRE_CONTROLS = 1000  # control points of one wire
MAX_EDITS = 10_000  # edits in one edit file
MAX_WIRE_COORDINATE = 1e6  # mesh units: a face in millimetres is ~200 wide
MAX_BLEND_SAMPLES = 1000  # samples of a user blending curve
MAX_BLEND_WEIGHT = 10.0  # |g(t)|: past ten times the way to the target a face folds over itself

BLENDING_FUNCTIONS = {
    "linear": lambda t: t,
    "sqrt": np.sqrt,
    "cubic": lambda t: t ** 3,
    "square": lambda t: t ** 2,
    "smooth": lambda t: smoothstep(t),
}


@lru_cache(maxsize=1)
def default_wire_spec() -> dict:
    return json.loads(resources.files("faceanim").joinpath("data", "wires.json").read_text())


def fit_curve(points: np.ndarray, n_control: int) -> Curve:
    """A clamped cubic B-spline with ``n_control`` control points fitted to a polyline (chord-length
    parameters, least squares; the ends are interpolated)."""
    from scipy.interpolate import BSpline

    p = np.asarray(points, dtype=np.float64)
    chord = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]
    if chord[-1] <= 0:
        raise DeformError("the landmarks of a wire coincide; they cannot define a curve")
    u = chord / chord[-1]
    knots = clamped_knots(n_control)
    b = BSpline.design_matrix(u, knots, 3).toarray()
    control, *_ = np.linalg.lstsq(b, p, rcond=None)
    control[0], control[-1] = p[0], p[-1]
    return Curve(control)


@dataclass
class WireSet:
    """Named wires on a base face with their groups, the localizing exponent k, and for wires
    along a slit (lips, lids) the side they keep to: ``sides[j] = (slit, 'upper' | 'lower')``."""

    wires: list[Wire]
    groups: list[str]
    k: float = 2.0
    sides: list = field(default_factory=list)

    @property
    def names(self) -> list[str]:
        return [w.name for w in self.wires]

    def influence(self, mesh, lm478=None) -> WireInfluence:
        """Bind to a base face. With the face's landmarks, the wires move its skin only (eyeballs,
        teeth, gums and tongue modelled as shells of the mesh stay still) and wires with a side
        keep to it (the paper's wires are not limited: without landmarks they reach everything
        in range, across the slit)."""
        v = mesh.vertices if isinstance(mesh, Mesh) else np.asarray(mesh)
        masks = None
        if lm478 is not None and isinstance(mesh, Mesh):
            from faceanim.face.regions import skin, slit_sides

            on_skin = skin(mesh, lm478).astype(float)
            lower = slit_sides(mesh, lm478) if any(self.sides) else None
            frame = face_frame(lm478)
            x = frame.to_local(v)[:, 0]
            masks = []
            for side in self.sides:
                if not side:
                    masks.append(on_skin)
                    continue
                # the side matters between the slit's corners; beyond them both wires act, faded
                # in over a fifth of the slit's width, so the skin past the corners has no seam
                corner_x = frame.to_local(np.asarray(lm478)[list(SLITS[side[0]]["corners"])])[:, 0]
                beyond = past_corners(x, corner_x, 1.0, 0.4)
                own = lower[side[0]] == (side[1] == "lower")
                masks.append(np.where(own, 1.0, beyond) * on_skin)
        return wire_influence(v, self.wires, self.k, masks)


def default_wires(lm478: np.ndarray, spec: dict | None = None) -> WireSet:
    """The default wires placed from a face's 478 landmarks."""
    spec = spec or default_wire_spec()
    lm = np.asarray(lm478, dtype=np.float64)
    iod = face_frame(lm).iod
    wires, groups, sides = [], [], []
    for d in spec["wires"]:
        curve = fit_curve(lm[d["through"]], int(d["controls"]))
        wires.append(Wire(curve, np.asarray(d["range"], dtype=np.float64) * iod, d["name"]))
        groups.append(d.get("group", "other"))
        sides.append(tuple(d["side"]) if d.get("side") else None)
    return WireSet(wires, groups, float(spec.get("k", 2.0)), sides)


@dataclass
class WireTemplate:
    """An expression as wires: the wire curves' control points and radial scales over a base
    face's reference curves (the paper's compact template)."""

    wireset: WireSet
    controls: list[np.ndarray]
    scales: np.ndarray
    n_vertices: int
    meta: dict = field(default_factory=dict)

    @property
    def n_numbers(self) -> int:
        """What the template costs once the base face's reference curves are known: the wire
        control points and the scales."""
        return sum(c.size for c in self.controls) + len(self.scales)

    def to_dict(self) -> dict:
        return {
            "format": WIRE_FORMAT, "n_vertices": int(self.n_vertices), "k": self.wireset.k,
            "meta": self.meta,
            "wires": [{"name": w.name, "group": g, "side": list(side) if side else None,
                       "reference": w.reference.control.round(9).tolist(),
                       "range": w.range.round(9).tolist(), "wire": c.round(9).tolist(), "scale": float(s)}
                      for w, g, side, c, s in zip(self.wireset.wires, self.wireset.groups,
                                                  self.wireset.sides or [None] * len(self.controls),
                                                  self.controls, self.scales)],
        }

    def save(self, path) -> None:
        write_json(path, self.to_dict())

    @classmethod
    def from_dict(cls, d, source: str = "wire file") -> WireTemplate:
        """A template from its JSON form (:meth:`to_dict`), every field checked."""
        def bad(msg: str) -> InputFileError:
            return InputFileError(f"{source}: not a faceanim wire template ({msg})")

        if not isinstance(d, dict) or not isinstance(d.get("wires"), list) or not d["wires"]:
            raise bad("it needs a non-empty 'wires' list")
        if "format" in d and d["format"] != WIRE_FORMAT:
            raise bad(f"its 'format' is not '{WIRE_FORMAT}'; a file from another tool or a newer faceanim")
        if len(d["wires"]) > MAX_WIRES:
            raise bad(f"more than {MAX_WIRES} wires")
        try:
            n_vertices = check_number(d.get("n_vertices"), "n_vertices", 1, 1e8, integer=True)
            k = check_number(d.get("k", 2.0), "k", 0.0, 64.0)
            wires, groups, controls, scales, sides = [], [], [], [], []
            for j, w in enumerate(d["wires"]):
                if not isinstance(w, dict):
                    raise bad(f"wire {j} is not an object")
                name = w.get("name")
                if not isinstance(name, str) or not name:
                    raise bad(f"wire {j} needs a name")
                if any(w.name == name for w in wires):
                    raise bad(f"two wires are named '{shown(name)}'; each wire once")
                reference = check_points(w.get("reference"), f"wire '{name}' reference", min_count=4)
                if np.abs(reference).max() > MAX_WIRE_COORDINATE:
                    raise bad(f"wire '{shown(name)}' reference has a coordinate beyond {MAX_WIRE_COORDINATE:g}")
                if len(reference) > MAX_WIRE_CONTROLS:
                    raise bad(f"wire '{name}' has more than {MAX_WIRE_CONTROLS} control points")
                r = w.get("range")
                r = [check_number(x, f"wire '{name}' range", 0.0, 1e6, low_inclusive=False)
                     for x in (r if isinstance(r, list) else [r])]
                wires.append(Wire(Curve(reference), np.array(r), name))
                group = w.get("group", "other")
                if not isinstance(group, str):
                    raise bad(f"wire '{name}' group must be text")
                groups.append(group)
                side = w.get("side")
                if side is not None:
                    if not (isinstance(side, list) and len(side) == 2 and isinstance(side[0], str) and side[0] in SLITS
                            and side[1] in ("upper", "lower")):
                        raise bad(f"wire '{name}' side must be [slit, 'upper' | 'lower'] with a slit of "
                                  f"{', '.join(SLITS)}")
                    side = tuple(side)
                sides.append(side)
                c = check_points(w.get("wire"), f"wire '{name}' control points")
                if np.abs(c).max() > MAX_WIRE_COORDINATE:
                    raise bad(f"wire '{shown(name)}' has a control point beyond {MAX_WIRE_COORDINATE:g}")
                if c.shape != reference.shape:
                    raise bad(f"wire '{name}' has {len(c)} wire control points for {len(reference)} reference ones")
                controls.append(c)
                scales.append(check_number(w.get("scale", 1.0), f"wire '{name}' scale", 0.0, 1e3, low_inclusive=False))
        except DeformError as exc:
            raise bad(str(exc)) from None
        meta = d.get("meta", {})
        if not isinstance(meta, dict):
            raise bad("'meta' must be an object")
        return cls(WireSet(wires, groups, k, sides), controls, np.array(scales), n_vertices, dict(meta))

    @classmethod
    def load(cls, path) -> WireTemplate:
        return cls.from_dict(read_json(path, "wire file"), str(path))

    def rebuild(self, base: Mesh | np.ndarray, bound: WireInfluence | None = None, lm478=None) -> np.ndarray:
        """The template's vertices on ``base``: the wires applied to the base face."""
        v = base.vertices if isinstance(base, Mesh) else np.asarray(base)
        if len(v) != self.n_vertices:
            raise DeformError(f"this template was extracted on a base face with {self.n_vertices} vertices; "
                              f"this mesh has {len(v)}: give the face it was extracted on (--face MESH)")
        bound = bound or self.wireset.influence(base, lm478)
        return bound.apply(self.controls, self.scales)


def extract_template(base: Mesh, template: Mesh, wireset: WireSet, bound: WireInfluence | None = None,
                     lm478=None) -> WireTemplate:
    """Fit the wires of ``wireset`` to an expression template of the same topology (eqs. 9-13)."""
    if template.n_vertices != base.n_vertices or not np.array_equal(template.faces, base.faces):
        raise DeformError(f"'{template.name}' has another topology than the base '{base.name}' "
                          f"({template.n_vertices} vs {base.n_vertices} vertices); wire extraction needs "
                          "the same vertices in the same order")
    bound = bound or wireset.influence(base, lm478)
    controls, scales = extract_wires(bound, template.vertices)
    return WireTemplate(wireset, controls, scales, base.n_vertices, {"template": template.name})


def align_template(base: Mesh, template: Mesh, lm478: np.ndarray) -> Mesh:
    """``template`` rigidly aligned to ``base`` on the skull (scans differ in head pose); a face
    mask without a skull is aligned on bony landmarks."""
    from faceanim.face.frame import rigid_align
    from faceanim.face.landmarks import STABLE_LANDMARKS
    from faceanim.rig.transfer import points_on_landmarks, skull_vertices

    if template.n_vertices != base.n_vertices:
        raise DeformError(f"'{template.name}' has {template.n_vertices} vertices, the base '{base.name}' "
                          f"{base.n_vertices}; wire extraction needs the same topology")
    stable = skull_vertices(base, lm478, face_frame(lm478))
    if len(stable):
        r, t = rigid_align(template.vertices[stable], base.vertices[stable])
    else:
        idx = list(STABLE_LANDMARKS)
        r, t = rigid_align(points_on_landmarks(template, base, lm478)[idx], np.asarray(lm478)[idx])
    return template.with_vertices(template.vertices @ r.T + t)


def blend(a: WireTemplate, b: WireTemplate, t: float, group_functions: dict[str, str] | None = None) -> WireTemplate:
    """Feature-wise non-uniform blending (section 5): each wire moves from a to b by g(t) of its
    group (``{'eyes': 'sqrt', 'mouth': 'cubic'}``; other groups linear)."""
    if a.wireset.names != b.wireset.names or a.n_vertices != b.n_vertices:
        raise DeformError("the two templates were extracted with different wires or on different base faces")
    funcs = group_functions or {}
    controls, scales = [], []
    for j, group in enumerate(a.wireset.groups):
        g = blending_function(funcs.get(group, "linear"))(float(t))
        controls.append(a.controls[j] + g * (b.controls[j] - a.controls[j]))
        scales.append(a.scales[j] + g * (b.scales[j] - a.scales[j]))
    return WireTemplate(a.wireset, controls, np.array(scales), a.n_vertices, {"blend": float(t)})


def blending_function(name: str):
    """A named blending curve g(t) on [0, 1] (linear, sqrt, cubic, square, smooth) or a
    comma list of samples g(0), ..., g(1) for a user curve (linear between samples)."""
    if name in BLENDING_FUNCTIONS:
        return BLENDING_FUNCTIONS[name]
    parts = str(name).split(",")
    try:
        if len(parts) > MAX_BLEND_SAMPLES:
            raise ValueError
        ys = np.array([float(x) for x in parts])
    except ValueError:
        raise DeformError(f"unknown blending function '{shown(name)}'; use one of {', '.join(BLENDING_FUNCTIONS)} "
                          f"or up to {MAX_BLEND_SAMPLES} samples like 0,0.1,0.5,1") from None
    if len(ys) < 2 or not np.all(np.isfinite(ys)) or np.abs(ys).max() > MAX_BLEND_WEIGHT:
        raise DeformError(f"a blending curve needs at least two finite samples between -{MAX_BLEND_WEIGHT:g} and "
                          f"{MAX_BLEND_WEIGHT:g} (1 = the target template), got '{shown(name)}'")
    xs = np.linspace(0.0, 1.0, len(ys))
    return lambda t: np.interp(t, xs, ys)


def blend_blendshapes(a: WireTemplate, b: WireTemplate, bound: WireInfluence) -> dict[str, np.ndarray]:
    """The blend from ``a`` to ``b`` as blendshapes: ``from`` (template a) plus one per feature
    group (its wires' share of b - a). Wire deformation is linear in the wires once the reference
    curves are fixed, so ``from + sum_g g_g(t) * group_g`` is exactly the blended template at t."""
    if a.wireset.names != b.wireset.names:
        raise DeformError("the two templates were extracted with different wires")
    op = bound.deformer()
    shapes = {"from": op.displacements(bound.offsets(a.controls, a.scales))}
    delta_controls = [cb - ca + w.reference.control for ca, cb, w in zip(a.controls, b.controls, a.wireset.wires)]
    for group in dict.fromkeys(a.wireset.groups):
        sel = [j for j, g in enumerate(a.wireset.groups) if g == group]
        controls = [delta_controls[j] if j in sel else w.reference.control for j, w in enumerate(a.wireset.wires)]
        scales = np.array([1.0 + (b.scales[j] - a.scales[j]) if j in sel else 1.0 for j in range(len(a.scales))])
        shapes[group] = op.displacements(bound.offsets(controls, scales))
    return shapes


def parse_edits(spec, wireset: WireSet) -> tuple[dict[int, list[tuple[int, np.ndarray]]], dict[int, float]]:
    """Edits from JSON: ``{"edits": [{"wire": "upper_lip", "control": 3, "offset": [dx, dy, dz]},
    {"wire": "brow_L", "scale": 1.2}]}`` -> moves per wire index, scales per wire index."""
    if not isinstance(spec, dict) or not isinstance(spec.get("edits"), list):
        raise InputFileError('an edit file holds {"edits": [{"wire": name, "control": i, "offset": [dx, dy, dz]}, ...]}')
    moves: dict[int, list] = {}
    scales: dict[int, float] = {}
    if len(spec["edits"]) > MAX_EDITS:
        raise InputFileError(f"an edit file holds at most {MAX_EDITS} edits")
    for n, e in enumerate(spec["edits"]):
        if not isinstance(e, dict) or e.get("wire") not in wireset.names:
            wire = e.get("wire") if isinstance(e, dict) else None
            shown = f"'{wire[:40]}'" if isinstance(wire, str) else "(none)"
            raise InputFileError(f"edit {n}: unknown wire {shown}; the wires are {', '.join(wireset.names)}")
        unknown = sorted(set(e) - {"wire", "control", "offset", "scale"})
        if unknown:
            raise InputFileError(f"edit {n}: unknown key '{str(unknown[0])[:40]}'; an edit has wire, control, offset "
                                 "and/or scale")
        j = wireset.names.index(e["wire"])
        try:
            if "scale" in e:
                scales[j] = check_number(e["scale"], f"edit {n}: the scale", 0.0, 1e3, low_inclusive=False)
            if "control" in e:
                last = wireset.wires[j].reference.n_control - 1
                i = check_number(e["control"], f"edit {n}: wire '{e['wire']}' control (0..{last})", 0, last,
                                 integer=True)
                raw = e.get("offset")
                if not (isinstance(raw, list) and len(raw) == 3 and not any(isinstance(x, list) for x in raw)):
                    raise InputFileError(f"edit {n}: 'offset' must be one [dx, dy, dz]")
                off = check_points(raw, f"edit {n}: 'offset' [dx, dy, dz]")
                if off.shape != (1, 3) or np.abs(off).max() > 1e6:
                    raise InputFileError(f"edit {n}: 'offset' must be one [dx, dy, dz] of reasonable size")
                moves.setdefault(j, []).append((i, off[0]))
        except DeformError as exc:
            raise InputFileError(str(exc)) from None
    return moves, scales


def edit_template(t: WireTemplate, moves, scales) -> WireTemplate:
    """A copy of ``t`` with wire control points moved and scales set (local editing)."""
    controls = [c.copy() for c in t.controls]
    s = t.scales.copy()
    for j, items in moves.items():
        for i, off in items:
            controls[j][i] += off
    for j, value in scales.items():
        s[j] = value
    return WireTemplate(t.wireset, controls, s, t.n_vertices, dict(t.meta, edited=True))


def blend_chain(base: Mesh, lm478: np.ndarray, templates: list[WireTemplate], functions: dict[str, str],
                frames: int) -> tuple[Rig, np.ndarray]:
    """A feature-wise blend through a chain of templates a -> b -> c ... as a Rig and its curves.

    The rig's controls are ``from`` (template a) and, per segment i and wire group g, the group's
    share of (next - this) (``g``, or ``g@i`` for chains of more than two templates). Segment i's
    columns follow the group's blending function over the segment and hold their end value after
    it, so the curves (``frames`` per segment) give exactly the blended templates.
    ``functions``: wire group -> blending function (``sqrt``, ``cubic``, samples ``0,0.2,1``...);
    groups not named blend linearly.
    """
    if len(templates) < 2:
        raise DeformError("a blend needs at least two templates")
    for t in templates:
        if t.n_vertices != base.n_vertices:
            raise DeformError(f"a template was extracted on a base with {t.n_vertices} vertices; this base has "
                              f"{base.n_vertices}")
    groups = list(dict.fromkeys(templates[0].wireset.groups))
    unknown = sorted(set(functions) - set(groups))
    if unknown:
        raise DeformError(f"no wire group {', '.join(unknown)}; the groups are {', '.join(groups)}")
    curves_of = {g: blending_function(functions.get(g, "linear")) for g in groups}
    bound = templates[0].wireset.influence(base, lm478)
    shapes, columns = {}, []
    for i, (a, b) in enumerate(itertools.pairwise(templates)):
        seg = blend_blendshapes(a, b, bound)
        if i == 0:
            shapes["from"] = seg["from"]
            columns.append((None, None))
        for g, d in seg.items():
            if g != "from":
                shapes[g if len(templates) == 2 else f"{g}@{i + 1}"] = d
                columns.append((i, curves_of[g]))
    n_seg = len(templates) - 1
    ts = np.linspace(0.0, float(n_seg), check_frames(frames * n_seg, "frames of the blend chain"))
    curves = np.zeros((len(ts), len(columns)))
    for c, (seg_i, curve) in enumerate(columns):
        curves[:, c] = 1.0 if seg_i is None else curve(np.clip(ts - seg_i, 0.0, 1.0))
    return Rig.from_blendshapes(base, shapes), curves
