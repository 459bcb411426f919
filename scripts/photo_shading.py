"""EXPERIMENT (not used by faceanim photo): identity weights from the shading of the photos.

Analysis by synthesis: each view's grey level at the pixels where the candidate head's face
vertices project is explained by a second-order spherical-harmonic lighting of the head's normals
(9 coefficients per view, solved by least squares for every candidate: the lighting is estimated,
not assumed) times one albedo (absorbed in the coefficients); eyes, brows and lips are left out
(by the generic head's landmarks), residuals are weighted robustly (Huber, IRLS) against a varying
albedo. The identity weights of the leading ``modes`` minimise this together with fit_identity's
landmark, profile-silhouette and front-outline terms, by damped Gauss-Newton with a finite-difference
Jacobian, starting from fit_identity's weights. Cameras are refitted to the landmarks after each
step as fit_identity does.

Used by ``scripts/eval_photo_head.py --shading W`` (tuning ICT 1000-1009: own/other median 0.62
-> 0.42 at W 100; held out, FaceWarehouse 1 and ICT 300-303: 0.66 -> 0.34). Run as a script it
checks real photos (multiview-photos), where there is no truth: fitted on the front and one
three-quarter view, judged on the other (docs/photos.md):
``python scripts/photo_shading.py ../shared/data --weight 100``.
"""

from __future__ import annotations

import numpy as np

from faceanim.build import photo as P

BROWS = (70, 63, 105, 66, 107, 55, 65, 52, 53, 46, 300, 293, 334, 296, 336, 285, 295, 282, 283, 276)
EYE_REACH, BROW_REACH, LIP_REACH = 0.12, 0.08, 0.08  # IOD around those landmarks left out
FACE_REACH = 0.1  # skin within this of the 468 landmarks is the face
FACING = 0.25  # a vertex is used in a view where its normal's cosine to the camera is above this
BLUR = 0.7  # pixels of Gaussian blur of each photo's grey level
STEP = 0.25  # finite-difference step, in standard deviations of a mode
HUBER = 1.345
SATURATED = 250  # a channel this bright is clipped: its pixels are left out
DEPTH_TOLERANCE = 1.5  # pixels: a vertex this far behind the splatted depth is hidden
MAX_NFEV = 12
EFFECTIVE = 100.0  # weight 1: the shading term counts as this many residuals at its initial scale


def sh9(n: np.ndarray) -> np.ndarray:
    x, y, z = n[:, 0], n[:, 1], n[:, 2]
    return np.stack([np.ones_like(x), x, y, z, x * y, x * z, y * z, x * x - y * y, 3 * z * z - 1], axis=1)


def shading_vertices(head) -> np.ndarray:
    from faceanim.face.landmarks import EYE_LEFT, EYE_RIGHT, LIP_OUTER
    from scipy.spatial import cKDTree

    lm = head.landmarks()
    iod = float(np.linalg.norm(lm[33] - lm[263]))
    skin = head.parts["skin"]
    v = head.mesh.vertices[skin]
    keep = cKDTree(lm[:468]).query(v)[0] < FACE_REACH * iod
    for ids, reach in ((EYE_LEFT + EYE_RIGHT, EYE_REACH), (BROWS, BROW_REACH), (LIP_OUTER, LIP_REACH)):
        keep &= cKDTree(lm[list(ids)]).query(v)[0] > reach * iod
    # the lips' inside: between the outer lip line's extremes
    lip = lm[list(LIP_OUTER)]
    inside = ((v[:, 0] > lip[:, 0].min()) & (v[:, 0] < lip[:, 0].max()) & (v[:, 1] > lip[:, 1].min())
              & (v[:, 1] < lip[:, 1].max()) & (v[:, 2] > lip[:, 2].min() - 0.2 * iod))
    return skin[keep & ~inside]


def rotation(v):
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(v).as_matrix()


