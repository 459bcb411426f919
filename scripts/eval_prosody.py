"""How well the voice's prosody moves the upper face and head, against people talking on video.

For each talking-head VIDEO (with its sound):

1. the performer: ``faceanim perform VIDEO -o P.csv`` tracks the video (ARKit's 52 curves and the
   head's angles per frame, the same tracker users run; ``--tracker mediapipe``: MediaPipe's own
   52 scores instead, a second reading of the brows and lids);
2. ours: ``faceanim say --audio SOUND -o S.csv`` on the video's own sound alone (no picture);
3. whether the sound is the performer's own (:func:`sound_sync`: the tracked jaw follows the lip
   sync of the sound, at some offset under a second); clips whose sound is music or a dub are
   left out, the others are put on the picture's time;
4. the same event detector on both: brow raises (peaks of the brows' mean curve), nods (downward
   peaks of the head's pitch) and blinks (both eyes shut), and the scores of issue 34:

   - recall: the share of the performer's brow raises / nods with one of ours within
     ``--within`` seconds (300 ms);
   - count ratio: how many of ours per performer's event (goal <= 1.5);
   - blink rate ratio: ours / the performer's (goal 0.5 .. 1.5);
   - chance: the recall of our own events shifted in time by 1 to 3 s (both ways), what timing
     that knows nothing of the voice scores with the same number of events;
   - correlation over phrases (speech between pauses): of the brows' and the head pitch's mean;
   - the ceiling of any timing from the speech: the performer's own syllables, the peaks of their
     tracked jaw opening (:data:`JAW_PROMINENCE`, as many as their brow raises and nods), moved
     by the one offset (within 0.5 s) that scores best on the ``--tune`` clips, taken as the
     events. The sound cannot time the face better than the mouth that makes it does;
   - a model fitted to the performers: a ridge regression from the sound (its level, the level's
     rise, the pitch in semitones and voicing, each 0.5 s either side) to the head's pitch, its
     speed and the brows' mean (slow drifts removed), fitted on every clip but one and scored
     (Pearson r) on the one left out.

Clips named in ``--tune`` are the ones the constants were chosen on; the others are held out and
reported apart. Run (the clips with sound: d10 and d14 in the shared data; LivePortrait's other
driving and source clips with sound, and six 8 s HDTF clips in SadTalker's examples, fetched
outside the repository, see docs/speech.md)::

    OPENBLAS_NUM_THREADS=1 python scripts/eval_prosody.py ../shared/data/talking-head-videos/d1{0,4}.mp4 \\
        /work/ext/th/{d6,d11,d12,d20,s18}.mp4 /work/ext/th/{WDA,RD}_*.mp4 --tune d10,d12,d20 \\
        --work /tmp/eval_prosody

Tracking results and our curves are cached in ``--work`` (delete it after changing the tracker).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import numpy as np

from faceanim.io.arkit_csv import read_arkit_csv
from faceanim.standards.arkit import ARKIT_NAMES

FPS = 30.0
BROWS = [ARKIT_NAMES.index(n) for n in ("BrowInnerUp", "BrowOuterUpLeft", "BrowOuterUpRight")]
BLINKS = [ARKIT_NAMES.index(n) for n in ("EyeBlinkLeft", "EyeBlinkRight")]
BROW_PROMINENCE = 0.15  # a brow raise: the brows' mean curve up this much over its surroundings
NOD_PROMINENCE = np.radians(1.5)  # a nod: the head down this much and back, within NOD_WINDOW
NOD_WINDOW = 1.2  # seconds
BLINK_HEIGHT, BLINK_PROMINENCE = 0.5, 0.3  # a blink: both eyes' curves over 0.5, from 0.3 lower
GAP = 0.3  # seconds between two events of a kind at least
JAW_PROMINENCE = 0.2  # a syllable: the tracked jawOpen up this much over its surroundings
JAW_LAGS = np.round(np.arange(-0.5, 0.51, 0.1), 2)  # seconds: the offsets the ceiling tries
SHIFTS = (-3.0, -2.0, -1.0, 1.0, 2.0, 3.0)  # seconds: the chance recall's time shifts
SYNC_R = 0.25  # the performer's jaw and our lip sync's (from the sound) correlate this well at least,
SYNC_LAG = 1.0  # at an offset within this many seconds, for the sound to be the performer's own (the
#                 six HDTF clips, speech recorded with its picture, measure 0.26-0.65; two clips with
#                 music for sound 0.18 and 0.19)


def _smooth(x: np.ndarray, sigma: float = 2.0) -> np.ndarray:
    from scipy.ndimage import gaussian_filter1d

    return gaussian_filter1d(np.asarray(x, dtype=np.float64), sigma, mode="nearest")


def events(take) -> dict[str, np.ndarray]:
    """Times (s) of the take's brow raises, nods and blinks."""
    from scipy.signal import find_peaks

    gap = max(int(GAP * FPS), 1)
    brow = _smooth(take.weights[:, BROWS].mean(axis=1))
    b, _ = find_peaks(brow, prominence=BROW_PROMINENCE, distance=gap)
    pitch = _smooth(take.head[:, 1])  # faceanim's sign: positive is the head down
    n, _ = find_peaks(pitch, prominence=NOD_PROMINENCE, distance=gap, wlen=int(NOD_WINDOW * FPS) | 1)
    shut = take.weights[:, BLINKS].min(axis=1)  # both eyes: a wink is not a blink
    k, _ = find_peaks(shut, height=BLINK_HEIGHT, prominence=BLINK_PROMINENCE, distance=gap)
    return {"brow": b / FPS, "nod": n / FPS, "blink": k / FPS}


