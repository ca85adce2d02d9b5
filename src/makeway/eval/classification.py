"""Binary classification metrics for per-frame and per-actor EV judgements (SPEC §1).

``precision_recall_f1`` from counts; ``threshold_metrics`` sweeps the decision threshold over the
scores and reports the SPEC's headline numbers: max-F1 over thresholds (and where it is reached) and
precision at recall 0.8 (the best precision among thresholds whose recall is at least 0.8).
``pr_curve`` gives the precision–recall points behind them (plotted by
:func:`makeway.viz.pr_plot.plot_pr_curve`). Undefined values (no positives, no predictions) are
NaN, not 0, so that they cannot pass for a score.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def precision_recall_f1(tp: int, fp: int, fn: int) -> dict[str, Any]:
    """Precision, recall and F1 from counts (with the counts echoed)."""
    p = tp / (tp + fp) if tp + fp else float("nan")
    r = tp / (tp + fn) if tp + fn else float("nan")
    if tp and p + r > 0:
        f1 = 2 * p * r / (p + r)
    else:
        f1 = 0.0 if (tp + fp) and (tp + fn) else float("nan")
    return {"precision": p, "recall": r, "f1": f1, "tp": tp, "fp": fp, "fn": fn}


def threshold_metrics(scores: np.ndarray, labels: np.ndarray, recall_at: float = 0.8) -> dict[str, float]:
    """Max-F1 over thresholds, its threshold, and the best precision at recall ≥ ``recall_at``.

    Thresholds are cut only between distinct scores (a tie is never split).
    """
    scores = np.asarray(scores, dtype=np.float64).ravel()
    labels = np.asarray(labels).astype(bool).ravel()
    if scores.shape != labels.shape:
        raise ValueError(f"{scores.size} scores but {labels.size} labels")
    key = f"precision_at_recall_{recall_at:g}"
    n_pos = int(labels.sum())
    if n_pos == 0 or scores.size == 0:
        return {"max_f1": float("nan"), "max_f1_threshold": float("nan"), key: float("nan")}
    order = np.argsort(-scores, kind="stable")
    s, y = scores[order], labels[order]
    tp = np.cumsum(y)
    fp = np.cumsum(~y)
    last = np.r_[np.flatnonzero(np.diff(s)), len(s) - 1]
    tp, fp, thr = tp[last], fp[last], s[last]
    precision = tp / (tp + fp)
    recall = tp / n_pos
    denom = precision + recall
    f1 = np.where(denom > 0, 2 * precision * recall / np.maximum(denom, 1e-12), 0.0)
    best = int(np.argmax(f1))
    at = precision[recall >= recall_at]
    return {
        "max_f1": float(f1[best]),
        "max_f1_threshold": float(thr[best]),
        key: float(at.max()) if at.size else float("nan"),
    }


def pr_curve(scores: np.ndarray, labels: np.ndarray) -> dict[str, np.ndarray]:
    """Precision–recall points, one per distinct score used as the threshold (``score >= t``).

    Returns arrays ``precision``, ``recall`` and ``threshold`` in order of decreasing threshold
    (increasing recall); empty when there are no positives or no scores.
    """
    scores = np.asarray(scores, dtype=np.float64).ravel()
    labels = np.asarray(labels).astype(bool).ravel()
    if scores.shape != labels.shape:
        raise ValueError(f"{scores.size} scores but {labels.size} labels")
    n_pos = int(labels.sum())
    if n_pos == 0 or scores.size == 0:
        empty = np.empty(0, dtype=np.float64)
        return {"precision": empty, "recall": empty.copy(), "threshold": empty.copy()}
    order = np.argsort(-scores, kind="stable")
    s, y = scores[order], labels[order]
    last = np.r_[np.flatnonzero(np.diff(s)), len(s) - 1]
    tp = np.cumsum(y)[last].astype(np.float64)
    fp = np.cumsum(~y)[last].astype(np.float64)
    return {"precision": tp / (tp + fp), "recall": tp / n_pos, "threshold": s[last]}


def operating_point_metrics(probs: np.ndarray, labels: np.ndarray, threshold: float) -> dict[str, Any]:
    """A classifier's scores at its decision ``threshold`` (a probability is an EV at or above it):
    ``accuracy``, ``precision``, ``recall``, ``f1``, and over all thresholds ``max_f1`` and ``p_at_r80``
    (precision at recall 0.8), rounded to 4 digits; ``n`` crops."""
    y = np.asarray(labels).astype(bool)
    pred = np.asarray(probs) >= threshold
    prf = precision_recall_f1(int(np.sum(pred & y)), int(np.sum(pred & ~y)), int(np.sum(~pred & y)))
    thr = threshold_metrics(probs, y, recall_at=0.8)
    return {
        "accuracy": round(float(np.mean(pred == y)), 4),
        "precision": round(float(prf["precision"]), 4),
        "recall": round(float(prf["recall"]), 4),
        "f1": round(float(prf["f1"]), 4),
        "max_f1": round(float(thr["max_f1"]), 4),
        "p_at_r80": round(float(thr["precision_at_recall_0.8"]), 4),
        "n": int(len(y)),
    }
