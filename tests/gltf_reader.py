"""Accessors of a GLB decoded by hand from the glTF 2.0 spec (an oracle independent of the writer)."""

import numpy as np
import pygltflib

_DTYPES = {pygltflib.BYTE: np.int8, pygltflib.UNSIGNED_BYTE: np.uint8, pygltflib.SHORT: np.int16,
           pygltflib.UNSIGNED_SHORT: np.uint16, pygltflib.UNSIGNED_INT: np.uint32, pygltflib.FLOAT: np.float32}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
# the spec's dequantisation of normalised integers (glTF 2.0, "Animations" / KHR_mesh_quantization)
_NORMALIZE = {np.int8: lambda c: np.maximum(c / 127.0, -1.0), np.uint8: lambda c: c / 255.0,
              np.int16: lambda c: np.maximum(c / 32767.0, -1.0), np.uint16: lambda c: c / 65535.0}

def raw(gltf, index):
    """An accessor's stored values (dense, strided or sparse), undecoded."""
    acc = gltf.accessors[index]
    blob = gltf.binary_blob()
    n, dtype = _WIDTH[acc.type], np.dtype(_DTYPES[acc.componentType])
    if acc.bufferView is None:
        a = np.zeros((acc.count, n), dtype=dtype)
    else:
        view = gltf.bufferViews[acc.bufferView]
        stride = view.byteStride or n * dtype.itemsize
        start = view.byteOffset + (acc.byteOffset or 0)
        rows = np.arange(acc.count)[:, None] * stride + np.arange(n * dtype.itemsize)[None, :]
        a = np.frombuffer(blob, dtype=np.uint8)[start + rows].copy().view(dtype)
    if acc.sparse is not None:
        sp = acc.sparse
        iview, vview = gltf.bufferViews[sp.indices.bufferView], gltf.bufferViews[sp.values.bufferView]
        idx = np.frombuffer(blob, dtype=_DTYPES[sp.indices.componentType], count=sp.count,
                            offset=iview.byteOffset + (sp.indices.byteOffset or 0))
        val = np.frombuffer(blob, dtype=dtype, count=sp.count * n, offset=vview.byteOffset + (sp.values.byteOffset or 0))
        assert np.all(np.diff(idx.astype(np.int64)) > 0)
        a[idx] = val.reshape(-1, n)
    return a


def accessor(gltf, index):
    """Decode an accessor by hand from the glTF spec (dense, strided or sparse; normalised
    integers are dequantised to floats)."""
    acc = gltf.accessors[index]
    a = raw(gltf, index)
    if acc.normalized:
        a = _NORMALIZE[a.dtype.type](a.astype(np.float64))
    return a if a.shape[1] > 1 else a[:, 0]
