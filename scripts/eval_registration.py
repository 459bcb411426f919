"""How close `faceanim rig`'s ARKit shapes come to the truth on heads it has never seen, in another
topology, vertex order, unit and axes.

    python scripts/eval_registration.py ../shared/data [--seeds 100 101 102 103] [--vertices 8000 3000]
                                        [--sheet docs/registration_sheet.png]

For each seed an ICT identity is sampled (weights ~ N(0, 1) over ICT's 100 identity modes, from
the shared float16 modes, not the asset's int8 ones), its head (skin, mouth, teeth, eyeballs) is
decimated with fast-simplification (quadric error, a well-kept library) to each vertex count, its
vertex order shuffled, turned to centimetres with +z up and -y forward, landmarks detected
(``--forward -y --up +z``), and rigged with ``arkit``. Each generated shape is compared with the
truth: the identity plus ICT's own shape (ICT's model adds its expression deltas to any identity),
carried to the new vertices through their closest points on the full-resolution head and into the
new units and axes. Over the vertices the true shape moves (more than 5% of its largest motion;
for ``eyeLook*`` off the eyeballs, which faceanim turns and ICT does not):

- relative error ``|g - r| / |r|``, cosine ``<g, r> / |g| |r|``;
- blink closure: how much of the eyeball is still seen from the front after ``eyeBlink*`` at 1,
  as a share of what is seen before (0: closed; rays straight forward from the eyeball's
  front-facing vertices that hit no skin).

Seeds 0-1 were used while building the registration; report on others (the default 100-103).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from faceanim.autorig import auto_rig
from faceanim.face.face import Face, landmarks_478
from faceanim.face.landmarks import detect_landmarks
from faceanim.face.mesh import Mesh

sys.path.insert(0, str(Path(__file__).resolve().parent))
from eval_rig import ict_real, obj_vertices, sheet  # noqa: E402  (the ICT shapes read as eval_rig reads them)

KEEP = 24591  # ICT's skin, gums and tongue, teeth and eyeballs (the generic head's parts)
EYEBALLS = 21451  # ICT's eyeballs are its vertices from here to KEEP
MOVING = 0.05
# +z up, -y forward: x stays, y_new = -z_old, z_new = y_old
AXES = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])


def ict_faces(path: Path) -> np.ndarray:
    from faceanim.io.meshio import load_mesh

    m = load_mesh(path)
    return m.faces[(m.faces < KEEP).all(axis=1)]


def true_shapes(ict: Path) -> dict[str, np.ndarray]:
    """ICT's own ARKit shapes (``eval_rig.ict_real``) on the kept vertices."""
    neutral = obj_vertices(ict / "generic_neutral_mesh.obj")
    return {n: d[:KEEP] for n, d in ict_real(ict, neutral).items()}


def remeshed(vertices: np.ndarray, faces: np.ndarray, count: int, seed: int):
    """(Mesh in cm, +z up, -y forward, shuffled; per new vertex (source triangle, barycentric))."""
    import fast_simplification
    import trimesh

    ratio = 1.0 - min(1.0, count / len(vertices))
    v, f = fast_simplification.simplify(vertices.astype(np.float32), faces.astype(np.int32), target_reduction=ratio)
    v = np.asarray(v, dtype=np.float64)
    f = np.asarray(f)
    # each new vertex onto the closest point of the piece (skin, an eyeball, a tooth row) its own
    # piece came from: a decimated eyeball vertex can sink nearer to the lid than to the eyeball

    src_piece = Mesh(vertices, faces).vertex_components[faces[:, 0]]
    new_piece = Mesh(v, f).vertex_components
    tm = trimesh.Trimesh(vertices, faces, process=False)
    _, _, tri = trimesh.proximity.closest_point(tm, v)
    bary = np.zeros((len(v), 3))
    for piece in np.unique(new_piece):
        mine = np.flatnonzero(new_piece == piece)
        origin = np.bincount(src_piece[tri[mine]]).argmax()
        pool = np.flatnonzero(src_piece == origin)
        part = trimesh.Trimesh(vertices, faces[pool], process=False)
        closest, _, t = trimesh.proximity.closest_point(part, v[mine])
        tri[mine] = pool[t]
        bary[mine] = trimesh.triangles.points_to_barycentric(vertices[faces[tri[mine]]], closest)
    perm = np.random.default_rng(seed).permutation(len(v))
    inv = np.argsort(perm)
    mesh = Mesh((v @ AXES.T)[perm], inv[f], name=f"ict{seed}_{len(v)}")
    return mesh, tri[perm], bary[perm]


def carry(delta: np.ndarray, faces: np.ndarray, tri: np.ndarray, bary: np.ndarray) -> np.ndarray:
    return np.einsum("nk,nkd->nd", bary, delta[faces[tri]]) @ AXES.T


def scores(gen: np.ndarray, real: np.ndarray, keep: np.ndarray | None = None) -> tuple[float, float]:
    m = np.linalg.norm(real, axis=1)
    region = m > MOVING * m.max()
    if keep is not None:
        region &= keep
    g, r = gen[region].ravel(), real[region].ravel()
    return (float(np.linalg.norm(g - r) / np.linalg.norm(r)),
            float(g @ r / max(np.linalg.norm(g) * np.linalg.norm(r), 1e-30)))


