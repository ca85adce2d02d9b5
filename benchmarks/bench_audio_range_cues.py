"""Level-independent siren range cues, each measured alone, by emitted level (issue 25, item 1).

    .venv/bin/python benchmarks/bench_audio_range_cues.py [--data DIR ...] [--fit DIR ...]
        [--val DIR ...] [--segment 1.0] [--json FILE]
    (without --data/--fit/--val it simulates the three sets: held-out seeds 2026,2027,2030,2031 of
    test-split ingredients, training-split seeds 101,102 to fit and 77,78 to check; --n per seed)

Scenes: 8 s recordings of the array with the emitted siren level drawn over 110–135 dB at 1 m
(``bench_audio_range_levels.py --keep DIR`` writes the same held-out scenes). Each recording is cut
into ``--segment`` stretches every 0.5 s; a stretch counts when its nearest siren lies at 10–50 m at
its centre. On each stretch:

* **ground reflection** (:func:`makeway.perceive.audio.range_cues.reflection_delay`): the delay
  of the road-reflected path, read from the comb it leaves on the siren's harmonics, turned into a
  distance with the array height from ``array.yaml`` and the siren height unknown (prior 1.0–2.0 m,
  its middle for the point estimate). Reported: how often a delay is found, how often the best delay
  lies within 10 % of the true one, how often the true one is among the candidates at all, how
  often the comb is strong (score ≥ 0.5) and right, and the distance error of the found ones;
  beside it the same with the siren's true height (what the height prior costs);
* **air-absorption tilt** (:func:`~makeway.perceive.audio.range_cues.spectral_tilt`): the raw
  slope distance, offset by its median bias on the training-split stretches; its spread across
  sirens is the siren's own spectrum (reported per kind at 10–20 m, where absorption is nil);
* **the shipped networks**: the median of their distances over the 0.5 s windows inside the stretch;
* **level + reflection** (item 4): the reflection delay candidate whose distance is closest to the
  networks' (a steady-pitch siren leaves several delays that fit), taken when its comb score and
  its agreement with the networks pass thresholds fitted on the training-split stretches, blended
  with the networks' distance in log by a weight fitted there too; the networks' distance otherwise.
  Judged on the held-out stretches only; the validation stretches check the fit;
* **track-scaled** (item 4, no fitting): the networks' distance times one factor per siren track,
  the running median (causal) of the reflection's distance over the networks' along the track so
  far — the networks' error is mostly one factor per siren (its unknown emitted level).

Prints, per 5 dB band of the nearest siren's emitted level (and for synthesized and real sirens
apart), n, the delay's shares and the distance errors (median / mean, m) of each, beside the
issue's target (≤ 6 m / ≤ 8 m at 10–50 m in every band). About 7 minutes on 2 busy cores for
50 + 50 + 100 recordings.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from makeway.errors import InputError
from makeway.eval.siren_labels import label_recording, relative_position
from makeway.jsonable import to_jsonable
from makeway.perceive.audio.features import window_batch
from makeway.perceive.audio.range_cues import (
    SIREN_ABOVE_FLOOR_DB,
    SIREN_HEIGHT_PRIOR_M,
    check_array_audio,
    distance_from_delay,
    reflection_delay,
    reflection_tau,
    spectral_tilt,
)
from makeway.perceive.audio.siren_model import SirenModel
from makeway.progress import progress_bar
from makeway.sense.recording import read_recording, recording_folders
from makeway.sim.acoustics import air_absorption_db_per_m
from makeway.sim.audio_scenarios import held_out_folders

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_audio_range_levels import BANDS_DB, TARGET, siren_kind, siren_table

RANGE_M = (10.0, 50.0)
HOP_S = 0.5
HELD_OUT_SEEDS = (2026, 2027, 2030, 2031)
FIT_SEEDS = (101, 102)
VAL_SEEDS = (77, 78)
LEVELS_DB = (110.0, 135.0)
STRONG_SCORE = 0.5
"""A comb this clear (normalized correlation) is reported apart: how often, and how often right."""


def stretches(
    folder: Path, model: SirenModel, segment_s: float, above_floor_db: float = SIREN_ABOVE_FLOOR_DB
) -> list[dict[str, Any]]:
    """Every stretch of one recording whose nearest siren lies at 10–50 m, with the cues read."""
    rec = read_recording(folder)
    if not rec.sources:
        return []
    h_array = check_array_audio(rec)
    table = siren_table(rec)
    sr = rec.sample_rate
    labels = label_recording(rec)
    windows = window_batch(rec, labels)
    fs = rec.full_scale_db_spl
    net = np.concatenate(
        [model.predict(windows[i : i + 64], fs).distance for i in range(0, len(windows), 64)]
    )
    w_start = labels.start / sr
    w_end = w_start + labels.window / sr
    out: list[dict[str, Any]] = []
    for t0 in np.arange(0.0, rec.duration_s - segment_s + 1e-9, HOP_S):
        tc = np.array([t0 + 0.5 * segment_s])
        dists = [float(np.hypot(*relative_position(rec.ego, s, tc))[0]) for s in rec.sources]
        k = int(np.argmin(dists))
        d = dists[k]
        if not RANGE_M[0] <= d <= RANGE_M[1]:
            continue
        seg = rec.audio[round(t0 * sr) : round((t0 + segment_s) * sr)]
        refl = reflection_delay(seg, sr, above_floor_db=above_floor_db)
        inside = (w_start >= t0 - 1e-9) & (w_end <= t0 + segment_s + 1e-9)
        hs = float(table[k]["height_m"])
        out.append(
            {
                "siren": f"{folder}#{k}",
                "t0": float(t0),
                "d": d,
                "level": float(table[k]["level_db_1m"]),
                "kind": siren_kind(table[k]),
                "h_source": hs,
                "h_array": h_array,
                "tau_true": float(reflection_tau(d, hs, h_array)),
                "tau": refl.tau_s,
                "score": refl.score,
                "found": refl.found,
                "candidates": list(refl.candidates),
                "tilt_raw": spectral_tilt(seg, sr, air_absorption_db_per_m).distance_m,
                "d_net": float(np.median(net[inside])) if inside.any() else math.nan,
            }
        )
    return out


def collect(
    folders: list[Path], model: SirenModel, segment_s: float, what: str, above_floor_db: float
) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    with progress_bar(what, len(folders), unit="rec") as advance:
        for f in folders:
            rows += stretches(f, model, segment_s, above_floor_db)
            advance(1)
    return rows


def reflection_distance_of(rows: list[dict[str, Any]], height: str = "prior") -> np.ndarray:
    """The reflection cue's distance per stretch (NaN where no delay was found): with the siren
    height's prior middle, or (``height="true"``) the true height."""
    mid = 0.5 * sum(SIREN_HEIGHT_PRIOR_M)
    return np.array(
        [
            float(distance_from_delay(r["tau"], r["h_source"] if height == "true" else mid, r["h_array"]))
            if r["found"]
            else math.nan
            for r in rows
        ]
    )


