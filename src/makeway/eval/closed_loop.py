"""Metrics of one closed-loop run (SPEC §6–7): tracking errors, comfort, timing, clearance, action."""

from __future__ import annotations

from typing import Any

import numpy as np

from makeway.messages import YieldState
from makeway.plan.path import lateral_offsets
from makeway.sim.scenarios import Scenario

__all__ = ["compute_metrics", "decided_action", "first_transition_time"]


def first_transition_time(transitions: list[tuple[float, str, str, str]], state: YieldState) -> float | None:
    """Time (s) of the first transition into ``state``; ``None`` if it never happened."""
    for t, _, to, _ in transitions:
        if to == state.value:
            return t
    return None


def _time_in_first(
    transitions: list[tuple[float, str, str, str]], state: YieldState, end_s: float
) -> float | None:
    """How long (s) the machine stayed in ``state`` the first time it entered it (until ``end_s`` if
    it never left); ``None`` if it never entered it."""
    entered = first_transition_time(transitions, state)
    if entered is None:
        return None
    left = next((t for t, fr, _, _ in transitions if fr == state.value and t >= entered), end_s)
    return left - entered


def compute_metrics(
    scenario: Scenario,
    log: dict[str, np.ndarray],
    transitions: list[tuple[float, str, str, str]],
    replans: list[tuple[float, str]],
    actions: list[tuple[float, str, str]],
    ego_length_m: float = 4.8,
) -> dict[str, Any]:
    """The issue's closed-loop metrics from a run's log (definitions in the docstring lines below).

    * manoeuvre: from the first replan (pull-over or stop in lane) until the vehicle is stopped
      (or the run ends);
    * ``max_abs_e_lat_m``, ``yaw_error_range_rad``, ``yaw_rate_error_range_rad_s``: over the manoeuvre
      (the whole run when there is none);
    * ``settled_abs_e_lat_m``: the largest |e_lat| in the last second before the vehicle stopped
      (the last 2 s of the run if it never stopped);
    * ``max_lat_accel_mps2`` = max |v_x·ψ̇|, ``max_jerk_mps3`` = max |d a_x / dt| (0.1 s smoothing);
    * times from the first EV's signals switching on to EV_CONFIRMED, to the first MOVING_OVER (the
      yield starts) and to STOPPED_WAITING; ``yields``: how many manoeuvres were started;
    * ``time_stopped_waiting_s``: how long the car stood in its first STOPPED_WAITING before deciding
      that the EVs had passed (to the end of the run if it never did; ``None`` without a stop);
    * ``min_distance_to_ev_m``: the smallest gap between the ego's rectangle and any EV's;
      ``collision``: a gap ≤ 0 to an EV or to any other vehicle of the scenario.

    ``log`` holds the closed loop's columns (:data:`makeway.pipeline.closed_loop.LOG_COLUMNS`) at a
    fixed step; ``ego_length_m`` places the ego's front and rear for the intersection check.
    """
    t = log["t"]
    dt = float(t[1] - t[0]) if len(t) > 1 else 0.01
    speeds = log["vx"]
    on = np.flatnonzero(log["ev_on"] > 0.5)
    t_on = float(t[on[0]]) if on.size else None
    t_conf = first_transition_time(transitions, YieldState.EV_CONFIRMED)
    t_stop = first_transition_time(transitions, YieldState.STOPPED_WAITING)
    t_yield = first_transition_time(transitions, YieldState.MOVING_OVER)
    start = replans[0][0] if replans and replans[0][1] != "resume" else None
    end = t_stop if t_stop is not None else float(t[-1])
    man = (t >= start) & (t <= end) if start is not None else np.ones_like(t, dtype=bool)
    if t_stop is not None:
        settled = (t >= t_stop - 1.0) & (t <= t_stop)
    else:
        settled = t >= t[-1] - 2.0
    ax = log["ax"]
    k = max(1, int(round(0.1 / dt)))
    ax_s = np.convolve(ax, np.ones(k) / k, mode="same")
    jerk = np.abs(np.diff(ax_s)) / dt if len(ax_s) > 1 else np.zeros(1)
    jerk = jerk[k:-k] if len(jerk) > 2 * k else jerk

    gap = log["gap_to_ev"]
    traffic_gap = log.get("gap_to_traffic", np.full_like(gap, np.nan))
    stopped = t_stop is not None
    action = decided_action(actions)
    rest = speeds < 0.2
    front, rear = log["lane_s"] + 0.5 * ego_length_m, log["lane_s"] - 0.5 * ego_length_m
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
        "time_active_to_yield_s": (t_yield - t_on) if (t_yield is not None and t_on is not None) else None,
        "yields": sum(1 for _, _, to, _ in transitions if to == YieldState.MOVING_OVER.value),
        "time_stopped_waiting_s": _time_in_first(transitions, YieldState.STOPPED_WAITING, float(t[-1])),
        "min_distance_to_ev_m": float(np.nanmin(gap)) if np.isfinite(gap).any() else None,
        "collision": bool(
            (np.isfinite(gap).any() and np.nanmin(gap) <= 0.0)
            or (np.isfinite(traffic_gap).any() and np.nanmin(traffic_gap) <= 0.0)
        ),
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


def decided_action(actions: list[tuple[float, str, str]]) -> str:
    """What the decision did: its action when the ego came to a stop for the EV, else the first
    action other than driving on (``"continue"`` when there was none)."""
    moving = [a for _, st, a in actions if st == YieldState.MOVING_OVER.value and a != "clear_intersection"]
    if moving:
        return moving[-1]
    others = [a for _, _, a in actions if a not in ("continue", "resume", "wait")]
    return others[0] if others else "continue"