class Shading:
    """The shading residuals of a set of views for identity weights (see the module docstring)."""

    def __init__(self, head, views, modes: int, channels=(0, 1, 2)):
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
        self.images = [np.stack([gaussian_filter(v.image[..., c].astype(np.float64) / 255.0, BLUR) for c in channels])
                       for v in views]
        self.saturated = [np.stack([v.image[..., c] >= SATURATED for c in channels]) for v in views]

    def normals(self, sub_vertices):
        from faceanim.face.mesh import vertex_normals

        return vertex_normals(sub_vertices, self.sub_faces, self.incidence)[self.rows]

    def visible(self, k, cam, vertices):
        """(n,) bool per shading vertex: facing the camera and in front in a splatted depth buffer
        of the whole skin."""
        from scipy.ndimage import maximum_filter

        skin = self.head.parts["skin"]
        h, w = self.images[k].shape[1:]
        p = cam.project(vertices[skin])
        d = cam.depth(vertices[skin]) * cam.scale
        z = np.full((h, w), -np.inf)
        ix = np.clip(np.floor(p[:, 0]).astype(int), 0, w - 1)
        iy = np.clip(np.floor(p[:, 1]).astype(int), 0, h - 1)
        np.maximum.at(z, (iy, ix), d)
        z = maximum_filter(z, size=3)
        q = cam.project(vertices[self.idx])
        jx = np.clip(np.floor(q[:, 0]).astype(int), 0, w - 1)
        jy = np.clip(np.floor(q[:, 1]).astype(int), 0, h - 1)
        front = cam.depth(vertices[self.idx]) * cam.scale >= z[jy, jx] - DEPTH_TOLERANCE
        inside = (q[:, 0] > 2) & (q[:, 0] < w - 2) & (q[:, 1] > 2) & (q[:, 1] < h - 2)
        unsat = ~self.saturated[k][:, jy, jx].any(axis=0)
        n = self.normals(vertices[self.sub])
        return (n @ cam.direction > FACING) & front & inside & unsat

    def residual(self, k, cam, sub_vertices, visible):
        """Per channel, the photo at the projected vertices less the best lighting of their normals."""
        from scipy.ndimage import map_coordinates

        n = self.normals(sub_vertices)[visible]
        xy = cam.project(sub_vertices[self.rows][visible])
        h = sh9(n)
        out = []
        for img in self.images[k]:
            grey = map_coordinates(img, [xy[:, 1] - 0.5, xy[:, 0] - 0.5], order=1, mode="nearest")
            light = np.linalg.lstsq(h, grey, rcond=None)[0]
            out.append(grey - h @ light)
        return np.concatenate(out)


def huber(r, c=HUBER):
    """A residual whose square is twice Huber's loss of ``r`` (same sign)."""
    a = np.abs(r)
    return np.where(a <= c, r, np.sign(r) * np.sqrt(np.maximum(2 * c * a - c * c, 0.0)))


def fit_identity_shading(head, views, rec, w0, weight: float = 1.0, modes: int = 30, iterations: int = 3,
                         damping: float = 0.0, use_sides: bool = True, cameras: bool = True, log=None):
    """Identity weights refined from ``w0`` (fit_identity's) by the shading term, jointly with
    each view's camera (module docstring). Returns the (K,) weights."""
    from scipy.optimize import least_squares

    from faceanim.build.camera import ViewCamera
    from faceanim.build.profile import head_outline
    from faceanim.errors import LandmarkError
    from faceanim.face.mesh import vertex_normals

    basis, at_points = P.identity_model(head)
    k_all = basis.shape[0]
    p0, _ = P.prior_points(head)
    skin = head.parts["skin"]
    iod0 = float(np.linalg.norm(p0[P.OUTER_EYE_CORNERS[0]] - p0[P.OUTER_EYE_CORNERS[1]]))
    targets = []
    for v, kept in zip(views, rec.observed):
        rows, pix = P._view_targets(v)
        ok = np.isin(rows, kept)
        targets.append((rows[ok], pix[ok]))
    refused = rec.refused or [False] * len(views)
    use = [(v.role == "front" or v.profile) and not off for v, off in zip(views, refused)]
    spans = []
    for v, (rows, _) in zip(views, targets):
        if v.outline is None or not v.profile:
            spans.append(None)
            continue
        ends = [int(np.argmin(np.linalg.norm(v.outline - v.points[int(i)], axis=1))) for i in rows if i < 478]
        spans.append((min(ends), max(ends)) if len(ends) >= 2 else None)
    outline = 4.0
    if views[0].outline is None:
        try:
            views[0].outline = head_outline(views[0].image)
        except LandmarkError:
            outline = 0.0
    ears = P.ear_vertices(head)
    shading = Shading(head, views, modes)
    shaded = [u or (use_sides and v.role == "side" and not off) for v, u, off in zip(views, use, refused)]
    sub_basis = basis[:modes][:, shading.sub]  # (K, S, 3)
    w = np.asarray(w0, dtype=np.float64).copy()
    pts = p0 + np.tensordot(w, at_points, axes=1)
    cams = [P._refit_camera(v, pts, rows, pix) for v, (rows, pix) in zip(views, targets)]
    n_cam = 6 if cameras else 0
    active = [k for k in range(len(views)) if use[k] or shaded[k]]

    def camera(k, x):
        c = cams[k]
        if not n_cam:
            return c
        j = modes + n_cam * active.index(k)
        d = x[j:j + 6]
        return ViewCamera(c.rotation @ rotation(d[:3] * 0.01), c.scale * (1 + 0.01 * d[3]), c.offset + d[4:6], c.size)

    sigma = {}
    for it in range(iterations):
        verts = head.identity(w)
        nv = vertex_normals(verts, head.mesh.faces)
        fixed_a, fixed_b = [], []  # silhouette and outline rows, fixed correspondences and cameras
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
            for k in active:
                cam = camera(k, x)
                rows, pix = targets[k]
                if use[k]:
                    unit = cams[k].scale * iod0
                    out.append(((cam.project(pts[rows]) - pix) / (unit * P.IDENTITY_LANDMARK_SIGMA)).ravel())
                if k in vis and weight > 0:
                    sv = base_sub + np.tensordot(wk, sub_basis, axes=1)
                    r = shading.residual(k, cam, sv, vis[k]) / sigma[k]
                    out.append(huber(r) * np.sqrt(weight * EFFECTIVE / len(r)))
            out.append(10.0 * wk)  # the prior N(0, 1) at fit_identity's weight 100
            if damping:
                out.append(np.sqrt(damping) * (wk - w[:modes]))
            return np.concatenate(out)

        x0 = np.r_[w[:modes], np.zeros(n_cam * len(active))]
        before = float(np.sum(residuals(x0) ** 2))
        sol = least_squares(residuals, x0, method="trf", diff_step=1e-3, max_nfev=MAX_NFEV, x_scale=1.0)
        w[:modes] = sol.x[:modes]
        cams = [camera(k, sol.x) if k in active else c for k, c in enumerate(cams)]
        if log is not None:
            log(f"round {it}: cost {before:.1f} -> {2 * sol.cost:.1f} ({sol.nfev} evaluations)")
    return w


