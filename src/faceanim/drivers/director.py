"""The director (Lee et al. 1999, section 4): a scene script placed on a timeline.

A script (YAML or JSON) lists events; each is an action on the timeline:

    fps: 25
    seed: 1                      # for the jitter of repeated events
    events:
      - say: "Hello, how are you?"   # speech (synthesized), with its audio
        at: 0.5
      - expression: joy              # an MPEG-4 expression: joy sadness anger fear disgust surprise
        at: 0.0
        duration: 3.0
        intensity: 0.6
        envelope: smooth             # linear | smooth | peak
      - faps: {head_yaw: 8000, head_pitch: 3000}   # any FAP set (names or numbers)
        at: 2.0
        duration: 1.5
        envelope: peak
      - blink: {every: 3.0, jitter: 0.8}            # a repeated event with jitter
        from: 0.0
        to: 8.0
      - group: nod                   # a named group of actions, placed at 'at'
        at: 4.0
    groups:
      nod:
        - faps: {head_pitch: 6000}
          at: 0.0
          duration: 0.7
          envelope: peak

The events become actions, blended by the paper's weighted formula into one FAP stream; speech
events also place their audio on one sound track.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from faceanim.drivers.mpeg4 import (
    ENVELOPES,
    Action,
    FapStream,
    blend_actions,
    expression_faps,
    fap_set,
)
from faceanim.errors import InputFileError
from faceanim.face.faps import FapError

BLINK = {"close_t_l_eyelid": 1024, "close_t_r_eyelid": 1024, "close_b_l_eyelid": 150, "close_b_r_eyelid": 150}
BLINK_DURATION = 0.18
KNOWN = {"say", "expression", "faps", "blink", "group"}


@dataclass
class Scene:
    actions: list[Action]
    speech: list[tuple[float, Path]] = field(default_factory=list)  # (start, wav) of each say
    duration: float = 0.0
    fps: float = 25.0
    phones: list = field(default_factory=list)


def load_script(path) -> dict:
    """A director script from YAML or JSON."""
    import yaml

    p = Path(path)
    if not p.is_file():
        raise InputFileError(f"script '{p}' does not exist; check the path")
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f":{mark.line + 1}" if mark is not None else ""
        raise InputFileError(f"{p}{where}: not valid YAML or JSON ({getattr(exc, 'problem', exc)})") from None
    if not isinstance(data, dict) or not isinstance(data.get("events"), list):
        raise InputFileError(f"{p}: a script is a mapping with a list of 'events'")
    return data


def _number(event: dict, key: str, default=None, where: str = "") -> float:
    if key not in event:
        if default is None:
            raise InputFileError(f"{where}: needs '{key}'")
        return float(default)
    try:
        v = float(event[key])
    except (TypeError, ValueError):
        raise InputFileError(f"{where}: '{key}' must be a number, got {event[key]!r}") from None
    if not np.isfinite(v):
        raise InputFileError(f"{where}: '{key}' must be finite")
    return v


def build_scene(script: dict, rig, workdir: Path) -> Scene:
    """Turn a script into actions (and speech audio files in ``workdir``)."""
    from faceanim.drivers.speech import say_timed
    from faceanim.drivers.speech.visemes import viseme_actions

    fps = float(script.get("fps", 25.0))
    rng = np.random.default_rng(int(script.get("seed", 0)))
    groups = script.get("groups", {}) or {}
    actions: list[Action] = []
    speech: list[tuple[float, Path]] = []
    all_phones = []

    def place(events, offset, path):
        for k, ev in enumerate(events):
            where = f"{path}[{k}]"
            if not isinstance(ev, dict) or not (set(ev) & KNOWN):
                raise InputFileError(f"{where}: an event is one of {', '.join(sorted(KNOWN))}")
            kind = (set(ev) & KNOWN).pop()
            at = offset + _number(ev, "at", 0.0, where)
            try:
                if kind == "say":
                    wav = workdir / f"say{len(speech)}.wav"
                    phones = say_timed(str(ev["say"]), wav, voice=str(ev.get("voice", "en-us")))
                    phones = [type(p)(p.phone, p.start + at, p.end + at, p.word) for p in phones]
                    all_phones.extend(phones)
                    actions.extend(viseme_actions(phones, rig.lip_gap, _number(ev, "intensity", 1.0, where)))
                    speech.append((at, wav))
                elif kind == "blink":
                    spec = ev["blink"] or {}
                    every = float(spec.get("every", 3.0))
                    jitter = float(spec.get("jitter", 0.0))
                    if every <= 0:
                        raise InputFileError(f"{where}: blink 'every' must be positive")
                    t = offset + _number(ev, "from", 0.0, where)
                    end = offset + _number(ev, "to", t + 10.0, where)
                    while t < end:
                        actions.append(Action("blink", fap_set(BLINK), t, BLINK_DURATION, 1.0, "peak", weight=3.0))
                        t += max(0.3, every + rng.uniform(-jitter, jitter))
                elif kind == "group":
                    name = ev["group"]
                    if name not in groups:
                        raise InputFileError(f"{where}: no group '{name}'; the groups are {', '.join(groups) or 'none'}")
                    place(groups[name], at, f"groups.{name}")
                else:
                    faps = expression_faps(str(ev["expression"])) if kind == "expression" else fap_set(ev["faps"] or {})
                    envelope = str(ev.get("envelope", "smooth"))
                    if envelope not in ENVELOPES:
                        raise InputFileError(f"{where}: envelope must be one of {', '.join(ENVELOPES)}")
                    actions.append(Action(str(ev.get(kind)), faps, at, _number(ev, "duration", 1.0, where),
                                          _number(ev, "intensity", 1.0, where), envelope,
                                          _number(ev, "attack", 0.25, where), _number(ev, "release", 0.25, where),
                                          _number(ev, "weight", 0.3 if kind == "expression" else 1.0, where)))
            except FapError as exc:
                raise InputFileError(f"{where}: {exc}") from None

    place(script["events"], 0.0, "events")
    if not actions:
        raise InputFileError("the script places no actions on the timeline")
    duration = max(a.end for a in actions) + 0.2
    return Scene(actions, speech, duration, fps, all_phones)


def scene_stream(scene: Scene, name: str = "scene") -> FapStream:
    return blend_actions(scene.actions, int(np.ceil(scene.duration * scene.fps)) + 1, scene.fps, name)


def mix_speech(scene: Scene, path: Path) -> Path | None:
    """One 16 kHz WAV with every speech event at its place on the timeline."""
    from faceanim.drivers.speech.phonemes import (
        SAMPLE_RATE,
        load_wav,
        resample,
        write_wav,
    )

    if not scene.speech:
        return None
    track = np.zeros(int(np.ceil(scene.duration * SAMPLE_RATE)) + SAMPLE_RATE)
    for start, wav in scene.speech:
        x, rate = load_wav(wav)
        x = resample(x, rate)
        a = round(start * SAMPLE_RATE)
        track[a:a + len(x)] += x[: max(0, len(track) - a)]
    return write_wav(path, track)
