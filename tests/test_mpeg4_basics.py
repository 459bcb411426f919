"""MPEG-4 basics: the FAP table, FAP streams, .fap files, feature points and FAPU."""

import numpy as np
import pytest

from faceanim.drivers.mpeg4 import FapStream
from faceanim.errors import InputFileError, LandmarkError
from faceanim.face.face import Face, landmarks_478
from faceanim.standards.mpeg4 import FapError, direction_vector, fap, faps
from faceanim.face.fdp import feature_points
from faceanim.face.frame import face_frame
from faceanim.io.fapfile import parse_fap, read_fap, write_fap


def test_fap_table():
    table = faps()
    assert len(table) == 68 and [f.number for f in table] == list(range(1, 69))
    assert len({f.name for f in table}) == 68
    assert fap(3).name == "open_jaw" and fap(3).unit == "MNS" and fap(3).feature_points == ("2.1",)
    assert fap("head_yaw").is_rotation and fap("head_yaw").number == 49
    np.testing.assert_array_equal(direction_vector(fap("stretch_l_cornerlip")), [1, 0, 0])  # the face's left
    np.testing.assert_array_equal(direction_vector(fap("open_jaw")), [0, -1, 0])
    assert sum(f.is_rotation for f in table) == 8  # eyeball yaw and pitch, tongue roll, head pitch/yaw/roll
    for bad in (0, 69, "nose_flare", "x1"):
        with pytest.raises(FapError):
            fap(bad)


def _random_stream(rng, frames=12):
    s = FapStream.empty(frames, fps=30, name="C:\\Documents and Settings\\me\\talk.fap")
    s.mask[:] = rng.random((frames, 68)) < 0.3
    s.values[:, 2:] = np.where(s.mask[:, 2:], rng.integers(-500, 500, (frames, 66)), 0)
    s.values[3, 10] = 12.5
    s.mask[3, 10] = True
    s.mask[:, 0] = True
    s.viseme[:] = rng.integers(0, 15, (frames, 4))
    s.expression[:] = rng.integers(0, 7, (frames, 6))
    s.frame_numbers[:] = np.arange(frames) + 100
    return s


def test_fap_round_trip_is_exact(tmp_path, rng):
    s = _random_stream(rng)
    path = write_fap(tmp_path / "a.fap", s, integers=False)
    back = read_fap(path)
    assert back.name == s.name and back.fps == s.fps and back.n_frames == s.n_frames
    np.testing.assert_array_equal(back.mask, s.mask)
    np.testing.assert_array_equal(back.values, s.values)
    np.testing.assert_array_equal(back.viseme, s.viseme)
    np.testing.assert_array_equal(back.frame_numbers, s.frame_numbers)
    np.testing.assert_array_equal(back.expression[:, :], np.where(s.mask[:, 1:2], s.expression, 0))
    # by default values are whole FAPU units, as the format has them
    rounded = read_fap(write_fap(tmp_path / "b.fap", s))
    assert rounded.values[3, 10] == 12 and np.array_equal(np.delete(rounded.values, 10, 1), np.delete(s.values, 10, 1))


def test_real_world_quirks():
    mask = ["0"] * 68
    mask[2] = "1"   # open_jaw
    mask[47] = "1"  # head_pitch
    text = ("# made by hand\r\n\r\n2.1   D:\\fap files\\hello world.fap   25   2   \r\n"
            + " ".join(mask) + "  \r\n0 120 -300 \r\n# a comment between frames\n"
            + " ".join(["0"] * 68) + "\n1\n")
    s = parse_fap(text, "x.fap")
    assert s.name == "D:\\fap files\\hello world.fap" and s.fps == 25 and s.n_frames == 2
    assert s.column("open_jaw")[0] == 120 and s.column(48)[0] == -300 and not s.mask[1].any()


@pytest.mark.parametrize("text, message", [
    ("", "no header"),
    ("2.1 x 25\n", "header needs"),
    ("2.1 x 25 2\n" + "0 " * 68 + "\n0\n", "promises 2 frames but the file has 1"),
    ("2.1 x 25 1\n" + "0 " * 67 + "\n0\n", ":2: a mask line needs 68 bits"),
    ("2.1 x 25 1\n1 " + "0 " * 67 + "\n0\n", ":3: the mask on line 2 sets 1 FAPs, so this line needs 5 numbers"),
    ("2.1 x 25 1\n0 0 1 " + "0 " * 65 + "\n0 abc\n", ":3: value is not a number"),
    ("2.1 x -5 0\n", "frame rate must be positive"),
    ("2.1 x 25 1\n" + "2 " * 68 + "\n0\n", "mask bits must be 0 or 1"),
])
def test_malformed_files_name_the_line(text, message):
    with pytest.raises(InputFileError, match=message.replace("(", r"\(")):
        parse_fap(text, "bad.fap")


