"""Lip sync on a face's ARKit shapes: timed phones -> ARKit curves (``faceanim say``).

Each ARPAbet phone has a mouth target, a mix of ARKit shapes (``data/visemes_arkit.json``,
``phones``): the jaw opened by the vowel's height (AA 0.6 of ``jawOpen``, AE 0.5, EH 0.32, close
vowels 0.06-0.18), lips spread (IY, EH), neutral (AA, AH) or rounded (AO, UW, W: ``mouthFunnel``
and ``mouthPucker``), shut (p, b, m) or tucked under the teeth (f, v). Diphthongs are two targets
(AW: AA then UW). A vowel longer than its inherent duration (stressed) opens the jaw further, a
shorter one less (:data:`STRESS_RANGE`).

Co-articulation follows Cohen & Massaro's dominance model (1993): each phone weighs on the mouth
with a dominance that is flat over the phone and falls off exponentially before and after it
(:data:`VOWEL_FALL`, :data:`CONSONANT_FALL`); at each moment every shape's weight is the
dominance-weighted mean of the phones' targets, separately for the jaw and for the lips. A p/b/m dominates its
neighbours' lips, a t, d, n, l, k or g barely (the lips keep the shape of the vowels around it), so
the mouth keeps moving between words and closes only for a closure or a pause (``SIL``; the
utterance also starts and ends at rest). A p, b or m shuts the lips with ARKit's ``mouthClose``
(the lips together whatever the jaw): over the phone it equals ``jawOpen``, and lets go within
:data:`CLOSE_FALL` around it, so the lips meet even where the vowels around keep the jaw open.
"""

from __future__ import annotations

import json
from functools import lru_cache
from importlib import resources

import numpy as np

from faceanim.drivers.speech.phonemes import INHERENT_MS, Phone
from faceanim.errors import FaceAnimError
from faceanim.limits import check_frames

# seconds: a phone's dominance falls by e every this far outside it: a vowel's spreads wider (its
# lips' rounding reaches over the consonants around it) than a consonant's (a quick gesture)
VOWEL_FALL, CONSONANT_FALL = 0.05, 0.025
CLOSE_FALL = 0.015  # the lips of a p, b, m: shut over the phone, parting this fast around it
REACH = 10 * VOWEL_FALL  # beyond this a phone's dominance is negligible (e^-10)
STRESS_RANGE = (0.75, 1.15)  # the jaw of a vowel scaled by sqrt(duration / inherent), held to this
JAW_SHAPES = ("jawOpen", "mouthClose")  # the shapes the jaw's dominance rules; the lips' rule the rest
REST = 0.06  # seconds the curves go on after the last phone (the sound ends with it)


@lru_cache(maxsize=1)
def _table() -> dict:
    return json.loads(resources.files("faceanim").joinpath("data", "visemes_arkit.json").read_text())


def phone_target(phone: str) -> dict:
    """The mouth of an ARPAbet phone (stress digits ignored): ``{"arkit": {shape: weight}, "lips":
    dominance, "jaw": dominance}``. Unknown phones (noise, breath) are silence."""
    phones = _table()["phones"]
    p = phone.upper().rstrip("012")
    d = phones.get(p, phones["SIL"])
    return phones[d["same_as"]] if "same_as" in d else d


def speech_targets(phones: list[Phone]) -> list[tuple[float, float, dict, str]]:
    """(start, end, target, phone) per phone, diphthongs split into their two parts, a vowel's jaw
    scaled by its length against its inherent duration, with rest (SIL) long before and after."""
    table = _table()
    out = []
    for ph in phones:
        p = ph.phone.upper().rstrip("012")
        start, end = float(ph.start), float(max(ph.end, ph.start + 1e-3))
        if p in table["diphthongs"]:
            first, second, share = table["diphthongs"][p]
            cut = start + share * (end - start)
            parts = [(start, cut, first), (cut, end, second)]
        else:
            parts = [(start, end, p)]
        vowel = p in INHERENT_MS and p[0] in "AEIOU"
        scale = 1.0
        if vowel:
            ratio = (end - start) / (INHERENT_MS[p] / 1000.0)
            scale = float(np.clip(np.sqrt(ratio), *STRESS_RANGE))
        for a, b, name in parts:
            t = phone_target(name)
            arkit = dict(t["arkit"])
            if vowel and "jawOpen" in arkit:
                arkit["jawOpen"] = min(1.0, arkit["jawOpen"] * scale)
            out.append((a, b, {**t, "arkit": arkit}, name))
    if out:
        rest = phone_target("SIL")
        # at rest from well before the first phone until well after the last
        first, last = out[0][0], out[-1][1]
        out = [(first - 2 * REACH, first, rest, "SIL")] + out + [(last, last + 2 * REACH, rest, "SIL")]
    return out


