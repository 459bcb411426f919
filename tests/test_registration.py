"""The morphable generic head and the one registration every face gets (face/registration.py):
identity modes against ICT's own, the fit against known similarities and identities, the dense
correspondence on another topology, tongueOut, and non-faces refused."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import ICT, need
from faceanim.errors import LandmarkError
from faceanim.face.face import Face
from faceanim.face.generic_head import generic_head
from faceanim.face.mesh import Mesh
from faceanim.face.registration import face_to_head, fit_landmarks, register


def _turn(angle_deg: float, axis: int) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    v = np.zeros(3)
    v[axis] = np.radians(angle_deg)
    return Rotation.from_rotvec(v).as_matrix()


def test_identity_modes_are_icts_own_to_int8_rounding():
    """The asset's 100 modes against the shared float16 source (centimetres -> metres): every
    component within half a rounding step of its mode, and a head sampled with N(0, 1) weights
    within 0.2 mm RMS."""
    modes = np.load(need(ICT / "identity_modes.npz"))["modes"][:, :24591].astype(np.float64) * 0.01
    head = generic_head()
    ours = head.identity_basis().astype(np.float64)
    assert ours.shape == modes.shape == (100, 24591, 3)
    step = np.abs(modes).max(axis=(1, 2)) / 127
    assert np.all(np.abs(ours - modes).max(axis=(1, 2)) <= 0.51 * step + 1e-7)
    w = np.random.default_rng(0).standard_normal(100)
    sampled = head.identity(w) - head.mesh.vertices
    truth = np.einsum("k,kvd->vd", w, modes)
    assert np.sqrt(np.mean(np.sum((sampled - truth) ** 2, axis=1))) < 2e-4


def _known_face(seed: int, count: int = 100, scale: float = 100.0):
    """A head of known identity (``count`` modes at N(0, 1)) under a known similarity, with its
    exact landmarks: (Face, weights, s, R, t)."""
    head = generic_head()
    rng = np.random.default_rng(seed)
    w = np.zeros(100)
    w[:count] = rng.standard_normal(count)
    r = _turn(20, 1) @ _turn(-10, 0)
    t = np.array([3.0, -40.0, 7.0])
    v = head.identity(w)
    moved = scale * v @ r.T + t
    mesh = Mesh(moved, head.mesh.faces.copy(), name=f"known{seed}")
    return Face(mesh, head.landmarks(moved)), w, scale, r, t


def test_landmark_fit_recovers_a_known_similarity_and_the_identitys_large_modes():
    """Exact landmarks of a head of known identity, scaled x100, turned and moved: the fitted
    similarity is the true one (scale within 3%: a bigger head and a smaller scale look alike to
    468 points; rotation within 1.5 degrees) and the ten largest modes' weights come back
    (correlation over 0.9; the prior pulls the small ones towards 0)."""
    for seed in (3, 4, 5):
        face, w, s, r, t = _known_face(seed)
        fs, fr, ft, x, res = fit_landmarks(face.landmarks)
        assert fs == pytest.approx(s, rel=0.03)
        angle = np.degrees(np.arccos(np.clip((np.trace(fr.T @ r) - 1) / 2, -1, 1)))
        assert angle < 1.5
        assert np.corrcoef(x[:10], w[:10])[0, 1] > 0.9
        assert res < 1e-3  # metres on the generic head: the model reproduces the landmarks


def test_registration_of_a_remeshed_head_finds_its_true_surface_points():
    """A known identity resampled on another topology (Loop-free midpoint subdivision, vertex
    order shuffled, the face points' landmarks exact): the registered head's face region lies
    within 2% of an inter-ocular distance of the true head's own vertices (median), and the
    correspondence of the face mesh to the head lands each face vertex on the head's point
    that made it (within 3% IOD, 90th percentile)."""
    import trimesh

    from faceanim.face.regions import face_region

    head = generic_head()
    face0, w, s, r, t = _known_face(7)
    sub_v, sub_f = trimesh.remesh.subdivide(face0.mesh.vertices, face0.mesh.faces)
    perm = np.random.default_rng(1).permutation(len(sub_v))
    inv = np.argsort(perm)
    mesh = Mesh(sub_v[perm], inv[sub_f], name="remeshed")
    face = Face(mesh, face0.landmarks)
    reg = register(face)
    assert reg.coverage > 0.95 and reg.surface_error < 0.005 and reg.landmark_error < 0.01
    iod = face.frame.iod
    region = np.flatnonzero(face_region(head.mesh, head.landmarks()))
    off = np.linalg.norm(reg.vertices[region] - face0.mesh.vertices[region], axis=1) / iod
    assert np.median(off) < 0.02
    tri, bary = face_to_head(face, reg)
    on_head = np.einsum("vc,vcd->vd", bary, face0.mesh.vertices[head.mesh.faces[tri]])
    err = np.linalg.norm(on_head - mesh.vertices, axis=1) / iod
    assert np.percentile(err, 90) < 0.03


def test_a_shuffled_generic_head_corresponds_vertex_for_vertex_to_itself():
    """The generic head with its vertex order shuffled (nothing read off the topology): each
    vertex's corresponding head point is its own original vertex (within 0.5% IOD for 95%)."""
    head = generic_head()
    perm = np.random.default_rng(2).permutation(head.mesh.n_vertices)
    inv = np.argsort(perm)
    mesh = Mesh(head.mesh.vertices[perm], inv[head.mesh.faces], name="shuffled")
    face = Face(mesh, head.landmarks())
    tri, bary = face_to_head(face)
    point = np.einsum("vc,vcd->vd", bary, head.mesh.vertices[head.mesh.faces[tri]])
    err = np.linalg.norm(point - head.mesh.vertices[perm], axis=1) / face.frame.iod
    assert np.percentile(err, 95) < 0.005


def test_tongue_out_opens_the_mouth_and_puts_the_tongue_out_between_the_lips():
    """ARKit's tongueOut on the default face, as Apple's reference shows it: the lips part (the
    lower lip drops with the jaw, by a share of jawOpen), and the tongue goes over 1 cm past the
    lips' front at the default face's scale, between the parted lips: no tongue vertex at the lips'
    depth lies above the upper inner lip or below the lowered lower inner lip (pushed out with the
    lips shut, the tongue went through them)."""
    from faceanim.autorig import auto_rig
    from faceanim.rig.arkit import shows_tongue

    face = Face.default()
    auto = auto_rig(face, ["arkit"])
    assert len(auto.sets["arkit"]) == 52 and "tongueOut" in auto.sets["arkit"] and not auto.notes
    d, jaw = auto.shapes["tongueOut"], auto.shapes["jawOpen"]
    assert shows_tongue(auto.shapes, face.frame.iod)
    skin = np.asarray(face.skin)
    share = np.sum(d[skin] * jaw[skin]) / np.sum(jaw[skin] ** 2)
    assert 0.2 < share < 0.5 and np.abs(d[skin] - share * jaw[skin]).max() < 1e-3 * face.frame.iod
    lips = face.frame.to_local(generic_head().landmarks(face.mesh.vertices + d)[[13, 14]])  # its topology
    rest = face.frame.to_local(face.landmarks[[13, 14]])
    assert lips[0, 1] - lips[1, 1] > 0.1 * face.frame.iod  # parted
    moved = face.frame.to_local(face.mesh.vertices + d)
    iod = face.frame.iod
    lower_lip = skin & (np.abs(moved[:, 0] - lips[1, 0]) < 0.1 * iod) & (np.abs(moved[:, 1] - lips[1, 1]) < 0.15 * iod)
    inner, outer = rest[:, 2].max(), moved[lower_lip, 2].max()  # the lips' depth: inner edge to front
    tongue = ~skin & (np.linalg.norm(d - share * jaw, axis=1) > 1e-3 * iod)
    assert moved[tongue, 2].max() - outer > 0.01 * iod / 0.0906  # over 1 cm past the lips
    # the tongue's cross-section halfway through the lips: where its edges cross that depth
    f = face.mesh.faces[tongue[face.mesh.faces].all(axis=1)]
    a, b = moved[np.vstack([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])].transpose(1, 0, 2)
    depth = (inner + outer) / 2
    t = (depth - a[:, 2]) / np.where(a[:, 2] == b[:, 2], np.nan, b[:, 2] - a[:, 2])
    cross = (a + t[:, None] * (b - a))[(t >= 0) & (t <= 1)]
    assert len(cross) > 10
    assert (cross[:, 1] < lips[0, 1]).all() and (cross[:, 1] > lips[1, 1]).all()


@pytest.mark.skipif(not (ICT.parent / "facewarehouse-tester1").is_dir(), reason="FaceWarehouse scans are not here")
def test_a_scan_without_a_mouth_inside_gets_the_opening_of_tongue_out_and_is_told():
    """A FaceWarehouse scan has no tongue: its tongueOut is the mouth opening alone (a share of
    its own jawOpen, nothing else moves), and faceanim rig says so."""
    from faceanim.autorig import auto_rig
    from faceanim.rig.arkit import NO_TONGUE, shows_tongue

    face = Face.load(ICT.parent / "facewarehouse-tester1" / "pose_0.obj")
    auto = auto_rig(face, ["arkit"])
    assert len(auto.sets["arkit"]) == 52 and not auto.skipped
    d, jaw = auto.shapes["tongueOut"], auto.shapes["jawOpen"]
    share = np.sum(d * jaw) / np.sum(jaw ** 2)
    assert 0.2 < share < 0.5 and np.abs(d - share * jaw).max() < 1e-3 * face.frame.iod
    assert not shows_tongue(auto.shapes, face.frame.iod) and auto.notes == {"tongueOut": NO_TONGUE}


def _nonfaces():
    import trimesh

    rng = np.random.default_rng(0)
    plane = trimesh.Trimesh(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float),
                            np.array([[0, 1, 2], [0, 2, 3]])).subdivide().subdivide().subdivide()
    return {"sphere": trimesh.creation.icosphere(4), "cube": trimesh.creation.box(),
            "torus": trimesh.creation.torus(1.0, 0.3), "plane": plane,
            "noise": trimesh.Trimesh(rng.normal(size=(2000, 3)), rng.integers(0, 2000, (4000, 3)), process=False)}


