"""MOT metrics (CLEAR MOT, IDF1) on hand-made cases with known answers, and on real MOT15 ground truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from makeway.eval.mot import combine, evaluate_mot
from makeway.sense.motfile import MotData, read_mot


def mot(rows: list[tuple[int, int, float, float, float, float]]) -> MotData:
    a = np.array(rows, dtype=float).reshape(-1, 6)
    order = np.argsort(a[:, 0], kind="stable")
    a = a[order]
    return MotData(a[:, 0].astype(np.int64), a[:, 1].astype(np.int64), a[:, 2:6], np.ones(len(a)))


def test_perfect_tracker(mot15_root: Path) -> None:
    gt = read_mot(mot15_root / "TUD-Campus" / "gt" / "gt.txt", kind="gt")
    c = evaluate_mot(gt, gt)
    assert c.mota == 1.0 and c.idf1 == 1.0 and c.motp == pytest.approx(1.0)
    assert c.fp == c.fn == c.idsw == 0
    assert c.mostly_tracked == c.num_gt_ids and c.mostly_lost == 0


def test_known_counts() -> None:
    # one object over 6 frames; tracker has id 7 for frames 1-3, id 9 for frames 4-6,
    # misses frame 5, and has a false positive far away in frame 2
    gt = mot([(f, 1, 0, 0, 10, 10) for f in range(1, 7)])
    hyp_rows = [(f, 7, 0.5, 0, 10, 10) for f in (1, 2, 3)] + [(4, 9, 0, 0, 10, 10), (6, 9, 0, 0, 10, 10)]
    hyp_rows.append((2, 8, 100, 100, 10, 10))
    c = evaluate_mot(gt, mot(hyp_rows))
    assert (c.tp, c.fp, c.fn, c.idsw) == (5, 1, 1, 1)
    assert c.mota == pytest.approx(1 - (1 + 1 + 1) / 6)
    # identity: gt 1 ↔ hyp 7 (3 frames) is the best one-to-one pairing
    assert c.idtp == 3
    assert c.idf1 == pytest.approx(2 * 3 / (6 + 6))
    iou = 9.5 * 10 / (10 * 10 + 10 * 10 - 9.5 * 10)
    assert c.motp == pytest.approx((3 * iou + 2 * 1.0) / 5)


def test_iou_threshold_is_half() -> None:
    gt = mot([(1, 1, 0, 0, 10, 10)])
    just_in = mot([(1, 1, 3.3, 0, 10, 10)])  # IoU = 6.7 / 13.3 ≈ 0.504
    just_out = mot([(1, 1, 3.4, 0, 10, 10)])
    assert evaluate_mot(gt, just_in).tp == 1
    assert evaluate_mot(gt, just_out).tp == 0


def test_previous_match_is_kept_over_better_iou() -> None:
    # CLEAR MOT: a still-valid pairing from the last frame wins over a fresher, better overlap
    gt = mot([(1, 1, 0, 0, 10, 10), (2, 1, 0, 0, 10, 10)])
    hyp = mot([(1, 5, 1, 0, 10, 10), (2, 5, 2, 0, 10, 10), (2, 6, 0, 0, 10, 10)])
    c = evaluate_mot(gt, hyp)
    assert c.idsw == 0 and c.tp == 2 and c.fp == 1


def test_ignored_gt_rows_and_combine() -> None:
    gt = mot([(1, 1, 0, 0, 10, 10), (1, 2, 50, 50, 10, 10)])
    gt = MotData(gt.frames, gt.ids, gt.xywh, np.array([1.0, 0.0]))  # second row "do not consider"
    hyp = mot([(1, 3, 0, 0, 10, 10)])
    c = evaluate_mot(gt, hyp)
    assert c.num_gt == 1 and c.fn == 0 and c.mota == 1.0
    both = combine([c, c])
    assert both.num_gt == 2 and both.tp == 2 and both.mota == 1.0
    assert set(c.summary()) >= {"mota", "motp", "idf1", "id_switches"}
