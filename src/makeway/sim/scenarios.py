"""Built-in closed-loop scenarios: roads, the ego's start, and what the emergency vehicle does (SPEC §6).

Each :class:`Scenario` is pure data: the ego lane's centre line, lane geometry, intersections, the
ego's start speed, and an :class:`EVPlan` (the EV's own path, speed, and when its signals are on).
:func:`makeway.pipeline.closed_loop.run_scenario` drives them.
``seed003`` replays the field test of seed 003, the project report on the pull-over system
(``../shared/seeds/003_…``, digested in SPEC §6).

=================  ============================================================  ======================
name               situation                                                     right action
=================  ============================================================  ======================
``seed003``        seed 003's field test: ego at 13.4 m/s in the left lane of a   pull over one lane to
                   straight two-lane road; an EV 50 m behind switches lights and  the right edge, stop
                   siren on and closes at 20 m/s
``curve_behind``   the same on a left curve (R = 250 m) with clothoid entry        pull over and stop
``oncoming``       undivided two-way road; an EV comes the other way at 20 m/s    pull over and stop
``crossing``       an EV on a crossing road heads for the intersection ahead      stop before the
                                                                                  intersection
``signals_off``    EV from behind switches lights and siren off after 4 s and     yield, then resume
                   slows down (it was not called after all)
``no_ev``          an ordinary drive                                             continue
``no_ev_urban``    an ordinary drive on a two-way street through a crossroads     continue
                   every 70 m (where a siren not yet placed would stop the car)
``two_evs``        undivided road: an EV overtakes from behind on the centre      pull over and stop
                   line while another comes the other way; both active at once    until both have passed
``occluded_behind`` a truck follows the ego; an EV comes up in the other lane,    pull over and stop
                   hidden from the cameras behind the truck until close
``night_lights_``  night; an EV from behind with lights on and siren off          pull over and stop
``only``
``siren_only``     an EV from behind with its siren on and no lights to see       pull over and stop
``v2x_corridor``   an EV 500 m behind, announced by roadside units (V2X), closes  pull over and stop
                   at 25 m/s: the corridor should open long before it is heard
=================  ============================================================  ======================

An :class:`EVPlan` also drives the other vehicles of a scenario (``traffic``, signals never on): a
truck follows the same car-following rule as an EV. ``night`` tells the cameras it is dark.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from makeway.messages import ReferencePath
from makeway.plan.path import curved_road, make_path, offset_path, point_at, straight_road
from makeway.registry import Registry

LANE_WIDTH_M = 3.5


@dataclass(frozen=True)
class EVPlan:
    """What the emergency vehicle does: its path, speed, and signal timing.

    ``speed_mps(t)`` is the speed it wants; it keeps a ``min_gap_m`` behind a vehicle in its lane
    (an EV driver does not ram a car that has not yet moved over). Signals are on during
    ``[signals_on_s, signals_off_s)``.
    """

    path: ReferencePath
    start_s_m: float
    speed_mps: Callable[[float], float]
    signals_on_s: float
    signals_off_s: float = math.inf
    siren: bool = True
    lights: bool = True
    min_gap_m: float = 8.0
    length_m: float = 6.0
    width_m: float = 2.2
    v2x: bool = False  # broadcasts signed alerts (directly or relayed by roadside units)


@dataclass(frozen=True)
class Scenario:
    """A closed-loop scenario (see the module table)."""

    name: str
    description: str
    lane: ReferencePath  # the ego's lane centre line, direction of travel
    ego_speed_mps: float
    duration_s: float
    expected_action: str
    right_edge_offset_m: float
    speed_limit_mps: float
    intersections: tuple[tuple[float, float], ...] = ()
    ev: EVPlan | None = None
    ego_start_s_m: float = 0.0
    road_lines: tuple[ReferencePath, ...] = field(default_factory=tuple)  # for plots: lane edges
    more_evs: tuple[EVPlan, ...] = ()  # further emergency vehicles
    traffic: tuple[EVPlan, ...] = ()  # other vehicles (trucks that hide an EV)
    night: bool = False
    roadside_units: tuple[tuple[float, float], ...] = ()  # poles (x, y) of V2X roadside units, m

    @property
    def evs(self) -> tuple[EVPlan, ...]:
        """Every emergency vehicle, ``ev`` first."""
        return ((self.ev,) if self.ev is not None else ()) + self.more_evs


def _const(v: float) -> Callable[[float], float]:
    return lambda t: v


def _lane_lines(lane: ReferencePath, offsets: tuple[float, ...]) -> tuple[ReferencePath, ...]:
    return tuple(offset_path(lane, o) for o in offsets)


# Lane-edge lines (m left of the ego lane's centre line): ego in the left of two lanes; ego in its
# lane of a two-way road.
_LEFT_LANE_EDGES = (LANE_WIDTH_M / 2, -LANE_WIDTH_M / 2, -1.5 * LANE_WIDTH_M)
_TWO_WAY_EDGES = (LANE_WIDTH_M / 2, -LANE_WIDTH_M / 2, 1.5 * LANE_WIDTH_M)


def _scenario(
    name: str,
    description: str,
    lane: ReferencePath,
    ev: EVPlan | None,
    *,
    ego_speed_mps: float = 13.4,
    duration_s: float = 30.0,
    expected_action: str = "pull_over_and_stop",
    right_edge_offset_m: float = -LANE_WIDTH_M - 0.5,
    edge_offsets_m: tuple[float, ...] = _LEFT_LANE_EDGES,
    intersections: tuple[tuple[float, float], ...] = (),
    ego_start_s_m: float = 0.0,
    more_evs: tuple[EVPlan, ...] = (),
    traffic: tuple[EVPlan, ...] = (),
    night: bool = False,
) -> Scenario:
    """A scenario whose speed limit is the ego's start speed (m/s) and whose plotted road lines are
    ``lane`` offset by ``edge_offsets_m`` (m, left of the lane centre line positive)."""
    return Scenario(
        name=name,
        description=description,
        lane=lane,
        ego_speed_mps=ego_speed_mps,
        duration_s=duration_s,
        expected_action=expected_action,
        right_edge_offset_m=right_edge_offset_m,
        speed_limit_mps=ego_speed_mps,
        intersections=intersections,
        ev=ev,
        ego_start_s_m=ego_start_s_m,
        road_lines=_lane_lines(lane, edge_offsets_m),
        more_evs=more_evs,
        traffic=traffic,
        night=night,
    )


def seed003() -> Scenario:
    """Seed 003's field test: straight two-lane road, EV 50 m behind switches on (SPEC §6)."""
    lane = straight_road(600.0)
    ev_path = straight_road(800.0, start=(-200.0, 0.0))
    ev = EVPlan(
        path=ev_path,
        start_s_m=150.0,  # 50 m behind the ego at t = 0
        speed_mps=lambda t: 13.4 if t < 2.0 else 20.0,
        signals_on_s=2.0,
    )
    return _scenario(
        "seed003",
        "ego 13.4 m/s in the left lane of a straight two-lane road; EV 50 m behind switches "
        "lights and siren on at t = 2 s and closes at 20 m/s",
        lane,
        ev,
    )


