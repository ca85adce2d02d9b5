"""Seed 004's lit-light metrics: bulb-array and vehicle precision/recall, mAP50, mAP50:95, latency.

Boxes are ``(n, 4)`` ``x1, y1, x2, y2`` in the frame's pixels. All detections count as one class (a lit
emergency light); pass only the ground truth of the colours that count (the jurisdiction's set).

**Array level** (seed 004's bulb-array precision and recall): in each frame the detections are taken in
descending score order and each is matched to the not yet matched ground-truth box with the highest
IoU, when that IoU is ≥ 0.5 (:func:`match_frame`; the rule of :mod:`makeway.eval.detection`); each
ground truth is matched at most once. ``P = TP / detections``, ``R = TP / ground-truth boxes``, summed
over frames. Negative frames (no ground truth) add their detections as false positives.

**Vehicle level** (through the vehicle id of each ground-truth box, ABLDataset's ``test_id``): per
frame, a ground-truth vehicle is *found* when at least one of its boxes is matched. Predicted vehicles
are the found vehicles plus the *false vehicles*, defined here (the seed does not say how it groups
predictions): an unmatched detection whose centre lies inside a ground-truth vehicle's region — the
bounding box of that vehicle's boxes in the frame, grown by half its width and height on each side
(at least 10 px) — belongs to that vehicle and is not a false vehicle (another lamp of the same
vehicle, or a glow box around a labelled one); the remaining unmatched detections are grouped by
single linkage, two detections joining when the gap between their boxes is at most twice the longer
side of the larger one, and each group is one false vehicle. ``P = found / (found + false)``,
``R = found / ground-truth vehicles``, summed over frames (vehicle-frame pairs).

**mAP50, mAP50:95**: :func:`makeway.eval.detection.detection_metrics` over all frames of the set (one
class, all-point interpolated AP; COCO samples 101 recall points, which moves AP by up to ~0.01),
over every detection given; the P/R figures count only detections scoring at least
``score_threshold`` (the detector's operating point), so a detector run with a low threshold gives
both its ranking (mAP) and its operating point (P/R).

**Latency**: milliseconds per frame of the detector's ``detect`` call (mean and median).

:func:`summarise` reports each source alone and the worst source per figure (the lowest P, R, mAP
among the sources where the figure is defined; the highest latency).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from makeway.eval.detection import box_iou_matrix, detection_metrics

__all__ = [
    "FrameResult",
    "LightsMetrics",
    "evaluate_frames",
    "false_positive_breakdown",
    "match_frame",
    "metrics",
    "run_detector",
    "summarise",
    "vehicle_counts",
    "vehicle_regions",
]


def _boxes(b: Any) -> np.ndarray:
    arr = np.asarray(b, dtype=np.float64)
    if arr.size == 0:
        return np.zeros((0, 4))
    if arr.ndim != 2 or arr.shape[1] != 4:
        raise ValueError(f"boxes must be (n, 4) x1, y1, x2, y2; got shape {arr.shape}")
    return arr


@dataclass
class FrameResult:
    """One evaluated frame: its ``source`` and ``key``, ground truth (``gt_boxes``, ``gt_vehicles``)
    and detections (``boxes``, ``scores``, and ``colours`` when known) in its pixels, and the
    detector's time (ms)."""

    source: str
    key: str
    gt_boxes: np.ndarray
    gt_vehicles: Sequence[int]
    boxes: np.ndarray
    scores: np.ndarray
    ms: float = 0.0
    colours: Sequence[str] = ()


def match_frame(boxes: Any, scores: Any, gt_boxes: Any, iou_threshold: float = 0.5) -> np.ndarray:
    """For each detection, the index of the ground-truth box it matches, or -1 (module docstring:
    greedy in descending score order, best free IoU ≥ threshold, each ground truth once)."""
    b, g = _boxes(boxes), _boxes(gt_boxes)
    s = np.asarray(scores, dtype=np.float64).ravel()
    if len(s) != len(b):
        raise ValueError(f"{len(b)} boxes but {len(s)} scores")
    out = np.full(len(b), -1, dtype=np.int64)
    if len(b) == 0 or len(g) == 0:
        return out
    iou = box_iou_matrix(b, g)
    taken = np.zeros(len(g), bool)
    for d in np.argsort(-s, kind="stable"):
        free = np.where(taken, -1.0, iou[d])
        j = int(np.argmax(free))
        if free[j] >= iou_threshold:
            taken[j] = True
            out[d] = j
    return out


