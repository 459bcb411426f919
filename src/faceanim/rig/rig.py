"""The Rig: named controls over one rest mesh, compiled to one bound linear deformer, plus rigid parts.

Every method in faceanim ends here. A control drives a blendshape, a (V, 3) displacement per unit
of the control (an expression of GDEs at ``d = 1``, an action unit at ``m = 1``, a FAP per FAPU
unit, a group of wires in a blend). Blendshapes compile into the same :class:`LinearDeformer` as
every deformation method, with three handles per control (its x, y and z parts), so

    linear pose (F, V, 3) = rest + W (V, 3C) @ offsets,  offsets[f, 3c + a, a] = curves[f, c],

which is ``rest + sum_c curves[:, c] B_c`` evaluated as one sparse or dense product per frame.

A few parts of a face do not move linearly: the jaw turns about a hinge, the eyeballs and the
head turn about their centres. Each is a :class:`RigidPart`, applied after the linear step in the
order given: its rotation (from its controls) and translation move its vertices, weighted per
vertex (1 = rigid; a fading band where the jaw meets the cheeks). This is the one small nonlinear
step of a rig; writers that need linear data (glTF morph targets) take its exact derivative at
the neutral pose (:meth:`Rig.linearised`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from faceanim.deform.base import LinearDeformer
from faceanim.errors import DeformError
from faceanim.face.mesh import Mesh

HINGE_NEWTON_STEPS = 8  # from drop / z, Newton converges to machine precision in 4-5 steps for |a| < 1
HINGE_MAX_ANGLE = np.pi / 3  # a jaw opens at most 60 degrees


def axis_rotation(axis: int, angle) -> np.ndarray:
    """Rotation matrices (..., 3, 3) by ``angle`` radians about the x (0), y (1) or z (2) axis."""
    a = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    one, zero = np.ones_like(a), np.zeros_like(a)
    if axis == 0:
        m = [[one, zero, zero], [zero, c, -s], [zero, s, c]]
    elif axis == 1:
        m = [[c, zero, s], [zero, one, zero], [-s, zero, c]]
    else:
        m = [[c, -s, zero], [s, c, zero], [zero, zero, one]]
    return np.moveaxis(np.array(m), (0, 1), (-2, -1))


@dataclass
class RigidPart:
    """A part of the mesh that turns (and shifts) as a whole.

    Attributes
    ----------
    name : str
    rows : (R,) int
        Vertices of the part.
    share : (R,) float
        Share of the part's motion each vertex follows (1 = rigid; the jaw fades into the cheeks).
    pivot : (3,)
        Centre of rotation in mesh coordinates.
    axes : (3, 3)
        Rows: the x, y, z axes of the part's frame in mesh coordinates (the face frame).
    rotations : sequence of (control, axis, radians per unit)
        Rotation about a frame axis per unit of a control, composed in the order given
        (e.g. yaw, then pitch, then roll).
    translations : sequence of (control, (3,) mesh units per unit)
        Shift per unit of a control.
    from_rest : bool
        True: the motion is computed on the rest positions and added to the linear pose (a jaw
        whose lips were already shaped by FAPs); False: the part's current positions are turned
        (eyeballs, the head, after everything else).
    hinge : (3,) or None
        For a hinge driven by a *drop* instead of an angle (MPEG-4 open_jaw lowers the chin by
        ``value`` mesh units): the point (in the part's frame, relative to the pivot) whose drop the
        control gives; the angle is solved so that point drops by exactly that much.
    """

    name: str
    rows: np.ndarray
    share: np.ndarray
    pivot: np.ndarray
    axes: np.ndarray
    rotations: Sequence[tuple[str, int, float]] = ()
    translations: Sequence[tuple[str, np.ndarray]] = ()
    from_rest: bool = False
    hinge: np.ndarray | None = None

    @property
    def rigid(self) -> bool:
        """Every vertex follows the part fully (share all 1)."""
        return bool(np.all(self.share == 1.0))

    @property
    def controls(self) -> list[str]:
        names = [c for c, _, _ in self.rotations] + [c for c, _ in self.translations]
        return list(dict.fromkeys(names))

    def hinge_angle(self, drop: np.ndarray) -> np.ndarray:
        """Angles that lower the hinge point (y, z from the pivot) by ``drop``:
        y (1 - cos a) + z sin a = drop, by Newton's method from drop / z."""
        y, z = float(self.hinge[1]), max(float(self.hinge[2]), 1e-12)
        a = np.asarray(drop, dtype=np.float64) / z
        for _ in range(HINGE_NEWTON_STEPS):
            f = y * (1 - np.cos(a)) + z * np.sin(a) - drop
            a = a - f / (y * np.sin(a) + z * np.cos(a))
        return np.clip(a, -HINGE_MAX_ANGLE, HINGE_MAX_ANGLE)

    def transforms(self, values: Mapping[str, np.ndarray], n: int) -> tuple[np.ndarray, np.ndarray]:
        """Per-frame rotations (n, 3, 3) in the part's frame and shifts (n, 3) in mesh units."""
        r = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
        for control, axis, per_unit in self.rotations:
            v = values[control] * per_unit
            angle = self.hinge_angle(v) if self.hinge is not None else v
            r = r @ axis_rotation(axis, angle)
        t = np.zeros((n, 3))
        for control, vec in self.translations:
            t += values[control][:, None] * np.asarray(vec)[None]
        return r, t

    def derivative(self, control: str, rest: np.ndarray) -> np.ndarray:
        """Exact d(vertex positions)/d(control) at the neutral pose, (R, 3) for the part's rows:
        omega x (v - pivot) for a rotation (omega = the axis times radians per unit, or per unit of
        drop through the hinge: d angle / d drop = 1 / z at 0), the shift vector for a translation."""
        out = np.zeros((len(self.rows), 3))
        rel = rest[self.rows] - self.pivot
        for c, axis, per_unit in self.rotations:
            if c != control:
                continue
            rate = per_unit / max(float(self.hinge[2]), 1e-12) if self.hinge is not None else per_unit
            out += np.cross(self.axes[axis] * rate, rel)
        for c, vec in self.translations:
            if c == control:
                out += np.asarray(vec)[None]
        return out * self.share[:, None]


@dataclass(eq=False)
class Rig:
    """Named controls over a rest mesh: one bound :class:`LinearDeformer` over blendshape columns
    plus rigid parts.

    Parameters
    ----------
    mesh : Mesh
        The rest face.
    controls : list of str
        Control names, one per column of the curves (F, C) this rig takes.
    deformer : LinearDeformer
        Three handles per control (x, y, z parts of its blendshape); see the module docstring.
    rigid_parts : list of RigidPart
        Applied after the linear step, in order.
    limits : (C,) or (2, C) array, optional
        Range of each control: |value| <= limit, or (lowest, highest) values; values outside are
        clamped (inf: none).
    """

    mesh: Mesh
    controls: list[str]
    deformer: LinearDeformer
    rigid_parts: list[RigidPart] = field(default_factory=list)
    limits: np.ndarray | None = None

    def __post_init__(self):
        self.controls = list(self.controls)
        if len(set(self.controls)) != len(self.controls):
            raise DeformError("rig control names must be unique")
        if self.deformer.n_handles != 3 * len(self.controls):
            raise DeformError(f"a rig's deformer needs 3 handles per control ({3 * len(self.controls)}), "
                              f"got {self.deformer.n_handles}")
        known = set(self.controls)
        for part in self.rigid_parts:
            if set(part.controls) - known:
                raise DeformError(f"rigid part '{part.name}' uses unknown controls {set(part.controls) - known}")
        lim = np.full(len(self.controls), np.inf) if self.limits is None else np.asarray(self.limits, dtype=np.float64)
        self.limits = np.stack([-lim, lim]) if lim.ndim == 1 else lim
        if self.limits.shape != (2, len(self.controls)) or (self.limits[0] > self.limits[1]).any():
            raise DeformError(f"control limits must be (C,) or (2, C) low <= high, got shape {self.limits.shape}")
        self._index = {n: k for k, n in enumerate(self.controls)}

    # ------------------------------------------------------------------ building
    @classmethod
    def from_blendshapes(cls, mesh: Mesh, blendshapes: Mapping[str, np.ndarray] | None = None, *,
                         controls: Sequence[str] | None = None, rigid_parts: Sequence[RigidPart] = (),
                         limits=None, sparse: bool | None = None) -> Rig:
        """A rig from named (V, 3) blendshapes (as a dict, or a (C, 3V) sparse matrix with
        ``controls`` naming its rows). Controls that only drive rigid parts get a zero column."""
        if blendshapes is None or (isinstance(blendshapes, Mapping) and not blendshapes):
            if not controls:
                raise DeformError("a rig needs at least one control")
            blendshapes = sp.csr_matrix((len(controls), 3 * mesh.n_vertices))
        if isinstance(blendshapes, Mapping):
            names = list(blendshapes)
            rows = []
            for n in names:
                b = np.asarray(blendshapes[n], dtype=np.float64)
                if b.shape != mesh.vertices.shape:
                    raise DeformError(f"blendshape '{n}' must have shape ({mesh.n_vertices}, 3), got {b.shape}")
                if not np.all(np.isfinite(b)):
                    raise DeformError(f"blendshape '{n}' has NaN or infinite values")
                rows.append(b.reshape(-1))
            matrix = np.vstack(rows)
            extra = [c for c in (controls or []) if c not in blendshapes]
            if extra:
                matrix = np.vstack([matrix, np.zeros((len(extra), matrix.shape[1]))])
            names += extra
        else:
            names = list(controls)
            matrix = blendshapes
            if matrix.shape != (len(names), 3 * mesh.n_vertices):
                raise DeformError(f"the blendshape matrix must be ({len(names)}, {3 * mesh.n_vertices})")
        # W (V, 3C): W[v, 3c + a] = B_c[v, a]
        c_count, v_count = len(names), mesh.n_vertices
        if sp.issparse(matrix):
            coo = sp.coo_matrix(matrix)
            w = sp.csr_matrix((coo.data, (coo.col // 3, 3 * coo.row + coo.col % 3)), shape=(v_count, 3 * c_count))
            moving = np.flatnonzero(np.diff(w.indptr))
            w = w[moving]
        else:
            w = matrix.reshape(c_count, v_count, 3).transpose(1, 0, 2).reshape(v_count, 3 * c_count)
            moving = np.flatnonzero(np.any(w != 0, axis=1))
            w = w[moving]
            # sparse only where the moving rows themselves are mostly zeros (the rows no control
            # moves are dropped either way; counting them made a 61%-full AU rig sparse and slow)
            if sparse is None:
                sparse = np.count_nonzero(w) < 0.25 * w.size
            w = sp.csr_matrix(w) if sparse else w
        handle_names = [f"{n}.{a}" for n in names for a in "xyz"]
        deformer = LinearDeformer(mesh.vertices, w, moving, handle_names)
        return cls(mesh, names, deformer, list(rigid_parts), limits)

    # ------------------------------------------------------------------ curves
    @property
    def names(self) -> list[str]:
        """The control names (alias of ``controls``)."""
        return self.controls

    @property
    def n_controls(self) -> int:
        return len(self.controls)

    def index(self, name: str) -> int:
        try:
            return self._index[name]
        except KeyError:
            raise DeformError(f"unknown control '{name}'; this rig has: {', '.join(self.controls[:20])}"
                              + (" ..." if len(self.controls) > 20 else "")) from None

    def curves_from(self, values: Mapping[str, float] | Sequence[float] | np.ndarray) -> np.ndarray:
        """Control values as an (F, C) matrix: from ``{'smile': 0.7}`` (one frame), a (C,) vector
        or an (F, C) matrix."""
        if isinstance(values, Mapping):
            c = np.zeros((1, self.n_controls))
            for k, v in values.items():
                c[0, self.index(k)] = float(v)
            return c
        c = np.asarray(values, dtype=np.float64)
        if c.ndim == 1:
            c = c[None]
        if c.ndim != 2 or c.shape[1] != self.n_controls:
            raise DeformError(f"control curves must have shape (frames, {self.n_controls}), got {c.shape}")
        if not np.all(np.isfinite(c)):
            raise DeformError("control curves contain NaN or infinite values")
        return c

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, curves) -> np.ndarray:
        """Vertices (F, V, 3) for control curves sampled to an (F, C) matrix (values past a
        control's limit are clamped)."""
        c = np.clip(self.curves_from(curves), self.limits[0], self.limits[1])
        out = self.deformer.apply_blendshapes(c)
        if self.rigid_parts:
            self._rigid_step(out, c)
        return out

    def pose(self, values) -> np.ndarray:
        """Vertices (V, 3) for one set of control values, e.g. ``{'smile': 0.7, 'A': 0.3}``."""
        return self.evaluate(self.curves_from(values))[0]

    def _rigid_step(self, out: np.ndarray, c: np.ndarray) -> None:
        rest = self.mesh.vertices
        for part in self.rigid_parts:
            cols = [self.index(n) for n in part.controls]
            active = np.flatnonzero(np.abs(c[:, cols]).sum(1) > 0)
            if not len(active):
                continue
            values = {n: c[active, self.index(n)] for n in part.controls}
            r_local, t = part.transforms(values, len(active))
            r = part.axes.T[None] @ r_local @ part.axes[None]  # in mesh coordinates
            whole = part.rows.size == rest.shape[0] and np.array_equal(part.rows, np.arange(rest.shape[0]))
            w = part.share[None, :, None]
            for lo in range(0, len(active), 16):  # a few frames at a time: bounded temporaries
                f = active[lo:lo + 16]
                at = (f,) if whole else (f[:, None], part.rows[None])
                p = rest[part.rows][None] if part.from_rest else out[at]
                moved = (p - part.pivot) @ np.swapaxes(r[lo:lo + 16], 1, 2) + (part.pivot + t[lo:lo + 16])[:, None]
                if part.from_rest:
                    out[at] += w * (moved - p)
                elif part.rigid:
                    out[at] = moved
                else:
                    out[at] = p + w * (moved - p)

    # ------------------------------------------------------------------ linear views
    def blendshape(self, name: str) -> np.ndarray:
        """The (V, 3) displacement per unit of a control's linear part."""
        return self._column(self.index(name))

    def _column(self, k: int) -> np.ndarray:
        # unit offsets along x, y, z at the control's three handles: W's three columns
        return self.deformer.weight_columns(3 * k, 3 * k + 3)

    def linearised(self, name: str) -> np.ndarray:
        """The exact derivative of the vertex positions by one control at the neutral pose (V, 3):
        its blendshape plus each rigid part's rotation or shift to first order."""
        d = self._column(self.index(name))
        for part in self.rigid_parts:
            if name in part.controls:
                d[part.rows] += part.derivative(name, self.mesh.vertices)
        return d

    def blendshape_dict(self) -> dict[str, np.ndarray]:
        """Every control's linearised displacement by name."""
        return {n: self.linearised(n) for n in self.controls}

    def morph_targets(self, curves, names: Sequence[str] | None = None) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """Morph targets and weights for glTF: one target per control the curves use (or each of
        ``names``), scaled to the control's peak |value| so its weights lie in [-1, 1]. Linear
        controls are exact; rigid parts are linearised at the neutral pose."""
        c = np.clip(self.curves_from(curves), self.limits[0], self.limits[1])
        use = [self.index(n) for n in names] if names is not None else list(np.flatnonzero(np.abs(c).max(0) > 0))
        shapes, scales = {}, []
        for k in use:
            peak = float(np.abs(c[:, k]).max()) or 1.0
            shapes[self.controls[k]] = self.linearised(self.controls[k]) * peak
            scales.append(peak)
        weights = c[:, use] / np.array(scales) if use else np.zeros((len(c), 0))
        return shapes, weights

    def subset(self, names: Sequence[str]) -> Rig:
        """A rig with only the named controls (no rigid parts unless all their controls are kept)."""
        keep = [self.index(n) for n in names]
        cols = np.concatenate([[3 * k, 3 * k + 1, 3 * k + 2] for k in keep]) if keep else np.zeros(0, int)
        w = self.deformer.weights[:, cols]
        d = LinearDeformer(self.deformer.rest, w, self.deformer.rows,
                           [self.deformer.handle_names[i] for i in cols] if self.deformer.handle_names else None)
        parts = [p for p in self.rigid_parts if set(p.controls) <= set(names)]
        return Rig(self.mesh, list(names), d, parts, self.limits[:, keep])
