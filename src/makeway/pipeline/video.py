"""Framework B on a video (SPEC §2): detector → SORT → per-track classifier → smoother.

:class:`VisionPipeline` turns one frame into a :class:`~makeway.messages.PerceptionFrame`;
:func:`run_video` drives it over a file and writes, into an output folder:

* ``annotated.mp4`` — H.264 with boxes, track ids, EV state colours and an FPS panel;
* ``tracks.jsonl`` — one JSON object per processed frame (index, time, tracks with box, id, score,
  class, EV state);
* ``summary.json`` — frames, wall time, real-time factor and per-stage milliseconds per frame.

Decoding and encoding run on their own threads (both release the GIL in FFmpeg), so they overlap
with detection on the main thread. Outputs appear only when the run completes: an error midway (a
video that ends before its container's frame count included) leaves nothing half-written, and no
output folder that the run created.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from makeway.atomic import atomic_path, check_writable, removed_on_error, write_text_atomic
from makeway.messages import EVTrackState, PerceptionFrame
from makeway.perceive.vision.detectors import DETECTORS, Detector
from makeway.perceive.vision.ev_classifier import TrackClassifier
from makeway.progress import progress_bar
from makeway.sense.video import VideoReader
from makeway.track.smoother import TrackSmoother
from makeway.track.sort import Sort
from makeway.viz.annotate import draw_frame
from makeway.viz.video_writer import H264Writer

STAGES = ("read", "detect", "track", "classify", "annotate", "encode")


class VisionPipeline:
    """One frame in, one :class:`PerceptionFrame` out (Framework B, SPEC §2).

    Args:
        detector: a registered vehicle detector (see :func:`DETECTORS`).
        tracker: the SORT tracker (default ``Sort()`` with the paper's 1 / 3 / 0.3).
        classifier: per-track EV classifier; without one, tracks carry no EV state.
        smoother: the per-track output smoother used with the classifier (default ``TrackSmoother()``).
    """

    def __init__(
        self,
        detector: Detector,
        tracker: Sort | None = None,
        classifier: TrackClassifier | None = None,
        smoother: TrackSmoother | None = None,
    ) -> None:
        self.detector = detector
        self.tracker = tracker if tracker is not None else Sort()
        self.classifier = classifier
        self.smoother = smoother if smoother is not None else TrackSmoother()
        self.seconds: dict[str, float] = dict.fromkeys(STAGES, 0.0)

    def process(self, image_bgr: np.ndarray, frame_index: int, time_s: float) -> PerceptionFrame:
        """Detect, track, classify and smooth one frame."""
        t0 = time.perf_counter()
        arrays = self.detector.detect_arrays(image_bgr)
        self.seconds["detect"] += time.perf_counter() - t0
        return self.process_detections(image_bgr, frame_index, time_s, arrays)

    def process_detections(
        self,
        image_bgr: np.ndarray,
        frame_index: int,
        time_s: float,
        arrays: tuple[np.ndarray, np.ndarray, np.ndarray],
    ) -> PerceptionFrame:
        """Track, classify and smooth one frame whose detections were computed elsewhere.

        ``arrays`` is ``(boxes, scores, class_ids)`` as :meth:`Detector.detect_arrays` returns them;
        frames must arrive in order, once each.
        """
        t1 = time.perf_counter()
        boxes, scores, class_ids = arrays
        detections = Detector.to_detections((boxes, scores, class_ids))
        tracks = self.tracker.update(detections)
        t2 = time.perf_counter()
        states: tuple[EVTrackState, ...] = ()
        if self.classifier is not None:
            observations = self.classifier.classify(image_bgr, tracks, frame_index, time_s)
            states = tuple(self.smoother.update(observations, alive_track_ids=self.tracker.live_ids))
            live = {t.track_id for t in tracks}
            states = tuple(s for s in states if s.track_id in live)
        t3 = time.perf_counter()
        self.seconds["track"] += t2 - t1
        self.seconds["classify"] += t3 - t2
        return PerceptionFrame(frame_index, time_s, tuple(tracks), states)


@dataclass
class VideoRunSummary:
    """What :func:`run_video` did, for the CLI, the benchmark and ``summary.json``."""

    video: str
    out_dir: str | None
    detector: str
    detector_workers: int
    width: int
    height: int
    fps: float
    stride: int
    frames: int
    video_seconds: float
    wall_seconds: float
    realtime_factor: float
    ms_per_frame: dict[str, float]
    max_tracks: int
    unique_tracks: int
    active_ev_tracks: list[int] = field(default_factory=list)
    outputs: dict[str, str] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


class _Prefetch:
    """Runs an iterator on a background thread, a few items ahead of the consumer."""

    _END = object()

    def __init__(self, source: Iterator[Any], depth: int = 4) -> None:
        self._q: queue.Queue[Any] = queue.Queue(maxsize=depth)
        self._error: BaseException | None = None
        self._stop = threading.Event()
        self.seconds = 0.0
        self._thread = threading.Thread(target=self._run, args=(source,), daemon=True)
        self._thread.start()

    def _run(self, source: Iterator[Any]) -> None:
        try:
            while not self._stop.is_set():
                t0 = time.perf_counter()
                try:
                    item = next(source)
                except StopIteration:
                    break
                self.seconds += time.perf_counter() - t0
                self._q.put(item)
        except BaseException as exc:  # handed to the consumer
            self._error = exc
        finally:
            self._q.put(self._END)

    def __iter__(self) -> Iterator[Any]:
        while True:
            item = self._q.get()
            if item is self._END:
                self._thread.join()
                if self._error is not None:
                    raise self._error
                return
            yield item

    def close(self) -> None:
        self._stop.set()
        while self._thread.is_alive():
            try:
                self._q.get_nowait()
            except queue.Empty:
                time.sleep(0.001)
        self._thread.join()


def _detect_in_order(
    frames: Iterator[tuple[int, float, np.ndarray]], detectors: Sequence[Detector], seconds: list[float]
) -> Iterator[tuple[int, float, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """Detect on several frames at once, one detector per worker, yielding results in frame order.

    Detection is stateless, so consecutive frames can be detected concurrently (ONNX Runtime
    releases the GIL); tracking then consumes them strictly in order. On a 2-core machine two
    single-threaded sessions give more frames per second than one session with two threads.
    ``seconds[0]`` accumulates the detectors' busy time.
    """
    if len(detectors) == 1:
        (only,) = detectors
        for index, t_s, image in frames:
            t0 = time.perf_counter()
            arrays = only.detect_arrays(image)
            seconds[0] += time.perf_counter() - t0
            yield index, t_s, image, arrays
        return
    free: queue.Queue[Detector] = queue.Queue()
    for d in detectors:
        free.put(d)

    def job(image: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        det = free.get()
        t0 = time.perf_counter()
        try:
            return det.detect_arrays(image)
        finally:
            seconds[0] += time.perf_counter() - t0
            free.put(det)

    pending: deque[tuple[int, float, np.ndarray, Future[tuple[np.ndarray, np.ndarray, np.ndarray]]]] = deque()
    with ThreadPoolExecutor(max_workers=len(detectors), thread_name_prefix="detect") as pool:
        try:
            for index, t_s, image in frames:
                pending.append((index, t_s, image, pool.submit(job, image)))
                if len(pending) > len(detectors):
                    i, t, img, fut = pending.popleft()
                    yield i, t, img, fut.result()
            while pending:
                i, t, img, fut = pending.popleft()
                yield i, t, img, fut.result()
        finally:
            for *_, fut in pending:
                fut.cancel()


class _BackgroundWriter:
    """Feeds frames to an :class:`H264Writer` from a background thread."""

    def __init__(self, writer: H264Writer, depth: int = 8) -> None:
        self.writer = writer
        self.seconds = 0.0
        self._q: queue.Queue[np.ndarray | None] = queue.Queue(maxsize=depth)
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            frame = self._q.get()
            if frame is None:
                return
            if self._error is not None:
                continue
            t0 = time.perf_counter()
            try:
                self.writer.write(frame)
            except BaseException as exc:
                self._error = exc
            self.seconds += time.perf_counter() - t0

    def write(self, frame: np.ndarray) -> None:
        if self._error is not None:
            raise self._error
        self._q.put(frame)

    def abandon(self) -> None:
        """Stop after an error elsewhere; frames still queued are dropped."""
        self._error = self._error or RuntimeError("abandoned")
        self._q.put(None)
        self._thread.join()

    def finish(self) -> None:
        self._q.put(None)
        self._thread.join()
        if self._error is not None:
            raise self._error


def run_video(
    video: str | Path,
    out_dir: str | Path | None,
    *,
    detector: str | Detector = "yolox_nano",
    model: str | Path | None = None,
    score_threshold: float = 0.3,
    stride: int = 1,
    max_frames: int | None = None,
    write_video: bool = True,
    classifier: TrackClassifier | None = None,
    tracker: Sort | None = None,
    smoother: TrackSmoother | None = None,
    on_frame: Callable[[PerceptionFrame], None] | None = None,
    detector_workers: int | None = None,
    progress: bool = True,
) -> VideoRunSummary:
    """Run Framework B over ``video``; write the annotated video, JSONL and summary to ``out_dir``.

    Args:
        video: any file OpenCV/FFmpeg reads.
        out_dir: output folder (created); ``None`` runs without writing anything (benchmarks).
        detector: registered detector name or a ready :class:`Detector`. A named detector is built
            with class-agnostic NMS: Framework B needs one box per vehicle, and class-aware NMS
            sometimes keeps one vehicle twice (as ``car`` and ``truck``), which would split its track.
        model: ONNX file for the detector (default: searched, see ``MAKEWAY_MODELS``).
        score_threshold: detector score threshold.
        stride: process every ``stride``-th frame (the tracker then runs at ``fps / stride``).
        max_frames: stop after this many processed frames.
        write_video: also write ``annotated.mp4``.
        classifier: optional per-track EV classifier (SPEC §1); enables smoothing and EV states.
        tracker, smoother: override the defaults (``Sort()``, ``TrackSmoother()``).
        on_frame: called with each :class:`PerceptionFrame` (e.g. for live display).
        detector_workers: frames detected concurrently, each by its own single-threaded ONNX
            Runtime session (default: the number of CPU cores, at most 4). Ignored when a ready
            ``Detector`` instance is passed (it then runs alone, with its own thread setting).
        progress: show a rich progress bar.

    Raises:
        InputError: the video or the model is missing or unreadable, or ``out_dir`` cannot be
            written (before anything is written); the video ends well before its container's frame
            count (truncated or damaged: nothing is left behind, see
            :meth:`~makeway.sense.video.VideoReader.check_complete`).
    """
    if out_dir is not None:
        check_writable(out_dir, folder=True)
    reader = VideoReader(video, stride=stride, max_frames=max_frames)
    info = reader.info
    if isinstance(detector, Detector):
        detectors = [detector]
    else:
        workers = detector_workers if detector_workers is not None else min(os.cpu_count() or 1, 4)
        if workers < 1:
            raise ValueError(f"detector_workers must be >= 1, got {workers}")
        threads = None if workers == 1 else 1
        detectors = [
            DETECTORS[detector](
                model, score_threshold=score_threshold, class_agnostic=True, num_threads=threads
            )
            for _ in range(workers)
        ]
    det = detectors[0]
    pipe = VisionPipeline(det, tracker=tracker, classifier=classifier, smoother=smoother)
    detect_seconds = [0.0]
    total = info.frame_count if info.frame_count > 0 else None
    if total is not None:
        total = -(-total // stride)
        if max_frames is not None:
            total = min(total, max_frames)

    out = Path(out_dir) if out_dir is not None else None
    outputs: dict[str, str] = {}
    n_frames = 0
    max_tracks = 0
    seen_ids: set[int] = set()
    active_ids: set[int] = set()
    annotate_s = 0.0
    recent: deque[float] = deque(maxlen=26)  # completion times of the last frames, for the FPS overlay

    guard = removed_on_error(out) if out is not None else contextlib.nullcontext()
    with guard, progress_bar(f"detect {Path(video).name}", total, enabled=progress) as advance:
        jsonl_ctx = atomic_path(out / "tracks.jsonl") if out is not None else contextlib.nullcontext()
        with jsonl_ctx as jsonl_tmp:
            jsonl = jsonl_tmp.open("w", encoding="utf-8") if jsonl_tmp is not None else None
            writer: H264Writer | None = None
            bg: _BackgroundWriter | None = None
            if out is not None and write_video:
                writer = H264Writer(out / "annotated.mp4", info.fps / stride, info.width, info.height)
                bg = _BackgroundWriter(writer)
            frames = _Prefetch(iter(reader))
            wall0 = time.perf_counter()
            try:
                for index, t_s, image, arrays in _detect_in_order(iter(frames), detectors, detect_seconds):
                    frame = pipe.process_detections(image, index, t_s, arrays)
                    n_frames += 1
                    max_tracks = max(max_tracks, len(frame.tracks))
                    seen_ids.update(t.track_id for t in frame.tracks)
                    active_ids.update(s.track_id for s in frame.ev_states if s.active)
                    if jsonl is not None:
                        jsonl.write(json.dumps(frame.to_json(), separators=(",", ":")) + "\n")
                    if on_frame is not None:
                        on_frame(frame)
                    now = time.perf_counter()
                    recent.append(now)
                    span = recent[-1] - recent[0]
                    fps_now = (len(recent) - 1) / span if span > 0 else 0.0
                    if bg is not None:
                        ta = time.perf_counter()
                        annotated = draw_frame(
                            image, frame, fps_text=f"{fps_now:5.1f} fps ({det.name})", copy=False
                        )
                        annotate_s += time.perf_counter() - ta
                        bg.write(annotated)
                    advance(1)
                reader.check_complete()
                advance.finish()
                wall = time.perf_counter() - wall0
                if bg is not None:
                    bg.finish()
                    wall = time.perf_counter() - wall0
                if writer is not None:
                    writer.close()
                    outputs["video"] = str(writer.path)
            except BaseException:
                frames.close()
                if bg is not None:
                    bg.abandon()
                if writer is not None:
                    writer.abort()
                if jsonl is not None:
                    jsonl.close()
                raise
            finally:
                reader.close()
            if jsonl is not None:
                jsonl.close()
                outputs["tracks"] = str(out / "tracks.jsonl") if out is not None else ""

    seconds = dict(pipe.seconds)
    seconds["read"] = frames.seconds
    seconds["detect"] = detect_seconds[0]
    seconds["annotate"] = annotate_s
    seconds["encode"] = bg.seconds if bg is not None else 0.0
    video_seconds = n_frames * stride / info.fps
    summary = VideoRunSummary(
        video=str(video),
        out_dir=str(out) if out is not None else None,
        detector=det.name,
        detector_workers=len(detectors),
        width=info.width,
        height=info.height,
        fps=info.fps,
        stride=stride,
        frames=n_frames,
        video_seconds=round(video_seconds, 3),
        wall_seconds=round(wall, 3),
        realtime_factor=round(video_seconds / wall, 3) if wall > 0 else float("inf"),
        ms_per_frame={k: round(1000.0 * v / max(n_frames, 1), 3) for k, v in seconds.items()},
        max_tracks=max_tracks,
        unique_tracks=len(seen_ids),
        active_ev_tracks=sorted(active_ids),
        outputs=outputs,
    )
    if out is not None:
        summary.outputs["summary"] = str(out / "summary.json")
        write_text_atomic(out / "summary.json", json.dumps(summary.to_json(), indent=2) + "\n")
    return summary
