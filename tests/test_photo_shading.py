"""faceanim.build.shading (identity from the photos' shading) and the gentle warp of
faceanim.build.photo.fit_head, against independent oracles: a known lighting on an analytic sphere,
a real ICT identity (not the generic head) rendered by the project's renderer under its own fixed
lights, and heads whose control points are placed by hand."""

from __future__ import annotations

import numpy as np
import pytest

from faceanim.build import photo as P
from faceanim.build import shading as S
from faceanim.face.frame import similarity
from faceanim.face.generic_head import generic_head

from conftest import rendered_identity

SEED = 1001  # an identity of the tuning set (ICT seeds 1000-1009), never of the held-out ones


def sphere_normals(n: int = 2000, seed: int = 0) -> np.ndarray:
    v = np.random.default_rng(seed).standard_normal((n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_sh_lighting_is_recovered_on_a_sphere():
    n = sphere_normals()
    light = np.array([[0.6, 0.1, -0.2, 0.3, 0.05, -0.04, 0.02, 0.07, -0.03],
                      [0.5, -0.2, 0.1, 0.25, 0.0, 0.03, -0.05, 0.02, 0.04]]).T  # (9, 2): two channels
    got = S.solve_lighting(n, S.sh9(n) @ light)
    np.testing.assert_allclose(got, light, atol=1e-10)
    # a Lambertian sphere under one distant light (clamped cosine) is what 9 coefficients are for:
    # they explain it to within 5 % of its range (rms 3.6 %; Ramamoorthi & Hanrahan 2001), one coefficient
    # (a constant) does not
    d = np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8])
    grey = 0.2 + 0.7 * np.clip(n @ d, 0, None)
    fit = S.sh9(n) @ S.solve_lighting(n, grey)
    assert np.sqrt(np.mean((fit - grey) ** 2)) < 0.05 * np.ptp(grey)
    assert np.sqrt(np.mean((grey - grey.mean()) ** 2)) > 0.2 * np.ptp(grey)
    # the lighting's direction is where the fitted shading is brightest
    assert n[np.argmax(fit)] @ d > 0.95


def test_huber_keeps_small_residuals_and_tames_large_ones():
    r = np.array([-0.5, 0.0, 1.0, 5.0, -50.0])
    h = S.huber(r)
    np.testing.assert_allclose(h[:3], r[:3])
    np.testing.assert_allclose(h[3:] ** 2 / 2, S.HUBER * np.abs(r[3:]) - S.HUBER ** 2 / 2)
    assert np.all(np.sign(h) == np.sign(r))


@pytest.fixture(scope="module")
def person():
    """(head, true vertices, front + profile views, reconstruction) of one ICT identity, rendered
    by the project's renderer (its lights are fixed in the mesh's frame)."""
    head, truth, views = rendered_identity(SEED)
    rec = P.reconstruct(views, *P.prior_points(head))
    return head, truth, views, rec


def error(head, vertices, truth) -> float:
    """Mean distance (IOD) of the face's skin vertices from the truth's after a similarity."""
    from scipy.spatial import cKDTree

    lm = head.landmarks()
    iod = np.linalg.norm(lm[33] - lm[263])
    skin = head.parts["skin"]
    idx = skin[cKDTree(lm[:468]).query(head.mesh.vertices[skin])[0] < 0.1 * iod]
    s, r, t = similarity(vertices[idx], truth[idx])
    t_lm = head.landmarks(truth)
    return float(np.linalg.norm(s * vertices[idx] @ r.T + t - truth[idx], axis=1).mean()
                 / np.linalg.norm(t_lm[33] - t_lm[263]))


def test_the_shading_fit_lands_closer_to_the_true_head_than_the_landmarks(person):
    head, truth, views, rec = person
    w0 = P.fit_identity(head, views, rec)
    got = S.fit_identity_shading(head, views, rec, w0, rounds=1)
    before, after = error(head, head.identity(w0), truth), error(head, head.identity(got.weights), truth)
    assert after < 0.85 * before, (before, after)
    # only the leading modes move; the cameras still see the head where the photos show it
    np.testing.assert_array_equal(got.weights[S.MODES:], w0[S.MODES:])
    pts = head.landmarks(head.identity(got.weights))
    for v, cam in zip(views, got.cameras):
        rows = np.array([i for i in sorted(v.points) if i < 468])
        d = np.linalg.norm(cam.project(pts[rows]) - np.stack([v.points[i] for i in rows]), axis=1)
        assert np.median(d) < 0.05 * cam.scale * rec.iod


