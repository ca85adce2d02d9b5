"""Make way in closed loop: seed003 against seed 003's field test, the baselines, and every scenario.

    .venv/bin/python benchmarks/bench_pull_over.py [--seeds 10]

1. seed003 (ego 13.4 m/s, EV 50 m behind switches on) with feed-forward + feedback steering, Stanley
   and pure pursuit on the same vehicle, path and perception: max |e_lat| in the manoeuvre, settled
   |e_lat|, yaw and yaw-rate error ranges, printed next to the field test (0.55 m, ~0.10 m,
   −0.05…+0.01 rad, −0.08…+0.06 rad/s) and the targets (≤ 0.25 m, ≤ 0.05 m, ±0.03 rad).
2. The same over ``--seeds`` perception noise seeds (dropouts, latency jitter): worst and median.
3. Every built-in scenario: action taken vs the right one, collision, closest approach, time to stop.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys

from makeway.pipeline.closed_loop import run_scenario
from makeway.sim.perception import PerceptionConfig
from makeway.sim.scenarios import SCENARIOS

FIELD = {"max": 0.55, "settled": 0.10, "yaw": (-0.05, 0.01), "yaw_rate": (-0.08, 0.06)}


def _rng(v: list[float]) -> str:
    return f"[{v[0]:+.3f}, {v[1]:+.3f}]"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=10, help="perception seeds for the robustness sweep")
    args = ap.parse_args()

    sc = SCENARIOS["seed003"]()
    print("seed003: ego 13.4 m/s, EV 50 m behind switches lights and siren on (simulated perception)")
    header = (
        f"{'':28s} {'max|e_lat| m':>12s} {'settled m':>10s} {'yaw err rad':>18s} {'yaw-rate err rad/s':>20s}"
    )
    print(header)
    print(
        f"{'field test (seed 003)':28s} {FIELD['max']:12.3f} {FIELD['settled']:10.3f} "
        f"{_rng(list(FIELD['yaw'])):>18s} {_rng(list(FIELD['yaw_rate'])):>20s}"
    )
    print(f"{'target':28s} {'≤ 0.250':>12s} {'≤ 0.050':>10s} {'within ±0.030':>18s}")
    per_ctrl = {}
    for ctrl in ("ffb", "stanley", "pure_pursuit"):
        m = run_scenario(sc, controller=ctrl).metrics
        per_ctrl[ctrl] = m
        print(
            f"{'makeway ' + ctrl:28s} {m['max_abs_e_lat_m']:12.3f} {m['settled_abs_e_lat_m']:10.3f} "
            f"{_rng(m['yaw_error_range_rad']):>18s} {_rng(m['yaw_rate_error_range_rad_s']):>20s}"
        )
    ffb = per_ctrl["ffb"]
    print(
        f"ffb vs field test: max |e_lat| {FIELD['max'] / max(ffb['max_abs_e_lat_m'], 1e-9):.0f}× smaller; "
        f"EV on → detected {ffb['time_active_to_detected_s']:.2f} s, "
        f"→ stopped {ffb['time_active_to_stopped_s']:.2f} s; "
        f"max lateral accel {ffb['max_lat_accel_mps2']:.2f} m/s², max jerk {ffb['max_jerk_mps3']:.2f} m/s³"
    )

    maxes, settled, stops, gaps = [], [], [], []
    for seed in range(args.seeds):
        m = run_scenario(sc, perception=PerceptionConfig(seed=seed)).metrics
        maxes.append(m["max_abs_e_lat_m"])
        settled.append(m["settled_abs_e_lat_m"])
        stops.append(
            m["time_active_to_stopped_s"] if m["time_active_to_stopped_s"] is not None else float("inf")
        )
        gaps.append(m["min_distance_to_ev_m"])
    print(f"\nseed003 over {args.seeds} perception seeds (ffb): worst / median")
    print(f"  max |e_lat|      {max(maxes):.3f} / {statistics.median(maxes):.3f} m")
    print(f"  settled |e_lat|  {max(settled):.3f} / {statistics.median(settled):.3f} m")
    print(f"  EV on → stopped  {max(stops):.2f} / {statistics.median(stops):.2f} s")
    print(f"  closest approach {min(gaps):.2f} / {statistics.median(gaps):.2f} m (worst is the smallest)")

    print(
        f"\n{'scenario':14s} {'action':26s} {'expected':26s} {'ok':>3s} {'collision':>9s} "
        f"{'closest m':>9s} {'on→stop s':>9s}"
    )
    all_ok = True
    rows = {}
    for name in SCENARIOS:
        m = run_scenario(SCENARIOS[name]()).metrics
        ok = m["action_ok"] and not m["collision"]
        all_ok &= ok
        rows[name] = {k: m[k] for k in ("action", "expected_action", "collision", "min_distance_to_ev_m")}
        gap = "—" if m["min_distance_to_ev_m"] is None else f"{m['min_distance_to_ev_m']:.1f}"
        stop = "—" if m["time_active_to_stopped_s"] is None else f"{m['time_active_to_stopped_s']:.2f}"
        print(
            f"{name:14s} {m['action']:26s} {m['expected_action']:26s} {'yes' if ok else 'NO':>3s} "
            f"{'yes' if m['collision'] else 'no':>9s} {gap:>9s} {stop:>9s}"
        )
    targets = (
        ffb["max_abs_e_lat_m"] <= 0.25
        and ffb["settled_abs_e_lat_m"] <= 0.05
        and ffb["yaw_error_range_rad"][0] >= -0.03
        and ffb["yaw_error_range_rad"][1] <= 0.03
        and all(ffb["max_abs_e_lat_m"] < per_ctrl[c]["max_abs_e_lat_m"] for c in ("stanley", "pure_pursuit"))
        and all_ok
    )
    print(
        json.dumps(
            {
                "seed003": {
                    c: {
                        k: per_ctrl[c][k]
                        for k in ("max_abs_e_lat_m", "settled_abs_e_lat_m", "yaw_error_range_rad")
                    }
                    for c in per_ctrl
                },
                "seeds": {"max_abs_e_lat_worst": max(maxes), "time_to_stop_worst_s": max(stops)},
                "scenarios": rows,
                "targets_met": targets,
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
