"""Planning: reference paths for the pull-over manoeuvre and the local curve fit (SPEC §6).

:mod:`makeway.plan.path` builds roads, lateral offsets and the pull-over path (clear of
intersections, with its stop point); :mod:`makeway.plan.curvefit` fits a line or circle to the path
points near the vehicle and measures the tracking errors against it.
"""

from makeway.plan.curvefit import (
    ArcFit,
    LineFit,
    fit_circle,
    fit_local,
    nearest_point,
    tracking_errors,
    window,
    wrap_angle,
)
from makeway.plan.path import (
    MIN_TRANSITION_M,
    curved_road,
    lateral_offsets,
    load_path_csv,
    make_path,
    min_transition_m,
    nearest_index,
    offset_path,
    point_at,
    pull_over_path,
    save_path_csv,
    straight_road,
)

__all__ = [
    "MIN_TRANSITION_M",
    "ArcFit",
    "LineFit",
    "curved_road",
    "fit_circle",
    "fit_local",
    "lateral_offsets",
    "load_path_csv",
    "make_path",
    "min_transition_m",
    "nearest_index",
    "nearest_point",
    "offset_path",
    "point_at",
    "pull_over_path",
    "save_path_csv",
    "straight_road",
    "tracking_errors",
    "window",
    "wrap_angle",
]
