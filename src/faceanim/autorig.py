"""One-command rig: any face mesh in, every control faceanim has written as named morph targets
out (``faceanim rig``), in the names avatar tools use.

The sets (:data:`RIG_SETS`), each built from the input mesh and its landmarks alone:

- ``arkit``: Apple ARKit's blendshapes with Apple's exact names (``eyeBlinkLeft`` ... ; Left and
  Right are the subject's own sides). Displacement patterns learned from ICT FaceKit's
  artist-made ARKit shapes (the generic head) are carried onto the face by the retargeting of
  :mod:`faceanim.rig.retarget` (the face's registration: the generic head's morphable model
  fitted and moved onto the surface, dense correspondence part by part, motion carried by the
  registration's similarity): no shape is copied, every displacement is rebuilt on the face's
  own surface. The ``eyeLook*`` shapes also turn the eyeballs when the mesh has them (ICT's own
  move only the lids): by the angles a real Live Link Face take records for a look curve at 1
  (:data:`~faceanim.standards.arkit.LOOK_ANGLES`). ``tongueOut`` (which ICT lacks) is the generic
  head's own: the mouth opened and the tongue put out over the lower lip; a mesh with nothing in
  its mouth gets the opening alone, and is told so (``notes``).
- ``visemes``: the 15 Oculus visemes (``viseme_sil`` ... ``viseme_U``, MPEG-4's visemes 0-14)
  as mixes of the face's own ARKit shapes (``data/visemes_arkit.json``): posed by the FAP rig
  they came out as grimaces (a review's pictures); the ARKit shapes keep jaw, lips and teeth
  natural.
- ``rpm``: Ready Player Me's five extra shapes (``mouthOpen``, ``mouthSmile``, ``eyesClosed``,
  ``eyesLookUp``, ``eyesLookDown``: :data:`~faceanim.standards.visemes.RPM_EXTRAS`), each the sum
  of the face's own ARKit shapes it stands for.
- ``au``: FACS action units, each with its one-sided halves (Erdogdu's control points, the AU
  library learned from real scans).
- ``emotions``: the six basic emotions (``joy`` ... ``disgust``) as AU combinations.
- ``fap``: every MPEG-4 FAP the face supports (its name, e.g. ``open_jaw``), at the largest
  value faceanim's viseme and expression tables use.

:func:`vrm_expressions` binds VRM 1.0's expression presets to these targets.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from faceanim.catalogue import EMOTIONS, RIG_SETS
from faceanim.errors import FaceAnimError, shown
from faceanim.face.face import Face
from faceanim.rig.rig import Rig
from faceanim.standards.visemes import RPM_EXTRAS


# values a FAP takes at weight 1 when faceanim's tables never use it: a fifth of a FAPU x 1024
# for a displacement, 0.3 rad for an angle
FAP_DISTANCE_DEFAULT, FAP_ANGLE_DEFAULT = 200.0, 30000.0
HEAD_FAPS = ("head_pitch", "head_yaw", "head_roll")  # the whole head turning: a node's rotation, not a shape


@dataclass
class AutoRig:
    """A face's generated controls: ``shapes`` name -> (V, 3) displacement at weight 1, ``sets``
    set name -> its names (in order), ``skipped`` name -> why it could not be made on this face,
    ``eyes`` whether the mesh has eyeballs faceanim turns, ``notes`` name -> what a shape made
    does on this face when that is less than its name says (``tongueOut`` without a tongue)."""

    face: Face
    shapes: dict[str, np.ndarray]
    sets: dict[str, list[str]]
    skipped: dict[str, str] = field(default_factory=dict)
    eyes: bool = False
    notes: dict[str, str] = field(default_factory=dict)

    def rig(self) -> Rig:
        return Rig.from_blendshapes(self.face.mesh, self.shapes)


def full_rig(face: Face, sets=RIG_SETS, progress=None) -> Rig:
    """Every control of ``sets`` (default: all) on ``face`` as one Rig of blendshapes: what
    ``faceanim rig`` writes, to evaluate, render or export (:func:`auto_rig`'s shapes)."""
    return auto_rig(face, sets, progress).rig()


def parse_sets(text: str) -> list[str]:
    """``"arkit,visemes"`` -> the sets in :data:`RIG_SETS` order; ``all`` for every set."""
    asked = [s.strip().lower() for s in str(text).split(",")]
    if "" in asked:
        raise FaceAnimError(f"--set has an empty item; give one or more of: {', '.join(RIG_SETS)} (or all), "
                            "separated by single commas")
    twice = [s for k, s in enumerate(asked) if s in asked[:k]]
    if twice:
        raise FaceAnimError(f"rig set '{shown(twice[0])}' is given twice in --set; give each once")
    unknown = [s for s in asked if s not in RIG_SETS and s != "all"]
    if unknown:
        raise FaceAnimError(f"unknown rig set '{shown(unknown[0])}'; choose from: {', '.join(RIG_SETS)} (or all)")
    return list(RIG_SETS) if "all" in asked else [s for s in RIG_SETS if s in asked]


def viseme_mixes() -> list[dict]:
    """The 15 Oculus visemes as ARKit mixes (``data/visemes_arkit.json``), in MPEG-4's order."""
    import json
    from importlib import resources

    return json.loads(resources.files("faceanim").joinpath("data", "visemes_arkit.json").read_text())["visemes"]


def _fap_scales() -> dict[int, float]:
    """Per FAP number: the largest |value| faceanim's viseme and expression tables give it."""
    from faceanim.drivers.mpeg4 import fap_set, viseme_table

    table = viseme_table()
    out: dict[int, float] = {}
    for spec in list(table["visemes"].values()) + list(table["expressions"].values()):
        for number, value in fap_set(spec.get("faps") or {}).items():
            out[number] = max(out.get(number, 0.0), abs(value))
    return out


def auto_rig(face: Face, sets=RIG_SETS, progress=None, style: str = "realistic") -> AutoRig:
    """Every control of ``sets`` on ``face`` as named shapes (module docstring). ``progress``:
    an optional callable taking the name of each set as it starts; ``style``: the blinks' lids,
    realistic or stylised (:func:`~faceanim.rig.arkit.closed_blink`)."""
    from faceanim.standards.mpeg4 import faps
    from faceanim.rig.arkit import NO_TONGUE, arkit_shapes, shows_tongue
    from faceanim.rig.mpeg4 import FapRig
    from faceanim.rig.transfer import ExpressionTransfer, default_model

    sets = [s for s in RIG_SETS if s in set(sets)]
    if not sets:
        raise FaceAnimError(f"no rig set asked for; choose from: {', '.join(RIG_SETS)}")
    fap = FapRig.build(face) if {"arkit", "visemes", "rpm", "fap"} & set(sets) else None
    arkit = au_rig = None  # made once, for the sets that share them
    eyes = dict(fap.eyes) if fap is not None else {}
    if {"arkit", "visemes", "rpm"} & set(sets):  # eye plates (anime) turn too: the look presets apply
        from faceanim.rig.arkit import face_eyes

        eyes = face_eyes(face, eyes)
    rest = face.mesh.vertices
    shapes: dict[str, np.ndarray] = {}
    groups: dict[str, list[str]] = {}
    skipped: dict[str, str] = {}
    notes: dict[str, str] = {}

    def pose(values: dict[int, float]) -> np.ndarray:
        curves = np.zeros((1, fap.n_controls))
        for number, value in values.items():
            curves[0, number - 1] = value
        return fap.evaluate(curves)[0] - rest

    def add(group: str, made: dict[str, np.ndarray]) -> None:
        for name, d in made.items():
            if name in shapes:
                raise FaceAnimError(f"two rig sets both make a shape named '{name}'")
            shapes[name] = np.asarray(d, dtype=np.float64)
        groups[group] = list(made)

    for group in sets:
        if progress is not None:
            progress(group)
        if group == "arkit":
            made, why = arkit_shapes(face, eyes, style)
            arkit = made
            add(group, made)
            skipped.update(why)
            if "tongueOut" in made and not shows_tongue(made, face.frame.iod):
                notes["tongueOut"] = NO_TONGUE
        elif group in ("visemes", "rpm"):
            if arkit is None:
                arkit, _ = arkit_shapes(face, eyes, style)
            mixes = ({f"viseme_{v['oculus']}": v["arkit"] for v in viseme_mixes()} if group == "visemes"
                     else RPM_EXTRAS)
            add(group, {name: sum((w * arkit[n] for n, w in mix.items() if n in arkit), np.zeros_like(rest))
                        for name, mix in mixes.items()})
        elif group in ("au", "emotions"):
            if au_rig is None:
                au_rig = ExpressionTransfer(face).rig(default_model(), sides=True)
            names = [n for n in au_rig.controls if (n in EMOTIONS) == (group == "emotions")]
            add(group, {n: au_rig.blendshape(n) for n in names})
        elif group == "fap":
            scale = _fap_scales()
            made = {}
            for f in faps():
                if f.is_high_level or f.name in HEAD_FAPS:
                    continue
                if f.number in fap.unsupported:
                    skipped[f.name] = fap.unsupported[f.number]
                    continue
                value = scale.get(f.number) or (FAP_ANGLE_DEFAULT if f.is_rotation else FAP_DISTANCE_DEFAULT)
                made[f.name] = pose({f.number: value})
            add(group, made)
    return AutoRig(face, shapes, groups, skipped, eyes=bool(eyes) and all(eyes.get(s) is not None for s in "LR"),
                   notes=notes)


# VRM 1.0's expression presets from the targets above: (preset, {target: weight}), the first
# alternative whose targets all exist wins
VRM_PRESETS: dict[str, tuple[dict[str, float], ...]] = {
    "happy": ({"joy": 1.0}, {"mouthSmileLeft": 1.0, "mouthSmileRight": 1.0, "cheekSquintLeft": 0.5,
                             "cheekSquintRight": 0.5}),
    "angry": ({"anger": 1.0}, {"browDownLeft": 1.0, "browDownRight": 1.0, "noseSneerLeft": 0.4,
                               "noseSneerRight": 0.4, "mouthPressLeft": 0.5, "mouthPressRight": 0.5}),
    "sad": ({"sadness": 1.0}, {"browInnerUp": 1.0, "mouthFrownLeft": 1.0, "mouthFrownRight": 1.0}),
    "relaxed": ({"mouthSmileLeft": 0.35, "mouthSmileRight": 0.35, "eyeSquintLeft": 0.3, "eyeSquintRight": 0.3},
                {"joy": 0.4}),
    "surprised": ({"surprise": 1.0}, {"browInnerUp": 1.0, "browOuterUpLeft": 1.0, "browOuterUpRight": 1.0,
                                      "eyeWideLeft": 1.0, "eyeWideRight": 1.0, "jawOpen": 0.4}),
    "aa": ({"viseme_aa": 1.0}, {"jawOpen": 0.6}),
    "ih": ({"viseme_I": 1.0},),
    "ou": ({"viseme_U": 1.0}, {"mouthPucker": 1.0, "jawOpen": 0.2}),
    "ee": ({"viseme_E": 1.0},),
    "oh": ({"viseme_O": 1.0}, {"mouthFunnel": 1.0, "jawOpen": 0.3}),
    "blinkLeft": ({"eyeBlinkLeft": 1.0}, {"AU43_L": 1.0}),
    "blinkRight": ({"eyeBlinkRight": 1.0}, {"AU43_R": 1.0}),
    "blink": ({"eyeBlinkLeft": 1.0, "eyeBlinkRight": 1.0}, {"AU43": 1.0}),
    # VRM's look directions are the avatar's own (its left is the subject's left)
    "lookUp": ({"eyeLookUpLeft": 1.0, "eyeLookUpRight": 1.0},),
    "lookDown": ({"eyeLookDownLeft": 1.0, "eyeLookDownRight": 1.0},),
    "lookLeft": ({"eyeLookOutLeft": 1.0, "eyeLookInRight": 1.0},),
    "lookRight": ({"eyeLookInLeft": 1.0, "eyeLookOutRight": 1.0},),
    "neutral": ({},),
}
LOOK_PRESETS = ("lookUp", "lookDown", "lookLeft", "lookRight")
EYE_SPAN_M = 0.0935  # the default face's eye span (Face.frame.iod) in metres: an adult's


def metres_per_unit(face: Face) -> float:
    """The mesh's unit in metres, for formats that need metres (VRM): the power of ten that
    gives the face an adult's eye span (a mesh in millimetres: 0.001; in centimetres: 0.01)."""
    return float(10.0 ** np.round(np.log10(EYE_SPAN_M / face.frame.iod)))


def vrm_expressions(auto: AutoRig) -> tuple[dict[str, dict[str, float]], dict[str, str]]:
    """VRM 1.0 expression presets bound to ``auto``'s targets, and the presets left out with why
    (the look presets on a mesh without eyeballs; a preset none of whose targets were made)."""
    out, skipped = {}, {}
    for preset, options in VRM_PRESETS.items():
        if preset in LOOK_PRESETS and not auto.eyes:
            skipped[preset] = "the mesh has no eyeballs to turn"
            continue
        for binds in options:
            if all(n in auto.shapes for n in binds):
                out[preset] = dict(binds)
                break
        else:
            wanted = sorted({n for binds in options for n in binds})[:3]
            skipped[preset] = f"none of its shapes is in the rig (it binds {', '.join(wanted)}: add the set that makes them)"
    return out, skipped


THUMBNAIL_SIZE = 512  # pixels per side of a VRM's thumbnail


def thumbnail_png(face: Face, size: int = THUMBNAIL_SIZE) -> bytes:
    """The face rendered from the front, as PNG bytes (a VRM's thumbnail)."""
    import io

    from PIL import Image

    from faceanim.render import OffscreenRenderer

    with OffscreenRenderer(face.mesh, size=(size, size), **face.view(yaw=0.0, pitch=0.0)) as r:
        image = r.render(face.mesh.vertices)
    out = io.BytesIO()
    Image.fromarray(image).save(out, format="PNG")
    return out.getvalue()


def write_rigged(path, auto: AutoRig, compact: bool = False, meta: dict | None = None,
                 vrm_version: int = 1) -> tuple[Path, dict]:
    """The rig as a file by the suffix of ``path``: ``.glb`` (every shape a morph target, the sets
    in the scene's ``extras.morph_sets``; ``compact``: quantised) or ``.vrm`` (VRM 1.0, or 0.x with
    ``vrm_version`` 0: the presets of :func:`vrm_expressions`, each ARKit shape also a custom
    expression by its name for apps that drive them ("Perfect Sync"), the gaze's range maps reaching
    a look shape's full weight at its eye angle, ``meta`` over the restrictive defaults, a front
    render as the thumbnail). Returns (the path, the VRM presets left out with why)."""
    from faceanim.io.gltf import write_gltf

    face = auto.face
    extras = {"morph_sets": auto.sets}
    if Path(path).suffix.lower() != ".vrm":
        return write_gltf(path, face.mesh, auto.shapes, quantize=compact, extras=extras), {}
    from faceanim.io.vrm import write_vrm
    from faceanim.export import head_pivot
    from faceanim.standards.arkit import LOOK_ANGLES

    expressions, left_out = vrm_expressions(auto)
    look_at = {key: {"inputMaxValue": round(float(np.degrees(LOOK_ANGLES[look])), 2), "outputScale": 1.0}
               for key, look in (("rangeMapHorizontalOuter", "Out"), ("rangeMapHorizontalInner", "In"),
                                 ("rangeMapVerticalUp", "Up"), ("rangeMapVerticalDown", "Down"))}
    custom = {name: {name: 1.0} for name in auto.sets.get("arkit", [])}
    written = write_vrm(path, face.mesh, auto.shapes, expressions, head_pivot=head_pivot(face),
                        rotation=face.frame.rotation, scale=metres_per_unit(face),
                        eyes=0.5 * (face.landmarks[468] + face.landmarks[473]), meta=meta, look_at=look_at,
                        custom=custom, extras=extras, version=vrm_version, thumbnail=thumbnail_png(face))
    return written, left_out
