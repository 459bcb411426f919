"""Offscreen OpenGL rendering with moderngl on a headless EGL context.

Without a GPU, Mesa's llvmpipe rasterises on the CPU. The mesh is uploaded once (UVs, texture,
the triangle index buffer); each frame sends only float32 vertex positions and normals, draws
into a framebuffer with a depth buffer and reads RGB back with one call. One GL context serves
every renderer of a process (making an EGL context is slow).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
import os
import threading

import numpy as np

from faceanim.errors import FaceAnimError
from faceanim.face.mesh import Mesh
from faceanim.limits import check_size
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
# Multisample anti-aliasing: 4x MSAA costs llvmpipe about three times the frame time (23 ms
# against 8 ms at 512 x 512, benchmarks/bench_render.py), so it is off; set 4 here to have it.
SAMPLES = 0
CHUNKS, MIN_CHUNK = 4, 8000  # draw calls per frame, fewest triangles in one (see _setup_gl)

# Lighting is computed per vertex (Gouraud): at 30k vertices a triangle covers a few pixels,
# so this looks the same as per-pixel lighting, and work per pixel is what a CPU rasteriser
# pays for.
# Both sides are lit in the vertex shader; the fragment shader picks the side it sees. Three
# variants: TEXTURED samples the texture per pixel; VERTEX_COLOUR takes per-vertex colours
# sampled from the texture once (when the mesh has more vertices than the texture has texels,
# e.g. the default face: nothing is lost and llvmpipe skips a texture fetch per pixel);
# neither: one albedo (SKIN).
_VERTEX_SHADER = """
uniform mat4 mvp;
uniform mat3 model;            // mesh -> view coordinates (a rotation)
uniform vec3 light_dir[3];     // unit vectors towards the lights (view coordinates)
uniform float light_power[3];
uniform vec3 eye;
uniform vec3 view_dir;         // from the centre to the eye (parallel projection)
uniform bool parallel;
uniform float ambient;
uniform float diffuse;
uniform float specular;
uniform float shininess;
in vec3 in_position;
in vec3 in_normal;
#if defined(TEXTURED)
in vec2 in_uv;
out vec2 v_uv;
out vec3 v_light;              // front diffuse + ambient, front specular, back diffuse + ambient
#else
#if defined(VERTEX_COLOUR)
in vec3 in_colour;
#else
uniform vec3 albedo;
#endif
out vec4 v_colour;             // lit front colour, back diffuse + ambient
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
#if defined(TEXTURED)
    v_uv = in_uv;
    v_light = vec3(ambient + diffuse * front, specular * spec, ambient + diffuse * back);
#else
#if defined(VERTEX_COLOUR)
    vec3 base = in_colour;
#else
    vec3 base = albedo;
#endif
    v_colour = vec4(base * (ambient + diffuse * front) + vec3(specular * spec), ambient + diffuse * back);
#endif
    gl_Position = mvp * vec4(in_position, 1.0);
}
"""

_FRAGMENT_SHADER = """
uniform vec3 back_colour;      // the inside, lit on its own side, dark and matt
#if defined(TEXTURED)
uniform sampler2D tex;
in vec2 v_uv;
in vec3 v_light;
#else
in vec4 v_colour;
#endif
out vec3 f_colour;
void main() {
#if defined(TEXTURED)
    f_colour = gl_FrontFacing ? texture(tex, v_uv).rgb * v_light.x + vec3(v_light.y) : back_colour * v_light.z;
#else
    f_colour = gl_FrontFacing ? v_colour.rgb : back_colour * v_colour.a;
#endif
}
"""

_lock = threading.Lock()
_gl_lock = threading.RLock()  # one thread at a time in the shared context (renderers may live in several)
_state: dict = {}
_tokens = itertools.count()


def _keep_heap_mapped() -> None:
    """Stop glibc from handing the heap back to the kernel after every frame.

    llvmpipe allocates and frees megabytes of vertex and bin memory per draw; with glibc's
    default thresholds the freed top of the heap is trimmed and the next frame faults the
    pages back in, which took about a quarter of the CPU time of a frame (perf: brk and page
    faults). Up to 128 MiB of freed heap now stays mapped, and blocks under 32 MiB come from the
    heap instead of fresh mmaps. A process-wide setting, made once, with the first GL context.
    """
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-3, 32 << 20)  # M_MMAP_THRESHOLD (the largest glibc takes)
        libc.mallopt(-1, 128 << 20)  # M_TRIM_THRESHOLD
    except (OSError, AttributeError):  # not glibc: leave the allocator alone
        pass


def gl_context():
    """The process's moderngl context (headless EGL), made on first use and reused."""
    with _lock:
        ctx = _state.get("ctx")
        if ctx is not None and _state.get("pid") == os.getpid() and not _alive(ctx):
            ctx = None  # e.g. another library terminated the shared EGL display (VTK does on close)
        if ctx is None or _state.get("pid") != os.getpid():  # a forked child needs its own
            try:
                import moderngl
            except ImportError:
                raise FaceAnimError("rendering needs moderngl (pip install moderngl)") from None
            _keep_heap_mapped()
            try:
                ctx = moderngl.create_standalone_context(require=330, backend="egl")
            except Exception as exc:
                raise FaceAnimError(
                    f"could not make an offscreen OpenGL context with EGL ({exc}); on Debian/Ubuntu "
                    "install libegl1 libegl-mesa0 libgl1-mesa-dri (Mesa's software renderer)") from None
            _state.clear()
            _state.update(ctx=ctx, pid=os.getpid(), programs={}, owners={}, flush=_gl_flush())
        return ctx


