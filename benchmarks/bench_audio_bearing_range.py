"""Siren range from bearings alone, against the car's own motion (issue 25, item 1: the third
level-free cue, "bearing rate and Doppler against the ego's motion over seconds"), measured alone on
held-out scenes before it joins any estimate.

    .venv/bin/python benchmarks/bench_audio_bearing_range.py [--data DIR ...] [--far DIR ...]
        [--val DIR ...] [--n 30] [--json FILE]
    (without folders it simulates: held-out seeds 2026, 2027, 2030, 2031 of test-split ingredients,
    the same two first seeds with ``--far-start`` for 50–300 m, and training-split seeds 77, 78 to
    choose the settings; --n recordings per seed)

Every one-siren recording is run through the shipped siren networks window by window (0.5 s every
0.17 s). In each window the detector's own decision (probability ≥ its stored threshold) admits
the localizer's bearing, turned into the world frame with the car's logged heading; the car's
logged position is the observer's. :class:`makeway.track.bearings_only.BearingsOnlyRanger` fits a
constant-velocity siren to the last ``window_s`` seconds of those bearings, and its range at each
window is scored against the true distance, beside the networks' own distance on the same windows
(they rest on loudness). Also: how often the fit is *confident* (its posterior σ of ln range at
most 0.35, against the prior's 1.0: the bearings gave it a scale) and how good it is then,
whether its σ is honest (share of windows with |ln(range / truth)| inside its ±1σ), and a blend
(inverse variance in ln range, the networks at the ln-σ they show on the validation scenes) where
the fit is confident.
Beside it, the same fit on the *true* bearings plus Gaussian noise of 1° and 0.3° (4 s windows):
how sharp the bearings would have to be for the cue to range in these scenes' geometry.

The window length is chosen on the validation scenes by the blend's median |ln(distance / truth)|,
then run once on the held-out scenes (prior: 40 m, σ of ln range 1.0; bearing noise 3°).
Doppler is not measured: a siren's own pitch sweep (a wail glides over an octave within seconds)
is larger than the Doppler shift of any road speed (±6 % at 20 m/s), so a shift cannot be read
without knowing the siren's pattern; the approach classifier already reads pitch and level trends.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import tempfile
import time
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from makeway.eval.siren_labels import label_recording, relative_position
from makeway.jsonable import to_jsonable
from makeway.perceive.audio.features import window_batch
from makeway.perceive.audio.siren_model import SirenModel
from makeway.progress import progress_bar
from makeway.sense.recording import read_recording
from makeway.sim.audio_scenarios import held_out_folders
from makeway.track.bearings_only import BearingsOnlyRanger

BANDS_M = ((10.0, 50.0), (50.0, 100.0), (100.0, 150.0), (150.0, 300.0))
CONFIDENT = 0.35
WINDOWS_S = (2.0, 4.0, 6.0)
#: Bearing noise (°) of the oracle fits: the true bearing plus Gaussian noise of this σ, to show
#: how sharp bearings would have to be for the cue to range in these scenes.
ORACLE_SIGMAS_DEG = (1.0, 0.3)
ORACLE_WINDOW_S = 4.0
HELD_OUT_SEEDS = (2026, 2027, 2030, 2031)
FAR_SEEDS = (2026, 2027)
VAL_SEEDS = (77, 78)


def recording_rows(folder: Path, model: SirenModel) -> list[dict[str, Any]]:
    """One row per window of a one-siren recording in which the detector fires: truth, the
    networks' distance, the car's acceleration and turn rate, and each setting's fit."""
    rec = read_recording(folder)
    if len(rec.sources) != 1:
        return []
    labels = label_recording(rec, max_distance_m=1e9)
    windows = window_batch(rec, labels)
    preds = [model.predict(windows[i : i + 64], rec.full_scale_db_spl) for i in range(0, len(windows), 64)]
    prob = np.concatenate([p.prob for p in preds])
    theta = np.concatenate([p.theta for p in preds])
    dist = np.concatenate([p.distance for p in preds])
    t = labels.t_end
    ex, ey = rec.ego.position(t)
    yaw = rec.ego.heading(t)
    sx, sy = relative_position(rec.ego, rec.sources[0], t)
    truth = np.hypot(sx, sy)
    dt = 0.25
    ax, ay = rec.ego.position(t + dt)
    bx, by = rec.ego.position(t - dt)
    speed = np.hypot(ax - ex, ay - ey) / dt
    speed_before = np.hypot(ex - bx, ey - by) / dt
    accel = (speed - speed_before) / dt
    turn = (rec.ego.heading(t + dt) - rec.ego.heading(t - dt)) / (2 * dt)
    rangers: dict[Any, BearingsOnlyRanger] = {s: BearingsOnlyRanger(window_s=s) for s in WINDOWS_S}
    for deg in ORACLE_SIGMAS_DEG:
        rangers[("oracle", deg)] = BearingsOnlyRanger(window_s=ORACLE_WINDOW_S, sigma_rad=math.radians(deg))
    true_bearing = yaw + np.arctan2(sy, sx)
    noise = np.random.default_rng(zlib.crc32(folder.name.encode())).standard_normal(len(t))
    scenario = str(rec.meta.get("scenario", "?")) if rec.meta else "?"
    out: list[dict[str, Any]] = []
    for k in np.flatnonzero(prob >= model.threshold):
        bearing = float(yaw[k] + theta[k])
        fits = {}
        for s, r in rangers.items():
            b = bearing
            if isinstance(s, tuple):  # the true bearing with the oracle's noise
                b = float(true_bearing[k] + math.radians(s[1]) * noise[k])
            fit = r.update(float(t[k]), (float(ex[k]), float(ey[k])), b)
            fits[s] = None if fit is None else (fit.range_m, fit.ln_range_sigma)
        out.append(
            {
                "rec": str(folder),
                "scenario": scenario,
                "d": float(truth[k]),
                "d_net": float(dist[k]),
                "accel": float(accel[k]),
                "turn": float(turn[k]),
                "fits": fits,
            }
        )
    return out