def combine(rows: list[dict[str, Any]], params: dict[str, float]) -> np.ndarray:
    """Level + reflection (module docstring): per stretch, the candidate delay whose distance (at
    the prior's middle height) is nearest the networks' in log; used when its score ≥
    ``min_score`` and ``|log(d_refl / d_net)| ≤ max_log``, blended as
    ``exp((1 − w)·log d_net + w·log d_refl)``; the networks' distance otherwise."""
    mid = 0.5 * sum(SIREN_HEIGHT_PRIOR_M)
    out = np.empty(len(rows))
    for i, r in enumerate(rows):
        dn = r["d_net"]
        best, gap = math.nan, math.inf
        for tau, score in r["candidates"]:
            if score < params["min_score"]:
                continue
            dr = float(distance_from_delay(tau, mid, r["h_array"]))
            if math.isfinite(dr) and dr > 0 and abs(math.log(dr / dn)) < gap:
                best, gap = dr, abs(math.log(dr / dn))
        if math.isfinite(best) and gap <= params["max_log"]:
            w = params["weight"]
            out[i] = math.exp((1 - w) * math.log(dn) + w * math.log(best))
        else:
            out[i] = dn
    return out


def track_scaled(rows: list[dict[str, Any]]) -> np.ndarray:
    """The networks' distance rescaled per siren track by the reflection: for each stretch, the
    median over this siren's stretches so far (causal, this one included) of
    ``log(d_reflection / d_networks)`` scales ``d_networks``. The networks' error is mostly one
    factor per siren (its unknown emitted level), which the reflection, level-blind but noisy,
    can estimate over a track; the distance stays the networks' in shape."""
    mid = 0.5 * sum(SIREN_HEIGHT_PRIOR_M)
    logs: dict[str, list[float]] = {}
    out = np.empty(len(rows))
    order = sorted(range(len(rows)), key=lambda i: (rows[i]["siren"], rows[i]["t0"]))
    for i in order:
        r = rows[i]
        seen = logs.setdefault(r["siren"], [])
        dr = float(distance_from_delay(r["tau"], mid, r["h_array"])) if r["found"] else math.nan
        if math.isfinite(dr) and dr > 0 and math.isfinite(r["d_net"]) and r["d_net"] > 0:
            seen.append(math.log(dr / r["d_net"]))
        out[i] = r["d_net"] * math.exp(float(np.median(seen))) if seen else r["d_net"]
    return out


