"""Performance-driven animation (Chai, Xiao & Hodgins 2003) on the talking-head videos: how still,
how late and how faithful the avatar's face is, per video, for

- ``raw``: the per-frame linear mapping of the tracked controls (``perform(raw=True)``, no filter);
- ``one-euro``: a One-Euro filter (Casiez, Roussel & Vogel 2012) on the tracked controls, then the
  raw mapping; standard parameters (min_cutoff 1 Hz, beta 0.007, d_cutoff 1 Hz) and a tuned beta.
  The filter runs on each control in units of its spread over the motion database (the controls
  mix mouth widths and degrees; one beta then fits all 15);
- ``paper``: the paper's data-driven filtering and synthesis, one search on all 15 controls
  (``perform(whole_face=True)``), its window 20, overlap 5 (delay 4 frames), K 30;
- ``faceanim``: ``faceanim perform``'s default: feature-wise (the lower face from the mouth's
  opening, width and height, the upper face from the nose, eyes and brows), window 5, overlap 2
  (delay 1 frame), K 30;
- ``faceanim W20``: the same at the paper's window and overlap (what the shorter delay costs).

Columns (one row per video and method, then the mean over the videos per method):

- ``tracked``: frames where a face was found / frames.
- ``jitter@rest``: the mean frame-to-frame motion (mm) of the default face's face-region vertices,
  expression only (the head's rotation is the tracked pose for every method and is left out),
  over the still frames: the fifth of the frames with the least local motion of the tracked
  controls (each control's |frame-to-frame change| over its median over the clip, summed over the
  15 controls, averaged over a centred 10-frame window; the windows must be fully tracked).
- ``motion``: the same mean frame-to-frame vertex motion (mm) over all frames, for scale.
- ``mouth 5-95%``: the avatar's mouth opening (mm), 5th and 95th percentile.
- ``lag``: the delay (frames, positive = the avatar is late) in -10..+10 that maximises the
  Pearson correlation between the avatar's mouth opening at t + lag and the video's at t.
- ``r@lag``, ``r@0``: that correlation at the best lag and at lag 0. The avatar's mouth opening
  is the distance between the inner-lip landmarks 13 and 14 on the evaluated default face; the
  video's is the tracked raw ``mouth_open`` (outer-lip distance, fronto-parallel); tracked frames
  only. The issue's goal is r >= 0.85.
- ``r signed@0``: as ``r@0`` with the avatar's opening signed (landmark 13 minus 14 along the
  face's up axis): a distance cannot tell a crossed mouth (lower lip pushed through the upper)
  from an open one.
- below the table, the head rotation's own motion at rest, as tracked and smoothed (the table's
  jitter is the expression's).
- ``r eyes``, ``r brows``: the same correlation (lag 0, mean of left and right) for the lids'
  opening (landmarks 159-145, 386-374 along the up axis, against the tracked raw ``eye_open``) and
  the brows' height over the eyes (105-159, 334-386, against ``brow_raise``).

Also writes the table to ``--out`` (default /tmp/eval_performance.md) and, with ``--sheet``, a
contact sheet: for the two clips whose mouth moves most, four frames spread over the clip, each
video frame beside the avatar (``faceanim perform``'s default, with the smoothed head rotation).

Usage (from /work/main):
``python scripts/eval_performance.py ../shared/data/talking-head-videos [--sheet docs/performance_sheet.png]``
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from faceanim.drivers.video.filters import one_euro
from faceanim.drivers.video.tracking import track_video
from faceanim.face.controls import CONTROL_NAMES
from faceanim.face.face import Face
from faceanim.face.generic_head import generic_head
from faceanim.perform import default_database, hold_untracked, perform, performance_rig

MOUTH = CONTROL_NAMES.index("mouth_open")
STILL_FRACTION, STILL_WINDOW = 0.2, 10
MAX_LAG = 10
BETA = 0.007  # One-Euro's standard parameters (min_cutoff 1 Hz, d_cutoff 1 Hz)
BETA_TUNED = 0.5  # per database standard deviation per second: speech (mouth_open changing at ~2-10
# sd/s) lifts the cutoff to ~2-6 Hz, rest stays at 1 Hz
UPPER_LIP, LOWER_LIP = 13, 14
CHUNK = 128
METHODS = ("raw", "one-euro", "one-euro tuned", "paper", "faceanim", "faceanim W20")
# (upper, lower) landmark pairs measured along the face's up axis, and the tracked control
UPPER_PAIRS = {"eyes": (((159, 145), "eye_open_R"), ((386, 374), "eye_open_L")),
               "brows": (((105, 159), "brow_raise_R"), ((334, 386), "brow_raise_L"))}


def still_frames(tracking) -> np.ndarray:
    """Indices t (>= 1) of the still frames: the lowest STILL_FRACTION of the local motion of the
    tracked controls (see the module docstring); the motion at t is from t - 1 to t."""
    c = tracking.controls
    d = np.abs(np.diff(c, axis=0))  # (F-1, 15), NaN next to untracked frames
    scale = np.nanmedian(d, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    motion = np.sum(d / scale, axis=1)  # NaN if either frame is untracked
    motion = np.r_[np.nan, motion]  # motion[t]: t - 1 -> t
    half = STILL_WINDOW // 2
    local = np.full(len(motion), np.inf)
    for t in range(1, len(motion)):
        a, b = max(1, t - half), min(len(motion), t - half + STILL_WINDOW)
        w = motion[a:b]
        if len(w) == STILL_WINDOW and np.all(np.isfinite(w)):
            local[t] = w.mean()
    ok = np.flatnonzero(np.isfinite(local))
    if not len(ok):
        return ok
    n = max(1, round(STILL_FRACTION * len(ok)))
    return np.sort(ok[np.argsort(local[ok], kind="stable")[:n]])


def avatar_measures(weights: np.ndarray, rig, region: np.ndarray, up: np.ndarray):
    """Per frame: the mean motion (m) of the face-region vertices from the previous frame (NaN at
    frame 0), the mouth opening (m, distance 13-14), its signed version (along ``up``) and the
    gaps of :data:`UPPER_PAIRS` along ``up`` (dict: pair -> (F,))."""
    head = generic_head()
    step, dist, signed = [np.nan], [], []
    gaps = {pair: [] for group in UPPER_PAIRS.values() for pair, _ in group}
    last = None
    for a in range(0, len(weights), CHUNK):
        v = rig.evaluate(weights[a:a + CHUNK])
        face = v[:, region]
        if last is not None:
            step.append(float(np.linalg.norm(face[0] - last, axis=1).mean()))
        step.extend(np.linalg.norm(np.diff(face, axis=0), axis=2).mean(axis=1))
        last = face[-1]
        for vf in v:
            lm = head.landmarks(vf)
            gap = lm[UPPER_LIP] - lm[LOWER_LIP]
            dist.append(float(np.linalg.norm(gap)))
            signed.append(float(gap @ up))
            for a, b in gaps:
                gaps[(a, b)].append(float((lm[a] - lm[b]) @ up))
    return np.array(step), np.array(dist), np.array(signed), {k: np.array(v) for k, v in gaps.items()}


def lagged_corr(avatar: np.ndarray, video: np.ndarray, ok: np.ndarray, lag: int) -> float:
    """Pearson r between ``avatar[t + lag]`` and ``video[t]`` over t with both frames valid."""
    n = len(video)
    t = np.arange(max(0, -lag), min(n, n - lag))
    t = t[ok[t] & ok[t + lag]]
    if len(t) < 3:
        return float("nan")
    a, v = avatar[t + lag], video[t]
    if a.std() == 0 or v.std() == 0:
        return float("nan")
    return float(np.corrcoef(a, v)[0, 1])


def performances(tracking, db) -> dict:
    """The avatar's weights (F, 2L: lower and upper face) per method."""
    held = hold_untracked(tracking.controls, tracking.tracked)
    sd = db.controls.std(axis=0)
    sd = np.where(sd > 0, sd, 1.0)
    out = {"raw": perform(tracking, db, raw=True).weights}
    for name, beta in (("one-euro", BETA), ("one-euro tuned", BETA_TUNED)):
        filtered = one_euro(held / sd, tracking.fps, beta=beta) * sd
        out[name] = perform(dataclasses.replace(tracking, controls=filtered), db, raw=True).weights
    out["paper"] = perform(tracking, db, whole_face=True, window=20, overlap=5).weights
    out["faceanim"] = perform(tracking, db).weights
    out["faceanim W20"] = perform(tracking, db, window=20, overlap=5).weights
    return out


