"""How the siren listener should smooth its decision over windows (issue 4): the rule's selection.

    .venv/bin/python benchmarks/bench_audio_smoothing.py [--data DIR ... | --n 30 --seeds 77,78]
        [--model FILE] [--max-false-alarm 0.01] [--json FILE]

A live listener (``makeway audio listen``) decides on a causal mean of the last K windows' siren
probabilities. This benchmark scores the candidate rules on **validation** recordings — made of
training-split ingredients (``makeway audio simulate --split train``) but never trained on — so
that the rule is chosen before any held-out set is looked at:

* each window alone (seed 002's decision, the anchor);
* the mean of the probabilities of K windows (K = 2–6; 3 was the listener's rule until the
  twelfth session);
* the mean of the logits of K windows (K = 2–12; :class:`~makeway.perceive.audio.windows.StreamSmoother`).

For every rule it prints, in 10–50 m, the recall and the false alarms per window at the model's
stored threshold, and the recall with the threshold set for ≤ ``--max-false-alarm`` false alarms
on these windows. The rule picked is the one with the highest recall whose false alarms at the
stored threshold are within the target; the listener's default
(:data:`~makeway.perceive.audio.windows.LISTEN_SMOOTH`) was picked this way on 560 recordings
(``--data`` with seeds 301–306 and 77–78, see docs/journal.md, twelfth session) and checked
against the real mono material (``bench_audio_real.py --smooth K``).

Without ``--data`` it simulates ``--n`` recordings per seed of ``--seeds`` (training-split
ingredients) into a temporary folder.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from makeway.eval.siren import RANGE_10_50, calibrate_threshold, model_estimator
from makeway.eval.siren_labels import label_recording
from makeway.perceive.audio.features import window_batch
from makeway.perceive.audio.siren_model import DEFAULT_SIREN_MODEL, SirenModel
from makeway.perceive.audio.windows import LISTEN_SMOOTH, SMOOTH_AVERAGE, smoothed_probability
from makeway.progress import progress_bar
from makeway.sense.recording import read_recording
from makeway.sim.audio_scenarios import held_out_folders

RULES: list[tuple[str, int]] = (
    [("probability", 1)]
    + [("probability", k) for k in range(2, 7)]
    + [("logit", k) for k in (2, 3, 4, 5, 6, 8, 10, 12)]
)


def window_probabilities(
    model: SirenModel, folders: list[Path], progress: bool = True
) -> list[dict[str, Any]]:
    """Per recording: the detector's probability of every window, and the labels of the kept ones."""
    out = []
    estimate = model_estimator(model)
    with progress_bar("windows", len(folders), unit="rec", enabled=progress) as advance:
        for f in folders:
            rec = read_recording(f)
            labels = label_recording(rec)
            prob, _, _ = estimate(rec, window_batch(rec, labels))
            _, dist = labels.nearest()
            out.append({"prob": prob, "kept": labels.kept, "siren": labels.siren, "distance": dist})
            advance()
    return out


def score(
    recs: list[dict[str, Any]], average: str, k: int, threshold: float, max_fa: float
) -> dict[str, Any]:
    """Recall (10–50 m) and false alarms of one rule, at ``threshold`` and at the ≤ ``max_fa`` one."""
    p = np.concatenate([smoothed_probability(r["prob"], k, average)[r["kept"]] for r in recs])
    siren = np.concatenate([r["siren"][r["kept"]] for r in recs])
    dist = np.concatenate([r["distance"][r["kept"]] for r in recs])
    lo, hi = RANGE_10_50
    pos = siren & (dist >= lo) & (dist <= hi)
    t1 = calibrate_threshold(p, siren, max_fa)
    return {
        "average": average if k > 1 else None,
        "smooth": k,
        "recall": float(np.mean(p[pos] >= threshold)),
        "false_alarm_rate": float(np.mean(p[~siren] >= threshold)),
        "misses": int(np.sum(p[pos] < threshold)),
        "false_alarms": int(np.sum(p[~siren] >= threshold)),
        "threshold_at_max_fa": t1,
        "recall_at_max_fa": float(np.mean(p[pos] >= t1)),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--data", type=Path, action="append", default=None, help="folder of recordings (repeatable)"
    )
    ap.add_argument("--n", type=int, default=30, help="recordings per seed when simulating")
    ap.add_argument("--seeds", default="77,78", help="seeds to simulate (training-split ingredients)")
    ap.add_argument("--duration", type=float, default=8.0)
    ap.add_argument("--model", type=Path, default=DEFAULT_SIREN_MODEL)
    ap.add_argument("--max-false-alarm", type=float, default=0.01)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        seeds = [int(v) for v in args.seeds.split(",") if v.strip()]
        t0 = time.perf_counter()
        folders = held_out_folders(args.data, Path(tmp), args.n, seeds, args.duration, split="train")
        if args.data is None:
            print(
                f"simulated {len(folders)} validation recordings (training-split ingredients, seeds {seeds})"
            )
        model = SirenModel(args.model, threads=2, localizer=False, ranger=False)
        recs = window_probabilities(model, folders)
        print(f"{len(folders)} recordings, {time.perf_counter() - t0:.0f} s")

    thr, fa = model.threshold, args.max_false_alarm
    rows = [score(recs, average, k, thr, fa) for average, k in RULES]
    n_neg = int(sum((~r["siren"][r["kept"]]).sum() for r in recs))
    print(f"\n10–50 m; {n_neg} windows without a siren; stored threshold {thr:.3f}")
    print(
        f"{'rule':24s}{'recall':>10s}{'false al.':>11s}{'misses':>8s}{'f.a.':>6s}"
        f"{'   recall at ≤ ' + format(100 * fa, 'g') + ' % f.a. (t)':>32s}"
    )
    for r in rows:
        name = "each window" if r["smooth"] == 1 else f"{r['average']} mean of {r['smooth']}"
        mark = ""
        if r["smooth"] == LISTEN_SMOOTH and r["average"] == SMOOTH_AVERAGE:
            mark = "  ← listen default"
        elif r["smooth"] == 3 and r["average"] == "probability":
            mark = "  ← listen before (anchor)"
        print(
            f"{name:24s}{100 * r['recall']:9.2f} %{100 * r['false_alarm_rate']:9.2f} %{r['misses']:8d}"
            f"{r['false_alarms']:6d}{100 * r['recall_at_max_fa']:20.2f} %"
            f" ({r['threshold_at_max_fa']:.3f}){mark}"
        )
    within = [r for r in rows if r["false_alarm_rate"] <= fa]
    if within:
        best = max(within, key=lambda r: r["recall"])
        print(
            f"\nhighest recall with ≤ {100 * fa:g} % false alarms at the stored threshold: "
            f"{best['average'] or 'each window'} mean of {best['smooth']} ({100 * best['recall']:.2f} %)"
        )
    if args.json is not None:
        args.json.write_text(
            json.dumps({"recordings": len(folders), "negatives": n_neg, "rules": rows}, indent=1)
        )
    print(json.dumps({f"{r['average'] or 'window'}:{r['smooth']}": round(r["recall"], 5) for r in rows}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
