"""faceanim photo: photos in, a textured animatable head out; bad input exits 2 with one line and
no file. Photos: scikit-image's astronaut (always here) and ../shared/data/multiview-photos."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image

from faceanim.cli import main
from faceanim.errors import FaceAnimError
from faceanim.face.generic_head import generic_head
from faceanim.io.meshio import load_mesh

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
MULTI = DATA / "multiview-photos"
needs_photos = pytest.mark.skipif(not MULTI.is_dir(), reason="../shared/data/multiview-photos is not here")


@pytest.fixture(scope="module")
def astronaut(tmp_path_factory) -> Path:
    from skimage import data

    p = tmp_path_factory.mktemp("photos") / "astronaut.png"
    Image.fromarray(data.astronaut()).save(p)
    return p


def run(args) -> int:
    try:
        return main([str(a) for a in args])
    except SystemExit as exc:  # argparse's own refusals
        return exc.code


def test_one_front_photo_gives_a_textured_head_with_the_generic_topology(tmp_path, astronaut, capsys):
    out = tmp_path / "head.obj"
    assert run(["photo", "--front", astronaut, "-o", out]) == 0
    printed = capsys.readouterr().out
    assert "astronaut.png 0.0" in printed and "wrote" in printed
    m = load_mesh(out)
    g = generic_head()
    assert m.n_vertices == g.mesh.n_vertices
    np.testing.assert_array_equal(m.faces, g.mesh.faces)
    assert m.texture is not None and m.texture.shape[:2] == (1024, 1024)
    # the face's colours come from the photo: at the nose tip's triangle the atlas holds skin (red
    # well above blue, bright), as the photo shows there
    from skimage import data

    tri = g.landmark_triangles[4]
    uv = m.uv[m.face_uv[tri]].mean(0)
    h, w = m.texture.shape[:2]
    texel = m.texture[int((1 - uv[1]) * h), int(uv[0] * w)].astype(int)
    lm = g.landmarks(m.vertices)
    assert texel[0] > texel[2] + 30 and texel[0] > 120, texel
    photo_nose = data.astronaut()[119:133, 217:231].reshape(-1, 3).mean(0)  # the nose tip in the photo
    assert np.abs(texel - photo_nose).max() < 60, (texel, photo_nose)
    assert lm.shape == (478, 3)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["head.mtl", "head.obj", "head.texture.png"]


def test_rig_glb_carries_every_control(tmp_path, astronaut):
    import pygltflib

    out = tmp_path / "head.glb"
    assert run(["photo", "--front", astronaut, "--rig", "--texture-size", "256", "-o", out]) == 0
    gltf = pygltflib.GLTF2().load(str(out))
    from faceanim.catalogue import RIG_SETS

    names = gltf.meshes[0].extras["targetNames"]
    sets = gltf.scenes[0].extras["morph_sets"]  # what faceanim rig writes: the whole catalogue
    assert list(sets) == list(RIG_SETS) and sum(sets.values(), []) == names
    assert {"jawOpen", "eyeBlinkLeft", "mouthSmileRight", "tongueOut", "viseme_PP", "viseme_U", "mouthOpen",
            "eyesClosed", "AU12", "AU12_L", "AU43", "joy", "open_jaw"} <= set(names)
    assert len(sets["arkit"]) == 52


def test_png_shows_the_head_from_three_sides(tmp_path, astronaut):
    out = tmp_path / "head.png"
    assert run(["photo", "--front", astronaut, "--size", "128", "--texture-size", "256", "-o", out]) == 0
    img = np.asarray(Image.open(out))
    assert img.shape == (128, 3 * 128, 3)
    # each of the three views shows a head (pixels other than the background) in its middle
    for k in range(3):
        tile = img[:, 128 * k:128 * (k + 1)]
        assert (np.abs(tile[64].astype(int) - tile[0, 0]).sum(axis=1) > 30).sum() > 20


@needs_photos
def test_three_views_and_corrections(tmp_path):
    pts = tmp_path / "points.json"
    pts.write_text(json.dumps({"front": {"9.3": [112.0, 120.0]}}))
    out = tmp_path / "head.glb"
    assert run(["photo", "--front", MULTI / "front.jpg", "--side", MULTI / "left.jpg", "--side", MULTI / "right.jpg",
                "--points", pts, "--texture-size", "256", "-o", out]) == 0
    assert out.is_file()


def _one_line_and_nothing(tmp_path, capsys, args, match):
    before = set(tmp_path.iterdir())
    assert run(args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and match in err, err
    assert set(tmp_path.iterdir()) == before


def test_bad_input(tmp_path, astronaut, capsys):
    blank = tmp_path / "blank.png"
    Image.new("RGB", (200, 200), (90, 90, 90)).save(blank)
    corrupt = tmp_path / "corrupt.jpg"
    corrupt.write_bytes(b"\xff\xd8\xff\xe0" + b"\x00" * 100)
    bad_points = tmp_path / "p.json"
    bad_points.write_text(json.dumps({"front": {"77.7": [1, 2]}}))
    out = tmp_path / "o.glb"
    cases = [
        (["photo", "--front", blank, "-o", out], "no face found"),
        (["photo", "--front", corrupt, "-o", out], "not a readable image"),
        (["photo", "--front", tmp_path / "missing.jpg", "-o", out], "does not exist"),
        (["photo", "--front", astronaut, "--points", bad_points, "-o", out], "unknown point '77.7'"),
        (["photo", "--front", astronaut, "--rig", "-o", tmp_path / "o.obj"], "only a .glb holds"),
        (["photo", "--front", astronaut, "--texture-size", "4096", "-o", out], "--texture-size"),
        (["photo", "--front", astronaut, "-o", tmp_path / "o.ply"], "must end in one of"),
        (["photo", "--front", astronaut, "--side", astronaut, "-o", out], "shows the head from the front"),
        (["photo", "--front", astronaut, "-o", tmp_path / "no" / "o.glb"], "folder"),
    ]
    for args, match in cases:
        _one_line_and_nothing(tmp_path, capsys, args, match)
    # the output named as an input: refused, the photo kept
    copy = tmp_path / "copy.png"
    copy.write_bytes(Path(astronaut).read_bytes())
    before = copy.read_bytes()
    assert run(["photo", "--front", copy, "-o", tmp_path / "copy.png"]) == 2
    assert "also an input" in capsys.readouterr().err and copy.read_bytes() == before


@needs_photos
def test_a_side_view_as_front_is_refused(tmp_path, capsys):
    _one_line_and_nothing(tmp_path, capsys, ["photo", "--front", MULTI / "left.jpg", "-o", tmp_path / "o.glb"],
                          "give a frontal photo as --front")


# ---------------------------------------------------------------------------------------- fuzz
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.binary(max_size=300))
def test_photo_reader_takes_any_bytes(tmp_path, blob):
    from faceanim.build.photo import read_photo

    p = tmp_path / "x.jpg"
    p.write_bytes(blob)
    try:
        img = read_photo(p)
    except FaceAnimError as exc:
        assert "\n" not in str(exc)
    else:
        assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.uint8


json_values = st.recursive(st.none() | st.booleans() | st.floats(allow_nan=True) | st.integers() | st.text(max_size=6),
                           lambda c: st.lists(c, max_size=3) | st.dictionaries(st.text(max_size=6), c, max_size=3),
                           max_leaves=12)


@settings(max_examples=200, deadline=None)
@given(json_values)
def test_points_reader_takes_any_json(spec):
    from faceanim.build import photo as P

    head = generic_head()
    pix = head.landmarks()[:, :2] * 1000 + 256
    views = [P.PhotoView("f", np.zeros((512, 512, 3), np.uint8), "front", {i: pix[i] for i in range(478)}),
             P.PhotoView("s", np.zeros((512, 512, 3), np.uint8), "side", {i: pix[i] for i in range(478)})]
    try:
        P.apply_corrections(views, spec)
    except FaceAnimError as exc:
        assert "\n" not in str(exc)
    for v in views:
        for p in list(v.points.values()) + list(v.extra.values()):
            assert p.shape == (2,) and np.all(np.isfinite(p))
