"""Deformation speed and memory: faceanim's bound operators against the best a user can do with
scipy and numpy alone.

Run:  .venv/bin/python benchmarks/bench_deform.py [--blas-threads N]     (1-2 minutes on 2 cores)

1. An 89k-vertex face (the default head's face region, two Loop subdivisions; see
   :func:`face_with`) and 60 handles: the global
   thin-plate spline (no smoothing) and a rig of 60 geometry deformation elements (sparse, local).
   One frame and a 1,000-frame batch, each cold (bind + that first evaluation, nothing cached
   but the imports and the BLAS threads; best of 2-3 fresh binds) and warm (the bound operator
   reused; best of 30 single frames or 2 batches after a warm-up). Baselines and faceanim are
   called in turn (interleaved) so the machine's load hits them alike. Baselines:
   - scipy's RBFInterpolator refitted for every frame (the obvious way; its 1,000-frame time is
     10 measured frames times 100);
   - scipy's RBFInterpolator fitted once with all frames' offsets as a multi-column ``d`` of
     shape (H, 3F) and evaluated in one call (scipy solving all frames at once; there is nothing
     to keep for new frames, so cold = warm);
   - a dense W cached by a careful user (scipy's RBFInterpolator evaluated on the identity,
     d = I_H, gives the (V, H) weights), then ``rest + W @ offsets`` in numpy: all frames in one
     product ``W @ offsets (H, 3F)``, in float64 and float32;
   - for the GDE rig, the same weights as a scipy.sparse CSR matrix and the same products.
   The batch baselines keep their natural (V, F, 3) layout (rest added in place); faceanim
   returns (F, V, 3). Memory: the operator's bytes (``LinearDeformer.nbytes()`` / W.nbytes),
   what tracemalloc sees still allocated after binding and after the first frame, and the
   tracemalloc peak during the bind and during the 1,000-frame batch (its output included).
2. Binding one GDE on the default head (24,591 vertices, at eight of its landmarks), with the
   run's BLAS threads and with one.
3. Global RBF binding, per-frame cost and operator memory over vertex and handle counts.

Every table is printed with its baselines measured in the same run; compare the ratio columns.
Wall-clock times depend on the machine's load and are never asserted.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
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
from scipy.interpolate import RBFInterpolator
from trimesh.remesh import subdivide_loop

from faceanim.deform import (
    GeometryDeformationElement,
    bind_gdes,
    bind_rbf,
    element_influence,
)
from faceanim.deform.rbf import MAX_WEIGHTS
from faceanim.face.face import Face
from faceanim.face.mesh import Mesh

TPS = "thin_plate_spline"
N_FRAMES = 1000
COLD1, WARM1 = "1 frame, cold (bind + frame)", "1 frame, warm"
COLDN, WARMN = f"{N_FRAMES} frames, cold (bind + batch)", f"{N_FRAMES} frames, warm"


def face_with(levels: int) -> Mesh:
    """The default head's face (its skin inside the landmark oval, without the mouth cavity and eye
    sockets: 5,838 vertices) Loop-subdivided ``levels`` times: 22.7k vertices at 1, 89k at 2, 355k
    at 3. (The whole head has eyeballs, teeth and the back of the skull, and 24.6k vertices before
    any subdivision.)"""
    face = Face.default()
    keep = np.all(face.face_region[face.mesh.faces], axis=1)
    used = np.unique(face.mesh.faces[keep])
    index = np.full(face.mesh.n_vertices, -1)
    index[used] = np.arange(used.size)
    v, f = face.mesh.vertices[used], index[face.mesh.faces[keep]]
    if levels:
        v, f = subdivide_loop(v, f, levels)
    return Mesh(v, f, name=f"face_l{levels}")


@dataclass
class Setup:
    """Section 1's face, handles, frames and the rows collected."""

    mesh: Mesh
    handles: np.ndarray
    frames: np.ndarray  # (F, H, 3) float64
    rows: list = field(default_factory=list)
    mem: list = field(default_factory=list)
    errs: dict = field(default_factory=dict)

    @property
    def verts(self) -> np.ndarray:
        return self.mesh.vertices

    def scipy_frame(self, off):
        """scipy refitted for one frame: the obvious way."""
        return self.verts + RBFInterpolator(self.handles, off, kernel=TPS)(self.verts)

    def scipy_all(self, fr):
        """scipy fitted once for all frames: d (H, 3F), one evaluation, rest added in place."""
        n, h = fr.shape[:2]
        d = np.ascontiguousarray(fr.transpose(1, 0, 2)).reshape(h, 3 * n)
        out = RBFInterpolator(self.handles, d, kernel=TPS)(self.verts).reshape(len(self.verts), n, 3)
        out += self.verts[:, None]
        return out