def curve_behind() -> Scenario:
    """EV from behind on a left curve (R = 250 m) of a two-lane road."""
    lane = curved_road(60.0, 250.0, math.radians(70.0), after_m=200.0)
    ev_path = make_path(
        np.concatenate([np.linspace(-150.0, -1.0, 150), lane.x_m]),
        np.concatenate([np.zeros(150), lane.y_m]),
    )
    ev = EVPlan(
        path=ev_path, start_s_m=100.0, speed_mps=lambda t: 15.0 if t < 1.5 else 21.0, signals_on_s=1.5
    )
    return _scenario(
        "curve_behind",
        "ego 15 m/s in the left lane entering a left curve (R = 250 m); EV 50 m behind "
        "switches on at t = 1.5 s and closes at 21 m/s",
        lane,
        ev,
        ego_speed_mps=15.0,
    )


def oncoming() -> Scenario:
    """Undivided two-way road; the EV approaches in the opposite lane."""
    lane = straight_road(500.0)
    ev_path = straight_road(600.0, start=(400.0, LANE_WIDTH_M), heading_rad=math.pi)
    ev = EVPlan(path=ev_path, start_s_m=0.0, speed_mps=_const(20.0), signals_on_s=0.5)
    return _scenario(
        "oncoming",
        "ego 13.4 m/s on an undivided two-way road; an EV 400 m ahead comes the other way "
        "at 20 m/s with lights and siren on",
        lane,
        ev,
        right_edge_offset_m=-1.3,
        edge_offsets_m=_TWO_WAY_EDGES,
    )