def fit_combination(rows: list[dict[str, Any]]) -> dict[str, float]:
    """Grid search of :func:`combine`'s parameters for the lowest median + mean error on ``rows``."""
    d = np.array([r["d"] for r in rows])
    best: tuple[float, dict[str, float]] = (math.inf, {})
    grid = ((0.2, 0.3, 0.4, 0.5, 0.6), (0.15, 0.3, 0.5, 0.7, 1.0, 1.5), (0.25, 0.5, 0.75, 1.0))
    for s, g, w in itertools.product(*grid):
        p = {"min_score": s, "max_log": g, "weight": w}
        err = np.abs(combine(rows, p) - d)
        cost = float(np.median(err) + np.mean(err))
        if cost < best[0]:
            best = (cost, p)
    return best[1]


def _stats(err: np.ndarray) -> dict[str, float | None]:
    err = err[np.isfinite(err)]
    if not len(err):
        return {"median_m": None, "mean_m": None}
    return {"median_m": round(float(np.median(err)), 2), "mean_m": round(float(np.mean(err)), 2)}


def breakdown(rows: list[dict[str, Any]], tilt_offset: float, params: dict[str, float]) -> dict[str, Any]:
    """Every cue's figures over ``rows`` (module docstring)."""
    d = np.array([r["d"] for r in rows])
    tau_ok = np.array([r["found"] and abs(r["tau"] / r["tau_true"] - 1) < 0.1 for r in rows], dtype=bool)
    found = np.array([r["found"] for r in rows], dtype=bool)
    in_cands = np.array(
        [any(abs(c[0] / r["tau_true"] - 1) < 0.1 for c in r["candidates"]) for r in rows], dtype=bool
    )
    strong = np.array([r["score"] >= STRONG_SCORE for r in rows], dtype=bool)
    return {
        "n": len(rows),
        "strong_comb": round(float(strong.mean()), 3) if len(rows) else None,
        "strong_tau_within_10pc": round(float(tau_ok[strong].mean()), 3) if strong.any() else None,
        "reflection_found": round(float(found.mean()), 3) if len(rows) else None,
        "reflection_tau_within_10pc": round(float(tau_ok.mean()), 3) if len(rows) else None,
        "true_tau_among_candidates": round(float(in_cands.mean()), 3) if len(rows) else None,
        "reflection": _stats(np.abs(reflection_distance_of(rows) - d)),
        "reflection_true_height": _stats(np.abs(reflection_distance_of(rows, "true") - d)),
        "tilt": _stats(np.abs(np.array([r["tilt_raw"] for r in rows]) - tilt_offset - d)),
        "networks": _stats(np.abs(np.array([r["d_net"] for r in rows]) - d)),
        "level_and_reflection": _stats(np.abs(combine(rows, params) - d)) if rows else _stats(np.zeros(0)),
        "track_scaled": _stats(np.abs(track_scaled(rows) - d)) if rows else _stats(np.zeros(0)),
    }


def by_band(rows: list[dict[str, Any]], tilt_offset: float, params: dict[str, float]) -> dict[str, Any]:
    """:func:`breakdown` over all ``rows``, per emitted-level band, and for synthesized and real sirens."""
    out = {"all": breakdown(rows, tilt_offset, params)}
    out["synthesized"] = breakdown([r for r in rows if r["kind"].startswith("synth")], tilt_offset, params)
    out["real"] = breakdown([r for r in rows if not r["kind"].startswith("synth")], tilt_offset, params)
    for lo, hi in BANDS_DB:
        sel = [
            r
            for r in rows
            if lo <= r["level"] and (r["level"] < hi or (hi == BANDS_DB[-1][1] and r["level"] <= hi))
        ]
        out[f"{lo:g}-{hi:g}"] = breakdown(sel, tilt_offset, params)
    return out


