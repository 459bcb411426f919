"""A private PulseAudio server for tests and benchmarks: a virtual microphone that plays what is
played into it.

:class:`PulseLoopback` starts ``pulseaudio`` in user mode (also as root: ``--system=false``, its
own runtime, state and home folders in a folder of the caller's, no autospawn, no D-Bus) with one
null sink, ``faceanim_speaker``; its monitor, ``faceanim_speaker.monitor``, is the default source.
A program that records from the server (``faceanim live --mic pulse``: PortAudio's ALSA host API
through ALSA's ``pulse`` plugin, Debian's libasound2-plugins) hears what is played into the sink
(:meth:`PulseLoopback.play`, ``pacat``). :attr:`PulseLoopback.env` is the environment that reaches
the server (``PULSE_SERVER``, a client config without autospawn).

An idle null sink renders in blocks of up to two seconds, so a recording opened on an idle monitor
gets its first sound a second or two late; a stream of silence played for the server's whole life
(:meth:`PulseLoopback.start` starts it) keeps the sink rendering in 10 ms steps.

Debian packages: pulseaudio, pulseaudio-utils (pactl, pacat), libasound2-plugins (installed by
``bash scripts/setup.sh --tests``). :func:`unavailable` says why a server cannot be had here.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from pathlib import Path

SINK = "faceanim_speaker"
SOURCE = SINK + ".monitor"
RATE = 48000  # the null sink's rate (the monitor's, so the device's as PortAudio sees it through ALSA)


class PulseUnavailable(RuntimeError):
    """No PulseAudio server could be started here (its message says why)."""


def unavailable() -> str | None:
    """Why a loopback cannot run here (a missing program or ALSA's pulse plugin), else None."""
    for tool in ("pulseaudio", "pactl", "pacat"):
        if shutil.which(tool) is None:
            return f"{tool} is not installed (Debian: pulseaudio pulseaudio-utils; bash scripts/setup.sh --tests)"
    plugin = [p for d in ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib64", "/usr/lib")
              for p in Path(d).glob("alsa-lib/libasound_module_pcm_pulse.so")]
    if not plugin:
        return "ALSA's pulse plugin is not installed (Debian: libasound2-plugins; bash scripts/setup.sh --tests)"
    return None


class PulseLoopback:
    """A PulseAudio server of our own in ``folder`` (see the module docstring); a context manager."""

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        self.socket = self.folder / "native"
        self.server: subprocess.Popen | None = None
        self.keeper: subprocess.Popen | None = None
        self.players: list[subprocess.Popen] = []
        self.log = self.folder / "pulseaudio.log"
        client = self.folder / "client.conf"
        self.env = {**os.environ, "PULSE_SERVER": f"unix:{self.socket}", "PULSE_CLIENTCONFIG": str(client),
                    "PULSE_COOKIE": str(self.folder / "cookie")}
        for key in ("PULSE_SINK", "PULSE_SOURCE"):
            self.env.pop(key, None)

    def start(self, timeout: float = 15.0) -> PulseLoopback:
        reason = unavailable()
        if reason:
            raise PulseUnavailable(reason)
        for sub in ("run", "state", "home"):
            (self.folder / sub).mkdir(parents=True, exist_ok=True)
        (self.folder / "run").chmod(0o700)
        (self.folder / "client.conf").write_text("autospawn = no\n")
        script = self.folder / "default.pa"
        script.write_text(
            f"load-module module-null-sink sink_name={SINK} rate={RATE} channels=1 "
            f"sink_properties=device.description={SINK}\n"
            f"load-module module-native-protocol-unix socket={self.socket} auth-anonymous=1\n"
            f"set-default-sink {SINK}\nset-default-source {SOURCE}\n")
        server_env = {**self.env, "XDG_RUNTIME_DIR": str(self.folder / "run"),
                      "PULSE_RUNTIME_PATH": str(self.folder / "run" / "pulse"),
                      "PULSE_STATE_PATH": str(self.folder / "state"), "HOME": str(self.folder / "home")}
        server_env.pop("PULSE_SERVER", None)
        server_env.pop("DBUS_SESSION_BUS_ADDRESS", None)
        with open(self.log, "wb") as log:
            self.server = subprocess.Popen(
                ["pulseaudio", "--daemonize=no", "--system=false", "--exit-idle-time=-1", "--use-pid-file=no",
                 "--disallow-module-loading=no", "--realtime=no", "--high-priority=no", "-n", "-F", str(script),
                 "--log-target=stderr"], env=server_env, stdin=subprocess.DEVNULL, stdout=log, stderr=log)
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.server.poll() is not None:
                tail = self.log.read_text(errors="replace").strip().splitlines()[-3:]
                raise PulseUnavailable(f"pulseaudio exited ({self.server.returncode}): {' / '.join(tail)}")
            if self.socket.exists() and self.pactl("info", check=False).returncode == 0:
                break
            time.sleep(0.1)
        else:
            self.stop()
            raise PulseUnavailable(f"pulseaudio did not answer within {timeout:g} s")
        # silence played for the server's whole life: the sink renders in 10 ms steps (see above)
        self.keeper = subprocess.Popen(["pacat", "--playback", "--raw", "--format=s16le", f"--rate={RATE}",
                                        "--channels=1", "--latency-msec=10", "/dev/zero"], env=self.env,
                                       stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        # ready when a recording of the monitor gets its first sound at once (the sink's long idle
        # block is over)
        while time.monotonic() < end:
            t0 = time.monotonic()
            probe = subprocess.Popen(["parec", "--raw", "--format=s16le", "--rate=16000", "--channels=1",
                                      "--latency-msec=10"], env=self.env, stdout=subprocess.PIPE,
                                     stderr=subprocess.DEVNULL)
            got = probe.stdout.read(64)
            probe.kill()
            probe.wait()
            if got and time.monotonic() - t0 < 0.2:
                return self
        self.stop()
        raise PulseUnavailable(f"the null sink's monitor gave no sound within {timeout:g} s")

    def pactl(self, *args: str, check: bool = True) -> subprocess.CompletedProcess:
        return subprocess.run(["pactl", *args], env=self.env, capture_output=True, text=True, timeout=10,
                              check=check)

    def play(self, samples, rate: int, latency_ms: int = 10) -> subprocess.Popen:
        """Play float samples (mono, full scale 1) into the sink, now; returns the ``pacat`` playing them."""
        import numpy as np

        p = subprocess.Popen(["pacat", "--playback", "--raw", "--format=float32le", f"--rate={int(rate)}",
                              "--channels=1", f"--latency-msec={latency_ms}"], env=self.env,
                             stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        data = np.asarray(samples, dtype="<f4").tobytes()

        def write():
            try:
                p.stdin.write(data)
                p.stdin.close()
            except (BrokenPipeError, ValueError):
                pass

        import threading

        threading.Thread(target=write, daemon=True).start()
        self.players.append(p)
        return p

    def remove_sink(self) -> None:
        """Unload the null sink: its monitor, the virtual microphone, is gone (as when one is unplugged)."""
        modules = self.pactl("list", "short", "modules").stdout.splitlines()
        ids = [line.split()[0] for line in modules if "module-null-sink" in line]
        for i in ids:
            self.pactl("unload-module", i)

    def stop(self) -> None:
        for p in [*self.players, self.keeper, self.server]:
            if p is not None and p.poll() is None:
                p.terminate()
                try:
                    p.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
        self.players = []

    def __enter__(self) -> PulseLoopback:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
