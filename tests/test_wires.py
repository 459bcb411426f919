"""Wire deformation and extraction (Pyun, Shin & Shin 2001): oracles and bad input."""

import json

import numpy as np
import pytest
from conftest import FACEWAREHOUSE, need
from scipy.interpolate import BSpline
from scipy.spatial import cKDTree

from faceanim.cli import main
from faceanim.deform.wires import (
    Curve,
    Wire,
    clamped_knots,
    extract_wires,
    falloff,
    wire_influence,
)
from faceanim.errors import DeformError, FaceAnimError
from faceanim.face.face import landmarks_478
from faceanim.io.meshio import save_mesh
from faceanim.player import render_wires
from faceanim.rig.wires import (
    WireTemplate,
    blend,
    blend_blendshapes,
    blending_function,
    default_wires,
    edit_template,
    extract_template,
)


def test_falloff_and_curve_against_scipy(rng):
    x = np.linspace(0, 1.5, 31)
    np.testing.assert_allclose(falloff(x), np.where(x < 1, (1 - x * x) ** 2, 0.0))
    assert falloff(np.array([0.0]))[0] == 1.0 and falloff(np.array([1.0]))[0] == 0.0
    c = Curve(rng.normal(size=(6, 3)))
    u = np.linspace(0, 1, 50)
    np.testing.assert_allclose(c(u), BSpline(clamped_knots(6), c.control, 3)(u), atol=1e-12)
    np.testing.assert_allclose(c(np.array([0.0, 1.0])), c.control[[0, -1]], atol=1e-12)  # clamped ends


def test_closest_point_matches_dense_search(rng):
    c = Curve(rng.normal(size=(7, 3)))
    p = rng.normal(size=(300, 3))
    _, pr = c.closest(p)
    dense = c(np.linspace(0, 1, 200001))
    d, _ = cKDTree(dense).query(p)
    np.testing.assert_allclose(np.linalg.norm(p - pr, axis=1), d, atol=1e-6)


def test_single_wire_moves_points_on_the_curve_with_it(rng):
    ref = Curve(np.array([[0, 0, 0], [1, 0.2, 0], [2, -0.1, 0], [3, 0.1, 0], [4, 0, 0]], dtype=float))  # planar
    on_curve = ref(np.linspace(0.05, 0.95, 20))
    far = on_curve + [0, 0, 5.0]
    b = wire_influence(np.vstack([on_curve, far]), [Wire(ref, 1.0)], k=2)
    shift = np.array([0.0, 0.3, 0.0])
    moved = b.apply([ref.control + shift], [1.0])
    np.testing.assert_allclose(moved[:20] - on_curve, np.tile(shift, (20, 1)), atol=1e-9)  # f(0) = 1
    np.testing.assert_array_equal(moved[20:], far)  # out of range: f = 0
    # s = 1 is no scaling; s scales the offset from the curve where f > 0
    near = on_curve + [0, 0, 0.5]
    b2 = wire_influence(near, [Wire(ref, 1.0)], k=2)
    scaled = b2.apply(None, [2.0])
    np.testing.assert_allclose(scaled - near, (near - on_curve) * falloff(np.array([0.5]))[0], atol=1e-6)


def test_operator_equals_direct_formula_and_extraction_is_exact(rng):
    verts = rng.normal(size=(3000, 3))
    wires = [Wire(Curve(rng.normal(size=(5, 3))), 1.2, "a"),
             Wire(Curve(rng.normal(size=(8, 3))), np.linspace(0.8, 1.4, 8), "b")]
    b = wire_influence(verts, wires, k=2)
    controls = [w.reference.control + 0.1 * rng.normal(size=w.reference.control.shape) for w in wires]
    scales = np.array([1.25, 0.8])
    # oracle: eqs. 2-3 evaluated directly, vertex by vertex through the bound quantities
    direct = b.rest.copy()
    for j, w in enumerate(b.wires):
        direct += b.weights[:, j:j + 1] * ((scales[j] - 1.0) * b.radial[j] + b.basis[j] @ (controls[j] - w.reference.control))
    np.testing.assert_allclose(b.apply(controls, scales), direct, atol=1e-12)
    got_c, got_s = extract_wires(b, b.apply(controls, scales))
    np.testing.assert_allclose(got_s, scales, atol=1e-6)
    for g, c in zip(got_c, controls):
        np.testing.assert_allclose(g, c, atol=1e-6)


