"""glTF export: morph targets and their animation, read back and checked by Khronos' validator."""

import json
import shutil
import subprocess

import numpy as np
import pygltflib
import pytest
from conftest import ROOT

from faceanim.io.gltf import write_gltf

VALIDATOR = ROOT / "tools" / "validate_gltf.js"


def _accessor(gltf, index):
    """Decode an accessor by hand from the glTF spec (dense or sparse)."""
    acc = gltf.accessors[index]
    blob = gltf.binary_blob()
    n = {"SCALAR": 1, "VEC2": 2, "VEC3": 3}[acc.type]
    dtype = np.float32 if acc.componentType == pygltflib.FLOAT else np.uint32
    if acc.bufferView is None:
        a = np.zeros(acc.count * n, dtype=dtype)
    else:
        view = gltf.bufferViews[acc.bufferView]
        a = np.frombuffer(blob, dtype=dtype, count=acc.count * n, offset=view.byteOffset).copy()
    if acc.sparse is not None:
        sp = acc.sparse
        idx = np.frombuffer(blob, dtype=np.uint32, count=sp.count,
                            offset=gltf.bufferViews[sp.indices.bufferView].byteOffset)
        val = np.frombuffer(blob, dtype=dtype, count=sp.count * n,
                            offset=gltf.bufferViews[sp.values.bufferView].byteOffset)
        a.reshape(acc.count, n)[idx] = val.reshape(-1, n)
    return a.reshape(acc.count, n) if n > 1 else a


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
    np.testing.assert_allclose(_accessor(gltf, prim.attributes.POSITION), base_face.vertices, atol=1e-6)
    for k, name in enumerate(["smile", "A"]):
        np.testing.assert_allclose(_accessor(gltf, prim.targets[k]["POSITION"]), shapes[name], atol=1e-7)
    sampler = gltf.animations[0].samplers[0]
    np.testing.assert_allclose(_accessor(gltf, sampler.input), times, atol=1e-6)
    np.testing.assert_allclose(_accessor(gltf, sampler.output).reshape(-1, 2), weights, atol=1e-6)
    assert gltf.animations[0].channels[0].target.path == "weights"
    assert gltf.accessors[prim.targets[1]["POSITION"]].sparse.count == 60
    assert gltf.images and gltf.materials[0].pbrMetallicRoughness.baseColorTexture.index == 0


def test_khronos_validator_reports_no_errors(exported):
    if shutil.which("node") is None or not (ROOT / "tools" / "node_modules" / "gltf-validator").exists():
        pytest.skip("node or the gltf-validator npm package is missing (scripts/setup.sh installs it)")
    path = exported[0]
    out = subprocess.run(["node", str(VALIDATOR), str(path)], capture_output=True, text=True, check=True)
    report = json.loads(out.stdout)
    assert report["numErrors"] == 0, report["messages"]
    assert report["numWarnings"] == 0, report["messages"]
