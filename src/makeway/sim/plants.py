"""Plants the closed loop can steer: today's design model and CommonRoad's vehicle models (issue 30).

A *plant* is the simulated car itself; the controllers never see it, only its state (or a noisy
estimate of it, :mod:`makeway.sim.localization`) and their own design model
(:class:`makeway.vehicle.VehicleParams`). Every plant offers :class:`Plant`: ``reset(state)`` puts
it at a :class:`~makeway.messages.VehicleState` and ``advance(command, dt)`` applies a
:class:`~makeway.messages.ControlCommand` for ``dt`` seconds and returns the new state. Positions
are those of the centre of gravity (CG), world frame; ``v_x, v_y`` in the vehicle frame.

:data:`PLANTS` names them (``makeway simulate --plant``):

* ``linear`` (default): :class:`makeway.sim.vehicle.SingleTrackModel`, the linear single-track
  model the controllers' gains were designed on, with the design car's parameters and actuators.
* ``kinematic``, ``single_track``, ``single_track_drift``, ``multi_body``: the CommonRoad vehicle
  models (Althoff & Würsching, *CommonRoad: Vehicle Models*, TUM, 2020; PyPI
  ``commonroad-vehicle-models`` 3.0.2, module ``vehiclemodels``): ``vehicle_dynamics_ks`` (kinematic
  bicycle, rear-axle reference), ``_st`` (single track with linear tyres and load transfer),
  ``_std`` (single track with Pacejka tyres and wheel spin) and ``_mb`` (29-state multi-body:
  sprung mass with roll and pitch, unsprung masses, suspension, four Pacejka tyres), with one of
  the published parameter sets of :data:`VEHICLES` (Ford Escort, BMW 320i, VW Vanagon). The
  multi-body equations are evaluated by :mod:`makeway.sim.multibody`, our writing-out of the
  package's ``vehicle_dynamics_mb`` (the same equations and parameters, equal to ~1e-12 relative,
  about twice as fast).

**Road friction** (:data:`ROADS`: dry μ = 1.0, wet μ = 0.5). The Pacejka tyres of ``single_track_drift``
and ``multi_body`` take their peak friction from the tyre coefficients ``p_dy1`` (lateral, 1.0489
in the published set) and ``p_dx1`` (longitudinal, 1.1739); both are scaled by ``μ / p_dy1`` so
the lateral peak friction is exactly μ (the longitudinal one keeps its ratio, 1.12 μ); the
cornering stiffness ``p_ky1`` is kept, as with the friction scaling factor λ_μ of the Magic
Formula. ``single_track`` has linear tyres: its friction coefficient ``p_dy1`` cancels out of its
equations (``μ·C_S = −p_ky1``), so it never saturates, wet or dry; ``kinematic`` has no tyres.
On those two a wet road changes nothing (their metrics say ``friction_modelled: false``).

**Actuators** (:class:`ActuatorConfig`), in front of every CommonRoad model, whose inputs are the
steering-angle velocity and the longitudinal acceleration:

* steering: the command passes a pure transport delay (a ring buffer of control periods,
  :class:`DelayLine`), then a servo ``δ̇ = (δ_delayed − δ)/τ_δ`` whose rate the model's own
  published limit clips (``±0.4 rad/s`` for all three cars, against the design model's 0.6);
  the angle is clipped to the published lock;
* longitudinal: ``a_x`` follows the command (clipped to the design car's drive and brake limits)
  with a first-order lag ``τ_a`` and a jerk limit; speed never goes negative (a negative ``a_x``
  at rest is the brake holding the car). The Pacejka models turn ``a_x`` into drive and brake
  torques, so on a wet road the wheels may slip and the car brakes less than asked.

**Integration.** Classic RK4 on sub-steps whose length follows the stiffest mode: the wheel-spin
mode of the Pacejka models has the eigenvalue ``≈ −R_w² F_z C_κ / (I_w u)`` (``C_κ = p_kx1 F_z``),
about ``−4600/u`` s⁻¹ for the BMW, so the sub-step is ``h ≤ f · 2.785 I_w u /(R_w² F_z p_kx1)``: RK4
is stable to ``|λ h| ≤ 2.785`` on the negative real axis, ``f = stability_fraction`` (0.9) keeps a
10 % margin (the bound takes the static wheel load), and ``h`` is at most 5 ms (the suspension's
modes). The single-track model's lateral modes scale the same way with ``1/u``.
Accuracy check (seed003 and curve_behind, multi-body BMW 320i, dry and wet, 0.15 s steering delay,
closed loop): against ``f = 0.72`` (the bound with ``|λ h| ≤ 2``) the right-hand side is evaluated
14 % less often and ``e_lat`` moves by at most 0.3 mm; a 10 ms cap instead of 5 ms saves no more
than another 0.1 % and moves ``e_lat`` by 9 mm, so the cap stays. Below
``handover_low_mps`` (1 m/s) the dynamic models hand over to CommonRoad's kinematic model with the
CG as reference (``vehicle_dynamics_ks_cog``), as the models themselves do below 0.1 m/s, and back
above ``handover_high_mps`` (re-initialised with the package's ``init_*`` functions); standstill
is exact and cheap.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, Protocol

from vehiclemodels.init_mb import init_mb
from vehiclemodels.init_std import init_std
from vehiclemodels.parameters_vehicle1 import parameters_vehicle1
from vehiclemodels.parameters_vehicle2 import parameters_vehicle2
from vehiclemodels.parameters_vehicle3 import parameters_vehicle3
from vehiclemodels.utils.vehicle_dynamics_ks_cog import vehicle_dynamics_ks_cog
from vehiclemodels.vehicle_dynamics_ks import vehicle_dynamics_ks
from vehiclemodels.vehicle_dynamics_st import vehicle_dynamics_st
from vehiclemodels.vehicle_dynamics_std import vehicle_dynamics_std

from makeway.messages import ControlCommand, VehicleState
from makeway.registry import Registry
from makeway.sim.multibody import Derivative, multibody_rhs
from makeway.sim.vehicle import SingleTrackModel
from makeway.vehicle import VehicleParams

__all__ = [
    "PLANTS",
    "RK4_REAL_STABILITY",
    "ROADS",
    "VEHICLES",
    "ActuatorConfig",
    "CommonRoadPlant",
    "DelayLine",
    "LinearPlant",
    "Plant",
    "PlantDivergedError",
    "PlantSpec",
    "vehicle_parameters",
]

G = 9.81

VEHICLES: Registry[Callable[[], Any]] = Registry(
    "vehicle",
    {"ford_escort": parameters_vehicle1, "bmw320i": parameters_vehicle2, "vw_vanagon": parameters_vehicle3},
)
"""CommonRoad's published parameter sets by name (``vehiclemodels.parameters_vehicle1/2/3``)."""

