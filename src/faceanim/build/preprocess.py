"""Scan preprocessing (Erdogdu 2010, section 5.4) and the average face model it normalises to.

1. *Grid resampling*: crop the face (inside the landmark face oval, or a radius around the nose
   tip for raw scans), keep the front-most skin (no background, no back of the head, no mouth
   cavity, eyeballs or teeth), and resample it as a depth map ``z(x, y)`` on a regular ``n x n``
   grid in the face's frontal frame by scattered-data interpolation over the valid data points
   (``scipy.interpolate.griddata``, linear, as MATLAB's ``griddata``): holes inside the face are
   bridged, grid points outside the crop are dropped. The result is a quad mesh
   with (u, v) grid texture coordinates, plus the scan's own texture coordinates carried over
   where the scan has them, so its texture still maps.
2. *Landmarks* carry over to the nearest grid vertex.
3. *Pose and size normalisation*: the nose tip moves to the origin and the affine transform
   ``T = A B^-1`` (eqs. 5.1-5.4) maps the outer eye corners and the chin middle onto those of a
   reference face (the average face model) while keeping the nose tip at the origin.

The average face model (AFM, thesis 5.3 after Salah et al.): the landmark sets of several neutral
faces are brought to a consensus shape (each face translated to its nose tip, rotated to its
frontal frame and scaled to unit inter-ocular distance, then averaged), each face is morphed
onto the consensus by a landmark thin-plate spline, resampled on one regular x-y grid, and the
depths are averaged where the faces have data.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import griddata

from faceanim.deform.rbf import landmark_tps
from faceanim.errors import LandmarkError, MeshError
from faceanim.face.frame import face_frame
from faceanim.face.landmarks import BASIC22, FACE_OVAL
from faceanim.face.mesh import Mesh
from faceanim.limits import MAX_GRID

DEFAULT_GRID = 150
# the four landmarks of the normalisation (MediaPipe indices): nose tip, outer eye corners
# (subject's right, left) and chin middle
NOSE_TIP, EYE_OUTER_R, EYE_OUTER_L, CHIN = 4, 33, 263, 152
# landmarks that drive the morph of each face onto the consensus: the basic 22 and the oval
_MORPH = sorted(({i for _, i in BASIC22} - {13, 14}) | set(FACE_OVAL[::3]))  # inner lips coincide on closed mouths


@dataclass
class GridFace:
    """A face resampled on a regular grid: the mesh (grid vertices that have data, row-major),
    its landmarks (478, carried to the nearest grid vertex) and the grid index of each vertex."""

    mesh: Mesh
    landmarks: np.ndarray  # (478, 3)
    landmark_vertices: np.ndarray  # (478,) grid vertex of each landmark
    grid_index: np.ndarray  # (V, 2) row, column of each vertex
    shape: tuple[int, int]


def _grid_faces(valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two triangles per grid cell whose four corners are valid; vertex numbering over valid cells."""
    number = np.full(valid.shape, -1, dtype=np.int64)
    number[valid] = np.arange(valid.sum())
    a, b = number[:-1, :-1], number[:-1, 1:]
    c, d = number[1:, 1:], number[1:, :-1]
    ok = (a >= 0) & (b >= 0) & (c >= 0) & (d >= 0)
    # rows run top to bottom, columns left to right: (a, d, c) and (a, c, b) face the viewer
    tris = np.concatenate([np.stack([a[ok], d[ok], c[ok]], 1), np.stack([a[ok], c[ok], b[ok]], 1)])
    return number, tris


