"""The director (Lee et al. 1999, section 4): a scene script placed on a timeline.

A script (YAML or JSON) lists events; each event has exactly one of ``say``, ``expression``,
``faps``, ``blink`` or ``group``, and becomes actions on the timeline:

    fps: 25
    seed: 1                      # for the jitter of repeated events
    events:
      - say: "Hello, how are you?"   # speech (synthesized), with its audio
        at: 0.5
        voice: en-us                 # any voice `espeak-ng --voices` lists (default en-us)
        emotion: joy                 # carried phrase by phrase, livelier phrases more (optional)
        emotion_intensity: 0.6
        prosody: true                # brows, blinks, nods and leans from the voice (the default)
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

The script is checked against a schema (pydantic, unknown keys refused) before anything is
built: a misspelt key, a wrong type or a number out of range is refused with the file's line and
the key's path (``scene.yaml, line 7: events[1]: unknown key 'duraton' ...``). Ranges are checked
before anything is allocated or synthesized: times within :data:`~faceanim.limits.MAX_DURATION`,
a blink at most every :data:`MIN_BLINK_EVERY` s, groups nested at most
:data:`~faceanim.limits.MAX_NESTING` deep, and at most :data:`~faceanim.limits.MAX_ACTIONS` events
and actions once groups and repeats are expanded (counted per group, without expanding them).

The events become actions, blended by the paper's weighted formula into one FAP stream; speech
events also place their audio on one sound track exactly as long as the stream.
"""

from __future__ import annotations

import difflib
import json
import math
import re
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    ValidationError,
    model_validator,
)

from faceanim.drivers.mpeg4 import (
    ENVELOPES,
    Action,
    FapStream,
    blend_actions,
    expression_faps,
    fap_set,
    viseme_table,
)
from faceanim.drivers.speech.prosody import BLINK_FAPS
from faceanim.errors import InputFileError
from faceanim.errors import shown as _shown
from faceanim.standards.mpeg4 import FapError
from faceanim.limits import (
    MAX_ACTIONS,
    MAX_DURATION,
    MAX_FPS,
    MAX_FRAMES,
    MAX_NESTING,
    MAX_TEXT,
)

BLINK = BLINK_FAPS  # the eyelids shut (the same closure as the voice's blinks)
BLINK_DURATION = 0.18
MIN_BLINK_EVERY = 0.5  # seconds between blinks, at least (people blink every 2-10 s)
MIN_BLINK_GAP = 0.3  # jitter never brings two blinks closer than this
KINDS = ("say", "expression", "faps", "blink", "group")  # an event has exactly one of these
ONE_OF = "an event has one of " + ", ".join(KINDS)
TAIL = 0.2  # seconds of timeline after the last action
MAX_INTENSITY = 10.0
MAX_WEIGHT = 1000.0
MAX_FAP_VALUE = 1e6  # FAPU units (the rig clamps far below; a head turn of half a turn is ~314,159)
MAX_SEED = 2**32 - 1
MAX_SCRIPT_BYTES = 1_000_000  # a scene script larger than this is refused before it is read


class ScriptError(InputFileError):
    """A scene script that cannot be read or is not a valid scene."""


# ----------------------------------------------------------------------------------- schema

Seconds = Annotated[float, Field(ge=0.0, le=MAX_DURATION)]
Duration = Annotated[float, Field(gt=0.0, le=MAX_DURATION)]
Intensity = Annotated[float, Field(ge=0.0, le=MAX_INTENSITY)]
Fraction = Annotated[float, Field(ge=0.0, le=1.0)]
Name = Annotated[str, Field(min_length=1, max_length=200)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, allow_inf_nan=False)


class SayEvent(_Strict):
    say: Annotated[str, Field(min_length=1, max_length=MAX_TEXT)]
    at: Seconds = 0.0
    voice: Name = "en-us"
    intensity: Intensity = 1.0  # of the mouth's visemes
    prosody: bool = True  # brows on the voice's accents, blinks at its pauses, nods and leans per phrase
    emotion: Name | None = None  # an MPEG-4 expression carried by this speech, phrase by phrase
    emotion_intensity: Intensity = 0.6


