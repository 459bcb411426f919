"""Offscreen rendering of faces to images and video.

OpenGL through moderngl on a headless EGL context: on a machine without a display or a GPU,
Mesa's llvmpipe rasterises on the CPU (about 14 ms per 512 x 512 frame of the textured
whole-head default face on 2 cores, against about 50 ms with the VTK renderer used before:
benchmarks/bench_render.py). The mesh goes to the GL once; each frame uploads float32
positions and smooth normals (one sparse product, :mod:`.normals`). Landmark detection uses the parallel
(orthographic) front view, where a pixel maps to a ray along -z in closed form
(:meth:`OffscreenRenderer.pixel_rays`).

Modules: :mod:`.gl` (context, shaders, :class:`OffscreenRenderer`), :mod:`.camera` (framing and
matrices), :mod:`.normals`, :mod:`.video` (PNG and MP4 files).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from faceanim.face.mesh import Mesh
from faceanim.render.camera import view_rotation
from faceanim.render.gl import (
    BACK_FACE,
    BACKGROUND,
    SKIN,
    OffscreenRenderer,
    gl_context,
)
from faceanim.render.normals import VertexNormals
from faceanim.render.video import save_png, write_video

__all__ = ["BACKGROUND", "BACK_FACE", "SKIN", "OffscreenRenderer", "VertexNormals", "gl_context",
           "render_png", "save_png", "view_rotation", "write_video"]


def render_png(mesh: Mesh, path: str | os.PathLike, vertices: np.ndarray | None = None,
               size=(512, 512), yaw: float = 0.0, pitch: float = 0.0,
               frame_vertices: np.ndarray | None = None, margin: float = 1.08) -> Path:
    """Render one view of ``mesh`` to a PNG file (framed on ``frame_vertices`` if given, e.g.
    the face of a full head)."""
    with OffscreenRenderer(mesh, size=size, yaw=yaw, pitch=pitch, frame_vertices=frame_vertices,
                           margin=margin) as r:
        return save_png(path, r.render(vertices))
