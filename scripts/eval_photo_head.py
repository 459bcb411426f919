"""How well does a head from photos match the real head? (Lee et al. 1999, section 2, measured.)

1. Known truth: each FaceWarehouse scan (a real, textured head) is rendered from the front and
   from the side (a profile at 90 degrees, or a three-quarter view); the head is rebuilt from
   those two renders alone and compared with the scan: surface error over the face (mean
   distance from the scan's face vertices to the rebuilt skin, in inter-ocular distances) and
   the error per MPEG-4 feature point; the baseline is the generic head with no fitting
   (placed by the same similarity on the landmarks).
2. Real photos (``multiview-photos``): reprojection error of the landmarks in each view after
   the rebuild, and a contact sheet (photo | rebuilt head from the same camera).
3. Own or another person's (``--people``): FaceWarehouse tester 1's neutral scan and ICT
   identities sampled with N(0, 1) weights (seeds 300...: never used while building; rendered
   untextured), each rebuilt from a front and a profile render, with and without the morphable
   identity (``fit_head(identity=...)``). Each person's scan against the generic head, against
   the head from the person's own renders, and against the heads from everybody else's: the
   ratio own/other is how much closer a head from your photos is to you than to anybody else.

   ``--seeds 1000-1009`` runs section 3 on those ICT seeds alone (the tuning set); ``--shading W``
   adds the shading experiment of ``scripts/photo_shading.py`` (not used by faceanim photo).

Usage: ``python scripts/eval_photo_head.py ../shared/data [--poses 0,1,2] [--sheet out.png] [--people 4]``
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from faceanim.build.photo import (
    fit_head,
    fit_identity,
    load_views,
    prior_points,
    reconstruct,
)
from faceanim.face.face import Face, landmarks_478
from faceanim.standards.mpeg4 import fdp_spec
from faceanim.face.frame import similarity
from faceanim.face.generic_head import generic_head
from faceanim.face.landmarks import detect_landmarks
from faceanim.face.registration import fit_landmarks
from faceanim.io.meshio import load_mesh
from faceanim.render import OffscreenRenderer

SIZE = 512


def render(mesh, yaw: float) -> np.ndarray:
    with OffscreenRenderer(mesh, size=(SIZE, SIZE), yaw=yaw, parallel=True, background=(0.5, 0.5, 0.5)) as r:
        return r.render()


ALIGN_ITERATIONS = 15


def surface_error(truth: Face, rebuilt_vertices: np.ndarray, head, lm_rebuilt: np.ndarray) -> tuple[float, dict]:
    """Mean distance (IOD) from the scan's face vertices to the rebuilt skin, and per FDP.

    The rebuilt head is placed on the scan by a similarity on the 468 surface landmarks, then
    refined by similarity ICP (scan face vertices to their closest points on the rebuilt skin),
    as face-reconstruction benchmarks align before they measure. Placed by the landmarks alone,
    the scan measured 0.005-0.025 IOD from itself: MediaPipe's points on a render slide about
    0.02 IOD from the head's own landmark positions, as much as two people differ."""
    from faceanim.face.mesh import Mesh

    skin = head.parts["skin"]
    keep = np.isin(head.mesh.faces, skin).all(axis=1)
    rebuilt = Mesh(np.asarray(rebuilt_vertices, dtype=np.float64), head.mesh.faces[keep])
    face_v = truth.mesh.vertices[truth.face_region]
    s, r, t = similarity(lm_rebuilt[:468], truth.landmarks[:468])
    for _ in range(ALIGN_ITERATIONS):
        closest, _, _ = rebuilt.closest_points(((face_v - t) @ r) / s)
        s, r, t = similarity(closest, face_v)
    closest, _, _ = rebuilt.closest_points(((face_v - t) @ r) / s)
    iod = truth.frame.iod
    err = float(np.linalg.norm(s * closest @ r.T + t - face_v, axis=1).mean() / iod)
    lm = s * lm_rebuilt @ r.T + t
    per = {}
    for name, ids in fdp_spec()["points"].items():
        if name in ("3.5", "3.6"):
            continue
        per[name] = float(np.linalg.norm(lm[ids].mean(0) - truth.landmarks[ids].mean(0)) / iod)
    return err, per


