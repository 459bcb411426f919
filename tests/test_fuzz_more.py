"""Fuzzing the readers that tests/test_fuzz_readers.py does not cover: wire templates
(``WireTemplate.from_dict`` / ``.load``), wire edits (``parse_edits``), the average face model
(``AverageFace.load``), audio (``read_audio``) and transcripts (``read_text``).

Property: a valid result or a :class:`~faceanim.errors.FaceAnimError` (one line), never another
exception. "Valid" is checked, not assumed: a template that loads must rebuild to finite vertices
(or refuse with a FaceAnimError), edits must be finite and in range, an average face must have the
shapes the preprocessing uses, audio must be finite mono samples at a sane rate.

Bounded: at most 100 examples per test, no deadline, derandomized (the same examples on every run).
Each bug these fuzzers found (all fixed in 5ba2598) also has a plain regression case below, and the
fuzz tests start from those inputs (``@example``).
"""

import copy
import io
import json
import math
import tempfile
import zipfile
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from faceanim.errors import FaceAnimError

FUZZ = settings(max_examples=100, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.function_scoped_fixture])


def clean(fn, *args, **kwargs):
    """``fn(*args)``, or None when it raised a one-line FaceAnimError; any other exception propagates."""
    try:
        return fn(*args, **kwargs)
    except FaceAnimError as exc:
        assert "\n" not in str(exc), str(exc)
        return None


# hostile JSON values: what a damaged or hand-edited file holds where numbers, lists or names belong
HOSTILE = [None, True, False, 0, -1, 1, 2.5, -3.7, 1e300, -1e300, 10**30, -(10**30), float("nan"), float("inf"),
           float("-inf"), "", "x", "nan", "1e999", [], [1], [1, 2], [[1, 2, 3]], [None, None, None],
           [[0, 0], [1]], {}, {"a": 1}, [float("nan")] * 3, [1e300] * 3, ["nose", "upper"], ["mouth", "middle"]]
hostile = st.sampled_from(HOSTILE)
json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-10**20, 10**20),
              st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8)),
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=6), inner, max_size=4)),
    max_leaves=12)


def _replace_at(data, path, value):
    """A deep copy of ``data`` with the item at ``path`` (a list of keys / indices) replaced, or
    deleted when ``value`` is the DELETE marker."""
    out = copy.deepcopy(data)
    node = out
    for k in path[:-1]:
        node = node[k]
    if value is DELETE:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return out


DELETE = object()


def _paths(data, prefix=()):
    """Every path into a JSON-like value (dict keys and list indices)."""
    yield prefix
    if isinstance(data, dict):
        for k, v in data.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(data, list):
        for i, v in enumerate(data[:2]):  # the first items of long lists are enough
            yield from _paths(v, prefix + (i,))


@st.composite
def mutated_json(draw, valid):
    """``valid`` with one to three items replaced by hostile values (or deleted)."""
    data = valid
    for _ in range(draw(st.integers(1, 3))):
        paths = [p for p in _paths(data) if p]
        keyed = [p for p in paths if isinstance(p[-1], str)]
        if not paths:
            break
        # mostly a named field (n_vertices, k, side, scale ...), sometimes any item
        path = draw(st.sampled_from(keyed if keyed and draw(st.integers(0, 9)) < 7 else paths))
        value = draw(st.one_of(hostile, json_values, st.just(DELETE)))
        try:
            data = _replace_at(data, list(path), value)
        except (KeyError, IndexError, TypeError):
            pass
    return data


@st.composite
def mutated_bytes(draw, valid: bytes, header: int | None = None):
    """Truncation, byte flips (anywhere, or within the first ``header`` bytes), deletions, insertions."""
    b = bytearray(valid)
    op = draw(st.sampled_from(["truncate", "flip", "flip", "delete", "insert"]))
    if op == "truncate":
        return bytes(b[:draw(st.integers(0, max(len(b) - 1, 0)))])
    for _ in range(draw(st.integers(1, 8))):
        hi = min(len(b), header) if header else len(b)
        if not b:
            break
        i = draw(st.integers(0, hi - 1))
        if op == "flip":
            b[i] ^= draw(st.integers(1, 255))
        elif op == "delete":
            del b[i:i + draw(st.integers(1, 16))]
        else:
            b[i:i] = draw(st.sampled_from([b"\0", b"\xff" * 4, b"\x7f\xff\xff\xff", b"9999", b"nan", b"{", b"]"]))
    return bytes(b)


