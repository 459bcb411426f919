"""GL helpers for texture baking: triangles rasterised in UV space, and orthographic views.

Three small passes on the shared offscreen context (:func:`faceanim.render.gl.gl_context`),
each drawing once into float targets and reading the result back:

- :func:`uv_raster`: every triangle drawn at its texture coordinates; each texel learns which
  triangle covers its centre and its barycentric coordinates there (the caller interpolates
  any per-vertex attribute, e.g. the 3D point, from them);
- :func:`ortho_depth`: the depth map of a mesh seen by an orthographic camera given as
  ``pixel = matrix @ X + offset`` and ``depth = direction @ X`` (larger is nearer), the same
  convention as ``faceanim.build.camera.ViewCamera``;
- :func:`ortho_render`: an unlit textured picture through such a camera (albedo only: what a
  baked texture is checked against).

Pixel convention: pixel ``(x, y)`` covers ``[x, x + 1) x [y, y + 1)``, x right, y down, row 0 at
the top; texel row 0 is ``v = 1`` (images are stored top row first, v points up).
"""

from __future__ import annotations

import numpy as np

from faceanim.errors import FaceAnimError
from faceanim.render.gl import _gl_lock, _state, gl_context

_UV_VERTEX = """
#version 330
in vec2 in_uv;
in float in_depth;
in float in_id;
in vec3 in_bary;
flat out float v_id;
noperspective out vec3 v_bary;
void main() {
    v_id = in_id;
    v_bary = in_bary;
    gl_Position = vec4(2.0 * in_uv.x - 1.0, 1.0 - 2.0 * in_uv.y, in_depth, 1.0);
}
"""

_UV_FRAGMENT = """
#version 330
flat in float v_id;
noperspective in vec3 v_bary;
out vec4 f_out;
void main() {
    f_out = vec4(v_id, v_bary);
}
"""

_ORTHO_VERTEX = """
#version 330
uniform mat4 clip;        // mesh -> clip coordinates
uniform vec3 direction;   // depth = direction . X
in vec3 in_position;
#if defined(TEXTURED)
in vec2 in_uv;
out vec2 v_uv;
#else
out float v_depth;
#endif
void main() {
#if defined(TEXTURED)
    v_uv = in_uv;
#else
    v_depth = dot(direction, in_position);
#endif
    gl_Position = clip * vec4(in_position, 1.0);
}
"""

_ORTHO_FRAGMENT = """
#version 330
#if defined(TEXTURED)
uniform sampler2D tex;
in vec2 v_uv;
out vec4 f_out;
void main() { f_out = vec4(texture(tex, v_uv).rgb, 1.0); }
#else
in float v_depth;
out float f_out;
void main() { f_out = v_depth; }
#endif
"""

EMPTY_DEPTH = -np.inf  # depth map value where the mesh is not seen
_CLEAR_DEPTH = -3.0e38  # what the depth target is cleared to (GL clears to finite values)


def _program(ctx, name: str):
    programs = _state["programs"]  # cleared whenever the shared context is remade
    key = "bake:" + name
    if key not in programs:
        if name == "uv":
            programs[key] = ctx.program(vertex_shader=_UV_VERTEX, fragment_shader=_UV_FRAGMENT)
        else:
            head = "#version 330\n" + ("#define TEXTURED\n" if name == "textured" else "")
            programs[key] = ctx.program(vertex_shader=head + _ORTHO_VERTEX.replace("#version 330\n", "", 1),
                                        fragment_shader=head + _ORTHO_FRAGMENT.replace("#version 330\n", "", 1))
    return programs[key]


def _check_size(size) -> tuple[int, int]:
    w, h = int(size[0]), int(size[1])
    if w < 1 or h < 1 or w > 16384 or h > 16384:
        raise FaceAnimError(f"raster size must be 1..16384 pixels a side, got {w} x {h}")
    return w, h


def _draw(ctx, program, content, size, clear, uniforms=None, texture=None, components: int = 4) -> np.ndarray:
    """Draw non-indexed triangles into a float target with a depth test; (h, w, components)
    float32."""
    import moderngl

    w, h = size
    resources = []
    try:
        buffers = []
        for data, fmt, name in content:
            buf = ctx.buffer(np.ascontiguousarray(data, dtype=np.float32))
            resources.append(buf)
            buffers.append((buf, fmt, name))
        vao = ctx.vertex_array(program, buffers)
        resources.append(vao)
        colour = ctx.texture((w, h), components, dtype="f4")
        depth = ctx.depth_renderbuffer((w, h))
        resources += [colour, depth]
        fbo = ctx.framebuffer(color_attachments=[colour], depth_attachment=depth)
        resources.append(fbo)
        fbo.use()
        ctx.enable_only(moderngl.DEPTH_TEST)
        ctx.depth_func = "<"
        fbo.clear(*clear, depth=1.0)
        for name, value in (uniforms or {}).items():
            if name in program:
                program[name].write(np.asarray(value, dtype=np.float32).tobytes())
        if texture is not None:
            texture.use(0)
            if "tex" in program:
                program["tex"].value = 0
        vao.render(moderngl.TRIANGLES)
        out = np.frombuffer(fbo.read(components=components, dtype="f4", alignment=1), dtype=np.float32)
        return out.reshape(h, w, components).copy()
    finally:
        for r in reversed(resources):
            r.release()


