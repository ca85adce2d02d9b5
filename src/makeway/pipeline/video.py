"""Framework B on a video (SPEC §2): detector → SORT → per-track classifier → smoother; and
Framework A (seed 001): a one-stage EV detector → SORT → smoother fed by the detector's per-box
P(EV) (:class:`~makeway.perceive.vision.ev_detector.EVDetector`, ``run_video(ev_detectors=…)``).

:class:`VisionPipeline` turns one frame into a :class:`~makeway.messages.PerceptionFrame`;
:func:`run_video` drives it over a file and writes, into an output folder:

* ``annotated.mp4`` — H.264 with boxes, track ids, EV state colours and an FPS panel;
* ``tracks.jsonl`` — one JSON object per processed frame (index, time, tracks with box, id, score,
  class, EV state; under the lights rules also ``lights``: the red, blue and amber lights seen in
  the frame with their track id, box, colour, score and flash cue,
  :meth:`makeway.track.lights.LightTrack.to_dict`);
* ``summary.json`` — frames, wall time, real-time factor, per-stage milliseconds per frame (with
  ``lights``, the light detector's, under the lights rules), the active-EV rule and the tracks it
  turned active.

The input may also be a robotics log (an MCAP file or a ROS 2 bag folder) with a camera topic
(:func:`makeway.sense.logs.open_frame_source`); with ``mcap`` the run is also written as a
Foxglove MCAP file (:class:`makeway.viz.foxglove.DetectRecorder`).

The light detector runs beside the vehicle detector on the same worker threads; the light tracker
(and its flash cue) with SORT on the main thread.

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
from typing import Any, Protocol

import cv2
import numpy as np

from makeway.atomic import atomic_path, check_writable, removed_on_error, write_text_atomic
from makeway.messages import EVObservation, EVTrackState, LightDetection, PerceptionFrame
from makeway.perceive.health import CameraHealth
from makeway.perceive.vision.detectors import DETECTORS, Detector
from makeway.perceive.vision.ev_classifier import TrackClassifier
from makeway.perceive.vision.lights import DEFAULT_LIGHT_DETECTOR, LightDetector, VehicleContextLightDetector
from makeway.progress import progress_bar
from makeway.queues import LiveSource, paced
from makeway.sense.logs import open_frame_source
from makeway.track.lights import (
    ACTIVE_RULES,
    SATURATED,
    LightTrack,
    LightTracker,
    active_probability,
    build_light_detector,
    vehicle_light_evidence,
)
from makeway.track.one_stage import track_one_stage
from makeway.track.smoother import TrackSmoother
from makeway.track.sort import Sort
from makeway.viz.annotate import draw_frame
from makeway.viz.foxglove import DetectRecorder
from makeway.viz.video_writer import H264Writer

STAGES = ("read", "detect", "track", "classify", "annotate", "encode")


class FrameDetector(Protocol):
    """What the pipeline needs of a detector: ``name`` and ``detect_arrays(image_bgr)`` returning
    ``(boxes, scores, class_ids)`` — or, for a one-stage EV detector (Framework A), also a 4th array
    ``p_ev`` (:meth:`~makeway.perceive.vision.ev_detector.EVDetector.detect_arrays`)."""

    @property
    def name(self) -> str: ...

    def detect_arrays(self, image_bgr: np.ndarray) -> tuple[np.ndarray, ...]: ...


#: What ``lights`` means in :func:`run_video`: the light detector's registry name and colour set.
DEFAULT_LIGHTS = (DEFAULT_LIGHT_DETECTOR, "eu")


class VisionPipeline:
    """One frame in, one :class:`PerceptionFrame` out (Framework B, SPEC §2).

    Args:
        detector: a registered vehicle detector (see :func:`DETECTORS`).
        tracker: the SORT tracker (default ``Sort()`` with the paper's 1 / 3 / 0.3).
        classifier: per-track EV classifier (the ``crop`` and ``lights+crop`` rules use it).
        smoother: the per-track output smoother (default ``TrackSmoother()``).
        rule: how a vehicle track becomes an active EV, one of
            :data:`~makeway.track.lights.ACTIVE_RULES`: ``crop`` (the crop classifier alone),
            ``lights`` (a flashing red, blue or amber light in the upper part of the box or just
            above it) or ``lights+crop`` (such a light, and the classifier says EV); see
            :func:`~makeway.track.lights.active_probability` and
            :func:`~makeway.track.lights.vehicle_light_evidence`. The per-frame votes go through
            the smoother. Without a classifier, ``crop`` gives tracks no EV state.
        light_tracker: the light tracker of the lights rules (default ``LightTracker()``); its
            detections come with each frame (:meth:`process_detections`).
        camera_health: check the camera's health (:class:`~makeway.perceive.health.CameraHealth`;
            ``False`` checks nothing). While the camera
            is frozen or black, frames are not tracked: each reports the last trusted frame's tracks
            and states with the health, and the tracks resume when the camera does.
        frame_step: the index step between consecutive frames (the reader's stride). A larger
            step means frames were lost on the way; the tracker then coasts over them
            (:meth:`~makeway.track.sort.Sort.coast`) so that a gap does not end its tracks.
    """

    def __init__(
        self,
        detector: FrameDetector,
        tracker: Sort | None = None,
        classifier: TrackClassifier | None = None,
        smoother: TrackSmoother | None = None,
        *,
        rule: str = "crop",
        light_tracker: LightTracker | None = None,
        camera_health: bool = True,
        frame_step: int = 1,
    ) -> None:
        if frame_step < 1:
            raise ValueError(f"frame_step must be >= 1, got {frame_step}")
        self.camera_health = CameraHealth() if camera_health else None
        self.frame_step = int(frame_step)
        self._last_index: int | None = None
        self._last_frame: PerceptionFrame | None = None
        if rule not in ACTIVE_RULES:
            raise ValueError(f"unknown active rule {rule!r}; choose from: {', '.join(ACTIVE_RULES)}")
        self.detector = detector
        self.tracker = tracker if tracker is not None else Sort()
        self.classifier = classifier
        self.smoother = smoother if smoother is not None else TrackSmoother()
        self.rule = rule
        self.light_tracker = (
            (light_tracker if light_tracker is not None else LightTracker()) if rule != "crop" else None
        )
        #: The light tracks after the last frame (empty under the ``crop`` rule).
        self.light_tracks: list[LightTrack] = []
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
        arrays: tuple[np.ndarray, ...],
        lights: Sequence[LightDetection] = (),
    ) -> PerceptionFrame:
        """Track, classify and smooth one frame whose detections were computed elsewhere.

        ``arrays`` is ``(boxes, scores, class_ids)`` as :meth:`Detector.detect_arrays` returns them,
        or with a 4th array ``p_ev`` from a one-stage EV detector (Framework A): then the tracks'
        class-flip-free P(EV) comes from their detections (:func:`track_one_stage`) in place of the
        crop classifier's, under the same rules and smoother; ``lights`` the light detector's boxes
        in this frame (used by the lights rules); frames must arrive in order, once each.
        """
        t1 = time.perf_counter()
        health = None
        if self.camera_health is not None:
            health = self.camera_health.update(image_bgr, time_s)
            if not health.ok:  # nothing to learn from this image: hold the tracks, say why
                last = self._last_frame
                self.seconds["track"] += time.perf_counter() - t1
                return PerceptionFrame(
                    frame_index,
                    time_s,
                    last.tracks if last is not None else (),
                    last.ev_states if last is not None else (),
                    health,
                )
        if self._last_index is not None and frame_index - self._last_index > self.frame_step:
            self.tracker.coast((frame_index - self._last_index) // self.frame_step - 1)
        self._last_index = frame_index
        one_stage: dict[int, float] | None = None
        if len(arrays) > 3:
            tracks, one_stage = track_one_stage(self.tracker, arrays)
        else:
            tracks = self.tracker.update(Detector.to_detections((arrays[0], arrays[1], arrays[2])))
        evidence: dict[int, tuple[bool, bool]] = {}
        if self.light_tracker is not None:
            # white lights never make a vehicle active (headlights, street lamps): not tracked here
            kept = [d for d in lights if d.colour in SATURATED]
            self.light_tracks = self.light_tracker.update(kept, time_s, image_bgr)
            evidence = vehicle_light_evidence(tracks, self.light_tracks)
        t2 = time.perf_counter()
        states: tuple[EVTrackState, ...] = ()
        uses_crop = self.rule != "lights" and (self.classifier is not None or one_stage is not None)
        if uses_crop or self.rule != "crop":
            crop: dict[int, float | None] = {}
            if uses_crop and one_stage is not None:
                crop.update(one_stage)
            elif uses_crop:
                assert self.classifier is not None
                for obs in self.classifier.classify(image_bgr, tracks, frame_index, time_s):
                    crop[obs.track_id] = obs.probability
            observations = [
                EVObservation(
                    t.track_id,
                    frame_index,
                    time_s,
                    active_probability(
                        self.rule, *evidence.get(t.track_id, (False, False)), crop.get(t.track_id)
                    ),
                )
                for t in tracks
            ]
            states = tuple(self.smoother.update(observations, alive_track_ids=self.tracker.live_ids))
            live = {t.track_id for t in tracks}
            states = tuple(s for s in states if s.track_id in live)
        t3 = time.perf_counter()
        self.seconds["track"] += t2 - t1
        self.seconds["classify"] += t3 - t2
        self._last_frame = PerceptionFrame(frame_index, time_s, tuple(tracks), states, health)
        return self._last_frame


@dataclass
class VideoRunSummary:
    """What :func:`run_video` did, for the CLI, the benchmark and ``summary.json``."""

    video: str
    out_dir: str | None
    detector: str
    detector_workers: int
    rule: str
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
    topic: str | None = None
    """The camera topic read, when the input was a robotics log."""
    dropped_frames: int = 0
    seconds: dict[str, Any] | None = None
    """Per-second counts of the active-EV decisions when the run also fused them per second
    (:mod:`makeway.pipeline.clip_sound`: the sound track, the per-second decisions); else ``None``."""

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


class _LiveFrames:
    """Frames of a file delivered on the video's clock, as a live camera would deliver them, through
    a latest-wins queue of one frame (:class:`makeway.queues.LiveSource`): a frame that arrives
    while the pipeline is busy replaces the one waiting, so the pipeline always works on the newest."""

    def __init__(self, source: Iterator[Any], fps: float) -> None:
        self.feed: LiveSource[Any] = LiveSource(paced(source, fps), maxsize=1)
        self.seconds = 0.0

    def __iter__(self) -> Iterator[Any]:
        for _, item in self.feed:
            yield item

    def close(self) -> None:
        self.feed.close()


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


_Arrays = tuple[np.ndarray, ...]


def _detect_in_order(
    frames: Iterator[tuple[int, float, np.ndarray]],
    detectors: Sequence[FrameDetector],
    seconds: list[float],
    light_detectors: Sequence[LightDetector] | None = None,
) -> Iterator[tuple[int, float, np.ndarray, tuple[_Arrays, list[LightDetection]]]]:
    """Detect on several frames at once, one detector per worker, yielding results in frame order.

    Detection is stateless, so consecutive frames can be detected concurrently (ONNX Runtime
    releases the GIL); tracking then consumes them strictly in order. On a 2-core machine two
    single-threaded sessions give more frames per second than one session with two threads.
    With ``light_detectors`` (one per vehicle detector) each worker also finds the frame's lit
    lights (OpenCV releases the GIL too); else the light list is empty. ``seconds[0]``
    accumulates the vehicle detectors' busy time, ``seconds[1]`` the light detectors'.
    """
    lights = list(light_detectors) if light_detectors else [None] * len(detectors)
    if len(lights) != len(detectors):
        raise ValueError("one light detector per vehicle detector is needed")

    def both(
        det: FrameDetector, light: LightDetector | None, image: np.ndarray, index: int
    ) -> tuple[_Arrays, list[LightDetection]]:
        t0 = time.perf_counter()
        arrays = det.detect_arrays(image)
        t1 = time.perf_counter()
        found: list[LightDetection] = []
        if (
            isinstance(light, VehicleContextLightDetector)
            and light.uses_vehicles
            and isinstance(det, Detector)
        ):
            # a light detector that reads the vehicle context gets this frame's COCO vehicle boxes
            # (no second vehicle pass); behind another detector (classes not COCO's) it finds its own
            found = light.detect(image, index, vehicles=(arrays[0], arrays[1], arrays[2]))
        elif light is not None:
            found = light.detect(image, index)
        seconds[0] += t1 - t0
        seconds[1] += time.perf_counter() - t1
        return arrays, found

    if len(detectors) == 1:
        for index, t_s, image in frames:
            yield index, t_s, image, both(detectors[0], lights[0], image, index)
        return
    free: queue.Queue[tuple[FrameDetector, LightDetector | None]] = queue.Queue()
    for pair in zip(detectors, lights, strict=True):
        free.put(pair)

    def job(image: np.ndarray, index: int) -> tuple[_Arrays, list[LightDetection]]:
        det, light = free.get()
        try:
            return both(det, light, image, index)
        finally:
            free.put((det, light))

    pending: deque[tuple[int, float, np.ndarray, Future[tuple[_Arrays, list[LightDetection]]]]] = deque()
    with ThreadPoolExecutor(max_workers=len(detectors), thread_name_prefix="detect") as pool:
        try:
            for index, t_s, image in frames:
                pending.append((index, t_s, image, pool.submit(job, image, index)))
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


def draw_lights(image: np.ndarray, lights: Sequence[LightTrack]) -> None:
    """Draw light boxes in place: a thin box in the light's colour, thick and labelled with its
    flash frequency when flashing."""
    bgr = {"blue": (255, 128, 0), "red": (0, 0, 255), "amber": (0, 170, 255), "white": (255, 255, 255)}
    for lt in lights:
        colour = bgr.get(lt.colour, (0, 255, 0))
        p1 = (int(lt.box.x1) - 2, int(lt.box.y1) - 2)
        p2 = (int(np.ceil(lt.box.x2)) + 2, int(np.ceil(lt.box.y2)) + 2)
        cv2.rectangle(image, p1, p2, colour, 2 if lt.flashing else 1)
        if lt.flashing:
            cv2.putText(
                image,
                f"{lt.flash_hz:.1f}Hz",
                (p1[0], max(10, p1[1] - 3)),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.35,
                colour,
                1,
                cv2.LINE_AA,
            )


def _dropped(frames: _Prefetch | _LiveFrames) -> int:
    """Frames a live feed dropped while the pipeline was busy (0 for a file read in full)."""
    return frames.feed.dropped if isinstance(frames, _LiveFrames) else 0


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
    rule: str = "crop",
    light_detector: str = DEFAULT_LIGHTS[0],
    light_colours: str = DEFAULT_LIGHTS[1],
    light_tracker: LightTracker | None = None,
    topic: str | None = None,
    mcap: str | Path | DetectRecorder | None = None,
    frame_filter: Callable[[Iterator[tuple[int, float, np.ndarray]]], Iterator[tuple[int, float, np.ndarray]]]
    | None = None,
    realtime: bool = False,
    finish: Callable[[Path | None, float], tuple[dict[str, Any], dict[str, str]]] | None = None,
    ev_detectors: Sequence[FrameDetector] | None = None,
) -> VideoRunSummary:
    """Run Framework B (or A, with ``ev_detectors``) over ``video``; write the annotated video,
    JSONL and summary to ``out_dir``.

    Args:
        video: any file OpenCV/FFmpeg reads, or a robotics log (an MCAP file or a ROS 2 bag folder,
            :mod:`makeway.sense.logs`) whose camera ``topic`` is read instead (``None``: the log's
            only camera topic); frame times then come from the messages' stamps.
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
        rule: the active-EV rule (:class:`VisionPipeline`): ``crop``, ``lights`` or ``lights+crop``.
        light_detector, light_colours: the lights rules' light detector (registry name, one
            instance per detector worker) and its colour set
            (:data:`~makeway.perceive.vision.lights.COLOUR_SETS` name or colour list).
        light_tracker: override the default :class:`~makeway.track.lights.LightTracker`.
        topic: the camera topic when ``video`` is a log.
        mcap: also write the run as a Foxglove MCAP file here (:class:`makeway.viz.foxglove.DetectRecorder`:
            the camera image, box annotations, the tracks); on a log, in the log's own clock. A
            ready recorder may be given instead (a caller that adds channels of its own); the run
            closes it, or aborts it on an error.
        frame_filter: what the camera's frames pass through before detection, e.g. a sensor fault
            of :data:`makeway.sense.faults.VIDEO_FAULTS` (it gets and yields ``(frame_index,
            time_s, image_bgr)``).
        realtime: play the file as a live camera: frames arrive on the video's clock and, while
            the pipeline is busy, a newer frame replaces the one waiting (the oldest is dropped,
            never the newest; ``dropped_frames`` in the summary counts them). Without it every
            frame is processed, however long it takes.
        finish: called once after the last frame, inside the run's all-or-nothing guard, with the
            output folder and the seconds of video covered; it may write further outputs into the
            folder (atomically) and returns ``(seconds, outputs)``: what the summary's ``seconds``
            holds and the files it wrote (name → path). An error in it leaves nothing behind, as
            an error in the run does.
        ev_detectors: Framework A: ready one-stage EV detectors
            (:class:`~makeway.perceive.vision.ev_detector.EVDetector`, one per concurrent worker)
            used instead of ``detector``; each track's per-frame P(EV) is its detection's
            (:func:`track_one_stage`) and ``classifier`` is not needed.

    Raises:
        InputError: the video or the model is missing or unreadable, or ``out_dir`` cannot be
            written (before anything is written); the video ends well before its container's frame
            count (truncated or damaged: nothing is left behind, see
            :meth:`~makeway.sense.video.VideoReader.check_complete`).
    """
    if out_dir is not None:
        check_writable(out_dir, folder=True)
    if isinstance(mcap, str | Path):
        check_writable(mcap, folder=False)
    reader = open_frame_source(video, topic, stride=stride, max_frames=max_frames)
    start_ns = int(getattr(reader, "start_ns", 0))
    info = reader.info
    detectors: list[FrameDetector]
    if ev_detectors:
        detectors = list(ev_detectors)
    elif isinstance(detector, Detector):
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
    light_detectors = (
        [build_light_detector(light_detector, light_colours) for _ in detectors] if rule != "crop" else None
    )
    pipe = VisionPipeline(
        det,
        tracker=tracker,
        classifier=classifier,
        smoother=smoother,
        rule=rule,
        light_tracker=light_tracker,
        frame_step=stride,
    )
    detect_seconds = [0.0, 0.0]
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
    per_second: dict[str, Any] | None = None
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
            recorder = DetectRecorder(mcap) if isinstance(mcap, str | Path) else mcap
            if recorder is not None:
                recorder.start_ns = start_ns
            source: Iterator[tuple[int, float, np.ndarray]] = iter(reader)
            if frame_filter is not None:
                source = iter(frame_filter(source))
            frames: _Prefetch | _LiveFrames = (
                _LiveFrames(source, info.fps / stride) if realtime else _Prefetch(source)
            )
            wall0 = time.perf_counter()
            try:
                for index, t_s, image, (arrays, lights) in _detect_in_order(
                    iter(frames), detectors, detect_seconds, light_detectors
                ):
                    frame = pipe.process_detections(image, index, t_s, arrays, lights)
                    seen_lights = [lt for lt in pipe.light_tracks if lt.detected]
                    n_frames += 1
                    max_tracks = max(max_tracks, len(frame.tracks))
                    seen_ids.update(t.track_id for t in frame.tracks)
                    active_ids.update(s.track_id for s in frame.ev_states if s.active)
                    if jsonl is not None:
                        line = frame.to_json()
                        if light_detectors is not None:
                            line["lights"] = [lt.to_dict() for lt in seen_lights]
                        jsonl.write(json.dumps(line, separators=(",", ":")) + "\n")
                    if on_frame is not None:
                        on_frame(frame)
                    if recorder is not None:  # before the image is drawn on
                        recorder.frame(start_ns + int(round(t_s * 1e9)), image, frame, seen_lights)
                    now = time.perf_counter()
                    recent.append(now)
                    span = recent[-1] - recent[0]
                    fps_now = (len(recent) - 1) / span if span > 0 else 0.0
                    if bg is not None:
                        ta = time.perf_counter()
                        if light_detectors is not None:
                            draw_lights(image, seen_lights)
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
                if recorder is not None:
                    recorder.close()
                    outputs["mcap"] = str(recorder.path)
                if finish is not None:
                    covered = (n_frames + _dropped(frames)) * stride / info.fps
                    per_second, written = finish(out, covered)
                    outputs.update(written)
            except BaseException:
                frames.close()
                if recorder is not None:
                    recorder.abort()
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
    if light_detectors is not None:
        seconds["lights"] = detect_seconds[1]
    seconds["annotate"] = annotate_s
    seconds["encode"] = bg.seconds if bg is not None else 0.0
    dropped = _dropped(frames)
    video_seconds = (n_frames + dropped) * stride / info.fps
    summary = VideoRunSummary(
        video=str(video),
        out_dir=str(out) if out is not None else None,
        detector=det.name,
        detector_workers=len(detectors),
        rule=rule,
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
        topic=getattr(reader, "topic", None),
        dropped_frames=dropped,
        seconds=per_second,
    )
    if out is not None:
        summary.outputs["summary"] = str(out / "summary.json")
        write_text_atomic(out / "summary.json", json.dumps(summary.to_json(), indent=2) + "\n")
    return summary
