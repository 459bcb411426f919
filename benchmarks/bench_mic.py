"""faceanim live --mic: from the sound to the VMC packet, through a virtual microphone.

    .venv/bin/python benchmarks/bench_mic.py ../shared/data [--long 600] [--blas-threads 1]
    (about a minute; --long S plays S seconds of speech, with a minute of silence in it)

A private PulseAudio server (``tests/pulse_loopback.py``: a null sink whose monitor is the default
source; Debian's pulseaudio, pulseaudio-utils and libasound2-plugins) is the microphone. This
process plays the LibriVox clips (``speech-librivox/``) into the sink with 1 s pauses between them
(PortAudio, ALSA's pulse device; each callback's DAC time says when its samples sound), while
``faceanim live --mic pulse --to vmc://127.0.0.1:PORT`` (the command itself, its own process)
records the monitor; a receiver here notes when each VMC packet arrives (time.monotonic(), the
clock the player's times are on).

The reference: each clip aligned offline with its transcript (pocketsphinx's forced alignment), so
each phone's start is known in the played sound. A viseme onset is an open vowel (AA AE AH AW AY)
after a phone of another class, shown when jawOpen reaches 0.15, and a p, b or m, shown when
mouthPressLeft reaches 0.2 (only a p, b, m presses the lips), from 50 ms before the phone to 400
ms after it (one already shown 50 ms before is not counted); a speech onset (the first loud 20 ms
after 0.3 s of quiet, in the WAV) is shown when jawOpen reaches 0.05. Delay: from the phone's start
as played to the packet's arrival.

Baselines in the same run: ``direct``, the same sound fed to LiveLipSync 20 ms at a time without a
clock or any device (the lip sync's own delay: the decoder hears a phone about 90 ms after it
starts), measured the same way on the stream's time; and ``transport``, a second recorder of the
same monitor in this process (PortAudio, no lip sync): from a speech onset as played to the first
10 ms block over 0.02 RMS arriving (the sound path alone: player, sink, monitor, capture).

The run: ticks (30 a second) made, dropped (replaced before the compute took them), packets
received, the sound's 20 ms chunks heard, dropped (the lip sync behind by more than 0.5 s) and
PortAudio's input overflows, and the command's CPU time. Goals (issue 34): viseme onset p50 <= 150
ms; over a 10-minute run no chunk or frame dropped. Nothing is asserted here.
"""

from __future__ import annotations

import os
import resource
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from _timing import arguments, blas_threads, header, table  # noqa: E402

import numpy as np  # noqa: E402

from pulse_loopback import PulseLoopback, PulseUnavailable  # noqa: E402

RATE = 48000  # the player's rate (the null sink's)
OPEN = ("AA", "AE", "AH", "AW", "AY")
CLOSED = ("P", "B", "M")
PAUSE = 1.0  # seconds between clips
LEAD = 1.0  # seconds of silence before the first
VMC_NAMES = ("JawOpen", "MouthPressLeft")


def speech(folder: Path, seconds: float | None):
    """(16 kHz samples, [(clip, offset s)], the silent minute (start, end) or None): the clips with
    pauses, once, or repeated to ``seconds`` with a minute of silence after the first third."""
    from faceanim.live.audio import read_sound

    clips = [(wav.stem, read_sound(wav)) for wav in sorted(folder.glob("clip-*.wav"))]
    parts, placed, at, quiet = [np.zeros(int(LEAD * 16000), np.float32)], [], LEAD, None
    target = seconds or 0.0
    while True:
        for name, x in clips:
            placed.append((name, at))
            parts += [x, np.zeros(int(PAUSE * 16000), np.float32)]
            at += (len(x) + int(PAUSE * 16000)) / 16000
        if at >= target:
            break
        if quiet is None and seconds and at >= seconds / 3:
            parts.append(np.zeros(60 * 16000, np.float32))
            quiet = (at, at + 60.0)
            at += 60.0
    return np.concatenate(parts), placed, quiet


