"""Tracking and EV-state smoothing scored against a simulated roadside scene's ground truth (SPEC §1–2).

Used by ``makeway demo``'s tracking part (:mod:`makeway.apps.tracking_demo`): SORT tracks over the
simulated detections (:mod:`makeway.sim.traffic`) carry the simulated classifier probability and one
smoothed state per smoother threshold; :func:`score_scene_tracking` measures them.
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from makeway.eval.classification import precision_recall_f1, threshold_metrics
from makeway.eval.mot import evaluate_mot
from makeway.messages import EVState
from makeway.sense.motfile import MotData
from makeway.sim.traffic import Scene
from makeway.track.sort import iou_matrix

__all__ = ["DISPLAY_T", "THRESHOLDS", "SceneTrackRecord", "score_scene_tracking"]

#: Smoother thresholds T run side by side (seed 000, the Aurora per-frame CNN + smoother paper, Table 3);
#: T = 0 is the unsmoothed baseline.
THRESHOLDS: tuple[float, ...] = (0.0, 0.3, 0.5, 0.7)
#: The threshold whose state is displayed and reported as the headline.
DISPLAY_T = 0.5


@dataclass
class SceneTrackRecord:
    """One reported track in one frame, with the classifier output it got and the smoothed states."""

    frame: int
    track_id: int
    box: tuple[float, float, float, float]
    probability: float | None
    positive_fraction: float
    n_valid: int
    states: dict[float, EVState]


def score_scene_tracking(
    scene: Scene,
    records: list[list[SceneTrackRecord]],
    thresholds: Sequence[float] = THRESHOLDS,
    display_t: float = DISPLAY_T,
) -> dict[str, Any]:
    """Score tracks and smoothed EV states against a simulated scene's ground truth.

    ``records`` holds, per frame, the reported tracks (:class:`SceneTrackRecord`) with their
    classifier probability and the smoothed state at each smoother threshold of ``thresholds``.
    Returns (a) CLEAR MOT / IDF1 of the tracks, (b) per-frame classifier precision/recall/F1,
    (c) per-actor and per-frame smoother metrics per threshold (seed 000, Table 3), (d) time from
    each EV entering the view to its first active frame at ``display_t``; the keys are those of
    ``makeway demo``'s ``tracking/summary.json``.
    """
    fps = scene.fps
    flat = [r for row in records for r in row]
    # (a) MOT
    if flat:
        hyp = MotData(
            np.array([r.frame + 1 for r in flat], dtype=np.int64),
            np.array([r.track_id for r in flat], dtype=np.int64),
            np.array([[r.box[0], r.box[1], r.box[2] - r.box[0], r.box[3] - r.box[1]] for r in flat]),
            np.ones(len(flat)),
        )
    else:
        hyp = MotData(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 4)), np.zeros(0))
    mot = evaluate_mot(scene.gt, hyp).summary()

    # track -> actor by majority overlap (IoU >= 0.5 with the best-overlapping truth box)
    votes: dict[int, Counter[int]] = defaultdict(Counter)
    length: Counter[int] = Counter()
    for frame, row in zip(scene.frames, records, strict=True):
        if not row:
            continue
        length.update(r.track_id for r in row)
        if not frame.truth:
            continue
        iou = np.nan_to_num(
            iou_matrix(np.array([r.box for r in row]), np.array([t.box.as_array() for t in frame.truth]))
        )
        best = iou.argmax(axis=1)
        for i, r in enumerate(row):
            if iou[i, best[i]] >= 0.5:
                votes[r.track_id][frame.truth[best[i]].actor_id] += 1
    track_to_actor: dict[int, int | None] = {}
    for tid, n in length.items():
        top = votes[tid].most_common(1)
        track_to_actor[tid] = top[0][0] if top and top[0][1] >= 0.5 * n else None

    ev_ids = [a for a in scene.ev_ids if a in set(scene.visible_ids)]
    ev_set = set(ev_ids)

    # (b) per-frame classifier vs "EV with a lit bulb in this frame"
    scores, labels = [], []
    n_skipped = 0
    for frame in scene.frames:
        lit = {t.actor_id for t in frame.truth if t.lights_on}
        for d in frame.detections:
            if d.ev_probability is None:
                n_skipped += 1
                continue
            scores.append(d.ev_probability)
            labels.append(d.actor_id in lit)
    s_arr, y_arr = np.array(scores, dtype=np.float64), np.array(labels, dtype=bool)
    pred = s_arr >= 0.5
    classifier: dict[str, Any] = precision_recall_f1(
        int((pred & y_arr).sum()), int((pred & ~y_arr).sum()), int((~pred & y_arr).sum())
    )
    classifier.update(threshold_metrics(s_arr, y_arr))
    classifier.update(
        {"num_valid": len(s_arr), "num_positive_labels": int(y_arr.sum()), "num_skipped": n_skipped}
    )

    # (c) smoother, per T
    def actor_key(tid: int) -> tuple[str, int]:
        a = track_to_actor.get(tid)
        return ("actor", a) if a is not None else ("track", tid)

    per_actor: dict[str, dict[str, Any]] = {}
    per_frame: dict[str, dict[str, Any]] = {}
    ev_keys = {("actor", a) for a in ev_ids}
    for thr in thresholds:
        flagged = {actor_key(r.track_id) for r in flat if r.states[thr] is EVState.ACTIVE}
        pa = precision_recall_f1(len(flagged & ev_keys), len(flagged - ev_keys), len(ev_keys - flagged))
        pa["flagged"] = sorted(f"{k}:{v}" for k, v in flagged)
        per_actor[str(thr)] = pa
        tp = fp = fn = 0
        for r in flat:
            st = r.states[thr]
            if st is EVState.WARMING_UP:
                continue
            truth = track_to_actor.get(r.track_id) in ev_set
            act = st is EVState.ACTIVE
            tp += act and truth
            fp += act and not truth
            fn += truth and not act
        per_frame[str(thr)] = precision_recall_f1(tp, fp, fn)
    base = per_actor[str(thresholds[0])]
    for thr in thresholds:
        pa = per_actor[str(thr)]
        for k in ("precision", "recall", "f1"):
            b, v = base[k], pa[k]
            pa[f"{k}_change_pct"] = (
                100.0 * (v - b) / b if b and math.isfinite(b) and math.isfinite(v) else None
            )

    # (d) time to active, per EV
    evs: list[dict[str, Any]] = []
    for a in ev_ids:
        first_seen = first_cls = first_tracked = first_active = None
        n_seen = n_active = 0
        active_frames = {
            r.frame
            for r in flat
            if track_to_actor.get(r.track_id) == a and r.states[display_t] is EVState.ACTIVE
        }
        tracked_frames = {r.frame for r in flat if track_to_actor.get(r.track_id) == a}
        for frame in scene.frames:
            tb = next((t for t in frame.truth if t.actor_id == a), None)
            if tb is None or not tb.considered:
                continue
            n_seen += 1
            n_active += frame.index in active_frames
            if first_seen is None:
                first_seen = frame.index
            if first_cls is None and tb.box.width >= scene.config.cls_min_width_px:
                first_cls = frame.index
        if tracked_frames:
            first_tracked = min(tracked_frames)
        if active_frames:
            first_active = min(active_frames)
        actor = scene.actors[a]

        def dt(x: int | None, y: int | None) -> float | None:
            return (x - y) / fps if x is not None and y is not None else None

        evs.append(
            {
                "actor_id": a,
                "kind": actor.kind.name,
                "approaching": actor.approaching,
                "flash_hz": actor.flash_hz,
                "tracks": sorted(t for t, v in track_to_actor.items() if v == a),
                "first_seen_s": dt(first_seen, 0),
                "first_classifiable_s": dt(first_cls, 0),
                "first_tracked_s": dt(first_tracked, 0),
                "first_active_s": dt(first_active, 0),
                "time_to_active_s": dt(first_active, first_seen),
                "time_to_active_from_classifiable_s": dt(first_active, first_cls),
                "active_share_of_visible_frames": n_active / n_seen if n_seen else None,
            }
        )
    times: list[float | None] = [e["time_to_active_s"] for e in evs]
    known = [t for t in times if t is not None]
    worst = max(known) if known and len(known) == len(times) else None

    n_tracks = len(length)
    scene_info = {
        "num_frames": scene.num_frames,
        "fps": fps,
        "width": scene.width,
        "height": scene.height,
        "vehicles_visible": len(scene.visible_ids),
        "evs_visible": len(ev_ids),
        "gt_boxes_considered": int((scene.gt.conf != 0).sum()),
        "detections": sum(len(f.detections) for f in scene.frames),
        "false_positive_detections": sum(1 for f in scene.frames for d in f.detections if d.actor_id < 0),
        "tracks": n_tracks,
        "tracks_unmapped": sum(1 for v in track_to_actor.values() if v is None),
    }
    return {
        "mot": mot,
        "classifier": classifier,
        "smoother": {
            "thresholds": list(thresholds),
            "display_T": display_t,
            "per_actor": per_actor,
            "per_frame": per_frame,
        },
        "evs": evs,
        "time_to_active_s": worst,
        "scene": scene_info,
        "track_to_actor": track_to_actor,
    }


# -------------------------------------------------------------------------------------------- plots
