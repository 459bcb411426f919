"""The one place faceanim configures and runs Google's MediaPipe (``mediapipe==0.10.21``, whose
wheel carries its models): the face mesh (478 landmarks with the irises) on still images or a
video, face detection and selfie segmentation (profile photos).

MediaPipe is imported with its native logs quiet (TensorFlow Lite and glog print to the process's
stderr), and a missing install becomes one :class:`~faceanim.errors.LandmarkError` naming what
needed it. Every runner is a context manager; results are numpy arrays in pixels.
"""

from __future__ import annotations

import contextlib
import os

import numpy as np

from faceanim.errors import LandmarkError
from faceanim.io.files import native_stderr_quiet


def mediapipe(what: str = "landmark detection"):
    """The ``mediapipe`` module (its logs quiet); :class:`LandmarkError` naming ``what`` if missing."""
    os.environ.setdefault("GLOG_minloglevel", "2")
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
    try:
        import mediapipe as mp
    except ImportError:
        raise LandmarkError(f"{what} needs mediapipe==0.10.21 (pip install mediapipe==0.10.21)") from None
    return mp


class FaceMesh:
    """MediaPipe's face mesh: ``mesh(rgb)`` -> (478, 3) landmarks in pixels (x right, y down, z
    away from the camera scaled by the image width), or None where no face is found.

    ``video=False`` detects in every image on its own (still images: renders, photos); ``True``
    tracks from frame to frame (a clip or a camera: detection runs again only when the face is
    lost). ``confidence``: MediaPipe's minimum detection (and tracking) confidence."""

    def __init__(self, video: bool = False, confidence: float | None = None, what: str = "landmark detection"):
        mp = mediapipe(what)
        confidence = (0.5 if video else 0.3) if confidence is None else float(confidence)
        with native_stderr_quiet():
            self._fm = mp.solutions.face_mesh.FaceMesh(
                static_image_mode=not video, max_num_faces=1, refine_landmarks=True,
                min_detection_confidence=confidence, min_tracking_confidence=confidence)

    def __call__(self, rgb: np.ndarray) -> np.ndarray | None:
        img = np.ascontiguousarray(rgb)
        h, w = img.shape[:2]
        with native_stderr_quiet():  # its first run logs TensorFlow Lite's delegate and absl warnings
            result = self._fm.process(img)
        if not result.multi_face_landmarks:
            return None
        return np.array([[p.x * w, p.y * h, p.z * w] for p in result.multi_face_landmarks[0].landmark])

    def close(self) -> None:
        self._fm.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


@contextlib.contextmanager
def face_detector(model: int, confidence: float = 0.3, what: str = "face detection"):
    """MediaPipe's face detection (``model`` 0: short range, 1: full range): yields a callable
    ``rgb`` -> its detections (MediaPipe's objects, best first) or []."""
    mp = mediapipe(what)
    with native_stderr_quiet(), mp.solutions.face_detection.FaceDetection(
            model_selection=model, min_detection_confidence=confidence) as fd:
        def detect(rgb):  # quiet: the whole block runs in native_stderr_quiet
            found = fd.process(np.ascontiguousarray(rgb)).detections or []
            return sorted(found, key=lambda d: -d.score[0])
        yield detect


@contextlib.contextmanager
def selfie_segmenter(model: int, what: str = "person segmentation"):
    """MediaPipe's selfie segmentation (``model`` 0: general, 1: landscape): yields a callable
    ``rgb`` -> (H, W) float mask of the person."""
    mp = mediapipe(what)
    with native_stderr_quiet(), mp.solutions.selfie_segmentation.SelfieSegmentation(model_selection=model) as seg:
        yield lambda rgb: seg.process(np.ascontiguousarray(rgb)).segmentation_mask
