"""The seamless texture of a head built from photos (Lee et al. 1999, section 2.2).

Two steps, as in the paper: texture coordinates for the head in one atlas image
(:func:`atlas_uv`), and the atlas painted from the photos (:func:`bake_texture`, or
:func:`bake` for the split and timings as well). :func:`seam_step` measures the colour step
across the lines where one photo hands over to another.

**The atlas** (v up, as in OBJ). The skin (head, face and neck) is one chart over the whole
width; eyeballs, teeth, gums and tongue have tiles of their own in a strip along the bottom
(the paper: "eyes and teeth keep textures of their own"), 8 cells of ``STRIP / 2`` wide:

====================  =========================================================================
skin                  ``v`` in ``[STRIP, 1]`` (the whole atlas when there are no other parts)
eyeball_L, eyeball_R  cells 0-1 and 2-3: equal-area azimuthal projection along the eyeball's
                      axis (+z): the pupil in the middle, the back of the eye on the rim
teeth                 cells 4-5: top view (x, z), the front at the top of the tile
gums, tongue          cell 6 and the upper cell 7: top view (``gums_tongue`` split into the gums,
                      near the teeth, and the tongue, further from them)
cavities              the lower cell 7: skin that no direction sees (the mouth and eye sockets
                      behind the lips and lids); ``u`` along x, ``v`` down with the depth behind
                      the visible skin, painted from the colour at their rim to a dark red
====================  =========================================================================

The skin chart: ``u`` from the angle ``theta`` around a vertical axis (0 at the front, the
seam at the back of the head), remapped by ``theta + 0.6046 sin(theta)`` so that the front 120
degrees get half the width ("the highest resolution possible for the most detailed portions");
``v`` from the elevation angle above a centre at the height of the nose tip (the cranium and
upper face: the crown becomes a pole, not a line) and from the height below it, at half rate
further than one head radius down (the neck is squeezed, not the face; below the centre an
angle would fold back where the neck flares into the shoulders). The axis follows the middle of
the head's horizontal sections (the neck's middle is well behind the face's, else the throat
would wrap around it) and bends to pass through the top vertex, the pole: each triangle around
the pole gets a copy of the pole's UV between its other two corners, so no triangle there is a
sliver. The only seam is at the back: triangles across it take UVs past ``PERIOD`` (one turn of
``theta`` is ``PERIOD`` of the width), so the chart is periodic in ``u`` with that period and the
texels past it repeat those at its left edge; filling and blending wrap around, so the back of
the head shows no seam either. Vertices are never split: seams and the pole are UV copies
(``face_uv``). Skin that no direction sees from outside (:func:`exposed_vertices`: depth maps
from 48 directions, the neck closed) is a cavity and goes to the cavity tile. Where the surface
folds over itself seen from the axis (the ears, nostrils, the inner lids and lips: about 1% of
the chart's area on the ICT head) UVs overlap; the outermost surface gets the texels.

**The bake.** Each texel gets its 3D point and normal (the triangles drawn in UV space,
:func:`faceanim.render.bake.uv_raster`) and is projected into every photo; it is seen in a
photo when it faces the camera (``normal . direction > MIN_COSINE``), all four pixels its
colour is interpolated from show that surface (depth test against the photo's own depth map of
the head: nothing nearer, nothing farther across an outline) and it is inside the head's
outline by ``SILHOUETTE_MARGIN`` pixels. A photo with many pixels per texel is reduced first
(area average). A side no photo sees is taken from the mirror image: the point mirrored across
x = 0 (and its normal) in the photo that sees the other side; every photo turned by
``MIRROR_MIN_YAW`` or more lends one.

*The merge lines* (the paper's "feature lines"): each photo scores a vertex by its prior times
``normal . direction`` (front 1, other photos ``SIDE_PRIOR``, mirror images ``MIRROR_PRIOR``; 0
where it does not see the vertex); the scores are smoothed over the surface (``SMOOTH_STEPS``
averaging steps over vertex neighbours) and each texel takes the photo with the highest
interpolated score among those that see it. The front then hands over where
``cos(front) = 0.6 cos(side)``: about 60 degrees from the front for a true profile (the outer
brow, the cheek in front of the ear, the jaw), close to the paper's line through the skull top,
hairline, outer brow, ear junction, jaw and chin. We chose this over an explicit line through
feature points: it needs no points, works for three-quarter views and for any number of photos,
and the smoothing makes it a clean curve on the surface; the price is that it follows obliqueness,
not anatomy (the neck under the chin goes to the front photo, where the paper's line would give
it to the sides).

The per-photo atlases are merged with a Laplacian pyramid blend (Burt and Adelson 1983) under
the split masks (``PYRAMID_LEVELS`` levels), so a difference in exposure between photos fades
over the coarse levels instead of showing as a line (``blend="none"``: the hard split). Each
photo's atlas is extended beyond what it sees by the hard split, so the coarse levels, whose
masks reach far past the merge lines, mix real colours there. Texels no photo sees (the back of
the head with only a front photo, gutters between triangles, the pole's gaps) are filled by
push-pull from what is seen, wrapping around the seam. The eyeballs (a synthetic eye: white
sclera, an iris coloured from the front photo's iris pixels, a dark pupil), teeth, gums, tongue
and cavities are painted plain plausible colours: no photo sees them unoccluded.

:func:`view_camera` gives the exact camera of a parallel :class:`OffscreenRenderer`, to bake
from renders with known truth (tests/test_texture.py, benchmarks/bench_texture.py).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from faceanim.build.camera import ViewCamera
from faceanim.errors import FaceAnimError
from faceanim.face.mesh import vertex_normals
from faceanim.render.bake import EMPTY_DEPTH, ortho_depth, uv_raster

PART_NAMES = ("skin", "gums_tongue", "teeth", "eyeball_L", "eyeball_R")
PERIOD = 15 / 16  # width of one turn of the skin chart; the rest repeats its left edge
STRIP = 0.25  # height of the strip of tiles under the skin chart
MARGIN = 1 / 256  # free border inside the skin chart and each tile (4 texels at 1024)
FRONT_SQUEEZE = 0.6046  # u = theta + c sin(theta): front +-60 degrees = half the width
CELL = STRIP / 2
TILES = {  # (u0, v0, u1, v1)
    "eyeball_L": (0 * CELL, 0.0, 2 * CELL, STRIP),
    "eyeball_R": (2 * CELL, 0.0, 4 * CELL, STRIP),
    "teeth": (4 * CELL, 0.0, 6 * CELL, STRIP),
    "gums": (6 * CELL, 0.0, 7 * CELL, STRIP),
    "tongue": (7 * CELL, CELL, 8 * CELL, STRIP),
    "cavity": (7 * CELL, 0.0, 8 * CELL, CELL),
}

MIN_COSINE = 0.15  # a photo sees a point when normal . direction exceeds this
SIDE_PRIOR = 0.6  # photos after the first, against 1 for the front
MIRROR_PRIOR = 0.5  # a mirrored photo, against 1 for the front
SILHOUETTE_MARGIN = 2  # pixels inside the head's outline in a photo before its colours are used
MIRROR_MIN_YAW = 20.0  # photos turned at least this much also lend their mirror image
SMOOTH_STEPS = 100  # smoothing of the photo scores over the surface (vertex neighbourhoods)
PYRAMID_LEVELS = 6

IRIS_ANGLE = 0.5  # radians from the eyeball's axis to the rim of the iris
IRIS_MAX_LUMINANCE = 170.0
PUPIL_FRACTION = 0.4  # pupil radius / iris radius
SCLERA = (236, 232, 226)
PUPIL = (14, 12, 12)
DEFAULT_IRIS = (92, 64, 44)
TEETH = (238, 228, 204)
GUMS = (196, 108, 112)
TONGUE = (170, 72, 78)
CAVITY = (72, 26, 30)
# light that reaches the inside of the mouth between the lips: the gums and the body of the tongue
# lie in the lips' shadow (a pink mouth interior reads as shut lips to a landmark tracker), the
# tongue's tip, the part tongueOut brings past the teeth, fades back to full light
GUMS_LIGHT = 0.4
TONGUE_LIGHT = 0.3
TONGUE_TIP = 0.15  # the front fraction of the tongue's depth that fades to full light
EYE_AXIS = (0.0, 0.0, 1.0)


# ----------------------------------------------------------------------------- parts
def _part_labels(n_vertices: int, faces: np.ndarray, parts: dict) -> tuple[np.ndarray, np.ndarray]:
    """(vertex part index (-1: none), triangle part index) with indices into PART_NAMES."""
    if not isinstance(parts, dict) or "skin" not in parts:
        raise FaceAnimError("parts must be a dict of vertex indices with at least 'skin'")
    unknown = sorted(set(parts) - set(PART_NAMES))
    if unknown:
        raise FaceAnimError(f"unknown part name(s) {unknown}; use {', '.join(PART_NAMES)}")
    label = np.full(n_vertices, -1, dtype=np.int64)
    for k, name in enumerate(PART_NAMES):
        if name not in parts:
            continue
        idx = np.asarray(parts[name], dtype=np.int64).ravel()
        if idx.size and (idx.min() < 0 or idx.max() >= n_vertices):
            raise FaceAnimError(f"part '{name}' indexes missing vertices (0..{n_vertices - 1})")
        if (label[idx] >= 0).any():
            raise FaceAnimError(f"part '{name}' shares vertices with another part")
        label[idx] = k
    return label, label[faces[:, 0]]


def _gum_tongue_split(vertices: np.ndarray, gums: np.ndarray, teeth: np.ndarray) -> np.ndarray:
    """For the gums_tongue vertices: True on the tongue (further from the teeth than 12% of the
    dental arch's width), False on the gums; all gums when there are no teeth."""
    if not len(teeth) or not len(gums):
        return np.zeros(len(gums), dtype=bool)
    arch = np.ptp(vertices[teeth, 0])
    d, _ = cKDTree(vertices[teeth]).query(vertices[gums])
    return d > 0.12 * arch


def _sphere_fit(points: np.ndarray) -> tuple[np.ndarray, float]:
    a = np.c_[2 * points, np.ones(len(points))]
    b = (points ** 2).sum(1)
    x = np.linalg.lstsq(a, b, rcond=None)[0]
    c = x[:3]
    return c, float(np.sqrt(max(x[3] + c @ c, 1e-12)))


# ----------------------------------------------------------------------------- exposure
def _fibonacci_directions(n: int) -> np.ndarray:
    k = np.arange(n) + 0.5
    y = 1 - 2 * k / n
    r = np.sqrt(1 - y * y)
    a = np.pi * (1 + 5 ** 0.5) * k
    return np.stack([r * np.cos(a), y, r * np.sin(a)], 1)


def _ortho_frame(direction: np.ndarray) -> np.ndarray:
    """Rotation whose third row is ``direction`` (a camera looking along -direction)."""
    d = direction / np.linalg.norm(direction)
    up = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(up, d)
    x /= np.linalg.norm(x)
    return np.vstack([x, np.cross(d, x), d])


def _capped(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mesh with its lowest hole (the neck) closed by a fan to the middle of its rim, for
    visibility only: through the open neck one would see the inside of the mouth socket. Other
    holes (eye openings of a scan) stay open: what is seen through them is seen."""
    from scipy.sparse.csgraph import connected_components

    e = np.sort(np.vstack([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), 1)
    uniq, count = np.unique(e, axis=0, return_counts=True)
    rim = uniq[count == 1]
    if not len(rim):
        return vertices, faces
    n = len(vertices)
    graph = sp.coo_matrix((np.ones(len(rim)), (rim[:, 0], rim[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    loops, loop_of_edge = np.unique(label[rim[:, 0]], return_inverse=True)
    centres = np.zeros((len(loops), 3))
    np.add.at(centres, loop_of_edge.ravel(), (vertices[rim[:, 0]] + vertices[rim[:, 1]]) / 2)
    centres /= np.bincount(loop_of_edge.ravel(), minlength=len(loops))[:, None]
    neck = int(np.argmin(centres[:, 1]))
    cap = np.c_[rim, np.full(len(rim), n)][loop_of_edge.ravel() == neck]
    return np.vstack([vertices, centres[neck]]), np.vstack([faces, cap])


def exposed_vertices(vertices: np.ndarray, faces: np.ndarray, which: np.ndarray,
                     directions: int = 48, resolution: int = 320) -> np.ndarray:
    """(len(which),) bool: the vertices ``which`` that some direction sees from their outer
    side (orthographic depth maps of the whole mesh, its neck closed, from ``directions``
    directions around it). What no direction sees is a cavity: the mouth socket behind closed
    lips, the eye sockets behind lids and eyeballs."""
    v = np.asarray(vertices, dtype=np.float64)
    normals = vertex_normals(v, faces)[which]
    v, faces = _capped(v, faces)
    lo, hi = v.min(0), v.max(0)
    centre, radius = (lo + hi) / 2, float(np.linalg.norm(hi - lo) / 2) + 1e-9
    scale = (resolution / 2 - 2) / radius
    pts = v[which]
    seen = np.zeros(len(pts), dtype=bool)
    bias = 2.5 / scale
    for d in _fibonacci_directions(directions):
        rot = _ortho_frame(d)
        matrix = scale * rot[:2] * np.array([[1.0], [-1.0]])
        offset = resolution / 2 - matrix @ centre
        depth = ortho_depth(v, faces, matrix, offset, rot[2], (resolution, resolution))
        todo = ~seen
        px = pts[todo] @ matrix.T + offset - 0.5
        x0 = np.clip(np.floor(px[:, 0]).astype(np.int64), 0, resolution - 2)
        y0 = np.clip(np.floor(px[:, 1]).astype(np.int64), 0, resolution - 2)
        near = np.full(len(x0), np.inf, dtype=np.float32)  # the farthest of the 2x2: generous
        for dy in (0, 1):
            for dx in (0, 1):
                dd = depth[y0 + dy, x0 + dx]
                near = np.minimum(near, np.where(dd == EMPTY_DEPTH, -np.inf, dd))
        # facing the direction: through an open neck one sees the inside of the head
        ok = (pts[todo] @ rot[2] >= near - bias) & (normals[todo] @ rot[2] > 0)
        seen[np.flatnonzero(todo)[ok]] = True
        if seen.all():
            break
    return seen


# ----------------------------------------------------------------------------- atlas
@dataclass
class _SkinFrame:
    centre: np.ndarray  # (3,) y: the height of the centre (the nose tip); x, z: the axis there
    pole: int  # the top vertex, on the axis
    radius: float  # the head's radius about the axis at the centre's height
    heights: np.ndarray  # (B,) the vertical axis bends with height: its (x, z) at these heights
    axis_xz: np.ndarray  # (B, 2)

    def axis(self, y: np.ndarray) -> np.ndarray:
        """(N, 2) x and z of the axis at heights ``y``."""
        return np.stack([np.interp(y, self.heights, self.axis_xz[:, 0]),
                         np.interp(y, self.heights, self.axis_xz[:, 1])], 1)

    def relative(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(theta, horizontal distance from the axis, height above the centre) of points."""
        a = self.axis(points[:, 1])
        dx, dz = points[:, 0] - a[:, 0], points[:, 2] - a[:, 1]
        return np.arctan2(dx, dz), np.hypot(dx, dz), points[:, 1] - self.centre[1]


def _skin_frame(vertices: np.ndarray, skin: np.ndarray) -> _SkinFrame:
    """The chart's centre, pole and axis. The axis follows the middle of the horizontal sections
    of the head (the neck's middle is well behind the face's), smoothed, and bends to pass
    through the pole at the top."""
    p = vertices[skin]
    nose = p[np.argmax(p[:, 2])]
    lo_y, hi_y = float(p[:, 1].min()), float(p[:, 1].max())
    bins = 48
    edges = np.linspace(lo_y, hi_y, bins + 1)
    heights = (edges[:-1] + edges[1:]) / 2
    which = np.clip(np.searchsorted(edges, p[:, 1], side="right") - 1, 0, bins - 1)
    mid = np.full((bins, 2), np.nan)
    for b in range(bins):
        q = p[which == b]
        if len(q):
            mid[b] = [(q[:, 0].min() + q[:, 0].max()) / 2, (q[:, 2].min() + q[:, 2].max()) / 2]
    ok = ~np.isnan(mid[:, 0])
    mid = np.stack([np.interp(heights, heights[ok], mid[ok, k]) for k in range(2)], 1)
    kernel = np.exp(-0.5 * (np.arange(-6, 7) / 3.0) ** 2)
    kernel /= kernel.sum()
    mid = np.stack([np.convolve(np.pad(mid[:, k], 6, mode="edge"), kernel, mode="valid") for k in range(2)], 1)
    # the pole: the vertex highest above the centre, seen from the axis
    centre_xz = np.array([np.interp(nose[1], heights, mid[:, 0]), np.interp(nose[1], heights, mid[:, 1])])
    r = np.hypot(p[:, 0] - centre_xz[0], p[:, 2] - centre_xz[1])
    pole = int(skin[np.argmax(np.arctan2(p[:, 1] - nose[1], r))])
    top = vertices[pole]
    # bend the axis through the pole over the top half of the cranium
    w = np.clip((heights - nose[1]) / max(top[1] - nose[1], 1e-9), 0, 1)
    w = w * w * (3 - 2 * w)
    mid = mid * (1 - w[:, None]) + np.array([top[0], top[2]]) * w[:, None]
    heights = np.r_[heights, max(top[1], heights[-1]) + 1e-6]
    mid = np.vstack([mid, [top[0], top[2]]])
    frame = _SkinFrame(np.array([0.0, nose[1], 0.0]), pole, 1.0, heights, mid)
    _, rr, hh = frame.relative(p)
    band = np.abs(hh) < 0.1 * (hi_y - lo_y)
    radius = float(np.median(rr[band])) if band.any() else float(np.ptp(p[:, 0]) / 2)
    frame.radius = max(radius, 1e-9)
    frame.centre[[0, 2]] = frame.axis(np.array([nose[1]]))[0]
    return frame


def _elevation(r: np.ndarray, h: np.ndarray, radius: float) -> np.ndarray:
    """The chart's vertical coordinate of points ``q`` relative to the centre: the elevation
    angle above the centre (the cranium and upper face, up to pi/2 at the pole), the height in
    head radii below it (lower face and neck: the neck and shoulders flare out, which would fold
    an angle back), at half rate further than one radius down (the neck)."""
    s = np.arctan2(h, r)
    below = h < 0
    d = h[below] / radius
    s[below] = np.where(d < -1, -1 + 0.5 * (d + 1), d)
    return s


def _theta_to_u(theta: np.ndarray) -> np.ndarray:
    return PERIOD * (0.5 + (theta + FRONT_SQUEEZE * np.sin(theta)) / (2 * np.pi))


def _skin_chart(vertices: np.ndarray, tris: np.ndarray, frame: _SkinFrame, v_range) -> np.ndarray:
    """(T, 3, 2) corner UVs of the exposed skin triangles ``tris`` (T, 3)."""
    theta, r, h = frame.relative(vertices)
    elev = _elevation(r, h, frame.radius)
    elev[frame.pole] = np.pi / 2
    th = theta[tris].copy()
    at_pole = tris == frame.pole
    fan = at_pole.any(1)
    # across the seam at the back: the corners behind on the right (-x) go one turn on
    span = th.max(1) - th.min(1)
    wrap = (span > np.pi) & ~fan
    th[wrap] = np.where(th[wrap] < 0, th[wrap] + 2 * np.pi, th[wrap])
    # around the pole: its own angle is meaningless; it goes between the other two corners
    if fan.any():
        f = np.flatnonzero(fan)
        rest = np.argsort(at_pole[f], axis=1, kind="stable")[:, :2]  # the two other corners
        a = np.take_along_axis(th[f], rest, 1)
        turn = np.abs(a[:, 0] - a[:, 1]) > np.pi
        a[turn] = np.where(a[turn] < 0, a[turn] + 2 * np.pi, a[turn])
        sub = th[f]
        np.put_along_axis(sub, rest, a, 1)
        sub[at_pole[f]] = a.mean(1)
        th[f] = sub
    el = elev[tris]
    lo_el = float(elev[np.unique(tris)].min())
    v0, v1 = v_range
    u = _theta_to_u(th)
    u = np.minimum(u, 1 - 0.25 * MARGIN)  # a triangle reaching further past the seam is squeezed
    v = v0 + (el - lo_el) / (np.pi / 2 - lo_el) * (v1 - v0)
    return np.stack([u, v], -1)


def _fit_box(xy: np.ndarray, box) -> np.ndarray:
    """Points scaled uniformly and centred into ``box`` (u0, v0, u1, v1) inside its margin."""
    u0, v0, u1, v1 = box
    u0, v0, u1, v1 = u0 + MARGIN, v0 + MARGIN, u1 - MARGIN, v1 - MARGIN
    lo, hi = xy.min(0), xy.max(0)
    ext = np.maximum(hi - lo, 1e-12)
    s = min((u1 - u0) / ext[0], (v1 - v0) / ext[1])
    return (xy - (lo + hi) / 2) * s + np.array([(u0 + u1) / 2, (v0 + v1) / 2])


def _eyeball_uv(vertices: np.ndarray, tris: np.ndarray, verts: np.ndarray, box) -> np.ndarray:
    centre, _ = _sphere_fit(vertices[verts])
    phi, psi = _eye_angles(vertices, centre)
    ph, ps = phi[tris], psi[tris]
    # triangles around the back pole would wrap around the disc: give their corners one azimuth
    spread = np.ptp(np.unwrap(ps, axis=1), 1)
    bad = spread > np.pi / 2
    if bad.any():
        mean = np.arctan2(np.sin(ps[bad]).mean(1), np.cos(ps[bad]).mean(1))
        ps[bad] = mean[:, None]
    return _eye_disc(ph, ps, box)


def _eye_angles(points: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Angle from the eyeball's axis (phi) and azimuth around it (psi, 0 towards +x)."""
    axis = np.asarray(EYE_AXIS, dtype=np.float64)
    frame = _ortho_frame(axis)  # rows: x, y, axis
    d = (points - centre) @ frame.T
    phi = np.arctan2(np.hypot(d[:, 0], d[:, 1]), d[:, 2])
    psi = np.arctan2(d[:, 1], d[:, 0])
    return phi, psi


def _eye_disc(phi: np.ndarray, psi: np.ndarray, box) -> np.ndarray:
    u0, v0, u1, v1 = box
    half = min(u1 - u0, v1 - v0) / 2 - MARGIN
    rho = np.sin(np.clip(phi, 0, np.pi) / 2) * half  # equal-area azimuthal
    return np.stack([(u0 + u1) / 2 + rho * np.cos(psi), (v0 + v1) / 2 + rho * np.sin(psi)], -1)


def _cavity_layout(vertices: np.ndarray, faces: np.ndarray, hidden_tris: np.ndarray, exposed: np.ndarray):
    """Components of the hidden skin triangles and each hidden vertex's depth behind the
    visible skin: (component per hidden triangle, depth per vertex (nan off the cavities),
    number of components)."""
    tris = faces[hidden_tris]
    verts = np.unique(tris)
    n = len(vertices)
    e = np.vstack([tris[:, [0, 1]], tris[:, [1, 2]]])
    adj = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    from scipy.sparse.csgraph import connected_components

    _, comp = connected_components(adj, directed=False)
    tri_comp_raw = comp[tris[:, 0]]
    uniq, tri_comp = np.unique(tri_comp_raw, return_inverse=True)
    depth = np.full(n, np.nan)
    if exposed.any():
        d, _ = cKDTree(vertices[exposed]).query(vertices[verts])
        depth[verts] = d
    else:
        depth[verts] = 0.0
    return tri_comp.reshape(-1), depth, len(uniq)


def _cavity_uv(vertices, tris, tri_comp, depth, n_comp, box) -> np.ndarray:
    """u: the component's band, along x; v: down from the top of the tile with depth."""
    u0, v0, u1, v1 = box
    u0, v0, u1, v1 = u0 + MARGIN, v0 + MARGIN, u1 - MARGIN, v1 - MARGIN
    out = np.empty(tris.shape + (2,))
    band = (u1 - u0) / max(n_comp, 1)
    for c in range(n_comp):
        t = tris[tri_comp == c]
        verts = np.unique(t)
        x = vertices[verts, 0]
        d = depth[verts]
        xmap = np.zeros(len(vertices))
        xmap[verts] = (x - x.min()) / max(np.ptp(x), 1e-12)
        dmap = np.zeros(len(vertices))
        dmap[verts] = d / max(d.max(), 1e-12)
        gap = 0.1 * band
        out[tri_comp == c, :, 0] = u0 + c * band + gap / 2 + xmap[t] * (band - gap)
        out[tri_comp == c, :, 1] = v1 - dmap[t] * (v1 - v0)
    return out


@dataclass
class _Layout:
    tri_part: np.ndarray  # (T,) index into PART_NAMES, -1 unassigned
    exposed: np.ndarray  # (V,) bool, skin vertices some direction sees
    hidden_tris: np.ndarray  # (H,) skin triangles in the cavity tile
    tongue: np.ndarray  # (V,) bool


def _layout(vertices, faces, parts) -> _Layout:
    _, tlab = _part_labels(len(vertices), faces, parts)
    skin_tris = np.flatnonzero(tlab == 0)
    if len(skin_tris) < 4:
        raise FaceAnimError("the skin part has fewer than 4 triangles; give the head's skin vertices as 'skin'")
    skin_verts = np.unique(faces[skin_tris])
    exposed = np.zeros(len(vertices), dtype=bool)
    exposed[skin_verts] = exposed_vertices(vertices, faces, skin_verts)
    hidden = skin_tris[~exposed[faces[skin_tris]].any(1)]
    tongue = np.zeros(len(vertices), dtype=bool)
    if "gums_tongue" in parts:
        g = np.asarray(parts["gums_tongue"], dtype=np.int64).ravel()
        t = np.asarray(parts.get("teeth", []), dtype=np.int64).ravel()
        tongue[g] = _gum_tongue_split(vertices, g, t)
    return _Layout(tlab, exposed, hidden, tongue)


def atlas_uv(vertices: np.ndarray, faces: np.ndarray, parts: dict) -> tuple[np.ndarray, np.ndarray]:
    """Texture coordinates of a head in one atlas (see the module docstring for the layout).

    Parameters
    ----------
    vertices : (V, 3) head coordinates (x the subject's left, y up, z forward)
    faces : (T, 3) triangles
    parts : name -> vertex indices, names from ``PART_NAMES`` ("skin" required); triangles on
        vertices of no part get UV (0, 0)

    Returns ``(uv (U, 2), face_uv (T, 3))``, OBJ-style: seams are UV copies, vertices are
    never split.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    lay = _layout(vertices, faces, parts)
    corner = np.zeros(faces.shape + (2,))
    others = any(n in parts and len(parts[n]) for n in PART_NAMES[1:]) or len(lay.hidden_tris) > 0
    v_range = ((STRIP if others else 0.0) + MARGIN, 1 - MARGIN)

    skin_tris = np.flatnonzero(lay.tri_part == 0)
    hidden = np.zeros(len(faces), dtype=bool)
    hidden[lay.hidden_tris] = True
    chart = skin_tris[~hidden[skin_tris]]
    frame = _skin_frame(vertices, np.unique(faces[chart]))
    corner[chart] = _skin_chart(vertices, faces[chart], frame, v_range)

    if len(lay.hidden_tris):
        comp, depth, n_comp = _cavity_layout(vertices, faces, lay.hidden_tris, lay.exposed)
        corner[lay.hidden_tris] = _cavity_uv(vertices, faces[lay.hidden_tris], comp, depth, n_comp, TILES["cavity"])

    for k, name in enumerate(PART_NAMES[1:], start=1):
        tris = np.flatnonzero(lay.tri_part == k)
        if not len(tris):
            continue
        verts = np.unique(faces[tris])
        if name.startswith("eyeball"):
            corner[tris] = _eyeball_uv(vertices, faces[tris], verts, TILES[name])
        elif name == "teeth":
            corner[tris] = _top_view(vertices, faces[tris], verts, TILES["teeth"])
        else:  # gums and tongue, split
            is_tongue = lay.tongue[faces[tris]].all(1)
            for sel, box in ((~is_tongue, TILES["gums"]), (is_tongue, TILES["tongue"])):
                if sel.any():
                    corner[tris[sel]] = _top_view(vertices, faces[tris[sel]], np.unique(faces[tris[sel]]), box)
    flat = corner.reshape(-1, 2)
    uv, inverse = np.unique(flat, axis=0, return_inverse=True)
    return uv, inverse.reshape(-1, 3).astype(np.int64)


def _top_view(vertices, tris, verts, box) -> np.ndarray:
    """Top view (x right, the front (+z) at the top of the tile)."""
    xz = vertices[:, [0, 2]].copy()
    fitted = np.zeros((len(vertices), 2))
    fitted[verts] = _fit_box(xz[verts], box)
    return fitted[tris]


# ----------------------------------------------------------------------------- filtering
_KERNEL = np.array([1, 4, 6, 4, 1], dtype=np.float32) / 16


def _filter(img: np.ndarray, wrap: bool) -> np.ndarray:
    """Separable 5-tap binomial filter; x wraps around (the chart's period) or reflects."""
    import cv2

    h, w = img.shape[:2]
    k = _KERNEL
    src = np.ascontiguousarray(img, dtype=np.float32)
    if min(h, w) < 3:
        return src
    src = cv2.copyMakeBorder(src, 2, 2, 2, 2, cv2.BORDER_REFLECT_101)
    if wrap and w >= 2:
        src[:, :2] = src[:, w:w + 2]
        src[:, w + 2:] = src[:, 2:4]
    out = cv2.sepFilter2D(src, -1, k, k, borderType=cv2.BORDER_CONSTANT)
    return out[2:-2, 2:-2]


def _down(img: np.ndarray, wrap: bool) -> np.ndarray:
    return _filter(img, wrap)[::2, ::2]


_UP_WEIGHTS: dict = {}


def _up(img: np.ndarray, shape: tuple[int, int], wrap: bool) -> np.ndarray:
    """Twice the size (``shape``): samples on the even texels, filtered and normalised by the
    filtered sample pattern (right at borders and across a wrap of odd width too)."""
    shape = tuple(int(n) for n in shape)
    if min(shape) < 3:  # too small to filter: nearest
        return np.ascontiguousarray(img.repeat(2, 0).repeat(2, 1)[:shape[0], :shape[1]], dtype=np.float32)
    up = np.zeros(shape + img.shape[2:], dtype=np.float32)
    up[::2, ::2] = img[:(shape[0] + 1) // 2, :(shape[1] + 1) // 2]
    key = (shape, wrap)
    weight = _UP_WEIGHTS.get(key)
    if weight is None:
        ones = np.zeros(shape, dtype=np.float32)
        ones[::2, ::2] = 1.0
        weight = _filter(ones, wrap)
        if len(_UP_WEIGHTS) > 64:
            _UP_WEIGHTS.clear()
        _UP_WEIGHTS[key] = weight
    out = _filter(up, wrap)
    return out / (weight[..., None] if out.ndim == 3 else weight)


def push_pull(image: np.ndarray, known: np.ndarray, wrap: bool = False) -> np.ndarray:
    """``image`` (h, w, c) with the texels outside ``known`` (h, w) filled smoothly from the
    known ones (push-pull: Gortler et al. 1996): averages of the known texels over ever coarser
    levels, blended back down where a level knows too little. ``wrap``: x is periodic."""
    w0 = np.asarray(known, dtype=np.float32)
    img = np.asarray(image, dtype=np.float32)
    if not w0.any():
        return np.zeros_like(img)
    levels = [(img * w0[..., None], w0)]
    while min(levels[-1][1].shape) > 4 and (levels[-1][1] <= 1e-6).any():
        cw, ww = levels[-1]
        levels.append((_down(cw, wrap), _down(ww, wrap)))
    cw, ww = levels[-1]
    colour = cw / np.maximum(ww, 1e-12)[..., None]
    if (ww <= 1e-6).any():
        mean = (img * w0[..., None]).reshape(-1, img.shape[2]).sum(0) / w0.sum()
        colour[ww <= 1e-6] = mean
    for cw, ww in reversed(levels[:-1]):
        up = _up(colour, ww.shape, wrap)
        a = np.clip(ww, 0, 1)[..., None]
        colour = a * (cw / np.maximum(ww, 1e-12)[..., None]) + (1 - a) * up
    return colour


def pyramid_blend(images: list, masks: list, wrap: bool = False, levels: int = PYRAMID_LEVELS) -> np.ndarray:
    """Multiresolution spline (Burt and Adelson 1983): each band of the Laplacian pyramids of
    ``images`` (h, w, c, defined everywhere) weighted by the Gaussian pyramids of ``masks``
    (h, w, in [0, 1]), summed and collapsed. Where the masks sum to 1 this is the hard split at
    the finest level and an ever smoother transition at the coarser ones."""
    h, w = masks[0].shape
    levels = int(max(0, min(levels, np.floor(np.log2(max(min(h, w), 1) / 8)))))
    out = None
    gauss = [[np.asarray(im, dtype=np.float32)] for im in images]
    weights = [[np.asarray(m, dtype=np.float32)] for m in masks]
    for _ in range(levels):
        for g, m in zip(gauss, weights):
            g.append(_down(g[-1], wrap))
            m.append(_down(m[-1], wrap))
    for level in range(levels, -1, -1):
        num, den = 0.0, 0.0
        for g, m in zip(gauss, weights):
            band = g[level] if level == levels else g[level] - _up(g[level + 1], g[level].shape[:2], wrap)
            num = num + m[level][..., None] * band
            den = den + m[level]
        band = num / np.maximum(den, 1e-6)[..., None]
        out = band if out is None else band + _up(out, band.shape[:2], wrap)
    return out


# ----------------------------------------------------------------------------- colours
def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def eye_colour(phi: np.ndarray, psi: np.ndarray, iris) -> np.ndarray:
    """(N, 3) float colours (0..255) of a synthetic eye at angle ``phi`` from its axis and
    azimuth ``psi``: dark pupil, iris of colour ``iris`` with radial fibres and a dark limbal
    ring, white sclera a little warmer towards the back."""
    iris = np.asarray(iris, dtype=np.float64)
    pupil_r = PUPIL_FRACTION * IRIS_ANGLE
    edge = 0.025
    fibres = 1 + 0.12 * np.sin(psi * 41 + 2.5 * np.sin(psi * 7)) + 0.08 * np.sin(psi * 97 + 1.3)
    t = np.clip((phi - pupil_r) / (IRIS_ANGLE - pupil_r), 0, 1)
    ring = 1 - 0.45 * _smoothstep((t - 0.75) / 0.25) - 0.25 * (1 - _smoothstep(t / 0.2))
    iris_c = iris[None] * (fibres * ring)[:, None]
    back = _smoothstep((phi - np.pi / 2) / (np.pi / 2))[:, None]
    sclera = np.asarray(SCLERA, dtype=np.float64)[None] * (1 - back) + np.array([[222, 196, 190]]) * back
    a = _smoothstep((phi - pupil_r + edge / 2) / edge)[:, None]  # 0 in the pupil
    b = _smoothstep((phi - IRIS_ANGLE + edge / 2) / edge)[:, None]  # 1 on the sclera
    c = np.asarray(PUPIL, dtype=np.float64)[None] * (1 - a) + iris_c * a
    return np.clip(c * (1 - b) + sclera * b, 0, 255)


def _iris_colour(view, centre: np.ndarray, radius: float) -> np.ndarray | None:
    """The iris colour the photo shows around the front of an eyeball (None when it cannot)."""
    cam = view.camera
    axis = np.asarray(EYE_AXIS, dtype=np.float64)
    if cam.direction @ axis < 0.8:
        return None
    front = centre + radius * axis
    px = cam.project(front[None])[0]
    r = 0.85 * radius * np.sin(IRIS_ANGLE) * cam.scale
    img = np.asarray(view.image)
    h, w = img.shape[:2]
    if r < 1.5 or not (r <= px[0] < w - r and r <= px[1] < h - r):
        return None
    ys, xs = np.mgrid[int(px[1] - r):int(px[1] + r) + 1, int(px[0] - r):int(px[0] + r) + 1]
    inside = (xs + 0.5 - px[0]) ** 2 + (ys + 0.5 - px[1]) ** 2 <= r * r
    pix = img[ys[inside], xs[inside], :3].astype(np.float64)
    if len(pix) < 4:
        return None
    lum = pix @ np.array([0.299, 0.587, 0.114])
    lo, hi = np.percentile(lum, [20, 65])
    keep = (lum >= lo) & (lum <= hi)
    if not keep.any():
        return None
    colour = np.median(pix[keep], axis=0)
    # an iris is darker than this; brighter is skin or sclera (the eye is shut, or missed)
    return colour if colour @ np.array([0.299, 0.587, 0.114]) < IRIS_MAX_LUMINANCE else None


# ----------------------------------------------------------------------------- bake
def view_camera(renderer) -> ViewCamera:
    """The exact :class:`ViewCamera` of a parallel (orthographic)
    :class:`faceanim.render.OffscreenRenderer`: its renders are photos with a known camera."""
    if not renderer.parallel:
        raise FaceAnimError("only a parallel (orthographic) renderer has a ViewCamera")
    cam = renderer.camera
    basis = cam.view_matrix()[:3, :3]  # rows: image right, image up, towards the camera
    w, h = renderer.size
    scale = h / (2 * cam.parallel_scale)
    offset = np.array([w / 2, h / 2]) - scale * np.array([1.0, -1.0]) * (basis @ cam.eye)[:2]
    return ViewCamera(basis @ renderer.rotation, float(scale), offset, (int(w), int(h)))


@dataclass
class BakeView:
    """A photo and its camera (any object with ``image`` and ``camera`` will do)."""

    image: np.ndarray  # (H, W, 3) uint8
    camera: object  # faceanim.build.camera.ViewCamera


@dataclass
class Bake:
    """A baked atlas and how it was made.

    ``texture`` (H, W, 3) uint8; ``split`` (H, W) int16: which source painted each skin texel
    (an index into ``sources``; -1 where no photo sees the texel or it is not skin); ``sources``
    names them: ``"photo i"`` or ``"photo i mirrored"`` (i indexes ``views``); ``iris``: the
    iris colour of the eyes (from the front photo, or ``DEFAULT_IRIS``); ``seconds``: the time
    of each step.
    """

    texture: np.ndarray
    split: np.ndarray
    sources: list
    iris: np.ndarray
    seconds: dict


def _view_maps(v: np.ndarray, f: np.ndarray, cam) -> tuple[np.ndarray, np.ndarray]:
    """The head's depth map in a photo, and where the head covers the photo, shrunk by
    SILHOUETTE_MARGIN pixels (colours right at the outline mix in the background)."""
    import cv2

    depth = ortho_depth(v, f, cam.matrix, cam.offset, cam.direction, cam.size)
    cover = (depth > EMPTY_DEPTH).astype(np.uint8)
    inner = cv2.erode(cover, np.ones((3, 3), np.uint8), iterations=SILHOUETTE_MARGIN,
                      borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return depth, inner.astype(bool)


def _visible(cam, maps, points: np.ndarray, normals: np.ndarray, tolerance: float):
    """(seen (N,), x (N,), y (N,), cos (N,)): points facing the camera, inside the head's outline
    and not hidden in its depth map; x, y in pixel-centre coordinates for sampling (pixel
    (0, 0)'s centre is (0, 0))."""
    depth, inner = maps
    w, h = cam.size
    px = cam.project(points) - 0.5
    cos = normals @ cam.direction
    x, y = px[:, 0], px[:, 1]
    inside = (x >= 0) & (y >= 0) & (x <= w - 1) & (y <= h - 1)
    x0 = np.clip(np.floor(x).astype(np.int64), 0, max(w - 2, 0))
    y0 = np.clip(np.floor(y).astype(np.int64), 0, max(h - 2, 0))
    # the four pixels the colour is interpolated from must all show this surface: none nearer
    # (hidden), none farther (a colour across an outline, e.g. the inside of the neck)
    near = np.full(len(points), -np.inf, dtype=np.float32)
    far = np.full(len(points), np.inf, dtype=np.float32)
    for dy in (0, 1):
        for dx in (0, 1):
            d = depth[np.minimum(y0 + dy, h - 1), np.minimum(x0 + dx, w - 1)]
            near, far = np.maximum(near, d), np.minimum(far, d)
    slope = np.sqrt(np.clip(1 - cos * cos, 0, 1)) / np.maximum(cos, MIN_COSINE)
    bias = tolerance + 1.5 * slope / cam.scale
    xi = np.clip(np.rint(x).astype(np.int64), 0, w - 1)
    yi = np.clip(np.rint(y).astype(np.int64), 0, h - 1)
    z = cam.depth(points)
    seen = inside & (cos > MIN_COSINE) & (z >= near - bias) & (far >= z - bias) & inner[yi, xi]
    return seen, x.astype(np.float32), y.astype(np.float32), cos


def _sample(image: np.ndarray, x: np.ndarray, y: np.ndarray, shrink: float = 1.0) -> np.ndarray:
    """Bilinear colours of ``image`` at pixel-centre coordinates; ``shrink`` > 1: the photo has
    that many pixels per texel, so it is first reduced (area average) to about one."""
    import cv2

    img = np.ascontiguousarray(np.asarray(image)[..., :3])
    if shrink > 1.5:
        h, w = img.shape[:2]
        small = (max(1, round(w / shrink)), max(1, round(h / shrink)))
        img = cv2.resize(img, small, interpolation=cv2.INTER_AREA)
        x = ((x + 0.5) * small[0] / w - 0.5).astype(np.float32)
        y = ((y + 0.5) * small[1] / h - 0.5).astype(np.float32)
    n = len(x)
    cols = 1024  # remap wants maps under 32767 a side: the points as rows of 1024
    pad = -n % cols
    mx = np.r_[x, np.zeros(pad, np.float32)].reshape(-1, cols)
    my = np.r_[y, np.zeros(pad, np.float32)].reshape(-1, cols)
    out = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1, 3)[:n].astype(np.float32)


def _check_views(views) -> list:
    views = list(views)
    if not views:
        raise FaceAnimError("baking a texture needs at least one photo view")
    for i, view in enumerate(views):
        img, cam = getattr(view, "image", None), getattr(view, "camera", None)
        if img is None or cam is None:
            raise FaceAnimError(f"view {i} needs .image and .camera")
        img = np.asarray(img)
        if img.ndim != 3 or img.shape[2] < 3 or img.dtype != np.uint8:
            raise FaceAnimError(f"view {i}: the image must be (H, W, 3) uint8, got {img.shape} {img.dtype}")
        if tuple(cam.size) != (img.shape[1], img.shape[0]):
            raise FaceAnimError(f"view {i}: the camera is for a {cam.size[0]} x {cam.size[1]} photo, "
                                f"the image is {img.shape[1]} x {img.shape[0]}")
    return views


def _is_atlas(corners: np.ndarray, faces: np.ndarray, skin_tris: np.ndarray) -> bool:
    """Whether the skin's UVs are an :func:`atlas_uv` chart, periodic in u with PERIOD: some
    vertex has UVs exactly one period apart (on the seam), which no other layout has by chance."""
    c = corners[skin_tris].reshape(-1, 2)
    if not len(c) or c.min() < 0 or c.max() > 1:
        return False
    vid = faces[skin_tris].ravel()
    order = np.lexsort((c[:, 0], vid))
    vid, c = vid[order], c[order]
    first = np.r_[True, vid[1:] != vid[:-1]]  # each vertex's UVs sorted by u: first and last
    last = np.r_[vid[1:] != vid[:-1], True]
    span = c[last, 0] - c[first, 0]
    return bool(((np.abs(span - PERIOD) < 1e-7) & (np.abs(c[last, 1] - c[first, 1]) < 1e-9)).any())


def bake(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, face_uv: np.ndarray, parts: dict,
         views, size: int = 1024, blend: str = "pyramid") -> Bake:
    """Paint the atlas of a head from photos; see the module docstring. Returns a :class:`Bake`
    (the texture, the split between photos, the iris colour used and the time of each step).

    ``views``: objects with ``.image`` (H, W, 3) uint8 and ``.camera`` (a ViewCamera); the first
    is the front photo. ``size``: the atlas is ``size`` x ``size`` texels (a multiple of 16 makes
    the chart's period a whole number of texels; other sizes leave up to half a texel of
    mismatch along the seam at the back).
    ``blend``: "pyramid" (multiresolution merge) or "none" (hard split).
    """
    clock = time.perf_counter()
    seconds = {}

    def lap(name):
        nonlocal clock
        now = time.perf_counter()
        seconds[name] = now - clock
        clock = now

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    uv = np.asarray(uv, dtype=np.float64)
    face_uv = np.asarray(face_uv, dtype=np.int64)
    if face_uv.shape != f.shape or face_uv.min() < 0 or face_uv.max() >= len(uv):
        raise FaceAnimError("face_uv must be (T, 3) indices into uv, one row per triangle")
    size = int(size)
    if size < 64 or size > 8192:
        raise FaceAnimError(f"the atlas size must be 64 to 8192 texels, got {size}")
    if blend not in ("pyramid", "none"):
        raise FaceAnimError(f"blend must be 'pyramid' or 'none', got {blend!r}")
    views = _check_views(views)
    _, tlab = _part_labels(len(v), f, parts)
    normals = vertex_normals(v, f)
    corners = uv[face_uv]
    skin_tris = np.flatnonzero(tlab == 0)
    atlas = _is_atlas(corners, f, skin_tris)
    cavity = np.zeros(len(f), dtype=bool)
    strip = False
    if atlas:  # with a strip of tiles, no skin triangle crosses its top edge
        sv = corners[skin_tris, :, 1]
        below = sv.max(1) <= STRIP
        others = corners[(tlab > 0), :, 1]
        strip = bool(((sv.min(1) >= STRIP) | below).all() and (others <= STRIP).all()
                     and (below.any() or len(others)))
        cavity[skin_tris] = below & strip
    chart = (tlab == 0) & ~cavity

    # ---- every texel's triangle and barycentric coordinates
    skin_v = np.unique(f[skin_tris])
    lo, hi = v[skin_v].min(0), v[skin_v].max(0)
    diag = float(np.linalg.norm(hi - lo))
    dist = np.linalg.norm(v - (lo + hi) / 2, axis=1)
    zc = 1 - dist[f] / (dist.max() + 1e-12)  # where UVs overlap (ear folds) the outermost wins
    draw, ids, zs = corners, np.arange(len(f)), zc
    period = round(PERIOD * size) if atlas else size
    if atlas:
        past = np.flatnonzero(chart & (corners[:, :, 0].max(1) > PERIOD))
        if len(past):
            shifted = corners[past].copy()
            shifted[:, :, 0] -= PERIOD
            draw, ids, zs = np.concatenate([corners, shifted]), np.r_[ids, past], np.concatenate([zc, zc[past]])
    tri, bary = uv_raster(draw, (size, size), depth=zs, ids=ids)
    lap("uv raster")

    # ---- the skin chart's region of the atlas (rows, and one period of columns)
    tiled = ~chart & (tlab >= 0)  # triangles of the tiles: other parts and cavities
    rows = round((1 - STRIP) * size) if strip else size
    region = np.zeros((size, size), dtype=bool)
    region[:rows, :period] = True
    covered = tri >= 0
    is_chart = covered & chart[np.maximum(tri, 0)] & region
    ty, tx = np.nonzero(is_chart)
    t = tri[ty, tx]
    b = bary[ty, tx].astype(np.float64)
    X = np.einsum("nk,nkd->nd", b, v[f[t]])
    N = np.einsum("nk,nkd->nd", b, normals[f[t]])
    N /= np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12)

    # ---- sources: the photos, and the mirror images of the turned ones
    sources, names = [], []
    for i, view in enumerate(views):
        sources.append((i, False, 1.0 if i == 0 else SIDE_PRIOR))
        names.append(f"photo {i}")
        if abs(view.camera.yaw_degrees) >= MIRROR_MIN_YAW:
            sources.append((i, True, MIRROR_PRIOR))
            names.append(f"photo {i} mirrored")
    depth_maps = [_view_maps(v, f, view.camera) for view in views]
    lap("depth maps")

    tolerance = 0.003 * diag
    mirror = np.array([-1.0, 1.0, 1.0])
    chart_tris = np.flatnonzero(chart)
    cv = np.unique(f[chart_tris])
    # the texel's size on the surface (between horizontal neighbours), against each photo's pixel
    img_pos = np.full((size, size, 3), np.nan)
    img_pos[ty, tx] = X
    gaps = np.linalg.norm(img_pos[:, 1:] - img_pos[:, :-1], axis=-1)
    texel = float(np.nanmedian(gaps)) if np.isfinite(gaps).any() else 0.0
    texel_seen, texel_colour, vertex_score = [], [], np.zeros((len(sources), len(cv)))
    for j, (i, mirrored, prior) in enumerate(sources):
        cam, m = views[i].camera, (mirror if mirrored else 1.0)
        seen, x, y, _ = _visible(cam, depth_maps[i], X * m, N * m, tolerance * (3 if mirrored else 1))
        colour = np.zeros((len(X), 3), dtype=np.float32)
        if seen.any():
            colour[seen] = _sample(views[i].image, x[seen], y[seen], texel * cam.scale)
        texel_seen.append(seen)
        texel_colour.append(colour)
        vs, _, _, vcos = _visible(cam, depth_maps[i], v[cv] * m, normals[cv] * m, tolerance * (3 if mirrored else 1))
        vertex_score[j] = prior * np.where(vs, vcos, 0.0)
    lap("sampling")

    # ---- the split: photo scores smoothed over the surface, best photo that sees each texel
    n = len(v)
    local = np.full(n, -1, dtype=np.int64)
    local[cv] = np.arange(len(cv))
    e = local[np.vstack([f[chart_tris][:, [0, 1]], f[chart_tris][:, [1, 2]], f[chart_tris][:, [2, 0]]])]
    adj = sp.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])),
                        shape=(len(cv), len(cv))).tocsr()
    adj.data[:] = 1.0
    deg = np.asarray(adj.sum(1)).ravel()
    step = sp.diags(1 / np.maximum(deg, 1)) @ adj
    s = vertex_score.T
    for _ in range(SMOOTH_STEPS):
        s = 0.5 * s + 0.5 * (step @ s)
    texel_score = np.einsum("nk,nkj->nj", b, s[local[f[t]]])
    seen_all = np.stack(texel_seen, 1)
    texel_score = np.where(seen_all, texel_score, -np.inf)
    label = np.argmax(texel_score, 1)
    label[~seen_all.any(1)] = -1
    split = np.full((size, size), -1, dtype=np.int16)
    split[ty, tx] = label
    lap("split")

    # ---- merge the photos' atlases over the region, then fill what no photo sees
    wrap = atlas
    reg = (slice(0, rows), slice(0, period))
    shape = (rows, period)
    ry, rx = ty, tx  # region coordinates = atlas coordinates (the region starts at 0, 0)
    owners = [j for j in range(len(sources)) if (label == j).any()]
    seen_region = split[reg] >= 0
    hard = np.zeros(shape + (3,), dtype=np.float32)  # the hard split
    for j in owners:
        sel = label == j
        hard[ry[sel], rx[sel]] = texel_colour[j][sel]
    if blend == "none" or len(owners) <= 1:
        merged = hard
    else:
        # each photo's atlas, extended beyond what it sees by the hard split (filled where no
        # photo sees): the coarse levels, whose masks reach far past the merge lines, then mix
        # the same colours there instead of a guess
        base = push_pull(hard, seen_region, wrap)
        images, masks = [], []
        for j in owners:
            img = base.copy()
            img[ry[texel_seen[j]], rx[texel_seen[j]]] = texel_colour[j][texel_seen[j]]
            images.append(img)
            mask = np.zeros(shape, dtype=np.float32)
            mask[ry[label == j], rx[label == j]] = 1.0
            masks.append(mask)
        merged = pyramid_blend(images, masks, wrap)
    lap("merge")
    out = np.zeros((size, size, 3), dtype=np.float32)
    out[reg] = push_pull(merged, seen_region, wrap)
    if atlas and period < size:
        out[:rows, period:] = out[:rows, :size - period]
    lap("fill")

    # ---- parts no photo sees: eyes, teeth, gums and tongue, cavities
    iris = None
    eyes = {}
    for name in ("eyeball_L", "eyeball_R"):
        if name in parts and len(parts[name]) >= 4:
            centre, radius = _sphere_fit(v[np.asarray(parts[name], dtype=np.int64)])
            eyes[name] = centre
            got = _iris_colour(views[0], centre, radius)
            if got is not None:
                iris = got if iris is None else (iris + got) / 2
    iris = np.asarray(DEFAULT_IRIS if iris is None else iris, dtype=np.float64)
    py, px_ = np.nonzero(covered & tiled[np.maximum(tri, 0)])
    if len(py):
        pt = tri[py, px_]
        pb = bary[py, px_].astype(np.float64)
        P = np.einsum("nk,nkd->nd", pb, v[f[pt]])
        colour = np.zeros((len(pt), 3))
        lab = tlab[pt]
        for k, name in enumerate(PART_NAMES):
            sel = lab == k
            if not sel.any():
                continue
            if name in eyes:
                phi, psi = _eye_angles(P[sel], eyes[name])
                colour[sel] = eye_colour(phi, psi, iris)
            elif name in ("teeth", "gums_tongue"):
                colour[sel] = _mouth_colours(v, f, parts, name, P[sel], pt[sel], pb[sel])
        cav = cavity[pt]
        if cav.any():
            colour[cav] = _cavity_colours(v, f, chart, cavity, corners, out, pt[cav], pb[cav])
        # triangles of no part keep black; the strip's gaps are filled below
        out[py, px_] = colour
    if atlas and strip:
        known = np.zeros((size, size), dtype=bool)
        known[py, px_] = True
        for box in TILES.values():
            _fill_tile(out, known, box)
    elif not atlas and len(py):
        known = split >= 0
        known[py, px_] = True
        out = push_pull(np.where(known[..., None], out, 0), known)
    lap("parts")
    texture = np.clip(np.rint(out), 0, 255).astype(np.uint8)
    return Bake(texture, split, names, iris, seconds)


