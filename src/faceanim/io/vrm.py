"""VRM export: a head as a VRM avatar, VRM 1.0 (``VRMC_vrm``) or 0.x (the ``VRM`` extension).

:func:`write_vrm` writes the mesh, its morph targets, UV seams and texture exactly as
:func:`faceanim.io.gltf.write_gltf` does (one shared writer, :func:`~faceanim.io.gltf.build_gltf`),
and adds what a VRM 1.0 consumer (three-vrm, UniVRM, VTuber applications) needs:

- **meta**: name, authors, the VRM Public License 1.0 URL and its settings. The defaults are the
  most restrictive ones the licence offers (only the author may use the avatar, personal
  non-profit use, credit required, no redistribution, no modification, no violent, sexual,
  political/religious or antisocial use); the caller widens them through ``meta``.
- **humanoid**: the spec requires hips, spine, head and both legs (upper leg, lower leg, foot)
  and both arms (upper arm, lower arm, hand). A head has none of the body, so the avatar gets an
  invisible skeleton of adult proportions in metres (no geometry hangs on it): hips, spine,
  chest, neck and head up the midline (x = 0), legs down to feet 8 cm above the ground (y = 0),
  arms straight out along x (the T pose). Every bone is a node with a translation only (no
  rotation or scale: the rest pose is the identity), so the mesh node is a child of ``head``.
- **units and axes**: VRM is in metres, +Y up, the avatar facing +Z (its left is +X). faceanim
  meshes come in any unit and orientation, so the vertices (and the morph deltas) are
  transformed, never the nodes: a file position is ``scale * rotation @ (v - head_pivot)``,
  relative to the head bone, which stands at :data:`HEAD_BONE_HEIGHT`. ``rotation``'s rows are
  the avatar's left, up and forward directions in mesh coordinates (a proper rotation, as
  faceanim's ``FaceFrame.rotation``). The vertex count and order are kept (the first V glTF
  vertices are the mesh's; UV-seam copies follow, ``primitive.extras.sourceVertex``).
- **expressions**: VRM presets bound to morph targets (``node``: the mesh's node, ``index``: the
  target, ``weight`` in [0, 1]). Emotions fade blinking out as they rise (``overrideBlink:
  "blend"``: their lids are already shaped); blinks fade the gaze (``overrideLookAt: "blend"``:
  eyes turning under a closed lid poke through it); mouth shapes and gaze override nothing.
- **lookAt**: type ``expression`` (the gaze moves the four look presets, no eye bones), with
  ``offsetFromHeadBone`` at the point between the eyes when ``eyes`` is given; each range map
  reaches weight 1 at 90 degrees unless ``look_at`` says otherwise (the convention of UniVRM
  and three-vrm for expression gaze).
- **firstPerson**: the head mesh is ``thirdPersonOnly`` (a VR user's own camera sits inside it).

- **custom expressions** (``custom``): any others by name, e.g. one per ARKit blendshape for apps
  that drive them by Apple's names ("Perfect Sync").

- **thumbnail**: a PNG (a front render) as the meta's thumbnail image.

**VRM 0.x** (``version=0``; VSeeFace, VMagicMirror and many VTuber apps read only 0.x): the same
data in 0.x's form: the avatar faces -Z (0.x's convention: vertices and bones turned half a turn
about +Y), the ``VRM`` extension with ``specVersion`` 0.0; ``meta`` with 0.x's fields (title,
author, ``allowedUserName``, ``commercialUssageName``, ``licenseName`` ... from the 1.0 fields:
:func:`vrm0_meta`); ``humanoid.humanBones`` as a list; ``firstPerson`` with the head bone, the eye
offset (in 0.x's Unity axes), the mesh ``ThirdPersonOnly`` and BlendShape gaze curves;
``blendShapeMaster.blendShapeGroups`` with 0.x's preset names (``A``, ``Blink_L``, ``Joy`` ...;
:data:`~faceanim.standards.vrm.VRM0_FROM_1`) and weights in 0..100, each custom expression (and
1.0's ``surprised``) a group of preset ``unknown``; ``materialProperties`` keeping the glTF
material (``VRM_USE_GLTFSHADER``).

Animations are not written (VRM leaves them unused), nor spring bones or MToon materials: the
material is the same PBR skin as the glTF.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from faceanim.errors import FaceAnimError, shown
from faceanim.face.mesh import Mesh
from faceanim.io.files import check_output_path
from faceanim.io.gltf import build_gltf, checked_blendshapes, save_glb
from faceanim.standards.vrm import BLINKS, EMOTIONS, LICENSE_FIELDS, LICENSE_FLAGS, LOOKS, PRESETS, VRM0_FROM_1

VRM_EXTENSION = "VRMC_vrm"
VRM0_EXTENSION = "VRM"
HALF_TURN = np.diag([-1.0, 1.0, -1.0])  # VRM 1.0's axes (facing +Z) to 0.x's (facing -Z)
LICENSE_URL = "https://vrm.dev/licenses/1.0/"


# the humanoid's bones: name, parent, position in model space (metres, +Y up, facing +Z, the
# avatar's left at +X); an adult of about 1.7 m in the T pose, the head bone at the top of the neck
HEAD_BONE_HEIGHT = 1.50
SKELETON = (
    ("hips", None, (0.0, 0.92, 0.0)),
    ("spine", "hips", (0.0, 1.02, 0.0)),
    ("chest", "spine", (0.0, 1.20, 0.0)),
    ("neck", "chest", (0.0, 1.40, 0.0)),
    ("head", "neck", (0.0, HEAD_BONE_HEIGHT, 0.0)),
    ("leftUpperArm", "chest", (0.17, 1.38, 0.0)),
    ("leftLowerArm", "leftUpperArm", (0.45, 1.38, 0.0)),
    ("leftHand", "leftLowerArm", (0.70, 1.38, 0.0)),
    ("rightUpperArm", "chest", (-0.17, 1.38, 0.0)),
    ("rightLowerArm", "rightUpperArm", (-0.45, 1.38, 0.0)),
    ("rightHand", "rightLowerArm", (-0.70, 1.38, 0.0)),
    ("leftUpperLeg", "hips", (0.09, 0.87, 0.0)),
    ("leftLowerLeg", "leftUpperLeg", (0.09, 0.48, 0.0)),
    ("leftFoot", "leftLowerLeg", (0.09, 0.08, 0.0)),
    ("rightUpperLeg", "hips", (-0.09, 0.87, 0.0)),
    ("rightLowerLeg", "rightUpperLeg", (-0.09, 0.48, 0.0)),
    ("rightFoot", "rightLowerLeg", (-0.09, 0.08, 0.0)),
)
# the humanoid bones VRM 1.0 requires (VRMC_vrm.humanoid.humanBones.schema.json)
REQUIRED_BONES = ("hips", "spine", "head", "leftUpperLeg", "leftLowerLeg", "leftFoot", "rightUpperLeg",
                  "rightLowerLeg", "rightFoot", "leftUpperArm", "leftLowerArm", "leftHand", "rightUpperArm",
                  "rightLowerArm", "rightHand")

# a head in metres measures between these (bounding-box diagonal): outside, the scale is wrong
HEAD_SIZE_RANGE = (0.02, 3.0)

_ENUMS = LICENSE_FIELDS
_FLAGS = LICENSE_FLAGS
_TEXTS = ("name", "version", "copyrightInformation", "contactInformation", "thirdPartyLicenses", "otherLicenseUrl")
_LISTS = ("authors", "references")
# the most restrictive settings of the VRM Public License 1.0 (also the spec's defaults), written out
DEFAULT_META = {
    "authors": ["unknown"],
    "licenseUrl": LICENSE_URL,
    "avatarPermission": "onlyAuthor",
    "commercialUsage": "personalNonProfit",
    "creditNotation": "required",
    "modification": "prohibited",
    **{flag: False for flag in _FLAGS},
}
_RANGE_MAPS = ("rangeMapHorizontalInner", "rangeMapHorizontalOuter", "rangeMapVerticalDown", "rangeMapVerticalUp")
DEFAULT_RANGE_MAP = {"inputMaxValue": 90.0, "outputScale": 1.0}


def expression_overrides(preset: str) -> dict:
    """A VRM 1.0 preset's overrides: an emotion blends the blink, a blink blends the gaze."""
    blink = "blend" if preset in EMOTIONS else "none"
    look = "blend" if preset in BLINKS else "none"
    return {"overrideBlink": blink, "overrideLookAt": look, "overrideMouth": "none"}


