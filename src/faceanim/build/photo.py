"""A person's animatable full head from photos (Lee, Escher, Sannier & Magnenat-Thalmann 1999, s. 2).

The paper's cloning half, step by step:

1. **Feature points in each photo** (2.1): MediaPipe's 478 face-mesh landmarks on the front view
   and on any side view it can read (three-quarter views); a true profile, where landmark
   detectors fail, gives its midline points from the head's silhouette
   (:mod:`faceanim.build.profile`). Points a user corrects in a JSON file replace detected ones.
2. **Cameras and 3D points**: the paper assumes exactly orthogonal front and side photos. We
   solve each photo's own scaled orthographic camera (:class:`~faceanim.build.camera.ViewCamera`)
   and the 3D points together, alternating two linear least-squares steps (points given the
   cameras: a triangulation, with the generic head as a weak prior that fills what no photo sees,
   e.g. depth from a single front photo; cameras given the points: an affine fit projected onto
   a scaled rotation; a profile's yaw stays at 90 degrees). The front photo and a profile's
   silhouette points steer the 3D points; three-quarter views are measured to mislead depth (the
   face mesh's landmarks slide as the face turns, ``THREE_QUARTER_WEIGHT``) and give their
   camera, their texture and a check that the views agree (and show one person's face:
   :mod:`faceanim.build.identity`). The MPEG-4 feature points (FDPs) are
   read off the 3D landmarks.
3. **Head modification** (2.1.2): the generic head (:mod:`faceanim.face.generic_head`) is moved
   by a global affine fit and then warped onto the 3D points by **Dirichlet free-form
   deformation** (Sibson coordinates, with the paper's 27 extra points around the head) or, as the
   alternative, the thin-plate spline of the RBF core. Eyeballs and teeth move as rigid bodies
   (rotation, translation, uniform scale) fitted to where the warp takes them: scaled, not warped.
   By default the head is the person's identity fitted to the photos (landmarks, silhouettes and
   shading: :func:`fit_identity`, :mod:`faceanim.build.shading`) and only placed on the points by a
   similarity (the warp bent it onto the landmarks' noise and undid the identity: docs/photos.md);
   ``fast`` leaves the shading out and warps as above (``method`` matters only then).
4. **Expression off**: a photo that smiles or opens its mouth would give a head whose rest pose
   smiles. The generic head's own blendshapes (jaw open, smile, lip raise/lower, stretch, pucker,
   funnel) are fitted to the photo's mouth first; the texture is taken on the head *with* that
   expression (lips sample lips, not teeth), and the head is returned *without* it.
5. **Seamless texture** (2.2): :mod:`faceanim.build.texture` (views resampled into one atlas
   through the fitted head, split where the photos' obliqueness crosses (the paper's feature
   lines run through brow, ear and jaw), mirrored for an unseen side, blended with a Laplacian
   pyramid).
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from faceanim.build.camera import ViewCamera
from faceanim.errors import FaceAnimError, InputFileError, LandmarkError, shown
from faceanim.face.frame import similarity

# the face mesh's 468 surface points (468..477 are the irises, which sit on the eyeballs)
SURFACE_LANDMARKS = np.arange(468)
OUTER_EYE_CORNERS = (33, 263)
# texture atlas pixels per side: a 2048 atlas from 4000 px photos needs about 1.5 GB (4096: 5 GB)
MAX_TEXTURE_SIZE = 2048
# characters of a path shown in a message (the end: the file name is what tells photos apart)
PATH_SHOWN = 80
# photos: the largest side we read (a phone photo is ~4000 px; detection works on far less)
MAX_PHOTO_SIDE = 8192
MAX_PHOTO_PIXELS = 40_000_000
# a front photo turned more than this (degrees of yaw) is not a front view (multiview-photos:
# front.jpg 0.1, the three-quarter views 24-35; FaceWarehouse's photos within 9)
MAX_FRONT_YAW = 20.0
# the median reprojection error of a side view (inter-ocular distances) beyond which the views cannot
# show one head. Measured (front + three-quarter views): one man's own views 0.024; another
# person's front with his views 0.027-0.054 (FaceWarehouse, the astronaut, four video frames), so
# this refuses clearly different faces (8 of those 14 pairs) and never one person's views; faces of
# similar shape cannot be told apart by geometry alone: faceanim.build.identity compares the faces
DISAGREEMENT = 0.033
# a side photo must turn the head at least this far from the front one (degrees of yaw)
MIN_SIDE_TURN = 15.0
# the generic-head prior's weight against one view's pixels (per point, relative units)
PRIOR_WEIGHT = 0.02
# the face mesh's landmarks slide over the face as it turns: in a three-quarter view they sit
# 0.03-0.09 inter-ocular distances from where the front view puts the same point (FaceWarehouse
# renders with known cameras), and triangulating them made depth worse than the generic head's
# (0.045 against 0.032 IOD at any weight tried: 0.1, 0.25, 1): so they steer no 3D point
THREE_QUARTER_WEIGHT = 0.0
# where a landmark faces away from a camera it is occluded in that view: cos(angle) below this
VISIBLE_COS = 0.15
# the generic head's blendshapes that a photo's expression is fitted with (then taken off)
EXPRESSION_SHAPES = ("jawOpen", "mouthSmile_L", "mouthSmile_R", "mouthUpperUp_L", "mouthUpperUp_R",
                     "mouthLowerDown_L", "mouthLowerDown_R", "mouthStretch_L", "mouthStretch_R",
                     "mouthFunnel", "mouthPucker", "mouthClose")
# landmarks the expression is fitted on: lips, mouth corners, chin
MOUTH_LANDMARKS = (0, 13, 14, 17, 37, 39, 40, 61, 78, 80, 81, 82, 84, 87, 88, 91, 95, 146, 178, 181, 185,
                   191, 267, 269, 270, 291, 308, 310, 311, 312, 314, 317, 318, 321, 324, 375, 402, 405,
                   409, 415, 152, 148, 377, 176, 400)
EXTRA_POINTS = ("head_top", "head_back")
# a landmark that an expression shape moves less than this (metres) places the head for the fit
STILL = 2e-4


@dataclass
class PhotoView:
    """One photo and the 2D points found in it (pixels, x right, y down).

    ``points``: MediaPipe landmark index -> (2,) pixel; ``extra``: named points with no landmark
    (``head_top``, ``head_back`` on a profile); ``role``: "front" or "side"; ``profile``: True
    when the points came from the silhouette (a true profile).
    """

    name: str
    image: np.ndarray
    role: str
    points: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)
    profile: bool = False
    facing: int = 0
    mediapipe: np.ndarray | None = None  # (478, 3) MediaPipe's own 3D estimate, pixels
    # (N, 2) pixels: a profile's silhouette edge, head top to neck; a front view's closed head outline
    # (profile.head_outline), found by fit_identity when it needs it
    outline: np.ndarray | None = None

    @property
    def size(self) -> tuple[int, int]:
        return int(self.image.shape[1]), int(self.image.shape[0])


# ---------------------------------------------------------------------------------------- reading
def _named(path) -> str:
    """A photo's path as a message shows it: printable, its end kept (the file name)."""
    return shown(path, PATH_SHOWN, tail=True)


