"""Action-unit rig: binding and posing cost on the 30k-vertex default face.

    .venv/bin/python benchmarks/bench_facs.py

Prints: binding an ExpressionTransfer (placement, regions, the surface or TPS solve), compiling
every AU and emotion to blendshapes, and posing frames from AU weights, against the baseline of
re-solving the warp for each frame (what an implementation without a bound operator does).
"""

import time

import numpy as np

from faceanim.face.default import default_face, default_landmarks
from faceanim.face.face import Face, landmarks_478
from faceanim.rig.transfer import ExpressionTransfer, default_model


def best(f, n=3):
    times = []
    for _ in range(n):
        t = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t)
    return min(times), out


def main():
    face = default_face()
    lm = landmarks_478(face, default_landmarks(face))
    model = default_model()
    print(f"default face: {face.n_vertices} vertices, {len(model.samples)} learned AUs\n")
    print("| step | surface | tps (thesis) |")
    print("|---|---|---|")
    rows = {}
    for method in ("surface", "tps"):
        def bind(method=method):
            return ExpressionTransfer(Face(face, lm), method=method)

        t_bind, xf = best(bind, 2)
        t_rig, rig = best(lambda xf=xf: xf.rig(model, sides=False), 1)
        curves = np.random.default_rng(0).uniform(0, 1, size=(1000, len(rig.names)))
        rig.evaluate(curves[:10])
        t_frames, _ = best(lambda rig=rig, curves=curves: rig.evaluate(curves), 3)
        # baseline: re-solve the warp for one frame (bind + apply)
        t_naive, _ = best(lambda: bind().mixture_delta(model, {12: 0.5}), 1)
        rows[method] = (t_bind, t_rig, len(rig.names), t_frames, t_naive)
    for k, label in enumerate(("bind (place, regions, solve)", "compile blendshapes")):
        print(f"| {label} | " + " | ".join(f"{rows[m][k]:.2f} s" for m in rows) + " |")
    print("| blendshapes | " + " | ".join(str(rows[m][2]) for m in rows) + " |")
    print("| 1000 frames from AU weights | " + " | ".join(
        f"{rows[m][3]:.2f} s ({rows[m][3] * 1000 / 1000:.2f} ms/frame)" for m in rows) + " |")
    print("| re-solve per frame (baseline), 1 frame | " + " | ".join(f"{rows[m][4]:.2f} s" for m in rows) + " |")
    print("| speed-up of the bound rig | " + " | ".join(
        f"{rows[m][4] / (rows[m][3] / 1000):.0f}x" for m in rows) + " |")


if __name__ == "__main__":
    main()
