"""The closed loop (SPEC §7): perceived EV → yield decision → path → control → vehicle, measured.

:func:`run_scenario` steps a built-in :class:`~makeway.sim.scenarios.Scenario` at 100 Hz:

1. every EV, and every truck of the scenario, (:class:`~makeway.sim.ev_actor.EVActor`) moves along
   its own path, keeping a gap behind a vehicle in its lane, and the simulated world
   (:class:`~makeway.sim.world.SimWorld`) shows them;
2. a belief source (:class:`~makeway.fuse.source.BeliefSource`) publishes an
   :class:`~makeway.messages.EVBelief`. ``perception`` picks it: any object with
   ``build(scenario, world) -> BeliefSource``, e.g. a
   :class:`~makeway.sim.perception.PerceptionConfig` (a model of perception: latency, dropouts,
   noise; the default) or a :class:`~makeway.pipeline.siren_perception.SirenPerceptionConfig` (the
   siren stack itself on the array's audio rendered as the car drives) or a
   :class:`~makeway.pipeline.fused_perception.FusedPerceptionConfig` (siren stack, cameras and V2X
   fused into one track per EV). :data:`PERCEPTIONS` names them for the command line (``simulated``,
   ``siren``, ``vision``, ``v2x``, ``fused``); every source gives a belief per EV
   (:meth:`~makeway.fuse.source.BeliefSource.beliefs`) and the most urgent one;
3. the yield state machine decides at 20 Hz from every EV's belief
   (:meth:`~makeway.decide.yield_fsm.YieldStateMachine.update_all`); the planner replans the
   reference path on a new manoeuvre;
4. the lateral controller (feed-forward + feedback by default, or a baseline) and the longitudinal
   controller command the plant: by default the linear single-track model the controllers were
   designed on; ``plant`` picks another (:class:`~makeway.sim.plants.PlantSpec`: CommonRoad's
   kinematic, single-track, single-track-drift or multi-body model with a published parameter set,
   a dry or wet road and a steering delay). The controllers keep their design model
   (:class:`~makeway.vehicle.VehicleParams`) and never see the plant's parameters;
5. with ``localization`` the controllers and the planner see a GNSS/IMU estimate of the car's state
   (:mod:`makeway.sim.localization`), not the truth; the metrics are always measured on the truth.

Every step is logged; :class:`ClosedLoopResult` holds the log and the metrics of
:func:`makeway.eval.closed_loop.compute_metrics`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np

from makeway.control import LATERAL_CONTROLLERS, LongitudinalController
from makeway.control.delay import DelayCompensated
from makeway.decide import YieldConfig, YieldStateMachine
from makeway.eval.closed_loop import compute_metrics
from makeway.frames import to_vehicle_frame
from makeway.fuse.source import BeliefSource
from makeway.geometry import rect_distance, rectangle_corners
from makeway.messages import ControlCommand, EVBelief, RoadContext, SirenObservation, VehicleState, YieldState
from makeway.pipeline.fused_perception import FusedPerceptionConfig
from makeway.pipeline.siren_perception import SirenPerceptionConfig
from makeway.plan.path import nearest_index, point_at
from makeway.plan.planner import YieldPlanner
from makeway.registry import Registry
from makeway.sim.cameras import CAMERA_FIGURES
from makeway.sim.ev_actor import EVActor
from makeway.sim.live_array import LiveAudioConfig
from makeway.sim.localization import Localization, LocalizationConfig
from makeway.sim.perception import PerceptionConfig
from makeway.sim.plants import G, LinearPlant, Plant, PlantSpec
from makeway.sim.scenarios import EVPlan, Scenario
from makeway.sim.world import EVTruth, SimWorld
from makeway.vehicle import VehicleParams

__all__ = ["DT_S", "PERCEPTIONS", "ClosedLoopResult", "PerceptionSpec", "run_scenario"]

DT_S = 0.01
DECIDE_EVERY = 5  # decisions at 20 Hz
LOG_COLUMNS = [
    "t",
    "x",
    "y",
    "yaw",
    "vx",
    "vy",
    "yaw_rate",
    "steer",
    "ax",
    "steer_cmd",
    "accel_cmd",
    "e_lat",
    "yaw_error",
    "yaw_rate_error",
    "curvature",
    "lane_s",
    "ev_x",
    "ev_y",
    "ev_yaw",
    "ev_on",
    "belief_detected",
    "belief_conf",
    "belief_distance",
    "belief_bearing",
    "state",
    "target_speed",
    "gap_to_ev",
    "gap_to_traffic",
]


@dataclass
class ClosedLoopResult:
    """The log of one closed-loop run and its metrics."""

    scenario: str
    controller: str
    metrics: dict[str, Any]
    log: dict[str, np.ndarray]
    transitions: list[tuple[float, str, str, str]]
    replans: list[tuple[float, str]]
    paths: list[tuple[float, np.ndarray, np.ndarray]] = field(default_factory=list)
    actions: list[tuple[float, str, str]] = field(default_factory=list)
    siren: list[tuple[SirenObservation, EVBelief]] = field(default_factory=list)
    """With siren perception: every listener observation and the belief it gave."""


class PerceptionSpec(Protocol):
    """Settings of one kind of perception that can build its belief source for a run;
    ``sees_lights`` says whether its senses include cameras that see an EV's lights (the duty to
    yield of a car without them: :meth:`~makeway.decide.duty.DutyToYield.for_senses`)."""

    @property
    def sees_lights(self) -> bool: ...

    def build(self, scenario: Scenario, world: SimWorld) -> BeliefSource: ...


def simulated_perception(seed: int = 0, **_: Any) -> PerceptionSpec:
    """A model of perception (latency, dropouts, noise), seeded."""
    return PerceptionConfig(seed=seed)


def siren_perception(
    seed: int = 0, siren: str = "synth", noise: str = "generated", **_: Any
) -> PerceptionSpec:
    """The siren stack on the roof array's audio: ``siren`` synth|real, street ``noise`` generated|real."""
    return SirenPerceptionConfig(audio=LiveAudioConfig(seed=seed, siren=siren, noise=noise))


