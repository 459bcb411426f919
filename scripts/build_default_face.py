"""Build faceanim's embedded default face from a real photograph.

The photo is scikit-image's ``astronaut`` (Eileen Collins, NASA, public domain). The MediaPipe
face mesh (model inside the ``mediapipe==0.10.21`` wheel, ``refine_landmarks=True``) gives 478
3D landmarks; the mesh uses the face-mesh topology (triangles recovered from MediaPipe's
tesselation edge list), the eye openings are closed over the iris landmarks and the mouth
opening is closed by a recessed mouth cavity so that an opening mouth shows a dark interior.

Writes ``src/faceanim/assets/default_face.npz`` and ``default_face.png``. Run it with
``python scripts/build_default_face.py``; the result is committed, so users never need it.
"""

from __future__ import annotations

import sys
from collections import Counter
from pathlib import Path

import numpy as np
from matplotlib.path import Path as Polygon2D
from PIL import Image
from scipy.spatial import Delaunay

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from faceanim.face.landmarks import detect_landmarks_in_image

ASSETS = ROOT / "src" / "faceanim" / "assets"

RIGHT_EYE_RING = [33, 7, 163, 144, 145, 153, 154, 155, 133, 173, 157, 158, 159, 160, 161, 246]
LEFT_EYE_RING = [263, 249, 390, 373, 374, 380, 381, 382, 362, 398, 384, 385, 386, 387, 388, 466]
INNER_LIP_RING = [78, 95, 88, 178, 87, 14, 317, 402, 318, 324, 308, 415, 310, 311, 312, 13,
                  82, 81, 80, 191]
RIGHT_IRIS = [468, 469, 470, 471, 472]
LEFT_IRIS = [473, 474, 475, 476, 477]


def tesselation_triangles() -> np.ndarray:
    """Triangles of the MediaPipe face mesh from its tesselation edge list.

    Every face is a 3-cycle of the edge graph; the graph also has two 3-cycles that are not
    faces (each of their edges is already shared by two faces), which are dropped.
    """
    import mediapipe as mp

    edges = {tuple(sorted(e)) for e in mp.solutions.face_mesh_connections.FACEMESH_TESSELATION}
    neighbours: dict[int, set[int]] = {}
    for a, b in edges:
        neighbours.setdefault(a, set()).add(b)
        neighbours.setdefault(b, set()).add(a)
    cycles = {tuple(sorted((a, b, c))) for a, b in edges for c in neighbours[a] & neighbours[b]}
    use = Counter()
    for a, b, c in cycles:
        use.update([(a, b), (b, c), (a, c)])
    faces = [t for t in cycles if not all(use[e] == 3 for e in [(t[0], t[1]), (t[1], t[2]), (t[0], t[2])])]
    return np.array(sorted(faces), dtype=np.int64)


def pull_inside(ring: list[int], inner: list[int], pix: np.ndarray) -> None:
    """Move iris points hidden under an eyelid (outside the eye opening) just inside it."""
    poly = Polygon2D(pix[ring, :2])
    centre = pix[inner[0]]
    for i in inner[1:]:
        t = 1.0
        while not poly.contains_point(centre[:2] + t * (pix[i, :2] - centre[:2])) and t > 0:
            t -= 0.05
        if t < 1.0:
            pix[i] = centre + 0.9 * t * (pix[i] - centre)


def cap(ring: list[int], inner: list[int], points2d: np.ndarray) -> np.ndarray:
    """Triangulate a hole bounded by ``ring`` with interior points ``inner`` (2D Delaunay)."""
    ids = np.array(ring + inner)
    tri = Delaunay(points2d[ids])
    poly = Polygon2D(points2d[ring])
    centroids = points2d[ids][tri.simplices].mean(axis=1)
    keep = poly.contains_points(centroids)
    return ids[tri.simplices[keep]]