def collect(folders: list[Path], model: SirenModel, what: str) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    with progress_bar(what, len(folders), unit="rec") as advance:
        for f in folders:
            rows += recording_rows(f, model)
            advance(1)
    return rows


def _median(v: list[float]) -> float | None:
    return round(statistics.median(v), 3) if v else None


def score(rows: list[dict[str, Any]], s: Any, net_sigma: float) -> dict[str, Any]:
    """Figures of setting ``s`` on ``rows`` (module docstring)."""
    with_fit = [r for r in rows if r["fits"][s] is not None]
    ln_fit = [abs(math.log(max(r["fits"][s][0], 0.1) / r["d"])) for r in with_fit]
    rel_fit = [abs(r["fits"][s][0] - r["d"]) / r["d"] for r in with_fit]
    rel_net = [abs(r["d_net"] - r["d"]) / r["d"] for r in with_fit]
    inside = [abs(math.log(max(r["fits"][s][0], 0.1) / r["d"])) <= r["fits"][s][1] for r in with_fit]
    conf = [r for r in with_fit if r["fits"][s][1] <= CONFIDENT]
    rel_conf = [abs(r["fits"][s][0] - r["d"]) / r["d"] for r in conf]
    rel_conf_net = [abs(r["d_net"] - r["d"]) / r["d"] for r in conf]
    blend: list[float] = []
    ln_blend: list[float] = []
    for r in with_fit:
        rng, st = r["fits"][s]
        est = r["d_net"]
        if st <= CONFIDENT:
            wn, wt = 1.0 / net_sigma**2, 1.0 / st**2
            est = math.exp((wn * math.log(r["d_net"]) + wt * math.log(rng)) / (wn + wt))
        blend.append(abs(est - r["d"]) / r["d"])
        ln_blend.append(abs(math.log(max(est, 0.1) / r["d"])))
    return {
        "windows": len(rows),
        "with_fit": len(with_fit),
        "fit_median_abs_ln": _median(ln_fit),
        "fit_median_rel": _median(rel_fit),
        "net_median_rel": _median(rel_net),
        "within_1sigma": round(sum(inside) / len(inside), 3) if inside else None,
        "confident_share": round(len(conf) / len(with_fit), 3) if with_fit else None,
        "confident_fit_median_rel": _median(rel_conf),
        "confident_net_median_rel": _median(rel_conf_net),
        "blend_median_rel": _median(blend),
        "blend_median_abs_ln": _median(ln_blend),
    }


def net_ln_sigma(rows: list[dict[str, Any]]) -> float:
    """The networks' spread of ln(distance / truth) on ``rows`` (1.4826 × MAD, robust)."""
    e = np.array([math.log(max(r["d_net"], 0.1) / r["d"]) for r in rows])
    return float(1.4826 * np.median(np.abs(e - np.median(e)))) if len(e) else 0.5


def in_band(rows: list[dict[str, Any]], lo: float, hi: float) -> list[dict[str, Any]]:
    return [r for r in rows if lo <= r["d"] < hi]


def _f(v: Any, pct: bool = True) -> str:
    if v is None:
        return "—"
    return f"{100 * v:.0f} %" if pct else f"{v:.3f}"


