"""Fuzzing the readers: for every generated input, a valid result or a FaceAnimError, never another
exception; through the CLI, exit 0 or 2, and on 2 no output and no temporary file.

Generated inputs: free text and bytes, structured files with interesting tokens (NaN, inf, 1e400,
huge and negative indices, text where numbers belong) and mutations and truncations of valid files.
Each test is bounded (tens to a couple of hundred examples, no deadline).
"""

import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from faceanim.errors import FaceAnimError

# FACEANIM_FUZZ_SCALE=20 runs twenty times the examples with fresh random seeds (a deeper hunt);
# by default the examples are the same on every run (derandomized), so CI is reproducible
SCALE = max(1, int(os.environ.get("FACEANIM_FUZZ_SCALE", "1")))
FUZZ = settings(max_examples=150 * SCALE, deadline=None, derandomize=SCALE == 1, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.function_scoped_fixture])
FUZZ_CLI = settings(FUZZ, max_examples=60 * SCALE)

NUMBERS = ["0", "1", "-1", "2", "3", "0.5", "-0.0", "1e400", "-1e400", "1e308", "1e-320", "nan", "NaN", "inf",
           "-inf", "1e12", "99999999999999999999999", "-99999999999999999999", "0x10", "1_000", "", "abc",
           "\u00bd", "\u0663", "1e5", "25", "240", "241", "200000", "200001", "4294967296"]
token = st.one_of(st.sampled_from(NUMBERS), st.text(alphabet=st.characters(blacklist_categories=("Cs",)),
                                                      max_size=6))


def expect_clean(fn, *args, **kwargs):
    """Run ``fn``: any exception but a FaceAnimError fails the test; FaceAnimError messages are one line."""
    try:
        return fn(*args, **kwargs)
    except FaceAnimError as exc:
        assert "\n" not in str(exc), str(exc)
        return None


def mutate(data: bytes, draw) -> bytes:
    """Delete, insert, replace or duplicate a few bytes, or truncate."""
    b = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["del", "ins", "rep", "trunc", "dup"]))
        i = draw(st.integers(0, max(len(b) - 1, 0)))
        if op == "del" and b:
            del b[i:i + draw(st.integers(1, 8))]
        elif op == "ins":
            b[i:i] = draw(st.sampled_from([b"\0", b"\xff", b"-", b"9999999999", b"nan", b"\n", b" ", b"/", b"e400",
                                          b"f 1\n", b"v 1 2\n", b"#", b"\r", b"0 0 0 0"]))
        elif op == "rep" and b:
            b[i] = draw(st.integers(0, 255))
        elif op == "trunc":
            b = b[:i]
        elif op == "dup" and b:
            j = draw(st.integers(i, len(b)))
            b[j:j] = b[i:j]
    return bytes(b)


@st.composite
def mutated(draw, source):
    return mutate(source() if callable(source) else source, draw)


@pytest.fixture(scope="module")
def folder():
    with tempfile.TemporaryDirectory() as d:
        yield Path(d)


# ====================================================================== .fap
def _valid_fap() -> str:
    from faceanim.drivers.mpeg4 import FapStream
    from faceanim.io.fapfile import format_fap

    s = FapStream.empty(3, fps=25, name="fuzz")
    s.mask[:, [0, 1, 2, 47]] = True
    s.values[:, 2] = [10, -20, 30]
    s.values[:, 47] = 100
    s.viseme[:] = [1, 2, 30, 1]
    s.expression[:] = [1, 40, 2, 10, 0, 1]
    return format_fap(s)


@st.composite
def fap_texts(draw):
    kind = draw(st.sampled_from(["free", "structured", "mutated"]))
    if kind == "free":
        return draw(st.text(max_size=600))
    if kind == "mutated":
        return mutate(_valid_fap().encode(), draw).decode("utf-8", errors="replace")
    count = draw(st.integers(0, 3))
    header = " ".join([draw(st.sampled_from(["2.1", "1", "x"])), draw(st.text(max_size=5)) or "n",
                       draw(token), draw(st.sampled_from([str(count), *NUMBERS]))])
    lines = [header]
    for _ in range(draw(st.integers(0, 4))):
        bits = draw(st.lists(st.sampled_from(["0", "1", "2", "x"]), min_size=66, max_size=70))
        lines.append(" ".join(bits))
        lines.append(" ".join(draw(st.lists(token, max_size=12))))
    return "\n".join(lines) + draw(st.sampled_from(["", "\n", "\r\n", "\x00"]))