ROADS: Registry[float] = Registry("road", {"dry": 1.0, "wet": 0.5})
"""Peak tyre–road friction coefficient μ by road surface."""


class PlantDivergedError(ValueError):
    """The car went out of control and the model's equations broke down (a division by zero or
    an overflow in CommonRoad's model, or a yaw rate beyond any car's): the loop was unstable."""


RK4_REAL_STABILITY = 2.785
"""Where the classic RK4 method's stability region meets the negative real axis (``|λ h|``)."""

MAX_YAW_RATE_RADPS = 5.0
"""A yaw rate no car on tyres reaches (beyond it the car is spinning: the run has diverged)."""


class Plant(Protocol):
    """A simulated car: put it somewhere, then drive it one control period at a time."""

    def reset(self, state: VehicleState) -> None: ...

    def state(self) -> VehicleState: ...

    def advance(self, command: ControlCommand, dt: float) -> VehicleState: ...


class DelayLine:
    """A pure transport delay of ``delay_s`` on a signal sampled every ``dt`` seconds (a ring buffer).

    ``push(u)`` returns the value pushed ``n = delay_s/dt`` calls before (until the buffer has
    filled: ``initial``, or the first value pushed when it is ``None``); ``delay_s`` must be a whole
    number of periods.
    """

    def __init__(self, delay_s: float, dt: float, initial: float | None = None) -> None:
        if delay_s < 0.0 or not dt > 0.0:
            raise ValueError("the delay must be ≥ 0 and the period > 0")
        n = round(delay_s / dt)
        if abs(n * dt - delay_s) > 1e-9 + 1e-6 * delay_s:
            raise ValueError(f"a delay of {delay_s} s is not a whole number of {dt} s periods")
        self.steps = n
        self._buffer: deque[float] = deque(maxlen=n + 1)
        if initial is not None:
            self._buffer.extend([initial] * n)

    def push(self, value: float) -> float:
        """Insert ``value``; return the one ``steps`` pushes ago."""
        if not self._buffer:
            self._buffer.extend([value] * (self.steps + 1))
        else:
            self._buffer.append(value)
        return self._buffer[0]


