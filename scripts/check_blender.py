#!/usr/bin/env python
"""Import faceanim's glb files into Blender and check what Blender made of them.

Runs under a Python that has Blender's module ``bpy`` (PyPI's ``bpy`` 5.0.1 wants Python 3.11;
faceanim keeps it in its own venv, ``.venv-blender``, since the wheel is 374 MB / 0.8 GB
installed)::

    .venv-blender/bin/python scripts/check_blender.py OUT.glb [OUT2.glb ...] [--json report.json]
    .venv-blender/bin/python scripts/check_blender.py arkit.glb --render docs/blender_import.png \\
        --pose jawOpen=1 --size 512

For each file: an empty scene (``read_factory_settings(use_empty=True)``), Blender's own glTF
importer (``bpy.ops.import_scene.gltf``, default options), then Blender's result against the file
itself, read here with nothing but ``json`` and numpy (an oracle independent of faceanim's writer
and of Blender's reader):

- every mesh object: its vertex count against the file's POSITION count, its shape keys (the key
  blocks less "Basis") against the mesh's ``extras.targetNames`` in order, its Basis coordinates
  and every shape key's displacement against the file's positions and morph targets (Blender
  turns glTF's Y-up into Z-up: file ``(x, y, z)`` is Blender ``(x, -z, y)``; dequantised for
  KHR_mesh_quantization), as the largest absolute difference in the file's world units;
- the actions: their slots, which data-block uses each, their fcurves (``key_blocks["jawOpen"].value``,
  ``rotation_quaternion``), the keyframes' times and values against the file's samplers, the frame
  range;
- a few whole frames (``scene.frame_set``): every shape key's value against the file's weights at
  that time, each animated node's rotation, and the evaluated world positions of every vertex
  against the file's (morph weights applied, node chain with its animated rotation).

Blender converts seconds to frames with the scene's frame rate (24 fps in factory settings, a
glb carries none): ``--fps 25`` sets the scene's rate before importing so that a 25 fps
animation lands on whole frames. ``--dump NPZ`` saves Blender's side (Basis, displacements, values
and world positions at the checked frames) for a test to compare with its own reader. Exit code 0
when every check passes, 1 when one fails, 2 for a file that cannot be read.
"""

from __future__ import annotations

import argparse
import json
import math
import struct
import sys
import time
from pathlib import Path

import numpy as np

# Tolerances: Blender stores coordinates, keyframes and values as float32.
GEOMETRY_TOL = 1e-5  # file units (metres): 10 micrometres
WEIGHT_TOL = 1e-4
ROTATION_TOL = 1e-4  # quaternion components
TIME_TOL = 1e-4  # seconds

# glTF (Y up, -Z forward) to Blender (Z up, -Y forward): (x, y, z) -> (x, -z, y)
AXES = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

_DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}


