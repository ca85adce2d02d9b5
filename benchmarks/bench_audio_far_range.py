"""Sirens beyond 50 m: distance, far/near call and uncertainty out to 300 m (issue 25, item 2).

    .venv/bin/python benchmarks/bench_audio_far_range.py [--data DIR ... | --n 25
        --seeds 2026,2027,2030,2031 --levels 110,135 --split test] [--far-ranger PATH]
        [--keep DIR] [--json FILE]

Without ``--data`` it simulates the held-out far scenes: ``--n`` 8 s recordings per seed of
test-split sirens, tones and street noise (``makeway audio simulate --split test --far-start
--siren-level 110,135``: EVs out to ~300 m, emitted levels 110–135 dB at 1 m, the real range).
``--split train --seeds 77,78`` makes the validation scenes the thresholds are chosen on.

Every recording is run as ``makeway audio listen --far-ranger`` runs it: the shipped siren networks
(detector, localizer, default rangers) on every 0.5 s window, the listener's decision (logit mean of
8 windows at the stored threshold), and the far ranger fed each window in order. Windows are
labelled with the nearest siren out to 400 m and scored when it lies at 10–300 m, in the bands
10–50, 50–100, 100–150 and 150–300 m. Printed side by side, on the very same windows:

* ``networks``: the shipped stack's distance (the anchor: trained within 100 m);
* ``level-only``: the level-only oracle of ``bench_audio_range_levels.py`` — the true distance
  scaled by ``10^((122.5 − L)/20)`` for the siren's true emitted level ``L``: a perfect loudness
  ranger that assumes the middle of the real range (no propagation error at all);
* ``far ranger``: the listener's distance with the far ranger (its own where its far probability
  reaches :data:`~makeway.perceive.audio.far_range.FAR_DISTANCE_PROBABILITY`, the networks'
  below).

For each: the median relative distance error ``|d̂ − d| / d`` per band (target ≤ 25 % to 150 m),
and the far/near call — far when ``d̂ > 100 m`` (the far ranger: far probability ≥
:data:`~makeway.perceive.audio.far_range.FAR_CALL_PROBABILITY`) against ``d > 100 m`` — right in
what share of the windows at 10–300 m (target ≥ 95 %), over all windows and over the windows the
listener reports as a siren, and per 20–100 m band of true distance (where the mistakes lie).
For the far ranger's own distance: the share of windows whose ln-distance error lies within ±1σ /
±2σ (calibrated: 68 % / 95 %). Then, for choosing on
validation scenes: far/near accuracy per far-call threshold, and the median relative error per band
for each switch threshold. Last, the far ranger's cost per window (features + network, one thread)
beside the whole stack's. The last line is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from makeway.jsonable import to_jsonable
from makeway.perceive.audio.far_range import (
    DEFAULT_FAR_RANGER,
    FAR_BOUNDARY_M,
    FAR_CALL_PROBABILITY,
    FAR_DISTANCE_PROBABILITY,
    FarRanger,
    combined_distance,
)
from makeway.perceive.audio.features import band_level_db
from makeway.perceive.audio.siren_model import SirenModel
from makeway.perceive.audio.windows import LISTEN_SMOOTH, SMOOTH_AVERAGE, smoothed_probability
from makeway.progress import progress_bar
from makeway.sense.recording import read_recording
from makeway.sim.audio_scenarios import held_out_folders
from makeway.train.far_range import far_rows

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_audio_range_levels import siren_table

BANDS_M = ((10.0, 50.0), (50.0, 100.0), (100.0, 150.0), (150.0, 300.0))
CALL_BANDS_M = (
    (10.0, 30.0),
    (30.0, 50.0),
    (50.0, 70.0),
    (70.0, 90.0),
    (90.0, 110.0),
    (110.0, 130.0),
    (130.0, 150.0),
    (150.0, 200.0),
    (200.0, 300.0),
)
"""Bands of true distance the far/near call is broken down by (where its mistakes lie)."""
TARGET_RELATIVE = 0.25
"""Median relative error to reach at 50–150 m."""
TARGET_FAR_NEAR = 0.95
ORACLE_LEVEL_DB = 122.5
CALL_GRID = (0.3, 0.4, 0.5, 0.6, 0.7, 0.8)
SWITCH_GRID = (0.0, 0.3, 0.5, 0.7, 1.01)


def collect(folders: list[Path], model: SirenModel, far: FarRanger) -> dict[str, np.ndarray]:
    """Per-window arrays of every recording (module docstring), with the far ranger's outputs."""
    parts = []
    with progress_bar("recordings", len(folders), unit="rec") as advance:
        for i, folder in enumerate(folders):
            rec = read_recording(folder)
            a = far_rows(rec, model)
            a["far_distance"], a["far_sigma"], a["far_probability"] = far.run_rows(a["rows"])
            a["is_siren"] = smoothed_probability(a["prob"], LISTEN_SMOOTH, SMOOTH_AVERAGE) >= model.threshold
            table = siren_table(rec) if rec.sources else []
            a["emitted_db"] = np.array(
                [float(table[k]["level_db_1m"]) if k >= 0 else np.nan for k in a["source"]]
            )
            a["recording"] = np.full(len(a["rows"]), i)
            del a["rows"]
            parts.append(a)
            advance(1)
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def relative_errors(a: dict[str, np.ndarray], estimate: np.ndarray, sel: np.ndarray) -> dict[str, Any]:
    d = a["true_distance"]
    out: dict[str, Any] = {}
    for lo, hi in BANDS_M:
        m = sel & (d >= lo) & (d < hi)
        rel = np.abs(estimate[m] - d[m]) / d[m]
        out[f"{lo:g}-{hi:g}"] = {"n": int(m.sum()), "median": float(np.median(rel)) if m.any() else None}
    return out


