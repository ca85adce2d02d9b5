"""Longitudinal control: hold a speed, or come to a comfortable, jerk-limited stop at a point (SPEC §6).

:class:`LongitudinalController` returns an acceleration command each control period, in one of
three modes (``mode``):

* **drive**: ``a = k_v (v_ref − v_x)`` with ``v_ref`` the target speed, capped near a stop point at
  the speed the onset deceleration can still stop from.
* **brake**: to stop at the point ``d`` ahead takes the constant deceleration
  ``a_req = v_x² / (2 d′)``. Braking starts when ``a_req`` reaches ``onset_fraction·stop_decel``
  (the jerk-limited onset then peaks near ``stop_decel``) and commands ``−a_req`` — self-correcting:
  braking too little makes ``a_req`` grow, too much makes it shrink. Near rest the deceleration is
  capped at ``√(2 j_end v_x)`` (``j_end = end_jerk_fraction·max_jerk``), so it falls linearly to zero
  as the speed does and the car does not stop with a jolt; the speed in the cap is predicted
  ``actuator_lag_s`` ahead from the measured ``a_x`` because the brakes lag the command. That end
  phase runs ``a³/(24 j_end²)`` further than a constant-deceleration stop, and a positive
  acceleration still being ramped off runs further too, so ``d′`` is ``d`` less both. A car at rest
  short of the point by more than ``stop_tolerance_m`` creeps on at ``creep_speed_mps``.
* **hold**: at rest within ``stop_tolerance_m`` of the point (or past it) it brakes with
  ``hold_decel`` and stays put until the stop point is released (``stop_distance_m=None``) or moves
  on by more than ``release_m``.

Every command is clipped to ``[−max_decel, max_accel]`` and its change per period to
``±max_jerk·Δt`` (``Δt`` from successive ``state.time_s``; ``nominal_dt_s`` on the first call). The
controller keeps its previous command, so use one instance per vehicle and :meth:`reset` it between
runs.

**A firmer stop.** The comfort limits above are the default. One call may raise them for one stop:
:meth:`LongitudinalController.accel` takes ``max_decel_mps2`` and ``max_jerk_mps3`` (the yield
decision's, :attr:`~makeway.messages.YieldDecision.max_decel_mps2`, set only for a stop before an
intersection an emergency vehicle heads for that the comfortable deceleration cannot make). They
replace ``max_decel`` and ``max_jerk`` for that call only (the end phase's ``j_end`` scales with the
jerk: a firm stop also ends more briskly, and runs less past its point); the next call without them
is back to comfort (the jerk limit then brings a firmer command back gradually).
"""

from __future__ import annotations

import math

from makeway.messages import VehicleState

__all__ = ["LongitudinalController"]


