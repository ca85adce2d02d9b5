"""Framework B's "active EV" rules on the real clips: crop classifier vs lit/flashing lights (issue 23).

Framework B (YOLOX-nano → SORT → shipped EV crop head) is recorded once per clip and cached under
``--cache`` (``makeway.pipeline.clip_record.cached_clip``, the same cache as
``bench_track_sweep.py``): every track's box and crop probability per frame. The light detector
(``--detector``, default the registry's default) and :class:`makeway.track.lights.LightTracker`
then run over every frame (red, blue and amber lights only, as in the pipeline), and each (frame,
vehicle track) gets its lights evidence (a lit or flashing light in the upper part of the box or
just above it, :func:`makeway.track.lights.vehicle_light_evidence`). Each rule of
:data:`makeway.track.lights.ACTIVE_RULES` turns evidence and crop probability into a per-frame
probability, the track smoother (window 25, min 6, T 0.5: the pipeline's default) replays it, and an
actor (SORT track) is predicted positive when it is active on at least one frame. Labels:
``src/makeway/data/video_track_labels.csv``. Every track of the five clips is an actor, for every
rule; a second row per rule counts only the tracks of at least 6 frames (the smoother's
``min_frames``: a shorter track cannot turn active under any rule).

Prints per rule and colour set the per-actor TP/FP/FN/TN, precision, recall, F1, the tracks flagged
on the two no-EV clips (target 0), then the speed of lights detector + tracker + flash cue on
``traffic_no_ev`` (640×360; target ≥ 2× real time at 25 fps, i.e. ≤ 20 ms per frame; wall and CPU
time, with the load average, since a shared machine's wall time says little) and of four cameras
per step (four frames per 40 ms step, serially and on two threads), then one JSON line.

    .venv/bin/python benchmarks/bench_active_rule.py                 # rules (us, eu) and speed
    .venv/bin/python benchmarks/bench_active_rule.py --speed-only
    .venv/bin/python benchmarks/bench_active_rule.py --detector cnn  # another registered detector
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from collections import defaultdict
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from makeway.eval.actor_sweep import EV_CLIPS, NO_EV_CLIPS, TRACK_LABELS, ClipRecord, read_track_labels
from makeway.eval.classification import precision_recall_f1
from makeway.jsonable import to_jsonable
from makeway.messages import Box, EVObservation, EVState, Track
from makeway.paths import data_dir
from makeway.perceive.vision.ev_classifier import DEFAULT_MODEL
from makeway.perceive.vision.lights import DEFAULT_LIGHT_DETECTOR
from makeway.pipeline.clip_record import cached_clip
from makeway.sense.video import VideoReader
from makeway.track.lights import (
    ACTIVE_RULES,
    SATURATED,
    LightTracker,
    active_probability,
    build_light_detector,
    vehicle_light_evidence,
)
from makeway.track.smoother import TrackSmoother

MIN_FRAMES = 6  # the smoother's min_frames: shorter tracks can never turn active under any rule
TARGET_RT = 2.0  # lights detector + tracking + flash cue, × real time on 640×360 at 25 fps


def light_evidence(
    video: Path,
    rec: ClipRecord,
    detector_name: str,
    colours: str,
    progress: bool = False,
    follow: bool = False,
    tracker_kw: dict[str, Any] | None = None,
) -> dict[tuple[int, int], tuple[bool, bool]]:
    """``(frame, track id) → (lit, flashing)`` for every recorded vehicle track of one clip; with
    ``follow`` the light tracker gets the vehicle tracks (lights follow their vehicle)."""
    det = build_light_detector(detector_name, colours)
    tracker = LightTracker(**(tracker_kw or {}))
    by_frame: dict[int, list[Track]] = defaultdict(list)
    for f, tid, box in zip(rec.frame.tolist(), rec.track_id.tolist(), rec.boxes.tolist(), strict=True):
        by_frame[f].append(Track(tid, Box(*box)))
    out: dict[tuple[int, int], tuple[bool, bool]] = {}
    with VideoReader(video) as reader:
        for index, t_s, image in reader:
            found = [d for d in det.detect(image, index) if d.colour in SATURATED]  # as the pipeline
            vehicles = by_frame.get(index, [])
            lights = tracker.update(found, t_s, image, vehicles=vehicles if follow else None)
            for tid, ev in vehicle_light_evidence(vehicles, lights).items():
                out[(index, tid)] = ev
    return out


def actor_active(
    rec: ClipRecord, evidence: dict[tuple[int, int], tuple[bool, bool]], rule: str
) -> dict[int, bool]:
    """Per track: active on at least one frame under ``rule`` through the default smoother."""
    out = {}
    for tid in rec.track_ids:
        sel = np.flatnonzero(rec.track_id == tid)
        sm = TrackSmoother()
        active = False
        for j in sel:
            f = int(rec.frame[j])
            p = float(rec.probability[j])
            lit, flashing = evidence.get((f, tid), (False, False))
            prob = active_probability(rule, lit, flashing, None if math.isnan(p) else p)
            (state,) = sm.update([EVObservation(tid, f, 0.0, prob)], alive_track_ids=[tid])
            if state.state is EVState.ACTIVE:
                active = True
                break
        out[tid] = active
    return out


def speed(video: Path, detector_name: str, colours: str, frames: int) -> dict[str, float]:
    """Detector + tracker + flash cue on one camera (ms per frame, wall and CPU time), and on four
    cameras per step (four different frames of the clip per 40 ms step), serially and on two
    worker threads (the detector releases the GIL; trackers then update in order)."""
    det = build_light_detector(detector_name, colours)
    with VideoReader(video, max_frames=frames) as reader:
        images = [img for _, _, img in reader]

    def one_camera() -> None:
        tracker = LightTracker()
        for i, img in enumerate(images):
            tracker.update([d for d in det.detect(img, i) if d.colour in SATURATED], i / 25.0, img)

    w0, c0 = time.perf_counter(), time.process_time()
    one_camera()
    one, one_cpu = (time.perf_counter() - w0) / len(images), (time.process_time() - c0) / len(images)
    n_steps = len(images) // 4
    steps = [[images[(s + c * n_steps) % len(images)] for c in range(4)] for s in range(n_steps)]

    def four_cameras(pool: ThreadPoolExecutor | None) -> tuple[float, float]:
        trackers = [LightTracker() for _ in range(4)]
        dets = [build_light_detector(detector_name, colours) for _ in range(4)]
        t0, c0 = time.perf_counter(), time.process_time()
        for s, step in enumerate(steps):
            jobs = [(dets[c], img, s) for c, img in enumerate(step)]
            if pool is None:
                found = [d.detect(img, k) for d, img, k in jobs]
            else:
                found = list(pool.map(lambda job: job[0].detect(job[1], job[2]), jobs))
            for c, img in enumerate(step):
                trackers[c].update([d for d in found[c] if d.colour in SATURATED], s / 25.0, img)
        n = max(n_steps, 1)
        return (time.perf_counter() - t0) / n, (time.process_time() - c0) / n

    four, four_cpu = four_cameras(None)
    with ThreadPoolExecutor(max_workers=2) as pool:
        four_2t, _ = four_cameras(pool)
    return {
        "ms_per_frame": 1000 * one,
        "cpu_ms_per_frame": 1000 * one_cpu,
        "realtime_x_at_25fps": (1 / 25) / one,
        "realtime_x_at_25fps_cpu": (1 / 25) / one_cpu,
        "four_cameras_ms_per_step": 1000 * four,
        "four_cameras_realtime_x_at_25fps": (1 / 25) / four,
        "four_cameras_cpu_ms_per_step": 1000 * four_cpu,
        "four_cameras_2threads_ms_per_step": 1000 * four_2t,
        "four_cameras_2threads_realtime_x_at_25fps": (1 / 25) / four_2t,
        "load_average_1min": os.getloadavg()[0],
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--cache", type=Path, default=Path("reports/track_probs"), help="Framework B record cache"
    )
    ap.add_argument("--detector", default=DEFAULT_LIGHT_DETECTOR, help="light detector (registry name)")
    ap.add_argument("--colours", default="us,eu", help="colour sets to compare (comma list)")
    ap.add_argument("--speed-frames", type=int, default=150, help="frames of traffic_no_ev timed")
    ap.add_argument("--labels", type=Path, default=TRACK_LABELS)
    ap.add_argument("--speed-only", action="store_true", help="only the speed figures")
    ap.add_argument(
        "--follow-vehicles",
        action="store_true",
        help="the light tracker gets the vehicle tracks, so lights follow their vehicle (the pipeline "
        "does not: on these clips it did not help)",
    )
    ap.add_argument("--gate", type=float, default=None, help="light tracker's gate (default its own)")
    ap.add_argument(
        "--max-gap-s", type=float, default=None, help="light tracker's max_gap_s (default its own)"
    )
    ap.add_argument("--no-speed", action="store_true", help="skip the speed figures")
    args = ap.parse_args()

    root = data_dir()
    if root is None:
        print("error: shared data not found (set MAKEWAY_DATA)", file=sys.stderr)
        return 2
    labels = read_track_labels(args.labels)
    records = {}
    for clip in () if args.speed_only else (*EV_CLIPS, *NO_EV_CLIPS):
        records[clip], _ = cached_clip(
            root / "video" / f"{clip}.mp4", args.cache, DEFAULT_MODEL, progress=True
        )

    tracker_kw = {k: v for k, v in (("gate", args.gate), ("max_gap_s", args.max_gap_s)) if v is not None}
    results: dict[str, object] = {
        "detector": args.detector,
        "follow_vehicles": args.follow_vehicles,
        "tracker": tracker_kw,
    }
    head = (
        ""
        if args.speed_only
        else f"{'colours':8s} {'rule':12s} {'TP':>3s} {'FP':>3s} {'FN':>3s} {'TN':>4s}  prec   rec    F1"
    )
    if head:
        print(f"{head}  | no-EV flagged (target 0)")
    for colours in [c.strip() for c in args.colours.split(",") if c.strip() and records]:
        evidence = {
            clip: light_evidence(
                root / "video" / f"{clip}.mp4",
                rec,
                args.detector,
                colours,
                follow=args.follow_vehicles,
                tracker_kw=tracker_kw,
            )
            for clip, rec in records.items()
        }
        for rule in ACTIVE_RULES:
            if rule == "crop" and colours != args.colours.split(",")[0].strip():
                continue  # the crop rule does not depend on the colour set
            counts = {1: [0, 0, 0, 0], MIN_FRAMES: [0, 0, 0, 0]}  # tp fp fn tn per actor set
            no_ev = 0
            flagged: dict[str, list[int]] = {}
            for clip, rec in records.items():
                pred = actor_active(rec, evidence[clip], rule)
                flagged[clip] = sorted(t for t, a in pred.items() if a)
                for tid, a in pred.items():
                    y = bool(labels.label(clip, tid))
                    cell = (0 if y else 1) if a else (2 if y else 3)
                    for min_len, c in counts.items():
                        if int(np.sum(rec.track_id == tid)) >= min_len:
                            c[cell] += 1
                    if clip in NO_EV_CLIPS and a:
                        no_ev += 1
            name = "—" if rule == "crop" else colours
            for min_len, (tp, fp, fn, tn) in counts.items():
                m = precision_recall_f1(tp, fp, fn)
                tag = "" if min_len == 1 else f" (tracks >= {min_len} frames)"
                print(
                    f"{name:8s} {rule:12s} {tp:3d} {fp:3d} {fn:3d} {tn:4d}  {m['precision']:.3f} "
                    f"{m['recall']:.3f} {m['f1']:.3f} | {no_ev}{tag}"
                )
                results[f"{name}/{rule}" + ("" if min_len == 1 else f"/min{min_len}")] = {
                    "tp": tp,
                    "fp": fp,
                    "fn": fn,
                    "tn": tn,
                    **m,
                    "no_ev_flagged": no_ev,
                    "flagged": flagged,
                }
    if not args.no_speed:
        colours0 = args.colours.split(",")[0].strip()
        sp = speed(root / "video" / "traffic_no_ev.mp4", args.detector, colours0, args.speed_frames)
        print(
            f"speed ({args.detector}, {colours0}, traffic_no_ev 640×360, load average "
            f"{sp['load_average_1min']:.1f} on {os.cpu_count()} cores):\n"
            f"  one camera: {sp['ms_per_frame']:.1f} ms/frame wall = "
            f"{sp['realtime_x_at_25fps']:.2f}× real time "
            f"at 25 fps, {sp['cpu_ms_per_frame']:.1f} ms CPU = {sp['realtime_x_at_25fps_cpu']:.2f}× "
            f"(target ≥ {TARGET_RT:g}×, i.e. ≤ {40 / TARGET_RT:.0f} ms)\n"
            f"  four cameras: {sp['four_cameras_ms_per_step']:.1f} ms per step = "
            f"{sp['four_cameras_realtime_x_at_25fps']:.2f}× real time "
            f"({sp['four_cameras_cpu_ms_per_step']:.1f} "
            f"ms CPU = {40 / sp['four_cameras_cpu_ms_per_step']:.2f}× on one free core); on 2 threads "
            f"{sp['four_cameras_2threads_ms_per_step']:.1f} ms = "
            f"{sp['four_cameras_2threads_realtime_x_at_25fps']:.2f}×"
        )
        results["speed"] = sp
    print(json.dumps(to_jsonable(results, digits=4)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