def _cavity_colours(v, f, chart, cavity, corners, atlas_img, tris, bary) -> np.ndarray:
    """Colours of cavity texels: from the colour of the skin at the cavity's rim, darkening to
    CAVITY with depth behind the visible skin (each cavity its own rim colour)."""
    from scipy.sparse.csgraph import connected_components

    n = len(v)
    size = atlas_img.shape[0]
    ct = np.flatnonzero(cavity)
    e = np.vstack([f[ct][:, [0, 1]], f[ct][:, [1, 2]]])
    _, comp = connected_components(sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)),
                                   directed=False)
    exposed = np.zeros(n, dtype=bool)
    exposed[f[chart].ravel()] = True
    # a chart UV for each exposed vertex, and the atlas colour there
    vert_uv = np.zeros((n, 2))
    vert_uv[f[chart].ravel()] = corners[chart].reshape(-1, 2)
    ex = np.flatnonzero(exposed)
    col = np.clip((vert_uv[ex] * [size, -size] + [0, size]).astype(np.int64), 0, size - 1)
    ex_colour = atlas_img[col[:, 1], col[:, 0]]
    tree = cKDTree(v[ex])
    cav_v = np.unique(f[ct])
    depth = np.zeros(n)
    nearest = np.zeros(n, dtype=np.int64)
    depth[cav_v], nearest[cav_v] = tree.query(v[cav_v])
    # the rim: exposed vertices nearest to the cavity's vertices, averaged per cavity
    rim = np.zeros((comp.max() + 1, 3))
    cnt = np.zeros(comp.max() + 1)
    np.add.at(rim, comp[cav_v], ex_colour[nearest[cav_v]])
    np.add.at(cnt, comp[cav_v], 1)
    rim /= np.maximum(cnt, 1)[:, None]
    deepest = np.zeros(comp.max() + 1)
    np.maximum.at(deepest, comp[cav_v], depth[cav_v])
    c = comp[f[tris, 0]]
    d = np.einsum("nk,nk->n", bary, depth[f[tris]])
    a = _smoothstep(d / np.maximum(0.6 * deepest[c], 1e-12))[:, None]
    return rim[c] * (1 - a) + np.asarray(CAVITY, dtype=np.float64)[None] * a


