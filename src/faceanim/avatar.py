"""Whole avatars rigged in place: a skinned multi-mesh glTF/VRM in, the same avatar out with its
head meshes carrying faceanim's morph targets (``faceanim rig avatar.glb -o out.glb``).

1. **The head.** Among the scene's meshes (:mod:`faceanim.io.scene`), the head is the mesh named
   by ``--head-mesh``, else the one whose name says so (Ready Player Me's ``Wolf3D_Head``,
   VRoid's ``Face``, any ``head``/``face``; two such meshes are refused, naming both), else the
   highest mesh in the scene on whose render a face is found. Its companions are the smaller
   meshes inside its box (eyes, teeth, lashes, brows: ``EyeLeft``, ``Wolf3D_Teeth`` ...): rigged
   with it as one face.
2. **One face.** Each mesh in its bind pose (world space, as a viewer shows the file), its
   primitives welded where they touch (a face split into skin, lips and eyes by material is one
   surface), the meshes side by side in one :class:`~faceanim.face.mesh.Mesh`; landmarks found on
   its render (the head alone: no hair or body in the way), then :func:`~faceanim.autorig.auto_rig`.
3. **Back in place.** Each shape split back to its mesh and primitive vertices and written by
   :func:`~faceanim.io.scene.write_scene`: every node, skin, animation, material, texture and other
   mesh unchanged, the head meshes gaining the targets. Targets the avatar already has by a name
   faceanim makes are kept (reported) unless ``replace``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from faceanim.errors import FaceAnimError, LandmarkError, MeshError, shown

HEAD_NAMES = ("head", "face")  # a mesh whose lower-cased name contains one is a head candidate
NOT_HEAD = ("hair", "headwear", "hat", "helmet", "eye", "teeth", "tooth", "tongue", "brow", "lash", "glass")
COMPANION_MARGIN = 0.1  # a companion's box lies inside the head's, grown by this share of its size


@dataclass
class AvatarRig:
    """What :func:`rig_avatar` did: the head and companion meshes (names), the targets written,
    the avatar's own targets kept, and the face that was rigged (one Mesh over those meshes);
    ``replaced``: the written targets that replaced the avatar's own (``replace``)."""

    head: str
    companions: list[str]
    written: list[str]
    kept: list[str] = field(default_factory=list)
    skipped: dict = field(default_factory=dict)
    face: object = None
    replaced: list[str] = field(default_factory=list)
    notes: dict = field(default_factory=dict)


def _is_head_name(name: str) -> bool:
    low = name.lower()
    return any(h in low for h in HEAD_NAMES) and not any(n in low for n in NOT_HEAD)


def find_head(scene, head_mesh: str | None = None, forward: str = "+z", up: str = "+y") -> tuple[int, list[int]]:
    """(the head mesh's index, the companion meshes' indices) of ``scene`` (module docstring, 1);
    ``forward``/``up``: where a face looks on the renders that find a head by geometry."""
    infos = [m for m in scene.meshes() if m.editable and m.bbox is not None and m.n_vertices > 0]
    if not infos:
        raise MeshError(f"'{shown(scene.path.name, tail=True)}' has no triangle mesh to rig")
    if head_mesh is not None:
        named = [m for m in infos if m.name == head_mesh]
        if not named:
            names = ", ".join(f"'{shown(m.name)}'" for m in infos[:8])
            raise FaceAnimError(f"no mesh named '{shown(head_mesh)}' in the avatar; its meshes: {names}")
        head = named[0]
    else:
        named = [m for m in infos if _is_head_name(m.name)]
        if len(named) > 1:
            both = " and ".join(f"'{shown(m.name)}'" for m in named[:2])
            raise FaceAnimError(f"two meshes could be the head ({both}); choose one with --head-mesh NAME")
        if named:
            head = named[0]
        else:
            head = _head_by_geometry(scene, infos, forward, up)
    lo, hi = head.bbox
    grow = COMPANION_MARGIN * (hi - lo)
    companions = [m.index for m in infos if m.index != head.index and m.n_vertices < head.n_vertices
                  and np.all(m.bbox[0] >= lo - grow) and np.all(m.bbox[1] <= hi + grow)
                  and not any(n in m.name.lower() for n in ("hair", "glass", "hat"))]
    return head.index, companions


