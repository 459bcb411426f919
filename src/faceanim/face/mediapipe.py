"""The one place faceanim configures and runs Google's MediaPipe, through its Tasks API
(``mediapipe>=0.10.30``: numpy 2, Python 3.11-3.13): the Face Landmarker (478 landmarks with the
irises, the facial transformation matrix and ARKit's 52 blendshape scores) on still images or a
video, the face detector and selfie segmentation (profile photos).

The models ship inside faceanim (``assets/mediapipe/``, Apache-2.0, notice
``LICENSE-MediaPipe.txt``): mediapipe's own wheels carry none from 0.10.30 on, and nothing is
downloaded at run time. Each file is checked against its SHA-256 once per process; a missing or
damaged one is one :class:`~faceanim.errors.LandmarkError` saying to reinstall faceanim.

MediaPipe is imported with its native logs quiet (LiteRT and glog print to the process's stderr),
and a missing install becomes one :class:`~faceanim.errors.LandmarkError` naming what needed it.
Every runner is a context manager (MediaPipe's finalisers fail at interpreter shutdown: close them
before); results are numpy arrays in pixels.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
import weakref
import zipfile
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from faceanim.errors import LandmarkError
from faceanim.io.files import native_stderr_quiet

INSTALL = "pip install 'mediapipe>=0.10.30'"
# the shipped models and their SHA-256 (assets/mediapipe/LICENSE-MediaPipe.txt says where each is from)
MODELS = {
    "face_landmarker.task": "64184e229b263107bc2b804c6625db1341ff2bb731874b0bcc2fe6544e0bc9ff",
    "face_detection_full_range_sparse.tflite": "2c3728e6da56f21e21a320433396fb06d40d9088f2247c05e5635a688d45dfe1",
    "selfie_segmentation.tflite": "9ee168ec7c8f2a16c56fe8e1cfbc514974cbbb7e434051b455635f1bd1462f5c",
    "selfie_segmentation_landscape.tflite": "a77d03f4659b9f6b6c1f5106947bf40e99d7655094b6527f214ea7d451106edd",
}
# ARKit's 52 blendshapes in the order MediaPipe's Face Landmarker scores them (after its "_neutral")
BLENDSHAPE_NAMES = (
    "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight", "cheekPuff",
    "cheekSquintLeft", "cheekSquintRight", "eyeBlinkLeft", "eyeBlinkRight", "eyeLookDownLeft",
    "eyeLookDownRight", "eyeLookInLeft", "eyeLookInRight", "eyeLookOutLeft", "eyeLookOutRight",
    "eyeLookUpLeft", "eyeLookUpRight", "eyeSquintLeft", "eyeSquintRight", "eyeWideLeft", "eyeWideRight",
    "jawForward", "jawLeft", "jawOpen", "jawRight", "mouthClose", "mouthDimpleLeft", "mouthDimpleRight",
    "mouthFrownLeft", "mouthFrownRight", "mouthFunnel", "mouthLeft", "mouthLowerDownLeft",
    "mouthLowerDownRight", "mouthPressLeft", "mouthPressRight", "mouthPucker", "mouthRight",
    "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper", "mouthSmileLeft",
    "mouthSmileRight", "mouthStretchLeft", "mouthStretchRight", "mouthUpperUpLeft", "mouthUpperUpRight",
    "noseSneerLeft", "noseSneerRight")
VIDEO_STEP_MS = 1000.0 / 30.0  # a video's frames are stamped this far apart unless given their times


def mediapipe(what: str = "landmark detection"):
    """The ``mediapipe`` module with its Tasks API (its logs quiet); :class:`LandmarkError`
    naming ``what`` if missing or too old."""
    os.environ.setdefault("GLOG_minloglevel", "2")
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
    try:
        with native_stderr_quiet():
            import mediapipe as mp
            from mediapipe.tasks.python import vision  # noqa: F401 (the Tasks API: 0.10.x and newer)
    except ImportError:
        raise LandmarkError(f"{what} needs MediaPipe's Tasks API ({INSTALL})") from None
    return mp


@lru_cache(maxsize=None)
def model_bytes(name: str) -> bytes:
    """The bytes of one shipped model (:data:`MODELS`), checked against its SHA-256."""
    from importlib import resources

    try:
        data = resources.files("faceanim").joinpath("assets", "mediapipe", name).read_bytes()
    except OSError:
        data = b""
    if hashlib.sha256(data).hexdigest() != MODELS[name]:
        raise LandmarkError(f"faceanim's MediaPipe model {name} is missing or damaged; reinstall faceanim "
                            "(pip install --force-reinstall faceanim, or bash scripts/setup.sh in a checkout)")
    return data


def _bundled(task: str, member: str) -> bytes:
    """One model out of a shipped ``.task`` bundle (a zip), e.g. the Face Landmarker's face detector."""
    with zipfile.ZipFile(io.BytesIO(model_bytes(task))) as z:
        return z.read(member)