def crossing() -> Scenario:
    """An EV on a crossing road heads for the intersection the ego approaches."""
    lane = straight_road(400.0)
    box = (160.0, 174.0)  # the crossing road occupies s = 160 … 174 m of the ego's path
    centre_x = 0.5 * (box[0] + box[1])
    ev_path = straight_road(400.0, start=(centre_x - 1.75, -200.0), heading_rad=math.pi / 2)
    ev = EVPlan(path=ev_path, start_s_m=60.0, speed_mps=_const(10.0), signals_on_s=0.5)
    return _scenario(
        "crossing",
        "ego 13.4 m/s towards an intersection 160 m ahead; an EV on the crossing road, "
        "140 m from it, heads for it at 10 m/s with lights and siren on",
        lane,
        ev,
        duration_s=35.0,
        expected_action="stop_before_intersection",
        right_edge_offset_m=-1.3,
        edge_offsets_m=(LANE_WIDTH_M / 2, -LANE_WIDTH_M / 2),
        intersections=(box,),
    )


def _seed003_variant(
    name: str,
    description: str,
    ev_start_s_m: float,
    *,
    ev_speed_mps: Callable[[float], float] = lambda t: 13.4 if t < 2.0 else 20.0,
    signals_off_s: float = math.inf,
    siren: bool = True,
    lights: bool = True,
    duration_s: float = 30.0,
    night: bool = False,
) -> Scenario:
    """seed003's road and EV path with another EV: it starts ``ev_start_s_m`` along its path (the ego
    is at 200 m of it), switches its signals on at t = 2 s and by default drives 13.4 m/s, then 20 m/s."""
    base = seed003()
    assert base.ev is not None
    ev = EVPlan(
        path=base.ev.path,
        start_s_m=ev_start_s_m,
        speed_mps=ev_speed_mps,
        signals_on_s=2.0,
        signals_off_s=signals_off_s,
        siren=siren,
        lights=lights,
    )
    return _scenario(name, description, base.lane, ev, duration_s=duration_s, night=night)


def signals_off() -> Scenario:
    """EV from behind switches its signals off after 4 s and falls back: yield, then resume."""
    return _seed003_variant(
        "signals_off",
        "as seed003, but the EV switches lights and siren off at t = 6 s and slows to 8 m/s "
        "(call cancelled): the ego yields, waits, then resumes",
        150.0,
        ev_speed_mps=lambda t: 13.4 if t < 2.0 else (18.0 if t < 6.0 else 8.0),
        signals_off_s=6.0,
        duration_s=35.0,
    )


def no_ev() -> Scenario:
    """An ordinary drive: nothing to yield to."""
    base = seed003()
    return _scenario(
        "no_ev",
        "ego 13.4 m/s on the straight two-lane road, no emergency vehicle",
        base.lane,
        None,
        duration_s=20.0,
        expected_action="continue",
    )


