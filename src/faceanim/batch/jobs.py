"""Job files: read, check and expand into tasks.

A job file (YAML or JSON) has four keys::

    operation: transfer                  # a faceanim command that makes files
    inputs:                              # the command's input arguments by CLI name
      source_neutral: scans/pose_0.obj   #   a path,
      source_expressive: scans/pose_*.obj  # a glob (sorted matches),
      target: [heads/a.obj, heads/b.obj]   # a list of paths or globs,
      transcript: "clips/{audio}.txt"    #   or a pattern on an earlier input's stem
    options: {au: all, magnitude: 1.0}   # the command's other options, as on the command line
    output: "{target}/{source_expressive}.obj"   # under OUTDIR; {name} is an input's stem

Paths are relative to the job file's folder. The tasks are every combination of the inputs (a
pattern input follows the inputs it names). Every error names the key and the line it is on.
"""

from __future__ import annotations

import glob
import json
import os
import re
import string
from dataclasses import dataclass, field
from pathlib import Path

from faceanim.errors import FaceAnimError, shown

MAX_JOB_BYTES = 1 << 20  # a job file is a few lines; a megabyte is not one
MAX_TASKS = 1_000_000  # combinations of the inputs
MAX_MATCHES = 200_000  # files one glob may match
KEYS = ("operation", "inputs", "options", "output")


_UniqueKeyLoader = None  # made on first use (yaml is imported late)
MAX_SCANNED = 500_000  # folders and files a recursive glob may look at
MAX_NAME_BYTES, MAX_PATH_BYTES = 255, 4096  # what file systems take


class JobError(FaceAnimError):
    """A job file that cannot be run as written."""


@dataclass
class Job:
    """A checked job: the operation, input names in order, options, output pattern, the job
    file's folder, and the source line of each key (``lines["inputs.target"]``)."""

    operation: str
    inputs: dict[str, list[str] | str]
    options: dict[str, object]
    output: str
    base: Path
    source: str = "job"
    lines: dict[str, int] = field(default_factory=dict)

    def where(self, key: str) -> str:
        line = self.lines.get(key)
        return f"{self.source}, line {line}" if line else self.source


@dataclass(frozen=True)
class Task:
    """One combination: input name -> path, and the output path (under the output folder)."""

    inputs: tuple[tuple[str, str], ...]
    output: str

    @property
    def input_paths(self) -> dict[str, str]:
        return dict(self.inputs)


class _Twice(Exception):
    def __init__(self, key, line=None):
        self.key, self.line = str(key), line


def _unique_pairs(pairs):
    out = {}
    for k, v in pairs:
        if k in out:
            raise _Twice(k)
        out[k] = v
    return out


def _unique_key_loader():
    import yaml

    class Loader(yaml.SafeLoader):
        """The safe YAML loader, refusing a mapping that names a key twice (it keeps the last)."""

        def construct_mapping(self, node, deep=False):
            seen = set()
            for key_node, _ in node.value:
                if isinstance(key_node, yaml.ScalarNode):
                    if key_node.value in seen:
                        raise _Twice(key_node.value, key_node.start_mark.line + 1)
                    seen.add(key_node.value)
            return super().construct_mapping(node, deep)

    return Loader


def _lines(text: str) -> dict[str, int]:
    """Line numbers (1-based) of the top-level keys and of the keys under inputs/options."""
    import yaml

    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError:
        return {}
    out: dict[str, int] = {}
    if isinstance(node, yaml.MappingNode):
        for k, v in node.value:
            if isinstance(k, yaml.ScalarNode):
                out[str(k.value)] = k.start_mark.line + 1
                if isinstance(v, yaml.MappingNode):
                    for k2, _ in v.value:
                        if isinstance(k2, yaml.ScalarNode):
                            out[f"{k.value}.{k2.value}"] = k2.start_mark.line + 1
    return out


