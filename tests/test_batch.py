"""faceanim batch (issue 13): job files, the Dask run, the manifest, a killed worker, bad input.

1. Job files: read_job/expand on their own (paths relative to the job file's folder, sorted globs,
   lists, patterns on earlier inputs, every combination, the output pattern) and every refusal
   naming its line; hypothesis fuzz of read_job (bytes, text, structured documents).
2. End to end on a LocalCluster of 2 workers, in a subprocess as a user runs it: each output is
   byte for byte what the same command writes when run directly; the manifest rows; a rerun skips
   everything without starting a cluster; a changed input redoes only its task, a deleted output
   only its own; an empty mesh among the inputs fails its task with the direct run's message
   while the rest finish, exit 1. The default face (no face input) is bound once for its tasks.
3. The issue's fault test: a worker SIGKILLed mid-batch; every output still complete and equal to
   the direct run's, exit 0; a rerun skips all.
4. Bad input to the batch command itself: one line on stderr, exit 2, nothing written.
Cases the first version got wrong (format specs, NUL, link loops, keys given twice, malformed
scheduler addresses, refusals without their line) are ordinary tests now.
"""

import itertools
import json
import os
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from faceanim.batch.jobs import Job, JobError, expand, read_job
from faceanim.cli import main
from faceanim.errors import FaceAnimError

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

MANIFEST = "faceanim-batch.sqlite"
SLOW = 900  # seconds a batch subprocess may take on a loaded 2-core machine (never asserted as a speed)

FUZZ = settings(max_examples=150, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.function_scoped_fixture])


# ----------------------------------------------------------------------------------------- helpers
def write(folder: Path, name: str, text: str) -> Path:
    p = folder / name
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(text)
    return p


def touch(folder: Path, *names: str) -> None:
    for n in names:
        (folder / n).parent.mkdir(parents=True, exist_ok=True)
        (folder / n).write_text(f"# {n}\n")


def tree(folder: Path) -> dict:
    """Every file and folder under ``folder`` with its size and mtime (to prove nothing was written)."""
    out = {}
    for root, dirs, files in os.walk(folder):
        for n in dirs + files:
            p = Path(root) / n
            st_ = p.lstat()
            # a folder's mtime moves when a probe file comes and goes: what counts is what stays
            out[str(p.relative_to(folder))] = None if p.is_dir() else (st_.st_size, st_.st_mtime_ns)
    return out


def one_line_job_error(exc_info) -> str:
    msg = str(exc_info.value)
    assert isinstance(exc_info.value, FaceAnimError)
    assert "\n" not in msg and msg.strip(), repr(msg)
    return msg


def run_main(argv, capsys) -> tuple[int, str, str]:
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse refusals
        rc = exc.code
    out, err = capsys.readouterr()
    return rc, out, err


def batch(job, out, *extra, timeout=SLOW) -> subprocess.CompletedProcess:
    """``faceanim batch`` as a user runs it (its own process, so the LocalCluster is its own)."""
    return subprocess.run([sys.executable, "-m", "faceanim", "batch", str(job), "-o", str(out), *map(str, extra)],
                          capture_output=True, text=True, timeout=timeout)


def rows(out: Path) -> dict:
    """The manifest read with sqlite3 directly: output -> (state, outputs, error)."""
    db = sqlite3.connect(out / MANIFEST)
    try:
        return {o: (s, json.loads(files), e) for o, s, files, e in
                db.execute("SELECT output, state, outputs, error FROM tasks")}
    finally:
        db.close()


def stamps(paths) -> dict:
    return {str(p): (p.stat().st_mtime_ns, p.stat().st_ino) for p in paths}


def hidden_temps(folder: Path) -> list[str]:
    return sorted(str(p) for p in folder.rglob(".*") if "faceanim-" in p.name)


def save_shape(path: Path, kind: str) -> Path:
    """A small closed mesh (a few hundred triangles at most) that renders differently per kind."""
    import trimesh

    mesh = {"sphere": lambda: trimesh.creation.icosphere(subdivisions=2),
            "box": lambda: trimesh.creation.box(extents=(1.0, 1.4, 0.8)),
            "cylinder": lambda: trimesh.creation.cylinder(radius=0.6, height=1.5, sections=24),
            "cone": lambda: trimesh.creation.cone(radius=0.8, height=1.2, sections=24)}[kind]()
    path.parent.mkdir(parents=True, exist_ok=True)
    mesh.export(path)
    return path


# ============================================================ 1. job files: parsing and expansion
def test_paths_are_relative_to_the_job_files_folder(tmp_path, monkeypatch):
    touch(tmp_path, "data/m/a.obj", "data/m/b.obj", "elsewhere/data/m/zzz.obj")
    job_file = write(tmp_path, "jobs/j.yaml",
                     "operation: render\ninputs:\n  face: ../data/m/*.obj\noutput: '{face}.png'\n")
    monkeypatch.chdir(tmp_path / "elsewhere")  # a relative glob here would find zzz.obj
    job = read_job(job_file)
    assert job.base == (tmp_path / "jobs").resolve()
    got = [Path(t.input_paths["face"]).resolve() for t in expand(job)]
    assert got == [(tmp_path / "data/m/a.obj").resolve(), (tmp_path / "data/m/b.obj").resolve()]
    # an absolute path is taken as it is
    absolute = write(tmp_path, "jobs/abs.yaml", f"operation: render\ninputs:\n  face: {tmp_path / 'data/m/b.obj'}\n"
                                                "output: '{face}.png'\n")
    assert [t.input_paths["face"] for t in expand(read_job(absolute))] == [str(tmp_path / "data/m/b.obj")]


