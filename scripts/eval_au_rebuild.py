"""Rebuild real expressions from the neutral scan with control-point displacements only.

    python scripts/eval_au_rebuild.py ../shared/data/facewarehouse-tester1 [--landmark-learning]
    python scripts/eval_au_rebuild.py ../shared/data/ict-facekit


The thesis' own test (Erdogdu 2010, ch. 6): for each expressive scan pose_k of one person,
learn the displacements of the control points from (pose_0, pose_k), warp pose_0 with them,
and compare with the real scan. Error over the face region (inside the landmark face oval):
|rebuilt - real| / |real - neutral| (Frobenius norms, scans rigidly aligned on the skull).
Works on any folder of pose_0.obj .. pose_N.obj scans of one person in one topology, and on
a folder of blendshapes beside a neutral mesh (ICT: generic_neutral_mesh.obj + *.obj).
"""

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from faceanim.deform.rbf import RadialBasis
from faceanim.deform.surface import bind_surface
from faceanim.face.face import Face, landmarks_478
from faceanim.face.frame import face_frame, rigid_align
from faceanim.face.landmarks import BASIC22, detect_landmarks
from faceanim.face.regions import face_region
from faceanim.io.meshio import load_mesh
from faceanim.rig.facs import default_library
from faceanim.rig.transfer import (
    ExpressionTransfer,
    learn_expression,
    points_on_landmarks,
    skull_vertices,
)


