"""Build faceanim's generic head asset from the ICT FaceKit generic neutral head (MIT licence).

Lee et al. (1999) deform "a previously constructed, animation-ready generic model" onto the
feature points found in photos. Ours is the ICT Face Model's generic neutral head (light-stage
scans, USC ICT, MIT licence: its notice ships as ``assets/LICENSE-ICT-FaceKit.txt``):

- parts kept as separate shells of one mesh: the skin (head, neck, mouth socket, eye sockets),
  gums and tongue, teeth, and the two eyeballs; the transparent overlay shells over the eyes
  (lacrimal fluid, eye blend, eye occlusion) are dropped: they need alpha blending to look right;
- units turned from centimetres to metres; +z forward, +y up, +x the subject's left (as ICT);
- the 478 MediaPipe landmarks detected once on a render of it and stored on its triangles
  (triangle + barycentric), so they follow any deformation of the head;
- its 53 expression blendshapes (Apple ARKit names with ``_L``/``_R``) stored as sparse float16
  deltas (metres): they let the photo pipeline take the smile off a smiling photo;
- ``tongueOut``, which ICT lacks (ARKit's 52nd shape), made here by geometry as Apple's reference
  shows it: the mouth open (ICT's ``jawOpen`` at 0.45: lips, jaw, teeth) and the tongue out over
  the lower lip. ICT's tongue is fused with its gums in one shell, so the tongue is the part of
  that shell away from the teeth (over 3 mm) between the mouth floor and the palate, in front of
  the throat; it is pushed 4.5 cm forward, flattened to 8 mm and narrowed by a quarter as it
  leaves the mouth, resting 2 mm above the lowered lower lip, its tip bending 4 mm down past the
  lips; the push
  fades in from the root and out towards the gums (:func:`tongue_out`). Pushed out with the lips
  shut, the tongue went through them;
- ICT's 100 PCA identity modes (``identity_modes.npz``: light-stage scans of many people; a head is
  ``neutral + sum_i w_i mode_i`` with ``w_i ~ N(0, 1)``), all 100 kept, each stored as int8 with a
  float32 scale of its own (metres per step): 4.5 MB in the asset, a sampled head within 0.1 mm
  RMS of the float16 source. The table behind that choice (``--modes-table``):

  | modes | storage | asset MB | truncation RMS mm | rounding RMS mm |
  |---:|---|---:|---:|---:|
  | 30 | int8 | 1.4 | 1.10 | 0.10 |
  | 50 | int8 | 2.3 | 0.69 | 0.10 |
  | 50 | float16 | 5.7 | 0.69 | 0 |
  | 100 | int8 | 4.5 | 0 | 0.10 |
  | 100 | float16 | 11.4 | 0 | 0 |

  (RMS distance over the kept vertices of 50 heads sampled with ``w ~ N(0, 1)``; a sampled head
  is 5.8 mm RMS from the mean head.)

Usage: ``python scripts/build_generic_head.py ../shared/data/ict-facekit [--keep-landmarks]`` (writes
``src/faceanim/assets/generic_head.npz``; the result is committed, users never run this).
"""

from __future__ import annotations

import argparse
import gzip
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

ASSETS = ROOT / "src" / "faceanim" / "assets"
# ICT vertex ranges (connected components of generic_neutral_mesh.obj, checked in main())
PARTS = {"skin": (0, 14062), "gums_tongue": (14062, 17039), "teeth": (17039, 21451),
         "eyeball_L": (21451, 23021), "eyeball_R": (23021, 24591)}
KEEP = 24591
# MediaPipe's inner-lip points (the corners 78 and 308 excepted)
UPPER_INNER_LIP = (191, 80, 81, 82, 13, 312, 311, 310, 415)
LOWER_INNER_LIP = (95, 88, 178, 87, 14, 317, 402, 318, 324)
CM = 0.01


def obj_vertices(path: Path) -> np.ndarray:
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as fh:
        rows = [line.split()[1:4] for line in fh if line.startswith("v ")]
    return np.array(rows, dtype=np.float64)


