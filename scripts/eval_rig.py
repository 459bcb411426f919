"""How close `faceanim rig`'s ARKit shapes come to real artist-made ones, learned on one person and
tested on another.

    python scripts/eval_rig.py ../shared/data [--sheet docs/rig_sheet.png]

1. **ICT FaceKit** (the only real ARKit shapes here): the ICT neutral with its vertex order
   shuffled (so nothing can be read off its topology), landmarks detected, rigged; each
   generated shape against ICT's own: ``|generated - real| / |real - neutral|`` over the vertices
   the real shape moves (more than 5% of its largest motion): skin, mouth, teeth, eyeballs and
   eyelashes (ICT's transparent eye overlays are left out: they are drawn with alpha blending).
   Two generators:
   - faceanim's (patterns learned from ICT's own shapes, carried): *in-sample*, it measures what
     the landmarks, correspondence and transfer lose;
   - **FaceWarehouse -> ICT**: ARKit shapes made from the FACS AU library, which was learned from
     FaceWarehouse tester 1's scans, by the usual ARKit-to-FACS table (:data:`ARKIT_FACS`):
     nothing learned from ICT. Reported raw and at the best scale per shape (which uses ICT).
2. **ICT -> FaceWarehouse**: on tester 1's neutral scan, how much of each of the person's 19
   real expressions (aligned on the skull) a basis can rebuild (non-negative least squares on
   the face region, weights up to 1): the generated ARKit shapes (learned from ICT: another
   person) against the AU rig learned from this very person (in-sample).
3. Time and size of `faceanim rig` on the default face and ICT.
4. The eye angles a look curve stands for (``standards/arkit.LOOK_ANGLES``), regressed from the Live
   Link Face take in ``arkit-curves/`` (its eye yaw/pitch against its look curves).
"""

from __future__ import annotations

import argparse
import gzip
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from faceanim.autorig import auto_rig
from faceanim.face.face import Face, landmarks_478
from faceanim.face.frame import rigid_align
from faceanim.face.landmarks import detect_landmarks
from faceanim.face.mesh import Mesh
from faceanim.face.regions import face_region
from faceanim.standards.arkit import ARKIT_NAMES, ict_name
from faceanim.io.meshio import load_mesh
from faceanim.standards.arkit import apple_name
from faceanim.rig.transfer import ExpressionTransfer, default_model, skull_vertices

# ICT's transparent eye overlays (lacrimal fluid, eye blend, occlusion: drawn with alpha blending,
# not part of the generic head) are left out of the scores; its eyelashes (25351-26718) count
OVERLAYS = slice(24591, 25351)
ICT_KEPT = 24591  # ICT's head, mouth, teeth and eyeballs: the parts the generic head has
MOVING = 0.05  # a vertex is in a shape's moving region above this share of its largest motion

# ARKit blendshapes as FACS action units (Apple's descriptions against FACS; the usual table of
# avatar tools). Shapes with no AU in faceanim's library are left out of the FaceWarehouse row.
ARKIT_FACS = {
    "browDownLeft": {"AU4_L": 1}, "browDownRight": {"AU4_R": 1}, "browInnerUp": {"AU1": 1},
    "browOuterUpLeft": {"AU2_L": 1}, "browOuterUpRight": {"AU2_R": 1},
    "cheekSquintLeft": {"AU6_L": 1}, "cheekSquintRight": {"AU6_R": 1},
    "eyeBlinkLeft": {"AU43_L": 1}, "eyeBlinkRight": {"AU43_R": 1},
    "eyeSquintLeft": {"AU7_L": 1}, "eyeSquintRight": {"AU7_R": 1},
    "eyeWideLeft": {"AU5_L": 1}, "eyeWideRight": {"AU5_R": 1},
    "jawOpen": {"AU26": 1}, "mouthFunnel": {"AU22": 1}, "mouthPucker": {"AU18": 1},
    "mouthSmileLeft": {"AU12_L": 1}, "mouthSmileRight": {"AU12_R": 1},
    "mouthFrownLeft": {"AU15_L": 1}, "mouthFrownRight": {"AU15_R": 1},
    "mouthDimpleLeft": {"AU14_L": 1}, "mouthDimpleRight": {"AU14_R": 1},
    "mouthStretchLeft": {"AU20_L": 1}, "mouthStretchRight": {"AU20_R": 1},
    "mouthRollLower": {"AU28": 1}, "mouthRollUpper": {"AU28": 1}, "mouthShrugLower": {"AU17": 1},
    "mouthPressLeft": {"AU24_L": 1}, "mouthPressRight": {"AU24_R": 1},
    "mouthLowerDownLeft": {"AU16_L": 1}, "mouthLowerDownRight": {"AU16_R": 1},
    "mouthUpperUpLeft": {"AU10_L": 1}, "mouthUpperUpRight": {"AU10_R": 1},
    "noseSneerLeft": {"AU9_L": 1}, "noseSneerRight": {"AU9_R": 1},
}


