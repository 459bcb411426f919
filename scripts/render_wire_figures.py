"""Pictures of the wires (Pyun, Shin & Shin 2001, Figures 1, 2 and 4).

    python scripts/render_wire_figures.py [../shared/data] -o docs/images

wires.png: the default wires on faceanim's default face. With the data folder, also
wires_facewarehouse.png: the FaceWarehouse neutral with its wires | real smile | smile rebuilt
from its wires (wire curves drawn) | real mouth stretch | rebuilt; and a row of the blend from
brow lower to mouth stretch, uniform (top) and with sqrt for the eyes and t^3 for the mouth.
"""

import argparse
from pathlib import Path

import numpy as np

from faceanim.face.default import default_face, default_landmarks
from faceanim.face.face import landmarks_478
from faceanim.face.landmarks import FACE_OVAL
from faceanim.player import render_wires
from faceanim.render import save_png
from faceanim.rig.wires import (
    align_template,
    blend,
    default_wires,
    extract_template,
)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data", type=Path, nargs="?")
    ap.add_argument("-o", "--out", type=Path, default=Path("docs/images"))
    ap.add_argument("--size", type=int, default=320)
    args = ap.parse_args(argv)
    face = default_face()
    lm = landmarks_478(face, default_landmarks(face))
    save_png(args.out / "wires.png", render_wires(face, default_wires(lm), size=2 * args.size))
    print(f"wrote {args.out / 'wires.png'}")
    if args.data is None:
        return
    from faceanim.face.landmarks import detect_landmarks
    from faceanim.io.meshio import load_mesh

    fw = args.data / "facewarehouse-tester1"
    base = load_mesh(fw / "pose_0.obj")
    blm = landmarks_478(base, detect_landmarks(base))
    ws = default_wires(blm)
    bound = ws.influence(base, blm)
    size = args.size
    frame = blm[list(FACE_OVAL)]
    row = [render_wires(base, ws, size=size, frame_vertices=frame)]
    templates = {}
    for pose in (2, 1, 3):
        real = align_template(base, load_mesh(fw / f"pose_{pose}.obj"), blm)
        t = extract_template(base, real, ws, bound)
        templates[pose] = t
        if pose in (2, 1):
            row.append(_plain(base, real.vertices, size, frame))
            row.append(render_wires(base, ws, vertices=t.rebuild(base, bound), controls=t.controls, size=size,
                                    frame_vertices=frame))
    rows = [np.concatenate(row, axis=1)]
    for funcs in ({}, {"eyes": "sqrt", "mouth": "cubic"}):
        strip = [_plain(base, blend(templates[3], templates[1], s, funcs).rebuild(base, bound), size, frame)
                 for s in np.linspace(0, 1, 5)]
        rows.append(np.concatenate(strip, axis=1))
    save_png(args.out / "wires_facewarehouse.png", np.concatenate(rows, axis=0))
    print(f"wrote {args.out / 'wires_facewarehouse.png'}")


def _plain(mesh, vertices, size, frame):
    from faceanim.render import OffscreenRenderer

    with OffscreenRenderer(mesh, size=(size, size), parallel=True, frame_vertices=frame, margin=1.15) as r:
        return r.render(vertices)


if __name__ == "__main__":
    main()