def read_photo(path: str | os.PathLike, what: str = "photo") -> np.ndarray:
    """An RGB photo as (H, W, 3) uint8, turned upright by its EXIF orientation (8- and 16-bit,
    grey, palette, RGBA, CMYK)."""
    import warnings

    from PIL import Image, ImageOps, UnidentifiedImageError

    from faceanim.io.files import check_input_file

    p = check_input_file(path, what, "an image file (JPEG or PNG)")
    name = _named(p)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # Pillow's decompression-bomb warning: checked below
            im = Image.open(p)  # reads the header only
        with im:
            w, h = im.size
            if max(w, h) > MAX_PHOTO_SIDE:
                raise InputFileError(f"{what} '{name}' is {w}x{h} pixels; give at most {MAX_PHOTO_SIDE} pixels a "
                                     "side (scale it down first)")
            if w * h > MAX_PHOTO_PIXELS:
                raise InputFileError(f"{what} '{name}' has {w * h / 1e6:.0f} million pixels; give at most "
                                     f"{MAX_PHOTO_PIXELS / 1e6:.0f} million (scale it down first)")
            if min(w, h) < 32:
                raise InputFileError(f"{what} '{name}' is {w}x{h} pixels; a face needs at least 32 a side")
            im.load()
            im = ImageOps.exif_transpose(im)
            if im.mode in ("I", "I;16", "I;16B", "I;16L", "F"):  # 16-bit or float grey: scale to 8 bits
                a = np.asarray(im, dtype=np.float64)
                top = 65535.0 if im.mode != "F" and a.max() > 255 else max(float(a.max()), 1.0)
                a = np.clip(a / top * 255.0, 0, 255).astype(np.uint8)
                im = Image.fromarray(a, "L")
            rgb = np.asarray(im.convert("RGB"), dtype=np.uint8).copy()
    except InputFileError:
        raise
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError, Image.DecompressionBombError):
        raise InputFileError(f"{what} '{name}' is not a readable image (corrupt or not JPEG/PNG); "
                             "give a JPEG or PNG photo") from None
    return rgb


# ---------------------------------------------------------------------------------------- detection
def detect_view(image: np.ndarray, name: str, role: str) -> PhotoView:
    """Find the feature points of one photo: face-mesh landmarks, or for a side photo turned too
    far for them (a true profile, :func:`faceanim.build.profile.is_profile`) the midline points of
    the head's silhouette."""
    from faceanim.face.landmarks import detect_landmarks_in_image

    h, w = image.shape[:2]
    if role == "side":
        from faceanim.build.profile import is_profile, profile_points

        if is_profile(image):
            try:
                prof = profile_points(image)
            except LandmarkError as exc:
                raise LandmarkError(f"side photo '{_named(name)}': {exc}") from None
            return PhotoView(name, image, role, {int(k): np.asarray(v, float) for k, v in prof.points.items()},
                             {k: np.asarray(v, float) for k, v in prof.extra.items()}, True, prof.facing,
                             outline=np.asarray(prof.curve, dtype=np.float64))
    try:
        lm = detect_landmarks_in_image(image, scales=(1.0,))
    except LandmarkError:
        raise LandmarkError(f"no face found in the {role} photo '{_named(name)}'; give a photo where the face is "
                            "lit, sharp and fills a good part of the frame") from None
    pix = np.c_[lm[:, 0] * w, lm[:, 1] * h]
    mp3 = np.c_[lm[:, 0] * w, lm[:, 1] * h, lm[:, 2] * w]
    return PhotoView(name, image, role, {i: pix[i] for i in range(478)}, {}, False, 0, mp3)


# ---------------------------------------------------------------------------------------- corrections
def apply_corrections(views: list[PhotoView], spec: object, source: str = "points file") -> None:
    """Replace detected 2D points by a user's: ``{"front": {"9.3": [x, y], ...}, "side": {...}}``.

    Keys name the views ("front", "side", "side2" for a second side photo); points are named by
    MPEG-4 FDP ("9.3", the nose tip), by MediaPipe landmark ("mp:4") or as ``head_top`` /
    ``head_back``; values are pixels (x right, y down).
    """
    from faceanim.standards.mpeg4 import fdp_spec

    fdps = fdp_spec()["points"]
    if not isinstance(spec, dict):
        raise InputFileError(f"{source} must hold an object like {{\"front\": {{\"9.3\": [x, y]}}}}")
    by_key = {"front": [v for v in views if v.role == "front"]}
    sides = [v for v in views if v.role == "side"]
    for k, v in enumerate(sides):
        by_key["side" if k == 0 else f"side{k + 1}"] = [v]
    for key, points in spec.items():
        if key not in by_key or not by_key[key]:
            raise InputFileError(f"{source}: unknown view '{shown(key)}'; use "
                                 + ", ".join(k for k in by_key if by_key[k]))
        view = by_key[key][0]
        if not isinstance(points, dict):
            raise InputFileError(f"{source}: '{shown(key)}' must map point names to [x, y] pixels")
        w, h = view.size
        for name, xy in points.items():
            ok = isinstance(xy, (list, tuple)) and len(xy) == 2 and all(
                isinstance(c, (int, float)) and not isinstance(c, bool) and np.isfinite(c) for c in xy)
            if not ok or not (0 <= xy[0] <= w and 0 <= xy[1] <= h):
                raise InputFileError(f"{source}: point '{shown(name)}' of '{shown(key)}' must be [x, y] pixels "
                                     f"inside the {w}x{h} photo")
            p = np.array(xy, dtype=np.float64)
            if name in EXTRA_POINTS:
                view.extra[name] = p
            elif name in fdps:
                for i in fdps[name]:
                    view.points[int(i)] = p
            elif isinstance(name, str) and re.fullmatch(r"mp:[0-9]{1,3}", name) and int(name[3:]) < 478:
                view.points[int(name[3:])] = p
            else:
                raise InputFileError(f"{source}: unknown point '{shown(name)}'; name MPEG-4 feature points "
                                     "(e.g. 9.3, 2.1, 8.4), MediaPipe landmarks as mp:N (0..477), "
                                     "head_top or head_back")


