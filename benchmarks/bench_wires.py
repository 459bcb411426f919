"""Wire deformation speed on the 30k-vertex default face, and extraction time.

    .venv/bin/python benchmarks/bench_wires.py [../shared/data/facewarehouse-tester1]

Per frame after binding (the bound sparse operator, one product per frame) against the naive
per-frame evaluation that finds every vertex's closest point on every reference curve again
(what a wire deformer without binding does), measured in the same run. With the FaceWarehouse
folder, also the extraction time of one template on its 11.5k-vertex head.
"""

import sys
import time

import numpy as np

from faceanim.deform.wires import extract_wires, wire_influence
from faceanim.face.default import default_face, default_landmarks
from faceanim.face.face import landmarks_478
from faceanim.rig.wires import default_wires


def best(fn, repeat=5):
    fn()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def main():
    face = default_face()
    lm = landmarks_478(face, default_landmarks(face))
    wireset = default_wires(lm)
    rng = np.random.default_rng(0)
    t_bind = best(lambda: wireset.influence(face, lm), 3)
    bound = wireset.influence(face, lm)
    op = bound.deformer(np.float32)
    frames = np.stack([bound.offsets([w.reference.control + rng.normal(scale=1e-3, size=w.reference.control.shape)
                                      for w in wireset.wires], rng.uniform(0.9, 1.1, len(wireset.wires)))
                       for _ in range(1000)]).astype(np.float32)
    op.apply(frames[:10])
    t_frame = best(lambda: op.apply(frames[0]), 20)
    t_1000 = best(lambda: op.apply(frames), 3)
    naive = best(lambda: wire_influence(face.vertices, wireset.wires, wireset.k).apply(), 2)
    print(f"default face: {face.n_vertices} vertices, {len(wireset.wires)} wires, {op.n_handles} handles, "
          f"{op.rows.size if op.rows is not None else face.n_vertices} vertices in range\n")
    print("| step | time |")
    print("|---|---|")
    print(f"| bind (closest points, falloffs, side masks) | {t_bind * 1000:.0f} ms |")
    print(f"| 1 frame, bound operator (float32) | {t_frame * 1000:.2f} ms |")
    print(f"| 1000 frames, bound operator | {t_1000:.2f} s ({t_1000:.2f} ms/frame) |")
    print(f"| 1 frame, naive (closest points every frame) | {naive * 1000:.0f} ms |")
    print(f"| speed-up | {naive / t_frame:.0f}x |")
    if len(sys.argv) > 1:
        from pathlib import Path

        from faceanim.face.landmarks import detect_landmarks
        from faceanim.io.meshio import load_mesh
        from faceanim.rig.wires import align_template

        data = Path(sys.argv[1])
        base = load_mesh(data / "pose_0.obj")
        blm = landmarks_478(base, detect_landmarks(base))
        b = default_wires(blm).influence(base, blm)
        template = align_template(base, load_mesh(data / "pose_2.obj"), blm)
        t_ex = best(lambda: extract_wires(b, template.vertices), 5)
        print(f"| extract one template, {base.n_vertices}-vertex FaceWarehouse head | {t_ex * 1000:.0f} ms |")


if __name__ == "__main__":
    main()