def print_table(title: str, groups: dict[str, list[dict[str, Any]]], s: float, ns: float) -> dict:
    print(f"\n{title} (window {s:g} s; median relative error; confident: σ of ln range ≤ {CONFIDENT:g})")
    print(
        f"{'':22s} {'windows':>7s} {'fit':>5s} {'bearings':>9s} {'networks':>9s} {'in ±1σ':>7s} "
        f"{'confident':>9s} {'bearings':>9s} {'networks':>9s} {'blend':>6s}   true bearings + noise "
        f"({ORACLE_WINDOW_S:g} s): confident share, its error"
    )
    out = {}
    for name, rows in groups.items():
        sc = score(rows, s, ns)
        out[name] = sc
        fit_share = sc["with_fit"] / sc["windows"] if sc["windows"] else None
        oracle = {deg: score(rows, ("oracle", deg), ns) for deg in ORACLE_SIGMAS_DEG}
        sc["oracle"] = {f"{deg:g}deg": o for deg, o in oracle.items()}
        extra = "  ".join(
            f"{deg:g}°: {_f(o['confident_share'])} conf., {_f(o['confident_fit_median_rel'])}"
            for deg, o in oracle.items()
        )
        print(
            f"{name:22s} {sc['windows']:7d} {_f(fit_share):>5s} {_f(sc['fit_median_rel']):>9s} "
            f"{_f(sc['net_median_rel']):>9s} {_f(sc['within_1sigma']):>7s} {_f(sc['confident_share']):>9s} "
            f"{_f(sc['confident_fit_median_rel']):>9s} {_f(sc['confident_net_median_rel']):>9s} "
            f"{_f(sc['blend_median_rel']):>6s}   {extra}"
        )
    return out


def groups_of(rows: list[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    g: dict[str, list[dict[str, Any]]] = {"all": rows}
    for lo, hi in BANDS_M:
        g[f"{lo:g}–{hi:g} m"] = in_band(rows, lo, hi)
    for sc in sorted({r["scenario"] for r in rows}):
        g[f"  {sc}"] = [r for r in rows if r["scenario"] == sc]
    g["car steady (|a| < 0.3)"] = [r for r in rows if abs(r["accel"]) < 0.3 and abs(r["turn"]) < 0.02]
    g["car speeding/braking"] = [r for r in rows if abs(r["accel"]) >= 0.3]
    return g


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", action="append", default=[], help="held-out recordings (folder; repeatable)")
    ap.add_argument("--far", action="append", default=[], help="held-out far recordings (--far-start)")
    ap.add_argument("--val", action="append", default=[], help="validation recordings (training split)")
    ap.add_argument("--n", type=int, default=30, help="recordings per simulated seed")
    ap.add_argument("--json", default=None, help="write every figure here")
    args = ap.parse_args()
    t0 = time.time()
    model = SirenModel()
    with tempfile.TemporaryDirectory() as tmp:
        val = held_out_folders(args.val, Path(tmp) / "val", args.n, VAL_SEEDS, split="train")
        test = held_out_folders(args.data, Path(tmp) / "test", args.n, HELD_OUT_SEEDS)
        far = held_out_folders(args.far, Path(tmp) / "far", args.n, FAR_SEEDS, far_start=True)
        val_rows = collect(val, model, "validation")
        ns = net_ln_sigma(in_band(val_rows, 10.0, 300.0))
        choice = {s: score(val_rows, s, ns)["blend_median_abs_ln"] for s in WINDOWS_S}
        print(
            "validation (training-split seeds 77, 78), the blend's median |ln(distance / truth)| by window:"
        )
        for s, v in choice.items():
            print(f"  window {s:g} s: {_f(v, pct=False)}")
        best = min(choice, key=lambda s: math.inf if choice[s] is None else choice[s])
        print(f"chosen: window {best:g} s; networks' ln σ on validation {ns:.3f}")
        test_rows = collect(test, model, "held out") + collect(far, model, "held out, far")
    figures = {
        "validation": print_table("validation", groups_of(val_rows), best, ns),
        "held_out": print_table(
            "held out (seeds 2026, 2027, 2030, 2031; far: 2026, 2027)", groups_of(test_rows), best, ns
        ),
    }
    load = os.getloadavg()[0]
    print(f"\nwall time {time.time() - t0:.0f} s, load average {load:.1f}")
    result = {
        "chosen": {"window_s": best},
        "validation_choice": {f"{s:g}s": v for s, v in choice.items()},
        "net_ln_sigma": ns,
        "confident_rel_sigma": CONFIDENT,
        **figures,
    }
    print(json.dumps(to_jsonable(result)))
    if args.json:
        Path(args.json).write_text(json.dumps(to_jsonable(result), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
