"""Reading video files: frames as RGB arrays, with the clip's frame rate and size checked first.

ffmpeg (the binary inside ``imageio-ffmpeg``) decodes any common container and codec. A file
that is missing, empty, not a video, truncated before its first frame, or too large to be worth
decoding gets one :class:`~faceanim.errors.InputFileError` line; ffmpeg's own output is never
shown (it can echo the file's content).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from faceanim.errors import InputFileError, shown
from faceanim.io.files import check_input_file
from faceanim.limits import MAX_FPS, MAX_FRAMES, MAX_IMAGE_SIZE

PATH_SHOWN = 80


@dataclass(frozen=True)
class VideoInfo:
    """A video file's frame rate, frame size (width, height, as decoded: square pixels) and
    duration in seconds (0 when the container does not say)."""

    path: Path
    fps: float
    size: tuple[int, int]
    duration: float

    @property
    def frames_expected(self) -> int:
        """The number of frames the container announces (an estimate: fps x duration)."""
        return round(self.fps * self.duration)


def _name(path) -> str:
    return shown(path, PATH_SHOWN, tail=True)


def quiet_ffmpeg_remarks() -> None:
    """imageio-ffmpeg logs its own remarks on how ffmpeg ended ("We had to kill ffmpeg to stop it"
    when a Ctrl-C closes a reader or a writer): faceanim tells how a run ended, in one line."""
    import logging

    logging.getLogger("imageio_ffmpeg").setLevel(logging.ERROR)


def _reader(path: Path, fps: float | None = None):
    """imageio-ffmpeg's frame reader and the video's metadata; with ``fps``, frames at that constant
    rate (a variable-frame-rate clip, as phones record, is resampled: frame k is at k / fps)."""
    import imageio_ffmpeg

    from faceanim.io.files import native_stderr_quiet

    quiet_ffmpeg_remarks()

    with native_stderr_quiet():
        gen = imageio_ffmpeg.read_frames(str(path), pix_fmt="rgb24",
                                         output_params=["-fps_mode", "cfr", "-r", f"{fps:.6f}"] if fps else None)
        try:
            meta = next(gen)
        except (RuntimeError, OSError, StopIteration, ValueError):
            gen.close()
            raise InputFileError(f"video '{_name(path)}' is not a readable video (corrupt, empty or not a "
                                 "video); give an MP4, MOV, MKV, AVI or WebM file") from None
    return gen, meta


def video_info(path: str | os.PathLike) -> VideoInfo:
    """Check a video file and read its frame rate, size and duration (no frame is decoded)."""
    p = check_input_file(path, "video", "a video file")
    if p.stat().st_size == 0:
        raise InputFileError(f"video '{_name(p)}' is empty; give a video file")
    with open(p, "rb") as fh:
        head = fh.read(8)
    if head.startswith((b"\x89PNG", b"\xff\xd8\xff", b"BM", b"GIF8", b"II*\x00", b"MM\x00*")):
        raise InputFileError(f"'{_name(p)}' is a picture, not a video; give a video file (MP4, MOV, MKV, AVI, "
                             "WebM)")
    gen, meta = _reader(p)
    gen.close()
    fps = float(meta.get("fps") or 0.0)
    size = tuple(int(v) for v in (meta.get("size") or (0, 0)))
    duration = float(meta.get("duration") or 0.0)
    if not np.isfinite(fps) or not 0 < fps <= MAX_FPS:
        raise InputFileError(f"video '{_name(p)}' says it runs at {fps:g} frames per second; faceanim reads "
                             f"videos of up to {MAX_FPS:g}")
    if len(size) != 2 or min(size) < 16 or max(size) > MAX_IMAGE_SIZE:
        raise InputFileError(f"video '{_name(p)}' has frames of {size[0]}x{size[1]} pixels; give a video of "
                             f"16 to {MAX_IMAGE_SIZE} pixels a side")
    if not np.isfinite(duration) or duration < 0 or fps * duration > MAX_FRAMES:
        raise InputFileError(f"video '{_name(p)}' is {duration:g} s long ({fps * duration:.0f} frames); give at "
                             f"most {MAX_FRAMES} frames (cut it first)")
    return VideoInfo(p, fps, (size[0], size[1]), duration)


def video_frames(info: VideoInfo) -> Iterator[np.ndarray]:
    """The frames of a checked video, in order, as (H, W, 3) uint8 arrays. Stops after
    ``MAX_FRAMES``. A file that ends well before the frames its container announces (truncated or
    damaged: fewer than all but 2% of them, or 2) raises :class:`InputFileError` once its last
    readable frame has been given (containers' durations are estimates: a frame short is normal)."""
    gen, _ = _reader(info.path, info.fps)
    w, h = info.size
    n = 0
    try:
        for buf in gen:
            if n >= MAX_FRAMES:
                return
            frame = np.frombuffer(buf, dtype=np.uint8)
            if frame.size != w * h * 3:
                break
            yield frame.reshape(h, w, 3)
            n += 1
    except (RuntimeError, OSError):
        pass  # ffmpeg stopped on a damaged tail
    finally:
        gen.close()
    expected = info.frames_expected
    if n < expected - max(2, int(0.02 * expected)):
        raise InputFileError(f"video '{_name(info.path)}' ends after {n} of the {expected} frames it announces "
                             "(truncated or damaged); give the whole file or re-export it")


def video_sound(video, folder) -> Path | None:
    """The sound of ``video`` as a WAV in ``folder`` (None if it has none or ffmpeg cannot read
    it); ffmpeg's own messages are never shown."""
    import subprocess

    import imageio_ffmpeg

    wav = Path(folder) / "sound.wav"
    r = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-v", "error", "-nostdin", "-y", "-i", str(video), "-vn",
                        "-ac", "1", "-ar", "44100", str(wav)], capture_output=True, check=False)
    return wav if r.returncode == 0 and wav.is_file() and wav.stat().st_size > 1000 else None


def side_by_side(frames, face_frames, size: int):
    """Each video frame scaled to ``size`` pixels high (even width) beside the face's render."""
    import cv2

    for img, face_img in zip(frames, face_frames):
        h, w = img.shape[:2]
        width = max(2, int(round(w * size / h / 2)) * 2)
        yield np.hstack([cv2.resize(img, (width, size), interpolation=cv2.INTER_AREA), face_img])