class _Shaped(_Strict):
    at: Seconds = 0.0
    duration: Duration = 1.0
    intensity: Intensity = 1.0
    envelope: Literal[ENVELOPES] = "smooth"
    attack: Fraction = 0.25  # fractions of the duration spent rising and falling
    release: Fraction = 0.25
    weight: Annotated[float, Field(ge=0.0, le=MAX_WEIGHT)] | None = None

    @model_validator(mode="after")
    def _ramps(self):
        if self.attack + self.release > 1.0:
            raise ValueError(f"'attack' + 'release' must be at most 1 (fractions of the duration), "
                             f"got {self.attack:g} + {self.release:g}")
        return self


class ExpressionEvent(_Shaped):
    expression: Name


def _numeric_text(value):
    """A FAP value written as text ('5000', as from a NAME=VALUE command line) -> its number."""
    if isinstance(value, str) and re.fullmatch(r"\s*[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?\s*", value):
        return float(value)
    return value


class FapsEvent(_Shaped):
    faps: dict[Any, Annotated[float, BeforeValidator(_numeric_text), Field(ge=-MAX_FAP_VALUE, le=MAX_FAP_VALUE)]]


class BlinkSpec(_Strict):
    every: Annotated[float, Field(ge=MIN_BLINK_EVERY, le=MAX_DURATION)] = 3.0
    jitter: Annotated[float, Field(ge=0.0, le=MAX_DURATION)] = 0.0

    @model_validator(mode="after")
    def _jitter(self):
        if self.jitter > self.every:
            raise ValueError(f"'jitter' must be at most 'every' ({self.every:g} s), got {self.jitter:g}")
        return self


class BlinkEvent(_Strict):
    blink: BlinkSpec | None = None
    start: Seconds = Field(0.0, alias="from")
    to: Seconds | None = None  # default: 'from' + 10 s


class GroupEvent(_Strict):
    group: Annotated[str, Field(min_length=1, max_length=200)]
    at: Seconds = 0.0


EVENT_MODELS: dict[str, type[_Strict]] = {"say": SayEvent, "expression": ExpressionEvent, "faps": FapsEvent,
                                          "blink": BlinkEvent, "group": GroupEvent}
Event = SayEvent | ExpressionEvent | FapsEvent | BlinkEvent | GroupEvent


class _Top(_Strict):
    fps: Annotated[float, Field(gt=0.0, le=MAX_FPS)] = 25.0
    seed: Annotated[int, Field(ge=0, le=MAX_SEED)] = 0
    face: Name | None = None
    events: Annotated[list[Any], Field(min_length=1, max_length=MAX_ACTIONS)]
    groups: dict[str, Annotated[list[Any], Field(max_length=MAX_ACTIONS)]] | None = None


@dataclass(frozen=True)
class Script:
    """A validated scene script."""

    events: tuple[Event, ...]
    groups: dict[str, tuple[Event, ...]]
    fps: float = 25.0
    seed: int = 0
    face: str | None = None
    source: str = "script"
    voices: dict[str, str] = field(default_factory=dict)  # voice as written -> as espeak-ng lists it
    planned_actions: int = 0  # upper bound of the actions (speech counted after synthesis)
    planned_end: float = 0.0  # end of the timeline without speech, seconds


# ----------------------------------------------------------------------------------- lines




def _where(loc) -> str:
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{_shown(part)}" if out else _shown(part))
    return out or "the script"