# the tongue in the generic head's frame (metres; the gums_tongue shell): what lies over TONGUE_GAP from
# the teeth, between the mouth floor and the palate (heights) and in front of the throat (depth)
TONGUE_GAP, TONGUE_FLOOR, TONGUE_TOP, TONGUE_ROOT, TONGUE_LENGTH = 0.003, -0.046, -0.026, 0.03, 0.045
TONGUE_JAW = 0.45  # how far tongueOut opens the mouth (of ICT's jawOpen)
TONGUE_PUSH, TONGUE_DROP = 0.045, 0.004  # how far the tip goes forward and bends down
TONGUE_THICK, TONGUE_NARROW = 0.008, 0.25  # the tongue's height out of the mouth; its width lost
TONGUE_CLEAR = 0.002  # its underside over the lower inner lip
TONGUE_LIP_DEPTH = 0.01  # the lips' depth from their inner edge: past it the tip bends down


def tongue_out(vertices: np.ndarray, jaw: np.ndarray, lower_lip: np.ndarray, lower_lip_jaw: np.ndarray) -> np.ndarray:
    """(V, 3) the ``tongueOut`` displacement of the head ``vertices`` (metres, ICT's parts), given
    ICT's ``jawOpen`` displacement ``jaw`` (V, 3) and the lower inner lip's point ``lower_lip``
    (MediaPipe's 14) with its ``jawOpen`` motion: the mouth opens by ``TONGUE_JAW`` of ``jaw``,
    and each tongue vertex, with a weight ``w`` rising from 0 at the root to 1 at the tip and
    fading to 0 near the gums, moves forward by ``TONGUE_PUSH * w``, towards its place in a
    ``TONGUE_THICK`` slab resting over the opened lower lip (its height in the tongue kept) by
    ``w``, in by ``TONGUE_NARROW * w`` of its width, and, once past the lips, down by up to
    ``TONGUE_DROP`` over the lower lip."""
    from scipy.spatial import cKDTree

    from faceanim.face.regions import smoothstep

    g = np.arange(*PARTS["gums_tongue"])
    gap, _ = cKDTree(vertices[slice(*PARTS["teeth"])]).query(vertices[g])
    x, y, z = vertices[g, 0], vertices[g, 1], vertices[g, 2]
    tongue = (gap > TONGUE_GAP) & (y > TONGUE_FLOOR) & (y < TONGUE_TOP) & (z > TONGUE_ROOT)
    w = smoothstep((z - TONGUE_ROOT - 0.01) / TONGUE_LENGTH) * smoothstep((gap - TONGUE_GAP) / 0.004) * tongue
    out = TONGUE_JAW * np.asarray(jaw, dtype=np.float64)
    height = np.clip((y - TONGUE_FLOOR) / (TONGUE_TOP - TONGUE_FLOOR), 0.0, 1.0)
    slab = lower_lip[1] + TONGUE_JAW * lower_lip_jaw[1] + TONGUE_CLEAR + height * TONGUE_THICK
    out[g, 2] += TONGUE_PUSH * w
    past = z + out[g, 2] - lower_lip[2] - TONGUE_LIP_DEPTH  # how far out past the lips it ends
    out[g, 1] += w * (slab - y - out[g, 1]) - TONGUE_DROP * smoothstep(past / TONGUE_LIP_DEPTH)
    out[g, 0] -= TONGUE_NARROW * w * x
    return out