def _vector(value, what: str) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        v = np.full(0, np.nan)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise FaceAnimError(f"{what} must be a finite (3,) point in mesh coordinates")
    return v


def _rotation(value) -> np.ndarray:
    if value is None:
        return np.eye(3)
    try:
        r = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        r = np.full(0, np.nan)
    if r.shape != (3, 3) or not np.all(np.isfinite(r)) or np.abs(r @ r.T - np.eye(3)).max() > 1e-6 \
            or np.linalg.det(r) <= 0:
        raise FaceAnimError("rotation must be a (3, 3) proper rotation whose rows are the avatar's left, up and "
                            "forward directions in mesh coordinates (e.g. the face frame's rotation)")
    u, _, vt = np.linalg.svd(r)  # the nearest exact rotation (removes rounding)
    return u @ vt


def _meta(meta: Mapping | None, mesh_name: str) -> dict:
    out = {"name": mesh_name or "avatar", **DEFAULT_META}
    if meta is None:
        return out
    if not isinstance(meta, Mapping):
        raise FaceAnimError(f"VRM meta must be a mapping of meta fields, not {type(meta).__name__}")
    known = set(_ENUMS) | set(_FLAGS) | set(_TEXTS) | set(_LISTS) | {"licenseUrl"}
    for key, value in meta.items():
        if key not in known:
            raise FaceAnimError(f"unknown VRM meta field '{shown(key)}'; the fields are: {', '.join(sorted(known))}")
        if key == "licenseUrl":
            if value != LICENSE_URL:
                raise FaceAnimError(f"VRM 1.0 meta.licenseUrl must be {LICENSE_URL} (the VRM Public License); "
                                    "describe another licence in otherLicenseUrl")
        elif key in _ENUMS:
            if value not in _ENUMS[key]:
                raise FaceAnimError(f"VRM meta.{key} must be one of {', '.join(_ENUMS[key])}, not '{shown(value)}'")
        elif key in _FLAGS:
            if not isinstance(value, bool):
                raise FaceAnimError(f"VRM meta.{key} must be true or false, not '{shown(value)}'")
        elif key in _TEXTS:
            if not isinstance(value, str) or (key == "name" and not value):
                raise FaceAnimError(f"VRM meta.{key} must be a{' non-empty' if key == 'name' else ''} string")
        else:  # authors, references: lists of strings (authors' not empty), at least one
            if isinstance(value, str) or not isinstance(value, (list, tuple)) or not value \
                    or not all(isinstance(s, str) and (s or key == "references") for s in value):
                raise FaceAnimError(f"VRM meta.{key} must be a list of at least one "
                                    f"{'non-empty ' if key == 'authors' else ''}string")
            value = list(value)
        out[key] = value
    return out