def far_near(a: dict[str, np.ndarray], far_call: np.ndarray, sel: np.ndarray) -> dict[str, Any]:
    truth = a["true_distance"] > FAR_BOUNDARY_M
    heard = sel & a["is_siren"]
    return {
        "n": int(sel.sum()),
        "accuracy": float((far_call[sel] == truth[sel]).mean()) if sel.any() else None,
        "n_heard": int(heard.sum()),
        "accuracy_heard": float((far_call[heard] == truth[heard]).mean()) if heard.any() else None,
        "far_called_near": float((~far_call[sel & truth]).mean()) if (sel & truth).any() else None,
        "near_called_far": float(far_call[sel & ~truth].mean()) if (sel & ~truth).any() else None,
    }


def far_near_by_distance(a: dict[str, np.ndarray], far_call: np.ndarray, sel: np.ndarray) -> dict[str, Any]:
    """Share of windows whose far/near call is right, per band of true distance (:data:`CALL_BANDS_M`)."""
    d = a["true_distance"]
    out: dict[str, Any] = {}
    for lo, hi in CALL_BANDS_M:
        m = sel & (d >= lo) & (d < hi)
        right = far_call[m] == (d[m] > FAR_BOUNDARY_M)
        out[f"{lo:g}-{hi:g}"] = {"n": int(m.sum()), "right": float(right.mean()) if m.any() else None}
    return out


def coverage(a: dict[str, np.ndarray], sel: np.ndarray) -> dict[str, Any]:
    z = np.abs(np.log(a["far_distance"][sel]) - np.log(a["true_distance"][sel])) / a["far_sigma"][sel]
    out: dict[str, Any] = {"all": _cov(z)}
    for lo, hi in BANDS_M:
        m = (a["true_distance"][sel] >= lo) & (a["true_distance"][sel] < hi)
        out[f"{lo:g}-{hi:g}"] = _cov(z[m])
    return out


def _cov(z: np.ndarray) -> dict[str, Any]:
    if not len(z):
        return {"n": 0, "within_1sigma": None, "within_2sigma": None}
    return {
        "n": len(z),
        "within_1sigma": float((z <= 1.0).mean()),
        "within_2sigma": float((z <= 2.0).mean()),
    }


