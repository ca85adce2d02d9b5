"""Object-detection metrics on image sets: AP at an IoU threshold, mAP50, mAP50:95, and precision /
recall of a chosen set of detections.

Boxes are ``(n, 4)`` arrays ``x1, y1, x2, y2`` in image pixels (any consistent unit); one entry per
image in every list argument. IoU is area-based on continuous coordinates (no ``+1`` pixel
convention).

**Matching** (COCO's rule): per class, all detections of the set are taken in descending score order
(ties keep their input order); each is matched to the not yet matched ground-truth box of its image
with the highest IoU, if that IoU is at least the threshold (true positive), else it is a false
positive. Each ground-truth box is matched at most once. Taking detections in score order makes the
matches of the detections above any score threshold independent of those below it.

**AP** is the area under the precision–recall curve with all-point interpolation (PASCAL VOC 2010
on): precision is replaced by its running maximum from the right (the best precision at this
recall or higher), and the area is summed over the recall steps. COCO's tool samples that
envelope at 101 recall points instead (and keeps at most 100 detections per image), which moves AP
by up to about 0.01.
A class without ground-truth boxes has no AP (``nan``) and is left out of the mean.

**mAP50** is the mean over classes of AP at IoU 0.5; **mAP50:95** the mean of mAP over the IoU
thresholds 0.50, 0.55, …, 0.95.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "COCO_IOU_THRESHOLDS",
    "DetectionMetrics",
    "average_precision",
    "box_iou_matrix",
    "detection_metrics",
    "match_detections",
    "precision_recall",
]

#: IoU thresholds of mAP50:95 (COCO): 0.50, 0.55, …, 0.95.
COCO_IOU_THRESHOLDS: tuple[float, ...] = tuple(round(0.5 + 0.05 * k, 2) for k in range(10))


def _as_boxes(boxes: np.ndarray | Sequence[Sequence[float]]) -> np.ndarray:
    arr = np.asarray(boxes, dtype=np.float64)
    if arr.size == 0:
        return np.zeros((0, 4), dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 4:
        raise ValueError(f"boxes must be (n, 4) x1, y1, x2, y2; got shape {arr.shape}")
    return arr


def box_iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU ``(n, m)`` of every box of ``a`` ``(n, 4)`` with every box of ``b`` ``(m, 4)`` (xyxy).

    Boxes with no area have IoU 0 with everything."""
    a, b = _as_boxes(a), _as_boxes(b)
    iw = np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0])
    ih = np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1])
    inter = np.clip(iw, 0.0, None) * np.clip(ih, 0.0, None)
    area_a = np.clip(a[:, 2] - a[:, 0], 0.0, None) * np.clip(a[:, 3] - a[:, 1], 0.0, None)
    area_b = np.clip(b[:, 2] - b[:, 0], 0.0, None) * np.clip(b[:, 3] - b[:, 1], 0.0, None)
    union = area_a[:, None] + area_b[None, :] - inter
    out: np.ndarray = np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)
    return out


def _check_lengths(pred_boxes: Sequence[object], pred_scores: Sequence[object], gt: Sequence[object]) -> None:
    if not len(pred_boxes) == len(pred_scores) == len(gt):
        raise ValueError(
            f"one entry per image expected: {len(pred_boxes)} box arrays, {len(pred_scores)} score "
            f"arrays, {len(gt)} ground-truth arrays"
        )


