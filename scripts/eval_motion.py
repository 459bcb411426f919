"""Does the avatar's face do what the performer's does? The judge of motion fidelity (issue 20).

For each talking-head clip, ``faceanim perform``'s avatar (the default face) is rendered from the
front frame by frame, and the same measurements are taken on the video and on the renders, by the
same code: MediaPipe's Face Landmarker (video mode), the head's pose taken out (a similarity onto the
generic head's landmarks that no expression moves, as tracking does), then per frame, in the
generic head's units:

- ``gap``: the inner lips' opening (landmarks 13 - 14, up the face);
- ``width``: the mouth's width (corners 61 - 291);
- ``round``: the inner lip contour's width over its height (78 - 308 over 13 - 14), on frames where
  the mouth is open (the gap over a fifth of the width): small when the lips round ("o", "u");
- ``eye``: the lids' opening over the eye's width, both eyes averaged (159 - 145, 386 - 374);
- ``brow``: the brows' height over the upper lids (105 - 159, 334 - 386);
- ``smile``: the mouth corners' height over the middle of the lips (61, 291 against 0, 17);
- ``gaze x``, ``gaze y``: where the irises sit in the eyes (468, 473 against the corners), both eyes
  averaged, in eye widths.

Per clip and measure: ``r`` (Pearson, frames measured on both sides), ``range`` (the avatar's
p5-p95 over the performer's), ``rest`` (the avatar's median over the performer's still frames,
less the avatar's own neutral, in units of the performer's p5-p95: a face that smiles at rest
shows it here; for the eyes, the avatar's opening at rest over its neutral one, less 1: the goal is
within 10%), and for the eyes ``blink`` (the deepest closure, 1 - p2 / median of the eye
opening; the performer's and the avatar's) and ``blink ratio`` (the avatar's minimum opening over
the performer's, relative to each one's median, both floored at 5%: the goal is <= 1.5).

Clips d0, d3, d9 are the tuning set, d10, d14, d18 the held-out set (``--clips`` to choose);
the summary gives the median of each figure over each set.

Each ``--tracker`` (solve, live, mediapipe, synthesis; several comma-separated) makes the curves
from the same tracking and plays them on the same avatar; the summary gives per set the median and
the worst clip of: lip r, lip range, width r, blink depth (the avatar's deepest closure over the
performer's), eye r, brow r, smile r, round r, gaze x r, gaze y r.

Usage (from /work/main): ``python scripts/eval_motion.py ../shared/data [--clips d10,d14] [--size 512]
[--sheets DIR] [--face MESH] [--tracker solve,mediapipe] [--cache DIR]`` (``--face``: another avatar than the default face; ``--sheets``: a
contact sheet per clip, the video beside the avatar at the deepest blink, the widest and the most
rounded open mouth, and a still moment)
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

TUNING = ("d0", "d3", "d9")
HELD_OUT = ("d10", "d14", "d18")
MEASURES = ("gap", "width", "round", "eye", "brow", "smile", "gaze x", "gaze y")
CHUNK = 64
SHUT = 0.05  # an eye opening under this share of the open one counts as shut


class Measurer:
    """MediaPipe's face mesh in video mode over a stream of frames -> the measures per frame."""

    def __init__(self):
        from faceanim.drivers.video.tracking import rigid_landmarks
        from faceanim.face.generic_head import generic_head
        from faceanim.face.mediapipe import FaceMesh

        self._fm = FaceMesh(video=True, confidence=0.5, what="the motion judge")
        self._ref = generic_head().landmarks()
        self._rigid = rigid_landmarks()

    def __call__(self, frame: np.ndarray) -> np.ndarray:
        from faceanim.face.frame import similarity

        lm = self._fm(frame)
        if lm is None:
            return np.full(len(MEASURES), np.nan)
        q = lm * np.array([1.0, -1.0, -1.0])
        s, r, t = similarity(self._ref[self._rigid], q[self._rigid])
        f = ((q - t) @ r) / s  # fronto-parallel, generic head units (x the face's left, y up)
        return measures(f)

    def close(self):
        self._fm.close()


