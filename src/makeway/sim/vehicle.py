"""The ego vehicle: a linear single-track (bicycle) model with actuator limits (SPEC §6, seed 003).

Seed 003 is the project report of seed 001's work, which adds the complete feedback law and the
field-test figures (``../shared/seeds/003_…``, digested in SPEC §6).

**State.** A :class:`~makeway.messages.VehicleState`: world position ``(x, y)`` of the centre of
gravity (CG), heading ``ψ`` (``yaw_rad``), longitudinal and lateral CG velocities ``v_x, v_y`` in the
vehicle frame, yaw rate ``r``, actual front-wheel angle ``δ`` and longitudinal acceleration ``a_x``.
All positions the controllers see are CG positions.

**Lateral dynamics**: the linear single-track model of :mod:`makeway.vehicle` (the same equations the
controllers design against), with the car's :class:`~makeway.vehicle.VehicleParams`.

**World kinematics**: ``ẋ = v_x cos ψ − v_y sin ψ``, ``ẏ = v_x sin ψ + v_y cos ψ``, ``ψ̇ = r``.

**Low speed.** The tyre model divides by ``v_x`` and is singular at rest (and stiff just above). Below
``kinematic_blend_high_mps`` the derivatives of ``v_y`` and ``r`` are blended, with a C¹ smoothstep
weight, towards those of the kinematic bicycle model, which fully takes over below
``kinematic_blend_low_mps``. The kinematic model assumes no tyre slip: the rear axle moves along the
body axis and the front axle along the wheel, so ``r_kin = v_x tan δ / L`` and ``v_y,kin = b r_kin``;
its derivatives are those of these expressions (through ``a_x`` and ``δ̇``) plus a relaxation
``(r_kin − r)/τ_kin`` that pulls the blended state onto the kinematic manifold. At rest the vehicle
cannot yaw or slide.

**Actuators.** Steering: a first-order lag ``δ̇ = (δ_cmd − δ)/τ_δ`` with ``δ_cmd`` clipped to
``±max_steer_rad`` and ``δ̇`` to ``±max_steer_rate_radps``. Longitudinal: ``a_x`` follows the clipped
command with a first-order lag ``τ_a`` and its rate clipped to ``±max_jerk_mps3``. ``a_x`` is the
actuator's demand (drive or brake force over mass): speed never goes negative, so a negative ``a_x``
at rest is the brake holding the car, not reversing it.

**Integration.** Classic RK4 on sub-steps of at most ``max_substep_s`` (the lateral modes are about
−60 s⁻¹ at 3 m/s, far inside RK4's stability bound at 5 ms).
"""

from __future__ import annotations

import math

from makeway.messages import ControlCommand, VehicleState
from makeway.vehicle import VehicleParams

__all__ = ["SingleTrackModel"]


def _clip(value: float, low: float, high: float) -> float:
    return low if value < low else high if value > high else value


def _smoothstep(t: float) -> float:
    t = _clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