@dataclass(frozen=True)
class ActuatorConfig:
    """The actuators in front of a CommonRoad model (module docstring).

    * ``steer_delay_s``: pure transport delay of the steering command (0–0.2 s; electric power
      steering plus the bus and the controller's cycle);
    * ``steer_time_constant_s = 0.08``: the steering servo's time constant (a position loop on the
      rack; the rate limit is the parameter set's ``steering.v_max``);
    * ``accel_time_constant_s = 0.3``, ``max_jerk_mps3 = 10``: how fast drive and brake force build
      up (slower than the design model's 0.2 s);
    * ``max_accel_mps2 = 2.5``, ``max_decel_mps2 = 6.0``: the powertrain and (non-emergency) brake.
    """

    steer_delay_s: float = 0.0
    steer_time_constant_s: float = 0.08
    accel_time_constant_s: float = 0.3
    max_jerk_mps3: float = 10.0
    max_accel_mps2: float = 2.5
    max_decel_mps2: float = 6.0


def vehicle_parameters(vehicle: str, mu: float) -> Any:
    """CommonRoad's parameter set ``vehicle`` with the tyres' peak lateral friction set to ``mu``
    (``p_dx1`` and ``p_dy1`` scaled by ``mu / p_dy1``; module docstring)."""
    p = VEHICLES[vehicle]()
    if not mu > 0.0:
        raise ValueError("the friction coefficient must be positive")
    scale = mu / p.tire.p_dy1
    p.tire = replace(p.tire, p_dx1=p.tire.p_dx1 * scale, p_dy1=p.tire.p_dy1 * scale)
    return p


def _clip(value: float, low: float, high: float) -> float:
    return low if value < low else high if value > high else value


class LinearPlant:
    """Today's plant, :class:`~makeway.sim.vehicle.SingleTrackModel` with the design car's
    parameters, behind :class:`Plant`; an optional steering transport delay sits in front."""

    friction_modelled = False

    def __init__(self, params: VehicleParams | None = None, steer_delay_s: float = 0.0) -> None:
        self.model = SingleTrackModel(params)
        self.body_m = (self.model.params.length_m, self.model.params.width_m)
        self.steer_delay_s = steer_delay_s
        self._delay: DelayLine | None = None
        self._dt: float | None = None
        self._state: VehicleState | None = None

    def reset(self, state: VehicleState) -> None:
        self._state = state
        self._delay = None

    def state(self) -> VehicleState:
        """The car's :class:`~makeway.messages.VehicleState` now."""
        if self._state is None:
            raise RuntimeError("reset the plant first")
        return self._state

    def advance(self, command: ControlCommand, dt: float) -> VehicleState:
        if self._state is None:
            raise RuntimeError("reset the plant before advancing it")
        if self.steer_delay_s > 0.0:
            if self._delay is None or self._dt != dt:
                self._delay, self._dt = DelayLine(self.steer_delay_s, dt, self._state.steer_rad), dt
            command = replace(command, steer_rad=self._delay.push(command.steer_rad))
        self._state = self.model.step(self._state, command, dt)
        return self._state


def _bound(model: Callable[[list[float], list[float], Any], list[float]]) -> Callable[[Any], Derivative]:
    """CommonRoad's ``vehicle_dynamics_*(x, u, p)`` as a :data:`~makeway.sim.multibody.Derivative`
    for parameter set ``p`` (it may write into ``x``, so it gets a copy)."""

    def build(p: Any) -> Derivative:
        def f(x: list[float], u: list[float], k: list[float] | None = None, c: float = 0.0) -> list[float]:
            y = list(x) if k is None else [xi + c * ki for xi, ki in zip(x, k, strict=True)]
            return model(y, u, p)

        return f

    return build


# model name → its derivative for a parameter set; the multi-body model is our faster writing-out
# of the package's equations (makeway.sim.multibody; identical to rounding)
_MODELS: dict[str, Callable[[Any], Derivative]] = {
    "kinematic": _bound(vehicle_dynamics_ks),
    "single_track": _bound(vehicle_dynamics_st),
    "single_track_drift": _bound(vehicle_dynamics_std),
    "multi_body": multibody_rhs,
}


