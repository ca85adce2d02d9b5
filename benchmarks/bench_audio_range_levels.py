"""Siren recall and distance by emitted level and by siren kind (issue 25, item 3).

    .venv/bin/python benchmarks/bench_audio_range_levels.py [--data DIR ... | --n 20
        --seeds 2026,2027,2030,2031 --levels 110,135] [--keep DIR] [--json FILE]

Real sirens span about 110–135 dB SPL at 1 m; the shipped networks were trained on 110–120 dB.
Without ``--data`` this simulates held-out scenes (test-split sirens, tones and street noise only,
``--n`` 8 s recordings per seed, as ``makeway audio simulate --split test`` does) whose emitted siren
level is drawn uniformly from ``--levels`` (default 110–135 dB), and scores, on the windows of
``makeway audio eval``, the shipped behaviour of ``makeway audio listen``: the shipped detector,
localizer and rangers, the decision on the mean logit of the last 8 windows at the detector's stored
threshold. It prints, per 5 dB band of the nearest siren's emitted level and per siren kind:

* ``n``: windows with the nearest siren at 10–50 m (and the sirens they come from);
* recall at 10–50 m (false alarms have no emitted level: one overall figure over the negatives);
* the networks' distance error at 10–50 m, median and mean, beside the issue's target
  (≤ 6 m / ≤ 8 m in every band);
* the level-only oracle of ``bench_audio_range_bound.py`` — the true received level, every
  propagation effect removed, read against an assumed emitted level: ``d·10^((L̂ − L)/20)`` — for
  ``L̂`` = 115 dB (the networks' prior) and 122.5 dB (the middle of the real range): what loudness
  alone can give in each band.

``--keep DIR`` keeps the simulated scenes, so ``bench_audio_range_cues.py --data DIR`` measures the
level-independent cues on the very same scenes.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from makeway.errors import InputError
from makeway.eval.siren import evaluate, model_estimator
from makeway.eval.siren_labels import label_recording
from makeway.jsonable import to_jsonable
from makeway.perceive.audio.siren_model import SirenModel
from makeway.perceive.audio.windows import LISTEN_SMOOTH
from makeway.progress import progress_bar
from makeway.sense.recording import Recording, read_recording
from makeway.sim.audio_scenarios import held_out_folders

RANGE_M = (10.0, 50.0)
BANDS_DB = ((110.0, 115.0), (115.0, 120.0), (120.0, 125.0), (125.0, 130.0), (130.0, 135.0))
ORACLE_LEVELS_DB = (115.0, 122.5)
TARGET = {"distance_median_m": 6.0, "distance_mean_m": 8.0}


def siren_kind(info: dict[str, Any]) -> str:
    """A siren's kind from its ``meta.yaml`` entry: ``synth:<mode>``, ``tone:<mode>``, ``clip``
    (real road-video clips, mode unknown) or ``recording``."""
    if info.get("ingredient") == "synth":
        return f"synth:{info.get('mode', '?')}"
    kind = str(info.get("kind", "?"))
    return f"tone:{info.get('mode', '?')}" if kind == "tone" else kind


def siren_table(rec: Recording) -> list[dict[str, Any]]:
    """The simulator's ``meta.yaml`` entry of each siren source (level, height, kind)."""
    sirens = rec.meta.get("sirens") if rec.meta else None
    if not isinstance(sirens, list) or len(sirens) != len(rec.sources):
        raise InputError(rec.path or "recording", "no simulator meta.yaml with one entry per siren source")
    for s in sirens:
        if not isinstance(s, dict) or "level_db_1m" not in s:
            raise InputError(rec.path or "recording", "meta.yaml sirens lack level_db_1m")
    return sirens


def window_facts(folders: list[Path]) -> dict[str, np.ndarray]:
    """Per kept window, in :func:`~makeway.eval.siren.evaluate`'s order: the nearest siren's
    emitted level (NaN: none), kind and a siren id (recording × source)."""
    level: list[np.ndarray] = []
    kind: list[np.ndarray] = []
    ident: list[np.ndarray] = []
    for i, folder in enumerate(folders):
        rec = read_recording(folder)
        labels = label_recording(rec)
        k = labels.nearest_source()[labels.kept]
        table = siren_table(rec) if rec.sources else []
        lv = np.array([float(table[j]["level_db_1m"]) if j >= 0 else np.nan for j in k])
        kd = np.array([siren_kind(table[j]) if j >= 0 else "" for j in k], dtype=object)
        level.append(lv)
        kind.append(kd)
        ident.append(np.where(k >= 0, 100 * i + k, -1))
    return {
        "level": np.concatenate(level),
        "kind": np.concatenate(kind),
        "id": np.concatenate(ident),
    }


def _stats(err: np.ndarray) -> dict[str, float | None]:
    if not len(err):
        return {"median_m": None, "mean_m": None}
    return {"median_m": round(float(np.median(err)), 2), "mean_m": round(float(np.mean(err)), 2)}


def group_row(sel: np.ndarray, a: dict[str, np.ndarray], threshold: float) -> dict[str, Any]:
    """Recall and distance errors (networks, oracles) over the positive windows ``sel`` at 10–50 m."""
    d, level = a["distance"][sel], a["level"][sel]
    row: dict[str, Any] = {
        "n": int(sel.sum()),
        "sirens": len(set(a["id"][sel].tolist())),
        "recall": round(float(np.mean(a["prob"][sel] >= threshold)), 4) if sel.any() else None,
        "networks": _stats(np.abs(a["distance_hat"][sel] - d)),
    }
    for lv in ORACLE_LEVELS_DB:
        row[f"oracle_{lv:g}"] = _stats(np.abs(d * 10 ** ((lv - level) / 20.0) - d))
    return row