def _look_at(look_at: Mapping | None) -> dict:
    out = {name: dict(DEFAULT_RANGE_MAP) for name in _RANGE_MAPS}
    if look_at is None:
        return out
    if not isinstance(look_at, Mapping):
        raise FaceAnimError(f"look_at must be a mapping of range maps, not {type(look_at).__name__}")
    for key, value in look_at.items():
        if key not in _RANGE_MAPS:
            raise FaceAnimError(f"unknown VRM lookAt field '{shown(key)}'; give range maps: {', '.join(_RANGE_MAPS)}")
        if not isinstance(value, Mapping) or set(value) - {"inputMaxValue", "outputScale"}:
            raise FaceAnimError(f"lookAt.{key} must be a mapping with inputMaxValue (degrees) and outputScale")
        rm = dict(out[key])
        for field, number in value.items():
            if isinstance(number, bool) or not isinstance(number, (int, float)) or not math.isfinite(number):
                raise FaceAnimError(f"lookAt.{key}.{field} must be a finite number")
            rm[field] = float(number)
        if not 0 <= rm["inputMaxValue"] <= 180:
            raise FaceAnimError(f"lookAt.{key}.inputMaxValue must lie in 0..180 degrees")
        out[key] = rm
    return out


def _expressions(expressions: Mapping, names: list[str], node: int, custom: bool = False) -> dict:
    if not isinstance(expressions, Mapping):
        raise FaceAnimError(f"expressions must map VRM {'custom names' if custom else 'presets'} to "
                            f"{{morph target: weight}}, not {type(expressions).__name__}")
    index = {name: k for k, name in enumerate(names)}
    preset = {}
    for name, binds in expressions.items():
        if custom:
            if not isinstance(name, str) or not name or not name.isprintable() or len(name) > 64 or name in PRESETS:
                raise FaceAnimError(f"custom VRM expression name '{shown(name)}' must be 1 to 64 printable "
                                    "characters and not a preset's name")
        elif name not in PRESETS:
            raise FaceAnimError(f"unknown VRM expression preset '{shown(name)}'; the presets are: {', '.join(PRESETS)}")
        if not isinstance(binds, Mapping):
            raise FaceAnimError(f"VRM expression '{name}' must map morph target names to weights")
        if not binds and name != "neutral":
            raise FaceAnimError(f"VRM expression '{name}' binds no morph target; leave it out instead")
        out = []
        for target, weight in binds.items():
            if target not in index:
                listed = ", ".join(shown(n) for n in names[:8]) + (" ..." if len(names) > 8 else "")
                raise FaceAnimError(f"VRM expression '{name}' binds morph target '{shown(target)}', which is not "
                                    f"one of the {len(names)} blendshapes ({listed or 'none'})")
            if isinstance(weight, bool) or not isinstance(weight, (int, float, np.floating, np.integer)) \
                    or not 0 <= float(weight) <= 1:
                raise FaceAnimError(f"VRM expression '{name}': the weight of '{shown(target)}' must be a number "
                                    f"in 0..1, not '{shown(weight)}'")
            out.append({"node": node, "index": index[target], "weight": float(weight)})
        expr = {"isBinary": False, **expression_overrides(name)}
        if out:  # the schema wants at least one bind when the list is there
            expr["morphTargetBinds"] = out
        preset[name] = expr
    return preset if custom else {p: preset[p] for p in PRESETS if p in preset}


