"""Points picked in the viewer, checked by the same readers the commands use before they are saved.

Two kinds, each the JSON a command reads:

- ``landmarks``: points picked on the mesh, ``{"scheme": "custom", "points": [{"name": "nose_tip",
  "index": 4, "position": [x, y, z]}, ...]}`` in the model's own coordinates (its rest pose), as
  ``faceanim landmarks MESH --from JSON`` and ``--landmarks JSON`` read them
  (:meth:`faceanim.face.landmarks.Landmarks.from_dict`);
- ``photo``: points picked on photos, ``{"front": {"9.3": [x, y]}, "side": {...}}`` in pixels (x
  right, y down), as ``faceanim photo --points JSON`` reads them
  (:func:`faceanim.build.photo.apply_corrections`).
"""

from __future__ import annotations

import re
from functools import lru_cache

import numpy as np

from faceanim.errors import FaceAnimError, InputFileError

PHOTO_VIEWS = ("front", "side", "side2")


class PointsError(FaceAnimError):
    """Points the page sent that a command would refuse."""


@lru_cache(maxsize=1)
def point_names() -> dict:
    """The names the page offers: ``landmarks`` (name -> MediaPipe index: the named ones of the
    478 scheme), ``fdp`` (the MPEG-4 feature points a photo can correct), ``photo_extra``."""
    from faceanim.build.photo import EXTRA_POINTS
    from faceanim.standards.mpeg4 import fdp_spec
    from faceanim.face.landmarks import MEDIAPIPE_NAMES

    named = {n: i for i, n in MEDIAPIPE_NAMES.items() if not re.fullmatch(r"mp\d+", n)}
    return {"landmarks": named, "fdp": sorted(fdp_spec()["points"], key=_fdp_key),
            "photo_extra": list(EXTRA_POINTS)}


def _fdp_key(name: str):
    return tuple(int(x) if x.isdigit() else 0 for x in name.split("."))


def check_landmarks(data: object) -> dict:
    """Landmarks picked on the mesh, as ``landmarks --from`` reads them; the checked dict."""
    from faceanim.face.landmarks import Landmarks

    try:
        Landmarks.from_dict(data, "picked points")
    except FaceAnimError as exc:
        raise PointsError(str(exc)) from None
    return data


def check_photo_points(data: object, sizes: dict[str, tuple[int, int]]) -> dict:
    """Photo points as ``photo --points`` reads them: ``sizes`` gives each view's photo (width,
    height) in pixels; every view the points name must be one of them."""
    from faceanim.build.photo import PhotoView, apply_corrections

    if not isinstance(data, dict) or not data:
        raise PointsError('photo points must be an object like {"front": {"9.3": [x, y]}}')
    unknown = [k for k in data if k not in sizes]
    if unknown:
        raise PointsError(f"photo points name the view '{str(unknown[0])[:40]}', which has no photo here; "
                          f"views: {', '.join(sizes) or 'none'}")
    # the command's own check, on stand-in views of the photos' sizes (no pixels needed); a view
    # the points do not use stands in at 1 x 1 pixel so that "side2" stays the second side photo
    views = []
    for key in PHOTO_VIEWS:
        if key in sizes or (key == "side" and "side2" in sizes) or key == "front":
            w, h = sizes.get(key, (1, 1))
            views.append(PhotoView(key, np.empty((h, w, 0), np.uint8), "front" if key == "front" else "side"))
    try:
        apply_corrections(views, data, "picked points")
    except InputFileError as exc:
        raise PointsError(str(exc)) from None
    return data
