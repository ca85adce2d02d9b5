"""Lit-light detection on the held-out labelled frames: seed 004's metrics beside their targets.

Prints, per test source and for the worst source, array (bulb) P/R at IoU 0.5, vehicle P/R, mAP50,
mAP50:95 and ms/frame for these detectors:

* ``colour`` — the rule-based finder (``LIGHT_DETECTORS["colour"]``, the baseline);
* ``cnn+att`` — the shipped learned detector with seed 004's colour-attention block
  (``src/makeway/models/lights_det.onnx``: YOLOX-nano's pretrained early stages, fine-tuned);
* ``cnn-att`` — the same network trained by the same command with ``--no-attention`` (the ablation:
  the block's gain). Read from ``benchmarks/out/lights_det_no_attention.onnx``; trained there first
  (``makeway lights-train … --no-attention``, about 40 min on a shared 2-core machine) when missing
  and torch is installed;
* ``small+att`` — the earlier from-scratch network (``--arch small``), when
  ``benchmarks/out/lights_det_small.onnx`` exists (``git show 16d5812:src/makeway/models/lights_det.onnx``);
* ``verified`` — rule proposals scored by the learned verifier (``LIGHT_DETECTORS["verified"]``,
  ``src/makeway/models/lights_verifier.onnx``; ``makeway lights-train --verifier``). The shipped
  verifier reads each proposal's vehicle context, so its ms/frame include its own YOLOX-nano pass
  (as in ``makeway lights``; ``makeway detect`` hands over the boxes it already has).
  ``--compare-verifier OLD.onnx`` scores another verifier beside it in the same run (with or
  without the context columns: the model's metadata says which).

Test split (by source clip, :mod:`makeway.train.light_split`): ``night_ambulance_lights``,
``highway_cam_no_ev`` and the held-out ``ambulance_yolo`` images once labelled. Every labelled colour
counts (colour set ``all``). Anchors: array P ≥ 0.90 / R ≥ 0.88, vehicle P ≥ 0.95 / R ≥ 0.94 (issue 23);
seed 004 with attention on ABLDataset: P 88.8 / R 86.4 (array).

With ``--colours all,eu`` (the default) two tables: every labelled colour counts, and seed 004's
setting (``eu``: only blue and bluish-white lamps are ground truth, and detectors return only those
colours; seed 004 detects blue lights only). ``--breakdown`` adds where the false positives come from
(colour, size, near miss / on a labelled lamp / near the EV / elsewhere / negative frame).

    PYTHONPATH=src python benchmarks/bench_lights.py [--json out.json] [--threads 1] [--breakdown]
        [--colours all,eu] [--detectors colour,verified] [--compare-verifier OTHER.onnx]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from makeway.eval.lights import false_positive_breakdown, run_detector, summarise
from makeway.paths import data_dir
from makeway.perceive.vision.light_cnn import default_lights_model
from makeway.perceive.vision.light_verify import DEFAULT_VERIFIER_MODEL
from makeway.perceive.vision.lights import COLOUR_SETS, LIGHT_DETECTORS
from makeway.train.light_split import load_split

ROOT = Path(__file__).resolve().parents[1]
ABLATION = ROOT / "benchmarks" / "out" / "lights_det_no_attention.onnx"
SMALL = ROOT / "benchmarks" / "out" / "lights_det_small.onnx"
TARGETS = {"array_precision": 0.90, "array_recall": 0.88, "vehicle_precision": 0.95, "vehicle_recall": 0.94}
SEED004 = {"array_precision": 0.888, "array_recall": 0.864}


def _fmt(v: Any, pct: bool = True) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "   —  "
    return f"{100 * v:5.1f}%" if pct else f"{v:6.1f}"


def _ensure_ablation(path: Path) -> bool:
    if path.is_file():
        return True
    try:
        import torch  # noqa: F401
    except ImportError:
        print(f"(no {path} and no torch: the ablation row is skipped)")
        return False
    from makeway.apps.lights_train import train_lights

    path.parent.mkdir(parents=True, exist_ok=True)
    print(f"training the ablation (no colour attention) into {path} …", flush=True)
    train_lights(path, attention=False, threads=1, min_val_tp=1)  # the shipped model's recipe
    return True


def _gt_for(frame: Any, colours: tuple[str, ...]) -> tuple[Any, list[int]]:
    """The frame's ground-truth boxes and vehicle ids of the lamps whose colour counts."""
    keep = [i for i, c in enumerate(frame.colours) if c in colours]
    return frame.boxes[keep].reshape(-1, 4), [frame.vehicles[i] for i in keep]


