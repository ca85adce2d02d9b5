"""Where an emergency vehicle is relative to the ego and its road (SPEC §7 fusion; used by the
yield decision, SPEC §6)."""

from __future__ import annotations

import math

from makeway.messages import EVRelation


def classify_relation(
    rel_x: float, rel_y: float, rel_heading: float, *, same_road_half_width_m: float = 6.0
) -> EVRelation:
    """Where an EV is relative to the ego: from its position in the ego frame and its heading.

    Same direction (|Δheading| < 45°): behind or ahead by the sign of ``rel_x``. Opposite direction
    (|Δheading| > 135°) and ahead: oncoming (behind and opposite: it has gone, called AHEAD-like
    "receding" by the caller through ``approaching``). Otherwise crossing.
    """
    d = math.atan2(math.sin(rel_heading), math.cos(rel_heading))
    if abs(d) < math.radians(45):
        return EVRelation.BEHIND if rel_x < 0 else EVRelation.AHEAD
    if abs(d) > math.radians(135):
        return EVRelation.ONCOMING if rel_x > 0 else EVRelation.BEHIND
    if abs(rel_y) < same_road_half_width_m and abs(rel_x) < 10.0:
        return EVRelation.UNKNOWN
    return EVRelation.CROSSING
