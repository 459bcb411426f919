"""GLB size and write time, plain against quantised (KHR_mesh_quantization), and the
dequantisation error of the quantised file.

Run:  .venv/bin/python benchmarks/bench_gltf.py [--blas-threads N]     (seconds on 2 cores)

The default head (24,591 vertices, 766 more where its UV seams split them in the file, and its
1024 x 1024 texture as a PNG, the same bytes in both files) with N = 10 and 60 morph targets, each
written with a 3-frame weight animation (as `faceanim au ... -o x.glb` does), twice:
- "AU rig": the face's own FACS rig (every AU, its one-sided halves and the emotions, as
  `faceanim au --halves` builds them), the first N in the rig's order;
- "bumps": N synthetic smooth deltas (a Gaussian of 1.5 cm radius, cut at 1e-3 of its peak,
  peaks of a few millimetres to a centimetre).
Sizes are of the whole file and of its data without the texture (the PNG's buffer view taken
off: what quantisation can shrink). Write time is the best of 3 (benchmarks/_timing.py). The
error columns read the quantised file back (pygltflib), dequantise by the spec
(max(q / 32767, -1) times the node scale, plus its translation for positions) and compare with
the float64 input: the largest error of any coordinate, in micrometres and as a share of the
head's bounding-box diagonal, and (err/peak) the worst ratio of a target's largest error to its
own largest displacement. The error is bounded by half a quantisation step, s / 32767 / 2 with s
the largest half-extent of the head (or of a delta, if larger): the quantised file shares one
scale between positions and all deltas.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pygltflib
from _timing import arguments, best, blas_threads, fmt_ratio, header, table

from faceanim.face.face import Face
from faceanim.io.gltf import write_gltf
from faceanim.rig.transfer import ExpressionTransfer, default_model

_DTYPE = {pygltflib.SHORT: np.int16, pygltflib.FLOAT: np.float32}


def read_vec3(gltf: pygltflib.GLTF2, index: int) -> np.ndarray:
    """A VEC3 accessor (dense, strided or sparse), dequantised when normalised."""
    acc = gltf.accessors[index]
    blob = gltf.binary_blob()
    dtype = np.dtype(_DTYPE[acc.componentType])
    a = np.zeros((acc.count, 3), dtype=dtype)
    if acc.bufferView is not None:
        view = gltf.bufferViews[acc.bufferView]
        stride = view.byteStride or 3 * dtype.itemsize
        rows = np.frombuffer(blob, np.uint8, count=acc.count * stride, offset=view.byteOffset).reshape(-1, stride)
        a = rows[:, :3 * dtype.itemsize].copy().view(dtype)
    if acc.sparse is not None:
        sp = acc.sparse
        itype = np.uint16 if sp.indices.componentType == pygltflib.UNSIGNED_SHORT else np.uint32
        idx = np.frombuffer(blob, itype, count=sp.count, offset=gltf.bufferViews[sp.indices.bufferView].byteOffset)
        a[idx] = np.frombuffer(blob, dtype, count=sp.count * 3,
                               offset=gltf.bufferViews[sp.values.bufferView].byteOffset).reshape(-1, 3)
    a = a.astype(np.float64)
    return np.maximum(a / 32767, -1.0) if acc.normalized else a


def errors(path: Path, mesh, shapes) -> tuple[float, float, float]:
    """Largest |dequantised - original| of positions and of morph deltas (metres), and the
    largest delta error of a target over that target's own peak displacement."""
    gltf = pygltflib.GLTF2().load(str(path))
    prim = gltf.meshes[0].primitives[0]
    node = gltf.nodes[0]
    scale = np.array(node.scale or [1, 1, 1])
    centre = np.array(node.translation or [0, 0, 0])
    pos = read_vec3(gltf, prim.attributes.POSITION) * scale + centre
    pos_err = float(np.abs(pos[: mesh.n_vertices] - mesh.vertices).max())
    delta_err = peak_share = 0.0
    for k, d in enumerate(shapes.values()):
        err = float(np.abs(read_vec3(gltf, prim.targets[k]["POSITION"])[: mesh.n_vertices] * scale - d).max())
        delta_err = max(delta_err, err)
        peak = float(np.linalg.norm(d, axis=1).max())
        if peak > 0:
            peak_share = max(peak_share, err / peak)
    return pos_err, delta_err, peak_share