def _head_by_geometry(scene, infos, forward: str = "+z", up: str = "+y") -> object:
    """The highest mesh on whose render a face is found (meshes by the top of their box)."""
    from faceanim.face.landmarks import detect_landmarks

    for m in sorted(infos, key=lambda m: -m.bbox[1][1])[:4]:
        mesh, _ = scene.mesh_geometry(m.index)
        try:
            detect_landmarks(mesh, forward=forward, up=up)
        except LandmarkError:
            continue
        return m
    raise FaceAnimError(f"no head found among the avatar's {len(infos)} meshes (no face on their renders); "
                        "name it with --head-mesh NAME")


def avatar_face(scene, meshes: list[int], forward: str = "+z", up: str = "+y"):
    """(Face over the listed meshes side by side, per mesh (offset, welded count, weld index into
    its merged vertices)): module docstring, 2."""
    from faceanim.face.face import Face
    from faceanim.face.mesh import Mesh
    from faceanim.io.scene import weld

    parts, vertices, faces, offset = [], [], [], 0
    for mi in meshes:
        merged, _ = scene.mesh_geometry(mi)
        welded, index = weld(merged)
        parts.append((offset, welded.n_vertices, index))
        vertices.append(welded.vertices)
        faces.append(welded.faces + offset)
        offset += welded.n_vertices
    name = scene.meshes()[meshes[0]].name
    mesh = Mesh(np.vstack(vertices), np.vstack(faces), name=name or "head", source=str(scene.path))
    from faceanim.face.face import landmarks_478
    from faceanim.face.landmarks import detect_landmarks
    from faceanim.face.registration import check_face

    try:
        face = Face(mesh, landmarks_478(mesh, detect_landmarks(mesh, forward=forward, up=up)))
        check_face(face)
    except LandmarkError as exc:  # its advice (--landmarks) is for a single face mesh, refused for an avatar
        why = str(exc).split(";")[0].split(" (")[0]
        raise LandmarkError(f"{why} (the head mesh '{shown(mesh.name)}' rendered looking along {forward} with {up} "
                            "up); choose the head with --head-mesh NAME, or pass --forward/--up if the face points "
                            "elsewhere") from None
    return face, parts


def rig_avatar(source, output, sets, head_mesh: str | None = None, replace: bool = False,
               forward: str | None = None, up: str = "+y", progress=None, style: str = "realistic") -> AvatarRig:
    """Rig the head of the avatar file ``source`` in place and write it to ``output`` (module
    docstring). ``forward``: where the face looks (default +z; a VRM 0.x avatar faces -z)."""
    from faceanim.autorig import auto_rig
    from faceanim.io.scene import read_scene, write_scene

    scene = read_scene(source)
    if forward is None:
        forward = "-z" if "VRM" in (scene.document.extensions or {}) else "+z"
    head, companions = find_head(scene, head_mesh, forward, up)
    meshes = [head, *companions]
    face, parts = avatar_face(scene, meshes, forward, up)
    auto = auto_rig(face, sets, progress=progress, style=style)
    info = {m.index: m for m in scene.meshes()}
    existing = set()
    for mi in meshes:
        existing |= set(info[mi].target_names)
    kept = [] if replace else [n for n in auto.shapes if n in existing]
    names = [n for n in auto.shapes if n not in kept]
    additions = {}
    for mi, (offset, count, index) in zip(meshes, parts):
        additions[mi] = {n: auto.shapes[n][offset:offset + count][index] for n in names}
    notes = {}
    vrm = (scene.document.extensions or {}).get("VRMC_vrm")
    if isinstance(vrm, dict):
        notes = _bind_vrm(vrm, auto, {mi: info[mi] for mi in meshes}, names, replace)
    elif "VRM" in (scene.document.extensions or {}):
        notes["expressions"] = "VRM 0.x: the targets are added, its blend shape groups are left as they were"
    write_scene(scene, output, additions, replace=replace)
    return AvatarRig(info[head].name, [info[m].name for m in companions], names, kept, {**auto.skipped, **notes}, face,
                     [n for n in names if n in existing], auto.notes)