def vision_perception(seed: int = 0, cameras: str = "seed004", **_: Any) -> PerceptionSpec:
    """The camera rig's lights detector (modelled with the figures named ``cameras``,
    :data:`~makeway.sim.cameras.CAMERA_FIGURES`) into the multi-EV fusion, seeded."""
    return FusedPerceptionConfig(senses=("light",), seed=seed, cameras=CAMERA_FIGURES[cameras]())


def v2x_perception(seed: int = 0, **_: Any) -> PerceptionSpec:
    """Signed V2X alerts of equipped EVs, verified, into the multi-EV fusion, seeded."""
    return FusedPerceptionConfig(senses=("v2x",), seed=seed)


def fused_perception(
    seed: int = 0, siren: str = "synth", noise: str = "generated", cameras: str = "seed004", **_: Any
) -> PerceptionSpec:
    """Siren stack + cameras + V2X into the multi-EV fusion; ``siren``/``noise`` as for ``siren``,
    ``cameras`` as for ``vision``."""
    return FusedPerceptionConfig(
        audio=LiveAudioConfig(seed=seed, siren=siren, noise=noise),
        seed=seed,
        cameras=CAMERA_FIGURES[cameras](),
    )


PERCEPTIONS: Registry[Callable[..., PerceptionSpec]] = Registry(
    "perception",
    {
        "simulated": simulated_perception,
        "siren": siren_perception,
        "vision": vision_perception,
        "v2x": v2x_perception,
        "fused": fused_perception,
    },
)
"""Kinds of perception by name: ``PERCEPTIONS[name](seed=..., **options)`` gives a spec for
:func:`run_scenario` (``makeway simulate --perception NAME``)."""


# ----------------------------------------------------------------------------------------- the loop


