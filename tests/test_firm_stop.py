"""The firm stop before an intersection (issue 26, crossing): the yield decision allows a firmer
deceleration only for a stop before an intersection that an EV on the crossing road (or a siren not
yet placed) heads for and that comfort cannot make; the longitudinal controller honours that limit
for that stop only."""

from __future__ import annotations

import math

import numpy as np
import pytest

from makeway.control import LongitudinalController
from makeway.decide import YieldConfig, YieldStateMachine, firm_stop_distance_m
from makeway.fuse.relation import classify_relation
from makeway.messages import (
    ControlCommand,
    EVBelief,
    EVRelation,
    RoadContext,
    VehicleState,
    YieldDecision,
    YieldState,
)
from makeway.plan.path import straight_road
from makeway.plan.planner import YieldPlanner
from makeway.sim.vehicle import SingleTrackModel

DT = 0.05
LIMIT = 13.4
BOX = (160.0, 174.0)  # the crossing scenario's intersection


def _belief(t: float, relation: EVRelation, distance: float = 46.0) -> EVBelief:
    return EVBelief(
        time_s=t,
        detected=True,
        confidence=0.9,
        relation=relation,
        distance_m=distance,
        approaching=True,
        lights=True,
        siren=True,
    )


def _first_yield(
    relation: EVRelation,
    s_at_yield: float,
    v: float = LIMIT,
    config: YieldConfig | None = None,
    ax: float = 0.0,
) -> tuple[YieldStateMachine, YieldDecision, float]:
    """Drive at ``v`` (braking at ``ax`` < 0 when given, the speed kept for simplicity) so that the
    confirmed EV's first yield decision comes at ``s_at_yield`` (the machine confirms after 0.3 s);
    the machine, that decision and the ego's s then."""
    fsm = YieldStateMachine(config)
    t, s = 0.0, s_at_yield - v * 0.3
    for _ in range(40):
        road = RoadContext(s_m=s, intersections=(BOX,), speed_limit_mps=LIMIT)
        d = fsm.update(_belief(t, relation), VehicleState(t, s, 0.0, 0.0, v, ax_mps2=ax), road)
        if d.state is YieldState.MOVING_OVER:
            return fsm, d, s
        t, s = round(t + DT, 9), s + v * DT
    raise AssertionError(f"no yield: {fsm.history}")


def test_seed3_situation_gets_a_firm_stop_before_the_intersection() -> None:
    """Crossing seed 3: 28.5 m short at 13.36 m/s, already slowing at 0.37 m/s² to prepare, an EV
    heard close and approaching, not placed. Comfort (3 m/s² at 2.5 m/s³) needs about 40 m: a firm
    stop (4.5 m/s² at 8 m/s³) makes it with 3 m to spare."""
    cfg = YieldConfig()
    for relation in (EVRelation.UNKNOWN, EVRelation.CROSSING):
        _, d, s = _first_yield(relation, BOX[0] - 28.5, 13.36, ax=-0.37)
        assert BOX[0] - s == pytest.approx(28.5, abs=0.8)
        assert d.action == "stop_before_intersection" and not d.pull_over  # no room to move over
        assert d.stop_s_m is not None
        # planned on confirming, one period before the first MOVING_OVER decision
        planned_at = s - 13.36 * DT
        assert d.stop_s_m == pytest.approx(planned_at + firm_stop_distance_m(13.36, 4.5, 8.0, 0.2, 0.37))
        assert d.stop_s_m <= BOX[0] - cfg.firm_min_margin_m
        assert (d.max_decel_mps2, d.max_jerk_mps3) == (cfg.firm_decel_mps2, cfg.firm_jerk_mps3) == (4.5, 8.0)
        assert "braking firmly" in d.reason
    # firm braking switched off (firm = comfort): as before, the car clears the intersection first
    comfort_only = YieldConfig(firm_decel_mps2=3.0)
    _, d, _ = _first_yield(EVRelation.UNKNOWN, BOX[0] - 28.5, 13.36, comfort_only, -0.37)
    assert d.action == "clear_intersection" and d.stop_s_m is not None and d.stop_s_m > BOX[1]
    assert d.max_decel_mps2 is None


def test_comfort_everywhere_else() -> None:
    # room to stop comfortably: comfort limits (None), with the full 5 m margin
    _, d, _ = _first_yield(EVRelation.CROSSING, BOX[0] - 60.0)
    assert d.action == "stop_before_intersection" and d.stop_s_m == pytest.approx(BOX[0] - 5.0)
    assert d.max_decel_mps2 is None and d.max_jerk_mps3 is None
    # too close even for a firm stop: clear the intersection, comfort limits
    _, d, _ = _first_yield(EVRelation.CROSSING, BOX[0] - 15.0)
    assert d.action == "clear_intersection" and d.max_decel_mps2 is None
    # an EV behind us with the same intersection ahead: pull over after it at comfort
    _, d, _ = _first_yield(EVRelation.BEHIND, BOX[0] - 30.0)
    assert d.max_decel_mps2 is None and d.stop_s_m is not None and d.stop_s_m > BOX[1]
    # once stopped: waiting is back at comfort limits
    fsm, d, _ = _first_yield(EVRelation.UNKNOWN, BOX[0] - 30.0)
    assert d.max_decel_mps2 == 4.5
    t = d.time_s
    stop = d.stop_s_m
    assert stop is not None
    for _ in range(80):
        t = round(t + DT, 9)
        road = RoadContext(s_m=stop, intersections=(BOX,), speed_limit_mps=LIMIT)
        d = fsm.update(_belief(t, EVRelation.CROSSING), VehicleState(t, stop, 0.0, 0.0, 0.0), road)
    assert d.state is YieldState.STOPPED_WAITING and d.max_decel_mps2 is None


