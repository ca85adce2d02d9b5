"""The ego vehicle: a linear single-track (bicycle) model with actuator limits (SPEC §6, seed 003).

**State.** A :class:`~makeway.messages.VehicleState`: world position ``(x, y)`` of the centre of
gravity (CG), heading ``ψ`` (``yaw_rad``), longitudinal and lateral CG velocities ``v_x, v_y`` in the
vehicle frame, yaw rate ``r``, actual front-wheel angle ``δ`` and longitudinal acceleration ``a_x``.
All positions the controllers see are CG positions.

**Lateral dynamics** (seed 003, "Vehicle model"; linear tyres ``F_f = C_f α_f``, ``F_r = C_r α_r``
with ``α_f ≈ δ − (v_y + a r)/v_x`` and ``α_r ≈ −(v_y − b r)/v_x``)::

    m (v̇_y + v_x r) = C_f δ − (C_f + C_r)/v_x · v_y − (a C_f − b C_r)/v_x · r
    I_z ṙ           = a C_f δ − (a C_f − b C_r)/v_x · v_y − (a² C_f + b² C_r)/v_x · r

``C_f`` and ``C_r`` are **per axle** (both tyres of the axle together), as in seed 003's bicycle
model where one "wheel" stands for the axle. Steady state gives ``δ = L/R + K_us v_x²/R`` with the
understeer gradient ``K_us = (m/L)(b/C_f − a/C_r)`` (rad per m/s² of lateral acceleration).

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
from dataclasses import dataclass

import numpy as np

from makeway.messages import ControlCommand, VehicleState

__all__ = ["SingleTrackModel", "VehicleParams", "lateral_dynamics_matrices"]


@dataclass(frozen=True)
class VehicleParams:
    """A mid-size sedan (about a Toyota Camry / VW Passat class car).

    * ``mass_kg = 1600``: curb mass ~1500–1550 kg plus a driver and some load.
    * ``yaw_inertia_kgm2 = 2700``: the usual estimate ``I_z ≈ m·a·b·(1.0…1.1)``
      (1600·1.2·1.6 = 3070 is a little high for a car with mass concentrated between the axles;
      measured values for this class are 2500–3000 kg·m²).
    * ``a_m = 1.2``, ``b_m = 1.6``: CG-to-front / CG-to-rear axle; wheelbase 2.8 m, about 57 % of the
      weight on the front axle (front engine).
    * ``cf_npr = 1.2e5``, ``cr_npr = 1.4e5``: cornering stiffness **per axle** (both tyres), i.e.
      60–70 kN/rad per tyre, typical of 205–225 mm passenger tyres at ~4 kN load. With them the car
      understeers: ``K_us ≈ 2.7e−3 rad/(m/s²)`` ≈ 1.5 °/g, characteristic speed ≈ 32 m/s.
    * ``max_steer_rad = 0.55``: road-wheel lock (~31.5°, turning circle ≈ 11 m).
    * ``max_steer_rate_radps = 0.6``: road-wheel rate an electric power-steering actuator sustains
      (≈ 500 °/s at the hand wheel with a 15:1 ratio).
    * ``steer_time_constant_s = 0.1``: steering actuator lag.
    * ``max_accel_mps2 = 2.5``, ``max_decel_mps2 = 6.0``: powertrain and (non-emergency) brake limits.
    * ``max_jerk_mps3 = 8.0``, ``accel_time_constant_s = 0.2``: how fast drive/brake force changes.

    These are the actuators' physical limits; comfort limits belong to the controllers.
    """

    mass_kg: float = 1600.0
    yaw_inertia_kgm2: float = 2700.0
    a_m: float = 1.2
    b_m: float = 1.6
    cf_npr: float = 1.2e5
    cr_npr: float = 1.4e5
    max_steer_rad: float = 0.55
    max_steer_rate_radps: float = 0.6
    steer_time_constant_s: float = 0.1
    max_accel_mps2: float = 2.5
    max_decel_mps2: float = 6.0
    max_jerk_mps3: float = 8.0
    accel_time_constant_s: float = 0.2
    kinematic_blend_low_mps: float = 1.5
    kinematic_blend_high_mps: float = 3.0
    kinematic_relax_s: float = 0.05
    max_substep_s: float = 0.005

    @property
    def wheelbase_m(self) -> float:
        """``L = a + b``."""
        return self.a_m + self.b_m

    @property
    def L(self) -> float:  # noqa: N802 (seed 003's symbol)
        """Wheelbase ``L = a + b`` (seed 003's symbol)."""
        return self.a_m + self.b_m

    @property
    def understeer_gradient(self) -> float:
        """``K_us = (m/L)(b/C_f − a/C_r)`` in rad/(m/s²); positive: understeer."""
        return self.mass_kg / self.L * (self.b_m / self.cf_npr - self.a_m / self.cr_npr)


def lateral_dynamics_matrices(params: VehicleParams, vx: float) -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` of ``d/dt [v_y, r] = A [v_y, r] + B δ`` at speed ``vx`` (> 0), seed 003's model."""
    if not vx > 0.0:
        raise ValueError("the linear single-track model needs vx > 0")
    m, iz, a, b, cf, cr = (
        params.mass_kg,
        params.yaw_inertia_kgm2,
        params.a_m,
        params.b_m,
        params.cf_npr,
        params.cr_npr,
    )
    A = np.array(
        [
            [-(cf + cr) / (m * vx), -(a * cf - b * cr) / (m * vx) - vx],
            [-(a * cf - b * cr) / (iz * vx), -(a * a * cf + b * b * cr) / (iz * vx)],
        ]
    )
    B = np.array([[cf / m], [a * cf / iz]])
    return A, B


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
