"""Build faceanim's embedded default face: a whole head made from one real photograph.

The photo is scikit-image's ``astronaut`` (Eileen Collins, NASA, public domain). It goes through
faceanim's own photo pipeline (``faceanim.build.photo``, Lee et al. 1999, section 2) with one
front view: the generic head (ICT FaceKit) gets the face's proportions from the photo and its
depth from the generic head; the photo's smile and parted lips are fitted with the generic head's
blendshapes, the texture is taken on that smiling head (so lips sample lips and the teeth the
photo shows are not painted on the lips), and the head is stored without the smile. The fit leaves
the corners raised (0.07 inter-ocular distances over the middle of the lips; the generic head
0.005): ``NEUTRAL_MOUTH``, a mix of the head's own shapes chosen by looking at renders, lowers them
to 0.02 at the generic head's mouth width (-1 of mouthSmile alone would make a pout).

Writes ``src/faceanim/assets/default_head.npz`` (vertices, texture coordinates) and
``default_head.png`` (the texture atlas); triangles, parts and landmarks are the generic head's.
Run it with ``python scripts/build_default_face.py``; the result is committed, users never need it.
``--mouth-only`` paints the committed atlas's gums and tongue again (``texture.repaint_mouth``)
and keeps the committed geometry and every other texel: the head was built on MediaPipe's legacy
face mesh, a whole rebuild on the Face Landmarker moves the face (up to 18 mm) and every figure
measured on it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

ASSETS = ROOT / "src" / "faceanim" / "assets"
TEXTURE_SIZE = 1024
# the resting mouth: corners down without narrowing the mouth (issue 20)
NEUTRAL_MOUTH = {"mouthFrown_L": 0.2, "mouthFrown_R": 0.2, "mouthSmile_L": -0.5, "mouthSmile_R": -0.5,
                 "mouthStretch_L": 0.2, "mouthStretch_R": 0.2}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mouth-only", action="store_true",
                    help="repaint the committed texture's gums and tongue; keep everything else")
    args = ap.parse_args(argv)
    if args.mouth_only:
        from faceanim.build.texture import repaint_mouth
        from faceanim.face.default import default_face, default_parts

        m = default_face()
        texture = repaint_mouth(m.vertices, m.faces, m.uv, m.face_uv, default_parts(), m.texture)
        Image.fromarray(texture).save(ASSETS / "default_head.png", optimize=True)
        print(f"default head: gums and tongue repainted, {int((texture != m.texture).any(-1).sum())} texels changed")
        return
    from skimage import data

    from faceanim.build.photo import head_from_photos
    from faceanim.face.generic_head import generic_head

    photo = data.astronaut()
    ph = head_from_photos(("astronaut", photo), texture_size=TEXTURE_SIZE)
    m = ph.mesh
    shapes = generic_head().carried_shapes(ph.fitted.affine[:, :3])
    vertices = m.vertices + sum(w * shapes[name] for name, w in NEUTRAL_MOUTH.items())
    np.savez_compressed(
        ASSETS / "default_head.npz",
        vertices=vertices.astype(np.float32),
        uv=m.uv.astype(np.float32),
        face_uv=m.face_uv.astype(np.int32),
        affine=ph.fitted.affine,  # the fit's global part: carries the generic head's shapes over
    )
    Image.fromarray(m.texture).save(ASSETS / "default_head.png", optimize=True)
    taken = ", ".join(f"{n} {w:.2f}" for n, w in ph.fitted.expression.items() if w > 0.01)
    print(f"default head: {m.n_vertices} vertices, texture {m.texture.shape[1]}x{m.texture.shape[0]}; "
          f"expression taken off: {taken or 'none'}; " + ", ".join(f"{k} {v:.1f} s" for k, v in ph.timings.items()))


if __name__ == "__main__":
    main()
