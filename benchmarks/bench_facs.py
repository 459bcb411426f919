"""Action-unit rig: binding, compiling and posing cost and memory on the default head (24,591 vertices).

    .venv/bin/python benchmarks/bench_facs.py [--blas-threads N]

1. Binding an ExpressionTransfer from a fresh Face (its frame, skin and regions computed again:
   cold), surface (one sparse LU of the KKT system, SuperLU) and the thesis' TPS, each with BLAS
   limited to one thread (threadpoolctl) and with the run's BLAS threads, in the same run and
   called in turn. The surface bind limits BLAS to one thread around SuperLU itself; its
   "run's threads" row removes that limit for the measurement (``surface.one_blas_thread``
   replaced by a no-op), so the effect of the limit is what the two rows differ by. The TPS rows
   put the limit around the whole bind.
2. Compiling every AU and emotion to blendshapes, then posing from AU weights: one frame and
   1,000 frames, cold (bind + compile + evaluation) and warm, against
   - re-solving the warp for every frame (an implementation without a bound operator: a new
     ExpressionTransfer, then the frame's AU mixture; cold on a fresh Face, warm on the Face whose
     frame, skin and regions are cached; its 1,000-frame times are extrapolated from one frame);
   - the compiled blendshapes as one dense (3V, C) numpy matrix, ``rest + B @ weights`` (one BLAS
     product ``weights @ B.T`` for all frames).
3. Memory: tracemalloc kept/peak of the bind, the compile and the 1,000-frame batch; SuperLU's
   own factor storage, which tracemalloc does not see, from the factor's ``nnz``.

Compare the ratio columns; wall-clock times are never asserted.
"""

from __future__ import annotations

import contextlib

import numpy as np
from _timing import (
    Row,
    Stopwatch,
    arguments,
    best,
    blas_threads,
    fmt_bytes,
    header,
    interleaved,
    size_of,
    speed_table,
    table,
    traced,
)

from faceanim.deform import surface
from faceanim.face.face import Face
from faceanim.rig.transfer import ExpressionTransfer, default_model

N_FRAMES = 1000
METHODS = ("surface", "tps")


@contextlib.contextmanager
def superlu_threads_unlimited():
    """Remove bind_surface's own one-thread limit around SuperLU for the duration."""
    original = surface.one_blas_thread
    surface.one_blas_thread = contextlib.nullcontext
    try:
        yield
    finally:
        surface.one_blas_thread = original


class SpluSpy:
    """Stands in for scipy.sparse.linalg in faceanim.deform.surface and records the factor's nnz."""

    def __init__(self, real):
        self._real, self.nnz = real, None

    def __getattr__(self, name):
        return getattr(self._real, name)

    def splu(self, *args, **kwargs):
        lu = self._real.splu(*args, **kwargs)
        self.nnz = lu.nnz
        return lu


class DenseBlendshapes:
    """Baseline: the compiled blendshapes as one dense (3V, C) matrix."""

    def __init__(self, rig):
        v, c = rig.mesh.n_vertices, rig.n_controls
        w = rig.deformer.dense_weights()  # (V, 3C), W[v, 3c + a] = B_c[v, a]
        self.b = np.ascontiguousarray(w.reshape(v, c, 3).transpose(0, 2, 1).reshape(3 * v, c))
        self.rest = rig.mesh.vertices

    def frame(self, c):
        return (self.rest.reshape(-1) + self.b @ c).reshape(-1, 3)

    def batch(self, curves):
        out = (curves @ self.b.T).reshape(len(curves), -1, 3)
        out += self.rest
        return out


