"""Run Framework B (vehicle detector → SORT → per-track crop classifier) over a clip once and
record every track's per-frame probability, so that smoothers can be replayed and scored at no cost
(:mod:`makeway.eval.actor_sweep`).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from makeway.errors import InputError
from makeway.eval.actor_sweep import RECORD_CONFIG, ClipRecord
from makeway.messages import EVObservation, Track
from makeway.perceive.vision.detectors import DETECTORS
from makeway.perceive.vision.ev_classifier import EVTrackClassifier, load_crop_classifier
from makeway.pipeline.video import run_video
from makeway.track.sort import Sort

__all__ = ["cached_clip", "cached_record", "record_clip"]


class _Recorder:
    """A :class:`~makeway.perceive.vision.ev_classifier.TrackClassifier` that remembers what the
    inner one said."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.rows: list[tuple[int, int, float, float, float, float, float]] = []

    def classify(
        self, image_bgr: np.ndarray, tracks: Sequence[Track], frame_index: int, time_s: float
    ) -> list[EVObservation]:
        obs: list[EVObservation] = self.inner.classify(image_bgr, tracks, frame_index, time_s)
        for t, o in zip(tracks, obs, strict=True):
            p = float("nan") if o.probability is None else float(o.probability)
            self.rows.append((frame_index, t.track_id, t.box.x1, t.box.y1, t.box.x2, t.box.y2, p))
        return obs


def record_clip(
    video: str | Path,
    classifier: Any,
    *,
    model_path: str | Path | None = None,
    max_frames: int | None = None,
    progress: bool = False,
    frame_filter: Callable[[Iterator[Any]], Iterator[Any]] | None = None,
) -> ClipRecord:
    """Run Framework B over ``video`` with :data:`RECORD_CONFIG`; record every track's probability.

    Args:
        video: the clip.
        classifier: a :class:`~makeway.perceive.vision.ev_classifier.TrackClassifier` (e.g.
            :class:`~makeway.perceive.vision.ev_classifier.EVTrackClassifier`).
        model_path: detector ONNX file (default: searched).
        max_frames: stop after this many frames.
        progress: show a progress bar.
        frame_filter: what the frames pass through first (e.g. a sensor fault,
            :data:`makeway.sense.faults.VIDEO_FAULTS`; see :func:`~makeway.pipeline.video.run_video`).
    """
    cfg = RECORD_CONFIG
    det = DETECTORS[cfg["detector"]](
        model_path,
        score_threshold=cfg["score_threshold"],
        class_agnostic=cfg["class_agnostic"],
        num_threads=cfg["detector_threads"],
    )
    recorder = _Recorder(classifier)
    summary = run_video(
        video,
        None,
        detector=det,
        stride=cfg["stride"],
        max_frames=max_frames,
        write_video=False,
        classifier=recorder,
        tracker=Sort(**cfg["sort"]),
        progress=progress,
        frame_filter=frame_filter,
    )
    rows = recorder.rows
    arr = np.asarray(rows, dtype=np.float64).reshape(-1, 7)
    return ClipRecord(
        clip=Path(video).stem,
        fps=float(summary.fps),
        frames=int(summary.frames),
        frame=arr[:, 0].astype(np.int64),
        track_id=arr[:, 1].astype(np.int64),
        boxes=arr[:, 2:6].copy(),
        probability=arr[:, 6].copy(),
        meta={"config": cfg, "max_frames": max_frames},
    )


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def cached_clip(
    video: str | Path,
    cache_dir: str | Path,
    head: str | Path,
    *,
    max_frames: int | None = None,
    progress: bool = False,
    single_view: bool = False,
) -> tuple[ClipRecord, bool]:
    """:func:`record_clip` with the crop classifier file ``head`` (``.npz`` head or ``.onnx`` CNN),
    cached in ``cache_dir``; ``single_view`` judges each crop without its mirror image (heads only).

    The cache key covers the clip (name and size), the head file's contents, :data:`RECORD_CONFIG`,
    ``max_frames`` and ``single_view``; returns ``(record, from_cache)``.
    """
    head = Path(head)

    def record() -> ClipRecord:
        clf = EVTrackClassifier(
            load_crop_classifier(head, single_view=single_view, num_threads=1),
            margin=RECORD_CONFIG["crop_margin"],
            min_width=RECORD_CONFIG["min_width_px"],
        )
        return record_clip(video, clf, max_frames=max_frames, progress=progress)

    key = {
        "head": _sha256(head) if head.is_file() else str(head),
        **({"single_view": True} if single_view else {}),
    }
    return cached_record(video, cache_dir, record, key=key, max_frames=max_frames)


def cached_record(
    video: str | Path,
    cache_dir: str | Path,
    record: Callable[[], ClipRecord],
    *,
    key: dict[str, Any],
    max_frames: int | None = None,
    tag: str = "",
) -> tuple[ClipRecord, bool]:
    """The :class:`ClipRecord` that ``record()`` makes of ``video``, cached in ``cache_dir`` as
    ``<stem>.<tag><key>.npz``; returns ``(record, from_cache)``.

    The cache key covers the clip (name and size), :data:`RECORD_CONFIG`, ``max_frames`` and the
    caller's ``key`` entries (e.g. the classifier's file digest).

    Raises:
        InputError: the video is missing.
    """
    video = Path(video)
    if not video.is_file():
        raise InputError(video, "video not found")
    key_src = json.dumps(
        {
            "clip": video.name,
            "size": video.stat().st_size,
            "config": RECORD_CONFIG,
            "max_frames": max_frames,
            **key,
        },
        sort_keys=True,
    )
    digest = hashlib.sha256(key_src.encode()).hexdigest()[:16]
    target = Path(cache_dir) / f"{video.stem}.{tag}{digest}.npz"
    if target.is_file():
        return ClipRecord.load(target), True
    rec = record()
    target.parent.mkdir(parents=True, exist_ok=True)
    rec.save(target)
    return rec, False