@pytest.fixture(scope="module")
def nonface_files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("nonfaces")
    out = {}
    for name, m in _nonfaces().items():
        out[name] = folder / f"{name}.obj"
        m.export(out[name])
    return out


@pytest.mark.parametrize("name", ["sphere", "cube", "torus", "plane", "noise"])
def test_non_faces_are_refused_by_face_load(nonface_files, name):
    with pytest.raises(LandmarkError, match="no face found"):
        Face.load(nonface_files[name])


def test_landmarks_that_fit_no_head_are_refused_even_when_given():
    """Landmarks given in a file skip detection; the morphable head still judges them: the generic
    head's own landmarks pass, the same points scattered by 3 cm or squashed flat do not."""
    from faceanim.face.registration import check_face

    head = generic_head()
    lm = head.landmarks()
    # the head's triangles in another order: not recognised as the generic head by its topology
    mesh = Mesh(head.mesh.vertices, head.mesh.faces[::-1].copy(), name="head")
    check_face(Face(mesh, lm))
    rng = np.random.default_rng(4)
    for bad in (lm + rng.normal(scale=0.03, size=lm.shape), lm * np.array([1.0, 1.0, 0.2])):
        with pytest.raises(LandmarkError, match="no face found|mirrored|landmarks"):
            check_face(Face(mesh, bad))