class CommonRoadPlant:
    """One of CommonRoad's vehicle models (``model``: a key of :data:`PLANTS` other than ``linear``)
    with a published parameter set, a road and actuators (module docstring)."""

    def __init__(
        self,
        model: str,
        vehicle: str = "bmw320i",
        road: str = "dry",
        actuators: ActuatorConfig | None = None,
        *,
        max_substep_s: float = 0.005,
        handover_low_mps: float = 1.0,
        handover_high_mps: float = 1.5,
        stability_fraction: float = 0.9,
    ) -> None:
        if model not in _MODELS:
            raise ValueError(f"unknown CommonRoad model {model!r}; choose from: {', '.join(_MODELS)}")
        self.model = model
        self.vehicle = vehicle
        self.road = road
        self.mu = ROADS[road]
        self.p = vehicle_parameters(vehicle, self.mu)
        self.actuators = actuators if actuators is not None else ActuatorConfig()
        self.friction_modelled = model in ("single_track_drift", "multi_body")
        self.body_m = (float(self.p.l), float(self.p.w))
        self.max_substep_s = max_substep_s
        self.handover_low_mps = handover_low_mps
        self.handover_high_mps = handover_high_mps
        p = self.p
        self._f = _MODELS[model](p)
        self._f_kinematic = _bound(vehicle_dynamics_ks_cog)(p)
        # static wheel load and the wheel-spin mode's step bound per m/s (module docstring)
        fz = p.m * G * max(p.a, p.b) / (p.a + p.b)
        fz_wheel = fz if model == "single_track_drift" else 0.5 * fz
        limit = stability_fraction * RK4_REAL_STABILITY
        self._h_per_mps = limit * p.I_y_w / (p.R_w**2 * fz_wheel * p.tire.p_kx1)
        if model == "single_track":
            # lateral modes of the linear-tyre single track: |λ| ≈ μ C_S g (…)/u
            self._h_per_mps = limit / (-p.tire.p_ky1 * G * 2.0)
        self._x: list[float] = []
        self._kinematic = True  # below the hand-over speed: (x, y, δ, v, ψ) at the CG
        self._ax = 0.0
        self._time = 0.0
        self._delay: DelayLine | None = None
        self._dt: float | None = None

    # ------------------------------------------------------------------ conversions
    def reset(self, state: VehicleState) -> None:
        """Put the car at ``state`` (CG position, heading, velocities, wheel angle, ``a_x``)."""
        self._time = state.time_s
        self._ax = state.ax_mps2
        self._delay = None
        vx = max(state.vx_mps, 0.0)
        if self.model == "kinematic":
            c, s = math.cos(state.yaw_rad), math.sin(state.yaw_rad)
            # CommonRoad's KS: rear-axle reference, v along the body
            self._x = [state.x_m - self.p.b * c, state.y_m - self.p.b * s, state.steer_rad, vx, state.yaw_rad]
            self._kinematic = False
            return
        if vx < self.handover_low_mps:
            self._kinematic = True
            speed = math.hypot(vx, state.vy_mps) if vx > 0.0 else 0.0
            self._x = [state.x_m, state.y_m, state.steer_rad, speed, state.yaw_rad]
            return
        self._kinematic = False
        self._x = self._full_state(
            state.x_m, state.y_m, state.steer_rad, vx, state.vy_mps, state.yaw_rad, state.yaw_rate_radps
        )

    def _full_state(
        self, x: float, y: float, delta: float, vx: float, vy: float, yaw: float, yaw_rate: float
    ) -> list[float]:
        speed = math.hypot(vx, vy)
        beta = math.atan2(vy, vx) if speed > 0.0 else 0.0
        core = [x, y, delta, speed, yaw, yaw_rate, beta]
        if self.model == "single_track":
            return core
        if self.model == "single_track_drift":
            return list(init_std(core, self.p))
        return list(init_mb(core, self.p))

    def state(self) -> VehicleState:
        """The car's :class:`~makeway.messages.VehicleState` now."""
        x = self._x
        p = self.p
        L = p.a + p.b
        if self.model == "kinematic" or self._kinematic:
            delta, v, yaw = x[2], x[3], x[4]
            if self.model == "kinematic":  # rear axle → CG
                cx, cy = x[0] + p.b * math.cos(yaw), x[1] + p.b * math.sin(yaw)
                r = v * math.tan(delta) / L
                vx, vy = v, p.b * r
            else:  # ks_cog: v is the CG's speed along the slip angle β
                cx, cy = x[0], x[1]
                beta = math.atan(math.tan(delta) * p.b / L)
                r = v * math.cos(beta) * math.tan(delta) / L
                vx, vy = v * math.cos(beta), v * math.sin(beta)
        elif self.model == "multi_body":
            cx, cy, delta, vx, yaw, r, vy = x[0], x[1], x[2], x[3], x[4], x[5], x[10]
        else:  # single_track(_drift): speed and slip angle at the CG
            cx, cy, delta, yaw, r = x[0], x[1], x[2], x[4], x[5]
            vx, vy = x[3] * math.cos(x[6]), x[3] * math.sin(x[6])
        return VehicleState(
            time_s=self._time,
            x_m=cx,
            y_m=cy,
            yaw_rad=math.remainder(yaw, 2.0 * math.pi),
            vx_mps=vx,
            vy_mps=vy,
            yaw_rate_radps=r,
            steer_rad=delta,
            ax_mps2=self._ax,
        )

    # ------------------------------------------------------------------ stepping
    def _speed(self) -> float:
        """The forward speed the sub-step and the hand-over go by."""
        return self._x[3]

    def advance(self, command: ControlCommand, dt: float) -> VehicleState:
        """Apply ``command`` for ``dt`` seconds (through the actuators) and return the new state."""
        if not self._x:
            raise RuntimeError("reset the plant before advancing it")
        if not dt > 0.0:
            raise ValueError("dt must be positive")
        act = self.actuators
        steer = command.steer_rad
        if act.steer_delay_s > 0.0:
            if self._delay is None or self._dt != dt:  # until then the wheel holds its angle
                self._delay, self._dt = DelayLine(act.steer_delay_s, dt, self._x[2]), dt
            steer = self._delay.push(steer)
        sp = self.p.steering
        steer = _clip(steer, sp.min, sp.max)
        accel_cmd = _clip(command.accel_mps2, -act.max_decel_mps2, act.max_accel_mps2)
        t_left = dt
        always_kinematic = self.model == "kinematic"
        low, high = self.handover_low_mps, self.handover_high_mps
        while t_left > 1e-12:
            v = self._x[3]
            if not always_kinematic and ((v > high) if self._kinematic else (v < low)):
                self._switch_mode()
                v = self._x[3]
            h = self.max_substep_s
            if not self._kinematic and not always_kinematic:
                h = min(h, self._h_per_mps * max(v, low))
            h = min(h, t_left)
            try:
                self._substep(steer, accel_cmd, h)
            except (ArithmeticError, ValueError) as exc:
                raise PlantDivergedError(
                    f"the {self.model} car went out of control at t = {self._time:.2f} s ({exc})"
                ) from None
            t_left -= h
        self._time += dt
        out = self.state()
        if not (math.isfinite(out.x_m) and abs(out.yaw_rate_radps) < MAX_YAW_RATE_RADPS):
            raise PlantDivergedError(
                f"the {self.model} car went out of control at t = {self._time:.2f} s "
                f"(yaw rate {out.yaw_rate_radps:.1f} rad/s)"
            )
        return out

    def _switch_mode(self) -> None:
        if self.model == "kinematic":
            return
        v = self._speed()
        if self._kinematic and v > self.handover_high_mps:
            s = self.state()
            self._x = self._full_state(
                s.x_m, s.y_m, s.steer_rad, s.vx_mps, s.vy_mps, s.yaw_rad, s.yaw_rate_radps
            )
            self._kinematic = False
        elif not self._kinematic and v < self.handover_low_mps:
            s = self.state()
            self._x = [s.x_m, s.y_m, s.steer_rad, math.hypot(s.vx_mps, s.vy_mps), s.yaw_rad]
            self._kinematic = True

    def _substep(self, steer_target: float, accel_cmd: float, h: float) -> None:
        """One RK4 step of length ``h`` of the model with the actuator states held over it."""
        act = self.actuators
        sp = self.p.steering
        f = self._f_kinematic if self._kinematic else self._f
        x = self._x
        ax0 = self._ax
        # actuators: servo rate (the model clips it to its published limit) and a_x's lag
        steer_rate = _clip((steer_target - x[2]) / act.steer_time_constant_s, sp.v_min, sp.v_max)
        jerk = act.max_jerk_mps3
        d_ax = _clip((accel_cmd - ax0) / act.accel_time_constant_s, -jerk, jerk)
        ax1 = _clip(ax0 + h * d_ax, -act.max_decel_mps2, act.max_accel_mps2)
        # hold the acceleration at the sub-step's mid value; the brake cannot reverse the car
        a = 0.5 * (ax0 + ax1)
        if x[3] <= 0.0 and a <= 0.0:
            a = 0.0
        u = [steer_rate, a]
        half, sixth = 0.5 * h, h / 6.0
        k1 = f(x, u)
        k2 = f(x, u, k1, half)
        k3 = f(x, u, k2, half)
        k4 = f(x, u, k3, h)
        new = [
            xi + sixth * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
            for xi, a1, a2, a3, a4 in zip(x, k1, k2, k3, k4, strict=True)
        ]
        if new[3] < 0.0:  # came to rest inside the sub-step: stay at rest
            new[3] = 0.0
            if not self._kinematic and self.model != "kinematic":
                self._x = new
                s = self.state()
                new = [s.x_m, s.y_m, s.steer_rad, 0.0, s.yaw_rad]
                self._kinematic = True
        self._x = new
        self._ax = ax1