def score(folders: list[Path], threads: int = 2) -> dict[str, Any]:
    """Run the shipped listener's decision over ``folders`` and break it down (module docstring)."""
    model = SirenModel(threads=threads)
    arrays: dict[str, np.ndarray] = {}
    t0 = time.perf_counter()
    with progress_bar("scoring", len(folders), unit="rec") as advance:
        overall = evaluate(
            folders,
            model_estimator(model),
            threshold=model.threshold,
            smooth=LISTEN_SMOOTH,
            on_recording=lambda: advance(1),
            arrays=arrays,
        )
    facts = window_facts(folders)
    a = {**arrays, **facts}
    if len(a["level"]) != len(a["siren"]):
        raise SystemExit("window bookkeeping differs from evaluate's; cannot break down by level")
    pos = a["siren"]
    in_range = pos & (a["distance"] >= RANGE_M[0]) & (a["distance"] <= RANGE_M[1])
    by_band = {}
    for lo, hi in BANDS_DB:
        top = a["level"] <= hi if hi == BANDS_DB[-1][1] else a["level"] < hi
        by_band[f"{lo:g}-{hi:g}"] = group_row(in_range & (a["level"] >= lo) & top, a, model.threshold)
    by_kind = {
        k: group_row(in_range & (a["kind"] == k), a, model.threshold)
        for k in sorted({str(v) for v in a["kind"][in_range]})
    }
    return {
        "recordings": len(folders),
        "threshold": model.threshold,
        "smooth": LISTEN_SMOOTH,
        "false_alarm_rate": overall["false_alarm_rate"],
        "negatives": overall["negatives"],
        "all_10_50": group_row(in_range, a, model.threshold),
        "by_level_db": by_band,
        "by_kind": by_kind,
        "seconds": round(time.perf_counter() - t0, 1),
    }


def print_table(title: str, rows: dict[str, dict[str, Any]]) -> None:
    def fmt(s: dict[str, float | None]) -> str:
        if s["median_m"] is None:
            return f"{'–':>15s}"
        return f"{s['median_m']:>7.1f}/{s['mean_m']:<6.1f}m"

    head = "".join(f"{'oracle ' + format(v, 'g') + ' dB':>16s}" for v in ORACLE_LEVELS_DB)
    print(f"\n{title:16s}{'n (sirens)':>12s}{'recall':>9s}{'networks':>15s} {head}   (median/mean, 10–50 m)")
    for name, r in rows.items():
        rec = "–" if r["recall"] is None else f"{100 * r['recall']:.1f}%"
        oracles = "".join(fmt(r[f"oracle_{v:g}"]) + " " for v in ORACLE_LEVELS_DB)
        print(f"{name:16s}{r['n']:>7d} ({r['sirens']:>2d}){rec:>9s}{fmt(r['networks'])} {oracles}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, action="append", default=None, help="recordings (repeatable)")
    ap.add_argument("--n", type=int, default=20, help="recordings per seed to simulate without --data")
    ap.add_argument("--seeds", default="2026,2027,2030,2031", help="held-out seeds, pooled")
    ap.add_argument("--levels", default="110,135", help="emitted siren level range, dB SPL at 1 m")
    ap.add_argument("--duration", type=float, default=8.0, help="seconds per simulated recording")
    ap.add_argument("--keep", type=Path, default=None, help="simulate into this folder and keep it")
    ap.add_argument("--json", type=Path, default=None, help="also write the results to this JSON file")
    args = ap.parse_args()
    lo, hi = (float(v) for v in args.levels.split(","))
    seeds = [int(v) for v in args.seeds.split(",") if v.strip()]
    with tempfile.TemporaryDirectory() as tmp:
        out = args.keep if args.keep is not None else Path(tmp)
        t0 = time.perf_counter()
        try:
            folders = held_out_folders(args.data, out, args.n, seeds, args.duration, siren_level_db=(lo, hi))
            if not args.data:
                print(
                    f"simulated {len(folders)} held-out recordings (levels {lo:g}–{hi:g} dB) in "
                    f"{time.perf_counter() - t0:.0f} s, load {os.getloadavg()[0]:.1f}"
                )
            result = score(folders)
        except InputError as exc:
            raise SystemExit(str(exc)) from None
    print(
        f"\n{result['recordings']} recordings; decision: mean logit of {result['smooth']} windows at "
        f"threshold {result['threshold']:.3f}; false alarms {100 * (result['false_alarm_rate'] or 0):.2f}% "
        f"of {result['negatives']} negative windows. Target: median ≤ {TARGET['distance_median_m']:g} m, "
        f"mean ≤ {TARGET['distance_mean_m']:g} m in every band; recall ≥ 99.5 %."
    )
    print_table("emitted level", {"all": result["all_10_50"], **result["by_level_db"]})
    print_table("siren kind", result["by_kind"])
    print(f"\nscored in {result['seconds']:.0f} s, load average {os.getloadavg()}")
    text = json.dumps(to_jsonable(result), ensure_ascii=False)
    if args.json is not None:
        args.json.write_text(text, encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
