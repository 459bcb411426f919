"""Wire deformation speed and memory on the default head (24,591 vertices), and extraction time.

    .venv/bin/python benchmarks/bench_wires.py [../shared/data/facewarehouse-tester1] [--blas-threads N]

The default face with its 15 default wires, driven by 1,000 frames of random wire control
points (1 mm noise) and radial scales (0.9-1.1). One frame and the 1,000-frame batch, cold
(closest points + falloffs + side masks, then that first evaluation; best of 2) and warm (best
of 30 frames or 3 batches after a warm-up), methods called in turn (interleaved), for:

- baseline, cached closest points (what a careful user writes): the closest points, curve
  parameters, falloffs and eq. 3 blending weights computed once (``WireSet.influence``), kept
  per wire for the vertices it reaches only, then eqs. 2-3 in numpy per frame,
  ``p' = p + sum_j w_ij [B_j(u_ij) q_j + (s_j - 1)(p_i - p_iRj)]``; the batch evaluates each
  wire for all frames in one product ``B_j @ q_j (t_j, 3F)`` into a (V, F, 3) array;
- baseline, naive: the same numpy evaluation after finding every vertex's closest point on
  every reference curve again each frame (a wire deformer without binding; its 1,000-frame
  time is 2 measured frames times 500);
- faceanim: the bound sparse operator (``WireInfluence.deformer``, one product per frame),
  float64 and float32.

Inputs are prepared outside the timings in each method's own form (the baselines take the
control offsets q_j and scales s_j, faceanim the handle offsets of ``WireInfluence.offsets``;
building those costs the number given under the table). Memory: what tracemalloc sees kept
after binding and after the first frame, and the peaks during the bind and the batch.
With the FaceWarehouse folder, also the extraction time of one template on its 11.5k-vertex
head. Compare the ratio columns; wall-clock times are never asserted.
"""

from __future__ import annotations

import numpy as np
from _timing import (
    Row,
    Stopwatch,
    arguments,
    best,
    best_fresh,
    blas_threads,
    fmt_bytes,
    fmt_time,
    header,
    interleaved,
    once,
    size_of,
    speed_table,
    table,
    traced,
)

from faceanim.deform.wires import extract_wires
from faceanim.face.face import Face
from faceanim.rig.wires import default_wires

N_FRAMES = 1000
COLD1, WARM1 = "1 frame, cold (bind + frame)", "1 frame, warm"
COLDN, WARMN = f"{N_FRAMES} frames, cold (bind + batch)", f"{N_FRAMES} frames, warm"


class CachedWires:
    """The careful user's wire deformer: per wire, the vertices it reaches, their blending
    weights, B-spline basis at the closest curve parameter and radial vectors, kept once."""

    def __init__(self, influence, dtype=np.float64):
        self.rest = influence.rest.astype(dtype)
        self.parts = []
        for j in range(len(influence.wires)):
            idx = np.flatnonzero(influence.weights[:, j] > 0)
            self.parts.append((idx, influence.weights[idx, j].astype(dtype)[:, None],
                               influence.basis[j][idx].astype(dtype), influence.radial[j][idx].astype(dtype)))

    def nbytes(self) -> int:
        return size_of(self.rest, *(a for part in self.parts for a in part))

    def frame(self, q, s):
        """Positions (V, 3) for control offsets q (one (t_j, 3) per wire) and scales s (m,)."""
        out = self.rest.copy()
        for (idx, w, b, r), qj, sj in zip(self.parts, q, s):
            out[idx] += w * (b @ qj + (sj - 1.0) * r)
        return out

    def batch(self, q, s):
        """Positions (V, F, 3) for q (one (F, t_j, 3) per wire) and s (F, m)."""
        n = s.shape[0]
        out = np.empty((len(self.rest), n, 3), dtype=self.rest.dtype)
        out[:] = self.rest[:, None]
        for j, ((idx, w, b, r), qj) in enumerate(zip(self.parts, q)):
            d = (b @ np.ascontiguousarray(qj.transpose(1, 0, 2)).reshape(b.shape[1], 3 * n)).reshape(len(idx), n, 3)
            d += r[:, None, :] * (s[:, j] - 1.0)[None, :, None]
            d *= w[:, :, None]
            out[idx] += d
        return out


