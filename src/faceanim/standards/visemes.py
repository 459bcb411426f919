"""Mouth shapes by the names avatar tools use: Oculus (Meta) visemes and Ready Player Me's extras.

- :data:`OCULUS_VISEMES`: the 15 visemes of Oculus LipSync, as morph targets ``viseme_sil`` ...
  ``viseme_U``; their order is MPEG-4's visemes 0-14 (silence, p/b/m, f/v, th, t/d, k/g, ch/j/sh,
  s/z, n/l, r, a, e, i, o, u).
- :data:`RPM_EXTRAS`: the five extra shapes Ready Player Me avatars carry beside ARKit's 52 and the
  visemes (and which TalkingHead and other web players drive): both eyes closed, both looking up or
  down, the mouth open, a smile; each the ARKit shapes it stands for.
"""

from __future__ import annotations

OCULUS_VISEMES = ("sil", "PP", "FF", "TH", "DD", "kk", "CH", "SS", "nn", "RR", "aa", "E", "I", "O", "U")

RPM_EXTRAS: dict[str, dict[str, float]] = {
    "mouthOpen": {"jawOpen": 1.0},
    "mouthSmile": {"mouthSmileLeft": 1.0, "mouthSmileRight": 1.0},
    "eyesClosed": {"eyeBlinkLeft": 1.0, "eyeBlinkRight": 1.0},
    "eyesLookUp": {"eyeLookUpLeft": 1.0, "eyeLookUpRight": 1.0},
    "eyesLookDown": {"eyeLookDownLeft": 1.0, "eyeLookDownRight": 1.0},
}
