"""From yield decisions to reference paths (SPEC §6: move to the right edge, clear of intersections, stop).

:class:`YieldPlanner` keeps the path the controllers follow. It replans only when the decision asks
for something new — entering the pull-over, stopping in lane before an intersection, or resuming — so
the controllers track one smooth, curvature-continuous path per manoeuvre rather than a path that
jumps every cycle. A stop in lane whose stop point the decision moves (a re-planned yield) keeps the
lane and takes the new stop point.
"""

from __future__ import annotations

from collections.abc import Sequence

from makeway.messages import ReferencePath, YieldDecision, YieldState
from makeway.plan.path import min_transition_m, nearest_index, offset_path, pull_over_path


class YieldPlanner:
    """Holds the active reference path and replans it on new yield decisions.

    Args:
        lane: the ego lane's centre line (direction of travel).
        right_edge_offset_m: lateral offset of the stopping position from the lane centre (negative:
            right).
        intersections: ``(s_start, s_end)`` intervals of the lane inside intersections.
        max_lat_accel: comfort limit used to size the lane change (m/s²).
        reaction_s: the manoeuvre starts this far ahead in time of the decision (actuation delay).
    """

    def __init__(
        self,
        lane: ReferencePath,
        *,
        right_edge_offset_m: float,
        intersections: Sequence[tuple[float, float]] = (),
        max_lat_accel: float = 1.5,
        reaction_s: float = 0.2,
    ) -> None:
        self.lane = lane
        self.right_edge_offset_m = right_edge_offset_m
        self.intersections = tuple(intersections)
        self.max_lat_accel = max_lat_accel
        self.reaction_s = reaction_s
        self.path = lane
        self.offset_m = 0.0  # lateral offset the active path ends at
        self.replans: list[tuple[float, str]] = []
        self._mode = "lane"

    def lane_s(self, x: float, y: float, hint: int | None = None) -> tuple[float, int]:
        """Arc length of the ego's projection on the lane (for the map and the decision)."""
        k = nearest_index(self.lane, x, y, hint)
        return float(self.lane.s_m[k]), k

    def update(self, decision: YieldDecision, *, x: float, y: float, speed_mps: float) -> ReferencePath:
        """The path to follow after ``decision``; a new one only when the manoeuvre changes."""
        lane_s, _ = self.lane_s(x, y)
        start = lane_s + max(speed_mps, 1.0) * self.reaction_s
        state = decision.state
        if state in (YieldState.MOVING_OVER, YieldState.EV_CONFIRMED) and decision.stop_s_m is not None:
            if decision.pull_over and self._mode != "pull_over":
                transition = min_transition_m(
                    max(speed_mps, 5.0), self.right_edge_offset_m, self.max_lat_accel
                )
                self.path = pull_over_path(
                    self.lane,
                    start_s_m=start,
                    offset_m=self.right_edge_offset_m,
                    transition_m=transition,
                    stop_s_m=decision.stop_s_m,
                    intersections=self.intersections,
                )
                self.offset_m = self.right_edge_offset_m
                self._mode = "pull_over"
                self.replans.append((decision.time_s, "pull_over"))
            elif not decision.pull_over and (
                self._mode == "lane"
                or (self._mode == "stop_in_lane" and decision.stop_s_m != self.path.stop_s_m)
            ):
                self.path = ReferencePath(
                    self.lane.x_m,
                    self.lane.y_m,
                    self.lane.s_m,
                    self.lane.heading_rad,
                    self.lane.curvature_1pm,
                    stop_s_m=decision.stop_s_m,
                )
                self._mode = "stop_in_lane"
                self.replans.append((decision.time_s, "stop_in_lane"))
        elif state in (YieldState.RESUMING, YieldState.NO_EV) and self._mode != "lane":
            if self.offset_m != 0.0:
                side = offset_path(self.lane, self.offset_m)
                # sized for the speed it will reach on the way back, not the standstill it starts from
                back = max(speed_mps, decision.target_speed_mps, 5.0)
                transition = min_transition_m(back, -self.offset_m, self.max_lat_accel)
                self.path = pull_over_path(
                    side,
                    start_s_m=float(side.s_m[nearest_index(side, x, y)]) + 2.0,
                    offset_m=-self.offset_m,
                    transition_m=transition,
                    stop_s_m=None,
                )
            else:
                self.path = self.lane
            self.offset_m = 0.0
            self._mode = "lane"
            self.replans.append((decision.time_s, "resume"))
        return self.path

    def distance_to_stop(self, x: float, y: float, hint: int | None = None) -> float | None:
        """Distance along the active path from the ego to its stop point (``None``: no stop)."""
        if self.path.stop_s_m is None or self._mode == "lane":
            return None
        k = nearest_index(self.path, x, y, hint)
        return float(self.path.stop_s_m - self.path.s_m[k])
