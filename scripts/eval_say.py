"""What does ``faceanim say`` make the mouth do? Strips, vowel classes and closures (issue 20).

For each sentence the text is spoken (espeak-ng, timed per word as ``say`` does), the lip sync
curves are made on the default face's ARKit shapes and the face is rendered from the front at
every frame; the mouth is measured on the mesh at MediaPipe's landmark points (lip gap 13-14,
mouth width 61-291, rounding = the inner lips' width 78-308 over their gap, in the generic head's
units; the default face has the generic head's topology).

- **Strip** (``--strips DIR``): the rendered face at the middle of each phone, labelled.
- **Vowel classes**: the mouth at the middle of each vowel (a diphthong a third of the way in),
  grouped as open (AA, AE, AY, AW), mid (AH, EH, ER, EY), spread (IY, IH), rounded (AO, OW, UW,
  UH, OY) - the median gap, width and
  rounding per class, and whether each pair of classes differs by more than the spread within
  a class in at least one of the three.
- **Closures**: how many p, b, m have the lips shut at their middle frame; every run of frames inside a word with the lips shut (gap under 0.1 of the
  largest gap) longer than 80 ms where the phones under it are not p, b, m (a closure) or a pause.
- ``--paths arkit,fap``: also the MPEG-4 viseme path (``say -o x.fap`` played on the FAP rig), the
  one ``say`` used for every output before.

- ``--librivox DIR``: the same on recorded speech (each WAV aligned with its transcript), the
  timing a user's own recording gets.
- ``--voices de,es,fr``: the same for sentences of other languages (:data:`LANGUAGES`, spoken by
  that espeak-ng voice; phones from espeak-ng's IPA); vowel classes are measured on every voice.
- ``--recognition``: ``say --audio`` without a transcript hears phones with an English all-phone
  recogniser; how often its viseme class (:data:`VISUAL`) is the true one, per 10 ms of speech, on
  espeak-ng's speech of each voice (the truth: espeak-ng's own phones) and on the LibriVox clips
  (the truth: the forced alignment with the transcript), and how many p/b/m it hears as p/b/m.

Usage (from /work/main): ``python scripts/eval_say.py [--strips DIR] [--paths arkit,fap]
[--voices en-us,de,es,fr] [--recognition] [--librivox ../shared/data/speech-librivox [--only-librivox]]``
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "scripts"))

SENTENCES = ("how now brown cow", "Peter Piper picked a peck of pickled peppers",
             "the quick brown fox jumps over the lazy dog", "we do too, she said, you ought to see it")
LANGUAGES = {  # sentences with many p, b, m, rounded and open vowels
    "de": ("Peter und Paul bauen ein Boot am Meer", "bitte bring mir meine blaue Mappe"),
    "es": ("Pablo bebe mucho vino blanco", "mi madre compra pan en el mercado"),
    "fr": ("Pierre boit une bouteille de bon vin", "ma mère porte un beau pull blanc"),
}
# the mouth's classes for recognition: what the lips and jaw show
VISUAL = {"closed": "P B M", "labiodental": "F V", "rounded": "UW OW AO W UH OY R ER", "open": "AA AE AH AW AY",
          "spread": "IY IH EH EY Y", "dental": "TH DH", "post": "SH ZH CH JH", "tongue": "T D N L K G NG S Z HH"}
VISUAL_OF = {p: k for k, v in VISUAL.items() for p in v.split()}
CLASSES = {"open": ("AA", "AE", "AY", "AW"), "mid": ("AH", "EH", "ER", "EY"), "spread": ("IY", "IH"),
           "rounded": ("AO", "OW", "UW", "UH", "OY")}
DIPHTHONGS = ("AW", "AY", "EY", "OW", "OY")  # measured in their first part (a third of the way in)
CLOSURES = ("P", "B", "M", "SIL")
FPS = 30.0
SHUT = 0.1  # a gap under this share of the clip's largest is a closed mouth
LONG = 0.08  # seconds: a closure longer than this inside a word needs a closing phone


def curves_arkit(face, phones, n):
    from faceanim.drivers.speech.lipsync import lipsync_curves
    from faceanim.rig.arkit import arkit_shapes
    from faceanim.rig.rig import Rig

    shapes, _ = arkit_shapes(face)
    rig = Rig.from_blendshapes(face.mesh, shapes)
    return rig, lipsync_curves(phones, list(rig.controls), FPS, frames=n)


def curves_fap(face, phones, n):
    from faceanim.drivers.speech.visemes import speech_stream
    from faceanim.rig.mpeg4 import FapRig

    rig = FapRig.build(face)
    curves = rig.stream_curves(speech_stream(rig.lip_gap, phones, FPS))
    out = np.zeros((n, curves.shape[1]))
    out[:min(n, len(curves))] = curves[:n]
    return rig, out


def measure(face, rig, curves, size=384):
    """The mouth of each frame on the mesh itself (the generic head's landmark points, which the
    default face shares, in the face's frame, in the generic head's units): MediaPipe on these
    renders misses openings under about 0.008 (the parted lips show pink, not a dark mouth), so
    the renders are for the eye (the strips)."""
    from faceanim.face.generic_head import generic_head
    from faceanim.render import OffscreenRenderer

    head = generic_head()
    rot = face.frame.rotation
    lm = head.landmarks()
    scale = np.linalg.norm(lm[33] - lm[263]) / face.frame.iod
    imgs, out = [], []
    with OffscreenRenderer(face.mesh, size=(size, size), **face.view(yaw=0.0, pitch=0.0)) as r:
        for v in rig.evaluate(curves):
            imgs.append(r.render(v))
            p = head.landmarks(v) @ rot.T * scale
            gap = p[13, 1] - p[14, 1]
            width = abs(p[291, 0] - p[61, 0])
            inner = abs(p[308, 0] - p[78, 0])
            out.append([gap, width, inner / gap if gap > 0.1 * width else np.nan])
    return np.array(out), imgs


def strip(path, imgs, phones):
    import cv2
    import imageio.v3 as iio

    tiles = []
    for p in phones:
        if p.phone == "SIL":
            continue
        k = min(int(round(p.centre * FPS)), len(imgs) - 1)
        img = imgs[k]
        h, w = img.shape[:2]
        tile = img[int(h * 0.5):int(h * 0.9), int(w * 0.25):int(w * 0.75)].copy()
        cv2.putText(tile, p.phone, (6, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (255, 255, 0), 2)
        tiles.append(tile)
    rows = [np.hstack(tiles[i:i + 8] + [np.zeros_like(tiles[0])] * (8 - len(tiles[i:i + 8])))
            for i in range(0, len(tiles), 8)]
    iio.imwrite(path, np.vstack(rows))


def evaluate(face, sentence, how, strips: Path | None, voice: str = "en-us"):
    """``sentence``: text to speak, or a (WAV, transcript) pair of recorded speech (aligned)."""
    import tempfile

    from faceanim.drivers.speech import align, say_timed

    if isinstance(sentence, tuple):
        wav, sentence = sentence
        phones = align(wav, sentence)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            phones = say_timed(sentence, Path(tmp) / "s.wav", voice=voice)
    n = int(np.ceil((max(p.end for p in phones) + 0.2) * FPS)) + 1
    rig, curves = (curves_fap if how == "fap" else curves_arkit)(face, phones, n)
    mouth, imgs = measure(face, rig, curves)
    if strips:
        strips.mkdir(parents=True, exist_ok=True)
        lang = "" if voice == "en-us" else f"{voice}-"
        strip(strips / f"{how}-{lang}{'-'.join(sentence.lower().split()[:3]).replace(',', '')}.png", imgs, phones)
    vowels = []
    for p in phones:
        cls = next((c for c, members in CLASSES.items() if p.phone in members), None)
        if cls:
            at = p.start + (0.3 if p.phone in DIPHTHONGS else 0.5) * (p.end - p.start)
            k = min(int(round(at * FPS)), n - 1)
            vowels.append((cls, *mouth[k]))
    gap = np.nan_to_num(mouth[:, 0], nan=0.0)
    shut = gap < SHUT * max(gap.max(), 1e-9)
    t = np.arange(n) / FPS
    bad = []
    runs = np.split(np.flatnonzero(shut), np.flatnonzero(np.diff(np.flatnonzero(shut)) > 1) + 1)
    for run in runs:
        if len(run) < 2 or (len(run) - 1) / FPS <= LONG:
            continue
        a, b = t[run[0]], t[run[-1]]
        under = [p for p in phones if p.end > a and p.start < b]
        if under and under[0].start <= a and under[-1].end >= b and not any(p.phone in CLOSURES for p in under):
            bad.append((round(a, 2), round(b - a, 2), " ".join(p.phone for p in under)))
    bilabial = [bool(shut[min(int(round(p.centre * FPS)), n - 1)]) for p in phones if p.phone in ("P", "B", "M")]
    return vowels, bad, bilabial


def recognition(ref, heard, length: float) -> tuple[int, int, int, int]:
    """(10 ms steps of speech whose heard class is the true one, steps of speech, p/b/m of the
    truth heard as a p, b or m overlapping it, p/b/m of the truth)."""
    t = np.arange(0.0, length, 0.01) + 0.005

    def classes(phones):
        out = np.full(len(t), "", dtype=object)
        for p in phones:
            out[(t >= p.start) & (t < p.end)] = VISUAL_OF.get(p.phone.rstrip("012"), "")
        return out

    a, b = classes(ref), classes(heard)
    speech = a != ""
    closures = [p for p in ref if p.phone in ("P", "B", "M")]
    found = sum(any(q.phone in ("P", "B", "M") and q.start < p.end + 0.03 and q.end > p.start - 0.03 for q in heard)
                for p in closures)
    return int((a[speech] == b[speech]).sum()), int(speech.sum()), found, len(closures)


def recognition_table(librivox: Path | None, voices: list[str]) -> None:
    import tempfile

    from faceanim.drivers.speech import align, recognise_phones
    from faceanim.drivers.speech.phonemes import espeak_phones
    from faceanim.io.audio import write_wav

    print("\n## say --audio without a transcript (an English all-phone recogniser)\n")
    print("| speech | truth | seconds | viseme class right (10 ms steps) | p/b/m heard |\n|---|---|---:|---:|---:|")
    for voice in voices:
        right = total = found = n = 0
        seconds = 0.0
        for sentence in LANGUAGES.get(voice, SENTENCES):
            x, rate, phones = espeak_phones(sentence, voice)
            with tempfile.TemporaryDirectory() as tmp:
                wav = Path(tmp) / "s.wav"
                write_wav(wav, x, rate)
                heard = recognise_phones(wav)
            r = recognition(phones, heard, len(x) / rate)
            right, total, found, n = right + r[0], total + r[1], found + r[2], n + r[3]
            seconds += len(x) / rate
        print(f"| espeak-ng {voice} | espeak-ng's phones | {seconds:.1f} | {right / total:.0%} | {found}/{n} |")
    if librivox:
        from faceanim.io.audio import read_audio

        right = total = found = n = 0
        seconds = 0.0
        for wav in sorted(librivox.glob("*.wav")):
            x, rate = read_audio(wav)
            r = recognition(align(wav, wav.with_suffix(".txt").read_text()), recognise_phones(wav), len(x) / rate)
            right, total, found, n = right + r[0], total + r[1], found + r[2], n + r[3]
            seconds += len(x) / rate
        print(f"| LibriVox (English, recorded) | forced alignment | {seconds:.1f} | {right / total:.0%} | {found}/{n} |")


def main(argv=None) -> None:
    from faceanim.face.face import Face

    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument("--strips", type=Path, help="write a strip per sentence into this folder")
    ap.add_argument("--librivox", type=Path, help="also (or with --only-librivox, only) the recorded clips of "
                    "this folder (../shared/data/speech-librivox: WAV + transcript, aligned)")
    ap.add_argument("--only-librivox", action="store_true", help="leave the spoken sentences out")
    ap.add_argument("--voices", default="en-us", help="espeak-ng voices to speak with, comma-separated: en-us "
                    "speaks the English sentences, de, es, fr their own (default: en-us)")
    ap.add_argument("--recognition", action="store_true", help="only the recogniser's table (say --audio "
                    "without a transcript) on each voice's speech and the --librivox clips")
    ap.add_argument("--paths", default="arkit", help="arkit (say's lip sync), fap (the MPEG-4 visemes say used "
                    "before, still what it writes to .fap) or both: arkit,fap")
    args = ap.parse_args(argv)
    voices = args.voices.split(",")
    for v in voices:
        if v != "en-us" and v not in LANGUAGES:
            ap.error(f"no sentences for voice {v!r}; give en-us or one of {', '.join(LANGUAGES)}")
    if args.recognition:
        recognition_table(args.librivox, voices)
        return
    face = Face.default()
    for how in args.paths.split(","):
        if how not in ("arkit", "fap"):
            ap.error(f"unknown path {how!r}; give arkit, fap or arkit,fap")
        vowels, closures, bilabials = [], [], []
        inputs = [] if args.only_librivox else [(s, v) for v in voices for s in LANGUAGES.get(v, SENTENCES)]
        if args.librivox:
            inputs += [((wav, wav.with_suffix(".txt").read_text()), "en-us") for wav in sorted(args.librivox.glob("*.wav"))]
        for s, voice in inputs:
            v, bad, shut = evaluate(face, s, how, args.strips, voice)
            vowels += v
            closures += bad
            bilabials += shut
        print(f"\n## {how}\n\n| class | vowels | gap | width | rounding |\n|---|---:|---:|---:|---:|")
        stats = {}
        for cls in CLASSES:
            rows = np.array([v[1:] for v in vowels if v[0] == cls], dtype=float)
            if not len(rows):
                continue
            stats[cls] = rows
            med = np.nanmedian(rows, axis=0)
            print(f"| {cls} | {len(rows)} | {med[0]:.4f} | {med[1]:.4f} | {med[2]:.2f} |")
        names = list(stats)
        apart = []
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                ma, mb = np.nanmedian(stats[a], axis=0), np.nanmedian(stats[b], axis=0)
                spread = np.nanmax([np.nanstd(stats[a], axis=0), np.nanstd(stats[b], axis=0)], axis=0)
                apart.append((a, b, bool(np.any(np.abs(ma - mb) > spread))))
        print("classes told apart (some measure's medians differ by more than a class's spread): "
              + ", ".join(f"{a}/{b} {'yes' if ok else 'NO'}" for a, b, ok in apart))
        print(f"p/b/m with the lips shut at their middle: {sum(bilabials)} of {len(bilabials)}")
        print(f"closures over {LONG * 1000:.0f} ms inside words without p/b/m or a pause: {len(closures)} "
              f"{closures[:6]}")


if __name__ == "__main__":
    main()