class SingleTrackModel:
    """Integrates the single-track model (module docstring) one control period at a time."""

    def __init__(self, params: VehicleParams | None = None) -> None:
        self.params = params if params is not None else VehicleParams()

    def _derivative(
        self, s: tuple[float, ...], steer_cmd: float, accel_cmd: float
    ) -> tuple[float, float, float, float, float, float, float, float]:
        p = self.params
        _x, _y, psi, vx, vy, r, delta, ax = s
        v = vx if vx > 0.0 else 0.0
        cos_p, sin_p = math.cos(psi), math.sin(psi)
        dx = v * cos_p - vy * sin_p
        dy = v * sin_p + vy * cos_p

        # actuators
        d_delta = _clip(
            (steer_cmd - delta) / p.steer_time_constant_s, -p.max_steer_rate_radps, p.max_steer_rate_radps
        )
        if (delta >= p.max_steer_rad and d_delta > 0.0) or (delta <= -p.max_steer_rad and d_delta < 0.0):
            d_delta = 0.0
        d_ax = _clip((accel_cmd - ax) / p.accel_time_constant_s, -p.max_jerk_mps3, p.max_jerk_mps3)
        d_vx = ax if (vx > 0.0 or ax > 0.0) else 0.0

        # lateral: dynamic (linear tyres) blended into kinematic at low speed
        w = _smoothstep(
            (v - p.kinematic_blend_low_mps) / (p.kinematic_blend_high_mps - p.kinematic_blend_low_mps)
        )
        d_vy = d_r = 0.0
        if w > 0.0:
            m, iz, a, b, cf, cr = p.mass_kg, p.yaw_inertia_kgm2, p.a_m, p.b_m, p.cf_npr, p.cr_npr
            d_vy = (cf * delta - (cf + cr) / v * vy - (a * cf - b * cr) / v * r) / m - v * r
            d_r = (a * cf * delta - (a * cf - b * cr) / v * vy - (a * a * cf + b * b * cr) / v * r) / iz
        if w < 1.0:
            tan_d = math.tan(delta)
            r_kin = v * tan_d / p.L
            dr_kin = (d_vx * tan_d + v * d_delta / math.cos(delta) ** 2) / p.L
            dr_kin += (r_kin - r) / p.kinematic_relax_s
            dvy_kin = p.b_m * (d_vx * tan_d + v * d_delta / math.cos(delta) ** 2) / p.L
            dvy_kin += (p.b_m * r_kin - vy) / p.kinematic_relax_s
            d_vy = w * d_vy + (1.0 - w) * dvy_kin
            d_r = w * d_r + (1.0 - w) * dr_kin
        return dx, dy, r, d_vx, d_vy, d_r, d_delta, d_ax

    def step(self, state: VehicleState, command: ControlCommand, dt: float) -> VehicleState:
        """The state ``dt`` seconds later under ``command`` (held constant over ``dt``)."""
        if not dt > 0.0:
            raise ValueError("dt must be positive")
        p = self.params
        steer_cmd = _clip(command.steer_rad, -p.max_steer_rad, p.max_steer_rad)
        accel_cmd = _clip(command.accel_mps2, -p.max_decel_mps2, p.max_accel_mps2)
        n_sub = max(1, math.ceil(dt / p.max_substep_s - 1e-9))
        h = dt / n_sub
        s: tuple[float, ...] = (
            state.x_m,
            state.y_m,
            state.yaw_rad,
            max(state.vx_mps, 0.0),
            state.vy_mps,
            state.yaw_rate_radps,
            state.steer_rad,
            state.ax_mps2,
        )
        f = self._derivative
        for _ in range(n_sub):
            k1 = f(s, steer_cmd, accel_cmd)
            k2 = f(tuple(si + 0.5 * h * ki for si, ki in zip(s, k1, strict=True)), steer_cmd, accel_cmd)
            k3 = f(tuple(si + 0.5 * h * ki for si, ki in zip(s, k2, strict=True)), steer_cmd, accel_cmd)
            k4 = f(tuple(si + h * ki for si, ki in zip(s, k3, strict=True)), steer_cmd, accel_cmd)
            s = tuple(
                si + h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
                for si, a1, a2, a3, a4 in zip(s, k1, k2, k3, k4, strict=True)
            )
            x, y, psi, vx, vy, r, delta, ax = s
            if vx <= 0.0:  # came to rest inside the sub-step: stay at rest, do not reverse
                vx, vy, r = 0.0, 0.0, 0.0
            delta = _clip(delta, -p.max_steer_rad, p.max_steer_rad)
            ax = _clip(ax, -p.max_decel_mps2, p.max_accel_mps2)
            s = (x, y, psi, vx, vy, r, delta, ax)
        x, y, psi, vx, vy, r, delta, ax = s
        return VehicleState(
            time_s=state.time_s + dt,
            x_m=x,
            y_m=y,
            yaw_rad=math.remainder(psi, 2.0 * math.pi),
            vx_mps=vx,
            vy_mps=vy,
            yaw_rate_radps=r,
            steer_rad=delta,
            ax_mps2=ax,
        )
