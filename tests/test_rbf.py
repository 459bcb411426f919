"""RBF deformation: interpolation, affine reproduction, eq. 3 and eq. 5, scipy agreement, errors."""

import numpy as np
import pytest
from scipy.interpolate import RBFInterpolator

from faceanim.deform import RadialBasis, bind_rbf
from faceanim.errors import DeformError


def scattered(rng, n=40):
    return rng.normal(size=(n, 3))


@pytest.mark.parametrize("kernel", ["multiquadric", "gaussian", "thin_plate_spline"])
def test_interpolates_at_handles_without_smoothing(rng, kernel):
    c = scattered(rng)
    d = rng.normal(size=c.shape)
    deformer = bind_rbf(c, c, kernel=kernel, smoothing=0.0)
    np.testing.assert_allclose(deformer.apply(d), c + d, atol=1e-9)


def test_thin_plate_spline_reproduces_affine_maps(rng):
    c = scattered(rng, 25)
    A = np.array([[1.1, 0.2, -0.1], [0.05, 0.9, 0.3], [-0.2, 0.1, 1.2]])
    t = np.array([0.3, -0.5, 2.0])
    offsets = c @ A.T + t - c
    pts = rng.uniform(-3, 3, size=(500, 3))
    moved = bind_rbf(pts, c, kernel="thin_plate_spline", smoothing=0.0).apply(offsets)
    np.testing.assert_allclose(moved, pts @ A.T + t, atol=1e-9)
    # with smoothing too: an affine field has zero bending energy, so nothing is smoothed away
    moved = bind_rbf(pts, c, kernel="thin_plate_spline", smoothing=0.5).apply(offsets)
    np.testing.assert_allclose(moved, pts @ A.T + t, atol=1e-8)


def test_thin_plate_spline_matches_scipy_to_1e9(rng):
    c = scattered(rng, 60)
    d = rng.normal(size=c.shape)
    pts = rng.uniform(-2, 2, size=(2000, 3))
    ours = bind_rbf(pts, c, kernel="thin_plate_spline", smoothing=0.0).displacements(d)
    ref = RBFInterpolator(c, d, kernel="thin_plate_spline", smoothing=0.0, degree=1)(pts)
    assert np.abs(ours - ref).max() <= 1e-9 * np.abs(ref).max()


@pytest.mark.parametrize("kernel,degree", [("multiquadric", -1), ("multiquadric", 1), ("gaussian", -1),
                                           ("gaussian", 0)])
def test_uniform_stiffness_matches_scipy_epsilon(rng, kernel, degree):
    c = scattered(rng, 30)
    d = rng.normal(size=c.shape)
    pts = rng.uniform(-2, 2, size=(400, 3))
    s = 0.8
    ours = RadialBasis(c, kernel, smoothing=0.0, stiffness=s, degree=degree)(pts, d)
    ref = RBFInterpolator(c, d, kernel=kernel, epsilon=1.0 / s, degree=degree)(pts)
    np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-9 * np.abs(ref).max())


def test_per_centre_stiffness_is_distance_to_nearest_other_handle(rng):
    c = scattered(rng, 15)
    rb = RadialBasis(c, "multiquadric")
    dist = np.linalg.norm(c[:, None] - c[None], axis=-1)
    np.fill_diagonal(dist, np.inf)
    np.testing.assert_allclose(rb.stiffness, dist.min(1), rtol=1e-12)


