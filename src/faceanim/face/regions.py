"""Parts of a face found from its landmarks: the skin shell, the visible face, the region an expression may move, the sides of the mouth and eye slits, and the smooth ramps that blend them."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

from faceanim.errors import LandmarkError
from faceanim.face.frame import FaceFrame, face_frame
from faceanim.face.landmarks import (
    CHEEK_EXTREMES,
    CHIN,
    EYE_LEFT,
    EYE_RIGHT,
    FACE_OVAL,
    INNER_LIPS,
    LIP_OUTER,
    NOSE_TIP,
    SLITS,
)
from faceanim.face.mesh import Mesh

# inter-ocular distances of skin around the face outline that expressions may still move
FREE_MARGIN = 0.35  # inter-ocular distances an expression may spread beyond the visible face
# landmarks inside the oval that lie on the skin shell (nose tip, lip middles, brows): with the
# oval they pick the shell that carries most landmarks
SKIN_MARKERS = (NOSE_TIP, 0, 17, 70, 300)  # nose tip, upper and lower lip middle, right and left brow
JAW_DROP = 0.9  # inter-ocular distances below the chin an expression may still move (the throat)
CAVITY_DEPTH = 0.3  # deeper than this behind the front surface: mouth cavity, inside of the cheeks


def skin(mesh: Mesh, lm478: np.ndarray) -> np.ndarray:
    """Vertices of the face's skin shell: the connected part that carries most landmarks, so
    eyeballs, teeth, gums and tongue modelled as separate shells of one mesh are left out."""
    _, near = mesh.kdtree.query(np.asarray(lm478)[list(FACE_OVAL) + list(SKIN_MARKERS)])
    labels = mesh.vertex_components
    main = np.bincount(labels[near]).argmax()
    return labels == main


def depth_behind_front(mesh: Mesh, frame: FaceFrame, cell: float = 0.04) -> np.ndarray:
    """How far (mesh units) each vertex lies behind the front-most surface around its place in
    the frontal view: ~0 on visible skin, large on the inside of the cheeks, the mouth cavity or
    the back of the head. A vertex z-buffer on cells of ``cell`` inter-ocular distances, each
    cell taking the front-most depth of its 3 x 3 neighbourhood (so a cell that only a hidden
    vertex falls into still sees the surface in front of it)."""
    from scipy.ndimage import maximum_filter

    local = frame.to_local(mesh.vertices)
    ij = np.floor(local[:, :2] / (cell * frame.iod)).astype(np.int64)
    ij -= ij.min(0)
    top = np.full(ij.max(0) + 1, -np.inf)
    np.maximum.at(top, (ij[:, 0], ij[:, 1]), local[:, 2])
    top = maximum_filter(top, size=3, mode="constant", cval=-np.inf)
    return top[ij[:, 0], ij[:, 1]] - local[:, 2]


def face_region(mesh: Mesh, lm478: np.ndarray, frame: FaceFrame | None = None) -> np.ndarray:
    """Vertices of the face: skin inside the face oval seen from the front, not behind its rim,
    without the mouth cavity and eye sockets (skin behind the lip contour and lid margins)."""
    from matplotlib.path import Path as PolyPath

    frame = frame or face_frame(lm478)
    local = frame.to_local(mesh.vertices)
    oval = frame.to_local(np.asarray(lm478)[list(FACE_OVAL)])
    inside = PolyPath(oval[:, :2]).contains_points(local[:, :2])
    region = inside & (local[:, 2] > oval[:, 2].min() - 0.1 * frame.iod) & skin(mesh, lm478)
    region &= depth_behind_front(mesh, frame) < 0.15 * frame.iod
    for contour in (LIP_OUTER, EYE_RIGHT, EYE_LEFT):
        c = frame.to_local(np.asarray(lm478)[list(contour)])
        cavity = PolyPath(c[:, :2]).contains_points(local[:, :2]) & (local[:, 2] < c[:, 2].min() - 0.02 * frame.iod)
        region &= ~cavity
    return region


def free_region(mesh: Mesh, lm478: np.ndarray, frame: FaceFrame | None = None) -> np.ndarray:
    """Vertices an expression may move: the face region grown by a margin, and the jaw and
    throat below the mouth (the chin drags them along when the jaw drops)."""
    frame = frame or face_frame(lm478)
    face = face_region(mesh, lm478, frame)
    if not face.any():
        raise LandmarkError(f"no vertices of '{mesh.name}' lie inside the face outline of the landmarks; "
                            "are the landmarks for this mesh?")
    local = frame.to_local(mesh.vertices)
    p = frame.to_local(np.asarray(lm478))
    near = face.copy()
    dist = graph_distance(mesh, np.flatnonzero(face), limit=FREE_MARGIN * frame.iod)
    near |= np.isfinite(dist)
    # the jaw and throat: below the upper inner lip, down to JAW_DROP below the chin, in front of
    # the cheeks' widest points
    upper_lip = p[INNER_LIPS[0], 1]
    cheeks_z = min(p[i, 2] for i in CHEEK_EXTREMES)
    jaw = (local[:, 1] < upper_lip) & (local[:, 1] > p[CHIN, 1] - JAW_DROP * frame.iod) & \
          (local[:, 2] > cheeks_z + 0.1 * frame.iod)
    # the inside of the cheeks and the mouth cavity stay with the skull (they have no handles
    # and would otherwise swing freely); the inner lips just behind the lip line stay free
    inner = depth_behind_front(mesh, frame) > CAVITY_DEPTH * frame.iod
    return (near | jaw) & skin(mesh, lm478) & ~inner


def smoothstep(t) -> np.ndarray:
    """3t^2 - 2t^3 of ``t`` clipped to [0, 1]: the smooth 0 -> 1 ramp every mask here uses."""
    t = np.clip(np.asarray(t, dtype=np.float64), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def past_corners(x_local: np.ndarray, corner_x: np.ndarray, start: float, width: float) -> np.ndarray:
    """How far (0..1, smooth) points lie past a slit's corners along the face's x axis: 0 within
    ``start`` half-widths of the slit's centre, 1 beyond ``start + width`` half-widths."""
    centre, half = (corner_x[0] + corner_x[1]) / 2, abs(corner_x[1] - corner_x[0]) / 2
    return smoothstep((np.abs(x_local - centre) - start * half) / (width * half))


