"""The standards' tables in one place (faceanim/standards), and what is built from them."""

import json
from importlib import resources

import numpy as np

from faceanim.standards.arkit import APPLE_NAMES, ARKIT_NAMES, EYE_NAMES, HEAD_NAMES, LIVE_LINK_ORDER, ict_name, name_key
from faceanim.standards.visemes import OCULUS_VISEMES, RPM_EXTRAS
from faceanim.standards.vrm import PRESETS, VRM0_FROM_1, VRM0_PRESETS


def test_arkit_names_and_orders():
    assert len(ARKIT_NAMES) == len(set(ARKIT_NAMES)) == 52
    assert APPLE_NAMES[0] == "eyeBlinkLeft" and APPLE_NAMES[-1] == "tongueOut"
    assert len(LIVE_LINK_ORDER) == 61 and LIVE_LINK_ORDER[52:] == HEAD_NAMES + EYE_NAMES
    moved = [(a, b) for a, b in zip(ARKIT_NAMES, LIVE_LINK_ORDER) if a != b]  # Unreal's enum: L/R of jaw, mouth
    assert sorted(moved) == sorted([("JawRight", "JawLeft"), ("JawLeft", "JawRight"), ("MouthRight", "MouthLeft"),
                                    ("MouthLeft", "MouthRight")])
    assert {name_key(n) for n in ("eyeBlink_L", "EyeBlinkLeft", "eye_blink_left", "eyeBlink.L")} == {"eyeblinkleft"}
    assert ict_name("BrowInnerUp") == ("browInnerUp_L", "browInnerUp_R") and ict_name("JawLeft") == ("jawLeft",)


def test_oculus_visemes_are_the_order_of_the_viseme_table():
    table = json.loads(resources.files("faceanim").joinpath("data", "visemes_arkit.json").read_text())["visemes"]
    assert tuple(v["oculus"] for v in table) == OCULUS_VISEMES
    assert [v["mpeg4"] for v in table] == list(range(15))


def test_vrm_presets_of_both_versions():
    assert len(PRESETS) == 18 and len(VRM0_PRESETS) == 17
    assert set(PRESETS) - set(VRM0_FROM_1) == {"surprised"}  # 0.x has no preset for it
    assert VRM0_FROM_1["happy"] == "Joy" and VRM0_FROM_1["sad"] == "Sorrow" and VRM0_FROM_1["aa"] == "A"


def test_ready_player_me_extras_are_sums_of_the_faces_own_arkit_shapes():
    from faceanim.autorig import auto_rig
    from faceanim.face.face import Face

    rig = auto_rig(Face.default(), ["arkit", "rpm"])
    assert rig.sets["rpm"] == ["mouthOpen", "mouthSmile", "eyesClosed", "eyesLookUp", "eyesLookDown"]
    for name, mix in RPM_EXTRAS.items():
        want = sum(w * rig.shapes[n] for n, w in mix.items())
        np.testing.assert_allclose(rig.shapes[name], want, atol=1e-12)
    eyes = rig.shapes["eyesClosed"]
    assert np.abs(eyes).max() > 0.1 * np.abs(rig.shapes["mouthOpen"]).max()  # the lids move