def test_globs_are_sorted_lists_keep_their_order_and_folders_are_not_inputs(tmp_path):
    for n in ("z.obj", "a.obj", "m.obj", "b10.obj", "b9.obj"):  # created out of order
        touch(tmp_path, n)
    (tmp_path / "d.obj").mkdir()  # a folder the glob matches: not a task
    job = read_job(write(tmp_path, "j.yaml", "operation: render\ninputs:\n  face: '*.obj'\noutput: '{face}.png'\n"))
    names = [Path(t.input_paths["face"]).name for t in expand(job)]
    assert names == sorted(p.name for p in tmp_path.glob("*.obj") if p.is_file())
    assert names == ["a.obj", "b10.obj", "b9.obj", "m.obj", "z.obj"]
    # a list: its entries in the file's order, each glob's matches sorted
    job = read_job(write(tmp_path, "l.yaml", "operation: render\ninputs:\n  face: [z.obj, '[ma].obj', b9.obj]\n"
                                             "output: '{face}.png'\n"))
    assert [Path(t.input_paths["face"]).name for t in expand(job)] == ["z.obj", "a.obj", "m.obj", "b9.obj"]
    assert [t.output for t in expand(job)] == ["z.png", "a.png", "m.png", "b9.png"]


def test_every_combination_with_patterns_on_earlier_inputs(tmp_path):
    touch(tmp_path, "heads/h2.obj", "heads/h1.obj", "clips/y.wav", "clips/x.wav", "clips/x.txt", "clips/y.txt",
          "clips/z.txt")
    job = read_job(write(tmp_path, "j.json", json.dumps({
        "operation": "say", "inputs": {"face": "heads/*.obj", "audio": "clips/*.wav",
                                       "transcript": "clips/{audio}.txt"},
        "options": {"fps": 25}, "output": "{face}/{audio}.mp4"})))
    assert job.operation == "say" and list(job.inputs) == ["face", "audio", "transcript"]
    tasks = expand(job)
    # the oracle: itertools.product of the sorted files, the transcript following its audio
    want = [((("face", str(tmp_path / f"heads/{h}.obj")), ("audio", str(tmp_path / f"clips/{a}.wav")),
              ("transcript", str(tmp_path / f"clips/{a}.txt"))), f"{h}/{a}.mp4")
            for h, a in itertools.product(["h1", "h2"], ["x", "y"])]
    assert [(tuple((n, str(Path(p))) for n, p in t.inputs), t.output) for t in tasks] == want


def test_dashes_and_underscores_name_the_same_input(tmp_path):
    touch(tmp_path, "n.obj", "e1.obj", "e2.obj", "t.obj")
    job = read_job(write(tmp_path, "j.yaml", "operation: transfer\ninputs:\n  source-neutral: n.obj\n"
                                             "  source_expressive: 'e*.obj'\n  target: t.obj\n"
                                             "options: {au: all}\noutput: '{target}/{source_expressive}.obj'\n"))
    assert list(job.inputs) == ["source_neutral", "source_expressive", "target"]
    assert [t.output for t in expand(job)] == ["t/e1.obj", "t/e2.obj"]


# each: (file name, text, the words the one-line error must hold, including the line it names)
JOB_ERRORS = {
    "unknown key": ("j.yaml", "operation: render\ninputs:\n  face: a.obj\nextra: 1\noutput: '{face}.png'\n",
                    ["unknown key 'extra'", "line 4"]),
    "no output": ("j.yaml", "operation: render\ninputs:\n  face: a.obj\n", ["no 'output'"]),
    "input twice": ("j.yaml", "operation: transfer\ninputs:\n  source-neutral: a.obj\n  source_neutral: b.obj\n"
                              "output: '{source_neutral}.obj'\n", ["'source_neutral'", "twice", "line 4"]),
    "glob matches nothing": ("j.yaml", "operation: render\ninputs:\n  face: 'nothing*.obj'\noutput: '{face}.png'\n",
                             ["'nothing*.obj' matches no file", "line 3"]),
    "missing file": ("j.yaml", "operation: render\ninputs:\n\n  face: nothere.obj\noutput: '{face}.png'\n",
                     ["nothere.obj", "line 4"]),
    "pattern on a later input": ("j.yaml", "operation: say\ninputs:\n  transcript: '{audio}.txt'\n  audio: a.obj\n"
                                           "output: '{audio}.mp4'\n", ["'{audio}'", "earlier input", "line 3"]),
    "pattern finds no file": ("j.yaml", "operation: say\ninputs:\n  audio: '[ab].obj'\n  transcript: '{audio}.txt'\n"
                                        "output: '{audio}.mp4'\n", ["a.txt", "line 4"]),
    "output outside": ("j.yaml", "operation: render\ninputs:\n  face: a.obj\noutput: '../{face}.png'\n",
                       ["inside the output folder", "line 4"]),
    "output absolute": ("j.yaml", "operation: render\ninputs:\n  face: a.obj\noutput: '/tmp/{face}.png'\n",
                        ["inside the output folder", "line 4"]),
    "one file for two tasks": ("j.yaml", "operation: render\ninputs:\n  face: '*.obj'\n\noutput: all.png\n",
                               ["'all.png' to 2 tasks", "line 5"]),
    "output names no input": ("j.yaml", "operation: render\ninputs:\n  face: a.obj\noutput: '{mesh}.png'\n",
                              ["'{mesh}'", "line 4"]),
    "unmatched brace": ("j.yaml", "operation: render\ninputs:\n  face: a.obj\noutput: '{face.png'\n",
                        ["unmatched brace", "line 4"]),
    "option a mapping": ("j.yaml", "operation: render\ninputs:\n  face: a.obj\noptions:\n  size: {w: 64}\n"
                                   "output: '{face}.png'\n", ["option 'size'", "line 5"]),
    "input a number": ("j.yaml", "operation: render\ninputs:\n  face: 3\noutput: '{face}.png'\n",
                       ["input 'face'", "line 3"]),
    "bad yaml": ("j.yaml", "operation: render\ninputs:\n  face: [a.obj\noutput: x.png\n", ["not valid YAML", "line 4"]),
    "bad json": ("j.json", '{"operation": "render",\n "inputs": {"face": "a.obj"},\n "output": "x.png",,\n}\n',
                 ["not valid JSON", "line 3"]),
    "yaml list": ("j.yaml", "- operation: render\n", ["must be a mapping"]),
    "empty": ("j.yaml", "", ["must be a mapping"]),
    "truncated": ("j.yaml", "operation: render\ninputs:\n  fa", ["no 'output'"]),
    "truncated in a quote": ("j.yaml", "operation: render\ninputs:\n  face: 'a.o", ["not valid YAML", "line"]),
    "not utf-8": ("j.yaml", None, ["not UTF-8"]),
    "nul byte": ("j.yaml", "operation: render\x00\ninputs:\n  face: a.obj\noutput: x.png\n", ["not valid YAML"]),
    "too big": ("j.yaml", "operation: render\ninputs:\n  face: a.obj\noutput: x.png\n" + "#" * (2 << 20) + "\n",
                ["at most 1 MiB"]),
    "deep nesting": ("j.yaml", "[" * 100_000 + "]" * 100_000, ["nests too deeply"]),
    "deep nesting json": ("j.json", "[" * 100_000 + "]" * 100_000, ["nests too deeply"]),
    "billion laughs": ("j.yaml", "operation: render\ninputs:\n  face: a.obj\noptions:\n  lol: &a [x, x, x, x, x, x, x, x]\n"
                                 + "".join(f"  l{k}: &{chr(98 + k)} [{', '.join(['*' + chr(97 + k)] * 8)}]\n"
                                           for k in range(9))
                                 + "output: x.png\n", ["option 'l0'", "line 6"]),
}


