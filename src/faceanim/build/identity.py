"""Do the photos show one person? A face-recognition descriptor of each view, compared.

``faceanim photo`` rebuilds one head from a front photo and side photos; a side photo of somebody
else gives a head that is nobody (the geometric check of :func:`faceanim.build.photo.check_views`
catches a side view only when the two faces differ in shape enough for the rebuilt head to
disagree with a view, 8 of 14 such pairs). Here each photo's face is described by dlib's face
recognition network (a ResNet trained on about three million faces; ``face_recognition_models``
ships its weights): 128 numbers whose Euclidean distance is below :data:`SAME_PERSON` for one
person's faces. The face is found by MediaPipe's landmarks (they hold on turned faces), aligned
by dlib's 5-point shape predictor inside their box, and described once (no jitter: the same photo
gives the same numbers).

A side photo whose descriptor is farther than :data:`SAME_PERSON` from the front photo's is
refused. Views turned too far for the network (a true profile, or a yaw beyond
:data:`MAX_TURN`) are not judged by it; the geometric check still is.
``scripts/eval_photo_identity.py`` measures both checks on real photos and video frames.
"""

from __future__ import annotations

import os
from functools import lru_cache

import numpy as np

from faceanim.errors import LandmarkError

# dlib's documented decision threshold for this network: two descriptors closer than 0.6 are one
# person (99.38% on Labeled Faces in the Wild). Not tuned on our data; measured there
# (scripts/eval_photo_identity.py, 54 front/side pairs of 9 people): one person's pairs 0.17-0.54,
# two people's 0.60-0.97 (47 of 48 refused; geometry alone refuses 35).
SAME_PERSON = 0.6
# beyond this turn from the front photo (degrees of yaw) a descriptor is not compared: the network
# was trained on faces seen from the front to about three-quarters
MAX_TURN = 50.0


@lru_cache(maxsize=1)
def _models():
    """dlib's 5-point shape predictor and face recognition network (loaded once: about 0.5 s)."""
    from faceanim.extras import require

    dlib = require("dlib", "checking that the photos show one person")
    models = require("face_recognition_models", "checking that the photos show one person")
    folder = os.path.join(os.path.dirname(models.__file__), "models")
    predictor = dlib.shape_predictor(os.path.join(folder, "shape_predictor_5_face_landmarks.dat"))
    network = dlib.face_recognition_model_v1(os.path.join(folder, "dlib_face_recognition_resnet_model_v1.dat"))
    return dlib, predictor, network


def face_descriptor(image: np.ndarray, points: np.ndarray) -> np.ndarray:
    """The (128,) descriptor of the face whose landmarks (N, 2 pixels) are ``points`` in
    ``image`` ((H, W, 3) uint8 RGB)."""
    dlib, predictor, network = _models()
    image = np.ascontiguousarray(image[..., :3], dtype=np.uint8)
    # the landmarks' box: about the box of dlib's own detector, which the shape predictor was trained
    # on (the test compares the two descriptors)
    (x0, y0), (x1, y1) = points.min(axis=0), points.max(axis=0)
    box = dlib.rectangle(int(round(x0)), int(round(y0)), int(round(x1)), int(round(y1)))
    shape = predictor(image, box)
    return np.asarray(network.compute_face_descriptor(image, shape, 1), dtype=np.float64)


def view_descriptor(view) -> np.ndarray | None:
    """A :class:`~faceanim.build.photo.PhotoView`'s descriptor, or None for a profile (its points
    come from the silhouette: no face for the network)."""
    if view.profile:
        return None
    rows = [i for i in sorted(view.points) if i < 468]
    if len(rows) < 100:
        return None
    return face_descriptor(view.image, np.array([view.points[i] for i in rows], dtype=np.float64))


def check_one_person(views, turns, named) -> list[float | None]:
    """Refuse a side view whose face is not the front view's person. ``turns``: each side view's
    yaw from the front one (degrees); ``named``: a path as shown in messages. Returns each side
    view's descriptor distance from the front's (None where not judged)."""
    front = view_descriptor(views[0])
    out = []
    for v, turn in zip(views[1:], turns):
        d = None
        if front is not None and abs(turn) <= MAX_TURN:
            side = view_descriptor(v)
            if side is not None:
                d = float(np.linalg.norm(side - front))
        if d is not None and d > SAME_PERSON:
            raise LandmarkError(
                f"the side photo '{named(v.name)}' shows somebody other than the front photo '{named(views[0].name)}' "
                f"(face descriptor distance {d:.2f}; one person's photos are under {SAME_PERSON}); give photos of "
                "one person")
        out.append(d)
    return out
