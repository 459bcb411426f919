"""Offscreen OpenGL rendering with moderngl on a headless EGL context.

Without a GPU, Mesa's llvmpipe rasterises on the CPU. The mesh is uploaded once (UVs, texture,
the triangle index buffer); each frame sends only float32 vertex positions and normals, draws
into a framebuffer with a depth buffer and reads RGB back with one call. One GL context serves
every renderer of a process (making an EGL context is slow).
"""

from __future__ import annotations

import os
import threading

import numpy as np

from faceanim.errors import FaceAnimError
from faceanim.face.mesh import Mesh
from faceanim.render.camera import Camera
from faceanim.render.normals import VertexNormals

SKIN = (0.87, 0.72, 0.62)  # albedo for meshes without a texture
BACKGROUND = (0.16, 0.17, 0.2)
BACK_FACE = (0.05, 0.04, 0.04)  # the inside of a head seen through the eyes or the mouth
AMBIENT, DIFFUSE, SPECULAR, SHININESS = 0.12, 0.9, 0.15, 12.0
# key and fill lights: directions (view coordinates, towards the light) and intensities;
# a headlight shines along the camera's line of sight
LIGHTS = (((1.5, 2.0, 4.0), 0.75), ((-2.5, 0.5, 3.0), 0.35))
HEADLIGHT = 0.25
# Multisample anti-aliasing: 4x MSAA costs llvmpipe more than twice the frame time (about
# +10 ms at 512 x 512, benchmarks/bench_render.py), so it is off; set 4 here to have it.
SAMPLES = 0

# Lighting is computed per vertex (Gouraud): at 30k vertices a triangle covers a few pixels,
# so this looks the same as per-pixel lighting, and llvmpipe's cost is mostly per fragment.
# Both sides are lit in the vertex shader; the fragment shader picks the side it sees.
_VERTEX_SHADER = """
uniform mat4 mvp;
uniform mat3 model;            // mesh -> view coordinates (a rotation)
uniform vec3 light_dir[3];     // unit vectors towards the lights (view coordinates)
uniform float light_power[3];
uniform vec3 eye;
uniform vec3 view_dir;         // from the centre to the eye (parallel projection)
uniform bool parallel;
uniform float shininess;
in vec3 in_position;
in vec3 in_normal;
out vec3 v_light;              // diffuse front, specular front, diffuse back
#ifdef TEXTURED
in vec2 in_uv;
out vec2 v_uv;
#endif
void main() {
    vec3 p = model * in_position;
    vec3 n = model * in_normal;
    float len = length(n);
    n = len > 0.0 ? n / len : vec3(0.0, 0.0, 1.0);
    vec3 v = parallel ? view_dir : normalize(eye - p);
    float front = 0.0, spec = 0.0, back = 0.0;
    for (int i = 0; i < 3; i++) {
        float ndl = dot(n, light_dir[i]);
        if (ndl > 0.0) {
            front += light_power[i] * ndl;
            spec += light_power[i] * pow(max(dot(reflect(-light_dir[i], n), v), 0.0), shininess);
        } else {
            back -= light_power[i] * ndl;
        }
    }
    v_light = vec3(front, spec, back);
#ifdef TEXTURED
    v_uv = in_uv;
#endif
    gl_Position = mvp * vec4(in_position, 1.0);
}
"""

_FRAGMENT_SHADER = """
uniform vec3 albedo;
uniform vec3 back_colour;
uniform float ambient;
uniform float diffuse;
uniform float specular;
#ifdef TEXTURED
uniform sampler2D tex;
in vec2 v_uv;
#endif
in vec3 v_light;
out vec3 f_colour;
void main() {
    if (gl_FrontFacing) {
#ifdef TEXTURED
        vec3 base = texture(tex, v_uv).rgb;
#else
        vec3 base = albedo;
#endif
        f_colour = base * (ambient + diffuse * v_light.x) + vec3(specular * v_light.y);
    } else {  // the inside, lit on its own side, dark and matt
        f_colour = back_colour * (ambient + diffuse * v_light.z);
    }
}
"""

_lock = threading.Lock()
_state: dict = {}


def gl_context():
    """The process's moderngl context (headless EGL), made on first use and reused."""
    with _lock:
        ctx = _state.get("ctx")
        if ctx is None or _state.get("pid") != os.getpid():  # a forked child needs its own
            try:
                import moderngl
            except ImportError:
                raise FaceAnimError("rendering needs moderngl (pip install moderngl)") from None
            try:
                ctx = moderngl.create_standalone_context(require=330, backend="egl")
            except Exception as exc:
                raise FaceAnimError(
                    f"could not make an offscreen OpenGL context with EGL ({exc}); on Debian/Ubuntu "
                    "install libegl1 libegl-mesa0 libgl1-mesa-dri (Mesa's software renderer)") from None
            _state.clear()
            _state.update(ctx=ctx, pid=os.getpid(), programs={})
        return ctx


