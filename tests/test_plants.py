"""The plants behind one interface (issue 30): CommonRoad's vehicle models with published cars, wet
roads, a delayed steering actuator, the car's noisy estimate of itself, and the command line."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from makeway.cli.main import app
from makeway.control import FeedforwardFeedback
from makeway.control.delay import DelayCompensated, predict_state
from makeway.messages import ControlCommand, VehicleState
from makeway.sim.localization import LOCALIZATIONS, Localization
from makeway.sim.plants import (
    PLANTS,
    RK4_REAL_STABILITY,
    CommonRoadPlant,
    DelayLine,
    LinearPlant,
    PlantSpec,
    vehicle_parameters,
)
from makeway.sim.vehicle import SingleTrackModel
from makeway.vehicle import VehicleParams

COMMONROAD = ["kinematic", "single_track", "single_track_drift", "multi_body"]
DT = 0.01
runner = CliRunner()


def _drive(plant: object, steer: float, accel: float, seconds: float) -> list[VehicleState]:
    out = []
    for i in range(round(seconds / DT)):
        out.append(plant.advance(ControlCommand(i * DT, steer, accel), DT))  # type: ignore[attr-defined]
    return out


@pytest.mark.parametrize("model", COMMONROAD)
@pytest.mark.parametrize("vehicle", ["ford_escort", "bmw320i", "vw_vanagon"])
def test_state_round_trips_through_each_model(model: str, vehicle: str) -> None:
    plant = CommonRoadPlant(model, vehicle)
    p = plant.p
    delta, vx = 0.03, 12.0
    if model == "kinematic":  # no slip: v_y and r follow from δ
        r = vx * math.tan(delta) / (p.a + p.b)
        vy = p.b * r
    else:
        r, vy = 0.08, 0.15
    s = VehicleState(2.5, 10.0, -4.0, 0.7, vx, vy, r, delta, -1.0)
    plant.reset(s)
    back = plant.state()
    for name in (
        "time_s",
        "x_m",
        "y_m",
        "yaw_rad",
        "vx_mps",
        "vy_mps",
        "yaw_rate_radps",
        "steer_rad",
        "ax_mps2",
    ):
        assert getattr(back, name) == pytest.approx(getattr(s, name), abs=1e-9), name


@pytest.mark.parametrize("name", list(PLANTS))
def test_a_straight_drive_stays_straight(name: str) -> None:
    plant = PlantSpec(plant=name).build()
    plant.reset(VehicleState(0.0, 0.0, 0.0, 0.0, 13.4))
    states = _drive(plant, 0.0, 0.0, 2.0)
    last = states[-1]
    # the Pacejka tyres' own small lateral offsets (rolling slip × r_vy*) pull by millimetres
    tol = 0.01 if name in ("single_track_drift", "multi_body") else 1e-6
    assert abs(last.y_m) < tol and abs(last.yaw_rad) < tol / 10
    assert last.x_m == pytest.approx(13.4 * 2.0, rel=0.01)
    assert last.vx_mps == pytest.approx(13.4, abs=0.15)


def test_commonroad_single_track_agrees_with_our_linear_model_on_its_parameters() -> None:
    # both are single-track models; build ours from the BMW's published parameters (cornering
    # stiffness per axle = −p_ky1 · static axle load) and the same actuators, then step-steer
    p = vehicle_parameters("bmw320i", 1.0)
    L = p.a + p.b
    mg = p.m * 9.81
    ours = VehicleParams(
        mass_kg=p.m,
        yaw_inertia_kgm2=p.I_z,
        a_m=p.a,
        b_m=p.b,
        cf_npr=-p.tire.p_ky1 * mg * p.b / L,
        cr_npr=-p.tire.p_ky1 * mg * p.a / L,
        steer_time_constant_s=0.08,
        max_steer_rate_radps=0.4,
    )
    linear = LinearPlant(ours)
    st = CommonRoadPlant("single_track", "bmw320i")
    start = VehicleState(0.0, 0.0, 0.0, 0.0, 15.0)
    linear.reset(start)
    st.reset(start)
    a, b = _drive(linear, 0.02, 0.0, 3.0), _drive(st, 0.02, 0.0, 3.0)
    r_lin, r_st = a[-1].yaw_rate_radps, b[-1].yaw_rate_radps
    assert r_lin > 0.05  # a real turn: ~0.1 rad/s
    assert r_st == pytest.approx(r_lin, rel=0.03)
    assert max(abs(s1.y_m - s2.y_m) for s1, s2 in zip(a, b, strict=True)) < 0.1


def _peak_horizontal_accel(states: list[VehicleState]) -> float:
    """Largest |a| of the CG (world frame, finite differences of the world velocity)."""
    vx = np.array([s.vx_mps * math.cos(s.yaw_rad) - s.vy_mps * math.sin(s.yaw_rad) for s in states])
    vy = np.array([s.vx_mps * math.sin(s.yaw_rad) + s.vy_mps * math.cos(s.yaw_rad) for s in states])
    acc = np.hypot(np.diff(vx), np.diff(vy)) / DT
    return float(np.max(np.convolve(acc, np.ones(5) / 5, mode="valid")))


@pytest.mark.parametrize("model", ["single_track_drift", "multi_body"])
def test_on_a_wet_road_a_large_steer_saturates_near_mu_g(model: str) -> None:
    peaks = {}
    for road in ("wet", "dry"):
        plant = CommonRoadPlant(model, "bmw320i", road)
        plant.reset(VehicleState(0.0, 0.0, 0.0, 0.0, 20.0))
        # a 0.1 rad steer at 20 m/s asks for ~15 m/s² (v² δ / L): far beyond either road
        peaks[road] = _peak_horizontal_accel(_drive(plant, 0.1, 0.0, 1.5))
    # wet: the tyres saturate at μ g = 4.9 m/s² (the car slides on instead of turning harder)
    assert 0.9 * 0.5 * 9.81 < peaks["wet"] < 1.05 * 0.5 * 9.81, peaks
    if model == "single_track_drift":
        assert 0.9 * 9.81 < peaks["dry"] < 1.05 * 9.81, peaks
    # (the multi-body car's suspension and load transfer overshoot μ g transiently when dry)
    assert peaks["dry"] > 1.8 * peaks["wet"], peaks


def test_delay_line_delays_exactly() -> None:
    line = DelayLine(0.15, DT)
    out = [line.push(float(k)) for k in range(100)]
    assert out == [float(max(0, k - 15)) for k in range(100)]
    assert DelayLine(0.0, DT).push(3.0) == 3.0
    with pytest.raises(ValueError, match="whole number"):
        DelayLine(0.155, DT)


def test_the_plant_s_steering_starts_after_the_delay() -> None:
    plant = PlantSpec(plant="multi_body", steer_delay_s=0.15).build()
    plant.reset(VehicleState(0.0, 0.0, 0.0, 0.0, 10.0))
    states = _drive(plant, 0.05, 0.0, 0.3)
    assert all(s.steer_rad == 0.0 for s in states[:15])  # commands from t = 0 act at 0.15 s
    assert states[16].steer_rad > 0.0
    # then the published rate limit, 0.4 rad/s: 0.05 rad takes at least 0.125 s
    assert states[15 + 12].steer_rad < 0.05


def test_delay_prediction_matches_the_design_model_it_predicts_with() -> None:
    # predicting over the pending commands on the design model = what the design model does
    params = VehicleParams()
    plant = LinearPlant(params)
    s0 = VehicleState(0.0, 0.0, 0.0, 0.0, 15.0)
    plant.reset(s0)
    pending = [0.01 * math.sin(0.3 * k) for k in range(15)]
    states = [plant.advance(ControlCommand(k * DT, c, 0.0), DT) for k, c in enumerate(pending)]
    predicted = predict_state(s0, pending, params, DT)
    assert predicted.time_s == pytest.approx(0.15)
    assert predicted.y_m == pytest.approx(states[-1].y_m, abs=2e-3)
    assert predicted.yaw_rad == pytest.approx(states[-1].yaw_rad, abs=2e-4)
    assert predicted.steer_rad == pytest.approx(states[-1].steer_rad, abs=2e-4)


@pytest.mark.parametrize("vx, ax", [(15.0, 0.0), (3.05, -2.0), (1.0, 0.5)])
def test_the_mean_predictor_is_the_mean_of_its_two_predictions(vx: float, ax: float) -> None:
    # the default predictor integrates the design model and the kinematic bicycle in one pass:
    # exactly what each gives on its own (also across the 3 m/s switch to the kinematic model)
    params = VehicleParams()
    s0 = VehicleState(1.0, 3.0, -2.0, 0.4, vx, 0.05, 0.02, 0.01, ax)
    pending = [0.02 * math.sin(0.4 * k) for k in range(15)]
    comp = DelayCompensated(FeedforwardFeedback(params), params, 0.15, DT)
    comp._pending.extend(pending)
    tyres = predict_state(s0, pending, params, DT)
    bicycle = predict_state(s0, pending, params, DT, kinematic_below_mps=math.inf)
    mean = comp.predicted(s0)
    assert mean.x_m == 0.5 * (tyres.x_m + bicycle.x_m)
    assert mean.y_m == 0.5 * (tyres.y_m + bicycle.y_m)
    assert mean.vy_mps == 0.5 * (tyres.vy_mps + bicycle.vy_mps)
    assert mean.yaw_rate_radps == 0.5 * (tyres.yaw_rate_radps + bicycle.yaw_rate_radps)
    assert mean.yaw_rad == pytest.approx(0.5 * (tyres.yaw_rad + bicycle.yaw_rad), abs=1e-15)
    assert (mean.vx_mps, mean.steer_rad) == (tyres.vx_mps, tyres.steer_rad)
    if vx > 3.0:  # below it the design predictor is the kinematic bicycle too
        assert tyres.y_m != bicycle.y_m


def test_rtk_localization_has_its_documented_noise() -> None:
    cfg = LOCALIZATIONS["rtk"]()
    truth = VehicleState(0.0, 5.0, 5.0, 0.3, 10.0, 0.0, 0.02)
    loc = Localization(cfg, seed=3)
    est = [loc.estimate(truth, DT) for _ in range(3000)]
    ex = np.array([e.x_m - truth.x_m for e in est])
    # white noise of 0.02 m on top of a slowly wandering bias: the step-to-step differences show
    # the white part (σ√2), the spread the sum
    assert np.std(np.diff(ex)) == pytest.approx(0.02 * math.sqrt(2.0), rel=0.1)
    assert np.std(ex) < 0.1
    assert LOCALIZATIONS["perfect"]().perfect
    assert Localization(LOCALIZATIONS["perfect"]()).estimate(truth, DT) is truth


def test_simulate_on_the_multi_body_plant_reports_its_keys() -> None:
    r = runner.invoke(
        app,
        ["simulate", "seed003", "--plant", "multi_body", "--vehicle", "bmw320i", "--road", "wet", "--json"],
    )
    assert r.exit_code == 0, r.output
    m = json.loads(r.stdout.strip().splitlines()[-1])
    for key in (
        "max_abs_e_lat_m",
        "settled_abs_e_lat_m",
        "yaw_error_range_rad",
        "max_lat_accel_mps2",
        "collision",
    ):
        assert key in m
    assert m["plant"] == {
        "plant": "multi_body",
        "vehicle": "bmw320i",
        "road": "wet",
        "mu": 0.5,
        "steer_delay_s": 0.0,
    }
    assert m["friction_limit_mps2"] == pytest.approx(4.905)
    assert m["friction_modelled"] is True and m["friction_exceeded"] is False
    assert m["action"] == "pull_over_and_stop" and not m["collision"]
    assert m["max_abs_e_lat_m"] < 0.2


def test_the_default_plant_is_today_s_model() -> None:
    # same run with and without the plant option: identical metrics, no added keys
    from makeway.pipeline.closed_loop import run_scenario
    from makeway.sim.scenarios import SCENARIOS

    sc = SCENARIOS["no_ev"]()
    a = run_scenario(sc).metrics
    b = run_scenario(sc, plant=PlantSpec()).metrics
    assert "plant" not in a and b["plant"]["vehicle"] == "design"
    assert {k: b[k] for k in a} == a
    assert isinstance(PlantSpec().build(), LinearPlant)
    assert isinstance(LinearPlant().model, SingleTrackModel)
    assert FeedforwardFeedback(VehicleParams()).params == VehicleParams()


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["--plant", "bogus"], ["bogus", "multi_body", "single_track_drift"]),
        (["--plant", "multi_body", "--vehicle", "trabant"], ["trabant", "bmw320i", "vw_vanagon"]),
        (["--plant", "multi_body", "--road", "icy"], ["icy", "dry", "wet"]),
        (["--vehicle", "bmw320i"], ["linear", "--vehicle"]),
        (["--road", "wet"], ["linear", "friction"]),
        (["--plant", "kinematic", "--steer-delay", "0.125"], ["0.125", "0.01"]),
        (["--localization", "gps"], ["gps", "rtk"]),
    ],
    ids=["plant", "vehicle", "road", "linear-vehicle", "linear-wet", "delay", "localization"],
)
def test_bad_plant_options_error_in_one_line(args: list[str], words: list[str]) -> None:
    r = runner.invoke(app, ["simulate", "seed003", *args])
    assert r.exit_code == 2, r.output
    err = r.stderr.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1 and err.startswith("error:"), err
    for w in words:
        assert w in err, (w, err)


def test_a_plant_that_goes_out_of_control_says_so() -> None:
    from makeway.sim.plants import PlantDivergedError

    plant = CommonRoadPlant("multi_body", "bmw320i")
    plant.reset(VehicleState(0.0, 0.0, 0.0, 0.0, 15.0, 0.0, 0.0))
    plant._x[5] = 50.0  # a spinning car: 50 rad/s of yaw rate
    with pytest.raises(PlantDivergedError, match="out of control"):
        plant.advance(ControlCommand(0.0, 0.0, 0.0), DT)


def test_delay_compensation_restores_the_pull_over_on_the_design_car() -> None:
    # seed003 on the linear plant with a 0.15 s steering delay: uncompensated the feedback loses
    # its phase margin; predicting over the delay on the design model gives back today's figure
    # (the ``design`` predictor: the default ``mean`` one also averages in the kinematic bicycle)
    from makeway.pipeline.closed_loop import run_scenario
    from makeway.sim.scenarios import SCENARIOS

    sc = SCENARIOS["seed003"]()
    spec = PlantSpec(plant="linear", steer_delay_s=0.15)
    plain = run_scenario(sc, plant=spec).metrics
    compensated = run_scenario(sc, plant=spec, delay_compensation_s=0.15, delay_predictor="design").metrics
    undelayed = run_scenario(sc).metrics
    assert compensated["max_abs_e_lat_m"] < 0.2 * plain["max_abs_e_lat_m"]
    assert compensated["max_abs_e_lat_m"] == pytest.approx(undelayed["max_abs_e_lat_m"], abs=0.003)
    assert compensated["delay_compensation_s"] == 0.15 and not compensated["collision"]


def test_ffb_is_ahead_of_both_baselines_on_a_car_it_was_not_designed_on() -> None:
    # seed003 on CommonRoad's multi-body BMW 320i with a 0.15 s steering delay, every controller
    # with the same (default) predictor and only the design car's parameters
    from makeway.pipeline.closed_loop import run_scenario
    from makeway.sim.scenarios import SCENARIOS

    spec = PlantSpec(plant="multi_body", vehicle="bmw320i", road="dry", steer_delay_s=0.15)
    worst = {
        ctrl: run_scenario(
            SCENARIOS["seed003"](), controller=ctrl, plant=spec, delay_compensation_s=0.15
        ).metrics["max_abs_e_lat_m"]
        for ctrl in ("ffb", "stanley", "pure_pursuit")
    }
    assert worst["ffb"] < 0.05
    assert worst["ffb"] < worst["stanley"] and worst["ffb"] < worst["pure_pursuit"], worst


def test_the_rk4_step_bound_is_accurate() -> None:
    # the default sub-step (90 % of RK4's stability limit for the wheel-spin mode) against the
    # earlier bound (|λ h| ≤ 2): the same path to a fraction of a millimetre over a braking lane
    # change (the actuators' own first-order discretisation moves it by millimetres)
    def drive(fraction: float) -> np.ndarray:
        plant = CommonRoadPlant("multi_body", "bmw320i", stability_fraction=fraction)
        plant.reset(VehicleState(0.0, 0.0, 0.0, 0.0, 12.0))
        out = []
        for i in range(300):
            t = i * DT
            steer = 0.03 * math.sin(2.0 * math.pi * t / 3.0)
            s = plant.advance(ControlCommand(t, steer, -2.0 if t > 1.0 else 0.0), DT)
            out.append((s.x_m, s.y_m, s.yaw_rad))
        return np.array(out)

    default, earlier = drive(0.9), drive(2.0 / RK4_REAL_STABILITY)
    assert np.max(np.hypot(*(default[:, :2] - earlier[:, :2]).T)) < 5e-4
    assert np.max(np.abs(default[:, 2] - earlier[:, 2])) < 1e-4
