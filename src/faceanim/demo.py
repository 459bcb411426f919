"""The demo: the default face, expressions from two papers, written as GLB, MP4 and PNGs.

The default face is a whole head made from one photo (Lee et al. 1999's cloning, see
``faceanim.build.photo``); it blinks over its eyeballs and opens its jaw onto its teeth with the
generic head's own shapes.

Four expressions made of geometry deformation elements follow Noh et al.'s examples (figures 5,
7-9): a smile from the mouth corners and cheeks, sadness from lowered corners and raised inner
brows, anger from lowered, drawn-together brows and pressed lips, and the mouth shape for 'A'
from the jaw and lower lip (offsets and extents in metres, placed at landmarks of the default
face). The six basic emotions come from FACS action units learned from real scans (Erdogdu),
transferred to the default face by its landmarks; they are named ``facs_joy`` ..
``facs_disgust`` (the GDE set has its own ``sadness`` and ``anger``).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from faceanim.deform.gde import GeometryDeformationElement as GDE
from faceanim.drivers.keyframes import expression_tour
from faceanim.face.default import default_landmarks, default_shapes
from faceanim.face.face import HEAD_MARGIN, Face
from faceanim.limits import DEFAULT_FPS
from faceanim.player import frames_of, write_rig_gltf
from faceanim.render import OffscreenRenderer, save_png, write_video
from faceanim.rig.expressions import Expression, expression_rig
from faceanim.rig.rig import Rig


def demo_expressions(lm) -> list[Expression]:
    """Smile, sadness, anger and 'A' as GDE sets on a face with MediaPipe-478 landmarks ``lm``."""

    def e(name, metric, extent):
        return GDE(tuple(lm[name]), extent, metric, name=name)

    smile = Expression("smile", [
        e("mouth_corner_right", "euclidean", 0.028), e("mouth_corner_left", "euclidean", 0.028),
        e("cheek_right", "euclidean", 0.025), e("cheek_left", "euclidean", 0.025),
    ], np.array([[-0.010, 0.009, -0.004], [0.010, 0.009, -0.004], [0, 0.005, 0.003], [0, 0.005, 0.003]]))
    sadness = Expression("sadness", [
        e("mouth_corner_right", "euclidean", 0.025), e("mouth_corner_left", "euclidean", 0.025),
        e("brow_inner_right", "euclidean", 0.02), e("brow_inner_left", "euclidean", 0.02),
        e("lower_lip_bottom", "edges", 10),
    ], np.array([[0.0015, -0.008, 0], [-0.0015, -0.008, 0], [0.0015, 0.007, 0], [-0.0015, 0.007, 0],
                 [0, 0.003, 0.002]]))
    anger = Expression("anger", [
        e("brow_inner_right", "euclidean", 0.022), e("brow_inner_left", "euclidean", 0.022),
        e("brow_middle_right", "euclidean", 0.02), e("brow_middle_left", "euclidean", 0.02),
        e("upper_lip_inner", "edges", 8), e("lower_lip_inner", "edges", 8),
    ], np.array([[0.005, -0.008, 0.001], [-0.005, -0.008, 0.001], [0, -0.005, 0], [0, -0.005, 0],
                 [0, -0.0025, 0], [0, 0.0025, 0]]))
    mouth_a = Expression("A", [
        e("chin", "euclidean", 0.045), e("lower_lip_inner", "edges", 14), e("upper_lip_inner", "edges", 10),
    ], np.array([[0, -0.020, -0.006], [0, -0.012, 0], [0, 0.003, 0]]))
    return [smile, sadness, anger, mouth_a]


def emotion_blendshapes(face: Face) -> dict[str, np.ndarray]:
    """The six basic emotions on a face from the built-in action-unit library, ``facs_<name>``."""
    from faceanim.rig.transfer import ExpressionTransfer, default_model

    rig = ExpressionTransfer(face).rig(default_model(), sides=False)
    return {f"facs_{name}": d for name, d in rig.blendshape_dict().items() if not name.startswith("AU")}


def run_demo(out_dir: str | Path = "faceanim-demo", fps: float = DEFAULT_FPS, size: int = 512,
             quiet: bool = False, progress=None) -> list[Path]:
    """Build the default face and its expressions; write demo.glb, demo.mp4 and PNGs to ``out_dir``,
    all or none (made in a staging folder, moved in at the end: a stop or a full disk leaves the
    folder as it was). ``progress``: an optional callable taking the name of each stage as it starts."""
    from faceanim.io.files import atomic_folder

    out = Path(out_dir)
    with atomic_folder(out, "demo folder") as stage:
        made = _make_demo(stage, fps, size, quiet, progress)
    return [out / p.name for p in made]


def _make_demo(out: Path, fps: float, size: int, quiet: bool, progress) -> list[Path]:
    from tqdm import tqdm

    step = progress or (lambda name: None)
    step("the default face and its expressions")
    face = Face.default()
    shapes = expression_rig(face.mesh, demo_expressions(default_landmarks(face.mesh))).blendshape_dict()
    shapes.update(emotion_blendshapes(face))
    # the head's own eyelids close over its eyeballs and its jaw opens onto its teeth (the generic
    # head's ARKit shapes, carried over by the photo fit)
    arkit = default_shapes()
    shapes["blink"] = arkit["eyeBlink_L"] + arkit["eyeBlink_R"]
    shapes["jaw_open"] = arkit["jawOpen"]
    rig = Rig.from_blendshapes(face.mesh, shapes)
    _, curves = expression_tour(rig.controls).sample(fps)
    step("demo.glb")
    written = [write_rig_gltf(rig, curves, out / "demo.glb", fps, "expressions", names=rig.controls)]

    show = not quiet and sys.stderr.isatty()
    with OffscreenRenderer(face.mesh, size=(size, size), **face.view(margin=HEAD_MARGIN, yaw=20.0, pitch=4.0)) as renderer:
        step("the PNGs")
        written.append(save_png(out / "neutral.png", renderer.render()))
        for name in rig.controls:
            written.append(save_png(out / f"{name}.png", renderer.render(rig.pose({name: 1.0}))))
        step("demo.mp4")
        renderer.cull_unseen_backs(face.mesh.vertices)
        frames = renderer.render_frames(frames_of(rig, curves))  # a few frames at a time, pipelined
        with tqdm(total=len(curves), desc="rendering demo.mp4", unit="frame", disable=not show) as bar:
            written.append(write_video(out / "demo.mp4", frames, fps=fps, progress=bar))
    return written
