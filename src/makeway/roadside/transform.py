"""Transformation-based pixel → road: back-project a pixel through ``K[R|t]`` onto the road plane.

A fixed roadside camera with known intrinsics (any model of :mod:`makeway.sense.camera`) and pose in
the road frame (:mod:`makeway.roadside`: metres, ENU, road surface ``z = 0``) turns a pixel into the
ray ``d = R · unproject(u, v)`` from its centre ``C``; where the ray meets ``z = 0``,
``P = C − (C_z / d_z) · d``, is the road point. Rays that do not descend (at or above the horizon)
have no road point (NaN).

The pixel to back-project is a box's **ground-contact point**, the bottom centre ``((x1 + x2)/2, y2)``:
it lies on the road. The box centre lies half a vehicle height above it, and back-projecting it onto
the road lands beyond the vehicle — farther the taller the vehicle and the flatter the view (the
tall-object bias of seed 001's appendix B.1, which used the centre). The bottom edge is the vehicle's
nearest ground edge, so the road point is the near face of its footprint, not its centre: about half
a vehicle length short when it is seen along the road. :func:`box_ground_pixel` gives both points;
``locate(..., behind_m=L)`` pushes the road point ``L`` metres farther along the horizontal viewing
direction (e.g. half a typical vehicle length) to aim at the footprint's centre.

The calibration file (YAML)::

    model: pinhole                 # or kannala_brandt (then k is required)
    width: 1280                    # image size, pixels
    height: 720
    fx: 1372.5                     # OpenCV's K, pixels
    fy: 1372.5
    cx: 640.0
    cy: 360.0
    k: [0, 0, 0, 0]                # k1..k4 (cv2.fisheye); ignored by the pinhole
    rotation: [[...], [...], [...]]  # camera → road frame: d_road = rotation @ d_camera
    position_m: [9.5, 0.0, 10.0]   # the camera centre in the road frame, metres (z: height above the road)
    origin:                        # optional: the road frame's origin, WGS-84 (for lat/lon output)
      lat_deg: 30.6280
      lon_deg: -96.4818
      height_m: 0.0

:func:`read_transform_calibration` checks it and raises :class:`~makeway.errors.InputError` naming the
file and the problem: malformed YAML, a missing, unknown or ill-typed field, a rotation that is not
orthonormal (``max|RᵀR − I| > 1e-6``) or is a reflection, a camera not above the road (``z ≤ 0``) or
one that sees no road at all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from makeway.errors import InputError
from makeway.roadside.geodesy import LocalFrame
from makeway.sense.camera import Camera
from makeway.sense.fields import (
    ORTHONORMAL_TOLERANCE,
    camera_fields,
    number_field,
    rotation_field,
    vector_field,
)

__all__ = [
    "DEFAULT_LENGTH_M",
    "ORTHONORMAL_TOLERANCE",
    "TYPICAL_LENGTH_M",
    "RoadCamera",
    "box_ground_pixel",
    "read_transform_calibration",
    "typical_length_m",
    "write_transform_calibration",
]

#: Largest ``|RᵀR − I|`` entry a calibration's rotation may have.
_REQUIRED = ("model", "width", "height", "fx", "fy", "cx", "cy", "rotation", "position_m")
_KNOWN = {*_REQUIRED, "k", "origin"}


#: Typical length (m) of a vehicle by the class a COCO detector gives it: a mid-size car (EU new cars
#: average about 4.4–4.6 m), a motorcycle (2.0–2.3 m), a two-axle city bus (12 m, the EU limit for a
#: rigid two-axle bus), a rigid delivery truck (7–10 m). A box's bottom edge is the vehicle's near
#: face; its centre lies half a length farther along the road.
TYPICAL_LENGTH_M: dict[str, float] = {"car": 4.5, "motorcycle": 2.2, "bus": 12.0, "truck": 8.0}
#: Length (m) assumed for a class not in :data:`TYPICAL_LENGTH_M` (a car's).
DEFAULT_LENGTH_M = 4.5


def typical_length_m(labels: Any) -> np.ndarray:
    """The :data:`TYPICAL_LENGTH_M` of each detector class label (``str`` or a sequence of them),
    :data:`DEFAULT_LENGTH_M` for other labels; metres, shaped like ``labels``."""
    arr = np.asarray(labels, dtype=object)
    out = np.array([TYPICAL_LENGTH_M.get(str(v), DEFAULT_LENGTH_M) for v in arr.reshape(-1)], np.float64)
    return out.reshape(arr.shape)


def box_ground_pixel(boxes: Any, point: str = "bottom_centre") -> np.ndarray:
    """Boxes ``(..., 4)`` as ``x1, y1, x2, y2`` pixels → the pixel ``(..., 2)`` to back-project:
    ``bottom_centre`` (the ground-contact point) or ``centre`` (seed 001's choice, biased)."""
    b = np.asarray(boxes, np.float64)
    u = 0.5 * (b[..., 0] + b[..., 2])
    if point == "bottom_centre":
        v = b[..., 3]
    elif point == "centre":
        v = 0.5 * (b[..., 1] + b[..., 3])
    else:
        raise ValueError(f"point must be bottom_centre or centre, not {point!r}")
    return np.stack([u, v], axis=-1)


@dataclass(frozen=True)
class RoadCamera:
    """A fixed camera over the road: intrinsics, ``rotation`` (3×3, ``d_road = rotation @ d_camera``),
    ``position_m`` (its centre in the road frame, metres) and the road frame's WGS-84 origin, if known."""

    camera: Camera
    rotation: np.ndarray
    position_m: np.ndarray
    origin: LocalFrame | None = None

    def ray(self, pixels: Any) -> np.ndarray:
        """Pixels ``(..., 2)`` → unit rays ``(..., 3)`` in the road frame (NaN beyond the lens model)."""
        return self.camera.unproject(pixels) @ self.rotation.T

    def locate(self, pixels: Any, behind_m: Any = 0.0) -> np.ndarray:
        """Pixels ``(..., 2)`` → road points ``(..., 2)`` (``x`` east, ``y`` north, metres); NaN for a
        pixel whose ray does not reach the road. ``behind_m`` (metres, scalar or per pixel) moves
        each point that far farther from the camera along the ray's horizontal direction."""
        d = self.ray(pixels)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(d[..., 2] < -1e-9, -self.position_m[2] / d[..., 2], np.nan)
            xy = self.position_m[:2] + s[..., None] * d[..., :2]
            horiz = d[..., :2] / np.linalg.norm(d[..., :2], axis=-1, keepdims=True)
        return xy + np.asarray(behind_m, np.float64)[..., None] * horiz

    def project(self, points: Any) -> np.ndarray:
        """Road-frame points ``(..., 3)`` metres → pixels ``(..., 2)`` (NaN where not imaged)."""
        p = np.asarray(points, np.float64) - self.position_m
        return self.camera.project(p @ self.rotation)

    def to_dict(self) -> dict[str, Any]:
        """The calibration as the YAML file states it."""
        out: dict[str, Any] = {
            **self.camera.to_dict(),
            "rotation": [[float(v) for v in row] for row in self.rotation],
            "position_m": [float(v) for v in self.position_m],
        }
        if self.origin is not None:
            o = self.origin
            out["origin"] = {"lat_deg": o.lat0_deg, "lon_deg": o.lon0_deg, "height_m": o.h0_m}
        return out

    def summary(self) -> dict[str, Any]:
        """What a check of the calibration reports: model, height (m), downward tilt of the optical
        axis (degrees), the nearest and farthest road distance seen along the image's vertical centre
        line (metres from the camera's foot; ``null`` when that line reaches the horizon), and the
        horizon row there (pixels; ``null`` when not in the image)."""
        cam = self.camera
        axis = self.rotation[:, 2]
        tilt = math.degrees(math.asin(max(-1.0, min(1.0, -float(axis[2])))))
        rows = np.linspace(0.0, cam.height, 721)
        xy = self.locate(np.stack([np.full_like(rows, cam.cx), rows], axis=-1))
        dist = np.linalg.norm(xy - self.position_m[:2], axis=-1)
        seen = ~np.isnan(dist)
        return {
            "model": cam.model,
            "image": [cam.width, cam.height],
            "height_m": float(self.position_m[2]),
            "tilt_down_deg": tilt,
            "nearest_road_m": float(dist[seen].min()) if seen.any() else None,
            "farthest_road_m": None if (not seen.any() or not seen.all()) else float(dist.max()),
            "horizon_row_px": float(rows[seen].min()) if seen.any() and not seen.all() else None,
            "origin": None if self.origin is None else [self.origin.lat0_deg, self.origin.lon0_deg],
        }


def write_transform_calibration(camera: RoadCamera, path: str | Path) -> None:
    """Write ``camera`` as a calibration file (module docstring: layout)."""
    Path(path).write_text(yaml.safe_dump(camera.to_dict(), sort_keys=False), encoding="utf-8")


def read_transform_calibration(path: str | Path) -> RoadCamera:
    """Read and check a calibration file (module docstring: layout); InputError names the problem."""
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(path, "calibration file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot be read as a calibration file ({exc})") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        raise InputError(path, f"is not valid YAML{where}") from None

    def fail(problem: str) -> InputError:
        return InputError(path, problem)

    if not isinstance(doc, dict):
        raise fail("must be a YAML mapping of calibration fields (model, width, …, rotation, position_m)")
    missing = [k for k in _REQUIRED if k not in doc]
    if missing:
        raise fail(f"missing field(s) {', '.join(missing)}")
    unknown = sorted(str(k) for k in doc if k not in _KNOWN)
    if unknown:
        raise fail(f"unknown field(s) {', '.join(unknown)}")
    camera = camera_fields(doc, fail)
    rot = rotation_field(doc["rotation"], fail)
    pos = vector_field(doc["position_m"], "position_m", 3, fail)
    if pos[2] <= 0:
        raise fail(f"position_m: the camera must be above the road (z > 0 m), not z = {pos[2]:g}")
    origin = None
    if "origin" in doc:
        o = doc["origin"]
        if (
            not isinstance(o, dict)
            or not {"lat_deg", "lon_deg"} <= set(o)
            or not set(o)
            <= {
                "lat_deg",
                "lon_deg",
                "height_m",
            }
        ):
            raise fail("origin must be a mapping with lat_deg, lon_deg and optionally height_m")
        try:
            origin = LocalFrame(
                number_field(o["lat_deg"], "origin.lat_deg", fail),
                number_field(o["lon_deg"], "origin.lon_deg", fail),
                number_field(o.get("height_m", 0.0), "origin.height_m", fail),
            )
        except ValueError as exc:
            raise fail(str(exc)) from None
    road = RoadCamera(camera, rot, pos, origin)
    if road.summary()["nearest_road_m"] is None:
        raise fail("the camera sees no road: no pixel of the image's centre column looks below the horizon")
    return road