def match_detections(
    pred_boxes: Sequence[np.ndarray],
    pred_scores: Sequence[np.ndarray],
    gt_boxes: Sequence[np.ndarray],
    iou_thresholds: Sequence[float] = (0.5,),
) -> tuple[np.ndarray, np.ndarray]:
    """Match the detections of a set of images (one class) to its ground truth (module docstring).

    Args:
        pred_boxes: per image, the detections ``(n_i, 4)``.
        pred_scores: per image, their scores ``(n_i,)``.
        gt_boxes: per image, the ground-truth boxes ``(m_i, 4)``.
        iou_thresholds: the IoU thresholds to match at (each matched independently).

    Returns:
        ``scores`` ``(N,)`` of all detections in descending order (stable) and ``tp`` ``(T, N)`` bool:
        whether each of them is a true positive at each threshold.
    """
    _check_lengths(pred_boxes, pred_scores, gt_boxes)
    thresholds = np.asarray(iou_thresholds, dtype=np.float64)
    image_of: list[np.ndarray] = []
    row_of: list[np.ndarray] = []
    scores: list[np.ndarray] = []
    ious: list[np.ndarray] = []
    for i, (boxes, s, gt) in enumerate(zip(pred_boxes, pred_scores, gt_boxes, strict=True)):
        b = _as_boxes(boxes)
        s = np.asarray(s, dtype=np.float64).ravel()
        if len(s) != len(b):
            raise ValueError(f"image {i}: {len(b)} boxes but {len(s)} scores")
        ious.append(box_iou_matrix(b, gt))
        image_of.append(np.full(len(b), i, dtype=np.int64))
        row_of.append(np.arange(len(b), dtype=np.int64))
        scores.append(s)
    all_scores = np.concatenate(scores) if scores else np.zeros(0)
    images = np.concatenate(image_of) if image_of else np.zeros(0, dtype=np.int64)
    rows = np.concatenate(row_of) if row_of else np.zeros(0, dtype=np.int64)
    order = np.argsort(-all_scores, kind="stable")
    tp = np.zeros((len(thresholds), len(order)), dtype=bool)
    matched = [[np.zeros(ious[i].shape[1], dtype=bool) for i in range(len(ious))] for _ in thresholds]
    for k, d in enumerate(order):
        img, row = images[d], rows[d]
        iou_row = ious[img][row]
        if iou_row.size == 0:
            continue
        for t, thr in enumerate(thresholds):
            free = np.where(matched[t][img], -1.0, iou_row)
            best = int(np.argmax(free))
            if free[best] >= thr:
                matched[t][img][best] = True
                tp[t, k] = True
    return all_scores[order], tp


def average_precision(tp: np.ndarray, n_gt: int) -> float:
    """All-point interpolated AP of detections in descending score order (``tp`` ``(N,)`` bool) against
    ``n_gt`` ground-truth boxes; ``nan`` when ``n_gt`` is 0 (module docstring)."""
    if n_gt <= 0:
        return float("nan")
    hits = np.asarray(tp, dtype=np.float64).ravel()
    if hits.size == 0:
        return 0.0
    ctp = np.cumsum(hits)
    recall = ctp / n_gt
    precision = ctp / np.arange(1, len(hits) + 1)
    mrec = np.concatenate([[0.0], recall, [1.0]])
    mpre = np.concatenate([[0.0], precision, [0.0]])
    mpre = np.maximum.accumulate(mpre[::-1])[::-1]
    steps = np.flatnonzero(mrec[1:] != mrec[:-1])
    return float(np.sum((mrec[steps + 1] - mrec[steps]) * mpre[steps + 1]))


def precision_recall(
    pred_boxes: Sequence[np.ndarray],
    pred_scores: Sequence[np.ndarray],
    gt_boxes: Sequence[np.ndarray],
    *,
    iou_threshold: float = 0.5,
    score_threshold: float | None = None,
) -> tuple[float, float, int, int, int]:
    """Precision and recall of a set of detections (one class): ``(precision, recall, tp, n_det, n_gt)``.

    With ``score_threshold``, only detections scoring at least that count; otherwise all given ones
    (filter them first for an operating point that is not a threshold on the ranking score). Matching
    as in :func:`match_detections`. Precision is ``nan`` without detections, recall ``nan`` without
    ground truth.
    """
    _check_lengths(pred_boxes, pred_scores, gt_boxes)
    if score_threshold is not None:
        keep = [np.asarray(s, dtype=np.float64).ravel() >= score_threshold for s in pred_scores]
        pred_boxes = [_as_boxes(b)[k] for b, k in zip(pred_boxes, keep, strict=True)]
        pred_scores = [
            np.asarray(s, dtype=np.float64).ravel()[k] for s, k in zip(pred_scores, keep, strict=True)
        ]
    scores, tp = match_detections(pred_boxes, pred_scores, gt_boxes, (iou_threshold,))
    n_gt = int(sum(len(_as_boxes(g)) for g in gt_boxes))
    n_tp, n_det = int(tp[0].sum()), len(scores)
    precision = n_tp / n_det if n_det else float("nan")
    recall = n_tp / n_gt if n_gt else float("nan")
    return precision, recall, n_tp, n_det, n_gt


