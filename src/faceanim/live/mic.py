"""Live lip sync from a microphone (``faceanim live --mic [DEVICE]``): PortAudio through the
sounddevice package.

- :func:`find_input` picks the input device: the default one, an index, or a part of a name
  (``--mic pulse``: PortAudio's ALSA host API reaches PulseAudio or PipeWire through ALSA's
  ``pulse`` plugin); each way it can fail is one line of our own (no PortAudio, no input at all,
  no such device, several that match), never PortAudio's text.
- :class:`StreamResampler` brings the device's rate to the lip sync's 16 kHz block by block
  (polyphase rational resampling with a Kaiser-window low-pass designed by scipy). Its delay is
  half the filter, about 1 ms (libsoxr's streaming resampler, which the project's offline
  :func:`~faceanim.io.audio.resample` uses, holds back about 21 ms at 44.1 kHz).
- :class:`MicFeed` records from the device (PortAudio's callback, 10 ms blocks, low latency) into
  a queue; its own thread resamples and feeds the same
  :class:`~faceanim.drivers.speech.stream.LiveLipSync` as a sound file does
  (:class:`~faceanim.live.audio.AudioFeed`), 20 ms at a time. Blocks the device lost (PortAudio's
  input overflow) or that waited longer than :data:`MAX_BACKLOG` (the lip sync fell behind:
  dropped, so the mouth never lags further) are counted as lost. The device gone (unplugged, the
  sound server stopped: PortAudio ends the stream) or silent for :data:`NO_SOUND` seconds (no
  blocks at all) ends the feed with an error saying so.
"""

from __future__ import annotations

import queue
import threading
import time
from dataclasses import dataclass
from math import gcd

import numpy as np

from faceanim.drivers.speech.phonemes import SAMPLE_RATE
from faceanim.errors import FaceAnimError, shown
from faceanim.live.audio import CHUNK, SoundFeed

BLOCK = 0.01  # seconds of sound per PortAudio callback
MAX_BACKLOG = 0.5  # seconds of sound waiting to be fed beyond which the oldest is dropped
NO_SOUND = 3.0  # seconds without a block from the device (once it has given one) that end the feed
FIRST_SOUND = 10.0  # seconds the device may take to give its first block
LISTED = 8  # input devices named in a message at most


class MicError(FaceAnimError):
    """No microphone to be had: PortAudio missing, no input device, an unknown one, or it failed."""


@dataclass(frozen=True)
class InputDevice:
    """A PortAudio input device: its ``index``, ``name``, host API, input channels and default rate."""

    index: int
    name: str
    hostapi: str
    channels: int
    rate: float

    @property
    def label(self) -> str:
        return f"{self.index} '{shown(self.name, 40)}'"


def portaudio():
    """The sounddevice module (PortAudio started), or :class:`MicError` saying what to install."""
    from faceanim.extras import require
    from faceanim.io.files import native_stderr_quiet

    try:
        with native_stderr_quiet():  # ALSA logs its failed probes of the sound cards as PortAudio starts
            return require("sounddevice", "live --mic")
    except OSError:  # sounddevice's "PortAudio library not found", or a library that will not load
        raise MicError("--mic needs the PortAudio library, which is not installed; install it (Debian: apt-get "
                       "install libportaudio2, or bash scripts/setup.sh), or give --audio FILE") from None


def input_devices(sd=None) -> list[InputDevice]:
    """Every device PortAudio can record from."""
    from faceanim.io.files import native_stderr_quiet

    sd = sd or portaudio()
    with native_stderr_quiet():
        devices, apis = sd.query_devices(), sd.query_hostapis()
    return [InputDevice(int(d["index"]), str(d["name"]), str(apis[d["hostapi"]]["name"]),
                        int(d["max_input_channels"]), float(d["default_samplerate"]))
            for d in devices if int(d["max_input_channels"]) > 0]


def _listing(devices: list[InputDevice]) -> str:
    names = ", ".join(d.label for d in devices[:LISTED])
    return names + (f" and {len(devices) - LISTED} more" if len(devices) > LISTED else "")


