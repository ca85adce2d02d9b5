"""Siren recall and distance by emitted level and by siren kind (issue 25, item 3).

    .venv/bin/python benchmarks/bench_audio_range_levels.py [--data DIR ... | --n 20
        --seeds 2026,2027,2030,2031 --levels 110,135] [--combo NAME=NET+NET ...] [--keep DIR]
        [--json FILE]

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

``--combo NAME=NET+NET+…`` (repeatable) scores other ways of combining networks' distances on the
very same windows, beside the shipped combination (``shipped``): the geometric mean of the named
networks' distances (``SirenModel.run_alone`` on the features computed once). A ``NET`` is an ONNX
file or a shipped name (``localizer``, ``ranger``, ``ranger2`` … for ``models/siren_<name>.onnx``).
For every combination it also prints, on labels out to 300 m (the networks learnt to 100 m):

* the median relative distance error ``|d̂ − d| / d`` per distance band (10–50, 50–100, 100–150,
  150–300 m; target ≤ 25 % to 150 m);
* the far/near call — ``d̂ > 100 m`` against ``d > 100 m`` — right in what share of the windows
  with a siren within 300 m (target ≥ 95 %);
* with networks that give a σ of ln distance (``makeway audio train --distance-sigma``): the
  share of windows at 5–100 m whose ln distance error lies within ±1σ and ±2σ (a calibrated
  Gaussian: 68 % and 95 %).

``σ scale``: the factor ``k`` by which a combination's σ would have to be multiplied for ±kσ to
hold 68.3 % of those windows, and the share within ±2kσ after that scaling (fit ``k`` on
validation recordings, check it held out); the JSON also has quantiles of ``|ln d̂ − ln d| / σ``.

**Misses**: every siren with a missed window at 10–50 m — its recording, kind, name, emitted level,
the distances of the missed windows, the street noise's level at the array and the recording's
in-band siren-to-noise ratio — and the recall per 5 dB band of the *nominal margin*: the siren's
level at the array by spherical spreading alone (``L₁ₘ − 20·log₁₀ d``) minus the street noise's
A-weighted level (``meta.yaml``): whether misses are quiet, far sirens under loud streets.

``--keep DIR`` keeps the simulated scenes, so ``bench_audio_range_cues.py --data DIR`` measures the
level-independent cues on the very same scenes.
"""

from __future__ import annotations

import argparse
import itertools
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
from makeway.perceive.audio.siren_model import (
    DEFAULT_SIREN_MODEL,
    SirenModel,
    SirenPrediction,
    combine_distances,
)
from makeway.perceive.audio.windows import LISTEN_SMOOTH
from makeway.progress import progress_bar
from makeway.sense.recording import Recording, calibration_gain, read_recording
from makeway.sim.audio_scenarios import held_out_folders

RANGE_M = (10.0, 50.0)
BANDS_DB = ((110.0, 115.0), (115.0, 120.0), (120.0, 125.0), (125.0, 130.0), (130.0, 135.0))
ORACLE_LEVELS_DB = (115.0, 122.5)
TARGET = {"distance_median_m": 6.0, "distance_mean_m": 8.0}
FAR_BANDS_M = ((10.0, 50.0), (50.0, 100.0), (100.0, 150.0), (150.0, 300.0))
FAR_LABEL_M = 300.0
FAR_NEAR_M = 100.0
SIGMA_RANGE_M = (5.0, 100.0)
SHIPPED = "shipped"
ONE_SIGMA = 0.6827
Z_QUANTILES = (0.5, 0.6827, 0.8, 0.9, 0.9545, 0.99)
MARGIN_BANDS_DB = (-20.0, -10.0, -5.0, 0.0, 5.0, 10.0, 20.0, 40.0)


def parse_combo(text: str) -> tuple[str, list[Path]]:
    """``NAME=NET+NET+…`` → the name and the networks' files (module docstring)."""
    name, sep, members = text.partition("=")
    if not sep or not name.strip() or not members.strip():
        raise SystemExit(f"--combo takes NAME=NET+NET+…, not {text!r}")
    paths = []
    for m in (v.strip() for v in members.split("+")):
        p = Path(m) if m.endswith(".onnx") else DEFAULT_SIREN_MODEL.parent / f"siren_{m}.onnx"
        if not p.is_file():
            raise SystemExit(f"--combo {name}: no network {p}")
        paths.append(p)
    return name.strip(), paths


