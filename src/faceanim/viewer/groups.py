"""Morph targets of a glTF file grouped into the sets the viewer shows as slider panels.

A file faceanim wrote may say which set each target belongs to in its scene's extras (three.js:
``gltf.scene.userData``)::

    "morph_sets": {"arkit": [...], "visemes": [...], "au": [...], "emotions": [...], "fap": [...]}

Targets it names go to those sets (a set of another name is kept under its own name); every other
target is placed by its name: Apple's 52 ARKit names (``eyeBlinkLeft``, also Live Link Face's
``EyeBlinkLeft``, the ICT FaceKit's ``eyeBlink_L`` and either with an ``arkit_`` prefix),
``viseme_*`` and VRM's ``aa ih ou ee oh``, ``AU12``/``AU12_L``/``AU12_R``, the emotions (``joy``
``sadness`` ``surprise`` ``fear`` ``anger`` ``disgust``, ``facs_*`` of them, VRM's ``happy angry
sad relaxed surprised``), ``fap_*`` and the MPEG-4 FAP names (``open_jaw``), the rest under
``other``.
"""

from __future__ import annotations

import re
from functools import lru_cache

from faceanim.catalogue import EMOTIONS, RIG_SETS, SET_LABELS
from faceanim.standards.visemes import RPM_EXTRAS
from faceanim.standards.vrm import EMOTIONS as VRM_EMOTION_PRESETS
from faceanim.standards.vrm import VISEMES as VRM_VISEMES

SET_ORDER = (*RIG_SETS, "other")
SET_LABELS = {**SET_LABELS, "other": "Other"}
VRM_EMOTIONS = VRM_EMOTION_PRESETS + ("neutral",)
_AU = re.compile(r"AU\d+(_L|_R)?")
MAX_NAME = 200  # characters of a target name shown; longer names are cut


@lru_cache(maxsize=1)
def arkit_names() -> frozenset[str]:
    """Every spelling of an ARKit blendshape name, lower-cased: Apple's (``eyeblinkleft``) and the
    ICT FaceKit's (``eyeblink_l``)."""
    from faceanim.standards.arkit import ARKIT_NAMES, ict_name

    names = set()
    for column in ARKIT_NAMES:
        names.add(column.lower())
        names.update(n.lower() for n in ict_name(column))
    return frozenset(names)


@lru_cache(maxsize=1)
def fap_names() -> frozenset[str]:
    from faceanim.standards.mpeg4 import faps

    return frozenset(f.name for f in faps())


def set_of(name: str) -> str:
    """The set a morph target belongs to by its name alone."""
    low = name.lower()
    bare = low[6:] if low.startswith("arkit_") else low
    if bare in arkit_names():
        return "arkit"
    if low.startswith("viseme_") or low in VRM_VISEMES:
        return "visemes"
    if name in RPM_EXTRAS:
        return "rpm"
    if _AU.fullmatch(name):
        return "au"
    emotion = low[5:] if low.startswith("facs_") else low
    if emotion in EMOTIONS or low in VRM_EMOTIONS:
        return "emotions"
    if low.startswith("fap_") or name in fap_names():
        return "fap"
    return "other"


def target_names(doc: dict) -> list[str]:
    """The morph target names of every mesh in a glTF document, each once, in file order (three.js
    names them from ``mesh.extras.targetNames``; a target without a name gets its index)."""
    names: list[str] = []
    seen: set[str] = set()
    for mesh in doc.get("meshes") or []:
        if not isinstance(mesh, dict):
            continue
        prims = mesh.get("primitives") or []
        count = 0
        for prim in prims if isinstance(prims, list) else []:
            if isinstance(prim, dict) and isinstance(prim.get("targets"), list):
                count = max(count, len(prim["targets"]))
        extras = mesh.get("extras")
        given = extras.get("targetNames") if isinstance(extras, dict) else None
        given = given if isinstance(given, list) else []
        for k in range(count):
            name = given[k] if k < len(given) and isinstance(given[k], str) and given[k] else str(k)
            name = name[:MAX_NAME]
            if name not in seen:
                seen.add(name)
                names.append(name)
    return names


def scene_extras(doc: dict) -> dict:
    """The extras of the document's scene (the one ``scene`` names, else the first)."""
    scenes = doc.get("scenes")
    if not isinstance(scenes, list) or not scenes:
        return {}
    k = doc.get("scene", 0)
    scene = scenes[k] if isinstance(k, int) and 0 <= k < len(scenes) else scenes[0]
    extras = scene.get("extras") if isinstance(scene, dict) else None
    return extras if isinstance(extras, dict) else {}


def group_targets(names: list[str], morph_sets: object = None) -> list[dict]:
    """``names`` in slider groups: ``[{"set": "arkit", "label": "ARKit", "names": [...]}, ...]``,
    the known sets first in :data:`SET_ORDER`, empty sets left out. ``morph_sets`` (the scene
    extras' entry, if any) places the targets it names; the others are placed by name."""
    present = set(names)
    placed: dict[str, str] = {}
    order: list[str] = list(SET_ORDER)
    if isinstance(morph_sets, dict):
        for key, members in morph_sets.items():
            if not isinstance(key, str) or not isinstance(members, list):
                continue
            key = key[:MAX_NAME]
            if key not in order:
                order.insert(len(order) - 1, key)  # before "other"
            for m in members:
                if isinstance(m, str) and m in present and m not in placed:
                    placed[m] = key
    groups: dict[str, list[str]] = {}
    for n in names:
        groups.setdefault(placed.get(n) or set_of(n), []).append(n)
    return [{"set": s, "label": SET_LABELS.get(s, s), "names": groups[s]} for s in order if groups.get(s)]