def identity_modes(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """ICT's identity modes on the kept vertices as (int8 (K, KEEP, 3), float32 (K,) metres per
    step): each mode rounded on a scale of its own, its largest component at 127 steps."""
    modes = np.load(path)["modes"][:, :KEEP].astype(np.float64) * CM
    scale = np.abs(modes).max(axis=(1, 2)) / 127.0
    return np.round(modes / scale[:, None, None]).astype(np.int8), scale.astype(np.float32)


def modes_table(path: Path, samples: int = 50) -> None:
    """Print the accuracy/size table of the module docstring."""
    import zlib

    modes = np.load(path)["modes"][:, :KEEP].astype(np.float64) * CM
    q, scale = identity_modes(path)
    w = np.random.default_rng(0).standard_normal((samples, len(modes)))
    full = np.einsum("sk,kvd->svd", w, modes)
    print("| modes | storage | asset MB | truncation RMS mm | rounding RMS mm |")
    for k in (30, 50, 100):
        kept = np.einsum("sk,kvd->svd", w[:, :k], modes[:k])
        quant = np.einsum("sk,kvd->svd", w[:, :k], q[:k] * scale[:k, None, None].astype(np.float64))
        for kind, raw, err in (("int8", q[:k].tobytes(), quant - kept),
                               ("float16", modes[:k].astype(np.float16).tobytes(), kept.astype(np.float16) - kept)):
            print(f"| {k} | {kind} | {len(zlib.compress(raw, 6)) / 1e6:.1f} | "
                  f"{1e3 * np.sqrt(np.mean((full - kept) ** 2)) * np.sqrt(3):.2f} | "
                  f"{1e3 * np.sqrt(np.mean(err ** 2)) * np.sqrt(3):.2f} |")
    print(f"a sampled head is {1e3 * np.sqrt(np.mean(full ** 2)) * np.sqrt(3):.1f} mm RMS from the mean head")


def detected_landmarks(mesh, faces: np.ndarray, vertices: np.ndarray, ict: Path):
    """The 478 MediaPipe landmarks detected on a render of the head, as (triangles, barycentric)."""
    from faceanim.face.landmarks import detect_landmarks

    lms = detect_landmarks(mesh)
    order = np.argsort(lms.indices)
    assert (lms.indices[order] == np.arange(478)).all()
    tri, bary = lms.triangles[order].copy(), lms.barycentric[order].copy()
    positions = lms.positions[order]
    # the face mesh's 468 surface points lie on the skin: a ray through an open eye's lid margin
    # can land on the eyeball behind it (then a blink would not move the lid's landmarks)
    skin_tri = (faces < PARTS["skin"][1]).all(axis=1)
    off_skin = np.flatnonzero(~skin_tri[tri[:468]])
    if len(off_skin):
        pos, _, t = mesh.closest_points(positions[off_skin], skin_tri)
        tri[off_skin] = t
        bary[off_skin] = mesh.barycentric(pos, t)
    # the lips are closed: detection puts the upper and lower inner-lip points on one spot, and the
    # ray lands on one lip. Attach each to its own lip: the lower lip is what jawOpen moves down.
    drop = -(obj_vertices(ict / "jawOpen.obj")[:KEEP] * CM - vertices)[:, 1]
    moving = drop > 0.5 * drop[faces].max()
    lower_tri = moving[faces].all(axis=1)
    upper_tri = (~moving[faces]).all(axis=1)
    for group, allowed in ((LOWER_INNER_LIP, lower_tri), (UPPER_INNER_LIP, upper_tri)):
        pos, _, t = mesh.closest_points(positions[list(group)], allowed)
        tri[list(group)] = t
        bary[list(group)] = mesh.barycentric(pos, t)

    return tri, bary


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("ict", type=Path, help="the ict-facekit folder (generic_neutral_mesh.obj and the 53 shapes)")
    parser.add_argument("--keep-landmarks", action="store_true",
                        help="reuse the landmarks of the asset already there instead of detecting them "
                             "(detection moves them by float noise, and everything built on them would move)")
    parser.add_argument("--modes-table", action="store_true",
                        help="print the identity modes' accuracy/size table and stop")
    args = parser.parse_args(argv)
    if args.modes_table:
        modes_table(args.ict / "identity_modes.npz")
        return

    from faceanim.face.mesh import Mesh
    from faceanim.io.meshio import load_mesh

    src = load_mesh(args.ict / "generic_neutral_mesh.obj")
    labels = src.vertex_components
    for k, (name, (a, b)) in enumerate(PARTS.items()):
        if name in ("skin", "gums_tongue") and len(np.unique(labels[a:b])) != 1:
            raise SystemExit(f"{name}: vertices {a}..{b} are not one shell; is this the ICT generic head?")
    # polygons wholly inside the kept vertices (the dropped shells come last)
    sizes = np.asarray(src.polygon_sizes)
    poly_of_tri = np.repeat(np.arange(len(sizes)), sizes - 2)
    keep_poly = np.ones(len(sizes), bool)
    np.logical_and.at(keep_poly, poly_of_tri, (src.faces < KEEP).all(axis=1))
    keep_tri = keep_poly[poly_of_tri]
    vertices = src.vertices[:KEEP] * CM
    faces = src.faces[keep_tri]
    mesh = Mesh(vertices, faces, name="generic_head", source="faceanim:generic_head")

    if args.keep_landmarks:
        with np.load(ASSETS / "generic_head.npz") as old:
            tri, bary = old["landmark_triangles"].astype(np.int64), old["landmark_barycentric"].astype(np.float64)
    else:
        tri, bary = detected_landmarks(mesh, faces, vertices, args.ict)

    shapes, names = {}, []
    for path in sorted(args.ict.glob("*.obj*")):
        name = path.name.split(".")[0]
        if name == "generic_neutral_mesh":
            continue
        delta = (obj_vertices(path)[:KEEP] * CM) - vertices
        rows = np.flatnonzero(np.abs(delta).max(axis=1) > 1e-7)
        shapes[f"shape_rows_{name}"] = rows.astype(np.int32)
        shapes[f"shape_delta_{name}"] = delta[rows].astype(np.float16)
        names.append(name)
    if len(names) != 53:
        raise SystemExit(f"expected the 53 ICT expression shapes, found {len(names)}")
    jaw = obj_vertices(args.ict / "jawOpen.obj")[:KEEP] * CM - vertices
    corners = faces[tri[14]]
    delta = tongue_out(vertices, jaw, bary[14] @ vertices[corners], bary[14] @ jaw[corners])
    rows = np.flatnonzero(np.abs(delta).max(axis=1) > 1e-7)
    shapes["shape_rows_tongueOut"] = rows.astype(np.int32)
    shapes["shape_delta_tongueOut"] = delta[rows].astype(np.float16)
    names.append("tongueOut")

    modes, mode_scale = identity_modes(args.ict / "identity_modes.npz")

    ASSETS.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        ASSETS / "generic_head.npz",
        vertices=vertices.astype(np.float32),
        faces=faces.astype(np.int32),
        polygon_sizes=sizes[keep_poly].astype(np.int8),
        part_names=np.array(list(PARTS)),
        part_ranges=np.array(list(PARTS.values()), dtype=np.int32),
        landmark_triangles=tri.astype(np.int32),
        landmark_barycentric=bary.astype(np.float32),
        shape_names=np.array(names),
        identity_modes=modes,
        identity_scale=mode_scale,
        **shapes,
    )
    (ASSETS / "LICENSE-ICT-FaceKit.txt").write_text(
        "faceanim's generic head (generic_head.npz) is derived from the ICT Face Model\n"
        "(ICT-VGL/ICT-FaceKit, FaceXModel/generic_neutral_mesh.obj, its 53 expression shapes and its\n"
        "100 identity modes identity000 ... identity099): parts kept, units in metres, expression\n"
        "shapes stored as deltas, identity modes as deltas rounded to int8 with a scale per mode,\n"
        "and a tongueOut shape made by faceanim from the tongue's geometry.\n\n"
        + (args.ict / "LICENSE").read_text())
    print(f"wrote {ASSETS / 'generic_head.npz'}: {len(vertices)} vertices, {len(faces)} triangles, "
          f"{len(names)} shapes")


if __name__ == "__main__":
    main()
