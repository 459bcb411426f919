"""A head from photos (Lee et al. 1999, section 2): cameras, 3D points, expression, head fit.

Oracles: analytic similarity and camera recoveries, the renderer's own projection, synthetic
shapes made from the generic head's blendshapes, and real photos (multiview-photos: the yaw signs
the data's README states)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from faceanim.build import photo as P
from faceanim.build.camera import ViewCamera
from faceanim.errors import FaceAnimError, InputFileError, LandmarkError
from faceanim.face.frame import similarity
from faceanim.face.generic_head import generic_head

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
MULTI = DATA / "multiview-photos"
needs_photos = pytest.mark.skipif(not MULTI.is_dir(), reason="../shared/data/multiview-photos is not here")


def random_rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def yaw_rotation(deg: float) -> np.ndarray:
    """Camera rotation for a camera at ``deg`` degrees round the head (positive: the subject's left)."""
    a = np.radians(deg)
    d = np.array([np.sin(a), 0.0, np.cos(a)])  # head -> camera
    right = np.cross([0.0, 1.0, 0.0], d)
    right /= np.linalg.norm(right)
    return np.vstack([right, np.cross(d, right), d])


def test_similarity_recovers_a_known_transform():
    rng = np.random.default_rng(0)
    src = rng.normal(size=(50, 3))
    r = random_rotation(rng)
    dst = 2.5 * src @ r.T + np.array([1.0, -2.0, 0.5])
    s, r2, t = similarity(src, dst)
    assert s == pytest.approx(2.5)
    np.testing.assert_allclose(r2, r, atol=1e-10)
    np.testing.assert_allclose(t, [1.0, -2.0, 0.5], atol=1e-10)


def test_fit_camera_recovers_a_scaled_orthographic_camera():
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(60, 3))
    cam = ViewCamera(yaw_rotation(35.0), 120.0, np.array([300.0, 250.0]), (640, 480))
    got = P.fit_camera(pts, cam.project(pts), (640, 480))
    np.testing.assert_allclose(got.rotation, cam.rotation, atol=1e-9)
    assert got.scale == pytest.approx(120.0)
    np.testing.assert_allclose(got.offset, cam.offset, atol=1e-8)
    assert got.yaw_degrees == pytest.approx(35.0)


def test_view_camera_matches_the_renderer():
    """The renderer's parallel view at a yaw is a ViewCamera with that yaw (and the same pixels)."""
    from faceanim.render import OffscreenRenderer

    head = generic_head()
    pts = head.mesh.vertices[::97]
    for yaw in (0.0, 30.0, -90.0):
        with OffscreenRenderer(head.mesh, size=(256, 256), yaw=yaw, parallel=True) as r:
            pix = r.project(pts) * 256
        cam = P.fit_camera(pts, pix, (256, 256))
        assert cam.yaw_degrees == pytest.approx(yaw, abs=1e-6)
        assert np.abs(cam.project(pts) - pix).max() < 1e-6


def test_a_rendered_pixel_is_where_the_camera_projects_the_point():
    """project() agrees with the rendered image: the nose tip of the generic head projects into
    the head's silhouette and a point beside the head onto the background."""
    from faceanim.render import OffscreenRenderer

    head = generic_head()
    bg = (0.0, 0.0, 1.0)
    with OffscreenRenderer(head.mesh, size=(256, 256), yaw=60.0, parallel=True, background=bg) as r:
        img = r.render()
        nose = r.project(head.landmarks()[[4]])[0] * 256
        outside = r.project(head.landmarks()[[4]] + np.array([[0.0, 0.0, 0.5]]))[0] * 256
    assert tuple(img[int(nose[1]), int(nose[0])]) != (0, 0, 255)
    x, y = int(np.clip(outside[0], 0, 255)), int(np.clip(outside[1], 0, 255))
    assert tuple(img[y, x]) == (0, 0, 255)


def synthetic_views(points3d: np.ndarray, yaws=(0.0,)) -> list[P.PhotoView]:
    views = []
    for k, yaw in enumerate(yaws):
        cam = ViewCamera(yaw_rotation(yaw), 900.0, np.array([256.0, 256.0]), (512, 512))
        pix = cam.project(points3d)
        role = "front" if k == 0 else "side"
        v = P.PhotoView(f"v{k}", np.zeros((512, 512, 3), np.uint8), role, {i: pix[i] for i in range(478)})
        v.mediapipe = np.c_[pix, -900.0 * (points3d @ cam.rotation[2])]  # what MediaPipe's z would say
        views.append(v)
    return views


