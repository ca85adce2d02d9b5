"""Metrics: tracking (CLEAR MOT, IDF1), classification, closed-loop runs, siren recordings
(labels and scores), per-actor EV metrics on real clips.

Nothing here runs a pipeline; the pipelines and apps call these to score what they produced.
"""

from makeway.eval.classification import precision_recall_f1, threshold_metrics
from makeway.eval.closed_loop import compute_metrics
from makeway.eval.mot import MotCounts, combine, evaluate_mot

__all__ = [
    "MotCounts",
    "combine",
    "compute_metrics",
    "evaluate_mot",
    "precision_recall_f1",
    "threshold_metrics",
]
