"""Where an emergency vehicle is relative to the ego and its road (SPEC §7 fusion; used by the
yield decision, SPEC §6)."""

from __future__ import annotations

import math

from makeway.messages import EVRelation


def classify_relation(
    rel_x: float,
    rel_y: float,
    rel_heading: float,
    *,
    same_road_half_width_m: float = 6.0,
    off_road_ratio: float = 0.4,
    min_curve_radius_m: float = 250.0,
) -> EVRelation:
    """Where an EV is relative to the ego: from its position in the ego frame and its heading.

    Same direction (|Δheading| < 45°): behind or ahead by the sign of ``rel_x``. Opposite direction
    (|Δheading| > 135°) and ahead: oncoming (behind and opposite: it has gone, called AHEAD-like
    "receding" by the caller through ``approaching``). Otherwise crossing.

    Behind, ahead and oncoming need the EV on the ego's road: a road bending away at a radius of
    ``min_curve_radius_m`` or more is ``rel_x²/(2R)`` aside at ``rel_x`` along (3.2 m at 40 m, 20 m
    at 100 m for R = 250 m), and never more than ``off_road_ratio·|rel_x|`` (0.4: 22° off the ego's
    heading, reached 200 m on at R = 250 m). Off to the side by more than
    ``max(same_road_half_width_m, min(same_road_half_width_m + rel_x²/(2R), off_road_ratio·|rel_x|))``,
    an EV "driving along our road" is not on it (a wrong track heading — such as a crossing EV on
    a collision course whose far siren distances were compressed, so that it seems to pace the ego
    — or a road beside ours) and is not placed: ``UNKNOWN``.
    """
    d = math.atan2(math.sin(rel_heading), math.cos(rel_heading))
    bend = same_road_half_width_m + rel_x * rel_x / (2.0 * max(min_curve_radius_m, 1e-6))
    beside = abs(rel_y) > max(same_road_half_width_m, min(bend, off_road_ratio * abs(rel_x)))
    if abs(d) < math.radians(45) or abs(d) > math.radians(135):
        if beside:
            return EVRelation.UNKNOWN
        if abs(d) < math.radians(45):
            return EVRelation.BEHIND if rel_x < 0 else EVRelation.AHEAD
        return EVRelation.ONCOMING if rel_x > 0 else EVRelation.BEHIND
    if abs(rel_y) < same_road_half_width_m and abs(rel_x) < 10.0:
        return EVRelation.UNKNOWN
    return EVRelation.CROSSING