@FUZZ
@given(fap_texts())
def test_fuzz_parse_fap(text):
    from faceanim.io.fapfile import parse_fap

    s = expect_clean(parse_fap, text, "fuzz.fap")
    if s is not None:
        assert 1 <= s.n_frames <= 200_000 and 0 < s.fps <= 240 and np.isfinite(s.values).all()


@FUZZ
@given(st.one_of(st.binary(max_size=400), st.just(b""), mutated(lambda: _valid_fap().encode())))
def test_fuzz_read_fap_bytes(folder, data):
    from faceanim.io.fapfile import read_fap

    p = folder / "fuzz.fap"
    p.write_bytes(data)
    expect_clean(read_fap, p)


# ====================================================================== OBJ
VALID_OBJ = ("# a quad and a triangle\nmtllib none.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0.5 2 0.1\n"
             "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvt 0.5 1\nf 1/1 2/2 3/3 4/4\nf -2/-2 -3/-3 5/5\n")
OBJ_TOKENS = st.one_of(st.sampled_from(["1", "2", "3", "-1", "-4", "0", "6", "9999999999999999999999", "1/1",
                                        "1//1", "1/2/3/4", "/", "1/x", "-99", "2/-1", "3/0"]), token)


@st.composite
def obj_texts(draw):
    kind = draw(st.sampled_from(["structured", "mutated", "free"]))
    if kind == "free":
        return draw(st.binary(max_size=300))
    if kind == "mutated":
        return mutate(VALID_OBJ.encode(), draw)
    lines = []
    for _ in range(draw(st.integers(0, 12))):
        key = draw(st.sampled_from(["v", "vt", "f", "f", "vn", "g", "usemtl", "mtllib", "#", "o", "s", "l"]))
        parts = draw(st.lists(OBJ_TOKENS if key == "f" else token, max_size=5))
        lines.append(" ".join([key, *parts]))
    return ("\n".join(lines) + "\n").encode("utf-8", errors="replace")


@FUZZ
@given(obj_texts())
def test_fuzz_load_obj(folder, data):
    from faceanim.io.meshio import load_mesh

    p = folder / "fuzz.obj"
    p.write_bytes(data)
    m = expect_clean(load_mesh, p)
    if m is not None:
        assert np.isfinite(m.vertices).all() and m.faces.min() >= 0 and m.faces.max() < m.n_vertices
        if m.uv is not None:
            assert np.isfinite(m.uv).all() and m.face_uv.max() < len(m.uv)


@st.composite
def other_mesh_files(draw):
    suffix = draw(st.sampled_from([".ply", ".glb", ".gltf"]))
    return suffix, mutate(_valid_mesh_bytes(suffix), draw) if draw(st.booleans()) else draw(st.binary(max_size=300))


_MESH_BYTES: dict[str, bytes] = {}


def _valid_mesh_bytes(suffix: str) -> bytes:
    if suffix not in _MESH_BYTES:
        from faceanim.io.meshio import save_mesh

        m = _small_mesh()
        with tempfile.TemporaryDirectory() as d:
            if suffix == ".gltf":
                _MESH_BYTES[suffix] = json.dumps({"asset": {"version": "2.0"}, "meshes": [{"primitives": [
                    {"attributes": {"POSITION": 0}}]}], "accessors": [{"count": 3, "type": "VEC3",
                                                                      "componentType": 5126}]}).encode()
            else:
                save_mesh(m, Path(d) / f"m{suffix}")
                _MESH_BYTES[suffix] = (Path(d) / f"m{suffix}").read_bytes()
    return _MESH_BYTES[suffix]


def _small_mesh():
    from faceanim.face.mesh import Mesh

    n = 4
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    v = np.c_[x.ravel(), y.ravel(), 0.1 * np.sin(3 * x.ravel())]
    f = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            f += [[a, a + 1, a + n + 1], [a, a + n + 1, a + n]]
    return Mesh(v, np.array(f), uv=v[:, :2], name="grid")


@settings(FUZZ, max_examples=100 * SCALE)
@given(other_mesh_files())
def test_fuzz_load_ply_glb(folder, case):
    from faceanim.io.meshio import load_mesh

    suffix, data = case
    p = folder / f"fuzz{suffix}"
    p.write_bytes(data)
    m = expect_clean(load_mesh, p)
    if m is not None:
        assert np.isfinite(m.vertices).all()


# ====================================================================== handle files
json_leaf = st.one_of(st.none(), st.booleans(), st.integers(-10**20, 10**20),
                      st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8),
                      st.sampled_from([0, -1, 1, 0.5, 1e6, 1e300, "rbf", "gde", "multiquadric", "euclidean"]))