def _target_index(existing: tuple, added: list[str]) -> dict[str, int]:
    """Each target's index in a mesh after :func:`~faceanim.io.scene.write_scene` adds ``added``
    (a name it has keeps its place; new ones follow in order)."""
    index = {n: k for k, n in enumerate(existing)}
    for n in added:
        if n not in index:
            index[n] = len(index)
    return index


def _bind_vrm(vrm: dict, auto, meshes: dict, added: list[str], replace: bool) -> dict:
    """VRM 1.0's expression presets and one custom expression per ARKit shape bound to the targets
    (on every rigged mesh's node), in ``vrm`` (the file's VRMC_vrm, edited in place). A preset or
    custom expression the avatar already binds is kept unless ``replace``. Returns notes."""
    from faceanim.autorig import vrm_expressions
    from faceanim.io.vrm import expression_overrides

    bound, left_out = vrm_expressions(auto)
    expressions = vrm.setdefault("expressions", {})
    if not isinstance(expressions, dict):
        return {"expressions": "the VRM's expressions are not an object: left as they were"}
    preset = expressions.setdefault("preset", {})
    custom = expressions.setdefault("custom", {})
    kept = []

    def binds(targets: dict) -> list:
        out = []
        for info in meshes.values():
            if not info.nodes:
                continue
            index = _target_index(info.target_names, added)
            out += [{"node": int(info.nodes[0]), "index": index[t], "weight": float(w)} for t, w in targets.items()
                    if t in index]
        return out

    for table, items, is_preset in ((preset, bound, True),
                                    (custom, {n: {n: 1.0} for n in auto.sets.get("arkit", [])}, False)):
        for name, targets in items.items():
            have = table.get(name)
            if isinstance(have, dict) and have.get("morphTargetBinds") and not replace:
                kept.append(name)
                continue
            entry = {"isBinary": False, **(expression_overrides(name) if is_preset else {})}
            found = binds(targets)
            if found:
                entry["morphTargetBinds"] = found
            table[name] = entry
    notes = {p: why for p, why in left_out.items()}
    if kept:
        notes["VRM expressions kept"] = ", ".join(kept[:12]) + (" ..." if len(kept) > 12 else "")
    return notes


def is_avatar(path) -> bool:
    """Whether ``path`` is a glTF/VRM scene to rig in place: skinned, or more than one mesh."""
    from faceanim.io.gltf import glb_json

    if Path(path).suffix.lower() not in (".glb", ".vrm"):
        return False
    doc = glb_json(path)
    if not isinstance(doc, dict):
        return False
    meshes = doc.get("meshes") or []
    return bool(doc.get("skins")) or len(meshes) > 1 or Path(path).suffix.lower() == ".vrm"


@dataclass
class AvatarPlay:
    """What :func:`play_on_avatar` drove: per mesh name, the ARKit curves that found a target; the
    head bone turned (its node's name), or None."""

    driven: dict
    frames: int
    head_bone: str | None = None


HEAD_BONE_NAMES = ("head", "j_bip_c_head", "mixamorig:head", "bip01 head", "bip001 head", "cc_base_head")
FACING_SAMPLE = ("jawOpen", "eyeBlinkLeft", "eyeBlinkRight", "mouthSmileLeft", "mouthSmileRight", "browInnerUp")
AXIS_SNAP = 15.0  # degrees: a face this near an axis faces along it (the sample's parts are never quite symmetric)