def known_truth(data: Path, poses: list[int], side_yaw: float) -> None:
    """Rebuild each scan from its renders in several ways and compare each with the scan."""
    head = generic_head()
    prior, normals = prior_points(head)
    setups = {  # column -> (side yaws, method)
        "front only, dffd": ((), "dffd"),
        f"front + side {side_yaw:g}, dffd": ((side_yaw,), "dffd"),
        f"front + side {side_yaw:g}, rbf": ((side_yaw,), "rbf"),
        "front + 3/4 (40), dffd": ((40.0,), "dffd"),
    }
    cols = ["generic (no fit)", *setups]
    rows, fdp_sum, seconds = [], {c: [] for c in cols}, {c: [] for c in setups}
    for k in poses:
        scan = load_mesh(data / "facewarehouse-tester1" / f"pose_{k}.obj")
        truth = Face(scan, landmarks_478(scan, detect_landmarks(scan)))
        renders = {yaw: render(scan, yaw) for yaw in {0.0, side_yaw, 40.0}}
        err, per = surface_error(truth, head.mesh.vertices, head, head.landmarks())
        row = {"pose": k, "generic (no fit)": err}
        fdp_sum["generic (no fit)"].append(per)
        for col, (yaws, method) in setups.items():
            t = time.perf_counter()
            views = load_views(("front", renders[0.0]), [(f"side {y:g}", renders[y]) for y in yaws])
            rec = reconstruct(views, prior, normals)
            fh = fit_head(head, rec, method)
            seconds[col].append(time.perf_counter() - t)
            # the scan shows the photo's expression: compare the head with it (before it is taken off)
            err, per = surface_error(truth, fh.expressed, head, head.landmarks(fh.expressed))
            row[col] = err
            fdp_sum[col].append(per)
        rows.append(row)
        print({c: round(v, 4) for c, v in row.items()}, flush=True)
    print("\nSurface error over the face: mean distance from the scan's face vertices to the rebuilt skin, "
          "in inter-ocular distances (FaceWarehouse tester 1, rendered 512 px)")
    print("| pose | " + " | ".join(cols) + " |")
    print("|---|" + "---|" * len(cols))
    for r in rows:
        print(f"| {r['pose']} | " + " | ".join(f"{r[c]:.4f}" for c in cols) + " |")
    print("| mean | " + " | ".join(f"{np.mean([r[c] for r in rows]):.4f}" for c in cols) + " |")
    print("| seconds (detect + fit) | - | " + " | ".join(f"{np.mean(seconds[c]):.1f}" for c in setups) + " |")
    print("\nPer feature point: distance to the scan's (mean over poses, IOD)")
    print("| FDP | " + " | ".join(cols) + " |")
    print("|---|" + "---|" * len(cols))
    for n in fdp_sum[cols[0]][0]:
        print(f"| {n} | " + " | ".join(f"{np.mean([d[n] for d in fdp_sum[c]]):.3f}" for c in cols) + " |")
    print("| mean | " + " | ".join(f"{np.mean([np.mean(list(d.values())) for d in fdp_sum[c]]):.3f}" for c in cols)
          + " |")


def _people_truths(data: Path, seeds, scan: bool):
    from faceanim.face.mesh import Mesh

    head = generic_head()
    truths = []
    path = data / "facewarehouse-tester1" / "pose_0.obj"
    if scan and path.is_file():
        truths.append(("FaceWarehouse 1", load_mesh(path)))
    modes = np.load(data / "ict-facekit" / "identity_modes.npz")["modes"][:, :24591].astype(np.float64) * 0.01
    skin_faces = head.mesh.faces[np.isin(head.mesh.faces, head.parts["skin"]).all(axis=1)]
    for seed in seeds:
        w = np.random.default_rng(seed).standard_normal(len(modes))
        v = head.mesh.vertices + np.einsum("k,kvd->vd", w, modes)
        truths.append((f"ICT seed {seed}", Mesh(v, skin_faces, name=f"ict{seed}")))
    return truths