def w_frame(w, off, rest):
    """A cached W, one frame."""
    return rest + w @ off


def w_batch(w, fr, rest):
    """A cached W, all frames in one product W @ offsets (H, 3F); positions in (V, F, 3)."""
    n, h = fr.shape[:2]
    out = (w @ np.ascontiguousarray(fr.transpose(1, 0, 2)).reshape(h, 3 * n)).reshape(len(rest), n, 3)
    out += rest[:, None]
    return out


REFIT, FITTED_ONCE = "scipy RBFInterpolator refit per frame", "scipy RBFInterpolator fitted once, d (H, 3F)"


def tps_group(s: Setup, dtype, ref: np.ndarray) -> None:
    """The global thin-plate spline in one float type: scipy, numpy with a cached W, faceanim."""
    dt = np.dtype(dtype).name
    g = f"TPS {dt}"
    H = len(s.handles)
    verts, f64 = s.verts, dtype == np.float64
    rest, frames, one = verts.astype(dtype), s.frames.astype(dtype), s.frames[0].astype(dtype)

    def build_w():
        # the careful user's operator: scipy's interpolant of the identity is W (V, H)
        return RBFInterpolator(s.handles, np.eye(H), kernel=TPS)(verts).astype(dtype, copy=False)

    def bind():
        return bind_rbf(verts, s.handles, TPS, smoothing=0.0, dtype=dtype)

    np_name, fa_name = f"numpy cached W ({dt}), rest + W @ offsets", f"faceanim bind_rbf ({dt})"
    w, kept_w, peak_w = traced(build_w)
    d, kept_d, peak_d = traced(bind)
    _, kept_d1, _ = traced(lambda: d.apply(one))
    s.errs[fa_name] = np.abs(d.apply(s.frames[0]) - ref).max() / np.abs(ref - verts).max()

    # one frame: cold = a fresh bind + the frame (best of 3), warm = the frame (best of 30)
    fns = {np_name: lambda: w_frame(build_w(), one, rest), fa_name: lambda: bind().apply(one)}
    if f64:
        fns[REFIT] = lambda: s.scipy_frame(s.frames[0])
    cold = interleaved(fns, repeat=3, warmup=0)
    warm = interleaved({np_name: lambda: w_frame(w, one, rest), fa_name: lambda: d.apply(one)},
                       repeat=30, warmup=3, warmup_seconds=0.1)
    if f64:
        s.rows += [Row(COLD1, REFIT, cold[REFIT], baseline=True, group=g, note="nothing to reuse: cold = warm"),
                   Row(WARM1, REFIT, cold[REFIT], baseline=True, group=g)]
    s.rows += [Row(COLD1, np_name, cold[np_name], baseline=True, group=g, note="W = RBFInterpolator(d = I)"),
               Row(COLD1, fa_name, cold[fa_name], group=g),
               Row(WARM1, np_name, warm[np_name], baseline=True, group=g),
               Row(WARM1, fa_name, warm[fa_name], group=g)]

    # batches: cold best of 2 (each binds again); one traced call each (memory, and the warm-up);
    # warm best of 2, all interleaved
    cold = interleaved({np_name: lambda: w_batch(build_w(), frames, rest), fa_name: lambda: bind().apply(frames)},
                       repeat=2, warmup=0)
    np_cold, fa_cold = cold[np_name], cold[fa_name]
    _, _, peak_np = traced(lambda: w_batch(w, frames, rest))
    _, _, peak_fa = traced(lambda: d.apply(frames))
    fns = {np_name: lambda: w_batch(w, frames, rest), fa_name: lambda: d.apply(frames)}
    if f64:
        t10, _ = once(lambda: [s.scipy_frame(s.frames[k]) for k in range(10)])
        _, _, peak_1 = traced(lambda: s.scipy_frame(s.frames[0]))
        res, _, peak_all = traced(lambda: s.scipy_all(s.frames))
        s.errs["scipy fitted once vs refit (m)"] = np.abs(res[:, 0] - ref).max()
        del res
        fns[FITTED_ONCE] = lambda: s.scipy_all(s.frames)
    warm = interleaved(fns, repeat=2, warmup=0)
    if f64:
        est = t10 * N_FRAMES / 10
        s.rows += [Row(COLDN, REFIT, est, N_FRAMES, True, g, "10 frames measured x 100"),
                   Row(WARMN, REFIT, est, N_FRAMES, True, g, "10 frames measured x 100"),
                   Row(COLDN, FITTED_ONCE, warm[FITTED_ONCE], N_FRAMES, True, g,
                       "(V, F, 3); new frames need a new fit: cold = warm"),
                   Row(WARMN, FITTED_ONCE, warm[FITTED_ONCE], N_FRAMES, True, g, "(V, F, 3)")]
        s.mem += [[REFIT, "-", "-", "-", f"{fmt_bytes(peak_1)} (1 frame)", "-"],
                  [FITTED_ONCE, "-", "-", "-", "-", fmt_bytes(peak_all)]]
    s.rows += [Row(COLDN, np_name, np_cold, N_FRAMES, True, g, "(V, F, 3)"),
               Row(COLDN, fa_name, fa_cold, N_FRAMES, group=g, note="(F, V, 3)"),
               Row(WARMN, np_name, warm[np_name], N_FRAMES, True, g, "(V, F, 3)"),
               Row(WARMN, fa_name, warm[fa_name], N_FRAMES, group=g, note="(F, V, 3)")]
    s.mem += [[np_name, fmt_bytes(w.nbytes), fmt_bytes(kept_w), fmt_bytes(kept_w), fmt_bytes(peak_w),
               fmt_bytes(peak_np)],
              [fa_name, fmt_bytes(d.nbytes()), fmt_bytes(kept_d), fmt_bytes(kept_d + kept_d1), fmt_bytes(peak_d),
               fmt_bytes(peak_fa)]]