def head_bone(scene) -> int | None:
    """The avatar's head bone (a node index): VRM 1.0's or 0.x's humanoid ``head``, else the first
    skin joint whose name is a head's (:data:`HEAD_BONE_NAMES`, any case: VRoid's ``Head`` or
    ``J_Bip_C_Head``, Ready Player Me's and Mixamo's ``Head``); None when there is none, or when
    it is given by a matrix (glTF animates only a node's translation, rotation and scale)."""
    gltf = scene._json
    nodes = gltf.get("nodes", [])
    ext = gltf.get("extensions") or {}
    found = None
    try:  # VRM 1.0: {"head": {"node": N}}; VRM 0.x: [{"bone": "head", "node": N}, ...]
        found = ext["VRMC_vrm"]["humanoid"]["humanBones"]["head"]["node"]
    except (KeyError, TypeError):
        try:
            found = next((b.get("node") for b in ext["VRM"]["humanoid"]["humanBones"]
                          if isinstance(b, dict) and b.get("bone") == "head"), None)
        except (KeyError, TypeError):
            pass
    if found is None:
        joints = sorted({j for skin in gltf.get("skins", []) for j in skin.get("joints", []) if type(j) is int})
        found = next((j for j in joints if 0 <= j < len(nodes)
                      and str(nodes[j].get("name", "")).strip().lower() in HEAD_BONE_NAMES), None)
    if type(found) is not int or not 0 <= found < len(nodes) or "matrix" in nodes[found]:
        return None
    return found


def face_axes(scene, bone: int) -> np.ndarray:
    """(3, 3) rows: the avatar's left, up and forward in world space. Up is glTF's +Y; forward is
    the level direction from the head bone to the parts of the face its ARKit targets move (so a
    VRM 0.x avatar, which faces -Z, and one facing +Z both nod forward), the axis it is within
    :data:`AXIS_SNAP` of; +Z when that is unclear."""
    from faceanim.standards.arkit import name_key

    centre = scene._globals[bone][:3, 3]
    sample = {name_key(k) for k in FACING_SAMPLE}
    moved = []
    for mi in arkit_targets(scene):
        names = [n for n in dict.fromkeys(scene._target_names(mi)) if name_key(n) in sample]
        if not names:
            continue
        deltas = scene.targets(mi, names)
        hit = np.any([np.linalg.norm(d, axis=1) > 1e-6 for d in deltas.values()], axis=0)
        moved.append(scene._world_positions(mi)[hit])
    forward = np.array([0.0, 0.0, 1.0])
    if moved and sum(len(m) for m in moved):
        ahead = np.concatenate(moved).mean(axis=0) - centre
        ahead[1] = 0.0
        if np.linalg.norm(ahead) > 1e-3:
            forward = ahead / np.linalg.norm(ahead)
            k = int(np.argmax(np.abs(forward)))
            if abs(forward[k]) > np.cos(np.radians(AXIS_SNAP)):  # modelled facing an axis: that axis
                forward = np.sign(forward[k]) * np.eye(3)[k]
    up = np.array([0.0, 1.0, 0.0])
    return np.stack([np.cross(up, forward), up, forward])


def head_track(scene, bone: int, angles: np.ndarray) -> np.ndarray:
    """(F, 4) quaternions (x, y, z, w) of ``bone``'s local rotation that turn the head by ``angles``
    ((F, 3) yaw, pitch, roll in radians, faceanim's signs: :func:`~faceanim.export.head_rotations`)
    about its own pivot, in the avatar's frame (:func:`face_axes`), from its rest pose."""
    from scipy.spatial.transform import Rotation

    from faceanim.export import head_rotations

    nodes = scene._json["nodes"]
    parent = next((n for n, node in enumerate(nodes) if bone in node.get("children", [])), None)
    above = scene._globals[parent][:3, :3] if parent is not None else np.eye(3)
    u, _, vt = np.linalg.svd(above)  # its rotation (a parent's scale does not turn the head)
    p = u @ vt
    rest = Rotation.from_quat(nodes[bone]["rotation"]).as_matrix() if "rotation" in nodes[bone] else np.eye(3)
    turn = head_rotations(angles, face_axes(scene, bone))  # (F, 3, 3) in world space
    local = np.einsum("ji,fjk,kl,lm->fim", p, turn, p, rest)  # P^T D P R
    q = Rotation.from_matrix(local).as_quat()
    q[np.cumsum(np.r_[False, np.einsum("fi,fi->f", q[1:], q[:-1]) < 0]) % 2 == 1] *= -1  # no flips between keys
    return q