@pytest.mark.parametrize("case", list(JOB_ERRORS))
def test_job_file_errors_name_their_line(tmp_path, case):
    name, text, words = JOB_ERRORS[case]
    touch(tmp_path, "a.obj", "b.obj")
    p = tmp_path / name
    if text is None:
        p.write_bytes(b"operation: render\ninputs:\n  face: \xff\xfe.obj\noutput: x.png\n")
    else:
        p.write_text(text)

    with pytest.raises(JobError) as exc:
        expand(read_job(p))
    msg = one_line_job_error(exc)
    for w in words:
        assert w in msg, (w, msg)


def test_a_missing_job_file_or_a_folder(tmp_path):
    for p, words in ((tmp_path / "nothere.yaml", "does not exist"), (tmp_path, "is a folder")):
        with pytest.raises(JobError) as exc:
            read_job(p)
        assert words in one_line_job_error(exc)


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
def test_a_key_written_twice_is_refused(tmp_path, suffix):
    touch(tmp_path, "a.obj", "b.obj")
    text = ("operation: render\ninputs:\n  face: a.obj\n  face: b.obj\noutput: '{face}.png'\n" if suffix == ".yaml"
            else '{"operation": "render",\n "inputs": {"face": "a.obj",\n "face": "b.obj"}, "output": "{face}.png"}')
    with pytest.raises(JobError) as exc:
        read_job(write(tmp_path, "j" + suffix, text))
    assert "twice" in one_line_job_error(exc)


# format specs and conversions in a pattern: the job file is refused, one line, exit 2 (each was
# taken before, with what is said here)
FORMAT_SPECS = {
    "{face:d}.png": "ValueError from str.format escapes expand (faceanim batch: internal error, exit 1)",
    "{face:>99999999999999999999}.png": "ValueError ('Too many decimal digits') escapes expand (internal error)",
    "{face:>400}.png": "an output name longer than 255 bytes is accepted; every task then fails in the workers "
                       "(with {face:>300000000} the batch took 170 s and 4.5 GB before failing each task)",
    "{face}\x00.png": "a NUL in the output pattern is accepted; each task crashes in its worker with "
                      "ValueError('embedded null byte'), retried 3 times, Dask tracebacks on stderr, exit 1",
}


@pytest.mark.parametrize("pattern", list(FORMAT_SPECS), ids=["spec-d", "huge-width", "long-name", "nul"])
def test_output_patterns_that_cannot_name_a_file_are_refused(tmp_path, pattern):
    touch(tmp_path, "a.obj")
    job = read_job(write(tmp_path, "j.json", json.dumps({"operation": "render", "inputs": {"face": "a.obj"},
                                                          "output": pattern})))
    with pytest.raises(JobError) as exc:
        expand(job)
    assert "line" in one_line_job_error(exc)


def test_a_glob_through_symlink_loops_is_refused_in_time(tmp_path):
    loop = tmp_path / "loop"
    loop.mkdir()
    (loop / "a").symlink_to(".")
    (loop / "b").symlink_to(".")
    job = write(tmp_path, "j.yaml", "operation: render\ninputs:\n  face: 'loop/**/*.zzqq'\noutput: '{face}.png'\n")
    code = ("import sys\nfrom faceanim.batch.jobs import read_job, expand, JobError\n"
            "try:\n    expand(read_job(sys.argv[1]))\nexcept JobError as e:\n    print(e)\n    sys.exit(2)\n")
    try:
        proc = subprocess.run([sys.executable, "-c", code, str(job)], capture_output=True, text=True, timeout=30)
    except subprocess.TimeoutExpired:
        pytest.fail("expanding the glob ran for more than 30 s")
    assert proc.returncode == 2 and proc.stdout.strip() and "\n" not in proc.stdout.strip(), proc


# --------------------------------------------------------------------------- hypothesis fuzzing
def _check_read(path: Path):
    try:
        job = read_job(path)
    except FaceAnimError as exc:  # JobError is one
        assert "\n" not in str(exc) and str(exc).strip(), repr(str(exc))
        return None
    assert isinstance(job, Job)
    assert isinstance(job.operation, str) and job.operation and isinstance(job.output, str) and job.output
    assert job.inputs and all(isinstance(v, (str, list)) for v in job.inputs.values())
    return job