def test_reconstruct_recovers_the_frontal_shape_of_a_known_head():
    """A known shape (the generic head with a wider face and a smile) seen from the front: the
    rebuilt points match it in x and y (up to the similarity the gauge leaves free), far better
    than the generic head does."""
    head = generic_head()
    prior, normals = P.prior_points(head)
    v = head.mesh.vertices + 0.8 * head.shape("mouthSmile_L") + 0.5 * head.shape("jawOpen")
    truth = head.landmarks(v) * np.array([1.15, 0.95, 1.0])
    rec = P.reconstruct(synthetic_views(truth), prior, normals)
    # in the camera's image plane (depth comes from the generic head: one view cannot see it)
    cam = rec.cameras[0]
    pix = synthetic_views(truth)[0]
    target = np.stack([pix.points[i] for i in range(468)])
    err = np.linalg.norm(cam.project(rec.points[:468]) - target, axis=1).mean() / (cam.scale * rec.iod)
    base_cam = P.fit_camera(prior[:468], target, (512, 512))
    base = np.linalg.norm(base_cam.project(prior[:468]) - target, axis=1).mean() / (base_cam.scale * rec.iod)
    assert err < 0.005 and base > 10 * err
    assert abs(rec.cameras[0].yaw_degrees) < 1.0
    assert np.median(rec.errors[0]) < 0.005


def test_fit_expression_finds_the_blendshape_weights_of_a_synthetic_face():
    head = generic_head()
    v = head.mesh.vertices + 0.6 * head.shape("jawOpen") + 0.4 * head.shape("mouthSmile_L")
    a = np.array([[1.1, 0.02, 0.0, 0.01], [0.0, 0.9, 0.05, -0.02], [0.0, 0.0, 1.05, 0.0]])
    target = P.apply_affine(a, head.landmarks(v))
    w = P.fit_expression(head, target)
    assert w["jawOpen"] == pytest.approx(0.6, abs=0.08)
    assert w["mouthSmile_L"] == pytest.approx(0.4, abs=0.08)
    others = [x for n, x in w.items() if n not in ("jawOpen", "mouthSmile_L")]
    assert max(others) < 0.1


def _fake_reconstruction(head, points):
    return P.Reconstruction(points, [], [], [], float(np.linalg.norm(points[33] - points[263])))


@pytest.mark.parametrize("method", ["rbf", "dffd"])
def test_fit_head_meets_its_control_points_and_keeps_parts_rigid(method):
    head = generic_head()
    prior, _ = P.prior_points(head)
    rng = np.random.default_rng(3)
    # a different person: a global stretch plus a smooth bump on the nose and cheeks
    target = prior * np.array([1.1, 0.97, 1.05])
    bump = np.exp(-np.sum((prior - prior[4]) ** 2, axis=1) / 0.03 ** 2)[:, None] * np.array([0.0, 0.0, 0.006])
    target = target + bump + rng.normal(scale=1e-5, size=target.shape)
    fh = P.fit_head(head, _fake_reconstruction(head, target), method, keep_expression=True)
    rows = P.control_rows()
    got = np.vstack([head.landmarks(fh.vertices), fh.vertices[[P.extra_vertices(head)[n] for n in P.EXTRA_POINTS]]])
    iod = np.linalg.norm(target[33] - target[263])
    assert np.linalg.norm(got[rows] - target[rows], axis=1).max() / iod < 0.01
    for idx, _ in P.rigid_groups(head):
        a, b = head.mesh.vertices[idx[::7]], fh.vertices[idx[::7]]
        da = np.linalg.norm(a[:, None] - a[None], axis=2)
        db = np.linalg.norm(b[:, None] - b[None], axis=2)
        ratio = db[da > 1e-6] / da[da > 1e-6]
        assert ratio.std() < 1e-9  # rotation + translation + one uniform scale
        assert 0.9 < ratio.mean() < 1.15


