"""Issue 23: the holes an outside sweep found, each a regression test that failed before its fix."""

import numpy as np
import pytest
from test_arkit_csv import HEADER, row, write_take

from faceanim.cli import main
from faceanim.errors import FaceAnimError
from faceanim.io.arkit_csv import read_arkit_csv
from faceanim.standards.arkit import ARKIT_NAMES


def run(argv, capsys) -> tuple[int, str, str]:
    rc = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def _rows():
    w = np.zeros(52)
    w[ARKIT_NAMES.index("JawOpen")] = 0.5
    return [row("00:00:00:00.000"), row("00:00:00:06.000", w), row("00:00:00:12.000")]


# --------------------------------------------------------------------- 10: a BOM is accepted
def test_a_live_link_csv_with_a_byte_order_mark_reads_as_without(tmp_path):
    plain = write_take(tmp_path / "plain.csv", _rows())
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbf" + plain.read_bytes())
    a, b = read_arkit_csv(plain), read_arkit_csv(bom)
    assert np.array_equal(a.weights, b.weights) and np.array_equal(a.times, b.times)
    assert b.weights[1, ARKIT_NAMES.index("JawOpen")] == 0.5


# ------------------------------------------------- 6: a cell with no column is refused, not dropped
def test_a_live_link_row_with_a_cell_more_than_the_header_is_refused(tmp_path, capsys):
    rows = _rows()
    rows[1] = rows[1] + ["0.7"]
    take = write_take(tmp_path / "extra.csv", rows)
    with pytest.raises(FaceAnimError, match=r"line 3: 64 cells for 63 columns \(a cell with no column"):
        read_arkit_csv(take)
    rc, out, err = run(["arkit", "play", take, "-o", tmp_path / "x.csv"], capsys)
    assert rc == 2 and len(err.strip().splitlines()) == 1 and not (tmp_path / "x.csv").exists()
    # an empty cell after the last column (a trailing comma, as spreadsheets write) is no data
    rows[1][-1] = ""
    assert read_arkit_csv(write_take(tmp_path / "trailing.csv", rows)).weights.shape == (3, 52)
    assert len(HEADER) == 63


# ------------------------------------------------- 4: a tiny frame rate overflowed the glTF times
def test_a_fap_file_with_a_tiny_frame_rate_is_one_line_and_exit_2(tmp_path, capsys):
    values = " ".join(["0"] * 68)
    for fps in ("1e-30", "1e-5"):
        fap = tmp_path / "tiny.fap"
        fap.write_text(f"2.1 tiny {fps} 2\n{values}\n0\n{values}\n1\n")
        rc, out, err = run(["fap", "play", fap, "-o", tmp_path / "x.glb"], capsys)
        assert rc == 2, err
        assert "more than faceanim's limit of 3600 s; check the frame rate" in err and len(err.splitlines()) == 1
        assert not (tmp_path / "x.glb").exists()


def test_the_gltf_writer_refuses_times_beyond_float32(tmp_path):
    from faceanim.face.mesh import Mesh
    from faceanim.io.gltf import write_gltf

    mesh = Mesh(np.eye(3), np.array([[0, 1, 2]]))
    with pytest.raises(FaceAnimError, match="finite 32-bit numbers"):
        write_gltf(tmp_path / "x.glb", mesh, {"a": np.ones((3, 3))}, times=np.array([0.0, 1e39]),
                   weights=np.array([[0.0], [1.0]]))
    assert not (tmp_path / "x.glb").exists()
