"""The director: scripts to FAP streams, with groups, repeated events and speech."""

import json
import shutil

import numpy as np
import pytest

from faceanim.cli import main
from faceanim.drivers.director import build_scene, load_script, scene_stream
from faceanim.errors import InputFileError


class _Rig:
    lip_gap = 0.0


def _script(tmp_path, data, name="s.json"):
    p = tmp_path / name
    p.write_text(json.dumps(data) if not isinstance(data, str) else data)
    return p


def test_groups_blinks_and_expressions(tmp_path):
    data = {"fps": 50, "seed": 3, "events": [
        {"expression": "surprise", "at": 0.0, "duration": 2.0, "intensity": 0.5},
        {"blink": {"every": 0.8, "jitter": 0.2}, "from": 0.5, "to": 3.0},
        {"group": "nod", "at": 1.0}],
        "groups": {"nod": [{"faps": {"head_pitch": 6000}, "at": 0.2, "duration": 0.5, "envelope": "peak"}]}}
    scene = build_scene(load_script(_script(tmp_path, data)), _Rig(), tmp_path)
    s = scene_stream(scene)
    blinks = [a for a in scene.actions if a.name == "blink"]
    starts = np.array([a.start for a in blinks])
    assert len(blinks) >= 3 and np.all(np.diff(starts) >= 0.6 - 1e-9) and np.all(np.diff(starts) <= 1.0 + 1e-9)
    pitch = s.column("head_pitch")
    assert pitch.argmax() / s.fps == pytest.approx(1.45, abs=0.03)  # the group's peak at 1.0 + 0.2 + 0.25
    assert s.column("raise_l_i_eyebrow").max() > 0  # surprise raises the brows
    again = scene_stream(build_scene(load_script(_script(tmp_path, data)), _Rig(), tmp_path))
    np.testing.assert_array_equal(again.values, s.values)  # the seed makes jitter repeatable


@pytest.mark.parametrize("data, message", [
    ("events: [\n  - {faps: {open_jaw: 1}\n", "not valid YAML"),
    ({"nothing": 1}, "list of 'events'"),
    ({"events": [{"dance": 1}]}, "an event has one of say, expression, faps, blink, group"),
    ({"events": [{"group": "wave"}]}, "no group 'wave'"),
    ({"events": [{"faps": {"open_mouth": 10}}]}, "unknown FAP"),
    ({"events": [{"expression": "joy", "envelope": "square"}]}, "envelope"),
    ({"events": [{"expression": "joy", "at": "soon"}]}, "'at' must be a number"),
])
def test_bad_scripts(tmp_path, data, message):
    path = _script(tmp_path, data, "s.yaml")
    with pytest.raises(InputFileError, match=message):
        build_scene(load_script(path), _Rig(), tmp_path)


@pytest.mark.skipif(shutil.which("espeak-ng") is None, reason="espeak-ng is not installed (scripts/setup.sh installs it)")
def test_direct_command_with_speech(tmp_path):
    from faceanim.io.fapfile import read_fap

    path = _script(tmp_path, {"events": [{"say": "hello there", "at": 0.5}, {"expression": "joy", "duration": 2}]})
    out = tmp_path / "scene.fap"
    assert main(["direct", str(path), "-o", str(out)]) == 0
    s = read_fap(out)
    jaw = s.column("open_jaw")
    assert jaw[: int(0.4 * s.fps)].max() < jaw.max()  # speech starts at 0.5 s