def find_input(spec: str | None, sd=None) -> InputDevice:
    """The input device ``spec`` names: None or "" the default (else the first input), digits an
    index, anything else a part of a name (case ignored; a whole name wins over parts)."""
    sd = sd or portaudio()
    devices = input_devices(sd)
    if not devices:
        raise MicError("--mic: this machine has no audio input device (PortAudio finds none); plug a microphone "
                       "in or start the sound server (PulseAudio, PipeWire), or give --audio FILE")
    spec = (spec or "").strip()
    if not spec:
        try:
            default = int(sd.default.device[0])
        except (TypeError, ValueError, IndexError):
            default = -1
        return next((d for d in devices if d.index == default), devices[0])
    if spec.isdigit():
        found = [d for d in devices if d.index == int(spec)]
        if not found:
            raise MicError(f"--mic {shown(spec, 12)}: there is no input device {shown(spec, 12)}; the inputs here "
                           f"are {_listing(devices)} (give an index or a part of a name)")
        return found[0]
    key = spec.casefold()
    whole = [d for d in devices if d.name.casefold() == key]
    part = [d for d in devices if key in d.name.casefold()]
    found = whole or part
    if not found:
        raise MicError(f"--mic '{shown(spec, 40)}': no input device has that name; the inputs here are "
                       f"{_listing(devices)} (give an index or a part of a name)")
    if len(found) > 1:
        raise MicError(f"--mic '{shown(spec, 40)}': {len(found)} input devices match ({_listing(found)}); give "
                       "more of the name, or the index")
    return found[0]