def resample_to_grid(mesh: Mesh, lm478: np.ndarray, n: int = DEFAULT_GRID, crop: str = "oval",
                     radius: float = 1.6) -> GridFace:
    """Resample the face of ``mesh`` on an ``n x n`` grid in its frontal frame (thesis 5.4).

    ``crop='oval'`` keeps what lies inside the landmark face oval (seen from the front);
    ``crop='radius'`` keeps what lies within ``radius`` inter-ocular distances of the nose tip
    (for raw scans whose jaw line or forehead the oval would cut).
    """
    if n < 8:
        raise MeshError(f"the grid needs at least 8 x 8 vertices, got {n}")
    lm = np.asarray(lm478, dtype=np.float64)
    frame = face_frame(lm)
    local = frame.to_local(mesh.vertices)
    from matplotlib.path import Path as PolyPath

    if crop == "oval":
        oval = frame.to_local(lm[list(FACE_OVAL)])
        keep = PolyPath(oval[:, :2]).contains_points(local[:, :2])
        keep &= local[:, 2] > oval[:, 2].min() - 0.2 * frame.iod
    elif crop == "radius":
        keep = np.linalg.norm(local, axis=1) < radius * frame.iod
    else:
        raise MeshError(f"crop must be 'oval' or 'radius', got '{crop}'")
    # only the front-most surface at each place: the back of the head or the inside of the mouth
    # must not mix into the depth map
    from faceanim.face.regions import depth_behind_front, skin

    keep &= depth_behind_front(mesh, frame, cell=0.02) < 0.06 * frame.iod
    keep &= skin(mesh, lm)  # eyeballs, teeth and eyelashes modelled as separate shells stay out
    pts = local[keep]
    if len(pts) < 16:
        raise MeshError(f"'{mesh.name}' has only {len(pts)} vertices in the face region; is this a face "
                        "and are the landmarks for this mesh?")
    lo, hi = pts[:, :2].min(0), pts[:, :2].max(0)
    xs = np.linspace(lo[0], hi[0], n)
    ys = np.linspace(hi[1], lo[1], n)  # rows top to bottom
    gx, gy = np.meshgrid(xs, ys)
    # linear interpolation over the valid data points (MATLAB griddata in the thesis): holes inside
    # the face (open eyes or mouth of a scan) are bridged, the background outside the crop is not
    gz = griddata(pts[:, :2], pts[:, 2], (gx, gy), method="linear")
    flat = np.stack([gx.ravel(), gy.ravel()], 1)
    if crop == "oval":
        inside = PolyPath(oval[:, :2]).contains_points(flat).reshape(gz.shape)
    else:
        inside = (np.linalg.norm(flat, axis=1) < radius * frame.iod).reshape(gz.shape)
    valid = np.isfinite(gz) & inside
    _, tris = _grid_faces(valid)
    if len(tris) == 0:
        raise MeshError(f"no grid cell of '{mesh.name}' has scan data; check the landmarks")
    grid_local = np.stack([gx[valid], gy[valid], gz[valid]], 1)
    vertices = frame.origin + grid_local @ frame.rotation
    rows, cols = np.nonzero(valid)
    uv = np.stack([cols / (n - 1), 1.0 - rows / (n - 1)], 1)
    texture = None
    if mesh.uv is not None and mesh.texture is not None:
        # carry the scan's own texture coordinates over, so its texture still maps
        pos, _, tri = mesh.closest_points(vertices)
        bary = mesh.barycentric(pos, tri)
        uv = np.einsum("nk,nkd->nd", bary, mesh.uv[mesh.face_uv[tri]])
        texture = mesh.texture
    out = Mesh(vertices, tris, uv=uv, face_uv=tris.copy(), texture=texture, name=f"{mesh.name}-grid{n}")
    _, nearest = out.kdtree.query(lm)
    return GridFace(out, out.vertices[nearest], nearest, np.stack([rows, cols], 1), (n, n))