def test_a_firm_stop_stays_before_the_intersection_when_the_ev_is_placed_behind() -> None:
    fsm, d, s = _first_yield(EVRelation.UNKNOWN, BOX[0] - 30.0)
    stop = d.stop_s_m
    assert d.max_decel_mps2 == 4.5
    t, v = d.time_s, LIMIT
    for _ in range(10):  # braking firmly; the EV is now placed (wrongly or not) behind the car
        t, v = round(t + DT, 9), v - 4.5 * DT
        s += v * DT
        road = RoadContext(s_m=s, intersections=(BOX,), speed_limit_mps=LIMIT)
        ego = VehicleState(t, s, 0.0, 0.0, v, ax_mps2=-4.5)
        d = fsm.update(_belief(t, EVRelation.BEHIND), ego, road)
    assert d.stop_s_m == stop and d.max_decel_mps2 == 4.5
    assert "still stopping before the intersection" in d.reason


def test_a_crossing_ev_behind_every_intersection_needs_no_yield() -> None:
    fsm = YieldStateMachine()
    for k in range(20):
        t = k * DT
        road = RoadContext(s_m=190.0 + LIMIT * t, intersections=(BOX,), speed_limit_mps=LIMIT)
        ego = VehicleState(t, road.s_m, 0.0, 0.0, LIMIT)
        d = fsm.update(_belief(t, EVRelation.CROSSING, 15.0), ego, road)
        assert d.action == "continue" and d.state is not YieldState.MOVING_OVER
    # with no intersection on the map the table stays conservative: a crossing EV is yielded to
    fsm = YieldStateMachine()
    for k in range(10):
        t = k * DT
        road = RoadContext(s_m=LIMIT * t, speed_limit_mps=LIMIT)
        ego = VehicleState(t, road.s_m, 0.0, 0.0, LIMIT)
        d = fsm.update(_belief(t, EVRelation.CROSSING, 15.0), ego, road)
    assert d.state is YieldState.MOVING_OVER


def test_firm_stop_distance() -> None:
    v = 13.4
    # an instant full deceleration and no delay: v²/(2a); a delay adds v·delay
    assert firm_stop_distance_m(v, 4.5, 1e9, 0.0) == pytest.approx(v * v / 9.0)
    assert firm_stop_distance_m(v, 4.5, 1e9, 0.2) == pytest.approx(v * v / 9.0 + 0.2 * v)
    # against a fine numerical integration of the same profile, already braking at 1 m/s²
    x, u, a, t = 0.0, v, 1.0, 0.0
    h = 1e-4
    while u > 0.0:
        x += u * h
        u -= a * h
        t += h
        if t > 0.2:
            a = min(a + 8.0 * h, 4.5)
    assert firm_stop_distance_m(v, 4.5, 8.0, 0.2, 1.0) == pytest.approx(x, abs=0.01)
    assert firm_stop_distance_m(0.5, 4.5, 8.0, 0.0) < 0.5 * 0.5  # stops during the ramp
    with pytest.raises(ValueError):
        firm_stop_distance_m(v, 0.0, 8.0, 0.2)
    with pytest.raises(ValueError):
        YieldConfig(firm_decel_mps2=2.0)  # below comfort