def measures(f: np.ndarray) -> np.ndarray:
    """The six measures (module docstring) of one frame's 478 fronto-parallel landmarks."""
    gap = f[13, 1] - f[14, 1]
    width = abs(f[291, 0] - f[61, 0])
    inner = abs(f[308, 0] - f[78, 0])
    rnd = inner / gap if gap > 0.2 * width else np.nan
    eye = 0.5 * ((f[159, 1] - f[145, 1]) / abs(f[133, 0] - f[33, 0])
                 + (f[386, 1] - f[374, 1]) / abs(f[362, 0] - f[263, 0]))
    brow = 0.5 * ((f[105, 1] - f[159, 1]) + (f[334, 1] - f[386, 1]))
    smile = 0.5 * (f[61, 1] + f[291, 1]) - 0.5 * (f[0, 1] + f[17, 1])
    from faceanim.drivers.video.tracking import gaze_offsets

    g = gaze_offsets(f)
    return np.array([gap, width, rnd, eye, brow, smile, 0.5 * (g[0] + g[2]), 0.5 * (g[1] + g[3])])


def measure_video(path: Path) -> tuple[np.ndarray, float]:
    from faceanim.io.video import video_frames, video_info

    info = video_info(path)
    m = Measurer()
    try:
        out = np.array([m(fr) for fr in video_frames(info)])
    finally:
        m.close()
    return out, info.fps


def measure_avatar(face, vertices_iter, size: int, keep=()) -> tuple[np.ndarray, np.ndarray]:
    """Render each frame's vertices from the front (the default face, textured) and measure; also
    the neutral face's measures. The renders of the frames in ``keep`` (a dict, filled) are kept."""
    from faceanim.face.landmarks import _face_frame
    from faceanim.render import OffscreenRenderer

    rot = face.frame.rotation
    m = Measurer()
    out = []
    with OffscreenRenderer(face.mesh, size=(size, size), parallel=True, rotation=rot,
                           frame_vertices=_face_frame(face.mesh, rot), margin=1.0) as r:
        neutral_img = r.render(face.mesh.vertices)
        for _ in range(5):  # settle the tracker on the neutral face first
            neutral = m(neutral_img)
        for k, v in enumerate(vertices_iter):
            img = r.render(v)
            if k in keep:
                keep[k] = img
            out.append(m(img))
    m.close()
    return np.array(out), neutral


def still(values: np.ndarray, ok: np.ndarray, fraction: float = 0.2) -> np.ndarray:
    """Frames where the performer's measures move least (a centred 9-frame window)."""
    d = np.abs(np.diff(values[:, [0, 1, 3, 4, 5]], axis=0))
    scale = np.nanmedian(d, axis=0)
    motion = np.r_[np.nan, np.nansum(d / np.where(scale > 0, scale, 1.0), axis=1)]
    local = np.array([np.nanmean(motion[max(0, t - 4):t + 5]) if ok[max(0, t - 4):t + 5].all() else np.inf
                      for t in range(len(motion))])
    good = np.flatnonzero(np.isfinite(local))
    return good[np.argsort(local[good], kind="stable")[:max(1, int(fraction * len(good)))]]


