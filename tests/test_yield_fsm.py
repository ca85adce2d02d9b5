"""The yield state machine (SPEC §6), driven by hand-made belief sequences at 20 Hz.

The ego is a point on its path: it moves towards the decision's target speed with at most 4 m/s² of
braking and 2 m/s² of acceleration, and counts as stopped below 0.2 m/s (the machine's default).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import pytest

from makeway.decide import YieldConfig, YieldStateMachine, clear_stop_point, lane_change_length_m, needs_yield
from makeway.decide.duty import DUTY_PRESETS
from makeway.messages import EVBelief, EVRelation, RoadContext, VehicleState, YieldDecision, YieldState

DT = 0.05
LIMIT = 13.4
S = YieldState
R = EVRelation


def ev(
    t: float,
    relation: EVRelation = R.BEHIND,
    distance: float = 60.0,
    approaching: bool | None = True,
    *,
    conf: float = 0.9,
    lights: bool = True,
    siren: bool = True,
    rel_x: float | None = None,
) -> EVBelief:
    """A belief of an EV ``distance`` away; ``rel_x`` defaults from the relation."""
    if rel_x is None:
        sign = {R.BEHIND: -1.0, R.AHEAD: 1.0, R.ONCOMING: 1.0}.get(relation, math.nan)
        rel_x = sign * distance
    return EVBelief(
        time_s=t,
        detected=True,
        confidence=conf,
        relation=relation,
        rel_x_m=rel_x,
        distance_m=distance,
        approaching=approaching,
        lights=lights,
        siren=siren,
    )


def nothing(t: float) -> EVBelief:
    return EVBelief.nothing(t)


@dataclass
class Drive:
    """The machine, a point-mass ego on its path, and the road; :meth:`step` runs one period."""

    fsm: YieldStateMachine = field(default_factory=YieldStateMachine)
    s: float = 0.0
    v: float = LIMIT
    intersections: tuple[tuple[float, float], ...] = ()
    t: float = 0.0
    decisions: list[YieldDecision] = field(default_factory=list)
    positions: list[float] = field(default_factory=list)  # the ego's s at each decision

    def road(self) -> RoadContext:
        return RoadContext(s_m=self.s, intersections=self.intersections, speed_limit_mps=LIMIT)

    def step(self, belief: Callable[[float], EVBelief]) -> YieldDecision:
        d = self.fsm.update(belief(self.t), VehicleState(self.t, self.s, 0.0, 0.0, self.v), self.road())
        self.decisions.append(d)
        self.positions.append(self.s)
        dv = min(max(d.target_speed_mps - self.v, -4.0 * DT), 2.0 * DT)
        self.v = max(0.0, self.v + dv)
        self.s += self.v * DT
        self.t = round(self.t + DT, 9)
        return d

    def run(self, seconds: float, belief: Callable[[float], EVBelief]) -> YieldDecision:
        d = self.step(belief)
        for _ in range(int(round(seconds / DT)) - 1):
            d = self.step(belief)
        return d

    def until(self, state: YieldState, belief: Callable[[float], EVBelief], limit_s: float = 30.0) -> None:
        for _ in range(int(limit_s / DT)):
            if self.step(belief).state is state:
                return
        raise AssertionError(f"never reached {state} (now {self.fsm.state}); history {self.fsm.history}")

    @property
    def states(self) -> list[YieldState]:
        h = self.fsm.history
        return [h[0][1], *(to for _, _, to, _ in h)] if h else [self.fsm.state]


# ------------------------------------------------------------------------------------- full cycle


def test_full_cycle_for_an_ev_from_behind() -> None:
    drive = Drive()
    ev_s0, ev_v = -90.0, 20.0

    def world(t: float) -> EVBelief:
        rel = ev_s0 + ev_v * t - drive.s
        if abs(rel) > 100.0:  # out of the sensors' range
            return nothing(t)
        relation = R.BEHIND if rel < 0 else R.AHEAD
        closing = ev_v > drive.v if rel < 0 else ev_v < drive.v
        return ev(t, relation, abs(rel), closing, rel_x=rel)

    for _ in range(int(25.0 / DT)):
        drive.step(world)
        if drive.fsm.state is S.NO_EV and len(drive.fsm.history) > 1:
            break
    assert drive.states == [
        S.NO_EV,
        S.EV_CONFIRMED,
        S.MOVING_OVER,
        S.STOPPED_WAITING,
        S.EV_PASSED,
        S.RESUMING,
        S.NO_EV,
    ]
    times = {to: t for t, _, to, _ in drive.fsm.history}
    assert times[S.EV_CONFIRMED] == pytest.approx(0.3)
    assert times[S.RESUMING] - times[S.EV_PASSED] == pytest.approx(2.0)
    assert all(reason for *_, reason in drive.fsm.history)

    by_state: dict[YieldState, list[YieldDecision]] = {}
    for d in drive.decisions:
        by_state.setdefault(d.state, []).append(d)
        assert d.reason
    first = by_state[S.EV_CONFIRMED][0]
    assert first.action == "pull_over_and_stop" and first.pull_over and first.stop_s_m is not None
    moving = by_state[S.MOVING_OVER]
    assert {d.stop_s_m for d in moving} == {first.stop_s_m}  # the stop point is latched
    assert all(d.action == "pull_over_and_stop" and d.pull_over for d in moving)
    speeds = [d.target_speed_mps for d in moving]
    assert all(b <= a + 1e-9 for a, b in itertools.pairwise(speeds))  # only slows down
    assert speeds[-1] < 1.0
    # stopped near the stop point, and 0 m/s asked while waiting
    assert all(d.target_speed_mps == 0.0 and d.action == "wait" for d in by_state[S.STOPPED_WAITING])
    assert all(d.target_speed_mps == 0.0 for d in by_state[S.EV_PASSED])
    assert abs(by_state[S.STOPPED_WAITING][0].stop_s_m - drive.s) < 40.0
    resume = by_state[S.RESUMING]
    assert all(d.action == "resume" and not d.pull_over and d.target_speed_mps == LIMIT for d in resume)
    assert drive.decisions[-1].target_speed_mps == LIMIT and drive.decisions[-1].action == "continue"


def test_stop_point_leaves_room_for_the_lane_change_and_the_brakes() -> None:
    drive = Drive()
    d = drive.run(0.35, lambda t: ev(t))
    assert d.state is S.EV_CONFIRMED
    change = lane_change_length_m(LIMIT, -3.0, 1.5, 5.0)
    assert change > LIMIT**2 / 6.0  # at this speed the lane change needs more room than braking
    assert d.stop_s_m == pytest.approx(drive.positions[-1] + LIMIT * 0.2 + change)
    assert d.target_speed_mps <= LIMIT


# ------------------------------------------------------------------------------------ hysteresis


def test_single_frame_spike_does_not_confirm() -> None:
    drive = Drive()
    drive.run(1.0, lambda t: ev(t) if abs(t - 0.5) < 1e-6 else nothing(t))
    assert drive.fsm.history == [] and drive.fsm.state is S.NO_EV


def test_confirmation_needs_confirm_time_without_a_break() -> None:
    drive = Drive()
    # 0.25 s strong, then a frame under confirm_confidence (but above release), then strong again
    drive.run(0.25, lambda t: ev(t))
    drive.step(lambda t: ev(t, conf=0.5))
    assert drive.fsm.state is S.NO_EV
    start = drive.t
    drive.until(S.EV_CONFIRMED, lambda t: ev(t))
    assert drive.fsm.history[0][0] - start == pytest.approx(0.3)


def test_short_dip_does_not_release() -> None:
    drive = Drive()
    drive.until(S.MOVING_OVER, lambda t: ev(t))
    drive.run(0.5, lambda t: ev(t, conf=0.1))  # under release_confidence, shorter than the timeout
    drive.run(3.0, lambda t: ev(t, conf=0.45))  # between release and confirm: still seen
    assert drive.fsm.state in (S.MOVING_OVER, S.STOPPED_WAITING)
    assert S.EV_PASSED not in drive.states


def test_ev_beyond_relevant_distance_is_ignored() -> None:
    drive = Drive()
    drive.run(2.0, lambda t: ev(t, distance=200.0))
    assert drive.fsm.state is S.NO_EV


def test_signals_required_to_confirm() -> None:
    drive = Drive()
    drive.run(2.0, lambda t: ev(t, lights=False, siren=False))
    assert drive.fsm.state is S.NO_EV
    drive = Drive(fsm=YieldStateMachine(YieldConfig(signals_required=False)))
    drive.run(0.5, lambda t: ev(t, lights=False, siren=False))
    assert drive.fsm.state is not S.NO_EV


# --------------------------------------------------------------------------------------- dropouts


def test_dropout_shorter_than_timeout_keeps_moving_over() -> None:
    drive = Drive()
    drive.until(S.MOVING_OVER, lambda t: ev(t))
    drive.run(1.5, nothing)
    assert drive.fsm.state is S.MOVING_OVER
    d = drive.run(0.5, lambda t: ev(t))
    assert d.state is S.MOVING_OVER and d.pull_over
    assert S.EV_PASSED not in drive.states


def test_long_dropout_after_the_ev_was_close_means_it_passed() -> None:
    drive = Drive()
    drive.until(S.STOPPED_WAITING, lambda t: ev(t, distance=8.0))
    last_seen = drive.t - DT
    drive.until(S.EV_PASSED, nothing)
    t_passed = drive.fsm.history[-1][0]
    assert 2.0 < t_passed - last_seen <= 2.0 + DT + 1e-6  # the first period after the timeout
    assert "lost" in drive.fsm.history[-1][3]


def test_long_dropout_far_away_waits_for_the_signals_hold() -> None:
    drive = Drive()
    drive.until(S.STOPPED_WAITING, lambda t: ev(t, distance=80.0))
    last = drive.t - DT
    drive.run(3.0, nothing)  # lost for longer than the timeout, but it was 80 m away
    assert drive.fsm.state is S.STOPPED_WAITING
    drive.until(S.EV_PASSED, nothing)
    assert drive.fsm.history[-1][0] - last == pytest.approx(5.0, abs=DT)


# -------------------------------------------------------------------------------------- relations


def test_oncoming_approaching_pulls_over_receding_does_nothing() -> None:
    drive = Drive()
    d = drive.run(0.35, lambda t: ev(t, R.ONCOMING, 90.0, True))
    assert d.state is S.EV_CONFIRMED and d.action == "pull_over_and_stop" and d.pull_over
    assert drive.step(lambda t: ev(t, R.ONCOMING, 88.0, True)).state is S.MOVING_OVER

    drive = Drive()
    d = drive.run(3.0, lambda t: ev(t, R.ONCOMING, 40.0, False))
    assert d.state is S.EV_CONFIRMED and d.action == "continue" and not d.pull_over
    assert d.target_speed_mps == LIMIT and d.stop_s_m is None
    assert S.MOVING_OVER not in drive.states

    drive = Drive(fsm=YieldStateMachine(YieldConfig(yield_to_oncoming=False)))  # a divided road
    d = drive.run(2.0, lambda t: ev(t, R.ONCOMING, 60.0, True))
    assert d.action == "continue" and S.MOVING_OVER not in drive.states


def test_oncoming_ev_that_went_by_is_passed() -> None:
    drive = Drive()
    drive.until(S.STOPPED_WAITING, lambda t: ev(t, R.ONCOMING, 90.0, True))
    drive.run(1.0, lambda t: ev(t, R.ONCOMING, 5.0, True))
    # behind us now, going away (a simulator calls it BEHIND by its position)
    drive.until(S.EV_PASSED, lambda t: ev(t, R.BEHIND, 15.0, False), limit_s=1.0)
    assert "went by" in drive.fsm.history[-1][3]


def test_ahead_receding_follows_without_pulling_over() -> None:
    drive = Drive(v=10.0)
    for _ in range(60):
        d = drive.step(lambda t: ev(t, R.AHEAD, 40.0, False))
        if d.state is not S.NO_EV:
            assert d.action == "follow" and not d.pull_over and d.stop_s_m is None
            assert d.target_speed_mps <= drive.v + 4.0 * DT + 1e-9  # never faster than it was
    assert drive.fsm.state is S.EV_CONFIRMED and S.MOVING_OVER not in drive.states
    # it stops or reverses towards us: yield as for one from behind
    drive.run(0.1, lambda t: ev(t, R.AHEAD, 30.0, True))
    assert drive.fsm.state is S.MOVING_OVER
    assert drive.decisions[-1].action == "pull_over_and_stop"


def test_ahead_ev_that_pulls_away_after_overtaking_is_passed() -> None:
    drive = Drive()
    drive.until(S.STOPPED_WAITING, lambda t: ev(t, R.BEHIND, 20.0, True))
    drive.run(0.5, lambda t: ev(t, R.AHEAD, 5.0, False))  # alongside: not yet passed
    assert drive.fsm.state is S.STOPPED_WAITING
    drive.until(S.EV_PASSED, lambda t: ev(t, R.AHEAD, 15.0, False), limit_s=0.2)


def test_an_ev_never_near_reading_ahead_and_pulling_away_is_not_passed_at_once() -> None:
    # an oncoming EV's siren beyond the rangers' reach: placed ~50 m ahead whatever its true distance,
    # so while the car closes on it the track reads "ahead, pulling away" (oncoming seed 12)
    hold, gain = YieldConfig().far_passed_hold_s, YieldConfig().far_passed_gain_m
    drive = Drive()
    drive.until(S.STOPPED_WAITING, lambda t: ev(t, R.UNKNOWN, 50.0, True, rel_x=50.0))
    far = lambda t: ev(t, R.AHEAD, 50.0, False)  # noqa: E731
    drive.run(hold - 1.0, far)
    assert drive.fsm.state is S.STOPPED_WAITING  # never near: not taken for an EV that overtook us
    # the compressed distances wander by less than the gain: still not passed
    drive.run(0.5, lambda t: ev(t, R.AHEAD, 50.0 + 0.8 * gain, False))
    assert drive.fsm.state is S.STOPPED_WAITING
    # it comes on, goes by, and is passed by the oncoming rule
    drive.run(1.0, lambda t: ev(t, R.ONCOMING, 20.0, True))
    drive.until(S.EV_PASSED, lambda t: ev(t, R.ONCOMING, 15.0, False), limit_s=0.2)
    # an EV ahead that really drives off is let go after the hold, if it never came near
    drive = Drive()
    drive.until(S.STOPPED_WAITING, lambda t: ev(t, R.UNKNOWN, 50.0, True, rel_x=50.0))
    start = drive.t
    drive.until(S.EV_PASSED, far, limit_s=hold + 0.2)
    assert drive.t - start >= hold - DT and "pulling away for" in drive.fsm.history[-1][3]
    # … or at once when it is seen to drive off: its distance grows by the gain
    drive = Drive()
    drive.until(S.STOPPED_WAITING, lambda t: ev(t, R.UNKNOWN, 35.0, True, rel_x=35.0))
    start = drive.t
    drive.until(S.EV_PASSED, lambda t: ev(t, R.AHEAD, 35.0 + 20.0 * (t - start), False), limit_s=2.0)
    assert drive.t - start <= gain / 20.0 + 2 * DT and "m farther than" in drive.fsm.history[-1][3]


def test_ev_passing_before_we_stop_still_completes_the_stop() -> None:
    drive = Drive()
    drive.until(S.MOVING_OVER, lambda t: ev(t, R.BEHIND, 20.0, True))
    drive.run(0.5, lambda t: ev(t, R.AHEAD, 20.0, False))  # it overtook us while we slow down
    assert drive.fsm.state is S.MOVING_OVER and drive.v > 5.0
    assert "completing the stop" in drive.decisions[-1].reason
    drive.until(S.STOPPED_WAITING, nothing)
    assert drive.v < 0.2
    drive.step(nothing)
    assert drive.fsm.state is S.EV_PASSED and "passed" in drive.fsm.history[-1][3]
    assert drive.states[-4:] == [S.EV_CONFIRMED, S.MOVING_OVER, S.STOPPED_WAITING, S.EV_PASSED]


def test_unknown_relation_pulls_over_and_stops() -> None:
    """A siren heard and not placed: the UK preset yields at once (the default law prepares; see
    test_duty_to_yield)."""
    drive = Drive(fsm=YieldStateMachine(YieldConfig(duty=DUTY_PRESETS["uk"])))
    d = drive.run(0.35, lambda t: ev(t, R.UNKNOWN, math.nan, None, lights=False))
    assert d.state is S.EV_CONFIRMED and d.action == "pull_over_and_stop" and d.pull_over
    drive.until(S.STOPPED_WAITING, lambda t: ev(t, R.UNKNOWN, math.nan, None, lights=False))
    assert drive.v < 0.2


def test_behind_falling_back_is_not_yielded_to_yet() -> None:
    assert not needs_yield(R.BEHIND, False)
    assert needs_yield(R.BEHIND, None) and needs_yield(R.CROSSING, None) and needs_yield(R.UNKNOWN, None)
    assert not needs_yield(R.AHEAD, None) and needs_yield(R.AHEAD, True)
    assert not needs_yield(R.ONCOMING, True, yield_to_oncoming=False)


def test_approaching_from_distance_trend_when_not_given() -> None:
    drive = Drive()
    dist = iter(60.0 - 0.5 * k for k in range(1000))
    drive.run(0.5, lambda t: ev(t, R.AHEAD, next(dist), None))
    assert drive.fsm.state is S.MOVING_OVER  # an EV ahead whose distance shrinks comes at us


# ---------------------------------------------------------------------------------- intersections


def test_crossing_ev_stops_before_the_intersection() -> None:
    drive = Drive(v=10.0, intersections=((60.0, 75.0),))
    d = drive.run(0.35, lambda t: ev(t, R.CROSSING, 80.0, True))
    assert d.action == "stop_before_intersection"
    assert d.stop_s_m == pytest.approx(55.0)  # start − 5 m margin
    assert d.pull_over  # room to move over before it
    drive.until(S.STOPPED_WAITING, lambda t: ev(t, R.CROSSING, 60.0, True))
    assert 50.0 < drive.s < 60.0
    assert all(d.action == "stop_before_intersection" for d in drive.decisions if d.state is S.MOVING_OVER)


def test_crossing_ev_without_room_stops_in_lane() -> None:
    drive = Drive(v=8.0, intersections=((30.0, 45.0),))
    d = drive.run(0.35, lambda t: ev(t, R.CROSSING, 60.0, True))
    assert d.action == "stop_before_intersection" and not d.pull_over and d.stop_s_m == pytest.approx(25.0)
    cfg = YieldConfig(pull_over_before_intersection=False)
    drive = Drive(fsm=YieldStateMachine(cfg), v=10.0, intersections=((60.0, 75.0),))
    d = drive.run(0.35, lambda t: ev(t, R.CROSSING, 80.0, True))
    assert d.action == "stop_before_intersection" and not d.pull_over


def test_crossing_ev_too_late_to_stop_clears_the_intersection() -> None:
    drive = Drive(v=LIMIT, intersections=((12.0, 26.0),))  # 30 m needed to stop at 3 m/s²
    d = drive.run(0.35, lambda t: ev(t, R.CROSSING, 50.0, True))
    assert d.action == "clear_intersection" and not d.pull_over
    assert d.stop_s_m is not None and d.stop_s_m >= 26.0 + 5.0


def test_ego_inside_an_intersection_keeps_moving_and_never_stops_inside() -> None:
    box = (20.0, 40.0)
    for relation in (R.CROSSING, R.BEHIND):
        drive = Drive(s=30.0, v=2.0, intersections=(box,))

        def belief(t: float, r: EVRelation = relation) -> EVBelief:
            return ev(t, r, 40.0, True)

        d = drive.run(0.35, belief)
        assert d.action == "clear_intersection" and not d.pull_over
        assert d.stop_s_m is None or d.stop_s_m >= box[1] + 5.0
        drive.until(S.STOPPED_WAITING, belief)
        for dec, s in zip(drive.decisions, drive.positions, strict=True):
            if box[0] <= s <= box[1]:
                assert dec.target_speed_mps > 0.0
            assert dec.stop_s_m is None or not (box[0] <= dec.stop_s_m <= box[1])
        assert drive.s > box[1]
        after = [d for d in drive.decisions if d.state is S.MOVING_OVER and d.action != "clear_intersection"]
        assert after and after[-1].pull_over  # moved over once it had cleared the intersection


def test_ego_stopped_inside_an_intersection_drives_out() -> None:
    drive = Drive(s=25.0, v=0.0, intersections=((20.0, 40.0),))
    drive.run(1.0, lambda t: ev(t, R.CROSSING, 30.0, True))
    assert drive.fsm.state is S.MOVING_OVER and drive.decisions[-1].target_speed_mps > 0.0
    assert drive.v > 0.0


def test_stop_point_moves_out_of_an_intersection() -> None:
    # before it: the pull-over stop (≈48 m) falls in (40, 60); braking to 35 m is comfortable
    drive = Drive(v=LIMIT, intersections=((40.0, 60.0),))
    d = drive.run(0.35, lambda t: ev(t))
    assert d.stop_s_m == pytest.approx(35.0)
    assert d.action == "stop_before_intersection" and not d.pull_over  # no room to move over first
    drive.until(S.STOPPED_WAITING, lambda t: ev(t))
    assert drive.s < 40.0
    # after it: the intersection starts too close to stop before it
    drive = Drive(v=LIMIT, intersections=((25.0, 40.0),))
    d = drive.run(0.35, lambda t: ev(t))
    assert d.stop_s_m is not None and d.stop_s_m >= 45.0
    assert d.action == "clear_intersection" and not d.pull_over
    drive.until(S.STOPPED_WAITING, lambda t: ev(t))
    assert drive.s > 40.0


def test_clear_stop_point_rules() -> None:
    box = [(25.0, 40.0)]
    # no intersection in the way: the desired point (never closer than braking allows)
    assert clear_stop_point(0.0, 10.0, 20.0, []) == pytest.approx(20.0)
    assert clear_stop_point(0.0, 10.0, 5.0, []) == pytest.approx(100.0 / 6.0)
    # in the zone, comfortable to stop before it: start − margin
    assert clear_stop_point(0.0, 6.0, 30.0, box) == pytest.approx(20.0)
    # cannot reach start − margin comfortably but can still stop 1 m short of the start
    assert clear_stop_point(0.0, 12.0, 22.0, box) == pytest.approx(24.0)
    # cannot stop before it at all: after its end + exit margin
    assert clear_stop_point(0.0, LIMIT, 30.0, box) == pytest.approx(45.0)
    # chained intersections whose zones overlap: past both
    assert clear_stop_point(0.0, LIMIT, 30.0, [(25.0, 40.0), (43.0, 50.0)]) == pytest.approx(55.0)
    # inside an intersection, even at rest: past it
    assert clear_stop_point(30.0, 0.0, 30.0, box) == pytest.approx(45.0)
    # intersections behind the ego do not matter
    assert clear_stop_point(60.0, 0.0, 70.0, box) == pytest.approx(70.0)
    with pytest.raises(ValueError):
        clear_stop_point(0.0, 5.0, 10.0, [(30.0, 20.0)])


# ------------------------------------------------------------------------------------- signals


def test_siren_off_but_lights_on_keeps_yielding() -> None:
    drive = Drive()
    drive.until(S.STOPPED_WAITING, lambda t: ev(t, distance=40.0))
    drive.run(10.0, lambda t: ev(t, distance=40.0, siren=False, lights=True))
    assert drive.fsm.state is S.STOPPED_WAITING
    assert drive.decisions[-1].action == "wait" and drive.decisions[-1].target_speed_mps == 0.0


def test_lights_and_siren_off_passes_after_the_hold() -> None:
    drive = Drive()
    drive.until(S.STOPPED_WAITING, lambda t: ev(t, distance=40.0))
    dark = drive.t
    last_active = dark - DT
    drive.run(4.8, lambda t: ev(t, distance=40.0, siren=False, lights=False))
    assert drive.fsm.state is S.STOPPED_WAITING  # it may still pass: keep yielding
    drive.until(S.EV_PASSED, lambda t: ev(t, distance=40.0, siren=False, lights=False))
    assert drive.fsm.history[-1][0] - last_active == pytest.approx(5.0, abs=1e-6)
    assert "no lights or siren" in drive.fsm.history[-1][3]
    drive.until(S.RESUMING, lambda t: ev(t, distance=40.0, siren=False, lights=False))
    assert drive.fsm.history[-1][0] - drive.fsm.history[-2][0] == pytest.approx(2.0)


# -------------------------------------------------------------------------------- resuming


def test_new_ev_while_resuming_yields_again() -> None:
    drive = Drive()
    drive.until(S.STOPPED_WAITING, lambda t: ev(t, distance=20.0))
    drive.until(S.RESUMING, lambda t: ev(t, R.AHEAD, 30.0, False))  # it overtook us and drives off
    # the first EV still in view, driving away: no new yield
    drive.run(0.5, lambda t: ev(t, R.AHEAD, 40.0, False))
    assert drive.fsm.state is S.RESUMING
    # a second one comes up from behind
    drive.run(0.35, lambda t: ev(t, R.BEHIND, 70.0, True))
    assert drive.fsm.state is S.EV_CONFIRMED
    assert drive.fsm.history[-1][1] is S.RESUMING
    d = drive.step(lambda t: ev(t, R.BEHIND, 68.0, True))
    assert d.state is S.MOVING_OVER and d.pull_over and d.action == "pull_over_and_stop"


def test_second_ev_while_still_stopped_keeps_us_where_we_are() -> None:
    drive = Drive()
    drive.until(S.STOPPED_WAITING, lambda t: ev(t, distance=20.0))
    stop = drive.decisions[-1].stop_s_m
    drive.until(S.EV_PASSED, lambda t: ev(t, R.AHEAD, 30.0, False))
    s_stopped = drive.s
    drive.run(0.35, lambda t: ev(t, R.CROSSING, 60.0, True))  # another EV, on the crossing road
    assert drive.fsm.state is S.EV_CONFIRMED and drive.fsm.history[-1][1] is S.EV_PASSED
    drive.until(S.STOPPED_WAITING, lambda t: ev(t, R.CROSSING, 55.0, True), limit_s=0.2)
    assert drive.decisions[-1].stop_s_m == stop and drive.s == pytest.approx(s_stopped)


def test_a_premature_pass_is_withdrawn_when_the_ev_reappears() -> None:
    drive = Drive()
    drive.until(S.MOVING_OVER, lambda t: ev(t, R.BEHIND, 10.0, True))
    drive.run(2.2, nothing)  # lost close by: taken to have passed …
    assert "completing the stop" in drive.decisions[-1].reason
    drive.run(0.2, lambda t: ev(t, R.BEHIND, 8.0, True))  # … but it is still behind us
    drive.until(S.STOPPED_WAITING, lambda t: ev(t, R.BEHIND, 8.0, True))
    drive.run(1.0, lambda t: ev(t, R.BEHIND, 8.0, True))
    assert drive.fsm.state is S.STOPPED_WAITING


def test_resuming_times_out() -> None:
    drive = Drive(fsm=YieldStateMachine(YieldConfig(resume_timeout_s=1.0, resume_speed_mps=30.0)))
    drive.until(S.STOPPED_WAITING, lambda t: ev(t, distance=20.0))
    drive.until(S.RESUMING, lambda t: ev(t, R.AHEAD, 30.0, False))
    drive.until(S.NO_EV, nothing, limit_s=1.5)
    assert "longer than" in drive.fsm.history[-1][3]


# ------------------------------------------------------------------------------------ contract


def test_reset_time_and_config_checks() -> None:
    drive = Drive()
    drive.run(1.0, lambda t: ev(t))
    assert drive.fsm.history
    with pytest.raises(ValueError, match="backwards"):
        drive.fsm.update(nothing(0.0), VehicleState(0.0, 0.0, 0.0, 0.0, 0.0), RoadContext(s_m=0.0))
    drive.fsm.reset()
    assert drive.fsm.state is S.NO_EV and drive.fsm.history == []
    d = drive.fsm.update(nothing(0.0), VehicleState(0.0, 0.0, 0.0, 0.0, 5.0), RoadContext(s_m=0.0))
    assert d.action == "continue" and d.target_speed_mps == RoadContext(s_m=0.0).speed_limit_mps
    with pytest.raises(ValueError):
        YieldConfig(release_confidence=0.7, confirm_confidence=0.6)
    with pytest.raises(ValueError):
        YieldConfig(dropout_timeout_s=-1.0)