def texture_bytes(path: Path) -> int:
    """Bytes of the GLB's embedded images (their buffer views)."""
    gltf = pygltflib.GLTF2().load(str(path))
    return sum(gltf.bufferViews[im.bufferView].byteLength for im in gltf.images or [] if im.bufferView is not None)


def bumps(mesh, n: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    v = mesh.vertices
    out = {}
    for k, c in enumerate(rng.choice(len(v), size=n, replace=False)):
        w = np.exp(-np.sum((v - v[c]) ** 2, axis=1) / (2 * 0.015**2))
        w[w < 1e-3] = 0
        out[f"bump{k:02d}"] = w[:, None] * rng.normal(scale=0.005, size=3)
    return out


def best_write(path: Path, mesh, shapes, quantize: bool) -> float:
    names = list(shapes)
    times = np.array([0.0, 1.0, 2.0])
    weights = np.zeros((3, len(names)))
    weights[1, 0] = 1.0
    return best(lambda: write_gltf(path, mesh, shapes, times, weights, quantize=quantize), repeat=3, warmup=0)


def main() -> None:
    args = arguments(__doc__)
    with blas_threads(args.blas_threads):
        header("bench_gltf: plain against quantised GLB")
        face = Face.default()
        mesh = face.mesh
        diag = float(np.linalg.norm(np.ptp(mesh.vertices, axis=0)))
        rig = ExpressionTransfer(face).rig(default_model(), sides=True)
        au = rig.blendshape_dict()
        print(f"default face: {mesh.n_vertices} vertices, {mesh.n_faces} triangles, bounding-box diagonal "
              f"{diag * 100:.1f} cm; AU rig: {len(au)} targets")
        print()
        rows = []
        with tempfile.TemporaryDirectory() as tmp:
            for label, source in (("AU rig", au), ("bumps", None)):
                for n in (10, 60):
                    shapes = dict(list(au.items())[:n]) if source is not None else bumps(mesh, n)
                    plain, small = Path(tmp) / "plain.glb", Path(tmp) / "small.glb"
                    t_plain = best_write(plain, mesh, shapes, quantize=False)
                    t_small = best_write(small, mesh, shapes, quantize=True)
                    p_err, d_err, share = errors(small, mesh, shapes)
                    a, b = plain.stat().st_size, small.stat().st_size
                    tex = texture_bytes(plain)
                    assert tex == texture_bytes(small)
                    rows.append([label, n, f"{a / 1e6:.2f}", f"{b / 1e6:.2f}", fmt_ratio(a / b),
                                 f"{(a - tex) / 1e6:.2f}", f"{(b - tex) / 1e6:.2f}", fmt_ratio((a - tex) / (b - tex)),
                                 f"{t_plain:.2f}",
                                 f"{t_small:.2f}", fmt_ratio(t_plain / t_small), f"{p_err * 1e6:.2f}",
                                 f"{d_err * 1e6:.2f}", f"{max(p_err, d_err) / diag:.1e}", f"{share:.1e}"])
        table(rows, ["targets", "N", "plain MB", "quant. MB", "size ratio", "w/o texture: plain MB", "quant. MB",
                     "size ratio", "plain s", "quant. s",
                     "write time ratio", "pos err um", "delta err um", "err/diag", "err/peak"],
              notes=["the baseline is the plain (float32) GLB written in the same run; write times: best of 3",
                     f"texture (PNG, in both files): {tex / 1e6:.2f} MB"])


if __name__ == "__main__":
    main()
