"""faceanim live --mic: a microphone heard live (PortAudio through sounddevice).

End to end, the microphone is a virtual one: a private PulseAudio server (tests/pulse_loopback.py)
with a null sink whose monitor is the default source; the test plays a WAV into the sink
(``pacat``) and ``faceanim live --mic pulse`` records the monitor through ALSA's pulse plugin.
The oracles are the WAV's own: its loud and quiet stretches (the mouth must open in the one and
shut in the other, at a single delay found by matching the two) and the p, b, m of its clips
aligned offline with their transcripts (the lips must press there). Each test of the command
skips only when no PulseAudio server can be started here.

Unit tests: the streaming resampler against libsoxr on the whole signal (and against itself cut
differently), the choice of the input device on device lists made up for the test, the lip sync
through minutes of silence and of clipped noise (bounded, clean).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from faceanim.io.arkit_csv import read_arkit_csv
from faceanim.standards.arkit import ARKIT_NAMES

from pulse_loopback import PulseLoopback, PulseUnavailable

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
SPEECH = DATA / "speech-librivox"
needs_speech = pytest.mark.skipif(not (SPEECH / "clip-0870.wav").exists(), reason="needs ../shared/data/speech-librivox")
JAW, CLOSE, PRESS = (ARKIT_NAMES.index(n) for n in ("JawOpen", "MouthClose", "MouthPressLeft"))
RAW_PORTAUDIO = ("Expression '", "pa_linux_alsa", "PaAlsa", "PaErrorCode", "ALSA lib")


def _start_loopback(folder: Path) -> PulseLoopback:
    try:
        return PulseLoopback(folder).start()
    except PulseUnavailable as exc:
        pytest.skip(f"no PulseAudio server can be started here, so no virtual microphone: {exc}")


@pytest.fixture(scope="module")
def loopback(tmp_path_factory):
    lb = _start_loopback(tmp_path_factory.mktemp("pulse"))
    yield lb
    lb.stop()


def _live(*args, env=None, timeout=120):
    return subprocess.run([sys.executable, "-m", "faceanim", "live", *args], capture_output=True, text=True,
                          timeout=timeout, env=env)


def _popen(*args, env):
    return subprocess.Popen([sys.executable, "-m", "faceanim", "live", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env={**env, "OPENBLAS_NUM_THREADS": "1"})


def _recording(lb: PulseLoopback, timeout: float = 60.0) -> float:
    """time.monotonic() once a program records from the server (a source output exists)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if lb.pactl("list", "short", "source-outputs").stdout.strip():
            return time.monotonic()
        time.sleep(0.02)
    raise AssertionError("faceanim live never started recording")


