"""Players: any Rig and its control curves to MP4 (with sound) or glTF, and FAP streams on a FapRig.

The writers take a :class:`~faceanim.rig.rig.Rig` and an (F, C) matrix of control curves, whatever
built the rig (expressions, action units, FAPs, wires) and whatever drove the curves (key frames,
a FAP stream, speech, a scene script). Every control faceanim has on a face, as one Rig:
:func:`faceanim.autorig.full_rig`.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from faceanim.deform.wires import Curve
from faceanim.errors import FaceAnimError
from faceanim.face.face import Face
from faceanim.face.faps import FapStream
from faceanim.standards.mpeg4 import faps
from faceanim.face.mesh import Mesh
from faceanim.io.gltf import write_gltf
from faceanim.limits import check_video
from faceanim.render import OffscreenRenderer, write_video
from faceanim.rig.mpeg4 import FapRig
from faceanim.rig.rig import Rig
from faceanim.rig.wires import WireSet

CHUNK = 64  # frames evaluated at once while rendering (bounded memory for long clips)


def frames_of(rig: Rig, curves: np.ndarray, chunk: int = CHUNK) -> Iterator[np.ndarray]:
    """Vertices frame by frame, evaluated ``chunk`` frames at a time."""
    for a in range(0, len(curves), chunk):
        yield from rig.evaluate(curves[a:a + chunk])


def render_curves(rig: Rig, curves: np.ndarray, path, fps: float, view: dict | None = None, size: int = 512,
                  audio=None, progress=None) -> Path:
    """Render a rig driven by (F, C) curves to an MP4 (with the sound file ``audio``). ``view``:
    the camera (:meth:`Face.view <faceanim.face.face.Face.view>`: framed on the face oval, turned a
    little); without it the whole mesh, straight on."""
    check_video(len(curves), size, size)
    with OffscreenRenderer(rig.mesh, size=(size, size), **(view or {})) as r:
        r.cull_unseen_backs()
        frames = r.render_frames(frames_of(rig, curves))
        return write_video(path, frames, fps=fps, audio=audio, progress=progress)


def write_rig_gltf(rig: Rig, curves: np.ndarray, path, fps: float, name: str = "animation",
                   names=None, **options) -> Path:
    """A rig and its curves as glTF: one morph target per control the curves use (named by the
    control), weighted by the curve scaled to [-1, 1]. Linear controls are exact; rigid parts (jaw,
    eyes, head) are linearised at the neutral pose with their exact derivative (exact for small
    angles; the MP4 keeps true rotations)."""
    shapes, weights = rig.morph_targets(curves, names)
    if not shapes:
        raise FaceAnimError("the animation moves no control of this face")
    times = np.arange(len(weights)) / fps
    return write_gltf(path, rig.mesh, shapes, times=times, weights=weights, animation_name=name, **options)


def fap_targets(rig: FapRig, stream: FapStream) -> tuple[dict, np.ndarray]:
    """A FAP stream as morph targets: one per FAP the stream uses that this face can show, named by
    the FAP (``open_jaw``), and their (F, T) weights (the values scaled to [-1, 1];
    :meth:`Rig.morph_targets <faceanim.rig.rig.Rig.morph_targets>`)."""
    curves = rig.stream_curves(stream)
    used = [rig.controls[k] for k in np.flatnonzero(np.abs(curves).max(0) > 0)
            if rig.supported[k] and not faps()[k].is_high_level]
    if not used:
        raise FaceAnimError("the stream sets no FAP this face can show")
    return rig.morph_targets(curves, used)


def stream_animation(face: Face, rig: FapRig, stream: FapStream, faps_as_targets: bool = False, **fields):
    """A FAP stream on ``face`` as an :class:`~faceanim.export.Animation`: the stream itself (.fap), the
    FAP rig's curves (an MP4 renders them exactly, the camera :meth:`Face.view`), and either ARKit
    curves and the head's angles fitted to it (:func:`arkit_from_stream`, made only for an output that
    needs them) or, with ``faps_as_targets``, one morph target per FAP (:func:`fap_targets`)."""
    from functools import cache

    from faceanim.export import Animation

    fitted = cache(lambda: arkit_from_stream(face, rig, stream))
    a = Animation(stream.fps, arkit=lambda: fitted()[0], head=lambda: fitted()[1], face=face, rig=rig,
                  curves=rig.stream_curves(stream), rig_turns_head=True, fap=stream, name=stream.name or "faps",
                  view=face.view(), **fields)
    if faps_as_targets:  # the head's FAPs are targets too (linearised): no rotation node besides
        a.targets, a.weights = fap_targets(rig, stream)
        a.head = None
    return a


GROUP_COLOURS = {"brows": (255, 170, 0), "eyes": (0, 200, 255), "mouth": (255, 60, 60), "cheeks": (120, 255, 120),
                 "nose": (255, 255, 0), "other": (255, 255, 255)}


def render_wires(mesh: Mesh, wireset: WireSet, vertices=None, controls=None, size: int = 768,
                 frame_vertices=None) -> np.ndarray:
    """A frontal picture of the face with its wire curves drawn over it (colour by group) and
    their control points as dots; ``controls`` draws wire curves instead of the references;
    ``frame_vertices`` sets the framing (e.g. the face of a full head)."""
    import cv2



    with OffscreenRenderer(mesh, size=(size, size), parallel=True, frame_vertices=frame_vertices,
                           margin=1.15) as r:
        img = np.ascontiguousarray(r.render(vertices))
        for j, (w, g) in enumerate(zip(wireset.wires, wireset.groups)):
            curve = w.reference if controls is None else Curve(controls[j])
            pts = (r.project(curve(np.linspace(0, 1, 120))) * size).astype(np.int32)
            colour = GROUP_COLOURS.get(g, GROUP_COLOURS["other"])
            cv2.polylines(img, [pts.reshape(-1, 1, 2)], False, colour, 2, cv2.LINE_AA)
            for x, y in (r.project(curve.control) * size).astype(int):
                cv2.circle(img, (int(x), int(y)), 4, colour, -1, cv2.LINE_AA)
    return img


ARKIT_FIT_VERTICES = 3000  # face vertices the ARKit fit of a FAP stream looks at (evenly spread)
ARKIT_FIT_RIDGE = 0.01  # the fit's ridge, a share of the shapes' mean squared norm (keeps opposed pairs apart)


def arkit_from_stream(face: Face, rig: FapRig, stream: FapStream) -> tuple[np.ndarray, np.ndarray, float]:
    """A FAP stream as Live Link Face curves for ``face``: per frame, the ARKit weights in [0, 1]
    whose shapes on this face (:func:`~faceanim.rig.arkit.arkit_shapes`, those ``faceanim rig``
    writes: the curves drive that rig as they are) best reproduce the FAP
    rig's expression (bounded least squares with a small ridge over the visible face: skin inside
    the face oval turned towards the camera, where both rigs can be compared, not the mouth's
    inside, which the FAP rig leaves still; the head's rotation is taken apart). Returns ((F, 52) weights in Live Link Face's order, tongueOut 0; (F, 3) head
    yaw, pitch, roll in radians from FAPs 49, 48, 50; the fit's relative residual, the share of
    the expression's displacement the ARKit shapes do not reproduce). A left/right pair set at
    once (``JawLeft`` and ``JawRight``) keeps only its net."""
    from scipy.optimize import lsq_linear

    from faceanim.standards.arkit import ARKIT_NAMES
    from faceanim.rig.arkit import arkit_shapes
    from faceanim.standards.arkit import apple_name

    # tongueOut is not fitted: it opens the mouth by a share of jawOpen (a FAP jaw would be split
    # between the two) and the FAP rig puts out no tongue
    shapes = arkit_shapes(face, rig.eyes)[0]
    arkit = Rig.from_blendshapes(face.mesh, {n: d for n, d in shapes.items() if n != "tongueOut"})
    curves = rig.stream_curves(stream)
    index = {f.name: f.number - 1 for f in faps()}
    head = np.stack([curves[:, index[n]] for n in ("head_yaw", "head_pitch", "head_roll")], axis=1) * 1e-5
    expression = curves.copy()
    expression[:, [index[n] for n in ("head_yaw", "head_pitch", "head_roll")]] = 0.0
    from faceanim.face.mesh import vertex_normals

    facing = vertex_normals(face.mesh.vertices, face.mesh.faces) @ face.frame.rotation[2] > 0.3
    visible = np.flatnonzero(facing & np.asarray(face.skin) & np.asarray(face.face_region))
    if not len(visible):
        raise FaceAnimError("the face shows no skin towards the camera to fit ARKit curves on")
    rows = visible[np.unique(np.linspace(0, len(visible) - 1, min(ARKIT_FIT_VERTICES, len(visible))).astype(int))]
    a = np.stack([arkit.blendshape(n)[rows].ravel() for n in arkit.controls], axis=1)
    ridge = ARKIT_FIT_RIDGE * np.mean(np.sum(a ** 2, axis=0))
    # the ridge-regularised least squares ||a w - d||^2 + ridge ||w||^2 has the same minimiser as
    # ||L^T w - L^-1 a^T d||^2 with L L^T = a^T a + ridge I: each frame's bounded solve is then on a
    # 52 x 52 system instead of 9,000 x 52 (about 100x faster, the same weights)
    from scipy.linalg import cho_factor, solve_triangular

    low, _ = cho_factor(a.T @ a + ridge * np.eye(a.shape[1]), lower=True)
    low = np.tril(low)
    out = np.zeros((len(curves), len(ARKIT_NAMES)))
    column = [[apple_name(n) for n in ARKIT_NAMES].index(c) for c in arkit.controls]
    rest = face.mesh.vertices[rows]
    residual, total = 0.0, 0.0
    for f0 in range(0, len(curves), CHUNK):
        frames = rig.evaluate(expression[f0:f0 + CHUNK])[:, rows] - rest
        for j, d in enumerate(frames):
            d = d.ravel()
            if not np.any(d):
                continue
            fit = lsq_linear(low.T, solve_triangular(low, a.T @ d, lower=True), bounds=(0.0, 1.0), method="bvls")
            out[f0 + j, column] = fit.x
            residual += float(np.sum((a @ fit.x - d) ** 2))
            total += float(np.sum(d ** 2))
    # opposed directions (jaw or mouth to the left and to the right at once) cancel: keep the net
    for left, right in (("JawLeft", "JawRight"), ("MouthLeft", "MouthRight")):
        i, j = ARKIT_NAMES.index(left), ARKIT_NAMES.index(right)
        common = np.minimum(out[:, i], out[:, j])
        out[:, i] -= common
        out[:, j] -= common
    return out, head, (np.sqrt(residual / total) if total > 0 else 0.0)
