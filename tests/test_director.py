"""The director: scripts to FAP streams, with groups, repeated events and speech."""

import json
import re
import shutil

import numpy as np
import pytest

from faceanim.cli import main
from faceanim.drivers.director import build_scene, load_script, scene_stream
from faceanim.errors import InputFileError


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
    scene = build_scene(load_script(_script(tmp_path, data)), 0.0, tmp_path)
    s = scene_stream(scene)
    blinks = [a for a in scene.actions if a.name == "blink"]
    starts = np.array([a.start for a in blinks])
    assert len(blinks) >= 3 and np.all(np.diff(starts) >= 0.6 - 1e-9) and np.all(np.diff(starts) <= 1.0 + 1e-9)
    pitch = s.column("head_pitch")
    assert pitch.argmax() / s.fps == pytest.approx(1.45, abs=0.03)  # the group's peak at 1.0 + 0.2 + 0.25
    assert s.column("raise_l_i_eyebrow").max() > 0  # surprise raises the brows
    again = scene_stream(build_scene(load_script(_script(tmp_path, data)), 0.0, tmp_path))
    np.testing.assert_array_equal(again.values, s.values)  # the seed makes jitter repeatable


@pytest.mark.parametrize("data, message", [
    ("events: [\n  - {faps: {open_jaw: 1}\n", "not valid YAML"),
    ({"nothing": 1}, "list of 'events'"),
    ({"events": [{"dance": 1}]}, "an event has one of say, expression, faps, blink, group"),
    ({"events": [{"group": "wave"}]}, "no group 'wave'"),
    ({"events": [{"faps": {"open_mouth": 10}}]}, "unknown FAP"),
    ({"events": [{"expression": "joy", "envelope": "square"}]}, "envelope"),
    ({"events": [{"expression": "joy", "at": "soon"}]}, "'at' must be a number"),
    ({"events": [{"say": "hi", "emotion": "glee"}]}, r"events\[0\]\.emotion: unknown emotion 'glee'"),
    ({"events": [{"say": "hi", "prosody": "yes"}]}, "prosody"),
])
def test_bad_scripts(tmp_path, data, message):
    path = _script(tmp_path, data, "s.yaml")
    with pytest.raises(InputFileError, match=message):
        build_scene(load_script(path), 0.0, tmp_path)


@pytest.mark.skipif(shutil.which("espeak-ng") is None, reason="espeak-ng is not installed (scripts/setup.sh installs it)")
def test_speech_carries_its_voices_prosody_and_emotion_phrase_by_phrase(tmp_path):
    """A say event moves the brows, lids and head from its own voice (the same actions as
    prosody_actions of its sound, placed at its 'at'), none with prosody: false; its emotion is
    one expression action per phrase of the voice, each at emotion_intensity times the phrase's
    factor (the mean factor 1 over the phrases, each within EMOTION_RANGE)."""
    from faceanim.drivers.speech.prosody import EMOTION_RANGE, analyse, phrases, prosody_actions
    from faceanim.io.audio import read_audio

    words = "I went home. Then, after a long while, I came back again!"
    data = {"fps": 50, "events": [{"say": words, "at": 1.0, "emotion": "joy", "emotion_intensity": 0.8}]}
    scene = build_scene(load_script(_script(tmp_path, data)), 0.0, tmp_path)
    [(at, wav)] = scene.speech
    prosody = analyse(*read_audio(wav))
    expected = prosody_actions(prosody, 1.0)
    kinds = ("brow raise", "blink", "look away", "nod", "lean", "head rise")
    voice = [a for a in scene.actions if a.name in kinds]
    assert [(a.name, round(a.start, 6)) for a in voice] == [(a.name, round(a.start, 6)) for a in expected]
    assert any(a.name == "nod" for a in voice) and any(a.name == "lean" for a in voice)
    assert any(a.name == "head rise" and a.additive for a in voice)
    joy = [a for a in scene.actions if a.name == "joy"]
    assert len(joy) == len(phrases(prosody)) >= 2
    levels = np.array([a.intensity for a in joy])
    assert np.mean(levels / 0.8) == pytest.approx(1.0, abs=0.05)
    assert np.all(levels >= 0.8 * EMOTION_RANGE[0] - 1e-9) and np.all(levels <= 0.8 * EMOTION_RANGE[1] + 1e-9)
    assert joy[0].start >= 1.0 and all(b.start < a.end for a, b in zip(joy, joy[1:]))  # no gap between phrases
    still = build_scene(load_script(_script(tmp_path, {"events": [{"say": words, "prosody": False}]}, "b.json")),
                        0.0, tmp_path)
    assert not [a for a in still.actions if a.name in kinds]