def test_missing_file(tmp_path):
    with pytest.raises(InputFileError, match="does not exist"):
        read_fap(tmp_path / "nope.fap")


def test_feature_points_and_fapu(face, face_landmarks):
    lm = landmarks_478(face, face_landmarks)
    fp = feature_points(face, lm)
    frame = face_frame(lm)
    # oracles straight from the landmarks: pupils (irises) and outer lip corners
    es = abs(frame.to_local(lm[473])[0] - frame.to_local(lm[468])[0])
    assert fp.fapu["ES"] == pytest.approx(es, rel=1e-9)
    mw = abs(frame.to_local(lm[291])[0] - frame.to_local(lm[61])[0])
    assert fp.fapu["MW"] == pytest.approx(mw, rel=0.05)
    assert fp.unit("ES0") == pytest.approx(fp.fapu["ES"] / 1024) and fp.unit("AU") == 1e-5
    # the face's left is +x: left mouth corner 8.3 to the left of the right one 8.4
    assert frame.to_local(fp["8.3"])[0] > frame.to_local(fp["8.4"])[0]
    assert frame.to_local(fp["2.1"])[1] < frame.to_local(fp["9.15"])[1] < frame.to_local(fp["3.5"])[1]
    assert "6.1" in fp.missing and "10.1" in fp.missing
    with pytest.raises(LandmarkError, match="tongue"):
        fp["6.1"]


@pytest.fixture(scope="module")
def fap_rig(face, face_landmarks):
    from faceanim.rig.mpeg4 import FapRig

    return FapRig.build(Face(face, landmarks_478(face, face_landmarks)))


def test_linear_faps_move_their_feature_point_by_the_fapu(fap_rig, face):
    fp = fap_rig.points
    s = FapStream.empty(3)
    s.set("raise_l_cornerlip", 200, frames=[1])
    s.set("stretch_r_cornerlip", -150, frames=[2])
    v = fap_rig.evaluate(s)
    np.testing.assert_array_equal(v[0], face.vertices)  # an empty frame is the neutral face
    _, i = face.kdtree.query(fp["2.4"])
    moved = fp.frame.vectors_to_local(v[1][i] - face.vertices[i])
    np.testing.assert_allclose(moved, [0, 200 * fp.unit("MNS"), 0], atol=1e-12)
    _, j = face.kdtree.query(fp["2.5"])
    moved = fp.frame.vectors_to_local(v[2][j] - face.vertices[j])
    # -right = left (+x); 2.5 lies inside a triangle, so its nearest vertex moves by nearly (1e-4) its own amount
    np.testing.assert_allclose(moved, [150 * fp.unit("MW"), 0, 0], rtol=1e-3, atol=1e-9)
    # linear: twice the value, twice the displacement
    np.testing.assert_allclose(fap_rig.blendshape("raise_l_cornerlip")[i] * 200, v[1][i] - face.vertices[i])


def test_rotations_and_unsupported_faps(fap_rig, face):
    fp = fap_rig.points
    s = FapStream.empty(3)
    s.set("head_yaw", 30000, frames=[0])  # 0.3 rad to the face's left
    s.set("open_jaw", 400, frames=[1])
    s.set("raise_tongue_tip", 100, frames=[2])
    v = fap_rig.evaluate(s)
    # the head turns rigidly: distances kept, the gaze turned towards +x by 0.3 rad
    d0 = np.linalg.norm(face.vertices[::97] - face.vertices[5], axis=1)
    np.testing.assert_allclose(np.linalg.norm(v[0][::97] - v[0][5], axis=1), d0, atol=1e-12)
    tip = face.kdtree.query(fp["9.3"])[1]  # the vertex nearest the nose tip (9.3 lies inside a triangle)
    nose = fp.frame.to_local(v[0][tip]) - fp.frame.to_local(fp["7.1"])
    nose0 = fp.frame.to_local(face.vertices[tip]) - fp.frame.to_local(fp["7.1"])
    turn = np.arctan2(nose[0], nose[2]) - np.arctan2(nose0[0], nose0[2])
    assert turn == pytest.approx(0.3, abs=1e-9)
    # the jaw drops the chin by about open_jaw * MNS / 1024 and leaves the eyes alone
    _, c = face.kdtree.query(fp["2.1"])
    drop = -fp.frame.vectors_to_local(v[1][c] - face.vertices[c])[1]
    assert drop == pytest.approx(400 * fp.unit("MNS"), rel=0.02)
    _, e = face.kdtree.query(fp["3.1"])
    np.testing.assert_array_equal(v[1][e], face.vertices[e])
    # values past the limits are clamped and reported
    big = FapStream.empty(1)
    big.set("raise_l_cornerlip", 10000)
    assert any("clamped" in w for w in fap_rig.check(big))
    np.testing.assert_allclose(fap_rig.evaluate(big)[0], face.vertices + 4096 * fap_rig.blendshape("raise_l_cornerlip"))
    # open_jaw is unidirectional (faps.json): a negative value is clamped to 0, not a jaw pushed up
    up = FapStream.empty(1)
    up.set("open_jaw", -500)
    assert any("open_jaw" in w and "[0, 4096]" in w for w in fap_rig.check(up))
    np.testing.assert_array_equal(fap_rig.evaluate(up)[0], face.vertices)
    # the tongue's feature points are not placed (the default head's tongue is a shell inside the
    # mouth, but no landmark finds its tip): the FAP is reported and does nothing
    assert any("raise_tongue_tip" in w for w in fap_rig.check(s))
    np.testing.assert_array_equal(v[2], face.vertices)