class _Lines:
    """Line numbers (1-based) of key paths in the script's text, from YAML's node marks."""

    def __init__(self, node=None, text: str | None = None):
        self.node, self.text = node, text

    def line(self, loc) -> int | None:
        import yaml

        node = self.node
        if node is None:
            return self._scan(loc)
        line = node.start_mark.line + 1
        for part in loc:
            if isinstance(node, yaml.MappingNode):
                for key, value in node.value:
                    if isinstance(key, yaml.ScalarNode) and key.value == str(part):
                        line, node = key.start_mark.line + 1, value
                        break
                else:
                    return line
            elif isinstance(node, yaml.SequenceNode) and isinstance(part, int) and 0 <= part < len(node.value):
                node = node.value[part]
                line = node.start_mark.line + 1
            else:
                return line
        return line

    def _scan(self, loc) -> int | None:
        """JSON that YAML cannot compose: the first line with the last key of ``loc`` in quotes."""
        if self.text is None:
            return None
        keys = [p for p in loc if isinstance(p, str)]
        if not keys:
            return 1
        m = re.search(re.escape(json.dumps(keys[-1])) + r"\s*:", self.text)
        return self.text.count("\n", 0, m.start()) + 1 if m else None


class _Fail:
    """Raises :class:`ScriptError` with the source and line of a key path."""

    def __init__(self, source: str, lines: _Lines | None):
        self.source, self.lines = source, lines

    def __call__(self, loc, message: str):
        line = self.lines.line(loc) if self.lines is not None else None
        at = f"{self.source}, line {line}" if line is not None else self.source
        raise ScriptError(f"{at}: {_where(loc)}: {message}" if loc else f"{at}: {message}")


# ----------------------------------------------------------------------------------- reading


@lru_cache(maxsize=1)
def _yaml_loader():
    import yaml

    base = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml: fast, and caps nesting at 1000

    class Loader(base):
        pass

    # YAML 1.2 floats (1e3, 1.5e-2 are numbers, as in JSON; YAML 1.1 reads them as strings)
    Loader.add_implicit_resolver(
        "tag:yaml.org,2002:float",
        re.compile(r"^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?|[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)"
                   r"|\.[0-9_]+(?:[eE][-+][0-9]+)?|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$"),
        list("-+0123456789."))
    return Loader


def _check_nodes(node, source: str) -> None:
    """Refuse aliases (a few lines of aliases can stand for billions of events) and duplicate keys
    (YAML keeps the last silently), walking the node graph without recursion."""
    import yaml

    seen: set[int] = set()
    stack = [node]
    while stack:
        n = stack.pop()
        if id(n) in seen:
            line = n.start_mark.line + 1
            raise ScriptError(f"{source}, line {line}: YAML anchors and aliases (&name, *name) are not "
                              "supported in scene scripts; write the events out, or use groups")
        seen.add(id(n))
        if isinstance(n, yaml.MappingNode):
            keys: set[str] = set()
            for key, value in n.value:
                if isinstance(key, yaml.ScalarNode):
                    if key.value in keys:
                        raise ScriptError(f"{source}, line {key.start_mark.line + 1}: duplicate key "
                                          f"'{_shown(key.value)}'; give each key once")
                    keys.add(key.value)
                stack += [value, key]
        elif isinstance(n, yaml.SequenceNode):
            stack += n.value[::-1]


