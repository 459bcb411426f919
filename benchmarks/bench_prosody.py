"""The voice's prosody (drivers/speech/prosody.py): offline on a whole clip, and live chunk by chunk.

    .venv/bin/python benchmarks/bench_prosody.py ../shared/data [--blas-threads N] [--minutes M]
    (about a minute with the default --minutes 10)

- offline, per LibriVox clip (``speech-librivox/``): ``analyse`` (the two pitch passes, level,
  pauses, accents) and ``prosody_curves`` + ``prosody_head`` at 30 fps, cold (the first call in
  the process: parselmouth loads) and warm (best of 5), per second of sound; the baseline in the
  same run is the pitch alone: one pass of Praat's tracker over the clip (``Sound.to_pitch``),
  what any user of parselmouth pays to get a pitch at all;
- live: ``LiveProsody.feed`` + ``curves`` + ``head`` per 20 ms chunk (as ``live --audio`` feeds it,
  without the clock), mean, p99 and max, against the live lip sync's decoder on the same chunks
  (``LiveLipSync.feed`` + ``curves``, the work the same thread already does);
- memory: ``--minutes`` of the clips played one after another with pauses into one
  ``LiveProsody``: retained and peak bytes (tracemalloc), and the events it keeps at the end
  (it forgets what is older than LIVE_KEEP: bounded whatever the length).

Nothing is asserted here.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from _timing import arguments, best, blas_threads, fmt_bytes, fmt_ratio, fmt_time, header, table, traced

CHUNK = 320  # 20 ms at 16 kHz


def main() -> None:
    args = arguments(__doc__, data="the shared data folder (speech-librivox/)",
                     extra=(("--minutes", {"type": float, "default": 10.0, "help": "minutes of live stream for the memory row"}),))
    blas_threads(args.blas_threads)
    header("faceanim prosody: offline and live")
    import parselmouth

    from faceanim.drivers.speech.phonemes import SAMPLE_RATE
    from faceanim.drivers.speech.prosody import LiveProsody, analyse, prosody_curves, prosody_head
    from faceanim.drivers.speech.stream import LiveLipSync
    from faceanim.live.audio import APPLE, read_sound

    folder = Path(args.data or "../shared/data") / "speech-librivox"
    clips = sorted(folder.glob("clip-*.wav"))
    if not clips:
        raise SystemExit(f"bench_prosody: no clip-*.wav in {folder}; give the shared data folder")
    sounds = {c.stem: read_sound(c) for c in clips}
    names = list(APPLE)

    def offline(x):
        p = analyse(x, SAMPLE_RATE)
        n = int(len(x) / SAMPLE_RATE * 30)
        return prosody_curves(p, names, 30.0, n), prosody_head(p, 30.0, n)

    rows = []
    first = True
    for name, x in sounds.items():
        seconds = len(x) / SAMPLE_RATE
        t0 = time.perf_counter()
        offline(x)
        cold = time.perf_counter() - t0
        warm = best(lambda: offline(x))
        pitch = best(lambda: parselmouth.Sound(x.astype(np.float64), sampling_frequency=float(SAMPLE_RATE)).to_pitch(
            time_step=0.01, pitch_floor=75.0, pitch_ceiling=500.0))
        rows.append([name, f"{seconds:.1f} s", fmt_time(cold) + (" (first)" if first else ""), fmt_time(warm),
                     fmt_time(warm / seconds), fmt_time(pitch), fmt_ratio(pitch / warm)])
        first = False
    table(rows, ["clip", "sound", "cold", "warm", "warm / s of sound", "baseline: one pitch pass", "speed vs baseline"],
          "offline (analyse + curves + head at 30 fps)")

    rows = []
    for name, x in sounds.items():
        live, lip = LiveProsody(SAMPLE_RATE), LiveLipSync(APPLE)
        mine, theirs = [], []
        for k in range(0, len(x), CHUNK):
            part = x[k:k + CHUNK]
            t0 = time.perf_counter()
            live.feed(part)
            live.curves(names)
            live.head()
            t1 = time.perf_counter()
            lip.feed(part)
            lip.curves()
            t2 = time.perf_counter()
            mine.append(t1 - t0)
            theirs.append(t2 - t1)
        mine, theirs = np.array(mine), np.array(theirs)
        rows.append([name, fmt_time(mine.mean()), fmt_time(np.percentile(mine, 99)), fmt_time(mine.max()),
                     fmt_time(theirs.mean()), fmt_time(np.percentile(theirs, 99)), fmt_ratio(theirs.mean() / mine.mean())])
    table(rows, ["clip", "prosody / chunk", "p99", "max", "baseline: lip sync / chunk", "p99", "prosody cheaper by"],
          "live, per 20 ms chunk (LiveProsody.feed + curves + head; the lip sync's decoder on the same chunks)")

    gap = np.zeros(int(0.6 * SAMPLE_RATE), dtype=np.float32)
    stream = np.concatenate([np.r_[x, gap] for x in sounds.values()])
    total = int(args.minutes * 60 * SAMPLE_RATE)

    def run():
        live = LiveProsody(SAMPLE_RATE)
        fed = 0
        while fed < total:
            for k in range(0, len(stream), CHUNK):
                live.feed(stream[k:k + CHUNK])
            fed += len(stream)
        return live

    t0 = time.perf_counter()
    live, retained, peak = traced(run)
    spent = time.perf_counter() - t0
    kept = len(live.blinks) + len(live.nods) + len(live.leans) + len(live.accents) + len(live.looks)
    table([[f"{args.minutes:g} min", fmt_time(spent), fmt_ratio(args.minutes * 60 / spent), fmt_bytes(retained),
            fmt_bytes(peak), str(kept), str(live.phrase_index + 1)]],
          ["stream", "fed in (no clock, traced)", "x real time", "retained", "peak", "events kept at the end", "phrases heard"],
          "memory over a long stream (the clips over and over, 0.6 s pauses)")


if __name__ == "__main__":
    main()