def test_taking_the_expression_off_closes_a_fitted_open_mouth():
    """A face with an open jaw: the fit finds the jaw, and the returned rest pose has the lips of
    the neutral generic head (gap between the inner lips like the generic's), while the
    'expressed' head keeps the opening."""
    head = generic_head()
    prior, _ = P.prior_points(head)
    v = head.mesh.vertices + 0.7 * head.shape("jawOpen")
    target = np.vstack([head.landmarks(v), prior[478:]])
    fh = P.fit_head(head, _fake_reconstruction(head, target), "rbf")
    assert fh.expression["jawOpen"] > 0.5

    def gap(vv):
        lm = head.landmarks(vv)
        return np.linalg.norm(lm[13] - lm[14])

    assert gap(fh.expressed) > gap(head.mesh.vertices) + 0.01
    assert abs(gap(fh.vertices) - gap(head.mesh.vertices)) < 0.003


# ---------------------------------------------------------------------------------------- real photos
@needs_photos
def test_real_photos_yaw_signs_and_small_reprojection_error():
    head = generic_head()
    prior, normals = P.prior_points(head)
    views = P.load_views(MULTI / "front.jpg", [MULTI / "left.jpg", MULTI / "right.jpg"])
    rec = P.reconstruct(views, prior, normals)
    P.check_views(views, rec)
    yaws = [c.yaw_degrees for c in rec.cameras]
    assert abs(yaws[0]) < 10
    assert 20 < yaws[1] < 50  # left.jpg: the nose points to the image's left
    assert -50 < yaws[2] < -20
    assert np.median(rec.errors[0]) < 0.01


@needs_photos
def test_a_side_photo_given_as_front_is_refused():
    head = generic_head()
    prior, normals = P.prior_points(head)
    views = P.load_views(MULTI / "left.jpg", [MULTI / "front.jpg"])
    rec = P.reconstruct(views, prior, normals)
    with pytest.raises(LandmarkError, match="turned .* degrees; give a frontal photo"):
        P.check_views(views, rec)


@needs_photos
def test_views_of_two_different_people_are_refused():
    """The man of multiview-photos seen from the side with another man's front (a frame of the
    talking-head video d0.mp4): the views disagree beyond the tolerance."""
    video = DATA / "talking-head-videos" / "d0.mp4"
    if not video.is_file():
        pytest.skip("talking-head-videos/d0.mp4 is not here")
    import imageio.v3 as iio

    head = generic_head()
    prior, normals = P.prior_points(head)
    other = np.asarray(iio.imread(video, index=0))[..., :3]
    views = P.load_views(("d0.mp4 frame 0", other), [MULTI / "left.jpg"])
    rec = P.reconstruct(views, prior, normals)
    with pytest.raises(LandmarkError, match="do not agree"):
        P.check_views(views, rec)
    # and the man's own views agree
    views = P.load_views(MULTI / "front.jpg", [MULTI / "left.jpg"])
    P.check_views(views, P.reconstruct(views, prior, normals))


# ---------------------------------------------------------------------------------------- bad input
def test_read_photo_refuses_missing_corrupt_and_tiny_files(tmp_path):
    with pytest.raises(InputFileError, match="does not exist"):
        P.read_photo(tmp_path / "none.jpg")
    bad = tmp_path / "bad.jpg"
    bad.write_bytes(b"\xff\xd8\xff\xe0 not really a jpeg")
    with pytest.raises(InputFileError, match="not a readable image"):
        P.read_photo(bad)
    from PIL import Image

    Image.new("RGB", (8, 8)).save(tmp_path / "tiny.png")
    with pytest.raises(InputFileError, match="at least 32"):
        P.read_photo(tmp_path / "tiny.png")
    with pytest.raises(InputFileError, match="is a folder"):
        P.read_photo(tmp_path)


def test_read_photo_turns_an_exif_rotated_photo_upright(tmp_path):
    from PIL import Image

    img = Image.new("RGB", (60, 40), (255, 0, 0))
    img.paste((0, 255, 0), (0, 0, 10, 40))  # a green strip on the left
    exif = Image.Exif()
    exif[0x0112] = 6  # stored rotated: the viewer turns it 90 degrees clockwise
    img.save(tmp_path / "r.jpg", exif=exif, quality=95)
    rgb = P.read_photo(tmp_path / "r.jpg")
    assert rgb.shape == (60, 40, 3)
    assert rgb[2, 20, 1] > 200 and rgb[2, 20, 0] < 80  # the left strip is now on top