def _parse(text: str, source: str, is_json: bool) -> tuple[Any, _Lines]:
    import yaml

    lines = _Lines(text=text)
    if is_json:
        def pairs(items):
            out = {}
            for k, v in items:
                if k in out:
                    line = lines.line([k])
                    at = f"{source}, line {line}" if line is not None else source
                    raise ScriptError(f"{at}: duplicate key '{_shown(k)}'; give each key once")
                out[k] = v
            return out

        try:
            data = json.loads(text, object_pairs_hook=pairs)
        except json.JSONDecodeError as exc:
            raise ScriptError(f"{source}, line {exc.lineno}: not valid JSON ({exc.msg}, column {exc.colno})") from None
        except RecursionError:
            raise ScriptError(f"{source}: the JSON is nested too deeply for a scene script") from None
        except ValueError:  # a number too long for Python's int conversion (thousands of digits)
            raise ScriptError(f"{source}: a number in the JSON is absurdly long; give ordinary numbers") from None
        try:  # JSON is YAML's flow style: compose it for the lines of keys (tabs are JSON whitespace)
            lines = _Lines(yaml.compose(text.replace("\t", " "), Loader=_yaml_loader()))
        except (yaml.YAMLError, RecursionError):
            pass
        return data, lines
    loader = _yaml_loader()(text)
    try:
        node = loader.get_single_node()
        if node is None:
            return None, lines
        lines = _Lines(node)
        _check_nodes(node, source)
        data = loader.construct_document(node)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f", line {mark.line + 1}" if mark is not None else ""
        problem = _shown(getattr(exc, "problem", None) or "unreadable", 80)
        raise ScriptError(f"{source}{where}: not valid YAML or JSON ({problem})") from None
    except RecursionError:
        raise ScriptError(f"{source}: the YAML is nested too deeply for a scene script") from None
    finally:
        loader.dispose()
    return data, lines


def load_script(path) -> Script:
    """A validated director script from a YAML or JSON file (``.json`` is read as JSON, anything
    else as YAML). Every problem is a :class:`ScriptError` naming the file, line and key."""
    p = Path(path)
    if not p.is_file():
        raise ScriptError(f"script '{p}' does not exist; check the path")
    size = p.stat().st_size
    if size > MAX_SCRIPT_BYTES:
        raise ScriptError(f"script '{p}' has {size} bytes; a scene script has at most {MAX_SCRIPT_BYTES}: "
                          "split the scene")
    try:
        text = p.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError:
        raise ScriptError(f"script '{p}' is not UTF-8 text; save it as UTF-8") from None
    except OSError:
        raise ScriptError(f"cannot read script '{p}'; check that it is readable") from None
    data, lines = _parse(text, str(p), p.suffix.lower() == ".json")
    return validate_script(data, str(p), lines)


# ----------------------------------------------------------------------------------- validation

_EXPECTED = {"float_type": "a number", "float_parsing": "a number", "int_type": "a whole number",
             "int_from_float": "a whole number", "string_type": "a string (quote it)", "dict_type": "a mapping",
             "model_type": "a mapping", "model_attributes_type": "a mapping", "list_type": "a list",
             "bool_type": "true or false", "finite_number": "a finite number"}


def _type_name(value) -> str:
    if value is None:
        return "nothing"
    if type(value) is float:
        return f"{value:g}"
    if type(value) is int:
        return str(value) if abs(value) < 10**15 else "a very large number"
    return {bool: "true/false", str: "a string", list: "a list",
            dict: "a mapping"}.get(type(value), type(value).__name__)


def _pydantic_message(err: dict, model: type[BaseModel] | None, what: str) -> str:
    kind, loc, ctx = err["type"], err["loc"], err.get("ctx") or {}
    value = err.get("input")
    if "[key]" in loc:
        return f"a name here must be a string (quote it), got {_type_name(value)}"
    key = f"'{_shown(loc[-1])}'" if loc and isinstance(loc[-1], str) else "the value"
    if kind == "extra_forbidden":
        keys = [f.alias or name for name, f in model.model_fields.items()] if model else []
        keys = [k for k in keys if k in KINDS] + [k for k in keys if k not in KINDS]  # the kind first
        allowed = ", ".join(keys)
        close = difflib.get_close_matches(str(loc[-1]), keys, n=1)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        return f"unknown key {key}{hint}; {what} takes: {allowed}"
    if kind == "missing":
        return f"needs {key}"
    if kind in _EXPECTED:
        got = "" if kind == "finite_number" else f", got {_type_name(value)}"
        return f"{key} must be {_EXPECTED[kind]}{got}"
    bounds = {"greater_than_equal": ("at least", "ge"), "greater_than": ("more than", "gt"),
              "less_than_equal": ("at most", "le"), "less_than": ("less than", "lt")}
    if kind in bounds:
        word, c = bounds[kind]
        return f"{key} must be {word} {ctx.get(c):g}, got {value:g}"
    if kind == "literal_error":
        return f"{key} must be one of {', '.join(ENVELOPES)}" if loc[-1] == "envelope" else \
            f"{key} must be {ctx.get('expected')}"
    if kind in ("string_too_short", "too_short"):
        return f"{key} must not be empty"
    if kind == "string_too_long":
        return f"{key} is too long (at most {ctx.get('max_length')} characters)"
    if kind == "too_long":
        return f"{key} has too many entries (at most {ctx.get('max_length')})"
    if kind == "value_error":
        return str(ctx.get("error", err["msg"]))
    return f"{key}: {err['msg']}"


