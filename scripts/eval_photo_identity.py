"""Are the photos one person? Both checks of ``faceanim photo``, measured on every front/side pair.

Fronts: the multi-view man's front photo, scikit-image's astronaut, FaceWarehouse tester 1's
textured scan rendered from the front, and the most frontal frame of each of the six talking-head
videos. Sides: the man's two three-quarter photos, the scan rendered at +-30 degrees, and the
frames of the videos whose head turns most to either side (d3 and d9 turn 15-24 degrees; the
others hardly turn and give no side view). Every front goes with every side; a pair whose side is
not turned at least ``MIN_SIDE_TURN`` from its front is not a front/side pair and is left out.

For each pair: the geometric check (``check_views``: the head rebuilt from both views must agree
with each), the face-recognition distance (``identity``) and whether each check refuses it.
Nothing here was used to choose a threshold (the geometric one was set on the first 14 pairs of
another person's front with the man's sides; the identity one is dlib's own).

Usage: ``python scripts/eval_photo_identity.py ../shared/data``
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from faceanim.build.identity import MAX_TURN, SAME_PERSON, view_descriptor  # noqa: E402
from faceanim.build.photo import (  # noqa: E402
    MIN_SIDE_TURN,
    check_views,
    detect_view,
    prior_points,
    read_photo,
    reconstruct,
)
from faceanim.errors import LandmarkError  # noqa: E402
from faceanim.face.generic_head import generic_head  # noqa: E402

VIDEOS = ("d0", "d3", "d9", "d10", "d14", "d18")


def frames(video: Path) -> list[np.ndarray]:
    import cv2

    cap = cv2.VideoCapture(str(video))
    out = []
    while True:
        ok, f = cap.read()
        if not ok:
            break
        out.append(np.ascontiguousarray(f[:, :, ::-1]))
    return out


def yaw_of(view, prior, normals) -> float:
    return reconstruct([view], prior, normals).cameras[0].yaw_degrees


def render(mesh, yaw: float) -> np.ndarray:
    from faceanim.render import OffscreenRenderer

    with OffscreenRenderer(mesh, size=(512, 512), yaw=yaw, parallel=True, background=(0.5, 0.5, 0.5)) as r:
        return r.render()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", type=Path)
    ap.add_argument("--step", type=int, default=10, help="every n-th video frame is looked at for its turn")
    args = ap.parse_args()
    head = generic_head()
    prior, normals = prior_points(head)
    fronts, sides = [], []  # (person, name, view)
    mv = args.data / "multiview-photos"
    fronts.append(("man", "multiview front", detect_view(read_photo(mv / "front.jpg"), "front.jpg", "front")))
    for n in ("left", "right"):
        sides.append(("man", f"multiview {n}", detect_view(read_photo(mv / f"{n}.jpg"), f"{n}.jpg", "side")))
    from skimage import data as skdata

    fronts.append(("astronaut", "astronaut", detect_view(skdata.astronaut(), "astronaut", "front")))
    from faceanim.io.meshio import load_mesh

    scan = load_mesh(args.data / "facewarehouse-tester1" / "pose_0.obj")
    fronts.append(("facewarehouse", "FaceWarehouse 1 render 0", detect_view(render(scan, 0.0), "fw0", "front")))
    for yaw in (-30.0, 30.0):
        sides.append(("facewarehouse", f"FaceWarehouse 1 render {yaw:+.0f}",
                      detect_view(render(scan, yaw), f"fw{yaw:+.0f}", "side")))
    for v in VIDEOS:
        looked = []
        for k, f in enumerate(frames(args.data / "talking-head-videos" / f"{v}.mp4")):
            if k % args.step:
                continue
            try:
                view = detect_view(f, f"{v}#{k}", "front")
            except LandmarkError:
                continue
            looked.append((yaw_of(view, prior, normals), k, view))
        looked.sort(key=lambda t: t[0])
        yaw0, k0, front = min(looked, key=lambda t: abs(t[0]))
        fronts.append((v, f"{v} frame {k0} ({yaw0:+.0f} deg)", front))
        for yaw, k, view in (looked[0], looked[-1]):
            if abs(yaw - yaw0) >= MIN_SIDE_TURN:
                view.role = "side"
                sides.append((v, f"{v} frame {k} ({yaw:+.0f} deg)", view))
    descriptors = {}

    def descriptor(name, view):
        if name not in descriptors:
            descriptors[name] = view_descriptor(view)
        return descriptors[name]

    rows = []
    for fp, fname, front in fronts:
        for sp, sname, side in sides:
            rec = reconstruct([front, side], prior, normals)
            turn = rec.cameras[1].yaw_degrees - rec.cameras[0].yaw_degrees
            if abs(turn) < MIN_SIDE_TURN:
                continue
            try:
                check_views([front, side], rec)
                geometric = False
            except LandmarkError:
                geometric = True
            med = float(np.median(rec.errors[1]))
            d = None
            if abs(turn) <= MAX_TURN:
                a, b = descriptor(fname, front), descriptor(sname, side)
                if a is not None and b is not None:
                    d = float(np.linalg.norm(a - b))
            rows.append((fp == sp, fname, sname, turn, med, geometric, d, d is not None and d > SAME_PERSON))
    print("| same person | front | side | turn (deg) | reprojection (IOD) | geometric refuses | descriptor distance "
          "| identity refuses |")
    print("|---|---|---|---|---|---|---|---|")
    for same, fname, sname, turn, med, geo, d, ide in sorted(rows, key=lambda r: (not r[0], r[1], r[2])):
        print(f"| {'yes' if same else 'no'} | {fname} | {sname} | {turn:+.0f} | {med:.3f} | {'yes' if geo else 'no'} | "
              f"{'-' if d is None else f'{d:.2f}'} | {'yes' if ide else 'no'} |")
    same = [r for r in rows if r[0]]
    other = [r for r in rows if not r[0]]
    print()
    print(f"one person's pairs: {len(same)}; refused by geometry {sum(r[5] for r in same)}, by identity "
          f"{sum(r[7] for r in same)}, by either {sum(r[5] or r[7] for r in same)}; distances "
          f"{min((r[6] for r in same if r[6] is not None), default=float('nan')):.2f}-"
          f"{max((r[6] for r in same if r[6] is not None), default=float('nan')):.2f}")
    print(f"two people's pairs: {len(other)}; refused by geometry {sum(r[5] for r in other)}, by identity "
          f"{sum(r[7] for r in other)}, by either {sum(r[5] or r[7] for r in other)}; distances "
          f"{min((r[6] for r in other if r[6] is not None), default=float('nan')):.2f}-"
          f"{max((r[6] for r in other if r[6] is not None), default=float('nan')):.2f}")


if __name__ == "__main__":
    main()