@pytest.fixture(scope="module")
def face_wires(base_face):
    lm = landmarks_478(base_face, _landmarks(base_face))
    return lm, default_wires(lm)


def _landmarks(mesh):
    """The default face's 478 landmarks (on its triangles, not its vertices)."""
    from faceanim.face.default import default_landmarks

    return default_landmarks(mesh)


def test_default_wires_sit_on_the_face(base_face, face_wires):
    lm, ws = face_wires
    assert len(ws.wires) == 15 and {"eyes", "mouth", "brows"} <= set(ws.groups)
    iod = np.linalg.norm(lm[263] - lm[33])
    for w in ws.wires:
        _, dist, _ = base_face.closest_points(w.reference(np.linspace(0, 1, 30)))
        assert dist.max() < 0.15 * iod, w.name
    img = render_wires(base_face, ws, size=128)
    assert img.shape == (128, 128, 3)


def test_template_round_trip_and_exact_recovery_on_a_face(tmp_path, base_face, face_wires, rng):
    lm, ws = face_wires
    bound = ws.influence(base_face, lm)
    controls = [w.reference.control + rng.normal(scale=0.002, size=w.reference.control.shape) for w in ws.wires]
    scales = rng.uniform(0.8, 1.2, len(ws.wires))
    template = base_face.with_vertices(bound.apply(controls, scales))
    t = extract_template(base_face, template, ws, bound)
    for g, c in zip(t.controls, controls):
        np.testing.assert_allclose(g, c, atol=1e-6)
    t.save(tmp_path / "t.wires.json")
    back = WireTemplate.load(tmp_path / "t.wires.json")
    np.testing.assert_allclose(back.rebuild(base_face, lm478=lm), template.vertices, atol=1e-6)
    # local editing: one lip control point moves only the skin near the lip
    j = ws.names.index("upper_lip")
    edited = edit_template(back, {j: [(3, np.array([0, 0.003, 0]))]}, {}).rebuild(base_face, lm478=lm)
    moved = np.linalg.norm(edited - back.rebuild(base_face, lm478=lm), axis=1)
    assert moved.max() > 0.001 and moved[base_face.vertices[:, 1] > lm[168, 1]].max() < 1e-9


def test_blending_functions_and_blendshapes_are_exact(base_face, face_wires, rng):
    lm, ws = face_wires
    bound = ws.influence(base_face, lm)
    make = lambda: WireTemplate(ws, [w.reference.control + rng.normal(scale=0.002, size=w.reference.control.shape)
                                     for w in ws.wires], rng.uniform(0.9, 1.1, len(ws.wires)), base_face.n_vertices)
    a, b = make(), make()
    funcs = {"eyes": "sqrt", "mouth": "cubic"}
    shapes = blend_blendshapes(a, b, bound)
    for t in (0.0, 0.3, 1.0):
        direct = blend(a, b, t, funcs).rebuild(base_face, bound) - base_face.vertices
        via = shapes["from"] + sum(blending_function(funcs.get(g, "linear"))(t) * d
                                   for g, d in shapes.items() if g != "from")
        np.testing.assert_allclose(via, direct, atol=1e-10)
    np.testing.assert_allclose(blend(a, b, 1.0, funcs).controls[0], b.controls[0])
    assert blending_function("0,0.5,1")(0.25) == pytest.approx(0.25)
    with pytest.raises(DeformError, match="blending function"):
        blending_function("wobbly")


def test_bad_wires_and_templates(base_face, face_wires, rng):
    _, ws = face_wires
    with pytest.raises(DeformError, match="at least 4"):
        Curve(rng.normal(size=(3, 3)))
    pts = rng.normal(size=(5, 3))
    pts[2] = pts[1]
    with pytest.raises(DeformError, match="coincide"):
        Curve(pts)
    with pytest.raises(DeformError, match="positive"):
        Wire(Curve(rng.normal(size=(5, 3))), 0.0, "flat")
    far = Wire(Curve(rng.normal(size=(5, 3)) + 100.0), 0.01, "lost")
    b = wire_influence(base_face.vertices, ws.wires + [far], 2)
    with pytest.raises(DeformError, match="lost"):
        extract_wires(b, base_face.vertices)
    with pytest.raises(FaceAnimError, match="topology|vertices"):
        extract_wires(b, base_face.vertices[:-1])