@FUZZ
@given(data=st.binary(max_size=3000), suffix=st.sampled_from([".yaml", ".yml", ".json", ".txt", ""]))
def test_fuzz_read_job_bytes(data, suffix):
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / f"job{suffix}"
        p.write_bytes(data)
        _check_read(p)


@FUZZ
@given(text=st.text(max_size=2000), suffix=st.sampled_from([".yaml", ".json"]))
def test_fuzz_read_job_text(text, suffix):
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / f"job{suffix}"
        p.write_text(text, encoding="utf-8", errors="surrogatepass")
        _check_read(p)


# structured job documents: the keys and values a job file holds, plus junk; expanded in a folder
# with a few files. Braces hold no ':' or '!' here (format specs are refused above) and
# no '/' starts a glob (a glob over the whole disk is the symlink-loop case above).
WORDS = ["a.obj", "b.obj", "*.obj", "[ab].obj", "?.obj", "**/*.obj", "sub/c.obj", "../a.obj", "{face}", "{a}",
         "{face}.png", "{}", "{0}", "{face[0]}", "{face.x}", "{", "}", "{{face}}", "{face}/{face}.png", "x.png",
         "render", "transfer", "au", "wires apply", "", " ", "-", "--size", "nan", "1e400", "\x00", "\u202e", "\u00e9"]
scalar = st.one_of(st.sampled_from(WORDS), st.integers(-2, 10**20), st.floats(allow_nan=True), st.booleans(),
                   st.none(), st.text(alphabet="ab.*?[]{}-_ 0", max_size=8))
value = st.recursive(scalar, lambda s: st.one_of(st.lists(s, max_size=4),
                                                 st.dictionaries(st.sampled_from(WORDS + ["face", "size"]), s,
                                                                 max_size=3)), max_leaves=12)
doc = st.dictionaries(st.sampled_from(["operation", "inputs", "options", "output", "extra", "face"]), value,
                      max_size=5)
good = st.fixed_dictionaries({"operation": st.sampled_from(["render", "au", "rendr"]),
                              "inputs": st.dictionaries(st.sampled_from(["face", "audio", "target", "landmarks"]),
                                                        st.one_of(st.sampled_from(WORDS), st.lists(
                                                            st.sampled_from(WORDS), max_size=3)), max_size=3),
                              "output": st.sampled_from(WORDS)},
                             optional={"options": st.dictionaries(st.sampled_from(["size", "au", "yaw"]), scalar,
                                                                  max_size=2)})


@FUZZ
@given(document=st.one_of(doc, good), as_json=st.booleans())
def test_fuzz_structured_job_files_expand_cleanly(document, as_json):
    import yaml

    with tempfile.TemporaryDirectory() as d:
        folder = Path(d) / "w"
        touch(folder, "a.obj", "b.obj", "sub/c.obj")
        try:
            text = json.dumps(document) if as_json else yaml.safe_dump(document, allow_unicode=True)
        except ValueError:
            return
        p = folder / ("job.json" if as_json else "job.yaml")
        p.write_text(text, encoding="utf-8", errors="surrogatepass")
        job = _check_read(p)
        if job is None:
            return
        try:
            tasks = expand(job)
        except FaceAnimError as exc:
            assert "\n" not in str(exc), repr(str(exc))
            return
        for t in tasks:
            out = Path(t.output)
            assert not out.is_absolute() and ".." not in out.parts
        assert len({t.output for t in tasks}) == len(tasks)