@pytest.mark.skipif(shutil.which("espeak-ng") is None, reason="espeak-ng is not installed (scripts/setup.sh installs it)")
def test_direct_command_with_speech(tmp_path):
    from faceanim.io.fapfile import read_fap

    path = _script(tmp_path, {"events": [{"say": "hello there", "at": 0.5}, {"expression": "joy", "duration": 2}]})
    out = tmp_path / "scene.fap"
    assert main(["direct", str(path), "-o", str(out)]) == 0
    s = read_fap(out)
    jaw = s.column("open_jaw")
    assert jaw[: int(0.4 * s.fps)].max() < jaw.max()  # speech starts at 0.5 s


# ----------------------------------------------------------------------------------- schema


def _error(path) -> str:
    with pytest.raises(InputFileError) as err:
        load_script(path)
    text = str(err.value)
    assert "\n" not in text
    return text


MISSPELT = """fps: 25
events:
  - expression: joy
    at: 0.0
    duration: 5.5
  - blink: {every: 2.5, jitter: 0.6}
    from: 0.8
    to: 6.0
groups:
  nod:
    - faps: {head_pitch: 7000}
      at: 0.0
      duration: 0.6
"""


@pytest.mark.parametrize("good, bad, line, where, message", [
    ("    duration: 5.5", "    duraton: 5.5", 5, "events[0].duraton",
     ("unknown key 'duraton' (did you mean 'duration'?); an expression event takes: expression, at, duration, "
     "intensity, envelope, attack, release, weight")),
    ("  - blink: {every: 2.5, jitter: 0.6}", "  - blink: {evry: 2.5, jitter: 0.6}", 6, "events[1].blink.evry",
     "unknown key 'evry' (did you mean 'every'?); blink takes: every, jitter"),
    ("      duration: 0.6", "      duration: 0.6\n      intesity: 0.5", 14, "groups.nod[0].intesity",
     ("unknown key 'intesity' (did you mean 'intensity'?); a faps event takes: faps, at, duration, intensity, "
     "envelope, attack, release, weight")),
    ("    to: 6.0", "    until: 6.0", 8, "events[1].until", "unknown key 'until'; a blink event takes: blink, from, to"),
    ("fps: 25", "fps: 25\nsed: 3", 2, "sed",
     "unknown key 'sed' (did you mean 'seed'?); a scene script takes: fps, seed, face, events, groups"),
    ("  - expression: joy", "  - expresion: joy", 3, "events[0].expresion",
     "unknown key 'expresion' (did you mean 'expression'?); an event has one of say, expression, faps, blink, group"),
    ("    at: 0.0", "    at: soon", 4, "events[0].at", "'at' must be a number, got a string"),
    ("    at: 0.0", "    at: -1", 4, "events[0].at", "'at' must be at least 0, got -1"),
    ("    at: 0.0", "    at: 1e9", 4, "events[0].at", "'at' must be at most 3600, got 1e+09"),
    ("    duration: 5.5", "    duration: 0", 5, "events[0].duration", "'duration' must be more than 0, got 0"),
    ("    duration: 5.5", "    duration: .nan", 5, "events[0].duration", "'duration' must be a finite number"),
    ("    duration: 5.5", "    duration: true", 5, "events[0].duration", "'duration' must be a number, got true/false"),
    ("    duration: 5.5", "    duration: 5.5\n    intensity: 11", 6, "events[0].intensity",
     "'intensity' must be at most 10, got 11"),
    ("  - blink: {every: 2.5, jitter: 0.6}", "  - blink: {every: 0.3, jitter: 0.1}", 6, "events[1].blink.every",
     "'every' must be at least 0.5, got 0.3"),
    ("    to: 6.0", "    to: 1.0e9", 8, "events[1].to", "'to' must be at most 3600, got 1e+09"),
    ("    to: 6.0", "    to: 0.5", 8, "events[1].to", "'to' must be after 'from' (0.8 s), got 0.5"),
    ("fps: 25", "fps: 1000", 1, "fps", "'fps' must be at most 240, got 1000"),
    ("fps: 25", "fps: 25\nseed: 1.5", 2, "seed", "'seed' must be a whole number, got 1.5"),
    ("  - expression: joy", "  - expression: boredom", 3, "events[0].expression",
     "unknown expression 'boredom'; choose one of: joy, sadness, anger, fear, disgust, surprise"),
    ("    - faps: {head_pitch: 7000}", "    - faps: {open_mouth: 7000}", 11, "groups.nod[0].faps.open_mouth",
     ("unknown FAP 'open_mouth' (or one with fields, FAP 1 or 2); use FAP names like open_jaw, head_yaw or "
     "numbers 3 to 68")),
    ("  - expression: joy", "  - expression: joy\n    say: hello", 4, "events[0].say",
     ("an event has one of say, expression, faps, blink, group; this one has both 'expression' and 'say': "
     "split it in two")),
])
def test_schema_errors_name_the_key_and_the_line(tmp_path, good, bad, line, where, message):
    assert good in MISSPELT
    path = _script(tmp_path, MISSPELT.replace(good, bad, 1), "scene.yaml")
    assert _error(path) == f"{path}, line {line}: {where}: {message}"


