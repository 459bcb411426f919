"""Live sources: frames with the time they were captured, from a camera or a clip played in real time.

A source runs its own thread and keeps only the newest frame (:class:`Latest`): the capture never
waits for the compute. A frame the compute had no time to take is replaced by the next one and
counted as dropped, so latency does not grow when the compute falls behind.
"""

from __future__ import annotations

import threading
from abc import ABC, abstractmethod
import time
from dataclasses import dataclass

import numpy as np

from faceanim.errors import FaceAnimError


@dataclass
class Frame:
    """``index`` (frames captured so far, from 0), ``capture`` (time.monotonic() when it was
    captured), ``time`` (seconds of the source: the clip's time, or since the camera started),
    ``image`` (H, W, 3) RGB (None for a tick of a sound alone), ``mouth``: the (52,) ARKit
    curves a sound gives at that moment (:mod:`faceanim.live.audio`), if any, and ``head``: the
    head's (3,) yaw, pitch, roll the sound gives."""

    index: int
    capture: float
    time: float
    image: np.ndarray | None
    mouth: np.ndarray | None = None
    head: np.ndarray | None = None


class Latest:
    """A one-frame slot between a capture thread and the compute: :meth:`put` replaces a frame not
    yet taken (and counts it dropped); :meth:`get` waits for a new frame (None once the source has
    ended and the last frame was taken)."""

    def __init__(self):
        self._cv = threading.Condition()
        self._frame: Frame | None = None
        self._ended = False
        self.captured = 0
        self.dropped = 0
        self.error: FaceAnimError | None = None

    def put(self, frame: Frame) -> None:
        with self._cv:
            if self._frame is not None:
                self.dropped += 1
            self._frame = frame
            self.captured += 1
            self._cv.notify()

    def end(self, error: FaceAnimError | None = None) -> None:
        with self._cv:
            self._ended = True
            self.error = self.error or error
            self._cv.notify()

    def get(self, timeout: float = 0.25) -> Frame | None:
        """The newest frame; None when the source has ended. Waits in slices of ``timeout`` seconds
        (so that Ctrl-C is seen)."""
        with self._cv:
            while self._frame is None and not self._ended:
                self._cv.wait(timeout)
            frame, self._frame = self._frame, None
            return frame


class Source(ABC):
    """A thread feeding a :class:`Latest`; ``start()``, ``stop()``, ``fps``, ``name`` and ``images``
    (whether its frames carry pictures to track)."""

    name = "source"
    fps = 30.0
    images = True

    def __init__(self):
        self.slot = Latest()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._thread = threading.Thread(target=self._guarded, name=f"faceanim live {self.name}", daemon=True)
        self._thread.start()

    def _guarded(self) -> None:
        try:
            self._run()
            self.slot.end()
        except FaceAnimError as exc:
            self.slot.end(exc)
        except Exception as exc:  # noqa: BLE001 -- a capture failure ends the run with one line
            self.slot.end(FaceAnimError(f"{self.name} stopped ({type(exc).__name__})"))

    @abstractmethod
    def _run(self) -> None:
        """Capture until the source ends or :meth:`stop`, putting frames into :attr:`slot`."""

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)


class ClipSource(Source):
    """A video file played at its own frame rate as if it were live: frame i is captured at
    ``start + i / fps`` (decoding runs ahead by at most one frame), then the source ends. With
    ``realtime=False`` every frame is put as fast as it is taken (for tests: no frame dropped)."""

    def __init__(self, path, realtime: bool = True, seconds: float | None = None):
        from faceanim.io.video import video_info

        super().__init__()
        self.info = video_info(path)
        self.fps = float(self.info.fps)
        self.name = self.info.path.name
        self.realtime = realtime
        self.seconds = seconds

    def _run(self) -> None:
        from faceanim.io.video import video_frames

        start = time.monotonic()
        for i, image in enumerate(video_frames(self.info)):
            t = i / self.fps
            if self._stop.is_set() or (self.seconds is not None and t >= self.seconds):
                return
            if self.realtime:
                wait = start + t - time.monotonic()
                if wait > 0 and self._stop.wait(wait):
                    return
            else:
                while self.slot._frame is not None and not self._stop.is_set():  # the compute's pace
                    time.sleep(0.001)
            self.slot.put(Frame(i, time.monotonic(), t, image))


class CameraSource(Source):
    """A camera (OpenCV's capture, device ``index``): frames as the camera delivers them, timed
    from the first; ends when the camera stops giving frames (unplugged) or after ``seconds``."""

    def __init__(self, index: int, seconds: float | None = None):
        import cv2

        from faceanim.io.files import native_stderr_quiet

        super().__init__()
        with native_stderr_quiet():  # OpenCV logs its failed probes of the camera devices
            self.cap = cv2.VideoCapture(int(index))
            opened = self.cap.isOpened()
        if not opened:
            raise FaceAnimError(f"no camera {index} on this machine; give --video FILE instead")
        self.fps = float(self.cap.get(cv2.CAP_PROP_FPS) or 30.0)
        self.name = f"camera {index}"
        self.seconds = seconds

    def _run(self) -> None:
        start = None
        i = 0
        try:
            while not self._stop.is_set():
                ok, bgr = self.cap.read()
                now = time.monotonic()
                if not ok:
                    if i == 0:
                        raise FaceAnimError(f"{self.name} gives no frames; check that no other program uses it")
                    raise FaceAnimError(f"{self.name} stopped giving frames after {i} (unplugged?)")
                start = now if start is None else start
                if self.seconds is not None and now - start >= self.seconds:
                    return
                self.slot.put(Frame(i, now, now - start, np.ascontiguousarray(bgr[..., ::-1])))
                i += 1
        finally:
            self.cap.release()