def graph_distance(mesh: Mesh, sources: np.ndarray, limit: float | None = None) -> np.ndarray:
    e = sp.triu(mesh.adjacency, 1).tocoo()
    length = np.linalg.norm(mesh.vertices[e.row] - mesh.vertices[e.col], axis=1)
    g = sp.csr_matrix((np.maximum(length, 1e-12), (e.row, e.col)), shape=mesh.adjacency.shape)
    return csgraph.dijkstra(g, directed=False, indices=sources, min_only=True,
                            limit=np.inf if limit is None else limit)


def slit_sides(mesh: Mesh, lm478: np.ndarray) -> dict[str, np.ndarray]:
    """For each slit (mouth, eyes): True where a vertex is on the lower side (lower lip or lid).

    Decided by distance along the surface from the outer lip or lid margin landmarks, so the
    inner sides of parted lips or open lids land on their own side.
    """
    from scipy.spatial import cKDTree

    on_skin = np.flatnonzero(skin(mesh, lm478))
    tree_v = cKDTree(mesh.vertices[on_skin])
    out = {}
    for name, s in SLITS.items():
        _, up = tree_v.query(np.asarray(lm478)[list(s["upper"])])
        _, lo = tree_v.query(np.asarray(lm478)[list(s["lower"])])
        du = graph_distance(mesh, np.unique(on_skin[up]))
        dl = graph_distance(mesh, np.unique(on_skin[lo]))
        out[name] = dl < du
    return out