def read_job(path) -> Job:
    """A job file, checked for shape (not yet against the operation: see the command layer)."""
    import yaml

    global _UniqueKeyLoader
    if _UniqueKeyLoader is None:
        _UniqueKeyLoader = _unique_key_loader()
    path = Path(path)
    name = shown(path.name, 60, tail=True)
    try:
        if path.is_dir():
            raise JobError(f"job file '{name}' is a folder; give a .yaml or .json file")
        if path.exists() and not path.is_file():  # a pipe or a device: it could never end
            raise JobError(f"job file '{name}' is not a regular file (a device, pipe or socket); give a .yaml or "
                           ".json file")
        size = path.stat().st_size
        if size > MAX_JOB_BYTES:
            raise JobError(f"job file '{name}' is {size} bytes; a job file is a few lines (at most 1 MiB)")
        with open(path, "rb") as fh:
            raw = fh.read(MAX_JOB_BYTES + 1)  # a file that grows while read stops at the limit too
        if len(raw) > MAX_JOB_BYTES:
            raise JobError(f"job file '{name}' is larger than 1 MiB; a job file is a few lines")
    except FileNotFoundError:
        raise JobError(f"job file '{name}' does not exist; give the path of a .yaml or .json job file") from None
    except OSError:
        raise JobError(f"job file '{name}' cannot be read; check its permissions") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise JobError(f"job file '{name}' is not UTF-8 text; write it as YAML or JSON") from None
    try:
        doc = json.loads(text, object_pairs_hook=_unique_pairs) if path.suffix.lower() == ".json" \
            else yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 -- a SafeLoader subclass
    except _Twice as exc:
        raise JobError(f"key '{shown(exc.key)}' is given twice{f' (line {exc.line})' if exc.line else ''} in "
                       f"job file '{name}'; give it once") from None
    except (yaml.YAMLError, ValueError) as exc:
        mark = getattr(exc, "problem_mark", None)
        line = mark.line + 1 if mark is not None else getattr(exc, "lineno", None)
        at = f" (line {line})" if line else ""
        raise JobError(f"job file '{name}' is not valid {'JSON' if path.suffix.lower() == '.json' else 'YAML'}"
                       f"{at}; fix its syntax") from None
    except RecursionError:
        raise JobError(f"job file '{name}' nests too deeply; a job file is four keys") from None
    lines = _lines(text)

    def at(key: str) -> str:
        return f"{name}, line {lines[key]}" if key in lines else name

    if not isinstance(doc, dict):
        raise JobError(f"job file '{name}' must be a mapping with the keys {', '.join(KEYS)}")
    unknown = [k for k in doc if k not in KEYS]
    if unknown:
        raise JobError(f"unknown key '{shown(unknown[0])}' ({at(str(unknown[0]))}); a job file has: {', '.join(KEYS)}")
    for key in ("operation", "inputs", "output"):
        if key not in doc:
            raise JobError(f"job file '{name}' has no '{key}'; it needs: {', '.join(KEYS)} (options may be left out)")
    operation = doc["operation"]
    if not isinstance(operation, str) or not operation.strip():
        raise JobError(f"operation ({at('operation')}) must be a command name such as transfer or 'wires apply'")
    inputs = doc["inputs"]
    if not isinstance(inputs, dict) or not inputs:
        raise JobError(f"inputs ({at('inputs')}) must map each input's name to a path, a glob or a list")
    clean_inputs: dict[str, list[str] | str] = {}
    for k, v in inputs.items():
        key = str(k).replace("-", "_")
        where = at(f"inputs.{k}")
        if key in clean_inputs:
            raise JobError(f"input '{shown(k)}' ({where}) is given twice")
        if isinstance(v, str) and v.strip():
            clean_inputs[key] = v
        elif isinstance(v, list) and v and all(isinstance(x, str) and x.strip() for x in v):
            clean_inputs[key] = list(v)
        else:
            raise JobError(f"input '{shown(k)}' ({where}) must be a path, a glob or a non-empty list of them")
    options = doc.get("options") or {}
    if not isinstance(options, dict):
        raise JobError(f"options ({at('options')}) must map option names to values")
    clean_options: dict[str, object] = {}
    for k, v in options.items():
        key = str(k).replace("-", "_")
        if key in clean_options or key in clean_inputs:
            raise JobError(f"option '{shown(k)}' ({at(f'options.{k}')}) is given twice")
        ok = v is None or isinstance(v, (bool, int, float, str)) or (
            isinstance(v, list) and all(isinstance(x, (bool, int, float, str)) and not isinstance(x, bool) for x in v))
        if not ok:
            raise JobError(f"option '{shown(k)}' ({at(f'options.{k}')}) must be a number, a word, true/false or a "
                           "list of numbers or words")
        clean_options[key] = v
    output = doc["output"]
    if not isinstance(output, str) or not output.strip():
        raise JobError(f"output ({at('output')}) must be a file-name pattern such as \"{{target}}.glb\"")
    norm = {}
    for k, v in lines.items():
        head, _, rest = k.partition(".")
        norm[f"{head}.{rest.replace('-', '_')}" if rest else k] = v
    return Job(operation.strip(), clean_inputs, clean_options, output.strip(), path.resolve().parent, name, norm)