def farthest_points(points, n, start):
    d = np.min(np.linalg.norm(points[:, None] - start[None], axis=2), axis=1)
    out = []
    for _ in range(n):
        i = int(d.argmax())
        out.append(i)
        d = np.minimum(d, np.linalg.norm(points - points[i], axis=1))
    return np.array(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", type=Path)
    ap.add_argument("--landmark-learning", action="store_true",
                    help="also learn without correspondences (landmarks detected on every scan, TPS + snapping)")
    args = ap.parse_args(argv)
    files = sorted(args.data.glob("pose_*.obj"), key=lambda p: int(p.stem.split("_")[1]))
    if (args.data / "generic_neutral_mesh.obj").exists():
        files = [args.data / "generic_neutral_mesh.obj"] + sorted(
            p for p in args.data.glob("*.obj") if p.name != "generic_neutral_mesh.obj")
    elif len(files) < 2 or files[0].stem != "pose_0":
        sys.exit(f"{args.data}: expected pose_0.obj (neutral) and pose_1.obj ... (expressions), "
                 "or generic_neutral_mesh.obj and blendshapes")
    t0 = time.time()
    meshes = [load_mesh(f) for f in files]
    neutral = meshes[0]
    lm = landmarks_478(neutral, detect_landmarks(neutral))
    frame = face_frame(lm)
    lib = default_library()
    stable = skull_vertices(neutral, lm, frame)
    aligned = []
    for m in meshes:
        r, t = rigid_align(m.vertices[stable], neutral.vertices[stable])
        aligned.append(m.vertices @ r.T + t)
    v0 = aligned[0]
    face = face_region(neutral, lm, frame)
    fidx = np.flatnonzero(face)
    real = [a - v0 for a in aligned[1:]]

    def err(delta, k):
        return np.linalg.norm((delta - real[k])[fidx]) / np.linalg.norm(real[k][fidx])

    rows = {}
    rows["neutral (no motion)"] = (0, [1.0] * len(real))
    # global TPS on the basic 22 landmarks (followed through their triangles)
    ids = [i for _, i in BASIC22]
    pos, _, tri = neutral.closest_points(lm[ids])
    bary = neutral.barycentric(pos, tri)
    w = RadialBasis(pos, "thin_plate_spline", smoothing=0.0).weights(v0)
    rows["global TPS, 22 landmarks"] = (22, [err(w @ (np.einsum("nk,nkd->nd", bary, a[neutral.faces[tri]]) - pos), k)
                                             for k, a in enumerate(aligned[1:])])
    # uniform placement: farthest-point samples on the face + fixed anchors on the face border
    border = np.flatnonzero(face & ((neutral.adjacency @ (~face).astype(float)) > 0))
    anchors = border[farthest_points(v0[border], 40, v0[border][:1])]
    for n in (60, 120, 240):
        sel = fidx[farthest_points(v0[fidx], n, v0[anchors])]
        h = np.concatenate([sel, anchors])
        w = RadialBasis(v0[h], "thin_plate_spline", smoothing=0.0).weights(v0)[:, :n]
        rows[f"uniform {n} + border anchors, TPS"] = (n, [err(w @ (a[sel] - v0[sel]), k) for k, a in enumerate(aligned[1:])])
        vt = neutral.vertex_triangle
        b = (neutral.faces[vt[h]] == h[:, None]).astype(float)
        op = bind_surface(v0, neutral.faces, vt[h], b, None)
        rows[f"uniform {n} + border anchors, surface"] = (n, [
            err(op.displacements(np.vstack([a[sel] - v0[sel], np.zeros((len(anchors), 3))])), k)
            for k, a in enumerate(aligned[1:])])
    # anatomical control points from the AU library
    aus = lib.parse_action_units("all")
    samples = [learn_expression(neutral, m, lm, library=lib) for m in meshes[1:]]
    for method, label in (("tps", "thesis: AU points, TPS per face half"), ("surface", "faceanim: AU points, surface")):
        xf = ExpressionTransfer(Face(neutral, lm), lib, method=method)
        rows[label] = (len(xf.points.names), [err(xf.points_delta(s, aus), k) for k, s in enumerate(samples)])
    # the curve: fewer points (the thesis' eight AUs) and more (the 60 plus uniform fill)
    eight = lib.parse_action_units("1,2,4,12,14,15,17,20")
    xf = ExpressionTransfer(Face(neutral, lm), lib, method="surface")
    keep = sorted({p for a in eight for p in lib.action_unit(a).points} & set(xf.points.names))
    sub = ExpressionTransfer(Face(neutral, lm), lib, method="surface", names=keep)
    rows["faceanim: the thesis' 8 AUs' points, surface"] = (len(keep), [
        err(sub.points_delta(s, eight), k) for k, s in enumerate(samples)])
    cp = xf.points
    for n in (120, 240):
        extra = fidx[farthest_points(v0[fidx], n - len(cp.names), cp.positions)]
        vt = neutral.vertex_triangle
        tri = np.concatenate([cp.triangles, vt[extra]])
        bary = np.concatenate([cp.barycentric, (neutral.faces[vt[extra]] == extra[:, None]).astype(float)])
        op = bind_surface(v0, neutral.faces, tri, bary, xf.free)
        rows[f"faceanim: AU points + uniform fill to {n}, surface"] = (n, [
            err(op.displacements(np.vstack([xf.offsets(s), a[extra] - v0[extra]])), k)
            for k, (s, a) in enumerate(zip(samples, aligned[1:]))])
    # the thesis' learning without correspondences (5.5.3): landmark TPS + snapping, with the
    # expressive scans' landmarks as if marked by hand (the neutral ones followed onto the scan)
    # and, with --landmark-learning, as detected on every scan
    modes = [("hand-marked", lambda m: points_on_landmarks(m, neutral, lm))]
    if args.landmark_learning:
        modes.append(("detected on each scan", lambda m: landmarks_478(m, detect_landmarks(m))))
    for label, landmarks_of in modes:
        errs = [err(xf.points_delta(learn_expression(neutral, m, lm, landmarks_of(m), lib, method="landmarks"),
                                    aus), k) for k, m in enumerate(meshes[1:])]
        rows[f"faceanim, learned by landmark TPS + snapping, landmarks {label}"] = (len(xf.points.names), errs)

    names = [f.stem for f in files[1:]]
    print(f"\n{args.data}: {len(real)} expressions, face region {len(fidx)} of {neutral.n_vertices} vertices\n")
    print("| method | control points | median | mean | max |")
    print("|---|---|---|---|---|")
    for label, (n, e) in rows.items():
        e = np.asarray(e)
        print(f"| {label} | {n} | {np.median(e):.3f} | {e.mean():.3f} | {e.max():.3f} |")
    for label in ("thesis: AU points, TPS per face half", "faceanim: AU points, surface"):
        print(f"\nper expression ({label}):")
        print(" ".join(f"{n}:{x:.2f}" for n, x in zip(names, rows[label][1])))
    print(f"\n({time.time() - t0:.0f} s)")


if __name__ == "__main__":
    main()