def _validate(model: type[_Strict], data, loc: tuple, fail: _Fail, what: str):
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        errors = exc.errors(include_url=False)
        if fail.lines is not None:  # report the error that comes first in the file
            errors = sorted(errors, key=lambda e: fail.lines.line(loc + tuple(_clean(e["loc"]))) or 0)
        err = errors[0]
        fail(loc + tuple(_clean(err["loc"])), _pydantic_message(err, _owner(model, err["loc"]), _what(model, err)))


def _clean(loc) -> list:
    """A pydantic location without its internal parts (union members, '[key]')."""
    return [p for p in loc if p not in ("[key]", "BlinkSpec", "float", "constrained-float", "none")
            and not (isinstance(p, str) and p.startswith(("function-", "nullable[")))]


def _owner(model: type[BaseModel], loc) -> type[BaseModel]:
    return BlinkSpec if model is BlinkEvent and len(loc) > 1 and loc[0] == "blink" else model


def _what(model: type[BaseModel], err: dict) -> str:
    if _owner(model, err["loc"]) is BlinkSpec:
        return "blink"
    for kind, m in EVENT_MODELS.items():
        if m is model:
            return f"{'an' if kind[0] in 'ae' else 'a'} {kind} event"
    return "a scene script"


def _expressions() -> list[str]:
    return [d["name"] for d in viseme_table()["expressions"].values()]


def _event(data, loc: tuple, fail: _Fail) -> Event:
    if not isinstance(data, dict):
        fail(loc, f"{ONE_OF}, as a mapping (e.g. {{expression: joy, at: 0}}); got {_type_name(data)}")
    kinds = [k for k in data if k in KINDS]  # in the order written
    if not kinds:
        for key in data:
            close = difflib.get_close_matches(str(key), KINDS, n=1)
            if close:
                fail(loc + (key,), f"unknown key '{_shown(key)}' (did you mean '{close[0]}'?); {ONE_OF}")
        fail(loc, ONE_OF)
    if len(kinds) > 1:
        fail(loc + (kinds[1],), f"{ONE_OF}; this one has both '{kinds[0]}' and '{kinds[1]}': split it in two")
    kind = kinds[0]
    ev = _validate(EVENT_MODELS[kind], data, loc, fail, kind)
    if kind == "say" and ev.emotion is not None and ev.emotion not in _expressions():
        fail(loc + ("emotion",), f"unknown emotion '{_shown(ev.emotion)}'; choose one of: {', '.join(_expressions())}")
    if kind == "expression" and ev.expression not in _expressions():
        fail(loc + ("expression",), f"unknown expression '{_shown(ev.expression)}'; choose one of: "
                                    f"{', '.join(_expressions())}")
    if kind == "faps":
        for key in ev.faps:
            if isinstance(key, bool) or not isinstance(key, (str, int)):
                fail(loc + ("faps",), f"a FAP is a name (open_jaw) or a number (3), got {_type_name(key)}")
            try:
                fap_set({key: 0.0})
            except FapError:
                fail(loc + ("faps", key), f"unknown FAP '{_shown(key)}' (or one with fields, FAP 1 or 2); "
                                          "use FAP names like open_jaw, head_yaw or numbers 3 to 68")
        if not ev.faps:
            fail(loc + ("faps",), "'faps' must set at least one FAP, e.g. {head_yaw: 8000}")
    if kind == "blink":
        start = ev.start
        end = ev.to if ev.to is not None else start + 10.0
        if end <= start:
            fail(loc + ("to",), f"'to' must be after 'from' ({start:g} s), got {end:g}")
    return ev