def lipsync_curves(phones: list[Phone], names: list[str], fps: float = 25.0, frames: int | None = None,
                   start: float = 0.0) -> np.ndarray:
    """(F, len(names)) weights of the ARKit shapes ``names`` (Apple's names) over time for timed
    ``phones`` (the module docstring), sampled at ``fps`` from time ``start``; F covers the last
    phone and the rest after it, or is ``frames``."""
    targets = speech_targets(phones)
    if not targets:
        raise FaceAnimError("no speech was found to animate; check the audio and its transcript")
    end = targets[-1][0] + REST
    n = check_frames(int(frames) if frames is not None else int(np.ceil(end * fps)) + 1, "frames of speech")
    col = {name: k for k, name in enumerate(names)}
    jaw = np.array([name in JAW_SHAPES for name in names])
    num = np.zeros((n, len(names)))
    den = np.zeros((n, 2))  # the lips', the jaw's
    closing = np.zeros(n)  # how shut the p, b, m hold the lips
    t = float(start) + np.arange(n) / fps
    for a, b, target, phone in targets:
        lo, hi = np.searchsorted(t, [a - REACH, b + REACH])
        if hi <= lo:
            continue
        tt = t[lo:hi]
        outside = np.maximum(np.maximum(a - tt, tt - b), 0.0)
        fall = np.exp(-outside / (VOWEL_FALL if phone[0] in "AEIOU" else CONSONANT_FALL))
        d_lips, d_jaw = target["lips"] * fall, target["jaw"] * fall
        den[lo:hi, 0] += d_lips
        den[lo:hi, 1] += d_jaw
        if target.get("close_lips"):
            closing[lo:hi] = np.maximum(closing[lo:hi], np.exp(-outside / CLOSE_FALL))
        for shape, w in target["arkit"].items():
            k = col.get(shape)
            if k is not None:
                num[lo:hi, k] += (d_jaw if jaw[k] else d_lips) * w
    den = np.maximum(den, 1e-12)
    out = num / np.where(jaw[None], den[:, 1:2], den[:, 0:1])
    if "jawOpen" in col and "mouthClose" in col:
        k = col["mouthClose"]
        out[:, k] = np.maximum(out[:, k], closing * out[:, col["jawOpen"]])
    return np.clip(out, 0.0, 1.0)


def expression_mix(name: str) -> dict[str, float]:
    """An emotion (joy, sadness, surprise, fear, anger, disgust) as an ARKit mix after its FACS
    prototype (``data/visemes_arkit.json``, ``expressions``)."""
    table = _table()["expressions"]
    if name not in table:
        raise FaceAnimError(f"unknown expression '{name}'; choose one of: {', '.join(table)}")
    return dict(table[name])


def expression_curves(name: str, names: list[str], n_frames: int, fps: float, intensity=1.0,
                      ramp: float = 0.1) -> np.ndarray:
    """(F, len(names)) an expression over the whole clip: held at ``intensity``, rising and falling
    over ``ramp`` seconds at its ends; or, with ``intensity`` an (F,) array, at that intensity
    frame by frame (e.g. :func:`~faceanim.drivers.speech.prosody.emotion_intensity`, phrase by phrase)."""
    t = np.arange(n_frames) / fps
    if np.ndim(intensity):
        envelope = np.asarray(intensity, dtype=np.float64)
        if envelope.shape != (n_frames,):
            raise ValueError(f"an expression's intensity per frame needs {n_frames} values, got {envelope.shape}")
    else:
        duration = max(t[-1], 1e-9) if n_frames else 1e-9
        envelope = float(intensity) * np.clip(np.minimum(t, duration - t) / max(ramp, 1e-9), 0.0, 1.0)
    mix = expression_mix(name)
    out = np.zeros((n_frames, len(names)))
    for k, shape in enumerate(names):
        out[:, k] = mix.get(shape, 0.0) * envelope
    return out
