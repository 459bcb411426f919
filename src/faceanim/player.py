"""Playing FAP streams on a face: speech to FAPs, FAP streams to MP4 (with sound) or glTF."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from faceanim.drivers.mpeg4 import Action, FapStream, blend_actions
from faceanim.rig.mpeg4 import FapRig


def speech_stream(rig: FapRig, phones, fps: float = 25.0, extra: list[Action] | None = None,
                  name: str = "speech") -> FapStream:
    """A FAP stream for timed phones (co-articulated visemes), plus any other actions."""
    from faceanim.drivers.speech.visemes import viseme_actions

    actions = viseme_actions(phones, rig.lip_gap) + list(extra or [])
    end = max([p.end for p in phones] + [a.end for a in actions])
    return blend_actions(actions, int(np.ceil(end * fps)) + 1, fps, name)


def render_stream(rig: FapRig, stream: FapStream, path, lm478, size: int = 512, audio=None, progress=None) -> Path:
    """Render a FAP stream on the rig's face to an MP4 (with the WAV ``audio`` as its sound)."""
    from faceanim.face.landmarks import FACE_OVAL
    from faceanim.render import OffscreenRenderer, write_video

    with OffscreenRenderer(rig.mesh, size=(size, size), yaw=8, pitch=3,
                           frame_vertices=np.asarray(lm478)[list(FACE_OVAL)], margin=1.3) as r:
        frames = (r.render(v) for v in _chunks(rig, stream))
        return write_video(path, frames, fps=stream.fps, audio=audio, progress=progress)


def _chunks(rig: FapRig, stream: FapStream, size: int = 64):
    for a in range(0, stream.n_frames, size):
        sub = FapStream(stream.values[a:a + size], stream.mask[a:a + size], stream.fps, stream.name,
                        stream.viseme[a:a + size], stream.expression[a:a + size], stream.frame_numbers[a:a + size])
        yield from rig.evaluate(sub)


def gltf_stream(rig: FapRig, stream: FapStream, path) -> Path:
    """A FAP stream as a glTF animation: one morph target per FAP the stream uses, weighted by the
    FAP's values (scaled to [-1, 1]). The linear FAPs are exact; the jaw and head rotations are
    linearised around the neutral face (exact for small angles; the MP4 keeps true rotations)."""
    from faceanim.errors import FaceAnimError
    from faceanim.io.gltf import write_gltf

    shapes, columns, scales = {}, [], []
    for idx in np.flatnonzero(stream.mask.any(axis=0)):
        n = idx + 1
        if n in (3, 14, 15, 48, 49, 50):
            small = 50.0 if n in (3, 14, 15) else 1000.0
            probe = FapStream.empty(1, stream.fps)
            probe.values[0, idx] = small
            probe.mask[0, idx] = True
            per_unit = (rig.evaluate(probe)[0] - rig.mesh.vertices) / small
        elif n > 2 and rig.supported[idx]:
            per_unit = rig.blendshape(n)
        else:
            continue
        peak = float(np.abs(stream.values[stream.mask[:, idx], idx]).max()) or 1.0
        shapes[f"fap{n}"] = per_unit * peak
        columns.append(idx)
        scales.append(peak)
    if not shapes:
        raise FaceAnimError("the stream sets no FAP this face can show")
    weights = np.where(stream.mask[:, columns], stream.values[:, columns], 0.0) / np.array(scales)
    times = np.arange(stream.n_frames) / stream.fps
    return write_gltf(path, rig.mesh, shapes, times=times, weights=weights, animation_name=stream.name or "faps")
