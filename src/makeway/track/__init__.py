"""Tracking stage: SORT on 2D boxes and the per-track output smoother (SPEC §1–2); a siren's range
from its bearings against the car's own motion (:mod:`makeway.track.bearings_only`, measured, not in
the shipped path)."""

from makeway.track.smoother import TrackSmoother
from makeway.track.sort import Sort, associate, iou_matrix

__all__ = ["Sort", "TrackSmoother", "associate", "iou_matrix"]