def references(folder: Path, placed):
    """(open vowel onsets, p/b/m starts, speech onsets) in seconds of the played sound."""
    from faceanim.drivers.speech.phonemes import align

    aligned = {wav.stem: align(wav, wav.with_suffix(".txt").read_text()) for wav in folder.glob("clip-*.wav")}
    opens, closures = [], []
    for name, at in placed:
        prev = None
        for p in aligned[name]:
            cls = "open" if p.phone.rstrip("012") in OPEN else ("closed" if p.phone in CLOSED else p.phone)
            if cls == "open" and prev != "open":
                opens.append((at + p.start, at + p.end))
            if cls == "closed":
                closures.append((at + p.start, at + p.end))
            prev = cls
    return opens, closures


def speech_onsets(x: np.ndarray) -> list[float]:
    n = len(x) // 320
    loud = np.sqrt(np.mean(x[:n * 320].reshape(n, 320) ** 2, axis=1)) > 0.02
    out, quiet = [], 0
    for k, v in enumerate(loud):
        if v and quiet >= 15:
            out.append(k * 0.02)
        quiet = 0 if v else quiet + 1
    return out


def crossings(times, values, events, level, before=0.05, after=0.4):
    """Per event (start, end): the first time in [start - before, end + after] at which ``values``
    reach ``level`` minus the start, or None; events already at the level at start - before are
    left out. Returns (delays, counted)."""
    delays, counted = [], 0
    for start, end in events:
        k0 = np.searchsorted(times, start - before)
        if k0 >= len(times):
            continue
        if k0 > 0 and values[k0 - 1] >= level:
            continue
        counted += 1
        k1 = np.searchsorted(times, end + after, side="right")
        hit = np.flatnonzero(values[k0:k1] >= level)
        if len(hit):
            delays.append(times[k0 + hit[0]] - start)
    return delays, counted


def direct_feed(x: np.ndarray):
    """(stream times, jawOpen, mouthPressLeft) of the sound fed to LiveLipSync 20 ms at a time."""
    from faceanim.drivers.speech.stream import LiveLipSync
    from faceanim.live.audio import APPLE

    ls = LiveLipSync(APPLE)
    j, p = APPLE.index("jawOpen"), APPLE.index("mouthPressLeft")
    t, jaw, press = [], [], []
    for k in range(0, len(x), 320):
        ls.feed(x[k:k + 320])
        c = ls.curves()
        t.append(ls.stream.time)
        jaw.append(c[j])
        press.append(c[p])
    return np.array(t), np.array(jaw), np.array(press)


