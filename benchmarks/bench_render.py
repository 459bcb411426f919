"""Offscreen rendering speed: moderngl (EGL, Mesa llvmpipe) against the VTK/pyvista renderer it
replaced, on the textured default head (24,591 vertices, 1024 x 1024 texture), in the same run.

    .venv/bin/python benchmarks/bench_render.py [--frames 60] [--no-vtk]

Per size: the cold frame (renderer made, mesh uploaded, first image; the very first one also
makes the GL context and compiles the shaders), and warm frames (a new deformation every frame:
positions, normals, draw, read back) as the median wall time and the CPU time of the whole
process per frame (Mesa's rasteriser threads included; steadier than wall time on a shared
machine). Then the per-frame normals (sparse product against ``np.add.at``), 4x MSAA, and
150 frames at 512 x 512 rendered and encoded to H.264 MP4 (ffmpeg encodes in its own process
while the next frames render) against the 6 s they last at 25 fps. The VTK rows need pyvista
(kept in the venv for this benchmark only; faceanim does not depend on it).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from faceanim.face.default import default_face
from faceanim.face.mesh import vertex_normals
from faceanim.render import OffscreenRenderer, VertexNormals, write_video

SIZES = (256, 512, 1024)
VIDEO_FRAMES, FPS = 150, 25.0  # faceanim's default frame rate


def deformations(mesh, count: int):
    """Smooth, different vertex positions per frame (a jaw-like drop and a cheek bulge)."""
    v = mesh.vertices
    lo, hi = v.min(0), v.max(0)
    t = (v - lo) / (hi - lo)
    jaw = np.clip(0.45 - t[:, 1], 0, None)[:, None] * np.array([0.0, -0.12, 0.02]) * (hi - lo)
    bulge = np.exp(-((t[:, 0] - 0.5) ** 2) * 8)[:, None] * np.array([0.0, 0.0, 0.03]) * (hi - lo)
    for k in range(count):
        s = np.sin(2 * np.pi * k / 30)
        yield v + s * jaw + (1 - s) * 0.5 * bulge


class VtkRenderer:
    """The VTK/pyvista renderer faceanim used before (src/faceanim/render.py until this change),
    kept here as the baseline: same camera, lights and material."""

    def __init__(self, mesh, size=(512, 512), yaw=0.0, pitch=0.0, margin=1.08):
        os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
        import pyvista as pv
        import vtk

        vtk.vtkObject.GlobalWarningDisplayOff()
        pv.OFF_SCREEN = True
        self._source, faces, uv = mesh.per_vertex_uv()
        self._faces = faces
        pts = mesh.vertices[self._source]
        self.poly = pv.PolyData(pts, np.hstack([np.full((len(faces), 1), 3), faces]).ravel())
        self.poly.active_texture_coordinates = uv.astype(np.float32)
        self._set_normals(pts)
        self.plotter = pv.Plotter(off_screen=True, window_size=list(size))
        self.plotter.set_background((0.16, 0.17, 0.2))
        kwargs = dict(smooth_shading=False, specular=0.15, specular_power=12, ambient=0.12, diffuse=0.9)
        actor = self.plotter.add_mesh(self.poly, texture=pv.Texture(np.ascontiguousarray(mesh.texture[..., :3])),
                                      **kwargs)
        back = actor.GetProperty().NewInstance()
        back.DeepCopy(actor.GetProperty())
        back.SetColor(0.05, 0.04, 0.04)
        back.SetSpecular(0.0)
        actor.SetBackfaceProperty(back)
        lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
        c, half = (lo + hi) / 2, (hi - lo) / 2 * margin
        s = float(max(half[1], half[0] * size[1] / size[0]))
        dist = 4.0 * s / np.tan(np.radians(15.0))
        y, p = np.radians(yaw), np.radians(pitch)
        cam = self.plotter.camera
        cam.focal_point = tuple(c)
        cam.position = tuple(c + dist * np.array([np.sin(y) * np.cos(p), np.sin(p), np.cos(y) * np.cos(p)]))
        cam.up = (0.0, 1.0, 0.0)
        cam.view_angle = 2 * np.degrees(np.arctan(s / dist))
        cam.clipping_range = (dist - 4 * np.linalg.norm(half), dist + 4 * np.linalg.norm(half))
        self.plotter.remove_all_lights()
        for light in (pv.Light(position=tuple(c + s * np.array([1.5, 2.0, 4.0])), focal_point=tuple(c),
                               intensity=0.75, light_type="scene light"),
                      pv.Light(position=tuple(c + s * np.array([-2.5, 0.5, 3.0])), focal_point=tuple(c),
                               intensity=0.35, light_type="scene light"),
                      pv.Light(light_type="headlight", intensity=0.25)):
            self.plotter.add_light(light)

    def _set_normals(self, pts):
        self.poly.point_data["Normals"] = vertex_normals(pts, self._faces)
        self.poly.point_data.active_normals_name = "Normals"

    def render(self, vertices=None):
        if vertices is not None:
            pts = vertices[self._source]
            self.poly.points = pts
            self._set_normals(pts)
        self.plotter.render()
        return np.ascontiguousarray(self.plotter.screenshot(return_img=True)[..., :3])

    def close(self):
        self.plotter.close()


def time_renderer(make, mesh, size: int, frames: int) -> dict:
    poses = list(deformations(mesh, 8))
    t = time.perf_counter()
    r = make(mesh, (size, size))
    r.render()
    cold = time.perf_counter() - t
    for k in range(3):
        r.render(poses[k])
    walls = []
    cpu = time.process_time()
    for k in range(frames):
        t = time.perf_counter()
        r.render(poses[k % len(poses)])
        walls.append(time.perf_counter() - t)
    cpu = (time.process_time() - cpu) / frames
    r.close()
    return {"cold": cold * 1000, "warm": float(np.median(walls)) * 1000, "best": min(walls) * 1000,
            "cpu": cpu * 1000}


def time_video(make, mesh) -> tuple[float, float]:
    """Seconds to render and encode VIDEO_FRAMES frames at 512 x 512; the file's size in KiB."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.mp4"
        t = time.perf_counter()
        r = make(mesh, (512, 512))
        try:
            write_video(path, (r.render(v) for v in deformations(mesh, VIDEO_FRAMES)), fps=FPS)
        finally:
            r.close()
        return time.perf_counter() - t, path.stat().st_size / 1024


