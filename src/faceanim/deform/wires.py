"""Wire deformation (Singh & Fiume 1998, as used by Pyun, Shin & Shin 2001, section 3).

A wire is a tuple <W, R, f, r, s>: a wire curve W and a reference curve R (cubic B-splines with
the same knots, coincident at rest), a falloff f, a range r and a radial scale s. For a point p,
let p_R be its closest point on R (curve parameter u) and p_W = W(u). Then (eq. 2)

    p' = p + (s - 1) f(x) (p - p_R) + f(x) (p_W - p_R),     x = |p - p_R| / r(u),
    f(x) = (1 - x^2)^2 for x < 1, 0 beyond,

and several wires combine with the localizing exponent k (eq. 3):

    p' = p + sum_j f_j^k dp_j / sum_j f_j^k.

With the reference curves fixed, p_R, u, f and the blending weights are fixed too, and
``p_W - p_R = sum_l B_l(u) q_l`` with ``q_l = w_l - r_l`` the control-point offsets (eq. 6). So the
deformation is linear in the offsets q and in (s_j - 1): it binds once to a
:class:`~faceanim.deform.base.LinearDeformer` whose handles are every wire control point plus
three "scale handles" per wire (the x, y and z parts of ``(s_j - 1) * w_ij (p_i - p_iRj)``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.interpolate import BSpline
from scipy.spatial import cKDTree

from faceanim.deform.base import LinearDeformer
from faceanim.deform.rbf import check_points
from faceanim.errors import DeformError

DEGREE = 3
_SAMPLES_PER_SPAN = 48  # dense samples of the reference curve for the closest-point search


def clamped_knots(n_control: int, degree: int = DEGREE) -> np.ndarray:
    """Open uniform knot vector: the curve starts and ends at its end control points."""
    inner = np.linspace(0.0, 1.0, n_control - degree + 1)
    return np.concatenate([np.zeros(degree), inner, np.ones(degree)])


def falloff(x: np.ndarray) -> np.ndarray:
    """f(x) = (1 - x^2)^2 for x < 1, 0 beyond (f(0) = 1, f'(1) = 0)."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(x < 1.0, (1.0 - x * x) ** 2, 0.0)


@dataclass
class Curve:
    """A cubic B-spline through ``control`` (N >= 4, 3-D), clamped at both ends."""

    control: np.ndarray

    def __post_init__(self):
        c = check_points(self.control, "curve control points")
        if len(c) < DEGREE + 1:
            raise DeformError(f"a cubic B-spline curve needs at least {DEGREE + 1} control points, got {len(c)}")
        step = np.linalg.norm(np.diff(c, axis=0), axis=1)
        if (step <= 1e-12 * max(np.ptp(c, axis=0).max(), 1e-300)).any():
            k = int(np.flatnonzero(step <= 1e-12 * max(np.ptp(c, axis=0).max(), 1e-300))[0])
            raise DeformError(f"curve control points {k} and {k + 1} coincide; remove the repeated point")
        self.control = c
        self.knots = clamped_knots(len(c))

    @property
    def n_control(self) -> int:
        return len(self.control)

    def basis(self, u: np.ndarray) -> np.ndarray:
        """B_l(u): (len(u), N) basis functions at curve parameters ``u`` in [0, 1]."""
        u = np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0)
        return BSpline.design_matrix(u, self.knots, DEGREE).toarray()

    def __call__(self, u: np.ndarray) -> np.ndarray:
        return self.basis(u) @ self.control

    def closest(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Closest curve point of each of ``points``: (curve parameters u, positions)."""
        p = np.atleast_2d(np.asarray(points, dtype=np.float64))
        n = (self.n_control - DEGREE) * _SAMPLES_PER_SPAN + 1
        us = np.linspace(0.0, 1.0, n)
        samples = self(us)
        # start from the few nearest samples (a curve that comes back near itself has several
        # local minima), refine each by Newton steps on |C(u) - p|^2, keep the closest
        starts = 3
        _, idx = cKDTree(samples).query(p, k=starts)
        h = 1.0 / (n - 1)
        curve = BSpline(self.knots, self.control, DEGREE)
        deriv = curve.derivative()
        deriv2 = deriv.derivative()
        pp = np.repeat(p, starts, axis=0)
        u = us[idx.ravel()]
        for _ in range(5):
            c, d1, d2 = curve(u), deriv(u), deriv2(u)
            diff = c - pp
            g = (diff * d1).sum(1)
            hess = (d1 * d1).sum(1) + (diff * d2).sum(1)
            step = np.where(hess > 1e-300, g / np.where(hess > 1e-300, hess, 1.0), 0.0)
            u = np.clip(u - np.clip(step, -h, h), 0.0, 1.0)
        dist = np.linalg.norm(curve(u) - pp, axis=1).reshape(-1, starts)
        best = dist.argmin(1)
        u = u.reshape(-1, starts)[np.arange(len(p)), best]
        return u, curve(u)


@dataclass
class Wire:
    """A reference curve with its range r (one value, or one per control point, interpolated
    along the curve with the curve's own basis) and a name."""

    reference: Curve
    range: np.ndarray
    name: str = "wire"

    def __post_init__(self):
        r = np.atleast_1d(np.asarray(self.range, dtype=np.float64))
        if r.size == 1:
            r = np.full(self.reference.n_control, float(r[0]))
        if r.shape != (self.reference.n_control,):
            raise DeformError(f"wire '{self.name}': give one range or one per control point "
                              f"({self.reference.n_control}), got {r.size}")
        if not np.all(np.isfinite(r)) or (r <= 0).any():
            raise DeformError(f"wire '{self.name}': the range r must be positive, got {r.min():.4g}")
        self.range = r

    def range_at(self, u: np.ndarray) -> np.ndarray:
        return self.reference.basis(u) @ self.range


@dataclass
class WireInfluence:
    """Where wires act on a rest mesh: the fixed parts of eqs. 3-9 for every vertex
    (:meth:`deformer` is the bound operator).

    ``weights`` (V, m) are ``w_ij = f_ij^(k+1) / sum_j f_ij^k`` (0 where no wire reaches),
    ``radial`` (m, V, 3) the vectors ``p_i - p_iRj`` and ``basis`` (m, V, t_j) the ``B_l(u_ij)``.
    """

    wires: list[Wire]
    k: float
    rest: np.ndarray
    weights: np.ndarray
    radial: np.ndarray
    basis: list[np.ndarray]
    _operator: LinearDeformer | None = field(default=None, repr=False)

    @property
    def n_handles(self) -> int:
        return sum(w.reference.n_control for w in self.wires) + 3 * len(self.wires)

    def offsets(self, wire_controls=None, scales=None) -> np.ndarray:
        """Handle offsets (H, 3) of the bound operator from wire control points and scales."""
        rows = []
        for j, w in enumerate(self.wires):
            if wire_controls is None:
                rows.append(np.zeros((w.reference.n_control, 3)))
            else:
                c = np.asarray(wire_controls[j], dtype=np.float64)
                if c.shape != w.reference.control.shape:
                    raise DeformError(f"wire '{w.name}' needs {w.reference.n_control} control points, "
                                      f"got {c.shape}")
                rows.append(c - w.reference.control)
        s = np.ones(len(self.wires)) if scales is None else np.asarray(scales, dtype=np.float64)
        if s.shape != (len(self.wires),):
            raise DeformError(f"give one scale per wire ({len(self.wires)}), got {s.shape}")
        rows.append(np.repeat(s - 1.0, 3)[:, None] * np.tile(np.eye(3), (len(self.wires), 1)))
        return np.vstack(rows)

    def deformer(self, dtype=np.float64) -> LinearDeformer:
        """The bound operator: positions = rest + W @ offsets(wire controls, scales)."""
        cols, names = [], []
        for j, w in enumerate(self.wires):
            cols.append(self.weights[:, j:j + 1] * self.basis[j])
            names += [f"{w.name}[{i}]" for i in range(w.reference.n_control)]
        moved = np.flatnonzero(self.weights.sum(1) > 0)
        w_ctrl = np.hstack(cols)[moved]
        # scale handles: one column per axis, its offset (s - 1) on that axis only; a column weight
        # is the radial vector's component, so W @ offsets gives (s - 1) w_ij (p_i - p_iRj)
        scale_cols = np.zeros((len(moved), 3 * len(self.wires)))
        for j, w in enumerate(self.wires):
            scale_cols[:, 3 * j:3 * j + 3] = self.weights[moved, j:j + 1] * self.radial[j][moved]
            names += [f"{w.name}.scale_{a}" for a in "xyz"]
        full = np.hstack([w_ctrl, scale_cols])
        return LinearDeformer(self.rest.astype(dtype), sp.csr_matrix(full.astype(dtype)), moved,
                              handle_names=names)

    def apply(self, wire_controls=None, scales=None) -> np.ndarray:
        """Deformed vertex positions (V, 3) for wire control points and scales, through the bound
        operator (built once and kept)."""
        if self._operator is None:
            self._operator = self.deformer()
        return self._operator.apply(self.offsets(wire_controls, scales))


WEIGHT_CUTOFF = 1e-4  # blending weights below this are dropped: a share of the motion under 0.01%


def wire_influence(rest, wires: list[Wire], k: float = 1.0, masks=None) -> WireInfluence:
    """Closest points on every reference curve, falloffs and the eq. 3 blending weights.

    ``masks`` (one (V,) array of factors in [0, 1] or None per wire) scales a wire's falloff per
    vertex, e.g. keeps the upper-lip wire to the upper side of the mouth: the paper's falloff
    measures distance through the air, so without it a lip wire also drags the other lip a few
    millimetres away.
    """
    rest = check_points(rest, "mesh vertices")
    if not wires:
        raise DeformError("give at least one wire")
    if not np.isfinite(k) or k < 0:
        raise DeformError(f"the localizing exponent k must be >= 0, got {k}")
    m = len(wires)
    f = np.zeros((len(rest), m))
    radial = np.zeros((m, len(rest), 3))
    basis = []
    for j, w in enumerate(wires):
        # only vertices that can be in range matter: a ball around the curve's bounding box
        reach = w.range.max()
        lo, hi = w.reference.control.min(0) - reach, w.reference.control.max(0) + reach
        inside = np.all((rest >= lo) & (rest <= hi), axis=1)
        factor = None
        if masks is not None and masks[j] is not None:
            factor = np.clip(np.asarray(masks[j], dtype=np.float64), 0.0, 1.0)
            inside &= factor > 0
        near = np.flatnonzero(inside)
        b = np.zeros((len(rest), w.reference.n_control))
        if len(near):
            u, pr = w.reference.closest(rest[near])
            x = np.linalg.norm(rest[near] - pr, axis=1) / w.range_at(u)
            f[near, j] = falloff(x) * (1.0 if factor is None else factor[near])
            radial[j, near] = rest[near] - pr
            b[near] = w.reference.basis(u)
        basis.append(b)
    fk = f ** k
    total = fk.sum(1, keepdims=True)
    weights = np.divide(fk * f, total, out=np.zeros_like(f), where=total > 0)
    weights[weights < WEIGHT_CUTOFF] = 0.0
    return WireInfluence(list(wires), float(k), rest, weights, radial, basis)


def extract_wires(bound: WireInfluence, template, rcond: float = 1e-10) -> tuple[list[np.ndarray], np.ndarray]:
    """Wire curves and radial scales that best turn the bound rest mesh into ``template``
    (Pyun, Shin & Shin, eqs. 9-13).

    Every vertex gives three equations (x, y, z) in the unknowns: the scale s_j of each wire and
    the offsets q_jl = w_jl - r_jl of its control points,

        sum_j w_ij (p_i - p_iRj) s_j + sum_j sum_l w_ij B_l(u_ij) q_jl = dp_i + sum_j w_ij (p_i - p_iRj)

    (the paper's c_i enters with a minus sign: (s_j - 1) expands to s_j - 1), solved in the
    least-squares sense with the SVD pseudo-inverse of eq. 13, ``(A^T A)^+ A^T b``. Returns the wire
    control points (one (t_j, 3) array per wire) and the scales (m,).
    """
    t = check_points(template, "template vertices")
    if t.shape != bound.rest.shape:
        raise DeformError(f"the template has {len(t)} vertices, the base mesh {len(bound.rest)}: "
                          "wire extraction needs the same topology (vertex count and order)")
    empty = [w.name for j, w in enumerate(bound.wires) if not (bound.weights[:, j] > 0).any()]
    if empty:
        raise DeformError(f"the system is under-determined: no vertex lies within range of wire(s) "
                          f"{', '.join(empty)}; widen their range or move them onto the face")
    moved = np.flatnonzero(bound.weights.sum(1) > 0)
    w = bound.weights[moved]  # (n, m)
    m = len(bound.wires)
    sizes = [wi.reference.n_control for wi in bound.wires]
    g = np.hstack([w[:, j:j + 1] * bound.basis[j][moved] for j in range(m)])  # (n, T): w_ij B_l(u_ij)
    radial = np.stack([w[:, j:j + 1] * bound.radial[j][moved] for j in range(m)], axis=1)  # (n, m, 3)
    n, big_t = g.shape
    # A (3n, m + 3T): rows x, y, z of each vertex; columns s_1..s_m, then q (control point, axis)
    a = np.zeros((n, 3, m + 3 * big_t))
    a[:, :, :m] = radial.transpose(0, 2, 1)
    for axis in range(3):
        a[:, axis, m + axis::3] = g
    a = a.reshape(3 * n, -1)
    rhs = ((t - bound.rest)[moved] + radial.sum(1)).reshape(-1)
    ata = a.T @ a
    sol = np.linalg.pinv(ata, rcond=rcond, hermitian=True) @ (a.T @ rhs)
    scales = sol[:m]
    q = sol[m:].reshape(big_t, 3)
    controls, start = [], 0
    for wi, size in zip(bound.wires, sizes):
        controls.append(wi.reference.control + q[start:start + size])
        start += size
    return controls, scales
