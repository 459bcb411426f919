"""How well do mouth cues read off ARKit curves (``perform -o cues.tsv``) give the mouth's shapes?

There is no recording here whose mouth shapes are known frame by frame, so the classifier of
:func:`faceanim.drivers.cues.arkit_cues` is checked where the truth is known: ``say``'s own ARKit
curves of a sentence (espeak-ng's phones through the lip sync's co-articulation) against the
shapes of the phones under each 10 ms step (:func:`~faceanim.drivers.cues.phone_cues`). Its
thresholds were chosen on :data:`TUNE`; :data:`HELD_OUT` was not used to choose them. A step
counts as agreeing when the shapes are equal, or for G or H (teeth and tongue, which the curves
do not show) read as B or C, or for A and X (both shut) read as each other.

Usage (from /work/main): ``python scripts/eval_cues.py``
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

TUNE = ("how now brown cow", "Peter Piper picked a peck of pickled peppers",
        "the quick brown fox jumps over the lazy dog", "we do too, she said, you ought to see it",
        "father bought a hot pot of soup for you")
HELD_OUT = ("my mother bakes bread on Mondays", "would you like a cup of warm milk",
            "five violet moths flew past the old oak tree", "she sells sea shells by the sea shore",
            "a big black bug bit a big black bear")
FPS = 100.0
SHAPES = "ABCDEFGHX"


def agreement(sentences) -> tuple[float, dict]:
    from faceanim.drivers.cues import arkit_cues, phone_cues
    from faceanim.drivers.speech.lipsync import lipsync_curves
    from faceanim.drivers.speech.phonemes import espeak_phones

    from faceanim.standards.arkit import APPLE_NAMES

    names = list(APPLE_NAMES)
    confusion: dict = {}
    total = agree = 0
    for s in sentences:
        x, rate, phones = espeak_phones(s)
        curves = lipsync_curves(phones, names, FPS, frames=int(len(x) / rate * FPS))
        truth = phone_cues(phones)
        starts = np.array([t for t, _ in truth])
        for t, got in arkit_cues(curves, names, FPS):
            k = np.searchsorted(starts, t, side="right") - 1
            want = truth[k][1] if k >= 0 else "X"
            confusion[(want, got)] = confusion.get((want, got), 0) + 1
            total += 1
            agree += (want == got or (want in "GH" and got in "BC") or {want, got} == {"A", "X"})
    return agree / total, confusion


def main() -> None:
    for label, sentences in (("tuning sentences", TUNE), ("held-out sentences", HELD_OUT)):
        share, confusion = agreement(sentences)
        print(f"\n## {label}: {share:.0%} of 10 ms steps agree\n")
        print("| phones' shape \\ read off the curves | " + " | ".join(SHAPES) + " |")
        print("|---|" + "---:|" * len(SHAPES))
        for want in SHAPES:
            print(f"| {want} | " + " | ".join(str(confusion.get((want, g), 0)) for g in SHAPES) + " |")


if __name__ == "__main__":
    main()
