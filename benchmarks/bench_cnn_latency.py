"""EV crop CNN: ONNX Runtime latency for 100 crops in one batch, and held-out accuracy (issue 3, SPEC §1).

Loads an exported crop CNN (:class:`~makeway.perceive.vision.cnn_classifier.OnnxCropClassifier`),
takes 100 real crops of the committed ev_crops holdout as one batch and times ``session.run`` on
it with ONNX Runtime on ``--threads`` (default 2) intra-op threads: the median (and the fastest) of
``--repeats`` runs after warm-up, printed beside the target (≤ 10 ms per 100 crops on 2 cores). It
also times the whole ``predict_proba`` on uint8 crops already at the input size, as the video
pipeline cuts them (channel swap, normalisation, run). Then it scores the 250 held-out
crops and prints accuracy / F1 / max-F1 / P@R0.8 beside the target (≥ 0.97 / ≥ 0.96) and beside
the shipped detector-features + logistic-regression head, scored and timed end to end (its
feature extraction is its cost) in the same run.

    .venv/bin/python benchmarks/bench_cnn_latency.py [MODEL.onnx ...] [--threads 2] [--repeats 50]

The machine's 1-minute load average is printed first: other processes on the same cores inflate
the times.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from makeway.eval.classification import precision_recall_f1, threshold_metrics
from makeway.paths import data_dir
from makeway.perceive.vision.cnn_classifier import OnnxCropClassifier
from makeway.perceive.vision.ev_classifier import (
    DEFAULT_MODEL,
    FAST_MODEL,
    FASTEST_MODEL,
    EVCropClassifier,
    load_crop_classifier,
)
from makeway.sense.crops import EV_CROPS_HOLDOUT, holdout_split, read_crop_folder, read_holdout

TARGET_MS = 10.0
TARGET_ACCURACY, TARGET_F1 = 0.97, 0.96
DEFAULT_CNNS = (FAST_MODEL, FASTEST_MODEL)  # the shipped small CNNs: --classifier fast, fastest


def _metrics(probs: np.ndarray, labels: np.ndarray, threshold: float) -> dict[str, float]:
    y = labels.astype(bool)
    pred = probs >= threshold
    prf = precision_recall_f1(int(np.sum(pred & y)), int(np.sum(pred & ~y)), int(np.sum(~pred & y)))
    thr = threshold_metrics(probs, y, recall_at=0.8)
    return {
        "accuracy": float(np.mean(pred == y)),
        "f1": float(prf["f1"]),
        "max_f1": thr["max_f1"],
        "p_at_r80": thr["precision_at_recall_0.8"],
    }


def _times_ms(fn: Any, repeats: int) -> tuple[float, float]:
    """(median, fastest) milliseconds over ``repeats`` calls after 3 warm-up calls."""
    for _ in range(3):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times), min(times)


def main() -> int:
    shipped = ", ".join(p.name for p in DEFAULT_CNNS)
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "models",
        nargs="*",
        type=Path,
        help=f"ONNX crop CNNs or fine-tuned EfficientNet-Lite0 .npz deltas (default: the shipped {shipped})",
    )
    ap.add_argument("--threads", type=int, default=2, help="ONNX Runtime intra-op threads")
    ap.add_argument("--repeats", type=int, default=50, help="timed runs per model (median reported)")
    ap.add_argument("--batch", type=int, default=100, help="crops per batch")
    ap.add_argument("--no-head", action="store_true", help="skip scoring the shipped logistic head")
    args = ap.parse_args()

    root = data_dir()
    if root is None:
        print("error: shared data not found (set MAKEWAY_DATA)", file=sys.stderr)
        return 2
    models = args.models or list(DEFAULT_CNNS)
    missing = [m for m in models if not m.is_file()]
    if missing:
        print(
            f"error: {', '.join(map(str, missing))} not found; train one with e.g. `makeway classify train "
            "--arch small_cnn --data <data>/vision/ev_crops --input-size 64 --width 16 --epochs 20 --lr 1e-3 "
            "--min-lr 6.25e-5 --patience 2 --out ev_cnn.onnx` and pass its path",
            file=sys.stderr,
        )
        return 2
    crops = read_crop_folder(root / "vision" / "ev_crops")
    _, test_idx = holdout_split(crops, read_holdout(EV_CROPS_HOLDOUT))
    held = crops.subset(test_idx)
    images = held.load_images(224)
    batch = images[np.arange(args.batch) % len(images)]
    print(
        f"load average (1 min): {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs; {args.threads} ORT threads"
    )
    print(f"held-out: {len(held)} crops of ev_crops ({held.n_positive} positive); batch {args.batch} crops")
    print()
    header = (
        f"{'model':<28} {'input':>5} {'size kB':>8} {'run ms/100':>10} {'fastest':>8} {'e2e ms/100':>10} "
        f"{'accuracy':>8} {'F1':>6} {'max-F1':>6} {'P@R0.8':>6}"
    )
    print(header)
    print("-" * len(header))
    for path in models:
        clf = load_crop_classifier(path, num_threads=args.threads)
        assert isinstance(clf, OnnxCropClassifier)
        x = clf.preprocess(batch)
        # the pipeline cuts crops straight to the input size (crops_for_tracks), so e2e starts there
        small = held.load_images(clf.input_size)[np.arange(args.batch) % len(held)]
        run_ms, best_ms = _times_ms(lambda clf=clf, x=x: clf.run(x), args.repeats)
        e2e_ms, _ = _times_ms(lambda clf=clf, small=small: clf.predict_proba(small), args.repeats)
        m = _metrics(clf.predict_proba(images), held.labels, clf.threshold)
        scale = 100.0 / args.batch
        print(
            f"{path.name:<28} {clf.input_size:>5} {path.stat().st_size / 1e3:>8.0f} {run_ms * scale:>10.2f} "
            f"{best_ms * scale:>8.2f} {e2e_ms * scale:>10.2f} {m['accuracy']:>8.3f} {m['f1']:>6.3f} "
            f"{m['max_f1']:>6.3f} {m['p_at_r80']:>6.3f}"
        )
    if not args.no_head:
        head = EVCropClassifier.load(DEFAULT_MODEL, num_threads=args.threads)
        m = _metrics(head.predict_proba(held.load_images(head.input_size)), held.labels, head.threshold)
        # the head's cost is its feature extraction (crop and mirror image): e2e only
        small = held.load_images(head.input_size)[np.arange(args.batch) % len(held)]
        e2e_ms, _ = _times_ms(lambda: head.predict_proba(small), max(3, args.repeats // 10))
        print(
            f"{'shipped head (logreg)':<28} {head.input_size:>5} {DEFAULT_MODEL.stat().st_size / 1e3:>8.0f} "
            f"{'':>10} {'':>8} {e2e_ms * 100.0 / args.batch:>10.2f} {m['accuracy']:>8.3f} {m['f1']:>6.3f} "
            f"{m['max_f1']:>6.3f} {m['p_at_r80']:>6.3f}"
        )
    print(
        f"{'target':<28} {'':>5} {'':>8} {'≤ ' + format(TARGET_MS, 'g'):>10} {'':>8} {'':>10} "
        f"{'≥ ' + format(TARGET_ACCURACY, 'g'):>8} {'≥ ' + format(TARGET_F1, 'g'):>6}"
    )
    print(
        "\nrun = median of session.run on the preprocessed batch (fastest: its best run); "
        "e2e = median of predict_proba on uint8 BGR crops at the input size, as the pipeline cuts "
        "them (BGR→RGB, normalise, run)."
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
