"""Dirichlet free-form deformation (Lee et al. 1999): binding a head-sized mesh to ~550 control
points, and the bound operator's frames, against the project's thin-plate spline on the same points.

    .venv/bin/python benchmarks/bench_ffd.py [--blas-threads N]          (about a minute on 2 cores)

Mesh: the whole default head (24,591 vertices with its eyeballs, teeth, gums and tongue;
metres). Control points: the head's vertices nearest its 478 landmarks (the landmarks lie on
triangles; a vertex two landmarks share counts once), more vertices spread by farthest-point
sampling up to 523, and the paper's 27 enclosing points (``enclosing_points``): 550 sites,
the paper's use (feature points on the head plus 27 around it) with several times MPEG-4's 84
FDPs. Offsets: random, 1 mm.

1. Bind (cold: the triangulation and the sparse Sibson coordinates; best of 3 fresh binds,
   interleaved with the baseline) and apply (warm: one frame, best of 30; a 100-frame batch,
   best of 3), for:
   - baseline, ``bind_rbf(..., "thin_plate_spline", smoothing=0)``: the project's global TPS
     through the same points (a dense (V, H) operator; it too reproduces affine motions);
   - faceanim ``dirichlet_ffd``: the sparse (V, H) Sibson coordinates (``DirichletFFD``).
   Also: operator memory, nonzeros per row, and how exactly each reproduces an affine motion of
   all control points (both should, to rounding).
2. Bind time over the number of control points (80, 550 and 2,000 surface points + the 27), for
   the same 24,591 vertices, both methods.

Compare the ratio columns; wall-clock times depend on the machine's load and are never asserted.
"""

from __future__ import annotations

import numpy as np
from _timing import (
    Row,
    Stopwatch,
    arguments,
    best,
    blas_threads,
    fmt_bytes,
    fmt_time,
    header,
    interleaved,
    speed_table,
    table,
    traced,
)

from faceanim.deform.ffd import DirichletFFD, dirichlet_ffd, enclosing_points
from faceanim.deform.rbf import bind_rbf
from faceanim.face.default import default_face, default_landmarks

N_FRAMES = 100
TPS = "thin_plate_spline"
BIND, WARM1, WARMN = "bind (cold)", "1 frame, warm", f"{N_FRAMES} frames, warm"
BASE, FFD = "bind_rbf thin-plate spline (dense W)", "dirichlet_ffd (sparse Sibson W)"


def farthest(points: np.ndarray, chosen: np.ndarray, n: int) -> np.ndarray:
    """``n`` more indices of ``points``, each the farthest from all chosen so far."""
    d = np.min(np.linalg.norm(points[:, None] - points[chosen][None], axis=-1), axis=1)
    out = []
    for _ in range(n):
        i = int(np.argmax(d))
        out.append(i)
        d = np.minimum(d, np.linalg.norm(points - points[i], axis=1))
    return np.array(out, dtype=np.int64)


def landmark_vertices(mesh) -> np.ndarray:
    """The vertex nearest each landmark (the corner of its triangle with the largest barycentric
    weight), each vertex once, in landmark order."""
    lm = default_landmarks()
    corner = mesh.faces[lm.triangles, np.argmax(lm.barycentric, axis=1)]
    return np.array(list(dict.fromkeys(corner.tolist())), dtype=np.int64)


def sites_for(verts: np.ndarray, n_surface: int, landmarks: np.ndarray) -> np.ndarray:
    """``n_surface`` control points on the face (landmark vertices first, then farthest-point
    samples) and the 27 enclosing points."""
    base = landmarks[:n_surface]
    more = farthest(verts, base, n_surface - base.size) if n_surface > base.size else np.zeros(0, np.int64)
    return np.vstack([verts[np.r_[base, more]], enclosing_points(verts)])


def affine_error(deformer, sites: np.ndarray, verts: np.ndarray) -> float:
    """max |moved - A x - t| when all control points move by one affine map (A near identity)."""
    rng = np.random.default_rng(1)
    A, t = np.eye(3) + 0.05 * rng.normal(size=(3, 3)), 0.01 * rng.normal(size=3)
    return float(np.abs(deformer.apply(sites @ A.T + t - sites) - (verts @ A.T + t)).max())


