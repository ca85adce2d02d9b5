"""Approaching or receding (issue 4, item 3): the distance-trend classifier against the level/Doppler rule.

    .venv/bin/python benchmarks/bench_audio_approach.py [--data DIR ... | --n 30 --seeds 2026,2027
        --siren-level 110,120]
        [--approach-model FILE] [--rangers default|prior|wide[,...]] [--json FILE]

1. Held-out recordings: ``--data`` (folders of recordings, repeatable), or ``--n`` recordings per
   seed simulated with ``--seeds`` from the **test** groups only (``makeway audio simulate --split
   test``), as the other siren benchmarks make them, with the sirens' emitted level drawn from
   ``--siren-level`` (dB SPL at 1 m; 110–120 by default, real sirens span about 110–135).
2. Every recording runs as ``makeway audio listen`` runs it (the shipped siren networks, the
   listener's decision rule), and on every window the listener reports a siren moving by at least
   1 m/s relative to the car (:func:`~makeway.eval.siren_approach.approach_windows`) two answers
   are scored against the sign of the labelled range rate:

   * ``level`` — :class:`~makeway.perceive.audio.motion.ApproachEstimator`, the level slope and
     Doppler rule (``audio listen`` until the thirteenth session; the anchor);
   * ``trend`` — :class:`~makeway.perceive.audio.motion.TrendApproach` with the shipped classifier
     (the default of ``audio listen`` with the network).

   Printed side by side: ``correct`` (the share decided and right; undecided counts as wrong),
   ``decided``, the accuracy of the decided windows, ``correct`` per scenario and per band of
   relative speed, and the two errors apart (an approaching siren called receding is the costly
   one: the yield decision lets a receding EV go); plus the share of approaching windows (what
   always answering "approaching" would score).

``--rangers`` picks the distance networks whose distance the trend classifier reads (``default``:
the shipped ones; ``prior`` or ``wide``: :data:`~makeway.perceive.audio.siren_model.PRIOR_SIREN_RANGERS`
or :data:`~makeway.perceive.audio.siren_model.WIDE_SIREN_RANGERS`, with the localizer's distance);
several, comma-separated, run one after the other on the same recordings. The tables above are
printed for each set with its own classifier
(:func:`~makeway.perceive.audio.motion.approach_model_for`, or ``--approach-model``). Then every
set is scored with every shipped classifier (:data:`~makeway.perceive.audio.motion.APPROACH_MODELS`,
plus ``--approach-model``): a classifier was trained on one set's distances, and another set's
change what it reads — the cross table shows what the pairing is worth.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from makeway.eval.siren_approach import approach_recordings, approach_scores
from makeway.eval.siren_labels import label_recording
from makeway.perceive.audio.features import window_batch
from makeway.perceive.audio.motion import (
    APPROACH_METHODS,
    APPROACH_MODELS,
    TrendApproach,
    approach_model_for,
)
from makeway.perceive.audio.siren_model import (
    DEFAULT_SIREN_RANGERS,
    PRIOR_SIREN_RANGERS,
    WIDE_SIREN_RANGERS,
    SirenModel,
)
from makeway.progress import progress_bar
from makeway.sense.recording import read_recording
from makeway.sim.audio_scenarios import held_out_folders

ROWS = {"level": "level (anchor)", "trend": "trend"}
RANGERS = {"default": DEFAULT_SIREN_RANGERS, "prior": PRIOR_SIREN_RANGERS, "wide": WIDE_SIREN_RANGERS}


def _pct(v: float | None) -> str:
    return "—" if v is None else f"{100 * v:.2f} %"


def _update_cost(folder: Path, networks: SirenModel) -> dict[str, float]:
    """Median wall time (ms) of one ``update`` of each estimator over the windows of one recording
    (the network's distances and decisions are computed first and not timed)."""
    rec = read_recording(folder)
    labels = label_recording(rec)
    windows = window_batch(rec, labels)
    distance = networks.predict(windows, rec.full_scale_db_spl).distance
    out = {}
    for name in ROWS:
        est = APPROACH_METHODS[name]()
        times = []
        for i in range(len(windows)):
            t0 = time.perf_counter()
            est.update(windows[i], rec.sample_rate, float(labels.t_end[i]), distance_m=float(distance[i]))
            times.append(1000.0 * (time.perf_counter() - t0))
        out[name] = statistics.median(times)
    times = []
    for i in range(min(len(windows), 30)):  # the networks on one window: what a hop costs before these
        t0 = time.perf_counter()
        networks.predict(windows[i : i + 1], rec.full_scale_db_spl)
        times.append(1000.0 * (time.perf_counter() - t0))
    out["networks"] = statistics.median(times)
    return out


def _print_tables(results: dict[str, Any], n_recordings: int) -> None:
    """The detailed tables of one ranger set with its classifier against the level/Doppler rule."""
    anchor = results["level"]
    print(
        f"approaching/receding on {n_recordings} recordings, {anchor['windows']} scored windows "
        f"(siren reported, |range rate| >= 1 m/s); approaching share {_pct(anchor['approaching_share'])}"
    )
    scenarios = sorted(anchor["by_scenario"])
    print(
        f"{'':16s}{'correct':>10s}{'decided':>10s}{'acc|decided':>13s}"
        + "".join(f"{s[:13]:>15s}" for s in scenarios)
    )
    for name in ROWS:
        r = results[name]
        per = "".join(f"{_pct(r['by_scenario'][s]['correct']):>15s}" for s in scenarios)
        print(
            f"{ROWS[name]:16s}{_pct(r['correct']):>10s}{_pct(r['decided']):>10s}{_pct(r['accuracy_decided']):>13s}{per}"
        )
    bands = list(anchor["by_speed_mps"])
    print(f"\n{'correct by |range rate|':24s}" + "".join(f"{b + ' m/s':>14s}" for b in bands))
    for name in ROWS:
        r = results[name]["by_speed_mps"]
        print(f"{ROWS[name]:24s}" + "".join(f"{_pct(r[b]['correct']):>14s}" for b in bands))
    print(f"\n{'errors':24s}{'receding when approaching':>28s}{'approaching when receding':>28s}")
    for name in ROWS:
        r = results[name]
        print(
            f"{ROWS[name]:24s}{_pct(r['receding_when_approaching']):>28s}{_pct(r['approaching_when_receding']):>28s}"
        )
    gain = results["trend"]["correct"] / anchor["correct"] if anchor["correct"] else float("nan")
    print(f"\ntrend / level, share correct: {gain:.2f}×")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, action="append", default=None, help="recordings (default: simulate)")
    ap.add_argument("--n", type=int, default=30, help="recordings per seed to simulate without --data")
    ap.add_argument("--seeds", default="2026,2027", help="seeds of the simulated held-out sets")
    ap.add_argument("--duration", type=float, default=8.0, help="seconds per simulated recording")
    ap.add_argument("--siren-level", default="110,120", help="simulated sirens' level range, dB SPL at 1 m")
    ap.add_argument(
        "--approach-model", type=Path, default=None, help="classifier file (default: each set's own)"
    )
    ap.add_argument("--rangers", default="default", help="distance networks: default, prior, wide (a,b,...)")
    ap.add_argument("--json", type=Path, default=None, help="also write the results to this JSON file")
    args = ap.parse_args()
    sets = [r for r in args.rangers.split(",") if r]
    unknown = [r for r in sets if r not in RANGERS]
    if not sets or unknown:
        ap.error(f"--rangers takes {', '.join(sorted(RANGERS))} (comma-separated), not {args.rangers!r}")
    classifiers = {name: path for name, path in APPROACH_MODELS.items() if path.is_file()}
    if args.approach_model is not None:
        classifiers[str(args.approach_model)] = args.approach_model
    seeds = [int(s) for s in args.seeds.split(",")]
    lo, hi = (float(v) for v in args.siren_level.split(","))
    results: dict[str, Any] = {"cross": {}}
    cross: dict[str, dict[str, dict[str, Any]]] = results["cross"]
    with tempfile.TemporaryDirectory() as tmp:
        folders = held_out_folders(args.data, tmp, args.n, seeds, args.duration, siren_level_db=(lo, hi))
        results["recordings"] = len(folders)
        for rangers in sets:
            networks = SirenModel(threads=2, ranger=RANGERS[rangers], localizer_distance=True)
            own = args.approach_model or approach_model_for(RANGERS[rangers])
            print(f"\n== rangers {rangers}: {networks!r}; its classifier {own.name}")
            with progress_bar(f"recordings, rangers {rangers}", len(folders), unit="rec") as advance:
                arrays = approach_recordings(folders, networks, TrendApproach(model=None), advance=advance)
            scores = approach_scores(arrays, TrendApproach(own))
            _print_tables(scores, len(folders))
            results[rangers] = {"classifier": own.name, **scores}
            cross[rangers] = {
                name: approach_scores(arrays, TrendApproach(path))["trend"]
                for name, path in classifiers.items()
            }
            if rangers == sets[0]:
                cost = _update_cost(folders[0], networks)
    print(
        f"\n{'rangers':9s}{'classifier':>22s}{'correct':>10s}{'receding when approaching':>28s}"
        f"{'approaching when receding':>28s}"
    )
    for rangers, row in cross.items():
        for name, r in row.items():
            print(
                f"{rangers:9s}{Path(name).name[:22]:>22s}{_pct(r['correct']):>10s}"
                f"{_pct(r['receding_when_approaching']):>28s}{_pct(r['approaching_when_receding']):>28s}"
            )
    results["ms_per_update"] = cost
    print(
        f"cost per 0.17 s hop (median, one recording, rangers {sets[0]}): level {cost['level']:.2f} ms, "
        f"trend {cost['trend']:.2f} ms ({cost['trend'] / cost['level']:.2f}×); the networks on one "
        f"window, same run: {cost['networks']:.2f} ms"
    )
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