@dataclass
class _Plan:
    """What a list of events expands to, counted without expanding it."""

    depth: int = 0  # groups inside groups
    events: int = 0
    actions: int = 0  # speech not counted
    say_chars: int = 0
    end: float = 0.0  # seconds after the list's offset (speech from its start, blinks until 'to')


def _blink_count(ev: BlinkEvent) -> int:
    spec = ev.blink or BlinkSpec()
    end = ev.to if ev.to is not None else ev.start + 10.0
    return math.ceil((end - ev.start) / max(MIN_BLINK_GAP, spec.every - spec.jitter)) + 1


def _plan(events, groups: dict, fail: _Fail, loc: tuple, stack: tuple, memo: dict) -> _Plan:
    total = _Plan()
    for k, ev in enumerate(events):
        here = loc + (k,)
        total.events += 1
        if isinstance(ev, GroupEvent):
            name = ev.group
            if name not in groups:
                known = ", ".join(_shown(g) for g in list(groups)[:8]) or "none"
                fail(here + ("group",), f"no group '{_shown(name)}'; the groups are: {known}")
            if name in stack:
                chain = " -> ".join(_shown(g) for g in stack[stack.index(name):] + (name,))
                fail(here + ("group",), f"group '{_shown(name)}' places itself ({chain}); remove the loop")
            if len(stack) + 1 > MAX_NESTING:
                fail(here + ("group",), f"groups are nested more than {MAX_NESTING} deep "
                                        f"({' -> '.join(_shown(g) for g in stack + (name,))}); flatten them")
            if name not in memo:
                memo[name] = _plan(groups[name], groups, fail, ("groups", name), stack + (name,), memo)
            sub = memo[name]
            total.depth = max(total.depth, sub.depth + 1)
            total.events += sub.events
            total.actions += sub.actions
            total.say_chars += sub.say_chars
            total.end = max(total.end, ev.at + sub.end)
        elif isinstance(ev, BlinkEvent):
            total.actions += _blink_count(ev)
            total.end = max(total.end, ev.to if ev.to is not None else ev.start + 10.0)  # the last starts before
        elif isinstance(ev, SayEvent):
            total.say_chars += len(ev.say)
            total.end = max(total.end, ev.at)
        else:
            total.actions += 1
            total.end = max(total.end, ev.at + ev.duration)
        if total.events > MAX_ACTIONS or total.actions > MAX_ACTIONS:
            what = "events" if total.events > MAX_ACTIONS else "actions"
            fail(here, f"the scene expands to more than {MAX_ACTIONS} {what} (groups and repeated blinks "
                       "counted out); make it shorter or blink less often")
        if total.say_chars > MAX_TEXT:
            fail(here, f"the scene speaks more than {MAX_TEXT} characters (groups counted out); "
                       "split it into several scenes")
        if total.end > MAX_DURATION:
            fail(here, f"the scene runs past {MAX_DURATION:g} s (times inside groups add up); make it shorter")
    return total