def latency(folder: Path, model: SirenModel, far: FarRanger, n: int = 60) -> dict[str, float]:
    """ms per window: the far ranger alone (features + network) and the shipped stack alone."""
    from makeway.eval.siren_labels import label_recording
    from makeway.perceive.audio.features import window_batch

    rec = read_recording(folder)
    windows = window_batch(rec, label_recording(rec))[:n]
    sr = rec.sample_rate
    fs = rec.full_scale_db_spl or 135.0
    t0 = time.perf_counter()
    preds = [model.predict(w, fs) for w in windows]
    t1 = time.perf_counter()
    far.reset()
    for i, w in enumerate(windows):
        p = preds[i]
        far.update(
            w,
            sr,
            0.17 * i,
            level_db_spl=band_level_db(w, sr) + fs,
            distance_m=float(p.distance[0]),
            bearing_rad=float(p.theta[0]),
            siren_probability=float(p.prob[0]),
        )
    t2 = time.perf_counter()
    return {
        "stack_ms": 1000 * (t1 - t0) / len(windows),
        "far_ranger_ms": 1000 * (t2 - t1) / len(windows),
        "windows": len(windows),
    }


def pct(v: float | None) -> str:
    return "   —" if v is None else f"{100 * v:4.0f}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", action="append", type=Path, help="recordings (instead of simulating)")
    ap.add_argument("--n", type=int, default=25, help="recordings per seed when simulating")
    ap.add_argument("--seeds", default="2026,2027,2030,2031", help="scene seeds when simulating")
    ap.add_argument("--split", default="test", choices=("test", "train"), help="ingredients when simulating")
    ap.add_argument("--levels", default="110,135", help="emitted siren levels LOW,HIGH (dB SPL at 1 m)")
    ap.add_argument("--far-ranger", type=Path, default=DEFAULT_FAR_RANGER, help="far ranger ONNX file")
    ap.add_argument("--keep", type=Path, help="keep the simulated scenes in this folder")
    ap.add_argument("--threads", type=int, default=1, help="ONNX Runtime threads")
    ap.add_argument("--json", type=Path, help="also write the result here")
    args = ap.parse_args()
    lo, hi = (float(v) for v in args.levels.split(","))
    seeds = [int(s) for s in args.seeds.split(",") if s]
    model = SirenModel(threads=args.threads)
    far = FarRanger(args.far_ranger, threads=args.threads)
    print(f"siren stack: {model!r}; {far!r}")
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        out_dir = args.keep if args.keep is not None else Path(tmp)
        folders = held_out_folders(
            args.data, out_dir, args.n, seeds, 8.0, args.split, siren_level_db=(lo, hi), far_start=True
        )
        a = collect(folders, model, far)
        lat = latency(next(f for f in folders if read_recording(f).sources), model, far)
    d = a["true_distance"]
    sel = np.isfinite(d) & (d >= BANDS_M[0][0]) & (d < BANDS_M[-1][1])
    oracle = d * 10 ** ((ORACLE_LEVEL_DB - a["emitted_db"]) / 20.0)
    listened = combined_distance(a["distance"], a["far_distance"], a["far_probability"])
    estimators = {"networks": a["distance"], "level-only": oracle, "far ranger": listened}
    calls = {
        "networks": a["distance"] > FAR_BOUNDARY_M,
        "level-only": oracle > FAR_BOUNDARY_M,
        "far ranger": a["far_probability"] >= FAR_CALL_PROBABILITY,
    }
    result: dict[str, Any] = {
        "recordings": len(folders),
        "windows": int(sel.sum()),
        "levels_db": [lo, hi],
        "seeds": seeds if not args.data else None,
        "split": args.split if not args.data else None,
        "far_call_probability": FAR_CALL_PROBABILITY,
        "far_distance_probability": FAR_DISTANCE_PROBABILITY,
        "relative_error": {k: relative_errors(a, v, sel) for k, v in estimators.items()},
        "far_near": {k: far_near(a, v, sel) for k, v in calls.items()},
        "far_near_by_distance": {k: far_near_by_distance(a, v, sel) for k, v in calls.items()},
        "far_ranger_sigma": coverage(a, sel),
        "far_ranger_alone_relative_error": relative_errors(a, a["far_distance"], sel),
        "call_sweep": {f"{t:g}": far_near(a, a["far_probability"] >= t, sel) for t in CALL_GRID},
        "switch_sweep": {
            f"{t:g}": relative_errors(
                a, combined_distance(a["distance"], a["far_distance"], a["far_probability"], t), sel
            )
            for t in SWITCH_GRID
        },
        "latency": lat,
        "load_average": os.getloadavg(),
        "seconds": round(time.perf_counter() - t_start, 1),
    }
    bands = [f"{lo:g}-{hi:g}" for lo, hi in BANDS_M]
    print(
        f"\n{len(folders)} recordings, {int(sel.sum())} windows with the nearest siren at 10–300 m "
        f"(emitted {lo:g}–{hi:g} dB at 1 m)"
    )
    print("median relative distance error (%), per band of true distance:")
    print(f"{'':14s}" + "".join(f"{b + ' m':>12s}" for b in bands))
    n_row = result["relative_error"]["networks"]
    print(f"{'windows':14s}" + "".join(f"{n_row[b]['n']:>12d}" for b in bands))
    for name in estimators:
        r = result["relative_error"][name]
        print(f"{name:14s}" + "".join(f"{pct(r[b]['median']):>12s}" for b in bands))
    print(f"{'target':14s}{'':>12s}{'≤ 25':>12s}{'≤ 25':>12s}{'':>12s}")
    print(
        f"\nfar/near call (far = beyond {FAR_BOUNDARY_M:g} m), right in % of windows at 10–300 m "
        f"(target ≥ {100 * TARGET_FAR_NEAR:g} %):"
    )
    for name in calls:
        f = result["far_near"][name]
        print(
            f"{name:14s} all {pct(f['accuracy'])} %   heard by the listener {pct(f['accuracy_heard'])} % "
            f"({f['n_heard']} windows)   far called near {pct(f['far_called_near'])} %, "
            f"near called far {pct(f['near_called_far'])} %"
        )
    call_bands = [f"{lo:g}-{hi:g}" for lo, hi in CALL_BANDS_M]
    print("far/near right (%) per band of true distance (m):")
    print(f"{'':14s}" + "".join(f"{b:>9s}" for b in call_bands))
    by = result["far_near_by_distance"]
    print(f"{'windows':14s}" + "".join(f"{by['far ranger'][b]['n']:>9d}" for b in call_bands))
    for name in calls:
        print(f"{name:14s}" + "".join(f"{pct(by[name][b]['right']):>9s}" for b in call_bands))
    cov = result["far_ranger_sigma"]
    print(
        "\nfar ranger σ: ln-distance error within ±1σ / ±2σ (calibrated: 68 / 95 %): all "
        f"{pct(cov['all']['within_1sigma'])} / {pct(cov['all']['within_2sigma'])} %; "
        + "; ".join(f"{b} m {pct(cov[b]['within_1sigma'])} / {pct(cov[b]['within_2sigma'])}" for b in bands)
    )
    alone = result["far_ranger_alone_relative_error"]
    print(
        "far ranger's own distance everywhere: "
        + ", ".join(f"{b} m {pct(alone[b]['median'])} %" for b in bands)
    )
    print("\nfor choosing on validation scenes only:")
    print(
        "  far-call threshold → far/near right (all / heard): "
        + ", ".join(
            f"{t} {pct(v['accuracy'])}/{pct(v['accuracy_heard'])}" for t, v in result["call_sweep"].items()
        )
    )
    for t, v in result["switch_sweep"].items():
        print(
            f"  distance switch at far probability ≥ {t}: "
            + ", ".join(f"{b} {pct(v[b]['median'])}" for b in bands)
        )
    print(
        f"\ncost per window, one thread: shipped stack {lat['stack_ms']:.1f} ms, far ranger "
        f"{lat['far_ranger_ms']:.2f} ms (load average {os.getloadavg()[0]:.1f})"
    )
    if args.json is not None:
        args.json.write_text(json.dumps(to_jsonable(result), indent=1))
    print(json.dumps(to_jsonable(result)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
