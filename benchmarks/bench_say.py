"""faceanim say, stage by stage: the ARKit lip sync against the MPEG-4 viseme path it replaced.

Stages of ``faceanim say TEXT -o out.mp4`` on the default face, each timed for both paths in the
same run (cold: a fresh Face each time, as a new command starts; warm: the rig kept):

- speech and timing: espeak-ng's library in one utterance (a fresh process per text) against the
  word-by-word path (one espeak-ng run and one pocketsphinx alignment per word);
- the rig: the face's ARKit shapes (``arkit_shapes``) against the FAP rig (``FapRig.build``);
- the curves: phones -> ARKit curves (``lipsync_curves``) against phones -> FAP stream -> the FAP
  rig's control curves;
- one frame's vertices (the rig evaluated), per frame of the clip.

Usage (from /work/main): ``.venv/bin/python benchmarks/bench_say.py [--blas-threads N]`` (about a
minute; needs espeak-ng)
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from _timing import arguments, best, best_fresh, blas_threads, fmt_ratio, fmt_time, header, table

TEXT = "Peter Piper picked a peck of pickled peppers"
FPS = 25.0


def main() -> None:
    args = arguments(__doc__)
    blas_threads(args.blas_threads)
    header("faceanim say: ARKit lip sync against MPEG-4 visemes")
    from faceanim.drivers.speech import say_timed
    from faceanim.drivers.speech.lipsync import lipsync_curves
    from faceanim.drivers.speech.phonemes import say_word_by_word
    from faceanim.drivers.speech.visemes import speech_stream
    from faceanim.face.face import Face
    from faceanim.rig.arkit import arkit_shapes
    from faceanim.rig.mpeg4 import FapRig
    from faceanim.rig.rig import Rig

    with tempfile.TemporaryDirectory() as tmp:
        wav = Path(tmp) / "s.wav"
        t_lib, phones = best_fresh(lambda: say_timed(TEXT, wav), repeat=3)
        t_words, _ = best_fresh(lambda: say_word_by_word(TEXT, wav), repeat=3)
    t_ark, made = best_fresh(lambda: arkit_shapes(Face.default())[0], repeat=2)
    t_fap, fap = best_fresh(lambda: FapRig.build(Face.default()), repeat=2)
    face = Face.default()
    rig = Rig.from_blendshapes(face.mesh, made)
    names = list(rig.controls)
    c_ark = lipsync_curves(phones, names, FPS)
    t_cur_ark = best(lambda: lipsync_curves(phones, names, FPS))
    t_cur_fap = best(lambda: fap.stream_curves(speech_stream(fap.lip_gap, phones, FPS)))
    c_fap = fap.stream_curves(speech_stream(fap.lip_gap, phones, FPS))
    t_eval_ark = best(lambda: rig.evaluate(c_ark)) / len(c_ark)
    t_eval_fap = best(lambda: fap.evaluate(c_fap)) / len(c_fap)
    rows = [
        ("speech + phone timing (cold)", "espeak-ng library, one utterance", "one run + alignment per word",
         fmt_time(t_lib), fmt_time(t_words), fmt_ratio(t_words / t_lib)),
        ("rig of the default face (cold)", "ARKit shapes (52)", "FAP rig", fmt_time(t_ark), fmt_time(t_fap),
         fmt_ratio(t_fap / t_ark)),
        (f"curves ({len(phones)} phones, {len(c_ark)} frames, warm)", "lipsync_curves", "FAP stream + curves",
         fmt_time(t_cur_ark), fmt_time(t_cur_fap), fmt_ratio(t_cur_fap / t_cur_ark)),
        ("vertices per frame (warm)", "ARKit rig", "FAP rig (rigid jaw, eyes)", fmt_time(t_eval_ark),
         fmt_time(t_eval_fap), fmt_ratio(t_eval_fap / t_eval_ark)),
    ]
    table(rows, ("stage", "now", "before", "now", "before", "before / now"),
          title=f'"{TEXT}" on the default face ({face.mesh.n_vertices} vertices), {FPS:g} fps',
          notes=("cold: best of 2-3 fresh runs; warm: best of 5 after a warm-up; the render and the MP4 "
                 "encoding are the same for both paths",))


if __name__ == "__main__":
    main()