def no_ev_urban() -> Scenario:
    """An ordinary drive through crossroads: nothing to yield to, nowhere to stop.

    The rule that stops the car before an intersection for a siren it cannot yet place
    (:class:`~makeway.decide.yield_fsm.YieldConfig` ``stop_for_unplaced_siren``) can only act where an
    intersection lies ahead; this drive measures what it costs when nothing is there."""
    lane = straight_road(600.0)
    boxes = tuple((s0, s0 + 14.0) for s0 in np.arange(40.0, 560.0, 70.0).tolist())
    return _scenario(
        "no_ev_urban",
        "ego 13.4 m/s on a two-way street with a crossroads every 70 m (the first 40 m ahead), "
        "no emergency vehicle",
        lane,
        None,
        duration_s=20.0,
        expected_action="continue",
        right_edge_offset_m=-1.3,
        edge_offsets_m=_TWO_WAY_EDGES,
        intersections=boxes,
    )


def on_recorded_path(lane: ReferencePath, *, ego_speed_mps: float = 13.4, ev_gap_m: float = 50.0) -> Scenario:
    """seed003's situation on a recorded path (as the seeds replayed one): the ego starts
    ``ev_gap_m + 10`` m along it, the EV ``ev_gap_m`` behind on the same path, switching on at 2 s.
    """
    start = ev_gap_m + 10.0
    if float(lane.s_m[-1]) < start + 150.0:
        raise ValueError(
            f"the recorded path is {lane.s_m[-1]:.0f} m long; it needs at least {start + 150.0:.0f} m "
            f"(the EV starts {ev_gap_m:.0f} m behind the ego and the pull-over needs ~150 m)"
        )
    ev = EVPlan(
        path=lane,
        start_s_m=start - ev_gap_m,
        speed_mps=lambda t: ego_speed_mps if t < 2.0 else ego_speed_mps + 6.6,
        signals_on_s=2.0,
    )
    return _scenario(
        "recorded_path",
        f"seed003 on a recorded path ({lane.s_m[-1]:.0f} m): ego {ego_speed_mps:g} m/s, EV "
        f"{ev_gap_m:g} m behind switches on at t = 2 s",
        lane,
        ev,
        ego_speed_mps=ego_speed_mps,
        ego_start_s_m=start,
    )


def two_evs() -> Scenario:
    """Undivided two-way road: an EV overtakes from behind on the centre line while a second one
    comes the other way; the ego must wait until both have passed."""
    lane = straight_road(500.0)
    behind = EVPlan(
        path=straight_road(700.0, start=(-200.0, LANE_WIDTH_M / 2)),
        start_s_m=160.0,  # 40 m behind the ego
        speed_mps=lambda t: 13.4 if t < 1.0 else 18.0,
        signals_on_s=1.0,
    )
    oncoming = EVPlan(
        path=straight_road(600.0, start=(400.0, LANE_WIDTH_M + 0.5), heading_rad=math.pi),
        start_s_m=250.0,  # 150 m ahead of the ego
        speed_mps=_const(12.0),
        signals_on_s=0.5,
    )
    return _scenario(
        "two_evs",
        "ego 13.4 m/s on an undivided two-way road; an EV 40 m behind switches on at 1 s and "
        "overtakes on the centre line at 18 m/s while a second EV, 150 m ahead, comes the other way at "
        "12 m/s: stop and wait until both have passed",
        lane,
        behind,
        right_edge_offset_m=-1.3,
        edge_offsets_m=_TWO_WAY_EDGES,
        more_evs=(oncoming,),
    )


