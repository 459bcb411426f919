"""MPEG-4 playback speed on the 30k-vertex default face.

    .venv/bin/python benchmarks/bench_mpeg4.py [../shared/data/speech-librivox]

- FAP stream to mesh, one frame at a time after binding (the real-time case) and in batches,
  against the baseline of rebuilding the FaceDefTable for a frame;
- text to animation: timed phones -> co-articulated visemes -> FAP stream, against real time
  (synthesis and alignment timed separately).
"""

import sys
import time
from pathlib import Path

import numpy as np

from faceanim.drivers.mpeg4 import FapStream
from faceanim.drivers.speech import align, say_timed
from faceanim.drivers.speech.visemes import speech_stream
from faceanim.face.default import default_face, default_landmarks
from faceanim.face.face import Face, landmarks_478
from faceanim.rig.mpeg4 import FapRig


def main():
    face = default_face()
    lm = landmarks_478(face, default_landmarks(face))
    t = time.perf_counter()
    rig = FapRig.build(Face(face, lm))
    t_build = time.perf_counter() - t
    text = "Hello, how are you? I am a talking face built from the papers."
    wav = Path("/tmp") / "faceanim-bench-speech.wav"
    t = time.perf_counter()
    phones = say_timed(text, wav)
    t_tts = time.perf_counter() - t
    t = time.perf_counter()
    for _ in range(10):
        stream = speech_stream(rig.lip_gap, phones, 25.0)
    t_stream = (time.perf_counter() - t) / 10
    speech = phones[-1].end
    singles = [FapStream(stream.values[k:k + 1], stream.mask[k:k + 1], 25.0) for k in range(stream.n_frames)]
    for s in singles[:5]:
        rig.evaluate(s)
    best = np.inf
    for _ in range(3):
        t = time.perf_counter()
        for s in singles:
            rig.evaluate(s)
        best = min(best, (time.perf_counter() - t) / len(singles))
    t = time.perf_counter()
    rig.evaluate(stream)
    t_batch = (time.perf_counter() - t) / stream.n_frames
    print(f"default face: {face.n_vertices} vertices; '{text}' = {speech:.2f} s, {stream.n_frames} frames\n")
    print("| step | time |")
    print("|---|---|")
    print(f"| build the FaceDefTable (baseline per frame without binding) | {t_build * 1000:.0f} ms |")
    print(f"| FAP stream -> mesh, one frame at a time | {best * 1000:.2f} ms per frame ({t_build / best:.0f}x the baseline) |")
    print(f"| FAP stream -> mesh, all frames at once | {t_batch * 1000:.2f} ms per frame |")
    print(f"| phones -> visemes -> FAP stream | {t_stream * 1000:.1f} ms ({speech / t_stream:.0f}x real time) |")
    print(f"| synthesis word by word with espeak-ng + alignment of each word | {t_tts * 1000:.0f} ms |")
    if len(sys.argv) > 1:
        clips = sorted(Path(sys.argv[1]).glob("clip-*.wav"))
        total = sum(align(c, c.with_suffix(".txt").read_text())[-1].end for c in clips[:1])
        t = time.perf_counter()
        align(clips[0], clips[0].with_suffix(".txt").read_text())
        print(f"| alignment of {clips[0].name} ({total:.1f} s of speech) | {(time.perf_counter() - t) * 1000:.0f} ms |")


if __name__ == "__main__":
    main()
