"""Framework A against Framework B on the five labelled road clips (seed 001; issue 24, item 5).

A: the shipped one-stage EV detector (``ev_det_yolox.onnx``) → one SORT over all vehicles → the
per-track smoother fed by each box's P(EV). B: YOLOX-nano → SORT → the ``default`` crop head → the
same smoother (its per-frame probabilities recorded and cached as ``bench_track_sweep.py`` does).
Actors are tracks; B's carry the committed labels, A's take them by IoU overlap with B's
(``makeway.eval.framework_ab``). Prints per-actor precision / recall / F1 at the smoother's
T = 0.5 beside no smoothing, the per-frame row, the class flips (the track resets per-class
tracking would cause: seed 001's claim), ID switches on the other framework's EV actors, and
frames per second of the full ``makeway detect`` pipeline on the two 640-pixel-wide clips (target:
A ≥ 2× real time on 2 cores), with the load average; then one JSON line.

    .venv/bin/python benchmarks/bench_framework_ab.py                 # records, then caches
    .venv/bin/python benchmarks/bench_framework_ab.py --no-speed      # metrics only
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import json
import math
import os
import sys
from pathlib import Path
from typing import Any

from makeway.eval.actor_sweep import EV_CLIPS, NO_EV_CLIPS, ClipRecord, TrackLabels, read_track_labels, sweep
from makeway.eval.framework_ab import class_flips, id_switches, label_by_overlap, record_framework_a
from makeway.jsonable import to_jsonable
from makeway.paths import data_dir
from makeway.perceive.vision.ev_classifier import DEFAULT_MODEL
from makeway.perceive.vision.ev_detector import EV_DET_FILE, EVDetector
from makeway.pipeline.clip_record import cached_clip, cached_record

SPEED_CLIPS = ("fire_trucks_red_lights", "traffic_no_ev")  # 640×352 and 640×360


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]


def _fmt(x: float) -> str:
    return "  n/a" if math.isnan(x) else f"{x:.3f}"


def _speed(video: Path, framework: str, model: Path, head: Path) -> dict[str, float]:
    """Frames per second of the whole pipeline (decode → detect → track → judge → smooth, no
    outputs written) with two detector workers, as ``makeway detect --rule crop`` runs it."""
    from makeway.perceive.vision.ev_classifier import EVTrackClassifier, load_crop_classifier
    from makeway.pipeline.video import run_video

    if framework == "a":
        dets = [EVDetector(model, num_threads=1) for _ in range(2)]
        s = run_video(video, None, ev_detectors=dets, write_video=False, progress=False, rule="crop")
    else:
        clf = EVTrackClassifier(load_crop_classifier(head))
        s = run_video(
            video, None, classifier=clf, detector_workers=2, write_video=False, progress=False, rule="crop"
        )
    return {"fps": s.frames / s.wall_seconds, "realtime_factor": s.realtime_factor, "frames": s.frames}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, default=EV_DET_FILE, help="Framework A's detector (.onnx)")
    ap.add_argument("--head", type=Path, default=DEFAULT_MODEL, help="Framework B's crop classifier")
    ap.add_argument("--cache", type=Path, default=Path.home() / ".cache" / "makeway" / "framework_ab")
    ap.add_argument("--threshold", type=float, default=0.5, help="the smoother's T")
    ap.add_argument("--min-judged", type=int, default=6, help="actors: tracks with >= N judged frames")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--no-speed", action="store_true", help="skip the frames-per-second runs")
    args = ap.parse_args()

    root = data_dir()
    if root is None:
        print("error: shared data not found (set MAKEWAY_DATA)", file=sys.stderr)
        return 2
    labels = read_track_labels()
    det = EVDetector(args.model, num_threads=2)
    rec_a: list[ClipRecord] = []
    rec_b: list[ClipRecord] = []
    labels_a = TrackLabels(Path("overlap with the labelled tracks"))
    unmatched = 0
    flips_a, flips_b = [], []
    idsw_a = idsw_b = ev_b = ev_a = 0
    for clip in (*EV_CLIPS, *NO_EV_CLIPS):
        video = root / "video" / f"{clip}.mp4"
        b, _ = cached_clip(video, args.cache, args.head, max_frames=args.max_frames, progress=True)
        a, _ = cached_record(
            video,
            args.cache,
            functools.partial(record_framework_a, video, det, max_frames=args.max_frames, progress=True),
            key={"framework_a": _digest(args.model)},
            max_frames=args.max_frames,
            tag="a.",
        )
        la, n_un = label_by_overlap(a, b, labels)
        unmatched += n_un
        labels_a.explicit.update({(clip, t): v for t, v in la.items()})
        lb = {t: labels.label(clip, t) for t in b.track_ids}
        flips_a.append(class_flips(a, la))
        flips_b.append(class_flips(b, lb))
        s, n = id_switches(a, b, lb)  # A following B's EV actors
        idsw_a, ev_b = idsw_a + s, ev_b + n
        s, n = id_switches(b, a, la)  # B following A's EV actors
        idsw_b, ev_a = idsw_b + s, ev_a + n
        rec_a.append(a)
        rec_b.append(b)
        print(
            f"{clip:28s} A: {len(a.track_ids):3d} tracks ({sum(la.values())} EV, {n_un} unmatched); "
            f"B: {len(b.track_ids):3d} tracks ({sum(lb.values())} EV)"
        )
    out: dict[str, Any] = {"load_avg": os.getloadavg()}
    print(f"\nper actor (tracks with >= {args.min_judged} judged frames), smoother T = {args.threshold:g}")
    print(f"{'':34s} {'TP':>4s} {'FP':>4s} {'FN':>4s} {'TN':>4s}  {'prec':>5s} {'rec':>5s} {'F1':>5s}")
    for name, recs, labs in (("A", rec_a, labels_a), ("B", rec_b, labels)):
        rows, _ = sweep(recs, labs, (args.threshold,), min_judged=args.min_judged)
        out[name] = {}
        for r in rows:
            print(
                f"{name} {r.setting:32s} {r.tp:4d} {r.fp:4d} {r.fn:4d} {r.tn:4d}  "
                f"{_fmt(r.precision)} {_fmt(r.recall)} {_fmt(r.f1)}"
            )
            out[name][r.setting] = {
                k: getattr(r, k) for k in ("tp", "fp", "fn", "tn", "precision", "recall", "f1")
            }
    totals: dict[str, dict[str, int]] = {}
    for name, flips in (("A", flips_a), ("B", flips_b)):
        tot: dict[str, int] = {k: sum(getattr(f, k) for f in flips) for k in flips[0].__dataclass_fields__}
        out[f"{name}_class_flips"] = totals[name] = tot
        print(
            f"{name}: {tot['tracks_flipping']}/{tot['tracks']} tracks change class within their life, "
            f"{tot['flips']} changes (EV actors: {tot['ev_tracks_flipping']}/{tot['ev_tracks']}, "
            f"{tot['ev_flips']} changes)"
        )
    print(
        f"tracked per class, A would restart {totals['A']['flips']} tracks "
        f"(seed 001's claim); one SORT over all vehicles restarts none"
    )
    out["id_switches"] = {
        "A_following_B_ev_tracks": idsw_a, "B_ev_tracks": ev_b,
        "B_following_A_ev_tracks": idsw_b, "A_ev_tracks": ev_a,
    }  # fmt: skip
    out["A_unmatched_tracks"] = unmatched
    print(
        f"ID switches: A's tracks following B's {ev_b} EV tracks: {idsw_a}; "
        f"B's tracks following A's {ev_a} EV tracks: {idsw_b}"
    )
    if not args.no_speed:
        speed: dict[str, Any] = {}
        for clip in SPEED_CLIPS:
            video = root / "video" / f"{clip}.mp4"
            for fw in ("a", "b"):
                load = os.getloadavg()
                run = _speed(video, fw, args.model, args.head)
                speed[f"{fw}:{clip}"] = {**run, "load_avg": load}
                print(
                    f"speed {fw.upper()} {clip}: {run['fps']:.1f} frames/s = "
                    f"{run['realtime_factor']:.2f}× real "
                    f"time (target for A: ≥ 2×); load average {load[0]:.2f}, {load[1]:.2f}, {load[2]:.2f}"
                )
        out["speed"] = speed
    print(json.dumps(to_jsonable(out, digits=4)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
