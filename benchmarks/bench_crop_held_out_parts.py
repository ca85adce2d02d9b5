"""Shipped EV crop classifiers on the committed held-out part of every source (issue 24).

The cross-source protocol (``makeway classify cross-source``, ``bench_cross_source_seeds.py``)
judges a *recipe*: trained without a source, scored on all of it. A shipped model trained on every
source can only be judged on what its training left out: the committed held-out parts —
``ev_crops``' holdout (``src/makeway/data/ev_crops_holdout.txt``, 250 crops) and the crops of the
held-out ``ambulance_yolo`` photos (``src/makeway/data/ambulance_yolo_held_out.txt``, the images
the detector evaluation holds out; :func:`makeway.sense.crops.training_split`). ``road_clips`` has
no held-out part: it is scored whole and marked ``(in training)`` for the models that learnt from
it (``--trained-on-clips``).

Per model and source: accuracy, F1, recall and specificity at the model's own threshold, and the
worst held-out part, beside the anchor (the shipped ``default`` head, first model of the list).

    .venv/bin/python benchmarks/bench_crop_held_out_parts.py [--models default,general,imagenet]
        [--trained-on-clips general] [--threads 2] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

from makeway.apps.classify import CROSS_SOURCES, built_cross_sources
from makeway.atomic import check_writable
from makeway.errors import InputError
from makeway.eval.cross_source import predict_crop_set, score_crops
from makeway.paths import require_data_dir
from makeway.perceive.vision.ev_classifier import load_crop_classifier
from makeway.sense.crops import training_split

TARGET = 0.90


def _fmt(v: float | None) -> str:
    return "    —" if v is None else f"{v:5.3f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", default="default,general,imagenet", help="crop classifiers (names or files)")
    ap.add_argument(
        "--trained-on-clips",
        default="general",
        help="models that learnt from the road clips' crops (their road_clips row is marked in training)",
    )
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--data", type=Path, default=None, help="shared data folder (default ../shared/data)")
    ap.add_argument("--cache", type=Path, default=Path.home() / ".cache" / "makeway" / "cross_source")
    ap.add_argument("--json", type=Path, default=None, help="also write every figure here")
    args = ap.parse_args(argv)
    names = [m.strip() for m in args.models.split(",") if m.strip()]
    in_clips = {m.strip() for m in args.trained_on_clips.split(",") if m.strip()}
    try:
        data = require_data_dir(args.data)
        if args.json is not None:
            check_writable(args.json, folder=False)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        models = {name: load_crop_classifier(name, num_threads=args.threads) for name in names}
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"load average (1 min): {os.getloadavg()[0]:.1f}")
    sources = built_cross_sources(list(CROSS_SOURCES), data, args.cache, threads=args.threads, log=print)
    parts: dict[str, tuple[Any, str]] = {}
    for name, crops in sources.items():
        split = training_split(crops)
        if split is None:
            parts[name] = (crops, "whole")
        else:
            parts[name] = (crops.subset(split[1]), "held-out part")
        sub, what = parts[name]
        print(f"  {name}: {what}, {len(sub)} crops, {sub.n_positive} EVs")
    report: dict[str, Any] = {"models": {}, "sources": {k: v[1] for k, v in parts.items()}}
    print(f"\n{'model':10s} {'source':16s} {'crops':>6s} {'acc':>6s} {'F1':>6s} {'recall':>6s} {'spec':>6s}")
    for name, model in models.items():
        t0 = time.perf_counter()
        rows: dict[str, dict[str, Any]] = {}
        for source, (sub, _) in parts.items():
            score = score_crops(
                predict_crop_set(model, sub), sub.labels, model.threshold, model=name, source=source
            )
            in_training = source == "road_clips" and name in in_clips
            rows[source] = {**score.as_dict(), "in_training": in_training}
            note = " (in training)" if in_training else ""
            print(
                f"{name:10s} {source:16s} {score.n:6d} {_fmt(score.accuracy)} {_fmt(score.f1)} "
                f"{_fmt(score.recall)} {_fmt(score.specificity)}{note}"
            )
        held = {s: r["accuracy"] for s, r in rows.items() if not r["in_training"]}
        worst = min(held, key=held.__getitem__)
        print(
            f"{name:10s} worst held-out part: {held[worst]:.3f} ({worst}); {time.perf_counter() - t0:.0f} s"
        )
        report["models"][name] = {"rows": rows, "worst": {"source": worst, "accuracy": held[worst]}}
    print(f"\ntarget (issue 24, for the cross-source protocol): worst held-out source ≥ {TARGET:.2f}")
    print(f"anchor: {names[0]}, same parts, same run")
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