def obj_vertices(path: Path) -> np.ndarray:
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as fh:
        return np.array([line.split()[1:4] for line in fh if line.startswith("v ")], dtype=np.float64)


def ict_real(ict: Path, neutral: np.ndarray) -> dict[str, np.ndarray]:
    out = {}
    for column in ARKIT_NAMES:
        parts = ict_name(column)
        files = [ict / f"{n}.obj" if (ict / f"{n}.obj").exists() else ict / f"{n}.obj.gz" for n in parts]
        if files and all(f.exists() for f in files):
            out[apple_name(column)] = sum(obj_vertices(f) - neutral for f in files)
    return out


def shape_error(gen: np.ndarray, real: np.ndarray, best_scale: bool = False) -> float:
    m = np.linalg.norm(real, axis=1)
    m[OVERLAYS] = 0.0
    region = m > MOVING * m.max()
    g, r = gen[region], real[region]
    if best_scale:
        g = g * max(0.0, float(np.sum(g * r)) / max(float(np.sum(g * g)), 1e-30))
    return float(np.linalg.norm(g - r) / np.linalg.norm(r))


def summary(errors: dict[str, float]) -> str:
    e = np.array(list(errors.values()))
    worst = sorted(errors.items(), key=lambda kv: -kv[1])[:5]
    return (f"{len(e)} | {np.median(e):.2f} | {np.mean(e):.2f} | "
            + ", ".join(f"{n} {v:.2f}" for n, v in worst))


def fit_residual(basis: np.ndarray, target: np.ndarray, upper: float = 1.0) -> float:
    """Relative residual of the best non-negative combination (weights <= upper) of ``basis``
    (K, N) rebuilding ``target`` (N,)."""
    from scipy.optimize import lsq_linear

    res = lsq_linear(basis.T, target, bounds=(0.0, upper))
    return float(np.linalg.norm(basis.T @ res.x - target) / np.linalg.norm(target))