def _linear(spec: PlantSpec) -> Plant:
    if spec.vehicle is not None:
        raise ValueError(
            "the linear plant is the controllers' own design car; --vehicle applies to the CommonRoad "
            "plants (kinematic, single_track, single_track_drift, multi_body)"
        )
    if spec.road != "dry":
        raise ValueError("the linear plant has linear tyres without a friction limit; use --road dry")
    return LinearPlant(steer_delay_s=spec.steer_delay_s)


def _commonroad(model: str) -> Callable[[PlantSpec], Plant]:
    def build(spec: PlantSpec) -> Plant:
        return CommonRoadPlant(
            model,
            spec.vehicle or "bmw320i",
            spec.road,
            ActuatorConfig(steer_delay_s=spec.steer_delay_s),
        )

    build.__doc__ = f"CommonRoad's {model.replace('_', ' ')} model with a published parameter set."
    return build


PLANTS: Registry[Callable[[PlantSpec], Plant]] = Registry(
    "plant",
    {
        "linear": _linear,
        "kinematic": _commonroad("kinematic"),
        "single_track": _commonroad("single_track"),
        "single_track_drift": _commonroad("single_track_drift"),
        "multi_body": _commonroad("multi_body"),
    },
)
"""Plants by name: ``PLANTS[name](spec)`` builds one for a :class:`PlantSpec`."""


