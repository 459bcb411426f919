"""Radial basis function deformation (Noh, Fidaleo & Neumann 2000, section 2.4).

A handle set ``x_i`` (the paper's feature points) with offsets ``d_i`` defines the displacement
field

    F(x) = sum_i c_i h(||x - x_i||, s_i)  [+ p(x), a polynomial of degree <= 1]      (eq. 1)

whose coefficients solve ``(H + lambda I) c = d`` (eq. 5, Tikhonov smoothing; lambda = 0 gives
the exact interpolation of eq. 4). The matrix is LU-factored once when the system is bound;
afterwards the map from handle offsets to the displacement of any point is one matrix ``W``,
so evaluating a frame is a product (``LinearDeformer``).

Kernels (``r`` distance, ``s`` stiffness of the centre):

- ``multiquadric``: Hardy's ``h = sqrt(r^2 + s^2)`` (eq. 2), no polynomial by default. It enters
  the system negated (as in scipy), which leaves the exact interpolant unchanged but makes
  ``H + lambda I`` a true Tikhonov damping: with ``+h`` the matrix has N - 1 negative eigenvalues
  and adding ``lambda I`` pushes them towards zero, which can make eq. 5 singular;
- ``gaussian``: ``h = exp(-(r / s)^2)``, no polynomial by default;
- ``thin_plate_spline``: ``h = r^2 log r`` with its affine part (degree 1), scale free.

The stiffness defaults to the paper's eq. 3, ``s_i = min_{j != i} ||x_j - x_i||``: soft where
handles are scattered, stiff where they crowd. A number gives every centre the same stiffness
(in mesh units), which makes the kernels coincide with ``scipy.interpolate.RBFInterpolator``'s
``multiquadric`` / ``gaussian`` with ``epsilon = 1 / s``.

Coordinates are measured in units of the handles' bounding-box diagonal before the solve, so
``smoothing`` means the same on a face modelled in millimetres or in metres.
"""

from __future__ import annotations

import contextlib
import math
import numbers
import warnings

import numpy as np
import scipy.linalg as la
from scipy.spatial import cKDTree

from faceanim.deform.base import SMALL_SYSTEM, LinearDeformer, one_blas_thread
from faceanim.errors import DeformError, LandmarkError

KERNELS = ("multiquadric", "gaussian", "thin_plate_spline")
DEFAULT_DEGREE = {"multiquadric": -1, "gaussian": -1, "thin_plate_spline": 1}
MIN_DEGREE = {"multiquadric": -1, "gaussian": -1, "thin_plate_spline": 1}
DEFAULT_SMOOTHING = 0.01  # the paper's lambda, "determined experimentally"

_EVAL_CHUNK = 65536  # points per block when evaluating the basis on many points
MAX_WEIGHTS = 10**8  # entries of a dense weight matrix (points x handles, 800 MB in float64)


def _is_number(x) -> bool:
    return isinstance(x, (numbers.Real, np.number)) and not isinstance(x, (bool, np.bool_))


def _describe(value) -> str:
    """What a wrong value is, for an error message (a type, not the value: it may be huge)."""
    if isinstance(value, str):
        return "text"
    if value is None:
        return "null"
    if isinstance(value, (bool, np.bool_)):
        return "true/false"
    if isinstance(value, dict):
        return "an object"
    if isinstance(value, (list, tuple)):
        return "a list"
    if _is_number(value):
        return "a number"
    return type(value).__name__


def check_number(value, name: str, low: float = -math.inf, high: float = math.inf, *, integer: bool = False,
                 low_inclusive: bool = True) -> float:
    """``value`` as a float (int with ``integer``) if it is a real finite number in range; else a
    DeformError naming ``name``. Text, true/false, null and lists are refused, not converted."""
    if not _is_number(value):
        raise DeformError(f"{name} must be a number, got {_describe(value)}")
    try:
        v = float(value)
    except (OverflowError, ValueError):
        raise DeformError(f"{name} is too large") from None
    if not math.isfinite(v):
        raise DeformError(f"{name} must be a finite number, got {v}")
    if (v < low if low_inclusive else v <= low) or v > high:
        lo = f"at least {low:g}" if low_inclusive else f"more than {low:g}"
        hi = f" and at most {high:g}" if math.isfinite(high) else ""
        raise DeformError(f"{name} must be {lo}{hi}, got {v:g}")
    if integer:
        if v != int(v):
            raise DeformError(f"{name} must be a whole number, got {v:g}")
        return int(v)
    return v