def _image(mp, rgb: np.ndarray):
    img = np.ascontiguousarray(rgb)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        raise LandmarkError("MediaPipe takes (H, W, 3) uint8 RGB images")
    return mp.Image(image_format=mp.ImageFormat.SRGB, data=img)


def _close_quietly(runner) -> None:
    """Close a MediaPipe runner; at the interpreter's exit its dispatcher may already be shut down
    (RuntimeError): the process is ending, so the runner is only marked closed, and its own
    finaliser then has nothing left to do (before, it printed a traceback on stderr)."""
    with native_stderr_quiet():
        try:
            runner.close()
        except RuntimeError:
            runner._handle = None


@dataclass
class FaceResult:
    """One face found by the Face Landmarker: ``landmarks`` (478, 3) in pixels (x right, y down, z
    away from the camera scaled by the image width), ``blendshapes`` (51,) MediaPipe's ARKit
    scores in :data:`BLENDSHAPE_NAMES` order (all of ARKit's 52 but tongueOut), ``matrix`` (4, 4) its facial transformation (the
    canonical face model into camera space, centimetres)."""

    landmarks: np.ndarray
    blendshapes: np.ndarray
    matrix: np.ndarray


class FaceMesh:
    """MediaPipe's Face Landmarker: ``mesh(rgb)`` -> (478, 3) landmarks in pixels (x right, y
    down, z away from the camera scaled by the image width), or None where no face is found;
    :meth:`detect` gives the blendshape scores and the transformation matrix too.

    ``video=False`` detects in every image on its own (IMAGE mode: renders, photos); ``True``
    tracks from frame to frame (VIDEO mode: a clip or a camera; detection runs again only when
    the face is lost), each frame stamped with its ``time`` (seconds, increasing) or
    :data:`VIDEO_STEP_MS` after the last. ``confidence``: the minimum detection, presence and
    tracking confidence."""

    def __init__(self, video: bool = False, confidence: float | None = None, what: str = "landmark detection"):
        mp = mediapipe(what)
        from mediapipe.tasks.python import BaseOptions, vision

        confidence = (0.5 if video else 0.3) if confidence is None else float(confidence)
        mode = vision.RunningMode.VIDEO if video else vision.RunningMode.IMAGE
        options = vision.FaceLandmarkerOptions(
            base_options=BaseOptions(model_asset_buffer=model_bytes("face_landmarker.task")),
            running_mode=mode, num_faces=1, min_face_detection_confidence=confidence,
            min_face_presence_confidence=confidence, min_tracking_confidence=confidence,
            output_face_blendshapes=True, output_facial_transformation_matrixes=True)
        self._mp, self._video, self._last_ms, self._fl = mp, bool(video), -1, None
        with native_stderr_quiet():
            try:
                self._fl = vision.FaceLandmarker.create_from_options(options)
                # closed at the latest when the interpreter exits, before MediaPipe's modules go
                # (its own finaliser, run during teardown, fails with a traceback on stderr)
                self._finalizer = weakref.finalize(self, _close_quietly, self._fl)
            except (RuntimeError, ValueError):
                raise LandmarkError("MediaPipe could not load faceanim's face_landmarker.task; reinstall faceanim "
                                    f"and mediapipe ({INSTALL})") from None
            # one frame through the graph while its logs go nowhere: its calculators open (and log)
            # on worker threads after create returns, which a stop arriving then would let through
            blank = _image(mp, np.zeros((64, 64, 3), np.uint8))
            if self._video:
                self._fl.detect_for_video(blank, 0)
                self._last_ms = 0
            else:
                self._fl.detect(blank)

    def detect(self, rgb: np.ndarray, time: float | None = None) -> FaceResult | None:
        """The face in ``rgb`` (a video's next frame, at ``time`` seconds, in video mode) or None."""
        image = _image(self._mp, rgb)
        h, w = image.height, image.width
        with native_stderr_quiet():  # its first run logs LiteRT's delegate and absl warnings
            if self._video:
                ms = int(round(time * 1000.0)) if time is not None else int(round(self._last_ms + VIDEO_STEP_MS))
                ms = max(ms, self._last_ms + 1)  # MediaPipe wants strictly increasing stamps
                self._last_ms = ms
                result = self._fl.detect_for_video(image, ms)
            else:
                result = self._fl.detect(image)
        if not result.face_landmarks:
            return None
        lm = np.array([[p.x * w, p.y * h, p.z * w] for p in result.face_landmarks[0]], dtype=np.float64)
        scores = np.zeros(len(BLENDSHAPE_NAMES))
        if result.face_blendshapes:
            by_name = {c.category_name: c.score for c in result.face_blendshapes[0]}
            scores = np.array([by_name.get(n, 0.0) for n in BLENDSHAPE_NAMES], dtype=np.float64)
        matrix = (np.array(result.facial_transformation_matrixes[0], dtype=np.float64)
                  if result.facial_transformation_matrixes else np.eye(4))
        return FaceResult(lm, scores, matrix)

    def __call__(self, rgb: np.ndarray, time: float | None = None) -> np.ndarray | None:
        found = self.detect(rgb, time)
        return None if found is None else found.landmarks

    def close(self) -> None:
        if self._fl is not None:
            self._finalizer()
            self._fl = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


