"""Build the motion database that ships with faceanim (Chai, Xiao & Hodgins 2003, section 3).

From the MIT-licensed Live Link Face take in ``../shared/data/arkit-curves/`` (its notice ships as
``assets/LICENSE-arkit-curves.txt``): played on the generic head's 76 markers at 30 fps, head
pose taken out (the take was recorded with the head still, so none is applied), control
parameters and deformation bases computed (:func:`faceanim.build.motion.build_database`).
``faceanim perform`` uses it when no ``--db`` is given.

Usage: ``python scripts/build_default_motion.py ../shared/data/arkit-curves`` (writes
``src/faceanim/assets/motion_default.npz``; the result is committed, users never run this).
Deterministic: the same take gives the same file contents.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))


def main(argv=None) -> None:
    from faceanim.build.motion import build_database
    from faceanim.io.arkit_csv import read_arkit_csv

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("curves", type=Path, help="the arkit-curves folder of ../shared/data")
    ap.add_argument("-o", "--output", type=Path, default=ROOT / "src" / "faceanim" / "assets" / "motion_default.npz")
    args = ap.parse_args(argv)
    take = args.curves / "alex_rom_3.csv"
    db = build_database([("alex_rom_3", read_arkit_csv(take))], fps=30.0)
    db.save(args.output)
    shutil.copyfile(args.curves / "LICENSE", args.output.parent / "LICENSE-arkit-curves.txt")
    print(f"{args.output}: {db.n_frames} frames, {db.n_bases} deformation bases, "
          f"{args.output.stat().st_size / 2**20:.1f} MiB")


if __name__ == "__main__":
    main()
