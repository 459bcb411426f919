"""Named facial landmarks on any mesh: schemes, detection and JSON exchange.

Detection (seed paper section 2.2): render the mesh from the front with a parallel camera
(textured, or shaded in a skin colour when it has no texture), run the MediaPipe face mesh on
the render (model inside the shipped Face Landmarker, 478 points with the irises), and
cast a ray from each detected image point onto the surface. Each landmark keeps its MediaPipe
index, its triangle and barycentric coordinates, so it follows the surface when the mesh
deforms (:meth:`Landmarks.on`).

Left and right are the subject's own: ``mouth_corner_right`` is MediaPipe point 61, on the left
of a frontal image.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from faceanim.errors import LandmarkError, shown
from faceanim.io.files import read_json, write_json

# the basic 22-point set used by later modules (name, MediaPipe index)
BASIC22 = (
    ("eye_outer_right", 33), ("eye_inner_right", 133), ("eye_inner_left", 362), ("eye_outer_left", 263),
    ("brow_outer_right", 70), ("brow_middle_right", 105), ("brow_inner_right", 107),
    ("brow_inner_left", 336), ("brow_middle_left", 334), ("brow_outer_left", 300),
    ("nose_bridge", 168), ("nose_tip", 4), ("nostril_right", 98), ("nostril_left", 327),
    ("subnasale", 2),
    ("mouth_corner_right", 61), ("mouth_corner_left", 291),
    ("upper_lip_top", 0), ("upper_lip_inner", 13), ("lower_lip_inner", 14), ("lower_lip_bottom", 17),
    ("chin", 152),
)
# further well-known MediaPipe points, named in the 478 scheme
_EXTRA_NAMES = {
    10: "forehead_top", 468: "iris_centre_right", 473: "iris_centre_left",
    159: "upper_eyelid_right", 145: "lower_eyelid_right", 386: "upper_eyelid_left", 374: "lower_eyelid_left",
    234: "face_edge_right", 454: "face_edge_left", 50: "cheek_right", 280: "cheek_left",
}
MEDIAPIPE_NAMES = {i: f"mp{i}" for i in range(478)}
MEDIAPIPE_NAMES.update(_EXTRA_NAMES)
MEDIAPIPE_NAMES.update({i: n for n, i in BASIC22})

SCHEMES = {
    "mediapipe478": tuple((MEDIAPIPE_NAMES[i], i) for i in range(478)),
    "basic22": BASIC22,
}


@dataclass
class Landmarks:
    """Named 3D landmarks on a mesh surface.

    ``indices`` are MediaPipe indices; ``triangles`` and ``barycentric`` attach each point to the
    surface (``-1`` / zeros when a point was given by position only).
    """

    scheme: str
    names: list[str]
    indices: np.ndarray
    positions: np.ndarray
    triangles: np.ndarray
    barycentric: np.ndarray
    detected_on: str | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.names)

    def __contains__(self, name: str) -> bool:
        return name in self.names

    def __getitem__(self, name: str) -> np.ndarray:
        """Position of the landmark called ``name``."""
        try:
            return self.positions[self.names.index(name)]
        except ValueError:
            raise LandmarkError(f"no landmark named '{shown(name)}' in scheme '{self.scheme}'") from None

    def subset(self, scheme: str) -> Landmarks:
        """The landmarks of another (smaller) scheme, e.g. ``basic22`` out of ``mediapipe478``."""
        if scheme not in SCHEMES:
            raise LandmarkError(f"unknown landmark scheme '{scheme}'; choose one of: {', '.join(SCHEMES)}")
        where = {int(i): k for k, i in enumerate(self.indices)}
        missing = [n for n, i in SCHEMES[scheme] if i not in where]
        if missing:
            raise LandmarkError(f"scheme '{scheme}' needs landmarks missing here: {', '.join(missing[:5])}")
        sel = np.array([where[i] for _, i in SCHEMES[scheme]])
        return Landmarks(scheme, [n for n, _ in SCHEMES[scheme]], self.indices[sel], self.positions[sel],
                         self.triangles[sel], self.barycentric[sel], self.detected_on)

    def on(self, mesh_or_vertices, faces: np.ndarray | None = None) -> np.ndarray:
        """Positions of the landmarks on a deformed mesh of the same topology."""
        if hasattr(mesh_or_vertices, "vertices"):
            verts, faces = mesh_or_vertices.vertices, mesh_or_vertices.faces
        else:
            verts = np.asarray(mesh_or_vertices)
        if faces is None:
            raise LandmarkError("give the faces of the mesh to move landmarks onto it")
        if (self.triangles < 0).any():
            raise LandmarkError("these landmarks were given by position only and cannot follow a deformation")
        if faces is not None and len(self.triangles) and self.triangles.max() >= len(faces):
            raise LandmarkError(f"landmark triangle {int(self.triangles.max())} is not a triangle of this mesh "
                                f"({len(faces)} triangles); were the landmarks made for another mesh?")
        corners = verts[faces[self.triangles]]
        return np.einsum("nk,nkd->nd", self.barycentric, corners)

    def to_dict(self) -> dict:
        pts = []
        for k in range(len(self)):
            pts.append({
                "index": int(self.indices[k]), "name": self.names[k],
                "position": [float(x) for x in self.positions[k]],
                "triangle": int(self.triangles[k]),
                "barycentric": [float(x) for x in self.barycentric[k]],
            })
        d = {"scheme": self.scheme, "points": pts}
        if self.detected_on:
            d["detected_on"] = self.detected_on
        return d

    def save(self, path: str | os.PathLike) -> Path:
        write_json(path, self.to_dict())
        return Path(path)

    @classmethod
    def from_dict(cls, d: object, source: str = "landmarks") -> Landmarks:
        """Landmarks from a JSON object ``{"scheme": ..., "points": [{"name", "index", "position",
        "triangle", "barycentric"}, ...]}``; only ``position`` is required.

        Refused with a :class:`LandmarkError` naming the point: positions that are not three finite
        numbers (text, null, true/false, nested lists, NaN, infinity, beyond 1e12), indices that are
        not whole numbers or outside the MediaPipe range 0..477 (or outside the named scheme),
        repeated indices or names, null fields, triangles below -1, barycentrics that are not three
        finite numbers, more than ``MAX_POINTS`` points.
        """
        return _landmarks_from_dict(cls, d, source)

    @classmethod
    def load(cls, path: str | os.PathLike) -> Landmarks:
        return cls.from_dict(read_json(path, "landmark file"), str(path))

    def attached_to(self, mesh, max_distance: float = 0.05) -> Landmarks:
        """These landmarks snapped to ``mesh``'s surface, with triangles and barycentrics.

        Used when landmarks come from a file instead of detection. A point farther from the
        surface than ``max_distance`` times the mesh's bounding-box diagonal is refused.
        """
        limit = max_distance * mesh.bounding_box_diagonal
        # points far outside the mesh's box are refused before the closest-point search (whose
        # tree loses the far points and fails on them)
        lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
        box = np.linalg.norm(np.maximum(np.maximum(lo - self.positions, self.positions - hi), 0.0), axis=1)
        far = np.flatnonzero(box > limit)
        if far.size:
            k = far[0]
            raise LandmarkError(
                f"landmark '{self.names[k]}' is {box[k]:.4g} or more from the surface of '{mesh.name}' (more than "
                f"{limit:.4g}); are the landmarks for this mesh and in its units?")
        pos, dist, tri = mesh.closest_points(self.positions)
        far = np.flatnonzero(dist > limit)
        if far.size:
            k = far[0]
            raise LandmarkError(
                f"landmark '{self.names[k]}' is {dist[k]:.4g} from the surface of '{mesh.name}' (more than "
                f"{limit:.4g}); are the landmarks for this mesh and in its units?")
        return Landmarks(self.scheme, list(self.names), self.indices.copy(), pos, np.asarray(tri),
                         mesh.barycentric(pos, tri), self.detected_on)


MAX_POINTS = 100_000  # landmarks in one file
MAX_COORDINATE = 1e12


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _kind(x) -> str:
    if x is None:
        return "null"
    if isinstance(x, bool):
        return "true/false"
    if isinstance(x, str):
        return "text"
    if isinstance(x, dict):
        return "an object"
    if isinstance(x, list):
        return "a list"
    return type(x).__name__


def _vector(value, n: int, where: str, field: str) -> np.ndarray:
    if not isinstance(value, list) or len(value) != n or not all(_is_number(x) for x in value):
        got = (f"{len(value)} value(s)" if isinstance(value, list) and len(value) != n else
               "a list holding " + ", ".join(sorted({_kind(x) for x in value if not _is_number(x)}))
               if isinstance(value, list) else _kind(value))
        raise LandmarkError(f"{where} has an invalid {field}: expected {n} numbers, got {got}")
    try:
        v = np.array(value, dtype=np.float64)
    except OverflowError:
        v = np.array([np.inf])
    if not np.all(np.isfinite(v)) or np.abs(v).max() > MAX_COORDINATE:
        raise LandmarkError(f"{where} has an invalid {field}: NaN, infinite or absurdly large")
    return v


def _whole(value, where: str, field: str, low: int, high: int) -> int:
    if not _is_number(value) or (isinstance(value, float) and not value.is_integer()):
        raise LandmarkError(f"{where}: '{field}' must be a whole number, got "
                            f"{value if _is_number(value) else _kind(value)}")
    if not low <= value <= high:
        raise LandmarkError(f"{where}: '{field}' {int(value)} is out of range ({low}..{high})")
    return int(value)


def _landmarks_from_dict(cls, d: object, source: str) -> Landmarks:
    shape = "expected {'scheme': ..., 'points': [{'name', 'index', 'position': [x, y, z]}, ...]}"
    if not isinstance(d, dict):
        raise LandmarkError(f"{source}: {shape}, got {_kind(d)}")
    points = d.get("points")
    if not isinstance(points, list) or not points:
        raise LandmarkError(f"{source}: {shape}; 'points' is "
                            f"{'missing' if 'points' not in d else 'empty' if points == [] else _kind(points)}")
    if len(points) > MAX_POINTS:
        raise LandmarkError(f"{source}: {len(points)} points; at most {MAX_POINTS} are supported")
    scheme = d.get("scheme", "custom")
    if not isinstance(scheme, str) or not scheme.strip() or len(scheme) > 100:
        raise LandmarkError(f"{source}: 'scheme' must be a name (text), got {_kind(scheme)}")
    detected_on = d.get("detected_on")
    if detected_on is not None and not isinstance(detected_on, str):
        raise LandmarkError(f"{source}: 'detected_on' must be text, got {_kind(detected_on)}")
    allowed = {i for _, i in SCHEMES[scheme]} if scheme in SCHEMES else None
    names, idx, pos, tri, bary = [], [], [], [], []
    seen_index: dict[int, int] = {}
    seen_name: dict[str, int] = {}
    for k, p in enumerate(points):
        where = f"{source}: point {k}"
        if not isinstance(p, dict):
            raise LandmarkError(f"{where} must be an object with a 'position' [x, y, z], got {_kind(p)}")
        for key, value in p.items():
            if value is None:
                raise LandmarkError(f"{where}: '{str(key)[:40]}' is null; give a value or leave the key out")
        if "position" not in p:
            raise LandmarkError(f"{where} needs a 'position' [x, y, z]")
        xyz = _vector(p["position"], 3, where, "position")
        i = _whole(p["index"], where, "index", 0, len(MEDIAPIPE_NAMES) - 1) if "index" in p else -1
        if i >= 0:
            if allowed is not None and i not in allowed:
                raise LandmarkError(f"{where}: index {i} is not a landmark of scheme '{scheme}'")
            if i in seen_index:
                raise LandmarkError(f"{where}: index {i} repeats point {seen_index[i]}; each landmark once")
            seen_index[i] = k
        name = p.get("name")
        if name is not None and (not isinstance(name, str) or not name.strip() or len(name) > 200):
            raise LandmarkError(f"{where}: 'name' must be text, got {_kind(name)}")
        name = name or MEDIAPIPE_NAMES.get(i, f"point{k}")
        if name in seen_name:
            raise LandmarkError(f"{where}: name '{shown(name)}' repeats point {seen_name[name]}; each landmark once")
        seen_name[name] = k
        t = _whole(p["triangle"], where, "triangle", -1, 2**62) if "triangle" in p else -1
        if "barycentric" in p:
            b = _vector(p["barycentric"], 3, where, "barycentric")
        elif t >= 0:
            raise LandmarkError(f"{where} has a 'triangle' but no 'barycentric' [a, b, c]")
        else:
            b = np.zeros(3)
        names.append(name)
        idx.append(i)
        pos.append(xyz)
        tri.append(t)
        bary.append(b)
    return cls(scheme, names, np.array(idx, dtype=np.int64), np.array(pos), np.array(tri, dtype=np.int64),
               np.array(bary, dtype=np.float64), detected_on)


# detection runs MediaPipe on the render at these scales (about the centre) and keeps the median of
# each point: MediaPipe's points jitter by ~1% of the eye distance with the framing, and the
# median of three is steadier (AU rebuild on FaceWarehouse 0.185 -> 0.184, ICT 0.279 -> 0.278)
DETECTION_SCALES = (0.9, 1.0, 1.1)


def _zoom(img: np.ndarray, scale: float) -> tuple[np.ndarray, float, float]:
    """The image zoomed about its centre, same size (cropped, or padded with its corner colour);
    and the (x, y) offsets that map normalised coordinates back: x = (x' * w + dx) / (w * scale)."""
    import cv2

    h, w = img.shape[:2]
    big = cv2.resize(img, (max(1, round(w * scale)), max(1, round(h * scale))),
                     interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
    hh, ww = big.shape[:2]
    if scale >= 1:
        y0, x0 = (hh - h) // 2, (ww - w) // 2
        return np.ascontiguousarray(big[y0:y0 + h, x0:x0 + w]), x0, y0
    canvas = np.empty_like(img)
    canvas[:] = img[0, 0]
    y0, x0 = (h - hh) // 2, (w - ww) // 2
    canvas[y0:y0 + hh, x0:x0 + ww] = big
    return canvas, -x0, -y0


def detect_landmarks_in_image(rgb: np.ndarray, scales=DETECTION_SCALES, agreement: bool = False):
    """MediaPipe face mesh on an RGB image: (478, 3) points, x and y normalised to [0, 1], the
    median over the image zoomed by each of ``scales``. With ``agreement``: (points, how many
    scales found a face, the median distance of a scale's points from the median, normalised
    image units; 0 with one scale).

    Raises :class:`LandmarkError` when no face is found.
    """
    img = np.ascontiguousarray(np.asarray(rgb)[..., :3], dtype=np.uint8)
    if img.ndim != 3 or min(img.shape[:2]) < 32:
        raise LandmarkError(f"expected an RGB image of at least 32x32 pixels, got shape {img.shape}")
    from faceanim.face.mediapipe import FaceMesh
    from faceanim.io.files import native_stderr_quiet

    h, w = img.shape[:2]
    found = []
    # quiet from the graph's start to its close: its threads log (TensorFlow Lite's delegate, absl's
    # warnings) when they please, not only while a call of ours runs
    with native_stderr_quiet(), FaceMesh(video=False, confidence=0.3) as mesh:
        for s in scales:
            view, dx, dy = (img, 0, 0) if s == 1 else _zoom(img, s)
            p = mesh(view)
            if p is None:
                continue
            vh, vw = view.shape[:2]  # back to MediaPipe's normalised units of the whole image
            p = p / np.array([vw, vh, vw])
            p[:, 0] = (p[:, 0] * w + dx) / (w * s)
            p[:, 1] = (p[:, 1] * h + dy) / (h * s)
            found.append(p)
    if not found:
        raise LandmarkError("no face found in the image; check that the face is frontal, lit and large in the frame")
    stack = np.stack(found)
    med = np.median(stack, axis=0)
    if not agreement:
        return med
    spread = float(np.median(np.linalg.norm(stack[:, :, :2] - med[None, :, :2], axis=2)))
    return med, len(found), spread


# a rendered mesh is a face only when MediaPipe finds it at this many of the detection scales and
# their points agree within SCALE_SPREAD (normalised image units). Measured (median point distance
# from the scales' median): real faces (default face, FaceWarehouse's 20 scans, 12 remeshed ICT
# identities up to 2 standard deviations) 0.0009-0.0026, VRoid's anime face 0.0038; a sphere is
# found at one scale only, a torus at three with 0.027; cubes, planes, cylinders, cones and noise
# are not found at all (scripts/eval_registration.py --faces prints the table)
MIN_SCALES_FOUND = 2
SCALE_SPREAD = 0.012


def detect_landmarks(mesh, scheme: str = "mediapipe478", forward: str = "+z", up: str = "+y",
                     size: int = 768, return_image: bool = False):
    """Detect named landmarks on ``mesh`` by rendering it, running MediaPipe and ray casting.

    ``forward`` and ``up`` say which mesh axes the face looks along and points up (FaceWarehouse,
    ICT and faceanim's default face: +z and +y).
    """
    if scheme not in SCHEMES:
        raise LandmarkError(f"unknown landmark scheme '{scheme}'; choose one of: {', '.join(SCHEMES)}")
    with detection_view(mesh, forward, up, size) as r:
        image = r.render()
        try:
            pts2d, found, spread = detect_landmarks_in_image(image, agreement=True)
        except LandmarkError as exc:
            raise LandmarkError(
                f"{exc} (rendered '{mesh.name}' looking along {forward} with {up} up; "
                "pass --forward/--up if the face points elsewhere, or give landmarks in a JSON file)"
            ) from None
        if found < min(MIN_SCALES_FOUND, len(DETECTION_SCALES)) or spread > SCALE_SPREAD:
            raise LandmarkError(
                f"no face found in '{mesh.name}': the face detector's points are not stable on its render "
                f"(looking along {forward} with {up} up); pass --forward/--up if the face points elsewhere, "
                "or give landmarks in a JSON file")
        origins, dirs = r.pixel_rays(pts2d[:, :2])
    pos, tri = _cast_onto_surface(mesh, origins, dirs, r.rotation)
    bary = mesh.barycentric(pos, tri)
    names = [n for n, _ in SCHEMES[scheme]]
    idx = np.array([i for _, i in SCHEMES[scheme]])
    lms = Landmarks(scheme, names, idx, pos[idx], tri[idx], bary[idx], mesh.source or mesh.name)
    return (lms, image) if return_image else lms


def detection_view(mesh, forward: str = "+z", up: str = "+y", size: int = 768):
    """The parallel front view used for detection; its normalised image coordinates are the
    ones :func:`pick_surface_points` takes (x right, y down, in [0, 1])."""
    from faceanim.render import OffscreenRenderer, view_rotation

    rot = view_rotation(forward, up)
    # flat-shaded (each triangle on its own vertices): creases read more clearly to MediaPipe
    # than smooth shading (AU rebuild on FaceWarehouse 0.198 -> 0.185)
    return OffscreenRenderer(mesh.faceted(), size=(size, size), parallel=True, rotation=rot,
                             frame_vertices=_face_frame(mesh, rot), margin=1.0)


def pick_surface_points(mesh, xy, forward: str = "+z", up: str = "+y", *,
                        what: str = "pick") -> tuple[np.ndarray, np.ndarray]:
    """2D picks to 3D surface points by ray casting (seed paper section 2.2).

    ``xy`` (N, 2) are normalised coordinates in the front view that ``faceanim landmarks
    --image`` saves (x right, y down, in [0, 1]). Returns (positions (N, 3), triangle ids (N,)).
    A pick outside [0, 1] or one whose ray misses the mesh (the background around the face) is
    refused with a :class:`LandmarkError` naming it (``what`` says what it is, e.g. "GDE pick").
    A ray through a gap of the surface (an eye hole, parted lips) snaps to the nearest vertex.
    """
    try:
        xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
    except (TypeError, ValueError, OverflowError):
        raise LandmarkError(f"{what}s must be [x, y] pairs of numbers in 0..1") from None
    if xy.ndim != 2 or xy.shape[1] != 2 or not np.all(np.isfinite(xy)):
        raise LandmarkError(f"{what}s must be finite (N, 2) image coordinates, got shape {xy.shape}")
    out = ((xy < 0) | (xy > 1)).any(axis=1)
    if out.any():
        raise LandmarkError(f"{what} {_fmt_pick(xy[np.flatnonzero(out)[0]])} is outside the image: picks are "
                            "normalised coordinates in 0..1 (x right, y down)")
    with detection_view(mesh, forward, up) as r:
        origins, dirs = r.pixel_rays(xy)
    missed = _misses_the_mesh(mesh, origins, dirs, r.rotation)
    if missed.any():
        raise LandmarkError(f"{what} {_fmt_pick(xy[np.flatnonzero(missed)[0]])} does not hit the face (its ray "
                            f"misses '{mesh.name}' looking along {forward}); pick a point on the face in the "
                            "front view")
    return _cast_onto_surface(mesh, origins, dirs, r.rotation)


def _fmt_pick(p) -> str:
    return f"[{p[0]:.4g}, {p[1]:.4g}]"


def _misses_the_mesh(mesh, origins, dirs, rot) -> np.ndarray:
    """Rays that hit no triangle (front or back) and pass outside the mesh's outline in the view
    (outside the convex hull of the projected vertices, or farther from every projected vertex
    than a tenth of the projected size): the background, not a gap in the surface. A ray within
    two edge lengths of a vertex is never a miss (picks on the outline graze it)."""
    hit, _, _ = mesh.cast_rays(origins, dirs)
    if hit.all():
        return ~hit
    from scipy.spatial import Delaunay, QhullError, cKDTree

    view = (mesh.vertices @ rot.T)[:, :2]
    o = (origins[~hit] @ rot.T)[:, :2]
    span = float(np.linalg.norm(view.max(0) - view.min(0))) or 1.0
    dist, _ = cKDTree(view).query(o)
    outside = dist > 0.1 * span
    try:
        outside |= Delaunay(view).find_simplex(o) < 0
    except (QhullError, ValueError):
        pass  # a flat or degenerate outline: the distance test alone
    outside &= dist > 2.0 * mesh.mean_edge_length
    miss = np.zeros(len(origins), dtype=bool)
    miss[~hit] = outside
    return miss


def _cast_onto_surface(mesh, origins, dirs, rot) -> tuple[np.ndarray, np.ndarray]:
    """First front-facing hit of each ray; rays through an opening snap to the nearest vertex."""
    hit, pos, tri = mesh.cast_rays(origins, dirs)
    # a first hit on a back face means the ray went through an opening (eye holes of a scan,
    # parted lips) and met the inside of the head: treat it as a miss
    fv = mesh.vertices[mesh.faces[np.where(hit, tri, 0)]]
    normal = np.cross(fv[:, 1] - fv[:, 0], fv[:, 2] - fv[:, 0])
    hit &= (normal * dirs).sum(1) < 0
    if (~hit).any():
        v = _nearest_visible_vertex(mesh, origins[~hit], dirs[~hit], rot)
        pos[~hit] = mesh.vertices[v]
        tri[~hit] = mesh.vertex_triangle[v]
    return pos, tri


# candidates tried per ray that went through a gap, nearest first, until one is visible
SNAP_CANDIDATES = (32, 512, 8192)
# a ray through a gap takes the front-most visible vertex this far (fraction of the mesh's size in
# the view, at least half an edge) beyond the visible vertex nearest to it: the lid over an eye
# hole rather than the socket wall behind its rim
SNAP_WINDOW = 0.005


def _nearest_visible_vertex(mesh, origins, dirs, rot) -> np.ndarray:
    """For each (parallel) ray through a gap of the surface, a vertex at the gap's rim that the
    camera sees from outside (its own ray meets nothing in front of it, on a front face): the
    front-most of those within :data:`SNAP_WINDOW` of the nearest one in the image. On a dense
    mesh the vertex nearest in the image is as likely to lie on the back of the head as on the
    rim, so visibility is checked, not guessed from depth."""
    from scipy.spatial import cKDTree

    verts = mesh.vertices
    view = verts @ rot.T
    tree = cKDTree(view[:, :2])
    plane = (origins @ rot.T)[:, :2]
    span = float(np.linalg.norm(view[:, :2].max(0) - view[:, :2].min(0)))
    window = max(0.5 * mesh.mean_edge_length, SNAP_WINDOW * span)
    tol = 2.0 * mesh.mean_edge_length
    d = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    out = np.full(len(origins), -1, dtype=np.int64)
    for count in SNAP_CANDIDATES:
        todo = np.flatnonzero(out < 0)
        if todo.size == 0:
            break
        count = min(count, len(verts))
        dist, idx = tree.query(plane[todo], k=count)
        dist, idx = dist.reshape(len(todo), count), idx.reshape(len(todo), count)
        ray_d = np.repeat(d[todo], count, axis=0)
        cand = verts[idx.ravel()]
        t_v = np.einsum("ij,ij->i", cand - np.repeat(origins[todo], count, axis=0), ray_d)
        starts = cand - t_v[:, None] * ray_d  # each candidate's own ray, from the origins' plane
        hit, pos, tri = mesh.cast_rays(starts, ray_d)  # all pending rays' candidates at once
        # seen, on the outside of the surface (through an eye hole the camera sees the inside
        # of the back of the head: back faces)
        fv = verts[mesh.faces[np.maximum(tri, 0)]]
        outside = np.einsum("ij,ij->i", np.cross(fv[:, 1] - fv[:, 0], fv[:, 2] - fv[:, 0]), ray_d) < 0
        seen = (hit & (np.einsum("ij,ij->i", pos - starts, ray_d) >= t_v - tol) & outside).reshape(len(todo), count)
        for row, k in enumerate(todo):
            if seen[row].any():
                near = seen[row] & (dist[row] <= dist[row, int(np.argmax(seen[row]))] + window)
                out[k] = idx[row][near][int(np.argmax(view[idx[row][near], 2]))]
            elif count == len(verts) or count == SNAP_CANDIDATES[-1]:
                out[k] = idx[row][int(np.argmax(view[idx[row], 2]))]  # nothing visible: the front-most
    return out


def _face_frame(mesh, rot: np.ndarray) -> np.ndarray:
    """Vertices that frame the face for detection: the front-facing part of a head.

    A full head (with neck and shoulders) renders the face small; framing the front half of the
    upper part keeps the face large enough for the detector.
    """
    v = mesh.vertices @ rot.T
    lo, hi = v.min(0), v.max(0)
    depth = hi[2] - lo[2]
    front = v[:, 2] >= hi[2] - 0.6 * depth
    sel = v[front]
    if len(sel) < 3:
        return mesh.vertices
    return sel @ rot


# the face oval of the MediaPipe face mesh, in order (forehead top, subject's left side, chin, ...)
FACE_OVAL = (10, 338, 297, 332, 284, 251, 389, 356, 454, 323, 361, 288, 397, 365, 379, 378, 400, 377,
             152, 148, 176, 149, 150, 136, 172, 58, 132, 93, 234, 127, 162, 21, 54, 103, 67, 109)


# outer lip contour and the lid margins: what projects inside them and lies behind them is the
# mouth cavity or the eye socket, not visible skin
LIP_OUTER = (61, 185, 40, 39, 37, 0, 267, 269, 270, 409, 291, 375, 321, 405, 314, 17, 84, 181, 91, 146)


EYE_RIGHT = (33, 246, 161, 160, 159, 158, 157, 173, 133, 155, 154, 153, 145, 144, 163, 7)


EYE_LEFT = (263, 466, 388, 387, 386, 385, 384, 398, 362, 382, 381, 380, 374, 373, 390, 249)


# landmarks on bone that barely move with expressions: rigid alignment of expressive scans
STABLE_LANDMARKS = (168, 6, 197, 195, 133, 362, 33, 263, 234, 454, 10, 151)

# the slits of a face (mouth, eyes) by MediaPipe indices: the two corners and the middle of the
# upper and lower margins, so a vertex can be told to be on the upper or lower lip or lid
SLITS = {
    "mouth": {"corners": (61, 291), "upper": (0, 37, 267, 39, 269), "lower": (17, 84, 314, 181, 405)},
    "eye_R": {"corners": (33, 133), "upper": (159, 158, 160, 157, 161), "lower": (145, 144, 153, 154, 163)},
    "eye_L": {"corners": (263, 362), "upper": (386, 385, 387, 384, 388), "lower": (374, 373, 380, 381, 390)},
}
# named MediaPipe points the face frame, the jaw and the regions use
NOSE_TIP = 4  # the pronasale
CHIN = 152  # menton, the lowest point of the chin on the face oval
EYE_OUTER_CORNERS = (33, 263)  # subject's right, left (exocanthion)
MOUTH_CORNERS = (61, 291)  # subject's right, left (cheilion)
INNER_LIPS = (13, 14)  # upper, lower inner lip at the centre
CHEEK_EXTREMES = (234, 454)  # the widest points of the face oval, in front of the ears
