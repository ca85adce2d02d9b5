"""The closed loop (SPEC §7): perceived EV → yield decision → path → control → vehicle, measured.

:func:`run_scenario` steps a built-in :class:`~makeway.sim.scenarios.Scenario` at 100 Hz:

1. the EV moves along its own path (keeping a gap behind a vehicle in its lane);
2. perception publishes an :class:`~makeway.messages.EVBelief`: simulated
   (:class:`~makeway.sim.perception.SimulatedPerception`: latency, dropouts, noise; the default), or
   the siren stack itself (:class:`~makeway.pipeline.siren_perception.SirenPerception`, with a
   :class:`~makeway.pipeline.siren_perception.SirenPerceptionConfig`): the array's audio rendered
   as the car drives, the shipped siren networks, and the fused EV track;
3. the yield state machine decides at 20 Hz; the planner replans the reference path on a new
   manoeuvre;
4. the lateral controller (feed-forward + feedback by default, or a baseline) and the longitudinal
   controller command the single-track vehicle model.

Every step is logged; :class:`ClosedLoopResult` holds the log and the metrics the issue names
(``max_abs_e_lat_m``, ``settled_abs_e_lat_m``, error ranges, comfort, timing, clearance, action).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from makeway.control import LATERAL_CONTROLLERS, LongitudinalController
from makeway.decide import YieldConfig, YieldStateMachine
from makeway.frames import to_vehicle_frame
from makeway.messages import ControlCommand, EVBelief, RoadContext, SirenObservation, VehicleState, YieldState
from makeway.perceive.audio.siren_model import SirenModel
from makeway.pipeline.siren_perception import SirenPerception, SirenPerceptionConfig
from makeway.plan.path import lateral_offsets, nearest_index, point_at
from makeway.plan.planner import YieldPlanner
from makeway.sim.perception import EVTruth, PerceptionConfig, SimulatedPerception
from makeway.sim.scenarios import EVPlan, Scenario
from makeway.sim.vehicle import SingleTrackModel, VehicleParams

EGO_LENGTH_M, EGO_WIDTH_M = 4.8, 1.85
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


# ----------------------------------------------------------------------------------------- geometry


def _corners(x: float, y: float, yaw: float, length: float, width: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    hl, hw = 0.5 * length, 0.5 * width
    local = np.array([[hl, hw], [hl, -hw], [-hl, -hw], [-hl, hw]])
    return local @ np.array([[c, s], [-s, c]]) + np.array([x, y])


def _overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Separating-axis test for two convex quadrilaterals."""
    for poly in (a, b):
        for i in range(4):
            edge = poly[(i + 1) % 4] - poly[i]
            axis = np.array([-edge[1], edge[0]])
            pa, pb = a @ axis, b @ axis
            if pa.max() < pb.min() or pb.max() < pa.min():
                return False
    return True