def write_vrm(path: str | os.PathLike, mesh: Mesh, blendshapes: Mapping[str, np.ndarray],
              expressions: Mapping[str, Mapping[str, float]], *, head_pivot, rotation=None,
              scale: float = 1.0, eyes=None, meta: Mapping | None = None, look_at: Mapping | None = None,
              extras: dict | None = None, custom: Mapping[str, Mapping[str, float]] | None = None,
              version: int = 1, thumbnail: bytes | None = None) -> Path:
    """Write ``mesh`` with its blendshapes as a VRM 1.0 (or, ``version=0``, 0.x) avatar (see the
    module docstring).

    Parameters
    ----------
    blendshapes : name -> (V, 3) vertex displacement in mesh coordinates (the morph targets,
        written in this order, named in ``mesh.extras.targetNames``)
    expressions : VRM preset name (:data:`PRESETS`) -> {morph target name: weight in 0..1}; presets
        left out are not written; ``neutral`` may bind nothing
    head_pivot : (3,) where the head bone sits, in mesh coordinates (the top of the neck)
    rotation : (3, 3) proper rotation whose rows are the avatar's left, up and forward directions
        in mesh coordinates (``Face.frame.rotation``); default: the mesh is already +Y up, facing +Z
    scale : metres per mesh unit (0.001 for a mesh in millimetres)
    eyes : (3,) the point between the eyes in mesh coordinates: the lookAt origin
        (``offsetFromHeadBone``), which is left out without it
    meta : VRM meta fields over the restrictive defaults (:data:`DEFAULT_META`; ``name`` defaults
        to the mesh's name): ``name``, ``version``, ``authors`` (list), ``avatarPermission``,
        ``commercialUsage``, ``creditNotation``, ``allowRedistribution``, ``modification``, ...
    look_at : range maps over :data:`DEFAULT_RANGE_MAP`, e.g.
        ``{"rangeMapHorizontalOuter": {"inputMaxValue": 30, "outputScale": 1}}``
    extras : JSON-safe metadata stored as the scene's ``extras``
    custom : custom expression name -> {morph target name: weight in 0..1} (names not presets')
    version : 1 (VRM 1.0, ``VRMC_vrm``) or 0 (VRM 0.x, ``VRM``)
    thumbnail : PNG bytes of the avatar's thumbnail (meta), or None

    Raises :class:`FaceAnimError` (one line) on an unknown preset or target name, a weight outside
    0..1, bad meta values, a scale that does not make a head-sized avatar, or an output path that
    cannot be written (checked before any work; nothing is left behind).
    """
    path = check_output_path(path)
    if version not in (0, 1) or isinstance(version, bool):
        raise FaceAnimError(f"the VRM version must be 0 (VRM 0.x) or 1 (VRM 1.0), not '{shown(version)}'")
    if thumbnail is not None and (not isinstance(thumbnail, bytes) or not thumbnail.startswith(b"\x89PNG")):
        raise FaceAnimError("the VRM thumbnail must be the bytes of a PNG image")
    pivot = _vector(head_pivot, "head_pivot")
    rot = _rotation(rotation)
    eye_point = None if eyes is None else _vector(eyes, "eyes")
    if isinstance(scale, bool) or not isinstance(scale, (int, float, np.floating)) or not math.isfinite(scale) \
            or scale <= 0:
        raise FaceAnimError(f"scale (metres per mesh unit) must be a positive number, not '{shown(scale)}'")
    scale = float(scale)
    blendshapes = checked_blendshapes(mesh, blendshapes)
    names = list(blendshapes)
    mesh_node = 0  # build_gltf's node 0 holds the mesh
    preset = _expressions(expressions, names, mesh_node)
    customs = _expressions(custom or {}, names, mesh_node, custom=True)
    doc_meta = _meta(meta, mesh.name)
    ranges = _look_at(look_at)

    # metres, +Y up, facing +Z (0.x: -Z), relative to the head bone: transform the data, not the nodes
    axes = rot if version == 1 else HALF_TURN @ rot
    moved = scale * (mesh.vertices - pivot) @ axes.T
    size = float(np.linalg.norm(moved.max(0) - moved.min(0)))
    if not HEAD_SIZE_RANGE[0] <= size <= HEAD_SIZE_RANGE[1]:
        raise FaceAnimError(f"with scale {scale:g} the mesh measures {size:.3g} m across, not a head's size "
                            f"({HEAD_SIZE_RANGE[0]:g}-{HEAD_SIZE_RANGE[1]:g} m): give scale as metres per mesh "
                            "unit (0.001 for millimetres, 0.01 for centimetres)")
    vrm_mesh = dataclasses.replace(mesh, vertices=moved)
    shapes = {name: scale * np.asarray(d, dtype=np.float64) @ axes.T for name, d in blendshapes.items()}
    gltf = build_gltf(vrm_mesh, shapes, extras=extras)
    thumb = None if thumbnail is None else _append_image(gltf, thumbnail)

    import pygltflib as g

    bone_index = {}
    nodes = gltf.nodes
    root = len(nodes)
    nodes.append(g.Node(name="root", children=[]))
    position = {name: np.asarray(p) for name, _, p in SKELETON}
    for name, parent, p in SKELETON:
        bone_index[name] = len(nodes)
        local = np.asarray(p) - (position[parent] if parent else 0.0)
        local = local if version == 1 else local * HALF_TURN.diagonal()
        nodes.append(g.Node(name=name, translation=[round(float(x), 6) for x in local], children=[]))
        nodes[bone_index[parent] if parent else root].children.append(bone_index[name])
    nodes[bone_index["head"]].children.append(mesh_node)
    for node in nodes:
        if node.children == []:
            node.children = None  # glTF: children, when present, are not empty
    gltf.scenes[0].nodes = [root]
    eye_offset = None if eye_point is None else scale * rot @ (eye_point - pivot)  # VRM 1.0's axes
    if version == 0:
        ext = _vrm0_extension(gltf, doc_meta, bone_index, mesh_node, preset, customs, ranges, eye_offset, thumb)
        gltf.extensionsUsed = [*(gltf.extensionsUsed or []), VRM0_EXTENSION]
        gltf.extensions = {**(gltf.extensions or {}), VRM0_EXTENSION: ext}
        return save_glb(gltf, path)
    if thumb is not None:
        doc_meta = {**doc_meta, "thumbnailImage": thumb}

    vrm = {
        "specVersion": "1.0",
        "meta": doc_meta,
        "humanoid": {"humanBones": {name: {"node": bone_index[name]} for name, _, _ in SKELETON}},
        "firstPerson": {"meshAnnotations": [{"node": mesh_node, "type": "thirdPersonOnly"}]},
    }
    if any(p in preset for p in LOOKS) or eye_point is not None:
        look = {"type": "expression", **ranges}
        if eye_offset is not None:
            look = {"offsetFromHeadBone": [float(x) for x in eye_offset], **look}
        vrm["lookAt"] = look
    if preset or customs:
        vrm["expressions"] = {**({"preset": preset} if preset else {}), **({"custom": customs} if customs else {})}
    gltf.extensionsUsed = [*(gltf.extensionsUsed or []), VRM_EXTENSION]
    gltf.extensions = {**(gltf.extensions or {}), VRM_EXTENSION: vrm}
    return save_glb(gltf, path)