@pytest.fixture(scope="module")
def folder():
    with tempfile.TemporaryDirectory() as d:
        yield Path(d)


_counter = iter(range(10**9))


def write(folder: Path, data: bytes, suffix: str) -> Path:
    p = folder / f"f{next(_counter)}{suffix}"
    p.write_bytes(data)
    return p


# ====================================================================== wire templates and edits
@pytest.fixture(scope="module")
def wire_base():
    """The default face (a whole head), its landmarks, the default wires and a valid template on them
    (each wire's control points moved a little, scales not 1)."""
    from faceanim.face.default import default_face, default_landmarks
    from faceanim.rig.wires import WireTemplate, default_wires

    base = default_face()
    lm = default_landmarks(base).positions
    wireset = default_wires(lm)
    rng = np.random.default_rng(5)
    controls = [w.reference.control + rng.normal(scale=1e-3, size=w.reference.control.shape) for w in wireset.wires]
    template = WireTemplate(wireset, controls, np.linspace(0.9, 1.1, len(wireset.wires)), base.n_vertices,
                            {"template": "fuzz"})
    bound = wireset.influence(base, lm)
    return base, lm, template, bound


def _check_template(t, base, lm):
    """A template that loaded must rebuild on its base to finite vertices, or refuse cleanly."""
    from faceanim.rig.wires import WireTemplate

    assert isinstance(t, WireTemplate)
    v = clean(t.rebuild, base, lm478=lm)
    if v is not None:
        assert v.shape == base.vertices.shape and np.all(np.isfinite(v)), "a loaded template rebuilds to garbage"


def _valid_template_dict(wire_base):
    return wire_base[2].to_dict()


def test_the_valid_template_round_trips(wire_base):
    from faceanim.rig.wires import WireTemplate

    base, lm, template, _ = wire_base
    t = WireTemplate.from_dict(json.loads(json.dumps(template.to_dict())))
    assert np.allclose(t.rebuild(base, lm478=lm), template.rebuild(base, lm478=lm), atol=1e-8)


@FUZZ
@given(data=st.data())
@example(data=None)  # the known failures first (see test_wire_template_regressions)
def test_fuzz_wire_template_from_dict(wire_base, data):
    from faceanim.rig.wires import WireTemplate

    base, lm, _, _ = wire_base
    valid = _valid_template_dict(wire_base)
    if data is None:
        specs = [_replace_at(valid, ["n_vertices"], float("inf")),
                 _replace_at(valid, ["wires", 0, "side"], ["nose", "upper"])]
    else:
        specs = [data.draw(st.one_of(mutated_json(valid), json_values), label="spec")]
    for spec in specs:
        t = clean(WireTemplate.from_dict, spec)
        if t is not None:
            _check_template(t, base, lm)


@FUZZ
@given(data=st.data())
def test_fuzz_wire_template_load_bytes(wire_base, folder, data):
    """Random bytes, truncations and byte-level damage of a valid .wires.json file."""
    from faceanim.rig.wires import WireTemplate

    base, lm, _, _ = wire_base
    valid = json.dumps(_valid_template_dict(wire_base)).encode()
    raw = data.draw(st.one_of(st.binary(max_size=300), mutated_bytes(valid)), label="bytes")
    t = clean(WireTemplate.load, write(folder, raw, ".wires.json"))
    if t is not None:
        _check_template(t, base, lm)


_VALID_EDITS = {"edits": [{"wire": "upper_lip", "control": 3, "offset": [0, 0.002, 0]},
                          {"wire": "brow_L", "scale": 1.2},
                          {"wire": "lower_lip", "control": 0, "offset": [0.001, 0, 0], "scale": 0.9}]}


