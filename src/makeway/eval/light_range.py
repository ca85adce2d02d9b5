"""How far the lights detector sees: per-frame recall of a lit EV against distance, measured on real
labelled frames from a calibrated camera, and carried over to the car's camera rig (issue 26 item 1).

The closed loop's cameras (:class:`makeway.sim.cameras.CameraFigures`) detect a lit light in a frame
with a probability that falls with distance. Seed 004's field figures fill that table by default; this
module measures makeway's own detector for it.

**What is measured.** For every labelled frame in which a vehicle shows at least one lit lamp (an
on-phase of its light bar) and every such vehicle:

* ``distance_m`` — from the camera's centre to the point where the ray through the centre of the
  vehicle's lamp boxes meets the plane ``lamp_height_m`` above the road (metres; the camera's
  road calibration, :class:`makeway.roadside.transform.RoadCamera`, gives the ray and the camera's
  height). An ambulance's roof bar and upper flashers sit about 2.2–2.8 m up; 0.3 m of error in that
  height moves the distance by about 7 % for a camera 6.6 m up;
* ``found_strict`` — a detection matched to one of the vehicle's lamp boxes at IoU ≥ 0.5 (seed 004's
  array rule, :func:`makeway.eval.lights.match_frame`);
* ``found_loose`` — any detection centred in the vehicle's region (its lamps' bounding box grown by half
  its size, at least 10 px; :func:`makeway.eval.lights.vehicle_regions`): enough for the azimuth the
  fusion uses, and what the simulated cameras model;
* ``lamp_px`` — the median height of the vehicle's lamp boxes (pixels);
* ``others`` — the frame's detections centred outside every lit vehicle's region (what a detector
  that fires everywhere pays for a loose hit).

**Carried over to the rig.** A detector sees pixels, not metres: a light ``d`` metres from a camera of
focal length ``f_src`` (pixels per radian) covers about the pixels it covers ``d·f_rig/f_src`` metres
from a camera of focal length ``f_rig`` (:func:`rig_equivalent_m`). The rig's 180° fisheyes have
``f ≈ 366`` px/rad near the axis; the lens model's radial stretch off the axis (under 15 % at 45°) is
left out. Resolution, blur, compression and exposure of the two cameras are taken as alike.

:func:`recall_by_distance` bins the rows by rig-equivalent distance.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass
from itertools import pairwise
from typing import Any, Protocol

import numpy as np

from makeway.eval.lights import match_frame, run_detector, vehicle_regions

__all__ = ["LitVehicleFrame", "lit_vehicle_frames", "recall_by_distance", "rig_equivalent_m"]


class _Ray(Protocol):
    position_m: np.ndarray

    def ray(self, pixels: Any) -> np.ndarray: ...


@dataclass(frozen=True)
class LitVehicleFrame:
    """One lit vehicle in one frame (module docstring): ``source``, frame ``key``, ``vehicle`` id,
    ``distance_m`` from the camera (m), ``lamp_px`` (median lamp box height, px), and whether the
    detector found its light strictly and loosely; ``others``: the frame's detections outside every
    lit vehicle's region."""

    source: str
    key: str
    vehicle: int
    distance_m: float
    lamp_px: float
    found_strict: bool
    found_loose: bool
    others: int = 0

    def to_dict(self) -> dict[str, Any]:
        """The row as a JSON-ready dict."""
        return asdict(self)


def _lamp_distance(camera: _Ray, boxes: np.ndarray, lamp_height_m: float) -> float:
    """Distance (m) from the camera to where the ray through the lamps' centre meets the plane
    ``lamp_height_m`` above the road; NaN when the ray does not reach it."""
    centre = np.array(
        [[0.5 * (boxes[:, 0].min() + boxes[:, 2].max()), 0.5 * (boxes[:, 1].min() + boxes[:, 3].max())]]
    )
    d = camera.ray(centre)[0]
    drop = lamp_height_m - float(camera.position_m[2])
    if not np.all(np.isfinite(d)) or abs(d[2]) < 1e-9 or drop / d[2] <= 0.0:
        return float("nan")
    return float(drop / d[2])  # along a unit ray, the parameter is the distance


