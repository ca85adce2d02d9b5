"""The siren network (issue 4) against the classical baselines and seed 002, on held-out recordings.

    .venv/bin/python benchmarks/bench_audio_model.py [--data DIR | --n 30 --seeds 2026,2027 --duration 8]
        [--model FILE] [--localizer FILE|none|auto] [--ranger FILE|none|auto]
        [--localizer-distance auto|yes|no]
        [--baselines gccphat,srp,normmusic] [--latency-reps 60] [--smooth 1,8] [--smooth-probability 3]
        [--keep DIR] [--json FILE]

1. Held-out recordings: ``--data`` (a folder of recordings), or ``--n`` recordings per seed
   simulated with seeds 2026 and 2027 (``--seeds``; pooled: one 30-recording set moves recall by
   1.5 points and false alarms by 3 from seed to seed) from the **test** groups only (siren models,
   clip blocks and street recordings the shipped model never trained on; ``makeway audio simulate
   --split test``).
2. Runs the model (default: the shipped one) and every baseline on the same labelled windows and
   prints, in 10–50 m and overall, recall / false alarms / angle and distance errors beside seed 002
   (recall 99.16 %, 9.64° / 19.18°, 9.30 m / 10.58 m) and the issue's targets; then recall and angle
   error per 10 m bin like seed 002's Table II. ``--smooth`` adds rows for the model with its
   decision on the causal mean logit of K windows (``makeway audio listen --smooth K``, default 8;
   K = 1 is seed 002's per-window decision), ``--smooth-probability`` rows with the mean
   probability of K windows (``--average probability``; 3 was ``listen``'s rule until the twelfth
   session, the anchor of the logit mean).
3. Latency: one 0.5 s, 8-channel, 48 kHz window through features + all heads, ONNX Runtime on
   2 threads, median of ``--latency-reps`` runs, beside the 25 ms target and the baselines' cost per
   window measured in the same run.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from makeway.eval.siren import calibrate_threshold, evaluate, model_estimator
from makeway.eval.siren_labels import label_recording
from makeway.perceive.audio.features import window_batch
from makeway.perceive.audio.siren_model import DEFAULT_SIREN_MODEL, SirenModel
from makeway.progress import progress_bar
from makeway.sense.recording import read_recording
from makeway.sim.audio_scenarios import held_out_folders

SEED_002 = {
    "recall": 0.9916,
    "angle_median_deg": 9.64,
    "angle_mean_deg": 19.18,
    "distance_median_m": 9.30,
    "distance_mean_m": 10.58,
}
TARGET = {
    "recall": ">= 99.5 %",
    "false_alarm_rate": "<= 1 %",
    "angle_median_deg": "<= 5°",
    "angle_mean_deg": "<= 10°",
    "distance_median_m": "<= 6 m",
}
COLUMNS = (
    ("recall", "recall", True),
    ("false_alarm_rate", "false alarms", True),
    ("angle_median_deg", "angle med", False),
    ("angle_mean_deg", "angle mean", False),
    ("distance_median_m", "dist med", False),
    ("distance_mean_m", "dist mean", False),
)


def _fmt(v: Any, pct: bool) -> str:
    if v is None:
        return "—"
    return f"{100 * v:.2f} %" if pct else f"{v:.2f}"


def _table(title: str, rows: dict[str, dict[str, Any]]) -> None:
    print(f"\n{title}")
    print(f"{'':22s}" + "".join(f"{h:>14s}" for _, h, _ in COLUMNS))
    for name, r in rows.items():
        print(f"{name:22s}" + "".join(f"{_fmt(r.get(k), p):>14s}" for k, _, p in COLUMNS))


def latency_ms(model: SirenModel, window: np.ndarray, reps: int) -> float:
    for _ in range(5):
        model.predict(window)
    times = []
    for _ in range(reps):
        t0 = time.perf_counter()
        model.predict(window)
        times.append(1000.0 * (time.perf_counter() - t0))
    return statistics.median(times)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=None, help="held-out recordings (default: simulate)")
    ap.add_argument("--n", type=int, default=30, help="recordings per seed to simulate without --data")
    ap.add_argument(
        "--seeds",
        default="2026,2027",
        help="seeds of the simulated held-out sets, pooled (30 recordings per seed by default)",
    )
    ap.add_argument("--duration", type=float, default=8.0, help="seconds per simulated recording")
    ap.add_argument("--model", type=Path, default=DEFAULT_SIREN_MODEL)
    ap.add_argument(
        "--localizer",
        default="auto",
        help="second model for bearing and distance: a file, 'none', or 'auto' (the shipped "
        "localizer with the shipped model)",
    )
    ap.add_argument(
        "--ranger",
        default="auto",
        help="further models whose distances are averaged in: comma-separated files, 'none', or "
        "'auto' (the shipped rangers with the shipped model)",
    )
    ap.add_argument(
        "--localizer-distance",
        default="auto",
        choices=("auto", "yes", "no"),
        help="whether the localizer's distance joins the rangers' ('auto': the shipped rule)",
    )
    ap.add_argument("--baselines", default="gccphat,srp,normmusic")
    ap.add_argument(
        "--smooth",
        default="1,8",
        help="decision smoothing (mean logit of K windows) to report for the model, in windows "
        "(1 = per window, seed 002's)",
    )
    ap.add_argument(
        "--smooth-probability",
        default="3",
        help="decision smoothing by the mean probability of K windows to report beside it",
    )
    ap.add_argument("--latency-reps", type=int, default=60)
    ap.add_argument("--keep", type=Path, default=None, help="simulate into this folder and keep it")
    ap.add_argument("--json", type=Path, default=None, help="also write every result to this JSON file")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        seeds = [int(v) for v in args.seeds.split(",") if v.strip()]
        out = args.keep if args.keep is not None else Path(tmp) / "test"
        t0 = time.perf_counter()
        folders = held_out_folders([args.data] if args.data else None, out, args.n, seeds, args.duration)
        if args.data is None:
            print(
                f"simulated {len(folders)} held-out recordings of {args.duration:g} s "
                f"(seeds {', '.join(map(str, seeds))}) in {time.perf_counter() - t0:.0f} s"
            )
        recs = [read_recording(f) for f in folders]  # read once, shared by every method

        def companion(value: str) -> Path | bool:  # 'auto' (the shipped one), 'none' or a file
            return {"auto": True, "none": False}.get(value, Path(value))

        rangers: list[Path] | bool = (
            args.ranger == "auto"
            if args.ranger in ("auto", "none")
            else [Path(v) for v in args.ranger.split(",") if v.strip()]
        )
        model = SirenModel(
            args.model,
            threads=2,
            localizer=companion(args.localizer),
            ranger=rangers,
            localizer_distance={"auto": None, "yes": True, "no": False}[args.localizer_distance],
        )
        print(f"model: {model!r} ({args.model.stat().st_size / 1e6:.2f} MB)")
        results: dict[str, dict[str, Any]] = {}
        smooths = sorted({1, *(int(v) for v in args.smooth.split(",") if v.strip())})  # 1: the table's anchor
        methods: list[tuple[str, Any, int, str]] = [
            ("model" if k == 1 else f"model, smooth {k}", model_estimator(model), k, "logit") for k in smooths
        ]
        methods += [
            (f"model, p-mean {k}", model_estimator(model), k, "probability")
            for k in sorted({int(v) for v in args.smooth_probability.split(",") if v.strip()} - {1})
        ]
        methods += [(b, b, 1, "logit") for b in args.baselines.split(",") if b]
        pooled: dict[str, np.ndarray] = {}
        for name, method, smooth, average in methods:
            with progress_bar(f"eval {name}", len(recs), unit="rec") as advance:
                results[name] = evaluate(
                    recs,
                    method,
                    on_recording=advance,
                    name=name,
                    arrays=pooled if name == "model" else None,
                    threshold=model.threshold if name.startswith("model") else 0.5,
                    smooth=smooth,
                    average=average,
                )

        first = results["model"]
        print(
            f"\nheld-out: {len(recs)} recordings, {first['windows']} windows "
            f"({first['positives']} with a siren "
            f"≤ 100 m, {first['range_10_50']['positives']} of them in 10–50 m; {first['negatives']} without)"
        )
        rows = {n: r["range_10_50"] for n, r in results.items()}
        rows["seed 002 (their data)"] = SEED_002
        _table("10–50 m (the issue's target range)", rows)
        print(f"{'target':22s}" + "".join(f"{TARGET.get(k, ''):>14s}" for k, _, _ in COLUMNS))
        _table("all windows (≤ 100 m)", {n: r for n, r in results.items()})

        print("\nby distance (model): n, recall, angle median / mean — seed 002 Table II's layout")
        for b in first["by_distance"]:
            lo, hi = b["range_m"]
            if b["n"]:
                print(
                    f"  {lo:3.0f}–{hi:3.0f} m  n={b['n']:4d}  recall {_fmt(b['recall'], True):>9s}  "
                    f"angle {_fmt(b['angle_median_deg'], False):>6s}° / "
                    f"{_fmt(b['angle_mean_deg'], False):>6s}°"
                )

        # the detection trade-off: recall in 10–50 m when the threshold is set for 1 % false alarms
        neg = pooled["prob"][~pooled["siren"]]
        if len(neg):
            t1 = calibrate_threshold(pooled["prob"], pooled["siren"], 0.01)
            d = pooled["distance"]
            in_range = pooled["siren"] & (d >= 10) & (d <= 50)
            r1 = float(np.mean(pooled["prob"][in_range] >= t1)) if in_range.any() else float("nan")
            fa1 = float(np.mean(neg >= t1))
            print(
                f"\nmodel, threshold for ≤ 1 % false alarms (t = {t1:.3f}): false alarms {100 * fa1:.2f} %, "
                f"recall 10–50 m {100 * r1:.2f} % (target ≥ 99.5 % at ≤ 1 %)"
            )
            results["at_1pct_false_alarms"] = {"threshold": t1, "false_alarm_rate": fa1, "recall_10_50": r1}

        # more than one siren: windows with two sirens within 100 m, both found among the sources
        two = found_both = 0
        for rec in recs:
            if len(rec.sources) < 2:
                continue
            lab = label_recording(rec)
            sel = np.flatnonzero(lab.present.sum(axis=1) >= 2)
            if not len(sel):
                continue
            wins = window_batch(rec, lab)[sel]
            pred = model.predict(wins, rec.full_scale_db_spl)
            for j, w in enumerate(sel):
                got = [s["bearing_rad"] for s in model.sources(pred, j, wins[j])]
                truth = lab.theta[w][lab.present[w]]
                ok = all(
                    any(abs(math.remainder(g - t, 2 * math.pi)) <= math.radians(15) for g in got)
                    for t in truth
                )
                two += 1
                found_both += int(ok)
        if two:
            print(
                f"\ntwo sirens within 100 m: {two} windows; both found within 15° in {found_both} "
                f"({100 * found_both / two:.1f} %)"
            )
            results["two_sirens"] = {"windows": two, "both_found_15deg": found_both}

        rec0 = recs[0]
        window = window_batch(rec0, label_recording(rec0))[0]
        lat = latency_ms(model, window, args.latency_reps)
        # the anchor, timed in this run on this machine: each classical baseline's cost per window
        # (detector + bearing) from its evaluation above; seed 002's ~50 ms came from other hardware
        anchors = ", ".join(
            f"{b} {results[b]['ms_per_window']:.1f} ms"
            for b in args.baselines.split(",")
            if b and results.get(b, {}).get("ms_per_window")
        )
        print(
            f"\nlatency, one 0.5 s × 8 ch × 48 kHz window, features + all heads (ORT, 2 threads): "
            f"{lat:.1f} ms  | target ≤ 25 ms ({lat / 25.0:.2f}× of it) "
            f"| baselines in this run: {anchors or '—'}"
        )
        results["latency_ms"] = {"median": round(lat, 2), "reps": args.latency_reps}
        if args.json is not None:
            args.json.write_text(json.dumps(results, indent=1))
        print(
            json.dumps(
                {
                    n: {k: r[k] for k in ("recall", "false_alarm_rate")}
                    for n, r in results.items()
                    if "recall" in r
                }
            )
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