def arkit_targets(scene) -> dict[int, dict[int, int]]:
    """The scene's morph targets named by ARKit (any spelling, :func:`~faceanim.standards.arkit.name_key`):
    {mesh index: {target index: column of :data:`~faceanim.standards.arkit.ARKIT_NAMES`}}, meshes with
    none left out."""
    from faceanim.standards.arkit import ARKIT_NAMES, name_key

    column = {name_key(n): k for k, n in enumerate(ARKIT_NAMES)}
    out = {}
    for info in scene.meshes():
        found = {t: column[name_key(n)] for t, n in enumerate(info.target_names) if name_key(n) in column}
        if found and info.nodes:
            out[info.index] = found
    return out


def play_on_avatar(source, output, curves: np.ndarray, fps: float, name: str = "take",
                   extras: dict | None = None, head: np.ndarray | None = None) -> AvatarPlay:
    """The avatar file ``source`` written to ``output`` as it was (meshes, skins, materials, its own
    targets and animations, edits made in Blender), with one more animation, ``name``: ``curves``
    (F, 52, Live Link Face order, clamped to 0..1) played onto its own morph targets by their ARKit
    names, at ``fps``; its other targets stay at 0; ``head`` ((F, 3) yaw, pitch, roll, radians) turns
    its head bone (:func:`head_bone`, :func:`head_track`) when it has one; ``extras`` are merged into
    the scene's (a sound beside it: ``{"audio": "x.wav"}``). Refused when no target carries an ARKit
    name."""
    from faceanim.standards.arkit import ARKIT_NAMES
    from faceanim.io.scene import read_scene, write_scene

    scene = read_scene(source)
    targets = arkit_targets(scene)
    if not targets:
        raise FaceAnimError(f"'{shown(Path(source).name, 60)}' has no morph target named by ARKit (jawOpen, "
                            "eyeBlinkLeft ... in any spelling: JawOpen, eyeBlink_L); rig it first with faceanim rig")
    w = np.clip(np.asarray(curves, dtype=np.float64), 0.0, 1.0)
    info = {m.index: m for m in scene.meshes()}
    weights, driven = {}, {}
    for mi, found in targets.items():
        rows = np.zeros((len(w), len(info[mi].target_names)))
        for t, k in found.items():
            rows[:, t] = w[:, k]
        weights[mi] = rows
        driven[info[mi].name] = sorted({ARKIT_NAMES[k] for k in found.values()}, key=ARKIT_NAMES.index)
    if extras:
        doc = scene.document
        if doc.scenes:
            target = doc.scenes[doc.scene or 0]
            target.extras = {**(target.extras if isinstance(target.extras, dict) else {}), **extras}
    animation = {"name": name, "times": np.arange(len(w)) / float(fps), "weights": weights}
    bone = None
    if head is not None:
        angles = np.asarray(head, dtype=np.float64)
        if angles.shape != (len(w), 3) or not np.isfinite(angles).all():
            raise FaceAnimError(f"the head's angles need ({len(w)}, 3) finite values, one row per frame")
        bone = head_bone(scene)
        if bone is not None:
            animation["rotations"] = {bone: head_track(scene, bone, angles)}
    write_scene(scene, output, {}, animation=animation)
    return AvatarPlay(driven, len(w), None if bone is None else str(scene._json["nodes"][bone].get("name", bone)))

