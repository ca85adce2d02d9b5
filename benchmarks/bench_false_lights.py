"""False lights of makeway's own lights detector on real footage without a lit emergency light,
beside the rate the simulated cameras assume (issue 26 item 1).

The closed loop's cameras (:class:`makeway.sim.cameras.CameraFigures`) report a false light — a
brake light, traffic light or reflection taken for an emergency light — at
``false_lights_per_hour`` (an assumption: 60 per hour, each 0.2–1.0 s). This runs the detector
(default: ``verified``, the default of ``makeway lights``, every colour) and the light tracker over
every stretch of :data:`makeway.eval.false_lights.NEGATIVE_STRETCHES` at 10 frames per second and
prints per stretch: seconds, frames, boxes, false light events (light tracks), their durations, how
many flashed, and the rate per hour with its exact 95 % interval — then the rate over the sources
no detector was trained on, and over all. With ``--night``, the night clip's checked frames without
a lit lamp (its light bar dark between bursts; single frames, so boxes per frame only) are run too.

    .venv/bin/python benchmarks/bench_false_lights.py [--detector verified] [--colours all]
        [--night] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

from makeway.atomic import check_writable
from makeway.errors import InputError
from makeway.eval.false_lights import NEGATIVE_STRETCHES, count_false_lights, poisson_rate_interval, pooled
from makeway.paths import require_data_dir
from makeway.sim.cameras import CameraFigures
from makeway.track.lights import build_light_detector


def _night_boxes(root: Path, detector: Any) -> dict[str, Any]:
    """Boxes per frame on the night clip's checked frames without a lit lamp (test split)."""
    from makeway.train.light_split import load_split

    frames, _ = load_split("test", root, input_size=None)
    dark = [f for f in frames if f.source == "night_ambulance_lights" and not len(f.boxes)]
    boxes = [len(detector.detect(f.image)) for f in dark]
    return {"frames": len(dark), "boxes": sum(boxes), "boxes_per_frame": sum(boxes) / max(1, len(dark))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--detector", default="verified", help="light detector (registry name)")
    ap.add_argument("--colours", default="all", help="colour set (all, us, eu, …)")
    ap.add_argument("--rate", type=float, default=10.0, help="frames per second read (the cameras' rate)")
    ap.add_argument("--night", action="store_true", help="also the night clip's dark-bar frames")
    ap.add_argument("--json", type=Path, default=None, help="also write every figure here")
    args = ap.parse_args(argv)
    try:
        root = require_data_dir()
        if args.json is not None:
            check_writable(args.json, folder=False)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    detector = build_light_detector(args.detector, args.colours)
    assumed = CameraFigures().false_lights_per_hour
    print(f"load average (1 min): {os.getloadavg()[0]:.1f}; detector {args.detector}, colours {args.colours}")
    print(
        f"\n{'stretch':28s} {'role':10s} {'s':>6s} {'frames':>6s} {'boxes':>5s} {'events':>6s} "
        f"{'flash':>5s} {'median s':>8s}   events/h (95 %)"
    )
    counts = []
    report: dict[str, Any] = {"detector": args.detector, "colours": args.colours, "stretches": []}
    t0 = time.perf_counter()
    for stretch in NEGATIVE_STRETCHES:
        c = count_false_lights(root / "video" / f"{stretch.clip}.mp4", stretch, detector, rate_hz=args.rate)
        counts.append(c)
        hours = c.seconds / 3600.0
        low, high = poisson_rate_interval(c.events, hours)
        med = statistics.median(c.durations_s) if c.durations_s else 0.0
        print(
            f"{stretch.clip:28s} {stretch.role:10s} {c.seconds:6.1f} {c.frames:6d} {c.boxes:5d} "
            f"{c.events:6d} {c.flashing_events:5d} {med:8.2f}   "
            f"{c.events / hours:6.0f} ({low:.0f}–{high:.0f})"
        )
        report["stretches"].append(
            {
                "clip": stretch.clip,
                "role": stretch.role,
                "seconds": round(c.seconds, 2),
                "frames": c.frames,
                "boxes": c.boxes,
                "events": c.events,
                "flashing_events": c.flashing_events,
                "durations_s": c.durations_s,
                "per_hour": [round(c.events / hours, 1), round(low, 1), round(high, 1)],
            }
        )
    for name, subset in (
        ("never trained on", [c for c in counts if c.stretch.role != "training"]),
        ("all", counts),
    ):
        events, hours = pooled(subset)
        low, high = poisson_rate_interval(events, hours)
        print(
            f"{name:39s} {hours * 3600:6.1f} {'':6s} {'':5s} {events:6d} {'':5s} {'':8s}   "
            f"{events / hours:6.0f} ({low:.0f}–{high:.0f})"
        )
        report[name.replace(" ", "_")] = {
            "events": events,
            "seconds": round(hours * 3600, 1),
            "per_hour": [round(events / hours, 1), round(low, 1), round(high, 1)],
        }
    print(f"anchor: the simulated cameras' assumption, {assumed:.0f} false lights per hour")
    report["assumed_per_hour"] = assumed
    if args.night:
        night = _night_boxes(root, detector)
        print(
            f"night clip, frames with its light bar dark: {night['frames']} frames, {night['boxes']} boxes "
            f"({night['boxes_per_frame']:.1f} per frame)"
        )
        report["night_dark_bar"] = night
    print(f"wall {time.perf_counter() - t0:.0f} s")
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