def test_a_blank_photo_has_no_face():
    blank = np.full((256, 256, 3), 128, np.uint8)
    with pytest.raises(LandmarkError, match="no face found"):
        P.detect_view(blank, "blank.png", "front")


def test_corrections_replace_points_and_refuse_unknown_names():
    head = generic_head()
    views = synthetic_views(head.landmarks(), yaws=(0.0, 40.0))
    P.apply_corrections(views, {"front": {"9.3": [10.0, 20.0], "mp:33": [5.0, 6.0]}, "side": {"head_top": [1.0, 2.0]}})
    np.testing.assert_array_equal(views[0].points[4], [10.0, 20.0])  # 9.3 is landmark 4
    np.testing.assert_array_equal(views[0].points[33], [5.0, 6.0])
    np.testing.assert_array_equal(views[1].extra["head_top"], [1.0, 2.0])
    for spec, msg in [({"front": {"99.9": [1, 2]}}, "unknown point '99.9'"),
                      ({"front": {"mp:478": [1, 2]}}, "unknown point"),
                      ({"back": {"9.3": [1, 2]}}, "unknown view 'back'"),
                      ({"front": {"9.3": [1, float("nan")]}}, r"must be \[x, y\]"),
                      ({"front": {"9.3": [1e9, 2]}}, "inside the 512x512 photo"),
                      ({"front": {"9.3": "here"}}, r"must be \[x, y\]"),
                      ({"front": [1, 2]}, "must map point names"),
                      ([1, 2], "must hold an object")]:
        with pytest.raises(InputFileError, match=msg):
            P.apply_corrections(views, spec)


def test_unknown_method_is_refused():
    with pytest.raises(FaceAnimError, match="choose dffd or rbf"):
        P.head_from_photos(("f", np.zeros((64, 64, 3), np.uint8)), method="magic")


def test_a_correction_moves_the_rebuilt_point_to_the_given_pixel():
    """--points: the corrected nose tip (FDP 9.3) is where the rebuilt head's nose tip projects
    in the front photo, 6 px from where it was detected."""
    head = generic_head()
    prior, normals = P.prior_points(head)
    views = synthetic_views(head.landmarks())
    want = views[0].points[4] + np.array([6.0, -4.0])
    P.apply_corrections(views, {"front": {"9.3": want.tolist()}})
    rec = P.reconstruct(views, prior, normals)
    got = rec.cameras[0].project(rec.points[[4]])[0]
    assert np.linalg.norm(got - want) < 0.5


def test_two_side_photos_of_one_side_are_refused():
    head = generic_head()
    prior, normals = P.prior_points(head)
    views = synthetic_views(head.landmarks(), yaws=(0.0, 35.0, 30.0))
    rec = P.reconstruct(views, prior, normals)
    with pytest.raises(LandmarkError, match="same side of the head"):
        P.check_views(views, rec)
    views = synthetic_views(head.landmarks(), yaws=(0.0, 35.0, -30.0))
    P.check_views(views, P.reconstruct(views, prior, normals))  # one of each side: fine


def test_odd_photos_are_read_or_refused_in_one_line(tmp_path):
    from PIL import Image

    grey16 = (np.linspace(0, 65535, 64 * 48).reshape(48, 64)).astype(np.uint16)
    Image.fromarray(grey16).save(tmp_path / "g16.png")
    rgb = P.read_photo(tmp_path / "g16.png")
    assert rgb.dtype == np.uint8 and rgb.shape == (48, 64, 3)
    assert rgb[0, 0, 0] < 5 and rgb[-1, -1, 0] > 250  # the full 16-bit range, not clipped white
    big = tmp_path / "big.png"
    Image.new("L", (8000, 5500)).save(big)  # 44 million pixels, each side under the limit
    with pytest.raises(InputFileError, match="44 million pixels; give at most 40 million"):
        P.read_photo(big)
    with pytest.raises(InputFileError, match="not a regular file"):
        P.read_photo("/dev/null")
    with pytest.raises(InputFileError, match="path is empty"):
        P.read_photo("")
    head = generic_head()
    views = synthetic_views(head.landmarks())
    for name in ("mp:\u00b2", "mp:\u0663", "mp:0004", "mp: 4"):
        with pytest.raises(InputFileError, match="unknown point"):
            P.apply_corrections(views, {"front": {name: [1.0, 2.0]}})