def _check_eyeball_turn(rig, head, parts=None):
    assert rig.eyes["L"] is not None and rig.eyes["R"] is not None and 23 not in rig.unsupported
    s = FapStream.empty(1)
    s.set("yaw_l_eyeball", 20000)  # 0.2 rad to the face's left
    v = rig.evaluate(s)[0]
    rows, centre = rig.eyes["L"]
    if parts is not None:  # the rows are exactly the left eyeball's shell
        np.testing.assert_array_equal(np.sort(rows), parts["eyeball_L"])
    moved = np.zeros(head.n_vertices, dtype=bool)
    moved[rows] = True
    np.testing.assert_array_equal(v[~moved], head.vertices[~moved])
    before = rig.points.frame.vectors_to_local(head.vertices[rows] - centre)
    after = rig.points.frame.vectors_to_local(v[rows] - centre)
    np.testing.assert_allclose(np.linalg.norm(after, axis=1), np.linalg.norm(before, axis=1), atol=1e-9)
    front = before[:, 2].argmax()  # the front of the eye (the cornea) turns by 0.2 rad about y
    turn = np.arctan2(after[front, 0], after[front, 2]) - np.arctan2(before[front, 0], before[front, 2])
    assert turn == pytest.approx(0.2, abs=1e-6)


def test_eyeballs_turn_on_a_head_that_has_them(fap_rig, face):
    from conftest import ICT, need

    from faceanim.face.default import default_parts
    from faceanim.face.landmarks import detect_landmarks
    from faceanim.io.meshio import load_mesh
    from faceanim.rig.mpeg4 import FapRig

    # the default face is a whole head with eyeballs
    _check_eyeball_turn(fap_rig, face, default_parts())
    head = load_mesh(need(ICT / "generic_neutral_mesh.obj"))
    _check_eyeball_turn(FapRig.build(Face(head, landmarks_478(head, detect_landmarks(head)))), head)


def test_a_face_mask_has_no_eyeballs_to_turn(face, face_landmarks):
    """The default head's skin alone (no inner shells): the eyeball FAPs are reported, as for any
    face mask, and do nothing."""
    from faceanim.face.default import default_parts
    from faceanim.face.mesh import Mesh
    from faceanim.rig.mpeg4 import FapRig

    skin = default_parts()["skin"]
    keep = np.all(np.isin(face.faces, skin), axis=1)
    new = np.full(face.n_vertices, -1)
    new[skin] = np.arange(skin.size)
    mask = Mesh(face.vertices[skin], new[face.faces[keep]])
    rig = FapRig.build(Face(mask, face_landmarks.positions))
    assert all(rig.eyes[k] is None for k in "LR")
    assert {23, 24, 25, 26} <= set(rig.unsupported)
    s = FapStream.empty(1)
    s.set("yaw_l_eyeball", 20000)
    np.testing.assert_array_equal(rig.evaluate(s)[0], mask.vertices)