def figures(perf: np.ndarray, av: np.ndarray, neutral: np.ndarray) -> dict:
    out = {}
    rest = still(perf, np.isfinite(perf[:, [0, 3]]).all(axis=1))
    for k, name in enumerate(MEASURES):
        p, a = perf[:, k], av[:, k]
        ok = np.isfinite(p) & np.isfinite(a)
        if ok.sum() < 10:
            out[name] = {}
            continue
        span_p = np.percentile(p[ok], 95) - np.percentile(p[ok], 5)
        span_a = np.percentile(a[ok], 95) - np.percentile(a[ok], 5)
        r = float(np.corrcoef(p[ok], a[ok])[0, 1]) if p[ok].std() > 0 and a[ok].std() > 0 else float("nan")
        at_rest = a[rest][np.isfinite(a[rest])]
        bias = (float(np.median(at_rest)) - neutral[k]) / span_p if at_rest.size and np.isfinite(neutral[k]) else np.nan
        out[name] = {"r": r, "range": span_a / span_p if span_p > 0 else np.nan, "rest": bias}
    for label, series in (("performer", perf[:, 3]), ("avatar", av[:, 3])):
        s = series[np.isfinite(series)]
        out["eye"][f"blink {label}"] = 1.0 - np.percentile(s, 2) / np.median(s)
    rest_eye = av[rest, 3][np.isfinite(av[rest, 3])]
    out["eye"]["rest vs neutral"] = float(np.median(rest_eye) / neutral[3] - 1.0) if rest_eye.size else np.nan
    pe, ae = perf[:, 3][np.isfinite(perf[:, 3])], av[:, 3][np.isfinite(av[:, 3])]
    # MediaPipe's lids on a shut eye measure 0-8% of the open eye (even below 0): the performer's
    # minimum is floored at 5% so that the ratio says how far the avatar is from shut
    out["eye"]["blink ratio"] = max(np.percentile(ae, 2) / np.median(ae), SHUT) / max(np.percentile(pe, 2) / np.median(pe), SHUT)
    return out


def sheet_frames(perf: np.ndarray) -> dict[str, int]:
    """The performer's frames a contact sheet shows: the deepest blink, the widest open mouth, the
    most rounded open mouth, and a still (neutral) moment."""
    out = {}
    eye, gap, rnd = perf[:, 3], perf[:, 0], perf[:, 2]
    if np.isfinite(eye).any():
        out["blink"] = int(np.nanargmin(eye))
    if np.isfinite(gap).any():
        out["open"] = int(np.nanargmax(gap))
    if np.isfinite(rnd).sum() >= 5:
        out["rounded"] = int(np.nanargmin(rnd))
    ok = np.isfinite(perf[:, [0, 3]]).all(axis=1)
    if ok.sum() >= 10:
        out["neutral"] = int(still(perf, ok)[0])
    return out


def write_sheet(path: Path, video: Path, chosen: dict[str, int], renders, height: int = 256,
                labels: tuple = ()) -> None:
    """One row per chosen frame: the video frame beside the avatar's render (``renders`` a dict
    frame -> image, or a list of such dicts: one avatar column each, headed by ``labels``)."""
    import cv2
    import imageio.v3 as iio

    from faceanim.io.video import video_frames, video_info

    want = {k: None for k in chosen.values()}
    for k, img in enumerate(video_frames(video_info(video))):
        if k in want:
            want[k] = img
        if all(v is not None for v in want.values()):
            break
    columns = renders if isinstance(renders, list) else [renders]
    rows = []
    for label, k in chosen.items():
        v = want[k]
        v = cv2.resize(v, (int(round(v.shape[1] * height / v.shape[0])), height), interpolation=cv2.INTER_AREA)
        avatars = []
        for c, col in enumerate(columns):
            a = cv2.resize(col[k], (height, height), interpolation=cv2.INTER_AREA).copy()
            if c < len(labels):
                cv2.putText(a, labels[c], (8, height - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 0), 2)
            avatars.append(a)
        row = np.hstack([v, *avatars]).copy()
        cv2.putText(row, f"{label} (frame {k})", (8, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 0), 2)
        rows.append(row)
    width = max(r.shape[1] for r in rows)
    iio.imwrite(path, np.vstack([np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows]))


def _cached(cache: Path | None, key: str, make):
    """``make()``, kept as a pickle in ``cache`` under ``key`` (tuning runs re-measure the same clips)."""
    import pickle

    if cache is None:
        return make()
    f = cache / f"{key}.pkl"
    if f.exists():
        return pickle.loads(f.read_bytes())
    value = make()
    cache.mkdir(parents=True, exist_ok=True)
    f.write_bytes(pickle.dumps(value))
    return value


