"""A vehicle's camera rig: the rig file, pixel → ray in the vehicle frame, and the azimuth of what a
camera sees.

Frames and units:

* **Vehicle frame** (:mod:`makeway.messages`): metres, ``x`` forward, ``y`` left, ``z`` up, origin on
  the ground under the centre of the rear axle.
* **Camera frame** (:mod:`makeway.sense.camera`): OpenCV axes, ``x`` right, ``y`` down, ``z`` forward.
* **Azimuth** ``atan2(y, x)`` in the vehicle frame, degrees in ``(−180, 180]``: 0 straight ahead,
  positive to the left (90 = left, ±180 = behind). **Elevation** ``atan2(z, √(x² + y²))``, degrees,
  positive up.

The rig file (YAML) lists the cameras::

    cameras:
      - name: front                 # unique within the rig
        model: kannala_brandt       # or pinhole (then k may be left out and is ignored)
        width: 1280                 # image size, pixels
        height: 960
        fx: 366.0                   # focal lengths and principal point, pixels (OpenCV's K)
        fy: 366.4
        cx: 643.5
        cy: 478.0
        k: [0.062, -0.011, 0.004, -0.0009]   # k1..k4 as cv2.fisheye
        rotation: [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]   # d_vehicle = rotation @ d_camera
        translation_m: [3.7, 0.0, 0.6]       # the camera centre in the vehicle frame, metres

Instead of ``rotation`` a camera may give ``yaw_pitch_roll_deg: [yaw, pitch, roll]`` (degrees). The
rotation is then ``Rz(yaw) · Ry(pitch) · Rx(roll) · R0``, rotations about the vehicle's own axes:

* ``R0`` is the camera at rest — looking straight ahead along vehicle ``x``, image right along
  vehicle ``−y``, image down along vehicle ``−z``: ``R0 = [[0, 0, 1], [−1, 0, 0], [0, −1, 0]]``.
* ``roll`` turns the camera about its optical axis (right-hand rule about vehicle ``x``): positive
  lowers the image's right side.
* ``pitch`` turns about vehicle ``y`` (right-hand rule): positive tilts the optical axis **down**
  (ISO 8855: nose down).
* ``yaw`` turns about vehicle ``z`` (right-hand rule): positive turns the optical axis to the
  **left**; the optical axis then points at azimuth = yaw.

So ``[90, 20, 0]`` is a left-mirror camera looking left and 20° down, ``[180, 0, 0]`` a rear camera.

A camera's pixel ``(u, v)`` (image frame, ``0 ≤ u ≤ width``, ``0 ≤ v ≤ height``) gives the unit ray
``d = R @ unproject(u, v)`` in the vehicle frame, starting at the camera centre ``t``. The azimuth of
the ray's direction is what a camera alone can say; with a range ``ρ`` along the ray (metres, from the
camera centre) the point ``t + ρ·d`` is known and its azimuth and elevation seen from the vehicle
origin are given instead (they differ from the direction's by the camera's offset, a few degrees at
10 m).

:func:`read_rig` checks the whole file and raises :class:`~makeway.errors.InputError` naming the
file, the camera and the problem: malformed YAML, a missing or unknown field, a wrong type, a
rotation that is not orthonormal (``max|RᵀR − I| > 1e-6``) or not proper (``det R ≠ +1``), a
duplicate camera name. Queries raise it for an unknown camera name or a pixel outside the image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import yaml

from makeway.errors import InputError
from makeway.sense.camera import Camera
from makeway.sense.fields import (
    ORTHONORMAL_TOLERANCE,
    camera_fields,
    rotation_field,
    vector_field,
)

__all__ = [
    "DEFAULT_RIG",
    "ORTHONORMAL_TOLERANCE",
    "R0",
    "Direction",
    "Rig",
    "RigCamera",
    "default_rig_path",
    "load_rig",
    "read_rig",
    "rotation_from_yaw_pitch_roll",
]

#: ``makeway rig … default`` and :func:`load_rig` ("default") read this shipped 4-camera rig.
DEFAULT_RIG = "default"
#: Largest ``|RᵀR − I|`` entry a rig's rotation may have.
#: Camera → vehicle rotation of a camera looking straight ahead (x right, y down, z forward → vehicle).
R0 = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])

_REQUIRED = ("name", "model", "width", "height", "fx", "fy", "cx", "cy", "translation_m")
_KNOWN = {*_REQUIRED, "k", "rotation", "yaw_pitch_roll_deg"}


class Direction(NamedTuple):
    """Azimuth and elevation in the vehicle frame, degrees (arrays shaped like the query's pixels)."""

    azimuth_deg: np.ndarray
    elevation_deg: np.ndarray


def rotation_from_yaw_pitch_roll(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    """The camera → vehicle rotation ``Rz(yaw)·Ry(pitch)·Rx(roll)·R0`` (module docstring: signs)."""
    y, p, r = (math.radians(a) for a in (yaw_deg, pitch_deg, roll_deg))
    rz = np.array([[math.cos(y), -math.sin(y), 0.0], [math.sin(y), math.cos(y), 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[math.cos(p), 0.0, math.sin(p)], [0.0, 1.0, 0.0], [-math.sin(p), 0.0, math.cos(p)]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(r), -math.sin(r)], [0.0, math.sin(r), math.cos(r)]])
    return rz @ ry @ rx @ R0


def _direction(d: np.ndarray) -> Direction:
    az = np.degrees(np.arctan2(d[..., 1], d[..., 0]))
    el = np.degrees(np.arctan2(d[..., 2], np.hypot(d[..., 0], d[..., 1])))
    return Direction(az, el)


@dataclass(frozen=True)
class RigCamera:
    """One camera of a rig: its intrinsics, ``rotation`` (3×3, ``d_vehicle = rotation @ d_camera``)
    and ``translation_m`` (the camera centre in the vehicle frame, metres)."""

    name: str
    camera: Camera
    rotation: np.ndarray
    translation_m: np.ndarray

    def ray_vehicle(self, pixels: Any) -> np.ndarray:
        """Pixels ``(..., 2)`` → unit rays ``(..., 3)`` in the vehicle frame (from the camera centre)."""
        return self.camera.unproject(pixels) @ self.rotation.T

    def to_dict(self) -> dict[str, Any]:
        """The camera as a rig file's entry (with ``rotation``)."""
        return {
            "name": self.name,
            **self.camera.to_dict(),
            "rotation": [[float(v) for v in row] for row in self.rotation],
            "translation_m": [float(v) for v in self.translation_m],
        }


@dataclass(frozen=True)
class Rig:
    """The cameras of one vehicle, read from ``source`` (the rig file; named in error messages)."""

    cameras: tuple[RigCamera, ...]
    source: Path

    @property
    def names(self) -> list[str]:
        """The camera names, in file order."""
        return [c.name for c in self.cameras]

    def camera(self, name: str) -> RigCamera:
        """The camera called ``name``; an unknown name raises InputError listing the rig's cameras."""
        for cam in self.cameras:
            if cam.name == name:
                return cam
        raise InputError(self.source, f"has no camera {name!r}; its cameras: {', '.join(self.names)}")

    def check_pixels(self, name: str, u: Any, v: Any) -> np.ndarray:
        """``(u, v)`` as pixels ``(..., 2)`` of camera ``name``, checked to lie in its image and in its
        lens model's field; InputError naming the first pixel that does not."""
        cam = self.camera(name)
        px = np.stack(np.broadcast_arrays(np.asarray(u, np.float64), np.asarray(v, np.float64)), axis=-1)
        bad = ~cam.camera.in_image(px)
        if np.any(bad):
            bu, bv = px[bad][0]
            raise InputError(
                self.source,
                f"pixel ({bu:g}, {bv:g}) is outside the image of camera {name!r} "
                f"(0 ≤ u ≤ {cam.camera.width}, 0 ≤ v ≤ {cam.camera.height})",
            )
        rays = cam.camera.unproject(px)
        beyond = np.isnan(rays[..., 0])
        if np.any(beyond):
            bu, bv = px[beyond][0]
            raise InputError(
                self.source,
                f"pixel ({bu:g}, {bv:g}) of camera {name!r} lies beyond its lens model's field of view",
            )
        return px

    def ray_vehicle(self, name: str, u: Any, v: Any) -> np.ndarray:
        """Unit rays ``(..., 3)`` in the vehicle frame for pixels ``(u, v)`` (scalars or arrays) of
        camera ``name``; they start at the camera centre."""
        return self.camera(name).ray_vehicle(self.check_pixels(name, u, v))

    def azimuth(self, name: str, u: Any, v: Any, range_m: Any = None) -> Direction:
        """Azimuth and elevation (degrees, vehicle frame) of pixels ``(u, v)`` of camera ``name``.

        Without ``range_m``: of the ray's direction. With ``range_m`` (metres along the ray from the
        camera centre, > 0; scalar or one per pixel): of the point at that range, seen from the
        vehicle origin.
        """
        d = self.ray_vehicle(name, u, v)
        if range_m is None:
            return _direction(d)
        rng = np.asarray(range_m, dtype=np.float64)
        if not np.all(np.isfinite(rng) & (rng > 0)):
            raise ValueError(f"range_m must be positive and finite, not {range_m}")
        return _direction(self.camera(name).translation_m + rng[..., None] * d)

    def to_dict(self) -> dict[str, Any]:
        """The rig as a rig file states it (rotations as matrices)."""
        return {"cameras": [c.to_dict() for c in self.cameras]}


def default_rig_path() -> Path:
    """The shipped 4-camera rig file (front, left mirror, right mirror, rear; 180° fisheyes)."""
    return Path(str(resources.files("makeway") / "data" / "rig_default.yaml"))


def load_rig(spec: str | Path) -> Rig:
    """:func:`read_rig` of a path, or of the shipped rig when ``spec`` is ``"default"``."""
    return read_rig(default_rig_path() if str(spec) == DEFAULT_RIG else Path(spec))


def read_rig(path: str | Path) -> Rig:
    """Read and check a rig file (module docstring: layout); InputError names file and problem."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(path, "rig file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot be read as a rig file ({exc})") from None
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise InputError(path, f"is not valid YAML{where}: {problem}") from None
    if not isinstance(doc, dict) or "cameras" not in doc:
        raise InputError(path, "must be a YAML mapping with a 'cameras:' list")
    unknown = sorted(str(k) for k in doc if k != "cameras")
    if unknown:
        raise InputError(path, f"unknown top-level field(s) {', '.join(unknown)}; only 'cameras' is read")
    entries = doc["cameras"]
    if not isinstance(entries, list) or not entries:
        raise InputError(path, "'cameras' must be a non-empty list of camera entries")
    cameras: list[RigCamera] = []
    for i, entry in enumerate(entries, start=1):
        cam = _read_camera(path, i, entry)
        if cam.name in {c.name for c in cameras}:
            raise InputError(path, f"camera {i}: the name {cam.name!r} is used twice")
        cameras.append(cam)
    return Rig(tuple(cameras), path)


def _read_camera(path: Path, index: int, entry: Any) -> RigCamera:
    if not isinstance(entry, dict):
        raise InputError(path, f"camera {index} must be a mapping of fields, not {type(entry).__name__}")
    label = f"camera {index}" + (f" ({entry['name']!r})" if isinstance(entry.get("name"), str) else "")

    def fail(problem: str) -> InputError:
        return InputError(path, f"{label}: {problem}")

    unknown = sorted(str(k) for k in entry if k not in _KNOWN)
    if unknown:
        raise fail(f"unknown field(s) {', '.join(unknown)}")
    missing = [k for k in _REQUIRED if k not in entry]
    if missing:
        raise fail(f"missing field(s) {', '.join(missing)}")
    name = entry["name"]
    if not isinstance(name, str) or not name.strip():
        raise fail("name must be a non-empty string")
    camera = camera_fields(entry, fail)
    has_r, has_ypr = "rotation" in entry, "yaw_pitch_roll_deg" in entry
    if has_r == has_ypr:
        raise fail("give exactly one of rotation (3×3) and yaw_pitch_roll_deg ([yaw, pitch, roll])")
    if has_r:
        rot = rotation_field(entry["rotation"], fail)
    else:
        ypr = vector_field(entry["yaw_pitch_roll_deg"], "yaw_pitch_roll_deg", 3, fail)
        rot = rotation_from_yaw_pitch_roll(*ypr)
    t = vector_field(entry["translation_m"], "translation_m", 3, fail)
    return RigCamera(name, camera, rot, t)