def run_scenario(
    scenario: Scenario,
    *,
    controller: str = "ffb",
    perception: PerceptionSpec | None = None,
    params: VehicleParams | None = None,
    yield_config: YieldConfig | None = None,
    plant: PlantSpec | None = None,
    localization: LocalizationConfig | None = None,
    localization_seed: int = 0,
    delay_compensation_s: float = 0.0,
    delay_predictor: str = "mean",
) -> ClosedLoopResult:
    """Run ``scenario`` in closed loop with the lateral controller ``controller`` (a name of
    :data:`~makeway.control.LATERAL_CONTROLLERS`) and the belief source ``perception`` builds
    (default: :class:`~makeway.sim.perception.PerceptionConfig`, the model of perception).

    ``params`` is the controllers' design car (and, with no ``plant``, the simulated car too);
    ``plant`` picks another simulated car (module docstring; its metrics then add ``plant``,
    ``friction_limit_mps2``, ``friction_modelled`` and ``friction_exceeded``); ``localization``
    the noise of the car's estimate of its own state, seeded with ``localization_seed``;
    ``delay_compensation_s`` > 0 wraps the lateral controller in
    :class:`~makeway.control.delay.DelayCompensated` for that nominal steering delay with the
    predictor ``delay_predictor`` (``mean``, ``design`` or ``kinematic``; the design car only).
    """
    params = params if params is not None else VehicleParams()
    lateral = LATERAL_CONTROLLERS[controller](params)
    if delay_compensation_s > 0.0:
        lateral = DelayCompensated(lateral, params, delay_compensation_s, DT_S, delay_predictor)
    model: Plant
    if plant is None:
        model = LinearPlant(params)
        body = (params.length_m, params.width_m)
    else:
        model = plant.build()
        body = getattr(model, "body_m", (params.length_m, params.width_m))
    locator = Localization(localization, localization_seed) if localization is not None else None
    longitudinal = LongitudinalController()
    spec: PerceptionSpec = perception if perception is not None else PerceptionConfig()
    config = yield_config if yield_config is not None else YieldConfig()
    fsm = YieldStateMachine(replace(config, duty=config.duty.for_senses(spec.sees_lights)))
    world = SimWorld()
    sensing = spec.build(scenario, world)
    planner = YieldPlanner(
        scenario.lane, right_edge_offset_m=scenario.right_edge_offset_m, intersections=scenario.intersections
    )
    x0, y0, h0 = point_at(scenario.lane, scenario.ego_start_s_m)
    ego = VehicleState(0.0, x0, y0, h0, scenario.ego_speed_mps)
    model.reset(ego)
    ev_actors = [EVActor(p, body[0], body[1]) for p in scenario.evs]
    others = [EVActor(p, body[0], body[1]) for p in scenario.traffic]
    world.night = scenario.night

    n = int(round(scenario.duration_s / DT_S))
    log: dict[str, list[float]] = {k: [] for k in LOG_COLUMNS}
    states = list(YieldState)
    decision = fsm.update_all(_beliefs(sensing, 0.0, ego), ego, _road(scenario, 0.0))
    path = planner.path
    hint: int | None = None
    lane_hint: int | None = None
    paths: list[tuple[float, np.ndarray, np.ndarray]] = [(0.0, path.x_m, path.y_m)]
    ev_truth: EVTruth | None = None
    truths: list[EVTruth] = []
    traffic: list[EVTruth] = []
    actions: list[tuple[float, str, str]] = []  # (time, state, action) whenever the action changes
    for i in range(n):
        t = i * DT_S
        if ev_actors or others:
            truths = [
                _with_station(a.step(t, DT_S, ego.x_m, ego.y_m), a.plan, k + 1)
                for k, a in enumerate(ev_actors)
            ]
            traffic = [_with_station(a.step(t, DT_S, ego.x_m, ego.y_m), a.plan, 0) for a in others]
            world.evs, world.traffic = tuple(truths), tuple(traffic)
            ev_truth = world.ev = truths[0] if truths else None
        beliefs = _beliefs(sensing, t, ego)
        belief = beliefs[0]
        est = locator.estimate(ego, DT_S) if locator is not None else ego
        lane_k = nearest_index(scenario.lane, ego.x_m, ego.y_m, lane_hint)
        lane_hint = lane_k
        lane_s = float(scenario.lane.s_m[lane_k])
        if i % DECIDE_EVERY == 0:
            decision = fsm.update_all(beliefs, ego, _road(scenario, lane_s))
            if not actions or actions[-1][1:] != (decision.state.value, decision.action):
                actions.append((t, decision.state.value, decision.action))
            new_path = planner.update(decision, x=est.x_m, y=est.y_m, speed_mps=est.vx_mps)
            if new_path is not path:
                path = new_path
                hint = None
                paths.append((t, path.x_m, path.y_m))
        steer_cmd, errors, hint = lateral.steer(est, path, hint)
        if est is not ego:  # the metrics measure the truth
            errors, _ = lateral.errors(ego, path, hint)
        stop_d = planner.distance_to_stop(est.x_m, est.y_m, hint) if decision.stop_s_m is not None else None
        target = decision.target_speed_mps
        for truth in truths + traffic:
            target = min(target, _follow_speed(ego, truth, body))
        accel_cmd = longitudinal.accel(
            est, target, stop_d, max_decel_mps2=decision.max_decel_mps2, max_jerk_mps3=decision.max_jerk_mps3
        )
        ego_box = rectangle_corners(ego.x_m, ego.y_m, ego.yaw_rad, body[0], body[1])
        gap = min((_gap(ego_box, v) for v in truths), default=math.nan)
        gap_traffic = min((_gap(ego_box, v) for v in traffic), default=math.nan)
        row = {
            "t": t,
            "x": ego.x_m,
            "y": ego.y_m,
            "yaw": ego.yaw_rad,
            "vx": ego.vx_mps,
            "vy": ego.vy_mps,
            "yaw_rate": ego.yaw_rate_radps,
            "steer": ego.steer_rad,
            "ax": ego.ax_mps2,
            "steer_cmd": steer_cmd,
            "accel_cmd": accel_cmd,
            "e_lat": errors.e_lat,
            "yaw_error": errors.yaw_error,
            "yaw_rate_error": errors.yaw_rate_error,
            "curvature": errors.curvature_1pm,
            "lane_s": lane_s,
            "ev_x": ev_truth.x_m if ev_truth is not None else math.nan,
            "ev_y": ev_truth.y_m if ev_truth is not None else math.nan,
            "ev_yaw": ev_truth.heading_rad if ev_truth is not None else math.nan,
            "ev_on": float(any(v.lights or v.siren for v in truths)),
            "belief_detected": float(belief.detected),
            "belief_conf": belief.confidence,
            "belief_distance": belief.distance_m,
            "belief_bearing": belief.bearing_rad,
            "state": float(states.index(decision.state)),
            "target_speed": decision.target_speed_mps,
            "gap_to_ev": gap,
            "gap_to_traffic": gap_traffic,
        }
        for k, v in row.items():
            log[k].append(float(v))
        ego = model.advance(ControlCommand(t, steer_cmd, accel_cmd), DT_S)

    close = getattr(sensing, "close", None)  # a belief source that holds a network releases it
    if close is not None:
        close()
    arrays = {k: np.asarray(v) for k, v in log.items()}
    transitions = [(t, a.value, b.value, why) for t, a, b, why in fsm.history]
    metrics = compute_metrics(scenario, arrays, transitions, planner.replans, actions, body[0])
    if plant is not None:
        limit = plant.mu * G
        metrics["plant"] = plant.describe()
        metrics["friction_limit_mps2"] = limit
        metrics["friction_modelled"] = bool(getattr(model, "friction_modelled", False))
        metrics["friction_exceeded"] = bool(metrics["max_lat_accel_mps2"] > limit)
        metrics["delay_compensation_s"] = delay_compensation_s
    if localization is not None:
        metrics["localization_perfect"] = localization.perfect
    siren = list(getattr(sensing, "observations", []))
    return ClosedLoopResult(
        scenario.name, controller, metrics, arrays, transitions, planner.replans, paths, actions, siren
    )