def performance_curves(tracking, tracker: str, settings=None):
    """The performance of a tracking by ``tracker`` (solve, synthesis, mediapipe)."""
    from faceanim.perform import default_database, mediapipe_performance, perform, solve_performance

    if tracker == "solve":
        return solve_performance(tracking, settings)
    if tracker == "live":  # the live solve, causal, stepped on every frame (drops: benchmarks/bench_live.py)
        from faceanim.live.performer import LiveSolver
        from faceanim.perform import Performance

        live = LiveSolver(settings)
        samples = []
        for k in range(tracking.n_frames):
            ok = bool(tracking.tracked[k])
            samples.append(live.step(tracking.landmarks[k] if ok else None, k / tracking.fps,
                                     tracking.scores[k] if ok else None))
        return Performance(tracking.fps, np.array([x.arkit for x in samples]), np.zeros((tracking.n_frames, 6)),
                           tracking.tracked.copy(), {"tracker": "live"}, tracker="solve")
    if tracker == "mediapipe":
        return mediapipe_performance(tracking)
    return perform(tracking, default_database())


def avatar_frames(performance, face, rig_cache: dict):
    """The avatar's vertices per frame, as ``faceanim arkit play`` (ARKit curves) or ``perform
    --tracker synthesis`` (the bases' rig) renders them, without the head's turn (the judge takes
    the pose out)."""
    from faceanim.export import Animation, face_frames
    from faceanim.perform import default_database, performance_rig

    if performance.is_arkit:
        if "shapes" not in rig_cache:
            from faceanim.rig.arkit import arkit_shapes

            rig_cache["shapes"] = arkit_shapes(face)[0]
        yield from face_frames(Animation(performance.fps, arkit=performance.weights, face=face,
                                         shapes=rig_cache["shapes"]), CHUNK)
        return
    if "bases" not in rig_cache:
        rig_cache["bases"] = performance_rig(face, default_database())
    rig = rig_cache["bases"]
    for a in range(0, performance.n_frames, CHUNK):
        yield from rig.evaluate(performance.weights[a:a + CHUNK])


def run_clip(path: Path, face, size: int, sheets: Path | None = None, tracker: str = "solve",
             cache: Path | None = None, settings=None, rig_cache: dict | None = None) -> dict:
    from faceanim.drivers.video.tracking import track_video

    t = time.perf_counter()
    perf_m, fps = _cached(cache, f"judge_{path.stem}", lambda: measure_video(path))
    tracking = _cached(cache, f"tracking_{path.stem}", lambda: track_video(path))
    performance = performance_curves(tracking, tracker, settings)
    rig_cache = {} if rig_cache is None else rig_cache

    def frames():
        yield from avatar_frames(performance, face, rig_cache)

    chosen = sheet_frames(perf_m) if sheets else {}
    renders = {k: None for k in chosen.values()}
    av_m, neutral = measure_avatar(face, frames(), size, renders)
    fig = figures(perf_m, av_m, neutral)
    if sheets:
        write_sheet(sheets / f"{path.stem}_{tracker}.png", path, chosen, renders)
        fig["sheet"] = (chosen, renders)
    fig["frames"] = len(perf_m)
    fig["series"] = (perf_m, av_m)
    fig["seconds"] = time.perf_counter() - t
    return fig


def fmt(x) -> str:
    return "n/a" if x is None or not np.isfinite(x) else f"{x:.2f}"