def held_out_view(head, views, w, k):
    """How well identity ``w`` explains view ``k`` (not used to fit it): the view's camera fitted
    to its landmarks on the head; (median landmark reprojection error in IOD, median absolute
    shading residual after the view's own best lighting, 0..1 grey levels)."""
    p0, _ = P.prior_points(head)
    _, at_points = P.identity_model(head)
    pts = p0 + np.tensordot(w, at_points, axes=1)
    rows, pix = P._view_targets(views[k])
    rows, pix = rows[rows < 468], pix[rows < 468]
    cam = P.fit_camera(pts[rows], pix, views[k].size)
    verts = head.identity(w)
    n = verts[P.OUTER_EYE_CORNERS[0]] - verts[P.OUTER_EYE_CORNERS[1]]
    lm_err = float(np.median(np.linalg.norm(cam.project(pts[rows]) - pix, axis=1)) / (cam.scale * np.linalg.norm(n)))
    sh = Shading(head, views, 1)
    vis = sh.visible(k, cam, verts)
    r = sh.residual(k, cam, verts[sh.sub], vis)
    return lm_err, float(np.median(np.abs(r)))


def main(argv=None):
    """Real photos (multiview-photos: front, left and right three-quarter views): fit with the
    front and one side, judge on the other side (a view neither fit saw)."""
    import argparse
    from pathlib import Path

    from faceanim.face.generic_head import generic_head

    ap = argparse.ArgumentParser(description=main.__doc__)
    ap.add_argument("data", type=Path)
    ap.add_argument("--weight", type=float, default=30.0)
    args = ap.parse_args(argv)
    d = args.data / "multiview-photos"
    head = generic_head()
    prior, normals = P.prior_points(head)
    every = P.load_views(d / "front.jpg", [d / "left.jpg", d / "right.jpg"])
    print("| fitted on | judged on | head | landmark error (IOD, median) | shading residual (median abs) |")
    print("|---|---|---|---:|---:|")
    for used, judged in ((1, 2), (2, 1)):
        views = [every[0], every[used]]
        rec = P.reconstruct(views, prior, normals)
        w0 = P.fit_identity(head, views, rec)
        w = fit_identity_shading(head, views, rec, w0, weight=args.weight)
        test = [every[0], every[judged]]
        for name, ww in (("generic", np.zeros_like(w0)), ("fit_identity", w0), (f"+ shading {args.weight:g}", w)):
            lm, res = held_out_view(head, test, ww, 1)
            print(f"| front + {Path(every[used].name).name} | {Path(every[judged].name).name} | {name} | {lm:.4f} | "
                  f"{res:.4f} |", flush=True)


if __name__ == "__main__":
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
    main()