def _stop(distance_m: float, limits: dict[str, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    model, ctrl = SingleTrackModel(), LongitudinalController()
    state = VehicleState(0.0, 0.0, 0.0, 0.0, LIMIT)
    xs, cmds, axs = [], [], []
    for _ in range(800):
        a = ctrl.accel(state, LIMIT, distance_m - state.x_m, **limits)
        state = model.step(state, ControlCommand(state.time_s, 0.0, a), 0.01)
        xs.append(state.x_m)
        cmds.append(a)
        axs.append(state.ax_mps2)
    return np.array(xs), np.array(cmds), np.array(axs)


def test_the_controller_honours_the_firm_limit_for_that_stop_only() -> None:
    d = 27.0  # 13.4 m/s: comfort needs ~40 m, 4.5 m/s² at 8 m/s³ about 26 m
    xs, cmds, axs = _stop(d, {"max_decel_mps2": 4.5, "max_jerk_mps3": 8.0})
    assert xs[-1] == pytest.approx(d, abs=0.5)
    assert cmds.min() >= -4.5 - 1e-9 and cmds.min() < -4.0  # it did use the firm deceleration
    assert np.abs(np.diff(cmds)).max() <= 8.0 * 0.01 + 1e-9
    assert axs.min() >= -4.5 - 1e-6
    xs, cmds, _ = _stop(d, {})  # the same stop at comfort limits: never beyond 3 m/s², and overruns
    assert cmds.min() >= -3.0 - 1e-9 and np.abs(np.diff(cmds)).max() <= 2.5 * 0.01 + 1e-9
    assert xs[-1] > d + 5.0
    # a firm command is given back at the comfort jerk once the firm limits are no longer passed
    ctrl = LongitudinalController()
    state = VehicleState(0.0, 0.0, 0.0, 0.0, LIMIT)
    a = 0.0
    for k in range(200):
        state = VehicleState(k * 0.01, 0.0, 0.0, 0.0, LIMIT, ax_mps2=a)
        a = ctrl.accel(state, LIMIT, 15.0, max_decel_mps2=4.5, max_jerk_mps3=8.0)
    assert a == pytest.approx(-4.5)
    after = [
        ctrl.accel(VehicleState(1.99 + k * 0.01, 0.0, 0.0, 0.0, LIMIT), LIMIT, None) for k in range(1, 50)
    ]
    assert after[0] == pytest.approx(-4.5 + 2.5 * 0.01)
    assert np.abs(np.diff([a, *after])).max() <= 2.5 * 0.01 + 1e-9
    with pytest.raises(ValueError):
        ctrl.accel(state, LIMIT, 10.0, max_decel_mps2=-1.0)


def test_the_planner_takes_a_moved_stop_point_in_lane() -> None:
    lane = straight_road(300.0)
    planner = YieldPlanner(lane, right_edge_offset_m=-1.3, intersections=(BOX,))
    first = YieldDecision(1.0, YieldState.MOVING_OVER, "stop_before_intersection", False, 10.0, 156.0)
    path = planner.update(first, x=130.0, y=0.0, speed_mps=13.0)
    assert path.stop_s_m == 156.0
    moved = YieldDecision(1.5, YieldState.MOVING_OVER, "stop_before_intersection", False, 8.0, 157.0)
    path = planner.update(moved, x=136.0, y=0.0, speed_mps=11.0)
    assert path.stop_s_m == 157.0 and planner.distance_to_stop(136.0, 0.0) == pytest.approx(21.0, abs=0.6)
    assert planner.update(moved, x=137.0, y=0.0, speed_mps=10.0) is path  # unchanged: no new path


def test_an_unplaced_ev_with_an_intersection_near_stops_before_it() -> None:
    # 11 m/s, 35 m short: a pull-over would end ~8 m before the intersection; it stops before it
    _, d, _ = _first_yield(EVRelation.UNKNOWN, BOX[0] - 35.0, 11.0)
    assert d.action == "stop_before_intersection" and d.stop_s_m == pytest.approx(BOX[0] - 5.0)
    assert d.max_decel_mps2 is None  # comfortable
    # the same EV far from any intersection: a plain pull-over
    _, d, _ = _first_yield(EVRelation.UNKNOWN, BOX[0] - 120.0, 11.0)
    assert d.action == "pull_over_and_stop" and d.stop_s_m is not None and d.stop_s_m < BOX[0] - 50.0


def test_an_unplaced_receding_ev_with_an_intersection_ahead_slows() -> None:
    cfg = YieldConfig()
    for boxes, action in (((BOX,), "prepare"), ((), "continue")):
        fsm = YieldStateMachine(cfg)
        for k in range(10):
            t = k * DT
            road = RoadContext(s_m=100.0, intersections=boxes, speed_limit_mps=LIMIT)
            d = fsm.update(_receding(t), VehicleState(t, 100.0, 0.0, 0.0, LIMIT), road)
        assert d.state is YieldState.EV_CONFIRMED and d.action == action
        if action == "prepare":
            assert d.target_speed_mps == pytest.approx(cfg.duty.prepare_speed_fraction * LIMIT)


def _receding(t: float) -> EVBelief:
    return EVBelief(
        time_s=t,
        detected=True,
        confidence=0.9,
        relation=EVRelation.UNKNOWN,
        distance_m=40.0,
        approaching=False,
        lights=True,
        siren=True,
    )


def test_an_ev_along_our_road_must_be_on_it() -> None:
    # on our road (or a curve's sweep of it) as before
    assert classify_relation(-60.0, 1.5, 0.0) is EVRelation.BEHIND
    assert classify_relation(-100.0, 20.0, 0.2) is EVRelation.BEHIND  # R = 250 m curve, 100 m back
    assert classify_relation(45.0, -3.5, math.pi) is EVRelation.ONCOMING
    # beside our road, "driving along it": not placed (crossing seed 11's siren track, 34 m ahead
    # and 25 m to the right, heading along our road)
    assert classify_relation(34.0, -25.0, 0.05) is EVRelation.UNKNOWN
    assert classify_relation(-1.5, 16.0, 0.0) is EVRelation.UNKNOWN
    assert classify_relation(40.0, -30.0, math.pi / 2) is EVRelation.CROSSING
