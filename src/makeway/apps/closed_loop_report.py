"""Plots and summaries of closed-loop runs, in the manner of seed 003's Figs. 12–16 (SPEC §6).

``write_closed_loop_report(result, out_dir)`` writes ``paths.png`` (reference paths, driven path, the
EV, and where the EV was detected), ``speed.png``, ``errors.png`` (lateral, yaw and yaw-rate error
against time with the field-test bounds), ``states.png`` (yield state and perception), and
``metrics.json``. With siren perception in the loop it also writes ``siren.png`` (the EV's true
distance and bearing against what the siren stack heard and the fused track it kept) and
``siren.jsonl`` (every listener message with the belief it gave). Matplotlib's Agg backend; all
writes are atomic.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from makeway.atomic import atomic_path, write_text_atomic
from makeway.frames import to_vehicle_frame
from makeway.jsonable import to_jsonable
from makeway.messages import YieldState
from makeway.pipeline.closed_loop import ClosedLoopResult
from makeway.sim.scenarios import Scenario

FIELD_TEST = {"max_abs_e_lat_m": 0.55, "settled_abs_e_lat_m": 0.10, "yaw_error_range_rad": (-0.05, 0.01)}


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Any, path: Path) -> None:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, bbox_inches="tight")
    _plt().close(fig)


_EVENTS = {
    YieldState.EV_CONFIRMED.value: ("EV confirmed", "tab:green", "--"),
    YieldState.STOPPED_WAITING.value: ("stopped, waiting", "0.3", "-."),
}


def _event_lines(ax: Any, result: ClosedLoopResult) -> None:
    """Vertical lines, each labelled once for the legend: the EV's signals switching on (red
    dotted), the decision confirming the EV (green dashed) and the car stopping to wait (grey)."""
    on = np.flatnonzero(result.log["ev_on"] > 0.5)
    if on.size:
        ax.axvline(result.log["t"][on[0]], color="tab:red", ls=":", lw=1, label="EV signals on")
    labelled: set[str] = set()
    for t, _, to, _ in result.transitions:
        if to in _EVENTS:
            text, colour, style = _EVENTS[to]
            ax.axvline(t, color=colour, ls=style, lw=0.9, label=None if to in labelled else text)
            labelled.add(to)


def _legend(ax: Any, *more: Any, **kwargs: Any) -> None:
    """One legend on ``ax`` holding the labelled lines of ``ax`` and of the ``more`` axes (twins)."""
    handles, labels = ax.get_legend_handles_labels()
    for other in more:
        h, lab = other.get_legend_handles_labels()
        handles, labels = handles + h, labels + lab
    if handles:
        ax.legend(handles, labels, fontsize=8, **kwargs)


def write_closed_loop_report(
    result: ClosedLoopResult, scenario: Scenario, out_dir: str | Path
) -> dict[str, str]:
    """Write the plots and ``metrics.json`` of one run into ``out_dir``; return the files by name."""
    plt = _plt()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    log = result.log
    t = log["t"]
    files: dict[str, str] = {}

    # Fig. 12: paths with the detection point
    fig, ax = plt.subplots(figsize=(10, 3.6))
    for line in scenario.road_lines:
        ax.plot(line.x_m, line.y_m, color="0.75", lw=1)
    ax.plot(scenario.lane.x_m, scenario.lane.y_m, color="0.5", ls="--", lw=1, label="original lane centre")
    for k, (_, px, py) in enumerate(result.paths[1:]):
        ax.plot(px, py, color="tab:green", lw=1.2, alpha=0.8, label="reference path" if k == 0 else None)
    ax.plot(log["x"], log["y"], color="tab:blue", lw=2, label=f"ego ({result.controller})")
    if np.isfinite(log["ev_x"]).any():
        ax.plot(log["ev_x"], log["ev_y"], color="tab:red", lw=1.2, alpha=0.7, label="EV")
    conf = [tr for tr in result.transitions if tr[2] == YieldState.EV_CONFIRMED.value]
    if conf:
        i = int(np.searchsorted(t, conf[0][0]))
        ax.plot(log["x"][i], log["y"][i], "k*", ms=12, label="EV detected")
    stop = [tr for tr in result.transitions if tr[2] == YieldState.STOPPED_WAITING.value]
    if stop:
        i = int(np.searchsorted(t, stop[0][0]))
        ax.plot(log["x"][i], log["y"][i], "s", color="tab:blue", ms=8, label="stopped")
    for s0, s1 in scenario.intersections:
        i0 = int(np.searchsorted(scenario.lane.s_m, s0))
        i1 = int(np.searchsorted(scenario.lane.s_m, s1))
        ax.axvspan(
            scenario.lane.x_m[i0],
            scenario.lane.x_m[min(i1, len(scenario.lane) - 1)],
            color="orange",
            alpha=0.2,
        )
    xs = np.concatenate([log["x"], log["ev_x"][np.isfinite(log["ev_x"])]])
    ax.set_xlim(float(np.min(xs)) - 20, float(np.max(xs)) + 20)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{scenario.name}: paths and detection point")
    ax.legend(fontsize=8, loc="best", ncol=3)
    _save(fig, out / "paths.png")
    files["paths"] = str(out / "paths.png")

    # Fig. 13: speed
    fig, ax = plt.subplots(figsize=(10, 3))
    ax.plot(t, log["vx"], color="tab:blue", label="ego speed")
    ax.plot(t, log["target_speed"], color="0.5", ls="--", lw=1, label="decision target speed")
    _event_lines(ax, result)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("speed (m/s)")
    _legend(ax)
    ax.grid(alpha=0.3)
    _save(fig, out / "speed.png")
    files["speed"] = str(out / "speed.png")

    # Figs. 14–16: errors
    fig, axes = plt.subplots(3, 1, figsize=(10, 7.5), sharex=True)
    specs = [
        ("e_lat", "lateral error e_lat (m)", [0.55, -0.55], "field test max |e_lat| 0.55 m"),
        ("yaw_error", "yaw error (rad)", [-0.05, 0.01], "field test range −0.05…+0.01 rad"),
        ("yaw_rate_error", "yaw-rate error (rad/s)", [-0.08, 0.06], "field test range −0.08…+0.06 rad/s"),
    ]
    for ax, (key, label, bounds, note) in zip(axes, specs, strict=True):
        ax.plot(t, log[key], color="tab:blue", lw=1.2, label="makeway")
        for k, b in enumerate(bounds):
            ax.axhline(b, color="tab:orange", ls=":", lw=1, label=note if k == 0 else None)
        _event_lines(ax, result)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        _legend(ax, loc="upper right")
    axes[-1].set_xlabel("time (s)")
    axes[0].set_title(f"{scenario.name}: tracking errors ({result.controller})")
    _save(fig, out / "errors.png")
    files["errors"] = str(out / "errors.png")

    # states and perception
    fig, ax = plt.subplots(figsize=(10, 2.8))
    names = [s.value for s in YieldState]
    ax.step(t, log["state"], where="post", color="tab:purple", label="yield state")
    ax.set_yticks(range(len(names)))
    ax.set_yticklabels(names, fontsize=8)
    ax2 = ax.twinx()
    ax2.plot(t, log["belief_conf"], color="tab:red", lw=0.8, alpha=0.6, label="perception confidence")
    ax2.set_ylim(-0.05, 1.05)
    ax2.set_ylabel("confidence")
    _event_lines(ax, result)
    ax.set_xlabel("time (s)")
    ax.set_title(f"{scenario.name}: decision")
    _legend(ax, ax2, loc="center right")
    _save(fig, out / "states.png")
    files["states"] = str(out / "states.png")

    if result.siren:
        files.update(_siren_report(result, out))

    doc = {
        "scenario": scenario.name,
        "description": scenario.description,
        "controller": result.controller,
        "metrics": to_jsonable(result.metrics, digits=5),
        "transitions": [
            {"time_s": round(tt, 3), "from": a, "to": b, "reason": why}
            for tt, a, b, why in result.transitions
        ],
        "replans": [{"time_s": round(tt, 3), "what": what} for tt, what in result.replans],
    }
    write_text_atomic(out / "metrics.json", json.dumps(doc, indent=2) + "\n")
    files["metrics"] = str(out / "metrics.json")
    return files


def _siren_report(result: ClosedLoopResult, out: Path) -> dict[str, str]:
    """``siren.png`` and ``siren.jsonl`` of a run with siren perception (module docstring)."""
    plt = _plt()
    log = result.log
    t = log["t"]
    dx, dy = log["ev_x"] - log["x"], log["ev_y"] - log["y"]
    rel_x, rel_y = to_vehicle_frame(dx, dy, log["yaw"])
    on = log["ev_on"] > 0.5
    true_d = np.where(on, np.hypot(rel_x, rel_y), np.nan)
    true_b = np.where(on, np.degrees(np.arctan2(rel_y, rel_x)), np.nan)
    obs_t = np.array([o.t_end for o, _ in result.siren])
    heard = [(o.t_end, o.sources[0]) for o, _ in result.siren if o.is_siren and o.sources]
    fused = [(b.time_s, b.distance_m, b.bearing_rad) for _, b in result.siren if b.detected]
    fig, axes = plt.subplots(3, 1, figsize=(10, 7.5), sharex=True)
    axes[0].plot(
        obs_t, [o.smoothed_probability for o, _ in result.siren], color="tab:purple", lw=1, label="P(siren)"
    )
    axes[0].set_ylabel("P(siren), smoothed")
    axes[0].set_ylim(-0.05, 1.05)
    axes[1].plot(t, true_d, color="k", lw=1.2, label="true (siren on)")
    axes[2].plot(t, true_b, color="k", lw=1.2, label="true (siren on)")
    if heard:
        ht = np.array([h[0] for h in heard])
        hd = np.array([np.nan if h[1].distance_m is None else h[1].distance_m for h in heard])
        axes[1].plot(ht, hd, ".", color="tab:orange", ms=3, label="heard (networks)")
        axes[2].plot(
            ht, np.degrees([h[1].bearing_rad for h in heard]), ".", color="tab:orange", ms=3, label="heard"
        )
    if fused:
        ft = np.array([f[0] for f in fused])
        axes[1].plot(ft, [f[1] for f in fused], color="tab:blue", lw=1, label="fused track")
        axes[2].plot(ft, np.degrees([f[2] for f in fused]), color="tab:blue", lw=1, label="fused track")
    axes[1].set_ylabel("distance (m)")
    axes[1].set_ylim(0, 150)
    axes[2].set_ylabel("bearing (°, 0 ahead, + left)")
    axes[2].set_ylim(-185, 185)
    for ax in axes:
        _event_lines(ax, result)
        ax.grid(alpha=0.3)
        _legend(ax, loc="upper right")
    axes[2].set_xlabel("time (s)")
    axes[0].set_title(f"{result.scenario}: what the siren stack heard")
    _save(fig, out / "siren.png")
    lines = [
        json.dumps(
            {
                **o.to_json(),
                "belief": {
                    "detected": b.detected,
                    "relation": b.relation.value,
                    "distance_m": to_jsonable(b.distance_m, digits=2),
                    "bearing_rad": to_jsonable(b.bearing_rad, digits=4),
                    "approaching": b.approaching,
                },
            }
        )
        for o, b in result.siren
    ]
    write_text_atomic(out / "siren.jsonl", "\n".join(lines) + "\n")
    return {"siren_plot": str(out / "siren.png"), "siren_jsonl": str(out / "siren.jsonl")}