class LongitudinalController:
    """Comfort-limited speed keeping and stopping at a point (module docstring)."""

    def __init__(
        self,
        *,
        max_accel: float = 1.5,
        max_decel: float = 3.0,
        max_jerk: float = 2.5,
        k_v: float = 0.8,
        stop_decel: float = 2.0,
        creep_speed_mps: float = 0.5,
        stop_tolerance_m: float = 0.1,
        hold_decel: float = 1.0,
        standstill_mps: float = 0.05,
        release_m: float = 0.2,
        creep_zone_m: float = 5.0,
        onset_fraction: float = 0.8,
        end_jerk_fraction: float = 0.8,
        actuator_lag_s: float = 0.2,
        nominal_dt_s: float = 0.01,
    ) -> None:
        if not (0.0 < stop_decel <= max_decel):
            raise ValueError("stop_decel must be in (0, max_decel]")
        positive = max_accel > 0.0 and max_jerk > 0.0 and end_jerk_fraction > 0.0
        if not (positive and 0.0 < onset_fraction <= 1.0):
            raise ValueError("limits must be positive and onset_fraction in (0, 1]")
        self.max_accel = max_accel
        self.max_decel = max_decel
        self.max_jerk = max_jerk
        self.k_v = k_v
        self.stop_decel = stop_decel
        self.creep_speed_mps = creep_speed_mps
        self.stop_tolerance_m = stop_tolerance_m
        self.hold_decel = hold_decel
        self.standstill_mps = standstill_mps
        self.nominal_dt_s = nominal_dt_s
        self.release_m = release_m
        self.creep_zone_m = creep_zone_m  # a stop point that moves on to within this is crept to
        self.onset_fraction = onset_fraction
        self.end_jerk_fraction = end_jerk_fraction
        self.end_jerk = end_jerk_fraction * max_jerk
        self.lag_s = actuator_lag_s
        self.mode = "drive"
        self._last_accel: float | None = None
        self._last_time: float | None = None

    def reset(self) -> None:
        """Forget the previous command and mode."""
        self.mode = "drive"
        self._last_accel = None
        self._last_time = None

    def _desired(self, v: float, ax: float, target: float, d: float | None, jerk: float) -> float:
        a_drive = self.k_v * (target - v)
        if d is None:
            self.mode = "drive"
            return a_drive
        stopped = v < self.standstill_mps
        if stopped and d <= self.stop_tolerance_m:
            self.mode = "hold"
        if self.mode == "hold":
            if d <= self.stop_tolerance_m + self.release_m:
                return -self.hold_decel
            # the stop point moved on: drive to a far one, creep to a near one
            self.mode = "drive" if d > self.creep_zone_m else "brake"
        # distance the end phase adds to a constant-deceleration stop, and the distance covered while
        # a positive acceleration is still being ramped off
        end_jerk = self.end_jerk_fraction * jerk
        correction = self.stop_decel**3 / (24.0 * end_jerk**2)
        a_pos = max(ax, 0.0)
        t_ramp = a_pos / jerk + (self.lag_s if a_pos > 0.0 else 0.0)
        lead = (v + 0.5 * a_pos * t_ramp) * t_ramp
        d_eff = d - correction - lead
        a_req = v * v / (2.0 * max(d_eff, 1e-3))
        onset = self.onset_fraction * self.stop_decel
        if a_req >= onset or d <= self.stop_tolerance_m:
            self.mode = "brake"
        elif self.mode == "brake" and a_req < 0.5 * onset and d > self.creep_zone_m:
            self.mode = "drive"  # the stop point moved further away
        if self.mode == "drive":
            # never faster than a speed the onset deceleration can still stop from
            return self.k_v * (min(target, math.sqrt(2.0 * onset * max(d_eff, 0.0))) - v)
        cap = math.sqrt(2.0 * end_jerk * max(v + min(ax, 0.0) * self.lag_s, 0.0))
        short = stopped or (v < self.creep_speed_mps and a_req < 0.4 * cap)
        if d > self.stop_tolerance_m and short:
            # at rest (or nearly) short of the point: creep on, braking again when needed
            return min(a_drive, self.k_v * (self.creep_speed_mps - v))
        return min(a_drive, -min(a_req, cap))

    def accel(
        self,
        state: VehicleState,
        target_speed_mps: float,
        stop_distance_m: float | None,
        *,
        max_decel_mps2: float | None = None,
        max_jerk_mps3: float | None = None,
    ) -> float:
        """Acceleration command (m/s²) for ``state``: hold ``target_speed_mps``, and stop at
        ``stop_distance_m`` ahead (along the path; negative when past it) when given.

        ``max_decel_mps2`` (m/s², > 0) and ``max_jerk_mps3`` (m/s³, > 0) replace the comfort limits
        ``max_decel`` and ``max_jerk`` for this call (``None``: the comfort limits)."""
        decel = self.max_decel if max_decel_mps2 is None else float(max_decel_mps2)
        jerk = self.max_jerk if max_jerk_mps3 is None else float(max_jerk_mps3)
        if not (decel > 0.0 and jerk > 0.0 and math.isfinite(decel) and math.isfinite(jerk)):
            raise ValueError(f"max_decel_mps2 and max_jerk_mps3 must be finite and > 0, got {decel}, {jerk}")
        v = max(state.vx_mps, 0.0)
        a_des = self._desired(v, state.ax_mps2, max(target_speed_mps, 0.0), stop_distance_m, jerk)
        a_des = min(max(a_des, -decel), self.max_accel)
        if self._last_accel is None or self._last_time is None:
            previous = state.ax_mps2
            dt = self.nominal_dt_s
        else:
            previous = self._last_accel
            dt = state.time_s - self._last_time
            if not dt > 0.0:
                dt = self.nominal_dt_s
        step = jerk * dt
        a_cmd = min(max(a_des, previous - step), previous + step)
        # a firmer command of the last call comes back at the jerk limit, not in one step
        a_cmd = min(max(a_cmd, min(-decel, previous)), self.max_accel)
        self._last_accel = a_cmd
        self._last_time = state.time_s
        return a_cmd