def test_the_unmodified_script_is_valid(tmp_path):
    script = load_script(_script(tmp_path, MISSPELT, "scene.yaml"))
    assert script.fps == 25 and len(script.events) == 2 and list(script.groups) == ["nod"]
    assert script.events[1].start == 0.8 and script.events[1].to == 6.0 and script.events[1].blink.every == 2.5


def test_json_scripts_name_the_line_too(tmp_path):
    text = '{\n\t"fps": 25,\n\t"events": [\n\t\t{"expression": "joy",\n\t\t "duration": 2},\n' \
           '\t\t{"faps": {"head_yaw": 8000}, "at": 1e-1,\n\t\t "intesity": 1}\n\t]\n}\n'
    path = _script(tmp_path, text, "scene.json")  # tab-indented JSON: YAML cannot read it, JSON can
    assert _error(path) == (f"{path}, line 7: events[1].intesity: unknown key 'intesity' (did you mean "
                            "'intensity'?); a faps event takes: faps, at, duration, intensity, envelope, attack, "
                            "release, weight")
    fixed = load_script(_script(tmp_path, text.replace("intesity", "intensity"), "scene.json"))
    assert fixed.events[1].at == pytest.approx(0.1)  # 1e-1 is a number (YAML 1.1 would read a string)
    path = _script(tmp_path, '{"events": [{"expression": "joy",\n "at": 1, "at": 2}]}', "dup.json")
    assert _error(path) == f"{path}, line 2: duplicate key 'at'; give each key once"
    path = _script(tmp_path, '{"events": [{"expression": "joy"}', "broken.json")
    assert _error(path).startswith(f"{path}, line 1: not valid JSON (Expecting")