def _fill_tile(out: np.ndarray, known: np.ndarray, box) -> None:
    """Fill the texels of the tile ``box`` (u0, v0, u1, v1) of the atlas ``out`` that are not
    ``known`` from those that are (:func:`push_pull`), in place."""
    size = out.shape[0]
    u0, v0, u1, v1 = box
    rows = slice(round((1 - v1) * size), round((1 - v0) * size))
    cols = slice(round(u0 * size), round(u1 * size))
    if known[rows, cols].any():
        out[rows, cols, :3] = push_pull(out[rows, cols, :3], known[rows, cols])


def _mouth_colours(v, f, parts, name, points, tris, bary) -> np.ndarray:
    """Colours of teeth or gums_tongue texels at ``points`` (barycentric ``bary`` in ``tris``):
    the part's colour darkening towards the back of the mouth, the gums and the tongue's body in
    the lips' shadow (GUMS_LIGHT, TONGUE_LIGHT) and the tongue's tip lit."""
    idx = np.asarray(parts[name], dtype=np.int64)
    zmax, zmin = v[idx, 2].max(), v[idx, 2].min()
    back = np.clip((zmax - points[:, 2]) / max(zmax - zmin, 1e-12), 0, 1)
    shade = (1 - 0.55 * back)[:, None]
    if name == "teeth":
        return np.asarray(TEETH, dtype=np.float64)[None] * shade
    tongue = _gum_tongue_split(v, idx, np.asarray(parts.get("teeth", []), dtype=np.int64))
    is_t = np.zeros(len(v))
    is_t[idx] = tongue
    wt = np.einsum("nk,nk->n", bary, is_t[f[tris]])[:, None]
    tip = np.zeros((len(wt), 1))
    if tongue.any():
        tz = v[idx[tongue], 2]
        front = (points[:, 2] - tz.min()) / max(np.ptp(tz), 1e-12)
        tip = _smoothstep((front - (1 - TONGUE_TIP)) / TONGUE_TIP)[:, None]
    light = GUMS_LIGHT * (1 - wt) + (TONGUE_LIGHT + (1 - TONGUE_LIGHT) * tip) * wt
    return (np.asarray(GUMS)[None] * (1 - wt) + np.asarray(TONGUE)[None] * wt) * shade * light