def orient_towards_viewer(faces: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Consistent winding with normals pointing to the camera (+z in face space)."""
    import trimesh

    tm = trimesh.Trimesh(vertices, faces, process=False)
    trimesh.repair.fix_winding(tm)
    faces = np.asarray(tm.faces)
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    if np.cross(b - a, c - a)[:, 2].sum() < 0:
        faces = faces[:, [0, 2, 1]]
    return faces


def main(argv=None) -> None:
    import argparse

    argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args(argv)
    from skimage import data

    photo = data.astronaut()
    h, w = photo.shape[:2]
    # one detection at the photo's own scale, as the committed asset was built (faceanim's
    # detection of rendered meshes takes the median over three zooms)
    lm = detect_landmarks_in_image(photo, scales=(1.0,))  # (478, 3) normalised x, y, z
    # image space, in pixels: x right, y up, z towards the camera
    pix = np.c_[lm[:, 0] * w, -lm[:, 1] * h, -lm[:, 2] * w]

    faces = tesselation_triangles()
    pull_inside(RIGHT_EYE_RING, RIGHT_IRIS, pix)
    pull_inside(LEFT_EYE_RING, LEFT_IRIS, pix)
    xy = pix[:, :2]
    faces = np.vstack([faces, cap(RIGHT_EYE_RING, RIGHT_IRIS, xy), cap(LEFT_EYE_RING, LEFT_IRIS, xy)])

    # mouth cavity: a fan from the inner lip ring to a point behind the lips
    lips = pix[INNER_LIP_RING]
    mouth_width = np.linalg.norm(pix[78] - pix[308])
    cavity = lips.mean(axis=0) - np.array([0.0, 0.0, 0.35 * mouth_width])
    pix = np.vstack([pix, cavity])
    c = len(pix) - 1
    ring = INNER_LIP_RING
    fan = np.array([[ring[i], ring[(i + 1) % len(ring)], c] for i in range(len(ring))])
    faces = orient_towards_viewer(np.vstack([faces, fan]), pix)
    used = np.zeros(len(pix), dtype=bool)
    used[faces.ravel()] = True
    assert used.all(), f"vertices without triangles: {np.flatnonzero(~used)}"

    # photo crop used as texture
    lo = np.floor(np.r_[pix[:, 0].min(), -pix[:, 1].max()]).astype(int) - 8
    hi = np.ceil(np.r_[pix[:, 0].max(), -pix[:, 1].min()]).astype(int) + 8
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [w, h])
    crop = photo[lo[1]:hi[1], lo[0]:hi[0]]

    # face frame: x from the right to the left outer eye corner, y from chin to forehead
    x_axis = pix[263] - pix[33]
    x_axis /= np.linalg.norm(x_axis)
    up = pix[10] - pix[152]
    y_axis = up - x_axis * (up @ x_axis)
    y_axis /= np.linalg.norm(y_axis)
    z_axis = np.cross(x_axis, y_axis)
    rot = np.vstack([x_axis, y_axis, z_axis])
    scale = 0.09 / np.linalg.norm(pix[263] - pix[33])  # outer eye corners 9 cm apart, in metres
    centre = (pix[:478].max(axis=0) + pix[:478].min(axis=0)) / 2
    transform = np.eye(4)
    transform[:3, :3] = scale * rot
    transform[:3, 3] = -scale * rot @ centre

    ASSETS.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        ASSETS / "default_face.npz",
        image_vertices=pix.astype(np.float64),
        faces=faces.astype(np.int32),
        crop_origin=lo.astype(np.int32),
        crop_size=np.array(crop.shape[1::-1], dtype=np.int32),
        image_size=np.array([w, h], dtype=np.int32),
        transform=transform,
    )
    Image.fromarray(crop).save(ASSETS / "default_face.png", optimize=True)
    print(f"default face: {len(pix)} vertices, {len(faces)} triangles, texture {crop.shape[1]}x{crop.shape[0]}")


if __name__ == "__main__":
    main()