def test_multiquadric_system_is_eq2_with_tikhonov_eq5(rng):
    """Independent oracle: build H from eq. 2/3 directly and solve (H + lambda I) c = y."""
    c = scattered(rng, 12) * 3.0
    y = rng.normal(size=c.shape)
    lam = 0.05
    pts = rng.normal(size=(50, 3))
    rb = RadialBasis(c, "multiquadric", smoothing=lam)
    # the library solves in coordinates scaled by the handles' bounding-box diagonal L
    L = np.linalg.norm(c.max(0) - c.min(0))
    x = c / L
    r = np.linalg.norm(x[:, None] - x[None], axis=-1)
    s = np.where(np.eye(len(x), dtype=bool), np.inf, r).min(0)
    H = -np.sqrt(r ** 2 + s[None, :] ** 2)  # negated multiquadric, see the module docstring
    coef = np.linalg.solve(H + lam * np.eye(len(x)), y)
    rp = np.linalg.norm(pts[:, None] / L - x[None], axis=-1)
    expected = -np.sqrt(rp ** 2 + s[None, :] ** 2) @ coef
    np.testing.assert_allclose(rb(pts, y), expected, atol=1e-10)


@pytest.mark.parametrize("kernel", ["multiquadric", "gaussian", "thin_plate_spline"])
def test_smoothing_trades_exactness_for_stability(rng, kernel):
    c = scattered(rng, 30)
    clean = np.sin(c) * 0.3
    noisy = clean + rng.normal(scale=0.05, size=c.shape)
    residual, roughness = [], []
    for lam in [0.0, 0.01, 0.1, 1.0]:
        rb = RadialBasis(c, kernel, smoothing=lam)
        residual.append(np.abs(rb(c, noisy) - noisy).max())
        roughness.append(np.abs(rb.coefficients(noisy)[:30]).sum())
    assert residual[0] < 1e-8
    assert all(a < b for a, b in zip(residual, residual[1:]))  # less exact as lambda grows
    assert all(a > b for a, b in zip(roughness, roughness[1:]))  # smaller coefficients: smoother


def test_float32_path_agrees(rng):
    c = scattered(rng, 60)
    pts = rng.uniform(-2, 2, size=(5000, 3))
    d = rng.normal(size=c.shape) * 0.1
    deformer = bind_rbf(pts, c, kernel="thin_plate_spline", smoothing=0.0)
    fast = deformer.astype(np.float32)
    ref = deformer.apply(d)
    assert fast.apply(d).dtype == np.float32
    assert np.abs(fast.apply(d) - ref).max() < 1e-5 * np.abs(ref).max()


def test_batch_of_frames_equals_frame_by_frame(rng):
    c = scattered(rng, 20)
    pts = rng.normal(size=(300, 3))
    deformer = bind_rbf(pts, c, kernel="gaussian", smoothing=0.01)
    frames = rng.normal(size=(70, 20, 3))
    batch = deformer.apply(frames)
    for f in [0, 33, 69]:
        np.testing.assert_allclose(batch[f], deformer.apply(frames[f]), atol=1e-12)


def test_rows_restrict_motion_bit_identically(rng):
    c = scattered(rng, 10)
    pts = rng.normal(size=(200, 3))
    rows = np.arange(0, 200, 3)
    deformer = bind_rbf(pts, c, rows=rows)
    out = deformer.apply(rng.normal(size=(10, 3)))
    others = np.setdiff1d(np.arange(200), rows)
    assert np.array_equal(out[others], pts[others])
    assert not np.allclose(out[rows], pts[rows])


def test_coincident_handles_are_named(rng):
    c = scattered(rng, 8)
    c[5] = c[2]
    with pytest.raises(DeformError, match="handles 2 and 5 coincide"):
        RadialBasis(c)


def test_bad_handles(rng):
    with pytest.raises(DeformError, match="NaN"):
        RadialBasis(np.array([[0, 0, 0], [1, 0, 0], [np.nan, 0, 0]]))
    with pytest.raises(DeformError, match="unknown kernel 'cubic'"):
        RadialBasis(scattered(rng), "cubic")
    with pytest.raises(DeformError, match="at least 4 handles"):
        RadialBasis(scattered(rng, 3), "thin_plate_spline")
    with pytest.raises(DeformError, match="one plane"):
        flat = scattered(rng, 10)
        flat[:, 2] = 0
        RadialBasis(flat, "thin_plate_spline")
    with pytest.raises(DeformError, match="smoothing"):
        RadialBasis(scattered(rng), smoothing=-1)