def main() -> None:
    args = arguments(__doc__)
    with blas_threads(args.blas_threads):
        header("bench_ffd: Dirichlet FFD (Sibson coordinates) against the thin-plate spline", touch=2**29)
        clock = Stopwatch()
        face = default_face()
        rng = np.random.default_rng(0)
        verts = face.vertices
        marks = landmark_vertices(face)
        sites = sites_for(face.vertices, 523, marks)
        h = len(sites)
        one = rng.normal(scale=1e-3, size=(h, 3))
        frames = rng.normal(scale=1e-3, size=(N_FRAMES, h, 3))

        def bind_base():
            return bind_rbf(verts, sites, TPS, smoothing=0.0)

        def bind_ffd():
            return dirichlet_ffd(sites, verts)

        # section 1: one traced bind each (memory; also the warm-up of imports and caches)
        base, _, peak_base = traced(bind_base)
        ffd, _, peak_ffd = traced(bind_ffd)
        system = DirichletFFD(sites)
        t_tri = best(lambda: DirichletFFD(sites), repeat=3, warmup=0)
        t_coords = best(lambda: system.coordinates(verts), repeat=3, warmup=0)
        cold = interleaved({BASE: bind_base, FFD: bind_ffd}, repeat=3, warmup=0)
        warm = interleaved({BASE: lambda: base.apply(one), FFD: lambda: ffd.apply(one)},
                           repeat=30, warmup=3, warmup_seconds=0.2)
        batch = interleaved({BASE: lambda: base.apply(frames), FFD: lambda: ffd.apply(frames)}, repeat=3, warmup=1)
        nnz = ffd.weights.nnz / ffd.n_vertices
        rows = [Row(BIND, BASE, cold[BASE], baseline=True, note="LU of the (H + 4) system, W = basis @ inverse"),
                Row(BIND, FFD, cold[FFD],
                    note=f"Delaunay {fmt_time(t_tri)} + coordinates {fmt_time(t_coords)} (best of 3 each)"),
                Row(WARM1, BASE, warm[BASE], baseline=True),
                Row(WARM1, FFD, warm[FFD]),
                Row(WARMN, BASE, batch[BASE], N_FRAMES, True, note="(F, V, 3)"),
                Row(WARMN, FFD, batch[FFD], N_FRAMES, note="(F, V, 3)")]
        print(f"## default head: {len(verts)} vertices, {h} control points ({len(marks)} landmark vertices + "
              f"{h - 27 - len(marks)} spread = {h - 27} on the head + 27 enclosing), "
              f"{system.n_tetrahedra} Delaunay tetrahedra\n")
        speed_table(rows, notes=[
            (f"Sibson coordinates: {nnz:.1f} nonzeros per row on average (natural neighbours), "
            f"max {np.diff(ffd.weights.indptr).max()}; the TPS weights are dense ({h} per row)"),
            (f"affine motion of all control points, max |moved - affine image| (m; the head is "
            f"{np.ptp(verts[:, 1]):.2f} m tall): TPS {affine_error(base, sites, verts):.1e}, "
            f"DFFD {affine_error(ffd, sites, verts):.1e}"),
            (f"partition of unity, max |row sum - 1|: DFFD "
            f"{np.abs(np.asarray(ffd.weights.sum(axis=1)).ravel() - 1).max():.1e}")])
        table([[BASE, fmt_bytes(base.nbytes()), fmt_bytes(peak_base)],
               [FFD, fmt_bytes(ffd.nbytes()), fmt_bytes(peak_ffd)]],
              ["method", "operator", "peak: bind"],
              notes=[("operator: LinearDeformer.nbytes() (after the frames above, with its evaluation forms); "
                     "peak: tracemalloc during one bind")])
        clock.lap("bind and apply")

        # section 2: bind time over the number of control points
        out = []
        for n in (80, 523, 2000):
            s = sites_for(face.vertices, n, marks)
            times = interleaved({BASE: lambda s=s: bind_rbf(verts, s, TPS, smoothing=0.0),
                                 FFD: lambda s=s: dirichlet_ffd(s, verts)}, repeat=2, warmup=0)
            d = dirichlet_ffd(s, verts)
            out.append([f"{len(s)}", fmt_time(times[BASE]), fmt_time(times[FFD]),
                        f"{times[BASE] / times[FFD]:.2f}x", f"{d.weights.nnz / d.n_vertices:.1f}"])
        table(out, ["control points", "TPS bind", "DFFD bind", "TPS / DFFD", "DFFD nonzeros per row"],
              title=f"## bind time over the number of control points ({len(verts)} vertices; best of 2, interleaved)")
        clock.lap("scaling")
        print(clock.line())


if __name__ == "__main__":
    main()
