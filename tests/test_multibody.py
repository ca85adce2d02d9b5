"""Our writing-out of CommonRoad's multi-body model (makeway.sim.multibody) against the package's
own ``vehicle_dynamics_mb``: the same derivative to rounding on random states of every car and road."""

from __future__ import annotations

import math

import numpy as np
import pytest
from vehiclemodels.init_mb import init_mb
from vehiclemodels.vehicle_dynamics_mb import vehicle_dynamics_mb

from makeway.sim.multibody import multibody_rhs
from makeway.sim.plants import VEHICLES, vehicle_parameters

# spread of each state about the package's own initial state (init_mb) for a random motion:
# body roll/pitch and their rates, heights, unsprung masses, wheel speeds (±3 rad/s: slip of a few
# per cent up to wheel spin and lock-up) and the compliant joints
SPREAD = [0, 0, 0, 0, 0, 0, 0.03, 0.2, 0.02, 0.1, 0.5, 0.02, 0.1]
SPREAD += [0.02, 0.2, 0.5, 0.005, 0.1] * 2 + [3.0] * 4 + [0.002, 0.002]


def _random_states(p: object, rng: np.random.Generator, n: int) -> list[list[float]]:
    out = []
    for _ in range(n):
        core = [
            rng.uniform(-100, 100),
            rng.uniform(-100, 100),
            rng.uniform(-0.4, 0.4),  # wheel angle
            rng.uniform(0.5, 40.0),  # speed
            rng.uniform(-math.pi, math.pi),
            rng.uniform(-0.8, 0.8),  # yaw rate
            rng.uniform(-0.3, 0.3),  # slip angle
        ]
        x = np.asarray(init_mb(core, p), dtype=float) + rng.normal(size=29) * np.asarray(SPREAD)
        out.append([float(v) for v in x])
    return out


def _agree(ref: list[float], ours: list[float]) -> float:
    """Worst difference relative to the component's own size (and an absolute 1e-12 in SI units
    below that: a derivative that cancels to ~1e-15 on one side may be exactly 0 on the other)."""
    return max(abs(a - b) / (abs(a) + 1e-3) for a, b in zip(ref, ours, strict=True))


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("vehicle", list(VEHICLES))
def test_the_derivative_is_commonroad_s_on_random_states(vehicle: str, seed: int) -> None:
    mu = (1.0, 0.5)[seed]  # dry, wet
    p = vehicle_parameters(vehicle, mu)
    f = multibody_rhs(p)
    rng = np.random.default_rng([seed, list(VEHICLES).index(vehicle)])
    worst = 0.0
    for x in _random_states(p, rng, 150):
        u = [float(rng.uniform(-0.8, 0.8)), float(rng.uniform(-14.0, 14.0))]  # beyond both limits
        before = list(x)
        ours = f(x, u)
        assert x == before  # the state is not written into
        ref = vehicle_dynamics_mb(list(x), u, p)
        assert len(ours) == 29
        worst = max(worst, _agree(ref, ours))
    assert worst <= 1e-9


def test_the_limits_and_corner_cases_are_commonroad_s() -> None:
    p = vehicle_parameters("bmw320i", 1.0)
    f = multibody_rhs(p)
    base = init_mb([0.0, 0.0, 0.0, 20.0, 0.3, 0.1, 0.02], p)
    cases = []
    for delta, rate in ((p.steering.max, 0.3), (p.steering.min, -0.3), (p.steering.max, -0.3)):
        x = list(base)
        x[2] = delta  # at the steering lock, turning further or back
        cases.append((x, [rate, 1.0]))
    x = list(base)
    x[23], x[26] = -1.0, -0.5  # wheels spinning backwards: their derivative is held at zero
    cases.append((x, [0.0, -3.0]))
    x = list(base)
    x[3] = p.longitudinal.v_max + 1.0  # above the top speed: no more drive
    cases.append((x, [0.0, 2.0]))
    x = list(base)
    x[3], x[10] = 0.05, 0.01  # below 0.1 m/s: the kinematic branch
    cases.append((x, [0.1, 1.0]))
    for x, u in cases:
        assert _agree(vehicle_dynamics_mb(list(x), u, p), f(x, u)) <= 1e-9, (x[:4], u)
    # reversing spins the wheels backwards through a zero wheel speed: both divide by zero
    x = list(base)
    x[3] = -5.0
    with pytest.raises(ZeroDivisionError):
        vehicle_dynamics_mb(list(x), [0.0, 0.0], p)
    with pytest.raises(ZeroDivisionError):
        f(x, [0.0, 0.0])


def test_a_runge_kutta_stage_is_the_derivative_at_the_stage_state() -> None:
    p = vehicle_parameters("vw_vanagon", 0.5)
    f = multibody_rhs(p)
    rng = np.random.default_rng(3)
    for x in _random_states(p, rng, 40):
        u = [float(rng.uniform(-0.3, 0.3)), float(rng.uniform(-3.0, 3.0))]
        k = f(x, u)
        for c in (0.0005, 0.001):
            stage = [xi + c * ki for xi, ki in zip(x, k, strict=True)]
            assert f(x, u, k, c) == f(stage, u)  # the same arithmetic: bit for bit
    x = _random_states(p, rng, 1)[0]
    x[3] = 0.05  # the kinematic branch takes the stage's state as well
    k = [0.0] * 29
    k[3], k[0] = 10.0, 1.0
    stage = [xi + 0.001 * ki for xi, ki in zip(x, k, strict=True)]
    assert f(x, [0.0, 0.5], k, 0.001) == f(stage, [0.0, 0.5])


def test_the_plant_drives_as_on_commonroad_s_own_function() -> None:
    # the same manoeuvre (a steering sine while braking, into the stiff low-speed wheel modes) on
    # the plant as shipped and on the plant with the package's vehicle_dynamics_mb
    from makeway.messages import ControlCommand, VehicleState
    from makeway.sim.plants import ActuatorConfig, CommonRoadPlant, _bound

    runs = []
    for ours in (True, False):
        plant = CommonRoadPlant("multi_body", "ford_escort", "wet", ActuatorConfig(steer_delay_s=0.1))
        if not ours:
            plant._f = _bound(vehicle_dynamics_mb)(plant.p)
        plant.reset(VehicleState(0.0, 0.0, 0.0, 0.2, 9.0))
        states = []
        for i in range(250):
            steer = 0.06 * math.sin(2.0 * math.pi * 0.5 * i * 0.01)
            states.append(plant.advance(ControlCommand(i * 0.01, steer, -2.5), 0.01))
        runs.append(states)
    assert runs[0][-1].vx_mps < 4.0  # it did brake into the slow, stiff regime
    for a, b in zip(*runs, strict=True):
        assert math.hypot(a.x_m - b.x_m, a.y_m - b.y_m) < 1e-9
        assert abs(a.yaw_rad - b.yaw_rad) < 1e-11 and abs(a.vy_mps - b.vy_mps) < 1e-9