class VmcClock:
    """A VMC receiver on 127.0.0.1 that notes when each frame arrives (time.monotonic()) beside the
    time it carries (the run's clock, which the file sink's rows are on): :attr:`offset` maps the
    run's seconds to this process's monotonic clock."""

    def __init__(self):
        import socket
        import threading

        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.1)
        self.port = self.sock.getsockname()[1]
        self.frames: list[tuple[float, float]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        import socket

        from faceanim.io.vmc import decode_frame

        while not self._stop.is_set():
            try:
                data = self.sock.recv(65536)
            except socket.timeout:
                continue
            self.frames.append((time.monotonic(), decode_frame(data)["time"]))

    @property
    def offset(self) -> float:
        arrived, sent = np.array(self.frames).T
        return float(np.median(arrived - sent))

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.sock.close()


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert not any(raw in err for raw in RAW_PORTAUDIO), err  # our words, never PortAudio's
    return lines[0]


# -- the streaming resampler -----------------------------------------------------------------------
def _test_signal(rate: int, seconds: float = 1.0) -> np.ndarray:
    """A chirp from 100 Hz to 0.8 of the lower Nyquist frequency, a tone and a little noise."""
    rng = np.random.default_rng(5)
    t = np.arange(int(rate * seconds)) / rate
    top = 0.4 * min(rate, 16000)
    chirp = np.sin(2 * np.pi * (100 * t + 0.5 * (top - 100) / seconds * t ** 2))
    return (0.4 * chirp + 0.2 * np.sin(2 * np.pi * 440 * t) + 0.01 * rng.standard_normal(len(t))).astype(np.float32)


@pytest.mark.parametrize("rate", [44100, 48000, 22050, 32000, 16000, 8000])
def test_stream_resampler_is_libsoxr_on_the_whole_and_deaf_to_the_cuts(rate):
    from faceanim.io.audio import resample
    from faceanim.live.mic import StreamResampler

    x = _test_signal(rate)
    whole = StreamResampler(rate)(x)
    rng = np.random.default_rng(rate)
    cuts = np.cumsum(rng.integers(1, 700, size=len(x)))
    cuts = cuts[cuts < len(x)]
    r = StreamResampler(rate)
    pieces = np.concatenate([r(p) for p in np.split(x, cuts)])
    assert np.allclose(pieces, whole, atol=1e-6)  # the same samples however the blocks come
    want = resample(x, rate, 16000)  # libsoxr, the whole signal at once
    n = len(x) * 16000 // rate
    assert abs(len(whole) - n) <= 1
    assert r.lag == round(r.delay * 16000) and r.delay <= 0.0025  # a whole number of samples, 1-2.5 ms
    got = whole[r.lag:r.lag + n - 200]
    ref = want[:len(got)]
    assert np.sqrt(np.mean((got - ref)[100:] ** 2)) < 0.01 * np.sqrt(np.mean(ref ** 2))


def test_stream_resampler_stops_what_16_khz_cannot_hold():
    from faceanim.live.mic import StreamResampler

    rate = 48000
    t = np.arange(rate) / rate
    for hz, gain in ((3000, 1.0), (7000, 1.0), (10000, 0.0), (15000, 0.0)):
        y = StreamResampler(rate)(np.sin(2 * np.pi * hz * t).astype(np.float32))[2000:]
        assert np.sqrt(2 * np.mean(y ** 2)) == pytest.approx(gain, abs=0.02), hz  # 10 kHz would fold onto 6 kHz


# -- which device ----------------------------------------------------------------------------------
class FakePortAudio:
    """What sounddevice answers about a machine's devices (made up for the test)."""

    def __init__(self, devices, default=-1):
        self.devices = [dict(index=i, name=n, hostapi=0, max_input_channels=c, default_samplerate=48000.0)
                        for i, (n, c) in enumerate(devices)]

        class Default:
            device = [default, -1]

        self.default = Default()

    def query_devices(self):
        return self.devices

    def query_hostapis(self):
        return ({"name": "ALSA"},)


def test_find_input_by_default_index_and_name():
    from faceanim.live.mic import MicError, find_input

    sd = FakePortAudio([("HDA Intel PCH: ALC3246 Analog (hw:0,0)", 2), ("HDMI 0", 0), ("USB Audio Mic (hw:1,0)", 1),
                        ("pulse", 32), ("pulse monitor", 32), ("default", 32)], default=5)
    assert find_input(None, sd).name == "default"
    assert find_input("", sd).index == 5
    assert find_input("2", sd).name.startswith("USB")
    assert find_input("usb", sd).index == 2  # a part of the name, case ignored
    assert find_input("PULSE", sd).index == 3  # a whole name wins over the names it is part of
    assert find_input(None, FakePortAudio([("HDMI", 0), ("USB Mic", 1)])).name == "USB Mic"  # no default: the first
    for spec, phrase in (("1", "no input device 1"), ("9", "no input device 9"), ("speaker", "no input device has"),
                         ("pulse m", None), ("a", "input devices match")):
        if phrase is None:
            assert find_input(spec, sd).index == 4
            continue
        with pytest.raises(MicError, match=phrase) as err:
            find_input(spec, sd)
        assert "\n" not in str(err.value) and "--mic" in str(err.value)
        if "match" not in phrase:
            assert "2 'USB Audio Mic (hw:1,0)'" in str(err.value) and "HDMI" not in str(err.value)
    with pytest.raises(MicError, match="no audio input device"):
        find_input(None, FakePortAudio([("HDMI 0", 0)]))


class FakeStream:
    """sounddevice's InputStream as MicFeed uses it: the test calls the callback itself."""

    def __init__(self, **kw):
        self.kw, self.started, self.closed = kw, False, False

    def start(self):
        self.started = True

    def abort(self):
        pass

    def close(self):
        self.closed = True

    def give(self, block: np.ndarray, overflow: bool = False) -> None:
        class Status:
            input_overflow = overflow

        self.kw["callback"](block.reshape(len(block), -1).astype(np.float32), len(block), None, Status())


def _mic(monkeypatch, channels=1):
    from faceanim.live.mic import InputDevice, MicFeed

    sd = FakePortAudio([("USB Mic", channels)])
    sd.InputStream = FakeStream
    return MicFeed(InputDevice(0, "USB Mic", "ALSA", channels, 48000.0), sd=sd)


def _wait(cond, timeout=10.0):
    end = time.monotonic() + timeout
    while not cond() and time.monotonic() < end:
        time.sleep(0.01)
    return cond()


def test_mic_feed_hears_blocks_drops_a_backlog_and_says_when_the_device_goes(monkeypatch):
    """MicFeed on a stand-in for PortAudio: 48 kHz stereo blocks are mixed down, resampled and fed
    20 ms at a time; a backlog beyond MAX_BACKLOG is dropped and counted; overflows are counted;
    the stream ended by PortAudio, or silent, ends the feed with an error of our own."""
    from faceanim.live import mic
    from faceanim.live.mic import MAX_BACKLOG, MicError

    feed = _mic(monkeypatch, channels=2)
    assert feed.stream.kw["channels"] == 1 and feed.stream.kw["samplerate"] == 48000.0
    assert feed.stream.kw["blocksize"] == 480
    rng = np.random.default_rng(2)
    backlog = [rng.standard_normal((480, 2)) * 0.1 for _ in range(int(MAX_BACKLOG / 0.01) + 40)]
    for b in backlog:  # all waiting before the feed starts: more than MAX_BACKLOG behind
        feed.stream.give(b)
    feed.stream.give(np.zeros((480, 2)), overflow=True)
    feed.start()
    assert _wait(lambda: feed.blocks == len(backlog) + 1)
    assert feed.stream.started and feed.dropped >= 0.5 * MAX_BACKLOG / 0.02 and feed.overflows == 1
    heard, dropped = feed.chunks, feed.dropped
    for _ in range(10):  # a second of sound as it comes, 0.1 s at a time
        for _ in range(10):
            feed.stream.give(np.full((480, 2), 0.05))
        assert _wait(lambda: feed.queue.empty())
    assert _wait(lambda: feed.chunks >= heard + 49) and feed.dropped == dropped
    assert feed.error is None and np.all(np.isfinite(feed.curves()))
    feed.stream.kw["finished_callback"]()  # PortAudio ended the stream: the device is gone
    assert _wait(lambda: feed.finished)
    assert isinstance(feed.error, MicError) and "stopped giving sound after" in str(feed.error)
    feed.stop()
    assert feed.stream.closed

    monkeypatch.setattr(mic, "NO_SOUND", 0.3)
    feed = _mic(monkeypatch)
    feed.start()
    feed.stream.give(np.zeros(480))
    assert _wait(lambda: feed.finished)
    assert isinstance(feed.error, MicError) and "gave no sound for 0.3 s" in str(feed.error)
    feed.stop()


# -- the lip sync through silence and noise ----------------------------------------------------------
def test_lip_sync_through_minutes_of_silence_and_clipping_stays_bounded_and_at_rest():
    """Three minutes of a quiet room (noise 50 dB under full scale), then 20 s of noise clipped at
    full scale: the utterance is closed at MAX_UTTERANCE at the latest, the phones kept stay few,
    the curves finite in [0, 1], and the mouth at rest while the room is quiet."""
    from faceanim.drivers.speech.stream import KEEP, MAX_UTTERANCE, LiveLipSync
    from faceanim.live.audio import APPLE

    ls = LiveLipSync(APPLE)
    rng = np.random.default_rng(3)
    longest, most, moved = 0.0, 0, 0
    quiet_chunks = 180 * 50
    for k in range(quiet_chunks + 20 * 50):
        loud = k >= quiet_chunks
        x = np.clip(rng.standard_normal(320) * (3.0 if loud else 0.003), -1, 1).astype(np.float32)
        ls.feed(x)
        c = ls.curves()
        assert np.all(np.isfinite(c)) and c.min() >= 0.0 and c.max() <= 1.0
        longest = max(longest, ls.stream.time - ls.stream.offset)
        most = max(most, len(ls.stream.phones), len(ls.closures))
        moved += (not loud) and c.max() > 0.02
    assert longest <= MAX_UTTERANCE + 0.021  # a new utterance at least every 15 s
    assert most <= (KEEP + MAX_UTTERANCE) / 0.03  # phones of 30 ms at least: the last seconds, not the stream
    assert ls.stream.time == pytest.approx(200.0)
    assert moved == 0  # a quiet room keeps the mouth shut


# -- the command, bad input ------------------------------------------------------------------------
def test_live_mic_without_the_portaudio_library(tmp_path):
    """sounddevice finds no PortAudio (ctypes' find_library, hidden here as on a machine without
    libportaudio2): one line saying what to install, exit 2, nothing written."""
    hide = tmp_path / "hide"
    hide.mkdir()
    (hide / "sitecustomize.py").write_text(
        "import ctypes.util\n_find = ctypes.util.find_library\n"
        "ctypes.util.find_library = lambda name: None if 'portaudio' in name else _find(name)\n")
    out = tmp_path / "out" / "take.csv"
    out.parent.mkdir()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(hide), os.environ.get("PYTHONPATH", "")])}
    r = _live("--mic", "--to", f"file:{out}", "--seconds", "2", env=env)
    assert r.returncode == 2
    line = _one_line(r.stderr)
    assert "PortAudio" in line and "libportaudio2" in line and "--audio" in line
    assert not list(out.parent.iterdir())


