"""faceanim view in headless Chromium: frames per second with every morph target live.

    .venv/bin/python benchmarks/bench_viewer.py [--seconds 8] [--width 1100 --height 760] [--quality fast,high]

The page of ``faceanim view`` (its own server, three.js from the package) in Debian's chromium
driven by Playwright, on the default head (24,591 vertices; 25,339 in glTF with the texture's
seam copies) rigged by ``faceanim.autorig`` with every control it has (ARKit, visemes, AUs,
emotions, FAPs: the glb with the most morph targets faceanim writes), with the ARKit set alone,
and with no morph target at all (the baseline: the same page, mesh and texture). Each frame the
page's own per-frame hook sets every morph weight to a new non-zero value (0.05..1, a different
phase per target), so every target is live and the page renders every frame; frames per second
are the page's renders over ``--seconds`` after a 2 s warm-up.

Without a GPU, Chromium draws WebGL with SwiftShader on the CPU (2 cores here): the figures are
CPU rendering, far below what a GPU gives. ``fast`` is the page's default on software WebGL (no
multisampling, no environment map, Lambert shading), ``high`` its full look (``?quality=high``).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from _timing import table  # noqa: E402

FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]

MEASURE = """async ([seconds]) => {
  const live = [...viewer.bindings.values()].flat();
  viewer.onFrame.push((t) => {
    live.forEach(({ mesh, index }, k) => { mesh.morphTargetInfluences[index] = 0.05 + 0.95 * (0.5 + 0.5 * Math.sin(3 * t + k)); });
  });
  await new Promise((r) => setTimeout(r, 2000));
  const r0 = viewer.renders, t0 = performance.now();
  await new Promise((r) => setTimeout(r, seconds * 1000));
  const fps = (viewer.renders - r0) / ((performance.now() - t0) / 1000);
  const nonzero = live.every(({ mesh, index }) => mesh.morphTargetInfluences[index] > 0);
  viewer.onFrame.length = 0;
  return [fps, nonzero];
}"""


def models(folder: Path) -> list[tuple[str, Path]]:
    """(label, glb): the default head with all its controls, with the ARKit set, with none."""
    from faceanim.face.face import Face
    from faceanim.io.gltf import write_gltf

    face = Face.default()
    try:
        from faceanim.autorig import RIG_SETS, auto_rig

        full = auto_rig(face, RIG_SETS)
        arkit = {n: full.shapes[n] for n in full.sets.get("arkit", [])}
        shapes, sets = full.shapes, full.sets
    except ImportError:  # before faceanim.autorig: the player's full rig
        from faceanim.autorig import full_rig

        rig = full_rig(face)
        shapes, sets, arkit = rig.blendshape_dict(), None, {}
    out = [("default head, every control", write_gltf(folder / "all.glb", face.mesh, shapes,
                                                      extras={"morph_sets": sets} if sets else None))]
    if arkit:
        out.append(("default head, ARKit set", write_gltf(folder / "arkit.glb", face.mesh, arkit)))
    out.append(("default head, no morph target (baseline)", write_gltf(folder / "rest.glb", face.mesh)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=8.0, help="measured seconds per case")
    ap.add_argument("--width", type=int, default=1100, help="browser window width (the panel takes 340 px)")
    ap.add_argument("--height", type=int, default=760)
    ap.add_argument("--quality", default="fast,high", help="the page's looks to measure: fast, high")
    args = ap.parse_args()

    from playwright.sync_api import sync_playwright

    from faceanim.viewer.server import Viewer, ViewerServer, check_model, check_vendor

    check_vendor()
    chromium = shutil.which("chromium") or "/usr/bin/chromium"
    qualities = [q.strip() for q in args.quality.split(",") if q.strip()]
    rows = []
    with tempfile.TemporaryDirectory() as tmp, sync_playwright() as pw:
        t = time.perf_counter()
        cases = models(Path(tmp))
        print(f"models written in {time.perf_counter() - t:.1f} s")
        browser = pw.chromium.launch(executable_path=chromium, headless=True, args=FLAGS)
        version = browser.version
        baseline = {}
        for label, glb in cases:
            server = ViewerServer(Viewer(check_model(glb)), 0)
            threading.Thread(target=server.serve_forever, daemon=True).start()
            try:
                for quality in qualities:
                    page = browser.new_page(viewport={"width": args.width, "height": args.height})
                    page.goto(f"{server.url}?quality={quality}")
                    page.wait_for_function("window.viewer && (viewer.ready || viewer.error)", timeout=300_000)
                    if page.evaluate("viewer.error"):
                        raise SystemExit(page.evaluate("viewer.error"))
                    morphs, verts = page.evaluate("[viewer.morphCount, viewer.vertexCount]")
                    renderer = page.evaluate("""() => { const gl = viewer.renderer.getContext();
                        const e = gl.getExtension('WEBGL_debug_renderer_info');
                        return gl.getParameter(e ? e.UNMASKED_RENDERER_WEBGL : gl.RENDERER); }""")
                    fps, live = page.evaluate(MEASURE, [args.seconds])
                    page.close()
                    if not morphs:
                        baseline[quality] = fps
                    rows.append([label, quality, morphs, f"{verts:,}", f"{fps:.1f}", f"{1000 / fps:.0f} ms",
                                 "yes" if live and morphs else "-", quality])
                    print(f"  {label}, {quality}: {fps:.1f} fps", flush=True)
            finally:
                server.shutdown()
                server.server_close()
        browser.close()
    for r in rows:
        base = baseline.get(r.pop())
        r.append(f"{float(r[4]) / base:.2f}" if base else "-")
    table(rows, ["model", "look", "morph targets", "vertices", "fps", "per frame", "all weights live",
                 "x baseline fps"],
          title=f"faceanim view, {args.width - 340} x {args.height} px canvas, Chromium {version}, "
                f"{renderer} (CPU)",
          notes=["fps: the page's renders per second while every morph weight changes every frame "
                 f"({args.seconds:g} s after a 2 s warm-up); the baseline row is the same page and mesh "
                 "with no morph target."])


if __name__ == "__main__":
    main()