class Recorder:
    """The shipped model as ``model_estimator`` sees it, that also runs every candidate network on
    the same features and records each one's distance and σ (all windows, in call order)."""

    def __init__(self, model: SirenModel, nets: dict[Path, SirenModel], cache: Path | None = None) -> None:
        self.model, self.nets, self.cache = model, nets, cache
        self.calls = 0
        self.shipped: list[np.ndarray] = []
        self.shipped_sigma: list[np.ndarray | None] = []
        self.out: dict[Path, list[SirenPrediction]] = {p: [] for p in nets}

    def check_array(self, mics: np.ndarray, sample_rate: int, source: str | Path) -> None:
        self.model.check_array(mics, sample_rate, source)

    def predict(self, windows: np.ndarray, full_scale_db_spl: float | None = None) -> SirenPrediction:
        gain = calibration_gain(full_scale_db_spl, self.model.full_scale_db_spl)
        part = None if self.cache is None else self.cache / f"{self.calls:06d}.npz"
        self.calls += 1
        if part is not None and part.is_file():
            with np.load(part) as z:
                feats = {k: z[k] for k in z.files}
        else:
            feats = self.model.features.transform(windows * np.float32(gain) if gain != 1.0 else windows)
            if part is not None:
                np.savez(part, **feats)
        for p, net in self.nets.items():
            self.out[p].append(net.run_alone(feats))
        pred = self.model.run_features(feats)
        self.shipped.append(pred.distance)
        self.shipped_sigma.append(pred.distance_sigma)
        return pred

    def combined(self, paths: list[Path]) -> tuple[np.ndarray, np.ndarray | None]:
        """Distance and σ of the geometric mean of ``paths``' networks over every recorded window."""
        members = []
        for p in paths:
            parts = self.out[p]
            sig = [q.distance_sigma for q in parts]
            members.append(
                SirenPrediction(
                    np.zeros(0),
                    np.zeros(0),
                    np.concatenate([q.distance for q in parts]),
                    None,
                    np.concatenate(sig) if all(x is not None for x in sig) else None,  # type: ignore[arg-type]
                )
            )
        return combine_distances(members)


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
    street: list[np.ndarray] = []
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
        street.append(np.full(len(k), street_dba(rec)))
    return {
        "level": np.concatenate(level),
        "kind": np.concatenate(kind),
        "id": np.concatenate(ident),
        "street_dba": np.concatenate(street),
    }


def street_dba(rec: Recording) -> float:
    """The street noise's A-weighted level at the array (dB, the simulator's ``meta.yaml``; NaN
    when it states none)."""
    noise = rec.meta.get("street_noise") if rec.meta else None
    value = noise.get("level_dba") if isinstance(noise, dict) else None
    return float(value) if isinstance(value, int | float) else float("nan")