def _append_image(gltf, png: bytes) -> int:
    """Add a PNG to the document's binary blob as an image; its index."""
    import pygltflib as g

    blob = bytearray(gltf.binary_blob() or b"")
    while len(blob) % 4:
        blob.append(0)
    gltf.bufferViews.append(g.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(png)))
    blob.extend(png)
    while len(blob) % 4:
        blob.append(0)
    gltf.buffers[0].byteLength = len(blob)
    gltf.set_binary_blob(bytes(blob))
    gltf.images = [*(gltf.images or []), g.Image(bufferView=len(gltf.bufferViews) - 1, mimeType="image/png")]
    return len(gltf.images) - 1


def _texture(gltf, image: int) -> int:
    """A texture sampling ``image`` (VRM 0.x's meta names its thumbnail by texture); its index."""
    import pygltflib as g

    if not gltf.samplers:
        gltf.samplers = [g.Sampler(magFilter=g.LINEAR, minFilter=g.LINEAR)]
    gltf.textures = [*(gltf.textures or []), g.Texture(sampler=0, source=image)]
    return len(gltf.textures) - 1


def vrm0_meta(meta: Mapping) -> dict:
    """VRM 0.x's meta from VRM 1.0's fields (as :func:`write_vrm` checks them): who may use the
    avatar, violent, sexual and commercial use, and the licence: ``Redistribution_Prohibited``
    unless redistribution is allowed; ``CC0`` or ``CC_BY`` when the 1.0 fields are those licences'
    (everyone, commercial, modification and redistribution allowed; credit unnecessary or required);
    else ``Other``, the VRM Public License's URL (and ``otherLicenseUrl``, when given) saying more."""
    users = {"onlyAuthor": "OnlyAuthor", "onlySeparatelyLicensedPerson": "ExplicitlyLicensedPerson",
             "everyone": "Everyone"}[meta["avatarPermission"]]
    free = meta["avatarPermission"] == "everyone" and meta["commercialUsage"] == "corporation" \
        and meta["modification"] == "allowModificationRedistribution" and meta["allowRedistribution"]
    if not meta["allowRedistribution"]:
        licence = "Redistribution_Prohibited"
    elif free:
        licence = "CC0" if meta["creditNotation"] == "unnecessary" else "CC_BY"
    else:
        licence = "Other"
    allow = {True: "Allow", False: "Disallow"}
    return {
        "title": meta["name"], "version": meta.get("version", ""), "author": ", ".join(meta["authors"]),
        "contactInformation": meta.get("contactInformation", ""), "reference": ", ".join(meta.get("references", [])),
        "allowedUserName": users, "violentUssageName": allow[meta["allowExcessivelyViolentUsage"]],
        "sexualUssageName": allow[meta["allowExcessivelySexualUsage"]],
        "commercialUssageName": allow[meta["commercialUsage"] != "personalNonProfit"],
        "otherPermissionUrl": LICENSE_URL, "licenseName": licence,
        "otherLicenseUrl": meta.get("otherLicenseUrl", "") or (LICENSE_URL if licence == "Other" else ""),
    }


