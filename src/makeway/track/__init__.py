"""Tracking stage: SORT on 2D boxes and the per-track output smoother (SPEC §1–2)."""

from makeway.track.smoother import SMOOTH_AVERAGES, StreamSmoother, TrackSmoother
from makeway.track.sort import Sort, associate, iou_matrix

__all__ = ["SMOOTH_AVERAGES", "Sort", "StreamSmoother", "TrackSmoother", "associate", "iou_matrix"]