def eye_visible(face: Face, vertices: np.ndarray, eyeball: np.ndarray, side: str) -> float:
    """How much of one eyeball is seen from the front with the mesh at ``vertices``: the share of
    its front-facing vertices (``eyeball`` (V,) bool; ``side`` L or R, the subject's) from which a
    ray straight forward leaves without hitting the skin."""
    mesh = face.mesh.with_vertices(vertices)
    fwd = face.frame.rotation[2]
    x = face.frame.to_local(face.mesh.vertices)[:, 0]
    normals = mesh.vertex_normals()
    mine = np.flatnonzero(eyeball & ((x > 0) == (side == "L")) & (normals @ fwd > 0.7))
    skin_tris = np.flatnonzero(face.skin[face.mesh.faces].all(axis=1))
    skin_mesh = Mesh(vertices, face.mesh.faces[skin_tris])
    hit, _, _ = skin_mesh.cast_rays(vertices[mine] + 1e-4 * face.frame.iod * fwd, np.tile(fwd, (len(mine), 1)))
    return float(1.0 - hit.mean()) if len(mine) else float("nan")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", type=Path, help="the shared data folder (ict-facekit/)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[100, 101, 102, 103])
    ap.add_argument("--vertices", type=int, nargs="+", default=[8000, 3000])
    ap.add_argument("--sheet", type=Path, help="write a picture sheet of generated shapes here")
    ap.add_argument("--verbose", action="store_true", help="every shape's figures")
    args = ap.parse_args(argv)
    ict = args.data / "ict-facekit"
    neutral = obj_vertices(ict / "generic_neutral_mesh.obj")[:KEEP]
    faces = ict_faces(ict / "generic_neutral_mesh.obj")
    modes = np.load(ict / "identity_modes.npz")["modes"][:, :KEEP].astype(np.float64)
    real = true_shapes(ict)
    eyeball_tris = np.flatnonzero((faces >= EYEBALLS).all(axis=1))
    rows, sheet_rows = [], []
    print("| identity | vertices | time s | shapes | median rel. error | median cosine | worst (error) | "
          "eyeball seen after blink L / R |")
    print("|---|---:|---:|---:|---:|---:|---|---|")
    for seed in args.seeds:
        w = np.random.default_rng(seed).standard_normal(len(modes))
        head = neutral + np.einsum("k,kvd->vd", w, modes)
        for count in args.vertices:
            mesh, tri, bary = remeshed(head, faces, count, seed)
            t = time.perf_counter()
            face = Face(mesh, landmarks_478(mesh, detect_landmarks(mesh, forward="-y", up="+z")))
            auto = auto_rig(face, ["arkit"])
            took = time.perf_counter() - t
            err, cos = {}, {}
            # faceanim's eyeLook* also turn the eyeballs (ICT's move the lids only): scored off them
            lids = ~np.isin(tri, eyeball_tris)
            for name, delta in real.items():
                if name in auto.shapes:
                    err[name], cos[name] = scores(auto.shapes[name], carry(delta, faces, tri, bary),
                                                  lids if name.startswith("eyeLook") else None)
            eyeball = np.isin(tri, eyeball_tris)
            blink = [eye_visible(face, mesh.vertices + auto.shapes[f"eyeBlink{s}"], eyeball, s[0])
                     / eye_visible(face, mesh.vertices, eyeball, s[0]) for s in ("Left", "Right")]
            truth_blink = [eye_visible(face, mesh.vertices + carry(real[f"eyeBlink{s}"], faces, tri, bary), eyeball, s[0])
                           / eye_visible(face, mesh.vertices, eyeball, s[0]) for s in ("Left", "Right")]
            worst = sorted(err.items(), key=lambda kv: -kv[1])[:3]
            rows.append((np.median(list(err.values())), np.median(list(cos.values())), blink))
            print(f"| seed {seed} | {mesh.n_vertices} | {took:.1f} | {len(err)} | {np.median(list(err.values())):.3f} | "
                  f"{np.median(list(cos.values())):.3f} | " + ", ".join(f"{n} {v:.2f}" for n, v in worst)
                  + f" | {blink[0]:.2f} / {blink[1]:.2f} (truth {truth_blink[0]:.2f} / {truth_blink[1]:.2f}) |", flush=True)
            if args.verbose:
                for n in err:
                    print(f"    {n}: error {err[n]:.3f} cosine {cos[n]:.3f}")
            if args.sheet and len(sheet_rows) < 4:
                # shown upright: the renderer looks along +z with +y up
                upright = Face(mesh.with_vertices(mesh.vertices @ AXES), face.landmarks @ AXES)
                truth = {n: carry(d, faces, tri, bary) @ AXES for n, d in real.items()}
                sheet_rows.append((upright, truth, f"truth {mesh.name}"))
                sheet_rows.append((upright, {n: d @ AXES for n, d in auto.shapes.items()}, f"faceanim {mesh.name}"))
    e = np.array([r[0] for r in rows])
    c = np.array([r[1] for r in rows])
    b = np.array([r[2] for r in rows])
    print(f"\nover all heads: median relative error {np.median(e):.3f} (worst head {e.max():.3f}), "
          f"median cosine {np.median(c):.3f} (worst head {c.min():.3f}), eyeball seen after a blink at most {b.max():.2f}")
    if args.sheet:
        sheet(args.sheet, sheet_rows)


if __name__ == "__main__":
    main()
