"""The car's own model: its parameters and the linear single-track (bicycle) dynamics (SPEC §6, seed 003).

Seed 003 is the project report of seed 001's work, which adds the complete feedback law and the
field-test figures (``../shared/seeds/003_…``, digested in SPEC §6).

The controllers design their gains against this model, and the simulator's plant
(:class:`makeway.sim.vehicle.SingleTrackModel`) integrates it, so both import it from here.

**Lateral dynamics** (seed 003, "Vehicle model"; linear tyres ``F_f = C_f α_f``, ``F_r = C_r α_r``
with ``α_f ≈ δ − (v_y + a r)/v_x`` and ``α_r ≈ −(v_y − b r)/v_x``)::

    m (v̇_y + v_x r) = C_f δ − (C_f + C_r)/v_x · v_y − (a C_f − b C_r)/v_x · r
    I_z ṙ           = a C_f δ − (a C_f − b C_r)/v_x · v_y − (a² C_f + b² C_r)/v_x · r

``C_f`` and ``C_r`` are **per axle** (both tyres of the axle together), as in seed 003's bicycle
model where one "wheel" stands for the axle. Steady state gives ``δ = L/R + K_us v_x²/R`` with the
understeer gradient ``K_us = (m/L)(b/C_f − a/C_r)`` (rad per m/s² of lateral acceleration).
Units: SI throughout (kg, m, s, rad, N/rad).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["VehicleParams", "lateral_dynamics_matrices"]


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

    * ``length_m = 4.8``, ``width_m = 1.85``: the body's footprint (clearance and collision checks).

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
    length_m: float = 4.8
    width_m: float = 1.85

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
