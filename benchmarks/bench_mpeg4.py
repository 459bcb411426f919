"""MPEG-4 playback speed and memory on the default head (24,591 vertices).

    .venv/bin/python benchmarks/bench_mpeg4.py [../shared/data/speech-librivox] [--blas-threads N]

A spoken sentence (espeak-ng word by word, timed phones -> co-articulated visemes -> FAP stream at
25 fps) with head turns (head_yaw and head_pitch) added over its second half, so frames use the
lips, the jaw hinge and the head rotation. FAP stream -> mesh, one frame and the whole clip, cold
(the FaceDefTable built from a fresh Face, then the evaluation; best of 3) and warm (best of
30 single frames or 5 clips after a warm-up), methods called in turn (interleaved):

- faceanim: the FapRig kept between clips (``FapRig.evaluate``: one sparse product per frame plus
  the rigid jaw and head steps);
- baseline (a), the FaceDefTable rebuilt per clip: ``FapRig.build`` on a Face whose skin, slits and
  feature points are already cached (the per-FAP graph distances are computed again), then the
  evaluation (for one frame: a clip of one frame);
- baseline (b), what a user writes with the table in hand: the 68 FAP blendshapes as one dense
  (3V, 68) numpy matrix, ``rest + D @ fap`` per frame (one BLAS product ``FAPs @ D.T`` for the
  clip), then the jaw and head rotations in numpy (the 3x3 matrices from
  ``RigidPart.transforms``, the vertex work vectorised over the frames that use each part).

Memory: the rig's bytes (deformer and rigid parts), what tracemalloc sees kept after the build and
after the first frame, and the peaks during the build and the clip. Then text to animation
against real time (synthesis and, with the LibriVox folder, forced alignment). Compare the ratio
columns; wall-clock times are never asserted.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from _timing import (
    Row,
    Stopwatch,
    arguments,
    best,
    best_fresh,
    blas_threads,
    fmt_bytes,
    fmt_ratio,
    fmt_time,
    header,
    interleaved,
    once,
    size_of,
    speed_table,
    table,
    traced,
)

from faceanim.drivers.speech import align, say_timed
from faceanim.drivers.speech.visemes import speech_stream
from faceanim.face.face import Face
from faceanim.standards.mpeg4 import fap
from faceanim.rig.mpeg4 import FapRig

TEXT = "Hello, how are you? I am a talking face built from the papers."
HEAD_TURN = 15000.0  # AU (1e-5 rad): 0.15 rad


class DenseFapPlayer:
    """Baseline (b): the FAP blendshapes as one dense (3V, 68) matrix and the rigid steps in numpy."""

    def __init__(self, rig: FapRig):
        v, c = rig.mesh.n_vertices, rig.n_controls
        w = rig.deformer.dense_weights()  # (V, 3C), W[v, 3c + a] = B_c[v, a]
        self.d = np.ascontiguousarray(w.reshape(v, c, 3).transpose(0, 2, 1).reshape(3 * v, c))
        self.rest = rig.mesh.vertices
        self.limits = rig.limits
        self.parts = [(p, [rig.index(n) for n in p.controls], p.share[:, None],
                       p.rows.size == v and np.array_equal(p.rows, np.arange(v))) for p in rig.rigid_parts]

    def nbytes(self) -> int:
        return size_of(self.d)

    def _rotations(self, part, cols, c):
        r_local, t = part.transforms({n: c[:, i] for n, i in zip(part.controls, cols)}, len(c))
        return part.axes.T[None] @ r_local @ part.axes[None], t  # in mesh coordinates

    def frame(self, c):
        """Positions (V, 3) for one frame of 68 FAP values."""
        c = np.clip(c, self.limits[0], self.limits[1])
        out = (self.rest.reshape(-1) + self.d @ c).reshape(-1, 3)
        for part, cols, w, _ in self.parts:
            if not np.any(c[cols]):
                continue
            r, t = self._rotations(part, cols, c[None])
            p = self.rest[part.rows] if part.from_rest else out[part.rows]
            moved = (p - part.pivot) @ r[0].T + part.pivot + t[0]
            if part.from_rest:
                out[part.rows] += w * (moved - p)
            else:
                out[part.rows] = p + w * (moved - p)
        return out

    def clip(self, curves):
        """Positions (F, V, 3) for (F, 68) FAP values."""
        c = np.clip(curves, self.limits[0], self.limits[1])
        out = (c @ self.d.T).reshape(len(c), -1, 3)
        out += self.rest
        for part, cols, w, whole in self.parts:
            active = np.flatnonzero(np.any(c[:, cols] != 0, axis=1))
            if not len(active):
                continue
            r, t = self._rotations(part, cols, c[active])
            at = (active,) if whole else (active[:, None], part.rows[None])
            p = self.rest[part.rows][None] if part.from_rest else out[at]
            moved = np.matmul(p - part.pivot, np.swapaxes(r, 1, 2)) + (part.pivot + t)[:, None]
            if part.from_rest:
                out[at] += w * (moved - p)
            else:
                out[at] = p + w * (moved - p)
        return out


def rig_bytes(rig: FapRig) -> int:
    return rig.deformer.nbytes() + sum(size_of(p.rows, p.share) for p in rig.rigid_parts)


def main() -> None:
    args = arguments(__doc__, data="LibriVox folder (clip-*.wav with clip-*.txt) for the alignment time")
    with blas_threads(args.blas_threads):
        header("bench_mpeg4: FAP stream -> mesh against rebuilding the table and a dense numpy player", touch=2**30)
        clock = Stopwatch()
        face = Face.default()
        mesh, lm = face.mesh, face.landmarks
        rig = FapRig.build(face)  # also fills the face's caches (skin, slits, feature points)
        clock.lap("setup")

        # ---------------------------------------------------------------- the clip
        with tempfile.TemporaryDirectory() as tmp:
            wav = Path(tmp) / "speech.wav"
            t_tts, phones = once(lambda: say_timed(TEXT, wav))
        t_stream = best(lambda: speech_stream(rig.lip_gap, phones, 25.0), repeat=5)
        stream = speech_stream(rig.lip_gap, phones, 25.0)
        n = stream.n_frames
        half = np.arange(n // 2, n)
        phase = np.linspace(0, 2 * np.pi, len(half))
        stream.set("head_yaw", HEAD_TURN * np.sin(phase), half)
        stream.set("head_pitch", 0.5 * HEAD_TURN * np.sin(2 * phase), half)
        curves = rig.stream_curves(stream)
        speech = phones[-1].end
        jaw = np.abs(curves[:, fap("open_jaw").number - 1]) > 0
        head = np.abs(curves[:, fap("head_yaw").number - 1]) > 0
        k_jaw = int(np.flatnonzero(jaw & ~head)[np.argmax(curves[jaw & ~head, 2])])  # widest open, no head
        k_head = int(np.flatnonzero(jaw & head)[0]) if (jaw & head).any() else int(np.flatnonzero(head)[0])
        print(f"## default face: {mesh.n_vertices} vertices; '{TEXT}' = {speech:.2f} s of speech, {n} frames "
              f"at 25 fps: {int(jaw.sum())} with the jaw open, {int(head.sum())} with head turns\n")

        # ---------------------------------------------------------------- players
        dense = DenseFapPlayer(rig)
        err = max(np.abs(dense.clip(curves) - rig.evaluate(curves)).max(),
                  np.abs(dense.frame(curves[k_head]) - rig.evaluate(curves[k_head:k_head + 1])[0]).max())

        def rebuild():
            return FapRig.build(face)  # the Face's caches are warm: skin, slits, feature points

        def cold_rig():
            return FapRig.build(Face(mesh, lm))  # a fresh Face: its caches are computed again

        fa, dn, rb = "faceanim FapRig", "(b) dense numpy (3V, 68) + rigid steps", "(a) FaceDefTable rebuilt per clip"
        rows: list[Row] = []
        cold1 = interleaved({fa: lambda: cold_rig().evaluate(curves[k_head:k_head + 1]),
                             dn: lambda: DenseFapPlayer(cold_rig()).frame(curves[k_head])}, repeat=3, warmup=0)
        rows += [Row("1 frame (jaw + head), cold", dn, cold1[dn], baseline=True, note="build + densify + frame"),
                 Row("1 frame (jaw + head), cold", fa, cold1[fa], note="build + frame")]
        for label, k in (("1 frame, lips + jaw, warm", k_jaw), ("1 frame, lips + jaw + head turn, warm", k_head)):
            one = curves[k:k + 1]
            warm = interleaved({dn: lambda one=one: dense.frame(one[0]), fa: lambda one=one: rig.evaluate(one)},
                               repeat=30, warmup=3, warmup_seconds=0.1)
            t_rb, _ = best_fresh(lambda one=one: rebuild().evaluate(one), repeat=3)
            rows += [Row(label, rb, t_rb, baseline=True), Row(label, dn, warm[dn], baseline=True),
                     Row(label, fa, warm[fa])]
        singles = [curves[k:k + 1] for k in range(n)]
        loop = interleaved({dn: lambda: [dense.frame(s[0]) for s in singles],
                            fa: lambda: [rig.evaluate(s) for s in singles]}, repeat=5, warmup=1)
        label = f"clip frame by frame ({n} calls), warm"
        rows += [Row(label, dn, loop[dn], n, baseline=True), Row(label, fa, loop[fa], n)]
        clip = interleaved({rb: lambda: rebuild().evaluate(curves), dn: lambda: dense.clip(curves),
                            fa: lambda: rig.evaluate(curves)}, repeat=5, warmup=1)
        label = f"whole clip ({n} frames) in one call, warm"
        rows += [Row(label, rb, clip[rb], n, baseline=True, note="build + clip"),
                 Row(label, dn, clip[dn], n, baseline=True), Row(label, fa, clip[fa], n)]
        coldn = interleaved({fa: lambda: cold_rig().evaluate(curves), dn: lambda: DenseFapPlayer(cold_rig()).clip(curves)},
                            repeat=3, warmup=0)
        label = f"whole clip ({n} frames), cold"
        rows += [Row(label, dn, coldn[dn], n, baseline=True, note="build + densify + clip"),
                 Row(label, fa, coldn[fa], n, note="build + clip")]
        speed_table(rows, notes=[
            f"clip: {speech:.2f} s of speech; real time is {fmt_time(1 / 25)} per frame",
            f"max |dense numpy - faceanim| over the clip: {err:.1e} m"])
        clock.lap("playback")

        # ---------------------------------------------------------------- memory
        built, kept_b, peak_b = traced(cold_rig)
        _, kept_1, _ = traced(lambda: built.evaluate(curves[:1]))
        _, _, peak_clip = traced(lambda: built.evaluate(curves))
        player, kept_d, peak_d = traced(lambda: DenseFapPlayer(built))
        _, _, peak_dclip = traced(lambda: player.clip(curves))
        _, _, peak_r = traced(lambda: rebuild().evaluate(curves))
        table([[fa, fmt_bytes(rig_bytes(built)), fmt_bytes(kept_b), fmt_bytes(kept_b + kept_1), fmt_bytes(peak_b),
                fmt_bytes(peak_clip)],
               [dn, fmt_bytes(player.nbytes()), f"+{fmt_bytes(kept_d)}", "-", f"+{fmt_bytes(peak_d)} (densify)",
                fmt_bytes(peak_dclip)],
               [rb, "-", "-", "-", "= faceanim's", f"{fmt_bytes(peak_r)} (build + clip)"]],
              ["method", "operator", "kept after build", "kept after 1st frame", "peak: build", f"peak: clip ({n})"],
              notes=[("operator: the deformer's weights and the rigid parts' rows and weights / the dense matrix; "
                     "kept/peak: tracemalloc relative to before the call, the build from a fresh Face (its caches "
                     "included); the dense player comes on top of the rig it was made from"),
                     f"clip output: {fmt_bytes(n * mesh.n_vertices * 3 * 8)}"])
        clock.lap("memory")

        # ---------------------------------------------------------------- text to animation
        rows = [["phones -> visemes -> FAP stream (best of 5)", fmt_time(t_stream), fmt_ratio(speech / t_stream)],
                ["espeak-ng word by word + alignment of each word (once)", fmt_time(t_tts),
                 fmt_ratio(speech / t_tts)]]
        if args.data is not None:
            clip_wav = min(Path(args.data).glob("clip-*.wav"))
            text = clip_wav.with_suffix(".txt").read_text()
            align(clip_wav, text)  # loads the model once
            t_align, timed = best_fresh(lambda: align(clip_wav, text), repeat=2)
            rows.append([f"forced alignment of {clip_wav.name} ({timed[-1].end:.1f} s of speech, best of 2)",
                         fmt_time(t_align), fmt_ratio(timed[-1].end / t_align)])
        table(rows, ["text to animation", "time", "x real time"],
              notes=[f"real time: {speech:.2f} s of synthesized speech (and the clip's own length for alignment)"])
        clock.lap("speech")
        print(clock.line())


if __name__ == "__main__":
    main()
