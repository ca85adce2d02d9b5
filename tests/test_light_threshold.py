"""Choosing the verifier's operating threshold by grouped cross-validation over the training sources:
photo copies and clips stay in one fold, out-of-fold scores come from models that never saw the
group, and the threshold maximises min(precision, recall) of the full detector."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import require_module
from makeway.eval.lights import FrameResult
from makeway.train.light_verifier import (
    THRESHOLDS,
    choose_threshold,
    detector_results,
    frame_group,
    grouped_folds,
    out_of_fold,
)


def test_frame_groups_keep_photo_copies_and_clips_together() -> None:
    a = frame_group("ambulance_yolo", "valid/images/0002_jpg.rf.c61edce7.jpg")
    b = frame_group("ambulance_yolo", "0002_jpg.rf.ffff0000.jpg")
    c = frame_group("ambulance_yolo", "0003_jpg.rf.c61edce7.jpg")
    assert a == b != c
    assert frame_group("fire_trucks_red_lights", "12") == frame_group("fire_trucks_red_lights", "300")


def test_grouped_folds_are_balanced_and_never_split_a_group() -> None:
    groups = ["clip"] * 50 + [f"photo{i // 2}" for i in range(60)] + ["other"] * 20
    fold = grouped_folds(groups, 4)
    assert set(fold.tolist()) == {0, 1, 2, 3}
    for g in set(groups):
        assert len(set(fold[[i for i, x in enumerate(groups) if x == g]].tolist())) == 1
    sizes = np.bincount(fold)
    assert sizes.max() == 50 and sizes.min() >= 20  # the big clip alone; photos spread over the rest
    assert np.array_equal(fold, grouped_folds(groups, 4))  # deterministic
    with pytest.raises(ValueError, match="groups cannot fill"):
        grouped_folds(["a", "a", "b"], 3)


def _rows(n_frames: int, rng: np.random.Generator) -> tuple[dict, np.ndarray]:
    """Synthetic verifier rows: per frame 1 true lamp proposal and 9 others; feature 0 separates
    them with noise. Returns the rows and the true-lamp flags."""
    xs, ys, fr, boxes, frames = [], [], [], [], []
    for k in range(n_frames):
        gt = np.array([[10.0, 10.0, 20.0, 20.0]])
        b = np.array([[10, 10, 20, 20], *[[40 + 12 * j, 40, 50 + 12 * j, 50] for j in range(9)]], float)
        y = np.array([True] + [False] * 9)
        x = rng.normal(size=(10, 3)).astype(np.float32)
        x[:, 0] += 3.5 * y
        xs.append(x)
        ys.append(y)
        fr.append(np.full(10, k))
        boxes.append(b)
        src = "clip" if k < n_frames // 3 else "ambulance_yolo"
        frames.append((src, f"{k // 2}_jpg.rf.{k}.jpg", gt, [1]))
    frame = np.concatenate(fr)
    rows = {
        "x": np.concatenate(xs),
        "y": np.concatenate(ys),
        "frame": frame,
        "origin": frame.copy(),
        "frames": frames,
        "boxes": boxes,
    }
    return rows, rows["y"]


def test_out_of_fold_scores_and_the_threshold_they_choose() -> None:
    require_module("xgboost")
    rows, y = _rows(60, np.random.default_rng(0))
    oof = out_of_fold(rows, 3, threads=1)
    assert oof.shape == y.shape and np.all((oof >= 0) & (oof <= 1))
    # out-of-fold scores still rank true lamps above the rest (the signal is real, not memorised)
    assert oof[y].mean() > oof[~y].mean() + 0.4
    t, score = choose_threshold(lambda t: detector_results(rows, oof, t))
    assert t in THRESHOLDS and t > THRESHOLDS[0]  # every proposal kept is not the best trade-off
    assert score > 0.7


def test_choose_threshold_prefers_balance_and_breaks_ties_low() -> None:
    gt = np.array([[0.0, 0.0, 10.0, 10.0], [20.0, 0.0, 30.0, 10.0]])
    # two true detections scoring 0.9 and 0.6, one false at 0.3: threshold 0.35–0.6 gives P = R = 1
    boxes = np.array([[0, 0, 10, 10], [20, 0, 30, 10], [50, 50, 60, 60]], float)
    scores = np.array([0.9, 0.6, 0.3])

    def at(t: float) -> list[FrameResult]:
        keep = scores >= t
        return [FrameResult("s", "0", gt, [1, 1], boxes[keep], scores[keep])]

    t, score = choose_threshold(at)
    assert score == 1.0 and t == 0.35  # the lowest candidate above the false box's 0.3
    # no true positive anywhere: the lowest candidate, score 0
    t0, s0 = choose_threshold(lambda t: [FrameResult("s", "0", gt, [1, 1], boxes[2:], scores[2:])])
    assert t0 == THRESHOLDS[0] and s0 == 0.0
