"""Deformation speed and memory: faceanim's bound operators against refitting scipy per frame.

Run:  .venv/bin/python benchmarks/bench_deform.py          (about two minutes on 2 cores)

Prints three tables:
1. 100k-vertex face, 60 handles: one frame and 1,000 frames, for the baseline (scipy's
   RBFInterpolator refitted every frame, the obvious way) and for faceanim's global RBF
   (float64 and float32) and a rig of 60 geometry deformation elements (sparse), with the
   speed-up over the baseline measured in the same run and the error against scipy.
2. Binding one GDE on the 30k-vertex default face.
3. Global RBF binding, per-frame cost and operator memory over vertex and handle counts.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from scipy.interpolate import RBFInterpolator
from trimesh.remesh import subdivide_loop

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from faceanim.deform import (
    GeometryDeformationElement,
    bind_gdes,
    bind_rbf,
    element_influence,
)
from faceanim.face.default import default_face
from faceanim.face.mesh import Mesh


def best(fn, repeat=7, number=1, warmup=0.05):
    """Best mean time of ``number`` calls over ``repeat`` runs (seconds).

    Calls ``fn`` for ``warmup`` seconds first: right after a large solve, OpenBLAS's worker
    threads were seen to slow small products 10-20x for a short while, which is not the
    steady state of an animation loop.
    """
    end = time.perf_counter() + warmup
    while time.perf_counter() < end:
        fn()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        for _ in range(number):
            fn()
        times.append((time.perf_counter() - t) / number)
    return min(times)


def face_with(levels: int) -> Mesh:
    base = default_face(dense=False)
    v, f = subdivide_loop(base.vertices, base.faces, levels) if levels else (base.vertices, base.faces)
    return Mesh(v, f, name=f"face_l{levels}")


def table(rows, header):
    widths = [max(len(str(r[i])) for r in rows + [header]) for i in range(len(header))]
    line = "  ".join(h.ljust(w) for h, w in zip(header, widths))
    print(line)
    print("-" * len(line))
    for r in rows:
        print("  ".join(str(c).ljust(w) for c, w in zip(r, widths)))
    print()


def ms(s):
    return f"{s * 1e3:.2f} ms"


def main():
    rng = np.random.default_rng(0)
    mesh = face_with(4)  # ~118k vertices
    V = mesh.n_vertices
    H = 60
    handles = mesh.vertices[rng.choice(V, H, replace=False)]
    frames = rng.normal(scale=0.002, size=(1000, H, 3))
    print(f"# 1. {V} vertices, {H} handles (thin-plate spline, no smoothing)\n")

    def scipy_frame(k=0):
        return RBFInterpolator(handles, frames[k], kernel="thin_plate_spline")(mesh.vertices)

    base = best(scipy_frame, repeat=3, warmup=0)
    ref = scipy_frame(0)

    d64 = bind_rbf(mesh.vertices, handles, "thin_plate_spline", smoothing=0.0)
    d32 = d64.astype(np.float32)
    err64 = np.abs(d64.displacements(frames[0]) - ref).max() / np.abs(ref).max()
    err32 = np.abs(d32.displacements(frames[0]) - ref).max() / np.abs(ref).max()

    # a rig of 60 GDEs: Euclidean extent 1.5 cm, spread over the face
    centres = mesh.vertices[rng.choice(V, H, replace=False)]
    gdes = [GeometryDeformationElement(tuple(c), 0.015, "euclidean") for c in centres]
    t = time.perf_counter()
    rig = bind_gdes(mesh, gdes)
    t_rig_bind = time.perf_counter() - t
    rig32 = rig.astype(np.float32)

    rows = []
    rows.append(["scipy RBFInterpolator refit/frame", ms(base), f"{base * 1000:.1f} s (est.)", "1x", "-", "-"])
    for name, d, err in [("faceanim RBF dense float64", d64, f"{err64:.1e}"),
                         ("faceanim RBF dense float32", d32, f"{err32:.1e}"),
                         ("faceanim 60 GDEs sparse float64", rig, "n/a"),
                         ("faceanim 60 GDEs sparse float32", rig32, "n/a")]:
        off = frames[0].astype(d.dtype)
        one = best(lambda d=d, off=off: d.apply(off), repeat=20)
        many_off = frames.astype(d.dtype)
        many = best(lambda d=d, many_off=many_off: d.apply(many_off), repeat=3, warmup=0)
        rows.append([name, ms(one), f"{many:.3f} s", f"{base / one:.0f}x", err, f"{d.nbytes() / 2**20:.1f} MiB"])
    table(rows, ["method", "1 frame", "1000 frames", "speed-up/frame", "max rel err vs scipy", "operator"])
    print(f"GDE rig: {len(rig.moving_vertices)} of {V} vertices can move; "
          f"binding 60 GDEs took {t_rig_bind * 1e3:.0f} ms\n")

    print("# 2. binding one GDE on the default face\n")
    face = default_face()
    lm_ids = [61, 291, 152, 105, 334, 1, 14, 50]
    rows = []
    for metric, extent in [("edges", 4), ("edges", 10), ("euclidean", 0.01), ("euclidean", 0.025)]:
        for_each = []
        sizes = []
        for i in lm_ids:
            e = GeometryDeformationElement(tuple(face.vertices[i]), extent, metric)
            element_influence(face, e)  # warm caches (adjacency, k-d tree) as a rig would
            for_each.append(best(lambda: element_influence(face, e), repeat=5))
            sizes.append(element_influence(face, e).region.size)
        rows.append([f"{metric} {extent}", f"{face.n_vertices}", f"{int(np.mean(sizes))}",
                     ms(float(np.median(for_each))), ms(float(np.max(for_each)))])
    table(rows, ["metric/extent", "vertices", "region (mean)", "bind (median)", "bind (max)"])

    print("# 3. global RBF (multiquadric, eq. 3 stiffness) over sizes: bind, one frame, memory\n")
    rows = []
    for n in [1_000, 10_000, 100_000, 1_000_000]:
        pts = rng.uniform(-0.1, 0.1, size=(n, 3))
        for h in [10, 60, 200]:
            hd = pts[rng.choice(n, h, replace=False)]
            t = time.perf_counter()
            d = bind_rbf(pts, hd, "multiquadric", dtype=np.float32)
            tb = time.perf_counter() - t
            off = rng.normal(scale=1e-3, size=(h, 3)).astype(np.float32)
            one = best(lambda d=d, off=off: d.apply(off), repeat=5)
            rows.append([f"{n:,}", h, ms(tb), ms(one), f"{d.nbytes() / 2**20:.1f} MiB"])
    table(rows, ["vertices", "handles", "bind", "1 frame (float32)", "operator"])


if __name__ == "__main__":
    main()