def lit_vehicle_frames(
    frames: Iterable[tuple[str, str, np.ndarray, np.ndarray, Sequence[int]]],
    detector: Any,
    camera: _Ray,
    *,
    lamp_height_m: float = 2.4,
) -> list[LitVehicleFrame]:
    """Run ``detector`` once on each ``(source, key, BGR image, lamp boxes (n, 4) px, vehicle id per
    box)`` frame (:func:`makeway.eval.lights.run_detector`) and return one row per lit vehicle (module
    docstring); frames without a lamp box are skipped. ``camera`` is the calibrated camera that took
    the frames (a ``RoadCamera``)."""
    if not 0.0 < lamp_height_m < float(camera.position_m[2]):
        raise ValueError(
            "lamp_height_m must lie between the road and the camera "
            f"(0–{float(camera.position_m[2]):.2f} m), not {lamp_height_m:g}"
        )

    def lit(
        items: Iterable[tuple[str, str, np.ndarray, np.ndarray, Sequence[int]]],
    ) -> Iterator[tuple[str, str, np.ndarray, np.ndarray, Sequence[int]]]:
        for source, key, image, gt, vehicles in items:
            g = np.asarray(gt, np.float64).reshape(-1, 4)
            if len(g) and len(vehicles) != len(g):
                raise ValueError(f"{source} frame {key}: {len(g)} lamp boxes but {len(vehicles)} vehicle ids")
            if len(g):
                yield source, key, image, g, vehicles

    out: list[LitVehicleFrame] = []
    for res in run_detector(detector, lit(frames)):
        source, key, g, boxes = res.source, res.key, res.gt_boxes, res.boxes
        vehicles = list(res.gt_vehicles)
        match = match_frame(boxes, res.scores, g)
        ids = np.asarray(vehicles)
        regions = vehicle_regions(g, vehicles)
        cx, cy = 0.5 * (boxes[:, 0] + boxes[:, 2]), 0.5 * (boxes[:, 1] + boxes[:, 3])
        on = {v: (cx >= r[0]) & (cx <= r[2]) & (cy >= r[1]) & (cy <= r[3]) for v, r in regions.items()}
        others = int((~np.logical_or.reduce([np.zeros(len(boxes), bool), *on.values()])).sum())
        for v, hits in on.items():
            own = g[ids == v]
            strict = bool(np.any(np.isin(match[match >= 0], np.flatnonzero(ids == v))))
            loose = bool(hits.any())
            out.append(
                LitVehicleFrame(
                    source=source,
                    key=str(key),
                    vehicle=int(v),
                    distance_m=_lamp_distance(camera, own, lamp_height_m),
                    lamp_px=float(np.median(own[:, 3] - own[:, 1])),
                    found_strict=strict,
                    found_loose=loose,
                    others=others,
                )
            )
    return out


def rig_equivalent_m(distance_m: Any, source_focal_px: float, rig_focal_px: float) -> np.ndarray:
    """The distance (m) at which a camera of focal length ``rig_focal_px`` (px/rad) sees a light as
    large, in pixels, as a camera of ``source_focal_px`` sees it ``distance_m`` away."""
    if source_focal_px <= 0 or rig_focal_px <= 0:
        raise ValueError("focal lengths must be positive (pixels per radian)")
    return np.asarray(distance_m, np.float64) * (rig_focal_px / source_focal_px)


def recall_by_distance(
    rows: Sequence[LitVehicleFrame], distances_m: Any, edges_m: Sequence[float]
) -> list[dict[str, Any]]:
    """Per bin ``[edges_m[i], edges_m[i+1])`` of ``distances_m`` (one per row, e.g. the rig-equivalent
    distances): the bin, the number of lit vehicle-frames ``n``, and the shares found strictly and
    loosely (None for an empty bin). Rows with a NaN distance fall in no bin."""
    d = np.asarray(distances_m, np.float64).ravel()
    if len(d) != len(rows):
        raise ValueError(f"{len(rows)} rows but {len(d)} distances")
    if len(edges_m) < 2 or any(b <= a for a, b in pairwise(edges_m)):
        raise ValueError("edges_m must be at least two increasing distances")
    strict = np.array([r.found_strict for r in rows], bool)
    loose = np.array([r.found_loose for r in rows], bool)
    out = []
    for lo, hi in pairwise(edges_m):
        sel = (d >= lo) & (d < hi)
        n = int(sel.sum())
        out.append(
            {
                "from_m": float(lo),
                "to_m": float(hi),
                "n": n,
                "recall_strict": float(strict[sel].mean()) if n else None,
                "recall_loose": float(loose[sel].mean()) if n else None,
            }
        )
    return out