def _program(ctx, textured: bool):
    programs = _state["programs"]
    if textured not in programs:
        head = "#version 330\n" + ("#define TEXTURED\n" if textured else "")
        programs[textured] = ctx.program(vertex_shader=head + _VERTEX_SHADER,
                                          fragment_shader=head + _FRAGMENT_SHADER)
    return programs[textured]


class OffscreenRenderer:
    """Renders one mesh (with changing vertex positions) from a fixed camera.

    Parameters
    ----------
    mesh : Mesh
    size : (width, height) in pixels
    yaw, pitch : camera angles in degrees around the face (0, 0 is straight on)
    parallel : orthographic projection (used for landmark detection)
    rotation : (3, 3) rotation from mesh to view coordinates (see :func:`view_rotation`)
    frame_vertices : vertices whose bounds set the framing (default: the mesh's)
    use_texture : draw the texture when the mesh has one, else a skin-coloured shaded surface
    background : RGB in [0, 1]
    margin : the framed box is this much larger than the bounds of ``frame_vertices``

    Use it as a context manager (or call :meth:`close`) to free its GL buffers.
    """

    def __init__(self, mesh: Mesh, size=(512, 512), yaw: float = 0.0, pitch: float = 0.0,
                 parallel: bool = False, rotation: np.ndarray | None = None,
                 frame_vertices: np.ndarray | None = None, use_texture: bool = True,
                 background=BACKGROUND, margin: float = 1.08):
        import moderngl

        self.mesh = mesh
        self.size = (int(size[0]), int(size[1]))
        if min(self.size) < 1:
            raise FaceAnimError(f"image size must be positive, got {self.size}")
        self.rotation = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
        self.background = tuple(float(c) for c in background)[:3]
        self._source, faces, uv = mesh.per_vertex_uv()
        self._identity = len(self._source) == mesh.n_vertices and \
            bool((self._source == np.arange(mesh.n_vertices)).all())
        self._normals = VertexNormals(mesh.faces, mesh.n_vertices,
                                      rows=None if self._identity else self._source)
        self.textured = bool(use_texture and uv is not None and mesh.texture is not None)

        fv = self._view(mesh.vertices if frame_vertices is None else frame_vertices)
        self.camera = Camera(fv, self.size, yaw, pitch, parallel, margin)
        self.centre = self.camera.centre
        self.parallel_scale = self.camera.parallel_scale
        self.parallel = self.camera.parallel
        model = np.eye(4)
        model[:3, :3] = self.rotation
        self._mvp = self.camera.projection_matrix() @ self.camera.view_matrix() @ model
        # draw upside down so that rows come back from GL top first (no flip on the CPU); the
        # mirror turns the winding around, so front faces are clockwise on screen
        self._mvp = np.diag([1.0, -1.0, 1.0, 1.0]) @ self._mvp

        self._resources = []
        self.ctx = ctx = gl_context()
        self._program = _program(ctx, self.textured)
        n = len(self._source)
        self._positions = self._keep(ctx.buffer(reserve=n * 12, dynamic=True))
        self._normal_buffer = self._keep(ctx.buffer(reserve=n * 12, dynamic=True))
        content = [(self._positions, "3f", "in_position"), (self._normal_buffer, "3f", "in_normal")]
        self._texture = None
        if self.textured:
            content.append((self._keep(ctx.buffer(np.ascontiguousarray(uv, dtype=np.float32))), "2f", "in_uv"))
            image = np.ascontiguousarray(np.asarray(mesh.texture)[::-1, :, :3], dtype=np.uint8)  # v up
            self._texture = self._keep(ctx.texture((image.shape[1], image.shape[0]), 3, image.tobytes(),
                                                   alignment=1))
            if max(image.shape[:2]) > 2 * max(self.size):  # shrunk on screen: mipmaps against aliasing
                self._texture.build_mipmaps()
                self._texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
            else:  # about one texel a pixel or larger: bilinear is enough, and cheaper in llvmpipe
                self._texture.filter = (moderngl.LINEAR, moderngl.LINEAR)
            self._texture.repeat_x = self._texture.repeat_y = False
        index = self._keep(ctx.buffer(np.ascontiguousarray(faces, dtype=np.uint32)))
        self._vao = self._keep(ctx.vertex_array(self._program, content, index_buffer=index, index_element_size=4))

        samples = min(SAMPLES, ctx.max_samples)
        self._fbo = self._keep(ctx.framebuffer(
            color_attachments=[self._keep(ctx.renderbuffer(self.size, 4, samples=samples))],
            depth_attachment=self._keep(ctx.depth_renderbuffer(self.size, samples=samples))))
        self._resolved = self._fbo
        if samples > 1:
            self._resolved = self._keep(ctx.framebuffer(
                color_attachments=[self._keep(ctx.renderbuffer(self.size, 4))]))
        self._upload(mesh.vertices)

    def _keep(self, resource):
        self._resources.append(resource)
        return resource

    def _view(self, vertices: np.ndarray) -> np.ndarray:
        return np.asarray(vertices, dtype=np.float64) @ self.rotation.T

    def _upload(self, vertices: np.ndarray) -> None:
        v = np.asarray(vertices, dtype=np.float32)
        if v.shape != (self.mesh.n_vertices, 3):
            raise FaceAnimError(f"expected vertices of shape ({self.mesh.n_vertices}, 3) to render, got {v.shape}")
        normals = self._normals(v, normalise=False)  # unit length in the shader
        if not self._identity:
            v = np.take(v, self._source, axis=0)
        self._positions.write(np.ascontiguousarray(v))
        self._normal_buffer.write(normals)

    def _set_uniforms(self) -> None:
        prog, cam = self._program, self.camera
        prog["mvp"].write(self._mvp.T.astype(np.float32).tobytes())  # GL matrices are column-major
        prog["model"].write(self.rotation.T.astype(np.float32).tobytes())
        dirs = [np.asarray(d, dtype=np.float64) / np.linalg.norm(d) for d, _ in LIGHTS] + [cam.direction]
        prog["light_dir"].write(np.asarray(dirs, dtype=np.float32).tobytes())
        prog["light_power"].write(np.array([p for _, p in LIGHTS] + [HEADLIGHT], dtype=np.float32).tobytes())
        prog["eye"].value = tuple(cam.eye)
        prog["view_dir"].value = tuple(cam.direction)
        prog["parallel"].value = cam.parallel
        prog["back_colour"].value = BACK_FACE
        for name, value in (("ambient", AMBIENT), ("diffuse", DIFFUSE), ("specular", SPECULAR),
                            ("shininess", SHININESS)):
            prog[name].value = value
        if self.textured:
            prog["tex"].value = 0
        else:
            prog["albedo"].value = SKIN

    def render(self, vertices: np.ndarray | None = None) -> np.ndarray:
        """(H, W, 3) uint8 image of the mesh, optionally with other vertex positions (which
        stay for later calls without ``vertices``)."""
        import moderngl

        if self._vao is None:
            raise FaceAnimError("this renderer is closed")
        if vertices is not None:
            self._upload(vertices)
        ctx = self.ctx
        self._fbo.use()
        ctx.enable_only(moderngl.DEPTH_TEST)
        ctx.front_face = "cw"
        self._fbo.clear(*self.background, 1.0, depth=1.0)
        self._set_uniforms()
        if self._texture is not None:
            self._texture.use(0)
        self._vao.render(moderngl.TRIANGLES)
        if self._resolved is not self._fbo:
            ctx.copy_framebuffer(self._resolved, self._fbo)
        w, h = self.size
        image = np.empty((h, w, 3), dtype=np.uint8)
        self._resolved.read_into(image, components=3, alignment=1)
        return image

    def pixel_rays(self, xy_normalised: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rays (origins, directions) in mesh coordinates through normalised image points.

        Only for the parallel front view: ``x`` right and ``y`` down in [0, 1] as MediaPipe
        reports them.
        """
        if not self.parallel:
            raise FaceAnimError("pixel rays are defined for the parallel (orthographic) view only")
        w, h = self.size
        height = 2.0 * self.parallel_scale
        width = height * w / h
        xy = np.asarray(xy_normalised, dtype=np.float64)
        x = self.centre[0] + (xy[:, 0] - 0.5) * width
        y = self.centre[1] + (0.5 - xy[:, 1]) * height
        z = np.full_like(x, self.centre[2] + 10.0 * max(self.parallel_scale, 1.0))
        origins_view = np.stack([x, y, z], axis=1)
        d_view = np.array([0.0, 0.0, -1.0])
        return origins_view @ self.rotation, np.tile(d_view @ self.rotation, (len(x), 1))

    def project(self, points: np.ndarray) -> np.ndarray:
        """Normalised image coordinates (x right, y down) of mesh-space points, parallel view."""
        if not self.parallel:
            raise FaceAnimError("projection is defined for the parallel (orthographic) view only")
        v = self._view(np.atleast_2d(points))
        height = 2.0 * self.parallel_scale
        width = height * self.size[0] / self.size[1]
        return np.stack([(v[:, 0] - self.centre[0]) / width + 0.5, 0.5 - (v[:, 1] - self.centre[1]) / height], 1)

    def close(self) -> None:
        """Free the GL buffers, texture and framebuffers (the shared context stays)."""
        for resource in reversed(self._resources):
            resource.release()
        self._resources = []
        self._vao = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __del__(self):
        try:
            if self._resources and _state.get("pid") == os.getpid():
                self.close()
        except Exception:
            pass
