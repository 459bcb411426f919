"""Video analysis on the talking-head videos (Chai et al. 2003, section 2): per video, frames
tracked, tracking speed, the neutral frame found, the range of the head's turns and of the main
control parameters, and the jitter of the raw control signal at rest (the median frame-to-frame
change over the stillest fifth of the clip: the noise the paper's data-driven filter removes).

Usage: ``python scripts/eval_tracking.py ../shared/data/talking-head-videos``
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from faceanim.drivers.video.tracking import CONTROL_NAMES, track_video

STILL_FRACTION = 0.2
WINDOW = 5  # frames: stillness is judged over this many


def jitter_at_rest(controls: np.ndarray) -> np.ndarray:
    """(15,) median |frame-to-frame change| of each parameter over the stillest windows."""
    d = np.abs(np.diff(controls, axis=0))
    motion = np.nansum(d, axis=1)
    windows = np.convolve(np.nan_to_num(motion, nan=np.inf), np.ones(WINDOW) / WINDOW, mode="valid")
    calm = np.argsort(windows)[: max(1, int(STILL_FRACTION * len(windows)))]
    rows = np.unique(np.concatenate([np.arange(k, k + WINDOW) for k in calm]))
    return np.nanmedian(d[rows], axis=0)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("videos", type=Path, help="the talking-head-videos folder")
    args = p.parse_args(argv)
    show = [CONTROL_NAMES.index(n) for n in ("mouth_open", "mouth_width", "eye_open_R", "eye_open_L", "brow_raise_R")]
    print("| video | frames | tracked | tracking fps | neutral | yaw range (deg) | "
          + " | ".join(f"{CONTROL_NAMES[k]} 5-95%" for k in show) + " | jitter at rest (mouth_open, eye_open_R) |")
    print("|---|---|---|---|---|---|" + "---|" * len(show) + "---|")
    for path in sorted(args.videos.glob("*.mp4")):
        t = time.perf_counter()
        tr = track_video(path)
        dt = time.perf_counter() - t
        c = tr.controls
        ranges = " | ".join(f"{np.nanpercentile(c[:, k], 5):+.2f} .. {np.nanpercentile(c[:, k], 95):+.2f}" for k in show)
        jit = jitter_at_rest(c)
        print(f"| {path.name} | {tr.n_frames} | {int(tr.tracked.sum())} | {tr.n_frames / dt:.0f} | {tr.neutral} | "
              f"{np.nanmin(tr.pose[:, 0]):+.0f} .. {np.nanmax(tr.pose[:, 0]):+.0f} | {ranges} | "
              f"{jit[0]:.4f}, {jit[8]:.4f} |", flush=True)
    print("control parameters: change from the neutral frame in units of the performer's own mouth width "
          "(mouth), eye width (eyes, brows); tracking fps includes decoding")


if __name__ == "__main__":
    main()