# =========================================== bad input to the command: one line, exit 2, nothing
RENDER = "operation: render\ninputs:\n  face: '*.obj'\noptions:\n  size: 64\noutput: '{face}.png'\n"
CLI_ERRORS = {
    "unknown operation": ("operation: rendr\ninputs:\n  face: a.obj\noutput: '{face}.png'\n", [],
                          ["unknown operation 'rendr'", "line 1"]),
    "unknown option": (RENDER.replace("size: 64", "size: 64\n  colour: red"), [], ["unknown option 'colour'", "line 6"]),
    "unknown input": ("operation: render\ninputs:\n  face: a.obj\n  mesh: b.obj\noutput: '{face}.png'\n", [],
                      ["unknown input 'mesh'", "line 4"]),
    "glob matches nothing": (RENDER.replace("'*.obj'", "'none*.obj'"), [], ["matches no file", "line 3"]),
    "output outside": (RENDER.replace("'{face}.png'", "'../{face}.png'"), [], ["inside the output folder", "line 6"]),
    "one file for two tasks": (RENDER.replace("'{face}.png'", "x.png"), [], ["to 2 tasks", "line 6"]),
    "a list for one value": (RENDER.replace("size: 64", "size: [64, 32]"), [], ["option 'size'", "one value",
                                                                                  "line 5"]),
    "a value for a switch": ("operation: au\ninputs:\n  face: a.obj\noptions:\n  halves: 3\noutput: '{face}.obj'\n", [],
                             ["option 'halves'", "switch", "line 5"]),
    "a switch for a value": (RENDER.replace("size: 64", "size: true"), [], ["option 'size'", "line 5"]),
    "required input missing": ("operation: fap play\ninputs:\n  face: a.obj\noutput: '{face}.csv'\n", [],
                               ["needs 'fap'"]),
    "suffix refused": (RENDER.replace("'{face}.png'", "'{face}.obj'"), [], ["must end in one of: .png"]),
    "bad yaml": ("operation: render\ninputs:\n  face: [a.obj\noutput: x.png\n", [], ["not valid YAML", "line 4"]),
    "empty job": ("", [], ["must be a mapping"]),
    "workers 0": (RENDER, ["--workers", "0"], ["--workers"]),
    "workers 1000": (RENDER, ["--workers", "1000"], ["--workers"]),
    "workers 1.5": (RENDER, ["--workers", "1.5"], ["--workers"]),
    "retries -1": (RENDER, ["--retries", "-1"], ["--retries"]),
    "retries 1e9": (RENDER, ["--retries", "1000000000"], ["--retries"]),
    "workers and scheduler": (RENDER, ["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], ["--workers"]),
}


@pytest.mark.parametrize("case", list(CLI_ERRORS))
def test_bad_input_to_the_command_one_line_exit_2_nothing_written(tmp_path, capsys, case):
    text, extra, words = CLI_ERRORS[case]
    save_shape(tmp_path / "a.obj", "sphere")
    save_shape(tmp_path / "b.obj", "box")
    job = write(tmp_path, "job.yaml", text)
    before = tree(tmp_path)
    rc, out, err = run_main(["batch", job, "-o", tmp_path / "out", *extra], capsys)
    assert rc == 2, (rc, out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("faceanim batch: error: "), err
    for w in words:
        assert w in lines[0], (w, lines[0])
    assert tree(tmp_path) == before, "something was written"


@pytest.mark.parametrize("change", [("size: 64", "size: 5"), ("'{face}.png'", "'{face}.obj'")], ids=["size", "suffix"])
def test_a_refused_option_value_names_its_line(tmp_path, capsys, change):
    save_shape(tmp_path / "a.obj", "sphere")
    job = write(tmp_path, "job.yaml", RENDER.replace(*change))
    rc, out, err = run_main(["batch", job, "-o", tmp_path / "out"], capsys)
    assert rc == 2 and ("line 5" in err or "line 6" in err), err


def test_the_output_folder_is_a_file_or_has_no_parent_or_holds_a_foreign_manifest(tmp_path, capsys):
    save_shape(tmp_path / "a.obj", "sphere")
    job = write(tmp_path, "job.yaml", RENDER)
    (tmp_path / "afile").write_text("mine")
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / MANIFEST).write_text("not sqlite, the user's own notes")
    for out, words in ((tmp_path / "afile", "is a file"), (tmp_path / "no" / "such", "does not exist"),
                       (foreign, "not a faceanim batch manifest")):
        before = tree(tmp_path)
        rc, _, err = run_main(["batch", job, "-o", out], capsys)
        assert rc == 2 and len(err.strip().splitlines()) == 1 and words in err, (out, err)
        assert tree(tmp_path) == before
    assert (tmp_path / "afile").read_text() == "mine"
    assert (foreign / MANIFEST).read_text() == "not sqlite, the user's own notes"


def test_an_output_folder_that_cannot_be_made(tmp_path, capsys):
    save_shape(tmp_path / "a.obj", "sphere")
    job = write(tmp_path, "job.yaml", RENDER)
    if os.geteuid() == 0:  # root writes through permissions; /proc refuses a new folder to anyone
        if not Path("/proc/self").is_dir():
            pytest.skip("no /proc to stand in for an unwritable folder")
        out = Path("/proc/faceanim-batch-test-out")
    else:
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o555)
        out = ro / "out"
    rc, _, err = run_main(["batch", job, "-o", out], capsys)
    assert rc == 2 and len(err.strip().splitlines()) == 1, err
    assert not out.exists()


# ======================================================== 2. end to end on a LocalCluster of two
def direct_render(mesh: Path, out: Path, capsys) -> bytes:
    """The oracle: the same command run directly (faceanim render MESH --size 64 -o OUT)."""
    rc, _, err = run_main(["render", mesh, "--size", "64", "-o", out], capsys)
    assert rc == 0, err
    return out.read_bytes()


def test_batch_end_to_end_matches_direct_runs_and_resumes(tmp_path, capsys):
    meshes = tmp_path / "meshes"
    for name, kind in (("a", "sphere"), ("b", "box"), ("c", "cylinder")):
        save_shape(meshes / f"{name}.obj", kind)
    job = write(tmp_path / "jobs", "render.yaml",
                "operation: render\ninputs:\n  face: ../meshes/*.obj\noptions: {size: 64}\noutput: 'png/{face}.png'\n")
    out = tmp_path / "out"
    ref = tmp_path / "ref"
    ref.mkdir()
    expected = {n: direct_render(meshes / f"{n}.obj", ref / f"{n}.png", capsys) for n in "abc"}
    assert len(set(expected.values())) == 3, "the renders must differ for the oracle to mean anything"

    # first run: three tasks, each output the direct run's bytes; the manifest has a row per task
    p = batch(job, out, "--workers", 2, "--quiet")
    assert p.returncode == 0, p.stderr
    assert "3 done, 0 skipped" in p.stdout and "0 failed" in p.stdout, p.stdout
    pngs = {n: out / "png" / f"{n}.png" for n in "abc"}
    for n, path in pngs.items():
        assert path.read_bytes() == expected[n], n
    assert rows(out) == {f"png/{n}.png": ("done", [f"png/{n}.png"], "") for n in "abc"}
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file()) == \
        [MANIFEST] + [f"png/{n}.png" for n in "abc"]

    # rerun (an input touched, its content the same): everything skipped, no cluster started, nothing rewritten
    os.utime(meshes / "a.obj", ns=(time.time_ns(), time.time_ns()))
    before = stamps(pngs.values())
    p = batch(job, out, "--workers", 2, "--quiet")
    assert p.returncode == 0, p.stderr
    assert "0 done, 3 skipped" in p.stdout and "cluster" not in p.stdout, p.stdout
    assert stamps(pngs.values()) == before

    # one input's content changes: only its task is redone, and it matches the direct run again
    save_shape(meshes / "b.obj", "cone")
    new_b = direct_render(meshes / "b.obj", ref / "b2.png", capsys)
    assert new_b != expected["b"]
    before = stamps([pngs["a"], pngs["c"]])
    p = batch(job, out, "--workers", 2, "--quiet")
    assert p.returncode == 0, p.stderr
    assert "1 done, 2 skipped" in p.stdout, p.stdout
    assert pngs["b"].read_bytes() == new_b
    assert stamps([pngs["a"], pngs["c"]]) == before

    # an output deleted: only it is redone
    pngs["c"].unlink()
    before = stamps([pngs["a"], pngs["b"]])
    p = batch(job, out, "--workers", 2, "--quiet")
    assert p.returncode == 0, p.stderr
    assert "1 done, 2 skipped" in p.stdout, p.stdout
    assert pngs["c"].read_bytes() == expected["c"]
    assert stamps([pngs["a"], pngs["b"]]) == before

    # an empty mesh among the inputs: its task fails with the direct run's one-line message, the
    # batch goes on (the others are done already and skipped), exit 1, no output for it
    (meshes / "bad.obj").write_bytes(b"")
    as_the_job_names_it = str(meshes / "bad.obj")  # the job's folder joined with its glob, normalised
    rc, _, direct_err = run_main(["render", as_the_job_names_it, "--size", "64", "-o", ref / "bad.png"], capsys)
    assert rc == 2 and not (ref / "bad.png").exists()
    message = direct_err.strip().split(": error: ", 1)[1]
    p = batch(job, out, "--workers", 2, "--quiet")
    assert p.returncode == 1, (p.stdout, p.stderr)
    assert "0 done, 3 skipped" in p.stdout and "1 failed" in p.stdout, p.stdout
    assert f"failed: png/bad.png: {message}" in p.stderr.splitlines(), p.stderr
    assert not (out / "png" / "bad.png").exists()
    got = rows(out)
    assert got["png/bad.png"] == ("failed", [], message)
    assert all(got[f"png/{n}.png"][0] == "done" for n in "abc")
    assert pngs["b"].read_bytes() == new_b and pngs["a"].read_bytes() == expected["a"]
    assert hidden_temps(out) == []


