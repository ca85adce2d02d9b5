"""EV detection on images: Framework B (vehicle detector + crop classifier per box) on the committed
held-out split of ``ambulance_yolo/valid``, beside seed 001's detector (issue 24, items 4 and 3).

For each crop classifier (default: ``default`` and ``fast``) it runs
:func:`makeway.apps.evaluate_detector.evaluate_detector` on the validation part and on the held-out
part (``src/makeway/data/ambulance_yolo_held_out.txt``) and prints, per part and per ranking score
(``product`` = detector score × P(EV), ``classifier`` = P(EV)): mAP50, mAP50:95, and precision /
recall at the classifier's own threshold (IoU ≥ 0.5 against the class-0 boxes), beside the
vehicle detector alone (every vehicle box called an EV, ranked by its detector score: the anchor,
and the recall ceiling of Framework B) and seed 001's figures (mAP50 0.85 target, P 0.949,
R 0.821). The ranking score is chosen on the validation part; the held-out part is reported, not
tuned on. ``ms/image`` is detector + crops + classifier wall
time on ``--threads`` ONNX Runtime threads.

Framework A (the one-stage EV detector ``ev_det_yolox.onnx``, ``--framework a``) is scored on the
held-out part only (its "validation" part would be its own training images): boxes ranked by
``ev_score``, P and R at the threshold stored in the model. ``--no-framework-a`` skips it.

Caveat printed with the table: the ``fast`` CNN was distilled (on the default head's soft labels,
not on the boxes' labels) from crops of every ``ambulance_yolo/valid`` image, held-out ones
included; the ``default`` head never saw ``ambulance_yolo``.

``--labels original`` scores against the export's class-0 boxes as they are; the default
``corrected`` applies the audited corrections (``makeway.sense.label_corrections``).

    .venv/bin/python benchmarks/bench_evaluate_detector.py [--classifier default --classifier fast]
        [--threads 2] [--json] [--labels corrected|original]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any

from makeway.apps.evaluate_detector import BoxJudgements, evaluate_detector, score_judgements
from makeway.eval.detection import detection_metrics, precision_recall
from makeway.paths import data_dir

SEED_001 = {"map50": 0.85, "precision": 0.949, "recall": 0.821}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--classifier", action="append", help="crop classifier(s) (default: default, fast)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--json", action="store_true", help="also print every row as a JSON line")
    parser.add_argument("--no-framework-a", action="store_true", help="skip the one-stage EV detector")
    parser.add_argument("--model-a", default=None, help="Framework A's model file (default: the shipped one)")
    parser.add_argument(
        "--labels",
        default="corrected",
        choices=["corrected", "original"],
        help="ground truth: the audited corrections applied (default) or the export's boxes as they are",
    )
    args = parser.parse_args(argv)
    base = data_dir()
    if base is None:
        print("shared data folder not found; set MAKEWAY_DATA", file=sys.stderr)
        return 2
    data = base / "vision" / "ambulance_yolo" / "valid"
    print(
        f"load average (1 min): {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; threads {args.threads}; "
        f"{args.labels} labels"
    )
    header = (
        f"{'classifier':<10} {'part':<10} {'score':<10} {'images':>6} {'boxes':>5} {'mAP50':>6} "
        f"{'mAP50:95':>8} {'P':>6} {'R':>6} {'ms/image':>8}"
    )
    print(header)
    print(
        f"{'seed 001':<10} {'':<10} {'':<10} {'':>6} {'':>5} {SEED_001['map50']:>6.3f} {'':>8} "
        f"{SEED_001['precision']:>6.3f} {SEED_001['recall']:>6.3f} {'':>8}"
    )
    rows: list[dict[str, Any]] = []
    for clf in args.classifier or ["default", "fast"]:
        for split in ("validation", "held_out"):
            judged: list[BoxJudgements] = []
            run = evaluate_detector(
                data, classifier=clf, split=split, threads=args.threads, judgements=judged, labels=args.labels
            )
            if not any(r["split"] == split and r["score"] == "detector" for r in rows):
                boxes, det, gt = ([getattr(j, k) for j in judged] for k in ("boxes", "det_scores", "gt"))
                m = detection_metrics(boxes, det, gt)
                p, r, *_ = precision_recall(boxes, det, gt)
                anchor = {"split": split, "score": "detector", "map50": m.map50, "map50_95": m.map50_95}
                rows.append({**anchor, "precision": p, "recall": r, "classifier": "none"})
                print(
                    f"{'none':<10} {split:<10} {'detector':<10} {m.n_images:>6} {m.n_boxes:>5} "
                    f"{m.map50:>6.3f} {m.map50_95:>8.3f} {p:>6.3f} {r:>6.3f} {'':>8}"
                )
            for score in ("product", "classifier"):
                row = {**run, **score_judgements(judged, run["threshold"], score)}
                rows.append(row)
                print(
                    f"{clf:<10} {split:<10} {score:<10} {row['n_images']:>6} {row['n_boxes']:>5} "
                    f"{row['map50']:>6.3f} {row['map50_95']:>8.3f} {row['precision']:>6.3f} "
                    f"{row['recall']:>6.3f} {row['ms_per_image']:>8.1f}"
                )
    if not args.no_framework_a:
        row = evaluate_detector(
            data,
            framework="a",
            split="held_out",
            threads=args.threads,
            model=args.model_a,
            labels=args.labels,
        )
        rows.append(row)
        print(
            f"{'A':<10} {'held_out':<10} {'ev_score':<10} {row['n_images']:>6} {row['n_boxes']:>5} "
            f"{row['map50']:>6.3f} {row['map50_95']:>8.3f} {row['precision']:>6.3f} "
            f"{row['recall']:>6.3f} {row['ms_per_image']:>8.1f}"
        )
    print(
        "'A': Framework A, one detector with the classes EV / other vehicle (P and R at its stored "
        "threshold on ev_score)."
    )
    print(
        "'none' / 'detector': every vehicle box called an EV, ranked by the detector's score (the anchor: "
        "its R is the ceiling of the classifier rows)."
    )
    print(
        "P and R at the classifier's own threshold (the same for both scores); the fast CNN was distilled "
        "on crops of every ambulance_yolo/valid image (held-out ones too), the default head never saw them."
    )
    if args.json:
        for row in rows:
            print(json.dumps(row))
    return 0


if __name__ == "__main__":
    sys.exit(main())
