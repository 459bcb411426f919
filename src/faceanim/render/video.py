"""Images and video out: PNG with Pillow, H.264 MP4 through ffmpeg (imageio-ffmpeg)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from faceanim.errors import FaceAnimError
from faceanim.io.files import atomic_output


def save_png(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write an RGB image as PNG atomically."""
    from PIL import Image

    path = Path(path)
    with atomic_output(path) as tmp:
        Image.fromarray(np.asarray(image, dtype=np.uint8)).save(tmp, format="PNG")
    return path


def write_video(path: str | os.PathLike, frames, fps: float = 30.0, progress=None, audio=None) -> Path:
    """Encode an iterable of RGB frames to MP4 (H.264, yuv420p, index at the front for playback
    on the web) with imageio-ffmpeg, with the sound of the WAV file ``audio`` (AAC) when given.

    Frames are streamed to ffmpeg as they come (a generator is never held in memory), and ffmpeg
    encodes in its own process while the next frames are rendered.
    """
    import imageio_ffmpeg

    path = Path(path)
    with atomic_output(path) as tmp:
        writer = None
        try:
            for frame in frames:
                frame = np.ascontiguousarray(frame, dtype=np.uint8)
                if writer is None:
                    if frame.ndim != 3 or frame.shape[2] != 3:
                        raise FaceAnimError(f"video frames must be (H, W, 3) RGB images, got shape {frame.shape}")
                    h, w = frame.shape[:2]
                    if w % 2 or h % 2:
                        raise FaceAnimError(f"video frames need even width and height, got {w}x{h}")
                    size = (w, h)
                    sound = {} if audio is None else {"audio_path": str(audio), "audio_codec": "aac"}
                    writer = imageio_ffmpeg.write_frames(
                        str(tmp), size, fps=fps, codec="libx264", pix_fmt_out="yuv420p",
                        quality=None, bitrate=None,
                        output_params=["-crf", "18", "-preset", "medium", "-movflags", "+faststart"],
                        macro_block_size=1, ffmpeg_log_level="error", **sound)
                    writer.send(None)
                elif frame.shape[1::-1] != size or frame.shape[2:] != (3,):
                    raise FaceAnimError(f"video frame of shape {frame.shape} after frames of {size[0]}x{size[1]}")
                writer.send(frame)
                if progress is not None:
                    progress.update(1)
            if writer is None:
                raise FaceAnimError("no frames to write")
        finally:
            if writer is not None:
                writer.close()
    return path