def main(argv=None) -> None:
    from faceanim.face.face import Face

    p = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    p.add_argument("data", type=Path, help="the shared data folder (../shared/data)")
    p.add_argument("--clips", default=",".join(TUNING + HELD_OUT), help="clip names (default: all six)")
    p.add_argument("--size", type=int, default=512, help="render size of the avatar (pixels)")
    p.add_argument("--face", help="the avatar's mesh (default: the embedded default face), e.g. the ICT head "
                   "or a head from photos")
    p.add_argument("--sheets", type=Path, help="write a contact sheet per clip into this folder (the video "
                   "beside the avatar at its deepest blink, widest and most rounded mouth, and a still moment)")
    p.add_argument("--tracker", default="solve", help="solve, live (the live solve, causal, on every frame), synthesis "
                   "or mediapipe, or several, comma-separated (each on the same clips, the same avatar and the same "
                   "judge)")
    p.add_argument("--cache", type=Path, help="keep the judge's measures of each clip and its tracking here")
    args = p.parse_args(argv)
    face = Face.load(args.face) if args.face else Face.default()
    trackers = args.tracker.split(",")
    results = {t: {} for t in trackers}
    rig_cache: dict = {}
    if args.sheets:
        args.sheets.mkdir(parents=True, exist_ok=True)
    for name in args.clips.split(","):
        path = args.data / "talking-head-videos" / f"{name}.mp4"
        for tracker in trackers:
            f = results[tracker][name] = run_clip(path, face, args.size, args.sheets, tracker, args.cache,
                                                  rig_cache=rig_cache)
            print(f"{name} {tracker}: {f['frames']} frames, {f['seconds']:.0f} s; " + ", ".join(
                f"{k} {fmt(v)}" for k, v in summary_row(f).items()), flush=True)
        if args.sheets and len(trackers) > 1:  # the performer beside every tracker's avatar
            chosen = results[trackers[0]][name]["sheet"][0]
            write_sheet(args.sheets / f"{name}.png", path, chosen,
                        [results[t][name]["sheet"][1] for t in trackers], labels=tuple(trackers))
    for tracker in trackers:
        print(f"\n### {tracker}\n")
        print("| clip | set | " + " | ".join(SUMMARY) + " |")
        print("|---|---|" + "---:|" * len(SUMMARY))
        for name, f in results[tracker].items():
            kind = "tuning" if name in TUNING else "held out" if name in HELD_OUT else "-"
            print(f"| {name} | {kind} | " + " | ".join(fmt(v) for v in summary_row(f).values()) + " |")
    print("\n### median (worst clip) per set\n")
    print("| set | measure | " + " | ".join(trackers) + " |")
    print("|---|---|" + "---|" * len(trackers))
    for label, group in (("tuning", TUNING), ("held out", HELD_OUT)):
        for key in SUMMARY:
            cells = []
            for tracker in trackers:
                vals = [summary_row(results[tracker][n])[key] for n in group if n in results[tracker]]
                vals = [v for v in vals if v is not None and np.isfinite(v)]
                if not vals:
                    cells.append("n/a")
                    continue
                # the worst clip: the lowest correlation, the ratio farthest from 1
                worst = max(vals, key=lambda v: abs(np.log(max(v, 1e-9)))) if key in RATIOS else min(vals)
                cells.append(f"{np.median(vals):.2f} ({worst:.2f})")
            if any(c != "n/a" for c in cells):
                print(f"| {label} | {key} | " + " | ".join(cells) + " |")


# the figures the summary gives per clip: correlations (r) and ratios (1 = the performer's)
SUMMARY = ("lip r", "lip range", "width r", "blink depth", "eye r", "brow r", "smile r", "round r", "gaze x r",
           "gaze y r")
RATIOS = ("lip range", "blink depth")


def summary_row(f: dict) -> dict:
    """One clip's :data:`SUMMARY` figures: ``blink depth`` is the avatar's deepest closure over the
    performer's (1 - p2 / median of the eye opening, each)."""
    e = f["eye"]
    depth = e["blink avatar"] / e["blink performer"] if e.get("blink performer") else float("nan")
    return {"lip r": f["gap"].get("r"), "lip range": f["gap"].get("range"), "width r": f["width"].get("r"),
            "blink depth": depth, "eye r": e.get("r"), "brow r": f["brow"].get("r"), "smile r": f["smile"].get("r"),
            "round r": f["round"].get("r"), "gaze x r": f["gaze x"].get("r"), "gaze y r": f["gaze y"].get("r")}


if __name__ == "__main__":
    main()