def main() -> None:
    args = arguments(__doc__, data="FaceWarehouse tester folder (pose_0.obj, pose_2.obj) for the extraction time")
    with blas_threads(args.blas_threads):
        header("bench_wires: bound wire deformer against cached and naive numpy wires", touch=2**30)
        clock = Stopwatch()
        face = Face.default()
        mesh, lm = face.mesh, face.landmarks
        wireset = default_wires(lm)
        rng = np.random.default_rng(0)
        m = len(wireset.wires)
        refs = [w.reference.control for w in wireset.wires]
        # inputs: control offsets q (per wire (F, t_j, 3)) and scales (F, m)
        q = [rng.normal(scale=1e-3, size=(N_FRAMES,) + r.shape) for r in refs]
        s = rng.uniform(0.9, 1.1, size=(N_FRAMES, m))
        influence = wireset.influence(mesh, lm)
        t_offsets = best(lambda: influence.offsets([r + qj[0] for r, qj in zip(refs, q)], s[0]), repeat=20)
        offsets = np.stack([influence.offsets([r + qj[f] for r, qj in zip(refs, q)], s[f]) for f in range(N_FRAMES)])
        q0, s0 = [qj[0] for qj in q], s[0]

        def bind_cached(dtype):
            return CachedWires(wireset.influence(mesh, lm), dtype)

        def bind_faceanim(dtype):
            return wireset.influence(mesh, lm).deformer(dtype)

        rows: list[Row] = []
        mem: list[list[str]] = []
        naive_name = "naive numpy, closest points every frame"
        # naive: one frame = a new influence (closest points) + the numpy evaluation
        t_naive, _ = best_fresh(lambda: bind_cached(np.float64).frame(q0, s0), repeat=2)
        t_naive2, _ = once(lambda: [bind_cached(np.float64).frame([qj[f] for qj in q], s[f]) for f in (1, 2)])
        _, _, peak_naive = traced(lambda: bind_cached(np.float64).frame(q0, s0))
        g = "float64"
        rows += [Row(COLD1, naive_name, t_naive, baseline=True, group=g, note="nothing to reuse: cold = warm"),
                 Row(WARM1, naive_name, t_naive, baseline=True, group=g),
                 Row(COLDN, naive_name, t_naive2 * N_FRAMES / 2, N_FRAMES, True, g, "2 frames measured x 500"),
                 Row(WARMN, naive_name, t_naive2 * N_FRAMES / 2, N_FRAMES, True, g, "2 frames measured x 500")]
        mem.append([naive_name, "-", "-", "-", f"{fmt_bytes(peak_naive)} (1 frame)", "-"])
        errors = {}
        for dtype in (np.float64, np.float32):
            g = np.dtype(dtype).name
            cached_name, fa_name = f"numpy, cached closest points ({g})", f"faceanim bound operator ({g})"
            qd, sd = [qj.astype(dtype) for qj in q], s.astype(dtype)
            qd0, sd0, off, off0 = [qj[0] for qj in qd], sd[0], offsets.astype(dtype), offsets[0].astype(dtype)
            cw, kept_c, peak_c = traced(lambda dtype=dtype: bind_cached(dtype))
            op, kept_f, peak_f = traced(lambda dtype=dtype: bind_faceanim(dtype))
            _, kept_f1, _ = traced(lambda op=op, off0=off0: op.apply(off0))
            errors[fa_name] = np.abs(op.apply(off0) - cw.frame(qd0, sd0)).max()
            cold = interleaved({cached_name: lambda dtype=dtype, qd0=qd0, sd0=sd0: bind_cached(dtype).frame(qd0, sd0),
                                fa_name: lambda dtype=dtype, off0=off0: bind_faceanim(dtype).apply(off0)},
                               repeat=2, warmup=0)
            warm = interleaved({cached_name: lambda cw=cw, qd0=qd0, sd0=sd0: cw.frame(qd0, sd0),
                                fa_name: lambda op=op, off0=off0: op.apply(off0)},
                               repeat=30, warmup=3, warmup_seconds=0.1)
            cold_n = interleaved({cached_name: lambda dtype=dtype, qd=qd, sd=sd: bind_cached(dtype).batch(qd, sd),
                                  fa_name: lambda dtype=dtype, off=off: bind_faceanim(dtype).apply(off)},
                                 repeat=2, warmup=0)
            _, _, peak_cn = traced(lambda cw=cw, qd=qd, sd=sd: cw.batch(qd, sd))
            _, _, peak_fn = traced(lambda op=op, off=off: op.apply(off))
            warm_n = interleaved({cached_name: lambda cw=cw, qd=qd, sd=sd: cw.batch(qd, sd),
                                  fa_name: lambda op=op, off=off: op.apply(off)},
                                 repeat=3, warmup=0)
            batch_err = np.abs(op.apply(off[:5]) - cw.batch([qj[:5] for qj in qd], sd[:5]).transpose(1, 0, 2)).max()
            errors[fa_name] = max(errors[fa_name], batch_err)
            rows += [Row(COLD1, cached_name, cold[cached_name], baseline=True, group=g),
                     Row(COLD1, fa_name, cold[fa_name], group=g),
                     Row(WARM1, cached_name, warm[cached_name], baseline=True, group=g),
                     Row(WARM1, fa_name, warm[fa_name], group=g),
                     Row(COLDN, cached_name, cold_n[cached_name], N_FRAMES, True, g, "(V, F, 3)"),
                     Row(COLDN, fa_name, cold_n[fa_name], N_FRAMES, group=g, note="(F, V, 3)"),
                     Row(WARMN, cached_name, warm_n[cached_name], N_FRAMES, True, g, "(V, F, 3)"),
                     Row(WARMN, fa_name, warm_n[fa_name], N_FRAMES, group=g, note="(F, V, 3)")]
            mem += [[cached_name, fmt_bytes(cw.nbytes()), fmt_bytes(kept_c), fmt_bytes(kept_c), fmt_bytes(peak_c),
                     fmt_bytes(peak_cn)],
                    [fa_name, fmt_bytes(op.nbytes()), fmt_bytes(kept_f), fmt_bytes(kept_f + kept_f1),
                     fmt_bytes(peak_f), fmt_bytes(peak_fn)]]
        moving = op.n_vertices if op.rows is None else op.rows.size
        print(f"## default face: {mesh.n_vertices} vertices, {m} wires, {op.n_handles} handles, {moving} vertices "
              f"in range of some wire; {N_FRAMES} frames\n")
        speed_table(rows, notes=[
            ("groups: float64 and float32 (the naive baseline is float64 only); cold = the influence (closest "
            "points, falloffs, side masks) + that method's cache + the first evaluation"),
            (f"building faceanim's handle offsets from wire controls and scales: {fmt_time(t_offsets)} per frame "
            "(not in the times above)"),
            "max |faceanim - cached numpy| (m), frame 0 and frames 0-4 of the batch: "
            + ", ".join(f"{k}: {v:.1e}" for k, v in errors.items())])
        table(mem, ["method", "operator", "kept after bind", "kept after 1st frame", "peak: bind",
                    f"peak: {N_FRAMES} frames"],
              notes=[("operator: LinearDeformer.nbytes() / the cached arrays; kept/peak: tracemalloc, relative to "
                     "before the call (the batch peak includes its output)")])
        clock.lap("wires")
        if args.data is not None:
            from faceanim.io.meshio import load_mesh
            from faceanim.rig.wires import align_template

            base = Face.load(args.data / "pose_0.obj")  # landmarks detected by rendering the mesh
            b = default_wires(base.landmarks).influence(base.mesh, base.landmarks)
            template = align_template(base.mesh, load_mesh(args.data / "pose_2.obj"), base.landmarks)
            t_ex = best(lambda: extract_wires(b, template.vertices), repeat=5)
            table([[f"extract one template (pose_2), {base.mesh.n_vertices}-vertex FaceWarehouse head",
                    fmt_time(t_ex)]], ["step", "time (best of 5)"])
            clock.lap("extraction")
        print(clock.line())


if __name__ == "__main__":
    main()