def syllables(take) -> np.ndarray:
    """Times (s) of the take's syllables: peaks of its jawOpen curve."""
    from scipy.signal import find_peaks

    jaw = _smooth(take.weights[:, ARKIT_NAMES.index("JawOpen")], 1.0)
    k, _ = find_peaks(jaw, prominence=JAW_PROMINENCE, distance=max(int(GAP * FPS), 1))
    return k / FPS


def ceiling(tuned: list[dict], held: list[dict], within: float) -> None:
    """Print how well the performer's own syllables (moved by the offset best on ``tuned``) time
    their brow raises and nods on ``held``: what no timing from the speech is likely to beat."""
    if not tuned or not held:
        return
    print("\nceiling: the performer's own syllables (tracked jaw peaks) as the events")
    for kind, label in (("brow", "brow raises"), ("nod", "nods")):
        def score(rows, lag):
            hit = total = ours = 0
            luck = 0.0
            for r in rows:
                mine = r["syllables"] + lag
                h, t = recall(r["theirs"][kind], mine, within)
                hit, total, ours = hit + h, total + t, ours + len(mine)
                luck += chance(r["theirs"][kind], mine, within, r["seconds"]) if t else 0.0
            return hit, total, ours, luck
        lag = max(JAW_LAGS, key=lambda g: (score(tuned, g)[0], -abs(g)))
        hit, total, ours, luck = score(held, lag)
        print(f"{label}: offset {lag:+.1f} s (tuned), held out recall {hit}/{total} = {hit / max(total, 1):.2f} "
              f"(chance {luck / max(total, 1):.2f}), syllables per theirs {ours / max(total, 1):.2f}")


CONTEXT = range(-15, 16, 3)  # frames of the sound either side a ridge regression sees (0.5 s)
RIDGE = 10.0


