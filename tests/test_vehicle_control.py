"""Single-track vehicle model, lateral controllers with their gain design, and the stop controller
(SPEC §6, seed 003)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from makeway.control import (
    LATERAL_CONTROLLERS,
    FeedforwardFeedback,
    LongitudinalController,
    PurePursuit,
    Stanley,
    default_gains,
    design_gains,
    path_error_model,
)
from makeway.control.lateral import DESIGN_RESIDUAL_DELAY_S
from makeway.messages import ControlCommand, ReferencePath, TrackingErrors, VehicleState
from makeway.plan.path import make_path
from makeway.sim.vehicle import SingleTrackModel
from makeway.vehicle import VehicleParams, lateral_dynamics_matrices

P = VehicleParams()
DT = 0.01


def _path(x: np.ndarray, y: np.ndarray) -> ReferencePath:
    """A ReferencePath from points (the planner's own constructor)."""
    return make_path(x, y)


def _straight(length: float = 400.0, spacing: float = 0.5) -> ReferencePath:
    x = np.arange(0.0, length, spacing)
    return _path(x, np.zeros_like(x))


def _circle(radius: float, turn: int = 1, length: float = 400.0, spacing: float = 0.5) -> ReferencePath:
    th = np.arange(0.0, length, spacing) / radius
    return _path(radius * np.sin(th), turn * radius * (1.0 - np.cos(th)))


def _lane_change(width: float = 3.5, length: float = 60.0, spacing: float = 0.5) -> ReferencePath:
    """Straight 60 m, a quintic lane change of ``width`` over ``length``, straight 120 m."""
    x = np.arange(0.0, 60.0 + length + 120.0, spacing)
    t = np.clip((x - 60.0) / length, 0.0, 1.0)
    return _path(x, width * (10 * t**3 - 15 * t**4 + 6 * t**5))


def _drive(
    controller: object, path: ReferencePath, start: VehicleState, seconds: float
) -> tuple[list[TrackingErrors], list[VehicleState], np.ndarray]:
    model = SingleTrackModel(P)
    state, hint = start, None
    errors, states, commands = [], [], []
    for _ in range(round(seconds / DT)):
        delta, err, hint = controller.steer(state, path, hint)  # type: ignore[attr-defined]
        errors.append(err)
        states.append(state)
        commands.append(delta)
        state = model.step(state, ControlCommand(state.time_s, delta, 0.0), DT)
    return errors, states, np.array(commands)


def _e_lat(errors: list[TrackingErrors]) -> np.ndarray:
    return np.array([e.e_lat for e in errors])


# ============================================================================================ vehicle


def test_params_wheelbase_and_understeer() -> None:
    assert abs(P.L - 2.8) < 1e-12
    assert P.wheelbase_m == P.L
    k_us = P.mass_kg / P.L * (P.b_m / P.cf_npr - P.a_m / P.cr_npr)
    assert P.understeer_gradient == pytest.approx(k_us)
    assert P.understeer_gradient > 0.0  # understeering sedan
    # about 1.5 deg/g
    assert 1.0 < math.degrees(P.understeer_gradient * 9.81) < 2.5


def test_lateral_matrices_are_seed_equations() -> None:
    vx, vy, r, delta = 12.0, 0.1, 0.05, 0.02
    A, B = lateral_dynamics_matrices(P, vx)
    m, iz, a, b, cf, cr = P.mass_kg, P.yaw_inertia_kgm2, P.a_m, P.b_m, P.cf_npr, P.cr_npr
    dvy = (cf * delta - (cf + cr) / vx * vy - (a * cf - b * cr) / vx * r) / m - vx * r
    dr = (a * cf * delta - (a * cf - b * cr) / vx * vy - (a * a * cf + b * b * cr) / vx * r) / iz
    np.testing.assert_allclose((A @ [vy, r] + B[:, 0] * delta), [dvy, dr], rtol=1e-12)
    for speed in (1.0, 10.0, 40.0):
        assert np.all(np.linalg.eigvals(lateral_dynamics_matrices(P, speed)[0]).real < 0.0)
    with pytest.raises(ValueError):
        lateral_dynamics_matrices(P, 0.0)


@pytest.mark.parametrize("speed", [8.0, 15.0, 25.0, 30.0])
def test_steady_state_cornering_matches_understeer_formula(speed: float) -> None:
    model = SingleTrackModel(P)
    delta = 0.02
    state = VehicleState(0.0, 0.0, 0.0, 0.0, speed)
    for _ in range(1500):
        state = model.step(state, ControlCommand(state.time_s, delta, 0.0), DT)
    radius = state.vx_mps / state.yaw_rate_radps
    predicted = P.L / radius + P.understeer_gradient * speed**2 / radius
    assert predicted == pytest.approx(delta, rel=0.02)
    assert state.steer_rad == pytest.approx(delta, rel=1e-6)


def test_straight_line_stays_straight() -> None:
    model = SingleTrackModel(P)
    state = VehicleState(0.0, 3.0, -2.0, 0.4, 20.0)
    for _ in range(1000):
        state = model.step(state, ControlCommand(state.time_s, 0.0, 0.0), DT)
    assert state.yaw_rad == pytest.approx(0.4, abs=1e-12)
    assert state.vy_mps == 0.0 and state.yaw_rate_radps == 0.0
    assert state.x_m == pytest.approx(3.0 + 200.0 * math.cos(0.4), abs=1e-9)
    assert state.y_m == pytest.approx(-2.0 + 200.0 * math.sin(0.4), abs=1e-9)
    assert state.time_s == pytest.approx(10.0)


def test_braking_stops_without_reversing_and_stays_stopped() -> None:
    model = SingleTrackModel(P)
    state = VehicleState(0.0, 0.0, 0.0, 0.0, 10.0, steer_rad=0.1)
    xs, vs, axs = [], [], []
    for _ in range(600):
        state = model.step(state, ControlCommand(state.time_s, 0.1, -8.0), DT)  # beyond the brake limit
        xs.append(state.x_m)
        vs.append(state.vx_mps)
        axs.append(state.ax_mps2)
    assert min(vs) >= 0.0
    assert vs[-1] == 0.0
    assert np.all(np.diff(xs) >= -1e-12)  # never rolls back
    assert min(axs) >= -P.max_decel_mps2 - 1e-9
    assert np.max(np.abs(np.diff([0.0, *axs]))) <= P.max_jerk_mps3 * DT + 1e-9
    # at rest the car neither yaws nor slides
    assert state.yaw_rate_radps == 0.0 and state.vy_mps == 0.0
    # about 10²/(2·6) ≈ 8.3 m plus the actuator's ramp-up
    assert 8.0 < xs[-1] < 12.0


def test_step_steer_converges_and_respects_actuator_limits() -> None:
    model = SingleTrackModel(P)
    state = VehicleState(0.0, 0.0, 0.0, 0.0, 15.0)
    steer, rates = [], []
    for _ in range(800):
        state = model.step(state, ControlCommand(state.time_s, 0.05, 0.0), DT)
        steer.append(state.steer_rad)
        rates.append(state.yaw_rate_radps)
    assert np.max(np.abs(np.diff([0.0, *steer]))) <= P.max_steer_rate_radps * DT + 1e-9
    r_ss = 15.0 * 0.05 / (P.L + P.understeer_gradient * 15.0**2)
    assert rates[-1] == pytest.approx(r_ss, rel=1e-4)
    assert np.ptp(rates[-100:]) < 1e-5
    # a command beyond lock is held at lock
    for _ in range(300):
        state = model.step(state, ControlCommand(state.time_s, 2.0, 0.0), DT)
    assert state.steer_rad == pytest.approx(P.max_steer_rad)


def _smooth_run(max_substep_s: float) -> np.ndarray:
    model = SingleTrackModel(dataclasses.replace(P, max_substep_s=max_substep_s))
    state = VehicleState(0.0, 0.0, 0.0, 0.0, 15.0)
    for _ in range(300):
        state = model.step(state, ControlCommand(state.time_s, 0.03, 0.3), DT)
    return np.array([state.x_m, state.y_m, state.yaw_rad, state.vx_mps, state.vy_mps, state.yaw_rate_radps])


def test_rk4_refinement_converges_at_fourth_order() -> None:
    reference = _smooth_run(0.000625)
    errors = [float(np.max(np.abs(_smooth_run(h) - reference))) for h in (0.01, 0.005, 0.0025)]
    assert errors[0] < 1e-6
    assert errors[0] / errors[1] > 10.0 and errors[1] / errors[2] > 10.0


def test_control_period_refinement_converges() -> None:
    def run(dt: float) -> np.ndarray:
        model = SingleTrackModel(P)
        state = VehicleState(0.0, 0.0, 0.0, 0.0, 12.0)
        for _ in range(round(4.0 / dt)):
            cmd = ControlCommand(state.time_s, 0.04 * math.sin(state.time_s), 0.0)
            state = model.step(state, cmd, dt)
        return np.array([state.x_m, state.y_m, state.yaw_rad])

    # the command is held over each period (zero-order hold): first-order convergence in dt
    reference = run(0.001)
    errors = [float(np.max(np.abs(run(dt) - reference))) for dt in (0.04, 0.02, 0.01)]
    assert errors[0] / errors[1] > 1.8 and errors[1] / errors[2] > 1.8
    assert errors[2] < 0.02


def test_low_speed_blends_into_kinematic_model() -> None:
    model = SingleTrackModel(P)
    for speed in (0.5, 1.0):
        state = VehicleState(0.0, 0.0, 0.0, 0.0, speed)
        for _ in range(500):
            state = model.step(state, ControlCommand(state.time_s, 0.3, 0.0), DT)
        kinematic = speed * math.tan(0.3) / P.L
        assert state.yaw_rate_radps == pytest.approx(kinematic, rel=1e-3)
        assert state.vy_mps == pytest.approx(P.b_m * kinematic, rel=1e-3)
    # starting from rest with the wheel turned: finite, smooth, and turning the right way
    state = VehicleState(0.0, 0.0, 0.0, 0.0, 0.0, steer_rad=0.3)
    for _ in range(600):
        state = model.step(state, ControlCommand(state.time_s, 0.3, 1.0), DT)
    assert all(math.isfinite(v) for v in dataclasses.astuple(state))
    assert state.yaw_rad > 0.0 and state.vx_mps > 4.0


# ======================================================================================= gain design


def test_gain_schedule_is_stable_with_margin_everywhere() -> None:
    gains = default_gains(P)
    assert gains.speeds_mps[0] == 5.0 and gains.speeds_mps[-1] == 30.0
    assert gains.eigenvalues.shape == (26, 5)
    assert gains.max_real_eigenvalue() < -0.5
    assert np.all(gains.k_e > 0.0) and np.all(gains.k_theta > 0.0) and np.all(gains.k_omega > 0.0)
    # the eigenvalues are those of A − B K C
    A, B, C = path_error_model(P, 13.0)
    K = np.array([[gains.k_e[8], gains.k_theta[8], gains.k_omega[8]]])
    np.testing.assert_allclose(
        np.sort_complex(np.linalg.eigvals(A - B @ K @ C)), np.sort_complex(gains.eigenvalues[8]), rtol=1e-9
    )
    # interpolated between grid speeds (still stable there), clamped outside
    for v in np.arange(5.0, 30.0, 0.37):
        A, B, C = path_error_model(P, float(v))
        K = np.array([gains.gains(float(v))])
        assert np.max(np.linalg.eigvals(A - B @ K @ C).real) < -0.5
    assert gains.gains(2.0) == gains.gains(5.0)
    assert gains.gains(45.0) == gains.gains(30.0)
    k_lo, k_hi = gains.gains(13.0), gains.gains(14.0)
    assert gains.gains(13.5) == pytest.approx(tuple((a + b) / 2 for a, b in zip(k_lo, k_hi, strict=True)))


def test_gain_design_is_cached() -> None:
    """The design runs once per parameter set: the same parameters give the very same object,
    other parameters another design (how long a design takes is a benchmark's matter, not a test's)."""
    params = dataclasses.replace(P, mass_kg=1700.0)  # not yet in the cache
    gains = default_gains(params)
    assert default_gains(params) is gains
    assert default_gains(dataclasses.replace(params)) is gains  # equal parameters, another instance
    assert default_gains(P) is not gains and default_gains(P).gains(13.0) != gains.gains(13.0)
    assert gains.max_real_eigenvalue() < -0.5


def test_gain_design_optimum_beats_its_start_and_neighbours() -> None:
    from makeway.control.lateral import _lqr_cost

    single = design_gains(P, [13.4])
    # the design model with the 0.05 s residual steering delay (a Padé state) the gains tolerate
    A, B, C = path_error_model(P, 13.4, DESIGN_RESIDUAL_DELAY_S)
    Q = np.diag([1 / 0.02**2, 0.0, 1 / 0.05**2, 1 / 0.2**2, 0.0, 0.0])
    R = np.array([[1 / 0.05**2]])
    X0 = np.diag(np.array([0.5, 0.2, 0.05, 0.05, 0.01, 0.01]) ** 2)
    k = np.array([single.k_e[0], single.k_theta[0], single.k_omega[0]])
    best, grad = _lqr_cost(k, A, B, C, Q, R, X0)
    assert best == pytest.approx(single.cost[0])
    assert np.max(np.abs(grad)) < 1e-3 * best
    for i in range(3):
        for f in (0.9, 1.1):
            other = k.copy()
            other[i] *= f
            assert _lqr_cost(other, A, B, C, Q, R, X0)[0] > best


# ===================================================================================== lateral control


def test_registry_controllers_share_the_interface() -> None:
    assert set(LATERAL_CONTROLLERS) == {"ffb", "stanley", "pure_pursuit"}
    path = _straight()
    start = VehicleState(0.0, 0.0, 0.3, 0.0, 13.4)
    for cls in LATERAL_CONTROLLERS.values():
        delta, err, index = cls(P).steer(start, path, None)
        assert isinstance(err, TrackingErrors) and isinstance(index, int)
        assert err.e_lat == pytest.approx(0.3)
        assert delta < 0.0  # left of the path: steer right


def test_ffb_converges_from_an_offset_on_a_straight() -> None:
    errors, _, commands = _drive(FeedforwardFeedback(P), _straight(), VehicleState(0, 0, 0.5, 0, 13.4), 12.0)
    e = _e_lat(errors)
    assert e[0] == pytest.approx(0.5)
    assert np.max(np.abs(e[300:])) < 0.02  # within 3 s
    assert np.max(np.abs(e[-200:])) < 1e-3
    assert np.min(e) > -0.05  # little overshoot
    assert np.max(np.abs(commands)) <= P.max_steer_rad


@pytest.mark.parametrize("turn", [1, -1])
def test_ffb_on_a_circle_steady_error_small(turn: int) -> None:
    errors, _, _ = _drive(FeedforwardFeedback(P), _circle(100.0, turn), VehicleState(0, 0, 0, 0, 15.0), 20.0)
    e = _e_lat(errors)
    assert np.max(np.abs(e[-500:])) < 0.02
    assert np.max(np.abs(e)) < 0.05
    assert errors[-1].kind == "arc" and errors[-1].curvature_1pm == pytest.approx(turn / 100.0, rel=1e-3)


def _steady_start(radius: float, speed: float) -> VehicleState:
    """The linear model's steady cornering on the circle of ``_circle``, at its start."""
    kappa = 1.0 / radius
    vy = (P.b_m - P.mass_kg * P.a_m * speed**2 / (P.L * P.cr_npr)) * speed * kappa
    delta = P.L * kappa + P.understeer_gradient * speed**2 * kappa
    return VehicleState(0.0, 0.0, 0.0, -math.atan2(vy, speed), speed, vy, speed * kappa, delta)


class _FeedforwardOnly(FeedforwardFeedback):
    def steer(self, state: VehicleState, path: ReferencePath, hint: int | None = None):  # type: ignore[no-untyped-def]
        errors, index, _ = self._errors(state, path, hint)
        return self.feedforward(errors.curvature_1pm, state.vx_mps), errors, index


def test_feedforward_does_the_work_on_a_circle() -> None:
    path = _circle(100.0)
    start = _steady_start(100.0, 15.0)
    # δ_ff alone keeps the car on the circle once it is cornering steadily
    ff_only, _, _ = _drive(_FeedforwardOnly(P), path, start, 15.0)
    assert np.max(np.abs(_e_lat(ff_only))) < 0.02
    # feedback alone (no δ_ff, no sideslip term) needs a standing error to hold the steering
    no_ff = FeedforwardFeedback(P, sideslip_compensation=False)
    no_ff.feedforward = lambda curvature_1pm, vx: 0.0  # type: ignore[method-assign]
    fb_only, _, _ = _drive(no_ff, path, start, 15.0)
    # (k_e ≈ 0.71 rad/m at 15 m/s: a couple of centimetres for the 0.034 rad this circle needs)
    assert np.max(np.abs(_e_lat(fb_only)[-300:])) > 0.01


def test_seed_law_keeps_a_sideslip_offset_that_the_compensation_removes() -> None:
    path = _circle(100.0)
    seed, _, _ = _drive(
        FeedforwardFeedback(P, sideslip_compensation=False), path, VehicleState(0, 0, 0, 0, 15.0), 20.0
    )
    comp, _, _ = _drive(FeedforwardFeedback(P), path, VehicleState(0, 0, 0, 0, 15.0), 20.0)
    ctrl = FeedforwardFeedback(P)
    k_e, k_theta, _ = ctrl.gains.gains(15.0)
    # seed law, steady: δ_fb = −k_e e − k_θ θ̃_ss = 0, so e = −k_θ θ̃_ss / k_e (about +4 cm here)
    predicted = -k_theta * ctrl.steady_yaw_error(0.01, 15.0) / k_e
    assert _e_lat(seed)[-1] == pytest.approx(predicted, rel=0.05)
    assert abs(_e_lat(comp)[-1]) < 1e-3 < abs(predicted)


def test_ffb_beats_stanley_and_pure_pursuit_on_a_lane_change() -> None:
    path = _lane_change()
    start = VehicleState(0.0, 0.0, 0.0, 0.0, 13.4)
    worst = {}
    for name, cls in LATERAL_CONTROLLERS.items():
        errors, states, _ = _drive(cls(P), path, start, 14.0)
        worst[name] = float(np.max(np.abs(_e_lat(errors))))
        assert states[-1].y_m == pytest.approx(3.5, abs=0.05)  # all complete the change
    assert worst["ffb"] < 0.05
    assert worst["ffb"] < worst["stanley"]
    assert worst["ffb"] < worst["pure_pursuit"]


def test_baseline_parameters_are_used() -> None:
    path = _lane_change()
    start = VehicleState(0.0, 0.0, 0.0, 0.0, 13.4)
    short, _, _ = _drive(PurePursuit(P, lookahead_time_s=0.4), path, start, 10.0)
    long, _, _ = _drive(PurePursuit(P, lookahead_time_s=1.2), path, start, 10.0)
    assert np.max(np.abs(_e_lat(long))) > np.max(np.abs(_e_lat(short)))  # pure pursuit cuts corners
    soft, _, _ = _drive(Stanley(P, k=0.5), path, start, 10.0)
    stiff, _, _ = _drive(Stanley(P, k=5.0), path, start, 10.0)
    assert np.max(np.abs(_e_lat(soft))) > np.max(np.abs(_e_lat(stiff)))


# ================================================================================ longitudinal control


def _stop_run(
    v0: float, stop_x: float, seconds: float = 20.0, target: float = 13.4
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    model = SingleTrackModel(P)
    ctrl = LongitudinalController()
    state = VehicleState(0.0, 0.0, 0.0, 0.0, v0)
    xs, vs, cmds, axs = [], [], [], []
    for _ in range(round(seconds / DT)):
        a = ctrl.accel(state, target, stop_x - state.x_m)
        cmds.append(a)
        state = model.step(state, ControlCommand(state.time_s, 0.0, a), DT)
        xs.append(state.x_m)
        vs.append(state.vx_mps)
        axs.append(state.ax_mps2)
    return np.array(xs), np.array(vs), np.array(cmds), np.array(axs)


def test_stop_at_a_point_from_30_mph_within_comfort_limits() -> None:
    ctrl = LongitudinalController()
    xs, vs, cmds, axs = _stop_run(13.4, 80.0)
    assert abs(xs[-1] - 80.0) < 0.5
    assert np.max(xs) - 80.0 < 0.5
    assert vs[-1] == 0.0 and np.min(vs) >= 0.0
    stopped = np.nonzero(vs == 0.0)[0][0]
    assert np.all(vs[stopped:] == 0.0)  # stays stopped
    assert np.ptp(xs[stopped:]) == 0.0
    assert np.min(cmds) >= -ctrl.max_decel - 1e-9 and np.max(cmds) <= ctrl.max_accel + 1e-9
    assert np.max(np.abs(np.diff(cmds))) <= ctrl.max_jerk * DT + 1e-9
    assert np.min(axs) >= -ctrl.max_decel - 1e-9
    assert np.max(np.abs(np.diff(axs))) <= ctrl.max_jerk * DT + 1e-9
    # the deceleration has eased off by the time the car comes to rest (no stopping jolt)
    assert abs(axs[stopped - 1]) < 0.5


@pytest.mark.parametrize(("v0", "stop_x"), [(13.4, 150.0), (8.0, 60.0), (0.0, 20.0), (0.0, 0.5)])
def test_stop_at_a_point_from_other_starts(v0: float, stop_x: float) -> None:
    xs, vs, cmds, _ = _stop_run(v0, stop_x, seconds=25.0)
    assert abs(xs[-1] - stop_x) < 0.3
    assert vs[-1] == 0.0
    assert np.max(np.abs(np.diff(cmds))) <= 2.5 * DT + 1e-9


def test_speed_keeping_and_release() -> None:
    model = SingleTrackModel(P)
    ctrl = LongitudinalController()
    state = VehicleState(0.0, 0.0, 0.0, 0.0, 8.0)
    for _ in range(2000):
        state = model.step(state, ControlCommand(state.time_s, 0.0, ctrl.accel(state, 13.4, None)), DT)
    assert state.vx_mps == pytest.approx(13.4, abs=0.05)
    # held at a stop, then released: drives off again
    ctrl.reset()
    state = VehicleState(0.0, 0.0, 0.0, 0.0, 0.0)
    for _ in range(200):
        state = model.step(state, ControlCommand(state.time_s, 0.0, ctrl.accel(state, 13.4, 0.0)), DT)
    assert ctrl.mode == "hold" and state.vx_mps == 0.0
    for _ in range(500):
        state = model.step(state, ControlCommand(state.time_s, 0.0, ctrl.accel(state, 13.4, None)), DT)
    assert state.vx_mps > 3.0
