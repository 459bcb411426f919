"""Real photos (multiview-photos: a front and two three-quarter views of one man; no truth): the
shading fit of faceanim photo (:mod:`faceanim.build.shading`) judged on a view it never saw.

Each run builds the head from the front and one three-quarter view and judges it on the other:

- identity: the unseen view's camera fitted to its detected landmarks on the head; the median
  landmark reprojection error (IOD) and the median absolute shading residual after the view's own
  best SH lighting (0..1 grey levels), for the generic head, fit_identity's and the shading fit's;
- texture (``--texture``): ``faceanim photo``'s whole pipeline (``head_from_photos``) with the
  warps given, the textured head rendered unlit through the unseen view's camera (fitted to its
  landmarks on the head) and compared with the photo inside the photo's face oval (median |RGB|
  difference, 0..255), and the landmarks' reprojection error in the photos the texture came from
  (median, IOD; each through the camera the texture was taken with).

    python scripts/photo_shading.py ../shared/data --weight 100 [--texture fast,0,0.02,inf]
"""

from __future__ import annotations

import numpy as np

from faceanim.build import photo as P
from faceanim.build.shading import Shading, fit_identity_shading


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
    sh = Shading(head, [v.image for v in views])
    vis = sh.visible(k, cam, verts)
    r = sh.residual(k, cam, verts[sh.sub], vis)
    return lm_err, float(np.median(np.abs(r)))


def texture_check(ph, unseen) -> tuple[float, float, list[float]]:
    """(median |RGB| difference in the unseen view's face oval, the unseen view's landmark error
    (IOD), per photo used the landmark error through the texture's camera (IOD))."""
    import cv2

    from faceanim.face.landmarks import FACE_OVAL
    from faceanim.render.bake import ortho_render

    from faceanim.face.generic_head import generic_head

    m = ph.mesh
    verts = ph.fitted.expressed  # the head with the photos' expression, as the texture was taken
    lm = generic_head().landmarks(verts)
    iod = float(np.linalg.norm(lm[33] - lm[263]))
    rows = np.arange(468)
    pix = np.stack([unseen.points[i] for i in rows])
    lm_n = generic_head().landmark_matrix() @ m.vertex_normals(verts)  # only the landmarks a view sees face-on
    cam = P.fit_camera(lm[rows], pix, unseen.size)
    seen = lm_n[rows] @ cam.direction > 0.3
    cam = P.fit_camera(lm[rows[seen]], pix[seen], unseen.size)
    lm_err = float(np.median(np.linalg.norm(cam.project(lm[rows[seen]]) - pix[seen], axis=1)) / (cam.scale * iod))
    w, h = unseen.size
    img = ortho_render(verts, m.faces, m.uv[m.face_uv], m.texture, cam.matrix, cam.offset, cam.direction, (w, h))
    mask = np.zeros((h, w), np.uint8)
    oval = np.stack([unseen.points[i] for i in FACE_OVAL]).astype(np.int32)
    cv2.fillPoly(mask, [oval], 1)
    diff = np.abs(img.astype(np.int32) - unseen.image.astype(np.int32)).mean(axis=2)
    used = []
    for v, c in zip(ph.views, ph.cameras):
        r = np.array([i for i in sorted(v.points) if i < 468])
        p = np.stack([v.points[i] for i in r])
        ok = (lm_n[r] @ c.direction) > 0.3
        used.append(float(np.median(np.linalg.norm(c.project(lm[r[ok]]) - p[ok], axis=1)) / (c.scale * iod)))
    return float(np.median(diff[mask > 0])), lm_err, used


def main(argv=None):
    """Real photos (multiview-photos: front, left and right three-quarter views): fit with the
    front and one side, judge on the other side (a view neither fit saw)."""
    import argparse
    import time
    from pathlib import Path

    from faceanim.face.generic_head import generic_head

    ap = argparse.ArgumentParser(description=main.__doc__)
    ap.add_argument("data", type=Path)
    ap.add_argument("--weight", type=float, default=100.0)
    ap.add_argument("--texture", help="comma-separated: fast, or a deadband (IOD; inf: no warp) of faceanim photo")
    ap.add_argument("--skip-identity", action="store_true")
    args = ap.parse_args(argv)
    d = args.data / "multiview-photos"
    head = generic_head()
    prior, normals = P.prior_points(head)
    every = P.load_views(d / "front.jpg", [d / "left.jpg", d / "right.jpg"])
    if not args.skip_identity:
        print("| fitted on | judged on | head | landmark error (IOD, median) | shading residual (median abs) |")
        print("|---|---|---|---:|---:|")
        for used, judged in ((1, 2), (2, 1)):
            views = [every[0], every[used]]
            rec = P.reconstruct(views, prior, normals)
            w0 = P.fit_identity(head, views, rec)
            w = fit_identity_shading(head, views, rec, w0, weight=args.weight).weights
            test = [every[0], every[judged]]
            for name, ww in (("generic", np.zeros_like(w0)), ("fit_identity", w0), (f"+ shading {args.weight:g}", w)):
                lm, res = held_out_view(head, test, ww, 1)
                print(f"| front + {Path(every[used].name).name} | {Path(every[judged].name).name} | {name} | {lm:.4f} | "
                      f"{res:.4f} |", flush=True)
    if args.texture:
        print("\n| fitted on | judged on | faceanim photo | unseen view: median abs RGB in the face oval | unseen "
              "landmarks (IOD) | texture cameras: landmark error front, side (IOD) | seconds |")
        print("|---|---|---|---:|---:|---|---:|")
        for used, judged in ((1, 2), (2, 1)):
            for variant in args.texture.split(","):
                t = time.perf_counter()
                kw = {"fast": True} if variant == "fast" else {"deadband": float(variant)}
                ph = P.head_from_photos(d / "front.jpg", [d / ("left.jpg" if used == 1 else "right.jpg")], **kw)
                sec = time.perf_counter() - t
                rgb, lm, own = texture_check(ph, every[judged])
                print(f"| front + {Path(every[used].name).name} | {Path(every[judged].name).name} | {variant} | "
                      f"{rgb:.1f} | {lm:.4f} | {', '.join(f'{e:.4f}' for e in own)} | {sec:.0f} |", flush=True)


if __name__ == "__main__":
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
    main()
