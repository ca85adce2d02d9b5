"""``makeway track`` and ``makeway mot-eval``: SORT on MOTChallenge files and their CLEAR MOT scores."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from makeway.atomic import check_writable
from makeway.eval.mot import evaluate_mot
from makeway.pipeline.mot import track_mot
from makeway.sense.motfile import read_mot, write_mot_tracks

__all__ = ["MotTrackRun", "score_mot_files", "track_mot_file"]


@dataclass(frozen=True)
class MotTrackRun:
    """What :func:`track_mot_file` did: ``frames`` (the last frame number), ``detections`` (rows
    read), ``tracks`` (distinct ids written), ``boxes`` (rows written) and, with ground truth,
    ``metrics`` (:meth:`~makeway.eval.mot.MotCounts.summary`: MOTA, MOTP, IDF1, ID switches, …)."""

    frames: int
    detections: int
    tracks: int
    boxes: int
    metrics: dict[str, Any] | None


def track_mot_file(
    mot_det: str | Path,
    out: str | Path,
    *,
    gt: str | Path | None = None,
    max_age: int = 1,
    min_hits: int = 3,
    iou_threshold: float = 0.3,
    min_score: float | None = None,
) -> MotTrackRun:
    """Run SORT (:func:`~makeway.pipeline.mot.track_mot`) on the MOTChallenge detection file
    ``mot_det`` and write the tracks to ``out`` as ``frame,id,x,y,w,h,1,-1,-1,-1`` rows (pixels);
    with ``gt``, also score them against that ground truth.

    Raises:
        InputError: ``out`` cannot be written, or ``mot_det`` / ``gt`` cannot be read (all checked
            before anything is written).
    """
    check_writable(out, folder=False)
    dets = read_mot(mot_det, kind="detection")
    truth = read_mot(gt, kind="gt") if gt is not None else None  # read before writing anything
    tracks = track_mot(
        dets, max_age=max_age, min_hits=min_hits, iou_threshold=iou_threshold, min_score=min_score
    )
    rows = [
        (int(f), int(i), float(b[0]), float(b[1]), float(b[2]), float(b[3]))
        for f, i, b in zip(tracks.frames, tracks.ids, tracks.xywh, strict=True)
    ]
    write_mot_tracks(out, rows)
    metrics = evaluate_mot(truth, tracks).summary() if truth is not None else None
    return MotTrackRun(
        frames=dets.num_frames,
        detections=len(dets),
        tracks=len(np.unique(tracks.ids)),
        boxes=len(rows),
        metrics=metrics,
    )


def score_mot_files(gt: str | Path, tracks: str | Path, *, iou: float = 0.5) -> dict[str, Any]:
    """CLEAR MOT and identity metrics (MOTA, MOTP, IDF1, ID switches, …) of the MOTChallenge tracker
    output ``tracks`` against the ground truth ``gt``; a match needs IoU ≥ ``iou``.

    Raises:
        InputError: either file cannot be read.
    """
    return evaluate_mot(read_mot(gt, kind="gt"), read_mot(tracks, kind="tracks"), iou_threshold=iou).summary()
