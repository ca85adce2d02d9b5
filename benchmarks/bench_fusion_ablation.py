"""Which senses make way: audio only, vision only, V2X only and all fused, on every closed-loop
scenario, and the fused car driving through held-out real street noise with false lights around
(SPEC §7; issue 26 item 5).

    .venv/bin/python benchmarks/bench_fusion_ablation.py [--seeds 2] [--no-ev-runs 12] [--full]
        [--far-ranger [PATH]]
    .venv/bin/python benchmarks/bench_fusion_ablation.py --only-no-ev --no-ev-runs 180 --first-no-ev-seed 280

Perceptions (``makeway simulate --perception``):

* ``audio`` — ``siren``: the siren stack on the roof array's audio (synthesized siren in generated
  street noise), its own EV track;
* ``vision`` — the camera rig's lights detector (modelled, :mod:`makeway.sim.cameras`) into the
  multi-EV fusion;
* ``v2x`` — the equipped EVs' signed alerts, verified, into the multi-EV fusion;
* ``fused`` — all three into the multi-EV fusion;
* ``onboard`` (the ``v2x_corridor`` scenario only) — siren and cameras without V2X, the anchor of
  the corridor's "yield ≥ 10 s earlier" target.

Every scenario × perception × seed: the action (the expected one?), collision, EV on → stopped,
how long the car then stood before deciding the EVs had passed (``waited_s``), extra yields
(manoeuvres after the first), the peak deceleration; per perception the expected-action
rate, collisions and the median EV on → stopped; crossing: how often the car stopped before the
intersection (target ≥ 95 %), the peak deceleration (a firm stop before an intersection may use up to
4.5 m/s², comfort is 3 m/s²) and the closest approach to the EV; corridor: when the yield started,
fused against on-board. Every decision uses the default
duty to yield (audible and visual, :mod:`makeway.decide.duty`).

Then ``--no-ev-runs`` drives of ``no_ev`` (20 s each) with the fused perception through held-out real
street recordings (scene seeds 100, 101, …) with the cameras' false lights: false yields (manoeuvres
started) per hour (target ≤ 0.1 over ≥ 2 h; hearing alone under the old rule: 13.5), and the
slow-downs to prepare (a confirmed EV whose evidence does not yet oblige a yield) per hour, with the
exact 95 % upper bound on the false-yield rate, and after each confirmation the lowest speed the car
reached (a stop without a yield would show as 0). ``--full`` runs 10 seeds and 360 drives (2 h of
driving); the default is a quick look. ``--only-no-ev`` runs the no-EV drives alone and
``--first-no-ev-seed`` picks their first scene seed (to split the 2 h between processes: seeds 100…279
and 280…459 are the 360 drives of ``--full``). ``--no-ev-scenario no_ev_urban`` drives a street with a
crossroads every 70 m instead of the open road: there a siren not yet placed may stop the car before
the next intersection (the rule a crossing EV needs), so false sirens cost more. The wall time is
printed.
The last line is one JSON object with every run.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from typing import Any

from scipy.stats import chi2

from makeway.decide import YieldConfig
from makeway.perceive.audio.far_range import DEFAULT_FAR_RANGER, FarRanger
from makeway.perceive.audio.siren_model import SirenModel
from makeway.pipeline.closed_loop import ClosedLoopResult, PerceptionSpec, run_scenario
from makeway.pipeline.fused_perception import FusedPerceptionConfig
from makeway.pipeline.siren_perception import SirenPerceptionConfig
from makeway.sim.cameras import CAMERA_FIGURES
from makeway.sim.live_array import LiveAudioConfig
from makeway.sim.scenarios import SCENARIOS

PERCEPTIONS = ("audio", "vision", "v2x", "fused")
TARGETS = {
    "action_ok": "every run",
    "crossing_stop_before": 0.95,
    "false_yields_per_hour": 0.1,
    "corridor_earlier_s": 10.0,
    "no_ev_hours": 2.0,
}


def spec(
    kind: str,
    seed: int,
    model: SirenModel,
    noise: str = "generated",
    far: FarRanger | None = None,
    cameras: str = "seed004",
) -> PerceptionSpec:
    """The perception ``kind`` for one scene seed (the siren networks and the far ranger, when
    one is given, shared between runs; ``cameras`` names the simulated cameras' figures,
    :data:`~makeway.sim.cameras.CAMERA_FIGURES`)."""
    audio = LiveAudioConfig(seed=seed, noise=noise)
    if kind == "audio":
        return SirenPerceptionConfig(audio=audio, model=model, far_ranger=far)
    senses = {
        "vision": ("light",),
        "v2x": ("v2x",),
        "fused": ("siren", "light", "v2x"),
        "onboard": ("siren", "light"),
    }[kind]
    return FusedPerceptionConfig(
        senses=senses, audio=audio, seed=seed, model=model, far_ranger=far, cameras=CAMERA_FIGURES[cameras]()
    )


def row(res: ClosedLoopResult) -> dict[str, Any]:
    """One run's figures."""
    m = res.metrics
    return {
        "action": m["action"],
        "action_ok": m["action_ok"],
        "collision": m["collision"],
        "stopped_s": m["time_active_to_stopped_s"],
        "yield_s": m["time_active_to_yield_s"],
        "extra_yields": max(0, m["yields"] - 1),
        "waited_s": m["time_stopped_waiting_s"],
        "clear_of_intersections": m["stopped_clear_of_intersections"],
        "min_gap_m": m["min_distance_to_ev_m"],
        "peak_decel_mps2": round(max(-float(res.log["ax"].min()), 0.0), 2),
    }