def validate_script(data, source: str = "script", lines: _Lines | None = None) -> Script:
    """A :class:`Script` from parsed YAML/JSON ``data``, or a :class:`ScriptError` naming the first
    problem (with its line when ``lines`` maps key paths to the file's lines)."""
    fail = _Fail(source, lines)
    if not isinstance(data, dict):
        fail((), f"a script is a mapping with a list of 'events' (e.g. events: [{{expression: joy}}]), "
                 f"got {_type_name(data)}")
    if "events" not in data:
        fail((), "a script is a mapping with a list of 'events' (e.g. events: [{expression: joy}])")
    top = _validate(_Top, data, (), fail, "script")
    events = tuple(_event(ev, ("events", k), fail) for k, ev in enumerate(top.events))
    groups = {name: tuple(_event(ev, ("groups", name, k), fail) for k, ev in enumerate(evs))
              for name, evs in (top.groups or {}).items()}
    plan = _plan(events, groups, fail, ("events",), (), {})
    n_frames = math.ceil((plan.end + BLINK_DURATION + TAIL) * top.fps) + 1
    if n_frames > MAX_FRAMES:
        fail(("fps",), f"the scene needs {n_frames} frames at {top.fps:g} fps; faceanim makes at most "
                       f"{MAX_FRAMES}: lower 'fps' or shorten the scene")
    voices = {}
    for loc, ev in _all_events(events, groups):
        if isinstance(ev, SayEvent):
            from faceanim.drivers.speech.phonemes import (
                SpeechError,
                check_text,
                check_voice,
            )

            try:
                check_text(ev.say)
            except SpeechError as exc:
                fail(loc + ("say",), str(exc))
            if ev.voice not in voices:
                try:
                    voices[ev.voice] = check_voice(ev.voice)
                except SpeechError as exc:
                    fail(loc + ("voice",), str(exc))
    return Script(events, groups, top.fps, top.seed, top.face, source, voices, plan.actions, plan.end)


def _all_events(events, groups):
    """(location, event) of every event as written (groups once each), in file order."""
    for k, ev in enumerate(events):
        yield ("events", k), ev
    for name, evs in groups.items():
        for k, ev in enumerate(evs):
            yield ("groups", name, k), ev


# ----------------------------------------------------------------------------------- building


@dataclass
class Scene:
    actions: list[Action]
    speech: list[tuple[float, Path]] = field(default_factory=list)  # (start, wav) of each say
    duration: float = 0.0
    fps: float = 25.0
    phones: list = field(default_factory=list)

    @property
    def n_frames(self) -> int:
        """Frames of the scene's FAP stream (and of its video)."""
        return int(np.ceil(self.duration * self.fps)) + 1


def _voice_actions(ev: SayEvent, wav: Path, at: float, phones) -> list[Action]:
    """A say event's upper face and head from its voice's prosody (``prosody``), and its ``emotion``
    phrase by phrase (:func:`~faceanim.drivers.speech.prosody.emotion_actions`)."""
    from faceanim.drivers.speech.prosody import analyse, emotion_actions, prosody_actions
    from faceanim.io.audio import read_audio

    prosody = analyse(*read_audio(wav, "speech audio"))
    out = prosody_actions(prosody, at) if ev.prosody else []
    if ev.emotion:
        out += emotion_actions(prosody, ev.emotion, ev.emotion_intensity, max(p.end for p in phones) - at, at)
    return out