def _check_edits(result, wire_base):
    from faceanim.rig.wires import edit_template

    base, _lm, template, bound = wire_base
    moves, scales = result
    names = template.wireset.names
    for j, items in moves.items():
        assert 0 <= j < len(names)
        for i, off in items:
            assert isinstance(i, int) and 0 <= i < template.wireset.wires[j].reference.n_control
            assert np.shape(off) == (3,) and np.all(np.isfinite(off))
    for j, s in scales.items():
        assert 0 <= j < len(names) and math.isfinite(s)
    edited = edit_template(template, moves, scales)
    v = clean(edited.rebuild, base, bound)
    if v is not None:
        assert np.all(np.isfinite(v)), "accepted edits rebuild to garbage"


@FUZZ
@given(spec=st.one_of(mutated_json(_VALID_EDITS), json_values))
@example(spec={"edits": [{"wire": "brow_L", "scale": [1]}]})
def test_fuzz_parse_edits(wire_base, spec):
    from faceanim.rig.wires import parse_edits

    result = clean(parse_edits, spec, wire_base[2].wireset)
    if result is not None:
        _check_edits(result, wire_base)


def test_the_valid_edits_parse(wire_base):
    from faceanim.rig.wires import parse_edits

    moves, scales = parse_edits(_VALID_EDITS, wire_base[2].wireset)
    _check_edits((moves, scales), wire_base)
    assert len(moves) == 2 and len(scales) == 2


# each bug the fuzzers found, as one plain regression case
_BAD_EDITS = {
    "scale_list": {"wire": "brow_L", "scale": [1]},
    "scale_null": {"wire": "brow_L", "scale": None},
    "control_text": {"wire": "brow_L", "control": "x", "offset": [0, 0, 0]},
    "control_null": {"wire": "brow_L", "control": None, "offset": [0, 0, 0]},
    "control_infinity": {"wire": "brow_L", "control": float("inf"), "offset": [0, 0, 0]},
    "control_fraction": {"wire": "brow_L", "control": 1.9, "offset": [0, 0, 0]},
    "control_true": {"wire": "brow_L", "control": True, "offset": [0, 0, 0]},
    "offset_text": {"wire": "brow_L", "control": 1, "offset": "abc"},
    "offset_ragged": {"wire": "brow_L", "control": 1, "offset": [[1, 2], [3]]},
    "scale_1e300": {"wire": "brow_L", "scale": 1e300},
}


@pytest.mark.parametrize("name", list(_BAD_EDITS))
def test_bad_edit_is_refused(wire_base, name):
    from faceanim.rig.wires import edit_template, parse_edits

    base, _lm, template, bound = wire_base
    with pytest.raises(FaceAnimError):
        moves, scales = parse_edits({"edits": [_BAD_EDITS[name]]}, template.wireset)
        v = edit_template(template, moves, scales).rebuild(base, bound)
        if not np.all(np.isfinite(v)):
            raise AssertionError("rebuilt to non-finite vertices")  # not a FaceAnimError: the case fails


_BAD_TEMPLATES = {
    "n_vertices_infinity": (["n_vertices"], float("inf")),
    "side_unknown_slit": (["wires", 0, "side"], ["nose", "upper"]),
    "side_slit_is_a_list": (["wires", 0, "side"], [[], None]),
    "duplicate_wire_name": (["wires", 1, "name"], "brow_R"),
}
_STILL_FAILING: dict[str, str] = {}  # name -> reason, for cases found failing and not yet fixed


@pytest.mark.parametrize("name", [pytest.param(n, marks=[pytest.mark.xfail(strict=True, reason=_STILL_FAILING[n])]
                                               if n in _STILL_FAILING else []) for n in _BAD_TEMPLATES])
def test_bad_template_is_refused(wire_base, name):
    from faceanim.rig.wires import WireTemplate

    base, lm, _, _ = wire_base
    path, value = _BAD_TEMPLATES[name]
    spec = _replace_at(_valid_template_dict(wire_base), path, value)
    with pytest.raises(FaceAnimError):
        WireTemplate.from_dict(spec).rebuild(base, lm478=lm)


