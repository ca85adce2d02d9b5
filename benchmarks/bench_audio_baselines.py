"""Classical siren baselines (issue 4) on a small held-out simulated set, next to seed 002.

    .venv/bin/python benchmarks/bench_audio_baselines.py [--n 8] [--duration 8] [--train 6] [--keep DIR]

1. Simulates ``--train`` recordings (seed 1000) to fit the band-energy detector's two logistic
   constants, and ``--n`` held-out recordings (seed 2026) of ``--duration`` s, all scenarios, 25 %
   without siren, into a temporary folder (real siren/noise ingredients when ../shared/data exists).
2. Runs gccphat, srp and normmusic (each with the fitted detector) on every labelled window and prints
   recall / false alarms / angle errors overall and in 10–50 m, beside seed 002 (recall 99.16 %,
   angle median 9.64°, mean 19.18°, distance median 9.30 m) and the issue's targets.
3. Prints each method's latency per 0.5 s, 8-channel, 48 kHz window on this machine (detector +
   bearing; the future model's target is ≤ 25 ms), and the JSON of every run last.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from makeway.eval.siren import evaluate
from makeway.eval.siren_labels import label_recording
from makeway.perceive.audio.doa import DOA_METHODS, SirenEnergyDetector
from makeway.perceive.audio.features import window_batch
from makeway.sense.recording import read_recording
from makeway.sim.audio_scenarios import generate_recordings

SEED_002 = {"recall": 0.9916, "angle_median_deg": 9.64, "angle_mean_deg": 19.18, "distance_median_m": 9.30}
TARGET = {"recall": 0.995, "angle_median_deg": 5.0, "angle_mean_deg": 10.0, "distance_median_m": 6.0}


def _fmt(v: float | None, pct: bool = False) -> str:
    if v is None:
        return "—"
    return f"{100 * v:.2f} %" if pct else f"{v:.2f}"


def fit_detector(paths: list[Path]) -> SirenEnergyDetector:
    det = SirenEnergyDetector()
    scores, ys = [], []
    for p in paths:
        rec = read_recording(p)
        lab = label_recording(rec)
        scores.append(det.scores(window_batch(rec, lab)[lab.kept]))
        ys.append(lab.siren[lab.kept])
    return det.fit_scores(np.concatenate(scores), np.concatenate(ys))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=8, help="held-out recordings")
    ap.add_argument("--train", type=int, default=6, help="recordings to fit the detector on")
    ap.add_argument("--duration", type=float, default=8.0, help="seconds per recording")
    ap.add_argument("--keep", type=Path, default=None, help="simulate into this folder and keep it")
    args = ap.parse_args()

    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep if args.keep is not None else Path(tmp)
        t0 = time.perf_counter()
        train = generate_recordings(root / "train", args.train, duration_s=args.duration, seed=1000)
        test = generate_recordings(root / "test", args.n, duration_s=args.duration, seed=2026)
        t_sim = time.perf_counter() - t0
        print(f"simulated {args.train} + {args.n} recordings of {args.duration:g} s in {t_sim:.1f} s")
        det = fit_detector(train)
        print(f"detector fitted on the training set: {det!r}")
        results = {}
        for name in DOA_METHODS:
            results[name] = evaluate(test, name, detector=det)

    first = next(iter(results.values()))
    print(
        f"\nheld-out: {args.n} recordings, {first['windows']} windows "
        f"({first['positives']} with a siren ≤ 100 m, "
        f"{first['range_10_50']['positives']} in 10–50 m, {first['negatives']} without)"
    )
    head = (
        f"{'':12s} {'recall':>9s} {'false al.':>9s} {'angle med':>9s} {'angle mean':>10s} {'dist med':>8s}"
        f"   | 10–50 m: {'recall':>9s} {'angle med':>9s} {'angle mean':>10s} {'dist med':>8s}"
        f" {'ms/window':>9s}"
    )
    print(head)
    for name, r in results.items():
        q = r["range_10_50"]
        print(
            f"{name:12s} {_fmt(r['recall'], True):>9s} {_fmt(r['false_alarm_rate'], True):>9s} "
            f"{_fmt(r['angle_median_deg']):>9s} {_fmt(r['angle_mean_deg']):>10s} "
            f"{_fmt(r['distance_median_m']):>8s}   | {'':9s}{_fmt(q['recall'], True):>9s} "
            f"{_fmt(q['angle_median_deg']):>9s} {_fmt(q['angle_mean_deg']):>10s} "
            f"{_fmt(q['distance_median_m']):>8s} {r['ms_per_window']:>9.1f}"
        )
    for label, ref in (("seed 002", SEED_002), ("target", TARGET)):
        print(
            f"{label:12s} {'':>9s} {'':>9s} {'':>9s} {'':>10s} {'':>8s}   | {'':9s}"
            f"{_fmt(ref['recall'], True):>9s} {_fmt(ref['angle_median_deg']):>9s} "
            f"{_fmt(ref['angle_mean_deg']):>10s} {_fmt(ref['distance_median_m']):>8s}"
            f"{'':>10s}" + (" ≤ 25" if label == "target" else " ~50")
        )
    print(
        "\nby distance (gccphat): "
        + ", ".join(
            f"{int(b['range_m'][0])}–{int(b['range_m'][1])} m n={b['n']} "
            f"angle med {_fmt(b['angle_median_deg'])}"
            for b in results["gccphat"]["by_distance"]
            if b["n"]
        )
    )
    print(f"\ntotal {time.perf_counter() - t_all:.1f} s")
    for r in results.values():
        print(json.dumps(r, separators=(",", ":")))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