COMMANDS = {
    "landmarks": lambda m, d: ["landmarks", m, "-o", d / "out.json"],
    "rig": lambda m, d: ["rig", m, "-o", d / "out.glb"],
    "au": lambda m, d: ["au", "--face", m, "--au", "12", "-o", d / "out.obj"],
    "preprocess": lambda m, d: ["preprocess", m, "-o", d / "out.obj"],
    "wires extract": lambda m, d: ["wires", "extract", "--face", m, "--template", m, "-o", d / "out.wires.json"],
    "fap play": lambda m, d: ["fap", "play", d / "in.fap", "--face", m, "-o", d / "out.csv"],
    "arkit play": lambda m, d: ["arkit", "play", d / "in.csv", "--face", m, "-o", d / "out.glb"],
}


@pytest.mark.parametrize("command", list(COMMANDS))
def test_every_command_that_takes_a_face_refuses_a_sphere(nonface_files, tmp_path, capsys, command):
    """One line on stderr naming the problem, exit 2, nothing written."""
    from faceanim.cli import main
    from faceanim.face.faps import FapStream
    from faceanim.io.arkit_csv import write_arkit_csv
    from faceanim.standards.arkit import ARKIT_NAMES
    from faceanim.io.fapfile import write_fap

    stream = FapStream.empty(4, 25.0)
    stream.set("open_jaw", np.full(4, 300.0))
    write_fap(tmp_path / "in.fap", stream)
    write_arkit_csv(tmp_path / "in.csv", np.zeros((4, len(ARKIT_NAMES))), 30.0)
    before = sorted(p.name for p in tmp_path.iterdir())
    rc = main([str(a) for a in COMMANDS[command](nonface_files["sphere"], tmp_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "no face found" in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == before


@pytest.mark.skipif(not (ICT.parent / "facewarehouse-tester1").is_dir(), reason="FaceWarehouse scans are not here")
def test_left_and_right_shapes_are_mirror_pairs_on_a_mirrored_mesh():
    """A real scan and its mirror image (x negated, triangles flipped), each rigged on its own
    (landmarks detected on each): every Left shape of the mirror is the mirror image of the
    scan's Right shape, of equal strength (norms within 10%) and the same pattern (cosine over
    0.9), and the other way round."""
    from faceanim.autorig import auto_rig
    from faceanim.face.face import landmarks_478
    from faceanim.face.landmarks import detect_landmarks

    face = Face.load(ICT.parent / "facewarehouse-tester1" / "pose_0.obj")
    flip = np.array([-1.0, 1.0, 1.0])
    mirror = Mesh(face.mesh.vertices * flip, face.mesh.faces[:, ::-1].copy(), name="mirror")
    a = auto_rig(face, ["arkit"]).shapes
    b = auto_rig(Face(mirror, landmarks_478(mirror, detect_landmarks(mirror))), ["arkit"]).shapes
    pairs = [(n, n.replace("Left", "Right")) for n in a if n.endswith("Left")]
    assert len(pairs) >= 20
    for left, right in pairs:
        for x, y in ((b[left], a[right]), (b[right], a[left])):
            y = y * flip
            nx, ny = np.linalg.norm(x), np.linalg.norm(y)
            assert abs(nx - ny) <= 0.1 * max(nx, ny), (left, nx, ny)
            assert float(np.sum(x * y)) / (nx * ny) > 0.9, left


def test_weighted_similarity_ignores_points_of_weight_zero():
    """Umeyama with weights: a known similarity comes back exactly from the pairs of weight 1
    when a third of the pairs are thrown far off and given weight 0 (unweighted, they pull it)."""
    from scipy.spatial.transform import Rotation

    from faceanim.face.frame import similarity

    rng = np.random.default_rng(5)
    a = rng.normal(size=(30, 3))
    r = Rotation.random(random_state=2).as_matrix()
    b = 2.5 * a @ r.T + np.array([1.0, -2.0, 3.0])
    b[:10] += rng.normal(scale=5.0, size=(10, 3))
    w = np.r_[np.zeros(10), np.ones(20)]
    s, fr, t = similarity(a, b, weights=w)
    assert s == pytest.approx(2.5, rel=1e-9) and np.allclose(fr, r, atol=1e-9) and np.allclose(t, [1, -2, 3])
    s0, _, _ = similarity(a, b)
    assert abs(s0 - 2.5) > 0.05


def test_an_open_mouth_is_fitted_as_jaw_open_not_as_tongue_out():
    """tongueOut carries a share of jawOpen: the landmark fit must not split an open mouth between
    them (the registered head would put out its tongue)."""
    from faceanim.face.registration import fit_landmarks

    head = generic_head()
    names = list(head.shape_names)
    opened = head.landmarks(head.mesh.vertices + 0.8 * head.shape("jawOpen"))
    _, _, _, x, _ = fit_landmarks(opened, head)
    weights = dict(zip(names, x[head.n_identity:]))
    assert weights["tongueOut"] == 0 and weights["jawOpen"] > 0.5
