"""Labelled crops from the road clips' tracks: a crop source for the cross-source protocol (issue 24).

The per-track labels (:data:`makeway.eval.actor_sweep.TRACK_LABELS`) belong to the track ids that
YOLOX-nano → SORT gives under :data:`~makeway.eval.actor_sweep.RECORD_CONFIG`.
:func:`cached_track_boxes` runs exactly that over a clip once, with no crop classifier (the
classifier never changes the tracks), and caches every track's box per frame as a
:class:`~makeway.eval.actor_sweep.ClipRecord` (probabilities NaN). :func:`build_track_crops` then
takes every ``every``-th frame of each track's life, cuts the square crop the pipeline's classifier
sees (10 % context per side of the longer box side, boxes under 18 px wide skipped; SPEC §1) and
writes a crop folder whose ``group`` column is the track (``<clip>#<track id>``), so that
near-identical frames of one vehicle never straddle a split.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from makeway.errors import InputError
from makeway.eval.actor_sweep import RECORD_CONFIG, TRACK_LABELS, ClipRecord, read_track_labels
from makeway.messages import Box, EVObservation, Track
from makeway.perceive.vision.crops import square_crop
from makeway.pipeline.clip_record import cached_record, record_clip
from makeway.progress import progress_bar
from makeway.sense.crops import write_crop_folder
from makeway.sense.video import VideoReader

__all__ = ["build_track_crops", "cached_track_boxes", "track_group"]


class _NoJudgement:
    """A track classifier that judges nothing (``probability=None`` for every track): lets
    :func:`~makeway.pipeline.clip_record.record_clip` record the tracks' boxes at the detector's cost."""

    def classify(
        self, image_bgr: np.ndarray, tracks: Sequence[Track], frame_index: int, time_s: float
    ) -> list[EVObservation]:
        return [EVObservation(t.track_id, frame_index, time_s, None, source="vision") for t in tracks]


def track_group(clip: str, track_id: int) -> str:
    """The ``group`` value of a track's crops: ``<clip>#<track id>``."""
    return f"{clip}#{int(track_id)}"


def cached_track_boxes(
    video: str | Path, cache_dir: str | Path, *, max_frames: int | None = None, progress: bool = False
) -> tuple[ClipRecord, bool]:
    """Every track's box per frame of ``video`` under :data:`RECORD_CONFIG` (track ids as in the
    label file), cached in ``cache_dir``; returns ``(record, from_cache)``. ``max_frames`` stops
    after that many frames (the track ids of the frames recorded do not change).

    The cache key covers the clip (name and size), :data:`RECORD_CONFIG` and ``max_frames``.

    Raises:
        InputError: the video is missing or unreadable.
    """
    return cached_record(
        video,
        cache_dir,
        lambda: record_clip(video, _NoJudgement(), max_frames=max_frames, progress=progress),
        key={"boxes_only": True},
        max_frames=max_frames,
        tag="boxes.",
    )


def _sampled_rows(rec: ClipRecord, every: int) -> dict[int, list[int]]:
    """Frame index → rows of ``rec`` to crop there: each track's frames ``first, first + every, …``."""
    wanted: dict[int, list[int]] = {}
    for tid in rec.track_ids:
        rows = np.flatnonzero(rec.track_id == tid)
        first = int(rec.frame[rows].min())
        for r in rows.tolist():
            if (int(rec.frame[r]) - first) % every == 0:
                wanted.setdefault(int(rec.frame[r]), []).append(r)
    return wanted


def build_track_crops(
    out: str | Path,
    videos: Sequence[str | Path],
    *,
    labels: str | Path = TRACK_LABELS,
    cache_dir: str | Path,
    every: int = 5,
    margin: float | None = None,
    size: int = 224,
    max_frames: int | None = None,
    progress: bool = True,
) -> dict[str, int]:
    """Write a crop folder at ``out`` (``images/`` + ``labels.csv`` with ``image,emergency,group``)
    from the labelled tracks of ``videos`` (module docstring): one crop every ``every`` frames of
    each track, ``size`` px, ``margin`` context per side (default: the pipeline's,
    ``RECORD_CONFIG["crop_margin"]``), tracks' boxes from :func:`cached_track_boxes` in
    ``cache_dir``; ``max_frames`` uses only the first frames of each clip.

    Returns the counts ``clips``, ``tracks`` (with at least one crop), ``positive``, ``negative``
    and ``crops``.

    Raises:
        InputError: a video is missing or unreadable, the label file is malformed, or a clip or one of
            its tracks has no label (checked for every clip before any crop is written).
        ValueError: ``every < 1``.
    """
    if every < 1:
        raise ValueError(f"every must be >= 1, got {every}")
    margin = float(RECORD_CONFIG["crop_margin"] if margin is None else margin)
    min_width = float(RECORD_CONFIG["min_width_px"])
    track_labels = read_track_labels(labels)
    paths = [Path(v) for v in videos]
    if not paths:
        raise InputError(Path(labels), "no road clips given to crop from")
    for path in paths:
        if not path.is_file():
            raise InputError(path, "video not found")
        if path.stem not in track_labels.clips:
            raise InputError(Path(labels), f"no labels for clip {path.stem!r}")
    records: list[tuple[Path, ClipRecord]] = []
    for path in paths:
        rec, _ = cached_track_boxes(path, cache_dir, max_frames=max_frames, progress=progress)
        for tid in rec.track_ids:
            track_labels.label(rec.clip, tid)  # raises before anything is written
        records.append((path, rec))
    counts = {"clips": len(records), "tracks": 0, "positive": 0, "negative": 0}
    tracks_seen: set[str] = set()
    total = sum(rec.frames for _, rec in records)

    def items(advance: Callable[[int], Any]) -> Iterator[tuple[str, np.ndarray, int, str | None]]:
        for path, rec in records:
            wanted = _sampled_rows(rec, every)
            with VideoReader(path, max_frames=rec.frames) as reader:
                for index, _, image in reader:
                    advance(1)
                    for r in wanted.get(index, []):
                        x1, y1, x2, y2 = (float(v) for v in rec.boxes[r])
                        crop = square_crop(
                            image, Box(x1, y1, x2, y2), margin=margin, size=size, min_width=min_width
                        )
                        if crop is None:
                            continue
                        tid = int(rec.track_id[r])
                        label = track_labels.label(rec.clip, tid)
                        group = track_group(rec.clip, tid)
                        tracks_seen.add(group)
                        counts["positive" if label else "negative"] += 1
                        yield f"{rec.clip}_t{tid}_f{index:05d}.jpg", crop, label, group

    with progress_bar("crops from road clips", total, enabled=progress, unit="frames") as adv:
        counts["crops"] = write_crop_folder(out, items(adv))
    counts["tracks"] = len(tracks_seen)
    return counts
