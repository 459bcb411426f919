"""Performance-driven animation (Chai, Xiao & Hodgins 2003): the cost of one video frame, stage by
stage, on a ~27k-vertex target, and retargeting at run time against the per-vertex transfer the
paper replaces.

    .venv/bin/python benchmarks/bench_perform.py ../shared/data [--blas-threads N]   (about a minute)

Video: ``talking-head-videos/d3.mp4`` (354 frames, 512 x 512). Target: the ICT head from
``ict-facekit/`` (26,719 vertices, its landmarks detected); the default face (24,591) without the data.

1. Per frame, streaming (each stage timed over the whole clip, per frame): decoding, tracking
   (MediaPipe's Face Landmarker + pose + 15 controls), filtering and synthesis as ``perform`` does it
   (feature-wise: two segment queries per frame, W = 5, K = 30 nearest by k-d tree, graph or
   brute force, local PCA, blend), and retargeting (the 2L basis weights, lower and upper
   face, blended into all vertices: one sparse (3V, 2L) x (2L,) product). End to end = the sum
   (rendering excluded); frames per second = 1 / that. 1b: the same for the ARKit solve
   (``perform``'s default): the solve per frame, and the target's 52 ARKit shapes blended.
2. Retargeting at run time, single frame and 100-frame batch, warm:
   - baseline: per-vertex transfer at run time (expression cloning as the paper describes it):
     the frame's motion on the source head (its shapes weighted, lower and upper face), interpolated
     at each target vertex's corresponding point and turned by that vertex's Jacobian (all
     precomputed: only the per-frame work is timed);
   - faceanim: the precomputed target bases blended (eq. 7), the rig's ``LinearDeformer``.
   Plus the bind (cold, once per face and database), and the retained and peak memory of it.

Compare ratios; wall-clock times depend on the machine's load and are never asserted.
"""

from __future__ import annotations

import time

import numpy as np
from _timing import arguments, best, blas_threads, fmt_bytes, fmt_time, header, table, traced

from faceanim.drivers.video.tracking import track_frames
from faceanim.face.face import Face
from faceanim.face.generic_head import generic_head
from faceanim.io.video import video_frames, video_info
from faceanim.perform import EYE_CONTROLS, EYE_CURVES, default_database, face_regions, perform, performance_rig
from faceanim.face.registration import face_to_head