# ====================================================================== the average face model
def _valid_npz() -> bytes:
    return resources.files("faceanim").joinpath("assets", "average_face.npz").read_bytes()


def _check_average_face(ref):
    from faceanim.build.preprocess import AverageFace

    assert isinstance(ref, AverageFace)
    x, y, depth, lm = (np.asarray(a) for a in (ref.x, ref.y, ref.depth, ref.landmarks))
    assert x.ndim == 1 and y.ndim == 1 and len(x) >= 2 and len(y) >= 2, "grid axes must be 1-D"
    assert np.all(np.isfinite(x)) and np.all(np.isfinite(y))
    assert depth.shape == (len(y), len(x)), "depth must be len(y) x len(x)"
    assert lm.shape == (478, 3) and lm.dtype.kind == "f" and np.all(np.isfinite(lm)), "landmarks (478, 3), finite"


def _npz(**arrays) -> bytes:
    b = io.BytesIO()
    np.savez(b, **arrays)
    return b.getvalue()


def test_the_valid_average_face_loads(folder):
    from faceanim.build.preprocess import AverageFace

    _check_average_face(AverageFace.load(write(folder, _valid_npz(), ".npz")))


@FUZZ
@given(data=st.data())
@example(data=None)
def test_fuzz_average_face_load_bytes(folder, data):
    from faceanim.build.preprocess import AverageFace

    valid = _valid_npz()
    raw = valid[: len(valid) // 2] if data is None else data.draw(
        st.one_of(st.binary(max_size=300), mutated_bytes(valid)), label="bytes")
    ref = clean(AverageFace.load, write(folder, raw, ".npz"))
    if ref is not None:
        _check_average_face(ref)


_ARRAYS = {
    "x": [np.zeros(0), np.zeros((2, 2)), np.array([np.nan, 1.0]), np.array(["a", "b"]), np.linspace(0, 1, 150)],
    "y": [np.zeros(1), np.full(150, np.inf), np.linspace(1, 0, 150)],
    "depth": [np.zeros(5), np.zeros((3, 3)), np.full((150, 150), np.nan), np.zeros((150, 150))],
    "landmarks": [np.zeros(3), np.zeros((477, 3)), np.full((478, 3), np.nan), np.zeros((478, 3), dtype=np.int8),
                  np.array(["x"] * 3), np.zeros((478, 3)) + 1e300],
    "sources": [np.array([]), np.array([1, 2]), np.array(["a"])],
}


@FUZZ
@given(data=st.data())
@example(data=None)
def test_fuzz_average_face_arrays(folder, data):
    from faceanim.build.preprocess import AverageFace

    valid = dict(np.load(io.BytesIO(_valid_npz())))
    if data is None:
        arrays = dict(valid, landmarks=np.zeros(3))
    else:
        arrays = dict(valid)
        for key in data.draw(st.lists(st.sampled_from(sorted(_ARRAYS)), min_size=1, max_size=3, unique=True)):
            if data.draw(st.booleans(), label=f"drop {key}") and key != "x":
                arrays.pop(key)
            else:
                arrays[key] = data.draw(st.sampled_from(_ARRAYS[key]), label=key)
    ref = clean(AverageFace.load, write(folder, _npz(**arrays), ".npz"))
    if ref is not None:
        _check_average_face(ref)


