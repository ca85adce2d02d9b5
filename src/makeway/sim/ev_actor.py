"""The emergency vehicle of a closed-loop scenario, moving along its planned path."""

from __future__ import annotations

import math

from makeway.plan.path import point_at
from makeway.sim.perception import EVTruth
from makeway.sim.scenarios import EVPlan

__all__ = ["EVActor"]


class EVActor:
    """Moves an :class:`~makeway.sim.scenarios.EVPlan` along its path at the plan's speed profile,
    keeping the plan's minimum gap behind the ego when the ego is ahead in its lane (a simple
    car-following rule: speed = (gap − min gap) / 1.5 s, acceleration within −6…3 m/s²).

    ``ego_width_m`` is the ego's width (m), to tell whether it is in the EV's lane.
    """

    def __init__(self, plan: EVPlan, ego_length_m: float, ego_width_m: float) -> None:
        self.plan = plan
        self.ego_length_m = ego_length_m
        self.ego_width_m = ego_width_m
        self.s = plan.start_s_m
        self.v = plan.speed_mps(0.0)
        self._pose_s = math.nan  # the arc length self._pose is at (the last step's end)
        self._pose = (0.0, 0.0, 0.0)

    def _pose_at_s(self) -> tuple[float, float, float]:
        """``(x, y, heading)`` on the plan's path at ``self.s`` (kept from the last look-up)."""
        if self.s != self._pose_s:
            self._pose = point_at(self.plan.path, self.s)
            self._pose_s = self.s
        return self._pose

    def step(self, t: float, dt: float, ego_x: float, ego_y: float) -> EVTruth:
        """Advance ``dt`` seconds from time ``t`` with the ego's CG at ``(ego_x, ego_y)`` (world, m)."""
        p = self.plan
        want = p.speed_mps(t)
        x, y, h = self._pose_at_s()
        # the ego in the EV's lane ahead of it: keep the gap (a simple car-following rule)
        dx, dy = ego_x - x, ego_y - y
        along = dx * math.cos(h) + dy * math.sin(h)
        across = -dx * math.sin(h) + dy * math.cos(h)
        if along > 0.0 and abs(across) < 0.5 * (p.width_m + self.ego_width_m) + 0.3:
            gap = along - 0.5 * (p.length_m + self.ego_length_m)
            want = min(want, max(0.0, (gap - p.min_gap_m) / 1.5))
        accel = float(min(max((want - self.v) / 1.0, -6.0), 3.0))
        self.v = max(0.0, self.v + accel * dt)
        self.s = min(self.s + self.v * dt, float(p.path.s_m[-1]))
        x, y, h = self._pose_at_s()
        on = p.signals_on_s <= t < p.signals_off_s
        return EVTruth(t, x, y, h, self.v, lights=on and p.lights, siren=on and p.siren)
