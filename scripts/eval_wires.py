"""Wire extraction on real expression templates (Pyun, Shin & Shin 2001, section 5).

    python scripts/eval_wires.py ../shared/data/facewarehouse-tester1

For every expression pose_k (same topology as the neutral pose_0), extract the default wires
(eqs. 9-13), rebuild the expression from them, and report |rebuilt - real| / |real - neutral|
over the face region (scans rigidly aligned on the skull), the storage ratio (the template's
vertex coordinates / the wire numbers) and the extraction time. Baselines in the same run: no
motion (1.0) and the paper's wires without the side masks; first, the exact-recovery check on
templates made by known wires.
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from faceanim.deform.wires import extract_wires
from faceanim.face.face import landmarks_478
from faceanim.face.landmarks import detect_landmarks
from faceanim.face.regions import face_region
from faceanim.io.meshio import load_mesh
from faceanim.rig.wires import align_template, default_wires


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", type=Path)
    args = ap.parse_args(argv)
    files = sorted(args.data.glob("pose_*.obj"), key=lambda p: int(p.stem.split("_")[1]))
    if len(files) < 2 or files[0].stem != "pose_0":
        sys.exit(f"{args.data}: expected pose_0.obj (neutral) and pose_1.obj ... (expressions)")
    base = load_mesh(files[0])
    lm = landmarks_478(base, detect_landmarks(base))
    face = face_region(base, lm)
    wireset = default_wires(lm)
    rng = np.random.default_rng(0)

    # exact recovery: templates made by known wires and scales
    bound = wireset.influence(base, lm)
    worst_c = worst_s = 0.0
    for _ in range(5):
        controls = [w.reference.control + rng.normal(scale=0.02 * np.ptp(w.reference.control), size=w.reference.control.shape)
                    for w in wireset.wires]
        scales = rng.uniform(0.7, 1.3, len(wireset.wires))
        got_c, got_s = extract_wires(bound, bound.apply(controls, scales))
        worst_c = max(worst_c, max(np.abs(a - b).max() for a, b in zip(got_c, controls)))
        worst_s = max(worst_s, np.abs(got_s - scales).max())
    print(f"exact recovery (5 templates from known wires): control points {worst_c:.1e}, scales {worst_s:.1e}")

    rows = {"paper (no side masks)": wireset.influence(base), "faceanim (lip and lid wires keep to their side)": bound}
    results = {k: [] for k in rows}
    times, ratio = [], None
    for f in files[1:]:
        template = align_template(base, load_mesh(f), lm)
        real = template.vertices - base.vertices
        for label, b in rows.items():
            t = time.perf_counter()
            c, s = extract_wires(b, template.vertices)
            if label.startswith("faceanim"):
                times.append(time.perf_counter() - t)
            rebuilt = b.apply(c, s)
            results[label].append(np.linalg.norm((rebuilt - template.vertices)[face]) / np.linalg.norm(real[face]))
        ratio = 3 * base.n_vertices / (sum(x.size for x in c) + len(s))
    print(f"\n{args.data}: {len(files) - 1} expressions, {len(wireset.wires)} wires, face region {face.sum()} vertices\n")
    print("| method | median | mean | max |")
    print("|---|---|---|---|")
    print("| neutral (no motion) | 1.000 | 1.000 | 1.000 |")
    for label, e in results.items():
        e = np.asarray(e)
        print(f"| {label} | {np.median(e):.3f} | {e.mean():.3f} | {e.max():.3f} |")
    print("\nper expression (faceanim):")
    print(" ".join(f"{f.stem}:{x:.2f}" for f, x in zip(files[1:], results["faceanim (lip and lid wires keep to their side)"])))
    print(f"\nstorage: {3 * base.n_vertices} template coordinates -> {3 * base.n_vertices / ratio:.0f} wire numbers "
          f"({ratio:.0f}x); extraction {np.median(times) * 1000:.0f} ms median, {max(times) * 1000:.0f} ms max "
          f"on {base.n_vertices} vertices")


if __name__ == "__main__":
    main()
