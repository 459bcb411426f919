"""Held-out synthesis on the real ARKit take (Chai, Xiao & Hodgins 2003, section 4): a motion
database built from the take's first 70% is driven by the control signals of its last 30%, clean
and with tracking-like noise, and the synthesised markers are compared with the real ones.

Methods (all on the same database, 30 fps, the markers rebuilt from basis weights where the
method gives weights):

- ``direct (linear)``: ``faceanim perform --raw``, the least-squares linear map from the 15
  controls to the basis weights, frame by frame;
- ``nearest frame``: the database frame whose controls are nearest (in units of their spread);
- ``per-frame 10-NN``: the mean of the 10 nearest frames;
- ``paper``: one search on all 15 controls, W 20, K 30, overlap 5 (``perform(whole_face=True)``);
- ``faceanim``: ``faceanim perform``'s default (feature-wise, W 5, K 30, overlap 2).

Noise: Gaussian, per control, 0.3 of the median absolute frame-to-frame change the talking-head
videos' tracked controls show (``--noise-from``; measured, not guessed), or 0.15 of each control's
spread over the database without that folder; and three times that. Error: mean marker distance (mm) over the held-out
frames, all 76 markers and the 19 tracked ones (lips, lids, brows, nose).

Usage (from the repository root; about a minute):
``python scripts/eval_synthesis.py ../shared/data/arkit-curves/alex_rom_3.csv [--noise-from ../shared/data/talking-head-videos]``
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from scipy.spatial import cKDTree  # noqa: E402

from faceanim.build.motion import MotionDatabase, build_database  # noqa: E402
from faceanim.drivers.video.tracking import Tracking, track_video  # noqa: E402
from faceanim.face.generic_head import generic_head  # noqa: E402
from faceanim.io.arkit_csv import read_arkit_csv  # noqa: E402
from faceanim.perform import face_regions, hold_untracked, perform  # noqa: E402

SPLIT = 0.7


def part(db: MotionDatabase, a: int, b: int) -> MotionDatabase:
    """Frames a..b of a one-take database as a database of its own (same bases)."""
    return dataclasses.replace(db, markers=db.markers[a:b], controls=db.controls[a:b], raw=db.raw[a:b],
                               neutral=0, take_starts=np.array([0]), rotation_error=db.rotation_error[a:b],
                               weights=db.weights[a:b])


def markers_of(weights: np.ndarray, db: MotionDatabase) -> np.ndarray:
    """(F, P, 3) markers of (F, 2L [+ 2]) lower/upper basis weights (the blinks, if any, left out)."""
    low = face_regions()["lower"][db.marker_vertices][None, :, None]
    n = db.n_bases
    lower = np.einsum("fl,lpd->fpd", weights[:, :n], db.bases)
    upper = np.einsum("fl,lpd->fpd", weights[:, n:2 * n], db.bases)
    return db.rest + low * lower + (1 - low) * upper


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("take", type=Path, help="a Live Link Face CSV (the shared alex_rom_3.csv)")
    p.add_argument("--noise-from", type=Path, help="a folder of videos to measure the tracking noise on")
    args = p.parse_args(argv)
    generic_head()
    full = build_database([("take", read_arkit_csv(args.take))], fps=30.0)
    cut = int(SPLIT * full.n_frames)
    train, test = part(full, 0, cut), part(full, cut, full.n_frames)
    spread = train.controls.std(axis=0)
    if args.noise_from:
        steps = []
        for video in sorted(args.noise_from.glob("*.mp4")):
            tr = track_video(video)
            steps.append(np.median(np.abs(np.diff(hold_untracked(tr.controls, tr.tracked), axis=0)), axis=0))
        sigma = 0.3 * np.median(steps, axis=0)
        noise_note = "0.3 x the videos' median frame-to-frame change per control"
    else:
        sigma = 0.15 * spread
        noise_note = "0.15 x each control's spread"
    rng = np.random.default_rng(0)
    rows = []
    unit = rng.normal(size=test.controls.shape)
    for label, query in (("clean", test.controls), ("noisy", test.controls + sigma * unit),
                         ("noisy x3", test.controls + 3 * sigma * unit)):
        n = len(query)
        tracking = Tracking(30.0, np.ones(n, bool), np.zeros((n, 6)), np.zeros((n, 19, 2)), test.raw, query, 0)
        tree = cKDTree(train.controls / spread)
        _, nn = tree.query(query / spread, k=10)
        results = {
            "direct (linear, --raw)": markers_of(perform(tracking, train, raw=True, smooth_head=False).weights, train),
            "nearest frame": train.markers[nn[:, 0]],
            "per-frame 10-NN": train.markers[nn].mean(axis=1),
            "paper (whole face, W 20, overlap 5)": markers_of(
                perform(tracking, train, whole_face=True, window=20, overlap=5, smooth_head=False).weights, train),
            "faceanim (feature-wise, W 5, overlap 2)": markers_of(perform(tracking, train, smooth_head=False).weights,
                                                                 train),
        }
        for method, m in results.items():
            d = np.linalg.norm(m - test.markers, axis=2) * 1e3
            rows.append((label, method, d.mean(), d[:, :19].mean()))
    print(f"database: the take's first {SPLIT:.0%} ({cut} frames at 30 fps); queries: the last "
          f"{1 - SPLIT:.0%} ({full.n_frames - cut} frames); noise: {noise_note}\n")
    print("| controls | method | marker error, all 76 (mm) | the 19 tracked (mm) |")
    print("|---|---|---:|---:|")
    for label, method, e_all, e_19 in rows:
        print(f"| {label} | {method} | {e_all:.2f} | {e_19:.2f} |")


if __name__ == "__main__":
    main()
