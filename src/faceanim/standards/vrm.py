"""VRM's expression presets and licence fields, 1.0 (``VRMC_vrm``) and 0.x (the ``VRM`` extension).

VRM 1.0 names its presets in lowerCamel (:data:`PRESETS`: five emotions, five vowels, three
blinks, four gaze directions, neutral); VRM 0.x, which VSeeFace, VMagicMirror and many VTuber apps
read, names its blend shape groups in UpperCamel with other words for some (:data:`VRM0_PRESETS`;
``Joy`` for 1.0's ``happy``, ``Sorrow`` for ``sad``, ``Fun`` for ``relaxed``, ``A`` for ``aa``;
1.0's ``surprised`` has no 0.x preset and goes as a custom group). :data:`VRM0_FROM_1` maps one to
the other. The licence fields of VRM 1.0's meta and their values are :data:`LICENSE_FIELDS`; 0.x's
are :data:`VRM0_LICENSE_FIELDS`.
"""

from __future__ import annotations

EMOTIONS = ("happy", "angry", "sad", "relaxed", "surprised")
VISEMES = ("aa", "ih", "ou", "ee", "oh")
BLINKS = ("blink", "blinkLeft", "blinkRight")
LOOKS = ("lookUp", "lookDown", "lookLeft", "lookRight")
PRESETS = EMOTIONS + VISEMES + BLINKS + LOOKS + ("neutral",)

# VRM 0.x blendShapeMaster presetName values (lower case in the file) and their display names
VRM0_FROM_1 = {
    "neutral": "Neutral", "aa": "A", "ih": "I", "ou": "U", "ee": "E", "oh": "O", "blink": "Blink",
    "blinkLeft": "Blink_L", "blinkRight": "Blink_R", "happy": "Joy", "angry": "Angry", "sad": "Sorrow",
    "relaxed": "Fun", "lookUp": "LookUp", "lookDown": "LookDown", "lookLeft": "LookLeft", "lookRight": "LookRight",
}
VRM0_PRESETS = tuple(VRM0_FROM_1.values())

# VRM Public License 1.0 (meta of VRMC_vrm): field -> its allowed values, the most restrictive first
LICENSE_FIELDS = {
    "avatarPermission": ("onlyAuthor", "onlySeparatelyLicensedPerson", "everyone"),
    "commercialUsage": ("personalNonProfit", "personalProfit", "corporation"),
    "creditNotation": ("required", "unnecessary"),
    "modification": ("prohibited", "allowModification", "allowModificationRedistribution"),
}
LICENSE_FLAGS = ("allowExcessivelyViolentUsage", "allowExcessivelySexualUsage", "allowPoliticalOrReligiousUsage",
                 "allowAntisocialOrHateUsage", "allowRedistribution")

# VRM 0.x meta: field -> allowed values, the most restrictive first
VRM0_LICENSE_FIELDS = {
    "allowedUserName": ("OnlyAuthor", "ExplicitlyLicensedPerson", "Everyone"),
    "violentUssageName": ("Disallow", "Allow"),  # sic: the 0.x schema's spelling
    "sexualUssageName": ("Disallow", "Allow"),
    "commercialUssageName": ("Disallow", "Allow"),
    "licenseName": ("Redistribution_Prohibited", "CC0", "CC_BY", "CC_BY_NC", "CC_BY_SA", "CC_BY_NC_SA", "CC_BY_ND",
                    "CC_BY_NC_ND", "Other"),
}

# licence presets for faceanim rig --license: VRM 1.0 meta fields (0.x's follow from them)
CC0_URL = "https://creativecommons.org/publicdomain/zero/1.0/"
CC_BY_URL = "https://creativecommons.org/licenses/by/4.0/"
_OPEN = {"avatarPermission": "everyone", "commercialUsage": "corporation",
         "modification": "allowModificationRedistribution", "allowRedistribution": True}
LICENSE_PRESETS: dict[str, dict] = {
    "private": {},  # the most restrictive settings (the writer's defaults)
    "cc0": {**_OPEN, "creditNotation": "unnecessary", "otherLicenseUrl": CC0_URL},
    "cc-by": {**_OPEN, "creditNotation": "required", "otherLicenseUrl": CC_BY_URL},
}
