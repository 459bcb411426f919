"""Lip sync as the sound comes: audio in chunks -> phones heard so far -> ARKit mouth curves now.

:class:`PhoneStream` runs pocketsphinx's all-phone decoder (the model and phone bigram that ship
with it, as :func:`~faceanim.drivers.speech.phonemes.recognise_phones` does offline) on chunks of
16 kHz audio and reads its best path after each chunk: the phones heard so far with their times.
The newest phone of that path is still being heard and may yet change; a phone shows up in it
about a tenth of a second after it starts (``benchmarks/bench_live.py``). An utterance is closed
and a new one started at a pause (:data:`PAUSE` of quiet audio after at least :data:`MIN_UTTERANCE`
of sound) and after :data:`MAX_UTTERANCE` at the latest, so the decoder's work per chunk stays
small however long the stream runs (and what is kept, however long it has been quiet). A phone
heard where every 20 ms block under it was quiet (under :data:`QUIET_RMS`: a room's hiss, which
the decoder hears as f or v) is silence: a microphone in a quiet room keeps the mouth shut; but a
quiet p, b or m (:data:`CLOSURES`) stays itself, its closure being silent by nature.

:class:`LiveLipSync` turns the phones into the face's mouth at the present moment with the same
targets and co-articulation as ``faceanim say`` (:func:`~faceanim.drivers.speech.lipsync.lipsync_curves`):
the phones known so far, the one being heard held on until now, evaluated at now (the
co-articulation sees only the past: no anticipation of the next phone). A p, b or m is often
recognised only once it is over (it lasts 50-100 ms, the decoder's delay is about as long):
shown where it was, it would never be seen; so a closure first heard after its end is shown from
the moment it is heard, for its own length (at least :data:`MIN_CLOSURE`).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from faceanim.drivers.speech.lipsync import lipsync_curves
from faceanim.drivers.speech.phonemes import FRAME, SAMPLE_RATE, Phone, SpeechError

PAUSE = 0.25  # seconds of quiet audio that end an utterance
MIN_UTTERANCE = 1.0  # seconds an utterance lasts at least before a pause may end it
MAX_UTTERANCE = 15.0  # seconds after which an utterance is ended whatever the audio
QUIET_RMS = 0.01  # a 20 ms block under this RMS (full scale 1) is quiet
KEEP = 2.0  # seconds of past phones kept for the co-articulation
NOISE = ("+NSN+", "+SPN+", "+BREATH+", "+NOISE+", "<s>", "</s>", "<sil>")
CLOSURES = ("P", "B", "M")
MIN_CLOSURE = 0.06  # seconds a closure heard late is shown


class PhoneStream:
    """pocketsphinx's all-phone decoder over a stream of 16 kHz samples: :meth:`feed` a chunk, then
    :attr:`phones` are the phones heard (times in seconds from the stream's start; the last one is
    still being heard)."""

    def __init__(self):
        from faceanim.extras import require

        pocketsphinx = require("pocketsphinx", "live lip sync")
        Decoder = pocketsphinx.Decoder

        model = Path(os.path.dirname(pocketsphinx.__file__)) / "model" / "en-us"
        try:
            self.dec = Decoder(allphone=str(model / "en-us-phone.lm.bin"), lm=None, samprate=SAMPLE_RATE,
                               loglevel="FATAL", beam=1e-20, pbeam=1e-20, lw=2.0)
        except (RuntimeError, ValueError):
            raise SpeechError("the speech recogniser could not start (pocketsphinx's model is missing); reinstall "
                              "faceanim's dependencies (bash scripts/setup.sh)") from None
        self.done: list[Phone] = []  # phones of closed utterances (and the part of this one kept)
        self.current: list[Phone] = []  # the open utterance's best path so far
        self.offset = 0.0  # the open utterance's start, in stream seconds
        self.heard = 0  # samples fed
        self.quiet = 0  # samples of quiet audio at the end of the stream
        self.loud = 0  # samples of sound in the open utterance
        self.levels = bytearray()  # per 10 ms frame of the open utterance: 1 where its block was loud
        self.dec.start_utt()

    @property
    def time(self) -> float:
        """Seconds of audio fed."""
        return self.heard / SAMPLE_RATE

    @property
    def phones(self) -> list[Phone]:
        return self.done + self.current

    def feed(self, samples: np.ndarray) -> None:
        """Decode a chunk of 16 kHz float samples (full scale 1)."""
        x = np.asarray(samples, dtype=np.float32).ravel()
        if not len(x):
            return
        self.dec.process_raw((np.clip(x, -1, 1) * 32767).astype("<i2").tobytes(), False, False)
        self.heard += len(x)
        block, frame = SAMPLE_RATE // 50, int(FRAME * SAMPLE_RATE)
        at = self.heard - len(x) - int(round(self.offset * SAMPLE_RATE))  # the chunk's start in the utterance
        for k in range(0, len(x), block):
            part = x[k:k + block]
            loud = float(np.sqrt(np.mean(np.square(part, dtype=np.float64)))) >= QUIET_RMS
            if not loud:
                self.quiet += len(part)
            else:
                self.quiet = 0
                self.loud += len(part)
            first, last = (at + k) // frame, -(-(at + k + len(part)) // frame)
            if len(self.levels) < last:
                self.levels.extend(bytes(last - len(self.levels)))
            if loud:
                self.levels[first:last] = b"\x01" * (last - first)
        self.current = self._path()
        length = self.time - self.offset
        if (self.quiet >= PAUSE * SAMPLE_RATE and self.loud >= MIN_UTTERANCE * SAMPLE_RATE) or length >= MAX_UTTERANCE:
            self._restart()

    def _path(self) -> list[Phone]:
        out = []
        for seg in self.dec.seg() or []:
            quiet = not any(self.levels[max(seg.start_frame, 0):seg.end_frame + 1])
            # a quiet p, b or m is the lips shut, as a stop's closure is (it is silent by nature): kept
            name = "SIL" if seg.word in NOISE or (quiet and seg.word not in CLOSURES) else seg.word
            start, end = seg.start_frame * FRAME, (seg.end_frame + 1) * FRAME
            out.append(Phone(name, self.offset + start, self.offset + end, ""))
        return out

    def _restart(self) -> None:
        self.dec.end_utt()
        self.done = [p for p in self.done + self._path() if p.end >= self.time - KEEP]
        self.current = []
        self.offset = self.time
        self.loud = 0
        self.levels = bytearray()
        self.dec.start_utt()


class LiveLipSync:
    """The mouth now (ARKit curves ``names``, Apple's names) from a :class:`PhoneStream`: :meth:`feed`
    16 kHz audio, then :meth:`curves` at any moment up to the audio fed."""

    def __init__(self, names: list[str]):
        self.names = list(names)
        self.stream = PhoneStream()
        self.closures: dict = {}  # (phone, start in 50 ms steps) -> the window it is shown in

    def feed(self, samples: np.ndarray) -> None:
        self.stream.feed(samples)

    def current_phone(self) -> str:
        """The phone being heard now ("SIL" before any)."""
        phones = self.stream.phones
        return phones[-1].phone if phones else "SIL"

    def curves(self, now: float | None = None) -> np.ndarray:
        """(len(names),) the mouth at ``now`` (seconds of the stream; the audio fed so far if None)."""
        now = self.stream.time if now is None else float(now)
        recent = [p for p in self.stream.phones if p.end >= now - KEEP and p.start <= now]
        if not recent or all(p.phone == "SIL" for p in recent):
            return np.zeros(len(self.names))
        last = recent[-1]
        recent[-1] = Phone(last.phone, last.start, max(last.end, now) + 0.1, "")  # still being heard
        for k, p in enumerate(recent):
            if p.phone.rstrip("012") in CLOSURES:
                key = (p.phone, int(round(p.start / 0.05)))
                if key not in self.closures:  # first heard now: where it is, or from now if it is over
                    late = p.end <= now
                    self.closures[key] = (now, now + max(p.end - p.start, MIN_CLOSURE)) if late else (p.start, p.end)
                a, b = self.closures[key]
                recent[k] = Phone(p.phone, a, max(b, p.end if a == p.start else b), "")
        recent.sort(key=lambda p: p.start)
        self.closures = {k: w for k, w in self.closures.items() if w[1] >= now - KEEP}
        return lipsync_curves(recent, self.names, fps=1.0, frames=1, start=now)[0]