def test_cli_extract_apply_blend(tmp_path, base_face, face_wires, rng, capsys):
    lm, ws = face_wires
    base = tmp_path / "base.obj"
    save_mesh(base_face, base)
    lmf = tmp_path / "lm.json"
    lmf.write_text(json.dumps({"points": [{"index": i, "position": p.tolist()} for i, p in enumerate(lm)]}))
    bound = ws.influence(base_face, lm)
    files = []
    for n in range(2):
        controls = [w.reference.control + rng.normal(scale=0.002, size=w.reference.control.shape) for w in ws.wires]
        tpl = tmp_path / f"t{n}.obj"
        save_mesh(base_face, tpl, vertices=bound.apply(controls, np.ones(len(ws.wires))))
        out = tmp_path / f"t{n}.wires.json"
        assert main(["wires", "extract", "--base", str(base), "--template", str(tpl), "--landmarks", str(lmf),
                     "-o", str(out), "--no-align"]) == 0
        assert "rebuild error 0.000" in capsys.readouterr().out
        files.append(out)
    edit = tmp_path / "edit.json"
    edit.write_text(json.dumps({"edits": [{"wire": "brow_L", "scale": 1.3}]}))
    assert main(["wires", "apply", "--base", str(base), "--wires", str(files[0]), "--landmarks", str(lmf),
                 "--edit", str(edit), "-o", str(tmp_path / "a.obj")]) == 0
    assert main(["wires", "blend", "--base", str(base), "--from", str(files[0]), "--to", str(files[1]),
                 "--landmarks", str(lmf), "--eyes", "sqrt", "--mouth", "cubic", "--frames", "5",
                 "-o", str(tmp_path / "b.glb")]) == 0
    import pygltflib

    assert main(["wires", "blend", "--base", str(base), "--from", str(files[0]), "--to", str(files[1]),
                 "--to", str(files[0]), "--landmarks", str(lmf), "--frames", "4", "-o", str(tmp_path / "c.glb")]) == 0
    names = pygltflib.GLTF2().load(str(tmp_path / "c.glb")).meshes[0].extras["targetNames"]
    assert names[0] == "from" and "mouth@1" in names and "mouth@2" in names
    # bad input: unknown wire in an edit, another topology, a broken wire file
    edit.write_text(json.dumps({"edits": [{"wire": "tail", "scale": 2}]}))
    assert main(["wires", "apply", "--base", str(base), "--wires", str(files[0]), "--landmarks", str(lmf),
                 "--edit", str(edit), "-o", str(tmp_path / "x.obj")]) == 2
    assert "unknown wire" in capsys.readouterr().err
    bad = tmp_path / "bad.wires.json"
    bad.write_text(json.dumps({"wires": [{"name": "x"}]}))
    assert main(["wires", "apply", "--base", str(base), "--wires", str(bad), "--landmarks", str(lmf),
                 "-o", str(tmp_path / "x.obj")]) == 2
    assert not (tmp_path / "x.obj").exists()


def test_real_templates_rebuild(tmp_path):
    """A real FaceWarehouse smile through its wires: far closer than no motion."""
    from faceanim.face.landmarks import detect_landmarks
    from faceanim.face.regions import face_region
    from faceanim.io.meshio import load_mesh
    from faceanim.rig.wires import align_template

    base = load_mesh(need(FACEWAREHOUSE / "pose_0.obj"))
    lm = landmarks_478(base, detect_landmarks(base))
    template = align_template(base, load_mesh(FACEWAREHOUSE / "pose_2.obj"), lm)
    ws = default_wires(lm)
    t = extract_template(base, template, ws, lm478=lm)
    face = face_region(base, lm)
    err = np.linalg.norm((t.rebuild(base, lm478=lm) - template.vertices)[face]) / np.linalg.norm(
        (template.vertices - base.vertices)[face])
    assert err < 0.4  # measured 0.29; no motion is 1.0


def test_wires_move_the_skin_not_the_eyeballs_or_teeth():
    """On a head with eyeballs, teeth, gums and tongue as shells, wires bound with the face's
    landmarks move only the skin (each shell is rigid or driven by a rigid part elsewhere)."""
    from faceanim.face.default import default_parts
    from faceanim.face.face import Face
    from faceanim.rig.wires import default_wires

    face = Face.default()
    bound = default_wires(face.landmarks).influence(face.mesh, face.landmarks)
    moving = bound.deformer().moving_vertices
    parts = default_parts()
    inner = np.concatenate([parts[k] for k in ("teeth", "gums_tongue", "eyeball_L", "eyeball_R")])
    assert not np.isin(inner, moving).any()
    assert np.isin(moving, parts["skin"]).all() and len(moving) > 5000