def main() -> None:
    args = arguments(__doc__, "the shared data folder (../shared/data)")
    blas_threads(args.blas_threads)
    header("faceanim perform: one video frame, stage by stage")
    data = args.data
    video = data / "talking-head-videos" / "d3.mp4"
    ict = data / "ict-facekit" / "generic_neutral_mesh.obj"
    face = Face.load(ict) if ict.is_file() else Face.default()
    db = default_database()
    info = video_info(video)

    t0 = time.perf_counter()
    frames = list(video_frames(info))
    t_decode = (time.perf_counter() - t0) / len(frames)
    t0 = time.perf_counter()
    tr = track_frames(frames, info.fps)
    t_track = (time.perf_counter() - t0) / len(frames)

    t0 = time.perf_counter()
    rig, retained, peak = traced(lambda: performance_rig(face, db))
    t_bind = time.perf_counter() - t0

    synth = {}
    for search in ("kdtree", "graph", "brute"):
        t0 = time.perf_counter()
        weights = perform(tr, db, search=search).weights
        synth[search] = (time.perf_counter() - t0) / len(weights)
    one = weights[len(weights) // 2][None]
    t_blend = best(lambda: rig.deformer.apply_blendshapes(one), repeat=30)

    rows = []
    for search in ("kdtree", "graph", "brute"):
        total = t_decode + t_track + synth[search] + t_blend
        rows.append([search, fmt_time(t_decode), fmt_time(t_track), fmt_time(synth[search]), fmt_time(t_blend),
                     fmt_time(total), f"{1 / total:.0f}", f"{1 / (total - t_decode):.0f}"])
    table(rows, ["K-NN search", "decode", "track", "filter + synthesise", "retarget (blend)", "end to end",
                 "frames/s", "frames/s without decoding"],
          title=f"\n1. Per frame over {len(frames)} frames of {video.name}; target {face.mesh.n_vertices} vertices, "
                f"L = {db.n_bases} bases")

    # 1b. the ARKit solve (perform's default): per frame, and its 52 shapes blended on the target
    from faceanim.perform import solve_performance
    from faceanim.rig.arkit import arkit_rig

    t0 = time.perf_counter()
    solved = solve_performance(tr)
    t_solve = (time.perf_counter() - t0) / len(frames)
    t0 = time.perf_counter()
    arig, _ = arkit_rig(face)
    t_arkit_bind = time.perf_counter() - t0
    one_arkit = solved.weights[len(frames) // 2][None]
    t_arkit_blend = best(lambda: arig.deformer.apply_blendshapes(one_arkit), repeat=30)
    rows = []
    for label, t_make, t_b in (("solve (ARKit, default)", t_solve, t_arkit_blend),
                               ("synthesis (k-d tree)", synth["kdtree"], t_blend)):
        total = t_decode + t_track + t_make + t_b
        rows.append([label, fmt_time(t_track), fmt_time(t_make), fmt_time(t_b), fmt_time(total), f"{1 / total:.0f}",
                     f"{1 / (total - t_decode):.0f}"])
    table(rows, ["tracker", "track (MediaPipe)", "curves", "blend on the target", "end to end", "frames/s",
                 "frames/s without decoding"],
          title=f"\n1b. The trackers per frame (the same tracking); the ARKit rig's bind {fmt_time(t_arkit_bind)}")

    # 2. run-time retargeting: per-vertex transfer vs blended bases
    head = generic_head()
    regions = face_regions()
    tri, bary = face_to_head(face)
    corners = head.mesh.faces[tri]
    jac = np.broadcast_to(face.registration.scale * face.registration.rotation, (len(tri), 3, 3))
    curves = db.basis_curves.copy()
    curves[:, [list(db.curve_names).index(c) for c in EYE_CURVES]] = 0.0  # the lids are the blinks' own
    shapes = np.stack([head.shape(n) for n in db.curve_names])  # (C, Vs, 3)
    eyes = np.stack([rig.blendshape(n) for n in EYE_CONTROLS])  # (10, V, 3): blinks and gaze, as the rig has them

    n_l = db.n_bases

    def per_vertex(w):  # the frame's source motion (lower and upper face), carried vertex by vertex
        motion = (np.einsum("fc,cvd->fvd", w[:, :n_l] @ curves, shapes) * regions["lower"][None, :, None]
                  + np.einsum("fc,cvd->fvd", w[:, n_l:2 * n_l] @ curves, shapes) * regions["upper"][None, :, None])
        at = np.einsum("vc,fvcd->fvd", bary, motion[:, corners])
        return face.mesh.vertices + np.einsum("vij,fvj->fvi", jac, at) + np.einsum("fk,kvd->fvd", w[:, 2 * n_l:], eyes)

    batch = weights[:100]
    check = np.abs(per_vertex(one)[0] - rig.evaluate(one)[0]).max()
    rows = []
    for label, fn in (("per-vertex transfer at run time (baseline)", per_vertex),
                      ("blended target bases (eq. 7, LinearDeformer)", rig.evaluate)):
        rows.append([label, fmt_time(best(lambda fn=fn: fn(one), repeat=10)),
                     fmt_time(best(lambda fn=fn: fn(batch), repeat=3) / len(batch))])
    table(rows, ["method", "1 frame", "per frame in a 100-frame batch"],
          title=f"\n2. Retargeting at run time ({face.mesh.n_vertices} target vertices; the two agree within "
                f"{check:.1e} mesh units)",
          notes=[f"bind (once per face and database, cold, under tracemalloc): {fmt_time(t_bind)}; the rig retains "
                 f"{fmt_bytes(retained)}, peak {fmt_bytes(peak)} while binding"])


if __name__ == "__main__":
    main()