# ---------------------------------------------------------------------------------------- geometry
def fit_camera(points3d: np.ndarray, pixels: np.ndarray, size, weights=None) -> ViewCamera:
    """The scaled orthographic camera that best maps ``points3d`` onto ``pixels``."""
    w = np.ones(len(pixels)) if weights is None else weights
    x = np.c_[points3d, np.ones(len(points3d))]
    sw = np.sqrt(w)[:, None]
    m, *_ = np.linalg.lstsq(x * sw, pixels * sw, rcond=None)  # (4, 2): affine camera
    a = (m[:3].T) * np.array([[1.0], [-1.0]])  # s * R[:2]
    u, sv, vt = np.linalg.svd(a, full_matrices=False)
    r2 = u @ vt
    s = float(sv.mean())
    rot = np.vstack([r2, np.cross(r2[0], r2[1])])
    proj = s * (points3d @ rot.T)[:, :2] * np.array([1.0, -1.0])
    offset = ((pixels - proj) * w[:, None]).sum(0) / w.sum()
    return ViewCamera(rot, s, offset, tuple(size))


def initial_camera(view: PhotoView, generic_lm: np.ndarray) -> ViewCamera:
    """A first camera: from MediaPipe's own 3D landmarks (a rotation by Procrustes), or for a
    profile from its facing direction."""
    if view.mediapipe is not None:
        mp = view.mediapipe * np.array([1.0, -1.0, -1.0])  # x right, y up, z towards the camera
        s, r, _ = similarity(generic_lm[SURFACE_LANDMARKS], mp[SURFACE_LANDMARKS])
        cam = ViewCamera(r, s, np.zeros(2), view.size)
        idx = np.array(sorted(view.points))
        pix = np.stack([view.points[i] for i in idx])
        off = (pix - cam.project(generic_lm[idx])).mean(0)
        return ViewCamera(r, s, off, view.size)
    idx = np.array(sorted(view.points))
    return fit_profile_camera(generic_lm[idx], np.stack([view.points[i] for i in idx]), view.facing, view.size)


def profile_rotation(facing: int) -> np.ndarray:
    """The camera of a true profile: yaw +90 (the subject's left towards the camera, the nose to
    the image's left, ``facing`` -1) or -90."""
    yaw = np.radians(90.0 if facing < 0 else -90.0)
    d = np.array([np.sin(yaw), 0.0, np.cos(yaw)])  # head -> camera
    right = np.cross([0.0, 1.0, 0.0], d)
    return np.vstack([right, np.cross(d, right), d])


def fit_profile_camera(points3d: np.ndarray, pixels: np.ndarray, facing: int, size) -> ViewCamera:
    """A profile's camera from midline points: the yaw is fixed at +-90 degrees (points on the
    midline plane cannot tell a yaw from a scale), the head's pitch (an in-plane turn of the
    picture), the scale and the offset are fitted (a 2D similarity, Umeyama)."""
    r0 = profile_rotation(facing)
    q = (points3d @ r0.T)[:, :2]  # camera coordinates, y up
    s, rot2, t = similarity(q, pixels * np.array([1.0, -1.0]))
    rz = np.eye(3)
    rz[:2, :2] = rot2
    return ViewCamera(rz @ r0, s, t * np.array([1.0, -1.0]), tuple(size))


@dataclass
class Reconstruction:
    """Cameras and 3D points from photos, in the generic head's frame and size.

    ``points``: (478 + extras, 3) 3D positions (rows 478.. the ``extra`` names in order);
    ``observed``: per view, (n,) row indices seen in it (a profile's points that disagree with the
    front view left out, :func:`profile_outliers`); ``errors``: per view, (n,) reprojection errors
    in inter-ocular distances; ``refused``: per view, True for a profile that steers nothing (most
    of its points disagree with the front view: its camera is fitted on the points that agree).
    """

    points: np.ndarray
    cameras: list[ViewCamera]
    observed: list[np.ndarray]
    errors: list[np.ndarray]
    iod: float
    refused: list[bool] = field(default_factory=list)  # per view: a profile whose points disagree with the front's


def _observations(view: PhotoView, extra_rows: dict) -> tuple[np.ndarray, np.ndarray]:
    rows = [i for i in sorted(view.points) if i < 468]
    pix = [view.points[i] for i in rows]
    for name, p in sorted(view.extra.items()):
        if name in extra_rows:
            rows.append(extra_rows[name])
            pix.append(p)
    return np.array(rows, dtype=np.int64), np.array(pix, dtype=np.float64).reshape(-1, 2)


# a profile's midline point further than this (inter-ocular distances) from where the front view
# alone puts it is a misdetection, and a profile with more than PROFILE_REFUSED of its landmarks so
# far off steers nothing. Measured on profile renders of ICT identities (seeds 1000-1009): a good
# detection's points lie at most 0.19 from the front-only head (the lips of a person whose mouth is
# far from the generic head's depth), a chin found on the neck (seed 1008) 0.52-0.97
PROFILE_OUTLIER = 0.3
PROFILE_REFUSED = 0.5


def profile_outliers(view: PhotoView, rows: np.ndarray, pix: np.ndarray, front: Reconstruction,
                     iterations: int = 3) -> np.ndarray:
    """(n,) bool: which of a profile's observations (``rows``, ``pix``) disagree with the front view.

    The profile's camera is fitted to the 3D points rebuilt from the front photo alone (depth from
    the generic head), again without the points more than three median residuals off; a landmark
    further than ``PROFILE_OUTLIER`` from its front-view position is out. The head top and back (no
    front landmark) are never out."""
    keep = np.ones(len(rows), bool)
    lm = rows < 478
    res = np.zeros(len(rows))
    for _ in range(iterations):
        if keep.sum() < 3:
            break
        cam = fit_profile_camera(front.points[rows[keep]], pix[keep], view.facing, view.size)
        res = np.linalg.norm(cam.project(front.points[rows]) - pix, axis=1) / (cam.scale * front.iod)
        keep = ~lm | (res <= max(3.0 * float(np.median(res[lm])), 0.05))
    return lm & (res > PROFILE_OUTLIER)


