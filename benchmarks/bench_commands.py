"""Whole commands as a user runs them: wall time from the shell to the exit, not per-frame rates.

Each command runs as its own process (``.venv/bin/faceanim ...``), best of ``--repeat`` runs,
on the embedded default face. Baselines in the same run: the interpreter alone (``python -c
pass``) and with numpy imported (the floor of any command that computes); each command cold
(``FACEANIM_CACHE=off``: everything computed) and warm (the user cache primed by one run before).
The goal (issue 22): ``--help``/``--version`` <= 0.1 s; fixed set-up <= 1.5 s.

Usage (from /work/main): ``python benchmarks/bench_commands.py [--repeat 3]``
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _timing import arguments, fmt_ratio, fmt_time, header, table

ROOT = Path(__file__).resolve().parents[1]
EXE = Path(sys.executable).with_name("faceanim")


def wall(argv: list[str], env: dict, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run(argv, env=env, check=True, capture_output=True)
        best = min(best, time.perf_counter() - t0)
    return best


def main() -> None:
    args = arguments(__doc__, extra=[("--repeat", {"type": int, "default": 3, "help": "runs per command (best)"})])
    header("whole commands, wall time (a process each)")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        cold = {**os.environ, "FACEANIM_CACHE": "off"}
        warm = {**os.environ, "FACEANIM_CACHE": str(out / "cache")}
        floors = [("python -c pass", [sys.executable, "-c", "pass"]),
                  ("python -c 'import numpy'", [sys.executable, "-c", "import numpy"])]
        rows = [[name, fmt_time(wall(argv, cold, args.repeat)), "", ""] for name, argv in floors]
        commands = [
            ("faceanim --help", ["--help"]),
            ("faceanim --version", ["--version"]),
            ("faceanim say TEXT -o x.csv", ["say", "Peter Piper picked a peck", "-o", str(out / "s.csv")]),
            ("faceanim say TEXT -o x.glb", ["say", "Peter Piper picked a peck", "-o", str(out / "s.glb")]),
            ("faceanim rig -o x.glb --set arkit,visemes", ["rig", "-o", str(out / "r.glb"), "--set", "arkit,visemes"]),
            ("faceanim rig -o x.vrm (all sets)", ["rig", "-o", str(out / "r.vrm")]),
        ]
        for name, argv in commands:
            c = wall([str(EXE), *argv], cold, args.repeat)
            subprocess.run([str(EXE), *argv], env=warm, check=True, capture_output=True)  # primes the cache
            w = wall([str(EXE), *argv], warm, args.repeat)
            rows.append([name, fmt_time(c), fmt_time(w), fmt_ratio(c / w)])
    table(rows, ["command", "cold (no cache)", "warm (cache primed)", "cold / warm"])


if __name__ == "__main__":
    main()
