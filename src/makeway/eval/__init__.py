"""Metrics and report writers."""

from makeway.eval.mot import MotCounts, combine, evaluate_mot

__all__ = ["MotCounts", "combine", "evaluate_mot"]