# ------------------------------------------------------------------------------------------------
# The file, read from the glTF 2.0 spec
# ------------------------------------------------------------------------------------------------
class Glb:
    def __init__(self, path):
        data = Path(path).read_bytes()
        if len(data) < 20:
            raise ValueError(f"{path}: not a GLB (too short)")
        magic, version, length = struct.unpack_from("<4sII", data, 0)
        if magic != b"glTF" or version != 2:
            raise ValueError(f"{path}: not a glTF 2.0 binary")
        self.doc, self.blob, off = None, b"", 12
        while off + 8 <= min(length, len(data)):
            size, kind = struct.unpack_from("<II", data, off)
            chunk = data[off + 8:off + 8 + size]
            if kind == 0x4E4F534A:
                self.doc = json.loads(chunk)
            elif kind == 0x004E4942:
                self.blob = chunk
            off += 8 + size
        if self.doc is None:
            raise ValueError(f"{path}: no JSON chunk")

    def accessor(self, index: int) -> np.ndarray:
        """(count, width) float64: dense, strided or sparse; normalised integers dequantised."""
        acc = self.doc["accessors"][index]
        n, dtype = _WIDTH[acc["type"]], np.dtype(_DTYPES[acc["componentType"]])
        count = acc["count"]
        if "bufferView" in acc:
            view = self.doc["bufferViews"][acc["bufferView"]]
            start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
            stride = view.get("byteStride") or n * dtype.itemsize
            a = np.ndarray((count, n), dtype=dtype, buffer=self.blob, offset=start,
                           strides=(stride, dtype.itemsize)).copy()
        else:
            a = np.zeros((count, n), dtype=dtype)
        sparse = acc.get("sparse")
        if sparse:
            iv = self.doc["bufferViews"][sparse["indices"]["bufferView"]]
            vv = self.doc["bufferViews"][sparse["values"]["bufferView"]]
            idx = np.frombuffer(self.blob, dtype=_DTYPES[sparse["indices"]["componentType"]], count=sparse["count"],
                                offset=iv.get("byteOffset", 0) + sparse["indices"].get("byteOffset", 0))
            val = np.frombuffer(self.blob, dtype=dtype, count=sparse["count"] * n,
                                offset=vv.get("byteOffset", 0) + sparse["values"].get("byteOffset", 0))
            a[idx.astype(np.int64)] = val.reshape(-1, n)
        out = a.astype(np.float64)
        if acc.get("normalized"):
            scale = {np.int8: 127.0, np.uint8: 255.0, np.int16: 32767.0, np.uint16: 65535.0}[dtype.type]
            out = out / scale
            if dtype.kind == "i":
                out = np.maximum(out, -1.0)
        return out

    # nodes ---------------------------------------------------------------------------------------
    def parents(self) -> dict[int, int]:
        return {c: i for i, node in enumerate(self.doc.get("nodes", [])) for c in node.get("children", [])}

    def local_matrix(self, index: int, pose: dict | None = None) -> np.ndarray:
        node = self.doc["nodes"][index]
        if "matrix" in node:
            return np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T
        pose = pose or {}
        t = np.array(pose.get((index, "translation"), node.get("translation", [0, 0, 0])), dtype=np.float64)
        q = np.array(pose.get((index, "rotation"), node.get("rotation", [0, 0, 0, 1])), dtype=np.float64)
        s = np.array(pose.get((index, "scale"), node.get("scale", [1, 1, 1])), dtype=np.float64)
        m = np.eye(4)
        m[:3, :3] = quat_matrix(q) * s[None, :]
        m[:3, 3] = t
        return m

    def world_matrix(self, index: int, pose: dict | None = None) -> np.ndarray:
        parents, m = self.parents(), np.eye(4)
        while index is not None:
            m = self.local_matrix(index, pose) @ m
            index = parents.get(index)
        return m

    # animation -----------------------------------------------------------------------------------
    def channels(self, animation: int = 0) -> list[dict]:
        """Each channel: node, path, times (K,), values (K, width), interpolation."""
        anims = self.doc.get("animations", [])
        if not anims:
            return []
        anim, out = anims[animation], []
        for ch in anim["channels"]:
            sampler = anim["samplers"][ch["sampler"]]
            times = self.accessor(sampler["input"])[:, 0]
            values = self.accessor(sampler["output"])
            interp = sampler.get("interpolation", "LINEAR")
            if interp == "CUBICSPLINE":  # in-tangent, value, out-tangent per key: keep the values
                values = values.reshape(len(times), 3, -1)[:, 1]
            values = values.reshape(len(times), -1)
            out.append({"node": ch["target"].get("node"), "path": ch["target"]["path"], "times": times,
                        "values": values, "interpolation": interp})
        return out


def sample(channel: dict, t: float) -> np.ndarray:
    """A channel's value at time t (LINEAR: lerp, slerp for rotations; STEP; CUBICSPLINE taken
    as linear between its values, good enough at the keys)."""
    times, values = channel["times"], channel["values"]
    if t <= times[0]:
        return values[0].copy()
    if t >= times[-1]:
        return values[-1].copy()
    k = int(np.searchsorted(times, t, side="right")) - 1
    if channel["interpolation"] == "STEP":
        return values[k].copy()
    u = (t - times[k]) / (times[k + 1] - times[k])
    if channel["path"] == "rotation":
        return slerp(values[k], values[k + 1], u)
    return (1 - u) * values[k] + u * values[k + 1]


def quat_matrix(q) -> np.ndarray:
    x, y, z, w = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def slerp(a, b, u: float) -> np.ndarray:
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    d = float(np.dot(a, b))
    if d < 0:
        b, d = -b, -d
    if d > 0.9995:
        q = a + u * (b - a)
    else:
        th = math.acos(min(d, 1.0))
        q = (math.sin((1 - u) * th) * a + math.sin(u * th) * b) / math.sin(th)
    return q / np.linalg.norm(q)