def test_live_mic_without_any_input_device(tmp_path):
    """No sound card and no sound server (PULSE_SERVER names none, ALSA's pulse device cannot
    open): PortAudio lists no input, and the command says so."""
    cards = Path("/proc/asound/cards")
    if cards.exists() and "no soundcards" not in cards.read_text() and cards.read_text().strip():
        pytest.skip("this machine has a sound card, so it has input devices")
    (tmp_path / "client.conf").write_text("autospawn = no\n")
    env = {**os.environ, "PULSE_SERVER": f"unix:{tmp_path / 'none'}", "PULSE_CLIENTCONFIG": str(tmp_path / "client.conf")}
    out = tmp_path / "take.csv"
    for mic in ([], ["pulse"], ["0"]):
        r = _live("--mic", *mic, "--to", f"file:{out}", env=env)
        assert r.returncode == 2
        assert "no audio input device" in _one_line(r.stderr)
    assert not out.exists()


def test_live_mic_refuses_unknown_devices_and_other_sounds(loopback, tmp_path):
    out = tmp_path / "take.csv"
    for mic, phrase in (("nosuchdevice", "no input device has that name"), ("99", "there is no input device 99")):
        r = _live("--mic", mic, "--to", f"file:{out}", env=loopback.env)
        assert r.returncode == 2
        line = _one_line(r.stderr)
        assert phrase in line and "'pulse'" in line  # the devices there are
    for args, phrase in ((["--mic", "--audio", "x.wav"], "not both"), (["--mic", "--mouth", "audio"], "--mouth"),
                         (["--mic", "pulse", "--to", "file:x.txt"], "--to")):
        r = _live(*args, *([] if "--to" in args else ["--to", f"file:{out}"]), env=loopback.env)
        assert r.returncode == 2 and phrase in _one_line(r.stderr)
    assert not list(tmp_path.iterdir())


