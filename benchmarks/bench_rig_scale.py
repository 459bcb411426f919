"""Rigging from 2,000 to 400,000 vertices: time and memory of `faceanim rig` (every set) per mesh size.

    .venv/bin/python benchmarks/bench_rig_scale.py ../shared/data [--blas-threads N]   (about 10 minutes)

needs ``fast-simplification`` (``.venv/bin/pip install -e '.[eval]'``).

One real surface at every size: FaceWarehouse tester 1's neutral scan (11,510 vertices) decimated
to 2,000 (fast-simplification), as it is, subdivided once and twice (every triangle split in four:
45,822 and 183,078 vertices, the same surface), and subdivided three times then decimated to
400,000. Each size runs in a fresh process (cold: imports, MediaPipe's models, every cache
empty), as a user's `faceanim rig` does, stage by stage:

- load + landmarks: read the OBJ, render, detect, cast the rays, check it is a face;
- registration: the morphable head fitted and moved onto the surface, the correspondence;
- each set as `auto_rig` makes it (arkit includes the registration's first use);
- peak: the process's peak resident memory (``ru_maxrss``: everything, C libraries included).

The last two columns are the time and memory each 100,000 vertices add beyond the smallest mesh
(whose run is mostly fixed cost: imports, MediaPipe's models, the morphable head): equal down the
column is linear. There is no outside baseline for making 200 shapes on an arbitrary mesh; the
cost of reading and detecting (which any tool pays) is the first column.

Timings on a shared machine are noisy; nothing here is asserted.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

from _timing import arguments, header, table

ROOT = Path(__file__).resolve().parents[1]

WORKER = r"""
import json, resource, sys, time
sys.path.insert(0, sys.argv[2])
t0 = time.perf_counter()
from faceanim.autorig import auto_rig
from faceanim.face.face import Face
t = time.perf_counter()
face = Face.load(sys.argv[1])
stages = {"imports": t - t0, "load + landmarks": time.perf_counter() - t}
t = time.perf_counter()
face.correspondence
stages["registration"] = time.perf_counter() - t
marks = []
def progress(name):
    marks.append((name, time.perf_counter()))
t = time.perf_counter()
rig = auto_rig(face, progress=progress)
end = time.perf_counter()
for (name, a), (_, b) in zip(marks, marks[1:] + [("end", end)]):
    stages[name] = b - a
stages["total"] = end - t0
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps({"vertices": face.mesh.n_vertices, "shapes": len(rig.shapes), "stages": stages, "peak": peak}))
"""


def meshes(data: Path, out: Path) -> list[Path]:
    import fast_simplification
    import numpy as np
    import trimesh

    sys.path.insert(0, str(ROOT / "src"))
    from faceanim.io.meshio import load_mesh

    scan = load_mesh(data / "facewarehouse-tester1" / "pose_0.obj")
    base = trimesh.Trimesh(scan.vertices, scan.faces, process=False)

    def decimated(m, count):
        v, f = fast_simplification.simplify(np.asarray(m.vertices, np.float32), np.asarray(m.faces),
                                            target_reduction=1.0 - count / len(m.vertices))
        return trimesh.Trimesh(np.asarray(v, np.float64), f, process=False)

    sub1 = base.subdivide()
    sub2 = sub1.subdivide()
    made = {"2k": decimated(base, 2000), "scan": base, "sub1": sub1, "sub2": sub2,
            "400k": decimated(sub2.subdivide(), 400_000)}
    paths = []
    for name, m in made.items():
        p = out / f"fw_{name}.obj"
        m.export(p)
        paths.append(p)
    return paths


def main() -> None:
    args = arguments(__doc__, "the shared data folder (../shared/data)")
    data = args.data or ROOT.parent / "shared" / "data"
    header("faceanim rig, every set, per mesh size (FaceWarehouse tester 1 decimated and subdivided)")
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for path in meshes(data, Path(tmp)):
            env_cmd = [sys.executable, "-c", WORKER, str(path), str(ROOT / "src")]
            if args.blas_threads:
                import os

                env = dict(os.environ, OPENBLAS_NUM_THREADS=str(args.blas_threads))
            else:
                env = None
            run = subprocess.run(env_cmd, capture_output=True, text=True, env=env)
            if run.returncode != 0:
                print(f"{path.name}: failed ({run.stderr.strip().splitlines()[-1:]})")
                continue
            r = json.loads(run.stdout.strip().splitlines()[-1])
            results.append(r)
            print(f"{r['vertices']:,} vertices: {r['stages']['total']:.1f} s, peak {r['peak'] / 2**30:.2f} GiB", flush=True)
    stages = ["load + landmarks", "registration", "arkit", "visemes", "au", "emotions", "fap"]
    small = min(results, key=lambda r: r["vertices"])
    rows = []
    for r in results:
        s = r["stages"]
        extra = (r["vertices"] - small["vertices"]) / 1e5
        marginal = ((f"{(s['total'] - small['stages']['total']) / extra:.1f}",
                     f"{(r['peak'] - small['peak']) / 2**30 / extra:.2f}") if extra > 0 else ("-", "-"))
        rows.append([f"{r['vertices']:,}"] + [f"{s.get(k, 0.0):.1f}" for k in stages]
                    + [f"{s['total']:.1f}", f"{r['peak'] / 2**30:.2f}", *marginal])
    print()
    table(rows, ["vertices"] + [f"{k} s" for k in stages] + ["total s", "peak GiB", "s per 100k above the smallest",
                                                              "GiB per 100k above the smallest"])
    print("\ntotal includes imports (2-3 s); registration is timed on its own, so arkit is the rest of that set; "
          "the last two columns are the cost of the vertices beyond the smallest mesh's (equal down the column: "
          "linear)")


if __name__ == "__main__":
    main()
