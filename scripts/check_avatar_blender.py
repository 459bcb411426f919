#!/usr/bin/env python
"""A whole avatar rigged by faceanim, in Blender: does it still pose with its skeleton, and does
each new shape key move the face?

Runs under a Python that has Blender's module ``bpy`` (``.venv-blender``, see
``scripts/check_blender.py``)::

    .venv-blender/bin/python scripts/check_avatar_blender.py RIGGED.glb --mesh Face \\
        --keys eyeBlinkLeft,jawOpen [--head-bone Head] [--json report.json]

An empty scene, Blender's own glTF importer (default options), then, reported as JSON:

- ``meshes``: every mesh object, its vertex count and shape keys, and ``armature``: whether it is
  deformed by an armature modifier;
- ``pose``: the bone that weighs most on the ``--mesh`` object turned 20 degrees about its own x
  axis: the largest and the median distance the mesh's evaluated vertices move (the avatar still
  poses with its skeleton);
- ``keys``: each asked shape key set to 1 alone: the largest distance the evaluated vertices move
  (in Blender's world units), and the same key's largest displacement as stored in the shape key
  data (what the file's morph target became);
- ``head_keys`` (with ``--head-bone NAME``): at each key of that bone's imported rotation
  (Blender's action, evaluated at the key's frame): the bone's pivot and the centroids of the
  ``--mesh`` object's evaluated vertices that its ``eyeBlinkLeft`` and ``eyeBlinkRight`` keys
  move (the eyes, as Blender's armature poses them), in Blender's world (Z up).

Exit code 0 when the file imports, 2 when it cannot be read.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np


def evaluated(obj, depsgraph) -> np.ndarray:
    ev = obj.evaluated_get(depsgraph)
    mesh = ev.to_mesh()
    co = np.empty(len(mesh.vertices) * 3)
    mesh.vertices.foreach_get("co", co)
    world = np.array(ev.matrix_world)
    ev.to_mesh_clear()
    co = co.reshape(-1, 3)
    return co @ world[:3, :3].T + world[:3, 3]


def head_keys(bpy, head, bone: str) -> list[dict]:
    """The eyes and the pivot at each key of ``bone``'s rotation (module docstring)."""
    arm = next((m.object for m in head.modifiers if m.type == "ARMATURE" and m.object is not None), None)
    if arm is None or arm.animation_data is None or arm.animation_data.action is None:
        return []
    action = arm.animation_data.action
    path = f'pose.bones["{bone}"].rotation_quaternion'
    curves = [c for c in _fcurves(action) if c.data_path == path]
    if not curves:
        return []
    frames = sorted({k.co[0] for c in curves for k in c.keyframe_points})
    blocks = head.data.shape_keys.key_blocks
    basis = np.empty(len(head.data.vertices) * 3)
    head.data.shape_keys.reference_key.data.foreach_get("co", basis)
    eyes = {}
    for side in ("eyeBlinkLeft", "eyeBlinkRight"):
        co = np.empty(basis.size)
        blocks[side].data.foreach_get("co", co)
        eyes[side] = np.linalg.norm((co - basis).reshape(-1, 3), axis=1) > 1e-6
    out = []
    scene = bpy.context.scene
    for f in frames:
        scene.frame_set(int(math.floor(f)), subframe=float(f - math.floor(f)))
        world = evaluated(head, bpy.context.evaluated_depsgraph_get())
        pivot = arm.matrix_world @ arm.pose.bones[bone].head
        out.append({"frame": float(f), "pivot": [float(x) for x in pivot],
                    **{side: world[mask].mean(axis=0).tolist() for side, mask in eyes.items()}})
    return out


def _fcurves(action):
    """An action's F-curves (Blender 4.4+ keeps them in layers, strips and channel bags)."""
    if hasattr(action, "fcurves") and len(action.fcurves):
        return list(action.fcurves)
    out = []
    for layer in getattr(action, "layers", []):
        for strip in layer.strips:
            for bag in getattr(strip, "channelbags", []):
                out.extend(bag.fcurves)
    return out


def main(argv=None) -> int:
    import bpy

    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument("glb", type=Path)
    ap.add_argument("--mesh", required=True, help="the head mesh's name in the file")
    ap.add_argument("--keys", default="", help="comma-separated shape keys to try")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--head-bone", help="report the eyes at each key of this bone's rotation")
    args = ap.parse_args(argv)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    try:
        bpy.ops.import_scene.gltf(filepath=str(args.glb))
    except RuntimeError as exc:
        print(f"cannot import {args.glb}: {str(exc).splitlines()[0]}", file=sys.stderr)
        return 2
    report = {"meshes": {}, "pose": None, "keys": {}}
    for obj in bpy.data.objects:
        if obj.type != "MESH":
            continue
        keys = obj.data.shape_keys
        report["meshes"][obj.name] = {
            "vertices": len(obj.data.vertices),
            "shape_keys": [k.name for k in keys.key_blocks][1:] if keys else [],
            "armature": any(m.type == "ARMATURE" and m.object is not None for m in obj.modifiers),
        }
    head = next((o for o in bpy.data.objects if o.type == "MESH" and o.data.name == args.mesh), None)
    head = head or bpy.data.objects.get(args.mesh)
    if head is None:
        print(f"no mesh named {args.mesh} in {args.glb}", file=sys.stderr)
        return 2
    report["head_object"] = head.name
    if args.head_bone:
        report["head_keys"] = head_keys(bpy, head, args.head_bone)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    rest = evaluated(head, depsgraph)
    arm = next((m.object for m in head.modifiers if m.type == "ARMATURE" and m.object is not None), None)
    if arm is not None and head.vertex_groups:
        weight = {g.name: 0.0 for g in head.vertex_groups}
        names = {g.index: g.name for g in head.vertex_groups}
        for v in head.data.vertices:
            for g in v.groups:
                weight[names[g.group]] += g.weight
        bone = max((n for n in weight if n in arm.pose.bones), key=lambda n: weight[n], default=None)
        if bone is not None:
            pb = arm.pose.bones[bone]
            pb.rotation_mode = "XYZ"
            pb.rotation_euler = (math.radians(20.0), 0.0, 0.0)
            bpy.context.view_layer.update()
            moved = np.linalg.norm(evaluated(head, bpy.context.evaluated_depsgraph_get()) - rest, axis=1)
            report["pose"] = {"bone": bone, "max": float(moved.max()), "median": float(np.median(moved))}
            pb.rotation_euler = (0.0, 0.0, 0.0)
            bpy.context.view_layer.update()
    blocks = head.data.shape_keys.key_blocks if head.data.shape_keys else {}
    basis = None
    if head.data.shape_keys:
        n = len(head.data.vertices)
        basis = np.empty(n * 3)
        head.data.shape_keys.reference_key.data.foreach_get("co", basis)
        basis = basis.reshape(-1, 3)
    for name in [k for k in args.keys.split(",") if k]:
        if name not in blocks:
            report["keys"][name] = None
            continue
        for k in blocks:
            k.value = 0.0
        blocks[name].value = 1.0
        bpy.context.view_layer.update()
        moved = np.linalg.norm(evaluated(head, bpy.context.evaluated_depsgraph_get()) - rest, axis=1)
        stored = np.empty(basis.size)
        blocks[name].data.foreach_get("co", stored)
        report["keys"][name] = {"moved": float(moved.max()),
                                "stored": float(np.linalg.norm(stored.reshape(-1, 3) - basis, axis=1).max())}
        blocks[name].value = 0.0
    text = json.dumps(report, indent=1)
    if args.json:
        args.json.write_text(text)
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
