"""Build faceanim's average face model (thesis 5.3-5.4) from the neutral faces at hand.

    python scripts/build_average_face.py [--data ../shared/data]

Always uses faceanim's default face; adds the neutral scans of ../shared/data when present
(FaceWarehouse tester 1 pose_0, the ICT generic neutral head). Writes
src/faceanim/assets/average_face.npz and a render next to it for a look (not committed).
"""

import argparse
from pathlib import Path

from faceanim.build.preprocess import DEFAULT_GRID, build_average_face
from faceanim.face.default import default_face, default_landmarks
from faceanim.face.face import landmarks_478
from faceanim.face.landmarks import detect_landmarks
from faceanim.io.meshio import load_mesh

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--grid", type=int, default=DEFAULT_GRID)
    ap.add_argument("-o", "--output", type=Path, default=ROOT / "src/faceanim/assets/average_face.npz")
    ap.add_argument("--image", type=Path, help="also render the average face to this PNG")
    args = ap.parse_args(argv)
    face = default_face()
    faces = [("faceanim default face", face, landmarks_478(face, default_landmarks(face)))]
    for name, path in (("FaceWarehouse tester 1 pose_0", args.data / "facewarehouse-tester1" / "pose_0.obj"),
                       ("ICT FaceKit generic neutral", args.data / "ict-facekit" / "generic_neutral_mesh.obj")):
        if path.exists():
            mesh = load_mesh(path)
            faces.append((name, mesh, landmarks_478(mesh, detect_landmarks(mesh))))
    afm = build_average_face(faces, args.grid)
    afm.save(args.output)
    print(f"average of {len(faces)} faces ({'; '.join(afm.sources)}) -> {args.output}")
    if args.image:
        from faceanim.render import render_png

        render_png(afm.mesh(), args.image, size=(512, 512), yaw=20, pitch=5)
        print(f"wrote {args.image}")


if __name__ == "__main__":
    main()