def _check_leaves(points, name: str) -> None:
    """Refuse nested lists that hold anything but numbers (text, null, true/false, objects) or
    that nest deeper than a list of points."""
    stack = [(points, 0)]
    while stack:
        x, depth = stack.pop()
        if isinstance(x, (list, tuple)):
            if depth >= 2:
                raise DeformError(f"{name} must be a list of [x, y, z] points; it is nested too deeply")
            stack.extend((y, depth + 1) for y in x)
        elif isinstance(x, np.ndarray):
            if x.dtype.kind not in "iuf":
                raise DeformError(f"{name} must hold numbers only")
        elif not _is_number(x):
            raise DeformError(f"{name} must hold numbers only, got {_describe(x)}")


def check_points(points, name: str, min_count: int = 1) -> np.ndarray:
    """Validate an (N, 3) array of finite points, naming ``name`` in the error."""
    if isinstance(points, np.ndarray):
        if points.dtype.kind not in "iuf":
            if points.dtype.kind == "O":
                _check_leaves(points.tolist(), name)
            else:
                raise DeformError(f"{name} must be an array of 3-D points (numbers)")
    else:
        _check_leaves(points, name)
    try:
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise DeformError(f"{name} must be an array of 3-D points: lists of 3 numbers each") from None
    if p.ndim == 1 and p.size == 3:
        p = p[None]
    if p.ndim != 2 or p.shape[1] != 3:
        raise DeformError(f"{name} must have shape (N, 3), got {p.shape}")
    if p.shape[0] < min_count:
        raise DeformError(f"{name} needs at least {min_count} point(s), got {p.shape[0]}")
    bad = ~np.all(np.isfinite(p), axis=1)
    if bad.any():
        idx = np.flatnonzero(bad)
        raise DeformError(
            f"{name} contain NaN or infinite coordinates at index {', '.join(map(str, idx[:5]))}"
            + (" ..." if idx.size > 5 else "")
        )
    return p


def _kernel(kernel: str, r: np.ndarray, s: np.ndarray | None) -> np.ndarray:
    if kernel == "multiquadric":
        # negated, as in scipy: -sqrt(r^2 + s^2) is conditionally positive definite, so the
        # Tikhonov term of eq. 5 damps the system; the exact interpolant (lambda = 0) is the same
        return -np.sqrt(r * r + s * s)
    if kernel == "gaussian":
        return np.exp(-((r / s) ** 2))
    if kernel == "thin_plate_spline":
        with np.errstate(divide="ignore", invalid="ignore"):
            out = r * r * np.log(r)
        out[r == 0] = 0.0
        return out
    raise DeformError(f"unknown kernel '{kernel}'; choose one of: {', '.join(KERNELS)}")


def _polynomial(x: np.ndarray, degree: int) -> np.ndarray:
    if degree < 0:
        return np.empty((x.shape[0], 0))
    if degree == 0:
        return np.ones((x.shape[0], 1))
    return np.hstack([np.ones((x.shape[0], 1)), x])


