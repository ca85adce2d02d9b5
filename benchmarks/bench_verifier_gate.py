"""Routing lit-light proposals by size between the main verifier and a small-lamp verifier: grouped
cross-validation on the training frames as recorded, and the validation clip, per size gate (how
the shipped 6 px gate of ``lights_verifier_small.onnx`` was chosen; docs/model_card_lights.md, "A
small-lamp verifier").

Both verifiers are fitted as ``makeway lights-train --verifier`` fits them (three boosters, the same
ignored columns, appearance axes fitted on their own training rows): the main one on the recorded
training frames, the small-lamp one on those frames and their copies shrunk by ``--scales``. Each
gets out-of-fold scores from the same grouped folds (clips and photos whole). For each gate, a
proposal whose longer side is under the gate takes the small-lamp verifier's score, any other the
main verifier's; the operating threshold is chosen as for one verifier (max min(P, R) over the
out-of-fold training frames pooled with validation). Printed per gate: the threshold, the
cross-validated min(P, R) and AP50 over the recorded training frames, and validation's array P / R,
vehicle R and AP50. Gate 0 is the main verifier alone (it reproduces the shipped main model's
figures), a gate of 1000 px the small-lamp verifier for every proposal.

    .venv/bin/python benchmarks/bench_verifier_gate.py [--scales 1,0.5,0.35,0.25] [--gates 0,4,5,6,8,10,1000]
        [--json out.json]

About 8 minutes on 2 cores (the proposals of 2,096 training frames and their features, then 24
boosters).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from makeway.eval.lights import metrics, summarise
from makeway.paths import data_dir
from makeway.perceive.vision.light_verify import (
    CONTEXT_FEATURE_NAMES,
    FEATURE_NAMES,
    ProposalAppearance,
    vehicle_detector,
)
from makeway.train.light_verifier import (
    CV_FOLDS,
    IGNORED_CONTEXT_FEATURES,
    IGNORED_FEATURES,
    THRESHOLDS,
    choose_threshold,
    detector_results,
    fit_verifier,
    out_of_fold,
    verifier_rows,
)

SEEDS = (0, 1, 2)


def _subset(rows: dict[str, Any], keep_frames: np.ndarray) -> dict[str, Any]:
    """The rows of the frames ``keep_frames`` (bool per frame), frames renumbered."""
    idx = np.flatnonzero(keep_frames)
    remap = np.full(len(keep_frames), -1)
    remap[idx] = np.arange(len(idx))
    keep = keep_frames[rows["origin"]]
    frame = np.asarray(rows["frame"])
    new_frame = np.where(frame >= 0, remap[np.maximum(frame, 0)], -1)
    return {
        "x": rows["x"][keep],
        "y": rows["y"][keep],
        "frame": new_frame[keep],
        "origin": remap[rows["origin"][keep]],
        "frames": [rows["frames"][i] for i in idx],
        "boxes": [rows["boxes"][i] for i in idx],
        "colours": [rows["colours"][i] for i in idx],
    }


def _sides(rows: dict[str, Any]) -> np.ndarray:
    """The longer side (px) of each row's proposal (the extra label positives, which never enter an
    evaluation, get a large value)."""
    frame = np.asarray(rows["frame"])
    out = np.full(len(frame), 1e9)
    for k, boxes in enumerate(rows["boxes"]):
        sel = np.flatnonzero(frame == k)
        b = boxes.reshape(-1, 4)
        out[sel] = np.maximum(b[:, 2] - b[:, 0], b[:, 3] - b[:, 1])
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scales", default="1,0.5,0.35,0.25", help="the small-lamp verifier's training shrinks")
    ap.add_argument("--gates", default="0,4,5,6,8,10,1000", help="size gates (px) to score")
    ap.add_argument("--json", type=Path, default=None, help="also write the table as JSON")
    args = ap.parse_args(argv)
    root = data_dir()
    if root is None:
        print("shared data not found (set MAKEWAY_DATA)", file=sys.stderr)
        return 2
    scales = tuple(float(v) for v in args.scales.split(","))
    gates = [float(v) for v in args.gates.split(",")]
    t0 = time.perf_counter()
    vehicles = vehicle_detector(num_threads=1).detect_arrays
    raw = ProposalAppearance(n_components=8)
    train = verifier_rows(
        "train", root, label_positives=True, vehicles=vehicles, extra_features=raw.vectors, scales=scales
    )
    val = verifier_rows("val", root, vehicles=vehicles, extra_features=raw.vectors)
    print(
        f"rows: {len(train['y'])} train, {len(val['y'])} validation ({time.perf_counter() - t0:.0f} s)",
        flush=True,
    )
    width = len(FEATURE_NAMES + CONTEXT_FEATURE_NAMES)
    ignored = IGNORED_FEATURES + IGNORED_CONTEXT_FEATURES
    recorded = np.array(["@" not in key for _, key, _, _ in train["frames"]])
    fitted: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for name in ("main", "small"):
        fit_rows = recorded[train["origin"]] if name == "main" else np.ones(len(train["y"]), bool)
        app = ProposalAppearance(n_components=8)
        app.fit(train["x"][fit_rows, width:], seed=0)

        def project(rows: dict[str, Any], app: ProposalAppearance = app) -> dict[str, Any]:
            return {
                **rows,
                "x": np.concatenate([rows["x"][:, :width], app.project(rows["x"][:, width:])], axis=1),
            }

        tr, va = project(train), project(val)
        rows = _subset(tr, recorded) if name == "main" else tr
        oof = np.mean([out_of_fold(rows, CV_FOLDS, seed=s, ignored=ignored) for s in SEEDS], axis=0)
        clf = [fit_verifier(rows["x"], rows["y"], seed=s, ignored=ignored) for s in SEEDS]
        pval = np.mean([c.predict_proba(va["x"])[:, 1] for c in clf], axis=0)
        if name == "small":  # its out-of-fold scores on the recorded frames' rows only
            oof = oof[recorded[train["origin"]]]
        fitted[name] = (oof, pval)
        print(
            f"{name} verifier: out-of-fold scores and validation ({time.perf_counter() - t0:.0f} s)",
            flush=True,
        )
    rec = _subset(train, recorded)
    side_tr, side_va = _sides(rec), _sides(val)
    table = []
    print(
        f"\n{'gate px':>7s} {'thr':>5s} {'CV minPR':>9s} {'CV AP50':>8s} {'val P':>6s} {'val R':>6s} "
        f"{'val vehR':>8s} {'val AP50':>8s}"
    )
    for gate in gates:
        p_tr = np.where(side_tr < gate, fitted["small"][0], fitted["main"][0])
        p_va = np.where(side_va < gate, fitted["small"][1], fitted["main"][1])
        thr, _ = choose_threshold(
            lambda t, a=p_tr, b=p_va: detector_results(rec, a, t) + detector_results(val, b, t)
        )
        cv = summarise(detector_results(rec, p_tr, thr))["all"]
        va = summarise(detector_results(val, p_va, thr))["all"]
        row = {
            "gate_px": gate,
            "threshold": thr,
            "cv_min_pr": min(cv["array_precision"], cv["array_recall"]),
            "cv_ap50": metrics(detector_results(rec, p_tr, THRESHOLDS[0])).map50,
            "val_precision": va["array_precision"],
            "val_recall": va["array_recall"],
            "val_vehicle_recall": va["vehicle_recall"],
            "val_ap50": metrics(detector_results(val, p_va, THRESHOLDS[0])).map50,
        }
        table.append(row)
        print(
            f"{gate:7g} {thr:5.2f} {row['cv_min_pr']:9.3f} {row['cv_ap50']:8.3f} {row['val_precision']:6.3f} "
            f"{row['val_recall']:6.3f} {row['val_vehicle_recall']:8.3f} {row['val_ap50']:8.3f}",
            flush=True,
        )
    print(
        "anchor: gate 0 = the main verifier alone (shipped lights_verifier.onnx: "
        "CV min(P, R) 0.325, AP50 0.253)"
    )
    if args.json is not None:
        args.json.write_text(json.dumps({"scales": list(scales), "gates": table}, indent=1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