def gde_group(s: Setup, rng) -> int:
    """60 GDEs (local, sparse, float64) against the same weights as one scipy.sparse matrix."""
    g = "GDE float64"
    verts, frames, one = s.verts, s.frames, s.frames[0]
    centres = verts[rng.choice(len(verts), len(s.handles), replace=False)]
    gdes = [GeometryDeformationElement(tuple(c), 0.015, "euclidean") for c in centres]

    def bind():
        # a fresh Mesh: its k-d tree and adjacency are built again, as on a first bind
        return bind_gdes(Mesh(s.mesh.vertices, s.mesh.faces), gdes)

    fa_name, sp_name = "faceanim bind_gdes (float64)", "scipy.sparse CSR W (float64), same weights"
    rig, kept, peak_bind = traced(bind)
    _, kept1, _ = traced(lambda: rig.apply(one))
    w = sp.csr_matrix(rig.dense_weights())  # the same weights over all vertices, one CSR matrix
    cold, _ = best_fresh(lambda: bind().apply(one), repeat=2)
    warm = interleaved({sp_name: lambda: w_frame(w, one, verts), fa_name: lambda: rig.apply(one)},
                       repeat=30, warmup=3, warmup_seconds=0.1)
    s.rows += [Row(COLD1, fa_name, cold, group=g, note="no baseline: the sparse one needs this bind"),
               Row(WARM1, sp_name, warm[sp_name], baseline=True, group=g),
               Row(WARM1, fa_name, warm[fa_name], group=g)]
    fa_cold, _ = best_fresh(lambda: bind().apply(frames), repeat=2)
    _, _, peak_sp = traced(lambda: w_batch(w, frames, verts))
    _, _, peak_fa = traced(lambda: rig.apply(frames))
    warm = interleaved({sp_name: lambda: w_batch(w, frames, verts), fa_name: lambda: rig.apply(frames)},
                       repeat=2, warmup=0)
    s.rows += [Row(COLDN, fa_name, fa_cold, N_FRAMES, group=g, note="(F, V, 3)"),
               Row(WARMN, sp_name, warm[sp_name], N_FRAMES, True, g, "(V, F, 3), one product W @ (H, 3F)"),
               Row(WARMN, fa_name, warm[fa_name], N_FRAMES, group=g, note="(F, V, 3)")]
    s.mem += [[sp_name, fmt_bytes(size_of(w)), "-", "-", "(uses faceanim's bind)", fmt_bytes(peak_sp)],
              [fa_name, fmt_bytes(rig.nbytes()), fmt_bytes(kept), fmt_bytes(kept + kept1), fmt_bytes(peak_bind),
               fmt_bytes(peak_fa)]]
    return len(rig.moving_vertices)