FACEWAREHOUSE = DATA / "facewarehouse-tester1"


@pytest.mark.skipif(not FACEWAREHOUSE.is_dir(), reason="../shared/data/facewarehouse-tester1 is not here")
@pytest.mark.parametrize("yaw", [90.0, -90.0])
def test_a_true_profile_gives_the_depth_of_the_midline(yaw):
    """A real head (FaceWarehouse scan) rendered from the front and in true profile: the side view
    goes through the silhouette, its camera is the profile on the right side, and the rebuilt nose
    sticks out from the eyes as far as the scan's does (within 0.05 IOD), nearer than the generic
    head's guess."""
    from faceanim.face.face import Face, landmarks_478
    from faceanim.face.landmarks import detect_landmarks
    from faceanim.io.meshio import load_mesh
    from faceanim.render import OffscreenRenderer

    scan = load_mesh(FACEWAREHOUSE / "pose_0.obj")
    truth = Face(scan, landmarks_478(scan, detect_landmarks(scan)))
    renders = []
    for y in (0.0, yaw):
        with OffscreenRenderer(scan, size=(512, 512), yaw=y, parallel=True, background=(0.5, 0.5, 0.5)) as r:
            renders.append(r.render())
    head = generic_head()
    prior, normals = P.prior_points(head)
    views = P.load_views(("front", renders[0]), [("profile", renders[1])])
    assert views[1].profile and views[1].facing == (-1 if yaw > 0 else 1)
    rec = P.reconstruct(views, prior, normals)
    P.check_views(views, rec)
    assert rec.cameras[1].yaw_degrees == pytest.approx(yaw, abs=8)

    def protrusion(lm, iod):
        eyes = lm[[33, 263, 133, 362]].mean(0)
        return (lm[4, 2] - eyes[2]) / iod

    want = protrusion(truth.landmarks, truth.frame.iod)
    got = protrusion(rec.points, rec.iod)
    generic = protrusion(prior, np.linalg.norm(prior[33] - prior[263]))
    assert abs(got - want) < 0.05
    assert abs(got - want) < abs(generic - want)


def test_a_saved_photo_head_loads_with_its_landmarks_not_detected(tmp_path, monkeypatch):
    """A head with the generic head's topology (written by faceanim photo, or the default face)
    carries its landmarks in its triangles: Face.load reads them off without detection, exactly;
    any other mesh is still detected."""
    import faceanim.face.landmarks as L
    from faceanim.face.default import default_face, default_landmarks
    from faceanim.face.face import Face
    from faceanim.face.mesh import Mesh
    from faceanim.io.meshio import save_mesh

    mesh = default_face()
    save_mesh(mesh, tmp_path / "head.obj")

    def no_detection(*a, **k):
        raise AssertionError("detection was run")

    monkeypatch.setattr(L, "detect_landmarks", no_detection)
    face = Face.load(tmp_path / "head.obj")
    np.testing.assert_allclose(face.landmarks, default_landmarks(mesh).positions, atol=1e-6)
    other = Mesh(mesh.vertices, mesh.faces[:-1])  # one triangle fewer: not the generic topology
    assert generic_head().landmarks_on(other) is None


def test_the_pipeline_gives_a_head_with_its_feature_points():
    """head_from_photos on one real photo (the astronaut): the generic topology, texture
    coordinates for every triangle corner, the 3D MPEG-4 feature points on the head's skin, and the
    rebuilt nose tip where the photo shows it (front camera)."""
    from skimage import data

    ph = P.head_from_photos(("astronaut", data.astronaut()), texture_size=64)
    g = generic_head()
    assert ph.mesh.n_vertices == g.mesh.n_vertices and ph.mesh.face_uv.shape == g.mesh.faces.shape
    assert ph.mesh.texture.shape == (64, 64, 3)
    fdp = ph.feature_points()
    assert {"9.3", "2.1", "8.3", "8.4", "4.1", "11.1"} <= set(fdp)
    np.testing.assert_allclose(fdp["9.3"], ph.landmarks[4], atol=0.002)  # the nose tip, snapped to the skin
    cam = ph.reconstruction.cameras[0]
    assert np.linalg.norm(cam.project(ph.fitted.expressed[g.mesh.faces[g.landmark_triangles[4]]]).mean(0)
                          - ph.views[0].points[4]) < 3.0  # pixels, in a 512 px photo