@dataclass(frozen=True)
class DetectionMetrics:
    """Metrics of detections against ground truth over a set of images.

    ``ap50`` and ``ap50_95`` map each class id to its AP at IoU 0.5 and its mean AP over
    :data:`COCO_IOU_THRESHOLDS` (``nan`` for a class without ground truth); ``map50`` and
    ``map50_95`` are their means over the classes with ground truth. ``n_boxes`` and
    ``n_detections`` count ground-truth boxes and detections of the scored classes.
    """

    map50: float
    map50_95: float
    ap50: dict[int, float]
    ap50_95: dict[int, float]
    n_images: int
    n_boxes: int
    n_detections: int


def _of_class(values: Sequence[np.ndarray], classes: Sequence[np.ndarray] | None, c: int) -> list[np.ndarray]:
    if classes is None:
        return [np.asarray(v) for v in values]
    return [np.asarray(v)[np.asarray(k).ravel() == c] for v, k in zip(values, classes, strict=True)]


def detection_metrics(
    pred_boxes: Sequence[np.ndarray],
    pred_scores: Sequence[np.ndarray],
    gt_boxes: Sequence[np.ndarray],
    *,
    pred_classes: Sequence[np.ndarray] | None = None,
    gt_classes: Sequence[np.ndarray] | None = None,
    classes: Sequence[int] | None = None,
) -> DetectionMetrics:
    """Per-class AP at IoU 0.5 and over IoU 0.50:0.95, and their means (module docstring).

    Without ``pred_classes`` / ``gt_classes`` all boxes are one class (id 0). ``classes`` picks the
    class ids to score (default: every id seen in the ground truth or the detections).
    """
    _check_lengths(pred_boxes, pred_scores, gt_boxes)
    if (pred_classes is None) != (gt_classes is None):
        raise ValueError("give class ids for both the detections and the ground truth, or for neither")
    if classes is None:
        if pred_classes is None or gt_classes is None:
            classes = [0]
        else:
            seen = [np.asarray(k).ravel() for k in (*pred_classes, *gt_classes)]
            classes = sorted({int(c) for k in seen for c in k.tolist()})
    ap50: dict[int, float] = {}
    ap50_95: dict[int, float] = {}
    n_boxes = n_det = 0
    for c in classes:
        boxes_c = _of_class(pred_boxes, pred_classes, c)
        scores_c = _of_class(pred_scores, pred_classes, c)
        gt_c = _of_class(gt_boxes, gt_classes, c)
        n_gt = int(sum(len(_as_boxes(g)) for g in gt_c))
        _, tp = match_detections(boxes_c, scores_c, gt_c, COCO_IOU_THRESHOLDS)
        aps = np.array([average_precision(row, n_gt) for row in tp])
        ap50[int(c)] = float(aps[0])
        ap50_95[int(c)] = float(aps.mean()) if n_gt else float("nan")
        n_boxes += n_gt
        n_det += tp.shape[1]
    scored = [c for c in ap50 if np.isfinite(ap50[c])]
    return DetectionMetrics(
        map50=float(np.mean([ap50[c] for c in scored])) if scored else float("nan"),
        map50_95=float(np.mean([ap50_95[c] for c in scored])) if scored else float("nan"),
        ap50=ap50,
        ap50_95=ap50_95,
        n_images=len(gt_boxes),
        n_boxes=n_boxes,
        n_detections=n_det,
    )