def test_the_shading_residual_is_smallest_at_the_true_head(person):
    """The term itself, without the fit: the true head through its true cameras explains the
    renders' shading better than the generic head does (each with its own best lighting)."""
    from faceanim.build.texture import view_camera
    from faceanim.face.mesh import Mesh
    from faceanim.render import OffscreenRenderer

    head, truth, views, _ = person
    skin_faces = head.mesh.faces[np.isin(head.mesh.faces, head.parts["skin"]).all(axis=1)]
    sh = S.Shading(head, [v.image for v in views])
    for k, yaw in enumerate((0.0, 90.0)):
        with OffscreenRenderer(Mesh(truth, skin_faces), size=(512, 512), yaw=yaw, parallel=True) as r:
            cam = view_camera(r)
        res = {}
        for name, verts in (("truth", truth), ("generic", head.mesh.vertices)):
            # each head placed on the truth by a similarity on the landmarks, seen by the true camera
            s, rot, t = similarity(head.landmarks(verts)[:468], head.landmarks(truth)[:468])
            placed = s * verts @ rot.T + t
            vis = sh.visible(k, cam, placed)
            assert vis.sum() > 200
            res[name] = float(np.median(np.abs(sh.residual(k, cam, placed[sh.sub], vis))))
        assert res["truth"] < 0.5 * res["generic"], res
        assert res["truth"] < 0.02, res  # grey levels 0..1 (8-bit renders): the renderer's shading is nearly SH


def on_points(head, w, noise: float = 0.0, seed: int = 0):
    """A reconstruction whose 3D points are the morphable head's own (``w``), each moved by up to
    ``noise`` IOD."""
    _, at_points = P.identity_model(head)
    p0, _ = P.prior_points(head)
    pts = p0 + np.tensordot(w, at_points, axes=1)
    iod = float(np.linalg.norm(pts[33] - pts[263]))
    d = np.random.default_rng(seed).standard_normal(pts.shape)
    d *= noise * iod / np.linalg.norm(d, axis=1, keepdims=True)
    return P.Reconstruction(pts + d, [], [], [], iod), iod


def test_the_gentle_warp_leaves_a_head_on_its_points_and_moves_one_off_them():
    head = generic_head()
    w = np.random.default_rng(SEED).standard_normal(head.n_identity)
    skin = head.parts["skin"]  # (the eyeballs and teeth are the generic head's, rigid, by design)
    g = head.identity(w)[skin]
    # every point within the deadband (0.015 IOD of noise against 0.02): the head is not bent
    rec, iod = on_points(head, w, noise=0.015)
    gentle = P.fit_head(head, rec, keep_expression=True, identity=w, deadband=0.02).vertices[skin]
    full = P.fit_head(head, rec, keep_expression=True, identity=w).vertices[skin]
    s, r, t = similarity(g, gentle)
    moved_gentle = np.linalg.norm(s * g @ r.T + t - gentle, axis=1) / iod
    moved_full = np.linalg.norm(s * g @ r.T + t - full, axis=1) / iod
    assert moved_gentle.max() < 0.003, moved_gentle.max()
    assert moved_full.max() > 0.01, moved_full.max()
    # one control point (the nose tip) 0.1 IOD forward: the head moves there by the excess only
    rec, iod = on_points(head, w)
    rec.points[4, 2] += 0.1 * iod
    gentle = P.fit_head(head, rec, keep_expression=True, identity=w, deadband=0.02).vertices
    full = P.fit_head(head, rec, keep_expression=True, identity=w).vertices
    tip = head.landmarks(gentle)[4] - head.landmarks(head.identity(w))[4]
    tip_full = head.landmarks(full)[4] - head.landmarks(head.identity(w))[4]
    assert tip_full[2] / iod > 0.06, tip_full / iod
    assert 0.75 < tip[2] / tip_full[2] < 0.85, (tip / iod, tip_full / iod)  # 0.08 of the 0.1
    # far from it (the chin, the ears) nothing moves
    far = np.linalg.norm(g - head.landmarks(head.identity(w))[4], axis=1) > 1.5 * iod
    assert np.abs(gentle[skin][far] - g[far]).max() / iod < 0.005
    # infinitely wide, with a similarity: the head only placed, its shape untouched
    none = P.fit_head(head, rec, keep_expression=True, identity=w, deadband=np.inf, affine=False).vertices[skin]
    s, r, t = similarity(g, none)
    assert np.linalg.norm(s * g @ r.T + t - none, axis=1).max() < 1e-6 * iod


def test_gentle_residual_is_a_soft_threshold():
    r = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.03, 0.04]])
    np.testing.assert_allclose(P.gentle_residual(r, 0.02), [[0, 0, 0], [0, 0, 0], [0, 0.018, 0.024]], atol=1e-12)
    np.testing.assert_array_equal(P.gentle_residual(r, 0.0), r)
    np.testing.assert_array_equal(P.gentle_residual(r, np.inf), 0 * r)
