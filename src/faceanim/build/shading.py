"""Identity from the shading of the photos (analysis by synthesis), for :func:`faceanim.build.photo.head_from_photos`.

Front landmarks say little about a face's shape (a detected landmark on a render sits 0.015 IOD
from the head's own even for the true identity); its shading says more. Each view's colour at the
pixels where the candidate head's face vertices project is explained by a second-order
spherical-harmonic lighting of the head's normals (:func:`sh9`: 9 coefficients per view and colour
channel, solved by linear least squares for every candidate, :func:`solve_lighting`: the lighting
is estimated, never assumed) times one albedo, absorbed in the coefficients. Eyes, brows and lips
are left out (:func:`shading_vertices`, by the generic head's landmarks); hidden vertices are left
out by the head's depth map in each photo (the texture baker's own GL depth pass and visibility
test, :func:`faceanim.build.texture._visible`); so are clipped pixels; residuals are divided by
their robust scale at the start and weighted by Huber's loss (a real photo's albedo varies).

:func:`fit_identity_shading` refines :func:`~faceanim.build.photo.fit_identity`'s weights: the
leading ``modes`` identity weights and each view's camera (rotation, scale, offset: cameras fitted
to detected landmarks are 1-2 px off, which doubles the residual at the true shape) minimise this
term together with fit_identity's landmark, profile-silhouette and front-outline terms and its
prior (``scipy.optimize.least_squares``, finite differences, three rounds with visibility and
correspondences found again). Measured (docs/photos.md, own/other surface error of the morphable
head, tuning ICT seeds 1000-1009): 0.62 without, 0.48 at weight 30, 0.42 at weight 100.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from faceanim.build.camera import ViewCamera

BROWS = (70, 63, 105, 66, 107, 55, 65, 52, 53, 46, 300, 293, 334, 296, 336, 285, 295, 282, 283, 276)
EYE_REACH, BROW_REACH, LIP_REACH = 0.12, 0.08, 0.08  # IOD around those landmarks left out
FACE_REACH = 0.1  # skin within this of the 468 landmarks is the face
FACING = 0.25  # a vertex is used in a view where its normal's cosine to the camera is above this
BLUR = 0.7  # pixels of Gaussian blur of each photo's colours
HUBER = 1.345
SATURATED = 250  # a channel this bright is clipped: its pixels are left out
DEPTH_TOLERANCE = 0.003  # of the skin's bounding-box diagonal, as the texture baker's visibility test
MAX_NFEV = 12  # evaluations of the residuals per round beyond the Jacobians
ROUNDS = 3
MODES = 30
# the term's weight: 1 makes it count like EFFECTIVE residuals at their initial robust scale;
# 100 was the best of 1, 30, 100 on ICT seeds 1000-1009 (the largest tried)
WEIGHT = 100.0
EFFECTIVE = 100.0
CAMERA_STEP = 0.01  # the camera's parameters: rotation in 0.01 rad, scale in 1 %, offset in pixels


def sh9(normals: np.ndarray) -> np.ndarray:
    """(N, 9) the second-order real spherical harmonics (unnormalised) of unit ``normals`` (N, 3)."""
    x, y, z = normals[:, 0], normals[:, 1], normals[:, 2]
    return np.stack([np.ones_like(x), x, y, z, x * y, x * z, y * z, x * x - y * y, 3 * z * z - 1], axis=1)


def solve_lighting(normals: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The 9 SH coefficients (per column of ``values`` (N,) or (N, C)) that best explain
    ``values`` as a lighting of ``normals`` (linear least squares)."""
    return np.linalg.lstsq(sh9(normals), values, rcond=None)[0]


def huber(r: np.ndarray, c: float = HUBER) -> np.ndarray:
    """A residual whose square is twice Huber's loss of ``r`` (same sign)."""
    a = np.abs(r)
    return np.where(a <= c, r, np.sign(r) * np.sqrt(np.maximum(2 * c * a - c * c, 0.0)))


@lru_cache(maxsize=2)
def shading_vertices(head) -> np.ndarray:
    """Skin vertices of the face that shading may explain: within ``FACE_REACH`` of the 468
    surface landmarks, not near the eyes, brows or lips, not inside the lips (read-only)."""
    from scipy.spatial import cKDTree

    from faceanim.face.landmarks import EYE_LEFT, EYE_RIGHT, LIP_OUTER

    lm = head.landmarks()
    iod = float(np.linalg.norm(lm[33] - lm[263]))
    skin = head.parts["skin"]
    v = head.mesh.vertices[skin]
    keep = cKDTree(lm[:468]).query(v)[0] < FACE_REACH * iod
    for ids, reach in ((EYE_LEFT + EYE_RIGHT, EYE_REACH), (BROWS, BROW_REACH), (LIP_OUTER, LIP_REACH)):
        keep &= cKDTree(lm[list(ids)]).query(v)[0] > reach * iod
    lip = lm[list(LIP_OUTER)]
    inside = ((v[:, 0] > lip[:, 0].min()) & (v[:, 0] < lip[:, 0].max()) & (v[:, 1] > lip[:, 1].min())
              & (v[:, 1] < lip[:, 1].max()) & (v[:, 2] > lip[:, 2].min() - 0.2 * iod))
    out = skin[keep & ~inside]
    out.setflags(write=False)
    return out


