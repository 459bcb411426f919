"""Rhubarb Lip Sync's cue files: the mouth shape (A-H, X) from each moment on.

``.tsv``: one line per cue, its start in seconds (two decimals), a tab, its shape; the first at 0.00,
the last line the recording's end with the mouth at rest (X). ``.json``: ``{"metadata":
{"soundFile", "duration"}, "mouthCues": [{"start", "end", "value"}, ...]}``, each cue ending where
the next starts. Times are multiples of 0.01 s (the duration truncated to one), as Rhubarb writes
them, so a tool that reads Rhubarb's output reads these.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from faceanim.errors import FaceAnimError
from faceanim.io.files import atomic_output
from faceanim.standards.rhubarb import CUE_SUFFIXES, SHAPES


def hundredths(seconds: float) -> int:
    """A time as Rhubarb writes it: truncated to 0.01 s, in hundredths."""
    return int(math.floor(float(seconds) * 100 + 1e-6))


def tidy_cues(cues: list[tuple[float, str]], duration: float) -> list[tuple[int, int, str]]:
    """(start, end, shape) in hundredths from (start seconds, shape) pairs: from 0 to the duration,
    rest (X) before the first, equal neighbours merged, cues shorter than 0.01 s dropped."""
    end = hundredths(duration)
    if end < 1:
        raise FaceAnimError("the cues would cover less than 0.01 s; give longer speech")
    out: list[list] = [[0, "X"]]
    for start, shape in sorted(((hundredths(s), v) for s, v in cues), key=lambda c: c[0]):
        if shape not in SHAPES:
            raise FaceAnimError(f"'{shape}' is not a Rhubarb mouth shape; they are {', '.join(SHAPES)}")
        start = min(max(start, 0), end)
        if start == out[-1][0]:
            out[-1][1] = shape
        elif shape != out[-1][1]:
            out.append([start, shape])
    merged: list[list] = []
    for start, shape in out:  # a shape overwritten at the same time may now equal the one before
        if not merged or shape != merged[-1][1]:
            merged.append([start, shape])
    starts = [c[0] for c in merged] + [end]
    return [(a, b, shape) for (a, shape), b in zip(merged, starts[1:]) if b > a]


def write_cues(path, cues: list[tuple[float, str]], duration: float, sound_file: str = "") -> Path:
    """Write ``cues`` ((start seconds, shape) in time order, each until the next) over ``duration``
    seconds as Rhubarb's ``.tsv`` or ``.json`` (by the suffix); ``sound_file`` is the JSON's
    ``metadata.soundFile``."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in CUE_SUFFIXES:
        raise FaceAnimError(f"mouth cues are written to .tsv or .json, not '{suffix}'")
    rows = tidy_cues(cues, duration)
    if suffix == ".tsv":
        text = "".join(f"{a / 100:.2f}\t{shape}\n" for a, _, shape in rows) + f"{rows[-1][1] / 100:.2f}\tX\n"
    else:
        doc = {"metadata": {"soundFile": str(sound_file), "duration": round(rows[-1][1] / 100, 2)},
               "mouthCues": [{"start": round(a / 100, 2), "end": round(b / 100, 2), "value": shape}
                             for a, b, shape in rows]}
        text = json.dumps(doc, indent=2) + "\n"
    with atomic_output(path, "mouth cue file") as tmp:
        tmp.write_text(text, encoding="utf-8", newline="\n")
    return path


def cue_sound(cues_path) -> Path:
    """Where the sound of a cue file goes when faceanim made the sound: the file an earlier JSON of
    ours names in ``metadata.soundFile`` (we wrote it: it is replaced), else ``OUT.wav``, else
    ``OUT-1.wav``, ... - never a file the user did not name or we did not write."""
    import os

    out = Path(cues_path)
    if out.suffix.lower() == ".json" and out.is_file() and out.stat().st_size < 1 << 24:
        try:
            named = json.loads(out.read_text(encoding="utf-8"))["metadata"]["soundFile"]
        except (ValueError, KeyError, TypeError, OSError, UnicodeDecodeError):
            named = None
        if isinstance(named, str) and Path(named).name == named and named.lower().endswith(".wav") \
                and os.path.isfile(out.with_name(named)) and not os.path.islink(out.with_name(named)):
            return out.with_name(named)
    candidate, k = out.with_suffix(".wav"), 1
    while os.path.lexists(candidate):
        candidate = out.with_name(f"{out.stem}-{k}.wav")
        k += 1
    return candidate
