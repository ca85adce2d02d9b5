"""Framework A against Framework B on the labelled road clips (seed 001; issue 24, item 5).

Seed 001 argues for Framework B (vehicle detector → SORT → crop classifier) over Framework A (one
detector with the classes EV / other vehicle → SORT) partly because in A a class flip resets the
track id. Here both run over the shared road clips and are scored per actor with the machinery of
:mod:`makeway.eval.actor_sweep` (the per-track smoother replayed on recorded per-frame
probabilities):

* **B's record** is the labelled one: the tracks of :data:`~makeway.eval.actor_sweep.RECORD_CONFIG`
  (YOLOX-nano → SORT; their ids are the label file's) with the crop classifier's P(EV) per frame.
* **A's record** (:func:`record_framework_a`): the one-stage detector's boxes → one SORT (same
  settings) over all vehicles → each track's per-frame P(EV) = ``c0 / (c0 + c1)`` of its detection,
  and its argmax class.
* **A's tracks get labels by overlap** (:func:`label_by_overlap`): in every frame A's tracks and the
  labelled tracks are matched one-to-one by IoU ≥ 0.5 (Hungarian, :func:`makeway.track.sort.associate`);
  an A track takes the label of the labelled track it matched on most frames. An A track that
  never matches one (a box YOLOX-nano's SORT never tracked) takes its clip's ``*`` label and is
  counted as ``unmatched``.

Beside per-actor precision, recall and F1, :func:`class_flips` counts the resets seed 001's claim
is about: a track whose argmax class changes within its life would, tracked per class, end and
restart at each change. :func:`id_switches` counts, for each EV actor of one framework, how often
the other framework's track following it (IoU ≥ 0.5) changes its id.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from makeway.eval.actor_sweep import RECORD_CONFIG, ClipRecord, TrackLabels
from makeway.eval.detection import box_iou_matrix
from makeway.track.one_stage import track_one_stage
from makeway.track.sort import Sort, associate

__all__ = [
    "FlipCount",
    "class_flips",
    "frame_matches",
    "id_switches",
    "label_by_overlap",
    "record_framework_a",
]

MATCH_IOU = 0.5


def record_framework_a(
    video: str | Path, detector: Any, *, max_frames: int | None = None, progress: bool = False
) -> ClipRecord:
    """Framework A over ``video``: ``detector`` (an
    :class:`~makeway.perceive.vision.ev_detector.EVDetector`) → one SORT with
    :data:`RECORD_CONFIG`'s settings → every confirmed track's box and P(EV) per frame
    (``meta["class_id"]`` holds the argmax classes, row-aligned)."""
    from makeway.progress import progress_bar
    from makeway.sense.video import VideoReader

    tracker = Sort(**RECORD_CONFIG["sort"])
    rows: list[tuple[int, int, float, float, float, float, float]] = []
    classes: list[int] = []
    with VideoReader(video, max_frames=max_frames) as reader:
        total = reader.info.frame_count if max_frames is None else max_frames
        with progress_bar(f"Framework A {Path(video).name}", total, enabled=progress) as bar:
            for index, _, image in reader:
                tracks, probs = track_one_stage(tracker, detector.detect_arrays(image))
                for t in tracks:
                    b = t.box
                    rows.append((index, t.track_id, b.x1, b.y1, b.x2, b.y2, probs[t.track_id]))
                    classes.append(int(t.class_id))
                bar()
        fps, frames = reader.info.fps, reader.frames_yielded
    arr = np.asarray(rows, dtype=np.float64).reshape(-1, 7)
    return ClipRecord(
        clip=Path(video).stem,
        fps=float(fps),
        frames=int(frames),
        frame=arr[:, 0].astype(np.int64),
        track_id=arr[:, 1].astype(np.int64),
        boxes=arr[:, 2:6].copy(),
        probability=arr[:, 6].copy(),
        meta={"framework": "a", "class_id": classes, "sort": RECORD_CONFIG["sort"]},
    )


def frame_matches(a: ClipRecord, b: ClipRecord, iou: float = MATCH_IOU) -> Iterator[tuple[int, int, int]]:
    """``(frame, a_track, b_track)`` for every one-to-one IoU match (≥ ``iou``) between the tracks
    of two records of one clip, frame by frame in order."""
    for frame in sorted(set(a.frame.tolist()) & set(b.frame.tolist())):
        ia = np.flatnonzero(a.frame == frame)
        ib = np.flatnonzero(b.frame == frame)
        m = box_iou_matrix(a.boxes[ia], b.boxes[ib])
        for i, j in zip(*associate(m, iou), strict=True):
            yield frame, int(a.track_id[ia[i]]), int(b.track_id[ib[j]])


def label_by_overlap(
    a: ClipRecord, reference: ClipRecord, labels: TrackLabels, iou: float = MATCH_IOU
) -> tuple[dict[int, int], int]:
    """Labels of ``a``'s tracks from the labelled ``reference`` tracks (module docstring):
    ``({a_track: 0/1}, n_unmatched)``."""
    votes: dict[int, Counter[int]] = {}
    for _, ta, tb in frame_matches(a, reference, iou):
        votes.setdefault(ta, Counter())[tb] += 1
    out: dict[int, int] = {}
    unmatched = 0
    for tid in a.track_ids:
        if tid in votes:
            ref = votes[tid].most_common(1)[0][0]
            out[tid] = labels.label(reference.clip, ref)
        else:
            unmatched += 1
            out[tid] = labels.default.get(a.clip, 0)
    return out, unmatched


@dataclass(frozen=True)
class FlipCount:
    """Per-frame class changes within tracks: ``tracks`` judged, ``tracks_flipping`` (at least one
    change), ``flips`` (all changes = the resets per-class tracking would add), and the same two
    for the EV actors only."""

    tracks: int
    tracks_flipping: int
    flips: int
    ev_tracks: int
    ev_tracks_flipping: int
    ev_flips: int


def class_flips(record: ClipRecord, labels: dict[int, int], threshold: float = 0.5) -> FlipCount:
    """Changes of each track's per-frame class (P(EV) ≥ ``threshold`` is class EV — for A the
    argmax of its two classes at 0.5), frames without a judgement skipped."""
    tracks = flipping = flips = ev_tracks = ev_flipping = ev_flips = 0
    for tid in record.track_ids:
        p = record.probabilities_of(tid)
        p = p[~np.isnan(p)]
        if not p.size:
            continue
        n = int(np.count_nonzero(np.diff((p >= threshold).astype(np.int8))))
        tracks += 1
        flipping += n > 0
        flips += n
        if labels.get(tid, 0):
            ev_tracks += 1
            ev_flipping += n > 0
            ev_flips += n
    return FlipCount(tracks, flipping, flips, ev_tracks, ev_flipping, ev_flips)


def id_switches(follower: ClipRecord, leader: ClipRecord, leader_labels: dict[int, int]) -> tuple[int, int]:
    """``(switches, ev_actors)``: for each EV track of ``leader`` (label 1), the ``follower`` track
    matched to it (IoU ≥ 0.5) frame by frame; a switch is a change of that track id between two
    consecutive matched frames."""
    followed: dict[int, list[int]] = {}
    for _, tf, tl in frame_matches(follower, leader):
        if leader_labels.get(tl, 0):
            followed.setdefault(tl, []).append(tf)
    switches = sum(int(np.count_nonzero(np.diff(ids))) for ids in followed.values())
    return switches, sum(1 for v in leader_labels.values() if v)
