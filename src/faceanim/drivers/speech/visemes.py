"""Phones to the 14 MPEG-4 visemes, co-articulated (Lee et al. 1999, section 3.3).

Each phone becomes a viseme action covering the phone and spreading into its neighbours by its
group's overlap (vowels spread most, plosives least), with the group's intensity and weight: the
weighted blending of :mod:`faceanim.drivers.mpeg4` then mixes neighbouring mouth shapes, and a
plosive's heavy weight closes the lips even inside an expression that opens the mouth.
"""

from __future__ import annotations

import numpy as np

from faceanim.drivers.mpeg4 import Action, blend_actions, fap_set, viseme_table
from faceanim.drivers.speech.phonemes import Phone
from faceanim.errors import FaceAnimError
from faceanim.face.faps import FapStream
from faceanim.standards.mpeg4 import FapError, fap
from faceanim.limits import check_frames

# a p/b/m closes a face whose neutral lips are parted: the mid-lips each move half the gap (in
# MNS), the lip points beside them a little less so the closed lips stay round
LIP_CLOSURE = {"lower_t_midlip": 0.5, "raise_b_midlip": 0.5, "lower_t_lip_lm": 0.4, "lower_t_lip_rm": 0.4,
               "raise_b_lip_lm": 0.4, "raise_b_lip_rm": 0.4}


def _phone_map() -> dict[str, int]:
    out = {}
    for number, d in viseme_table()["visemes"].items():
        for p in d["phones"]:
            out[p] = int(number)
    return out


def phone_viseme(phone: str) -> int:
    """The MPEG-4 viseme number (0-14) of an ARPAbet phone (stress digits ignored)."""
    p = phone.upper().rstrip("012")
    table = _phone_map()
    if p not in table:
        raise FapError(f"no viseme for the phone '{phone}'")
    return table[p]


def viseme_actions(phones: list[Phone], lip_gap: float = 0.0, intensity: float = 1.0) -> list[Action]:
    """Co-articulated viseme actions for timed phones.

    ``lip_gap`` is the neutral face's gap between the inner lips in MNS units (from
    :class:`~faceanim.rig.mpeg4.FapRig`): visemes marked ``close_lips`` close it.
    """
    table = viseme_table()
    groups = table["groups"]
    actions = []
    for ph in phones:
        v = phone_viseme(ph.phone)
        d = table["visemes"][str(v)]
        if not d["faps"]:
            continue
        g = groups[d["group"]]
        length = max(ph.end - ph.start, 0.02)
        spread = g["overlap"] * length
        faps = fap_set(d["faps"])
        if d.get("close_lips") and lip_gap:
            for name, share in LIP_CLOSURE.items():
                n = fap(name).number
                faps[n] = faps.get(n, 0.0) + share * lip_gap
        # the action rises over [start - spread, start + spread] and falls over [end - spread,
        # end + spread]: neighbours with equal spreads hand over exactly at the phone boundary
        duration = length + 2 * spread
        ramp = min(2 * spread / duration, 0.5)
        actions.append(Action(f"viseme {v} {d['name']} ({ph.phone})", faps, ph.start - spread, duration,
                              intensity * g["intensity"], "smooth", ramp, ramp, g["weight"],
                              {"viseme": v, "phone": ph.phone, "phone_start": ph.start, "phone_end": ph.end}))
    return actions


def speech_stream(lip_gap: float, phones, fps: float = 25.0, extra: list[Action] | None = None,
                  name: str = "speech") -> FapStream:
    """A FAP stream for timed phones (co-articulated visemes), plus any other actions.
    ``lip_gap``: the face's neutral gap between the inner lips in MNS (:attr:`FapRig.lip_gap`)."""
    actions = viseme_actions(phones, lip_gap) + list(extra or [])
    if not phones and not actions:
        raise FaceAnimError("no speech was found to animate; check the audio and its transcript")
    end = max([p.end for p in phones] + [a.end for a in actions])
    return blend_actions(actions, check_frames(int(np.ceil(end * fps)) + 1, "frames of speech"), fps, name)
