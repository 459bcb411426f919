"""How far do two artists agree? One artist's ARKit and viseme shapes carried onto the other
artist's avatar through faceanim's one registration, scored as faceanim's own shapes are
(``eval_avatar.py``): the ceiling a generated rig can be held to (issue 33).

    python scripts/eval_artists.py A.glb B.glb [--shapes]

Each avatar's head is welded and rigged as ``faceanim rig`` does (``eval_avatar.load_avatar``),
and registered to the generic head (ICT FaceKit). A's shapes reach B so: each of B's vertices has
its point on the generic head (the registration's dense correspondence, ``face_to_head``); A's
vertices have theirs; B's point is found on A's mesh laid out at those head points (the closest
point on A's triangles that the front view sees and whose corners are on the same side of every
slit), and A's displacement there is interpolated, taken into the generic head's frame
(A's registration: ``delta_head = R_A^T delta_A / s_A``) and out into B's (``s_B R_B
delta_head``), as faceanim's retargeting moves every shape. Then per shape, over the vertices the
receiving artist's shape moves (more than 5% of its largest motion): cosine and the relative error
at the best scale (``eval_avatar.compare``). Rows: A's shapes on B against B's artist, faceanim's
on B against B's artist, and the same for A; and what the carrying itself loses: faceanim's shapes
made on A, carried to B, against faceanim's made on B. Shapes either artist left empty are left out.
``--shapes`` prints every shape's figures.

The avatars are used for measuring only; they are never copied into the project.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from eval_avatar import compare, load_avatar, set_summary  # noqa: E402


def head_points(face) -> tuple[np.ndarray, np.ndarray]:
    """(each vertex's point on the generic head at rest (V, 3), the side of each slit of the head
    vertex nearest it (V, S) booleans). Skin or not is not part of it: one artist's eye piece
    must find what the other put in its place, lid or eyeball."""
    from faceanim.face.registration import _head_sides

    head = face.registration.head
    tri, bary = face.correspondence
    corners = head.mesh.faces[tri]
    points = np.einsum("vc,vcd->vd", bary, head.mesh.vertices[corners])
    sides, _ = _head_sides(head)
    return points, sides[corners[np.arange(len(tri)), np.argmax(bary, axis=1)]]


def front_visible(face, resolution: int = 512) -> np.ndarray:
    """(V,) bool: the vertices the front view sees (a depth map along the face's -z)."""
    from faceanim.build.texture import _ortho_frame
    from faceanim.render.bake import EMPTY_DEPTH, ortho_depth

    v = face.mesh.vertices
    rot = _ortho_frame(face.frame.rotation[2])
    lo, hi = v.min(0), v.max(0)
    centre, radius = (lo + hi) / 2, float(np.linalg.norm(hi - lo) / 2) + 1e-9
    scale = (resolution / 2 - 2) / radius
    matrix = scale * rot[:2] * np.array([[1.0], [-1.0]])
    offset = resolution / 2 - matrix @ centre
    depth = ortho_depth(v, face.mesh.faces, matrix, offset, rot[2], (resolution, resolution))
    px = np.clip(np.rint(v @ matrix.T + offset - 0.5).astype(np.int64), 0, resolution - 1)
    d = depth[px[:, 1], px[:, 0]]
    return (d != EMPTY_DEPTH) & (v @ rot[2] >= d - 2.5 / scale)


def carry(src, src_shapes: dict, dst, names) -> dict[str, np.ndarray]:
    """``src``'s shapes ``names`` (each (V_src, 3)) on ``dst``'s vertices (module docstring)."""
    from faceanim.face.registration import _closest_on

    p_src, k_src = head_points(src)
    p_dst, k_dst = head_points(dst)
    faces = src.mesh.faces
    tri_key = k_src[faces]  # (T, 3, K)
    # what the front view sees of the source: a brow card or an eyeline plate over the skin
    # stands for the skin under it, whose head points are the same
    same = (tri_key == tri_key[:, :1]).all(axis=(1, 2)) & front_visible(src)[faces].any(axis=1)
    keys, group = np.unique(k_dst, axis=0, return_inverse=True)
    tri = np.empty(len(p_dst), dtype=np.int64)
    bary = np.empty((len(p_dst), 3))
    for g, key in enumerate(keys):
        pool = np.flatnonzero(same & (tri_key[:, 0] == key).all(axis=1))
        if not len(pool):
            pool = np.arange(len(faces))
        mine = np.flatnonzero(group.ravel() == g)
        t, b = _closest_on(p_src, faces[pool], p_dst[mine])
        tri[mine], bary[mine] = pool[t], b
    rs, rd = src.registration, dst.registration
    out = {}
    for n in names:
        d = np.einsum("vc,vcd->vd", bary, np.asarray(src_shapes[n], dtype=np.float64)[faces[tri]])
        out[n] = (d @ rs.rotation / rs.size_scale) @ (rd.size_scale * rd.rotation).T
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("a", type=Path, help="an avatar (.glb/.vrm) whose face carries an artist's ARKit shapes")
    ap.add_argument("b", type=Path, help="another artist's avatar")
    ap.add_argument("--shapes", action="store_true", help="print every shape's figures")
    args = ap.parse_args(argv)
    A, B = load_avatar(args.a), load_avatar(args.b)
    (fa, auto_a, art_a, empty_a, _), (fb, auto_b, art_b, empty_b, _) = A, B
    names = [n for n in art_a if n in art_b and n not in empty_a and n not in empty_b]
    left = sorted(set(art_a) ^ set(art_b)) + sorted(set(empty_a) | set(empty_b))
    a_on_b, b_on_a = carry(fa, art_a, fb, names), carry(fb, art_b, fa, names)
    # what the carrying itself loses: faceanim's shapes on A carried to B against faceanim's on B
    auto_a_on_b = carry(fa, auto_a.shapes, fb, names)
    tables = {
        f"faceanim's {fa.mesh.name} carried on {fb.mesh.name} (the carry's own loss)":
            {n: compare(auto_a_on_b[n], auto_b.shapes[n]) for n in names},
        f"{fa.mesh.name}'s artist on {fb.mesh.name}": {n: compare(a_on_b[n], art_b[n]) for n in names},
        f"faceanim on {fb.mesh.name}": {n: compare(auto_b.shapes[n], art_b[n]) for n in names},
        f"{fb.mesh.name}'s artist on {fa.mesh.name}": {n: compare(b_on_a[n], art_a[n]) for n in names},
        f"faceanim on {fa.mesh.name}": {n: compare(auto_a.shapes[n], art_a[n]) for n in names},
    }
    print(f"{fa.mesh.name} ({fa.mesh.n_vertices} vertices) and {fb.mesh.name} ({fb.mesh.n_vertices}): "
          f"{len(names)} shapes both artists made; left out: {', '.join(left) or 'none'}\n")
    print("| shapes | set | count | median cosine | median best-scale error | worst cosine |")
    print("|---|---|---:|---:|---:|---|")
    for title, rows in tables.items():
        for label, count, cos, err, _, worst in set_summary(rows):
            print(f"| {title} | {label} | {count} | {cos:.2f} | {err:.2f} | {worst} |")
    if args.shapes:
        print("\n| shape | " + " | ".join(tables) + " |")
        print("|---|" + "---:|" * len(tables))
        for n in names:
            print(f"| {n} | " + " | ".join(f"{t[n][0]:.2f} / {t[n][1]:.2f}" for t in tables.values()) + " |")
        print("\n(cosine / best-scale error)")


if __name__ == "__main__":
    from faceanim.errors import FaceAnimError

    try:
        main()
    except FaceAnimError as exc:  # a missing or damaged avatar: one line, as faceanim's commands say it
        print(f"{Path(__file__).name}: error: {exc}", file=sys.stderr)
        sys.exit(2)
