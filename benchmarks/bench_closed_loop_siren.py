"""Make way with the siren stack as perception: every built-in scenario, heard, against the same
scenarios with the perception model (SPEC §7's closed loop; issue 5 item 7 once issue 4 landed).

    .venv/bin/python benchmarks/bench_closed_loop_siren.py [--seeds 0,1] [--sirens synth,real]

For each scenario, scene seed and siren kind (``synth``: a procedural siren in generated street
noise, needs no data; ``real``: a held-out real siren in held-out real street recordings), the car
drives in closed loop hearing the EV through
:class:`~makeway.pipeline.siren_perception.SirenPerception` (array audio rendered as it drives →
the shipped siren networks → the fused EV track). The anchor is the same scenario with the
simulated perception (:class:`~makeway.sim.perception.SimulatedPerception`, seed 0). Printed per
run, side by side with the anchor:

* the action and whether it is the scenario's expected one, collision, stopped;
* the time from the EV's signals on to EV_CONFIRMED and to standstill;
* ``extra yields``: manoeuvres started after the first one (a receding EV taken for an approaching
  one starts a second pull-over), and the final state;
* the run's wall time against the simulated time (the audio stack's cost).

Then ``--no-ev-runs`` drives of the ``no_ev`` scenario (20 s each, no emergency vehicle) through
held-out real street recordings (scene seeds 100, 101, …): how often the car yields to nothing, as
false yields per hour of driving, beside the modelled perception (which never hears what is not
there) and the listener's per-window false-alarm rate on the same audio.

``--rangers`` picks the networks that place the siren: ``default`` (the shipped
:data:`~makeway.perceive.audio.siren_model.DEFAULT_SIREN_RANGERS`), ``prior`` (the rangers trained
on sirens of 110–120 dB at 1 m) or ``wide`` (those trained on 105–140 dB), each averaged with the
localizer's distance, and each with its own approaching/receding classifier
(:func:`~makeway.perceive.audio.motion.approach_model_for`); to compare them on the same scenes and
seeds. ``--far-ranger [PATH]`` adds the far ranger (opt-in;
:mod:`makeway.perceive.audio.far_range`; without a path the shipped one): far sirens get its
distance and no approach call, and the track treats them as beyond ranging. ``--siren-level LO,HI`` draws the
heard siren's emitted level from that range (dB SPL at 1 m; default 110–120, the networks' training
prior; real sirens span about 110–135).

The last line is one JSON object with every run.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

from makeway.perceive.audio.far_range import DEFAULT_FAR_RANGER, FarRanger
from makeway.perceive.audio.siren_model import (
    DEFAULT_SIREN_RANGERS,
    PRIOR_SIREN_RANGERS,
    WIDE_SIREN_RANGERS,
    SirenModel,
)
from makeway.pipeline.closed_loop import ClosedLoopResult, run_scenario
from makeway.pipeline.siren_perception import SirenPerceptionConfig
from makeway.sim.live_array import LiveAudioConfig
from makeway.sim.scenarios import SCENARIOS

RANGERS = {"default": DEFAULT_SIREN_RANGERS, "prior": PRIOR_SIREN_RANGERS, "wide": WIDE_SIREN_RANGERS}
"""The ranger sets ``--rangers`` chooses from (module docstring)."""


def _row(res: ClosedLoopResult, wall_s: float, duration_s: float) -> dict[str, Any]:
    m = res.metrics
    moves = sum(1 for _, _, to, _ in res.transitions if to == "moving_over")
    return {
        "action": m["action"],
        "action_ok": m["action_ok"],
        "collision": m["collision"],
        "stopped": m["stopped"],
        "detected_s": m["time_active_to_detected_s"],
        "stopped_s": m["time_active_to_stopped_s"],
        "extra_yields": max(0, moves - 1),
        "final_state": m["final_state"],
        "real_time_factor": round(duration_s / wall_s, 2),
    }


def _fmt(v: Any) -> str:
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.2f}"
    return str(v)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", default="0,1", help="scene seeds (comma-separated)")
    ap.add_argument("--sirens", default="synth,real", help="siren kinds: synth, real (needs the data)")
    ap.add_argument("--scenarios", default=",".join(SCENARIOS), help="scenario names (comma-separated)")
    ap.add_argument("--no-ev-runs", type=int, default=20, help="no-EV drives through real street noise")
    ap.add_argument("--siren-level", default="110,120", help="siren level range, dB SPL at 1 m")
    ap.add_argument("--no-anchor", action="store_true", help="skip the modelled-perception anchor runs")
    ap.add_argument("--rangers", default="default", choices=sorted(RANGERS), help="distance networks")
    ap.add_argument(
        "--far-ranger",
        nargs="?",
        const=str(DEFAULT_FAR_RANGER),
        default=None,
        help="also run the far ranger (opt-in; without a value: the shipped one)",
    )
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",") if s]
    sirens = [s for s in args.sirens.split(",") if s]
    names = [s for s in args.scenarios.split(",") if s]
    lo, hi = (float(v) for v in args.siren_level.split(","))
    model = SirenModel(ranger=RANGERS[args.rangers], localizer_distance=True)
    far = FarRanger(args.far_ranger) if args.far_ranger else None
    print(f"siren stack: {model!r}" + (f" + {far!r}" if far is not None else ""))
    runs: list[dict[str, Any]] = []
    cols = (
        "action",
        "action_ok",
        "collision",
        "stopped",
        "detected_s",
        "stopped_s",
        "extra_yields",
        "final_state",
    )
    print(
        f"{'scenario':13s} {'perception':16s} "
        + " ".join(f"{c:>13s}" for c in cols)
        + f" {'×real time':>10s}"
    )
    for name in names:
        sc = SCENARIOS[name]()
        if not args.no_anchor:
            t0 = time.perf_counter()
            anchor = _row(run_scenario(sc), time.perf_counter() - t0, sc.duration_s)
            runs.append({"scenario": name, "perception": "simulated", "seed": 0, **anchor})
            print(
                f"{name:13s} {'simulated':16s} "
                + " ".join(f"{_fmt(anchor[c]):>13s}" for c in cols)
                + f" {anchor['real_time_factor']:>10.2f}",
                flush=True,
            )
        for kind in sirens:
            for seed in seeds:
                noise = "real" if kind == "real" else "generated"
                cfg = SirenPerceptionConfig(
                    audio=LiveAudioConfig(seed=seed, siren=kind, noise=noise, siren_level_db=(lo, hi)),
                    model=model,
                    far_ranger=far,
                )
                t0 = time.perf_counter()
                res = run_scenario(sc, perception=cfg)
                row = _row(res, time.perf_counter() - t0, sc.duration_s)
                label = f"siren {kind} s{seed}"
                runs.append({"scenario": name, "perception": f"siren:{kind}", "seed": seed, **row})
                print(
                    f"{name:13s} {label:16s} "
                    + " ".join(f"{_fmt(row[c]):>13s}" for c in cols)
                    + f" {row['real_time_factor']:>10.2f}",
                    flush=True,
                )
    quiet = SCENARIOS["no_ev"]()
    false_yields, windows, alarms = 0, 0, 0
    for k in range(args.no_ev_runs):
        cfg = SirenPerceptionConfig(
            audio=LiveAudioConfig(seed=100 + k, noise="real"), model=model, far_ranger=far
        )
        res = run_scenario(quiet, perception=cfg)
        false_yields += sum(1 for _, _, to, _ in res.transitions if to == "moving_over")
        windows += len(res.siren)
        alarms += sum(o.is_siren for o, _ in res.siren)
    hours = args.no_ev_runs * quiet.duration_s / 3600.0
    no_ev = {
        "drives": args.no_ev_runs,
        "hours": round(hours, 4),
        "false_yields": false_yields,
        "false_yields_per_hour": round(false_yields / hours, 2) if hours else None,
        "window_false_alarm_rate": round(alarms / windows, 5) if windows else None,
    }
    if args.no_ev_runs:
        print(
            f"no EV, real held-out street noise: {false_yields} false yields in {args.no_ev_runs} drives "
            f"({hours * 60:.1f} min) = {no_ev['false_yields_per_hour']} per hour; listener false alarms "
            f"{100 * (no_ev['window_false_alarm_rate'] or 0):.2f} % of windows "
            "(modelled perception: 0 per hour)"
        )
    heard = [r for r in runs if r["perception"] != "simulated"]
    anchors = [r for r in runs if r["perception"] == "simulated"]
    summary = {
        "siren_runs": len(heard),
        "siren_action_ok": sum(r["action_ok"] for r in heard),
        "siren_collisions": sum(r["collision"] for r in heard),
        "siren_extra_yields": sum(r["extra_yields"] for r in heard),
        "simulated_action_ok": f"{sum(r['action_ok'] for r in anchors)}/{len(anchors)}",
    }
    print(
        f"siren stack: expected action in {summary['siren_action_ok']}/{len(heard)} runs, "
        f"{summary['siren_collisions']} collisions, {summary['siren_extra_yields']} extra yields "
        f"(simulated perception: expected action in {summary['simulated_action_ok']})"
    )
    rangers = [r.path.name for r in model.rangers]
    far_name = None if far is None else far.path.name
    print(
        json.dumps(
            {"rangers": rangers, "far_ranger": far_name, "summary": summary, "no_ev": no_ev, "runs": runs}
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
