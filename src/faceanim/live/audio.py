"""Live lip sync: a sound file played in real time, or a microphone, drives the mouth, alone or
with a video's face.

- :class:`AudioFeed` plays a sound (any file :func:`~faceanim.io.audio.read_audio` reads) in real
  time in its own thread, 20 ms at a time, into a
  :class:`~faceanim.drivers.speech.stream.LiveLipSync`: the phones heard so far, the mouth now;
  :class:`faceanim.live.mic.MicFeed` does the same with a microphone (both :class:`SoundFeed`).
- :class:`AudioSource` is a source of ticks (30 a second) for a run with no video (a file's or a
  microphone's feed): each tick carries the face's ARKit curves at that moment, the mouth from the
  lip sync and the brows, blinks and looks from the voice's prosody
  (:class:`~faceanim.drivers.speech.prosody.LiveProsody`: brows on pitch accents, blinks at
  pauses), with the head's nods and leans per phrase; :class:`IdleFace` adds a slow head sway so
  the avatar is never still (deterministic: the same sound gives the same curves).
- :func:`merge_mouth` puts the sound's mouth into a video frame's curves (``--mouth``).
"""

from __future__ import annotations

import threading
import time
from abc import ABC, abstractmethod

import numpy as np

from faceanim.drivers.speech.phonemes import SAMPLE_RATE
from faceanim.drivers.speech.prosody import BLINKS, BROWS, LOOKS, LiveProsody
from faceanim.drivers.speech.stream import LiveLipSync
from faceanim.errors import FaceAnimError
from faceanim.standards.arkit import APPLE_NAMES, ARKIT_NAMES
from faceanim.live.performer import LiveSample
from faceanim.live.sources import Frame, Source

APPLE = list(APPLE_NAMES)
MOUTH = np.array([n.startswith(("Jaw", "Mouth")) for n in ARKIT_NAMES])  # the curves the lip sync drives
UPPER = np.array([n in BROWS + BLINKS + LOOKS for n in APPLE_NAMES])  # and those the voice's prosody drives
CLOSE = ARKIT_NAMES.index("MouthClose")
CHUNK = SAMPLE_RATE // 50  # 20 ms of audio per step
TICK_FPS = 30.0
HEAD_SWAY = ((0.21, 2.0), (0.13, 1.5), (0.08, 0.8))  # (Hz, degrees) of yaw, pitch and roll


def read_sound(path) -> np.ndarray:
    """A sound file as 16 kHz float samples; refused when silent."""
    from faceanim.drivers.speech.phonemes import SILENT_RMS
    from faceanim.io.audio import read_audio, resample

    x, rate = read_audio(path, "sound")
    x = resample(x, rate, SAMPLE_RATE)
    if not len(x) or float(np.sqrt(np.mean(np.square(x, dtype=np.float64)))) < SILENT_RMS:
        raise FaceAnimError("the sound is silent; give a recording of someone speaking")
    return x


class SoundFeed(ABC):
    """A sound fed into a lip sync and the voice's prosody in its own thread, 20 ms at a time:
    :meth:`curves` is the face now (the (52,) ARKit curves in Live Link order: the mouth, the
    brows, the blinks and the looks away, and an emotion if it :meth:`carry`-ies one; 0
    elsewhere), :meth:`head` the head's angles.
    ``error``: why it stopped early (a :class:`~faceanim.errors.FaceAnimError`: a microphone
    gone), else None; ``chunks``: 20 ms chunks fed so far. Subclasses feed in :meth:`_run`
    (:class:`AudioFeed`, :class:`faceanim.live.mic.MicFeed`)."""

    name = "sound"

    def __init__(self, seconds: float | None = None):
        self.lipsync = LiveLipSync(APPLE)
        self.prosody = LiveProsody(SAMPLE_RATE)
        self.lock = threading.Lock()
        self.started: float | None = None
        self.seconds = seconds
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: Exception | None = None
        self.chunks = 0
        self.emotion: np.ndarray | None = None  # (52,) an emotion's ARKit mix at its intensity, or None

    def carry(self, emotion: str, intensity: float) -> None:
        """Carry ``emotion`` (an expression's name, :func:`~faceanim.drivers.speech.lipsync.expression_mix`)
        at ``intensity`` while speaking, phrase by phrase (:attr:`LiveProsody.emotion_level`)."""
        from faceanim.drivers.speech.lipsync import expression_mix

        mix = expression_mix(emotion)
        self.emotion = float(intensity) * np.array([mix.get(n, 0.0) for n in APPLE])

    @property
    def duration(self) -> float:
        """Seconds of sound there are (inf for a microphone)."""
        return np.inf

    def start(self) -> None:
        self.started = time.monotonic()
        self._thread = threading.Thread(target=self._guarded, name=f"faceanim live {self.name}", daemon=True)
        self._thread.start()

    def _guarded(self) -> None:
        try:
            self._run()
        except Exception as exc:  # noqa: BLE001 -- reported by the run (a FaceAnimError says what)
            self.error = exc

    @abstractmethod
    def _run(self) -> None:
        """Feed the sound, chunk by chunk, with :meth:`_feed` until it ends or :meth:`stop`."""

    def _feed(self, samples: np.ndarray) -> None:
        with self.lock:
            self.lipsync.feed(samples)
            self.prosody.feed(samples)
        self.chunks += 1

    def curves(self) -> np.ndarray:
        with self.lock:
            mouth = self.lipsync.curves()
            upper = self.prosody.curves(APPLE)
            level = self.prosody.emotion_level
        out = np.zeros(len(ARKIT_NAMES))
        out[MOUTH] = mouth[MOUTH]
        out[UPPER] = upper[UPPER]
        if self.emotion is not None:
            out = np.clip(out + level * self.emotion, 0.0, 1.0)
        return out

    def head(self) -> np.ndarray:
        """(3,) the head's yaw, pitch, roll (radians) the voice gives now."""
        with self.lock:
            return self.prosody.head()

    @property
    def finished(self) -> bool:
        return self._thread is not None and not self._thread.is_alive()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)