def normalising_transform(lm478: np.ndarray, reference_lm478: np.ndarray) -> np.ndarray:
    """The 4x4 affine ``T`` of eqs. 5.1-5.4: nose tip to the origin, then the outer eye corners and
    the chin middle onto the reference's (whose nose tip is at its origin)."""
    lm = np.asarray(lm478, dtype=np.float64)
    ref = np.asarray(reference_lm478, dtype=np.float64)
    idx = [EYE_OUTER_R, EYE_OUTER_L, CHIN]
    b = lm[idx] - lm[NOSE_TIP]
    a = ref[idx] - ref[NOSE_TIP]

    def homogeneous(p):
        m = np.zeros((4, 4))
        m[:3, :3] = p.T
        m[3, :] = 1.0
        return m  # the 4th column is the origin (the nose tip)

    bm = homogeneous(b)
    if abs(np.linalg.det(bm)) < 1e-12 * max(np.abs(b).max(), 1e-300) ** 3:
        raise LandmarkError("the eye corners, chin and nose tip lie in one plane; the landmarks are degenerate")
    t = homogeneous(a) @ np.linalg.inv(bm)
    shift = np.eye(4)
    shift[:3, 3] = -lm[NOSE_TIP]
    return t @ shift


def apply_transform(t: np.ndarray, points: np.ndarray) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64)
    return p @ t[:3, :3].T + t[:3, 3]


def preprocess(mesh: Mesh, lm478: np.ndarray, reference: AverageFace | None = None, n: int = DEFAULT_GRID,
               crop: str = "oval") -> GridFace:
    """Thesis 5.4 end to end: grid resampling, landmark carry-over, normalisation to the AFM."""
    grid = resample_to_grid(mesh, lm478, n, crop)
    ref = reference or default_average_face()
    t = normalising_transform(grid.landmarks, ref.landmarks)
    grid.mesh = grid.mesh.with_vertices(apply_transform(t, grid.mesh.vertices))
    grid.landmarks = apply_transform(t, grid.landmarks)
    return grid


# ---------------------------------------------------------------------------- average face
@dataclass
class AverageFace:
    """Average face model: a depth map on a regular grid (NaN where no face has data) in a frame
    with the nose tip at the origin, unit inter-ocular distance, x to the subject's left, y up,
    z forward, and the consensus landmarks (478) in the same frame."""

    x: np.ndarray  # (n,)
    y: np.ndarray  # (n,) top to bottom
    depth: np.ndarray  # (n, n)
    landmarks: np.ndarray  # (478, 3)
    sources: tuple[str, ...] = ()

    def mesh(self) -> Mesh:
        valid = np.isfinite(self.depth)
        _, tris = _grid_faces(valid)
        gx, gy = np.meshgrid(self.x, self.y)
        v = np.stack([gx[valid], gy[valid], self.depth[valid]], 1)
        rows, cols = np.nonzero(valid)
        uv = np.stack([cols / (len(self.x) - 1), 1.0 - rows / (len(self.y) - 1)], 1)
        return Mesh(v, tris, uv=uv, face_uv=tris.copy(), name="average-face")

    def save(self, path) -> None:
        from faceanim.io.files import atomic_output, npz_bytes

        with atomic_output(path) as tmp, open(tmp, "wb") as fh:
            fh.write(npz_bytes(x=self.x.astype(np.float32), y=self.y.astype(np.float32),
                               depth=self.depth.astype(np.float32), landmarks=self.landmarks,
                               sources=np.array(self.sources)))

    @classmethod
    def load(cls, path) -> AverageFace:
        from pathlib import Path

        from faceanim.errors import InputFileError

        if not Path(path).is_file():
            raise InputFileError(f"average face model '{path}' does not exist; check the path")
        what = f"'{path}' is not an average face model written by faceanim"
        try:
            with np.load(path, allow_pickle=False) as d:
                if not hasattr(d, "files") or not {"x", "y", "depth", "landmarks"} <= set(d.files):
                    raise InputFileError(f"{what} (it needs the arrays x, y, depth and landmarks)")
                x, y, depth, lm = (np.asarray(d[k]) for k in ("x", "y", "depth", "landmarks"))
                sources = tuple(str(s) for s in np.atleast_1d(d["sources"])) if "sources" in d.files else ()
        except InputFileError:
            raise
        except Exception as exc:  # zip, npy and decompression errors of a damaged file
            raise InputFileError(f"{what} ({type(exc).__name__}: the file is damaged or of another kind)") from None
        for name, a in (("x", x), ("y", y), ("depth", depth), ("landmarks", lm)):
            if a.dtype.kind not in "fiu":
                raise InputFileError(f"{what} ({name} is not numeric)")
        n = x.shape[0] if x.ndim == 1 else 0
        if not (x.ndim == 1 and y.ndim == 1 and 2 <= n <= MAX_GRID and y.shape == (n,) and depth.shape == (n, n)):
            raise InputFileError(f"{what} (x and y must be 2..{MAX_GRID} grid positions and depth n x n)")
        if lm.shape != (478, 3) or not np.all(np.isfinite(lm)) or not np.all(np.isfinite(x)) \
                or not np.all(np.isfinite(y)) or np.isinf(depth).any():
            raise InputFileError(f"{what} (landmarks must be 478 finite points; x, y finite; depth finite or NaN)")
        try:
            face_frame(lm)  # the landmarks must be a face's (proportions, not mirrored)
        except LandmarkError as exc:
            raise InputFileError(f"{what} (its landmarks are not a face's: {exc})") from None
        return cls(x.astype(np.float64), y.astype(np.float64), depth.astype(np.float64), lm.astype(np.float64), sources)


