"""faceanim photo refuses a side photo of somebody else (issue 23, hole 7): the face-recognition
check of faceanim.build.identity, on real photos. The astronaut's front with the multi-view man's
side photo passes the geometric check (their faces are alike in shape); the network tells them
apart. One person's own views are accepted (test_cli_photo builds the man's head from all three)."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from faceanim.cli import main

pytest.importorskip("dlib", reason="faceanim's 'identity' extra is not installed")
from test_cli_photo import MULTI, needs_photos, run  # noqa: E402


@pytest.fixture(scope="module")
def astronaut(tmp_path_factory):
    from PIL import Image
    from skimage import data

    p = tmp_path_factory.mktemp("photos") / "astronaut.png"
    Image.fromarray(data.astronaut()).save(p)
    return p


@needs_photos
def test_a_side_photo_of_somebody_else_is_refused_though_the_shapes_agree(tmp_path, astronaut, capsys):
    from faceanim.build.identity import SAME_PERSON
    from faceanim.build.photo import check_views, load_views, prior_points, reconstruct
    from faceanim.face.generic_head import generic_head

    side = MULTI / "left.jpg"
    # the geometric check alone takes this pair: the hole
    views = load_views(astronaut, (side,))
    check_views(views, reconstruct(views, *prior_points(generic_head())))

    out = tmp_path / "head.glb"
    assert run(["photo", "--front", astronaut, "--side", side, "-o", out]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "left.jpg' shows somebody other than the front photo" in err, err
    distance = float(err.split("distance ")[1].split(";")[0])
    assert distance > SAME_PERSON
    assert not out.exists() and list(tmp_path.iterdir()) == []


@needs_photos
def test_descriptors_of_one_man_are_near_and_of_two_people_far(astronaut):
    """The descriptor from MediaPipe's box agrees with the one from dlib's own face detector (an
    independent way to find the face); the man's three views lie within dlib's threshold of each
    other, the astronaut beyond it from each of them."""
    import dlib

    from faceanim.build.identity import SAME_PERSON, _models, face_descriptor, view_descriptor
    from faceanim.build.photo import detect_view, read_photo

    views = [detect_view(read_photo(MULTI / f"{n}.jpg"), n, "front" if n == "front" else "side")
             for n in ("front", "left", "right")]
    own = [view_descriptor(v) for v in views]
    other = view_descriptor(detect_view(read_photo(astronaut), "astronaut", "front"))
    for a in range(3):
        for b in range(a + 1, 3):
            assert np.linalg.norm(own[a] - own[b]) < SAME_PERSON
        assert np.linalg.norm(own[a] - other) > SAME_PERSON
    _, predictor, network = _models()
    image = views[0].image
    (box,) = dlib.get_frontal_face_detector()(image, 1)
    theirs = np.asarray(network.compute_face_descriptor(image, predictor(image, box), 1))
    assert np.linalg.norm(theirs - own[0]) < 0.1
    assert np.array_equal(face_descriptor(image, np.array([views[0].points[i] for i in range(468)])), own[0])


@needs_photos
def test_without_the_identity_extra_photo_with_sides_says_what_to_install(tmp_path, capsys, monkeypatch):
    from faceanim.build import identity

    identity._models.cache_clear()
    monkeypatch.setitem(sys.modules, "dlib", None)  # import dlib raises ImportError
    try:
        out = tmp_path / "head.obj"
        code = run(["photo", "--front", MULTI / "front.jpg", "--side", MULTI / "left.jpg", "-o", out])
        err = capsys.readouterr().err
    finally:
        identity._models.cache_clear()
    assert code == 2 and err.count("\n") == 1, err
    assert "faceanim's 'identity' extra, which is not installed: pip install 'faceanim[identity]'" in err
    assert not out.exists()


def test_a_front_photo_alone_needs_no_identity_check(tmp_path, astronaut, monkeypatch):
    from faceanim.build import identity

    identity._models.cache_clear()
    monkeypatch.setitem(sys.modules, "dlib", None)
    try:
        assert main(["photo", "--front", str(astronaut), "-o", str(tmp_path / "h.obj")]) == 0
    finally:
        identity._models.cache_clear()
