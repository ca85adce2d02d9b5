"""Simulated EV perception for closed-loop scenarios (SPEC §6–7).

The closed loop's default perception: a model of the perception stack rather than the stack itself
(the siren stack can run in the loop instead: :mod:`makeway.pipeline.siren_perception`; the crop
classifier cannot yet, for want of rendered camera images). It turns the true ego and EV states into the
:class:`~makeway.messages.EVBelief` a perception stack would publish, with the imperfections that
matter for the decision:

* **latency** — a measurement describes the world ``latency_s`` earlier (default 0.3 s: a 0.5 s
  audio window or a few video frames plus smoothing);
* **rate** — new measurements arrive at ``rate_hz`` (default 10 Hz); between them the last one is held;
* **range** — an EV with signals on is perceived within ``range_m`` (sirens carry ~100–150 m in
  traffic; default 120 m);
* **dropouts** — each measurement is lost with probability ``dropout_prob``, and bursts of
  ``burst_s`` start with probability ``burst_prob`` per second (occlusion, wind noise);
* **noise** — bearing error (degrees, Gaussian), distance error proportional to distance, and a
  range-rate error (the Doppler shift or a track gives it) for approaching/receding;
* **confidence** — rises with proximity, drops to 0 when nothing is perceived.

The relation (behind, ahead, oncoming, crossing) is classified from the (noisy) relative position and
the EV's heading, as a fused tracker would. Deterministic for a seed.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from makeway.frames import to_vehicle_frame
from makeway.fuse.relation import classify_relation
from makeway.messages import EVBelief, VehicleState
from makeway.sim.world import EVTruth, SimWorld

if TYPE_CHECKING:
    from makeway.sim.scenarios import Scenario


@dataclass(frozen=True)
class PerceptionConfig:
    """Imperfections of the simulated EV perception (see the module docstring)."""

    latency_s: float = 0.3
    rate_hz: float = 10.0
    range_m: float = 120.0
    dropout_prob: float = 0.05
    burst_prob_per_s: float = 0.02
    burst_s: float = 1.0
    bearing_noise_deg: float = 4.0
    distance_noise_frac: float = 0.08
    range_rate_noise_mps: float = 1.0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.latency_s < 0 or self.rate_hz <= 0 or self.range_m <= 0:
            raise ValueError("latency_s must be >= 0, rate_hz and range_m > 0")
        if not (0.0 <= self.dropout_prob < 1.0 and self.burst_prob_per_s >= 0.0):
            raise ValueError("dropout_prob must lie in [0, 1) and burst_prob_per_s be >= 0")

    @property
    def sees_lights(self) -> bool:
        """The model of perception reports the EV's lights."""
        return True

    def build(self, scenario: Scenario, world: SimWorld) -> SimulatedPerception:
        """The belief source of these settings for a closed-loop run in ``world``."""
        return SimulatedPerception(self, world)


class SimulatedPerception:
    """Turns true states into delayed, noisy, dropped-out :class:`EVBelief` messages.

    A :class:`~makeway.fuse.source.BeliefSource`: call :meth:`update` every simulation step with the
    current time and the ego's state; it reads the EV's truth from ``world`` (``world.ev`` is
    ``None`` when there is no EV) and returns the belief published at that time.
    """

    def __init__(self, config: PerceptionConfig | None = None, world: SimWorld | None = None) -> None:
        self.config = config if config is not None else PerceptionConfig()
        self.world = world if world is not None else SimWorld()
        self._rng = np.random.default_rng(self.config.seed)
        self._pending: deque[tuple[float, EVBelief]] = deque()
        self._next_sample_s = 0.0
        self._burst_until_s = -1.0
        self._last: EVBelief | None = None
        self._prev_distance: tuple[float, float] | None = None

    def update(self, time_s: float, ego: VehicleState) -> EVBelief:
        """The belief published by ``time_s`` (s) for the ego at ``ego`` (world frame)."""
        cfg = self.config
        ego_x, ego_y, ego_yaw, ev = ego.x_m, ego.y_m, ego.yaw_rad, self.world.ev
        while time_s + 1e-9 >= self._next_sample_s:
            sample_t = self._next_sample_s
            self._next_sample_s += 1.0 / cfg.rate_hz
            belief = self._measure(sample_t, ego_x, ego_y, ego_yaw, ev)
            self._pending.append((sample_t + cfg.latency_s, belief))
        while self._pending and self._pending[0][0] <= time_s + 1e-9:
            _, self._last = self._pending.popleft()
        if self._last is None:
            return EVBelief.nothing(time_s)
        return self._last

    def beliefs(self) -> list[EVBelief]:
        """The last published belief when it perceives an EV (this model sees one EV)."""
        return [self._last] if self._last is not None and self._last.detected else []

    def _measure(self, t: float, ego_x: float, ego_y: float, ego_yaw: float, ev: EVTruth | None) -> EVBelief:
        cfg = self.config
        rng = self._rng
        if rng.random() < cfg.burst_prob_per_s / cfg.rate_hz:
            self._burst_until_s = t + cfg.burst_s
        if ev is None or not (ev.lights or ev.siren):
            self._prev_distance = None
            return EVBelief.nothing(t)
        dx, dy = ev.x_m - ego_x, ev.y_m - ego_y
        rel_x, rel_y = (float(v) for v in to_vehicle_frame(dx, dy, ego_yaw))
        distance = math.hypot(rel_x, rel_y)
        if distance > cfg.range_m or t < self._burst_until_s or rng.random() < cfg.dropout_prob:
            return EVBelief.nothing(t)
        bearing = math.atan2(rel_y, rel_x) + math.radians(cfg.bearing_noise_deg) * rng.standard_normal()
        dist_m = max(1.0, distance * (1.0 + cfg.distance_noise_frac * rng.standard_normal()))
        approaching: bool | None = None
        if self._prev_distance is not None:  # range rate as a Doppler/track estimate: truth + noise
            t0, d0 = self._prev_distance
            if t - t0 > 0:
                rate = (distance - d0) / (t - t0) + cfg.range_rate_noise_mps * rng.standard_normal()
                approaching = rate < 0.0
        self._prev_distance = (t, distance)
        relation = classify_relation(
            dist_m * math.cos(bearing), dist_m * math.sin(bearing), ev.heading_rad - ego_yaw
        )
        confidence = float(np.clip(0.55 + 0.45 * (1.0 - distance / cfg.range_m), 0.0, 1.0))
        return EVBelief(
            time_s=t,
            detected=True,
            confidence=confidence,
            relation=relation,
            rel_x_m=dist_m * math.cos(bearing),
            rel_y_m=dist_m * math.sin(bearing),
            distance_m=dist_m,
            bearing_rad=math.atan2(math.sin(bearing), math.cos(bearing)),
            approaching=approaching,
            lights=ev.lights,
            siren=ev.siren,
            source="simulated",
        )