def test_yaml_oddities_are_refused_cleanly(tmp_path):
    cases = {
        "events:\n  - &a {expression: joy}\n  - *a\n": "line 2: YAML anchors and aliases (&name, *name) are not "
                                                       "supported in scene scripts; write the events out, or use groups",
        "events:\n  - expression: joy\n    at: 1\n    at: 2\n": "line 4: duplicate key 'at'; give each key once",
        "events:\n  - say: no\n": "line 2: events[0].say: 'say' must be a string (quote it), got true/false",
        "": "a script is a mapping with a list of 'events' (e.g. events: [{expression: joy}]), got nothing",
        "root:x:0:0:root:/root:/bin/bash\n": "line 1: a script is a mapping with a list of 'events' (e.g. events: "
                                              "[{expression: joy}]), got a string",
        "events: [" * 2000: "not valid YAML or JSON",
        "fps: 25\n": "a script is a mapping with a list of 'events' (e.g. events: [{expression: joy}])",
        "events: []\n": "line 1: events: 'events' must not be empty",
        "events: [3]\n": "line 1: events[0]: an event has one of say, expression, faps, blink, group, as a mapping "
                         "(e.g. {expression: joy, at: 0}); got 3",
        "events: [{blink: [1]}]\n": "events[0].blink: 'blink' must be a mapping, got a list",
    }
    for k, (text, message) in enumerate(cases.items()):
        path = _script(tmp_path, text, f"s{k}.yaml")
        error = _error(path)
        assert error.startswith(str(path)) and message in error, error
        assert "root:x" not in error
    big = tmp_path / "big.yaml"
    big.write_bytes(b"#" * 1_000_001)
    assert _error(big) == f"script '{big}' has 1000001 bytes; a scene script has at most 1000000: split the scene"
    (tmp_path / "bin.yaml").write_bytes(b"\xff\xfe\x00events")
    assert _error(tmp_path / "bin.yaml") == f"script '{tmp_path / 'bin.yaml'}' is not UTF-8 text; save it as UTF-8"
    assert _error(tmp_path / "none.yaml") == f"script '{tmp_path / 'none.yaml'}' does not exist; check the path"


# ----------------------------------------------------------------------------------- ranges before allocating


def _refused_fast(tmp_path, data, message, name="s.json"):
    import time
    import tracemalloc

    path = _script(tmp_path, data, name)
    tracemalloc.start()
    start = time.perf_counter()
    try:
        with pytest.raises(InputFileError) as err:
            build_scene(load_script(path), 0.0, tmp_path)
        elapsed = time.perf_counter() - start
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert message in str(err.value), str(err.value)
    assert elapsed < 1.0 and peak < 20_000_000, (elapsed, peak)  # milliseconds and a few MB, not gigabytes
    return str(err.value)


def test_huge_scenes_are_refused_before_anything_is_built(tmp_path):
    from faceanim.limits import MAX_ACTIONS, MAX_NESTING

    # a blink every 0.3 s for 1e9 s
    _refused_fast(tmp_path, {"events": [{"blink": {"every": 0.3}, "from": 0, "to": 1e9}]},
                  "events[0].blink.every: 'every' must be at least 0.5, got 0.3")
    _refused_fast(tmp_path, {"events": [{"blink": {"every": 0.5}, "from": 0, "to": 1e9}]},
                  "events[0].to: 'to' must be at most 3600, got 1e+09")
    # groups 10 wide and 8 deep: 10^8 events on one timeline
    groups = {f"g{d}": [{"group": f"g{d + 1}", "at": 0.1 * k} for k in range(10)] for d in range(MAX_NESTING - 1)}
    groups[f"g{MAX_NESTING - 1}"] = [{"expression": "joy", "at": 0.1 * k, "duration": 0.5} for k in range(10)]
    message = _refused_fast(tmp_path, {"events": [{"group": "g0"}], "groups": groups},
                            f"the scene expands to more than {MAX_ACTIONS} events")
    assert "groups.g" in message  # where the count ran over
    # nine deep
    deep = {f"g{d}": [{"group": f"g{d + 1}"}] for d in range(MAX_NESTING + 1)}
    deep[f"g{MAX_NESTING + 1}"] = [{"expression": "joy"}]
    _refused_fast(tmp_path, {"events": [{"group": "g0"}], "groups": deep},
                  f"groups are nested more than {MAX_NESTING} deep (g0 -> g1")
    # a group that places itself
    _refused_fast(tmp_path, {"events": [{"group": "a"}], "groups": {"a": [{"group": "b"}], "b": [{"group": "a"}]}},
                  "groups.b[0].group: group 'a' places itself (a -> b -> a); remove the loop")
    # blinks repeated by a group: 15 x 7,201 blinks
    _refused_fast(tmp_path, {"events": [{"group": "b", "at": 0}],
                             "groups": {"b": [{"blink": {"every": 0.5}, "from": 0, "to": 3600}] * 15}},
                  f"the scene expands to more than {MAX_ACTIONS} actions")
    # times inside groups add up past an hour
    _refused_fast(tmp_path, {"events": [{"group": "late", "at": 3000}],
                             "groups": {"late": [{"expression": "joy", "at": 500, "duration": 200}]}},
                  "events[0]: the scene runs past 3600 s")
    # an hour at 240 fps is more frames than a stream may have
    _refused_fast(tmp_path, {"fps": 240, "events": [{"expression": "joy", "duration": 3600}]},
                  "fps: the scene needs 864093 frames at 240 fps; faceanim makes at most 200000")