class RadialBasis:
    """An RBF system on fixed centres, factored once (the paper's per-GDE RBF system).

    Parameters
    ----------
    centres : (N, 3) array
        Rest positions of the handles (feature points ``x_i``).
    kernel : {'multiquadric', 'gaussian', 'thin_plate_spline'}
    smoothing : float
        Tikhonov ``lambda`` of eq. 5 (0 interpolates exactly).
    stiffness : None or float
        ``None``: per-centre ``s_i`` of eq. 3. A float: the same ``s`` (mesh units) for all.
    degree : int, optional
        Degree of the added polynomial: -1 none, 0 constant, 1 affine. Defaults to the
        kernel's usual choice (none for multiquadric and gaussian, 1 for the thin-plate spline).
    """

    def __init__(self, centres, kernel: str = "multiquadric", smoothing: float = DEFAULT_SMOOTHING,
                 stiffness: float | None = None, degree: int | None = None):
        if not isinstance(kernel, str):
            raise DeformError(f"kernel must be a name ({', '.join(KERNELS)}), got {_describe(kernel)}")
        if kernel not in KERNELS:
            shown = kernel if len(kernel) <= 40 and kernel.isprintable() else kernel[:40].encode("unicode_escape").decode()
            raise DeformError(f"unknown kernel '{shown}'; choose one of: {', '.join(KERNELS)}")
        c = check_points(centres, "handles")
        if degree is None:
            degree = DEFAULT_DEGREE[kernel]
        if not _is_number(degree) or degree not in (-1, 0, 1):
            raise DeformError(f"polynomial degree must be -1, 0 or 1, got "
                              f"{degree if _is_number(degree) else _describe(degree)}")
        degree = int(degree)
        if degree < MIN_DEGREE[kernel]:
            raise DeformError(f"the {kernel} kernel needs a polynomial of degree >= {MIN_DEGREE[kernel]}")
        try:
            smoothing = check_number(smoothing, "smoothing", 0.0)
        except DeformError as exc:
            raise DeformError(f"{exc} (smoothing must be a finite number >= 0)") from None
        n = c.shape[0]
        m = _polynomial(c[:1], degree).shape[1]
        if n < max(m, 1):
            raise DeformError(
                f"the {kernel} kernel with a degree-{degree} polynomial needs at least {m} handles, got {n}"
            )
        self.kernel = kernel
        self.smoothing = smoothing
        self.degree = degree
        self.centres = c

        # coincident handles make the system singular: name them
        if n > 1:
            with np.errstate(over="ignore", invalid="ignore"):
                span = float(np.linalg.norm(c.max(axis=0) - c.min(axis=0)))
            if not math.isfinite(span):
                raise DeformError("the handles are too far apart to solve (coordinates near the float limit); "
                                  "check their units")
            tree = cKDTree(c)
            pairs = sorted(tree.query_pairs(max(span, 1.0) * 1e-9))
            if pairs:
                i, j = pairs[0]
                more = f" (and {len(pairs) - 1} more pair(s))" if len(pairs) > 1 else ""
                raise DeformError(
                    f"handles {i} and {j} coincide at {np.round(c[i], 9).tolist()}{more}; "
                    "remove the duplicate or move it apart"
                )
        else:
            span = 0.0
        self.centre = c.mean(axis=0)
        self.scale = span if span > 0 else 1.0
        x = (c - self.centre) / self.scale

        if stiffness is None:
            if n > 1:
                dist, _ = cKDTree(x).query(x, k=2)
                s = dist[:, 1]
            else:
                s = np.ones(1)
        else:
            try:
                stiffness = check_number(stiffness, "stiffness", 0.0, low_inclusive=False)
            except DeformError as exc:
                raise DeformError(f"{exc} (stiffness must be a positive number)") from None
            s = np.full(n, stiffness / self.scale)
        self.stiffness = s * self.scale  # in mesh units, for reporting
        self._s = s
        self._x = x

        P = _polynomial(x, degree)
        if m and np.linalg.matrix_rank(P) < m:
            raise DeformError(
                f"the handles are degenerate for a degree-{degree} polynomial "
                "(a thin-plate spline needs at least 4 handles not all in one plane)"
            )
        K = self._basis_block(x)
        A = np.zeros((n + m, n + m))
        A[:n, :n] = K + smoothing * np.eye(n)
        A[:n, n:] = P
        A[n:, :n] = P.T
        # small dense solves run 4-30x slower with two OpenBLAS threads on a busy 2-core machine
        # (a GDE's 21-unknown system: 7.9 ms vs 1.8 ms; benchmarks/bench_deform.py): one thread
        # below SMALL_SYSTEM unknowns, the machine's threads above
        limit = one_blas_thread() if n + m <= SMALL_SYSTEM else contextlib.nullcontext()
        with warnings.catch_warnings(), limit:
            warnings.simplefilter("error", la.LinAlgWarning)
            try:
                self._lu = la.lu_factor(A, check_finite=False)
                # rows of the inverse that map centre values to coefficients (eq. 4/5)
                rhs = np.zeros((n + m, n))
                rhs[:n] = np.eye(n)
                self._inverse = la.lu_solve(self._lu, rhs, check_finite=False)
            except (la.LinAlgWarning, la.LinAlgError, ValueError):
                raise DeformError(
                    "the RBF system is singular for these handles; use smoothing > 0 or spread the handles"
                ) from None
        if not np.all(np.isfinite(self._inverse)):
            raise DeformError("the RBF system is singular for these handles; use smoothing > 0")
        self._n, self._m = n, m

    @property
    def n_centres(self) -> int:
        return self._n

    def _basis_block(self, x: np.ndarray) -> np.ndarray:
        r = np.sqrt(np.maximum(
            (x * x).sum(1)[:, None] + (self._x * self._x).sum(1)[None, :] - 2.0 * x @ self._x.T, 0.0))
        return _kernel(self.kernel, r, self._s[None, :])

    def basis(self, points) -> np.ndarray:
        """Evaluation matrix ``[h(||p - x_i||, s_i), p(x)]`` of shape (M, N + m)."""
        p = (np.asarray(points, dtype=np.float64) - self.centre) / self.scale
        return np.hstack([self._basis_block(p), _polynomial(p, self.degree)])

    def coefficients(self, values) -> np.ndarray:
        """Solve eq. 5 for the coefficients given values at the centres (back-substitution)."""
        v = np.asarray(values, dtype=np.float64)
        rhs = np.zeros((self._n + self._m,) + v.shape[1:])
        rhs[: self._n] = v
        limit = one_blas_thread() if len(rhs) <= SMALL_SYSTEM else contextlib.nullcontext()
        with limit:
            return la.lu_solve(self._lu, rhs, check_finite=False)

    def weights(self, points, column: int | None = None) -> np.ndarray:
        """(M, N) matrix mapping values at the centres to values at ``points``.

        With ``column``, only that centre's weights, shape (M,).
        """
        p = np.asarray(points, dtype=np.float64)
        if column is not None:
            # einsum, not BLAS: OpenBLAS's threaded gemv was seen to cost ~4 ms per call here
            # for a few hundred rows, far more than the arithmetic
            col = np.ascontiguousarray(self._inverse[:, column])
            return np.concatenate([np.einsum("ij,j->i", self.basis(p[a:a + _EVAL_CHUNK]), col)
                                   for a in range(0, max(p.shape[0], 1), _EVAL_CHUNK)])[: p.shape[0]]
        out = np.empty((p.shape[0], self._n))
        for a in range(0, p.shape[0], _EVAL_CHUNK):
            out[a:a + _EVAL_CHUNK] = self.basis(p[a:a + _EVAL_CHUNK]) @ self._inverse
        return out

    def __call__(self, points, values) -> np.ndarray:
        """Evaluate the interpolant of ``values`` (N, k) at ``points`` (M, 3)."""
        return self.basis(points) @ self.coefficients(values)