# -- the command, end to end with a virtual microphone ---------------------------------------------
def _speech_with_pauses():
    """(16 kHz samples, {part: (start, end) s}): a clip, a pause, clipped noise, a pause, a clip."""
    from faceanim.live.audio import read_sound

    a, b = read_sound(SPEECH / "clip-0870.wav"), read_sound(SPEECH / "clip-0880.wav")
    rng = np.random.default_rng(1)
    noise = np.clip(3.0 * rng.standard_normal(2 * 16000), -1.0, 1.0).astype(np.float32)
    parts = [("lead", np.zeros(12800, np.float32)), ("clip-0870", a), ("pause1", np.zeros(24000, np.float32)),
             ("noise", noise), ("pause2", np.zeros(24000, np.float32)), ("clip-0880", b),
             ("tail", np.zeros(16000, np.float32))]
    at, spans = 0, {}
    for name, x in parts:
        spans[name] = (at / 16000, (at + len(x)) / 16000)
        at += len(x)
    return np.concatenate([x for _, x in parts]), spans


def _loud(x: np.ndarray) -> np.ndarray:
    """Per 20 ms of the WAV: loud (RMS over 0.02, full scale 1)."""
    n = len(x) // 320
    return np.sqrt(np.mean(x[:n * 320].reshape(n, 320) ** 2, axis=1)) > 0.02


