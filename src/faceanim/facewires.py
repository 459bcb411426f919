"""Wire curves on a face: the default set placed from landmarks, and expression templates.

The default set (``data/wires.json``, 15 wires: brows, eyelids, lips, nasolabial folds,
forehead, cheeks, chin, nose) follows Pyun, Shin & Shin's Figure 1: each reference curve is a
cubic B-spline fitted by least squares through landmarks of the MediaPipe face mesh, with a
range in inter-ocular distances, so it sits on any face whose landmarks are known.

A *template* is an expression stored as its wires (wire control points, radial scales) over the
reference curves of a base face: ``extract`` (eqs. 9-13) and ``rebuild`` are inverse of each other.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources

import numpy as np

from .deform.wires import BoundWires, Curve, Wire, bind_wires, clamped_knots, extract_wires
from .errors import DeformError, InputFileError
from .facs import face_frame
from .fileio import read_json, write_json
from .mesh import Mesh

BLENDING_FUNCTIONS = {
    "linear": lambda t: t,
    "sqrt": np.sqrt,
    "cubic": lambda t: t ** 3,
    "square": lambda t: t ** 2,
    "smooth": lambda t: t * t * (3 - 2 * t),
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
    """Named wires on a base face with their groups and the localizing exponent k."""

    wires: list[Wire]
    groups: list[str]
    k: float = 2.0

    @property
    def names(self) -> list[str]:
        return [w.name for w in self.wires]

    def bind(self, vertices) -> BoundWires:
        return bind_wires(vertices, self.wires, self.k)


def default_wires(lm478: np.ndarray, spec: dict | None = None) -> WireSet:
    """The default wires placed from a face's 478 landmarks."""
    spec = spec or default_wire_spec()
    lm = np.asarray(lm478, dtype=np.float64)
    iod = face_frame(lm).iod
    wires, groups = [], []
    for d in spec["wires"]:
        curve = fit_curve(lm[d["through"]], int(d["controls"]))
        wires.append(Wire(curve, np.asarray(d["range"], dtype=np.float64) * iod, d["name"]))
        groups.append(d.get("group", "other"))
    return WireSet(wires, groups, float(spec.get("k", 2.0)))


@dataclass
class WireTemplate:
    """An expression as wires: the wire curves' control points and radial scales over a base
    face's reference curves (the paper's compact template)."""

    wireset: WireSet
    controls: list[np.ndarray]
    scales: np.ndarray
    n_vertices: int
    meta: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "format": "faceanim wires 1", "n_vertices": int(self.n_vertices), "k": self.wireset.k,
            "meta": self.meta,
            "wires": [{"name": w.name, "group": g, "reference": w.reference.control.round(9).tolist(),
                       "range": w.range.round(9).tolist(), "wire": c.round(9).tolist(), "scale": float(s)}
                      for w, g, c, s in zip(self.wireset.wires, self.wireset.groups, self.controls, self.scales)],
        }

    def save(self, path) -> None:
        write_json(path, self.to_dict())

    @classmethod
    def from_dict(cls, d, source: str = "wire file") -> WireTemplate:
        try:
            wires, groups, controls, scales = [], [], [], []
            for w in d["wires"]:
                wires.append(Wire(Curve(np.asarray(w["reference"], dtype=np.float64)), w["range"], str(w["name"])))
                groups.append(str(w.get("group", "other")))
                c = np.asarray(w["wire"], dtype=np.float64)
                if c.shape != wires[-1].reference.control.shape:
                    raise DeformError(f"wire '{w['name']}' has {len(c)} wire control points for "
                                      f"{wires[-1].reference.n_control} reference ones")
                controls.append(c)
                scales.append(float(w.get("scale", 1.0)))
            return cls(WireSet(wires, groups, float(d.get("k", 2.0))), controls, np.array(scales),
                       int(d["n_vertices"]), dict(d.get("meta", {})))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputFileError(f"{source}: not a faceanim wire template ({exc!r})") from None

    @classmethod
    def load(cls, path) -> WireTemplate:
        return cls.from_dict(read_json(path, "wire file"), str(path))

    def rebuild(self, base: Mesh | np.ndarray, bound: BoundWires | None = None) -> np.ndarray:
        """The template's vertices on ``base``: the wires applied to the base face."""
        v = base.vertices if isinstance(base, Mesh) else np.asarray(base)
        if len(v) != self.n_vertices:
            raise DeformError(f"this template was extracted on a base face with {self.n_vertices} vertices; "
                              f"this mesh has {len(v)}")
        bound = bound or self.wireset.bind(v)
        return bound.apply(self.controls, self.scales)


def extract_template(base: Mesh, template: Mesh, wireset: WireSet, bound: BoundWires | None = None) -> WireTemplate:
    """Fit the wires of ``wireset`` to an expression template of the same topology (eqs. 9-13)."""
    if template.n_vertices != base.n_vertices or not np.array_equal(template.faces, base.faces):
        raise DeformError(f"'{template.name}' has another topology than the base '{base.name}' "
                          f"({template.n_vertices} vs {base.n_vertices} vertices); wire extraction needs "
                          "the same vertices in the same order")
    bound = bound or wireset.bind(base.vertices)
    controls, scales = extract_wires(bound, template.vertices)
    return WireTemplate(wireset, controls, scales, base.n_vertices, {"template": template.name})


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
    try:
        ys = np.array([float(x) for x in str(name).split(",")])
    except ValueError:
        raise DeformError(f"unknown blending function '{name}'; use one of {', '.join(BLENDING_FUNCTIONS)} "
                          "or samples like 0,0.1,0.5,1") from None
    if len(ys) < 2 or not np.all(np.isfinite(ys)):
        raise DeformError(f"a blending curve needs at least two finite samples, got '{name}'")
    xs = np.linspace(0.0, 1.0, len(ys))
    return lambda t: np.interp(t, xs, ys)