def bind_rbf(rest, handles, kernel: str = "multiquadric", smoothing: float = DEFAULT_SMOOTHING,
             stiffness: float | None = None, degree: int | None = None, rows=None,
             dtype=np.float64) -> LinearDeformer:
    """Bind a global RBF deformer: handles at ``handles`` move the vertices ``rest``.

    ``rows`` restricts the deformation to those vertex indices (others stay bit-identical).
    Returns a :class:`LinearDeformer` whose ``apply(offsets)`` gives the deformed mesh.
    """
    rest = check_points(rest, "mesh vertices")
    system = RadialBasis(handles, kernel, smoothing, stiffness, degree)
    pts = rest if rows is None else rest[np.asarray(rows)]
    if pts.shape[0] * system.n_centres > MAX_WEIGHTS:
        raise DeformError(f"{system.n_centres} handles on {pts.shape[0]} vertices need a weight matrix of more "
                          f"than {MAX_WEIGHTS:.0e} entries; use fewer handles or GDEs (local regions)")
    with np.errstate(over="ignore", invalid="ignore"):
        w = system.weights(pts)
    if not np.all(np.isfinite(w)):
        raise DeformError("the RBF solve gave non-finite weights for these handles (coordinates too large or "
                          "the system is near singular); check the handles' units or use smoothing > 0")
    return LinearDeformer(rest.astype(dtype), w.astype(dtype), rows)


def landmark_tps(source, target, what: str = "landmarks", merge_repeated: bool = False, smoothing: float = 0.0):
    """The thesis' 3D thin-plate spline through landmark pairs (eqs. 4.11-4.19).

    ``smoothing`` > 0 trades exactness for smoothness (the Tikhonov term of :class:`RadialBasis`,
    in its normalised units): detected landmarks carry noise, which an exact spline turns into
    local folds.

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
        system = RadialBasis(src, "thin_plate_spline", smoothing=float(smoothing))
    except DeformError as exc:
        raise LandmarkError(f"{what}: {exc}") from None
    coeff = system.coefficients(dst - src)

    def warp(points):
        p = np.asarray(points, dtype=np.float64)
        return p + system.basis(p) @ coeff

    return warp