def _table(report: dict[str, Any], title: str) -> None:
    sources = [s for s in next(iter(report["detectors"].values())) if s not in ("all", "worst")]
    print(f"\n{title}")
    head = (
        f"{'source':26s} {'detector':11s} {'arrP':>6s} {'arrR':>6s} {'vehP':>6s} {'vehR':>6s} "
        f"{'mAP50':>6s} {'mAP50:95':>8s} {'ms/fr':>6s}  frames/boxes/dets/FP-frames"
    )
    print(head)
    print("-" * len(head))
    for src in [*sources, "all", "worst"]:
        for name, summ in report["detectors"].items():
            m = summ[src]
            extra = (
                f"  {m['frames']}/{m['gt_boxes']}/{m['detections']}/{m['fp_frames']}"
                if src != "worst"
                else "  ("
                + ", ".join(f"{k}:{v}" for k, v in m["worst_source"].items() if k.startswith("array"))
                + ")"
            )
            print(
                f"{src:26s} {name:11s} {_fmt(m['array_precision'])} {_fmt(m['array_recall'])} "
                f"{_fmt(m['vehicle_precision'])} {_fmt(m['vehicle_recall'])} {_fmt(m['map50'])} "
                f"{_fmt(m['map50_95']):>8s} {_fmt(m['ms_mean'], pct=False)}{extra}"
            )
    print(
        "anchor (targets, worst source):   arrP ≥ 90.0%  arrR ≥ 88.0%  vehP ≥ 95.0%  vehR ≥ 94.0%   "
        "(seed 004 CA RT-DETR on ABLDataset, blue lamps: arrP 88.8% arrR 86.4%)"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, default=None, help="also write the figures as JSON")
    ap.add_argument("--threads", type=int, default=1, help="ONNX Runtime threads (default 1)")
    ap.add_argument("--model", type=Path, default=default_lights_model(), help="the attention model")
    ap.add_argument("--ablation", type=Path, default=ABLATION, help="the no-attention model")
    ap.add_argument(
        "--small", type=Path, default=SMALL, help="the earlier small model (row skipped if absent)"
    )
    ap.add_argument("--verifier", type=Path, default=DEFAULT_VERIFIER_MODEL, help="the verifier model")
    ap.add_argument(
        "--compare-verifier",
        type=Path,
        action="append",
        default=[],
        help="another verifier model scored beside the shipped one (row named by its file stem)",
    )
    ap.add_argument("--split", default="test", choices=["test", "val"], help="which split to score")
    ap.add_argument(
        "--colours",
        default="all,eu",
        help="comma-separated colour sets, one table each: 'all' (every labelled colour counts) and "
        "'eu' (seed 004's setting: blue and bluish-white lamps are the ground truth and the only "
        "colours detected)",
    )
    ap.add_argument(
        "--detectors",
        default="colour,cnn+att,cnn-att,small+att,verified",
        help="comma-separated rows to run (default: all available)",
    )
    ap.add_argument(
        "--breakdown",
        action="store_true",
        help="also print where each detector's false positives come from (per source)",
    )
    ap.add_argument(
        "--map-threshold",
        type=float,
        default=0.05,
        help="CNN peaks kept for mAP (P/R use the model's threshold)",
    )
    args = ap.parse_args(argv)
    root = data_dir()
    if root is None:
        print("shared data not found (set MAKEWAY_DATA)", file=sys.stderr)
        return 2
    sets = [c.strip() for c in args.colours.split(",") if c.strip()]
    for c in sets:
        if c not in COLOUR_SETS:
            print(f"unknown colour set {c!r}; choose from {', '.join(COLOUR_SETS)}", file=sys.stderr)
            return 2
    wanted = {d.strip() for d in args.detectors.split(",") if d.strip()}
    frames, _ = load_split(args.split, root, input_size=None)
    models: dict[str, Path] = {}
    if "cnn+att" in wanted:
        models["cnn+att"] = args.model
    if "cnn-att" in wanted and _ensure_ablation(args.ablation):
        models["cnn-att"] = args.ablation
    if "small+att" in wanted and args.small.is_file():
        models["small+att"] = args.small
    verifiers: dict[str, Path] = {}
    if "verified" in wanted:
        if args.verifier.is_file():
            verifiers["verified"] = args.verifier
        else:
            print(f"(no {args.verifier}: the verified row is skipped)")
    for path in args.compare_verifier:
        verifiers[path.stem[:11]] = path
    full: dict[str, Any] = {"split": args.split, "frames": len(frames), "colour_sets": {}}
    for cset in sets:
        colours = COLOUR_SETS[cset]
        items = [(f.source, f.key, f.image, *_gt_for(f, colours)) for f in frames]
        detectors: dict[str, Any] = {}
        operating: dict[str, float] = {}
        if "colour" in wanted:
            detectors["colour"] = LIGHT_DETECTORS["colour"](colours=cset)
            operating["colour"] = 0.0
        for name, path in models.items():
            # run at a low threshold so mAP sees the ranking; P/R count the model's operating threshold
            probe = LIGHT_DETECTORS["cnn"](colours=cset, model=path, num_threads=args.threads)
            operating[name] = probe.threshold
            detectors[name] = LIGHT_DETECTORS["cnn"](
                colours=cset, model=path, num_threads=args.threads, threshold=args.map_threshold
            )
        for name, path in verifiers.items():
            probe_v = LIGHT_DETECTORS["verified"](colours=cset, model=path, num_threads=args.threads)
            operating[name] = probe_v.threshold
            detectors[name] = LIGHT_DETECTORS["verified"](
                colours=cset,
                model=path,
                num_threads=args.threads,
                threshold=min(args.map_threshold, probe_v.threshold),
            )
        report: dict[str, Any] = {"colours": list(colours), "thresholds": operating, "detectors": {}}
        breakdowns: dict[str, dict[str, Any]] = {}
        for name, det in detectors.items():
            results = run_detector(det, items)
            report["detectors"][name] = summarise(results, score_threshold=operating[name])
            if args.breakdown:
                breakdowns[name] = {
                    src: false_positive_breakdown(
                        [r for r in results if r.source == src], score_threshold=operating[name]
                    )
                    for src in sorted({r.source for r in results})
                }
        if breakdowns:
            report["false_positives"] = breakdowns
        n_gt = sum(len(it[3]) for it in items)
        _table(
            report,
            f"lit-light detection, {args.split} split ({len(items)} frames, {n_gt} boxes; colour set "
            f"{cset!r}: ground truth and detections {'/'.join(colours)}; IoU 0.5; ONNX Runtime "
            f"{args.threads} thread(s); P/R at score ≥ "
            + ", ".join(f"{k} {v:.2f}" for k, v in operating.items())
            + ")",
        )
        for name, per_src in breakdowns.items():
            for src, bd in per_src.items():
                print(
                    f"false positives of {name} on {src}: "
                    + "; ".join(
                        f"{cat} " + ", ".join(f"{k} {v}" for k, v in sorted(d.items(), key=lambda kv: -kv[1]))
                        for cat, d in bd.items()
                        if d
                    )
                    if any(bd.values())
                    else f"false positives of {name} on {src}: none"
                )
        if "cnn+att" in report["detectors"] and "cnn-att" in report["detectors"]:
            a, b = report["detectors"]["cnn+att"]["all"], report["detectors"]["cnn-att"]["all"]
            gains = {
                k: (a[k] - b[k]) if a[k] is not None and b[k] is not None else None
                for k in ("array_precision", "array_recall", "map50", "map50_95")
            }
            report["attention_gain_all"] = gains
            print(
                "colour-attention gain (all test frames, with − without): "
                + ", ".join(f"{k} {'—' if v is None else f'{100 * v:+.1f} pts'}" for k, v in gains.items())
            )
        for name, summ in report["detectors"].items():
            w = summ["worst"]
            met = [k for k, t in TARGETS.items() if w.get(k) is not None and w[k] >= t]
            print(
                f"{name} ({cset}): worst-source targets met: {', '.join(met) if met else 'none'} "
                f"of {', '.join(TARGETS)}"
            )
        full["colour_sets"][cset] = report
    if args.json is not None:
        args.json.write_text(json.dumps(full, allow_nan=False, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