def reconstruct(views: list[PhotoView], prior: np.ndarray, normals: np.ndarray, iterations: int = 20) -> Reconstruction:
    """Solve each photo's camera and the 3D points together (see the module docstring).

    ``prior``: (P, 3) the generic head's points (478 landmarks + extras); ``normals``: their
    surface normals (a landmark facing away from a camera is occluded there and not used). A
    profile's points are first checked against the front view (:func:`profile_outliers`).
    """
    n = len(prior)
    extra_rows = {name: 478 + k for k, name in enumerate(EXTRA_POINTS)}
    obs = [_observations(v, extra_rows) for v in views]
    refused = [False] * len(views)
    if views[0].role == "front" and any(v.profile for v in views[1:]):
        front = reconstruct(views[:1], prior, normals, iterations)
        for k, v in enumerate(views):
            if not v.profile:
                continue
            rows, pix = obs[k]
            out = profile_outliers(v, rows, pix, front)
            refused[k] = bool(out.sum() > PROFILE_REFUSED * (rows < 478).sum())
            obs[k] = (rows[~out], pix[~out])
    cams = [initial_camera(v, prior) for v in views]
    # a three-quarter view sees only one side: drop the landmarks facing away from its camera
    keep = []
    for v, cam, (rows, _) in zip(views, cams, obs):
        if v.role == "side" and not v.profile:
            keep.append(normals[rows] @ cam.direction > VISIBLE_COS)
        else:
            keep.append(np.ones(len(rows), bool))
    obs = [(rows[k], pix[k]) for (rows, pix), k in zip(obs, keep)]
    x = prior.copy()
    for _ in range(iterations):
        # the prior: the generic points under the similarity that fits x
        s, r, t = similarity(prior, x)
        base = s * prior @ r.T + t
        # points given the cameras: per point, sum_k |P_k X + o_k - x_k|^2 + lam |X - base|^2
        lam = PRIOR_WEIGHT * np.mean([c.scale for c in cams]) ** 2
        a = np.repeat(lam * np.eye(3)[None], n, axis=0)
        b = lam * base.copy()
        for v, cam, (rows, pix), off in zip(views, cams, obs, refused):
            m = cam.matrix  # (2, 3)
            wv = THREE_QUARTER_WEIGHT if (v.role == "side" and not v.profile) or off else 1.0
            a[rows] += wv * (m.T @ m)
            b[rows] += wv * ((pix - cam.offset) @ m)
        x = np.linalg.solve(a, b[..., None])[..., 0]
        # gauge: back into the generic head's frame and size
        s, r, t = similarity(x[SURFACE_LANDMARKS], prior[SURFACE_LANDMARKS])
        x = s * x @ r.T + t
        # cameras given the points (a profile's points lie on the midline: its yaw stays +-90)
        cams = [fit_profile_camera(x[rows], pix, v.facing, v.size) if v.profile else fit_camera(x[rows], pix, v.size)
                for v, (rows, pix) in zip(views, obs)]
    iod = float(np.linalg.norm(x[OUTER_EYE_CORNERS[0]] - x[OUTER_EYE_CORNERS[1]]))
    errors = [np.linalg.norm(cam.project(x[rows]) - pix, axis=1) / (cam.scale * iod)
              for cam, (rows, pix) in zip(cams, obs)]
    return Reconstruction(x, cams, [rows for rows, _ in obs], errors, iod, refused)


def check_views(views: list[PhotoView], rec: Reconstruction) -> None:
    """Refuse a front photo that is not frontal, a side photo that is, and views that cannot show
    one head (the median of a side view's reprojection errors beyond ``DISAGREEMENT``)."""
    front = rec.cameras[0]
    if abs(front.yaw_degrees) > MAX_FRONT_YAW:
        raise LandmarkError(
            f"the front photo '{_named(views[0].name)}' shows the head turned {abs(front.yaw_degrees):.0f} degrees; "
            "give a frontal photo as --front (side and three-quarter views go to --side)")
    turns = [cam.yaw_degrees - front.yaw_degrees for cam in rec.cameras[1:]]
    if len(turns) == 2 and np.sign(turns[0]) == np.sign(turns[1]):
        raise LandmarkError(
            f"both side photos ('{_named(views[1].name)}', '{_named(views[2].name)}') show the same side of the "
            "head; give one view of each side (or one side photo)")
    for v, cam, err in zip(views[1:], rec.cameras[1:], rec.errors[1:]):
        turn = abs(cam.yaw_degrees - front.yaw_degrees)
        if turn < MIN_SIDE_TURN:
            raise LandmarkError(
                f"the side photo '{_named(v.name)}' shows the head from the front (turned {turn:.0f} degrees from the "
                f"front photo, at least {MIN_SIDE_TURN:.0f} needed); give a profile or three-quarter view")
        med = float(np.median(err)) if len(err) else 0.0
        if med > DISAGREEMENT:
            raise LandmarkError(
                f"the photos do not agree: '{_named(v.name)}' is {med:.3f} inter-ocular distances off the head "
                f"rebuilt from all views (at most {DISAGREEMENT}); give photos of one person with one expression, "
                "or fix a bad point with --points")


# ---------------------------------------------------------------------------------------- the head
def extra_vertices(head) -> dict[str, int]:
    """Generic-head vertices of the named points a profile shows that are not landmarks."""
    v = head.mesh.vertices
    skin = head.parts["skin"]
    lm = head.landmarks()
    mid = skin[np.abs(v[skin, 0]) < 0.01]
    top = int(mid[np.argmax(v[mid, 1])])
    eye_y = lm[list(OUTER_EYE_CORNERS), 1].mean()
    band = mid[np.abs(v[mid, 1] - eye_y) < 0.02]
    back = int(band[np.argmin(v[band, 2])])
    return {"head_top": top, "head_back": back}


@lru_cache(maxsize=2)
def prior_points(head) -> tuple[np.ndarray, np.ndarray]:
    """The generic head's points (478 landmarks + extras) and their unit surface normals (computed
    once per head; read-only)."""
    from faceanim.face.mesh import vertex_normals

    nv = vertex_normals(head.mesh.vertices, head.mesh.faces)
    ex = extra_vertices(head)
    lm = head.landmarks()
    corners = nv[head.mesh.faces[head.landmark_triangles]]
    nl = np.einsum("lk,lkd->ld", head.landmark_barycentric, corners)
    pts = np.vstack([lm, head.mesh.vertices[[ex[n] for n in EXTRA_POINTS]]])
    nrm = np.vstack([nl, nv[[ex[n] for n in EXTRA_POINTS]]])
    nrm = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    pts.setflags(write=False)
    nrm.setflags(write=False)
    return pts, nrm


