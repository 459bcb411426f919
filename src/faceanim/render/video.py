"""Images and video out: PNG with Pillow, H.264 MP4 through ffmpeg (imageio-ffmpeg)."""

from __future__ import annotations

import contextlib
import os
import queue
import sys
import threading
from pathlib import Path

import numpy as np

from faceanim.errors import FaceAnimError, shown
from faceanim.io.files import atomic_output
from faceanim.limits import check_fps, check_video


def save_png(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write an RGB image as PNG atomically."""
    from PIL import Image

    path = Path(path)
    with atomic_output(path) as tmp:
        Image.fromarray(np.asarray(image, dtype=np.uint8)).save(tmp, format="PNG")
    return path


# x264 leaves a core to the renderer (llvmpipe rasterises on the CPU): on 2 cores, one encoder
# thread with frames handed over by a thread of ours was ~15 % faster end to end than x264's
# default 3 threads competing with llvmpipe's (benchmarks/bench_render.py)
ENCODER_THREADS = max(1, (os.cpu_count() or 2) - 1)
# x264 quality (visually lossless) and speed: "veryfast" takes 1.7 ms a 512 px frame against 4.3 ms for
# "medium", CPU that llvmpipe's rasteriser shares on 2 cores, and at crf 18 its files came out smaller
# (benchmarks/bench_mp4.py: 2.8x real time end to end against 2.2x)
CRF, PRESET = "18", "veryfast"
QUEUE_FRAMES = 4


class _Pump:
    """Hands frames to ffmpeg from a thread of its own, so that the next frame is rendered while
    this one goes down the pipe (a 512 x 512 frame is 768 KiB; the pipe holds 64)."""

    def __init__(self, writer):
        self.writer = writer
        self.queue: queue.Queue = queue.Queue(maxsize=QUEUE_FRAMES)
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, name="faceanim-video", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while True:
            frame = self.queue.get()
            if frame is None:
                return
            if self.error is None:  # after a failure keep draining, so that put() never blocks
                try:
                    self.writer.send(frame)
                except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
                    self.error = exc

    def _raise(self) -> None:
        if self.error is not None:  # ffmpeg's own message is not shown: it can quote any file it read
            raise FaceAnimError(FFMPEG_FAILED) from self.error

    def put(self, frame: np.ndarray) -> None:
        self._raise()
        self.queue.put(frame)

    def stop(self) -> None:
        """Send what is queued and end the thread."""
        if self.thread.is_alive():
            self.queue.put(None)
            self.thread.join()

    def finish(self) -> None:
        self.stop()
        self._raise()


FULL_DISK_BYTES = 16 << 20  # ffmpeg failed and less than this is free where it wrote: the disk is full
FFMPEG_FAILED = ("ffmpeg could not encode the video; check that the sound is a readable audio file and that the "
                 "disk has room (run with --verbose for ffmpeg's message)")


def write_video(path: str | os.PathLike, frames, fps: float = 25.0, progress=None, audio=None) -> Path:
    """Encode an iterable of RGB frames to MP4 (H.264, yuv420p, index at the front for playback
    on the web) with imageio-ffmpeg, with the sound of the WAV file ``audio`` (AAC) when given.

    Frames are streamed as they come (a generator is never held in memory: at most
    ``QUEUE_FRAMES`` wait for the pipe), and ffmpeg encodes in its own process while the next
    frames are rendered.
    """
    import imageio_ffmpeg

    from faceanim.io.video import quiet_ffmpeg_remarks

    quiet_ffmpeg_remarks()  # how the encode ended is told here, in one line
    fps = check_fps(fps, "the frame rate")
    if audio is not None:
        from faceanim.io.audio import read_audio

        read_audio(audio, "sound for the video")  # a clean error now rather than ffmpeg's later
    path = Path(path)
    with atomic_output(path) as tmp:
        writer = pump = ffmpeg = None
        try:
            for frame in frames:
                frame = np.ascontiguousarray(frame, dtype=np.uint8)
                if writer is None:
                    if frame.ndim != 3 or frame.shape[2] != 3:
                        raise FaceAnimError(f"video frames must be (H, W, 3) RGB images, got shape {frame.shape}")
                    h, w = frame.shape[:2]
                    check_video(1, w, h)
                    if w % 2 or h % 2:
                        raise FaceAnimError(f"video frames need even width and height, got {w}x{h}")
                    size = (w, h)
                    sound = {} if audio is None else {"audio_path": str(audio), "audio_codec": "aac"}
                    writer = imageio_ffmpeg.write_frames(
                        str(tmp), size, fps=fps, codec="libx264", pix_fmt_out="yuv420p",
                        quality=None, bitrate=None,
                        output_params=["-crf", CRF, "-preset", PRESET, "-threads", str(ENCODER_THREADS),
                                       "-movflags", "+faststart"],
                        macro_block_size=1, ffmpeg_log_level="error" if os.environ.get("FACEANIM_VERBOSE") else "quiet",
                        **sound)
                    writer.send(None)
                    ffmpeg = writer.gi_frame.f_locals.get("p") if writer.gi_frame is not None else None
                    pump = _Pump(writer)
                elif frame.shape != (size[1], size[0], 3):
                    raise FaceAnimError(f"video frame of shape {frame.shape} after frames of {size[0]}x{size[1]}")
                pump.put(frame)
                if progress is not None:
                    progress.update(1)
            if writer is None:
                raise FaceAnimError("no frames to write")
            pump.finish()
        finally:
            stopped = sys.exc_info()[1]
            interrupted = stopped is not None and not isinstance(stopped, Exception)  # Ctrl-C, SIGTERM, SIGHUP
            if pump is not None and not interrupted:
                pump.stop()
            if writer is not None and interrupted:
                # ffmpeg is killed, not left to finish a file about to be removed (it would complain
                # about the vanished file on the terminal), and waited for: a file it was making as it
                # died could appear after ours is removed. The pump is not stopped through its queue:
                # a stop raised inside queue.put can leave the queue's lock held (a deadlock seen
                # under load); its thread is a daemon, blocked or failing on the dead pipe
                if ffmpeg is not None and hasattr(ffmpeg, "kill"):
                    with contextlib.suppress(Exception):
                        ffmpeg.kill()
                        ffmpeg.wait(timeout=10)
                elif pump is None or not pump.thread.is_alive():
                    with contextlib.suppress(BaseException):
                        writer.throw(KeyboardInterrupt)
            elif writer is not None:
                try:
                    writer.close()
                except Exception as exc:  # noqa: BLE001 - ffmpeg's exit status, with its raw log
                    raise FaceAnimError(_failed(tmp)) from exc
                # imageio-ffmpeg does not look at how ffmpeg ended: a file it could not finish (its
                # trailer on a full disk) must not replace the user's
                code = ffmpeg.poll() if ffmpeg is not None and hasattr(ffmpeg, "poll") else 0
                if code != 0 and stopped is None:
                    raise FaceAnimError(_failed(tmp))
    return path


def _failed(tmp: Path) -> str:
    """What to say when ffmpeg did not finish the file ``tmp``: a full disk by name."""
    import shutil

    try:
        full = shutil.disk_usage(tmp.parent).free < FULL_DISK_BYTES
    except OSError:
        full = False
    if full:
        return (f"the disk holding '{shown(tmp.parent, 80, tail=True)}' is full; free some space and run the "
                "command again")
    return FFMPEG_FAILED