def poisson_upper95(count: int) -> float:
    """One-sided 95 % upper confidence bound on a Poisson mean after ``count`` events (exact,
    Garwood: half the 95th percentile of χ² with 2·(count + 1) degrees of freedom; 3.0 for 0)."""
    return float(chi2.ppf(0.95, 2 * (count + 1)) / 2.0)


def _f(v: Any) -> str:
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.2f}"
    return str(v)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=2, help="scene seeds per scenario and perception")
    ap.add_argument("--first-seed", type=int, default=0, help="the first scene seed")
    ap.add_argument("--scenarios", default=",".join(SCENARIOS), help="scenario names (comma-separated)")
    ap.add_argument("--perceptions", default=",".join(PERCEPTIONS), help="audio, vision, v2x, fused")
    ap.add_argument("--no-ev-runs", type=int, default=12, help="no-EV drives (20 s) through real noise")
    ap.add_argument("--full", action="store_true", help="10 seeds and 360 no-EV drives (2 h of driving)")
    ap.add_argument("--only-no-ev", action="store_true", help="skip the scenarios: only the no-EV drives")
    ap.add_argument("--first-no-ev-seed", type=int, default=100, help="scene seed of the first no-EV drive")
    ap.add_argument(
        "--no-ev-scenario",
        default="no_ev",
        choices=["no_ev", "no_ev_urban"],
        help="the no-EV drive: the open road, or a street with a crossroads every 70 m",
    )
    ap.add_argument(
        "--far-ranger",
        nargs="?",
        const=str(DEFAULT_FAR_RANGER),
        default=None,
        help="the siren stack with the far ranger behind it (opt-in; without a value: the shipped one)",
    )
    ap.add_argument(
        "--cameras",
        default="seed004",
        choices=list(CAMERA_FIGURES),
        help="the simulated cameras' figures: seed004 (seed 004's field test, the default) or makeway "
        "(today's lights detector by day, measured by bench_camera_figures.py)",
    )
    ap.add_argument(
        "--unplaced-siren-heard-s",
        type=float,
        default=YieldConfig().unplaced_siren_heard_s,
        help="how long (s) a siren not yet placed must be heard approaching before the car stops before "
        "an intersection for it (YieldConfig.unplaced_siren_heard_s, default %(default)s; 0: its "
        "confirmation alone)",
    )
    ap.add_argument(
        "--no-hold-short",
        action="store_true",
        help="while that call has not lasted long enough, drive on instead of braking towards the stop "
        "(YieldConfig.hold_short_while_heard=False)",
    )
    args = ap.parse_args()
    decide = YieldConfig(
        unplaced_siren_heard_s=args.unplaced_siren_heard_s, hold_short_while_heard=not args.no_hold_short
    )
    seeds = list(range(args.first_seed, args.first_seed + (10 if args.full else args.seeds)))
    no_ev_runs = 360 if args.full else args.no_ev_runs
    names = [] if args.only_no_ev else [s for s in args.scenarios.split(",") if s]
    kinds = [s for s in args.perceptions.split(",") if s]
    model = SirenModel()
    far = FarRanger(args.far_ranger) if args.far_ranger else None
    print(f"siren stack: {model!r}" + (f" + {far!r}" if far is not None else ""), flush=True)
    print(f"cameras: {args.cameras} ({CAMERA_FIGURES[args.cameras]().recall_source})", flush=True)
    if args.unplaced_siren_heard_s > 0.0:
        print(
            "the stop before an intersection for a siren not yet placed waits for "
            f"{args.unplaced_siren_heard_s:g} s of approaching call"
            + (", driving on meanwhile" if args.no_hold_short else ", braking towards the stop meanwhile"),
            flush=True,
        )
    wall0 = time.perf_counter()
    runs: list[dict[str, Any]] = []
    cols = (
        "action",
        "action_ok",
        "collision",
        "stopped_s",
        "yield_s",
        "waited_s",
        "extra_yields",
        "peak_decel_mps2",
    )
    print(
        f"{'scenario':18s} {'perception':10s} {'seed':>4s} " + " ".join(f"{c:>18s}" for c in cols), flush=True
    )
    for name in names:
        sc = SCENARIOS[name]()
        extra = ["onboard"] if name == "v2x_corridor" and "fused" in kinds else []
        for kind in kinds + extra:
            for seed in seeds:
                r = row(
                    run_scenario(
                        sc,
                        perception=spec(kind, seed, model, far=far, cameras=args.cameras),
                        yield_config=decide,
                    )
                )
                runs.append({"scenario": name, "perception": kind, "seed": seed, **r})
                print(
                    f"{name:18s} {kind:10s} {seed:>4d} " + " ".join(f"{_f(r[c]):>18s}" for c in cols),
                    flush=True,
                )
    scenario_wall = time.perf_counter() - wall0

    summary: dict[str, Any] = {}
    print("\nper perception (expected action in every run is the target; 0 collisions):")
    for kind in kinds:
        mine = [r for r in runs if r["perception"] == kind]
        if not mine:
            continue
        stops = [r["stopped_s"] for r in mine if r["stopped_s"] is not None and r["action_ok"]]
        s = {
            "runs": len(mine),
            "action_ok": sum(r["action_ok"] for r in mine),
            "action_ok_rate": round(sum(r["action_ok"] for r in mine) / len(mine), 3),
            "collisions": sum(r["collision"] for r in mine),
            "extra_yields": sum(r["extra_yields"] for r in mine),
            "median_on_to_stopped_s": round(statistics.median(stops), 2) if stops else None,
            "max_waited_s": max((r["waited_s"] for r in mine if r["waited_s"] is not None), default=None),
        }
        summary[kind] = s
        print(
            f"  {kind:8s} expected action {s['action_ok']}/{s['runs']} ({100 * s['action_ok_rate']:.0f} %), "
            f"collisions {s['collisions']}, extra yields {s['extra_yields']}, median EV on → stopped "
            f"{_f(s['median_on_to_stopped_s'])} s, longest wait once stopped {_f(s['max_waited_s'])} s"
        )
    print("\nper scenario, expected action (runs ok / runs):")
    print(f"  {'scenario':18s} " + " ".join(f"{k:>8s}" for k in kinds))
    for name in names:
        cells = []
        for kind in kinds:
            mine = [r for r in runs if r["scenario"] == name and r["perception"] == kind]
            cells.append(f"{sum(r['action_ok'] for r in mine)}/{len(mine)}" if mine else "—")
        print(f"  {name:18s} " + " ".join(f"{c:>8s}" for c in cells))
    for kind in kinds:
        cross = [r for r in runs if r["scenario"] == "crossing" and r["perception"] == kind]
        if cross:
            ok = sum(r["action"] == "stop_before_intersection" and r["clear_of_intersections"] for r in cross)
            peak = max(r["peak_decel_mps2"] for r in cross)
            gap = min((r["min_gap_m"] for r in cross if r["min_gap_m"] is not None), default=None)
            summary.setdefault(kind, {})["crossing_stop_before"] = round(ok / len(cross), 3)
            summary[kind]["crossing_peak_decel_mps2"] = peak
            print(
                f"crossing, {kind}: stopped before the intersection in {ok}/{len(cross)} (target ≥ 95 %), "
                f"peak deceleration {peak:.2f} m/s², closest approach to the EV {_f(gap)} m"
            )
    fused_c = [r["yield_s"] for r in runs if r["scenario"] == "v2x_corridor" and r["perception"] == "fused"]
    onb_c = [r["yield_s"] for r in runs if r["scenario"] == "v2x_corridor" and r["perception"] == "onboard"]
    if fused_c and onb_c and None not in fused_c:
        pairs = [(f, o) for f, o in zip(fused_c, onb_c, strict=True) if o is not None]
        earlier = [o - f for f, o in pairs]
        summary["corridor_earlier_s"] = round(min(earlier), 2) if earlier else None
        print(
            f"v2x_corridor: yield starts {statistics.median(fused_c):.1f} s after the EV switched on fused, "
            f"{_f(statistics.median([o for o in onb_c if o is not None]) if pairs else None)} s on-board "
            f"only: earlier by ≥ {_f(summary['corridor_earlier_s'])} s in every seed (target ≥ 10 s)"
        )

    t1 = time.perf_counter()
    quiet = SCENARIOS[args.no_ev_scenario]()
    false_yields = prepares = stopped = 0
    lowest: list[float] = []  # per drive with a confirmation: the lowest speed after it (m/s)
    for k in range(no_ev_runs):
        seed = args.first_no_ev_seed + k
        cfg = FusedPerceptionConfig(
            audio=LiveAudioConfig(seed=seed, noise="real"),
            seed=seed,
            model=model,
            far_ranger=far,
            cameras=CAMERA_FIGURES[args.cameras](),
        )
        res = run_scenario(quiet, perception=cfg, yield_config=decide)
        fy = res.metrics["yields"]
        pr = sum(1 for _, _, to, _ in res.transitions if to == "ev_confirmed")
        false_yields += fy
        prepares += pr
        first = next((t for t, _, to, _ in res.transitions if to == "ev_confirmed"), None)
        if first is not None:
            low = float(res.log["vx"][res.log["t"] >= first].min())
            lowest.append(low)
            stopped += low < 0.2
        if fy or pr:
            low_s = f", lowest speed after it {lowest[-1]:.1f} m/s" if first is not None else ""
            print(f"  no-EV drive seed {seed}: {fy} yields, {pr} confirmations{low_s}", flush=True)
        if (k + 1) % 20 == 0:
            print(f"  {k + 1}/{no_ev_runs} no-EV drives, {false_yields} false yields so far", flush=True)
    hours = no_ev_runs * quiet.duration_s / 3600.0
    no_ev = {
        "scenario": quiet.name,
        "drives": no_ev_runs,
        "hours": round(hours, 4),
        "false_yields": false_yields,
        "false_yields_per_hour": round(false_yields / hours, 3) if hours else None,
        "false_yields_per_hour_upper95": round(poisson_upper95(false_yields) / hours, 3) if hours else None,
        "false_confirmations_per_hour": round(prepares / hours, 3) if hours else None,
        "drives_stopped_after_a_confirmation": stopped,
        "lowest_speed_after_a_confirmation_mps": sorted(round(x, 2) for x in lowest),
        "false_lights_per_hour_modelled": FusedPerceptionConfig().cameras.false_rate_per_hour,
        "wall_s": round(time.perf_counter() - t1, 1),
    }
    if no_ev_runs:
        print(
            f"no EV ({quiet.name}), fused, real held-out street noise and false lights: {false_yields} "
            f"false yields in "
            f"{no_ev_runs} drives ({hours:.2f} h) = {no_ev['false_yields_per_hour']} per hour (target ≤ "
            f"{TARGETS['false_yields_per_hour']} over ≥ {TARGETS['no_ev_hours']:g} h; hearing alone, "
            f"old rule: 13.5); 95 % upper bound {no_ev['false_yields_per_hour_upper95']} per hour; "
            f"EVs confirmed (slow-downs) {no_ev['false_confirmations_per_hour']} per hour"
        )
        if lowest:
            print(
                f"  after a confirmation the car stopped in {stopped} of {len(lowest)} drives; lowest speed "
                f"median {statistics.median(lowest):.1f} m/s, least {min(lowest):.1f} m/s "
                f"(speed limit {quiet.speed_limit_mps:.1f} m/s)"
            )
    wall = time.perf_counter() - wall0
    print(f"wall time {wall:.0f} s (scenarios {scenario_wall:.0f} s, no-EV drives {no_ev['wall_s']:.0f} s)")
    print(
        json.dumps(
            {
                "far_ranger": None if far is None else far.path.name,
                "unplaced_siren_heard_s": args.unplaced_siren_heard_s,
                "hold_short_while_heard": decide.hold_short_while_heard,
                "summary": summary,
                "no_ev": no_ev,
                "targets": TARGETS,
                "wall_s": round(wall, 1),
                "runs": runs,
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
