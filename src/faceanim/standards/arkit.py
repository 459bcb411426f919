"""Apple ARKit's 52 face blendshapes, as the apps and engines that carry them name and order them.

- :data:`ARKIT_NAMES`: Live Link Face's CSV column order and spelling (``EyeBlinkLeft`` ...
  ``TongueOut``; Left/Right are the subject's sides); :data:`APPLE_NAMES` the same in Apple's own
  spelling (``eyeBlinkLeft``), the morph target names ARKit rigs carry ("Perfect Sync").
- :data:`HEAD_NAMES`, :data:`EYE_NAMES`: the angles a Live Link Face take records after the curves.
- :data:`LIVE_LINK_ORDER`: Unreal's ``EARFaceBlendShape`` order, the order of a Live Link Face UDP
  packet's values (the jaw's and the mouth's left and right the other way round from the CSV's,
  then the head's and the eyes' angles).
- :data:`LOOK_ANGLES`: radians an eyeball turns at ``eyeLook*`` weight 1.
- :func:`ict_name`: the ICT FaceKit shape(s) an ARKit curve drives; :func:`name_key`: a name
  reduced for matching across spellings.
"""

from __future__ import annotations

import re

ARKIT_NAMES = (
    "EyeBlinkLeft", "EyeLookDownLeft", "EyeLookInLeft", "EyeLookOutLeft", "EyeLookUpLeft", "EyeSquintLeft",
    "EyeWideLeft", "EyeBlinkRight", "EyeLookDownRight", "EyeLookInRight", "EyeLookOutRight", "EyeLookUpRight",
    "EyeSquintRight", "EyeWideRight", "JawForward", "JawRight", "JawLeft", "JawOpen", "MouthClose",
    "MouthFunnel", "MouthPucker", "MouthRight", "MouthLeft", "MouthSmileLeft", "MouthSmileRight",
    "MouthFrownLeft", "MouthFrownRight", "MouthDimpleLeft", "MouthDimpleRight", "MouthStretchLeft",
    "MouthStretchRight", "MouthRollLower", "MouthRollUpper", "MouthShrugLower", "MouthShrugUpper",
    "MouthPressLeft", "MouthPressRight", "MouthLowerDownLeft", "MouthLowerDownRight", "MouthUpperUpLeft",
    "MouthUpperUpRight", "BrowDownLeft", "BrowDownRight", "BrowInnerUp", "BrowOuterUpLeft", "BrowOuterUpRight",
    "CheekPuff", "CheekSquintLeft", "CheekSquintRight", "NoseSneerLeft", "NoseSneerRight", "TongueOut",
)
HEAD_NAMES = ("HeadYaw", "HeadPitch", "HeadRoll")
EYE_NAMES = ("LeftEyeYaw", "LeftEyePitch", "LeftEyeRoll", "RightEyeYaw", "RightEyePitch", "RightEyeRoll")


def apple_name(live_link: str) -> str:
    """Apple's name of an ARKit blendshape from Live Link Face's column name (``EyeBlinkLeft`` ->
    ``eyeBlinkLeft``)."""
    return live_link[0].lower() + live_link[1:]


APPLE_NAMES = tuple(apple_name(n) for n in ARKIT_NAMES)


def _unreal_order() -> tuple[str, ...]:
    names = list(ARKIT_NAMES)
    for a, b in (("JawLeft", "JawRight"), ("MouthLeft", "MouthRight")):
        i, j = names.index(a), names.index(b)
        names[i], names[j] = names[j], names[i]
    return tuple(names) + HEAD_NAMES + EYE_NAMES


LIVE_LINK_ORDER = _unreal_order()

# radians an eyeball turns at look weight 1: the Live Link Face take in ../shared/data/arkit-curves,
# its eye yaw/pitch regressed on the look curves (r = 0.999 yaw, 0.996 pitch; both eyes agree to 0.01)
LOOK_ANGLES = {"Out": 0.58, "In": 0.63, "Up": 0.45, "Down": 0.62}


def name_key(name: str) -> str:
    """A blendshape name reduced for matching across spellings: ``eyeBlink_L``, ``EyeBlinkLeft``,
    ``eye_blink_left``, ``eyeBlink.L`` -> ``eyeblinkleft`` (a trailing L/R after a separator, or a
    capital L/R after a lower-case letter, is the side)."""
    s = re.sub(r"(?:[._\s-]|(?<=[a-z]))L$", "Left", name.strip())
    s = re.sub(r"(?:[._\s-]|(?<=[a-z]))R$", "Right", s)
    return re.sub(r"[^a-z0-9]", "", s.lower())


def ict_name(arkit: str) -> tuple[str, ...]:
    """The ICT FaceKit shape(s) an ARKit curve drives: first letter lower-cased, a side Left/Right
    -> _L/_R (JawLeft, MouthRight... are directions: jawLeft, mouthRight); BrowInnerUp and
    CheekPuff drive both halves; TongueOut has none (empty)."""
    if arkit == "TongueOut":
        return ()
    if arkit in ("BrowInnerUp", "CheekPuff"):
        base = arkit[0].lower() + arkit[1:]
        return (f"{base}_L", f"{base}_R")
    name = arkit[0].lower() + arkit[1:]
    if name in ("jawLeft", "jawRight", "mouthLeft", "mouthRight"):  # directions, not sides
        return (name,)
    for side, tag in (("Left", "_L"), ("Right", "_R")):
        if name.endswith(side):
            return (name[: -len(side)] + tag,)
    return (name,)