def gl(mesh, size):
    return OffscreenRenderer(mesh, size=size, yaw=15.0, pitch=4.0)


def vtk(mesh, size):
    return VtkRenderer(mesh, size=size, yaw=15.0, pitch=4.0)


def best_of(fn, repeat):
    fn()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times) * 1000


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60, help="warm frames timed per size (default 60)")
    ap.add_argument("--no-vtk", action="store_true", help="skip the VTK/pyvista baseline")
    args = ap.parse_args()

    mesh = default_face()
    have_vtk = False
    if not args.no_vtk:
        try:
            import pyvista  # noqa: F401

            have_vtk = True
        except ImportError:
            print("(pyvista not importable: no VTK baseline)\n")
    load = os.getloadavg()[0]
    print(f"default face: {mesh.n_vertices} vertices, {mesh.n_faces} triangles, texture "
          f"{mesh.texture.shape[1]}x{mesh.texture.shape[0]}; {os.cpu_count()} cores, load average {load:.1f} "
          "(other work on the machine inflates wall times; CPU ms are steadier)\n")

    rows = []
    for name, make in (("moderngl", gl), ("VTK", vtk)):
        if name == "VTK" and not have_vtk:
            continue
        for size in SIZES:
            rows.append((name, size, time_renderer(make, mesh, size, args.frames)))
    print("| renderer | size | cold frame | warm frame (median) | warm (best) | CPU per frame |")
    print("|---|---|---|---|---|---|")
    for name, size, t in rows:
        print(f"| {name} | {size}x{size} | {t['cold']:.0f} ms | {t['warm']:.1f} ms | {t['best']:.1f} ms | "
              f"{t['cpu']:.1f} ms |")
    if have_vtk:
        for size in SIZES:
            g = next(t for n, s, t in rows if n == "moderngl" and s == size)
            v = next(t for n, s, t in rows if n == "VTK" and s == size)
            print(f"\nspeed-up at {size}: {v['warm'] / g['warm']:.1f}x (median wall), {v['cpu'] / g['cpu']:.1f}x (CPU)",
                  end="")
        print()

    v32 = mesh.vertices.astype(np.float32)
    normals = VertexNormals(mesh.faces, mesh.n_vertices)
    t_sparse = best_of(lambda: normals(v32, normalise=False), 50)
    t_unit = best_of(lambda: normals(v32), 50)
    t_f64 = best_of(lambda: vertex_normals(mesh.vertices, mesh.faces, mesh.face_incidence), 10)

    def add_at(v, f):  # the old way, for reference
        a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
        fn, n = np.cross(b - a, c - a), np.zeros_like(v)
        for i in range(3):
            np.add.at(n, f[:, i], fn)
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    t_add_at = best_of(lambda: add_at(mesh.vertices, mesh.faces), 10)
    print("\n| normals per frame | time |")
    print("|---|---|")
    print(f"| sparse incidence product, float32 (as rendered, unit length in the shader) | {t_sparse:.2f} ms |")
    print(f"| same, normalised | {t_unit:.2f} ms |")
    print(f"| faceanim.face.mesh.vertex_normals, float64 (files: glTF) | {t_f64:.2f} ms |")
    print(f"| baseline: np.add.at, float64 (the code before) | {t_add_at:.2f} ms |")

    import faceanim.render.gl as glmod

    samples = glmod.SAMPLES
    glmod.SAMPLES = 4
    try:
        ms = time_renderer(gl, mesh, 512, args.frames)
    finally:
        glmod.SAMPLES = samples
    base = next(t for n, s, t in rows if n == "moderngl" and s == 512)
    print(f"\n4x MSAA at 512x512: {ms['warm']:.1f} ms a frame (CPU {ms['cpu']:.1f} ms), "
          f"against {base['warm']:.1f} ms (CPU {base['cpu']:.1f} ms) without; off by default")

    from faceanim.render import video

    real = VIDEO_FRAMES / FPS
    print(f"\n| MP4, {VIDEO_FRAMES} frames 512x512 (H.264 crf {video.CRF}, {video.PRESET}, "
          f"{video.ENCODER_THREADS} encoder threads) | time | vs real time ({real:.0f} s) | size |")
    print("|---|---|---|---|")
    for name, make in (("moderngl", gl), ("VTK", vtk)):
        if name == "VTK" and not have_vtk:
            continue
        seconds, kib = time_video(make, mesh)
        print(f"| {name}: render + encode | {seconds:.2f} s ({seconds / VIDEO_FRAMES * 1000:.1f} ms/frame) | "
              f"{real / seconds:.1f}x faster | {kib:.0f} KiB |")


if __name__ == "__main__":
    main()