def shuffled(mesh: Mesh, seed: int = 0) -> tuple[Mesh, np.ndarray]:
    perm = np.random.default_rng(seed).permutation(mesh.n_vertices)
    inv = np.argsort(perm)
    return Mesh(mesh.vertices[perm], inv[mesh.faces], name=mesh.name + "_shuffled"), inv


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", type=Path, help="the shared data folder (ict-facekit/, facewarehouse-tester1/)")
    ap.add_argument("--sheet", type=Path, help="write a picture sheet of generated shapes here")
    args = ap.parse_args(argv)
    ict = args.data / "ict-facekit"
    fw = args.data / "facewarehouse-tester1"

    # 1. ICT ------------------------------------------------------------------------------
    neutral = load_mesh(ict / "generic_neutral_mesh.obj")
    real = ict_real(ict, neutral.vertices)
    mesh, inv = shuffled(neutral)
    face = Face(mesh, landmarks_478(mesh, detect_landmarks(mesh)))
    t = time.perf_counter()
    auto = auto_rig(face, ["arkit", "au"])
    print(f"ICT rig (arkit + au, shuffled, landmarks path): {time.perf_counter() - t:.1f} s")
    gen = {n: auto.shapes[n][inv] for n in auto.sets["arkit"]}
    rows = {"zero (no motion)": {n: 1.0 for n in real}}
    rows["faceanim rig (ICT patterns, in-sample)"] = {n: shape_error(gen[n], real[n]) for n in real if n in gen}
    from_aus = {n: sum(w * auto.shapes[a][inv] for a, w in aus.items()) for n, aus in ARKIT_FACS.items()}
    rows["FACS AUs learned on FaceWarehouse (FW -> ICT)"] = {n: shape_error(from_aus[n], real[n]) for n in from_aus}
    rows["same, best scale per shape (uses ICT)"] = {n: shape_error(from_aus[n], real[n], True) for n in from_aus}
    rows["faceanim rig, same shapes as the row above"] = {n: shape_error(gen[n], real[n]) for n in from_aus}
    print("\nARKit shapes on the ICT neutral vs ICT's own (relative error over the moving region)\n")
    print("| generator | shapes | median | mean | worst five |\n|---|---:|---:|---:|---|")
    for label, errors in rows.items():
        print(f"| {label} | {summary(errors)} |")
    # how well each basis spans ICT's real shapes (FW-learned AUs: out of sample)
    stack = np.array([auto.shapes[a][inv][:ICT_KEPT].ravel() for a in auto.sets["au"]])
    span = [fit_residual(stack, real[n][:ICT_KEPT].ravel(), 1.5) for n in real]
    print(f"\nICT's {len(real)} real shapes rebuilt from the AU rig learned on FaceWarehouse (NNLS, weights <= 1.5): "
          f"median residual {np.median(span):.2f}")

    # 2. FaceWarehouse --------------------------------------------------------------------
    if fw.is_dir():
        files = sorted(fw.glob("pose_*.obj"), key=lambda p: int(p.stem.split("_")[1]))
        meshes = [load_mesh(f) for f in files]
        n0 = meshes[0]
        lm = landmarks_478(n0, detect_landmarks(n0))
        fface = Face(n0, lm)
        stable = skull_vertices(n0, lm, fface.frame)
        region = np.flatnonzero(face_region(n0, lm, fface.frame))
        reals = []
        for m in meshes[1:]:
            r, tt = rigid_align(m.vertices[stable], n0.vertices[stable])
            reals.append((m.vertices @ r.T + tt - n0.vertices)[region].ravel())
        t = time.perf_counter()
        fauto = auto_rig(fface, ["arkit"])
        print(f"\nFaceWarehouse rig (arkit): {time.perf_counter() - t:.1f} s")
        arkit = np.array([fauto.shapes[n][region].ravel() for n in fauto.sets["arkit"]])
        au_rig = ExpressionTransfer(fface).rig(default_model(), sides=True)
        aus = np.array([au_rig.blendshape(n)[region].ravel() for n in au_rig.controls])
        res = {"ARKit shapes learned on ICT (ICT -> FW)": [fit_residual(arkit, r) for r in reals],
               "AU rig learned on this person (in-sample)": [fit_residual(aus, r, 1.5) for r in reals],
               "zero": [1.0] * len(reals)}
        print("\nFaceWarehouse tester 1's 19 real expressions rebuilt by each basis (relative residual, face region)\n")
        print("| basis | median | mean | max |\n|---|---:|---:|---:|")
        for label, e in res.items():
            print(f"| {label} | {np.median(e):.2f} | {np.mean(e):.2f} | {np.max(e):.2f} |")
        if args.sheet:
            ict_face = Face(neutral, face.landmarks)  # the same points: only the order was shuffled
            sheet(args.sheet, [(ict_face, real, "ICT's own"), (ict_face, gen, "faceanim on ICT"),
                               (fface, fauto.shapes, "faceanim on FaceWarehouse (learned on ICT)")])

    # 4. the eye angles of a look curve at 1 (standards/arkit.LOOK_ANGLES), from the real take ----------
    take = args.data / "arkit-curves" / "alex_rom_3.csv"
    if take.is_file():
        from faceanim.io.arkit_csv import read_arkit_csv
        from faceanim.standards.arkit import LOOK_ANGLES

        import csv

        with open(take, newline="") as fh:
            rows = list(csv.reader(fh))
        head, data = rows[0], np.array([[float(x) for x in r[2:]] for r in rows[1:]])
        col = {n: k for k, n in enumerate(head[2:])}
        read_arkit_csv(take)  # the take passes faceanim's own reader
        print("\nEye angle (rad) per unit of look curve, regressed on the Live Link take "
              "(angle ~ a * look_a + b * look_b + c):\n")
        print("| eye | out | in | r (yaw) | up | down | r (pitch) | LOOK_ANGLES |\n|---|---:|---:|---:|---:|---:|---:|---|")
        for eye in ("Left", "Right"):
            sign = -1.0 if eye == "Left" else 1.0  # Live Link's yaw: the left eye looking out is negative
            yaw, pitch = data[:, col[f"{eye}EyeYaw"]], data[:, col[f"{eye}EyePitch"]]
            out, inn = data[:, col[f"EyeLookOut{eye}"]], data[:, col[f"EyeLookIn{eye}"]]
            up, down = data[:, col[f"EyeLookUp{eye}"]], data[:, col[f"EyeLookDown{eye}"]]
            a = np.linalg.lstsq(np.column_stack([out, inn, np.ones(len(out))]), sign * yaw, rcond=None)[0]
            b = np.linalg.lstsq(np.column_stack([up, down, np.ones(len(up))]), -pitch, rcond=None)[0]
            r_yaw = abs(np.corrcoef(out - inn, yaw)[0, 1])
            r_pitch = abs(np.corrcoef(up - down, pitch)[0, 1])
            print(f"| {eye} | {a[0]:.2f} | {-a[1]:.2f} | {r_yaw:.3f} | {b[0]:.2f} | {-b[1]:.2f} | {r_pitch:.3f} | "
                  + ", ".join(f"{k} {v}" for k, v in LOOK_ANGLES.items()) + " |")

    # 3. time and size ----------------------------------------------------------------------
    print("\n| face | vertices | `faceanim rig` time | .glb | .glb --compact |\n|---|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        for label, given in (("default face", []), ("ICT head", [str(ict / "generic_neutral_mesh.obj")])):
            sizes, times = [], []
            for extra in ([], ["--compact"]):
                out = Path(tmp) / f"r{len(extra)}.glb"
                t = time.perf_counter()
                subprocess.run([sys.executable, "-m", "faceanim", "rig", *given, "-o", str(out), *extra], check=True,
                               capture_output=True)
                times.append(time.perf_counter() - t)
                sizes.append(out.stat().st_size / 2 ** 20)
            v = load_mesh(given[0]).n_vertices if given else Face.default().mesh.n_vertices
            print(f"| {label} | {v:,} | {min(times):.1f} s | {sizes[0]:.1f} MiB | {sizes[1]:.1f} MiB |")


SHEET_SHAPES = ("jawOpen", "eyeBlinkLeft", "mouthSmileLeft", "browInnerUp", "mouthPucker", "eyeLookOutLeft",
                "noseSneerLeft", "mouthFunnel")


def sheet(path: Path, rows, size: int = 220) -> None:
    """Rows of renders: each generator's shapes at weight 1 (columns: :data:`SHEET_SHAPES`)."""
    from faceanim.render import save_png
    from faceanim.render.gl import OffscreenRenderer

    lines = []
    for face, shapes, _label in rows:
        with OffscreenRenderer(face.mesh, size=(size, size), **face.view()) as r:
            cells = []
            for name in SHEET_SHAPES:
                cells.append(r.render(face.mesh.vertices + shapes[name]))
                cells.append(np.full((size, 4, 3), 255, np.uint8))
        lines.append(np.hstack(cells))
        lines.append(np.full((4, lines[-1].shape[1], 3), 255, np.uint8))
    path.parent.mkdir(parents=True, exist_ok=True)
    save_png(path, np.vstack(lines[:-1]))
    print(f"\nwrote {path}: rows " + ", ".join(label for *_, label in rows) + "; columns " + ", ".join(SHEET_SHAPES))


if __name__ == "__main__":
    main()