def _delay(t, jaw, loud, skip, lo, hi) -> tuple[float, float]:
    """The delay (s) at which the mouth open (jawOpen > 0.05 at times ``t``, seconds from the
    sound's start) best matches the WAV's loud 20 ms steps (``skip``: steps not compared),
    searched from lo to hi; and the share that match there."""
    best = (lo, -1.0)
    for d in np.arange(lo, hi, 1 / 120):
        k = np.floor((t - d) / 0.02).astype(int)
        ok = (k >= 0) & (k < len(loud))
        ok[ok] &= ~skip[k[ok]]
        share = float(np.mean((jaw[ok] > 0.05) == loud[k[ok]]))
        best = max(best, (d, share), key=lambda b: b[1])
    return best


@needs_speech
def test_live_mic_mouth_opens_and_shuts_with_the_speech_and_the_lips_press_for_p_b_m(loopback, tmp_path):
    """Speech played into the virtual microphone: at one delay (found by matching; between the
    moment it was played and 0.8 s later, on the clock of a VMC receiver of the same run) the
    take's mouth is open where the WAV is loud and shut in its pauses, shut again after clipped
    noise, opens with the speech after it, and the lips press (mouthPress) around most of the p,
    b, m of the clips aligned offline with their transcripts, rarely on their open vowels."""
    from faceanim.drivers.speech.phonemes import align

    wav, spans = _speech_with_pauses()
    seconds = len(wav) / 16000 + 2.0
    out = tmp_path / "take.csv"
    vmc = VmcClock()
    try:
        p = _popen("--mic", "pulse", "--to", f"file:{out}", "--to", f"vmc://127.0.0.1:{vmc.port}", "--seconds",
                   f"{seconds:.2f}", env=loopback.env)
        _recording(loopback)
        time.sleep(1.0)
        played = time.monotonic()
        loopback.play(wav, 16000)
        stdout, stderr = p.communicate(timeout=120)
    finally:
        vmc.close()
    assert p.returncode == 0, stderr
    assert _one_line(stderr).startswith("faceanim live: microphone ") and "'pulse'" in stderr
    chunks = int(stdout.split("; sound ")[1].split()[0])
    assert chunks >= 0.9 * seconds * 50  # the whole run heard, 20 ms at a time
    take = read_arkit_csv(out)
    assert take.n_samples == pytest.approx(seconds * 30, abs=3)
    assert len(vmc.frames) >= 0.9 * take.n_samples
    t = take.times + vmc.offset - played  # seconds from the moment the sound was played
    jaw, press = take.weights[:, JAW], take.weights[:, PRESS]
    assert np.all((take.weights >= 0) & (take.weights <= 1))
    loud = _loud(wav)
    step = np.arange(len(loud)) * 0.02
    noise = (step >= spans["noise"][0]) & (step < spans["noise"][1])
    delay, share = _delay(t, jaw, loud, noise, -0.5, 1.5)
    assert -0.03 <= delay <= 0.8, (delay, share)  # the mouth follows the sound (not before it, nor seconds later)
    assert share >= 0.75, share

    def during(name, a=0.0, b=0.0):
        s, e = spans[name]
        return (t >= s + delay + a) & (t < e + delay + b)

    for name in ("clip-0870", "clip-0880"):
        k = np.floor((t[during(name)] - delay) / 0.02).astype(int)
        speaking = loud[np.clip(k, 0, len(loud) - 1)]
        assert jaw[during(name)].max() > 0.3, name  # it opens
        assert np.mean(jaw[during(name)][speaking] > 0.05) >= 0.6, name  # while the speech is loud
    for name in ("lead", "pause1", "pause2", "tail"):
        assert np.mean(jaw[during(name, 0.35)] < 0.05) >= 0.95, name  # and it shuts when it stops
    closures, pressed, vowels, vowel_pressed = 0, 0, 0, 0
    for name in ("clip-0870", "clip-0880"):
        start = spans[name][0] + delay
        for ph in align(SPEECH / f"{name}.wav", (SPEECH / f"{name}.txt").read_text()):
            if ph.phone in ("P", "B", "M"):
                sel = (t >= start + ph.start - 0.05) & (t <= start + ph.end + 0.25)
                closures += 1
                pressed += bool(press[sel].max() >= 0.2)
            elif ph.phone.rstrip("012") in ("AA", "AE", "AH", "AO", "AW", "AY") and ph.end - ph.start >= 0.06:
                mid = (ph.start + ph.end) / 2
                sel = np.abs(t - (start + mid)) <= 0.02
                vowels += 1
                vowel_pressed += bool(sel.any() and press[sel].max() >= 0.2)
    assert closures >= 8 and pressed / closures >= 0.6, (pressed, closures)
    assert vowels >= 8 and vowel_pressed / vowels <= 0.2, (vowel_pressed, vowels)