def repaint_mouth(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, face_uv: np.ndarray, parts: dict,
                  texture: np.ndarray) -> np.ndarray:
    """A copy of an atlas from :func:`bake` with its gums and tongue tiles painted again (the
    colours of :func:`_mouth_colours`, the tiles' gaps filled as :func:`bake` fills them); the rest
    of the atlas is kept texel for texel. For a committed head whose interior colours changed."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    out = np.asarray(texture).astype(np.float64)
    size = out.shape[0]
    if out.ndim != 3 or out.shape[1] != size:
        raise FaceAnimError("the atlas must be a square (size, size, 3) image")
    if "gums_tongue" not in parts:
        return np.asarray(texture).copy()
    _, tlab = _part_labels(len(v), f, parts)
    mouth = np.flatnonzero(tlab == PART_NAMES.index("gums_tongue"))
    corners = np.asarray(uv, dtype=np.float64)[np.asarray(face_uv, dtype=np.int64)[mouth]]
    tri, bary = uv_raster(corners, (size, size), ids=mouth)
    py, px_ = np.nonzero(tri >= 0)
    pt = tri[py, px_]
    pb = bary[py, px_].astype(np.float64)
    P = np.einsum("nk,nkd->nd", pb, v[f[pt]])
    out[py, px_, :3] = _mouth_colours(v, f, parts, "gums_tongue", P, pt, pb)
    known = np.zeros((size, size), dtype=bool)
    known[py, px_] = True
    for key in ("gums", "tongue"):
        _fill_tile(out, known, TILES[key])
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def bake_texture(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, face_uv: np.ndarray, parts: dict,
                 views, size: int = 1024, blend: str = "pyramid") -> np.ndarray:
    """(size, size, 3) uint8 atlas of the head painted from ``views`` (see :func:`bake`)."""
    return bake(vertices, faces, uv, face_uv, parts, views, size, blend).texture


def seam_step(texture: np.ndarray, split: np.ndarray, width: int = 2) -> float:
    """Mean absolute RGB difference (0..255) across the merge lines of ``split``: for each pair
    of neighbouring texels painted from different photos, the mean of ``width`` texels just
    inside one side against the mean of ``width`` texels just outside, on the line through the
    pair. Only texels painted by a photo count (split >= 0)."""
    img = np.asarray(texture, dtype=np.float64)[..., :3]
    lab = np.asarray(split)
    steps = []
    for axis in (0, 1):
        img_a, lab_a = (img, lab) if axis == 1 else (img.transpose(1, 0, 2), lab.T)
        w = lab_a.shape[1]
        if w < 2 * width:
            continue
        # pair (x, x + 1) for x in [width - 1, w - width - 1]
        x = np.arange(width - 1, w - width)
        left, right = lab_a[:, x], lab_a[:, x + 1]
        ok = (left >= 0) & (right >= 0) & (left != right)
        inside, outside = 0.0, 0.0
        for k in range(width):
            ok &= (lab_a[:, x - k] == left) & (lab_a[:, x + 1 + k] == right)
            inside = inside + img_a[:, x - k]
            outside = outside + img_a[:, x + 1 + k]
        d = np.abs(inside - outside).mean(-1) / width
        steps.append(d[ok])
    allsteps = np.concatenate(steps) if steps else np.zeros(0)
    return float(allsteps.mean()) if len(allsteps) else 0.0