json_value = st.recursive(json_leaf, lambda c: st.lists(c, max_size=5) | st.dictionaries(st.text(max_size=6), c,
                                                                                         max_size=4),
                          max_leaves=16)


@pytest.fixture(scope="module")
def small_face():
    from faceanim.face.default import default_face

    return default_face()


def _valid_specs(face):
    v = face.vertices
    return [
        {"method": "rbf", "handles": v[[1, 61, 291, 152, 10]].tolist(), "offsets": [[0, -0.01, 0]] * 5,
         "kernel": "thin_plate_spline", "smoothing": 0.0, "degree": 1},
        {"method": "gde", "elements": [{"control": v[152].tolist(), "offset": [0, -0.01, 0], "extent": 3,
                                        "metric": "edges", "max_anchors": 20, "name": "chin"},
                                       {"control": v[61].tolist(), "offset": [0.01, 0, 0], "extent": 0.02,
                                        "metric": "euclidean", "smoothing": 0.01}]},
        {"method": "gde", "elements": [{"pick": [0.5, 0.6], "offset": [0, 0, 0.01], "extent": 2}]},
    ]


NUMBER_VALUES = st.one_of(st.sampled_from([0, -1, 1, 2, 3, 477, 478, 1000, 1001, 10**6, 10**12, 2**63, -2**63, 0.0,
                                            -0.0, 1e-300, 5e-324, 0.5, 1.5, 1e6, 1e7, 1e300, -1e300,
                                            float("nan"), float("inf"), -float("inf")]),
                          st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**30, 10**30))


def _get(obj, path):
    for k in path:
        obj = obj[k]
    return obj


def _paths(obj, prefix=()):
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _paths(v, prefix + (i,))


@st.composite
def handle_specs(draw, face):
    if draw(st.integers(0, 4)) == 0:
        return draw(json_value)
    spec = json.loads(json.dumps(draw(st.sampled_from(_valid_specs(face)))))
    for _ in range(draw(st.integers(1, 3))):
        paths = [p for p in _paths(spec) if p]
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent = spec
        for k in path[:-1]:
            parent = parent[k]
        op = draw(st.sampled_from(["number", "number", "replace", "delete", "add"]))
        if op == "number":
            numeric = [p for p in paths if isinstance(_get(spec, p), (int, float)) and not isinstance(_get(spec, p), bool)]
            if numeric:
                path = draw(st.sampled_from(numeric))
                parent = _get(spec, path[:-1])
                parent[path[-1]] = draw(NUMBER_VALUES)
        elif op == "replace":
            parent[path[-1]] = draw(json_value)
        elif op == "delete":
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent[draw(st.sampled_from(["pick", "control", "extra", "kernel", "max_anchors"]))] = draw(json_value)
        else:
            parent.append(draw(json_value))
    return spec


@settings(FUZZ, max_examples=200 * SCALE)
@given(st.data())
def test_fuzz_load_handles(small_face, data):
    from faceanim.deform.handles import load_handles

    spec = data.draw(handle_specs(small_face))
    result = expect_clean(load_handles, spec, small_face)
    if result is not None:
        deformer, offsets = result
        assert np.isfinite(deformer.apply(offsets)).all()


# ====================================================================== landmark files
@st.composite
def landmark_dicts(draw):
    if draw(st.integers(0, 4)) == 0:
        return draw(json_value)
    points = [{"name": "nose_tip", "index": 4, "position": [0.0, 0.1, 0.2], "triangle": 3,
               "barycentric": [0.2, 0.3, 0.5]},
              {"position": [0.1, 0.0, 0.0]}, {"index": 152, "position": [0, -1, 0]}]
    spec = {"scheme": draw(st.sampled_from(["mediapipe478", "basic22", "custom"])), "points": points,
            "detected_on": "x.obj"}
    for _ in range(draw(st.integers(1, 3))):
        paths = [p for p in _paths(spec) if p]
        path = draw(st.sampled_from(paths))
        parent = spec
        for k in path[:-1]:
            parent = parent[k]
        op = draw(st.sampled_from(["number", "replace", "delete", "dup"]))
        if op == "number":
            numeric = [p for p in paths if isinstance(_get(spec, p), (int, float)) and not isinstance(_get(spec, p), bool)]
            if numeric:
                path = draw(st.sampled_from(numeric))
                _get(spec, path[:-1])[path[-1]] = draw(NUMBER_VALUES)
        elif op == "replace":
            parent[path[-1]] = draw(json_value)
        elif op == "delete":
            del parent[path[-1]]
        elif isinstance(parent, list):
            parent.append(json.loads(json.dumps(parent[path[-1]])))
    return spec