def tilt_by_kind(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The raw tilt distance of stretches at 10–20 m per siren kind: absorption barely differs
    there, so its spread is the sirens' own spectra (metres of apparent distance)."""
    near = [r for r in rows if r["d"] <= 20.0 and math.isfinite(r["tilt_raw"])]
    out: dict[str, Any] = {}
    for k in sorted({r["kind"] for r in near}):
        v = np.array([r["tilt_raw"] for r in near if r["kind"] == k])
        out[k] = {"n": len(v), "median_m": round(float(np.median(v)), 1)}
    allv = np.array([r["tilt_raw"] for r in near])
    if len(allv):
        q = np.percentile(allv, [10, 50, 90])
        out["all"] = {
            "n": len(allv),
            "p10_m": round(float(q[0]), 1),
            "median_m": round(float(q[1]), 1),
            "p90_m": round(float(q[2]), 1),
        }
    return out


def print_rows(title: str, rows: dict[str, dict[str, Any]]) -> None:
    def fmt(s: dict[str, float | None]) -> str:
        return f"{'–':>13s}" if s["median_m"] is None else f"{s['median_m']:>6.1f}/{s['mean_m']:<5.1f}m"

    cols = (
        "reflection",
        "reflection_true_height",
        "tilt",
        "networks",
        "level_and_reflection",
        "track_scaled",
    )
    names = ("reflection", "refl.true h", "tilt", "networks", "level+refl.", "track-scaled")
    print(f"\n{title}")

    def pc(v: float | None) -> str:
        return "–" if v is None else f"{100 * v:.0f}%"

    head = f"{'level, dB':12s}{'n':>5s}{'found':>7s}{'τ±10%':>7s}{'in cand.':>9s}{'strong':>8s}{'τ±10%':>7s}"
    print(head + "".join(f"{c:>14s}" for c in names))
    for name, r in rows.items():
        print(
            f"{name:12s}{r['n']:>5d}{pc(r['reflection_found']):>7s}{pc(r['reflection_tau_within_10pc']):>7s}"
            f"{pc(r['true_tau_among_candidates']):>9s}"
            f"{pc(r['strong_comb']):>8s}{pc(r['strong_tau_within_10pc']):>7s}"
            + "".join(" " + fmt(r[c]) for c in cols)
        )


def simulated(out: Path, n: int, seeds: tuple[int, ...], split: str) -> list[Path]:
    return held_out_folders(None, out, n, seeds, 8.0, split, siren_level_db=LEVELS_DB)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, action="append", default=None, help="held-out recordings")
    ap.add_argument("--fit", type=Path, action="append", default=None, help="training-split recordings")
    ap.add_argument("--val", type=Path, action="append", default=None, help="validation recordings")
    ap.add_argument("--n", type=int, default=25, help="recordings per seed to simulate")
    ap.add_argument("--segment", type=float, default=1.0, help="stretch length, s")
    ap.add_argument(
        "--above-floor",
        type=float,
        default=SIREN_ABOVE_FLOOR_DB,
        help="dB a harmonic peak must stand over the noise floor (choose on validation)",
    )
    ap.add_argument("--json", type=Path, default=None, help="also write the results to this JSON file")
    args = ap.parse_args()
    model = SirenModel(threads=2)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        try:

            def folders(
                given: list[Path] | None, seeds: tuple[int, ...], split: str, name: str
            ) -> list[Path]:
                if given:
                    return [f for d in given for f in recording_folders(d)]
                return simulated(Path(tmp) / name, args.n, seeds, split)

            fit = collect(
                folders(args.fit, FIT_SEEDS, "train", "fit"), model, args.segment, "fit", args.above_floor
            )
            val = collect(
                folders(args.val, VAL_SEEDS, "train", "val"),
                model,
                args.segment,
                "validation",
                args.above_floor,
            )
            test = collect(
                folders(args.data, HELD_OUT_SEEDS, "test", "test"),
                model,
                args.segment,
                "held-out",
                args.above_floor,
            )
        except InputError as exc:
            raise SystemExit(str(exc)) from None
    if not (fit and val and test):
        raise SystemExit("a set has no stretch with a siren at 10–50 m")
    tilt = np.array([r["tilt_raw"] - r["d"] for r in fit])
    tilt_offset = float(np.nanmedian(tilt))
    params = fit_combination(fit)
    result = {
        "segment_s": args.segment,
        "tilt_offset_m": round(tilt_offset, 1),
        "combination": params,
        "validation": by_band(val, tilt_offset, params),
        "held_out": by_band(test, tilt_offset, params),
        "tilt_at_10_20_m_by_kind": tilt_by_kind(fit + val),
        "seconds": round(time.perf_counter() - t0, 1),
    }
    print(
        f"\nstretches of {args.segment:g} s with the nearest siren at 10–50 m: fit {len(fit)}, "
        f"validation {len(val)}, held-out {len(test)}; combination fitted on the training split: {params}; "
        f"tilt offset {tilt_offset:.0f} m"
    )
    print_rows("validation (training-split ingredients; distance error median/mean)", result["validation"])
    print_rows("held-out (test-split ingredients; distance error median/mean)", result["held_out"])
    print(f"target: ≤ {TARGET['distance_median_m']:g} m / ≤ {TARGET['distance_mean_m']:g} m in every band")
    print("\nraw tilt distance at 10–20 m by siren kind (the siren's own spectrum, m):")
    for k, v in result["tilt_at_10_20_m_by_kind"].items():
        print(f"  {k:16s} {v}")
    print(f"\n{result['seconds']:.0f} s, load average {os.getloadavg()}")
    text = json.dumps(to_jsonable(result), ensure_ascii=False)
    if args.json is not None:
        args.json.write_text(text, encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
