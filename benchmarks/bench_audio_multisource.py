"""More than one siren (issue 4): both sirens found, against the network's bearing map as anchor.

    .venv/bin/python benchmarks/bench_audio_multisource.py [--two DIR] [--one DIR] [--n 24]
        [--per-recording 20] [--grid] [--json FILE]

1. Recordings: ``--two`` (every recording has two EVs) and ``--one`` (one EV), or simulated from
   the **test** groups (``makeway audio simulate --split test``): ``--n`` two-siren recordings with
   seed 2028 and ``--n`` one-siren recordings with seed 2029, 8 s each.
2. Windows: every window with two sirens ≤ 100 m (two-siren set) or exactly one (one-siren set), at
   most ``--per-recording`` per recording (a fixed random draw).
3. Per window, the sirens reported by :meth:`SirenModel.sources` (the shipped detector + localizer:
   the nearest from the heads, further ones by time–frequency bin assignment,
   :mod:`makeway.perceive.audio.multisource`) against the anchor: further sirens read as peaks of
   the network's bearing map (holding ≥ 50 % of the first peak's mass, ≥ 30° apart — makeway's
   method until 2026-11-22), and the separator without its siren checks (``check_siren=False``:
   every further sound source reported, whether or not its bins carry a siren).
4. Prints, side by side: two-siren windows where *every* siren lies within 15° of a reported bearing
   (all; sirens ≥ 30° apart; both 10–50 m and ≥ 30° apart), and one-siren windows with a spurious
   second siren. ``--grid`` sweeps the separator's constants (choose them on ``--split train``
   recordings, never on the held-out ones).
5. Cost: median time of the separator per siren window (2 cores shared), beside the 25 ms budget
   of one window through the network.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from makeway.eval.siren_labels import label_recording
from makeway.perceive.audio.features import window_batch
from makeway.perceive.audio.multisource import SourceSeparator
from makeway.perceive.audio.siren_model import MAX_SOURCES, NEAR_ALONE_M, SirenModel
from makeway.progress import progress_bar
from makeway.sense.recording import read_recording, recording_folders

TOLERANCE_DEG = 15.0
MAP_PEAK_FRACTION = 0.5
MAP_SEPARATION_DEG = 30.0


def map_peaks(bmap: np.ndarray, first: float) -> list[float]:
    """The anchor: ``first`` plus the bearing-map peaks holding ≥ 50 % of the strongest peak's
    mass (±15° window), ≥ 30° from every bearing taken."""
    n = len(bmap)
    step = 2.0 * math.pi / n
    half = max(1, round(math.radians(MAP_SEPARATION_DEG) / step / 2))
    mass = np.convolve(np.concatenate([bmap[-half:], bmap, bmap[:half]]), np.ones(2 * half + 1), mode="valid")
    is_peak = (mass >= np.roll(mass, 1)) & (mass > np.roll(mass, -1))
    order = [int(k) for k in np.argsort(-mass) if is_peak[k]]
    taken = [first]
    for k in order[1:] if order else []:
        if mass[k] < MAP_PEAK_FRACTION * mass[order[0]] or len(taken) >= MAX_SOURCES:
            break
        az = math.atan2(math.sin(k * step), math.cos(k * step))
        if all(abs(math.remainder(az - t, 2 * math.pi)) >= math.radians(MAP_SEPARATION_DEG) for t in taken):
            taken.append(az)
    return taken


def all_found(got: list[float], truth: np.ndarray) -> bool:
    tol = math.radians(TOLERANCE_DEG)
    return all(any(abs(math.remainder(g - t, 2 * math.pi)) <= tol for g in got) for t in truth)


def collect(folders: list[Path], kind: str, per_rec: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``(window, truth bearings, truth distances)`` of the selected windows (module docstring)."""
    rng = np.random.default_rng(0)
    out = []
    for f in folders:
        rec = read_recording(f)
        lab = label_recording(rec)
        n_present = lab.present.sum(axis=1)
        sel = np.flatnonzero(n_present >= 2) if kind == "two" else np.flatnonzero(n_present == 1)
        if len(sel) > per_rec:
            sel = np.sort(rng.choice(sel, per_rec, replace=False))
        if not len(sel):
            continue
        wins = window_batch(rec, lab)[sel]
        for j, w in enumerate(sel):
            out.append((wins[j], lab.theta[w][lab.present[w]], lab.distance[w][lab.present[w]]))
    return out


def score(rows: list[tuple[bool, int, float, bool]]) -> dict[str, float]:
    """rows: (all found, n reported, separation deg, both 10–50 m)."""
    a = np.array(rows, dtype=np.float64).reshape(-1, 4)
    sep = a[:, 2] >= 30.0
    near = sep & (a[:, 3] > 0)
    return {
        "n": len(a),
        "all_found": float(a[:, 0].mean()) if len(a) else float("nan"),
        "all_found_sep30": float(a[sep, 0].mean()) if sep.any() else float("nan"),
        "n_sep30": int(sep.sum()),
        "all_found_10_50_sep30": float(a[near, 0].mean()) if near.any() else float("nan"),
        "n_10_50_sep30": int(near.sum()),
        "two_or_more": float((a[:, 1] >= 2).mean()) if len(a) else float("nan"),
    }