def test_the_default_face_when_no_face_is_given_is_bound_once_and_matches_direct_runs(tmp_path, capsys):
    from faceanim.cli.batch import plan
    from faceanim.face.faps import FapStream
    from faceanim.io.fapfile import write_fap

    for k, (key, peak) in enumerate((("open_jaw", 500.0), ("stretch_l_cornerlip", 300.0))):
        stream = FapStream.empty(8, 25.0)
        stream.set(key, peak * np.sin(np.linspace(0, np.pi, 8)))
        (tmp_path / "clips").mkdir(exist_ok=True)
        write_fap(tmp_path / "clips" / f"c{k}.fap", stream)
    job = write(tmp_path, "job.yaml", "operation: fap play\ninputs:\n  fap: clips/*.fap\noutput: '{fap}.csv'\n")
    out = tmp_path / "out"
    planned = plan(read_job(job), out.resolve())
    assert [t.output for t in planned] == ["c0.csv", "c1.csv"]
    # each task's faces to bind, (mesh, landmarks, forward, up): a mesh of None is the embedded default face
    faces = {tuple(t.faces) if hasattr(t, "faces") else (t.face,) for t in planned}
    assert len(faces) == 1, faces
    (keys,) = faces
    assert len(keys) == 1 and keys[0][:2] == (None, None), keys
    assert not out.exists()

    p = batch(job, out, "--workers", 2, "--quiet")
    assert p.returncode == 0, p.stderr
    assert "2 done" in p.stdout
    for k in range(2):
        rc, _, err = run_main(["fap", "play", tmp_path / "clips" / f"c{k}.fap", "-o", tmp_path / f"ref{k}.csv"], capsys)
        assert rc == 0, err
        assert (out / f"c{k}.csv").read_bytes() == (tmp_path / f"ref{k}.csv").read_bytes()
    assert (out / "c0.csv").read_bytes() != (out / "c1.csv").read_bytes()


