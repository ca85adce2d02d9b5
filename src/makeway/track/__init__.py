"""Tracking stage: SORT on 2D boxes and the per-track output smoother (SPEC §1–2)."""

from makeway.track.smoother import TrackSmoother
from makeway.track.sort import Sort, associate, iou_matrix

__all__ = ["Sort", "TrackSmoother", "associate", "iou_matrix"]