def main() -> None:
    args = arguments(__doc__)
    with blas_threads(args.blas_threads):
        header("bench_facs: AU rig bind, compile and posing against re-solving and dense blendshapes", touch=2**30)
        clock = Stopwatch()
        face = Face.default()
        mesh, lm = face.mesh, face.landmarks
        model = default_model()
        ExpressionTransfer(face, method="tps")  # fills the face's caches (for the re-solve baseline)
        print(f"## default face: {mesh.n_vertices} vertices, {len(model.samples)} learned AUs\n")

        # ------------------------------------------------------------ 1. binds, BLAS threads
        def bind(method):
            return ExpressionTransfer(Face(mesh, lm), method=method)  # a fresh Face: cold

        def surface_unlimited():
            with superlu_threads_unlimited():
                return bind("surface")

        def tps_one_thread():
            with blas_threads(1):
                return bind("tps")

        lim1, lim_run = "BLAS 1 thread", "BLAS threads of the run"
        t = interleaved({("surface", lim1): lambda: bind("surface"), ("surface", lim_run): surface_unlimited,
                         ("tps", lim1): tps_one_thread, ("tps", lim_run): lambda: bind("tps")},
                        repeat=3, warmup=0)
        rows = []
        for method, where in (("surface", "around SuperLU (faceanim's default)"), ("tps", "around the bind")):
            rows += [Row(f"bind {method}, cold", f"{lim_run}", t[(method, lim_run)], baseline=True,
                         note="faceanim's limit removed" if method == "surface" else "faceanim's default"),
                     Row(f"bind {method}, cold", f"{lim1} {where}", t[(method, lim1)])]
        speed_table(rows, notes=["best of 3 fresh binds each, the four called in turn"])
        clock.lap("binds")

        # ------------------------------------------------------------ 2. compile and pose
        rng = np.random.default_rng(0)
        rows, mem = [], []
        compile_rows = []
        for method in METHODS:
            spy = SpluSpy(surface.spl)
            surface.spl = spy
            try:
                xf, kept_b, peak_b = traced(lambda method=method: bind(method))
            finally:
                surface.spl = spy._real
            t_compile = best(lambda xf=xf: xf.rig(model, sides=False), repeat=2, warmup=0)
            rig, kept_c, peak_c = traced(lambda xf=xf: xf.rig(model, sides=False))
            _, kept_1, _ = traced(lambda rig=rig: rig.evaluate(np.zeros((1, rig.n_controls))))
            c = rig.n_controls
            curves = rng.uniform(0, 1, size=(N_FRAMES, c))
            one = curves[:1]
            dense = DenseBlendshapes(rig)
            err = np.abs(dense.batch(curves[:20]) - rig.evaluate(curves[:20])).max()
            au_mix = {au: float(w) for au, w in zip(sorted(model.samples), rng.uniform(0, 1, len(model.samples)))
                      if au in xf.library.action_units}

            def resolve(on=face, method=method, au_mix=au_mix):
                # no bound operator: solve the warp again for this frame's mixture (warm: on the Face
                # whose frame, skin and regions are cached; cold: on a fresh Face)
                return ExpressionTransfer(on, method=method).mixture_delta(model, au_mix) + mesh.vertices

            def cold(frames, method=method):
                return bind(method).rig(model, sides=False).evaluate(frames)

            g = method
            rs, dn, fa = "re-solve the warp per frame", "dense numpy blendshapes (3V, C)", "faceanim AU rig"
            t_cold = interleaved({rs: lambda resolve=resolve: resolve(Face(mesh, lm)),
                                  fa: lambda cold=cold, one=one: cold(one)}, repeat=2, warmup=0)
            t_resolve = best(resolve, repeat=2, warmup=0)
            warm = interleaved({dn: lambda dense=dense, one=one: dense.frame(one[0]),
                                fa: lambda rig=rig, one=one: rig.evaluate(one)}, repeat=30, warmup=3,
                               warmup_seconds=0.1)
            t_cold_n = interleaved({fa: lambda cold=cold, curves=curves: cold(curves)}, repeat=2, warmup=0)
            _, _, peak_n = traced(lambda rig=rig, curves=curves: rig.evaluate(curves))
            _, _, peak_dn = traced(lambda dense=dense, curves=curves: dense.batch(curves))
            warm_n = interleaved({dn: lambda dense=dense, curves=curves: dense.batch(curves),
                                  fa: lambda rig=rig, curves=curves: rig.evaluate(curves)}, repeat=3, warmup=1)
            label = f"{method}: "
            est = t_cold[rs] + (N_FRAMES - 1) * t_resolve
            rows += [Row(label + "1 frame, cold", rs, t_cold[rs], baseline=True, group=g, note="fresh Face"),
                     Row(label + "1 frame, cold", fa, t_cold[fa], group=g, note="fresh Face; bind + compile + frame"),
                     Row(label + "1 frame, warm", rs, t_resolve, baseline=True, group=g, note="cached Face"),
                     Row(label + "1 frame, warm", dn, warm[dn], baseline=True, group=g),
                     Row(label + "1 frame, warm", fa, warm[fa], group=g),
                     Row(label + f"{N_FRAMES} frames, cold", rs, est, N_FRAMES, True, g,
                         "cold frame + 999 x warm frame"),
                     Row(label + f"{N_FRAMES} frames, cold", fa, t_cold_n[fa], N_FRAMES, group=g,
                         note="bind + compile + frames"),
                     Row(label + f"{N_FRAMES} frames, warm", rs, t_resolve * N_FRAMES, N_FRAMES, True, g,
                         "1 warm frame measured x 1000"),
                     Row(label + f"{N_FRAMES} frames, warm", dn, warm_n[dn], N_FRAMES, True, g),
                     Row(label + f"{N_FRAMES} frames, warm", fa, warm_n[fa], N_FRAMES, group=g)]
            compile_rows.append([method, f"{c}", f"{t_compile:.2f} s", f"{err:.1e}",
                                 "sparse" if rig.deformer.is_sparse else "dense"])
            lu = "-" if spy.nnz is None else f"~{fmt_bytes(spy.nnz * 12)} (nnz {spy.nnz:,})"
            mem += [[f"{method}: bind (ExpressionTransfer)", "-", fmt_bytes(kept_b), "-", fmt_bytes(peak_b), "-", lu],
                    [f"{method}: compile -> {fa}", fmt_bytes(rig.deformer.nbytes()), fmt_bytes(kept_c),
                     fmt_bytes(kept_c + kept_1), fmt_bytes(peak_c), fmt_bytes(peak_n), "-"],
                    [f"{method}: {dn}", fmt_bytes(size_of(dense.b)), "-", "-", "-", fmt_bytes(peak_dn), "-"]]
            clock.lap(method)
        table(compile_rows, ["method", "blendshapes (AUs + emotions)", "compile (best of 2)",
                             "max |dense - rig| (m)", "rig operator"])
        speed_table(rows, notes=["groups: surface and tps rigs (each baseline uses that method's warp)"])
        table(mem, ["step", "operator", "kept after", "kept after 1st frame", "peak", f"peak: {N_FRAMES} frames",
                    "SuperLU factors"],
              notes=[("kept/peak: tracemalloc relative to before the call (the bind from a fresh Face, its caches "
                     "included); LU: SuperLU's own factor storage (about 12 bytes per stored entry), outside "
                     "tracemalloc and freed when the bind returns"),
                     f"{N_FRAMES}-frame output: {fmt_bytes(N_FRAMES * mesh.n_vertices * 3 * 8)}"])
        print(clock.line())


if __name__ == "__main__":
    main()