def _rotation(v: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(v).as_matrix()


class Shading:
    """The shading residuals of a set of views (``image`` (H, W, 3) uint8 each) for a head's
    vertices: the submesh around :func:`shading_vertices` gives their normals."""

    def __init__(self, head, images, channels=(0, 1, 2)):
        from scipy.ndimage import gaussian_filter

        from faceanim.face.mesh import face_incidence

        self.head = head
        self.idx = shading_vertices(head)
        faces = head.mesh.faces
        sub_faces = faces[np.isin(faces, self.idx).any(axis=1)]
        self.sub = np.unique(sub_faces)
        remap = np.full(head.mesh.n_vertices, -1)
        remap[self.sub] = np.arange(len(self.sub))
        self.sub_faces = remap[sub_faces]
        self.rows = remap[self.idx]  # the shading vertices in the submesh
        self.incidence = face_incidence(self.sub_faces, len(self.sub))
        skin = head.parts["skin"]
        self.skin_faces = faces[np.isin(faces, skin).all(axis=1)]
        self.images = [np.stack([gaussian_filter(np.asarray(im)[..., c].astype(np.float64) / 255.0, BLUR)
                                 for c in channels]) for im in images]
        self.saturated = [np.stack([np.asarray(im)[..., c] >= SATURATED for c in channels]) for im in images]

    def normals(self, sub_vertices: np.ndarray) -> np.ndarray:
        from faceanim.face.mesh import vertex_normals

        return vertex_normals(sub_vertices, self.sub_faces, self.incidence)[self.rows]

    def visible(self, k: int, cam: ViewCamera, vertices: np.ndarray) -> np.ndarray:
        """(n,) bool per shading vertex: seen by view ``k`` through ``cam`` (facing it by
        ``FACING``, not hidden in the skin's depth map, inside its outline) and not clipped."""
        from faceanim.build.texture import _view_maps, _visible

        skin_v = vertices[self.head.parts["skin"]]
        diag = float(np.linalg.norm(skin_v.max(0) - skin_v.min(0)))
        maps = _view_maps(vertices, self.skin_faces, cam)
        n = self.normals(vertices[self.sub])
        seen, x, y, cos = _visible(cam, maps, vertices[self.idx], n, DEPTH_TOLERANCE * diag)
        h, w = self.images[k].shape[1:]
        jx = np.clip(np.rint(x).astype(int), 0, w - 1)
        jy = np.clip(np.rint(y).astype(int), 0, h - 1)
        unsat = ~self.saturated[k][:, jy, jx].any(axis=0)
        return seen & (cos > FACING) & unsat

    def residual(self, k: int, cam: ViewCamera, sub_vertices: np.ndarray, visible: np.ndarray) -> np.ndarray:
        """Per channel, the photo at the projected vertices less the best SH lighting of their normals."""
        from scipy.ndimage import map_coordinates

        n = self.normals(sub_vertices)[visible]
        xy = cam.project(sub_vertices[self.rows][visible])
        h = sh9(n)
        grey = np.stack([map_coordinates(img, [xy[:, 1] - 0.5, xy[:, 0] - 0.5], order=1, mode="nearest")
                         for img in self.images[k]], axis=1)
        light = np.linalg.lstsq(h, grey, rcond=None)[0]
        return (grey - h @ light).T.ravel()


@dataclass
class ShadedIdentity:
    """:func:`fit_identity_shading`'s result: the identity ``weights`` (K,) and each view's
    ``cameras`` refined with them (they see ``head.identity(weights)``)."""

    weights: np.ndarray
    cameras: list


def fit_identity_shading(head, views, rec, w0, weight: float = WEIGHT, modes: int = MODES, rounds: int = ROUNDS,
                         use_sides: bool = True, log=None) -> ShadedIdentity:
    """Identity weights refined from ``w0`` (:func:`~faceanim.build.photo.fit_identity`'s) by the
    shading term with ``weight``, jointly with each view's camera (module docstring)."""
    from scipy.optimize import least_squares

    from faceanim.build import photo as P
    from faceanim.build.profile import head_outline
    from faceanim.errors import LandmarkError
    from faceanim.face.mesh import vertex_normals

    basis, at_points = P.identity_model(head)
    k_all = basis.shape[0]
    modes = min(int(modes), k_all)
    p0, _ = P.prior_points(head)
    skin = head.parts["skin"]
    iod0 = float(np.linalg.norm(p0[P.OUTER_EYE_CORNERS[0]] - p0[P.OUTER_EYE_CORNERS[1]]))
    targets, use, spans = P._identity_targets(views, rec)
    refused = rec.refused or [False] * len(views)
    outline = 4.0
    if views[0].outline is None:
        try:
            views[0].outline = head_outline(views[0].image)
        except LandmarkError:
            outline = 0.0
    ears = P.ear_vertices(head)
    shading = Shading(head, [v.image for v in views])
    shaded = [u or (use_sides and v.role == "side" and not off) for v, u, off in zip(views, use, refused)]
    sub_basis = basis[:modes][:, shading.sub]  # (K, S, 3)
    w = np.asarray(w0, dtype=np.float64).copy()
    pts = p0 + np.tensordot(w, at_points, axes=1)
    cams = [P._refit_camera(v, pts, rows, pix) for v, (rows, pix) in zip(views, targets)]
    active = [k for k in range(len(views)) if use[k] or shaded[k]]

    def camera(k, x):
        c = cams[k]
        j = modes + 6 * active.index(k)
        d = x[j:j + 6]
        return ViewCamera(c.rotation @ _rotation(d[:3] * CAMERA_STEP), c.scale * (1 + CAMERA_STEP * d[3]),
                          c.offset + d[4:6], c.size)

    sigma = {}
    for it in range(rounds):
        verts = head.identity(w)
        nv = vertex_normals(verts, head.mesh.faces)
        fixed_a, fixed_b = [], []  # silhouette and outline rows: correspondences and cameras fixed this round
        for v, cam, used, span in zip(views, cams, use, spans):
            if not used:
                continue
            unit = cam.scale * iod0
            if span is not None:
                sa, sb = P._silhouette_rows(v, cam, head.mesh.vertices, verts, nv, skin, basis, unit, span)
                fixed_a.append(sa / P.IDENTITY_SILHOUETTE_SIGMA)
                fixed_b.append(sb / P.IDENTITY_SILHOUETTE_SIGMA)
            if outline > 0 and v.role == "front" and v.outline is not None:
                oa, ob = P._outline_rows(v, cam, head.mesh.vertices, verts, nv, skin, ears, basis, unit)
                fixed_a.append(np.sqrt(outline) * oa / P.IDENTITY_OUTLINE_SIGMA)
                fixed_b.append(np.sqrt(outline) * ob / P.IDENTITY_OUTLINE_SIGMA)
        fa = np.vstack(fixed_a) if fixed_a else np.zeros((0, k_all))
        fb = np.concatenate(fixed_b) if fixed_b else np.zeros(0)
        fb_rest = fb - fa[:, modes:] @ w[modes:]
        fa = fa[:, :modes]
        vis = {k: shading.visible(k, cams[k], verts) for k in active if shaded[k]}
        vis = {k: m for k, m in vis.items() if m.sum() >= 30}  # too few pixels say nothing of the lighting
        base_sub = verts[shading.sub] - np.tensordot(w[:modes], sub_basis, axes=1)
        at_rest = p0 + np.tensordot(w[modes:], at_points[modes:], axes=1)
        for k in vis:  # the residuals' robust scale at the start (fit_identity's head), kept
            if k not in sigma:
                r0 = shading.residual(k, cams[k], verts[shading.sub], vis[k])
                sigma[k] = 1.4826 * float(np.median(np.abs(r0))) + 1e-6

        def residuals(x):
            wk = x[:modes]
            out = [fa @ wk - fb_rest]
            pts = at_rest + np.tensordot(wk, at_points[:modes], axes=1)
            sv = base_sub + np.tensordot(wk, sub_basis, axes=1)
            for k in active:
                cam = camera(k, x)
                rows, pix = targets[k]
                if use[k]:
                    unit = cams[k].scale * iod0
                    out.append(((cam.project(pts[rows]) - pix) / (unit * P.IDENTITY_LANDMARK_SIGMA)).ravel())
                if k in vis and weight > 0:
                    r = shading.residual(k, cam, sv, vis[k]) / sigma[k]
                    out.append(huber(r) * np.sqrt(weight * EFFECTIVE / len(r)))
            out.append(10.0 * wk)  # the prior N(0, 1) at fit_identity's weight 100
            return np.concatenate(out)

        x0 = np.r_[w[:modes], np.zeros(6 * len(active))]
        before = float(np.sum(residuals(x0) ** 2))
        sol = least_squares(residuals, x0, method="trf", diff_step=1e-3, max_nfev=MAX_NFEV, x_scale=1.0)
        w[:modes] = sol.x[:modes]
        cams = [camera(k, sol.x) if k in active else c for k, c in enumerate(cams)]
        if log is not None:
            log(f"round {it}: cost {before:.1f} -> {2 * sol.cost:.1f} ({sol.nfev} evaluations)")
    return ShadedIdentity(w, cams)
