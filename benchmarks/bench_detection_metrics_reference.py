"""Agreement of :mod:`makeway.eval.detection` with reference implementations of COCO mAP.

On seeded synthetic image sets (ground-truth boxes, jittered detections of some of them, spurious
boxes, random scores) it prints makeway's mAP50 and mAP50:95 beside those of ``pycocotools``
(``COCOeval``) and ``torchmetrics`` (``MeanAveragePrecision``, class-agnostic), whichever are
installed; neither is a dependency of makeway, so a missing one is reported and left out.

Expected differences: COCO samples the precision envelope at 101 recall points where makeway
integrates it exactly (all-point, VOC 2010), so mAP may differ by up to about 0.01; matching is the
same rule (score order, best free ground-truth box). Sets stay under COCO's 100 detections per
image, and every box is given area-range "all".

    .venv/bin/python benchmarks/bench_detection_metrics_reference.py [--sets 5] [--images 40]
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

import numpy as np

from makeway.eval.detection import detection_metrics


def synthetic_set(rng: np.random.Generator, n_images: int) -> tuple[list[np.ndarray], ...]:
    """``(pred_boxes, pred_scores, gt_boxes)`` per image, xyxy pixels in a 640×640 image."""
    preds, scores, gts = [], [], []
    for _ in range(n_images):
        m = int(rng.integers(0, 6))
        xy = rng.uniform(0, 500, size=(m, 2))
        wh = rng.uniform(20, 140, size=(m, 2))
        gt = np.concatenate([xy, xy + wh], axis=1)
        found = gt[rng.random(m) < 0.8]
        jitter = rng.normal(0.0, 0.08, size=found.shape) * np.repeat(found[:, 2:] - found[:, :2], 2, axis=1)
        n_fp = int(rng.integers(0, 4))
        fxy = rng.uniform(0, 500, size=(n_fp, 2))
        fp = np.concatenate([fxy, fxy + rng.uniform(20, 140, size=(n_fp, 2))], axis=1)
        det = np.concatenate([found + jitter, fp]).clip(0, 640)
        good = (det[:, 2] > det[:, 0] + 1) & (det[:, 3] > det[:, 1] + 1)
        det = det[good]
        s = np.concatenate([rng.uniform(0.3, 1.0, len(found)), rng.uniform(0.0, 0.8, n_fp)])[good]
        preds.append(det)
        scores.append(s)
        gts.append(gt)
    return preds, scores, gts


def with_pycocotools(preds: list[np.ndarray], scores: list[np.ndarray], gts: list[np.ndarray]) -> Any:
    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    def xywh(b: np.ndarray) -> list[float]:
        return [float(b[0]), float(b[1]), float(b[2] - b[0]), float(b[3] - b[1])]

    images = [{"id": i + 1, "width": 640, "height": 640} for i in range(len(gts))]
    anns = []
    for i, gt in enumerate(gts):
        for b in gt:
            box = xywh(b)
            anns.append(
                {"id": len(anns) + 1, "image_id": i + 1, "category_id": 1, "bbox": box,
                 "area": box[2] * box[3], "iscrowd": 0}
            )  # fmt: skip
    coco_gt = COCO()
    coco_gt.dataset = {"images": images, "annotations": anns, "categories": [{"id": 1, "name": "ev"}]}
    coco_gt.createIndex()
    dets = [
        {"image_id": i + 1, "category_id": 1, "bbox": xywh(b), "score": float(s)}
        for i, (bs, ss) in enumerate(zip(preds, scores, strict=True))
        for b, s in zip(bs, ss, strict=True)
    ]
    coco_dt = coco_gt.loadRes(dets)
    ev = COCOeval(coco_gt, coco_dt, "bbox")
    ev.evaluate()
    ev.accumulate()
    ev.summarize()
    return float(ev.stats[1]), float(ev.stats[0])  # AP50, AP50:95 (area all, 100 dets)


def with_torchmetrics(preds: list[np.ndarray], scores: list[np.ndarray], gts: list[np.ndarray]) -> Any:
    import torch
    from torchmetrics.detection import MeanAveragePrecision

    metric = MeanAveragePrecision(box_format="xyxy", iou_type="bbox")
    metric.update(
        [
            {"boxes": torch.tensor(b, dtype=torch.float32).reshape(-1, 4),
             "scores": torch.tensor(s, dtype=torch.float32),
             "labels": torch.zeros(len(s), dtype=torch.int64)}
            for b, s in zip(preds, scores, strict=True)
        ],
        [
            {"boxes": torch.tensor(g, dtype=torch.float32).reshape(-1, 4),
             "labels": torch.zeros(len(g), dtype=torch.int64)}
            for g in gts
        ],
    )  # fmt: skip
    out = metric.compute()
    return float(out["map_50"]), float(out["map"])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sets", type=int, default=5)
    parser.add_argument("--images", type=int, default=40)
    args = parser.parse_args(argv)
    references = {"pycocotools": with_pycocotools, "torchmetrics": with_torchmetrics}
    worst: float | None = None
    for k in range(args.sets):
        preds, scores, gts = synthetic_set(np.random.default_rng(k), args.images)
        ours = detection_metrics(preds, scores, gts)
        line = f"set {k}: makeway mAP50 {ours.map50:.4f} mAP50:95 {ours.map50_95:.4f}"
        for name, fn in references.items():
            try:
                ap50, ap = fn(preds, scores, gts)
            except ImportError as exc:
                line += f" | {name}: not installed ({exc.name})"
                continue
            worst = max(worst or 0.0, abs(ap50 - ours.map50), abs(ap - ours.map50_95))
            line += f" | {name} {ap50:.4f} {ap:.4f}"
        print(line)
    if worst is None:
        print("no reference implementation installed: nothing compared")
    else:
        print(f"largest difference from a reference: {worst:.4f} (101-point sampling: up to ~0.01 expected)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