@dataclass
class Detection:
    """A face found by MediaPipe's face detector: ``score``, ``keypoints`` (6, 2) in pixels (the
    subject's right eye, left eye, nose tip, mouth centre, right ear, left ear), ``width`` of its
    box in pixels."""

    score: float
    keypoints: np.ndarray
    width: float


@contextlib.contextmanager
def face_detector(model: int, confidence: float = 0.3, what: str = "face detection"):
    """MediaPipe's face detector (``model`` 0: short range, the Face Landmarker's own; 1: full
    range): yields a callable ``rgb`` -> its :class:`Detection` list, best first, or []."""
    mp = mediapipe(what)
    from mediapipe.tasks.python import BaseOptions, vision

    data = (_bundled("face_landmarker.task", "face_detector.tflite") if model == 0
            else model_bytes("face_detection_full_range_sparse.tflite"))
    options = vision.FaceDetectorOptions(base_options=BaseOptions(model_asset_buffer=data),
                                         min_detection_confidence=confidence)
    with native_stderr_quiet(), vision.FaceDetector.create_from_options(options) as fd:
        fd.detect(_image(mp, np.zeros((64, 64, 3), np.uint8)))  # its calculators open (and log) now

        def detect(rgb):  # quiet: the whole block runs in native_stderr_quiet
            image = _image(mp, rgb)
            h, w = image.height, image.width
            found = [Detection(float(d.categories[0].score), np.array([[k.x * w, k.y * h] for k in d.keypoints]),
                               float(d.bounding_box.width)) for d in fd.detect(image).detections]
            return sorted(found, key=lambda d: -d.score)
        yield detect


@contextlib.contextmanager
def selfie_segmenter(model: int, what: str = "person segmentation"):
    """MediaPipe's selfie segmentation (``model`` 0: general, 1: landscape): yields a callable
    ``rgb`` -> (H, W) float mask of the person."""
    mp = mediapipe(what)
    from mediapipe.tasks.python import BaseOptions, vision

    name = ("selfie_segmentation.tflite", "selfie_segmentation_landscape.tflite")[model]
    options = vision.ImageSegmenterOptions(base_options=BaseOptions(model_asset_buffer=model_bytes(name)),
                                           output_confidence_masks=True, output_category_mask=False)
    with native_stderr_quiet(), vision.ImageSegmenter.create_from_options(options) as seg:
        seg.segment(_image(mp, np.zeros((64, 64, 3), np.uint8)))  # its calculators open (and log) now

        def segment(rgb):
            mask = seg.segment(_image(mp, rgb)).confidence_masks[0].numpy_view()
            return np.array(mask.reshape(mask.shape[:2]), dtype=np.float32)
        yield segment
