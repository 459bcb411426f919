"""Lip-sync timing on real speech (issue 5): visemes against forced-alignment phones.

    python scripts/eval_lipsync.py ../shared/data/speech-librivox

For every clip (clip-NNNN.wav + clip-NNNN.txt): forced alignment gives the phones; the
co-articulated viseme actions are blended as faceanim plays them. Reported:
- viseme onset error: for each phone whose viseme differs from the previous one, the time at
  which its viseme becomes the dominant mouth shape (largest blending weight, 1 ms steps) minus
  the phone's start, median of the absolute values;
- closure: for every p, b, m, the gap between the inner lips (feature points 2.2 and 2.3) at
  the video frame nearest the phone's centre, on the default face (whose neutral lips are
  parted by a smile), as a fraction of its neutral gap;
- speed: phones -> FAP stream -> 30k-vertex mesh for every frame, against the audio's duration.
"""

import argparse
import time
from pathlib import Path

import numpy as np

from faceanim.drivers.speech import align, phone_viseme, viseme_actions
from faceanim.drivers.speech.visemes import speech_stream
from faceanim.face.default import default_face, default_landmarks
from faceanim.face.face import Face, landmarks_478
from faceanim.rig.mpeg4 import FapRig


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", type=Path)
    ap.add_argument("--fps", type=float, default=25.0)
    args = ap.parse_args(argv)
    clips = sorted(args.data.glob("clip-*.wav"))
    if not clips:
        raise SystemExit(f"{args.data}: no clip-*.wav files")
    face = default_face()
    lm = landmarks_478(face, default_landmarks(face))
    rig = FapRig.build(Face(face, lm))
    fp = rig.points
    _, upper = face.kdtree.query(fp["2.2"])
    _, lower = face.kdtree.query(fp["2.3"])

    def gap(v):
        return fp.frame.vectors_to_local(v[upper] - v[lower])[1]

    neutral_gap = gap(face.vertices)
    onset_err, closures, audio_s, anim_s = [], [], 0.0, 0.0
    print("| clip | seconds | phones | median onset error (ms) | p/b/m closed at centre |")
    print("|---|---|---|---|---|")
    for wav in clips:
        text = wav.with_suffix(".txt").read_text()
        phones = align(wav, text)
        acts = viseme_actions(phones, rig.lip_gap)
        t = np.arange(0.0, phones[-1].end + 0.3, 0.001)
        weights = np.stack([a.weight * a.envelope_at(t) for a in acts])  # (A, T)
        dominant = np.where(weights.max(0) > 0, weights.argmax(0), -1)
        errs = []
        prev = None
        for k, a in enumerate(acts):
            v = a.extra["viseme"]
            if v != prev:
                frames = np.flatnonzero(dominant == k)
                if len(frames):
                    errs.append(t[frames[0]] - a.extra["phone_start"])
            prev = v
        start = time.perf_counter()
        stream = speech_stream(rig.lip_gap, phones, args.fps)
        verts = rig.evaluate(stream)
        anim_s += time.perf_counter() - start
        audio_s += phones[-1].end
        closed = []
        for p in phones:
            if phone_viseme(p.phone) == 1:
                k = min(int(round(p.centre * args.fps)), len(verts) - 1)
                closed.append(gap(verts[k]) / neutral_gap)
        closures += closed
        onset_err += errs
        ok = sum(c < 0.1 for c in closed)
        print(f"| {wav.stem} | {phones[-1].end:.1f} | {len(phones)} | {np.median(np.abs(errs)) * 1000:.0f} | "
              f"{ok}/{len(closed)} |")
    e = np.abs(onset_err) * 1000
    c = np.asarray(closures)
    print(f"\nall clips: median onset error {np.median(e):.1f} ms (90th percentile {np.percentile(e, 90):.0f} ms, "
          f"{len(e)} viseme changes); p/b/m lip gap at the centre frame: max {c.max():.3f} of neutral, "
          f"{(c < 0.1).sum()}/{len(c)} below 10%; phones -> mesh frames {audio_s / anim_s:.0f}x real time "
          f"({anim_s:.2f} s for {audio_s:.1f} s of speech at {args.fps:g} fps)")


if __name__ == "__main__":
    main()
