"""Run SORT over a MOTChallenge detection file (SPEC §2): detections in, MOTChallenge tracks out."""

from __future__ import annotations

import numpy as np

from makeway.sense.motfile import MotData
from makeway.track.sort import Sort


def track_mot(
    dets: MotData,
    *,
    max_age: int = 1,
    min_hits: int = 3,
    iou_threshold: float = 0.3,
    min_score: float | None = None,
    num_frames: int | None = None,
) -> MotData:
    """Track every frame of ``dets`` with a fresh :class:`Sort`; return the tracks as :class:`MotData`.

    ``min_score`` drops detections whose confidence is below it before tracking (default: keep all,
    as the reference SORT does on MOT15).
    """
    if min_score is not None:
        dets = dets.select(dets.conf >= min_score)
    tracker = Sort(max_age=max_age, min_hits=min_hits, iou_threshold=iou_threshold)
    xyxy = dets.xyxy
    frames: list[np.ndarray] = []
    ids: list[np.ndarray] = []
    boxes: list[np.ndarray] = []
    previous = 0
    for f, rows in dets.by_frame(only=dets.frames_with_rows(num_frames)):
        tracker.skip(f - previous - 1)  # the empty frames between: no track is confirmed on them
        previous = f
        out_boxes, out_ids = tracker.update_arrays(xyxy[rows], dets.conf[rows])
        if len(out_ids):
            frames.append(np.full(len(out_ids), f, dtype=np.int64))
            ids.append(out_ids)
            boxes.append(out_boxes)
    if not frames:
        return MotData(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 4)), np.zeros(0))
    b = np.concatenate(boxes)
    xywh = np.concatenate([b[:, :2], b[:, 2:] - b[:, :2]], axis=1)
    return MotData(np.concatenate(frames), np.concatenate(ids), xywh, np.ones(len(b)))