def occluded_behind() -> Scenario:
    """A truck follows the ego; an EV comes up in the other lane, hidden from the cameras behind the
    truck until it is close (the siren is heard all along)."""
    lane = straight_road(600.0)
    truck = EVPlan(
        path=straight_road(800.0, start=(-200.0, 0.0)),
        start_s_m=184.0,  # 16 m behind the ego (centre to centre)
        speed_mps=_const(13.4),
        signals_on_s=math.inf,
        siren=False,
        lights=False,
        min_gap_m=5.0,
        length_m=12.0,
        width_m=2.5,
    )
    ev = EVPlan(
        path=straight_road(800.0, start=(-200.0, LANE_WIDTH_M)),
        start_s_m=120.0,  # 80 m behind the ego, in the other lane
        speed_mps=lambda t: 13.4 if t < 1.0 else 22.0,
        signals_on_s=1.0,
    )
    return _scenario(
        "occluded_behind",
        "ego 13.4 m/s in the right lane with a truck 16 m behind it; an EV 80 m behind in "
        "the left lane switches on at 1 s and closes at 22 m/s, hidden from the cameras by the truck "
        "until it is ~20 m away",
        lane,
        ev,
        right_edge_offset_m=-1.3,
        edge_offsets_m=(-LANE_WIDTH_M / 2, LANE_WIDTH_M / 2, 1.5 * LANE_WIDTH_M),
        traffic=(truck,),
    )


def night_lights_only() -> Scenario:
    """Night: an EV from behind with its lights on and its siren off (seed 004's case)."""
    return _seed003_variant(
        "night_lights_only",
        "night; as seed003 with the EV 60 m behind, lights on and siren off",
        140.0,  # 60 m behind
        siren=False,
        night=True,
    )


def siren_only() -> Scenario:
    """An EV from behind with its siren on and no light the cameras can see."""
    return _seed003_variant(
        "siren_only",
        "as seed003 with the EV 80 m behind, siren on and no lights visible: prepare, then "
        "yield once the siren is close and approaching",
        120.0,  # 80 m behind
        lights=False,
    )


def units_along(
    path: ReferencePath, spacing_m: float, offset_m: float = -6.0
) -> tuple[tuple[float, float], ...]:
    """Roadside unit poles every ``spacing_m`` (m) along ``path``, ``offset_m`` to its left
    (negative: right of the road), starting at its first point."""
    if spacing_m <= 0:
        raise ValueError(f"spacing_m must be > 0, not {spacing_m}")
    poles = []
    for s in np.arange(0.0, float(path.s_m[-1]) + 1e-9, spacing_m):
        x, y, yaw = point_at(path, float(s))
        poles.append((x - offset_m * math.sin(yaw), y + offset_m * math.cos(yaw)))
    return tuple(poles)


def v2x_corridor() -> Scenario:
    """An EV 500 m behind, announced by roadside units every 50 m, closes at 25 m/s on a two-lane
    road; the EV itself sends nothing."""
    lane = straight_road(1000.0)
    road = straight_road(1600.0, start=(-600.0, 0.0))
    ev = EVPlan(
        path=road,
        start_s_m=100.0,  # 500 m behind the ego
        speed_mps=lambda t: 13.4 if t < 1.0 else 25.0,
        signals_on_s=1.0,
    )
    return replace(
        _scenario(
            "v2x_corridor",
            "ego 13.4 m/s in the left lane of a straight two-lane road; an EV 500 m behind, seen by "
            "roadside units every 50 m that announce it, switches on at 1 s and closes at 25 m/s",
            lane,
            ev,
            duration_s=50.0,
        ),
        roadside_units=units_along(road, 50.0),
    )


SCENARIOS: Registry[Callable[[], Scenario]] = Registry(
    "scenario",
    {
        "seed003": seed003,
        "curve_behind": curve_behind,
        "oncoming": oncoming,
        "crossing": crossing,
        "signals_off": signals_off,
        "no_ev": no_ev,
        "no_ev_urban": no_ev_urban,
        "two_evs": two_evs,
        "occluded_behind": occluded_behind,
        "night_lights_only": night_lights_only,
        "siren_only": siren_only,
        "v2x_corridor": v2x_corridor,
    },
)
"""Built-in scenarios by name: ``SCENARIOS[name]()`` builds one (``makeway simulate NAME``)."""
