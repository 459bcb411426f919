"""faceanim live: a clip played in real time to a VMC receiver on 127.0.0.1, against offline perform.

    .venv/bin/python benchmarks/bench_live.py ../shared/data [--blas-threads N] [--clips d10,d14]
        [--tracker solve|synthesis]
    (about 3 minutes: each clip is played in real time, then tracked once more offline)

``--tracker``: the live tracker measured (default ``solve``: :class:`LiveSolver` against offline
``solve_performance``; ``synthesis``: :class:`LivePerformer` against offline ``perform``).

Per talking-head clip (``talking-head-videos/``), the clip is played at its own frame rate by
``ClipSource`` (frame i captured at start + i / fps, newest frame only) through ``run_live`` to a
VMC sink whose receiver (python-osc's server) runs in this process:

- sustained frames per second (frames processed over the run), frames dropped (captured, then
  replaced before the compute took them) and latency from each frame's capture to its datagram
  sent (p50, p95); flat-out frames per second: the same clip with each frame put as soon as the
  last is taken (``ClipSource(realtime=False)``: decoding, tracking, the step and the datagrams,
  no frame dropped), the rate the pipeline could keep up with;
- the streamed jawOpen - mouthClose against the video's inner lip gap (MediaPipe, offline
  tracking of every frame): Pearson r over the frames processed, and the same figure for offline
  ``perform`` (the baseline: the whole clip known before any frame is synthesised);
- per frame compute, warm: tracking (MediaPipe) and the live performer's step, against offline
  ``perform``'s synthesis per frame (the whole clip at once);
- cold: building the live performer (database, k-d trees, mouth maps) and MediaPipe's first frame;
  the performer's retained and peak memory.

Sound (``speech-librivox/``, each clip fed in 20 ms chunks as ``AudioFeed`` does, without the
clock): against the clip's offline forced alignment with its transcript (the reference), the
streamed viseme onsets (the first chunk at which the phone being heard is of the aligned phone's
viseme class; latency from the aligned start; found = share of the class changes seen at all) and
the p/b/m closures (the lips shut, mouthClose within 0.03 of jawOpen, from 30 ms before the phone to
150 ms after it); the baseline is the offline all-phone recognition of the whole clip
(``recognise_phones`` + ``say``'s curves: what ``faceanim say --audio`` does without a
transcript), measured the same way; and the streaming decoder's cost per 20 ms chunk.

Goals (issue 21): >= 30 fps sustained on a 30 fps clip, latency p50 <= 50 ms, p95 <= 100 ms,
drops <= 2%, jaw r >= 0.85 and within 0.03 of offline; sound: onset p50 <= 150 ms, closures
recall >= 0.8. Nothing is asserted here.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
from _timing import arguments, blas_threads, fmt_bytes, fmt_time, header, table, traced

from faceanim.drivers.video.tracking import FaceTracker, track_frames
from faceanim.standards.arkit import ARKIT_NAMES
from faceanim.io.files import native_stderr_quiet
from faceanim.io.video import video_frames, video_info
from faceanim.live.performer import LivePerformer, LiveSolver
from faceanim.live.pipeline import run_live
from faceanim.live.sinks import parse_sinks
from faceanim.live.sources import ClipSource
from faceanim.perform import arkit_curves, default_database, perform, solve_performance

CLIPS = ("d0", "d3", "d9", "d10", "d14", "d18")
VISEMES = {"closed": "P B M", "labiodental": "F V", "rounded": "UW OW AO W UH OY R ER", "open": "AA AE AH AW AY",
           "spread": "IY IH EH EY Y", "dental": "TH DH", "post": "SH ZH CH JH"}
CLASS = {p: k for k, v in VISEMES.items() for p in v.split()}


def sound_figures(times, curves, heard, ref):
    """(onset latencies, class changes, closures shut, closures) of a stream against the reference."""
    j, c = ARKIT_NAMES.index("JawOpen"), ARKIT_NAMES.index("MouthClose")
    lat, changes, shut, closures, prev = [], 0, 0, 0, None
    for p in ref:
        k = CLASS.get(p.phone.rstrip("012"))
        if k is not None and k != prev:
            changes += 1
            sel = np.flatnonzero((times >= p.start - 0.02) & (times <= p.end + 0.3))
            hit = [times[i] for i in sel if heard[i] == k]
            if hit:
                lat.append(hit[0] - p.start)
        prev = k
        if p.phone in ("P", "B", "M"):
            closures += 1
            sel = (times >= p.start - 0.03) & (times <= p.end + 0.15)
            shut += bool(sel.any() and (curves[sel, j] - curves[sel, c]).min() < 0.03)
    return lat, changes, shut, closures


def sound_table(folder) -> None:
    from faceanim.drivers.speech.lipsync import lipsync_curves
    from faceanim.drivers.speech.phonemes import SAMPLE_RATE, align, recognise_phones
    from faceanim.drivers.speech.stream import LiveLipSync
    from faceanim.live.audio import APPLE, read_sound

    rows, total = [], {"live": [[], 0, 0, 0], "offline": [[], 0, 0, 0]}
    for wav in sorted(folder.glob("clip-*.wav")):
        x = read_sound(wav)
        ref = align(wav, wav.with_suffix(".txt").read_text())
        ls = LiveLipSync(APPLE)
        times, curves, heard, cost = [], [], [], []
        for k in range(0, len(x), 320):
            t0 = time.perf_counter()
            ls.feed(x[k:k + 320])
            curves.append(ls.curves())
            cost.append(time.perf_counter() - t0)
            times.append(ls.stream.time)
            heard.append(CLASS.get(ls.current_phone().rstrip("012")))
        live = sound_figures(np.array(times), np.array(curves), heard, ref)
        phones = recognise_phones(wav)
        grid = np.arange(0, len(x) / SAMPLE_RATE, 0.02)
        off_curves = lipsync_curves(phones, APPLE, fps=50.0, frames=len(grid))
        off_heard = [CLASS.get(next((p.phone.rstrip("012") for p in phones if p.start <= t < p.end), "SIL"))
                     for t in grid]
        offline = sound_figures(grid, off_curves, off_heard, ref)
        for key, f in (("live", live), ("offline", offline)):
            acc = total[key]
            acc[0] += f[0]
            acc[1] += f[1]
            acc[2] += f[2]
            acc[3] += f[3]
        rows.append([wav.stem, f"{len(x) / SAMPLE_RATE:.1f} s", f"{1000 * np.median(live[0]):.0f}",
                     f"{1000 * np.percentile(live[0], 90):.0f}", f"{len(live[0])}/{live[1]}",
                     f"{live[2]}/{live[3]}", f"{len(offline[0])}/{offline[1]}", f"{offline[2]}/{offline[3]}",
                     fmt_time(float(np.mean(cost))), fmt_time(float(np.max(cost)))])
    lat, changes, shut, closures = total["live"]
    rows.append(["all", "", f"{1000 * np.median(lat):.0f}", f"{1000 * np.percentile(lat, 90):.0f}",
                 f"{len(lat)}/{changes} ({len(lat) / changes:.0%})", f"{shut}/{closures} ({shut / closures:.0%})",
                 f"{len(total['offline'][0])}/{total['offline'][1]}",
                 f"{total['offline'][2]}/{total['offline'][3]} ({total['offline'][2] / total['offline'][3]:.0%})", "", ""])
    table(rows, ["clip", "length", "onset p50 ms", "p90 ms", "onsets found", "closures shut",
                 "offline onsets found", "offline closures shut", "decode / 20 ms chunk", "max"])


def receiver():
    from pythonosc.dispatcher import Dispatcher
    from pythonosc.osc_server import ThreadingOSCUDPServer

    count = {"apply": 0}
    d = Dispatcher()
    d.map("/VMC/Ext/Blend/Apply", lambda *a: count.__setitem__("apply", count["apply"] + 1))
    server = ThreadingOSCUDPServer(("127.0.0.1", 0), d)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server, count


def jaw_r(curves: np.ndarray, gap: np.ndarray) -> float:
    j, c = ARKIT_NAMES.index("JawOpen"), ARKIT_NAMES.index("MouthClose")
    ok = np.isfinite(gap)
    return float(np.corrcoef((curves[:, j] - curves[:, c])[ok], gap[ok])[0, 1])


def browser_table(clip) -> None:
    """``faceanim live --to viewer`` on ``clip`` with the page open in headless Chromium (Debian's,
    SwiftShader: WebGL on the CPU), both on this machine: from each frame's capture to its weights
    set in the page, and the page's frames drawn per second while the stream runs."""
    import shutil
    import subprocess
    import sys

    chromium = shutil.which("chromium") or "/usr/bin/chromium"
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        print("(no browser table: the playwright package is not installed)")
        return
    if not Path(chromium).exists():
        print("(no browser table: chromium is not installed)")
        return
    flags = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
             "--disable-component-update", "--disable-sync", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
    proc = subprocess.Popen([sys.executable, "-m", "faceanim", "live", "--video", str(clip), "--to", "viewer:0",
                             "--no-browser"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    url = proc.stderr.readline().split("viewer ")[1].split()[0]
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=chromium, headless=True, args=flags)
        page = browser.new_page(viewport={"width": 760, "height": 760})
        page.goto(url)
        page.wait_for_function("window.viewer && window.viewer.ready", timeout=120_000)
        page.wait_for_function("faceanimLive.messages > 0", timeout=60_000)
        r0, t0 = page.evaluate("viewer.renders"), time.perf_counter()
        page.wait_for_function("faceanimLive.closed", timeout=120_000, polling=500)
        r1, t1 = page.evaluate("viewer.renders"), time.perf_counter()
        lat = np.array(page.evaluate("faceanimLive.latencies"))
        got = page.evaluate("faceanimLive.messages")
        browser.close()
    out, _ = proc.communicate(timeout=60)
    sent = int(out.split(" frames")[0].split()[-1]) if " frames" in out else 0
    table([[clip.stem, str(sent), str(got), f"{np.percentile(lat, 50):.0f}", f"{np.percentile(lat, 95):.0f}",
            f"{(r1 - r0) / (t1 - t0):.1f}"]],
          ["clip", "frames sent", "messages in the page", "capture to weights set p50 ms", "p95 ms",
           "page frames drawn / s (CPU WebGL)"])


def main() -> None:
    args = arguments(__doc__, "the shared data folder (../shared/data)",
                     extra=[("--clips", {"default": ",".join(CLIPS), "help": "clips to play, comma-separated "
                                                                             "(none: the sound table only)"}),
                            ("--tracker", {"default": "solve", "choices": ["solve", "synthesis"],
                                           "help": "the live tracker measured (default: solve)"})])
    blas_threads(args.blas_threads)
    header(f"faceanim live ({args.tracker}): clips played in real time to VMC on 127.0.0.1")
    folder = args.data / "talking-head-videos"
    db = default_database()
    solve = args.tracker == "solve"

    def live_tracker():
        return LiveSolver() if solve else LivePerformer(db)

    def offline(tracking):
        return arkit_curves(solve_performance(tracking) if solve else perform(tracking, db), db)

    t0 = time.perf_counter()
    _, kept, peak = traced(live_tracker)
    t_build = time.perf_counter() - t0
    t0 = time.perf_counter()
    with native_stderr_quiet(), FaceTracker() as tr:
        tr(np.zeros((64, 64, 3), dtype=np.uint8))
        t_first = time.perf_counter() - t0
    print(f"cold: live {args.tracker} built in {fmt_time(t_build)} (retained {fmt_bytes(kept)}, peak {fmt_bytes(peak)}); "
          f"MediaPipe's first frame {fmt_time(t_first)}\n")

    rows, compute_rows = [], []
    for name in [c for c in args.clips.split(",") if c]:
        clip = folder / f"{name}.mp4"
        info = video_info(clip)
        server, count = receiver()
        port = server.server_address[1]
        report = run_live(ClipSource(clip), parse_sinks([f"vmc://127.0.0.1:{port}"], info.fps, "bench"),
                          live_tracker(), keep_samples=True)
        time.sleep(0.2)
        server.shutdown()
        server.server_close()
        # flat out: every frame put as soon as the last is taken (the pipeline's own throughput)
        server, _ = receiver()
        flat = run_live(ClipSource(clip, realtime=False),
                        parse_sinks([f"vmc://127.0.0.1:{server.server_address[1]}"], info.fps, "bench"), live_tracker())
        server.shutdown()
        server.server_close()
        # offline: every frame tracked, then perform (the baseline), timed per frame
        frames = list(video_frames(info))
        t0 = time.perf_counter()
        tracking = track_frames(frames, info.fps)
        t_track = (time.perf_counter() - t0) / len(frames)
        t0 = time.perf_counter()
        offline_curves = offline(tracking)
        t_perform = (time.perf_counter() - t0) / len(frames)
        idx = np.array([int(round(s.time * info.fps)) for s in report.samples])
        live = np.array([s.arkit for s in report.samples])
        gap = tracking.inner_gap
        lat = np.array(report.latency) * 1000
        r_live, r_off = jaw_r(live, gap[idx]), jaw_r(offline_curves, gap)
        rows.append([name, f"{info.fps:g}", str(report.processed), f"{report.fps:.1f}", f"{flat.fps:.1f}",
                     f"{100 * report.dropped / max(report.captured, 1):.1f}%",
                     f"{np.percentile(lat, 50):.0f}", f"{np.percentile(lat, 95):.0f}", str(count["apply"]),
                     f"{r_live:.3f}", f"{r_off:.3f}", f"{r_live - r_off:+.3f}"])
        # the live step alone, warm, on this clip's landmarks
        lp = live_tracker()
        with native_stderr_quiet(), FaceTracker() as tr:
            found = [tr.detect(f, i / info.fps) for i, f in enumerate(frames)]
        t0 = time.perf_counter()
        for i, fd in enumerate(found):
            lm = None if fd is None else fd.landmarks
            if solve:
                lp.step(lm, i / info.fps, None if fd is None else fd.blendshapes)
            else:
                lp.step(lm, i / info.fps)
        t_step = (time.perf_counter() - t0) / len(frames)
        compute_rows.append([name, fmt_time(t_track), fmt_time(t_step), fmt_time(t_perform),
                             f"{t_step / t_perform:.2f}x"])
    if rows:
        table(rows, ["clip", "fps", "frames", "sustained fps", "flat-out fps", "dropped", "latency p50 ms", "p95 ms", "VMC applies",
                     "jaw r live", "jaw r offline", "live - offline"])
        print()
        table(compute_rows, ["clip", "tracking / frame", "live step / frame", "offline perform / frame (baseline)",
                         "live / offline"])
    if (args.data / "speech-librivox").is_dir():
        print()
        sound_table(args.data / "speech-librivox")
    print()
    browser_table(folder / "d10.mp4")


if __name__ == "__main__":
    main()
