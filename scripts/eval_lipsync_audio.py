"""Lip sync from audio alone (``faceanim say --audio clip.wav`` without a transcript) against the
forced alignment with the transcript, on the LibriVox clips.

    python scripts/eval_lipsync_audio.py ../shared/data/speech-librivox

Per clip, the phones heard (pocketsphinx's all-phone decoding, :func:`recognise_phones`) and the
phones of the forced alignment with the clip's transcript (:func:`align`, the reference), each
turned into viseme onsets (a phone whose viseme differs from the previous phone's; silence left
out). Reported:

- onset error: for each reference onset, the nearest heard onset of the same viseme within
  200 ms; median and 90th percentile of the absolute time differences (ms) and the share of
  reference onsets matched at all (the rest: a viseme heard as another);
- p/b/m closures: the share of the reference's p, b, m phones that a heard p, b or m overlaps
  (within 50 ms; recall) and the share of heard ones that a reference one overlaps (precision).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from faceanim.drivers.speech import align, phone_viseme, recognise_phones  # noqa: E402

MATCH = 0.2  # seconds: an onset further than this from any heard onset of its viseme is missed
SLACK = 0.05  # seconds: closures overlap within this
BILABIAL = ("P", "B", "M")


def onsets(phones) -> list[tuple[float, int]]:
    out, last = [], None
    for p in phones:
        if p.phone == "SIL":
            last = None
            continue
        v = phone_viseme(p.phone)
        if v != last:
            out.append((p.start, v))
        last = v
    return out


def overlaps(a, others) -> bool:
    return any(o.start - SLACK < a.end and a.start < o.end + SLACK for o in others)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("clips", type=Path, help="the speech-librivox folder (clip-NNNN.wav + clip-NNNN.txt)")
    args = p.parse_args(argv)
    errors, matched, total, recall, precision = [], 0, 0, [], []
    print("| clip | seconds | onsets | matched | median (ms) | p90 (ms) | p/b/m recall | p/b/m precision |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for wav in sorted(args.clips.glob("clip-*.wav")):
        reference = align(wav, wav.with_suffix(".txt").read_text(encoding="utf-8"))
        heard = recognise_phones(wav)
        ref_on, heard_on = onsets(reference), onsets(heard)
        errs = []
        for t, v in ref_on:
            times = np.array([h for h, hv in heard_on if hv == v])
            if len(times) and np.abs(times - t).min() <= MATCH:
                errs.append(float(np.abs(times - t).min()))
        ref_b = [q for q in reference if q.phone in BILABIAL]
        heard_b = [q for q in heard if q.phone in BILABIAL]
        r = np.mean([overlaps(q, heard_b) for q in ref_b]) if ref_b else np.nan
        pr = np.mean([overlaps(q, ref_b) for q in heard_b]) if heard_b else np.nan
        errors += errs
        matched += len(errs)
        total += len(ref_on)
        recall.append(r)
        precision.append(pr)
        print(f"| {wav.stem} | {reference[-1].end:.1f} | {len(ref_on)} | {len(errs) / max(len(ref_on), 1):.0%} | "
              f"{1e3 * np.median(errs):.0f} | {1e3 * np.percentile(errs, 90):.0f} | {r:.2f} | {pr:.2f} |")
    e = np.array(errors)
    print(f"| **all** | | {total} | {matched / max(total, 1):.0%} | {1e3 * np.median(e):.0f} | "
          f"{1e3 * np.percentile(e, 90):.0f} | {np.nanmean(recall):.2f} | {np.nanmean(precision):.2f} |")


if __name__ == "__main__":
    main()