def fit_affine(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(3, 4) least-squares affine map ``dst ~ A[:, :3] @ src + A[:, 3]``."""
    x = np.c_[src, np.ones(len(src))]
    m, *_ = np.linalg.lstsq(x, dst, rcond=None)
    return m.T


def apply_affine(a: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ a[:, :3].T + a[:, 3]


def fit_expression(head, target: np.ndarray, names=EXPRESSION_SHAPES, ridge: float = 1e-3) -> dict[str, float]:
    """Weights in [0, 1] of the generic head's expression blendshapes that best explain the mouth
    of ``target`` (478 landmarks in the head's frame), after a global affine fit."""
    from scipy.optimize import lsq_linear

    lmat = head.landmark_matrix()
    g = head.landmarks()
    moved = np.stack([np.linalg.norm((lmat @ head.shape(n))[:468], axis=1) for n in names]).max(0)
    still = np.flatnonzero(moved < STILL)  # the landmarks no expression shape moves: the head's pose
    a = fit_affine(g[still], target[still])
    rows = np.array(MOUTH_LANDMARKS)
    cols = np.stack([((lmat @ head.shape(n))[rows] @ a[:, :3].T).ravel() for n in names], axis=1)
    resid = (target[rows] - apply_affine(a, g[rows])).ravel()
    scale = np.linalg.norm(cols, axis=0).mean()
    lhs = np.vstack([cols, np.sqrt(ridge) * scale * np.eye(len(names))])
    rhs = np.r_[resid, np.zeros(len(names))]
    w = lsq_linear(lhs, rhs, bounds=(0.0, 1.0)).x
    return {n: float(v) for n, v in zip(names, w)}


# ---------------------------------------------------------------------------------------- identity
# the dense identity fit (fit_identity): each term's residuals in the generic head's inter-ocular
# distances, divided by these sigmas; the weights' prior N(0, 1)
IDENTITY_LANDMARK_SIGMA = 0.01  # a detected landmark in a front view
IDENTITY_SILHOUETTE_SIGMA = 0.01  # a point of a profile's silhouette edge
IDENTITY_ITERATIONS = 8
# a vertex is on the head's outline in a view where its normal is this close to perpendicular to
# the view (|cos|); a silhouette point further than SILHOUETTE_REACH (IOD) from every such vertex
# is not matched
RIM_COS = 0.3
SILHOUETTE_REACH = 0.1


@lru_cache(maxsize=2)
def identity_model(head) -> tuple[np.ndarray, np.ndarray]:
    """The identity modes at every vertex (K, V, 3) and at the reconstruction's points (K, 480, 3)
    (478 landmarks + extras), float64, computed once per head (read-only)."""
    basis = head.identity_basis().astype(np.float64)
    lmat = head.landmark_matrix()
    ex = extra_vertices(head)
    at_points = np.stack([np.vstack([lmat @ b, b[[ex[n] for n in EXTRA_POINTS]]]) for b in basis])
    basis.setflags(write=False)
    at_points.setflags(write=False)
    return basis, at_points


def _view_targets(view: PhotoView) -> tuple[np.ndarray, np.ndarray]:
    return _observations(view, {name: 478 + k for k, name in enumerate(EXTRA_POINTS)})


def _refit_camera(view: PhotoView, points: np.ndarray, rows: np.ndarray, pix: np.ndarray) -> ViewCamera:
    if view.profile:
        return fit_profile_camera(points[rows], pix, view.facing, view.size)
    return fit_camera(points[rows], pix, view.size)


def _silhouette_rows(view: PhotoView, cam: ViewCamera, neutral: np.ndarray, vertices: np.ndarray,
                     normals: np.ndarray, skin: np.ndarray, basis: np.ndarray, unit: float, span: tuple[int, int]):
    """Linear rows of a profile's silhouette term: for each point ``c`` of the photo's silhouette
    edge (between rows ``span`` of the outline), the head's nearest outline vertex ``v`` (its
    normal perpendicular to the view) and ``n . (P v(w) + o - c)`` with ``n`` the edge's normal."""
    from scipy.spatial import cKDTree

    curve = view.outline[span[0]:span[1] + 1]
    tangent = np.gradient(curve, axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    nrm = np.c_[-tangent[:, 1], tangent[:, 0]]
    rim = skin[np.abs(normals[skin] @ cam.direction) < RIM_COS]
    rim = rim[cam.depth(vertices[rim]) > cam.depth(vertices[skin]).mean()]  # the near side of the head
    proj = cam.project(vertices[rim])
    dist, k = cKDTree(proj).query(curve)
    ok = dist < SILHOUETTE_REACH * unit
    curve, nrm, idx = curve[ok], nrm[ok], rim[k[ok]]
    m = cam.matrix
    # d/dw of n . (M v(w)): n^T M B_k[v]
    a = np.einsum("nj,ji,kni->nk", nrm, m, basis[:, idx])
    b = np.einsum("nj,nj->n", nrm, curve - cam.offset - neutral[idx] @ m.T)
    return a / unit, b / unit


# the front view's outline term: the silhouette between the eyes' height and a little below the
# menton (cheeks, jaw, the neck's sides; the skull above is hair in a photo), points matched to an
# ear left out; a head vertex makes the outline where its projected normal is within
# OUTLINE_COS of the silhouette's
IDENTITY_OUTLINE_SIGMA = 0.01
OUTLINE_BELOW_CHIN = 0.3  # IOD below the menton
OUTLINE_COS = 0.7


@lru_cache(maxsize=2)
def ear_vertices(head) -> np.ndarray:
    """Skin vertices of the generic head's ears: lateral of the face's widest points (landmarks
    234, 454) by 0.05 IOD, behind them, between the subnasale's height less 0.15 IOD and the eyes'
    height plus 0.2 IOD (a front silhouette there is the ear's, which says little of the face)."""
    v = head.mesh.vertices
    skin = head.parts["skin"]
    lm = head.landmarks()
    iod = float(np.linalg.norm(lm[OUTER_EYE_CORNERS[0]] - lm[OUTER_EYE_CORNERS[1]]))
    wide = np.abs(lm[[234, 454], 0]).mean() + 0.05 * iod
    lo, hi = lm[2, 1] - 0.15 * iod, lm[list(OUTER_EYE_CORNERS), 1].mean() + 0.2 * iod
    sel = (np.abs(v[skin, 0]) > wide) & (v[skin, 1] > lo) & (v[skin, 1] < hi) & (v[skin, 2] < lm[[234, 454], 2].mean())
    out = skin[sel]
    out.setflags(write=False)
    return out


def _outline_rows(view: PhotoView, cam: ViewCamera, neutral: np.ndarray, vertices: np.ndarray,
                  normals: np.ndarray, skin: np.ndarray, ears: np.ndarray, basis: np.ndarray, unit: float):
    """Linear rows of the front view's outline term: for each point ``c`` of the photo's head
    outline between the eyes' height and ``OUTLINE_BELOW_CHIN`` below the menton, the nearest
    head vertex ``v`` on the outline (normal perpendicular to the view, its projection facing the
    same way as the silhouette's normal ``n``), and ``n . (P v(w) + o - c)``."""
    from scipy.spatial import cKDTree

    c = view.outline
    tangent = np.roll(c, -1, axis=0) - np.roll(c, 1, axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    nrm = np.c_[-tangent[:, 1], tangent[:, 0]]  # outward (head_outline runs counter-clockwise)
    eye_y = np.mean([view.points[i][1] for i in OUTER_EYE_CORNERS])
    low = view.points[152][1] + OUTLINE_BELOW_CHIN * unit
    band = (c[:, 1] > eye_y) & (c[:, 1] < low)
    c, nrm = c[band], nrm[band]
    m = cam.matrix
    rim = skin[np.abs(normals[skin] @ cam.direction) < RIM_COS]
    n2 = normals[rim] @ m.T
    n2 /= np.maximum(np.linalg.norm(n2, axis=1, keepdims=True), 1e-12)
    proj = cam.project(vertices[rim])
    tree = cKDTree(proj)
    near = tree.query_ball_point(c, SILHOUETTE_REACH * unit)
    idx, keep = np.zeros(len(c), np.int64), np.zeros(len(c), bool)
    for i, cand in enumerate(near):
        if not cand:
            continue
        cand = np.asarray(cand)
        cand = cand[n2[cand] @ nrm[i] > OUTLINE_COS]
        if not len(cand):
            continue
        j = cand[np.argmin(np.linalg.norm(proj[cand] - c[i], axis=1))]
        idx[i], keep[i] = rim[j], True
    keep &= ~np.isin(idx, ears)
    c, nrm, idx = c[keep], nrm[keep], idx[keep]
    a = np.einsum("nj,ji,kni->nk", nrm, m, basis[:, idx])
    b = np.einsum("nj,nj->n", nrm, c - cam.offset - neutral[idx] @ m.T)
    return a / unit, b / unit


def _identity_targets(views, rec) -> tuple[list, list[bool], list]:
    """What an identity fit steers by, per view: the (rows, pixels) of the landmarks the
    reconstruction kept (a profile's misdetections left out); whether the view's landmarks steer
    at all (a three-quarter view's slide over the face as it turns, as they steer no 3D point in
    reconstruct; nor does a refused profile); and a profile's silhouette span between its highest
    and lowest midline point kept (forehead 10 to menton 152), None for other views."""
    targets = []
    for v, kept in zip(views, rec.observed):
        rows, pix = _view_targets(v)
        ok = np.isin(rows, kept)
        targets.append((rows[ok], pix[ok]))
    refused = rec.refused or [False] * len(views)
    use = [(v.role == "front" or v.profile) and not off for v, off in zip(views, refused)]
    spans = []
    for v, (rows, _) in zip(views, targets):
        if v.outline is None or not v.profile:
            spans.append(None)
            continue
        ends = [int(np.argmin(np.linalg.norm(v.outline - v.points[int(i)], axis=1))) for i in rows if i < 478]
        spans.append((min(ends), max(ends)) if len(ends) >= 2 else None)
    return targets, use, spans


def fit_identity(head, views: list[PhotoView], rec: Reconstruction, iterations: int = IDENTITY_ITERATIONS,
                 prior: float = 100.0, outline: float = 4.0) -> np.ndarray:
    """The identity weights (K,) of the person the photos show, fitted to the photos themselves.

    Each view's camera (from :func:`reconstruct`) sees the morphable head ``v(w) = neutral + B w``;
    the weights minimise, over the views, the 2D distance from each detected landmark to where
    the camera projects the head's own (``IDENTITY_LANDMARK_SIGMA``), plus on a true profile the
    distance along the silhouette's normal from the silhouette edge to the head's outline there
    (``IDENTITY_SILHOUETTE_SIGMA``), plus, weighted by ``outline``, the same along the front view's
    head outline from the eyes down past the chin (:func:`_outline_rows`, ``IDENTITY_OUTLINE_SIGMA``),
    plus ``prior |w|^2``. Correspondences (which vertex makes the
    outline) are found again on each iteration and the cameras are refitted to the new head's
    points; within an iteration the problem is linear least squares. ``prior`` 100 was the best of
    1, 10, 100 on ICT identities sampled with seeds 1000-1009 (tuning set: own/other median 0.71,
    0.66, 0.62; the landmark-only identity of :func:`fit_head` 0.81); with the profile guard of
    :func:`reconstruct` 0.67 (seed 1008's chin found on the neck no longer makes a head so wrong
    that everybody else's looks close), ``outline`` 0.25, 1, 4, 16: 0.66, 0.63, 0.62, 0.65. :func:`head_from_photos`
    starts its warp from this identity (held out, FaceWarehouse 1 and ICT seeds 300-303: own/other
    median 0.65 against 0.66 from the reconstructed 3D landmarks, a lower own error for all five);
    the goal, 0.5, is not reached: a detected landmark on a render sits 0.015 IOD from the head's own
    even for the true weights, so landmarks say little about the identity (docs/photos.md)."""
    from faceanim.face.mesh import vertex_normals

    basis, at_points = identity_model(head)
    k = basis.shape[0]
    p0, _ = prior_points(head)
    skin = head.parts["skin"]
    iod0 = float(np.linalg.norm(p0[OUTER_EYE_CORNERS[0]] - p0[OUTER_EYE_CORNERS[1]]))
    targets, use, spans = _identity_targets(views, rec)
    cams = list(rec.cameras)
    if outline > 0 and views[0].role == "front" and views[0].outline is None:
        from faceanim.build.profile import head_outline

        try:
            views[0].outline = head_outline(views[0].image)
        except LandmarkError:  # no silhouette found around the head: the outline steers nothing
            outline = 0.0
    ears = ear_vertices(head)
    w = np.zeros(k)
    for _ in range(iterations):
        verts = head.identity(w)
        pts = p0 + np.tensordot(w, at_points, axes=1)
        nv = vertex_normals(verts, head.mesh.faces)
        a_rows, b_rows = [], []
        for v, cam, (rows, pix), used, span in zip(views, cams, targets, use, spans):
            if not used:
                continue
            m = cam.matrix
            unit = cam.scale * iod0
            a = np.einsum("ji,kri->rjk", m, at_points[:, rows]).reshape(-1, k)
            b = (pix - cam.offset - p0[rows] @ m.T).reshape(-1)
            a_rows.append(a / (unit * IDENTITY_LANDMARK_SIGMA))
            b_rows.append(b / (unit * IDENTITY_LANDMARK_SIGMA))
            if span is not None:
                sa, sb = _silhouette_rows(v, cam, head.mesh.vertices, verts, nv, skin, basis, unit, span)
                a_rows.append(sa / IDENTITY_SILHOUETTE_SIGMA)
                b_rows.append(sb / IDENTITY_SILHOUETTE_SIGMA)
            if outline > 0 and v.role == "front" and v.outline is not None:
                oa, ob = _outline_rows(v, cam, head.mesh.vertices, verts, nv, skin, ears, basis, unit)
                a_rows.append(np.sqrt(outline) * oa / IDENTITY_OUTLINE_SIGMA)
                b_rows.append(np.sqrt(outline) * ob / IDENTITY_OUTLINE_SIGMA)
        a = np.vstack(a_rows + [np.sqrt(prior) * np.eye(k)])
        b = np.concatenate(b_rows + [np.zeros(k)])
        w = np.linalg.lstsq(a, b, rcond=None)[0]
        pts = p0 + np.tensordot(w, at_points, axes=1)
        cams = [_refit_camera(v, pts, rows, pix) for v, (rows, pix) in zip(views, targets)]
    return w


@dataclass
class FittedHead:
    """The generic head fitted to a person: ``vertices`` (neutral, rigid parts placed),
    ``expressed`` (with the photo's expression: what the photos show, for the texture),
    ``expression`` the weights taken off, ``affine`` the global part of the fit."""

    vertices: np.ndarray
    expressed: np.ndarray
    expression: dict
    affine: np.ndarray


RIGID_PARTS = {"eyeball_L": ("eyeball_L",), "eyeball_R": ("eyeball_R",), "mouth": ("teeth", "gums_tongue")}


# the nose ridge and the eyes' inner corners, which the FDPs leave out (the paper regrets "too few
# points on nose ... no parameter on the central line between the eyes")
EXTRA_CONTROLS = (168, 6, 197, 195, 5, 1, 9, 151, 133, 362)
# FDPs on the inner lip lines coincide in a closed mouth but not in an open one: as controls they
# would tear the lips apart, so the lips are steered by their outer line (8.x) and the expression
INNER_LIP_FDPS = ("2.2", "2.3", "2.4", "2.5", "2.6", "2.7", "2.8", "2.9", "3.5", "3.6")


def control_landmarks() -> np.ndarray:
    """The landmarks that steer the generic head: the MPEG-4 feature points (FDPs) a photo shows,
    the face outline and the nose ridge, sorted."""
    from faceanim.standards.mpeg4 import fdp_spec
    from faceanim.face.landmarks import FACE_OVAL

    fdps = fdp_spec()["points"]
    rows = {int(i) for name, ids in fdps.items() if name not in INNER_LIP_FDPS for i in ids}
    rows |= set(FACE_OVAL) | set(EXTRA_CONTROLS)
    return np.array(sorted(rows), dtype=np.int64)


def control_rows() -> np.ndarray:
    """Rows of the reconstruction that steer the head: :func:`control_landmarks` and the extras."""
    return np.r_[control_landmarks(), 478 + np.arange(len(EXTRA_POINTS))]


@lru_cache(maxsize=2)
def head_deformer(head) -> tuple:
    """The generic head bound once for Dirichlet FFD: (the :class:`~faceanim.deform.base.LinearDeformer`
    from the control points of :func:`control_rows` and the 27 points around the head to every
    vertex, the number of control points). Cached per head (the binding takes about a second)."""
    from faceanim.deform.ffd import dirichlet_ffd, enclosing_points

    prior, _ = prior_points(head)
    sites = prior[control_rows()]
    v = head.mesh.vertices
    box = enclosing_points(np.vstack([v, sites]))
    return dirichlet_ffd(np.vstack([sites, box]), v), len(sites)


def gentle_residual(resid: np.ndarray, size: float) -> np.ndarray:
    """The warp's control-point residuals (N, 3) with a deadband of ``size``: each shortened by
    ``size`` (soft thresholding), so a point within ``size`` of its target does not move the head
    and one further off moves it by the excess only (``size`` inf: no warp)."""
    if not size > 0:
        return resid
    n = np.linalg.norm(resid, axis=1, keepdims=True)
    return resid * np.clip(1.0 - size / np.maximum(n, 1e-300), 0.0, 1.0)


def fit_head(head, rec: Reconstruction, method: str = "dffd", keep_expression: bool = False,
             identity: bool = True, deadband: float = 0.0, affine: bool = True) -> FittedHead:
    """Deform the generic head onto the reconstructed points (see the module docstring, 3-4).

    ``identity``: start from the person's own head shape, the morphable head's identity fitted to
    the reconstructed landmarks (:func:`~faceanim.face.registration.fit_landmarks`, prior N(0, 1)),
    so the shape between the feature points (nose, cheeks, jaw, forehead, the skull) is a real
    person's of that build, not the generic head's; the warp then only takes up what is left. An
    array: these identity weights (e.g. :func:`fit_identity`'s, as :func:`head_from_photos` does).

    ``deadband`` (inter-ocular distances): the warp takes up only what of each control point's
    residual exceeds it (:func:`gentle_residual`; the detector's own noise is about 0.015), so an
    identity fitted from the photos is not bent onto the landmarks' noise; inf: no warp.
    ``affine`` False: the global fit is a similarity (the identity keeps its proportions)."""
    g = head.mesh.vertices
    x = rec.points
    if isinstance(identity, np.ndarray):
        g = head.identity(identity)
    elif identity:
        from faceanim.face.registration import fit_landmarks

        weights = fit_landmarks(x[:478], head)[3][:head.n_identity]
        g = head.identity(weights)
    expr = {} if keep_expression else fit_expression(head, x[:478])
    delta = sum((w * head.shape(n) for n, w in expr.items() if w > 0), np.zeros_like(g))
    ge = g + delta
    ex = extra_vertices(head)
    rows = control_rows()
    sites_e = np.vstack([head.landmarks(ge), ge[[ex[n] for n in EXTRA_POINTS]]])[rows]
    if affine:
        a = fit_affine(head.landmarks(ge)[SURFACE_LANDMARKS], x[SURFACE_LANDMARKS])
    else:
        s_, r_, t_ = similarity(head.landmarks(ge)[SURFACE_LANDMARKS], x[SURFACE_LANDMARKS])
        a = np.c_[s_ * r_, t_]
    resid = gentle_residual(x[rows] - apply_affine(a, sites_e), deadband * rec.iod)
    if method == "dffd":
        deformer, n_sites = head_deformer(head)
        offsets = np.zeros((deformer.n_handles, 3))
        offsets[:n_sites] = resid
        warp = deformer.displacements(offsets)
    elif method == "rbf":
        from faceanim.deform.rbf import landmark_tps

        sites = np.vstack([head.landmarks(g), g[[ex[n] for n in EXTRA_POINTS]]])[rows]
        tps = landmark_tps(sites, sites + resid, "head control points", merge_repeated=True)
        warp = tps(g) - g
    else:
        raise FaceAnimError(f"unknown head fitting method '{shown(method)}'; choose dffd or rbf")
    neutral = apply_affine(a, g) + warp
    expressed = apply_affine(a, ge) + warp
    g0 = head.mesh.vertices
    for idx, near in rigid_groups(head):
        # each rigid part follows the skin around it (eyelids and socket; lips and mouth socket):
        # the generic head's part (rigid: the identity modes also reshape it) placed where the
        # person's is, then moved with its socket
        s0, r0, t0 = similarity(g0[idx], g[idx])
        part = s0 * g0[idx] @ r0.T + t0
        s, r, t = similarity(g[near], neutral[near])
        neutral[idx] = s * part @ r.T + t
        s, r, t = similarity(ge[near], expressed[near])
        expressed[idx] = s * (part + (ge[idx] - g[idx])) @ r.T + t
    return FittedHead(neutral, expressed, expr, a)


# skin within this distance (metres) of a rigid part is the part's socket: the part follows it
SOCKET_REACH = 0.006


@lru_cache(maxsize=2)
def rigid_groups(head) -> list[tuple[np.ndarray, np.ndarray]]:
    """(part vertices, the skin vertices around them) for the eyeballs and the teeth with gums
    (found once per head)."""
    from scipy.spatial import cKDTree

    v = head.mesh.vertices
    skin = head.parts["skin"]
    out = []
    for group in RIGID_PARTS.values():
        idx = np.concatenate([head.parts[p] for p in group])
        d, _ = cKDTree(v[idx]).query(v[skin], distance_upper_bound=SOCKET_REACH)
        out.append((idx, skin[np.isfinite(d)]))
    return out


def bake_cameras(head, views: list[PhotoView], rec: Reconstruction, fitted: FittedHead) -> list[ViewCamera]:
    """Each photo's camera for the texture: refitted to the photo's points (those the
    reconstruction kept) on the head as fitted, with the photo's expression (a head the warp does
    not put exactly on the 3D points is still seen where the photo shows it)."""
    ex = extra_vertices(head)
    pts = np.vstack([head.landmarks(fitted.expressed), fitted.expressed[[ex[n] for n in EXTRA_POINTS]]])
    cams = []
    for v, kept in zip(views, rec.observed):
        rows, pix = _view_targets(v)
        ok = np.isin(rows, kept)
        cams.append(_refit_camera(v, pts, rows[ok], pix[ok]))
    return cams


# ---------------------------------------------------------------------------------------- pipeline
@dataclass
class PhotoHead:
    """A person's head from photos: ``mesh`` (the generic head's topology, textured), its 478
    ``landmarks``, the ``parts`` (vertex indices), and how it was made (``views``,
    ``reconstruction``, ``fitted``, ``timings`` in seconds)."""

    mesh: object
    landmarks: np.ndarray
    parts: dict
    views: list
    reconstruction: Reconstruction
    fitted: FittedHead
    timings: dict
    cameras: list = field(default_factory=list)  # each photo's camera the texture was taken with

    def face(self):
        """The head as a :class:`~faceanim.face.face.Face` (its landmarks are known: no detection)."""
        from faceanim.face.face import Face

        return Face(self.mesh, self.landmarks)

    def feature_points(self) -> dict[str, np.ndarray]:
        """The 3D MPEG-4 feature points (FDPs) of the head, name -> (3,)."""
        return dict(self.face().feature_points.positions)


def load_views(front, sides=()) -> list[PhotoView]:
    """Read and detect the photos (paths or (name, image) pairs): the front first."""
    views = []
    for role, item in [("front", front)] + [("side", s) for s in sides]:
        if isinstance(item, tuple):
            name, image = item
        else:
            name, image = str(item), read_photo(item, f"{role} photo")
        views.append(detect_view(image, name, role))
    return views


# the warp's deadband (inter-ocular distances) after the shading fit: a control point this close
# to its target does not move the head (see fit_head). On ICT seeds 1000-1009 (tuning), own/other
# median: full warp 0.75, deadband 0.01 0.63, 0.02 0.52, 0.03 0.48, no warp 0.43 (affine) and 0.39
# (similarity); the texture's landmarks lie nearer the truth's in the renders without the warp too
# (front 0.0146 -> 0.0107 IOD, profile 0.035 -> 0.025): the warp followed the detector's noise.
# So no warp: the head is placed by a similarity and each photo's camera refitted to it
SHADED_DEADBAND = np.inf


def head_from_photos(front, sides=(), points=None, method: str = "dffd", keep_expression: bool = False,
                     texture_size: int = 1024, blend: str = "pyramid", progress=None, fast: bool = False,
                     deadband: float | None = None) -> PhotoHead:
    """The whole pipeline: photos -> a textured, animatable full head (module docstring, 1-5).

    ``front``/``sides``: image paths or ``(name, (H, W, 3) uint8)`` pairs; ``points``: corrections
    (:func:`apply_corrections`, a dict or a JSON path); ``method``: ``dffd`` or ``rbf``;
    ``progress``: an optional callable taking the name of each of the four stages as it starts;
    ``fast``: leave out the shading fit (:mod:`faceanim.build.shading`, about 20 s) and warp the
    landmark identity fully onto the 3D points, as before it; ``deadband``: the warp's after the
    shading fit (inter-ocular distances; default ``SHADED_DEADBAND``, inf: no warp).
    """
    step = progress or (lambda name: None)
    import time

    from faceanim.build.texture import BakeView, atlas_uv, bake_texture
    from faceanim.face.generic_head import generic_head
    from faceanim.face.mesh import Mesh
    from faceanim.io.files import read_json
    from faceanim.limits import check_range

    if method not in ("dffd", "rbf"):
        raise FaceAnimError(f"unknown head fitting method '{shown(method)}'; choose dffd or rbf")
    if len(sides) > 2:
        raise FaceAnimError(f"give at most two side photos (left and right), got {len(sides)}")
    texture_size = int(check_range(texture_size, "--texture-size", 64, MAX_TEXTURE_SIZE, integer=True))
    timings = {}
    t0 = time.perf_counter()
    step("feature points in the photos")
    head = generic_head()
    prior, normals = prior_points(head)
    views = load_views(front, sides)
    if points is not None:
        spec = read_json(points, "points file") if isinstance(points, (str, os.PathLike)) else points
        apply_corrections(views, spec, "points file")
    timings["feature points"] = time.perf_counter() - t0
    t = time.perf_counter()
    step("cameras and 3D points")
    rec = reconstruct(views, prior, normals)
    check_views(views, rec)
    if len(views) > 1:
        from faceanim.build.identity import check_one_person

        check_one_person(views, [c.yaw_degrees - rec.cameras[0].yaw_degrees for c in rec.cameras[1:]], _named)
    timings["cameras and 3D points"] = time.perf_counter() - t
    t = time.perf_counter()
    step("fitting the head")
    # the person's identity from the photos themselves (landmarks, a profile's silhouette, the
    # front outline), then the warp onto the 3D points
    weights = fit_identity(head, views, rec)
    if fast:
        fitted = fit_head(head, rec, method, keep_expression, identity=weights)
        cameras = rec.cameras
    else:
        from faceanim.build.shading import fit_identity_shading

        # the shading of the photos refines the identity; the head is placed on the 3D points by a
        # similarity, not bent onto them (the warp followed the landmarks' noise and undid the
        # identity; SHADED_DEADBAND), and each photo's camera is refitted to the head so that the
        # texture meets the photo's features
        weights = fit_identity_shading(head, views, rec, weights).weights
        fitted = fit_head(head, rec, method, keep_expression, identity=weights,
                          deadband=SHADED_DEADBAND if deadband is None else float(deadband), affine=False)
        cameras = bake_cameras(head, views, rec, fitted)
    timings[f"head modification ({method})"] = time.perf_counter() - t
    t = time.perf_counter()
    step("the texture")
    faces = head.mesh.faces
    uv, face_uv = atlas_uv(fitted.vertices, faces, head.parts)
    textured = [BakeView(v.image, c) for v, c in zip(views, cameras)]
    texture = bake_texture(fitted.expressed, faces, uv, face_uv, head.parts, textured, size=texture_size, blend=blend)
    timings["texture"] = time.perf_counter() - t
    name = Path(views[0].name).stem if views[0].name else "head"
    mesh = Mesh(fitted.vertices, faces, uv, face_uv, texture, head.mesh.polygon_sizes, name=name,
                source=f"photos:{views[0].name}")
    timings["total"] = time.perf_counter() - t0
    return PhotoHead(mesh, head.landmarks(fitted.vertices), head.parts, views, rec, fitted, timings, list(cameras))
