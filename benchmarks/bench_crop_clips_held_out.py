"""The ``general`` recipe on road video it never saw: leave one clip out (issue 24).

The shipped ``general`` crop classifier learnt from the crops of every labelled road clip, so its
per-actor figures on those clips are not held out. Here the same recipe (EfficientNet-Lite0
fine-tuned with quality matching, seed 0, 224 px, 3 epochs: ``docs/model_card_ev_general.md``) is
trained once per clip with an emergency vehicle, on ``ev_crops``' training part, the
``ambulance_yolo`` crops of the photos not held out, and the ``road_clips`` crops of every *other*
clip; Framework B (YOLOX-nano → SORT → the crop classifier → the track smoother: window 25, at
least 6 frames, T 0.5, the pipeline's defaults) then runs on the clip left out, beside the shipped
``default`` head on the same clip (the anchor: it never learnt from any clip). An actor (SORT track,
labelled by ``src/makeway/data/video_track_labels.csv``) is flagged when the smoother marks it EV on
at least one frame; every track counts, and again only those with the smoother's 6 judged frames.
Prints per clip and pooled: TP / FP / FN / TN, precision, recall, F1, and the
per-frame max-F1 over thresholds.

The crop sources come from ``makeway classify cross-source``'s cache (built on first use); each
trained delta and each clip recording is cached under ``--cache`` (about 3 min per training on two
idle cores, 1–3 min per clip recording).

    .venv/bin/python benchmarks/bench_crop_clips_held_out.py [--clips night_ambulance_lights,...]
        [--threads 2] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import sys
from pathlib import Path
from typing import Any

from makeway.apps.classify import built_cross_sources
from makeway.atomic import check_writable
from makeway.errors import InputError
from makeway.eval.actor_sweep import EV_CLIPS, TRACK_LABELS, ClipRecord, read_track_labels, sweep
from makeway.paths import require_data_dir
from makeway.perceive.vision.ev_classifier import DEFAULT_MODEL
from makeway.pipeline.clip_record import cached_clip

SMOOTHER_T = 0.5
#: Actor sets: every track, and the tracks the smoother can decide (at least its 6 frames).
MIN_JUDGED = (1, 6)


def _road_without(road: Path, clip: str, out: Path) -> Path:
    """A crop folder holding ``road``'s crops of every clip but ``clip`` (images linked, not copied)."""
    out.mkdir(parents=True, exist_ok=True)
    images = out / "images"
    if not images.exists():
        images.symlink_to((road / "images").resolve(), target_is_directory=True)
    with open(road / "labels.csv", newline="") as fh:
        rows = [r for r in csv.DictReader(fh) if r["group"].split("#", 1)[0] != clip]
    with open(out / "labels.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=["image", "emergency", "group"])
        writer.writeheader()
        writer.writerows(rows)
    return out


def _train(data: list[Path], out: Path, threads: int) -> Path:
    """The ``general`` recipe on ``data`` (reused when ``out`` exists)."""
    if out.is_file():
        return out
    from makeway.train.cnn import train_crop_cnn

    train_crop_cnn(
        data,
        out,
        arch="effnet_ft",
        input_size=224,
        epochs=3,
        lr=3e-4,
        patience=1,
        threads=threads,
        match_quality=True,
        seed=0,
        progress=False,
        log=print,
    )
    return out


def _actors(records: list[ClipRecord], labels: Any, min_judged: int) -> dict[str, Any]:
    rows, thr = sweep(records, labels, thresholds=(SMOOTHER_T,), min_judged=min_judged)
    row = next(r for r in rows if r.threshold == SMOOTHER_T)
    return {
        "tp": row.tp,
        "fp": row.fp,
        "fn": row.fn,
        "tn": row.tn,
        "precision": row.precision,
        "recall": row.recall,
        "f1": row.f1,
        "per_frame_max_f1": thr["max_f1"],
    }


def _line(name: str, m: dict[str, Any]) -> str:
    return (
        f"  {name:34s} {m['tp']:3d} {m['fp']:3d} {m['fn']:3d} {m['tn']:4d}  {m['precision']:5.3f} "
        f"{m['recall']:5.3f} {m['f1']:5.3f}   {m['per_frame_max_f1']:5.3f}"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--clips", default=",".join(EV_CLIPS), help="clips to leave out in turn (comma list)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--data", type=Path, default=None, help="shared data folder (default ../shared/data)")
    ap.add_argument("--sources", type=Path, default=Path.home() / ".cache" / "makeway" / "cross_source")
    ap.add_argument("--cache", type=Path, default=Path("reports/general_clips"), help="models and recordings")
    ap.add_argument("--json", type=Path, default=None, help="also write every figure here")
    args = ap.parse_args(argv)
    try:
        data = require_data_dir(args.data)
        if args.json is not None:
            check_writable(args.json, folder=False)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    clips = [c.strip() for c in args.clips.split(",") if c.strip()]
    unknown = [c for c in clips if not (data / "video" / f"{c}.mp4").is_file()]
    if unknown:
        print(f"error: no such clip in {data / 'video'}: {', '.join(unknown)}", file=sys.stderr)
        return 2
    print(f"load average (1 min): {os.getloadavg()[0]:.1f}")
    sources = built_cross_sources(["ambulance_yolo", "road_clips"], data, args.sources, log=print)
    ev_root = data / "vision" / "ev_crops"
    amb, road = (Path(str(sources[k].root)) for k in ("ambulance_yolo", "road_clips"))
    labels = read_track_labels(TRACK_LABELS)
    args.cache.mkdir(parents=True, exist_ok=True)
    held: dict[str, list[ClipRecord]] = {"general recipe, clip held out": [], "default (anchor)": []}
    report: dict[str, Any] = {"smoother_threshold": SMOOTHER_T}
    for clip in clips:
        folder = _road_without(road, clip, args.cache / f"road_clips_without_{clip}")
        model = _train([ev_root, amb, folder], args.cache / f"general_without_{clip}.npz", args.threads)
        video = data / "video" / f"{clip}.mp4"
        rec_g, _ = cached_clip(video, args.cache / "records", model, progress=True)
        rec_d, _ = cached_clip(video, args.cache / "records", DEFAULT_MODEL, progress=True)
        held["general recipe, clip held out"].append(rec_g)
        held["default (anchor)"].append(rec_d)
    for min_judged in MIN_JUDGED:
        key = f"min_judged_{min_judged}"
        report[key] = {"clips": {}, "pooled": {}}
        print(f"\nper actor (tracks with >= {min_judged} judged frames), smoother T = {SMOOTHER_T}")
        print(f"  {'clip / model':34s}  TP  FP  FN   TN   prec   rec    F1   per-frame max-F1")
        for k, clip in enumerate(clips):
            rows = {name: _actors([recs[k]], labels, min_judged) for name, recs in held.items()}
            report[key]["clips"][clip] = rows
            print(f"{clip}")
            for name, m in rows.items():
                print(_line(name, m))
        report[key]["pooled"] = {name: _actors(recs, labels, min_judged) for name, recs in held.items()}
        print("all clips together")
        for name, m in report[key]["pooled"].items():
            print(_line(name, m))
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