class AudioFeed(SoundFeed):
    """A sound file's samples (16 kHz) played in real time into the lip sync; ``seconds`` stops it
    early."""

    def __init__(self, samples: np.ndarray, seconds: float | None = None, name: str = "sound"):
        super().__init__(seconds)
        self.samples = samples
        self.name = name

    @property
    def duration(self) -> float:
        return len(self.samples) / SAMPLE_RATE

    def _run(self) -> None:
        end = len(self.samples) if self.seconds is None else min(len(self.samples), int(self.seconds * SAMPLE_RATE))
        for k in range(0, end, CHUNK):
            wait = self.started + (k + CHUNK) / SAMPLE_RATE - time.monotonic()
            if wait > 0 and self._stop.wait(wait):
                return
            self._feed(self.samples[k:min(k + CHUNK, end)])


class IdleFace:
    """A slow head sway for a face driven by sound alone, under the voice's nods and leans; the
    same every run (a fixed seed)."""

    def __init__(self, seed: int = 7):
        rng = np.random.default_rng(seed)
        self.phase = rng.uniform(0, 2 * np.pi, size=3)

    def at(self, t: float) -> np.ndarray:
        """The head's yaw, pitch, roll sway in radians at ``t`` seconds."""
        return np.array([np.radians(a) * np.sin(2 * np.pi * f * t + p) for (f, a), p in zip(HEAD_SWAY, self.phase)])


class AudioSource(Source):
    """Ticks at :data:`TICK_FPS` while a :class:`SoundFeed` plays (no picture): each :class:`Frame`
    has no image and the mouth's curves as ``mouth``. The run ends with the sound (a file's end,
    ``seconds``), or when the feed fails (a microphone gone: the run's error says why)."""

    images = False

    def __init__(self, feed: SoundFeed, seconds: float | None = None):
        super().__init__()
        self.feed = feed
        self.fps = TICK_FPS
        self.name = feed.name
        self.length = min(self.feed.duration, seconds if seconds is not None else np.inf)

    @classmethod
    def of_file(cls, path, seconds: float | None = None) -> AudioSource:
        """A sound file played in real time (refused when silent)."""
        from pathlib import Path

        return cls(AudioFeed(read_sound(path), seconds, Path(path).name), seconds)

    def _run(self) -> None:
        self.feed.start()
        i = 0
        try:
            while not self._stop.is_set():
                due = self.feed.started + (i + 1) / self.fps
                wait = due - time.monotonic()
                if wait > 0 and self._stop.wait(wait):
                    return
                if self.feed.error is not None:
                    raise self.feed.error
                if i / self.fps >= self.length:
                    return
                self.slot.put(Frame(i, time.monotonic(), i / self.fps, None, self.feed.curves(), self.feed.head()))
                i += 1
        finally:
            self.feed.stop()


def sound_sample(curves: np.ndarray, head: np.ndarray, t: float, idle: IdleFace) -> LiveSample:
    """A frame of a face driven by sound alone: the sound's curves (mouth, brows, blinks), its head
    motion over the idle sway."""
    from faceanim.perform import EYE_CONTROLS, eye_angles

    arkit = np.clip(np.array(curves, dtype=np.float64), 0.0, 1.0)
    eyes = eye_angles(arkit[[APPLE.index(n) for n in EYE_CONTROLS[2:]]])  # the looks away as the eyes' angles
    return LiveSample(t, False, np.zeros(0), arkit, np.asarray(head, dtype=np.float64) + idle.at(t), eyes)


def merge_mouth(sample: LiveSample, mouth: np.ndarray, how: str) -> None:
    """Put the sound's ``mouth`` into a video frame's ARKit curves (in place): ``audio`` replaces the
    video's mouth and jaw, ``both`` averages them (the lips shut when either shuts them), ``video``
    leaves them."""
    if how == "video":
        return
    a = sample.arkit.copy()
    if how == "audio":
        a[MOUTH] = mouth[MOUTH]
    else:
        a[MOUTH] = 0.5 * (a[MOUTH] + mouth[MOUTH])
        a[CLOSE] = max(sample.arkit[CLOSE], mouth[CLOSE])
    sample.arkit = np.clip(a, 0.0, 1.0)