def test_the_largest_allowed_blink_track_is_built(tmp_path):
    data = {"fps": 10, "seed": 1, "events": [{"blink": {"every": 0.5}, "from": 0, "to": 3600}]}
    scene = build_scene(load_script(_script(tmp_path, data)), 0.0, tmp_path)
    assert len(scene.actions) == 7200 and scene.actions[-1].start == pytest.approx(3599.5)
    assert scene.n_frames == 36000  # ceil((3599.5 + 0.18 + 0.2) * 10) + 1


# ----------------------------------------------------------------------------------- determinism, sound track


def test_an_event_with_two_kinds_never_picks_one(tmp_path):
    """It used to be resolved by set.pop(): 31 or 44 frames depending on the run."""
    data = {"events": [{"say": "hello", "expression": "joy", "duration": 1.0}]}
    with pytest.raises(InputFileError, match="this one has both 'say' and 'expression'"):
        build_scene(data, 0.0, tmp_path)


SCENE = {"fps": 30, "seed": 11, "events": [
    {"expression": "surprise", "at": 0.2, "duration": 2.0, "intensity": 0.7, "envelope": "linear"},
    {"faps": {"head_yaw": 6000, "3": 200}, "at": 0.5, "duration": 1.0, "envelope": "peak"},
    {"blink": {"every": 0.7, "jitter": 0.3}, "from": 0.1, "to": 3.0},
    {"group": "nod", "at": 1.0}, {"group": "nod", "at": 2.0}],
    "groups": {"nod": [{"faps": {"head_pitch": 5000}, "duration": 0.5, "envelope": "peak"},
                       {"blink": {"jitter": 0.2}, "from": 0.1, "to": 0.4}]}}

_DIGEST = """
import hashlib, sys
from pathlib import Path
from types import SimpleNamespace
from faceanim.drivers.director import build_scene, load_script, scene_stream
s = scene_stream(build_scene(load_script(sys.argv[1]), 0.0, Path(sys.argv[2])))
print(s.n_frames, hashlib.sha256(s.values.tobytes() + s.mask.tobytes()).hexdigest())
"""


def test_the_same_scene_gives_the_same_stream_in_any_process(tmp_path):
    import hashlib
    import os
    import subprocess
    import sys

    path = _script(tmp_path, SCENE)
    a = scene_stream(build_scene(load_script(path), 0.0, tmp_path))
    b = scene_stream(build_scene(SCENE, 0.0, tmp_path))  # a dict is validated the same way
    np.testing.assert_array_equal(a.values, b.values)
    np.testing.assert_array_equal(a.mask, b.mask)
    assert a.n_frames == 101 and a.column("head_pitch").max() > 0 and a.column("close_t_l_eyelid").max() > 0
    want = f"{a.n_frames} {hashlib.sha256(a.values.tobytes() + a.mask.tobytes()).hexdigest()}"
    for seed in ("1", "2"):  # string hashing differs between these processes; the stream must not
        env = dict(os.environ, PYTHONHASHSEED=seed)
        out = subprocess.run([sys.executable, "-c", _DIGEST, str(path), str(tmp_path)], env=env, check=True,
                             capture_output=True, text=True).stdout.split()
        assert " ".join(out) == want