def build_scene(script: Script | dict, lip_gap: float, workdir: Path) -> Scene:
    """Turn a script (a :class:`Script`, or a dict validated here) into actions, and speech audio
    files in ``workdir``. The same script gives the same scene, run after run."""
    from faceanim.drivers.speech import say_timed
    from faceanim.drivers.speech.visemes import viseme_actions

    if not isinstance(script, Script):
        script = validate_script(script)
    rng = np.random.default_rng(script.seed)
    actions: list[Action] = []
    speech: list[tuple[float, Path]] = []
    all_phones = []
    spoken: dict[tuple[str, str], tuple[Path, list]] = {}  # the same words in a repeated group: once
    blink_faps = fap_set(BLINK)

    def place(events, offset):
        for ev in events:
            if isinstance(ev, BlinkEvent):
                spec = ev.blink or BlinkSpec()
                t = offset + ev.start
                end = offset + (ev.to if ev.to is not None else ev.start + 10.0)
                while t < end:
                    actions.append(Action("blink", blink_faps, t, BLINK_DURATION, 1.0, "peak", weight=3.0))
                    t += max(MIN_BLINK_GAP, spec.every + rng.uniform(-spec.jitter, spec.jitter))
                continue
            at = offset + ev.at
            if isinstance(ev, GroupEvent):
                place(script.groups[ev.group], at)
            elif isinstance(ev, SayEvent):
                voice = script.voices.get(ev.voice) or ev.voice
                if (ev.say, voice) not in spoken:
                    wav = Path(workdir) / f"say{len(spoken)}.wav"
                    spoken[ev.say, voice] = (wav, say_timed(ev.say, wav, voice=voice))
                wav, phones = spoken[ev.say, voice]
                phones = [type(p)(p.phone, p.start + at, p.end + at, p.word) for p in phones]
                all_phones.extend(phones)
                actions.extend(viseme_actions(phones, lip_gap, ev.intensity))
                speech.append((at, wav))
                if ev.prosody or ev.emotion:
                    actions.extend(_voice_actions(ev, wav, at, phones))
            else:
                if isinstance(ev, ExpressionEvent):
                    name, faps, weight = ev.expression, expression_faps(ev.expression), 0.3
                else:
                    name, faps, weight = ", ".join(map(str, ev.faps)), fap_set(ev.faps), 1.0
                actions.append(Action(name, faps, at, ev.duration, ev.intensity, ev.envelope, ev.attack,
                                      ev.release, weight if ev.weight is None else ev.weight))
            if len(actions) > MAX_ACTIONS:
                raise ScriptError(f"{script.source}: the scene has more than {MAX_ACTIONS} actions once its speech "
                                  "is synthesized; split it into several scenes")

    place(script.events, 0.0)
    if not actions:
        raise ScriptError(f"{script.source}: the script places no actions on the timeline")
    duration = max(a.end for a in actions) + TAIL
    scene = Scene(actions, speech, duration, script.fps, all_phones)
    if duration > MAX_DURATION + BLINK_DURATION + TAIL or scene.n_frames > MAX_FRAMES:
        raise ScriptError(f"{script.source}: with its speech the scene lasts {duration:.1f} s ({scene.n_frames} "
                          f"frames); faceanim makes at most {MAX_DURATION:g} s and {MAX_FRAMES} frames")
    return scene


def scene_stream(scene: Scene, name: str = "scene") -> FapStream:
    return blend_actions(scene.actions, scene.n_frames, scene.fps, name)


def speech_track(scene: Scene) -> np.ndarray | None:
    """The scene's speech mixed on one 16 kHz track exactly as long as its FAP stream
    (``scene.n_frames / scene.fps`` seconds, to the nearest sample); None without speech."""
    from faceanim.drivers.speech.phonemes import SAMPLE_RATE
    from faceanim.io.audio import read_audio, resample

    if not scene.speech:
        return None
    track = np.zeros(round(scene.n_frames / scene.fps * SAMPLE_RATE), dtype=np.float32)
    loaded: dict[Path, np.ndarray] = {}
    for start, wav in scene.speech:
        if wav not in loaded:
            x, rate = read_audio(wav, "speech audio")
            loaded[wav] = resample(x, rate, SAMPLE_RATE)
        x = loaded[wav]
        a = round(start * SAMPLE_RATE)
        if a < len(track):
            piece = x[: len(track) - a]
            track[a:a + len(piece)] += piece
    return track


def mix_speech(scene: Scene, path: Path) -> Path | None:
    """One 16 kHz WAV with every speech event at its place on the timeline, exactly as long as the
    scene's FAP stream (so the video gets no trailing silence); None without speech."""
    from faceanim.drivers.speech.phonemes import SAMPLE_RATE
    from faceanim.io.audio import write_wav

    track = speech_track(scene)
    if track is None:
        return None
    return write_wav(path, track, SAMPLE_RATE)