def _vrm0_extension(gltf, meta: dict, bone_index: dict, mesh_node: int, preset: dict, customs: dict,
                    ranges: dict, eye_offset, thumb) -> dict:
    """The ``VRM`` (0.x) extension from what the 1.0 writer prepared (see the module docstring)."""
    meta0 = vrm0_meta(meta)
    if thumb is not None:
        meta0["texture"] = _texture(gltf, thumb)
    groups = []
    mesh = gltf.nodes[mesh_node].mesh
    for name, expr in [*preset.items(), *customs.items()]:
        preset0 = VRM0_FROM_1.get(name) if name in preset else None
        groups.append({
            "name": preset0 or (name[0].upper() + name[1:]),
            "presetName": (preset0 or "unknown").lower(),
            "binds": [{"mesh": mesh, "index": b["index"], "weight": round(100.0 * b["weight"], 4)}
                      for b in expr.get("morphTargetBinds", [])],
            "materialValues": [],
            "isBinary": False,
        })
    curve = [0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 0.0]  # linear from 0 to 1 (Unity keyframes: time, value, tangents)
    look = {}
    for key0, key1 in (("lookAtHorizontalInner", "rangeMapHorizontalInner"),
                       ("lookAtHorizontalOuter", "rangeMapHorizontalOuter"),
                       ("lookAtVerticalDown", "rangeMapVerticalDown"), ("lookAtVerticalUp", "rangeMapVerticalUp")):
        look[key0] = {"curve": curve, "xRange": ranges[key1]["inputMaxValue"], "yRange": ranges[key1]["outputScale"]}
    # 0.x keeps the eye offset in Unity's axes: the glTF 0.x axes with z the other way round
    offset = np.zeros(3) if eye_offset is None else HALF_TURN @ eye_offset * np.array([1.0, 1.0, -1.0])
    materials = [{"name": m.name or f"material{k}", "shader": "VRM_USE_GLTFSHADER", "renderQueue": 2000,
                  "floatProperties": {}, "vectorProperties": {}, "textureProperties": {}, "keywordMap": {},
                  "tagMap": {}} for k, m in enumerate(gltf.materials or [])]
    return {
        "exporterVersion": "faceanim",
        "specVersion": "0.0",
        "meta": meta0,
        "humanoid": {"humanBones": [{"bone": name, "node": bone_index[name], "useDefaultValues": True}
                                    for name, _, _ in SKELETON],
                     "armStretch": 0.05, "legStretch": 0.05, "upperArmTwist": 0.5, "lowerArmTwist": 0.5,
                     "upperLegTwist": 0.5, "lowerLegTwist": 0.5, "feetSpacing": 0.0, "hasTranslationDoF": False},
        "firstPerson": {"firstPersonBone": bone_index["head"],
                        "firstPersonBoneOffset": dict(zip("xyz", (float(v) for v in offset))),
                        "meshAnnotations": [{"mesh": mesh, "firstPersonFlag": "ThirdPersonOnly"}],
                        "lookAtTypeName": "BlendShape", **look},
        "blendShapeMaster": {"blendShapeGroups": groups},
        "secondaryAnimation": {"boneGroups": [], "colliderGroups": []},
        "materialProperties": materials,
    }