def fmt(x, spec=".2f") -> str:
    return "n/a" if x is None or not np.isfinite(x) else format(x, spec)


def head_jitter(tracking, face, still: np.ndarray) -> tuple[float, float]:
    """Mean frame-to-frame motion (m) of the face-region vertices from the head's rotation alone,
    over the still frames: tracked as is, and smoothed as ``perform`` does (One-Euro)."""
    from faceanim.export import head_pivot

    region = face.mesh.vertices[face.face_region] - head_pivot(face)
    out = []
    for smooth in (False, True):
        perf = perform(tracking, raw=True, smooth_head=smooth)
        rot = perf.rotations(face.frame.rotation)
        step = np.linalg.norm(np.einsum("fij,vj->fvi", np.diff(rot, axis=0), region), axis=2).mean(axis=1)
        out.append(float(np.mean(step[still - 1])) if len(still) else float("nan"))
    return out[0], out[1]


def contact_sheet(path: Path, chosen, face, rig, db) -> None:
    """Four frames of each chosen clip, each beside the face under faceanim perform's default."""
    import cv2

    from faceanim.io.video import video_frames, video_info
    from faceanim.perform import performance_frames
    from faceanim.render.gl import OffscreenRenderer
    from faceanim.render.video import save_png

    size = 256
    rows = []
    with OffscreenRenderer(face.mesh, size=(size, size), **face.view(yaw=0.0, pitch=0.0)) as renderer:
        for video, tracking in chosen:
            n = tracking.n_frames
            picks = [int((2 * k + 1) * n / 8) for k in range(4)]
            perf = perform(tracking, db)  # faceanim perform's default
            verts = {}
            for t, v in enumerate(performance_frames(perf, rig, face)):
                if t in picks:
                    verts[t] = v
            frames = {}
            for t, img in enumerate(video_frames(video_info(video))):
                if t in picks:
                    frames[t] = img
                if t >= max(picks):
                    break
            cells = []
            for t in picks:
                img = frames[t]
                w = round(img.shape[1] * size / img.shape[0])
                img = cv2.resize(img, (w, size), interpolation=cv2.INTER_AREA)
                if w != size:  # crop or pad to a square, centred
                    if w > size:
                        img = img[:, (w - size) // 2:(w - size) // 2 + size]
                    else:
                        pad = np.zeros((size, size, 3), np.uint8)
                        pad[:, (size - w) // 2:(size - w) // 2 + w] = img
                        img = pad
                img = np.ascontiguousarray(img)
                cv2.putText(img, f"{video.name} f{t}", (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 0), 1,
                            cv2.LINE_AA)
                face_img = np.ascontiguousarray(renderer.render(verts[t]))
                cells.append(np.hstack([img, face_img, np.full((size, 6, 3), 255, np.uint8)]))
            rows.append(np.hstack(cells))
            rows.append(np.full((6, rows[-1].shape[1], 3), 255, np.uint8))
    save_png(path, np.vstack(rows[:-1]))


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("videos", type=Path, help="the talking-head-videos folder")
    p.add_argument("--sheet", type=Path, help="write a contact sheet PNG here")
    p.add_argument("--out", type=Path, default=Path("/tmp/eval_performance.md"), help="the table, as Markdown")
    args = p.parse_args(argv)
    start = time.perf_counter()
    db = default_database()
    face = Face.default()
    rig = performance_rig(face, db)
    region = np.flatnonzero(face.face_region)
    up = face.frame.rotation[1]
    header = ("| video | method | tracked | jitter@rest (mm/frame) | motion (mm/frame) | mouth 5-95% (mm) | lag "
              "(frames) | r@lag | r@0 | r signed@0 | r eyes | r brows |")
    lines = [header, "|" + "---|" * (header.count("|") - 1)]
    per_method = {m: [] for m in METHODS}
    tracked_videos = []
    heads = []  # (raw, smoothed) head-rotation jitter at rest per video
    for video in sorted(args.videos.glob("*.mp4")):
        tracking = track_video(video)
        tracked_videos.append((video, tracking))
        ok = tracking.tracked
        mouth_video = tracking.raw[:, MOUTH]
        still = still_frames(tracking)
        heads.append(head_jitter(tracking, face, still))
        for method, weights in performances(tracking, db).items():
            step, dist, signed, gaps = avatar_measures(weights, rig, region, up)
            upper = {group: float(np.nanmean([lagged_corr(gaps[pair], tracking.raw[:, CONTROL_NAMES.index(c)], ok, 0)
                                              for pair, c in pairs]))
                     for group, pairs in UPPER_PAIRS.items()}
            lags = np.arange(-MAX_LAG, MAX_LAG + 1)
            rs = np.array([lagged_corr(dist, mouth_video, ok, int(k)) for k in lags])
            best = int(lags[np.nanargmax(rs)]) if np.isfinite(rs).any() else 0
            row = {"jitter": 1e3 * float(np.mean(step[still])) if len(still) else np.nan,
                   "motion": 1e3 * float(np.nanmean(step)),
                   "lo": 1e3 * np.percentile(dist, 5), "hi": 1e3 * np.percentile(dist, 95),
                   "lag": best, "r_lag": float(rs[lags == best][0]), "r0": lagged_corr(dist, mouth_video, ok, 0),
                   "r_signed": lagged_corr(signed, mouth_video, ok, 0), "tracked": ok.mean(),
                   "r_eyes": upper["eyes"], "r_brows": upper["brows"]}
            per_method[method].append(row)
            lines.append(f"| {video.name} | {method} | {int(ok.sum())}/{len(ok)} | {fmt(row['jitter'], '.3f')} | "
                         f"{fmt(row['motion'], '.3f')} | {row['lo']:.1f}..{row['hi']:.1f} | {best:+d} | "
                         f"{fmt(row['r_lag'])} | {fmt(row['r0'])} | {fmt(row['r_signed'])} | "
                         f"{fmt(row['r_eyes'])} | {fmt(row['r_brows'])} |")
            print(lines[-1], flush=True)
    for method, rows in per_method.items():
        def mean(key, rows=rows):
            return float(np.nanmean([r[key] for r in rows]))

        lines.append(f"| **mean** | {method} | {100 * mean('tracked'):.0f}% | {mean('jitter'):.3f} | "
                     f"{mean('motion'):.3f} | {mean('lo'):.1f}..{mean('hi'):.1f} | {mean('lag'):+.1f} | "
                     f"{mean('r_lag'):.2f} | {mean('r0'):.2f} | {mean('r_signed'):.2f} | {mean('r_eyes'):.2f} | "
                     f"{mean('r_brows'):.2f} |")
    lines += ["", ("jitter@rest and motion: expression only (no head rotation), face-region vertices of the default face. "
              "lag: only meaningful where r@lag is high (with r near 0 the peak is noise, often at +-10). "
              "Synthesis looks ahead: frame t is final once frame t + overlap - 1 is seen (4 frames for paper and "
              "faceanim W20, 1 for faceanim), a latency that does not show as lag in an offline run; One-Euro is "
              "causal, so its latency is its lag."),
              "", (f"Head rotation at rest (face-region vertices, the same for every method): "
                   f"{1e3 * np.mean([h[0] for h in heads]):.3f} mm/frame as tracked, "
                   f"{1e3 * np.mean([h[1] for h in heads]):.3f} smoothed by perform's One-Euro filter "
                   "(mean over the videos).")]
    table = "\n".join(lines)
    print("\n" + table)
    args.out.write_text(table + "\n")
    print(f"\ntable written to {args.out}")
    if args.sheet:
        spread = [np.nanstd(t.raw[:, MOUTH]) / np.nanmedian(t.raw[:, CONTROL_NAMES.index("mouth_width")])
                  for _, t in tracked_videos]
        chosen = [tracked_videos[k] for k in sorted(np.argsort(spread, kind="stable")[::-1][:2])]
        args.sheet.parent.mkdir(parents=True, exist_ok=True)
        contact_sheet(args.sheet, chosen, face, rig, db)
        print(f"contact sheet ({', '.join(v.name for v, _ in chosen)}) written to {args.sheet}")
    print(f"{time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