def _follow_speed(
    ego: VehicleState, other: EVTruth, body: tuple[float, float], time_gap_s: float = 1.5
) -> float:
    """Speed that keeps a 1.5 s gap (+ 2 m) behind another vehicle when it is ahead in the ego's lane
    (ACC); ``body`` is the ego's length and width (m)."""
    along, across = (
        float(v) for v in to_vehicle_frame(other.x_m - ego.x_m, other.y_m - ego.y_m, ego.yaw_rad)
    )
    if along <= 0.0 or abs(across) > 0.5 * (other.width_m + body[1]) + 0.3:
        return math.inf
    gap = along - 0.5 * (other.length_m + body[0])
    desired = 2.0 + time_gap_s * ego.vx_mps
    return max(0.0, other.speed_mps + (gap - desired) / 2.0)


def _gap(ego_box: np.ndarray, other: EVTruth) -> float:
    """The smallest distance (m) between the ego's rectangle and another vehicle's (≤ 0: touching)."""
    return rect_distance(
        ego_box, rectangle_corners(other.x_m, other.y_m, other.heading_rad, other.length_m, other.width_m)
    )


def _with_station(truth: EVTruth, plan: EVPlan, station: int) -> EVTruth:
    """The actor's truth with its plan's size, V2X equipment and station number."""
    return replace(truth, length_m=plan.length_m, width_m=plan.width_m, v2x=plan.v2x, station_id=station)


def _beliefs(sensing: BeliefSource, time_s: float, ego: VehicleState) -> list[EVBelief]:
    """This step's beliefs: the one :meth:`~makeway.fuse.source.BeliefSource.update` publishes (the
    most urgent) first, then every other EV the source tracks."""
    first = sensing.update(time_s, ego)
    return [first, *(b for b in sensing.beliefs() if b is not first and b.detected)]


def _road(scenario: Scenario, lane_s: float) -> RoadContext:
    return RoadContext(
        s_m=lane_s,
        lane_width_m=3.5,
        right_edge_offset_m=scenario.right_edge_offset_m,
        intersections=scenario.intersections,
        speed_limit_mps=scenario.speed_limit_mps,
    )
