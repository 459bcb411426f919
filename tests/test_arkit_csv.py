"""Live Link Face CSV takes: the real recording's known events, the ICT names, resampling, bad
files and a fuzz test of the reader."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from faceanim.errors import FaceAnimError, InputFileError
from faceanim.face.generic_head import generic_head
from faceanim.io.arkit_csv import read_arkit_csv
from faceanim.standards.arkit import ARKIT_NAMES, EYE_NAMES, HEAD_NAMES, ict_name

TAKE = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "arkit-curves" / "alex_rom_3.csv"
needs_take = pytest.mark.skipif(not TAKE.is_file(), reason="../shared/data/arkit-curves is not here")
HEADER = ["Timecode", "BlendShapeCount", *ARKIT_NAMES, *HEAD_NAMES, *EYE_NAMES]


def write_take(path: Path, rows) -> Path:
    lines = [",".join(HEADER)] + [",".join(str(c) for c in r) for r in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def row(timecode: str, weights=None, head=(0.0, 0.0, 0.0)):
    w = np.zeros(52) if weights is None else weights
    return [timecode, 61, *[f"{x:.4f}" for x in w], *head, *([0.0] * 6)]


@needs_take
def test_the_real_take_shows_its_known_events():
    """The data README's checks: JawOpen peaks near 0.95 around 76 s, TongueOut reaches 1.0 around
    90 s, both blinks about 0.99 around 79 s, the smiles about 0.89 around 93 s; 30 samples a
    second over about 134.4 s; head angles all zero."""
    take = read_arkit_csv(TAKE)
    assert take.n_samples == 4030 and take.duration == pytest.approx(134.4, abs=0.1)
    assert np.median(np.diff(take.times)) == pytest.approx(1 / 30, abs=1e-4)
    assert np.all(take.head == 0)
    w = take.weights

    def peak(name, around, width=3.0):
        k = ARKIT_NAMES.index(name)
        near = np.abs(take.times - around) < width
        return w[near, k].max()

    assert peak("JawOpen", 76) == pytest.approx(0.95, abs=0.02)
    assert peak("TongueOut", 90) == pytest.approx(1.0, abs=0.01)
    assert peak("EyeBlinkLeft", 79) > 0.97 and peak("EyeBlinkRight", 79) > 0.97
    assert peak("MouthSmileLeft", 93) == pytest.approx(0.89, abs=0.02)
    assert w.max() <= 1.0 and w.min() >= 0.0  # EyeLookInRight's 1.003 clamped
    r = take.resample(25.0)
    assert np.allclose(np.diff(r.times), 0.04) and r.weights.shape == (r.n_samples, 52)


def test_ict_names_cover_the_generic_head():
    names = {n for a in ARKIT_NAMES for n in ict_name(a)}
    assert names | {"tongueOut"} == set(generic_head().shape_names)  # tongueOut: faceanim's own
    assert ict_name("BrowInnerUp") == ("browInnerUp_L", "browInnerUp_R")
    assert ict_name("JawLeft") == ("jawLeft",) and ict_name("EyeBlinkLeft") == ("eyeBlink_L",)
    assert ict_name("TongueOut") == ()


def test_timecodes_resampling_and_ict_curves(tmp_path):
    w1 = np.zeros(52)
    w1[ARKIT_NAMES.index("JawOpen")] = 0.6
    w1[ARKIT_NAMES.index("CheekPuff")] = 0.4
    take = read_arkit_csv(write_take(tmp_path / "t.csv", [
        row("10:00:00:00.000"), row("10:00:00:00.000"),  # the first sample written twice: kept once
        row("10:00:00:06.000", w1), row("10:00:00:12.000")]))  # 0.1 s apart
    np.testing.assert_allclose(take.times, [0.0, 0.1, 0.2])
    r = take.resample(20.0)
    k = ARKIT_NAMES.index("JawOpen")
    np.testing.assert_allclose(r.weights[:, k], [0.0, 0.3, 0.6, 0.3, 0.0])
    names, curves = take.ict_curves()
    assert curves.shape == (3, 53)
    np.testing.assert_allclose(curves[1, names.index("cheekPuff_L")], 0.4)
    np.testing.assert_allclose(curves[1, names.index("cheekPuff_R")], 0.4)


@pytest.mark.parametrize("text, match", [
    ("", "is empty"),
    ("Timecode,EyeBlinkLeft\n00:00:00:00.0,0.1\n", "lacks the column"),
    (",".join(HEADER) + "\n" + "00:00:00:00.0,61," + ",".join(["0"] * 60) + "\n", "truncated row"),
    (",".join(HEADER) + "\n" + "00:00:00:00.0,61," + ",".join(["x"] + ["0"] * 60) + "\n", "EyeBlinkLeft is not a number"),
    (",".join(HEADER) + "\n" + "00:00:00:00.0,61," + ",".join(["nan"] + ["0"] * 60) + "\n", "NaN"),
    (",".join(HEADER) + "\n" + "soon,61," + ",".join(["0"] * 61) + "\n", "is not HH:MM:SS:FF.fff"),
    (",".join(HEADER) + "\n" + "00:00:00:99.0,61," + ",".join(["0"] * 61) + "\n", "out of range"),
    (",".join(HEADER) + "\n" + "00:00:01:00.0,61," + ",".join(["0"] * 61) + "\n", "1 sample"),
    (",".join(HEADER) + "\n" + "00:00:01:00.0,61," + ",".join(["0"] * 61) + "\n"
     + "00:00:00:00.0,61," + ",".join(["0"] * 61) + "\n", "time goes backwards"),
])
def test_bad_takes_are_one_line(tmp_path, text, match):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(InputFileError, match=match) as exc:
        read_arkit_csv(p)
    assert "\n" not in str(exc.value)


def test_binary_and_missing_files(tmp_path):
    p = tmp_path / "b.csv"
    p.write_bytes(b"\xff\xfe\x00binary")
    with pytest.raises(InputFileError, match="not text"):
        read_arkit_csv(p)
    with pytest.raises(InputFileError, match="does not exist"):
        read_arkit_csv(tmp_path / "none.csv")


cells = st.one_of(st.text(max_size=8), st.floats(allow_nan=True).map(str), st.integers().map(str),
                  st.sampled_from(["00:00:00:00.0", "00:00:00:02.0", "1e400", "-inf", ""]))


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.lists(cells, min_size=0, max_size=70), max_size=5), st.booleans())
def test_reader_takes_any_table(tmp_path, rows, with_header):
    p = tmp_path / "f.csv"
    lines = ([",".join(HEADER)] if with_header else []) + [",".join(r) for r in rows]
    p.write_text("\n".join(lines))
    try:
        take = read_arkit_csv(p)
    except FaceAnimError as exc:
        assert "\n" not in str(exc)
    else:
        assert np.all(np.isfinite(take.weights)) and np.all(np.diff(take.times) > 0)


def test_a_device_is_not_a_take(tmp_path):
    with pytest.raises(InputFileError, match="not a regular file"):
        read_arkit_csv("/dev/null")
    with pytest.raises(InputFileError, match="a folder"):
        read_arkit_csv(tmp_path)


def test_written_take_has_the_apps_layout(tmp_path):
    """As Live Link Face writes a take: LF line ends, the same header (names and order) as the shared
    recording, a timecode counting the app's 60 frames a second, BlendShapeCount 61."""
    from faceanim.io.arkit_csv import write_arkit_csv

    rec = Path(__file__).resolve().parents[2] / "shared" / "data" / "arkit-curves" / "alex_rom_3.csv"
    out = tmp_path / "t.csv"
    write_arkit_csv(out, np.zeros((3, 52)), 30.0)
    data = out.read_bytes()
    assert b"\r" not in data and data.endswith(b"\n")
    lines = data.decode().splitlines()
    assert [r.split(",")[0] for r in lines[1:]] == ["00:00:00:00.000", "00:00:00:02.000", "00:00:00:04.000"]
    assert {r.split(",")[1] for r in lines[1:]} == {"61"}
    if rec.exists():
        assert lines[0] == rec.read_text().splitlines()[0]