def blender_quat(q_xyzw) -> np.ndarray:
    """A glTF rotation (x, y, z, w) as Blender's (w, x, y, z) after the axis change."""
    x, y, z, w = q_xyzw
    return np.array([w, x, -z, y])


def quat_diff(a, b) -> float:
    """Largest component difference of two unit quaternions, either sign of b."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return float(min(np.abs(a - b).max(), np.abs(a + b).max()))


# ------------------------------------------------------------------------------------------------
# Blender's side
# ------------------------------------------------------------------------------------------------
def _fcurves_of(action, slot=None) -> list:
    """The fcurves of an action (Blender 4.4+'s layered actions: the channelbag of ``slot``, or of
    every slot; older Blender: action.fcurves)."""
    if getattr(action, "layers", None) is not None and len(action.layers):
        out = []
        for layer in action.layers:
            for strip in layer.strips:
                for bag in strip.channelbags:
                    if slot is None or bag.slot == slot:
                        out.extend(bag.fcurves)
        return out
    return list(getattr(action, "fcurves", []))


def _keyframes(fc) -> np.ndarray:
    co = np.zeros(2 * len(fc.keyframe_points), dtype=np.float32)
    fc.keyframe_points.foreach_get("co", co)
    return co.reshape(-1, 2).astype(np.float64)


def _coords(collection, n: int) -> np.ndarray:
    co = np.zeros(3 * n, dtype=np.float32)
    collection.foreach_get("co", co)
    return co.reshape(n, 3).astype(np.float64)


def slider_ranges(widen: bool = False) -> dict:
    """Shape keys whose animation leaves their slider range ([0, 1] unless widened), which Blender
    clamps every value to: {"object/key": [fcurve min, fcurve max, slider_min, slider_max]}.
    ``widen``: set each such range to cover its fcurve (the fix a Blender user makes by hand)."""
    import bpy

    out = {}
    for key in bpy.data.shape_keys:
        ad = key.animation_data
        if not (ad and ad.action):
            continue
        for fc in _fcurves_of(ad.action, getattr(ad, "action_slot", None)):
            if not (fc.data_path.startswith("key_blocks[") and fc.data_path.endswith("].value")):
                continue
            kb = key.path_resolve(fc.data_path.rsplit(".", 1)[0])
            values = _keyframes(fc)[:, 1]
            lo, hi = float(values.min()), float(values.max())
            if lo < kb.slider_min - 1e-7 or hi > kb.slider_max + 1e-7:
                out[f"{key.user.name}/{kb.name}"] = [lo, hi, kb.slider_min, kb.slider_max]
                if widen:
                    kb.slider_min, kb.slider_max = min(lo, kb.slider_min), max(hi, kb.slider_max)
    return out


def check_file(path: Path, frames: int = 5, fps: int | None = None, dump: Path | None = None,
               widen_sliders: bool = False) -> dict:
    import bpy

    glb = Glb(path)
    doc = glb.doc
    report: dict = {"path": str(path), "problems": []}
    problems = report["problems"]

    def expect(ok: bool, text: str):
        if not ok:
            problems.append(text)

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    if fps:  # whole rates only: the importer multiplies fps by fps_base where it should divide
        scene.render.fps, scene.render.fps_base = int(fps), 1.0
    rate = scene.render.fps / scene.render.fps_base
    report["scene_fps"] = rate
    t0 = time.perf_counter()
    result = bpy.ops.import_scene.gltf(filepath=str(path))
    report["import_seconds"] = round(time.perf_counter() - t0, 3)
    expect(result == {"FINISHED"}, f"the importer returned {sorted(result)}")
    report["objects"] = [{"name": o.name, "type": o.type, "parent": o.parent.name if o.parent else None}
                         for o in bpy.data.objects]
    report["clamped_keys"] = clamped = slider_ranges(widen=widen_sliders)
    report["widened_sliders"] = widen_sliders
    if clamped and not widen_sliders:
        problems.append(f"{len(clamped)} shape keys are animated outside their slider range, which Blender clamps "
                        f"({', '.join(sorted(clamped)[:4])}{', ...' if len(clamped) > 4 else ''}): the importer widens "
                        "the range to the first keyframe's weight only (io_scene_gltf2 animation_weight.py takes "
                        "min(coords[1:2]) for min(coords[1::2])); --widen-sliders does it after importing")

    nodes = doc.get("nodes", [])
    parents = glb.parents()
    channels = glb.channels()
    weight_channels = {c["node"]: c for c in channels if c["path"] == "weights"}
    npz: dict[str, np.ndarray] = {}

    # meshes --------------------------------------------------------------------------------------
    meshes = []
    for ni, node in enumerate(nodes):
        if "mesh" not in node:
            continue
        gm = doc["meshes"][node["mesh"]]
        name = node.get("name") or gm.get("name")
        ob = bpy.data.objects.get(name)
        entry: dict = {"node": ni, "object": name}
        meshes.append(entry)
        if ob is None or ob.type != "MESH":
            problems.append(f"node {ni} ({name}): no mesh object of that name in Blender")
            continue
        me = ob.data
        prims = gm["primitives"]
        file_pos = np.concatenate([glb.accessor(p["attributes"]["POSITION"]) for p in prims])
        names = list((gm.get("extras") or {}).get("targetNames") or [])
        n_targets = len(prims[0].get("targets", []))
        names = names if len(names) == n_targets else [f"target_{k}" for k in range(n_targets)]
        world = glb.world_matrix(ni)
        unit = float(abs(np.linalg.det(world[:3, :3])) ** (1 / 3))  # file local units -> metres
        entry.update(vertices=len(me.vertices), file_vertices=len(file_pos), polygons=len(me.polygons),
                     file_targets=names, local_unit=unit)
        expect(len(me.vertices) == len(file_pos),
               f"{name}: Blender has {len(me.vertices)} vertices, the file {len(file_pos)}")
        keys = me.shape_keys.key_blocks if me.shape_keys else []
        key_names = [k.name for k in keys][1:] if len(keys) else []
        entry["shape_keys"] = key_names
        expect(key_names == names, f"{name}: shape keys {key_names[:5]}... are not the file's targets {names[:5]}...")
        if len(me.vertices) != len(file_pos):
            continue
        n = len(file_pos)
        basis = _coords(keys[0].data if len(keys) else me.vertices, n)
        expected_basis = file_pos @ AXES.T
        entry["basis_max_abs"] = float(np.abs(basis - expected_basis).max() * unit)
        expect(entry["basis_max_abs"] <= GEOMETRY_TOL,
               f"{name}: Basis differs from the file's positions by {entry['basis_max_abs']:.3g}")
        npz[f"{name}/basis"] = basis.astype(np.float32)
        worst, worst_name, moved = 0.0, None, {}
        deltas = np.zeros((len(key_names), n, 3), dtype=np.float32)
        for k, kname in enumerate(key_names):
            d = _coords(keys[k + 1].data, n) - basis
            deltas[k] = d
            if k < n_targets and kname in names:
                j = names.index(kname)
                target = np.concatenate([glb.accessor(p["targets"][j]["POSITION"]) for p in prims]) @ AXES.T
                err = float(np.abs(d - target).max() * unit)
                moved[kname] = float(np.linalg.norm(target, axis=1).max() * unit)
                if err > worst:
                    worst, worst_name = err, kname
        npz[f"{name}/deltas"] = deltas
        entry["shape_key_max_abs"] = worst
        entry["shape_key_worst"] = worst_name
        if moved:
            biggest = max(moved, key=moved.get)
            entry["largest_displacement"] = {"key": biggest, "metres": moved[biggest]}
        expect(worst <= GEOMETRY_TOL, f"{name}: shape key '{worst_name}' differs from its morph target by {worst:.3g}")

    # actions -------------------------------------------------------------------------------------
    actions = []
    for action in bpy.data.actions:
        a = {"name": action.name, "frame_range": [float(x) for x in action.frame_range], "slots": []}
        slots = list(getattr(action, "slots", []))
        users = {}
        for idb in list(bpy.data.objects) + list(bpy.data.shape_keys):
            ad = idb.animation_data
            if ad and ad.action == action:
                users[getattr(ad, "action_slot", None) and ad.action_slot.identifier] = (
                    idb.user.name if idb.rna_type.identifier == "Key" else idb.name)
        for slot in slots or [None]:
            fcs = _fcurves_of(action, slot)
            ident = slot.identifier if slot is not None else None
            a["slots"].append({"slot": ident, "used_by": users.get(ident), "fcurves": len(fcs),
                               "data_paths": sorted({f.data_path for f in fcs}),
                               "interpolation": sorted({k.interpolation for f in fcs for k in f.keyframe_points[:2]})})
        actions.append(a)
    report["actions"] = actions
    if channels:
        expect(len(actions) >= 1, "the file is animated but Blender made no action")

    # keyframes against the file's samplers --------------------------------------------------------
    anim: dict = {}
    report["animation"] = anim
    if channels:
        times = np.concatenate([c["times"] for c in channels])
        anim["file_seconds"] = [float(times.min()), float(times.max())]
        anim["file_frames"] = [float(times.min() * rate), float(times.max() * rate)]
        if actions:
            lo = min(a["frame_range"][0] for a in actions)
            hi = max(a["frame_range"][1] for a in actions)
            anim["action_frames"] = [lo, hi]
            expect(abs(lo - times.min() * rate) < 1e-2 and abs(hi - times.max() * rate) < 1e-2,
                   f"action frame range {lo}..{hi} is not the file's {times.min() * rate}..{times.max() * rate}")
    for entry in meshes:
        ch = weight_channels.get(entry["node"])
        ob = bpy.data.objects.get(entry["object"])
        if ch is None or ob is None or ob.type != "MESH" or not ob.data.shape_keys:
            continue
        key = ob.data.shape_keys
        ad = key.animation_data
        if not (ad and ad.action):
            problems.append(f"{entry['object']}: the file animates its weights but its shape keys have no action")
            continue
        fcs = _fcurves_of(ad.action, getattr(ad, "action_slot", None))
        by_path = {f.data_path: f for f in fcs}
        names = entry["file_targets"]
        want = [f'key_blocks["{nm}"].value' for nm in names]
        entry["action"] = ad.action.name
        entry["fcurves"] = len(fcs)
        expect(sorted(by_path) == sorted(want) and len(fcs) == len(want),
               f"{entry['object']}: {len(fcs)} fcurves, want one per target ({len(want)})")
        tmax = vmax = 0.0
        for j, path_ in enumerate(want):
            fc = by_path.get(path_)
            if fc is None:
                continue
            co = _keyframes(fc)
            if len(co) != len(ch["times"]):
                problems.append(f"{path_}: {len(co)} keyframes, the file {len(ch['times'])}")
                continue
            tmax = max(tmax, float(np.abs(co[:, 0] / rate - ch["times"]).max()))
            vmax = max(vmax, float(np.abs(co[:, 1] - ch["values"][:, j]).max()))
        entry["keyframe_time_max_abs"], entry["keyframe_value_max_abs"] = tmax, vmax
        expect(tmax <= TIME_TOL, f"{entry['object']}: keyframe times differ by {tmax:.3g} s")
        expect(vmax <= WEIGHT_TOL, f"{entry['object']}: keyframe values differ by {vmax:.3g}")

    node_channels = [c for c in channels if c["path"] in ("rotation", "translation", "scale")]
    rotations = []
    for c in node_channels:
        nname = nodes[c["node"]].get("name")
        ob = bpy.data.objects.get(nname)
        r = {"node": c["node"], "object": nname, "path": c["path"]}
        rotations.append(r)
        ad = ob.animation_data if ob else None
        if not (ad and ad.action):
            problems.append(f"node {nname}: its {c['path']} is animated but the object has no action")
            continue
        prop = {"rotation": "rotation_quaternion", "translation": "location", "scale": "scale"}[c["path"]]
        fcs = [f for f in _fcurves_of(ad.action, getattr(ad, "action_slot", None)) if f.data_path == prop]
        r.update(action=ad.action.name, fcurves=len(fcs), data_path=prop)
        want = 4 if prop == "rotation_quaternion" else 3
        expect(len(fcs) == want, f"{nname}: {len(fcs)} {prop} fcurves, want {want}")
        if c["path"] == "rotation" and len(fcs) == 4:
            keys = np.stack([_keyframes(f) for f in sorted(fcs, key=lambda f: f.array_index)])  # (4, K, 2)
            if keys.shape[1] == len(c["times"]):
                got = keys[:, :, 1].T
                want_q = np.array([blender_quat(q) for q in c["values"]])
                r["keyframe_max_abs"] = float(max(quat_diff(a_, b_) for a_, b_ in zip(got, want_q)))
                expect(r["keyframe_max_abs"] <= ROTATION_TOL,
                       f"{nname}: rotation keyframes differ by {r['keyframe_max_abs']:.3g}")
            else:
                problems.append(f"{nname}: {keys.shape[1]} rotation keyframes, the file {len(c['times'])}")
    report["node_animation"] = rotations

    # whole frames ---------------------------------------------------------------------------------
    checked = []
    if channels:
        f0, f1 = anim["file_frames"]
        picks = sorted({int(np.rint(x)) for x in np.linspace(math.ceil(f0), math.floor(f1), max(frames, 1))})
        for f in picks:
            scene.frame_set(f)
            t = f * scene.render.fps_base / scene.render.fps
            pose = {(c["node"], c["path"]): sample(c, t) for c in node_channels}
            fr = {"frame": f, "seconds": t}
            depsgraph = bpy.context.evaluated_depsgraph_get()
            for entry in meshes:
                ob = bpy.data.objects.get(entry["object"])
                if ob is None or ob.type != "MESH" or entry.get("vertices") != entry.get("file_vertices"):
                    continue
                gm = doc["meshes"][nodes[entry["node"]]["mesh"]]
                prims = gm["primitives"]
                ch = weight_channels.get(entry["node"])
                w = sample(ch, t) if ch is not None else np.array(gm.get("weights", [0.0] * len(entry["file_targets"])))
                keys = ob.data.shape_keys.key_blocks if ob.data.shape_keys else []
                values = np.array([k.value for k in keys][1:])
                npz[f"{entry['object']}/values@{f}"] = values
                if len(values) == len(w):
                    fr["weight_max_abs"] = max(fr.get("weight_max_abs", 0.0), float(np.abs(values - w).max()))
                # world positions: the file's morphed vertices through its node chain, then the axes
                pos = np.concatenate([glb.accessor(p["attributes"]["POSITION"]) for p in prims])
                for j, wj in enumerate(w):
                    if wj != 0:
                        pos += wj * np.concatenate([glb.accessor(p["targets"][j]["POSITION"]) for p in prims])
                m = glb.world_matrix(entry["node"], pose)
                want = (pos @ m[:3, :3].T + m[:3, 3]) @ AXES.T
                ob_eval = ob.evaluated_get(depsgraph)
                me_eval = ob_eval.to_mesh()
                try:
                    co = _coords(me_eval.vertices, len(me_eval.vertices))
                finally:
                    ob_eval.to_mesh_clear()
                mw = np.array(ob_eval.matrix_world, dtype=np.float64)
                got = co @ mw[:3, :3].T + mw[:3, 3]
                npz[f"{entry['object']}/world@{f}"] = got.astype(np.float32)
                if got.shape == want.shape:
                    fr["world_max_abs"] = max(fr.get("world_max_abs", 0.0), float(np.abs(got - want).max()))
            for c in node_channels:
                if c["path"] != "rotation":
                    continue
                ob = bpy.data.objects.get(nodes[c["node"]].get("name"))
                if ob is not None:
                    q = np.array(ob.rotation_quaternion, dtype=np.float64)
                    fr["rotation_max_abs"] = max(fr.get("rotation_max_abs", 0.0),
                                                 quat_diff(q / np.linalg.norm(q), blender_quat(pose[(c["node"], "rotation")])))
            checked.append(fr)
        for key, tol, what in [("weight_max_abs", WEIGHT_TOL, "shape key values"),
                               ("world_max_abs", GEOMETRY_TOL, "world positions"),
                               ("rotation_max_abs", ROTATION_TOL, "node rotations")]:
            vals = [fr[key] for fr in checked if key in fr]
            if vals:
                anim[key] = max(vals)
                expect(max(vals) <= tol, f"{what} at whole frames differ from the file by {max(vals):.3g}")
    anim["frames_checked"] = [fr["frame"] for fr in checked]
    report["frames"] = checked
    report["meshes"] = meshes
    report["parents"] = {nodes[c].get("name", str(c)): nodes[p].get("name", str(p)) for c, p in parents.items()}
    report["extensions"] = doc.get("extensionsUsed", [])
    report["ok"] = not problems
    if dump is not None:
        np.savez_compressed(dump, **npz)
    return report


# ------------------------------------------------------------------------------------------------
# A picture
# ------------------------------------------------------------------------------------------------
def render(path: Path, out: Path, pose: dict[str, float], size: int = 512, engine: str = "EEVEE",
           yaw: float = 15.0) -> dict:
    """Import ``path`` into an empty scene, stop its animation, set shape keys (``pose``), and
    render the face (framed on the upper part of the mesh) with a key and a fill light."""
    import bpy
    from mathutils import Vector

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=str(path))
    scene = bpy.context.scene
    mesh_obs = [o for o in bpy.data.objects if o.type == "MESH"]
    if not mesh_obs:
        raise SystemExit(f"{path}: no mesh")
    for ob in bpy.data.objects:
        ob.animation_data_clear()
        if ob.rotation_mode == "QUATERNION":
            ob.rotation_quaternion = (1, 0, 0, 0)
    applied = {}
    for ob in mesh_obs:
        key = ob.data.shape_keys
        if key is None:
            continue
        key.animation_data_clear()
        for kb in key.key_blocks[1:]:
            kb.value = 0.0
        for name, value in pose.items():
            if name in key.key_blocks:
                key.key_blocks[name].value = value
                applied[name] = value
    missing = sorted(set(pose) - set(applied))
    if missing:
        raise SystemExit(f"{path}: no shape key {', '.join(missing)}")
    bpy.context.view_layer.update()
    pts = np.concatenate([np.array([tuple(ob.matrix_world @ Vector(c)) for c in ob.bound_box]) for ob in mesh_obs])
    lo, hi = pts.min(0), pts.max(0)
    height = hi[2] - lo[2]
    # the face: the top 60% of a bust, centred a little above the middle of that
    centre = Vector(((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, hi[2] - 0.42 * height))
    cam_data = bpy.data.cameras.new("camera")
    cam_data.lens = 85
    cam = bpy.data.objects.new("camera", cam_data)
    scene.collection.objects.link(cam)
    scene.camera = cam
    distance = 0.85 * height / (cam_data.sensor_width / cam_data.lens)  # frame ~0.85 of the height
    a = math.radians(yaw)
    cam.location = centre + Vector((distance * math.sin(a), -distance * math.cos(a), 0.02 * height))
    cam.rotation_euler = (math.radians(90) - math.atan2(0.02 * height, distance), 0.0, a)
    for name, energy, rot in [("key", 3.0, (50, 0, 35)), ("fill", 1.0, (70, 0, -60))]:
        ld = bpy.data.lights.new(name, "SUN")
        ld.energy = energy
        lo_ = bpy.data.objects.new(name, ld)
        lo_.rotation_euler = tuple(math.radians(x) for x in rot)
        scene.collection.objects.link(lo_)
    world = bpy.data.worlds.new("world")
    if world.node_tree is None:  # Blender before 5.0 makes a world without nodes
        world.use_nodes = True
    bg = world.node_tree.nodes.get("Background")
    if bg is not None:
        bg.inputs[0].default_value = (0.18, 0.2, 0.23, 1.0)
        bg.inputs[1].default_value = 0.6
    scene.world = world
    engines = {e.identifier for e in bpy.types.RenderSettings.bl_rna.properties["engine"].enum_items}
    scene.render.engine = {"EEVEE": "BLENDER_EEVEE_NEXT" if "BLENDER_EEVEE_NEXT" in engines else "BLENDER_EEVEE",
                           "WORKBENCH": "BLENDER_WORKBENCH", "CYCLES": "CYCLES"}[engine]
    if engine == "WORKBENCH":
        scene.display.shading.light = "STUDIO"
        scene.display.shading.color_type = "TEXTURE"
    scene.view_settings.view_transform = "Standard"
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = str(Path(out).resolve())
    t0 = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    return {"render": str(out), "engine": scene.render.engine, "seconds": round(time.perf_counter() - t0, 2),
            "pose": applied, "size": size}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("glb", nargs="+", type=Path, help="glb files to import and check")
    ap.add_argument("--json", type=Path, help="write the report here as JSON")
    ap.add_argument("--frames", type=int, default=5, help="whole frames to check (default 5, spread over the animation)")
    ap.add_argument("--fps", type=int, help="scene frame rate before importing (default Blender's 24)")
    ap.add_argument("--widen-sliders", action="store_true",
                    help="after importing, widen each shape key's slider range to its animation's (Blender clamps "
                         "values to it; its importer widens it to the first keyframe only)")
    ap.add_argument("--dump", type=Path, help="save Blender's arrays of the (first) file here (.npz)")
    ap.add_argument("--render", type=Path, help="render the first file to this PNG instead of checking")
    ap.add_argument("--pose", action="append", default=[], metavar="KEY=VALUE",
                    help="shape key values for --render (repeat)")
    ap.add_argument("--size", type=int, default=512, help="--render picture size in pixels (default 512)")
    ap.add_argument("--engine", choices=["EEVEE", "WORKBENCH", "CYCLES"], default="EEVEE")
    args = ap.parse_args(argv)
    try:
        import bpy
    except ImportError as exc:
        print(f"check_blender: Blender's Python module bpy is not importable here ({exc}); run this with a "
              "Python that has it, e.g. .venv-blender/bin/python", file=sys.stderr)
        return 2
    if args.render:
        pose = {}
        for item in args.pose:
            name, _, value = item.partition("=")
            pose[name] = float(value or 1.0)
        info = render(args.glb[0], args.render, pose, args.size, args.engine)
        print(json.dumps(info))
        return 0
    reports = []
    for k, path in enumerate(args.glb):
        try:
            rep = check_file(path, args.frames, args.fps, args.dump if k == 0 else None, args.widen_sliders)
        except (OSError, ValueError, KeyError) as exc:
            rep = {"path": str(path), "ok": False, "problems": [f"cannot read: {exc}"], "unreadable": True}
        reports.append(rep)
        print(summary(rep))
    out = {"blender": bpy.app.version_string, "files": reports}
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    if any(r.get("unreadable") for r in reports):
        return 2
    return 0 if all(r["ok"] for r in reports) else 1


def summary(rep: dict) -> str:
    lines = [f"{rep['path']}: {'OK' if rep['ok'] else 'FAILED'}"
             + (f" (imported in {rep['import_seconds']} s at {rep['scene_fps']:g} fps)" if "import_seconds" in rep else "")]
    for m in rep.get("meshes", []):
        keys = m.get("shape_keys", [])
        lines.append(f"  mesh {m['object']}: {m.get('vertices')} vertices (file {m.get('file_vertices')}), "
                     f"{len(keys)} shape keys ({', '.join(keys[:4])}{', ...' if len(keys) > 4 else ''})")
        if "basis_max_abs" in m:
            lines.append(f"    Basis vs positions max |diff| {m['basis_max_abs']:.3g} m; shape keys vs morph targets "
                         f"max |diff| {m['shape_key_max_abs']:.3g} m (worst {m['shape_key_worst']})")
        if "fcurves" in m:
            lines.append(f"    action {m['action']}: {m['fcurves']} fcurves; keyframes vs samplers: times "
                         f"{m['keyframe_time_max_abs']:.3g} s, values {m['keyframe_value_max_abs']:.3g}")
    for a in rep.get("actions", []):
        for s in a["slots"]:
            paths = s["data_paths"]
            lines.append(f"  action {a['name']} frames {a['frame_range'][0]:g}..{a['frame_range'][1]:g} slot {s['slot']} "
                         f"(used by {s['used_by']}): {s['fcurves']} fcurves {paths[0] if paths else ''}"
                         f"{' ...' if len(paths) > 1 else ''}")
    for r in rep.get("node_animation", []):
        lines.append(f"  node {r['object']}: {r['path']} -> {r.get('data_path')} in action {r.get('action')} "
                     f"({r.get('fcurves')} fcurves, keyframes max |diff| {r.get('keyframe_max_abs', float('nan')):.3g})")
    an = rep.get("animation", {})
    if an.get("frames_checked"):
        lines.append(f"  frames {an['frames_checked']}: shape key values max |diff| {an.get('weight_max_abs', float('nan')):.3g}, "
                     f"world positions {an.get('world_max_abs', float('nan')):.3g} m"
                     + (f", rotations {an['rotation_max_abs']:.3g}" if "rotation_max_abs" in an else ""))
    lines += [f"  PROBLEM: {p}" for p in rep.get("problems", [])]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
