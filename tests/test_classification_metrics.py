"""Classification metrics (SPEC §1): counts, max-F1 and precision at recall 0.8."""

from __future__ import annotations

import math

import numpy as np
import pytest

from makeway.eval.classification import precision_recall_f1, threshold_metrics


def test_counts() -> None:
    m = precision_recall_f1(8, 2, 4)
    assert m["precision"] == pytest.approx(0.8) and m["recall"] == pytest.approx(8 / 12)
    assert m["f1"] == pytest.approx(2 * 0.8 * (8 / 12) / (0.8 + 8 / 12))
    assert math.isnan(precision_recall_f1(0, 0, 3)["precision"])
    assert precision_recall_f1(0, 2, 3)["f1"] == 0.0


def test_threshold_sweep_by_hand() -> None:
    scores = np.array([0.9, 0.8, 0.7, 0.6, 0.4, 0.3])
    labels = np.array([1, 1, 0, 1, 0, 1])
    m = threshold_metrics(scores, labels)
    # cuts: top1 P1 R.25, top2 P1 R.5, top3 P.67 R.5, top4 P.75 R.75, top5 P.6 R.75, top6 P.67 R1
    # F1 per cut: .4, .667, .571, .75, .667, .8 → the best keeps everything (threshold 0.3)
    assert m["max_f1"] == pytest.approx(0.8) and m["max_f1_threshold"] == pytest.approx(0.3)
    assert m["precision_at_recall_0.8"] == pytest.approx(4 / 6)


def test_ties_are_not_split_and_degenerate_inputs() -> None:
    m = threshold_metrics(np.array([0.5, 0.5]), np.array([1, 0]))
    assert m["max_f1"] == pytest.approx(2 * 0.5 * 1 / 1.5)
    assert math.isnan(threshold_metrics(np.array([0.2]), np.array([0]))["max_f1"])
    with pytest.raises(ValueError, match="2 scores but 1 labels"):
        threshold_metrics(np.array([0.1, 0.2]), np.array([1]))
