"""How far loudness alone can take siren ranging, beside the shipped networks (issue 4, SPEC §3).

    .venv/bin/python benchmarks/bench_audio_range_bound.py [--data DIR ...] [--n 30 --seeds 2026,2027]
        [--json FILE]

The simulator draws each siren's emitted level uniformly from ``SIREN_LEVEL_DB_1M`` (110–120 dB SPL
at 1 m, independent of the siren's kind, the scene and the noise). A ranger that reads only the
received level therefore cannot know whether a siren is loud and far or quiet and near. This script
scores, on the same windows as ``makeway audio eval`` (nearest siren at 10–50 m), two rangers:

* **the shipped networks** (detector + localizer + rangers, ``SirenModel()``): their distance;
* **a level-only oracle**: it knows the true received level exactly — spreading, air absorption,
  ground reflection, rear attenuation, noise all removed — but not the emitted level, so it reports
  ``d · 10^((L̂ − L)/20)`` for the true distance ``d``, true emitted level ``L`` (from the
  recording's ``meta.yaml``) and an assumed level ``L̂``. Rows: ``L̂`` = 115 dB (the centre of the
  range, the natural choice), and the ``L̂`` (0.5 dB steps) that happens to give the lowest median
  error on these very windows: a choice no real ranger could make. One 60-recording set holds few
  sirens, so its drawn levels are luck; the last row keeps every window's geometry, redraws each
  siren's level from the prior 200 times and gives the mean of the median (and mean) errors: what
  loudness alone leaves on such scenes, expected.

Prints the median and mean absolute distance error of each, beside the issue's target (≤ 6 m median)
and seed 002 (9.30 m / 10.58 m). Where the networks' median lies below the oracle's, they already draw
on cues beyond loudness (the Doppler and level trend of the pass-by, the ground reflection); the
oracle's figure is what loudness alone leaves. Needs recordings written by ``makeway audio simulate``
(which stores each siren's level); others are refused. Without ``--data`` it simulates the held-out
sets of the other audio benchmarks (``--n`` recordings per seed, test-split ingredients only).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from makeway.errors import InputError
from makeway.eval.siren_labels import label_recording
from makeway.perceive.audio.features import window_batch
from makeway.perceive.audio.siren_model import SirenModel
from makeway.progress import progress_bar
from makeway.sense.recording import Recording, read_recording
from makeway.sim.audio_scenarios import SIREN_LEVEL_DB_1M, held_out_folders

SEED_002 = {"distance_median_m": 9.30, "distance_mean_m": 10.58}
TARGET_MEDIAN_M = 6.0
RANGE_M = (10.0, 50.0)
REDRAWS = 200


def emitted_levels(rec: Recording) -> np.ndarray:
    """Each siren source's emitted level (dB SPL at 1 m) from the simulator's ``meta.yaml``."""
    sirens = rec.meta.get("sirens") if rec.meta else None
    if not isinstance(sirens, list) or len(sirens) != len(rec.sources):
        raise InputError(rec.path or "recording", "no simulator meta.yaml with one entry per siren source")
    try:
        return np.array([float(s["level_db_1m"]) for s in sirens])
    except (KeyError, TypeError, ValueError):
        raise InputError(rec.path or "recording", "meta.yaml sirens lack level_db_1m") from None


def windows_of(rec: Recording, model: SirenModel) -> dict[str, np.ndarray]:
    """True distance, emitted level of the nearest siren and the networks' distance, for the kept
    windows whose nearest siren lies in 10–50 m."""
    labels = label_recording(rec)
    dist = np.where(labels.present, labels.distance, np.inf)
    k = np.argmin(dist, axis=1) if labels.n_sources else np.zeros(len(labels), dtype=int)
    d = dist[np.arange(len(labels)), k] if labels.n_sources else np.full(len(labels), np.inf)
    sel = labels.kept & labels.siren & (d >= RANGE_M[0]) & (d <= RANGE_M[1])
    if not sel.any():
        return {
            "d": np.empty(0),
            "level": np.empty(0),
            "d_net": np.empty(0),
            "source": np.empty(0, dtype=int),
        }
    windows = window_batch(rec, labels)[sel]
    net = np.concatenate(
        [
            model.predict(windows[i : i + 64], rec.full_scale_db_spl).distance
            for i in range(0, len(windows), 64)
        ]
    )
    return {"d": d[sel], "level": emitted_levels(rec)[k[sel]], "d_net": net, "source": k[sel]}


def summary(err: np.ndarray) -> dict[str, float]:
    return {
        "distance_median_m": round(float(np.median(err)), 3),
        "distance_mean_m": round(float(np.mean(err)), 3),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--data", type=Path, action="append", default=None, help="simulated recordings (repeatable)"
    )
    ap.add_argument("--n", type=int, default=30, help="recordings per seed to simulate without --data")
    ap.add_argument("--seeds", default="2026,2027", help="seeds of the simulated held-out sets, pooled")
    ap.add_argument("--json", type=Path, default=None, help="also write the results to this JSON file")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        seeds = [int(v) for v in args.seeds.split(",") if v.strip()]
        t0 = time.perf_counter()
        try:
            folders = held_out_folders(args.data, tmp, args.n, seeds)
            if not args.data:
                print(f"simulated {len(folders)} held-out recordings in {time.perf_counter() - t0:.0f} s")
            return report(folders, args.json)
        except InputError as exc:  # no recordings there, or ones without the simulator's meta.yaml
            raise SystemExit(str(exc)) from None


def report(folders: list[Path], json_path: Path | None) -> int:
    """Score the networks and the level-only oracle on ``folders``; print the table and JSON."""
    model = SirenModel(threads=2)
    parts: list[dict[str, np.ndarray]] = []
    with progress_bar("recordings", len(folders), unit="rec") as advance:
        for folder in folders:
            parts.append(windows_of(read_recording(folder), model))
            advance(1)
    d = np.concatenate([p["d"] for p in parts])
    level = np.concatenate([p["level"] for p in parts])
    d_net = np.concatenate([p["d_net"] for p in parts])
    source = np.concatenate([100 * i + p["source"] for i, p in enumerate(parts)])  # one id per siren
    if not len(d):
        raise SystemExit("no window with a siren at 10–50 m")

    def oracle(assumed_db: float, true_db: np.ndarray = level) -> np.ndarray:
        return np.abs(d * 10 ** ((assumed_db - true_db) / 20.0) - d)

    # the same sirens and geometry, each siren's level redrawn from the simulator's prior
    rng = np.random.default_rng(0)
    ids, inverse = np.unique(source, return_inverse=True)
    redrawn = [
        oracle(0.5 * sum(SIREN_LEVEL_DB_1M), rng.uniform(*SIREN_LEVEL_DB_1M, size=len(ids))[inverse])
        for _ in range(REDRAWS)
    ]

    centre = 0.5 * sum(SIREN_LEVEL_DB_1M)
    grid = np.arange(SIREN_LEVEL_DB_1M[0], SIREN_LEVEL_DB_1M[1] + 0.25, 0.5)
    best = float(grid[np.argmin([np.median(oracle(g)) for g in grid])])
    rows: dict[str, dict[str, Any]] = {
        "shipped networks": summary(np.abs(d_net - d)),
        f"level-only oracle, L̂ = {centre:g} dB": summary(oracle(centre)),
        f"level-only oracle, best L̂ = {best:g} dB": summary(oracle(best)),
        f"same, levels redrawn ({REDRAWS}×), L̂ = {centre:g} dB": {
            "distance_median_m": round(float(np.mean([np.median(e) for e in redrawn])), 3),
            "distance_mean_m": round(float(np.mean([np.mean(e) for e in redrawn])), 3),
        },
        "seed 002 (their data)": SEED_002,
    }
    print(
        f"\n{len(folders)} recordings, {len(d)} windows with the nearest siren at 10–50 m "
        f"(emitted levels {level.min():.1f}–{level.max():.1f} dB SPL at 1 m)"
    )
    print(f"{'distance error, 10–50 m':40s}{'median':>10s}{'mean':>10s}{'median ÷ target':>18s}")
    for name, r in rows.items():
        med, mean = r["distance_median_m"], r["distance_mean_m"]
        print(f"{name:40s}{med:>9.2f}m{mean:>9.2f}m{med / TARGET_MEDIAN_M:>17.3f}×")
    print(f"{'target':40s}{'≤ 6.00m':>10s}")
    result = {"windows": int(len(d)), "recordings": len(folders), "rows": rows, "best_assumed_level_db": best}
    if json_path is not None:
        json_path.write_text(json.dumps(result, indent=2), encoding="utf-8")
    print(json.dumps(result, ensure_ascii=False))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
