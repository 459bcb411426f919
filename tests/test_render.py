"""Offscreen rendering against independent oracles: the analytic projection of squares and
spheres (silhouettes within a pixel), depth order, back faces, texture orientation, the side a
yaw turns to, the photo behind the default face's texture, and the MP4 container."""

import subprocess
import wave

import numpy as np
import pytest
from PIL import Image

from faceanim.errors import FaceAnimError
from faceanim.face.mesh import Mesh, vertex_normals
from faceanim.render import (
    BACKGROUND,
    OffscreenRenderer,
    VertexNormals,
    gl_context,
    write_video,
)

BG = np.round(np.asarray(BACKGROUND) * 255)
FRAME = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])  # framing box: parallel_scale 1 with margin 1
RED, GREEN, BLUE, WHITE = (230, 20, 20), (20, 230, 20), (20, 20, 230), (230, 230, 230)


def quad(x0, x1, y0, y1, z=0.0, facing=+1):
    """Two triangles in the plane z, front side towards +z (or -z with facing=-1)."""
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], dtype=float)
    f = np.array([[0, 1, 2], [0, 2, 3]]) if facing > 0 else np.array([[0, 2, 1], [0, 3, 2]])
    return v, f


def uv_quad(x0, x1, y0, y1, z=0.0, u=(0.0, 1.0), w=(0.0, 1.0)):
    v, f = quad(x0, x1, y0, y1, z)
    uv = np.array([[u[0], w[0]], [u[1], w[0]], [u[1], w[1]], [u[0], w[1]]])
    return v, f, uv


def quadrants(n=64):
    """Texture image (row 0 at the top): red top-left, blue top-right, green bottom-left, white
    bottom-right."""
    t = np.zeros((n, n, 3), dtype=np.uint8)
    h = n // 2
    t[:h, :h], t[:h, h:], t[h:, :h], t[h:, h:] = RED, BLUE, GREEN, WHITE
    return t


def sphere(radius, subdivisions=5):
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return Mesh(np.asarray(s.vertices), np.asarray(s.faces))


def silhouette(img):
    return np.abs(img.astype(float) - BG).max(-1) > 8


def pixel_centres(n):
    """Normalised-device coordinates of pixel centres: x right, y up (row 0 at the top)."""
    c = (np.arange(n) + 0.5) / n * 2 - 1
    return c[None, :], -c[:, None]


def colour_of(img, rows, cols):
    return img[rows, cols].reshape(-1, 3).astype(float).mean(0)


