"""Does the temporal flash cue clean up the lit-light detector's boxes? (issue 23, item 6)

The shipped ``verified`` light detector judges one frame at a time. Here it runs on **every** frame
of a labelled clip, its boxes (at its operating threshold) go through :class:`LightTracker` as in
``makeway lights``, and each labelled frame is scored three ways with seed 004's metrics (the same
as ``bench_lights.py``):

With ``--follow-vehicles`` the tracker also gets YOLOX-nano → SORT vehicle tracks, so lights follow
their vehicle (:class:`LightTracker`; the pipeline does not pass them).

* ``per frame`` — the detector's boxes as they are (the anchor: ``bench_lights.py``'s figure);
* ``flashing`` — only boxes whose light track the flash cue calls flashing (1–4 Hz on/off over the
  tracker's window); the others keep 2 % of their score, so mAP still ranks them, last;
* ``flashing or new`` — as ``flashing``, but a track younger than the window (undecided) keeps its
  boxes too.

It also prints, for the boxes that match a labelled lamp (true) and those that do not (false), the
median age of their light track, the share of tracks older than one second and the share called
flashing: a flash cue needs about a second of one track's history to judge.

Clips: ``night_ambulance_lights`` (test split, every frame labelled) by default;
``--clips intersection_cam_ambulance`` adds the validation clip (no detector finds its 1.5–6 px lamps).

    .venv/bin/python benchmarks/bench_lights_flash.py [--clips night_ambulance_lights,...] [--json F]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from makeway.eval.lights import FrameResult, match_frame, summarise
from makeway.paths import data_dir
from makeway.perceive.vision.detectors import Detector
from makeway.perceive.vision.light_verify import VerifiedLightDetector, vehicle_detector
from makeway.sense.video import VideoReader
from makeway.track.lights import LightTrack, LightTracker
from makeway.track.sort import Sort
from makeway.train.light_labels import iter_label_frames, read_labels, source_path
from makeway.train.light_split import LABEL_DIR, SPLITS, load_split

POLICIES = ("per frame", "flashing", "flashing or new")
DOWN = 0.02  # score kept by a box the gate turns down (mAP still ranks it, last)
FIGURES = ("array_precision", "array_recall", "vehicle_precision", "vehicle_recall", "map50")


def _run_clip(
    name: str, root: Path, threads: int, follow: bool, tracker_kw: dict[str, Any]
) -> tuple[dict[str, Any], dict[str, Any]]:
    labels = read_labels(LABEL_DIR / f"{name}.csv")
    split = SPLITS[name]
    gt = {
        f.key: f for f in load_split(split, root, input_size=None, keep_images=False)[0] if f.source == name
    }
    with VideoReader(source_path(labels.source, root)) as reader:
        fps = float(reader.info.fps)
    probe = VerifiedLightDetector(colours="all", num_threads=threads)
    detector = VerifiedLightDetector(colours="all", num_threads=threads, threshold=min(0.01, probe.threshold))
    op = probe.threshold
    tracker = LightTracker(**tracker_kw)
    vehicles = vehicle_detector(threads) if follow else None
    sort = Sort() if follow else None
    results: dict[str, list[FrameResult]] = {p: [] for p in POLICIES}
    ages: dict[str, list[tuple[float, bool]]] = {"true": [], "false": []}
    for key, img in iter_label_frames(labels, root, every=True):
        dets = detector.detect(img, int(key))
        strong = [d for d in dets if d.score >= op]
        cars = None
        if (
            vehicles is not None and sort is not None
        ):  # as the pipeline: YOLOX-nano → SORT, the light tracker follows them
            arrays = vehicles.detect_arrays(img)
            cars = sort.update(Detector.to_detections((arrays[0], arrays[1], arrays[2])))
        tracks = tracker.update(strong, int(key) / fps, img, vehicles=cars)
        by_box: dict[tuple[float, ...], LightTrack] = {
            (t.box.x1, t.box.y1, t.box.x2, t.box.y2): t for t in tracks if t.detected
        }
        if key not in gt:
            continue
        frame = gt[key]
        boxes = np.array([[d.box.x1, d.box.y1, d.box.x2, d.box.y2] for d in dets], np.float64).reshape(-1, 4)
        base = np.array([d.score for d in dets], np.float64)
        track_of = [by_box.get((d.box.x1, d.box.y1, d.box.x2, d.box.y2)) for d in dets]
        flashing = np.array([t is not None and t.flashing for t in track_of], bool)
        new = np.array([t is not None and t.age_s < tracker.window_s for t in track_of], bool)
        keep = {
            "per frame": np.ones(len(dets), bool),
            "flashing": flashing,
            "flashing or new": flashing | new,
        }
        for policy, kept in keep.items():
            scores = np.where(kept, base, DOWN * base)
            results[policy].append(FrameResult(name, key, frame.boxes, frame.vehicles, boxes, scores))
        _book_ages(boxes, base, base >= op, track_of, frame.boxes, ages)
    summary = {p: summarise(rs, score_threshold=op)[name] for p, rs in results.items()}
    diag = {
        kind: {
            "boxes": len(v),
            "track_age_median_s": float(np.median([a for a, _ in v])) if v else None,
            "older_than_1s": float(np.mean([a > 1.0 for a, _ in v])) if v else None,
            "flashing": float(np.mean([f for _, f in v])) if v else None,
        }
        for kind, v in ages.items()
    }
    return summary, {"fps": fps, "threshold": op, "boxes": diag}


def _book_ages(
    boxes: np.ndarray,
    scores: np.ndarray,
    strong: np.ndarray,
    track_of: list[LightTrack | None],
    gt_boxes: np.ndarray,
    ages: dict[str, list[tuple[float, bool]]],
) -> None:
    """Record (track age, flashing) of each box at the operating threshold (``strong``), as true
    (matching a labelled lamp) or false."""
    sel = [i for i in np.flatnonzero(strong) if track_of[i] is not None]
    if not sel:
        return
    for i, j in zip(sel, match_frame(boxes[sel], scores[sel], gt_boxes), strict=True):
        t = track_of[i]
        assert t is not None
        ages["true" if j >= 0 else "false"].append((t.age_s, t.flashing))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clips", default="night_ambulance_lights", help="comma-separated labelled clips")
    ap.add_argument("--threads", type=int, default=1, help="ONNX Runtime threads (default 1)")
    ap.add_argument("--json", type=Path, default=None, help="also write the figures as JSON")
    ap.add_argument(
        "--follow-vehicles",
        action="store_true",
        help="lights follow their vehicle's SORT track (YOLOX-nano → SORT as in the pipeline)",
    )
    ap.add_argument("--gate", type=float, default=None, help="the light tracker's gate (default its own)")
    ap.add_argument("--max-gap-s", type=float, default=None, help="the light tracker's max_gap_s")
    args = ap.parse_args(argv)
    tracker_kw = {k: v for k, v in (("gate", args.gate), ("max_gap_s", args.max_gap_s)) if v is not None}
    root = data_dir()
    if root is None:
        print("shared data not found (set MAKEWAY_DATA)", file=sys.stderr)
        return 2
    clips = [c.strip() for c in args.clips.split(",") if c.strip()]
    for c in clips:
        if SPLITS.get(c) not in ("val", "test") or not (LABEL_DIR / f"{c}.csv").is_file():
            print(f"{c}: not a labelled validation or test clip", file=sys.stderr)
            return 2
    out: dict[str, Any] = {}
    for name in clips:
        summary, info = _run_clip(name, Path(root), args.threads, args.follow_vehicles, tracker_kw)
        out[name] = {
            "policies": summary,
            "follow_vehicles": args.follow_vehicles,
            "tracker": tracker_kw,
            **info,
        }
        print(
            f"\n{name} ({SPLITS[name]} split; every frame through the detector and LightTracker at "
            f"{info['fps']:.2f} fps, lights {'following their vehicle' if args.follow_vehicles else 'alone'}"
            f"{', ' + str(tracker_kw) if tracker_kw else ''}; "
            f"P/R at score ≥ {info['threshold']:.2f}, IoU 0.5)"
        )
        print(f"{'boxes kept':18s} {'arrP':>6s} {'arrR':>6s} {'vehP':>6s} {'vehR':>6s} {'mAP50':>6s}")
        for policy, m in summary.items():
            cells = " ".join("     —" if m[k] is None else f"{100 * m[k]:5.1f}%" for k in FIGURES)
            print(f"{policy:18s} {cells}")
        for kind, d in info["boxes"].items():
            if d["boxes"]:
                print(
                    f"  {kind} boxes {d['boxes']}: light track age median {d['track_age_median_s']:.2f} s, "
                    f"older than 1 s {100 * d['older_than_1s']:.0f} %, flashing {100 * d['flashing']:.1f} %"
                )
    print("anchor: bench_lights.py's 'verified' row (per frame); targets array P ≥ 90 %, R ≥ 88 % (issue 23)")
    if args.json is not None:
        args.json.write_text(json.dumps(out, allow_nan=False, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