# ========================================================== 3. the fault test: a worker is killed
def _children(pid: int) -> list[tuple[int, str]]:
    """(pid, command line) of every descendant of ``pid``: psutil if there, else /proc."""
    try:
        import psutil
    except ImportError:
        psutil = None
    if psutil is not None:
        out = []
        for c in psutil.Process(pid).children(recursive=True):
            try:
                out.append((c.pid, " ".join(c.cmdline())))
            except psutil.Error:
                pass
        return out
    parents = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
                parents[int(d.name)] = (int(stat.rsplit(")", 1)[1].split()[1]),
                                        (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace"))
            except (OSError, ValueError, IndexError):
                pass
    found, frontier = [], {pid}
    while frontier:
        kids = [(p, cmd) for p, (pp, cmd) in parents.items() if pp in frontier]
        found += kids
        frontier = {p for p, _ in kids}
    return found


def _worker_pids(pid: int) -> list[int]:
    return [p for p, cmd in _children(pid)
            if ("spawn_main" in cmd or "forkserver" in cmd or "dask" in cmd) and "resource_tracker" not in cmd]


def test_a_worker_killed_mid_batch_loses_nothing(tmp_path, capsys):
    from faceanim.face.default import default_face
    from faceanim.io.meshio import load_mesh, save_mesh

    faces = tmp_path / "faces"
    faces.mkdir()
    base = default_face()
    for k in range(10):  # ten faces (one bind each, then an AU on each: a second or two per task)
        save_mesh(base, faces / f"f{k:02d}.obj")
    job = write(tmp_path, "job.yaml", "operation: au\ninputs:\n  face: faces/f*.obj\noptions: {au: 12}\n"
                                      "output: '{face}.obj'\n")
    (tmp_path / "ref").mkdir()
    rc, _, err = run_main(["au", "--face", faces / "f00.obj", "--au", "12", "-o", tmp_path / "ref" / "ref.obj"], capsys)
    assert rc == 0, err
    ref = load_mesh(tmp_path / "ref" / "ref.obj")

    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "faceanim", "batch", str(job), "-o", str(out), "--workers", "2",
                             "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    killed = None
    try:
        deadline = time.monotonic() + SLOW
        while time.monotonic() < deadline and proc.poll() is None:
            done = [p for p in out.glob("f*.obj")] if out.is_dir() else []
            if done:
                workers = _worker_pids(proc.pid)
                if workers:
                    os.kill(workers[0], signal.SIGKILL)
                    killed = (workers[0], len(done))
                    break
            time.sleep(0.05)
        stdout, stderr = proc.communicate(timeout=SLOW)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert killed is not None, "no worker process was found to kill while the batch ran"
    assert killed[1] < 10, "the batch was over before a worker could be killed: the test proved nothing"

    assert proc.returncode == 0, (stdout, stderr)
    assert "10 done, 0 skipped" in stdout and "0 failed" in stdout, stdout
    for k in range(10):
        got = load_mesh(out / f"f{k:02d}.obj")
        np.testing.assert_array_equal(got.vertices, ref.vertices)
        np.testing.assert_array_equal(got.faces, ref.faces)
        assert (out / f"f{k:02d}.texture.png").read_bytes() == (tmp_path / "ref" / "ref.texture.png").read_bytes()
    assert {o: r[0] for o, r in rows(out).items()} == {f"f{k:02d}.obj": "done" for k in range(10)}
    assert hidden_temps(out) == []

    before = stamps(out.glob("f*"))
    p = batch(job, out, "--workers", 2, "--quiet")
    assert p.returncode == 0, p.stderr
    assert "0 done, 10 skipped" in p.stdout and "cluster" not in p.stdout, p.stdout
    assert stamps(out.glob("f*")) == before


# ================================================================ 4. a scheduler that is not there
@pytest.fixture(scope="module")
def unreachable(tmp_path_factory):
    """Two runs at once (each waits out the connect timeout): nothing listening on port 1, and an
    address that is not one."""
    tmp = tmp_path_factory.mktemp("sched")
    save_shape(tmp / "a.obj", "sphere")
    job = write(tmp, "job.yaml", RENDER)
    runs = {}
    for name, address in (("port 1", "tcp://127.0.0.1:1"), ("garbage", "garbage")):
        out = tmp / name.replace(" ", "")
        runs[name] = (out, subprocess.Popen([sys.executable, "-m", "faceanim", "batch", str(job), "-o", str(out),
                                             "--scheduler", address], stdout=subprocess.PIPE,
                                            stderr=subprocess.PIPE, text=True))
    results = {}
    for name, (out, proc) in runs.items():
        stdout, stderr = proc.communicate(timeout=SLOW)
        results[name] = (proc.returncode, stdout, stderr, out)
    return results


def test_an_unreachable_scheduler_is_one_line_and_exit_2(unreachable):
    rc, stdout, stderr, out = unreachable["port 1"]
    assert rc == 2, (stdout, stderr)
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and "tcp://127.0.0.1:1" in lines[0] and "scheduler" in lines[0], stderr


def test_an_unreachable_scheduler_writes_nothing(unreachable):
    rc, stdout, stderr, out = unreachable["port 1"]
    assert rc == 2 and not out.exists(), sorted(os.listdir(out))


def test_a_malformed_scheduler_address_is_one_line_exit_2_nothing_written(unreachable):
    rc, stdout, stderr, out = unreachable["garbage"]
    assert rc == 2, (stdout, stderr)
    assert len(stderr.strip().splitlines()) == 1, stderr
    assert not out.exists()


def test_a_file_given_as_an_option_counts_by_its_content(tmp_path):
    """A landmarks JSON under options is read relative to the job file like the inputs, and a
    change to its content redoes the task (it was in the signature by path only)."""
    from faceanim.face.default import default_face, default_landmarks
    from faceanim.io.meshio import save_mesh

    save_mesh(default_face(), tmp_path / "face.obj")
    default_landmarks().save(tmp_path / "lm.json")
    job = write(tmp_path, "job.yaml", "operation: au\ninputs:\n  face: face.obj\n"
                                      "options: {au: '12', landmarks: lm.json}\noutput: '{face}.obj'\n")
    out = tmp_path / "out"
    first = batch(job, out, "--workers", 1, "--quiet")
    assert first.returncode == 0 and "1 done" in first.stdout, (first.stdout, first.stderr)
    again = batch(job, out, "--workers", 1, "--quiet")
    assert "0 done, 1 skipped" in again.stdout, again.stdout
    with open(tmp_path / "lm.json", "a") as fh:
        fh.write("\n")  # same landmarks, other bytes: the content changed
    redone = batch(job, out, "--workers", 1, "--quiet")
    assert "1 done, 0 skipped" in redone.stdout, redone.stdout


def test_a_batch_never_writes_over_its_own_inputs(tmp_path, capsys):
    """-o the inputs' own folder with output '{face}.obj': the scans were overwritten (the review
    found it); now refused before anything runs."""
    save_shape(tmp_path / "a.obj", "sphere")
    job = write(tmp_path, "job.yaml", "operation: au\ninputs:\n  face: '*.obj'\noptions: {au: '12'}\n"
                                      "output: '{face}.obj'\n")
    before = tree(tmp_path)
    rc, _, err = run_main(["batch", job, "-o", tmp_path], capsys)
    assert rc == 2 and "would overwrite an input" in err and "line 5" in err, err
    assert tree(tmp_path) == before


def test_hidden_files_are_not_matched_by_a_plain_glob(tmp_path):
    touch(tmp_path, "a.obj", ".hidden.obj")
    (tmp_path / ".cache").mkdir()
    touch(tmp_path / ".cache", "b.obj")
    job = read_job(write(tmp_path, "j.yaml", "operation: render\ninputs:\n  face: '**/*.obj'\noutput: '{face}.png'\n"))
    assert [Path(t.input_paths["face"]).name for t in expand(job)] == ["a.obj"]
    job = read_job(write(tmp_path, "k.yaml", "operation: render\ninputs:\n  face: '.*.obj'\noutput: '{face}.png'\n"))
    assert [Path(t.input_paths["face"]).name for t in expand(job)] == [".hidden.obj"]


def test_options_are_files_only_where_the_command_takes_a_file(tmp_path, capsys):
    """A word option that happens to name a file beside the job ('12') stays a word; a file option
    that names nothing is refused with its line."""
    from faceanim.cli.batch import plan

    save_shape(tmp_path / "a.obj", "sphere")
    touch(tmp_path, "12")
    job = read_job(write(tmp_path, "j.yaml", "operation: au\ninputs:\n  face: a.obj\noptions: {au: '12'}\n"
                                             "output: '{face}.obj'\n"))
    (task,) = plan(job, tmp_path / "out")
    assert task.argv[task.argv.index("--au") + 1] == "12"
    job = write(tmp_path, "k.yaml", "operation: au\ninputs:\n  face: a.obj\noptions: {au: '12', landmarks: nope.json}\n"
                                    "output: '{face}.obj'\n")
    rc, _, err = run_main(["batch", job, "-o", tmp_path / "out"], capsys)
    assert rc == 2 and "option 'landmarks'" in err and "line 4" in err and "is not a file" in err, err


# ------------------------------------------------------------------- in this process or on a cluster


def test_a_cluster_pays_only_for_enough_work_left():
    from faceanim.batch.runner import CLUSTER_START, cluster_pays

    # two workers halve the time left: it pays once half of it exceeds the start-up and a bind
    assert not cluster_pays(0.5, 0.0, 12, 2)  # 6 s left: 3 s saved < 5 s start-up (a plain loop wins)
    assert cluster_pays(1.0, 0.0, 12, 2)  # 12 s left: 6 s saved
    assert not cluster_pays(1.0, 2.0, 12, 2)  # ...but not if every worker binds a face for 2 s again
    assert not cluster_pays(100.0, 0.0, 1, 8) and not cluster_pays(100.0, 0.0, 50, 1)  # one task, one core
    saved = lambda left, sec, n: left * sec * (1 - 1 / n)  # noqa: E731 -- the rule, written out
    for left, sec, n in itertools.product((2, 5, 40), (0.1, 0.4, 3.0), (2, 4)):
        assert cluster_pays(sec, 0.0, left, n) == (saved(left, sec, n) > CLUSTER_START)


def test_a_small_batch_runs_here_and_a_long_one_moves_the_rest_to_a_cluster(tmp_path, monkeypatch):
    from faceanim.batch import runner
    from faceanim.batch.runner import PlannedTask, run

    calls = []

    def work(argv, out_dir, bound):
        calls.append((argv[0], sorted(bound)))
        time.sleep(float(argv[1]))
        return {"state": "done", "outputs": [argv[0]], "error": "", "seconds": float(argv[1])}

    moved = {}

    def cluster_run(client, todo, *rest):
        moved["todo"] = [t.output for t in todo]

    monkeypatch.setattr(runner, "_client", lambda scheduler, workers: type("C", (), {"cluster": None,
                                                                                    "close": lambda self: None})())
    monkeypatch.setattr(runner, "_run_cluster", cluster_run)
    monkeypatch.setattr(runner.os, "cpu_count", lambda: 2)
    bound = []
    tasks = lambda sec: [PlannedTask(f"t{k}", [f"t{k}", str(sec)], ("face",), f"s{k}")  # noqa: E731
                         for k in range(8)]
    s = run(tasks(0.01), tmp_path / "small", lambda f: bound.append(f) or f, work)
    assert s.here == 8 and sorted(s.done) == [f"t{k}" for k in range(8)] and "todo" not in moved
    assert bound == ["face"] and all(b == ["face"] for _, b in calls)  # the face bound once, here
    assert rows(tmp_path / "small") == {f"t{k}": ("done", [f"t{k}"], "") for k in range(8)}
    # 1.6 s a task: after the first, 7 left x 1.6 s x 1/2 saved > 5 s of start-up -> the rest move
    s = run(tasks(1.6), tmp_path / "long", lambda f: f, work)
    assert s.here == 1 and moved["todo"] == [f"t{k}" for k in range(1, 8)]
    assert rows(tmp_path / "long") == {"t0": ("done", ["t0"], "")}
    # --workers 1: never a cluster
    moved.clear()
    s = run(tasks(1.6)[:4], tmp_path / "one", lambda f: f, work, workers=1)
    assert s.here == 4 and "todo" not in moved


def test_a_small_batch_in_this_process_matches_direct_runs(tmp_path, capsys):
    meshes = tmp_path / "meshes"
    for name, kind in (("a", "sphere"), ("b", "box")):
        save_shape(meshes / f"{name}.obj", kind)
    job = write(tmp_path, "render.yaml",
                "operation: render\ninputs:\n  face: meshes/*.obj\noptions: {size: 64}\noutput: '{face}.png'\n")
    expected = {n: direct_render(meshes / f"{n}.obj", tmp_path / f"ref-{n}.png", capsys) for n in "ab"}
    p = batch(job, tmp_path / "out", "--quiet")
    assert p.returncode == 0, p.stderr
    assert "on this process" in p.stdout and "local cluster of" not in p.stdout, p.stdout
    for n in "ab":
        assert (tmp_path / "out" / f"{n}.png").read_bytes() == expected[n]
    assert p.stderr == ""