def vehicle_regions(gt: np.ndarray, vehicles: Sequence[int]) -> dict[int, np.ndarray]:
    """Each ground-truth vehicle's region (module docstring, vehicle level): the bounding box of its
    boxes ``gt`` (``(n, 4)`` pixels) grown by half its width and height on each side, at least
    10 px; keyed by vehicle id."""
    out = {}
    for v in sorted(set(vehicles)):
        sel = gt[np.asarray(vehicles) == v]
        x1, y1 = sel[:, 0].min(), sel[:, 1].min()
        x2, y2 = sel[:, 2].max(), sel[:, 3].max()
        gx, gy = max(10.0, 0.5 * (x2 - x1)), max(10.0, 0.5 * (y2 - y1))
        out[v] = np.array([x1 - gx, y1 - gy, x2 + gx, y2 + gy])
    return out


def _groups(boxes: np.ndarray) -> int:
    """Single-linkage groups of boxes (gap ≤ twice the longer side of the larger box)."""
    n = len(boxes)
    parent = list(range(n))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    side = np.maximum(boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1])
    for i in range(n):
        for j in range(i + 1, n):
            gx = max(0.0, max(boxes[i, 0], boxes[j, 0]) - min(boxes[i, 2], boxes[j, 2]))
            gy = max(0.0, max(boxes[i, 1], boxes[j, 1]) - min(boxes[i, 3], boxes[j, 3]))
            if math.hypot(gx, gy) <= 2.0 * max(side[i], side[j]):
                parent[find(i)] = find(j)
    return len({find(i) for i in range(n)})


def vehicle_counts(
    boxes: Any, scores: Any, gt_boxes: Any, gt_vehicles: Sequence[int], iou_threshold: float = 0.5
) -> tuple[int, int, int]:
    """``(found vehicles, false vehicles, ground-truth vehicles)`` of one frame (module docstring)."""
    b, g = _boxes(boxes), _boxes(gt_boxes)
    if len(gt_vehicles) != len(g):
        raise ValueError(f"{len(g)} ground-truth boxes but {len(gt_vehicles)} vehicle ids")
    match = match_frame(b, scores, g, iou_threshold)
    vehicles = list(gt_vehicles)
    found = {vehicles[j] for j in match if j >= 0}
    regions = vehicle_regions(g, vehicles) if len(g) else {}
    loose = []
    for d in np.flatnonzero(match < 0):
        cx, cy = (b[d, 0] + b[d, 2]) / 2, (b[d, 1] + b[d, 3]) / 2
        inside = any(r[0] <= cx <= r[2] and r[1] <= cy <= r[3] for r in regions.values())
        if not inside:
            loose.append(b[d])
    false = _groups(np.array(loose).reshape(-1, 4)) if loose else 0
    return len(found), false, len(set(vehicles))


@dataclass(frozen=True)
class LightsMetrics:
    """Figures of one set of frames (module docstring). P/R are ``nan`` when undefined (no detections,
    no ground truth); ``fp_frames`` counts frames without ground truth that got a detection."""

    frames: int
    gt_boxes: int
    detections: int
    tp: int
    array_precision: float
    array_recall: float
    gt_vehicles: int
    found_vehicles: int
    false_vehicles: int
    vehicle_precision: float
    vehicle_recall: float
    map50: float
    map50_95: float
    negative_frames: int
    fp_frames: int
    ms_mean: float
    ms_median: float

    def to_dict(self) -> dict[str, Any]:
        return {
            k: (None if isinstance(v, float) and not math.isfinite(v) else v)
            for k, v in self.__dict__.items()
        }


def _ratio(a: int, b: int) -> float:
    return a / b if b else float("nan")