class StreamResampler:
    """Mono blocks at ``rate`` Hz to ``to`` Hz, block by block, the same output however the input
    is cut: rational resampling by ``up / down`` in polyphase form. The prototype low-pass (a
    Kaiser-window FIR by scipy, at ``rate * up``) passes to 0.9 of the lower Nyquist frequency and
    is 60 dB down from 1.1 of it; each output sample is one phase of it (about 100 taps) applied to
    the input samples before it. The last input samples are kept for the next block."""

    def __init__(self, rate: float, to: int = SAMPLE_RATE):
        from scipy.signal import firwin, kaiserord

        self.rate, self.to = int(round(rate)), int(to)
        if self.rate <= 0 or self.to <= 0:
            raise ValueError("sample rates must be positive")
        g = gcd(self.rate, self.to)
        self.up, self.down = self.to // g, self.rate // g  # output j is at input j * down / up
        self.consumed = 0  # input samples taken so far
        self.made = 0  # output samples made so far
        self.lag = 0  # output samples of delay
        if self.rate == self.to:
            self.phases = None
            return
        fast = self.rate * self.up  # the rate the prototype filter runs at
        edge = min(self.rate, self.to) / 2
        numtaps, beta = kaiserord(60.0, 0.2 * edge / (fast / 2))
        # the delay a whole number of output samples: (length - 1) / 2 fast samples, a multiple of
        # `down` (fast / to)
        self.lag = -(-(numtaps - 1) // (2 * self.down))
        length = 2 * self.lag * self.down + 1
        h = firwin(length, edge, window=("kaiser", beta), fs=fast) * self.up
        taps_per_phase = -(-length // self.up)
        h = np.r_[h, np.zeros(taps_per_phase * self.up - length)]  # a whole number of taps per phase
        self.phases = h.reshape(taps_per_phase, self.up).T  # phases[r, k] = h[r + k * up]
        self.history = np.zeros(taps_per_phase - 1)  # the input samples before the block

    @property
    def delay(self) -> float:
        """Seconds the output lags the input by (the filter's group delay: :attr:`lag` output samples)."""
        return 0.0 if self.phases is None else self.lag / self.to

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64).ravel()
        if self.phases is None:
            self.consumed += len(x)
            return x.astype(np.float32)
        if not len(x):
            return np.zeros(0, np.float32)
        taps = self.phases.shape[1]
        buf = np.r_[self.history, x]  # buf[i] is input sample consumed - (taps - 1) + i
        newest = self.consumed + len(x) - 1
        end = ((newest + 1) * self.up - 1) // self.down + 1  # every output whose newest input is here
        j = np.arange(self.made, end, dtype=np.int64)
        at = j * self.down  # output j on the fast clock
        n = at // self.up  # the newest input sample under it
        r = at - n * self.up  # the phase
        idx = (n - (self.consumed - (taps - 1)))[:, None] - np.arange(taps)[None, :]
        out = np.einsum("jk,jk->j", self.phases[r], buf[idx])
        self.consumed += len(x)
        self.made = end
        self.history = buf[len(buf) - (taps - 1):]
        return out.astype(np.float32)


class MicFeed(SoundFeed):
    """A microphone into the lip sync (see the module docstring). The device is opened here, so a
    device that cannot record is refused before the run starts; :meth:`start` starts recording."""

    def __init__(self, device: InputDevice, sd=None):
        super().__init__()
        self.sd = sd or portaudio()
        self.device = device
        self.name = f"microphone {device.label}"
        self.dropped = 0  # 20 ms chunks dropped here (the lip sync behind by more than MAX_BACKLOG)
        self.overflows = 0  # blocks before which PortAudio says the device lost sound
        self.blocks = 0  # blocks the device gave
        self.heard = 0.0  # seconds of sound fed
        self.queue: queue.SimpleQueue = queue.SimpleQueue()
        self.resampler = StreamResampler(device.rate)
        self._ended = threading.Event()  # PortAudio ended the stream (not by our stop)
        self._stopping = False
        self.stream = None
        rate = device.rate
        failed = None
        from faceanim.io.files import native_stderr_quiet

        for channels in dict.fromkeys((1, min(2, device.channels))):  # mono, else the device's two, mixed down
            try:
                with native_stderr_quiet():
                    self.stream = self.sd.InputStream(device=device.index, channels=channels, samplerate=rate,
                                                      dtype="float32", blocksize=int(round(BLOCK * rate)),
                                                      latency="low", callback=self._callback,
                                                      finished_callback=self._finished)
                break
            except Exception as exc:  # noqa: BLE001 -- PortAudio's own words are not shown
                failed = exc
        if self.stream is None:
            raise MicError(f"--mic: input device {device.label} cannot record ({type(failed).__name__}); check that "
                           "it is plugged in and that no other program holds it, or pick another with --mic NAME "
                           "or INDEX") from None

    def _callback(self, indata, frames, time_info, status) -> None:
        # PortAudio's thread: copy and go (never block here)
        if status.input_overflow:
            self.overflows += 1
        self.queue.put(indata.mean(axis=1) if indata.shape[1] > 1 else indata[:, 0].copy())

    def _finished(self) -> None:
        if not self._stopping:
            self._ended.set()

    def _gone(self, why: str) -> MicError:
        return MicError(f"the microphone {self.device.label} {why} after {self.heard:.1f} s of sound; check the "
                        "device (unplugged? the sound server stopped?) and start again")

    def _run(self) -> None:
        try:
            self.stream.start()
        except Exception:  # noqa: BLE001 -- PortAudio's own words are not shown
            raise self._gone("would not start") from None
        pending = np.zeros(0, np.float32)
        last = time.monotonic()
        backlog = int(MAX_BACKLOG / BLOCK)
        while not self._stop.is_set():
            if self._ended.is_set() and self.queue.empty():
                raise self._gone("stopped giving sound")
            try:
                block = self.queue.get(timeout=0.05)
            except queue.Empty:
                quiet = NO_SOUND if self.blocks else FIRST_SOUND
                if time.monotonic() - last > quiet:
                    raise self._gone(f"gave no sound for {quiet:g} s") from None
                continue
            last = time.monotonic()
            self.blocks += 1
            waiting = self.queue.qsize()
            if waiting > backlog:  # the lip sync fell behind: drop what waits, so the mouth stays now
                for _ in range(waiting):
                    self.queue.get_nowait()
                self.blocks += waiting
                self.dropped += int(round(waiting * BLOCK * SAMPLE_RATE / CHUNK))
            pending = np.r_[pending, self.resampler(block)]
            while len(pending) >= CHUNK and not self._stop.is_set():
                self._feed(pending[:CHUNK])
                pending = pending[CHUNK:]
                self.heard += CHUNK / SAMPLE_RATE

    def stop(self) -> None:
        self._stopping = True
        super().stop()
        if self.stream is not None:
            try:
                self.stream.abort()
                self.stream.close()
            except Exception:  # noqa: BLE001 -- a device already gone
                pass
