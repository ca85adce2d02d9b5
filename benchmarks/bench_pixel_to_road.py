"""Pixel → road on the simulated roadside camera: both methods of issue 27 item 1 against the truth.

    .venv/bin/python benchmarks/bench_pixel_to_road.py [--seeds 1,2,3] [--max-range-m 100] [--json FILE]

The simulated traffic camera (:mod:`makeway.sim.traffic`: 1280×720, 50° field of view, on a 10 m
pole 9.5 m beside a 4-lane road) has known geometry and every vehicle's true footprint centre. The
test scenes (``--seeds``, default traffic with EVs) give the simulated detector's boxes (3 % jitter)
of every counted vehicle whose box is not cut by the image border, within ``--max-range-m`` of the
pole. Each box is located by:

* **transform, box centre** — the anchor: seed 001's appendix B.1, the box centre through
  ``K[R|t]`` onto the road plane (the tall-object bias);
* **transform, bottom centre** — the ground-contact point through ``K[R|t]`` (lands on the
  footprint's near edge);
* **transform, bottom centre + 2.25 m** — pushed half a car length on along the view;
* **transform, + half the class length** — pushed half the typical length of the class a detector
  gives the vehicle (:func:`~makeway.roadside.transform.typical_length_m`: car 4.5 m, motorcycle
  2.2 m, truck 8 m, bus 12 m; an ambulance is a "truck", a police car a "car");
* **location reference** — a thin-plate spline through pixel ↔ GNSS pairs of a calibration drive
  (probe cars in scenes without EVs, seeds 101–103, every 5th frame, RTK noise σ = 2 cm),
  boxes inside the pairs' hull only (the share inside is printed); its 5-fold held-out error too;
  and the same moved by the class length's difference from the probe car's.

Printed: median and 95th-percentile error (metres, horizontal distance to the vehicle's footprint
centre), for all vehicles and for cars (the probe vehicle's kind), by range band.

Then both methods on the real clip ``intersection_cam_ambulance.mp4``, whose only ground truth is
its 37 hand-read road-marking landmarks (``src/makeway/data/intersection_cam_ambulance_points.csv``;
no GNSS drive exists for it): leave-one-out over the landmarks — the transformation refitted
without the point (:func:`~makeway.roadside.calibrate.leave_one_out_errors`), and a location
reference whose pairs are the other landmarks (:func:`~makeway.roadside.reference.kfold_errors`
with one fold per point).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from makeway.roadside.calibrate import leave_one_out_errors, read_road_points
from makeway.roadside.reference import LocationReference, kfold_errors
from makeway.roadside.simulated import SIM_ORIGIN, sim_observations, sim_pairs, sim_road_camera
from makeway.roadside.transform import box_ground_pixel, typical_length_m
from makeway.sim.traffic import EV_KINDS, VEHICLE_KINDS, TrafficConfig

DATA = Path(__file__).resolve().parents[1] / "src" / "makeway" / "data"


def _stats(err: np.ndarray) -> dict[str, float | int]:
    err = err[np.isfinite(err)]
    if not len(err):
        return {"n": 0}
    return {"n": len(err), "median_m": float(np.median(err)), "p95_m": float(np.percentile(err, 95))}


def real_clip() -> dict[str, object]:
    """Leave-one-out error of both methods over the real clip's landmarks (metres)."""
    pts = read_road_points(DATA / "intersection_cam_ambulance_points.csv")
    errors = {
        "transform (refit without the point)": leave_one_out_errors(pts.pixels, pts.xy, 1280, 720),
        "location reference (the other landmarks as pairs)": kfold_errors(
            pts.pixels, pts.xy, folds=len(pts.pixels)
        ),
    }
    print(f"real clip intersection_cam_ambulance.mp4: {len(pts.pixels)} landmarks, leave one out")
    out: dict[str, object] = {}
    for name, err in errors.items():
        out[name] = {**_stats(err), "max_m": float(err.max())}
        print(
            f"  {name:52s} median {np.median(err):.2f} m, p95 {np.percentile(err, 95):.2f} m, "
            f"max {err.max():.2f} m"
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="1,2,3", help="test scene seeds (comma-separated)")
    ap.add_argument("--max-range-m", type=float, default=100.0)
    ap.add_argument("--json", type=Path, help="also write the results here")
    args = ap.parse_args()

    cam = sim_road_camera()
    pixels, xy = sim_pairs()
    ref = LocationReference(pixels, xy, SIM_ORIGIN)
    held = kfold_errors(pixels, xy)
    obs_parts = [
        sim_observations(TrafficConfig(seed=int(s)), max_range_m=args.max_range_m)
        for s in args.seeds.split(",")
    ]
    boxes = np.concatenate([o.boxes for o in obs_parts])
    truth = np.concatenate([o.truth_xy for o in obs_parts])
    rng = np.concatenate([o.range_m for o in obs_parts])
    kind = np.concatenate([o.kind for o in obs_parts])
    # what a detector calls each vehicle (an ambulance is a "truck", a police car a "car")
    length = typical_length_m([(VEHICLE_KINDS.get(k) or EV_KINDS[k]).label for k in kind])
    bottom, centre = box_ground_pixel(boxes), box_ground_pixel(boxes, "centre")
    inside = ref.inside(bottom)
    methods = {
        "transform, box centre (anchor)": cam.locate(centre),
        "transform, bottom centre": cam.locate(bottom),
        "transform, bottom centre + 2.25 m": cam.locate(bottom, 2.25),
        "transform, + half the class length": cam.locate(bottom, 0.5 * length),
        "location reference (inside hull)": np.where(inside[:, None], ref.locate(bottom), np.nan),
        "location reference, class length": np.where(inside[:, None], ref.locate(bottom, length), np.nan),
    }
    bands = {
        f"all ≤ {args.max_range_m:g} m": rng <= args.max_range_m,
        "20–50 m": rng <= 50,
        "50–100 m": rng > 50,
    }
    results: dict[str, object] = {
        "pairs": len(pixels),
        "heldout_5fold": _stats(held),
        "boxes": len(boxes),
        "inside_hull_share": float(inside.mean()),
        "methods": {},
    }
    print(
        f"calibration pairs {len(pixels)}; 5-fold held-out error median {np.median(held):.2f} m, "
        f"p95 {np.percentile(held, 95):.2f} m; test boxes {len(boxes)} (seeds {args.seeds}), "
        f"{100 * inside.mean():.0f} % inside the pairs' hull"
    )
    header = f"{'method':36s} {'vehicles':9s} " + " ".join(f"{b:>20s}" for b in bands)
    print(header + "\n" + "-" * len(header))
    for name, est in methods.items():
        err = np.linalg.norm(est - truth, axis=1)
        row: dict[str, object] = {}
        for who, mask in (("all", np.ones(len(err), bool)), ("cars", kind == "car")):
            cells = []
            for band, bmask in bands.items():
                s = _stats(err[mask & bmask])
                row[f"{who} {band}"] = s
                cells.append(f"{s['median_m']:6.2f} / {s['p95_m']:6.2f} (n={s['n']:4d})" if s["n"] else "—")
            print(f"{name:36s} {who:9s} " + " ".join(f"{c:>20s}" for c in cells))
        results["methods"][name] = row  # type: ignore[index]
    print("cells: median / 95th percentile error, metres")
    results["real_clip_landmarks"] = real_clip()
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