# ---------------------------------------------------------------- geometry against the analytic projection
def test_square_silhouette_matches_the_parallel_projection():
    n = 200
    x0, x1, y0, y1 = -0.503, 0.3071, -0.2488, 0.4512  # edges between pixel centres
    v, f = quad(x0, x1, y0, y1)
    with OffscreenRenderer(Mesh(v, f), size=(n, n), parallel=True, frame_vertices=FRAME, margin=1.0) as r:
        assert r.parallel_scale == pytest.approx(1.0)
        mask = silhouette(r.render())
        corner = r.project(v[[0]])[0] * n  # the published projection agrees with the pixels
    x, y = pixel_centres(n)
    expected = (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
    # a pixel may differ only where an edge passes within a pixel of its centre
    pixel = 2.0 / n
    near_edge = ((np.abs(x - x0) < pixel) | (np.abs(x - x1) < pixel)) & (y > y0 - pixel) & (y < y1 + pixel) \
        | ((np.abs(y - y0) < pixel) | (np.abs(y - y1) < pixel)) & (x > x0 - pixel) & (x < x1 + pixel)
    assert not (mask != expected)[~near_edge].any()
    assert (mask != expected).sum() <= 0.1 * near_edge.sum()  # and there by sub-pixel rounding only
    assert corner == pytest.approx([(x0 + 1) / 2 * n, (1 - y0) / 2 * n])


@pytest.mark.parametrize("parallel", [True, False])
def test_sphere_silhouette_is_the_projected_disc(parallel):
    n, radius = 240, 0.6
    with OffscreenRenderer(sphere(radius), size=(n, n), parallel=parallel, frame_vertices=FRAME,
                           margin=1.0, use_texture=False) as r:
        mask = silhouette(r.render())
        scale = r.parallel_scale
    if parallel:
        rim = radius / scale
    else:  # the camera looks at the centre from 4 * scale / tan(15 deg); tangent rays of the sphere
        dist = 4 * scale / np.tan(np.radians(15))
        rim = (dist / scale) * radius / np.sqrt(dist**2 - radius**2)
    x, y = pixel_centres(n)
    r_px = np.hypot(x, y) * n / 2
    rim_px = rim * n / 2
    assert mask[r_px < rim_px - 1].all()  # inside by more than a pixel: covered
    assert not mask[r_px > rim_px + 1].any()  # outside by more than a pixel: background
    assert abs(mask.sum() - np.pi * rim_px**2) < 2 * np.pi * rim_px * 0.5  # area within half a pixel of rim


def test_default_framing_fits_the_mesh_bounds():
    n = 160
    v, f = quad(-0.5, 0.3, -0.25, 0.45)  # 0.8 wide, 0.7 high: the width fills the image
    with OffscreenRenderer(Mesh(v, f), size=(n, n), parallel=True, margin=1.0) as r:
        mask = silhouette(r.render())
        assert r.centre == pytest.approx([-0.1, 0.1, 0.0])
        assert r.parallel_scale == pytest.approx(0.4)
    rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    assert cols[0] <= 1 and cols[-1] >= n - 2
    assert abs(len(rows) - 0.7 / 0.8 * n) <= 2
    with OffscreenRenderer(Mesh(v, f), size=(n, n), parallel=True, margin=2.0) as r:
        mask = silhouette(r.render())
    assert abs(mask.any(0).sum() - n / 2) <= 2


# ---------------------------------------------------------------- shading
@pytest.mark.parametrize("parallel", [True, False])
def test_the_near_triangle_hides_the_far_one(parallel):
    """The near quad comes first in the triangle list: only a depth test keeps it in front."""
    vn, fn, un = uv_quad(-0.3, 0.3, -0.3, 0.3, z=0.3, u=(0.1, 0.2), w=(0.8, 0.9))  # red texels
    vf, ff, uf = uv_quad(-0.8, 0.8, -0.8, 0.8, z=-0.3, u=(0.8, 0.9), w=(0.8, 0.9))  # blue texels
    mesh = Mesh(np.vstack([vn, vf]), np.vstack([fn, ff + 4]), np.vstack([un, uf]), texture=quadrants())
    n = 100
    with OffscreenRenderer(mesh, size=(n, n), parallel=parallel, frame_vertices=FRAME, margin=1.0) as r:
        img = r.render()
    centre = colour_of(img, slice(45, 55), slice(45, 55))
    ring = colour_of(img, slice(18, 24), slice(45, 55))
    assert centre[0] > 3 * centre[2]  # red in front
    assert ring[2] > 3 * ring[0]  # blue around it


def test_back_faces_are_dark_and_front_faces_lit():
    n = 64
    for facing, check in ((+1, lambda c: c.mean() > 120), (-1, lambda c: c.max() < 20)):
        v, f = quad(-0.5, 0.5, -0.5, 0.5, facing=facing)
        with OffscreenRenderer(Mesh(v, f), size=(n, n), parallel=True, frame_vertices=FRAME, margin=1.0,
                               use_texture=False) as r:
            c = colour_of(r.render(), slice(24, 40), slice(24, 40))
        assert check(c), (facing, c)


def uv_grid(k):
    """k x k vertices over [-0.8, 0.8]^2 facing +z, uv 0..1 across."""
    t = np.linspace(0.0, 1.0, k)
    u, w = np.meshgrid(t, t)
    v = np.stack([-0.8 + 1.6 * u.ravel(), -0.8 + 1.6 * w.ravel(), np.zeros(k * k)], 1)
    i = (np.arange(k - 1)[None, :] + k * np.arange(k - 1)[:, None]).ravel()
    f = np.vstack([np.stack([i, i + 1, i + k + 1], 1), np.stack([i, i + k + 1, i + k], 1)])
    return v, f, np.stack([u.ravel(), w.ravel()], 1)


@pytest.mark.parametrize("vertices, shading", [(2, "texture"), (81, "vertex colours")])
def test_texture_is_mapped_the_right_way_round(vertices, shading):
    """UV (0, 0) is the bottom-left of the image; the image's first row is its top. Sampled per
    pixel (a coarse mesh) or per vertex (more vertices than texels) alike."""
    v, f, uv = uv_grid(vertices)
    n = 100
    with OffscreenRenderer(Mesh(v, f, uv, texture=quadrants()), size=(n, n), parallel=True,
                           frame_vertices=FRAME, margin=1.0) as r:
        assert r.shading == shading
        img = r.render()
    got = {name: colour_of(img, rows, cols) for name, rows, cols in (
        ("top-left", slice(20, 40), slice(20, 40)), ("top-right", slice(20, 40), slice(60, 80)),
        ("bottom-left", slice(60, 80), slice(20, 40)), ("bottom-right", slice(60, 80), slice(60, 80)))}
    for name, c in got.items():
        assert c.max() > 120, name
    assert np.argmax(got["top-left"]) == 0 and got["top-left"][0] > 3 * got["top-left"][1:].max()
    assert np.argmax(got["top-right"]) == 2 and got["top-right"][2] > 3 * got["top-right"][:2].max()
    assert np.argmax(got["bottom-left"]) == 1 and got["bottom-left"][1] > 3 * got["bottom-left"][[0, 2]].max()
    assert got["bottom-right"].min() > 0.8 * got["bottom-right"].max()  # white
    # no texture wanted: skin colour, no red or blue quadrants
    with OffscreenRenderer(Mesh(v, f, uv, texture=quadrants()), size=(n, n), parallel=True,
                           frame_vertices=FRAME, margin=1.0, use_texture=False) as r:
        assert r.shading == "albedo"
        img = r.render()
    assert np.ptp(img[20:80, 20:80].reshape(-1, 3).mean(0)) < 80
    assert img[50, 50, 0] > img[50, 50, 1] > img[50, 50, 2]  # SKIN = (0.87, 0.72, 0.62), lit


def test_vertex_colours_are_the_texture_sampled_at_the_vertices():
    """Per-vertex colours (the default face's case) render like the texture itself where it is
    smooth on the scale of the triangles; a texture finer than the mesh keeps per-pixel sampling."""
    k, n = 65, 96
    v, f, uv = uv_grid(k)
    x, y = np.meshgrid(np.linspace(0, 1, 48), np.linspace(0, 1, 48))
    tex = (255 * np.stack([x, 1 - y, 0.5 + 0.5 * np.sin(6 * x * y)], -1)).astype(np.uint8)  # smooth
    images = {}
    for texels in (48, 96):  # 2304 texels < 4225 vertices: vertex colours; 9216 > 4225: per pixel
        t = np.asarray(Image.fromarray(tex).resize((texels, texels), Image.BILINEAR)) if texels != 48 else tex
        with OffscreenRenderer(Mesh(v, f, uv, texture=t), size=(n, n), parallel=True, frame_vertices=FRAME,
                               margin=1.0) as r:
            images[r.shading] = r.render().astype(float)
    assert set(images) == {"vertex colours", "texture"}
    inner = (slice(8, 88), slice(8, 88))
    assert np.abs(images["vertex colours"][inner] - images["texture"][inner]).mean() < 3


def test_yaw_turns_the_camera_towards_plus_x():
    """A sphere red on its +x half and blue on its -x half: +x is on the right of the front view,
    and a positive yaw (from the subject's left, +x) shows mostly red."""
    s = sphere(0.6, subdivisions=4)
    uv = np.where(s.vertices[:, :1] > 0, [[0.75, 0.5]], [[0.25, 0.5]])  # right half red, left half blue
    tex = np.zeros((8, 8, 3), dtype=np.uint8)
    tex[:, :4], tex[:, 4:] = BLUE, RED
    mesh = Mesh(s.vertices, s.faces, uv, texture=tex)
    n = 120

    def redness(img):
        m = silhouette(img)
        return img[..., 0][m].astype(float).mean() - img[..., 2][m].astype(float).mean()

    with OffscreenRenderer(mesh, size=(n, n), frame_vertices=FRAME, margin=1.0) as r:
        img = r.render()
    assert colour_of(img, slice(50, 70), slice(70, 90))[0] > 100  # right of the image: +x, red
    assert colour_of(img, slice(50, 70), slice(30, 50))[2] > 100  # left: -x, blue
    with OffscreenRenderer(mesh, size=(n, n), yaw=60, frame_vertices=FRAME, margin=1.0) as r:
        assert redness(r.render()) > 50
    with OffscreenRenderer(mesh, size=(n, n), yaw=-60, frame_vertices=FRAME, margin=1.0) as r:
        assert redness(r.render()) < -50


def test_pitch_looks_from_above():
    """A positive pitch lifts the camera: the top (+y) cap of the sphere, green, comes forward."""
    s = sphere(0.6, subdivisions=4)
    uv = np.where(s.vertices[:, 1:2] > 0.3, [[0.25, 0.75]], [[0.75, 0.75]])
    tex = np.zeros((8, 8, 3), dtype=np.uint8)
    tex[:, :4], tex[:, 4:] = GREEN, BLUE
    mesh = Mesh(s.vertices, s.faces, uv, texture=tex)

    def green_share(img):
        m = silhouette(img)
        return (img[..., 1][m] > img[..., 2][m]).mean()

    shares = []
    for pitch in (-40, 0, 40):
        with OffscreenRenderer(mesh, size=(96, 96), pitch=pitch, frame_vertices=FRAME, margin=1.0) as r:
            shares.append(green_share(r.render()))
    assert shares[0] < shares[1] < shares[2]


# ---------------------------------------------------------------- the default face
def test_front_render_reproduces_the_photo(face):
    """Oracle: each visible vertex must show the texture colour at its UV where it projects (at
    the UV of each of its triangle corners: the head's atlas has seams, and its texture is meant to
    be continuous across them)."""
    size = 512
    with OffscreenRenderer(face, size=(size, size), parallel=True, margin=1.0) as r:
        img = r.render().astype(float).mean(-1)
        height = 2 * r.parallel_scale
        cx, cy = r.centre[:2]
    v = face.vertices
    front = np.flatnonzero(face.vertex_normals()[:, 2] > 0.7)
    # visible from the front (a ray cast, not the renderer): the head's inner shells (teeth, the mouth
    # cavity) face the camera too but are hidden behind the lips
    hit, pos, _ = face.cast_rays(v[front] + [0.0, 0.0, 1.0], np.tile([0.0, 0.0, -1.0], (len(front), 1)))
    shown = np.zeros(face.n_vertices, dtype=bool)
    shown[front[hit & (np.abs(pos[:, 2] - v[front, 2]) < 1e-4)]] = True
    assert shown.sum() > 3000
    corner = shown[face.faces.ravel()]
    vid, uv = face.faces.ravel()[corner], face.uv[face.face_uv.ravel()[corner]]
    px = ((v[vid, 0] - cx) / height + 0.5) * size
    py = (0.5 - (v[vid, 1] - cy) / height) * size
    rendered = img[py.astype(int).clip(0, size - 1), px.astype(int).clip(0, size - 1)]
    tex = face.texture.astype(float).mean(-1)
    th, tw = tex.shape

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


def test_new_vertices_move_the_render_and_stay(face):
    """render(vertices) draws those positions (and keeps them); the rest pose comes back."""
    shifted = face.vertices + [0.25 * np.ptp(face.vertices[:, 0]), 0.0, 0.0]
    with OffscreenRenderer(face, size=(96, 96), parallel=True, frame_vertices=face.vertices, margin=2.0) as r:
        rest = r.render()
        moved = r.render(shifted)
        assert np.array_equal(r.render(), moved)
        assert np.array_equal(r.render(face.vertices), rest)
        cols_rest = np.flatnonzero(silhouette(rest).any(0))
        cols_moved = np.flatnonzero(silhouette(moved).any(0))
        shift_px = 0.25 * np.ptp(face.vertices[:, 0]) / (2 * r.parallel_scale) * 96
        assert abs((cols_moved.mean() - cols_rest.mean()) - shift_px) < 1
        with pytest.raises(FaceAnimError):
            r.render(face.vertices[:10])


def test_drawing_in_chunks_makes_the_same_picture(face, monkeypatch):
    """The frame is drawn in a few flushed chunks (so llvmpipe rasterises while the next chunk
    is set up); the depth test across chunks gives the picture of one draw."""
    import faceanim.render.gl as gl

    images = []
    for chunks in (1, 4):
        monkeypatch.setattr(gl, "CHUNKS", chunks)
        with OffscreenRenderer(face, size=(160, 160), yaw=40, pitch=10) as r:  # self-occluding view
            assert len(r._chunks) == chunks
            images.append(r.render(face.vertices * [1.0, 1.0, 1.6]))
    assert silhouette(images[0]).mean() > 0.3
    assert np.array_equal(*images)


def test_one_context_shared_and_released(face):
    v, f = quad(-0.5, 0.5, -0.5, 0.5)
    a = OffscreenRenderer(face, size=(64, 64), use_texture=False)
    b = OffscreenRenderer(Mesh(v, f), size=(32, 48), parallel=True)
    assert a.ctx is b.ctx is gl_context()
    first = a.render()
    assert b.render().shape == (48, 32, 3)
    assert np.array_equal(a.render(), first)  # b's state does not leak into a's frame
    b.close()
    assert np.array_equal(a.render(), first)
    a.close()
    with pytest.raises(FaceAnimError):
        a.render()


def test_renderers_work_from_other_threads(face):
    """The shared context is made current on whichever thread renders, one at a time."""
    import threading

    with OffscreenRenderer(face, size=(64, 64), use_texture=False) as r:
        first = r.render()
        results = []
        threads = [threading.Thread(target=lambda: results.append(r.render())) for _ in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    assert len(results) == 4 and all(np.array_equal(img, first) for img in results)


# ---------------------------------------------------------------- normals
def test_vertex_normals_match_the_reference(face, rng):
    ref = vertex_normals(face.vertices, face.faces)
    got = VertexNormals(face.faces, face.n_vertices)(face.vertices)
    assert np.abs(got - ref).max() < 1e-4
    rows = rng.integers(0, face.n_vertices, 500)
    assert np.abs(VertexNormals(face.faces, face.n_vertices, rows=rows)(face.vertices) - ref[rows]).max() < 1e-4
    # a tetrahedron: each corner's normal is the sum of its three faces', pointing out
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    n = VertexNormals(f, 4)(v)
    assert n[0] == pytest.approx(-np.ones(3) / np.sqrt(3), abs=1e-6)
    assert n[3] @ [0, 0, 1] > 0


# ---------------------------------------------------------------- video
def test_video_is_written(tmp_path):
    import imageio_ffmpeg

    frames = (np.full((64, 80, 3), k * 20, dtype=np.uint8) for k in range(10))  # streamed
    path = write_video(tmp_path / "v.mp4", frames, fps=10)
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    assert meta["size"] == (80, 64)
    assert sum(1 for _ in reader) == 10
    data = path.read_bytes()
    assert 0 < data.find(b"moov") < data.find(b"mdat")  # faststart: the index comes first


def test_video_with_sound(tmp_path):
    import imageio_ffmpeg

    rate = 16000
    tone = (0.3 * 32767 * np.sin(2 * np.pi * 440 * np.arange(rate) / rate)).astype("<i2")
    with wave.open(str(tmp_path / "a.wav"), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(rate)
        w.writeframes(tone.tobytes())
    frames = [np.full((32, 32, 3), 100, dtype=np.uint8)] * 25
    path = write_video(tmp_path / "s.mp4", frames, fps=25, audio=tmp_path / "a.wav")
    probe = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(path)],
                           capture_output=True, text=True).stderr
    assert "Video: h264" in probe and "Audio: aac" in probe


def test_failed_video_leaves_no_file(tmp_path):
    with pytest.raises(FaceAnimError):
        write_video(tmp_path / "odd.mp4", [np.zeros((63, 80, 3), dtype=np.uint8)])
    with pytest.raises(FaceAnimError):
        write_video(tmp_path / "sizes.mp4", [np.zeros((64, 80, 3), np.uint8), np.zeros((64, 64, 3), np.uint8)])
    with pytest.raises(FaceAnimError):
        write_video(tmp_path / "none.mp4", [])
    with pytest.raises(FaceAnimError, match="does not exist") as exc:  # checked before ffmpeg starts
        write_video(tmp_path / "mute.mp4", (np.zeros((64, 64, 3), np.uint8) for _ in range(60)),
                    audio=tmp_path / "missing.wav")
    assert "\n" not in str(exc.value)
    secret = tmp_path / "notes.wav"
    secret.write_text("password: hunter2\n" * 50)  # not audio: refused without quoting the file
    with pytest.raises(FaceAnimError) as exc:
        write_video(tmp_path / "mute.mp4", (np.zeros((64, 64, 3), np.uint8) for _ in range(60)), audio=secret)
    assert "hunter2" not in str(exc.value) and "\n" not in str(exc.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.wav"]


def test_ffmpeg_failure_is_one_line_without_its_log(tmp_path, monkeypatch):
    """ffmpeg's own output can quote files it read: the error is ours, one line."""
    import imageio_ffmpeg

    def broken(*args, **kwargs):
        def gen():
            yield
            raise RuntimeError("ffmpeg said: /etc/passwd root:x:0:0\nmore lines")
        return gen()

    monkeypatch.setattr(imageio_ffmpeg, "write_frames", broken)
    with pytest.raises(FaceAnimError) as exc:
        write_video(tmp_path / "x.mp4", (np.zeros((64, 64, 3), np.uint8) for _ in range(5)))
    assert "passwd" not in str(exc.value) and "\n" not in str(exc.value) and "ffmpeg could not" in str(exc.value)
    assert list(tmp_path.iterdir()) == []


def test_pipelined_frames_are_the_frames_rendered_one_by_one(face):
    """render_frames draws frame k+1 before reading frame k back (two framebuffers in turn): the
    pictures, their order and the pose left for render() are those of rendering each in turn."""
    width = np.ptp(face.vertices[:, 0])
    poses = [face.vertices + [dx * width, 0.0, 0.0] for dx in (0.0, 0.1, -0.1, 0.2, 0.05)]
    with OffscreenRenderer(face, size=(96, 96), parallel=True, frame_vertices=face.vertices, margin=2.0) as r:
        one_by_one = [r.render(v) for v in poses]
        piped = list(r.render_frames(iter(poses)))
        assert len(piped) == len(poses) and all(np.array_equal(a, b) for a, b in zip(one_by_one, piped))
        assert len({a.tobytes() for a in piped}) == len(poses)  # the poses differ on screen
        assert np.array_equal(r.render(), one_by_one[-1])
        assert list(r.render_frames(iter([]))) == []


def test_back_faces_are_culled_only_where_none_shows():
    """cull_unseen_backs: a closed sphere shows no back face (culled, the same picture); the same
    sphere turned inside out shows only back faces, dark (kept: the picture must not change)."""
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=3)
    ball = Mesh(np.asarray(s.vertices), np.asarray(s.faces))
    inside_out = Mesh(np.asarray(s.vertices), np.asarray(s.faces)[:, ::-1])
    for mesh, culled in ((ball, True), (inside_out, False)):
        with OffscreenRenderer(mesh, size=(96, 96), yaw=20, pitch=10) as r:
            before = r.render()
            assert r.cull_unseen_backs() is culled and r.cull_backs is culled
            assert np.array_equal(r.render(), before)
            assert np.array_equal(list(r.render_frames(iter([mesh.vertices])))[0], before)