def metrics(
    results: Sequence[FrameResult], iou_threshold: float = 0.5, score_threshold: float = 0.0
) -> LightsMetrics:
    """All figures over a set of evaluated frames (P/R at ``score_threshold``, mAP over all)."""
    tp = n_det = n_gt = found = false = n_veh = neg = fp_frames = 0
    for r in results:
        keep = np.asarray(r.scores, np.float64).ravel() >= score_threshold
        boxes, scores = _boxes(r.boxes)[keep], np.asarray(r.scores, np.float64).ravel()[keep]
        match = match_frame(boxes, scores, r.gt_boxes, iou_threshold)
        tp += int((match >= 0).sum())
        n_det += len(match)
        n_gt += len(_boxes(r.gt_boxes))
        f, fa, nv = vehicle_counts(boxes, scores, r.gt_boxes, r.gt_vehicles, iou_threshold)
        found, false, n_veh = found + f, false + fa, n_veh + nv
        if len(_boxes(r.gt_boxes)) == 0:
            neg += 1
            fp_frames += int(len(match) > 0)
    if results:
        dm = detection_metrics(
            [_boxes(r.boxes) for r in results],
            [np.asarray(r.scores, np.float64) for r in results],
            [_boxes(r.gt_boxes) for r in results],
        )
        map50, map50_95 = dm.map50, dm.map50_95
    else:
        map50 = map50_95 = float("nan")
    ms = np.array([r.ms for r in results], np.float64)
    return LightsMetrics(
        frames=len(results),
        gt_boxes=n_gt,
        detections=n_det,
        tp=tp,
        array_precision=_ratio(tp, n_det),
        array_recall=_ratio(tp, n_gt),
        gt_vehicles=n_veh,
        found_vehicles=found,
        false_vehicles=false,
        vehicle_precision=_ratio(found, found + false),
        vehicle_recall=_ratio(found, n_veh),
        map50=float(map50),
        map50_95=float(map50_95),
        negative_frames=neg,
        fp_frames=fp_frames,
        ms_mean=float(ms.mean()) if len(ms) else float("nan"),
        ms_median=float(np.median(ms)) if len(ms) else float("nan"),
    )


_LOWER_IS_WORSE = (
    "array_precision",
    "array_recall",
    "vehicle_precision",
    "vehicle_recall",
    "map50",
    "map50_95",
)


def summarise(
    results: Sequence[FrameResult], iou_threshold: float = 0.5, score_threshold: float = 0.0
) -> dict[str, dict[str, Any]]:
    """Metrics per source (``{source: LightsMetrics.to_dict()}``), plus ``all`` (every frame pooled)
    and ``worst``: per figure the lowest value among the sources where it is defined (the highest for
    latency and ``fp_frames``), with ``worst_source`` naming where each came from."""
    by: dict[str, list[FrameResult]] = {}
    for r in results:
        by.setdefault(r.source, []).append(r)
    out: dict[str, dict[str, Any]] = {
        s: metrics(rs, iou_threshold, score_threshold).to_dict() for s, rs in sorted(by.items())
    }
    worst: dict[str, Any] = {}
    where: dict[str, str] = {}
    for key in (*_LOWER_IS_WORSE, "ms_mean", "fp_frames"):
        vals = [(m[key], s) for s, m in out.items() if m[key] is not None]
        if not vals:
            worst[key] = None
            continue
        v, s = (max if key in ("ms_mean", "fp_frames") else min)(vals)
        worst[key], where[key] = v, s
    worst["worst_source"] = where
    out["all"] = metrics(results, iou_threshold, score_threshold).to_dict()
    out["worst"] = worst
    return out


class _Detector(Protocol):
    def detect(self, frame_bgr: np.ndarray, frame: int = 0) -> list[Any]: ...


def run_detector(
    detector: _Detector,
    frames: Iterable[tuple[str, str, np.ndarray, np.ndarray, Sequence[int]]],
) -> list[FrameResult]:
    """Run a light detector on ``(source, key, BGR image, gt boxes, gt vehicles)`` frames, timing each
    ``detect`` call; returns one :class:`FrameResult` per frame."""
    out = []
    for source, key, img, gt, veh in frames:
        t0 = time.perf_counter()
        dets = detector.detect(img, 0)
        ms = (time.perf_counter() - t0) * 1000.0
        boxes = np.array([[d.box.x1, d.box.y1, d.box.x2, d.box.y2] for d in dets], np.float64).reshape(-1, 4)
        scores = np.array([d.score for d in dets], np.float64)
        colours = [d.colour for d in dets]
        out.append(FrameResult(source, key, _boxes(gt), list(veh), boxes, scores, ms, colours))
    return out


