"""Pictures of expression transfer between people (thesis ch. 6, Figures 6-1 .. 6-6).

    python scripts/render_transfer_figures.py ../shared/data -o docs/images/transfer.png

Rows: real FaceWarehouse expressions. Columns: the person's neutral scan, the real expressive
scan, the expression rebuilt from the 60 control points, and the same control-point motion
transferred to faceanim's default face and to the ICT generic head.
"""

import argparse
from pathlib import Path

import numpy as np

from faceanim.face.default import default_face, default_landmarks
from faceanim.face.face import Face, landmarks_478
from faceanim.face.landmarks import detect_landmarks
from faceanim.io.meshio import load_mesh
from faceanim.render import OffscreenRenderer, save_png
from faceanim.rig.facs import default_library
from faceanim.rig.transfer import ExpressionTransfer, learn_expression

ROWS = ((2, "smile"), (3, "brow lower"), (1, "mouth stretch"), (4, "brow raise"), (19, "eyes closed"), (13, "lip pucker"))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", type=Path)
    ap.add_argument("-o", "--output", type=Path, default=Path("docs/images/transfer.png"))
    ap.add_argument("--size", type=int, default=256)
    args = ap.parse_args(argv)
    lib = default_library()
    aus = lib.parse_action_units("all")
    fw = args.data / "facewarehouse-tester1"
    s0 = load_mesh(fw / "pose_0.obj")
    lm0 = landmarks_478(s0, detect_landmarks(s0))
    targets = [("FaceWarehouse (same person)", s0, lm0)]
    face = default_face()
    targets.append(("default face", face, landmarks_478(face, default_landmarks(face))))
    ict = args.data / "ict-facekit" / "generic_neutral_mesh.obj"
    if ict.exists():
        head = load_mesh(ict)
        targets.append(("ICT head", head, landmarks_478(head, detect_landmarks(head))))
    rigs = [ExpressionTransfer(Face(m, lm), lib) for _, m, lm in targets]
    views = []
    for (_, m, lm) in targets:
        from faceanim.face.landmarks import FACE_OVAL

        views.append(OffscreenRenderer(m, size=(args.size, args.size), yaw=12, pitch=3,
                                       frame_vertices=np.asarray(lm)[list(FACE_OVAL)]))
    rows = []
    for pose, label in ROWS:
        s1 = load_mesh(fw / f"pose_{pose}.obj")
        sample = learn_expression(s0, s1, lm0, library=lib)
        cells = [views[0].render(s0.vertices), views[0].render(s1.vertices)]
        for view, rig in zip(views, rigs):
            cells.append(view.render(rig.mesh.vertices + rig.points_delta(sample, aus)))
        rows.append(np.concatenate(cells, axis=1))
        print(f"pose_{pose} ({label}) done")
    for v in views:
        v.close()
    save_png(args.output, np.concatenate(rows, axis=0))
    print("columns: neutral scan | real expression | rebuilt from 60 control points | "
          + " | ".join(n for n, _, _ in targets[1:]))
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