def section_1(rng) -> None:
    mesh = face_with(2)
    V, H = mesh.n_vertices, 60
    s = Setup(mesh, mesh.vertices[rng.choice(V, H, replace=False)], rng.normal(scale=0.002, size=(N_FRAMES, H, 3)))
    print(f"## 1. {V} vertices, {H} handles; {N_FRAMES} frames of handle offsets "
          f"(output {fmt_bytes(N_FRAMES * V * 3 * 8)} in float64)\n")
    ref = s.scipy_frame(s.frames[0])
    for dtype in (np.float64, np.float32):
        tps_group(s, dtype, ref)
    moving = gde_group(s, rng)
    speed_table(s.rows, notes=[
        ("groups: TPS = the global thin-plate spline (scipy and faceanim give the same field) in float64 and "
        "float32; GDE = 60 local elements (no scipy equivalent: the sparse baseline multiplies faceanim's own "
        f"weights; {moving} of {V} vertices can move)"),
        "max |faceanim - scipy| / max displacement, frame 0: "
        + ", ".join(f"{k}: {v:.1e}" for k, v in s.errs.items())])
    table(s.mem, ["method", "operator", "kept after bind", "kept after 1st frame", "peak: bind",
                  f"peak: {N_FRAMES} frames"],
          notes=[("kept/peak: tracemalloc (numpy arrays, scipy.sparse and Python objects), relative to before the "
                 "call; the batch peak includes its output; 'kept after 1st frame' adds what the first evaluation "
                 "caches (faceanim's sparse path keeps a full-height CSC copy of W and a (V, 3) mask)")])


def section_2() -> None:
    print("## 2. the influence of one GDE on the default head (region, anchors, RBF solve)\n")
    head = Face.default()
    face, controls = head.mesh, head.landmarks[[61, 291, 152, 105, 334, 1, 14, 50]]  # mouth, chin, brows, nose, lip, cheek
    rows = []
    for metric, extent in [("edges", 4), ("edges", 10), ("euclidean", 0.01), ("euclidean", 0.025)]:
        times, times1, sizes = [], [], []
        for c in controls:
            e = GeometryDeformationElement(tuple(c), extent, metric)
            # caches warm (adjacency, k-d tree) as in a rig; BLAS as set for the run, then 1 thread
            times.append(best(lambda e=e: element_influence(face, e), repeat=5))
            with blas_threads(1):
                times1.append(best(lambda e=e: element_influence(face, e), repeat=5))
            sizes.append(element_influence(face, e).region.size)
        rows.append([f"{metric} {extent}", f"{face.n_vertices}", f"{int(np.mean(sizes))}",
                     fmt_time(float(np.median(times))), fmt_time(float(np.max(times))),
                     fmt_time(float(np.median(times1))), fmt_time(float(np.max(times1)))])
    table(rows, ["metric/extent", "vertices", "region (mean)", "bind (median of 8)", "bind (max of 8)",
                 "1 BLAS thread: median", "1 BLAS thread: max"])


def section_3(rng) -> None:
    print("## 3. global RBF (multiquadric, eq. 3 stiffness, float32) over sizes: bind, one frame, memory\n")
    rows = []
    for n in [1_000, 10_000, 100_000, 1_000_000]:
        pts = rng.uniform(-0.1, 0.1, size=(n, 3))
        for h in [10, 60, 200]:
            if n * h > MAX_WEIGHTS:
                rows.append([f"{n:,}", h, f"refused: {n * h:.0e} weights > MAX_WEIGHTS", "-", "-", "-"])
                continue
            hd = pts[rng.choice(n, h, replace=False)]
            tb, d = once(lambda pts=pts, hd=hd: bind_rbf(pts, hd, "multiquadric", dtype=np.float32))
            tb1 = None
            if n <= 100_000:  # (skipped for 1M, to keep the run short)
                with blas_threads(1):
                    tb1, _ = once(lambda pts=pts, hd=hd: bind_rbf(pts, hd, "multiquadric", dtype=np.float32))
            off = rng.normal(scale=1e-3, size=(h, 3)).astype(np.float32)
            one = best(lambda d=d, off=off: d.apply(off), repeat=5, warmup_seconds=0.05)
            rows.append([f"{n:,}", h, fmt_time(tb), fmt_time(tb1), fmt_time(one), fmt_bytes(d.nbytes())])
            del d
    table(rows, ["vertices", "handles", "bind (once)", "bind, 1 BLAS thread", "1 frame (warm)", "operator"],
          notes=[("bind: one call each (cold), with the run's BLAS threads and with one (not run at 1M vertices, "
                 "to keep the run short); 1 frame: best of 5 after a warm-up")])


def main() -> None:
    args = arguments(__doc__)
    with blas_threads(args.blas_threads):
        header("bench_deform: bound deformers against scipy and numpy", touch=7 * 2**29)
        clock = Stopwatch()
        rng = np.random.default_rng(0)
        section_1(rng)
        clock.lap("section 1")
        section_2()
        clock.lap("section 2")
        section_3(rng)
        clock.lap("section 3")
        print(clock.line())


if __name__ == "__main__":
    main()
