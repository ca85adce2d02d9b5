"""How far makeway's lights detectors see by day, carried over to the car's fisheye rig, beside the
figures the simulated cameras use (seed 004's field test; issue 26 item 1).

The closed loop's cameras (:class:`makeway.sim.cameras.CameraFigures`) detect a lit light in a frame
with a probability that falls with distance. Only one labelled real clip comes from a calibrated
camera: ``intersection_cam_ambulance`` (day, a fixed camera 6.6 m up, focal length 651 px/rad; the
hand calibration of docs/roadside_calibration.md). Every frame of it with a lit lamp of the
ambulance is run through each detector; the distance from the camera to the lamps comes from the
calibration (lamps taken ``--lamp-height`` m above the road), and is carried over to the rig's
fisheyes by the focal lengths (:func:`makeway.eval.light_range.rig_equivalent_m`: the same pixels on
the light). Per band of rig-equivalent distance: lit vehicle-frames, the share in which the
detector found the light (strict: a box matched at IoU ≥ 0.5; loose: any box on the vehicle, which
is what the simulated cameras model), and the frame's other boxes — beside seed 004's day figure
at that distance (the anchor; the default camera model).

The clip is the lights verifier's validation source (its settings were chosen on it; it was never
trained on). One ambulance, one clip: a coarse figure.

    .venv/bin/python benchmarks/bench_camera_figures.py [--detectors verified,cnn,colour]
        [--lamp-height 2.4] [--json out.json] [--threads 1] [--verifier OTHER.onnx]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from makeway.eval.light_range import lit_vehicle_frames, recall_by_distance, rig_equivalent_m
from makeway.paths import data_dir
from makeway.perceive.vision.lights import LIGHT_DETECTORS
from makeway.roadside.transform import read_transform_calibration
from makeway.sense.rig import load_rig
from makeway.sim.cameras import CAMERA_FIGURES
from makeway.train.light_split import load_split

ROOT = Path(__file__).resolve().parents[1]
CALIBRATION = ROOT / "src" / "makeway" / "data" / "intersection_cam_ambulance.yaml"
SOURCE = "intersection_cam_ambulance"
EDGES_M = (6.0, 10.0, 14.0, 18.0)


def _pct(v: float | None) -> str:
    return "   —  " if v is None else f"{100 * v:5.1f}%"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--detectors", default="verified,cnn,colour", help="light detectors (comma-separated)")
    ap.add_argument("--lamp-height", type=float, default=2.4, help="lamps' height above the road (m)")
    ap.add_argument("--rig", default="default", help="the car's camera rig (a rig file or 'default')")
    ap.add_argument("--threads", type=int, default=1, help="ONNX Runtime threads")
    ap.add_argument(
        "--verifier",
        type=Path,
        action="append",
        default=[],
        help="another verifier model for the 'verified' detector, scored as an extra row named by its "
        "file stem (repeatable)",
    )
    ap.add_argument("--json", type=Path, default=None, help="also write the figures and rows as JSON")
    args = ap.parse_args(argv)
    root = data_dir()
    if root is None:
        print("shared data not found (set MAKEWAY_DATA)", file=sys.stderr)
        return 2
    camera = read_transform_calibration(CALIBRATION)
    rig = load_rig(args.rig)
    rig_f = float(np.mean([c.camera.fx for c in rig.cameras]))
    src_f = float(camera.camera.fx)
    frames, _ = load_split("val", root, input_size=None)
    items = [
        (f.source, f.key, f.image, f.boxes, f.vehicles) for f in frames if f.source == SOURCE and len(f.boxes)
    ]
    seed004 = CAMERA_FIGURES["seed004"]()
    print(
        f"{SOURCE}: {len(items)} frames with a lit lamp; camera f = {src_f:.1f} px/rad, "
        f"{float(camera.position_m[2]):.2f} m up; rig f = {rig_f:.1f} px/rad (×{rig_f / src_f:.3f}); "
        f"lamps {args.lamp_height:g} m up",
        flush=True,
    )
    report: dict[str, Any] = {
        "source": SOURCE,
        "frames": len(items),
        "source_focal_px": src_f,
        "rig_focal_px": rig_f,
        "lamp_height_m": args.lamp_height,
        "detectors": {},
    }
    head = (
        f"{'detector':10s} {'rig-equiv. m':>12s} {'n':>4s} {'strict':>7s} {'loose':>7s} "
        f"{'other boxes/fr':>15s} {'seed 004 day':>13s}"
    )
    print(head)
    print("-" * len(head))
    rows_to_run: list[tuple[str, str, dict[str, Any]]] = []
    for name in [d.strip() for d in args.detectors.split(",") if d.strip()]:
        rows_to_run.append((name, name, {} if name == "colour" else {"num_threads": args.threads}))
    for path in args.verifier:
        rows_to_run.append((path.stem[:10], "verified", {"num_threads": args.threads, "model": path}))
    for name, kind, extra in rows_to_run:
        detector = LIGHT_DETECTORS[kind](colours="all", **extra)
        t0 = time.perf_counter()
        rows = lit_vehicle_frames(items, detector, camera, lamp_height_m=args.lamp_height)
        wall = time.perf_counter() - t0
        dist = np.array([r.distance_m for r in rows])
        equiv = rig_equivalent_m(dist, src_f, rig_f)
        bins = recall_by_distance(rows, equiv, EDGES_M)
        allbin = recall_by_distance(rows, equiv, (EDGES_M[0], EDGES_M[-1]))[0]
        others = float(np.mean([r.others for r in rows])) if rows else 0.0
        for b in [*bins, {**allbin, "from_m": EDGES_M[0], "to_m": EDGES_M[-1]}]:
            mid = 0.5 * (b["from_m"] + b["to_m"])
            sel = (equiv >= b["from_m"]) & (equiv < b["to_m"])
            oth = (
                float(np.mean([r.others for r, s in zip(rows, sel, strict=True) if s])) if sel.any() else None
            )
            print(
                f"{name:10s} {b['from_m']:5.0f}–{b['to_m']:<5.0f} {b['n']:5d} {_pct(b['recall_strict'])} "
                f"{_pct(b['recall_loose'])} {'—' if oth is None else f'{oth:.1f}':>15s} "
                f"{_pct(seed004.recall(mid, night=False)):>13s}"
            )
        report["detectors"][name] = {
            "bins": bins,
            "all": allbin,
            "other_boxes_per_frame": others,
            "distance_m": [float(np.nanmin(dist)), float(np.nanmax(dist))],
            "rig_equivalent_m": [float(np.nanmin(equiv)), float(np.nanmax(equiv))],
            "wall_s": wall,
            "rows": [r.to_dict() for r in rows],
        }
    d = report["detectors"]
    if d:
        first = next(iter(d.values()))
        lo, hi = first["distance_m"]
        print(
            f"distance from the camera {lo:.1f}–{hi:.1f} m → rig-equivalent "
            f"{first['rig_equivalent_m'][0]:.1f}–{first['rig_equivalent_m'][1]:.1f} m"
        )
    print(
        "anchor: seed 004's day figures (the default camera model, CameraFigures 'seed004'); "
        f"the 'makeway' camera model uses: {CAMERA_FIGURES['makeway']().recall_source}"
    )
    if args.json is not None:
        args.json.write_text(json.dumps(report, indent=1), encoding="utf-8")
    print(
        json.dumps(
            {k: {"all": v["all"], "other_boxes_per_frame": v["other_boxes_per_frame"]} for k, v in d.items()}
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
