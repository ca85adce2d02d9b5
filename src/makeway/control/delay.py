"""Steering-delay compensation: steer for where the car will be when the command takes effect.

A steering actuator with a transport delay ``T_d`` (0.1–0.2 s for electric power steering behind a
vehicle bus) applies each command ``T_d`` late; a feedback loop designed without it loses phase
margin and, at speed, oscillates. :class:`DelayCompensated` wraps any lateral controller with a
Smith-predictor-like step (O. J. M. Smith, "Closer control of loops with dead time", *Chem. Eng.
Prog.* 53, 1957): it keeps the commands
issued during the last ``T_d`` (sent, not yet applied), integrates a model of the design car
(:class:`~makeway.vehicle.VehicleParams`) forward over them from the measured state, and lets the
wrapped controller steer on that predicted state. Only the design car and the nominal delay ``T_d``
of the steering spec are used, never the plant's parameters. Three predictors (``model``):

* ``design``: the full linear single-track model the gains were designed on (with its
  tyres; the kinematic bicycle below ``kinematic_below_mps``). Exact on the design car; a car whose
  steering gain differs (the CommonRoad cars are about neutral-steer where the design car
  understeers: 27 % more yaw per radian at 13 m/s) is predicted wrongly throughout every
  transient, and that prediction error is fed back as if it were tracking error;
* ``kinematic``: the kinematic bicycle of the design car's wheelbase, steering lag and
  rate limit (``r = v_x tan δ / L``, ``v_y = b r``). It leaves out the tyres, the least certain
  part of any car (cornering stiffness changes with the car, its load, its tyres and the road);
  over 0.15 s at the pull-over's lateral accelerations (≤ 1.5 m/s²) tyre slip changes the
  predicted heading by a few milliradians. It suits a neutral-steer car (as CommonRoad's are)
  and costs the understeering design car itself accuracy;
* ``mean`` (default): the mean of the two predictions (position, heading, velocities, yaw rate).
  The design model cannot tell how a real car's steering gain lies between its own tyres'
  understeer and no tyres at all (neutral steer); the mean halves the worst prediction error over
  that range instead of betting on either end.

seed003 with a 0.15 s steering delay, feed-forward + feedback (max |e_lat|, m):

=================================  ========  ===========  ========
plant                              design    kinematic    mean
=================================  ========  ===========  ========
linear (the design car)            0.012     0.043        0.020
CommonRoad multi-body BMW 320i     0.029     0.011        0.019
=================================  ========  ===========  ========

(Stanley on the multi-body BMW: 0.023, 0.020, 0.021; ``benchmarks/bench_robust_pull_over.py``.)
All controllers get the same predictor.

Integration: explicit Euler on half control periods (the design model's lateral modes are slower
than −160 s⁻¹ above 3 m/s; Euler is stable to ``|λ h| < 2``). The longitudinal acceleration is held
at the measured ``a_x`` over the prediction.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

from makeway.messages import ReferencePath, TrackingErrors, VehicleState
from makeway.vehicle import VehicleParams

__all__ = ["PREDICTORS", "DelayCompensated", "predict_state"]

KINEMATIC_BELOW_MPS = 3.0
"""Below this speed the ``design`` predictor uses the kinematic bicycle (the tyre model's
``1/v_x`` terms grow without bound at standstill)."""

PREDICTORS: tuple[str, ...] = ("mean", "design", "kinematic")
"""The predictors :class:`DelayCompensated` offers (module docstring); the first is the default."""


def predict_state(
    state: VehicleState,
    pending: list[float] | deque[float],
    params: VehicleParams,
    dt: float,
    *,
    kinematic_below_mps: float = KINEMATIC_BELOW_MPS,
    substeps: int = 2,
) -> VehicleState:
    """``state`` advanced by ``len(pending)·dt`` on the design model, the steering commands
    ``pending`` (oldest first) each applied for ``dt`` through its steering lag and rate limit;
    the kinematic bicycle below ``kinematic_below_mps`` (``math.inf``: everywhere)."""
    return _predict(state, pending, params, dt, kinematic_below_mps, substeps)[0]


def _predict(
    state: VehicleState,
    pending: list[float] | deque[float],
    params: VehicleParams,
    dt: float,
    kinematic_below_mps: float,
    substeps: int,
    with_bicycle: bool = False,
) -> tuple[VehicleState, VehicleState]:
    """:func:`predict_state`, and beside it with ``with_bicycle`` the kinematic bicycle's prediction
    (``kinematic_below_mps = inf``) from the same state (else the first again): both share the
    steering angle and the speed, so the ``mean`` predictor integrates them in one pass, each
    exactly as on its own."""
    p = params
    x, y, psi = state.x_m, state.y_m, state.yaw_rad
    vx, vy, r, delta, ax = state.vx_mps, state.vy_mps, state.yaw_rate_radps, state.steer_rad, state.ax_mps2
    kx, ky, kpsi, kvy, kr = x, y, psi, vy, r  # the bicycle's
    m, iz, a, b, cf, cr = p.mass_kg, p.yaw_inertia_kgm2, p.a_m, p.b_m, p.cf_npr, p.cr_npr
    # the model's coefficients, grouped as the equations below group them (the same rounding)
    c_sum, c_moment, acf, c_inertia = cf + cr, a * cf - b * cr, a * cf, a * a * cf + b * b * cr
    L = p.L
    tau, rate, lock = p.steer_time_constant_s, p.max_steer_rate_radps, p.max_steer_rad
    h = dt / substeps
    cos, sin, tan = math.cos, math.sin, math.tan
    for cmd in pending:
        target = -lock if cmd < -lock else lock if cmd > lock else cmd
        for _ in range(substeps):
            d_delta = (target - delta) / tau
            d_delta = -rate if d_delta < -rate else rate if d_delta > rate else d_delta
            if vx > kinematic_below_mps:
                d_vy = (cf * delta - c_sum / vx * vy - c_moment / vx * r) / m - vx * r
                d_r = (acf * delta - c_moment / vx * vy - c_inertia / vx * r) / iz
                vy += h * d_vy
                r += h * d_r
                if with_bicycle:
                    kr = vx * tan(delta) / L
                    kvy = b * kr
            else:
                r = vx * tan(delta) / L
                vy = b * r
                kr, kvy = r, vy
            c, s = cos(psi), sin(psi)
            x += h * (vx * c - vy * s)
            y += h * (vx * s + vy * c)
            psi += h * r
            if with_bicycle:
                c, s = cos(kpsi), sin(kpsi)
                kx += h * (vx * c - kvy * s)
                ky += h * (vx * s + kvy * c)
                kpsi += h * kr
            vx = max(0.0, vx + h * ax)
            delta += h * d_delta
    t = state.time_s + dt * len(pending)
    two_pi = 2.0 * math.pi
    main = VehicleState(t, x, y, math.remainder(psi, two_pi), vx, vy, r, delta, state.ax_mps2)
    if not with_bicycle:
        return main, main
    return main, VehicleState(t, kx, ky, math.remainder(kpsi, two_pi), vx, kvy, kr, delta, state.ax_mps2)


def _mean_state(a: VehicleState, b: VehicleState) -> VehicleState:
    """The mean of two predictions of the same car at the same time (headings averaged on the circle)."""
    return VehicleState(
        a.time_s,
        0.5 * (a.x_m + b.x_m),
        0.5 * (a.y_m + b.y_m),
        math.remainder(a.yaw_rad + 0.5 * math.remainder(b.yaw_rad - a.yaw_rad, 2.0 * math.pi), 2.0 * math.pi),
        0.5 * (a.vx_mps + b.vx_mps),
        0.5 * (a.vy_mps + b.vy_mps),
        0.5 * (a.yaw_rate_radps + b.yaw_rate_radps),
        0.5 * (a.steer_rad + b.steer_rad),
        a.ax_mps2,
    )


class DelayCompensated:
    """A lateral controller that steers on the state predicted ``delay_s`` ahead (module docstring).

    ``inner`` is a lateral controller with ``steer`` and ``errors`` (those of
    :data:`~makeway.control.LATERAL_CONTROLLERS`); ``delay_s`` a whole number of control periods
    ``dt``; ``model`` the predictor (one of :data:`PREDICTORS`, module docstring).
    :meth:`steer` returns the command, and the errors and nearest index of the *present* state
    (what the car is doing now, for logs and the planner).
    """

    def __init__(
        self, inner: Any, params: VehicleParams, delay_s: float, dt: float, model: str = "mean"
    ) -> None:
        if model not in PREDICTORS:
            raise ValueError(f"unknown predictor {model!r}; choose from: {', '.join(PREDICTORS)}")
        self.model = model
        n = round(delay_s / dt)
        if n < 0 or abs(n * dt - delay_s) > 1e-9 + 1e-6 * delay_s:
            raise ValueError(f"a delay of {delay_s} s is not a whole number of {dt} s periods")
        self.inner = inner
        self.params = params
        self.dt = dt
        self.steps = n
        self._pending: deque[float] = deque(maxlen=max(n, 1))

    def predicted(self, state: VehicleState) -> VehicleState:
        """Where the design model puts the car when the next command takes effect."""
        if self.steps == 0:
            return state
        pending = list(self._pending)
        if len(pending) < self.steps:  # before the first commands: the wheel holds its angle
            pending = [state.steer_rad] * (self.steps - len(pending)) + pending
        if self.model != "mean":
            below = math.inf if self.model == "kinematic" else KINEMATIC_BELOW_MPS
            return predict_state(state, pending, self.params, self.dt, kinematic_below_mps=below)
        tyres, bicycle = _predict(state, pending, self.params, self.dt, KINEMATIC_BELOW_MPS, 2, True)
        return _mean_state(tyres, bicycle)

    def steer(
        self, state: VehicleState, path: ReferencePath, hint: int | None = None
    ) -> tuple[float, TrackingErrors, int]:
        delta, _, _ = self.inner.steer(self.predicted(state), path, hint)
        errors, index = self.inner.errors(state, path, hint)
        if self.steps > 0:
            self._pending.append(delta)
        return delta, errors, index

    def errors(
        self, state: VehicleState, path: ReferencePath, hint: int | None = None
    ) -> tuple[TrackingErrors, int]:
        """The errors of ``state`` (no prediction) and the nearest index."""
        result: tuple[TrackingErrors, int] = self.inner.errors(state, path, hint)
        return result