def _views(name: str, mesh, side_yaw: float, cache: Path | None):
    """The person's front and side renders with their detected points (cached in ``cache``: the
    renders and the detection are the same on every run)."""
    import pickle

    f = None
    if cache is not None:
        cache.mkdir(parents=True, exist_ok=True)
        f = cache / f"{name.replace(' ', '_')}_{side_yaw:g}.pkl"
        if f.is_file():
            return pickle.loads(f.read_bytes())
    views = load_views(("front", render(mesh, 0.0)), [("side", render(mesh, side_yaw))])
    if f is not None:
        f.write_bytes(pickle.dumps(views))
    return views


def people(data: Path, seeds, side_yaw: float, scan: bool = True, cache: Path | None = None,
           shading: float = 0.0, shading_options: dict | None = None, dense_only: bool = False) -> None:
    """Section 3 of the module docstring."""
    head = generic_head()
    prior, normals = prior_points(head)
    truths = _people_truths(data, seeds, scan)
    faces, built, dense, photo_dense = [], {True: [], False: []}, [], []
    for name, mesh in truths:
        face = Face(mesh, landmarks_478(mesh, detect_landmarks(mesh)))
        faces.append(face)
        views = _views(name, mesh, side_yaw, cache)
        rec = reconstruct(views, prior, normals)
        w = fit_identity(head, views, rec)
        if shading > 0:
            from faceanim.build.shading import fit_identity_shading

            w = fit_identity_shading(head, views, rec, w, weight=shading, **(shading_options or {})).weights
        if dense_only:
            dense.append(head.identity(w))
            continue
        dense.append(head.identity(w))
        # what faceanim photo makes with these weights: the morphable head warped onto the points
        photo_dense.append(fit_head(head, rec, "dffd", keep_expression=True, identity=w).vertices)
        for ident in (True, False):
            fh = fit_head(head, rec, "dffd", keep_expression=True, identity=ident)
            built[ident].append(fh.vertices)
    if dense_only:
        rows = []
        for i, ((name, _), face) in enumerate(zip(truths, faces)):
            errs = [surface_error(face, v, head, head.landmarks(v))[0] for v in dense]
            rows.append((name, errs[i], float(np.mean([e for j, e in enumerate(errs) if j != i]))))
            print(f"| {name} | {rows[-1][1]:.4f} | {rows[-1][2]:.4f} | {rows[-1][1] / rows[-1][2]:.2f} |", flush=True)
        print(f"| median | | | {np.median([o / t for _, o, t in rows]):.2f} |")
        return
    print(f"\nOwn or another person's head: surface error over the face (IOD), front + side {side_yaw:g} renders")
    print("| person | generic head | identity from the scan's 3D landmarks | own photos, identity | own, no identity "
          "| others', identity (mean) | own/other, identity | own/other, no identity |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    ratios = {True: [], False: []}
    gen_ratio, bounds, dense_rows = [], [], {"dense": [], "photo": []}
    for i, ((name, _), face) in enumerate(zip(truths, faces)):
        generic, _ = surface_error(face, head.mesh.vertices, head, head.landmarks())
        # the bound of a landmark-driven identity: fitted to the scan's own detected 3D landmarks
        bound_v = head.identity(fit_landmarks(face.landmarks, head)[3][:head.n_identity])
        bound, _ = surface_error(face, bound_v, head, head.landmarks(bound_v))
        bounds.append(bound / generic)
        row = {}
        for ident in (True, False):
            errs = [surface_error(face, v, head, head.landmarks(v))[0] for v in built[ident]]
            own = errs[i]
            other = float(np.mean([e for j, e in enumerate(errs) if j != i]))
            row[ident] = (own, other)
            ratios[ident].append(own / other)
        gen_ratio.append(row[True][0] / generic)
        for key, heads in (("dense", dense), ("photo", photo_dense)):
            errs = [surface_error(face, v, head, head.landmarks(v))[0] for v in heads]
            dense_rows[key].append((name, errs[i], float(np.mean([e for j, e in enumerate(errs) if j != i]))))
        print(f"| {name} | {generic:.4f} | {bound:.4f} | {row[True][0]:.4f} | {row[False][0]:.4f} | {row[True][1]:.4f} | "
              f"{row[True][0] / row[True][1]:.2f} | {row[False][0] / row[False][1]:.2f} |", flush=True)
    print(f"| median | | | | | | {np.median(ratios[True]):.2f} | {np.median(ratios[False]):.2f} |")
    print(f"own photo head / generic head (identity): median {np.median(gen_ratio):.2f}; identity from the scan's "
          f"own 3D landmarks / generic head: median {np.median(bounds):.2f}")
    what = "front landmarks + profile silhouette + front outline" + (f" + shading (weight {shading:g})" if shading else "")
    for key, title in (("dense", f"Dense identity (fit_identity: {what}; the morphable head alone, no warp)"),
                       ("photo", "The same weights warped onto the points (fit_head(identity=w): what faceanim "
                                 "photo makes)")):
        print(f"\n{title}")
        print("| person | own | others' (mean) | own/other |")
        print("|---|---:|---:|---:|")
        for name, own, other in dense_rows[key]:
            print(f"| {name} | {own:.4f} | {other:.4f} | {own / other:.2f} |")
        print(f"| median | | | {np.median([o / t for _, o, t in dense_rows[key]]):.2f} |")


def _true_cameras(mesh, side_yaw: float):
    from faceanim.build.texture import view_camera

    cams = []
    for yaw in (0.0, side_yaw):
        with OffscreenRenderer(mesh, size=(SIZE, SIZE), yaw=yaw, parallel=True, background=(0.5, 0.5, 0.5)) as r:
            cams.append(view_camera(r))
    return cams


def alignment(head, views, rec, fitted, truth_lm, true_cams) -> list[float]:
    """Per view, the median distance (IOD) in the photo between where the baked texture puts each
    of the 468 surface landmarks (the head's landmark through the camera the texture is taken
    with, :func:`faceanim.build.photo.bake_cameras`) and where the true head's landmark is in the
    render (its true camera): how far the texture's features sit from the photo's."""
    from faceanim.build.photo import bake_cameras
    from faceanim.face.mesh import vertex_normals

    cams = bake_cameras(head, views, rec, fitted)
    ours = head.landmarks(fitted.expressed)[:468]
    iod = float(np.linalg.norm(truth_lm[33] - truth_lm[263]))
    out = []
    for cam, tc in zip(cams, true_cams):
        # landmarks the true camera sees face-on enough
        nrm = vertex_normals(fitted.expressed, head.mesh.faces)
        lm_n = head.landmark_matrix() @ nrm
        seen = (lm_n[:468] @ tc.direction) > 0.3
        d = np.linalg.norm(cam.project(ours[seen]) - tc.project(truth_lm[:468][seen]), axis=1) / (tc.scale * iod)
        out.append(float(np.median(d)))
    return out


def people_warps(data: Path, seeds, side_yaw: float, warps: list[str], scan: bool, cache: Path | None,
                 shading: float, shading_options: dict | None = None) -> None:
    """Section 3 for several warps of one identity fit (fit_identity, + shading when ``shading``):
    ``warps`` as ``affine:D`` or ``sim:D``, the global fit and the deadband D (IOD, inf: no warp).
    Own/other per warp, and the texture's alignment against the truth (:func:`alignment`)."""
    head = generic_head()
    prior, normals = prior_points(head)
    truths = _people_truths(data, seeds, scan)
    faces, heads, aligns, secs = [], {k: [] for k in warps}, {k: [] for k in warps}, []
    for name, mesh in truths:
        face = Face(mesh, landmarks_478(mesh, detect_landmarks(mesh)))
        faces.append(face)
        views = _views(name, mesh, side_yaw, cache)
        true_lm = face.landmarks if name.startswith("FaceWarehouse") else head.landmarks(mesh.vertices)
        true_cams = _true_cameras(mesh, side_yaw)
        t = time.perf_counter()
        rec = reconstruct(views, prior, normals)
        w = fit_identity(head, views, rec)
        if shading > 0:
            from faceanim.build.shading import fit_identity_shading

            w = fit_identity_shading(head, views, rec, w, weight=shading, **(shading_options or {})).weights
        secs.append(time.perf_counter() - t)
        for k in warps:
            g, _, d = k.partition(":")
            fh = fit_head(head, rec, "dffd", keep_expression=True, identity=w, deadband=float(d), affine=g == "affine")
            heads[k].append(fh.vertices)
            aligns[k].append(alignment(head, views, rec, fh, true_lm, true_cams))
        print(f"{name}: identity fit {secs[-1]:.1f} s; alignment front/side (IOD) "
              + ", ".join(f"{k} {a[-1][0]:.4f}/{a[-1][1]:.4f}" for k, a in aligns.items()), flush=True)
    print(f"\nown/other by warp (identity: fit_identity{' + shading %g' % shading if shading else ''}); "
          f"identity fit {np.median(secs):.1f} s per person (median)")
    print("| warp | " + " | ".join(n for n, _ in truths) + " | median | alignment front, median (IOD) | side |")
    print("|---|" + "---:|" * (len(truths) + 3))
    for k in warps:
        ratios = []
        for i, face in enumerate(faces):
            errs = [surface_error(face, v, head, head.landmarks(v))[0] for v in heads[k]]
            ratios.append(errs[i] / float(np.mean([e for j, e in enumerate(errs) if j != i])))
        a = np.array(aligns[k])
        print(f"| {k} | " + " | ".join(f"{r:.2f}" for r in ratios) + f" | {np.median(ratios):.2f} | "
              f"{np.median(a[:, 0]):.4f} | {np.median(a[:, 1]):.4f} |", flush=True)


def real_photos(data: Path, sheet: Path | None) -> None:
    from faceanim.build.photo import head_from_photos

    d = data / "multiview-photos"
    t = time.perf_counter()
    ph = head_from_photos(d / "front.jpg", [d / "left.jpg", d / "right.jpg"])
    total = time.perf_counter() - t
    print("\nReal photos (multiview-photos): reprojection error per view (IOD)")
    print("| view | yaw (deg) | points | median | 95th pct | max |")
    print("|---|---|---|---|---|---|")
    for v, cam, e in zip(ph.views, ph.reconstruction.cameras, ph.reconstruction.errors):
        print(f"| {Path(v.name).name} | {cam.yaw_degrees:.1f} | {len(e)} | {np.median(e):.4f} | "
              f"{np.percentile(e, 95):.4f} | {e.max():.4f} |")
    print("timings: " + ", ".join(f"{k} {v:.2f} s" for k, v in ph.timings.items()) + f" (wall {total:.1f} s)")
    from faceanim.build.texture import BakeView, bake, seam_step

    views = [BakeView(v.image, c) for v, c in zip(ph.views, ph.cameras or ph.reconstruction.cameras)]
    steps = {}
    for blend in ("none", "pyramid"):
        b = bake(ph.fitted.expressed, ph.mesh.faces, ph.mesh.uv, ph.mesh.face_uv, ph.parts, views, blend=blend)
        steps[blend] = seam_step(b.texture, b.split)
    print(f"texture seam step (mean |RGB| across the merge lines, 0..255): hard split {steps['none']:.2f}, "
          f"Laplacian pyramid {steps['pyramid']:.2f}")
    if sheet is not None:
        from PIL import Image, ImageDraw

        from faceanim.render.bake import ortho_render

        m = ph.mesh
        tiles = []
        for v, cam, rows in zip(ph.views, ph.cameras or ph.reconstruction.cameras, ph.reconstruction.observed):
            h, w = v.image.shape[:2]
            # the rebuilt head through the photo's own solved camera (unlit albedo), the photo's
            # landmarks (green) and the rebuilt head's landmarks (red) on both
            render = ortho_render(m.vertices, m.faces, m.uv[m.face_uv], m.texture, cam.matrix, cam.offset,
                                  cam.direction, (w, h), background=(40, 40, 48))
            pair = []
            for img in (v.image, render):
                im = Image.fromarray(np.ascontiguousarray(img))
                d = ImageDraw.Draw(im)
                for i in rows[rows < 468][::3]:
                    x, y = v.points[int(i)]
                    d.point((x, y), fill=(0, 255, 0))
                    x, y = cam.project(ph.landmarks[[int(i)]])[0]
                    d.point((x, y), fill=(255, 0, 0))
                pair.append(np.asarray(im))
            tiles.append(np.vstack(pair))
        Image.fromarray(np.hstack(tiles)).save(sheet)
        print(f"contact sheet: {sheet} (top: photos; bottom: the rebuilt head through each photo's camera)")


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", type=Path, help="the shared data folder (../shared/data)")
    p.add_argument("--poses", default="0,1,2,3,4", help="FaceWarehouse poses to rebuild")
    p.add_argument("--side-yaw", type=float, default=90.0, help="yaw of the side render (90: a profile)")
    p.add_argument("--sheet", type=Path, help="write the real-photo contact sheet here (PNG)")
    p.add_argument("--skip-truth", action="store_true")
    p.add_argument("--skip-photos", action="store_true")
    p.add_argument("--people", type=int, default=0, help="section 3 with this many sampled ICT identities "
                   "(seeds 300..., held out) and FaceWarehouse tester 1")
    p.add_argument("--seeds", help="section 3 on these ICT seeds instead (e.g. 1000-1009, the tuning set), "
                   "without FaceWarehouse")
    p.add_argument("--cache", type=Path, help="keep each person's renders and detected points here")
    p.add_argument("--shading", type=float, default=0.0, help="section 3: refine fit_identity's weights by the "
                   "shading term with this weight (EXPERIMENT, scripts/photo_shading.py; not in faceanim photo)")
    p.add_argument("--shading-modes", type=int, default=30, help="leading identity modes the shading term moves")
    p.add_argument("--shading-iterations", type=int, default=3, help="rounds of the shading fit")
    p.add_argument("--dense-only", action="store_true", help="section 3: only fit_identity's heads")
    p.add_argument("--warps", help="section 3: compare warps of the identity, comma-separated affine:D or "
                   "sim:D (global fit, deadband D in IOD; inf: no warp), with the texture's alignment")
    args = p.parse_args(argv)
    opts = dict(modes=args.shading_modes, rounds=args.shading_iterations)
    if args.warps:
        if args.seeds:
            lo, _, hi = args.seeds.partition("-")
            seeds, scan = range(int(lo), int(hi or lo) + 1), False
        else:
            seeds, scan = range(300, 300 + args.people), True
        people_warps(args.data, seeds, args.side_yaw, args.warps.split(","), scan, args.cache, args.shading, opts)
    elif args.seeds:
        lo, _, hi = args.seeds.partition("-")
        people(args.data, range(int(lo), int(hi or lo) + 1), args.side_yaw, scan=False, cache=args.cache,
               shading=args.shading, shading_options=opts, dense_only=args.dense_only)
    elif args.people:
        people(args.data, range(300, 300 + args.people), args.side_yaw, cache=args.cache, shading=args.shading,
               shading_options=opts, dense_only=args.dense_only)
    if not args.skip_truth:
        known_truth(args.data, [int(k) for k in args.poses.split(",")], args.side_yaw)
    if not args.skip_photos:
        real_photos(args.data, args.sheet)


if __name__ == "__main__":
    main()
