"""MP4 output speed, end to end, as a user runs it (issue 22: >= 2.5x real time at 512 px for a
2-minute take), and where the frame time goes.

    .venv/bin/python benchmarks/bench_mp4.py [../shared/data]     (about 4 minutes here)

1. The whole command ``faceanim arkit play TAKE.csv -o x.mp4`` (512 x 512, 30 fps) on the
   2-minute Live Link Face recording of the shared data (``arkit-curves/alex_rom_3.csv``, 134 s),
   start-up and set-up included: wall time against the take's duration.
2. In one process, on the first 20 s of it (600 frames): the default face's ARKit rig evaluated,
   rendered and encoded, frame by frame as the writers did before (``render`` then read back, then
   the next frame) against pipelined (``render_frames``: frame k+1 drawn while llvmpipe rasterises
   frame k), with x264's preset ``medium`` (faceanim's) and ``veryfast``; and the bare parts: the
   rig's evaluation, drawing alone and encoding alone.

Wall-clock times on a shared 2-core machine are noisy: compare within a run; nothing is asserted.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

FPS, SIZE = 30.0, 512


def whole_command(take: Path, tmp: Path) -> float:
    out = tmp / "take.mp4"
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "faceanim", "arkit", "play", str(take), "-o", str(out), "--quiet",
                    "--fps", str(FPS), "--size", str(SIZE)], check=True, capture_output=True)
    return time.perf_counter() - t


def main() -> None:
    data = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parents[2] / "shared" / "data")
    take_path = data / "arkit-curves" / "alex_rom_3.csv"
    if not take_path.is_file():
        sys.exit(f"no take at {take_path}: give the shared data folder")
    from faceanim.export import Animation, face_frames
    from faceanim.face.face import Face
    from faceanim.io.arkit_csv import read_arkit_csv
    from faceanim.render import video
    from faceanim.render.gl import OffscreenRenderer
    from faceanim.render.video import write_video

    take = read_arkit_csv(take_path)
    default_preset = video.PRESET
    print(f"cores {os.cpu_count()}; take {take.duration:.1f} s; {SIZE} x {SIZE} at {FPS:g} fps; "
          f"x264 crf {video.CRF}, {video.ENCODER_THREADS} encoder thread(s)\n")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        whole = whole_command(take_path, tmp)
        print("| whole command (arkit play -o x.mp4) | wall | vs real time |\n|---|---:|---:|")
        print(f"| {take.duration:.0f} s take, start-up and set-up included | {whole:.1f} s | "
              f"{take.duration / whole:.2f}x |\n")

        face = Face.load("default")
        r = take.resample(FPS)
        n = int(20 * FPS)
        a = Animation(FPS, arkit=r.weights[:n], head=r.head[:n], face=face)
        frames = list(face_frames(a))  # evaluated once (timed apart below)
        t = time.perf_counter()
        list(face_frames(Animation(FPS, arkit=r.weights[:n], head=r.head[:n], face=face, shapes=a.shapes)))
        evaluate = time.perf_counter() - t
        rows = []
        with OffscreenRenderer(face.mesh, size=(SIZE, SIZE), **face.view(yaw=0.0, pitch=0.0)) as ren:
            ren.render(frames[0])
            t = time.perf_counter()
            for v in frames:
                ren.render(v)
            draw_one = time.perf_counter() - t
            t = time.perf_counter()
            for _ in ren.render_frames(iter(frames)):
                pass
            draw_piped = time.perf_counter() - t
            images = [ren.render(v) for v in frames[:150]]
            t = time.perf_counter()
            write_video(tmp / "enc.mp4", iter(images * 4), fps=FPS)
            encode = (time.perf_counter() - t) / 4 * n / 150
            video.PRESET = "veryfast" if default_preset != "veryfast" else "medium"
            t = time.perf_counter()
            write_video(tmp / "enc2.mp4", iter(images * 4), fps=FPS)
            encode_other = (time.perf_counter() - t) / 4 * n / 150
            video.PRESET = default_preset
            ren.render(face.mesh.vertices)
            ren.cull_backs = True
            t = time.perf_counter()
            for _ in ren.render_frames(iter(frames)):
                pass
            draw_culled = time.perf_counter() - t
            ren.cull_backs = False
            for preset in ("medium", "veryfast"):
                video.PRESET = preset
                for name, cull, make in (("one by one", False, lambda: (ren.render(v) for v in frames)),
                                         ("pipelined", False, lambda: ren.render_frames(iter(frames))),
                                         ("pipelined, unseen back faces culled", True,
                                          lambda: ren.render_frames(iter(frames)))):
                    ren.cull_backs = cull
                    t = time.perf_counter()
                    write_video(tmp / f"{preset}.mp4", make(), fps=FPS)
                    wall = time.perf_counter() - t
                    rows.append((preset, name, wall, (tmp / f"{preset}.mp4").stat().st_size / 1024))
            ren.cull_backs = False
            video.PRESET = default_preset
        seconds = n / FPS
        print(f"| {n} frames ({seconds:.0f} s), in one process | wall | ms/frame | vs real time | size |")
        print("|---|---:|---:|---:|---:|")
        print(f"| rig evaluated + head turned (numpy) | {evaluate:.2f} s | {evaluate / n * 1000:.1f} | - | - |")
        print(f"| drawn and read back, one by one | {draw_one:.2f} s | {draw_one / n * 1000:.1f} | - | - |")
        print(f"| drawn and read back, pipelined | {draw_piped:.2f} s | {draw_piped / n * 1000:.1f} | - | - |")
        print(f"| drawn and read back, pipelined, back faces culled | {draw_culled:.2f} s | "
              f"{draw_culled / n * 1000:.1f} | - | - |")
        other = "veryfast" if default_preset != "veryfast" else "medium"
        print(f"| encoded alone (x264 {default_preset}) | {encode:.2f} s | {encode / n * 1000:.1f} | - | - |")
        print(f"| encoded alone (x264 {other}) | {encode_other:.2f} s | {encode_other / n * 1000:.1f} | - | - |")
        for preset, name, wall, kib in rows:
            print(f"| render + encode, {name}, x264 {preset} | {wall:.2f} s | {wall / n * 1000:.1f} | "
                  f"{seconds / wall:.2f}x | {kib:.0f} KiB |")


if __name__ == "__main__":
    main()