def _fields(pattern: str, what: str) -> list[str]:
    if any(not c.isprintable() for c in pattern):
        raise JobError(f"{what} holds a control character (such as NUL or a newline); file names cannot")
    try:
        parsed = list(string.Formatter().parse(pattern))
    except ValueError:
        raise JobError(f"{what} '{shown(pattern, 80)}' has an unmatched brace; write {{name}} for an input's stem") \
            from None
    for _, f, spec, conversion in parsed:
        if f is not None and (spec or conversion or not f.isidentifier()):
            raise JobError(f"{what}: '{{{shown(f + ('!' + conversion if conversion else '') + (':' + spec if spec else ''), 40)}}}'"
                           " is not an input's name; write plain {name} (no format spec)")
    return [f for _, f, _, _ in parsed if f is not None]


def _expand_one(job: Job, name: str, value: str, known: dict[str, str]) -> list[str]:
    """The paths one input entry stands for, given the stems of the earlier inputs ``known``."""
    where = job.where(f"inputs.{name}")
    fields = _fields(value, f"input '{name}' ({where})")
    if fields:
        bad = [f for f in fields if f not in known]
        if bad:
            raise JobError(f"input '{name}' ({where}) names '{{{shown(bad[0])}}}', which is not an earlier input; "
                           f"use one of: {', '.join(known) or '(none before it)'}")
        value = value.format(**known)
    path = Path(os.path.normpath(value if Path(value).is_absolute() else job.base / value))
    if glob.has_magic(value):
        files = sorted(_glob(str(path), name, where))
        if not files:
            raise JobError(f"input '{name}' ({where}): '{shown(value, 80)}' matches no file")
        return files
    if not path.is_file():
        raise JobError(f"input '{name}' ({where}): '{shown(value, 80)}' is not a file"
                       + ("" if not fields else " (from its pattern)"))
    return [str(path)]


def _glob_regex(pattern: str) -> re.Pattern:
    """A glob as a regular expression over whole paths: ``*`` and ``?`` stay within a folder,
    ``**/`` spans folders, ``[...]`` is a set."""
    out, k = [], 0
    while k < len(pattern):
        c = pattern[k]
        if pattern.startswith("**/", k):
            out.append("(?:.*/)?")
            k += 3
        elif pattern.startswith("**", k):
            out.append(".*")
            k += 2
        elif c == "*":
            out.append("[^/]*")
            k += 1
        elif c == "?":
            out.append("[^/]")
            k += 1
        elif c == "[" and "]" in pattern[k + 2:]:
            end = pattern.index("]", k + 2)
            body = pattern[k + 1:end]
            body = "^" + body[1:] if body.startswith("!") else body
            out.append("[" + body.replace("\\", "\\\\") + "]")
            k = end + 1
        else:
            out.append(re.escape(c))
            k += 1
    return re.compile("".join(out) + r"\Z")