class Receiver:
    """VMC packets on 127.0.0.1: (arrival, datagram), decoded afterwards."""

    def __init__(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        self.sock.settimeout(0.1)
        self.port = self.sock.getsockname()[1]
        self.packets: list = []
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        while not self.stop.is_set():
            try:
                data = self.sock.recv(65536)
            except socket.timeout:
                continue
            self.packets.append((time.monotonic(), data))

    def curves(self):
        from faceanim.io.vmc import decode_frame

        self.stop.set()
        self.thread.join()
        t, jaw, press = [], [], []
        for arrived, data in self.packets:
            b = decode_frame(data)["blends"]
            t.append(arrived)
            jaw.append(b["JawOpen"])
            press.append(b["MouthPressLeft"])
        return np.array(t), np.array(jaw), np.array(press)


class Player:
    """The sound played into the sink by PortAudio; :meth:`played` maps time.monotonic() to
    seconds of the sound (each callback's DAC time: when its first sample sounds), so an underrun
    (the sound resumed later) shifts only what follows it."""

    def __init__(self, sd, x16k: np.ndarray):
        from faceanim.io.audio import resample

        self.x = resample(x16k, 16000, RATE)
        self.pos = 0
        self.marks = []
        self.done = threading.Event()
        self.stream = sd.OutputStream(device="pulse", samplerate=RATE, channels=1, dtype="float32",
                                      blocksize=RATE // 100, latency=0.05, callback=self._callback)

    def _callback(self, out, frames, info, status):
        now = time.monotonic()
        chunk = self.x[self.pos:self.pos + frames]
        out[:len(chunk), 0] = chunk
        out[len(chunk):, 0] = 0.0
        self.marks.append((now + (info.outputBufferDacTime - info.currentTime), self.pos / RATE))
        self.pos += frames
        if self.pos >= len(self.x):
            self.done.set()

    def played(self, t: np.ndarray) -> np.ndarray:
        """Seconds of the sound sounding at monotonic times ``t``: from the last callback's first
        sample before ``t`` (before the first callback: negative)."""
        at, pos = np.array(self.marks).T
        i = np.clip(np.searchsorted(at, t, side="right") - 1, 0, len(at) - 1)
        return pos[i] + (np.asarray(t) - at[i])

    @property
    def shifts(self) -> float:
        """ms between the latest and the earliest sample-0 time the callbacks imply (underruns)."""
        at, pos = np.array(self.marks).T
        return 1000 * float(np.ptp(at - pos))


class Recorder:
    """The monitor recorded here too (PortAudio, no lip sync): each 10 ms block's arrival and RMS."""

    def __init__(self, sd):
        self.blocks = []
        self.stream = sd.InputStream(device="pulse", samplerate=RATE, channels=1, dtype="float32",
                                     blocksize=RATE // 100, latency="low", callback=self._callback)

    def _callback(self, data, frames, info, status):
        self.blocks.append((time.monotonic(), float(np.sqrt(np.mean(np.square(data))))))


def pct(d):
    return (f"{1000 * np.percentile(d, 50):.0f}", f"{1000 * np.percentile(d, 90):.0f}") if len(d) else ("-", "-")


def main() -> None:
    args = arguments(__doc__, "the shared data folder (../shared/data)",
                     extra=[("--long", {"type": float, "default": None, "metavar": "S",
                                        "help": "play S seconds of speech (with a minute of silence in it)"})])
    blas_threads(args.blas_threads)
    header("faceanim live --mic: sound to VMC packet through a virtual microphone (PulseAudio)")
    folder = (args.data or Path(__file__).resolve().parents[2] / "shared" / "data") / "speech-librivox"
    x, placed, quiet = speech(folder, args.long)
    opens, closures = references(folder, placed)
    onsets = speech_onsets(x)
    once = placed[:len(list(folder.glob("clip-*.wav")))]
    first_end = once[-1][1] + 10.0 if args.long else len(x) / 16000
    print(f"sound: {len(x) / 16000:.1f} s, clips {len(placed)}, open-vowel onsets {len(opens)}, p/b/m {len(closures)}, "
          f"speech onsets {len(onsets)}" + (f", silent {quiet[0]:.0f}-{quiet[1]:.0f} s" if quiet else "") + "\n")

    t0 = time.perf_counter()
    dt, djaw, dpress = direct_feed(x[:int(first_end * 16000)])
    direct_s = time.perf_counter() - t0

    with tempfile.TemporaryDirectory() as tmp:
        try:
            lb = PulseLoopback(Path(tmp)).start()
        except PulseUnavailable as exc:
            print(f"(no virtual microphone: {exc})")
            return
        try:
            os.environ.update({k: v for k, v in lb.env.items() if k.startswith("PULSE")})
            import sounddevice as sd  # PortAudio starts now, seeing the server

            from faceanim.io.files import native_stderr_quiet

            rx = Receiver()
            cmd = [sys.executable, "-m", "faceanim", "live", "--mic", "pulse", "--to", f"vmc://127.0.0.1:{rx.port}"]
            proc = subprocess.Popen(cmd, env={**lb.env, "OPENBLAS_NUM_THREADS": "1"}, stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True)
            while not rx.packets and proc.poll() is None:
                time.sleep(0.01)
            rec, player = Recorder(sd), Player(sd, x)
            with native_stderr_quiet():  # ALSA's own lines (an underrun at the start)
                rec.stream.start()
                time.sleep(0.5)
                player.stream.start()
                player.done.wait(timeout=len(x) / 16000 + 60)
                time.sleep(1.5)
                for stream in (player.stream, rec.stream):  # closed while the server is there to answer
                    stream.stop()
                    stream.close()
            proc.send_signal(signal.SIGINT)
            _, status, usage = os.wait4(proc.pid, 0)
            out, err = proc.stdout.read(), proc.stderr.read()
            proc.returncode = os.waitstatus_to_exitcode(status)
        finally:
            lb.stop()
    vt, vjaw, vpress = rx.curves()
    vt = player.played(vt)  # seconds of the played sound
    summary = next((line for line in out.splitlines() if " frames in " in line), out.strip())

    # transport: speech onset -> first loud block at the second recorder
    bt = player.played(np.array([b[0] for b in rec.blocks]))
    brms = np.array([b[1] for b in rec.blocks])
    transport = crossings(bt, brms, [(s, s) for s in onsets], 0.02, before=0.0, after=0.3)[0]

    rows, pooled = [], {"direct": ([], 0), "mic": ([], 0)}
    kinds = (("open vowel: jawOpen >= 0.15", opens, 0, 0.15), ("p/b/m: mouthPressLeft >= 0.2", closures, 1, 0.2),
             ("speech onset: jawOpen >= 0.05", [(s, s) for s in onsets], 0, 0.05))
    for name, events, which, level in kinds:
        first = [e for e in events if e[0] < first_end - 1.0]
        d, dn = crossings(dt, (djaw, dpress)[which], first, level)
        m, mn = crossings(vt, (vjaw, vpress)[which], events, level)
        if which == 1 or level == 0.15:
            pooled["direct"] = (pooled["direct"][0] + d, pooled["direct"][1] + dn)
            pooled["mic"] = (pooled["mic"][0] + m, pooled["mic"][1] + mn)
        gap = f"{1000 * (np.median(m) - np.median(d)):+.0f}" if m and d else "-"
        rows.append([name, f"{len(d)}/{dn}", *pct(d), f"{len(m)}/{mn}", *pct(m), gap])
    d, dn = pooled["direct"]
    m, mn = pooled["mic"]
    rows.append(["visemes (open vowels and p/b/m)", f"{len(d)}/{dn}", *pct(d), f"{len(m)}/{mn}", *pct(m),
                 f"{1000 * (np.median(m) - np.median(d)):+.0f}" if m and d else "-"])
    rows.append(["transport: speech onset to a loud block recorded here", "", "", "",
                 f"{len(transport)}/{len(onsets)}", *pct(transport), ""])
    table(rows, ["event", "direct found", "direct p50 ms", "p90 ms", "mic found", "mic p50 ms", "p90 ms",
                 "mic - direct p50 ms"],
          notes=[f"direct: the first {first_end:.0f} s fed to LiveLipSync without a clock ({direct_s:.1f} s); "
                 f"mic: sound as played (DAC times; underruns moved it by {player.shifts:.0f} ms in all) to the VMC "
                 "packet's arrival"])

    cpu = usage.ru_utime + usage.ru_stime
    wall = vt[-1] - vt[0] if len(vt) > 1 else float("nan")
    gaps = int(np.sum(np.diff(vt) > 0.1)) if len(vt) > 1 else 0
    silent = ""
    if quiet:
        sel = (vt >= quiet[0] + 0.5) & (vt < quiet[1])
        silent = f"{100 * np.mean(vjaw[sel] > 0.05):.1f}%" if sel.any() else "-"
    table([[f"{wall:.0f} s", summary.split(" frames")[0].replace("stopped: ", ""), str(len(vt)), str(gaps),
            summary.split("; sound ")[1] if "; sound " in summary else "-", f"{cpu:.1f} s ({100 * cpu / wall:.0f}%)",
            silent or "-", str(proc.returncode)]],
          ["run", "ticks sent", "packets received", "gaps > 100 ms", "sound", "CPU (of one core)",
           "mouth open in the silent minute", "exit"])
    print(summary)
    if err.strip():
        print("stderr:", " / ".join(err.strip().splitlines()))


if __name__ == "__main__":
    main()