def _normalised_landmarks(lm478: np.ndarray) -> np.ndarray:
    frame = face_frame(lm478)
    return frame.to_local(lm478) / frame.iod


def build_average_face(faces, n: int = DEFAULT_GRID) -> AverageFace:
    """Average face model from neutral faces: ``faces`` is a sequence of (name, mesh, lm478)."""

    faces = list(faces)
    if not faces:
        raise MeshError("the average face needs at least one face")
    consensus = np.mean([_normalised_landmarks(lm) for _, _, lm in faces], axis=0)
    # rectify: the consensus itself in its own frontal frame (nose tip at the origin, unit IOD)
    consensus = _normalised_landmarks(consensus)
    oval = consensus[list(FACE_OVAL)]
    lo, hi = oval[:, :2].min(0), oval[:, :2].max(0)
    xs = np.linspace(lo[0], hi[0], n)
    ys = np.linspace(hi[1], lo[1], n)
    gx, gy = np.meshgrid(xs, ys)
    total = np.zeros((n, n))
    count = np.zeros((n, n))
    for _, mesh, lm in faces:
        local = _normalised_landmarks(lm)
        frame = face_frame(lm)
        # the thesis' sparse landmark set: a dense one folds the morph where detection is noisy
        warp = landmark_tps(local[_MORPH], consensus[_MORPH], "landmarks")
        grid = resample_to_grid(mesh, lm, n)
        morphed = warp(frame.to_local(grid.mesh.vertices) / frame.iod)
        z = griddata(morphed[:, :2], morphed[:, 2], (gx, gy), method="linear")
        # a face that does not quite reach the consensus outline is extended by its border depth,
        # so every face counts everywhere and the average has no steps where coverage changes
        gap = ~np.isfinite(z)
        z[gap] = griddata(morphed[:, :2], morphed[:, 2], (gx[gap], gy[gap]), method="nearest")
        ok = np.isfinite(z)
        total[ok] += z[ok]
        count[ok] += 1
    from matplotlib.path import Path as PolyPath

    inside = PolyPath(oval[:, :2]).contains_points(np.stack([gx.ravel(), gy.ravel()], 1)).reshape(n, n)
    depth = np.where((count > 0) & inside, total / np.maximum(count, 1), np.nan)
    return AverageFace(xs, ys, depth, consensus, tuple(name for name, _, _ in faces))


def default_average_face() -> AverageFace:
    """faceanim's average face model (built by scripts/build_average_face.py)."""
    from importlib import resources

    with resources.as_file(resources.files("faceanim").joinpath("assets", "average_face.npz")) as p:
        return AverageFace.load(p)