def test_drivers_never_iterate_over_sets():
    import ast
    from pathlib import Path

    from faceanim import drivers

    for file in sorted(Path(drivers.__file__).parent.rglob("*.py")):
        for node in ast.walk(ast.parse(file.read_text())):
            if isinstance(node, (ast.For, ast.comprehension)):
                it = node.iter
                assert not isinstance(it, (ast.Set, ast.SetComp)), f"{file}:{node.lineno}"
                assert not (isinstance(it, ast.Call) and getattr(it.func, "id", "") in ("set", "frozenset")), \
                    f"{file}:{node.lineno}"
            if isinstance(node, ast.Attribute) and node.attr == "pop" and isinstance(node.value, (ast.Set, ast.BinOp)):
                raise AssertionError(f"{file}:{node.lineno}: popping from a set")


def test_speech_track_is_exactly_as_long_as_the_stream(tmp_path):
    import soundfile as sf

    from faceanim.drivers.director import Scene, mix_speech, speech_track
    from faceanim.drivers.mpeg4 import Action

    rate = 22050
    t = np.arange(rate * 3) / rate
    long_wav = tmp_path / "long.wav"  # 3 s of speech that runs past the scene's end
    sf.write(long_wav, 0.25 * np.sin(2 * np.pi * 300 * t), rate, subtype="PCM_16")
    short_wav = tmp_path / "short.wav"
    sf.write(short_wav, 0.25 * np.sin(2 * np.pi * 300 * t[: rate // 2]), rate, subtype="PCM_24")
    for fps in (25.0, 30.0, 24.0, 29.97):
        actions = [Action("x", {3: 100.0}, 0.0, 1.9)]
        scene = Scene(actions, [(0.3, short_wav), (1.0, long_wav)], 1.9 + 0.2, fps)
        stream = scene_stream(scene)
        track = speech_track(scene)
        assert len(track) == round(stream.n_frames / stream.fps * 16000) == round(stream.duration * 16000)
        out = mix_speech(scene, tmp_path / "track.wav")
        info = sf.info(out)
        assert info.samplerate == 16000 and info.frames == round(stream.duration * 16000)
        assert np.abs(track[round(1.0 * 16000) + 100:]).max() > 0.2  # the long one is cut, not dropped
        assert np.abs(track[: round(0.3 * 16000) - 10]).max() == 0  # nothing before the first speech
    assert mix_speech(Scene(actions, [], 2.1, 25.0), tmp_path / "none.wav") is None


@pytest.mark.skipif(shutil.which("espeak-ng") is None, reason="espeak-ng is not installed (scripts/setup.sh installs it)")
def test_example_scene_and_its_sound_track(tmp_path):
    from conftest import ROOT

    from faceanim.drivers.director import mix_speech
    from faceanim.io.audio import read_audio

    script = load_script(ROOT / "examples" / "scene.yaml")
    assert script.voices == {"en-us": "en-us"} and script.face is None
    scene = build_scene(script, 0.0, tmp_path)
    stream = scene_stream(scene)
    kinds = {a.name for a in scene.actions}
    assert {"joy", "head_yaw", "head_pitch", "blink"} <= kinds and any(n.startswith("viseme") for n in kinds)
    assert stream.n_frames == scene.n_frames and stream.column("open_jaw").max() > 50
    x, rate = read_audio(mix_speech(scene, tmp_path / "track.wav"))
    assert rate == 16000 and len(x) == round(stream.duration * 16000)
    (tmp_path / "again").mkdir()
    again = scene_stream(build_scene(load_script(ROOT / "examples" / "scene.yaml"), 0.0, tmp_path / "again"))
    np.testing.assert_array_equal(again.values, stream.values)


@pytest.mark.skipif(shutil.which("espeak-ng") is None, reason="espeak-ng is not installed (scripts/setup.sh installs it)")
def test_direct_refuses_an_unknown_voice_with_its_line(tmp_path, capsys):
    path = _script(tmp_path, "events:\n  - say: hello\n    voice: ../../../../etc/passwd\n", "v.yaml")
    assert main(["direct", str(path), "-o", str(tmp_path / "v.fap")]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.endswith(f"{path}, line 3: events[0].voice: unknown espeak-ng voice '../../../../etc/passwd'; run "
                        "`espeak-ng --voices` to list them (e.g. en-us)")
    assert "root:" not in err and not (tmp_path / "v.fap").exists()


# ----------------------------------------------------------------------------------- fuzz

hypothesis = pytest.importorskip("hypothesis")
st = hypothesis.strategies

_KEYS = ["at", "duration", "intensity", "envelope", "attack", "release", "weight", "voice", "from", "to",
         "every", "jitter", "duraton", "intesity", "evry", "until", "group", "say", "expression", "faps", "blink"]
_scalars = (st.none() | st.booleans() | st.integers(-10**12, 10**12) | st.floats()
            | st.sampled_from([0, 0.5, 1, 2.5, 3600, 1e9, -1, "joy", "surprise", "peak", "nod", "head_yaw", "en-us",
                               "", "soon", "1e3"])
            | st.text(max_size=12))
_values = st.recursive(_scalars, lambda inner: st.lists(inner, max_size=3)
                       | st.dictionaries(st.sampled_from(_KEYS) | st.text(max_size=6), inner, max_size=3),
                       max_leaves=8)
_numbers = st.one_of(*[st.floats(0, 5)] * 6, st.integers(0, 4), st.floats(-5, 4000), _scalars)
_shaped = {"at": _numbers, "duration": _numbers, "intensity": _numbers, "envelope": st.sampled_from(
    ["linear", "smooth", "peak", "square"]), "attack": st.floats(0, 0.5) | _numbers, "release": st.floats(0, 0.5),
    "weight": _numbers}
_names = st.sampled_from(["a", "b", "c"])
_event_kinds = [
    st.fixed_dictionaries({"expression": st.sampled_from(["joy", "anger", "surprise"])}, optional=_shaped),
    st.fixed_dictionaries({"faps": st.dictionaries(st.sampled_from(["head_yaw", "open_jaw", "3", 19, 48]), _numbers,
                                                   min_size=1, max_size=3)}, optional=_shaped),
    st.fixed_dictionaries({"blink": st.none() | st.fixed_dictionaries(
        {}, optional={"every": st.floats(0.5, 5) | _numbers, "jitter": st.floats(0, 0.5)})},
        optional={"from": _numbers, "to": _numbers}),
    st.fixed_dictionaries({"group": _names}, optional={"at": _numbers}),
]
_odd_events = [
    st.fixed_dictionaries({"expression": st.sampled_from(["joy", "boredom"]) | _scalars},
                          optional=_shaped | {"duraton": _numbers, "intesity": _numbers}),
    st.fixed_dictionaries({"faps": st.dictionaries(st.sampled_from(["open_mouth", 1, 69, 2.5]) | _scalars, _numbers,
                                                   max_size=3)}, optional=_shaped),
    st.fixed_dictionaries({"blink": _values}, optional={"from": _numbers, "to": _numbers, "until": _numbers,
                                                        "evry": _numbers}),
    st.fixed_dictionaries({"group": _scalars}, optional={"at": _numbers}),
    st.fixed_dictionaries({"say": st.sampled_from(["", "...", "hello"]) | _scalars},
                          optional={"voice": st.sampled_from(["en-us", "../../etc/passwd", "xx"]) | _scalars,
                                    "expression": _scalars}),
    st.dictionaries(st.sampled_from(_KEYS) | st.text(max_size=6), _values, max_size=4),
    _values,
]
_events = st.one_of(*(_event_kinds * 3), *_odd_events)
_script_dicts = st.fixed_dictionaries(
    {"events": st.lists(_events, min_size=1, max_size=4)},
    optional={"fps": st.floats(1, 60), "seed": st.integers(0, 2**32 - 1),
              "groups": st.dictionaries(_names, st.lists(_events, max_size=4), max_size=3)})
_scripts = st.one_of(_script_dicts, _script_dicts, _script_dicts,
                     st.fixed_dictionaries({"events": st.lists(_events, max_size=4)},
                                           optional={"fps": _numbers, "seed": _numbers, "face": _scalars,
                                                     "groups": st.dictionaries(_names | _scalars, _values, max_size=3),
                                                     "sed": _scalars}),
                     _values)


def _check_reader(tmp_path, path) -> None:
    from faceanim.drivers.director import SayEvent, Script, _all_events
    from faceanim.errors import FaceAnimError

    try:
        script = load_script(path)
    except FaceAnimError as exc:
        assert "\n" not in str(exc) and str(exc)
        hypothesis.event("refused: " + re.sub(r"^.*?: ", "", str(exc))[:50])
        return
    assert isinstance(script, Script)
    hypothesis.event("valid")
    has_say = any(isinstance(ev, SayEvent) for _, ev in _all_events(script.events, script.groups))
    if has_say or script.planned_actions > 300 or (script.planned_end + 1) * script.fps > 20_000:
        return  # valid; too slow to build in a fuzz loop (speech is synthesized)
    try:
        scene = build_scene(script, 0.0, tmp_path)
    except FaceAnimError as exc:  # e.g. a scene whose events place nothing
        assert "\n" not in str(exc)
        return
    stream = scene_stream(scene)
    assert stream.n_frames == scene.n_frames and np.all(np.isfinite(stream.values))
    hypothesis.event("built and played")


@hypothesis.settings(max_examples=150, deadline=None,
                     suppress_health_check=[hypothesis.HealthCheck.function_scoped_fixture,
                                            hypothesis.HealthCheck.too_slow])
@hypothesis.given(data=_scripts, as_json=st.booleans())
def test_fuzz_script_reader_gives_a_scene_or_a_clean_error(tmp_path, data, as_json):
    import yaml

    if as_json:
        try:
            text = json.dumps(data)
        except (TypeError, ValueError):  # keys JSON cannot hold (None, tuples)
            return
        path = tmp_path / "fuzz.json"
    else:
        text = yaml.safe_dump(data, allow_unicode=True)
        path = tmp_path / "fuzz.yaml"
    path.write_text(text, encoding="utf-8")
    _check_reader(tmp_path, path)


@hypothesis.settings(max_examples=150, deadline=None,
                     suppress_health_check=[hypothesis.HealthCheck.function_scoped_fixture])
@hypothesis.given(text=st.text(alphabet=st.sampled_from(list("events:[]{}-,&*!|>'\"#%@` \n\t0123456789.eajoy"))
                               | st.characters(), max_size=200),
                  name=st.sampled_from(["fuzz.yaml", "fuzz.json", "fuzz.txt"]))
def test_fuzz_script_text_gives_a_scene_or_a_clean_error(tmp_path, text, name):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    _check_reader(tmp_path, path)


@pytest.mark.skipif(shutil.which("espeak-ng") is None, reason="espeak-ng is not installed (scripts/setup.sh installs it)")
def test_direct_mp4_has_no_sound_past_the_video(tmp_path):
    """The sound track used to run one second past the last frame."""
    import subprocess

    import imageio_ffmpeg

    path = _script(tmp_path, "fps: 25\nevents:\n  - say: hello there\n    at: 0.3\n  - expression: joy\n"
                             "    duration: 1.0\n", "sp.yaml")
    out = tmp_path / "sp.mp4"
    assert main(["direct", str(path), "--size", "64", "-o", str(out)]) == 0

    def decoded_seconds(stream: str) -> float:
        log = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-i", str(out), "-map", stream, "-f", "null", "-"],
                             capture_output=True, text=True, check=True).stderr
        h, m, s = re.findall(r"time=(\d+):(\d+):([\d.]+)", log)[-1]
        return 3600 * int(h) + 60 * int(m) + float(s)

    video, audio = decoded_seconds("0:v"), decoded_seconds("0:a")
    assert video > 1.0 and abs(audio - video) < 1024 / 16000  # within one AAC frame, not a second