@pytest.mark.parametrize("name", ["truncated", "npy_not_npz", "bad_crc", "landmarks_shape", "landmarks_nan"])
def test_bad_average_face_is_refused(folder, name):
    from faceanim.build.preprocess import AverageFace

    valid = _valid_npz()
    if name == "truncated":
        raw = valid[: len(valid) // 2]
    elif name == "npy_not_npz":
        b = io.BytesIO()
        np.save(b, np.ones(3))
        raw = b.getvalue()
    elif name == "bad_crc":
        # flip one byte inside the compressed data of the first member
        with zipfile.ZipFile(io.BytesIO(valid)) as z:
            info = z.infolist()[0]
        at = info.header_offset + 30 + len(info.filename) + len(info.extra) + info.compress_size // 2
        b = bytearray(valid)
        b[at] ^= 0x55
        raw = bytes(b)
    else:
        arrays = dict(np.load(io.BytesIO(valid)))
        arrays["landmarks"] = np.zeros(3) if name == "landmarks_shape" else np.full((478, 3), np.nan)
        raw = _npz(**arrays)
    with pytest.raises(FaceAnimError):
        _check_average_face(AverageFace.load(write(folder, raw, ".npz")))


# ====================================================================== audio
@pytest.fixture(scope="module")
def sounds():
    """Valid short sound files: 16-bit WAV, float WAV, 24-bit FLAC and OGG Vorbis (0.2 s)."""
    sf = pytest.importorskip("soundfile")
    x = (0.3 * np.sin(np.arange(3200) / 7.0)).astype(np.float32)
    out = {}
    for name, kw in {".wav": {"format": "WAV", "subtype": "PCM_16"}, "-float.wav": {"format": "WAV", "subtype": "FLOAT"},
                     ".flac": {"format": "FLAC", "subtype": "PCM_24"}, ".ogg": {"format": "OGG", "subtype": "VORBIS"}}.items():
        b = io.BytesIO()
        sf.write(b, x, 16000, **kw)
        out[name] = b.getvalue()
    return out


def _check_audio(result):
    from faceanim.limits import MAX_SAMPLE_RATE

    samples, rate = result
    assert isinstance(rate, int) and 1 <= rate <= MAX_SAMPLE_RATE
    assert samples.ndim == 1 and samples.dtype == np.float32 and samples.size > 0
    assert np.all(np.isfinite(samples))


@FUZZ
@given(data=st.data())
def test_fuzz_read_audio(folder, sounds, data):
    from faceanim.io.audio import read_audio

    name = data.draw(st.sampled_from(sorted(sounds)), label="format")
    suffix = ".wav" if name.endswith(".wav") else name
    valid = sounds[name]
    raw = data.draw(st.one_of(st.binary(max_size=200), mutated_bytes(valid), mutated_bytes(valid, header=64)),
                    label="bytes")
    result = clean(read_audio, write(folder, raw, suffix))
    if result is not None:
        _check_audio(result)


def test_the_valid_sounds_read(folder, sounds):
    from faceanim.io.audio import read_audio

    for name, raw in sounds.items():
        _check_audio(read_audio(write(folder, raw, ".wav" if name.endswith(".wav") else name)))


# ====================================================================== transcripts
@FUZZ
@given(raw=st.one_of(st.binary(max_size=300), st.text(max_size=100).map(lambda s: s.encode("utf-8", "surrogatepass")),
                     st.text(max_size=50).map(lambda s: s.encode("utf-16")),
                     st.text(max_size=50).map(lambda s: s.encode("latin-1", "replace"))))
def test_fuzz_read_text(folder, raw):
    from faceanim.io.files import read_text

    text = clean(read_text, write(folder, raw, ".txt"))
    if text is not None:
        assert isinstance(text, str)
        # the text is the file's, newlines read universally (\r\n and \r as \n)
        assert text == raw.decode("utf-8").replace("\r\n", "\n").replace("\r", "\n")


def test_read_text_refuses_special_files_cleanly(folder):
    from faceanim.io.files import read_text

    for p in (folder / "missing.txt", folder, Path("/dev/zero")):
        with pytest.raises(FaceAnimError):
            read_text(p)


def test_a_template_of_another_format_is_refused(wire_base):
    """A file whose 'format' is not this faceanim's wire template (another tool's, a newer version)
    is refused, not read as if it were one (the outside sweep's finding)."""
    from faceanim.rig.wires import WIRE_FORMAT, WireTemplate

    d = json.loads(json.dumps(wire_base[2].to_dict()))
    assert d["format"] == WIRE_FORMAT
    d["format"] = "faceanim wires 2"
    with pytest.raises(FaceAnimError, match="its 'format' is not 'faceanim wires 1'"):
        WireTemplate.from_dict(d)