def _points_to_edges(p: np.ndarray, q: np.ndarray) -> float:
    """Smallest distance from the corners ``p (4, 2)`` to the edges of rectangle ``q``."""
    a = q
    ab = np.roll(q, -1, axis=0) - q  # (4, 2) edges
    ap = p[:, None, :] - a[None, :, :]  # (4 points, 4 edges, 2)
    t = np.clip((ap * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0.0, 1.0)
    d = ap - t[..., None] * ab
    return float(np.sqrt((d * d).sum(-1)).min())


def rect_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Gap between two rectangles (0 when they touch or overlap)."""
    reach = float(np.ptp(a, axis=0).max() + np.ptp(b, axis=0).max())
    centre_gap = float(np.linalg.norm(a.mean(axis=0) - b.mean(axis=0)))
    if centre_gap > reach:  # far apart: the gap is at least this (exact enough for metrics)
        return centre_gap - 0.5 * reach
    if _overlap(a, b):
        return 0.0
    return min(_points_to_edges(a, b), _points_to_edges(b, a))


# -------------------------------------------------------------------------------------------- the EV


class _EVAgent:
    """Moves an :class:`EVPlan` along its path, keeping a gap behind the ego when in its lane."""

    def __init__(self, plan: EVPlan) -> None:
        self.plan = plan
        self.s = plan.start_s_m
        self.v = plan.speed_mps(0.0)

    def step(self, t: float, dt: float, ego_x: float, ego_y: float) -> EVTruth:
        p = self.plan
        want = p.speed_mps(t)
        x, y, h = point_at(p.path, self.s)
        # the ego in the EV's lane ahead of it: keep the gap (a simple car-following rule)
        dx, dy = ego_x - x, ego_y - y
        along = dx * math.cos(h) + dy * math.sin(h)
        across = -dx * math.sin(h) + dy * math.cos(h)
        if along > 0.0 and abs(across) < 0.5 * (p.width_m + EGO_WIDTH_M) + 0.3:
            gap = along - 0.5 * (p.length_m + EGO_LENGTH_M)
            want = min(want, max(0.0, (gap - p.min_gap_m) / 1.5))
        accel = float(np.clip((want - self.v) / 1.0, -6.0, 3.0))
        self.v = max(0.0, self.v + accel * dt)
        self.s = min(self.s + self.v * dt, float(p.path.s_m[-1]))
        x, y, h = point_at(p.path, self.s)
        on = p.signals_on_s <= t < p.signals_off_s
        return EVTruth(t, x, y, h, self.v, lights=on and p.lights, siren=on and p.siren)


# ----------------------------------------------------------------------------------------- the loop


def run_scenario(
    scenario: Scenario,
    *,
    controller: str = "ffb",
    perception: PerceptionConfig | SirenPerceptionConfig | None = None,
    params: VehicleParams | None = None,
    yield_config: YieldConfig | None = None,
    siren_model: SirenModel | None = None,
) -> ClosedLoopResult:
    """Run ``scenario`` in closed loop with the lateral controller ``controller`` (registry name).

    ``perception``: a :class:`~makeway.sim.perception.PerceptionConfig` (or ``None``) simulates
    perception; a :class:`~makeway.pipeline.siren_perception.SirenPerceptionConfig` runs the siren
    stack on simulated array audio, with ``siren_model`` (default: the shipped networks; pass one to
    share it between runs)."""
    if controller not in LATERAL_CONTROLLERS:
        raise ValueError(f"unknown controller {controller!r}; available: {', '.join(LATERAL_CONTROLLERS)}")
    params = params if params is not None else VehicleParams()
    model = SingleTrackModel(params)
    lateral = LATERAL_CONTROLLERS[controller](params)
    longitudinal = LongitudinalController()
    fsm = YieldStateMachine(yield_config)
    sensing: SimulatedPerception | SirenPerception
    if isinstance(perception, SirenPerceptionConfig):
        sensing = SirenPerception(
            scenario.duration_s, perception, model=siren_model, initial_speed_mps=scenario.ego_speed_mps
        )
    else:
        sensing = SimulatedPerception(perception)
    planner = YieldPlanner(
        scenario.lane, right_edge_offset_m=scenario.right_edge_offset_m, intersections=scenario.intersections
    )
    x0, y0, h0 = point_at(scenario.lane, scenario.ego_start_s_m)
    ego = VehicleState(0.0, x0, y0, h0, scenario.ego_speed_mps)
    ev_agent = _EVAgent(scenario.ev) if scenario.ev is not None else None

    n = int(round(scenario.duration_s / DT_S))
    log: dict[str, list[float]] = {k: [] for k in LOG_COLUMNS}
    states = list(YieldState)
    decision = fsm.update(sensing.update(0.0, x0, y0, h0, None), ego, _road(scenario, 0.0))
    path = planner.path
    hint: int | None = None
    lane_hint: int | None = None
    paths: list[tuple[float, np.ndarray, np.ndarray]] = [(0.0, path.x_m, path.y_m)]
    ev_truth: EVTruth | None = None
    actions: list[tuple[float, str, str]] = []  # (time, state, action) whenever the action changes
    for i in range(n):
        t = i * DT_S
        if ev_agent is not None:
            ev_truth = ev_agent.step(t, DT_S, ego.x_m, ego.y_m)
        belief = sensing.update(t, ego.x_m, ego.y_m, ego.yaw_rad, ev_truth)
        lane_k = nearest_index(scenario.lane, ego.x_m, ego.y_m, lane_hint)
        lane_hint = lane_k
        lane_s = float(scenario.lane.s_m[lane_k])
        if i % DECIDE_EVERY == 0:
            decision = fsm.update(belief, ego, _road(scenario, lane_s))
            if not actions or actions[-1][1:] != (decision.state.value, decision.action):
                actions.append((t, decision.state.value, decision.action))
            new_path = planner.update(decision, x=ego.x_m, y=ego.y_m, speed_mps=ego.vx_mps)
            if new_path is not path:
                path = new_path
                hint = None
                paths.append((t, path.x_m, path.y_m))
        steer_cmd, errors, hint = lateral.steer(ego, path, hint)
        stop_d = planner.distance_to_stop(ego.x_m, ego.y_m, hint) if decision.stop_s_m is not None else None
        target = decision.target_speed_mps
        if ev_truth is not None and scenario.ev is not None:
            target = min(target, _follow_speed(ego, ev_truth, scenario.ev))
        accel_cmd = longitudinal.accel(ego, target, stop_d)
        gap = math.nan
        if ev_truth is not None and scenario.ev is not None:
            gap = rect_distance(
                _corners(ego.x_m, ego.y_m, ego.yaw_rad, EGO_LENGTH_M, EGO_WIDTH_M),
                _corners(
                    ev_truth.x_m,
                    ev_truth.y_m,
                    ev_truth.heading_rad,
                    scenario.ev.length_m,
                    scenario.ev.width_m,
                ),
            )
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
            "ev_on": float(ev_truth is not None and (ev_truth.lights or ev_truth.siren)),
            "belief_detected": float(belief.detected),
            "belief_conf": belief.confidence,
            "belief_distance": belief.distance_m,
            "belief_bearing": belief.bearing_rad,
            "state": float(states.index(decision.state)),
            "target_speed": decision.target_speed_mps,
            "gap_to_ev": gap,
        }
        for k, v in row.items():
            log[k].append(float(v))
        ego = model.step(ego, ControlCommand(t, steer_cmd, accel_cmd), DT_S)

    arrays = {k: np.asarray(v) for k, v in log.items()}
    transitions = [(t, a.value, b.value, why) for t, a, b, why in fsm.history]
    metrics = compute_metrics(scenario, arrays, transitions, planner.replans, actions)
    siren = sensing.observations if isinstance(sensing, SirenPerception) else []
    return ClosedLoopResult(
        scenario.name, controller, metrics, arrays, transitions, planner.replans, paths, actions, siren
    )


def _follow_speed(ego: VehicleState, ev: EVTruth, plan: EVPlan, time_gap_s: float = 1.5) -> float:
    """Speed that keeps a 1.5 s gap (+ 2 m) behind the EV when it is ahead in the ego's lane (ACC)."""
    along, across = (float(v) for v in to_vehicle_frame(ev.x_m - ego.x_m, ev.y_m - ego.y_m, ego.yaw_rad))
    if along <= 0.0 or abs(across) > 0.5 * (plan.width_m + EGO_WIDTH_M) + 0.3:
        return math.inf
    gap = along - 0.5 * (plan.length_m + EGO_LENGTH_M)
    desired = 2.0 + time_gap_s * ego.vx_mps
    return max(0.0, ev.speed_mps + (gap - desired) / 2.0)


def _road(scenario: Scenario, lane_s: float) -> RoadContext:
    return RoadContext(
        s_m=lane_s,
        lane_width_m=3.5,
        right_edge_offset_m=scenario.right_edge_offset_m,
        intersections=scenario.intersections,
        speed_limit_mps=scenario.speed_limit_mps,
    )


# ------------------------------------------------------------------------------------------ metrics


def _first_time(transitions: list[tuple[float, str, str, str]], state: YieldState) -> float | None:
    for t, _, to, _ in transitions:
        if to == state.value:
            return t
    return None


def compute_metrics(
    scenario: Scenario,
    log: dict[str, np.ndarray],
    transitions: list[tuple[float, str, str, str]],
    replans: list[tuple[float, str]],
    actions: list[tuple[float, str, str]],
) -> dict[str, Any]:
    """The issue's closed-loop metrics from a run's log (definitions in the docstring lines below).

    * manoeuvre: from the first replan (pull-over or stop in lane) until the vehicle is stopped
      (or the run ends);
    * ``max_abs_e_lat_m``, ``yaw_error_range_rad``, ``yaw_rate_error_range_rad_s``: over the manoeuvre
      (the whole run when there is none);
    * ``settled_abs_e_lat_m``: the largest |e_lat| in the last second before the vehicle stopped
      (the last 2 s of the run if it never stopped);
    * ``max_lat_accel_mps2`` = max |v_x·ψ̇|, ``max_jerk_mps3`` = max |d a_x / dt| (0.1 s smoothing);
    * times from the EV's signals switching on to EV_CONFIRMED and to STOPPED_WAITING;
    * ``min_distance_to_ev_m``: the smallest gap between the two vehicles' rectangles.
    """
    t = log["t"]
    speeds = log["vx"]
    on = np.flatnonzero(log["ev_on"] > 0.5)
    t_on = float(t[on[0]]) if on.size else None
    t_conf = _first_time(transitions, YieldState.EV_CONFIRMED)
    t_stop = _first_time(transitions, YieldState.STOPPED_WAITING)
    start = replans[0][0] if replans and replans[0][1] != "resume" else None
    end = t_stop if t_stop is not None else float(t[-1])
    man = (t >= start) & (t <= end) if start is not None else np.ones_like(t, dtype=bool)
    if t_stop is not None:
        settled = (t >= t_stop - 1.0) & (t <= t_stop)
    else:
        settled = t >= t[-1] - 2.0
    ax = log["ax"]
    k = max(1, int(round(0.1 / DT_S)))
    ax_s = np.convolve(ax, np.ones(k) / k, mode="same")
    jerk = np.abs(np.diff(ax_s)) / DT_S if len(ax_s) > 1 else np.zeros(1)
    jerk = jerk[k:-k] if len(jerk) > 2 * k else jerk

    gap = log["gap_to_ev"]
    stopped = t_stop is not None
    action = _action(actions)
    rest = speeds < 0.2
    front, rear = log["lane_s"] + 0.5 * EGO_LENGTH_M, log["lane_s"] - 0.5 * EGO_LENGTH_M
    inter_ok = not any(np.any(rest & (front > s0) & (rear < s1)) for s0, s1 in scenario.intersections)
    return {
        "scenario": scenario.name,
        "max_abs_e_lat_m": float(np.max(np.abs(log["e_lat"][man]))),
        "settled_abs_e_lat_m": float(np.max(np.abs(log["e_lat"][settled]))),
        "yaw_error_range_rad": [float(log["yaw_error"][man].min()), float(log["yaw_error"][man].max())],
        "yaw_rate_error_range_rad_s": [
            float(log["yaw_rate_error"][man].min()),
            float(log["yaw_rate_error"][man].max()),
        ],
        "max_lat_accel_mps2": float(np.max(np.abs(log["vx"] * log["yaw_rate"]))),
        "max_jerk_mps3": float(np.max(jerk)) if jerk.size else 0.0,
        "time_active_to_detected_s": (t_conf - t_on) if (t_conf is not None and t_on is not None) else None,
        "time_active_to_stopped_s": (t_stop - t_on) if (t_stop is not None and t_on is not None) else None,
        "min_distance_to_ev_m": float(np.nanmin(gap)) if np.isfinite(gap).any() else None,
        "collision": bool(np.isfinite(gap).any() and np.nanmin(gap) <= 0.0),
        "stopped": stopped,
        "stopped_clear_of_intersections": inter_ok,
        "action": action,
        "expected_action": scenario.expected_action,
        "action_ok": action == scenario.expected_action,
        "final_state": transitions[-1][2] if transitions else YieldState.NO_EV.value,
        "final_speed_mps": float(speeds[-1]),
        "max_offset_from_lane_m": float(
            np.max(np.abs(lateral_offsets(scenario.lane, log["x"][::20], log["y"][::20])))
        ),
        "transitions": len(transitions),
    }


def _action(actions: list[tuple[float, str, str]]) -> str:
    """What the decision did: its action when the ego came to a stop for the EV, else the first
    action other than driving on (``"continue"`` when there was none)."""
    moving = [a for _, st, a in actions if st == YieldState.MOVING_OVER.value and a != "clear_intersection"]
    if moving:
        return moving[-1]
    others = [a for _, _, a in actions if a not in ("continue", "resume", "wait")]
    return others[0] if others else "continue"