def evaluate_frames(results: Sequence[FrameResult]) -> dict[str, dict[str, Any]]:
    """:func:`summarise` with the default IoU threshold 0.5 (the benchmark's entry)."""
    return summarise(results)


def _size_bin(side: float) -> str:
    for lim in (4, 8, 16, 32):
        if side < lim:
            return f"<{lim}px"
    return ">=32px"


def false_positive_breakdown(
    results: Sequence[FrameResult], iou_threshold: float = 0.5, score_threshold: float = 0.0
) -> dict[str, dict[str, int]]:
    """Where the false positives at ``score_threshold`` come from, counted per category:

    * ``colour``: the detection's colour (``?`` when the results carry none);
    * ``size``: the longer side of its box (<4, <8, <16, <32, ≥32 px);
    * ``where``: ``near miss`` (IoU 0.3–0.5 with a labelled lamp: box-size disagreement),
      ``on a labelled lamp`` (IoU < 0.3 but ≥ half of the smaller box inside a labelled lamp's:
      a glow or part box), ``near the EV`` (centre inside the vehicle region of the vehicle-level
      count: the bounding box of one vehicle's lamps grown by half its size — the EV's head, tail
      and sign lights, reflections on its body), ``negative frame`` (a frame without any labelled
      lamp), ``elsewhere`` (other cars' lights, street lamps, reflections away from the EV);
    * ``near_miss_on_missed_lamp``: near misses on a labelled lamp no detection matched (what a box
      fix could turn into a true positive), under ``where``.
    """
    out: dict[str, dict[str, int]] = {"colour": {}, "size": {}, "where": {}}

    def bump(cat: str, key: str) -> None:
        out[cat][key] = out[cat].get(key, 0) + 1

    for r in results:
        sc = np.asarray(r.scores, np.float64).ravel()
        keep = np.flatnonzero(sc >= score_threshold)
        boxes, scores = _boxes(r.boxes)[keep], sc[keep]
        colours = [r.colours[int(i)] for i in keep] if len(r.colours) == len(sc) else ["?"] * len(keep)
        gt = _boxes(r.gt_boxes)
        match = match_frame(boxes, scores, gt, iou_threshold)
        matched = set(match[match >= 0].tolist())
        regions = vehicle_regions(gt, list(r.gt_vehicles)) if len(gt) else {}
        iou = box_iou_matrix(boxes, gt) if len(gt) and len(boxes) else np.zeros((len(boxes), 0))
        for d in np.flatnonzero(match < 0):
            b = boxes[d]
            bump("colour", colours[d])
            bump("size", _size_bin(float(max(b[2] - b[0], b[3] - b[1]))))
            if not len(gt):
                bump("where", "negative frame")
                continue
            j = int(np.argmax(iou[d]))
            if iou[d, j] >= 0.3:
                bump("where", "near miss")
                if j not in matched:
                    bump("where", "near_miss_on_missed_lamp")
                continue
            iw = np.clip(np.minimum(b[2], gt[:, 2]) - np.maximum(b[0], gt[:, 0]), 0, None)
            ih = np.clip(np.minimum(b[3], gt[:, 3]) - np.maximum(b[1], gt[:, 1]), 0, None)
            small = np.minimum(
                max(1e-9, (b[2] - b[0]) * (b[3] - b[1])), (gt[:, 2] - gt[:, 0]) * (gt[:, 3] - gt[:, 1])
            )
            if np.max(iw * ih / np.maximum(small, 1e-9)) >= 0.5:
                bump("where", "on a labelled lamp")
                continue
            cx, cy = (b[0] + b[2]) / 2, (b[1] + b[3]) / 2
            inside = any(q[0] <= cx <= q[2] and q[1] <= cy <= q[3] for q in regions.values())
            bump("where", "near the EV" if inside else "elsewhere")
    return out