def sound_features(prosody, n: int, lag: float) -> np.ndarray:
    """(n, 45) the sound about each picture frame: level (dB under the loud speech, -40 in pauses),
    its rise, the pitch (semitones over the median, 0 unvoiced) and voicing, at :data:`CONTEXT`."""
    t = np.arange(n) / FPS - lag  # the picture's time on the sound's
    level = np.where(prosody.speaking, prosody.level - np.percentile(prosody.level, 95), -40.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        st = 12.0 * np.log2(prosody.pitch / np.nanmedian(prosody.pitch))
    cols = []
    for sig in (level, 10.0 * np.gradient(_smooth(level, 3.0)), np.where(np.isfinite(st), st, 0.0),
                prosody.speaking.astype(float)):
        at = np.interp(t, prosody.times, sig, left=0.0, right=0.0)
        cols += [np.roll(at, k) for k in CONTEXT]
    return np.c_[np.array(cols).T, np.ones(n)]


def motion_targets(take) -> dict[str, np.ndarray]:
    """The performer's head pitch, its speed and brows' mean per frame, slow drifts (1 s) removed."""
    pitch = _smooth(take.head[:, 1])
    brow = _smooth(take.weights[:, BROWS].mean(axis=1))
    return {"head pitch": pitch - _smooth(pitch, FPS), "its speed": np.gradient(pitch),
            "brows": brow - _smooth(brow, FPS)}


def fitted_model(rows: list[dict]) -> None:
    """Print the leave-one-clip-out r of a ridge regression from the sound to the performers'
    head pitch, its speed and brows (module docstring)."""
    if len(rows) < 3:
        return
    print("\na model fitted to the performers (ridge, leave one clip out): r on the clip left out")
    for key in rows[0]["motion"]:
        rs = []
        for k, held in enumerate(rows):
            rest = [r for j, r in enumerate(rows) if j != k]
            a = np.vstack([r["sound"] for r in rest])
            y = np.concatenate([(r["motion"][key] - r["motion"][key].mean()) / (r["motion"][key].std() + 1e-9)
                                for r in rest])
            w = np.linalg.solve(a.T @ a + RIDGE * np.eye(a.shape[1]), a.T @ y)
            guess, truth = held["sound"] @ w, held["motion"][key]
            rs.append(float(np.corrcoef(guess, truth)[0, 1]) if np.std(guess) > 0 and np.std(truth) > 0 else np.nan)
        print(f"{key}: median r {np.nanmedian(rs):.2f} ({', '.join(f'{r:.2f}' for r in rs)})")


def recall(theirs: np.ndarray, ours: np.ndarray, within: float) -> tuple[int, int]:
    """(how many of ``theirs`` have one of ``ours`` within ``within`` s, how many there are)."""
    if not len(theirs):
        return 0, 0
    if not len(ours):
        return 0, len(theirs)
    d = np.abs(theirs[:, None] - ours[None, :]).min(axis=1)
    return int(np.sum(d <= within)), len(theirs)


def chance(theirs: np.ndarray, ours: np.ndarray, within: float, duration: float) -> float:
    """Mean recall of ``ours`` shifted by :data:`SHIFTS` (wrapped round the clip)."""
    if not len(theirs):
        return float("nan")
    hits = [recall(theirs, np.mod(ours + s, duration), within)[0] for s in SHIFTS]
    return float(np.mean(hits))


def phrase_correlation(perf, ours, speaking_times: list[tuple[float, float]]) -> tuple[float, float]:
    """Correlation over phrases of the brows' mean and of the head pitch's mean (NaN with < 3)."""
    rows = []
    for a, b in speaking_times:
        i, j = int(a * FPS), int(np.ceil(b * FPS))
        j = min(j, len(perf.times), len(ours.times))
        if j - i < 3:
            continue
        rows.append((perf.weights[i:j, BROWS].mean(), ours.weights[i:j, BROWS].mean(),
                     perf.head[i:j, 1].mean(), ours.head[i:j, 1].mean()))
    if len(rows) < 3:
        return float("nan"), float("nan")
    r = np.array(rows)
    with np.errstate(invalid="ignore", divide="ignore"):
        return float(np.corrcoef(r[:, 0], r[:, 1])[0, 1]), float(np.corrcoef(r[:, 2], r[:, 3])[0, 1])


def sound_sync(perf, ours) -> tuple[float, float]:
    """(r, offset s): how well the performer's tracked jawOpen follows our lip sync's from the
    clip's sound (slow drifts removed), at the best offset within SYNC_LAG (positive: the picture
    after the sound). A dubbed clip or one with music for sound stays under SYNC_R."""
    col = ARKIT_NAMES.index("JawOpen")
    a = perf.weights[:, col] - _smooth(perf.weights[:, col], FPS)
    b = ours.weights[:, col] - _smooth(ours.weights[:, col], FPS)
    best = (-1.0, 0.0)
    for lag in range(-int(SYNC_LAG * FPS), int(SYNC_LAG * FPS) + 1):
        x, y = (a[lag:], b[:len(b) - lag]) if lag >= 0 else (a[:lag], b[-lag:])
        if len(x) > FPS and np.std(x) > 0 and np.std(y) > 0:
            best = max(best, (float(np.corrcoef(x, y)[0, 1]), lag / FPS))
    return best


def _run(cmd: list[str]) -> None:
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode:
        sys.exit(f"eval_prosody: {' '.join(cmd[:3])} ... failed: {done.stderr.strip().splitlines()[-1:]}")


def clip(video: Path, work: Path, within: float, tracker: str = "solve") -> dict:
    import soundfile as sf

    from faceanim.drivers.speech.prosody import analyse
    from faceanim.io.video import video_sound  # the video's sound, as perform reads it

    name = video.stem
    work.mkdir(parents=True, exist_ok=True)
    wav, say_csv = work / f"{name}.wav", work / f"{name}.say.csv"
    perf_csv = work / (f"{name}.perf.csv" if tracker == "solve" else f"{name}.perf-{tracker}.csv")
    faceanim = [sys.executable, "-m", "faceanim"]
    if not wav.exists():
        folder = work / f"{name}.sound"
        folder.mkdir(exist_ok=True)
        found = video_sound(video, folder)
        if found is None:
            sys.exit(f"eval_prosody: {video.name} has no sound; give clips of people talking")
        found.rename(wav)
    if not perf_csv.exists():
        _run([*faceanim, "perform", str(video), "--tracker", tracker, "-o", str(perf_csv), "--quiet"])
    if not say_csv.exists():
        _run([*faceanim, "say", "--audio", str(wav), "--fps", f"{FPS:g}", "-o", str(say_csv), "--quiet"])
    perf, ours = read_arkit_csv(perf_csv).resample(FPS), read_arkit_csv(say_csv).resample(FPS)
    n = min(len(perf.times), len(ours.times))
    for take in (perf, ours):
        take.times, take.weights, take.head = take.times[:n], take.weights[:n], take.head[:n]
    duration = n / FPS
    r, lag = sound_sync(perf, ours)
    theirs, mine = events(perf), events(ours)
    mine = {k: v + lag for k, v in mine.items()}  # on the picture's time
    x, rate = sf.read(wav, dtype="float64", always_2d=True)
    prosody = analyse(x.mean(axis=1), rate)
    edges = [0.0] + [v for p in prosody.pauses for v in p] + [prosody.duration]
    phrases = [(a, b) for a, b in zip(edges[::2], edges[1::2]) if b - a > 0.3]
    brow_r, pitch_r = phrase_correlation(perf, ours, phrases)
    out = {"clip": name, "seconds": duration, "brow_r": brow_r, "pitch_r": pitch_r, "sync": (r, lag),
           "theirs": theirs, "syllables": syllables(perf), "sound": sound_features(prosody, n, lag),
           "motion": motion_targets(perf)}
    for kind in ("brow", "nod", "blink"):
        hit, total = recall(theirs[kind], mine[kind], within)
        out[kind] = (hit, total, len(mine[kind]), chance(theirs[kind], mine[kind], within, duration))
    return out


def _table(rows: list[dict], title: str) -> None:
    if not rows:
        return
    print(f"\n{title}")
    print("| clip | s | brow raises: hit/theirs (ours, chance) | nods: hit/theirs (ours, chance) "
          "| blinks theirs/ours | brow r | pitch r |")
    print("|---|---:|---|---|---|---:|---:|")
    for r in rows:
        cells = [f"{r[k][0]}/{r[k][1]} ({r[k][2]}, {r[k][3]:.1f})" for k in ("brow", "nod")]
        print(f"| {r['clip']} | {r['seconds']:.1f} | {cells[0]} | {cells[1]} | {r['blink'][1]}/{r['blink'][2]} "
              f"| {r['brow_r']:.2f} | {r['pitch_r']:.2f} |")
    tot = {k: np.sum([r[k][:3] for r in rows], axis=0) for k in ("brow", "nod", "blink")}
    ch = {k: np.nansum([r[k][3] for r in rows]) for k in ("brow", "nod")}
    for k, label in (("brow", "brow raises"), ("nod", "nods")):
        hit, theirs, ours = tot[k]
        print(f"{label}: recall {hit}/{theirs} = {hit / max(theirs, 1):.2f} (chance {ch[k] / max(theirs, 1):.2f}), "
              f"ours per theirs {ours / max(theirs, 1):.2f}")
    theirs, ours = tot["blink"][1], tot["blink"][2]
    print(f"blinks: {theirs} theirs, {ours} ours, rate ratio {ours / max(theirs, 1):.2f}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("videos", nargs="+", type=Path)
    ap.add_argument("--tune", default="", help="comma-separated clip names the constants were chosen on")
    ap.add_argument("--work", type=Path, default=Path("eval_prosody_work"))
    ap.add_argument("--within", type=float, default=0.3, help="seconds an event of ours may be off (0.3)")
    ap.add_argument("--tracker", choices=("solve", "mediapipe"), default="solve",
                    help="what reads the performer's face (perform --tracker; default solve)")
    args = ap.parse_args(argv)
    tune = {t for t in args.tune.split(",") if t}
    rows = [clip(v, args.work, args.within, args.tracker) for v in args.videos]
    for r in rows:
        print(f"{r['clip']}: the performer's jaw follows the sound's lip sync r = {r['sync'][0]:.2f} at "
              f"{r['sync'][1]:+.2f} s" + ("" if r["sync"][0] >= SYNC_R else " (not the performer's own sound: left out)"))
    rows = [r for r in rows if r["sync"][0] >= SYNC_R]
    _table([r for r in rows if r["clip"] in tune], "tuned on")
    _table([r for r in rows if r["clip"] not in tune], "held out")
    ceiling([r for r in rows if r["clip"] in tune], [r for r in rows if r["clip"] not in tune], args.within)
    fitted_model(rows)


if __name__ == "__main__":
    main()
