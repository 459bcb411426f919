"""One export type and one suffix -> writer registry for every animation faceanim writes.

Whatever made an animation - a video performance, a recorded Live Link take, speech, a FAP stream,
a scene script, a live run - it is handed to the writers as one plain :class:`Animation`: a face
(its mesh), morph targets and their weights over time, ARKit's 52 curves, the head's and the eyes'
rotations, mouth cues and the sound. :data:`WRITERS` maps each output suffix to the writer of one
file format; :func:`write` picks the writer by the suffix. A command's ``-o`` accepts the suffixes
of the writers it can fill (:func:`suffixes`) and its ``--help`` lists them from here, as do the
live file sinks (``faceanim live --to file:PATH``).

A field that takes work to make (ARKit curves fitted to a FAP stream, the face's ARKit shapes)
may be given as a function of no arguments: a writer calls it only when its format needs it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from faceanim.errors import FaceAnimError, shown

if TYPE_CHECKING:  # numpy is imported when a writer runs: a command's --help reads WRITERS without it
    import numpy as np


@dataclass
class Animation:
    """An animation as the writers take it (any field may be None when the writer asked for does
    not need it; see :data:`WRITERS`).

    - ``fps``: frames per second of every per-frame array;
    - ``arkit``: (F, 52) ARKit weights 0..1 in Live Link Face order
      (:data:`~faceanim.standards.arkit.ARKIT_NAMES`);
    - ``head``: (F, 3) the head's yaw, pitch, roll in radians (faceanim's signs); ``eyes``: (F, 6)
      each eye's yaw, pitch, roll in radians, as Live Link Face writes them;
    - ``face``: the :class:`~faceanim.face.face.Face` animated (its mesh is what .glb and .mp4 show);
    - ``targets`` and ``weights``: morph targets on the face's mesh (name -> (V, 3) deltas) and
      their (F, T) weights, written instead of the face's ARKit shapes (e.g. one target per FAP);
    - ``shapes``: the face's ARKit shapes by Apple's names if already made
      (:func:`~faceanim.rig.arkit.arkit_shapes` otherwise);
    - ``rig`` and ``curves``: a :class:`~faceanim.rig.rig.Rig` and its (F, C) curves, which an MP4
      renders exactly (rigid jaw and eyes) instead of the morph targets; ``rig_turns_head``: the
      rig's curves turn the head themselves (a FAP rig), so an MP4 does not turn it by ``head`` again;
    - ``fap``: the :class:`~faceanim.face.faps.FapStream` a ``.fap`` file holds;
    - ``cues``: Rhubarb mouth cues (start seconds, shape) when known better than from the curves
      (from timed phones);
    - ``sound``: a WAV of the animation's sound, written beside a .glb or a cue file (named in it)
      and muxed into an MP4; ``sound_name``: the user's own file of that sound, named in a cue
      file instead of writing a copy;
    - ``video``: the video an MP4 shows beside the face (its frames and its sound);
    - ``name``, ``extras``: the glTF animation's name and the scene's extras; ``quantize``: compact
      glTF targets; ``size``, ``view``: the MP4's frame height and camera
      (:meth:`Face.view <faceanim.face.face.Face.view>`).
    """

    fps: float
    arkit: np.ndarray | Callable | None = None
    head: np.ndarray | Callable | None = None
    eyes: np.ndarray | None = None
    face: object = None
    targets: dict | Callable | None = None
    weights: np.ndarray | None = None
    shapes: dict | Callable | None = None
    rig: object = None
    curves: np.ndarray | None = None
    rig_turns_head: bool = False
    fap: object = None
    cues: list | None = None
    sound: Path | None = None
    sound_name: str = ""
    video: Path | None = None
    name: str = "animation"
    extras: dict = field(default_factory=dict)
    quantize: bool = False
    size: int = 512
    view: dict | None = None

    def need(self, name: str, why: str):
        """The field ``name`` (made now if given as a function); refused with ``why`` if missing."""
        import numpy as np

        value = getattr(self, name)
        if callable(value) and not isinstance(value, (np.ndarray, dict)):
            value = value()
            setattr(self, name, value)
        if value is None:
            raise FaceAnimError(why)
        return value

    @property
    def n_frames(self) -> int:
        import numpy as np

        for name in ("arkit", "weights", "curves", "head"):
            value = getattr(self, name)
            if isinstance(value, np.ndarray):
                return len(value)
        if self.fap is not None:
            return self.need("fap", "").n_frames
        raise FaceAnimError("the animation has no frames")


@dataclass(frozen=True)
class Writer:
    """One output format: its suffix, what it holds (for ``--help`` and errors), whether it shows a
    face, and the function writing an :class:`Animation` to a path (returning every file written)."""

    suffix: str
    holds: str
    shows_face: bool
    write: Callable


def head_pivot(face) -> np.ndarray:
    """(3,) the point the head turns about: midway between the face oval's sides in front of the
    ears (landmarks 234, 454) at the eyes' height, 0.3 inter-ocular distances further back (near
    the skull's centre; the neck's top is lower, but a head turning about it sways its face)."""
    fr = face.frame
    lm = face.landmarks
    centre = 0.5 * (lm[234] + lm[454])
    centre = centre + fr.rotation[1] * float((0.5 * (lm[33] + lm[263]) - centre) @ fr.rotation[1])
    return centre - fr.rotation[2] * 0.3 * fr.iod


def head_rotations(angles: np.ndarray, axes: np.ndarray | None = None) -> np.ndarray:
    """(F, 3, 3) the head's rotation per frame from (F, 3) yaw, pitch, roll in radians (faceanim's
    signs, :data:`~faceanim.drivers.video.tracking.POSE_NAMES`), in the coordinates of a mesh whose
    face frame has ``axes`` (3, 3; rows: the face's left, up and forward in mesh coordinates); without
    ``axes``, the face's own frame."""
    import numpy as np

    from faceanim.build.motion import head_rotation

    a = np.asarray(angles, dtype=np.float64).reshape(-1, 3)
    r = head_rotation(a[:, 0], a[:, 1], a[:, 2])
    if axes is None:
        return r
    f = np.asarray(axes, dtype=np.float64)
    return np.einsum("ji,fjk,kl->fil", f, r, f)  # F^T R F


def head_quaternions(angles: np.ndarray, axes: np.ndarray | None = None) -> np.ndarray:
    """(F, 4) :func:`head_rotations` as glTF quaternions (x, y, z, w)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(head_rotations(angles, axes)).as_quat()


def arkit_shapes_of(a: Animation) -> dict:
    """The animated face's ARKit shapes by Apple's names (made once and kept on ``a``)."""
    if a.shapes is None:
        from faceanim.rig.arkit import arkit_shapes

        face = a.need("face", "this output shows the face; give one")
        a.shapes = lambda: arkit_shapes(face)[0]
    return a.need("shapes", "the face has no ARKit shapes")


def _arkit(a: Animation) -> np.ndarray:
    import numpy as np

    return np.asarray(a.need("arkit", "this output holds ARKit curves, which this animation does not have"),
                      dtype=np.float64)


def _head(a: Animation) -> np.ndarray | None:
    """The head's (F, 3) angles, or None when the animation has none (a still head is zeros: a .glb
    still gets its ``head`` node, as ARKit rigs expect)."""
    import numpy as np

    return np.asarray(a.need("head", ""), dtype=np.float64) if a.head is not None else None


def write_csv(path: Path, a: Animation, progress=None) -> list[Path]:
    """Live Link Face CSV: the ARKit curves, the head's and the eyes' angles."""
    from faceanim.io.arkit_csv import write_arkit_csv

    arkit = _arkit(a)
    return [write_arkit_csv(path, arkit, a.fps, _head(a), a.eyes)]


def write_cue_file(path: Path, a: Animation, progress=None) -> list[Path]:
    """Rhubarb Lip Sync's mouth cues (.tsv or .json): ``cues`` if given, else classified from the
    ARKit curves; the sound named (the user's file) or written beside (``cue_sound``)."""
    from faceanim.io.rhubarb import cue_sound, write_cues

    if a.cues is not None:
        cues = a.cues
    else:
        from faceanim.drivers.cues import arkit_cues
        from faceanim.standards.arkit import ARKIT_NAMES

        cues = arkit_cues(_arkit(a), list(ARKIT_NAMES), a.fps)
    duration = a.n_frames / a.fps
    if a.sound is not None:
        from faceanim.io.audio import read_audio

        samples, rate = read_audio(a.sound)
        duration = len(samples) / rate
        if not a.sound_name:
            sound = cue_sound(path)
            return sound_beside(write_cues(path, cues, duration, sound.name), sound, samples, rate)
    return [write_cues(path, cues, duration, a.sound_name)]


def sound_beside(written: Path, companion: Path, samples, rate: int) -> list[Path]:
    """``written`` and the sound written as ``companion`` beside it; ``written`` removed if that fails
    (no half of the pair left behind)."""
    from faceanim.io.audio import write_wav

    try:
        return [written, write_wav(companion, samples, rate)]
    except BaseException:
        written.unlink(missing_ok=True)
        raise


def write_glb(path: Path, a: Animation, progress=None) -> list[Path]:
    """The face with morph targets and their weights animated (``targets``/``weights``, or the face's
    ARKit shapes by Apple's names driven by the ARKit curves), the head's rotation on a node ``head``
    turning about :func:`head_pivot`, the sound beside it (named in the scene's ``extras.audio``)."""
    import numpy as np

    from faceanim.io.gltf import sound_companion, write_gltf

    face = a.need("face", f"a {path.suffix} output shows the face; give one")
    sound = None
    extras = {"fps": a.fps, **a.extras}
    if a.sound is not None:
        from faceanim.io.audio import read_audio

        sound = read_audio(a.sound)
        companion = sound_companion(path)
        extras["audio"] = companion.name
    head = _head(a)
    rotations = None if head is None else head_quaternions(head, face.frame.rotation)
    if a.targets is not None:
        targets = a.need("targets", "")
        if not targets:
            raise FaceAnimError("the animation moves no control of this face")
        w = np.asarray(a.weights, dtype=np.float64)
    else:
        from faceanim.standards.arkit import ARKIT_NAMES, apple_name

        made = arkit_shapes_of(a)
        column = {apple_name(n): k for k, n in enumerate(ARKIT_NAMES)}
        names = [n for n in made if n in column]
        targets = {n: made[n] for n in names}
        w = np.clip(_arkit(a)[:, [column[n] for n in names]], 0.0, 1.0)
        extras["morph_sets"] = {"arkit": names}
    glb = write_gltf(path, face.mesh, targets, times=np.arange(len(w)) / a.fps, weights=w, animation_name=a.name,
                     rotations=rotations, pivot=None if rotations is None else head_pivot(face), extras=extras,
                     quantize=a.quantize)
    return [glb] if sound is None else sound_beside(glb, companion, *sound)


def face_frames(a: Animation, chunk: int = 64):
    """The animated face's vertices frame by frame: the rig's curves (or the targets' weights, or
    the ARKit shapes' curves) evaluated ``chunk`` frames at a time, then turned by the head's
    rotation about :func:`head_pivot`."""
    import numpy as np

    from faceanim.rig.rig import Rig

    face = a.need("face", "an MP4 shows the face; give one")
    if a.rig is not None:
        rig, curves = a.rig, np.asarray(a.curves, dtype=np.float64)
    elif a.targets is not None:
        rig, curves = Rig.from_blendshapes(face.mesh, a.need("targets", "")), np.asarray(a.weights, dtype=np.float64)
    else:
        from faceanim.standards.arkit import ARKIT_NAMES, apple_name

        rig = Rig.from_blendshapes(face.mesh, arkit_shapes_of(a))
        column = {apple_name(n): k for k, n in enumerate(ARKIT_NAMES)}
        curves = _arkit(a)[:, [column[c] for c in rig.controls]]
    head = None if a.rig is not None and a.rig_turns_head else _head(a)
    rot = None if head is None or not np.any(head) else head_rotations(head, face.frame.rotation)
    pivot = head_pivot(face) if rot is not None else None
    for s in range(0, len(curves), chunk):
        for j, v in enumerate(rig.evaluate(curves[s:s + chunk])):
            yield v if rot is None else (v - pivot) @ rot[s + j].T + pivot


def write_mp4(path: Path, a: Animation, progress=None) -> list[Path]:
    """The face rendered at ``size`` pixels (beside the frames of ``video`` when given, with its
    sound), with the animation's sound."""
    import tempfile

    from faceanim.limits import check_video
    from faceanim.render.gl import OffscreenRenderer
    from faceanim.render.video import write_video

    face = a.need("face", "an MP4 shows the face; give one")
    size = a.size
    check_video(a.n_frames, size, size)
    view = a.view if a.view is not None else face.view(yaw=0.0, pitch=0.0)
    with OffscreenRenderer(face.mesh, size=(size, size), **view) as r:
        r.cull_unseen_backs()  # back faces none of the rest pose shows are not drawn
        faces = r.render_frames(face_frames(a))
        if a.video is None:
            return [write_video(path, faces, fps=a.fps, audio=a.sound, progress=progress)]
        from faceanim.io.video import side_by_side, video_frames, video_info, video_sound

        info = video_info(a.video)
        with tempfile.TemporaryDirectory(dir=path.parent.resolve()) as tmp:
            sound = a.sound if a.sound is not None else video_sound(a.video, tmp)
            return [write_video(path, side_by_side(video_frames(info), faces, size), fps=a.fps, audio=sound,
                                progress=progress)]


def write_fap_file(path: Path, a: Animation, progress=None) -> list[Path]:
    """MPEG-4 FAPs (a .fap file for any MPEG-4 face player)."""
    from faceanim.io.fapfile import write_fap

    return [write_fap(path, a.need("fap", "a .fap output holds MPEG-4 FAPs, which this animation does not have"))]


WRITERS: dict[str, Writer] = {w.suffix: w for w in (
    Writer(".glb", "the face with its morph targets animated (glTF)", True, write_glb),
    Writer(".mp4", "the face rendered, with the sound (H.264)", True, write_mp4),
    Writer(".csv", "ARKit curves and head angles (Live Link Face CSV)", False, write_csv),
    Writer(".tsv", "mouth cues (Rhubarb Lip Sync, tab-separated)", False, write_cue_file),
    Writer(".json", "mouth cues (Rhubarb Lip Sync, JSON)", False, write_cue_file),
    Writer(".fap", "MPEG-4 FAPs for any MPEG-4 face player", False, write_fap_file),
)}


def suffixes(*leave_out: str) -> tuple[str, ...]:
    """The suffixes an animation is written to, in :data:`WRITERS` order, but ``leave_out``."""
    return tuple(s for s in WRITERS if s not in leave_out)


def write(path, a: Animation, progress=None) -> list[Path]:
    """Write ``a`` by the suffix of ``path`` (:data:`WRITERS`); returns every file written."""
    path = Path(path)
    writer = WRITERS.get(path.suffix.lower())
    if writer is None:
        raise FaceAnimError(f"unknown output kind '{shown(path.suffix)}'; write {', '.join(WRITERS)}")
    if writer.shows_face and a.face is None:
        raise FaceAnimError(f"a {writer.suffix} output shows the face animated; give the face")
    return writer.write(path, a, progress)
