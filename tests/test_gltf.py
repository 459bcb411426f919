"""glTF export: morph targets and their animation, read back and checked by Khronos' validator;
the quantised (KHR_mesh_quantization) variant read back and dequantised here, by hand, from the
glTF spec."""

import json
import shutil
import subprocess

import numpy as np
import pygltflib
import pytest
from conftest import ROOT
from gltf_reader import accessor as _accessor

from faceanim.errors import FaceAnimError
from faceanim.io.gltf import write_gltf

VALIDATOR = ROOT / "tools" / "validate_gltf.js"
# the quantised file's stated accuracy: no coordinate off by more than this share of the face's
# bounding-box diagonal (half a step is 5.4e-6 of it on the default head, when no delta widens the
# scale; see the report in benchmarks/bench_gltf.py)
QUANTIZED_RELATIVE_BOUND = 1e-4


def _validate(path):
    if shutil.which("node") is None or not (ROOT / "tools" / "node_modules" / "gltf-validator").exists():
        pytest.skip("node or the gltf-validator npm package is missing (scripts/setup.sh installs it)")
    out = subprocess.run(["node", str(VALIDATOR), str(path)], capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def _source_vertex(gltf, prim, mesh):
    """The glTF vertex -> mesh vertex map, checked against the layout docs/formats.md states: the
    mesh's own vertices first, in order, then the seam copies (one per extra UV of a vertex), and
    the triangles are the mesh's triangles."""
    n = gltf.accessors[prim.attributes.POSITION].count
    src = np.asarray((prim.extras or {}).get("sourceVertex", np.arange(n)), dtype=np.int64)
    assert src.shape == (n,) and n == len(mesh.per_vertex_uv()[0])
    np.testing.assert_array_equal(src[: mesh.n_vertices], np.arange(mesh.n_vertices))
    assert src[mesh.n_vertices:].max(initial=0) < mesh.n_vertices
    np.testing.assert_array_equal(src[_accessor(gltf, prim.indices).reshape(-1, 3).astype(np.int64)], mesh.faces)
    return src


def _smooth_local_deltas(mesh, n, rng, radius=0.015, amplitude=0.005):
    """``n`` Gaussian bumps, each moving the vertices near one random vertex (cut at 1e-3 of the peak)."""
    v = mesh.vertices
    shapes = {}
    for k, c in enumerate(rng.choice(len(v), size=n, replace=False)):
        w = np.exp(-np.sum((v - v[c]) ** 2, axis=1) / (2 * radius**2))
        w[w < 1e-3] = 0
        shapes[f"bump{k:02d}"] = w[:, None] * rng.normal(scale=amplitude, size=3)
    return shapes


@pytest.fixture(scope="module")
def exported(tmp_path_factory, base_face):
    rng = np.random.default_rng(0)
    local = np.zeros(base_face.vertices.shape)
    local[100:160] = rng.normal(scale=1e-3, size=(60, 3))  # stored as a sparse accessor
    shapes = {"smile": rng.normal(scale=1e-3, size=base_face.vertices.shape), "A": local}
    times = np.linspace(0, 2, 9)
    weights = np.stack([np.sin(times) ** 2, np.cos(times) ** 2], axis=1)
    path = tmp_path_factory.mktemp("gltf") / "face.glb"
    write_gltf(path, base_face, shapes, times, weights)
    return path, shapes, times, weights


def test_morph_targets_and_animation_read_back(exported, base_face):
    path, shapes, times, weights = exported
    gltf = pygltflib.GLTF2().load(str(path))
    prim = gltf.meshes[0].primitives[0]
    assert gltf.meshes[0].extras["targetNames"] == ["smile", "A"]
    # the head has UV seams: seam copies follow its own vertices and move with them
    src = _source_vertex(gltf, prim, base_face)
    assert len(src) > base_face.n_vertices
    np.testing.assert_allclose(_accessor(gltf, prim.attributes.POSITION), base_face.vertices[src], atol=1e-6)
    for k, name in enumerate(["smile", "A"]):
        np.testing.assert_allclose(_accessor(gltf, prim.targets[k]["POSITION"]), shapes[name][src], atol=1e-7)
    # every corner keeps its own texture coordinate (glTF's v runs downwards)
    uv = _accessor(gltf, prim.attributes.TEXCOORD_0)[_accessor(gltf, prim.indices).reshape(-1, 3).astype(np.int64)]
    want = base_face.uv[base_face.face_uv]
    np.testing.assert_allclose(uv, np.stack([want[..., 0], 1 - want[..., 1]], axis=-1), atol=1e-6)
    sampler = gltf.animations[0].samplers[0]
    np.testing.assert_allclose(_accessor(gltf, sampler.input), times, atol=1e-6)
    np.testing.assert_allclose(_accessor(gltf, sampler.output).reshape(-1, 2), weights, atol=1e-6)
    assert gltf.animations[0].channels[0].target.path == "weights"
    # rows 100..159 move, and so do their seam copies
    assert gltf.accessors[prim.targets[1]["POSITION"]].sparse.count == np.isin(src, np.arange(100, 160)).sum() >= 60
    assert gltf.images and gltf.materials[0].pbrMetallicRoughness.baseColorTexture.index == 0
    # the plain file: float data, no extension, no node transform, no scene extras
    assert not gltf.extensionsUsed and not gltf.extensionsRequired
    assert gltf.nodes[0].scale is None and gltf.nodes[0].translation is None
    assert not gltf.scenes[0].extras


def test_khronos_validator_reports_no_errors(exported):
    report = _validate(exported[0])
    assert report["numErrors"] == 0, report["messages"]
    assert report["numWarnings"] == 0, report["messages"]


@pytest.fixture(scope="module")
def quantized(tmp_path_factory, base_face):
    rng = np.random.default_rng(1)
    v = base_face.vertices
    shapes = _smooth_local_deltas(base_face, 6, rng)
    shapes["smile"] = rng.normal(scale=1e-3, size=v.shape)  # dense
    lower = np.clip((v[:, 1].mean() - v[:, 1]) / np.ptp(v[:, 1]), 0, None)
    shapes["jaw"] = np.outer(lower, [0.0, -0.03, -0.01])  # large and smooth: 2-3 cm at the chin
    shapes["tiny"] = np.full(v.shape, 1e-8)  # below half a quantisation step everywhere
    times = np.linspace(0, 2, 9)
    weights = np.abs(np.sin(np.outer(times, np.arange(1, len(shapes) + 1))))
    folder = tmp_path_factory.mktemp("gltfq")
    plain = write_gltf(folder / "plain.glb", base_face, shapes, times, weights)
    path = write_gltf(folder / "face_q.glb", base_face, shapes, times, weights, quantize=True,
                      extras={"audio": "speech.wav", "fps": 30, "tags": ["joy", None]})
    return path, plain, shapes, times, weights


def test_quantized_output_dequantises_within_the_stated_bound(quantized, base_face):
    path, plain, shapes, times, weights = quantized
    gltf = pygltflib.GLTF2().load(str(path))
    assert gltf.extensionsUsed == ["KHR_mesh_quantization"]
    assert gltf.extensionsRequired == ["KHR_mesh_quantization"]
    prim = gltf.meshes[0].primitives[0]
    names = list(shapes)
    assert gltf.meshes[0].extras["targetNames"] == names
    acc = gltf.accessors
    kinds = {"POSITION": (pygltflib.SHORT, True), "NORMAL": (pygltflib.BYTE, True),
             "TEXCOORD_0": (pygltflib.UNSIGNED_SHORT, True)}
    for attr, (component, normalized) in kinds.items():
        a = acc[getattr(prim.attributes, attr)]
        assert (a.componentType, bool(a.normalized)) == (component, normalized), attr
    assert acc[prim.indices].componentType == pygltflib.UNSIGNED_SHORT
    node = gltf.nodes[0]
    scale, centre = np.array(node.scale, dtype=np.float64), np.array(node.translation, dtype=np.float64)
    assert np.all(scale == scale[0]), "uniform scale: the normals need no correction"

    # positions: the node transform applied to the dequantised local coordinates
    src = _source_vertex(gltf, prim, base_face)
    pos = _accessor(gltf, prim.attributes.POSITION) * scale + centre
    diag = float(np.linalg.norm(np.ptp(base_face.vertices, axis=0)))
    half_step = scale[0] / 32767 / 2
    pos_err = np.abs(pos - base_face.vertices[src]).max()
    assert pos_err <= half_step * (1 + 1e-6)
    # morph deltas: the same local space, so the node's scale (not its translation) applies
    delta_err = 0.0
    for k, name in enumerate(names):
        t = acc[prim.targets[k]["POSITION"]]
        assert t.componentType == pygltflib.SHORT and t.normalized
        delta_err = max(delta_err, np.abs(_accessor(gltf, prim.targets[k]["POSITION"]) * scale
                                          - shapes[name][src]).max())
    assert delta_err <= half_step * (1 + 1e-6)
    assert max(pos_err, delta_err) < QUANTIZED_RELATIVE_BOUND * diag
    # local targets stay sparse, dense ones dense; a target under half a step everywhere is empty
    assert acc[prim.targets[0]["POSITION"]].sparse is not None
    assert acc[prim.targets[names.index("smile")]["POSITION"]].bufferView is not None
    tiny = acc[prim.targets[names.index("tiny")]["POSITION"]]
    assert tiny.bufferView is None and tiny.sparse is None

    normals = _accessor(gltf, prim.attributes.NORMAL)
    plain_gltf = pygltflib.GLTF2().load(str(plain))
    ref = _accessor(plain_gltf, plain_gltf.meshes[0].primitives[0].attributes.NORMAL)
    cos = np.sum(normals * ref, axis=1) / np.linalg.norm(normals, axis=1)
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 0.5
    uv = _accessor(gltf, prim.attributes.TEXCOORD_0)
    ref_uv = _accessor(plain_gltf, plain_gltf.meshes[0].primitives[0].attributes.TEXCOORD_0)
    assert np.abs(uv - ref_uv).max() <= 0.5 / 65535 + 1e-7
    np.testing.assert_array_equal(_accessor(gltf, prim.indices),
                                  _accessor(plain_gltf, plain_gltf.meshes[0].primitives[0].indices))

    sampler = gltf.animations[0].samplers[0]
    np.testing.assert_allclose(_accessor(gltf, sampler.input), times, atol=1e-6)
    np.testing.assert_allclose(_accessor(gltf, sampler.output).reshape(-1, len(names)), weights, atol=1e-6)
    assert gltf.scenes[gltf.scene].extras == {"audio": "speech.wav", "fps": 30, "tags": ["joy", None]}
    assert path.stat().st_size < plain.stat().st_size


def test_khronos_validator_accepts_quantized_output(quantized):
    report = _validate(quantized[0])
    assert report["numErrors"] == 0, report["messages"]
    assert report["numWarnings"] == 0, report["messages"]


def _binary_bytes_without_images(gltf):
    """Bytes of the binary chunk's buffer views other than the images'."""
    images = {im.bufferView for im in gltf.images or []}
    return sum(view.byteLength for k, view in enumerate(gltf.bufferViews) if k not in images)


# quantised geometry and morph data against the plain file's: positions, sparse rows, UVs and
# indices take half the bytes, normals a third, dense deltas two thirds (three int16 padded to 8
# bytes against 12); measured 0.512 on the default head with the deltas below (20 local bumps and a
# dense target). The whole file was under half on the old face mask, whose 26 KB texture hardly
# counted; the head's 1024 x 1024 atlas (600 KB) and its seam map in the JSON (150 KB) are the same
# in both files, so they are left out of the ratio and checked equal instead.
QUANTIZED_DATA_RATIO = 0.53


def test_quantized_default_face_data_is_about_half_the_size(tmp_path, face):
    shapes = _smooth_local_deltas(face, 20, np.random.default_rng(2))
    shapes["smile"] = np.random.default_rng(3).normal(scale=1e-3, size=face.vertices.shape)
    plain = write_gltf(tmp_path / "plain.glb", face, shapes)
    small = write_gltf(tmp_path / "small.glb", face, shapes, quantize=True)
    assert small.stat().st_size < plain.stat().st_size
    gltf = pygltflib.GLTF2().load(str(small))
    plain_gltf = pygltflib.GLTF2().load(str(plain))
    image = [g.binary_blob()[v.byteOffset:v.byteOffset + v.byteLength]
             for g in (gltf, plain_gltf) for v in [g.bufferViews[g.images[0].bufferView]]]
    assert image[0] == image[1]
    assert _binary_bytes_without_images(gltf) < QUANTIZED_DATA_RATIO * _binary_bytes_without_images(plain_gltf)
    prim = gltf.meshes[0].primitives[0]
    src = _source_vertex(gltf, prim, face)
    scale = gltf.nodes[0].scale[0]
    diag = float(np.linalg.norm(np.ptp(face.vertices, axis=0)))
    err = max(np.abs(_accessor(gltf, prim.targets[k]["POSITION"]) * scale - d[src]).max()
              for k, d in enumerate(shapes.values()))
    assert err < QUANTIZED_RELATIVE_BOUND * diag


@pytest.mark.parametrize("extras", [{"gain": float("nan")}, {1: "a"}, {"pair": (1, 2)}, {"x": np.float32(1)},
                                    ["audio"], {"f": print}])
def test_extras_must_be_json(tmp_path, base_face, extras):
    with pytest.raises(FaceAnimError, match="extras"):
        write_gltf(tmp_path / "x.glb", base_face, extras=extras)
    assert not (tmp_path / "x.glb").exists()


def test_extras_without_quantization(tmp_path, base_face):
    path = write_gltf(tmp_path / "x.glb", base_face, extras={"audio": "speech.wav"})
    gltf = pygltflib.GLTF2().load(str(path))
    assert gltf.scenes[0].extras == {"audio": "speech.wav"}
    assert gltf.accessors[gltf.meshes[0].primitives[0].attributes.POSITION].componentType == pygltflib.FLOAT


@pytest.mark.parametrize("quantize", [False, True])
def test_a_target_that_moves_nothing_is_valid(tmp_path, base_face, quantize):
    """An all-zero blendshape: an accessor without data (it once got two empty buffer views,
    which the validator rejects)."""
    path = write_gltf(tmp_path / "zero.glb", base_face, {"zero": np.zeros(base_face.vertices.shape)}, quantize=quantize)
    gltf = pygltflib.GLTF2().load(str(path))
    target = gltf.meshes[0].primitives[0].targets[0]["POSITION"]
    assert not np.any(_accessor(gltf, target))
    assert all(view.byteLength > 0 for view in gltf.bufferViews)
    report = _validate(path)
    assert report["numErrors"] == 0, report["messages"]


def test_quantized_keeps_float_uvs_outside_the_unit_square(tmp_path, base_face):
    from faceanim.face.mesh import Mesh

    tiled = Mesh(base_face.vertices, base_face.faces, base_face.uv * 2, base_face.face_uv, base_face.texture)
    bare = Mesh(base_face.vertices, base_face.faces)  # no UVs, no texture
    for mesh in (tiled, bare):
        path = write_gltf(tmp_path / "m.glb", mesh, quantize=True)
        gltf = pygltflib.GLTF2().load(str(path))
        attrs = gltf.meshes[0].primitives[0].attributes
        if mesh.uv is None:
            assert attrs.TEXCOORD_0 is None
        else:
            assert gltf.accessors[attrs.TEXCOORD_0].componentType == pygltflib.FLOAT
        pos = _accessor(gltf, attrs.POSITION) * gltf.nodes[0].scale + gltf.nodes[0].translation
        assert np.abs(pos[: mesh.n_vertices] - mesh.vertices).max() < 1e-4 * np.linalg.norm(np.ptp(mesh.vertices, 0))
        report = _validate(path)
        assert report["numErrors"] == 0, report["messages"]


def test_quantized_delta_larger_than_the_face_widens_the_scale(tmp_path, base_face):
    big = np.zeros(base_face.vertices.shape)
    big[:, 2] = 0.5  # half a metre: beyond the face's half-extent, so it sets the scale
    path = write_gltf(tmp_path / "big.glb", base_face, {"push": big}, quantize=True)
    gltf = pygltflib.GLTF2().load(str(path))
    scale = gltf.nodes[0].scale[0]
    assert scale == pytest.approx(0.5)
    prim = gltf.meshes[0].primitives[0]
    src = _source_vertex(gltf, prim, base_face)
    assert np.abs(_accessor(gltf, prim.targets[0]["POSITION"]) * scale - big[src]).max() <= scale / 32767 / 2 * (1 + 1e-6)
    pos = _accessor(gltf, prim.attributes.POSITION) * scale + gltf.nodes[0].translation
    assert np.abs(pos - base_face.vertices[src]).max() <= scale / 32767 / 2 * (1 + 1e-6)


def test_a_quantized_glb_is_refused_on_reading_not_misread(tmp_path, base_face):
    """trimesh ignores the normalized flag of KHR_mesh_quantization (it would return integers
    thousands of times too large): faceanim refuses the file with a clear message instead."""
    from faceanim.errors import MeshError
    from faceanim.io.meshio import load_mesh

    write_gltf(tmp_path / "q.glb", base_face, quantize=True)
    with pytest.raises(MeshError, match="quantized .* give the file written without --compact"):
        load_mesh(tmp_path / "q.glb")
    write_gltf(tmp_path / "p.glb", base_face)
    np.testing.assert_allclose(load_mesh(tmp_path / "p.glb").vertices, base_face.vertices, atol=1e-6)