def evaluate(
    model: SirenModel, windows: list, separators: dict[str, tuple[SourceSeparator, float]]
) -> tuple[dict, list]:
    """Scores of the anchor and of every ``name: (separator, near_alone_m)`` setting."""
    res: dict[str, list] = {"network bearing map": [], **{k: [] for k in separators}}
    times: list[float] = []
    batch = np.stack([w for w, _, _ in windows]) if windows else np.zeros((0,))
    pred = model.predict(batch) if len(windows) else None
    with progress_bar("windows", len(windows), unit="win") as advance:
        for i, (win, truth, dist) in enumerate(windows):
            sep = (
                abs(math.degrees(math.remainder(truth[0] - truth[-1], 2 * math.pi)))
                if len(truth) > 1
                else 0.0
            )
            near = bool(np.all((dist >= 10) & (dist <= 50)))
            detected = pred is not None and pred.prob[i] >= model.threshold
            first = float(pred.theta[i]) if pred is not None else 0.0
            got = map_peaks(pred.bearing_map[i], first) if detected and pred.bearing_map is not None else []
            if detected and pred.bearing_map is None:
                got = [first]
            res["network bearing map"].append((all_found(got, truth), len(got), sep, near))
            for name, (s, near_alone) in separators.items():
                model.separator, model.near_alone_m = s, near_alone
                t0 = time.perf_counter()
                got = [src["bearing_rad"] for src in model.sources(pred, i, win)] if pred is not None else []
                if len(got) and float(pred.distance[i]) >= near_alone:
                    times.append(time.perf_counter() - t0)
                res[name].append((all_found(got, truth), len(got), sep, near))
            advance(1)
    return {k: score(v) for k, v in res.items()}, times


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--two", type=Path, default=None, help="two-siren recordings (default: simulate)")
    ap.add_argument("--one", type=Path, default=None, help="one-siren recordings (default: simulate)")
    ap.add_argument("--n", type=int, default=24, help="recordings per set when simulating")
    ap.add_argument("--per-recording", type=int, default=20)
    ap.add_argument("--grid", action="store_true", help="sweep the separator's constants")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()

    model = SirenModel(threads=2)
    with tempfile.TemporaryDirectory() as tmp:
        sets: dict[str, Path] = {}
        for kind, given, seed, two_frac in (("two", args.two, 2028, 1.0), ("one", args.one, 2029, 0.0)):
            if given is not None:
                sets[kind] = given
                continue
            from makeway.sim.audio_scenarios import generate_recordings, source_pools

            sirens, noise = source_pools("test")
            out = Path(tmp) / kind
            generate_recordings(
                out,
                args.n,
                duration_s=8.0,
                seed=seed,
                siren_pool=sirens,
                noise_pool=noise,
                no_siren_fraction=0.0,
                two_siren_fraction=two_frac,
            )
            sets[kind] = out
        windows = {k: collect(recording_folders(d), k, args.per_recording) for k, d in sets.items()}

    sr, mics = model.config.sample_rate, model.mics
    if args.grid:
        separators = {
            f"c={c:g} share={s:g} near={d:g} m": (SourceSeparator(mics, sr, coherence=c, min_share=s), d)
            for c in (0.7, 0.8, 0.85)
            for s in (0.2, 0.3, 0.4)
            for d in (0.0, 10.0, 15.0)
        }
    else:
        separators = {
            "time–frequency bins": (SourceSeparator(mics, sr), NEAR_ALONE_M),
            "… without siren checks": (SourceSeparator(mics, sr, check_siren=False), NEAR_ALONE_M),
        }
    first = next(iter(separators.values()))
    print(f"model: {model!r}; separator: {first[0]!r}, none while the nearest is < {first[1]:g} m")
    two, t_two = evaluate(model, windows["two"], separators)
    one, t_one = evaluate(model, windows["one"], separators)

    print(
        f"\ntwo-siren windows: {two['network bearing map']['n']} "
        f"({two['network bearing map']['n_sep30']} with the sirens ≥ 30° apart, "
        f"{two['network bearing map']['n_10_50_sep30']} of them both in 10–50 m); "
        f"one-siren windows: {one['network bearing map']['n']}"
    )
    print(f"\n{'':28s}{'both found':>12s}{'≥ 30° apart':>13s}{'10–50 m':>10s}{'spurious 2nd':>14s}")
    for name in two:
        a, b = two[name], one[name]
        print(
            f"{name:28s}{100 * a['all_found']:11.1f}%{100 * a['all_found_sep30']:12.1f}%"
            f"{100 * a['all_found_10_50_sep30']:9.1f}%{100 * b['two_or_more']:13.1f}%"
        )
    t = np.array(t_two + t_one) * 1000.0
    if len(t):
        print(f"\nseparator: median {np.median(t):.1f} ms per siren window (network budget 25 ms per window)")
    if args.json is not None:
        args.json.write_text(
            json.dumps({"two": two, "one": one, "separator_ms": float(np.median(t))}, indent=1)
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
