"""Which camera vehicle track each fused EV is (issue 26 item 2): a siren heard or a light seen at
a bearing linked to the vehicle a camera tracks there, so the belief carries an obstacle id (as
Apollo's audio event names an obstacle) and planning or a log viewer can point at the vehicle.

:class:`ObstacleLinker` takes the EV beliefs of one period (:class:`~makeway.messages.EVBelief`,
vehicle frame) and the cameras' vehicle tracks as bearings
(:class:`~makeway.messages.VehicleBearing`, from
:func:`~makeway.perceive.vision.track_bearings.vehicle_bearings`) and returns the beliefs with
``obstacle_id`` set where one vehicle fits:

* **Bearing as the camera sees it.** A belief placed at a position (``rel_x_m``, ``rel_y_m``) is
  compared from the camera's centre (the parallax of a camera 2 m ahead of the origin is ~6° for a
  vehicle 20 m to the side); a belief with only a bearing is compared as it is.
* **Gate.** The normalised difference ``|Δ| / sqrt(σ_b² + σ_v²)`` (``σ_b``:
  ``belief_bearing_sigma_rad``, about the siren stack's angle error; ``σ_v`` the vehicle's, box width
  included) must be at most ``gate_sigmas``; beyond it a belief stays unlinked (an EV the cameras do
  not see, or see as no vehicle).
* **One vehicle per EV.** The pairs are assigned by least total squared normalised difference
  (:func:`scipy.optimize.linear_sum_assignment`); a vehicle whose crop classifier calls it not an
  active EV (``active`` False) costs ``inactive_penalty`` more, one it calls active
  ``active_bonus`` less, so two vehicles on nearly one bearing go to the one that looks like an EV.
* **Stable ids.** The vehicle an EV track was last linked to costs ``keep_bonus`` less while it
  stays inside the gate, so a link does not flip between neighbours on every noisy bearing; the
  memory lasts while the EV track is among the beliefs. Beliefs without a ``track_id`` are linked
  afresh each period.

Beliefs that are not ``detected``, or have no finite bearing (a mono siren: heard, not placed), are
returned unchanged with ``obstacle_id`` None.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import linear_sum_assignment

from makeway.messages import EVBelief, VehicleBearing

__all__ = ["ObstacleLinker", "ObstacleLinkerConfig"]


@dataclass(frozen=True)
class ObstacleLinkerConfig:
    """The gate and the preferences of :class:`ObstacleLinker` (module docstring). Angles in
    radians; costs in squared standard deviations."""

    belief_bearing_sigma_rad: float = math.radians(5.0)
    gate_sigmas: float = 3.0
    keep_bonus: float = 4.0
    active_bonus: float = 2.0
    inactive_penalty: float = 2.0

    def __post_init__(self) -> None:
        values = (
            self.belief_bearing_sigma_rad,
            self.gate_sigmas,
            self.keep_bonus,
            self.active_bonus,
            self.inactive_penalty,
        )
        if not all(math.isfinite(v) and v >= 0 for v in values) or self.gate_sigmas <= 0:
            raise ValueError("ObstacleLinkerConfig: every value must be finite and >= 0, gate_sigmas > 0")


class ObstacleLinker:
    """Links each period's EV beliefs to camera vehicle tracks (module docstring)."""

    def __init__(self, config: ObstacleLinkerConfig | None = None) -> None:
        self.config = config or ObstacleLinkerConfig()
        self._last: dict[int, str] = {}

    def reset(self) -> ObstacleLinker:
        """Forget the previous links; returns self."""
        self._last.clear()
        return self

    def _bearing_from(self, b: EVBelief, v: VehicleBearing) -> float:
        if math.isfinite(b.rel_x_m) and math.isfinite(b.rel_y_m):
            return math.atan2(b.rel_y_m - v.camera_xy_m[1], b.rel_x_m - v.camera_xy_m[0])
        return b.bearing_rad

    def update(self, beliefs: Sequence[EVBelief], vehicles: Sequence[VehicleBearing]) -> list[EVBelief]:
        """``beliefs`` with ``obstacle_id`` set to the vehicle each is linked to (``None`` where
        none fits), in the same order."""
        cfg = self.config
        out = [replace(b, obstacle_id=None) for b in beliefs]
        rows = [
            i
            for i, b in enumerate(beliefs)
            if b.detected and (math.isfinite(b.bearing_rad) or math.isfinite(b.rel_x_m + b.rel_y_m))
        ]
        if not rows or not vehicles:
            self._remember(out)
            return out
        big = 1e9
        cost = np.full((len(rows), len(vehicles)), big)
        gate2 = cfg.gate_sigmas**2
        for r, i in enumerate(rows):
            b = beliefs[i]
            last = self._last.get(b.track_id) if b.track_id is not None else None
            for c, v in enumerate(vehicles):
                seen = self._bearing_from(b, v)
                if not math.isfinite(seen):
                    continue
                d = math.remainder(seen - v.azimuth_rad, math.tau)
                d2 = d * d / max(cfg.belief_bearing_sigma_rad**2 + v.azimuth_sigma_rad**2, 1e-12)
                if d2 > gate2:
                    continue
                if v.active is True:
                    d2 -= cfg.active_bonus
                elif v.active is False:
                    d2 += cfg.inactive_penalty
                if last == v.obstacle_id:
                    d2 -= cfg.keep_bonus
                cost[r, c] = d2
        rr, cc = linear_sum_assignment(cost)
        for r, c in zip(rr, cc, strict=True):
            if cost[r, c] < big:
                i = rows[r]
                out[i] = replace(out[i], obstacle_id=vehicles[c].obstacle_id)
        self._remember(out)
        return out

    def _remember(self, beliefs: Sequence[EVBelief]) -> None:
        """Keep each present EV track's newest link (one period without a fitting vehicle keeps the
        old one); forget the tracks that are gone."""
        last: dict[int, str] = {}
        for b in beliefs:
            if b.track_id is None:
                continue
            link = b.obstacle_id or self._last.get(b.track_id)
            if link is not None:
                last[b.track_id] = link
        self._last = last
