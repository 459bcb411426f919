"""The seamless head texture (faceanim.build.texture): accuracy, seams and speed.

    .venv/bin/python benchmarks/bench_texture.py [--out DIR] [--size 1024]

1. FaceWarehouse oracle (needs ../shared/data and MediaPipe). The neutral scan gets a true
   texture in its own UVs: its photo projected onto it (camera fitted on MediaPipe landmarks of
   a render of the scan and of the photo). The textured scan is rendered from the front and both
   sides, once unlit (albedo: :func:`faceanim.render.bake.ortho_render`) and once with the
   project's renderer (lit: every view lit differently, like real photos), with exact cameras
   (:func:`faceanim.build.texture.view_camera`). Those renders are baked into our atlas, the
   re-textured scan is rendered from yaw 45 and compared with the scan (mean absolute RGB error
   over the front half of the head, 0..255), and the colour step across the merge lines is
   measured with the pyramid blend and with the hard split.
2. The generic head (faceanim.face.generic_head: the ICT head, 24.6k vertices with eyes,
   teeth, gums): atlas and bake times from three 1024 x 1024 renders, the seam step.

Pictures go to --out (default: a temporary folder): atlases, the split, the yaw-45 comparisons.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from PIL import Image

from faceanim.build import texture as tx
from faceanim.build.camera import ViewCamera
from faceanim.face.mesh import Mesh
from faceanim.io.meshio import load_mesh
from faceanim.render import OffscreenRenderer
from faceanim.render.bake import ortho_depth, ortho_render

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
SPLIT_COLOURS = np.array([[0, 0, 0], [220, 60, 60], [60, 200, 60], [60, 60, 220], [220, 200, 40], [40, 200, 220]],
                         dtype=np.uint8)


def save(path: Path, image: np.ndarray) -> None:
    Image.fromarray(np.ascontiguousarray(image)).save(path)
    print(f"  wrote {path}")


def fit_camera(points, pixels, size) -> ViewCamera:
    a = np.c_[points, np.ones(len(points))]
    sol = np.linalg.lstsq(a, pixels, rcond=None)[0]
    m = sol[:3].T * np.array([[1.0], [-1.0]])
    scale = float(np.linalg.norm(m, axis=1).mean())
    u, _, vt = np.linalg.svd(m / scale, full_matrices=False)
    r2 = u @ vt
    rot = np.vstack([r2, np.cross(r2[0], r2[1])])
    offset = pixels.mean(0) - scale * np.array([1.0, -1.0]) * (points.mean(0) @ rot.T)[:2]
    return ViewCamera(rot, scale, offset, size)


def unlit(mesh: Mesh, cam: ViewCamera) -> np.ndarray:
    return ortho_render(mesh.vertices, mesh.faces, mesh.uv[mesh.face_uv], mesh.texture, cam.matrix, cam.offset,
                        cam.direction, cam.size)


def front_half(mesh: Mesh, cam: ViewCamera) -> np.ndarray:
    depth = ortho_depth(mesh.vertices, mesh.faces, cam.matrix, cam.offset, cam.direction, cam.size)
    ys, xs = np.mgrid[0:cam.size[1], 0:cam.size[0]] + 0.5
    hit = depth > -np.inf
    pts = np.stack([(xs[hit] - cam.offset[0]) / cam.scale, -(ys[hit] - cam.offset[1]) / cam.scale, depth[hit]],
                   1) @ cam.rotation
    z = mesh.vertices[:, 2]
    mask = np.zeros(hit.shape, dtype=bool)
    mask[hit] = pts[:, 2] > (z.min() + z.max()) / 2
    return mask


def facewarehouse(out: Path, size: int) -> None:
    from faceanim.face.landmarks import detect_landmarks, detect_landmarks_in_image

    folder = DATA / "facewarehouse-tester1"
    if not folder.exists():
        print(f"FaceWarehouse: {folder} missing, skipped")
        return
    scan = load_mesh(folder / "pose_0.obj")
    photo = np.asarray(Image.open(folder / "pose_0.png").convert("RGB"))
    h, w = photo.shape[:2]
    marks = detect_landmarks(scan)
    pixels = detect_landmarks_in_image(photo)[:, :2] * [w, h]
    cam = fit_camera(marks.positions, pixels, (w, h))
    parts = {"skin": np.arange(scan.n_vertices)}
    truth = tx.bake_texture(scan.vertices, scan.faces, scan.uv, scan.face_uv, parts, [tx.BakeView(photo, cam)],
                            size=1024)
    scan = Mesh(scan.vertices, scan.faces, scan.uv, scan.face_uv, truth)
    save(out / "fw_truth_texture.png", truth)

    t0 = time.perf_counter()
    uv, face_uv = tx.atlas_uv(scan.vertices, scan.faces, parts)
    t_atlas = time.perf_counter() - t0
    views = {"unlit": [], "lit": []}
    for yaw in (0, 90, -90):
        with OffscreenRenderer(scan, (512, 512), yaw=yaw, parallel=True) as r:
            c = tx.view_camera(r)
            views["lit"].append(tx.BakeView(r.render(), c))
        views["unlit"].append(tx.BakeView(unlit(scan, c), c))
    save(out / "fw_photos.png", np.vstack([np.hstack([v.image for v in views[k]]) for k in ("unlit", "lit")]))
    with OffscreenRenderer(scan, (512, 512), yaw=45, parallel=True) as r:
        cam45 = tx.view_camera(r)
        lit45 = r.render()
    face = front_half(scan, cam45)
    ref = unlit(scan, cam45).astype(float)
    print(f"FaceWarehouse scan ({scan.n_vertices} vertices), photos 512 x 512, atlas {size} x {size}; "
          f"atlas_uv {t_atlas:.2f} s")
    print("  photos  blend    bake s  seam step  error@yaw45 (unlit)  error@yaw45 (lit, both lit)")
    for kind in ("unlit", "lit"):
        for blend in ("pyramid", "none"):
            t0 = time.perf_counter()
            b = tx.bake(scan.vertices, scan.faces, uv, face_uv, parts, views[kind], size=size, blend=blend)
            t_bake = time.perf_counter() - t0
            again = Mesh(scan.vertices, scan.faces, uv, face_uv, b.texture)
            got = unlit(again, cam45).astype(float)
            with OffscreenRenderer(again, (512, 512), yaw=45, parallel=True) as r:
                got_lit = r.render().astype(float)
            e_unlit = np.abs(got - ref)[face].mean()
            e_lit = np.abs(got_lit - lit45)[face].mean()
            print(f"  {kind:6s}  {blend:7s}  {t_bake:6.2f}  {tx.seam_step(b.texture, b.split):9.2f}  "
                  f"{e_unlit:19.2f}  {e_lit:27.2f}")
            save(out / f"fw_atlas_{kind}_{blend}.png", b.texture)
            save(out / f"fw_yaw45_{kind}_{blend}.png",
                 np.hstack([ref, got, lit45, got_lit]).astype(np.uint8))
    save(out / "fw_split.png", SPLIT_COLOURS[(b.split + 1) % len(SPLIT_COLOURS)])
    print("  sources:", b.sources)


def ict(out: Path, size: int) -> None:
    from faceanim.face.generic_head import generic_head

    gh = generic_head()
    v, f, parts = gh.mesh.vertices, gh.mesh.faces, gh.parts
    head = Mesh(v, f)
    views = []
    for yaw in (0, 90, -90):
        with OffscreenRenderer(head, (1024, 1024), yaw=yaw, parallel=True) as r:
            views.append(tx.BakeView(r.render(), tx.view_camera(r)))
    t0 = time.perf_counter()
    uv, face_uv = tx.atlas_uv(v, f, parts)
    t_atlas = time.perf_counter() - t0
    print(f"generic head ({len(v)} vertices, {len(f)} triangles), three 1024 x 1024 photos, atlas {size} x {size}: "
          f"atlas_uv {t_atlas:.2f} s")
    for blend in ("none", "pyramid"):  # the pyramid's atlas is rendered below
        best = None
        for _ in range(2):
            t0 = time.perf_counter()
            b = tx.bake(v, f, uv, face_uv, parts, views, size=size, blend=blend)
            el = time.perf_counter() - t0
            best = el if best is None else min(best, el)
        steps = ", ".join(f"{k} {s:.2f}" for k, s in b.seconds.items())
        print(f"  {blend:7s}: bake {best:.2f} s ({steps}); seam step {tx.seam_step(b.texture, b.split):.2f}")
        save(out / f"ict_atlas_{blend}.png", b.texture)
    textured = Mesh(v, f, uv, face_uv, b.texture)
    shots = []
    for yaw in (0, 45, 160):
        with OffscreenRenderer(textured, (512, 512), yaw=yaw, parallel=True) as r:
            shots.append(r.render())
    save(out / "ict_renders.png", np.hstack(shots))
    save(out / "ict_split.png", SPLIT_COLOURS[(b.split + 1) % len(SPLIT_COLOURS)])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--size", type=int, default=1024)
    args = ap.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="bench_texture_"))
    out.mkdir(parents=True, exist_ok=True)
    facewarehouse(out, args.size)
    ict(out, args.size)


if __name__ == "__main__":
    main()