def test_a_low_poly_eyeball_is_found_and_turns_about_its_centre(face, face_landmarks):
    """A game avatar's eyeball: a closed sphere whose vertices crowd its front (the mean of its
    vertices lies far in front of its centre, so the spread about that mean is not round). It is
    found, and turns about the sphere's own centre, not the vertices' mean."""
    import trimesh

    from faceanim.face.default import default_parts
    from faceanim.face.mesh import Mesh
    from faceanim.rig.mpeg4 import FapRig

    parts = default_parts()
    skin = parts["skin"]
    keep = np.all(np.isin(face.faces, skin), axis=1)
    new = np.full(face.n_vertices, -1)
    new[skin] = np.arange(skin.size)
    vertices, faces = [face.vertices[skin]], [new[face.faces[keep]]]
    frame = face_frame(face_landmarks.positions)
    forward = frame.rotation[2]
    ball = trimesh.creation.icosphere(subdivisions=2)
    unit = ball.vertices / np.linalg.norm(ball.vertices, axis=1, keepdims=True)
    # pull every vertex along the sphere towards the front pole: the same sphere, crowded in front
    pole = np.array([0.0, 0.0, 1.0])
    angle = np.arccos(np.clip(unit @ pole, -1, 1))
    axis = np.cross(pole, unit)
    norm = np.linalg.norm(axis, axis=1, keepdims=True)
    axis = np.where(norm > 1e-9, axis / np.maximum(norm, 1e-12), [1.0, 0.0, 0.0])
    from scipy.spatial.transform import Rotation

    crowded = Rotation.from_rotvec(axis * (0.6 * angle)[:, None]).apply(pole)
    to_face = Rotation.align_vectors([forward], [pole])[0]
    centres = {}
    for side in ("L", "R"):
        shell = face.vertices[parts[f"eyeball_{side}"]]
        centre, radius = shell.mean(axis=0) - 0.2 * frame.iod * forward, 0.12 * frame.iod
        centres[side] = centre
        faces.append(ball.faces + sum(len(v) for v in vertices))
        vertices.append(centre + radius * to_face.apply(crowded))
    mesh = Mesh(np.vstack(vertices), np.vstack(faces))
    rows = np.arange(len(vertices[0]), len(vertices[0]) + len(crowded))
    p = mesh.vertices[rows]
    dist = np.linalg.norm(p - p.mean(axis=0), axis=1)
    assert dist.std() > 0.25 * dist.mean()  # the vertices' mean test alone would refuse it
    assert np.linalg.norm(p.mean(axis=0) - centres["L"]) > 0.3 * 0.12 * frame.iod
    eyes = FapRig.build(Face(mesh, face_landmarks.positions)).eyes
    for side in ("L", "R"):
        assert eyes[side] is not None
        np.testing.assert_allclose(eyes[side][1], centres[side], atol=1e-6 * frame.iod)


def test_glb_linearisation_of_the_jaw_and_head_is_their_exact_derivative(fap_rig, face):
    """What a glTF morph target stores for open_jaw, thrust_jaw, the head turns: the derivative of
    the true (rotating) motion at the neutral pose, against central finite differences."""
    for name, h in (("open_jaw", 1e-3), ("thrust_jaw", 1e-3), ("shift_jaw", 1e-3), ("head_pitch", 1e-2),
                    ("head_yaw", 1e-2), ("head_roll", 1e-2), ("raise_b_midlip", 1e-3)):
        from faceanim.standards.mpeg4 import fap

        one_sided = fap(name).bidirectional is False  # cannot go negative (open_jaw, thrust_jaw)
        fd = fap_rig.pose({name: h}) - fap_rig.pose({name: 0.0 if one_sided else -h})
        fd /= h if one_sided else 2 * h
        lin = fap_rig.linearised(name)
        scale = np.abs(lin).max()
        assert scale > 0, name
        np.testing.assert_allclose(lin, fd, atol=2e-3 * scale, err_msg=name)


def test_every_eyelid_fap_moves_its_lid_on_whole_heads():
    """Each of the four eyelid FAPs moves skin on the default face and on the generic head (a lid's
    feature point can lie nearer the eyeball under it than any skin vertex; its influence was
    measured along the eyeball's shell and the FAP moved nothing: found on the generic head's
    right upper lid and the default face's right lower lid)."""
    from faceanim.face.face import Face
    from faceanim.face.generic_head import generic_head
    from faceanim.rig.mpeg4 import FapRig

    head = generic_head()
    for face in (Face.default(), Face(head.mesh, head.landmarks())):
        rig = FapRig.build(face)
        moved = {n: float(np.abs(rig.linearised(n)).max())
                 for n in ("close_t_l_eyelid", "close_t_r_eyelid", "close_b_l_eyelid", "close_b_r_eyelid")}
        assert min(moved.values()) > 0.5 * max(moved.values()) > 0, moved