def uv_raster(uv_corners: np.ndarray, size: tuple[int, int], depth: np.ndarray | None = None,
              ids: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rasterise triangles at their texture coordinates.

    Parameters
    ----------
    uv_corners : (T, 3, 2) texture coordinates of each triangle's corners (v up)
    size : (width, height) of the texture in texels
    depth : (T, 3) values in [0, 1] per corner; where triangles overlap in UV the smallest wins
        (default: all 0, the first triangle drawn wins)
    ids : (T,) the number reported for each triangle (default: its index)

    Returns ``(triangle (h, w) int64, -1 where no triangle covers the texel centre,
    barycentric (h, w, 3) float32)``; row 0 is v = 1.
    """
    uvc = np.asarray(uv_corners, dtype=np.float64).reshape(-1, 3, 2)
    t = len(uvc)
    w, h = _check_size(size)
    if t == 0:
        return np.full((h, w), -1, dtype=np.int64), np.zeros((h, w, 3), dtype=np.float32)
    if ids is None:
        ids = np.arange(t)
    ids = np.asarray(ids, dtype=np.int64)
    if ids.max(initial=0) >= 1 << 24:
        raise FaceAnimError("too many triangles to rasterise in UV space (at most 16.7 million)")
    z = np.zeros((t, 3)) if depth is None else np.clip(np.asarray(depth, dtype=np.float64).reshape(t, 3), 0, 1)
    bary = np.tile(np.eye(3, dtype=np.float32), (t, 1))
    content = [(uvc.reshape(-1, 2), "2f", "in_uv"), ((2 * z - 1).reshape(-1), "f", "in_depth"),
               (np.repeat(ids + 1, 3).astype(np.float32), "f", "in_id"), (bary, "3f", "in_bary")]
    ctx = gl_context()
    with _gl_lock, ctx:
        out = _draw(ctx, _program(ctx, "uv"), content, (w, h), (0.0, 0.0, 0.0, 0.0))
    tri = np.rint(out[..., 0]).astype(np.int64) - 1
    return tri, np.ascontiguousarray(out[..., 1:4])


def _clip_matrix(vertices: np.ndarray, matrix, offset, direction, size) -> tuple[np.ndarray, np.ndarray]:
    """4x4 mesh -> clip matrix of an orthographic camera, and the unit depth direction."""
    w, h = size
    a = np.asarray(matrix, dtype=np.float64).reshape(2, 3)
    b = np.asarray(offset, dtype=np.float64).reshape(2)
    d = np.asarray(direction, dtype=np.float64).reshape(3)
    depth = vertices @ d
    lo, hi = float(depth.min()), float(depth.max())
    pad = 0.01 * (hi - lo) + 1e-6
    lo, hi = lo - pad, hi + pad
    m = np.zeros((4, 4))
    m[0, :3], m[0, 3] = 2 * a[0] / w, 2 * b[0] / w - 1  # x right
    m[1, :3], m[1, 3] = 2 * a[1] / h, 2 * b[1] / h - 1  # row 0 (y down = 0) at the bottom of GL
    m[2, :3], m[2, 3] = -2 * d / (hi - lo), 1 + 2 * lo / (hi - lo)  # nearer (larger depth) -> smaller z
    m[3, 3] = 1.0
    return m, d


def ortho_depth(vertices: np.ndarray, faces: np.ndarray, matrix, offset, direction,
                size: tuple[int, int]) -> np.ndarray:
    """(h, w) float32 depth map (``direction @ X`` of the nearest surface, larger is nearer;
    ``EMPTY_DEPTH`` where nothing is seen) of the mesh through an orthographic camera:
    ``pixel = matrix @ X + offset``."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    w, h = _check_size(size)
    clip, d = _clip_matrix(v, matrix, offset, direction, (w, h))
    ctx = gl_context()
    with _gl_lock, ctx:
        program = _program(ctx, "depth")
        out = _draw(ctx, program, [(v[f].reshape(-1, 3), "3f", "in_position")], (w, h), (_CLEAR_DEPTH,) * 4,
                    uniforms={"clip": clip.T, "direction": d}, components=1)[..., 0]
    out[out <= _CLEAR_DEPTH / 2] = EMPTY_DEPTH
    return out


def ortho_render(vertices: np.ndarray, faces: np.ndarray, uv_corners: np.ndarray, texture: np.ndarray,
                 matrix, offset, direction, size: tuple[int, int], background=(0, 0, 0)) -> np.ndarray:
    """(h, w, 3) uint8 unlit picture of a textured mesh (bilinear texture, no mipmaps) through an
    orthographic camera, and nothing else: the albedo a baked texture should reproduce."""
    import moderngl

    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    uvc = np.asarray(uv_corners, dtype=np.float64).reshape(-1, 3, 2)
    w, h = _check_size(size)
    clip, d = _clip_matrix(v, matrix, offset, direction, (w, h))
    image = np.ascontiguousarray(np.asarray(texture)[::-1, :, :3], dtype=np.uint8)  # v up
    ctx = gl_context()
    with _gl_lock, ctx:
        tex = ctx.texture((image.shape[1], image.shape[0]), 3, image.tobytes(), alignment=1)
        try:
            tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
            tex.repeat_x = tex.repeat_y = False
            bg = tuple(c / 255.0 for c in background)
            out = _draw(ctx, _program(ctx, "textured"),
                        [(v[f].reshape(-1, 3), "3f", "in_position"), (uvc.reshape(-1, 2), "2f", "in_uv")],
                        (w, h), (*bg, 0.0), uniforms={"clip": clip.T, "direction": d}, texture=tex)
        finally:
            tex.release()
    return np.clip(np.rint(out[..., :3] * 255), 0, 255).astype(np.uint8)