@settings(FUZZ, max_examples=200 * SCALE)
@given(landmark_dicts())
def test_fuzz_landmarks_from_dict(small_face, spec):
    from faceanim.face.landmarks import Landmarks

    lm = expect_clean(Landmarks.from_dict, spec, "fuzz.json")
    if lm is not None:
        snapped = expect_clean(lm.attached_to, small_face)
        if snapped is not None:
            assert np.isfinite(snapped.positions).all()
        assert np.isfinite(lm.positions).all() and len(set(lm.names)) == len(lm)
        assert len({i for i in lm.indices if i >= 0}) == (lm.indices >= 0).sum()


@FUZZ
@given(st.one_of(landmark_dicts().map(lambda d: json.dumps(d).encode()),
                 mutated(json.dumps({"points": [{"index": 4, "position": [0, 1, 2]}]}).encode())))
def test_fuzz_landmarks_load(folder, data):
    from faceanim.face.landmarks import Landmarks

    p = folder / "lm.json"
    p.write_bytes(data)
    expect_clean(Landmarks.load, p)


# ====================================================================== through the CLI
def _run_cli(argv, work: Path, output: Path, inputs: set[str]):
    from faceanim.cli import main

    code = main(argv)
    assert code in (0, 2), f"exit {code} for {argv}"
    left = set(os.listdir(work)) - inputs
    if code == 2:
        assert left == set(), f"files left after an error: {left}"
    else:
        assert output.exists()
        assert not [n for n in left if ".faceanim-" in n], left
        for name in left:  # clean up for the next example
            (work / name).unlink()
    return code


@pytest.fixture(scope="module")
def face_obj(folder, small_face):
    from faceanim.io.meshio import save_mesh

    src = folder / "src"
    src.mkdir()
    save_mesh(small_face, src / "face.obj")
    return src / "face.obj"


CLI_COUNTS = {"deform": [0, 0], "obj": [0, 0], "landmarks": [0, 0], "fap": [0, 0]}


@FUZZ_CLI
@given(st.data())
def test_fuzz_cli_deform_handles(face_obj, small_face, data):
    spec = data.draw(handle_specs(small_face))
    with tempfile.TemporaryDirectory() as d:
        work = Path(d)
        (work / "h.json").write_text(json.dumps(spec))
        out = work / "out.obj"
        code = _run_cli(["deform", str(face_obj), "--handles", str(work / "h.json"), "-o", str(out)], work, out,
                        {"h.json"})
    CLI_COUNTS["deform"][code == 2] += 1


@FUZZ_CLI
@given(obj_texts())
def test_fuzz_cli_deform_obj(data):
    with tempfile.TemporaryDirectory() as d:
        work = Path(d)
        (work / "in.obj").write_bytes(data)
        (work / "h.json").write_text(json.dumps({"method": "rbf", "handles": [[0, 0, 0], [1, 0, 0], [0, 1, 0]],
                                                 "offsets": [[0, 0, 0.1], [0, 0, 0], [0, 0, 0]]}))
        out = work / "out.ply"
        code = _run_cli(["deform", str(work / "in.obj"), "--handles", str(work / "h.json"), "-o", str(out)], work,
                        out, {"in.obj", "h.json"})
    CLI_COUNTS["obj"][code == 2] += 1


@FUZZ_CLI
@given(landmark_dicts())
def test_fuzz_cli_landmarks_from(face_obj, spec):
    with tempfile.TemporaryDirectory() as d:
        work = Path(d)
        (work / "lm.json").write_text(json.dumps(spec))
        out = work / "out.json"
        code = _run_cli(["landmarks", str(face_obj), "--from", str(work / "lm.json"), "-o", str(out)], work, out,
                        {"lm.json"})
    CLI_COUNTS["landmarks"][code == 2] += 1


@settings(FUZZ, max_examples=30 * SCALE)
@given(fap_texts())
def test_fuzz_cli_fap_play(text):
    with tempfile.TemporaryDirectory() as d:
        work = Path(d)
        (work / "in.fap").write_text(text, encoding="utf-8", errors="surrogateescape")
        out = work / "out.glb"
        code = _run_cli(["fap", "play", str(work / "in.fap"), "-o", str(out)], work, out, {"in.fap"})
    CLI_COUNTS["fap"][code == 2] += 1


def test_fuzz_sanity():
    assert math.isinf(float("1e400"))  # the token set means what it says
