"""Offscreen rendering: a frontal render of the textured default face reproduces its photo."""

import numpy as np
import pytest

from faceanim.render import OffscreenRenderer, write_video


def test_front_render_reproduces_the_photo(face):
    """Oracle: each vertex must show the texture colour at its UV where it projects."""
    size = 512
    with OffscreenRenderer(face, size=(size, size), parallel=True, margin=1.0) as r:
        img = r.render().astype(float).mean(-1)
        height = 2 * r.parallel_scale
        cx, cy = r.centre[:2]
    v = face.vertices
    front = face.vertex_normals()[:, 2] > 0.7
    px = ((v[front, 0] - cx) / height + 0.5) * size
    py = (0.5 - (v[front, 1] - cy) / height) * size
    rendered = img[py.astype(int).clip(0, size - 1), px.astype(int).clip(0, size - 1)]
    tex = face.texture.astype(float).mean(-1)
    th, tw = tex.shape
    uv = face.uv[front]

    def sample(u, w):
        return tex[((1 - w) * th).astype(int).clip(0, th - 1), (u * tw).astype(int).clip(0, tw - 1)]

    ncc = np.corrcoef(rendered, sample(uv[:, 0], uv[:, 1]))[0, 1]
    mirrored = np.corrcoef(rendered, sample(1 - uv[:, 0], uv[:, 1]))[0, 1]
    upside_down = np.corrcoef(rendered, sample(uv[:, 0], 1 - uv[:, 1]))[0, 1]
    assert ncc > 0.8
    assert ncc > max(mirrored, upside_down) + 0.3


def test_faces_point_at_the_camera(face):
    """Shaded front render: lit skin, not the dark back faces of a mesh turned inside out."""
    with OffscreenRenderer(face, size=(128, 128), parallel=True, use_texture=False) as r:
        img = r.render().astype(float)
    centre = img[40:88, 40:88].mean(-1)
    assert centre.mean() > 120


def test_video_is_written(tmp_path):
    import imageio_ffmpeg

    frames = [np.full((64, 80, 3), k * 20, dtype=np.uint8) for k in range(10)]
    path = write_video(tmp_path / "v.mp4", frames, fps=10)
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    assert meta["size"] == (80, 64)
    assert sum(1 for _ in reader) == 10


def test_failed_video_leaves_no_file(tmp_path):
    from faceanim.errors import FaceAnimError

    with pytest.raises(FaceAnimError):
        write_video(tmp_path / "odd.mp4", [np.zeros((63, 80, 3), dtype=np.uint8)])
    assert list(tmp_path.iterdir()) == []