_DEFINES = {"texture": "#define TEXTURED\n", "vertex colours": "#define VERTEX_COLOUR\n", "albedo": ""}


def _gl_flush():
    """glFlush of the current context (moderngl has only glFinish), or None."""
    try:
        import ctypes

        egl = ctypes.CDLL("libEGL.so.1")
        egl.eglGetProcAddress.restype = ctypes.c_void_p
        egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
        address = egl.eglGetProcAddress(b"glFlush")
        return ctypes.CFUNCTYPE(None)(address) if address else None
    except (OSError, AttributeError):
        return None


def _alive(ctx) -> bool:
    try:
        with _gl_lock, ctx:
            ctx.buffer(reserve=4).release()
        return True
    except Exception:
        return False


def _program(ctx, shading: str):
    programs = _state["programs"]
    if shading not in programs:
        head = "#version 330\n" + _DEFINES[shading]
        programs[shading] = ctx.program(vertex_shader=head + _VERTEX_SHADER,
                                         fragment_shader=head + _FRAGMENT_SHADER)
    return programs[shading]


def sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(N, 3) float32 colours in [0, 1] of ``texture`` (row 0 at the top) at ``uv`` (v up),
    bilinear with clamped edges, as OpenGL samples it."""
    img = np.asarray(texture)[..., :3].astype(np.float32) / 255.0
    h, w = img.shape[:2]
    x = np.clip(np.asarray(uv[:, 0], dtype=np.float64) * w - 0.5, 0, w - 1)
    y = np.clip((1.0 - np.asarray(uv[:, 1], dtype=np.float64)) * h - 0.5, 0, h - 1)
    x0 = np.minimum(x.astype(np.int64), w - 2 if w > 1 else 0)
    y0 = np.minimum(y.astype(np.int64), h - 2 if h > 1 else 0)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bottom = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return np.ascontiguousarray(top * (1 - fy) + bottom * fy, dtype=np.float32)


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
        self.mesh = mesh
        self.size = (check_size(size[0], "image width"), check_size(size[1], "image height"))
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
        if not self.textured:
            self.shading = "albedo"
        elif len(self._source) >= mesh.texture.shape[0] * mesh.texture.shape[1]:
            self.shading = "vertex colours"  # the texture holds no detail between the vertices
        else:
            self.shading = "texture"

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
        self._vao = None
        self.ctx = ctx = gl_context()
        with _gl_lock, ctx:
            self._setup_gl(ctx, faces, uv)

    def _setup_gl(self, ctx, faces: np.ndarray, uv: np.ndarray | None) -> None:
        import moderngl

        mesh = self.mesh
        self._program = _program(ctx, self.shading)
        self._token = next(_tokens)
        self._uniforms = self._uniform_values()
        n = len(self._source)
        self._positions = self._keep(ctx.buffer(reserve=n * 12, dynamic=True))
        self._normal_buffer = self._keep(ctx.buffer(reserve=n * 12, dynamic=True))
        content = [(self._positions, "3f", "in_position"), (self._normal_buffer, "3f", "in_normal")]
        self._texture = None
        if self.shading == "vertex colours":
            colours = sample_texture(mesh.texture, uv)
            content.append((self._keep(ctx.buffer(colours)), "3f", "in_colour"))
        elif self.shading == "texture":
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
        # Draw in a few chunks with a glFlush after each but the last: llvmpipe's rasteriser
        # threads start on a flushed chunk while this thread shades and sets up the next one's
        # vertices and triangles (about a quarter off the frame time at 512 x 512, 30k vertices).
        per_chunk = -(-len(faces) // max(1, min(CHUNKS, len(faces) // MIN_CHUNK)))
        self._chunks = [(3 * first, 3 * min(per_chunk, len(faces) - first))
                        for first in range(0, len(faces), per_chunk)]
        self._vao = self._keep(ctx.vertex_array(self._program, content, index_buffer=index, index_element_size=4))

        self._fbo, self._resolved = self._framebuffers(ctx)
        self._fbo2 = self._resolved2 = None  # the second pair, made when frames are pipelined
        self.cull_backs = False  # back faces drawn (dark): see cull_unseen_backs
        self._upload(mesh.vertices)

    def _framebuffers(self, ctx) -> tuple:
        """A framebuffer to draw into (multisampled if :data:`SAMPLES`) and the one read back."""
        samples = min(SAMPLES, ctx.max_samples)
        fbo = self._keep(ctx.framebuffer(
            color_attachments=[self._keep(ctx.renderbuffer(self.size, 4, samples=samples))],
            depth_attachment=self._keep(ctx.depth_renderbuffer(self.size, samples=samples))))
        resolved = fbo
        if samples > 1:
            resolved = self._keep(ctx.framebuffer(color_attachments=[self._keep(ctx.renderbuffer(self.size, 4))]))
        return fbo, resolved

    def _keep(self, resource):
        self._resources.append(resource)
        return resource

    def _view(self, vertices: np.ndarray) -> np.ndarray:
        return np.asarray(vertices, dtype=np.float64) @ self.rotation.T

    def _prepare(self, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The positions and normals to upload for ``vertices`` (no GL: may run in another thread)."""
        v = np.asarray(vertices, dtype=np.float32)
        if v.shape != (self.mesh.n_vertices, 3):
            raise FaceAnimError(f"expected vertices of shape ({self.mesh.n_vertices}, 3) to render, got {v.shape}")
        normals = self._normals(v, normalise=False)  # unit length in the shader
        if not self._identity:
            v = np.take(v, self._source, axis=0)
        return np.ascontiguousarray(v), normals

    def _upload(self, vertices) -> None:
        """Upload ``vertices`` (V, 3), or what :meth:`_prepare` made of them (a pair)."""
        positions, normals = vertices if isinstance(vertices, tuple) else self._prepare(vertices)
        self._positions.write(positions)
        self._normal_buffer.write(normals)

    def _uniform_values(self) -> list:
        """(uniform, bytes) pairs of this renderer's camera, lights and material."""
        cam = self.camera
        f32 = lambda *values: np.asarray(values, dtype=np.float32).tobytes()  # noqa: E731
        dirs = [np.asarray(d, dtype=np.float64) / np.linalg.norm(d) for d, _ in LIGHTS] + [cam.direction]
        values = {
            "mvp": self._mvp.T.astype(np.float32).tobytes(),  # GL matrices are column-major
            "model": self.rotation.T.astype(np.float32).tobytes(),
            "light_dir": np.asarray(dirs, dtype=np.float32).tobytes(),
            "light_power": f32(*[p for _, p in LIGHTS], HEADLIGHT),
            "eye": f32(*cam.eye), "view_dir": f32(*cam.direction),
            "parallel": np.int32(cam.parallel).tobytes(),
            "albedo": f32(*SKIN), "back_colour": f32(*BACK_FACE),
            "ambient": f32(AMBIENT), "diffuse": f32(DIFFUSE), "specular": f32(SPECULAR),
            "shininess": f32(SHININESS), "tex": np.int32(0).tobytes(),
        }
        prog = self._program
        return [(prog[name], data) for name, data in values.items() if name in prog]

    def _set_uniforms(self) -> None:
        """Load this renderer's uniforms into the shared program unless they are still there."""
        owners = _state["owners"]
        if owners.get(self.shading) != self._token:
            for uniform, data in self._uniforms:
                uniform.write(data)
            owners[self.shading] = self._token

    def render(self, vertices: np.ndarray | None = None) -> np.ndarray:
        """(H, W, 3) uint8 image of the mesh, optionally with other vertex positions (which
        stay for later calls without ``vertices``)."""
        self._draw(vertices, self._fbo)
        return self._read(self._fbo, self._resolved)

    def cull_unseen_backs(self, vertices: np.ndarray | None = None) -> bool:
        """Skip back faces from now on (llvmpipe then sets up a third fewer triangles: about 4 ms
        of a 15 ms frame at 512 x 512) if none shows: if the mesh (at ``vertices``) renders the same
        with and without them. A mesh turned inside out, or open towards the camera, shows its
        back faces (dark) and keeps them. Returns whether they are culled."""
        self.cull_backs = False
        shown = self.render(vertices)
        self.cull_backs = True
        if not np.array_equal(self.render(), shown):
            self.cull_backs = False
        return self.cull_backs

    def render_frames(self, vertex_frames) -> Iterator[np.ndarray]:
        """The image of each (V, 3) vertex array of ``vertex_frames`` in turn, as :meth:`render`
        makes it, pipelined: frame k+1 is evaluated, uploaded and drawn (its vertices shaded and
        its triangles binned in this thread) while llvmpipe's threads still rasterise frame k,
        which is read back only then (two framebuffers in turn). (Evaluating frames ahead in a
        thread of their own was measured too: no faster on 2 cores, where llvmpipe's threads and
        x264 already take both.)"""
        if self._fbo2 is None:
            with _gl_lock, self.ctx:
                self._fbo2, self._resolved2 = self._framebuffers(self.ctx)
        targets = ((self._fbo, self._resolved), (self._fbo2, self._resolved2))
        pending = None
        for k, vertices in enumerate(vertex_frames):
            target = targets[k % 2]
            self._draw(vertices, target[0])
            if pending is not None:
                yield self._read(*pending)
            pending = target
        if pending is not None:
            yield self._read(*pending)

    def _draw(self, vertices, fbo) -> None:
        import moderngl

        if self._vao is None:
            raise FaceAnimError("this renderer is closed")
        ctx = self.ctx
        with _gl_lock, ctx:  # current on this thread even if another library made its own current
            if vertices is not None:
                self._upload(vertices)
            fbo.use()
            ctx.enable_only(moderngl.DEPTH_TEST | moderngl.CULL_FACE if self.cull_backs else moderngl.DEPTH_TEST)
            ctx.front_face = "cw"
            ctx.cull_face = "back"
            fbo.clear(*self.background, 1.0, depth=1.0)
            self._set_uniforms()
            if self._texture is not None:
                self._texture.use(0)
            flush = _state.get("flush")
            for k, (first, count) in enumerate(self._chunks):
                self._vao.render(moderngl.TRIANGLES, vertices=count, first=first)
                if flush is not None:  # the last chunk too: its frame rasterises while the next is drawn
                    flush()

    def _read(self, fbo, resolved) -> np.ndarray:
        w, h = self.size
        image = np.empty((h, w, 3), dtype=np.uint8)
        with _gl_lock, self.ctx:
            if resolved is not fbo:
                self.ctx.copy_framebuffer(resolved, fbo)
            resolved.read_into(image, components=3, alignment=1)
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
        """Normalised image coordinates (x right, y down) of mesh-space points, parallel view (any
        yaw and pitch)."""
        if not self.parallel:
            raise FaceAnimError("projection is defined for the parallel (orthographic) view only")
        v = self._view(np.atleast_2d(points))
        eye = v @ self.camera.view_matrix()[:3, :3].T + self.camera.view_matrix()[:3, 3]  # any yaw, pitch
        height = 2.0 * self.parallel_scale
        width = height * self.size[0] / self.size[1]
        return np.stack([eye[:, 0] / width + 0.5, 0.5 - eye[:, 1] / height], 1)

    def close(self) -> None:
        """Free the GL buffers, texture and framebuffers (the shared context stays)."""
        if self._resources:
            with _gl_lock, self.ctx:
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