@needs_speech
def test_live_mic_stops_cleanly_when_the_device_goes(tmp_path):
    """The virtual microphone removed mid-run (its null sink unloaded): the run stops by itself,
    says why in one line of its own, writes the take so far, exit 0 as any stop."""
    from faceanim.live.audio import read_sound

    lb = _start_loopback(tmp_path / "pulse")
    try:
        out = tmp_path / "take.csv"
        p = _popen("--mic", "pulse", "--to", f"file:{out}", env=lb.env)
        _recording(lb)
        lb.play(read_sound(SPEECH / "clip-0870.wav"), 16000)
        time.sleep(3.0)
        lb.remove_sink()
        stdout, stderr = p.communicate(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
        lb.stop()
    assert p.returncode == 0, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 2 and not any(raw in stderr for raw in RAW_PORTAUDIO), stderr
    assert "microphone 0 'pulse' stopped giving sound after" in lines[1] and lines[1].endswith("; stopped")
    assert stdout.splitlines()[-1] == f"wrote {out}"
    take = read_arkit_csv(out)
    assert 2.5 * 30 <= take.n_samples <= 6 * 30
    assert take.weights[:, JAW].max() > 0.2  # it heard the speech before the device went


def test_live_mic_stops_on_sigterm_and_ctrl_c_with_the_take_whole(loopback, tmp_path):
    for sig in (signal.SIGTERM, signal.SIGINT):
        out = tmp_path / f"take-{sig.name}.csv"
        p = _popen("--mic", "--to", f"file:{out}", "--to", "vmc://127.0.0.1:9", env=loopback.env)
        _recording(loopback)
        time.sleep(2.0)
        p.send_signal(sig)
        stdout, stderr = p.communicate(timeout=30)
        assert p.returncode == 0, stderr
        assert stdout.startswith("stopped: ") and "; sound " in stdout
        assert read_arkit_csv(out).n_samples >= 1.5 * 30
    assert not loopback.pactl("list", "short", "source-outputs").stdout.strip()  # the device let go


CLIPS = DATA / "talking-head-videos"


@needs_speech
@pytest.mark.skipif(not (CLIPS / "d18.mp4").exists(), reason="needs ../shared/data/talking-head-videos")
def test_live_mic_with_a_video_gives_the_video_the_mic_s_mouth(loopback, tmp_path):
    """--video with --mic --mouth audio: the video's face, the microphone's mouth (shut until the
    speech is played, open with it)."""
    from faceanim.live.audio import read_sound

    out = tmp_path / "take.csv"
    vmc = VmcClock()
    try:
        p = _popen("--video", str(CLIPS / "d18.mp4"), "--mic", "pulse", "--mouth", "audio", "--to", f"file:{out}",
                   "--to", f"vmc://127.0.0.1:{vmc.port}", env=loopback.env)
        while not vmc.frames and p.poll() is None:  # the clip has started
            time.sleep(0.01)
        time.sleep(2.0)
        played = time.monotonic()
        speech = read_sound(SPEECH / "clip-0880.wav")
        loopback.play(speech, 16000)
        stdout, stderr = p.communicate(timeout=120)
    finally:
        vmc.close()
    assert p.returncode == 0, stderr
    take = read_arkit_csv(out)
    t = take.times + vmc.offset - played  # seconds from the moment the sound was played
    jaw = take.weights[:, JAW]
    assert (t < 0).sum() > 30 and jaw[t < 0].max() < 0.05  # the video's speaker talks, the microphone is quiet: shut
    assert jaw[(t > 0) & (t < len(speech) / 16000 + 0.8)].max() > 0.3
    assert take.weights[:, ARKIT_NAMES.index("EyeBlinkLeft")].max() > 0.3  # the video's own eyes


def test_live_mic_without_the_sounddevice_package(monkeypatch, tmp_path, capsys):
    from faceanim.cli import main

    monkeypatch.setitem(sys.modules, "sounddevice", None)  # `import sounddevice` raises ImportError
    out = tmp_path / "take.csv"
    assert main(["live", "--mic", "--to", f"file:{out}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'live' extra" in err[0] and "pip install 'faceanim[live]'" in err[0]
    assert not out.exists()
