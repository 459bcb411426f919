"""``faceanim live``: the perform path with a clock. Capture, track, synthesise, send.

The source captures in its own thread (:mod:`faceanim.live.sources`) and keeps only the newest
frame; this loop takes it, tracks it (MediaPipe's Face Landmarker in video mode), steps the live
tracker (:class:`~faceanim.live.performer.LiveSolver` by default: the ARKit solve; or Chai et al.'s
synthesis, :class:`~faceanim.live.performer.LivePerformer`) and hands the sample to every sink
(:mod:`faceanim.live.sinks`). Each frame carries its capture time; the latency reported is from
capture to the last sink's send. Ctrl-C (or the source's end) stops the run; every sink is closed,
so file sinks are complete.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from faceanim.live.performer import LiveFace, LiveSolver
from faceanim.live.sinks import Sink
from faceanim.live.sources import Source

QUIET_FRAMES = 30  # the first frames are tracked with the native stderr silenced (MediaPipe's start-up log)


@dataclass
class LiveReport:
    """What a run did: frames ``captured`` by the source, ``processed`` and ``dropped`` (captured
    but replaced before the compute took them), ``tracked`` (a face found), ``seconds`` of the run,
    ``latency`` (s, per processed frame: capture to sent), ``written`` files, ``interrupted``, the
    source's ``error`` (a camera or a microphone gone) and the ``samples`` (kept when asked). With
    a microphone, ``sound``: (20 ms chunks fed to the lip sync, chunks dropped because it fell
    behind, blocks before which the device lost sound)."""

    captured: int = 0
    processed: int = 0
    dropped: int = 0
    tracked: int = 0
    seconds: float = 0.0
    latency: list = field(default_factory=list)
    written: list = field(default_factory=list)
    interrupted: bool = False
    error: str | None = None
    samples: list = field(default_factory=list)
    images: bool = True
    sound: tuple | None = None

    @property
    def fps(self) -> float:
        return self.processed / self.seconds if self.seconds > 0 else 0.0

    def summary(self) -> str:
        lat = np.array(self.latency) * 1000
        p50, p95 = (np.percentile(lat, [50, 95]) if len(lat) else (float("nan"),) * 2)
        share = 100.0 * self.dropped / max(self.captured, 1)
        found = f"face found in {self.tracked}, " if self.images else ""
        heard = "" if self.sound is None else (f"; sound {self.sound[0]} chunks of 20 ms, {self.sound[1]} dropped, "
                                               f"{self.sound[2]} overflows")
        return (f"{self.processed} frames in {self.seconds:.1f} s ({self.fps:.1f} fps), {found}"
                f"{self.dropped} dropped ({share:.1f}%), latency p50 {p50:.0f} ms, p95 {p95:.0f} ms{heard}")


def run_live(source: Source, sinks: list[Sink], performer: LiveFace | None = None,
             keep_samples: bool = False, tracker=None, notice=None, sound=None, mouth: str = "both") -> LiveReport:
    """Run until the source ends or Ctrl-C; see the module docstring. ``notice(text)`` is told once
    when the face has been lost for longer than the performer holds it. ``sound``: an
    :class:`~faceanim.live.audio.SoundFeed` (a file or a microphone) beside a video source, its
    mouth merged into each frame's by ``mouth`` (:func:`~faceanim.live.audio.merge_mouth`); if it
    fails (a microphone gone), the run stops with its error. A source of sound alone (frames
    without images) drives the whole face: the mouth, the voice's brows, blinks, looks and head,
    over an idle sway."""
    from faceanim.drivers.video.tracking import FaceTracker
    from faceanim.io.files import native_stderr_quiet
    from faceanim.live.audio import IdleFace, merge_mouth, sound_sample
    from faceanim.perform import LOST_HOLD

    if source.images:
        performer = performer or LiveSolver()
    report = LiveReport(images=source.images)
    idle = IdleFace()
    lost_since, said = None, False
    if tracker is None and source.images:
        with native_stderr_quiet():
            tracker = FaceTracker()
            tracker(np.zeros((64, 64, 3), dtype=np.uint8))  # MediaPipe's graph starts on its first frame

    def track(image, at):
        if report.processed >= QUIET_FRAMES:
            return tracker.detect(image, at)
        with native_stderr_quiet():  # MediaPipe logs as its face model starts on the first faces
            return tracker.detect(image, at)

    started = time.monotonic()
    try:
        source.start()
        if sound is not None:
            sound.start()
        while True:
            frame = source.slot.get()
            if frame is None:
                break
            if sound is not None and sound.error is not None:
                report.error = _said(sound.error, "the sound")
                break
            if frame.image is None:  # a tick of a sound alone
                sample = sound_sample(frame.mouth, frame.head, frame.time, idle)
            else:
                found = track(frame.image, frame.time)
                if isinstance(performer, LiveSolver):  # the solve and the scores take MediaPipe's scores
                    sample = performer.step(None if found is None else found.landmarks, frame.time,
                                            None if found is None else found.blendshapes)
                else:
                    sample = performer.step(None if found is None else found.landmarks, frame.time)
                if sound is not None:
                    merge_mouth(sample, sound.curves(), mouth)
            sample.capture = time.time() - (time.monotonic() - frame.capture)  # as the epoch, for a page
            for sink in sinks:
                sink.send(sample)
            report.latency.append(time.monotonic() - frame.capture)
            report.processed += 1
            report.tracked += int(sample.tracked)
            lost_since = None if sample.tracked or frame.image is None else (
                frame.time if lost_since is None else lost_since)
            if lost_since is not None and frame.time - lost_since > LOST_HOLD and not said and notice:
                notice(f"no face in view for {LOST_HOLD:g} s: the avatar eases to rest until the face is back")
                said = True
            if keep_samples:
                report.samples.append(sample)
    except KeyboardInterrupt:
        from faceanim.errors import STOPS

        STOPS.clear()  # a stop ends a live run as it should: its file sinks are still written
        report.interrupted = True
    finally:
        source.stop()
        if sound is not None:
            sound.stop()
        if tracker is not None:
            tracker.close()
        report.seconds = time.monotonic() - started
        report.captured, report.dropped = source.slot.captured, source.slot.dropped
        if source.slot.error is not None:
            report.error = str(source.slot.error)
        feed = sound if sound is not None else getattr(source, "feed", None)
        if hasattr(feed, "overflows"):  # a microphone
            report.sound = (feed.chunks, feed.dropped, feed.overflows)
        for sink in sinks:
            written = sink.close()
            if written is not None:
                report.written.append(written)
    return report


def _said(error: Exception, what: str) -> str:
    """An error as the run's report says it: a FaceAnimError's own message, else what stopped."""
    from faceanim.errors import FaceAnimError

    return str(error) if isinstance(error, FaceAnimError) else f"{what} stopped ({type(error).__name__})"