@dataclass(frozen=True)
class PlantSpec:
    """Which plant the closed loop steers: ``plant`` (a name of :data:`PLANTS`), ``vehicle`` (a name
    of :data:`VEHICLES`; ``None``: the BMW 320i on the CommonRoad plants, the design car on
    ``linear``), ``road`` (``dry`` or ``wet``) and the steering transport delay in seconds (whole
    0.01 s steps, the closed loop's period)."""

    plant: str = "linear"
    vehicle: str | None = None
    road: str = "dry"
    steer_delay_s: float = 0.0

    def check(self) -> None:
        """Raise ``UnknownNameError``/``ValueError`` for an unknown name or a bad combination."""
        PLANTS[self.plant]  # each look-up raises on an unknown name
        if self.vehicle is not None:
            VEHICLES[self.vehicle]
        ROADS[self.road]
        if not 0.0 <= self.steer_delay_s <= 0.5:
            raise ValueError(f"steering delay {self.steer_delay_s} s is outside 0–0.5 s")
        if abs(self.steer_delay_s * 100.0 - round(self.steer_delay_s * 100.0)) > 1e-6:
            raise ValueError(f"steering delay {self.steer_delay_s} s is not a whole number of 0.01 s steps")

    def build(self) -> Plant:
        """The plant, checked first (:meth:`check`)."""
        self.check()
        return PLANTS[self.plant](self)

    @property
    def mu(self) -> float:
        """The road's peak friction coefficient."""
        return ROADS[self.road]

    def describe(self) -> dict[str, Any]:
        """Name, vehicle, road, μ and delay (for metrics and reports)."""
        vehicle = (
            self.vehicle if self.vehicle is not None else ("design" if self.plant == "linear" else "bmw320i")
        )
        return {
            "plant": self.plant,
            "vehicle": vehicle,
            "road": self.road,
            "mu": self.mu,
            "steer_delay_s": self.steer_delay_s,
        }