def miss_rows(
    folders: list[Path], a: dict[str, np.ndarray], sel: np.ndarray, threshold: float
) -> list[dict[str, Any]]:
    """Every siren with a missed window among ``sel`` (module docstring, **Misses**), most missed
    first."""
    missed = sel & (a["prob"] < threshold)
    rows = []
    for sid in sorted(set(a["id"][missed].tolist())):
        mine = sel & (a["id"] == sid)
        gone = mine & missed
        rec = read_recording(folders[sid // 100])
        info = siren_table(rec)[sid % 100]
        snr = rec.meta.get("snr_band_db") if rec.meta else None
        d = a["distance"][gone]
        rows.append(
            {
                "recording": f"{folders[sid // 100].parent.name}/{folders[sid // 100].name}",
                "kind": siren_kind(info),
                "name": str(info.get("name", "")),
                "level_db_1m": round(float(info["level_db_1m"]), 1),
                "missed": int(gone.sum()),
                "windows": int(mine.sum()),
                "missed_distance_m": [round(float(d.min()), 1), round(float(d.max()), 1)],
                "street_dba": round(float(a["street_dba"][gone][0]), 1),
                "snr_band_db": float(snr) if isinstance(snr, int | float) else None,
            }
        )
    return sorted(rows, key=lambda r: -r["missed"])


def margin_rows(a: dict[str, np.ndarray], sel: np.ndarray, threshold: float) -> dict[str, Any]:
    """Recall per band of the nominal margin, ``L₁ₘ − 20·log₁₀ d`` minus the street noise's level
    (module docstring, **Misses**)."""
    margin = a["level"] - 20.0 * np.log10(np.maximum(a["distance"], 1e-3)) - a["street_dba"]
    out = {}
    edges = (-np.inf, *MARGIN_BANDS_DB, np.inf)
    for lo, hi in itertools.pairwise(edges):
        inside = sel & (margin >= lo) & (margin < hi)
        out[f"{lo:g}..{hi:g}"] = {
            "n": int(inside.sum()),
            "recall": round(float(np.mean(a["prob"][inside] >= threshold)), 4) if inside.any() else None,
        }
    return out


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


def far_rows(
    d_hat: np.ndarray, sigma: np.ndarray | None, d300: np.ndarray, d100: np.ndarray
) -> dict[str, Any]:
    """Relative error per distance band and the far/near call on labels to 300 m (``d300``: the
    nearest siren's distance per window, NaN: none within 300 m), and the σ coverage at 5–100 m
    (``d100``: the same on the windows the 10–50 m figures use) (module docstring)."""
    row: dict[str, Any] = {}
    ok = np.isfinite(d300) & (d300 > 0)
    rel = np.abs(d_hat - d300) / np.where(ok, d300, 1.0)
    for lo, hi in FAR_BANDS_M:
        sel = ok & (d300 >= lo) & (d300 < hi)
        row[f"rel_{lo:g}_{hi:g}"] = {
            "n": int(sel.sum()),
            "median": round(float(np.median(rel[sel])), 4) if sel.any() else None,
        }
    row["far_near_right"] = round(float(np.mean((d_hat[ok] > FAR_NEAR_M) == (d300[ok] > FAR_NEAR_M))), 4)
    row["far_windows"] = int((ok & (d300 > FAR_NEAR_M)).sum())
    row["far_called_far"] = (
        round(float(np.mean(d_hat[ok & (d300 > FAR_NEAR_M)] > FAR_NEAR_M)), 4) if row["far_windows"] else None
    )
    if sigma is not None:
        sel = np.isfinite(d100) & (d100 >= SIGMA_RANGE_M[0]) & (d100 <= SIGMA_RANGE_M[1])
        z = np.abs(np.log(np.maximum(d_hat[sel], 1e-3)) - np.log(d100[sel])) / np.maximum(sigma[sel], 1e-6)
        k = float(np.quantile(z, ONE_SIGMA)) if len(z) else float("nan")
        row["sigma"] = {
            "n": int(sel.sum()),
            "within_1": round(float(np.mean(z <= 1.0)), 4),
            "within_2": round(float(np.mean(z <= 2.0)), 4),
            "median_sigma": round(float(np.median(sigma[sel])), 4),
            "scale_68": round(k, 3),
            "within_2_scaled": round(float(np.mean(z <= 2.0 * k)), 4),
            "z_quantiles": {f"{q:g}": round(float(np.quantile(z, q)), 3) for q in Z_QUANTILES},
        }
    return row


def score(
    folders: list[Path],
    threads: int = 2,
    combos: dict[str, list[Path]] | None = None,
    feature_cache: Path | None = None,
) -> dict[str, Any]:
    """Run the shipped listener's decision over ``folders`` and break it down (module docstring);
    ``combos`` (name → networks) are scored on the same windows beside the shipped combination.
    ``feature_cache``: a folder where the windows' features are kept, per set of folders, so a
    second run on the same recordings only runs the networks."""
    model = SirenModel(threads=threads)
    combos = dict(combos or {})
    nets: dict[Path, SirenModel] = {}
    for paths in combos.values():
        for p in paths:
            if p not in nets:
                net = SirenModel(p, threads=threads, localizer=False, ranger=False)
                if net.features.config != model.features.config:
                    raise InputError(p, "reads other features than the shipped detector")
                nets[p] = net
    cache = None
    if feature_cache is not None:
        import hashlib

        key = hashlib.sha1("\n".join(str(Path(f).resolve()) for f in folders).encode()).hexdigest()[:16]
        cache = feature_cache / key
        cache.mkdir(parents=True, exist_ok=True)
    recorder = Recorder(model, nets, cache)
    arrays: dict[str, np.ndarray] = {}
    t0 = time.perf_counter()
    with progress_bar("scoring", len(folders), unit="rec") as advance:
        overall = evaluate(
            folders,
            model_estimator(recorder),
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

    def bands(a: dict[str, np.ndarray]) -> dict[str, Any]:
        out = {}
        for lo, hi in BANDS_DB:
            top = a["level"] <= hi if hi == BANDS_DB[-1][1] else a["level"] < hi
            out[f"{lo:g}-{hi:g}"] = group_row(in_range & (a["level"] >= lo) & top, a, model.threshold)
        return out

    by_band = bands(a)
    by_kind = {
        k: group_row(in_range & (a["kind"] == k), a, model.threshold)
        for k in sorted({str(v) for v in a["kind"][in_range]})
    }
    # every window was run (the smoothed decision needs each one's history): map them to the
    # kept windows of the figures above and to labels out to 300 m
    kept, d300 = [], []
    for folder in folders:
        rec = read_recording(folder)
        kept.append(label_recording(rec).kept)
        d300.append(label_recording(rec, max_distance_m=FAR_LABEL_M).nearest()[1])
    keep, far_d = np.concatenate(kept), np.concatenate(d300)
    shipped_all = np.concatenate(recorder.shipped)
    sig_parts = recorder.shipped_sigma
    shipped_sigma = np.concatenate(sig_parts) if all(x is not None for x in sig_parts) else None  # type: ignore[arg-type]
    if len(shipped_all) != len(keep) or not np.allclose(shipped_all[keep], a["distance_hat"], equal_nan=True):
        raise SystemExit("recorded windows differ from evaluate's; cannot compare combinations")
    d100 = np.full(len(keep), np.nan)
    d100[np.flatnonzero(keep)[pos]] = a["distance"][pos]
    combined: dict[str, Any] = {
        SHIPPED: {
            "all_10_50": group_row(in_range, a, model.threshold),
            "by_level_db": by_band,
            **far_rows(shipped_all, shipped_sigma, far_d, d100),
        }
    }
    for name, paths in combos.items():
        dist, sigma = recorder.combined(paths)
        b = {**a, "distance_hat": dist[keep]}
        combined[name] = {
            "networks": [p.name for p in paths],
            "all_10_50": group_row(in_range, b, model.threshold),
            "by_level_db": bands(b),
            **far_rows(dist, sigma, far_d, d100),
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
        "combinations": combined,
        "misses": miss_rows(folders, a, in_range, model.threshold),
        "recall_by_margin_db": margin_rows(a, in_range, model.threshold),
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


def print_combinations(rows: dict[str, dict[str, Any]]) -> None:
    """Distance by emitted level, and beyond 50 m, for every combination (module docstring)."""

    def ms(r: dict[str, Any]) -> str:
        s = r["networks"]
        return "–" if s["median_m"] is None else f"{s['median_m']:.1f}/{s['mean_m']:.1f}"

    bands = list(next(iter(rows.values()))["by_level_db"])
    print(f"\n{'distance, 10–50 m':18s}{'all':>12s}" + "".join(f"{b + ' dB':>12s}" for b in bands))
    for name, r in rows.items():
        print(
            f"{name:18s}{ms(r['all_10_50']):>12s}" + "".join(f"{ms(r['by_level_db'][b]):>12s}" for b in bands)
        )
    print(f"{'target':18s}" + f"{'≤ 6/8':>12s}" * (len(bands) + 1) + "   (median/mean m)")
    heads = [f"{lo:g}–{hi:g} m" for lo, hi in FAR_BANDS_M]
    print(
        f"\n{'relative error':18s}"
        + "".join(f"{h:>12s}" for h in heads)
        + f"{'far/near':>10s}"
        + f"{'far→far':>9s}{'±1σ':>7s}{'±2σ':>7s}{'σ scale':>8s}{'±2kσ':>8s}"
    )
    for name, r in rows.items():
        cells = []
        for lo, hi in FAR_BANDS_M:
            c = r[f"rel_{lo:g}_{hi:g}"]
            cells.append("–" if c["median"] is None else f"{100 * c['median']:.0f}% ({c['n']})")
        sig = r.get("sigma")
        far = "–" if r["far_called_far"] is None else f"{100 * r['far_called_far']:.0f}%"
        print(
            f"{name:18s}"
            + "".join(f"{c:>12s}" for c in cells)
            + f"{100 * r['far_near_right']:>9.1f}%"
            + f"{far:>9s}"
            + (
                f"{100 * sig['within_1']:>6.0f}%{100 * sig['within_2']:>6.0f}%"
                f"{sig['scale_68']:>8.2f}{100 * sig['within_2_scaled']:>7.0f}%"
                if sig
                else f"{'–':>7s}{'–':>7s}{'–':>8s}{'–':>8s}"
            )
        )
    print(
        f"{'target':18s}{'≤ 25 %':>12s}{'≤ 25 %':>12s}{'≤ 25 %':>12s}{'':>12s}{'≥ 95 %':>10s}"
        f"{'':>9s}{'68 %':>7s}{'95 %':>7s}{'1':>8s}{'95 %':>8s}"
    )


def print_misses(misses: list[dict[str, Any]], margins: dict[str, Any], limit: int = 15) -> None:
    """The sirens with missed windows and the recall by nominal margin (module docstring)."""
    print(f"\nmissed sirens at 10–50 m ({len(misses)}; the {min(limit, len(misses))} most missed)")
    print(
        f"{'recording':26s}{'kind':14s}{'name':22s}{'dB 1 m':>7s}{'missed':>10s}{'at m':>13s}"
        f"{'street':>8s}{'SNR':>7s}"
    )
    for r in misses[:limit]:
        lo, hi = r["missed_distance_m"]
        snr = "–" if r["snr_band_db"] is None else f"{r['snr_band_db']:.1f}"
        print(
            f"{r['recording']:26s}{r['kind']:14s}{r['name'][:21]:22s}{r['level_db_1m']:>7.1f}"
            f"{r['missed']:>4d} of {r['windows']:<3d}{lo:>6.1f}–{hi:<5.1f}{r['street_dba']:>7.1f} {snr:>6s}"
        )
    print("\nrecall by nominal margin (siren level at the array by spreading − street dB(A)), 10–50 m")
    cells = []
    for k, v in margins.items():
        rec = "–" if v["recall"] is None else f"{100 * v['recall']:.1f}%"
        cells.append(f"{k} dB: {rec} ({v['n']})")
    print("  " + "  ".join(cells))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, action="append", default=None, help="recordings (repeatable)")
    ap.add_argument("--n", type=int, default=20, help="recordings per seed to simulate without --data")
    ap.add_argument("--seeds", default="2026,2027,2030,2031", help="held-out seeds, pooled")
    ap.add_argument("--levels", default="110,135", help="emitted siren level range, dB SPL at 1 m")
    ap.add_argument("--duration", type=float, default=8.0, help="seconds per simulated recording")
    ap.add_argument(
        "--combo",
        action="append",
        default=[],
        help="NAME=NET+NET+…: also score the geometric mean of these networks' distances (repeatable)",
    )
    ap.add_argument("--keep", type=Path, default=None, help="simulate into this folder and keep it")
    ap.add_argument(
        "--feature-cache",
        type=Path,
        default=None,
        help="keep the windows' features in this folder: a rerun on the same recordings reuses them",
    )
    ap.add_argument("--json", type=Path, default=None, help="also write the results to this JSON file")
    args = ap.parse_args()
    lo, hi = (float(v) for v in args.levels.split(","))
    seeds = [int(v) for v in args.seeds.split(",") if v.strip()]
    combos = dict(parse_combo(c) for c in args.combo)
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
            result = score(folders, combos=combos, feature_cache=args.feature_cache)
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
    print_combinations(result["combinations"])
    print_misses(result["misses"], result["recall_by_margin_db"])
    print(f"\nscored in {result['seconds']:.0f} s, load average {os.getloadavg()}")
    text = json.dumps(to_jsonable(result), ensure_ascii=False)
    if args.json is not None:
        args.json.write_text(text, encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