def _glob(pattern: str, name: str, where: str) -> list[str]:
    """The files a glob matches, walking from its fixed part down without following links to
    folders (a link loop, or /proc, would never end) and looking at :data:`MAX_SCANNED` entries at
    most."""
    parts = pattern.split("/")
    fixed = []
    for part in parts[:-1]:
        if glob.has_magic(part):
            break
        fixed.append(part)
    root = "/".join(fixed) or ("/" if pattern.startswith("/") else ".")
    regex = _glob_regex(pattern)
    depth = None if "**" in pattern else len(parts) - len(fixed) - 1
    found, scanned = [], 0
    hidden_ok = "/." in "/" + pattern  # like glob: names starting with a dot only when the pattern says so
    for folder, dirs, names in os.walk(root, followlinks=False):
        if not hidden_ok:
            dirs[:] = [d for d in dirs if not d.startswith(".")]
            names = [n for n in names if not n.startswith(".")]
        level = 0 if folder == root else folder[len(root):].strip("/").count("/") + 1
        scanned += len(dirs) + len(names)
        if scanned > MAX_SCANNED:
            raise JobError(f"input '{name}' ({where}): the glob searches more than {MAX_SCANNED} files and folders; "
                           "narrow it")
        if depth is not None and level >= depth:
            dirs[:] = []
        dirs.sort()
        for n in names:
            full = os.path.join(folder, n)
            if regex.match(full) and os.path.isfile(full):
                found.append(full)
                if len(found) > MAX_MATCHES:
                    raise JobError(f"input '{name}' ({where}) matches more than {MAX_MATCHES} files; narrow the glob")
    return found


def expand(job: Job) -> list[Task]:
    """Every combination of the inputs as tasks (in a fixed order: the inputs in the file's order,
    each one's files sorted), each with its output path; refused when two tasks would write one
    file or an output leaves the output folder."""
    names = list(job.inputs)
    out_fields = _fields(job.output, f"output ({job.where('output')})")
    bad = [f for f in out_fields if f not in names]
    if bad:
        raise JobError(f"output ({job.where('output')}) names '{{{shown(bad[0])}}}', which is not an input; use "
                       f"one of: {', '.join(names)}")
    tasks: list[Task] = []

    def walk(k: int, chosen: list[tuple[str, str]]) -> None:
        if k == len(names):
            stems = {n: Path(p).stem for n, p in chosen}
            out = job.output.format(**stems)
            tasks.append(Task(tuple(chosen), out))
            if len(tasks) > MAX_TASKS:
                raise JobError(f"the inputs make more than {MAX_TASKS} tasks; split the job")
            return
        name = names[k]
        value = job.inputs[name]
        known = {n: Path(p).stem for n, p in chosen}
        entries = value if isinstance(value, list) else [value]
        for entry in entries:
            for path in _expand_one(job, name, entry, known):
                walk(k + 1, chosen + [(name, path)])

    walk(0, [])
    seen: dict[str, int] = {}
    for t in tasks:
        p = Path(t.output)
        if p.is_absolute() or ".." in p.parts or not p.name:
            raise JobError(f"output ({job.where('output')}) must stay inside the output folder: "
                           f"'{shown(t.output, 80)}'")
        if any(len(part.encode()) > MAX_NAME_BYTES for part in p.parts) or len(t.output.encode()) > MAX_PATH_BYTES:
            raise JobError(f"output ({job.where('output')}) makes a file name longer than {MAX_NAME_BYTES} bytes "
                           f"('{shown(t.output, 60)}'); shorten the pattern")
        seen[t.output] = seen.get(t.output, 0) + 1
    twice = [o for o, n in seen.items() if n > 1]
    if twice:
        raise JobError(f"output ({job.where('output')}) gives '{shown(twice[0], 80)}' to {seen[twice[0]]} tasks; "
                       "put every varying input's {name} in the pattern")
    return tasks
