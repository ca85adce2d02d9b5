"""Azimuth of lit lights with detection in the loop, on rendered camera-rig scenes.

A scene is one rig camera's image: a real background frame (resized to the camera's size) with one
lit emergency lamp rendered where the camera model puts it. The lamp is a flat rectangle
(``lamp_w_m`` × ``lamp_h_m``, facing the camera) at a known point in the vehicle frame; its outline is
projected through the camera's lens model (pinhole or Kannala–Brandt) and filled with a saturated
white core inside a coloured glow, as a lit bulb looks to a camera. The light detector runs on the
whole image; the detection nearest the lamp's projected centre (within ``match_px`` plus the lamp's
size) is taken, and the azimuth of its box centre through the rig (:meth:`Rig.azimuth`) is compared
with the true azimuth of the lamp centre seen from the camera centre (vehicle frame, degrees, 0
ahead, positive left). With the true range along the ray, the azimuth from the vehicle origin is
compared too.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from makeway.perceive.vision.lights import LightDetector
from makeway.sense.rig import Rig

__all__ = ["AzimuthResult", "LampScene", "random_scene", "render_lamp_scene", "score_scene"]

#: BGR of a lamp's glow per colour.
_GLOW_BGR = {"blue": (255, 80, 0), "red": (20, 20, 255), "amber": (0, 160, 255), "white": (240, 240, 240)}


@dataclass(frozen=True)
class LampScene:
    """One lamp in front of one rig camera: its centre ``point_m`` (vehicle frame, metres), colour,
    size (metres) and the background image it is drawn on."""

    camera: str
    point_m: tuple[float, float, float]
    colour: str = "blue"
    lamp_w_m: float = 0.30
    lamp_h_m: float = 0.12


@dataclass(frozen=True)
class AzimuthResult:
    """The score of one scene: ``found`` whether a detection matched the lamp; the azimuth errors
    (degrees, wrapped to ±180) of the ray from the camera centre and of the point at the true range
    seen from the vehicle origin; the lamp's true azimuth and range (metres from the camera)."""

    camera: str
    found: bool
    true_azimuth_deg: float
    range_m: float
    ray_error_deg: float | None
    origin_error_deg: float | None


def _wrap(deg: float) -> float:
    return (deg + 180.0) % 360.0 - 180.0


def _lamp_outline(scene: LampScene, rig: Rig, n: int = 24) -> np.ndarray:
    """Pixels ``(n, 2)`` of the lamp's outline (an ellipse of the lamp's size, facing the camera)."""
    cam = rig.camera(scene.camera)
    centre = np.asarray(scene.point_m, np.float64)
    view = centre - cam.translation_m
    view /= np.linalg.norm(view)
    up = np.array([0.0, 0.0, 1.0])
    side = np.cross(up, view)
    side /= np.linalg.norm(side)
    top = np.cross(view, side)
    t = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    pts = (
        centre
        + np.outer(np.cos(t), side) * scene.lamp_w_m / 2
        + np.outer(np.sin(t), top) * scene.lamp_h_m / 2
    )
    pts_cam = (pts - cam.translation_m) @ cam.rotation  # vehicle → camera: R^T d
    return np.asarray(cam.camera.project(pts_cam))


def render_lamp_scene(scene: LampScene, rig: Rig, background_bgr: np.ndarray) -> np.ndarray:
    """The background resized to the camera's image with the lit lamp drawn in (module docstring)."""
    cam = rig.camera(scene.camera).camera
    img = cv2.resize(background_bgr, (cam.width, cam.height), interpolation=cv2.INTER_AREA).copy()
    outline = _lamp_outline(scene, rig)
    if not np.all(np.isfinite(outline)):
        raise ValueError(f"lamp at {scene.point_m} is outside camera {scene.camera!r}'s lens model")
    poly = np.round(outline).astype(np.int32)
    core = np.zeros(img.shape[:2], np.uint8)
    cv2.fillPoly(core, [poly], 255)
    size = max(2.0, float(np.ptp(outline[:, 0])), float(np.ptp(outline[:, 1])))
    glow = cv2.GaussianBlur(core, (0, 0), sigmaX=max(1.0, size / 3)).astype(np.float32) / 255.0
    glow = np.clip(glow * 2.5, 0.0, 1.0)[..., None]
    colour = np.array(_GLOW_BGR[scene.colour], np.float32)
    out = img.astype(np.float32) * (1 - glow) + colour * glow
    out[core > 0] = 255.0
    return np.clip(out, 0, 255).astype(np.uint8)


def score_scene(
    scene: LampScene,
    rig: Rig,
    image_bgr: np.ndarray,
    detector: LightDetector,
    *,
    match_px: float = 6.0,
) -> AzimuthResult:
    """Run ``detector`` on the rendered image and score the azimuth of the detection matched to the
    lamp (module docstring)."""
    cam = rig.camera(scene.camera)
    centre = np.asarray(scene.point_m, np.float64)
    rel = centre - cam.translation_m
    rng = float(np.linalg.norm(rel))
    true_az = math.degrees(math.atan2(rel[1], rel[0]))
    true_origin_az = math.degrees(math.atan2(centre[1], centre[0]))
    outline = _lamp_outline(scene, rig)
    target = outline.mean(axis=0)
    reach = match_px + 0.5 * max(float(np.ptp(outline[:, 0])), float(np.ptp(outline[:, 1])))
    best, best_d = None, math.inf
    for det in detector.detect(image_bgr):
        cx, cy = det.box.center
        d = math.hypot(cx - target[0], cy - target[1])
        if d < best_d:
            best, best_d = det, d
    if best is None or best_d > reach:
        return AzimuthResult(scene.camera, False, true_az, rng, None, None)
    u, v = best.box.center
    ray = rig.azimuth(scene.camera, u, v)
    at_range = rig.azimuth(scene.camera, u, v, range_m=rng)
    return AzimuthResult(
        scene.camera,
        True,
        true_az,
        rng,
        abs(_wrap(float(ray.azimuth_deg) - true_az)),
        abs(_wrap(float(at_range.azimuth_deg) - true_origin_az)),
    )


def random_scene(
    rig: Rig,
    rng: np.random.Generator,
    *,
    cameras: Sequence[str] | None = None,
    range_m: tuple[float, float] = (5.0, 40.0),
    max_off_axis_deg: float = 80.0,
    colour: str = "blue",
) -> LampScene:
    """A lamp at a random direction within ``max_off_axis_deg`` of a random camera's axis (and above
    the road: 0.8–2.5 m high), at a random range from the camera in ``range_m``."""
    names = list(cameras) if cameras is not None else rig.names
    name = names[int(rng.integers(len(names)))]
    cam = rig.camera(name)
    axis = cam.rotation @ np.array([0.0, 0.0, 1.0])
    for _ in range(1000):
        dist = float(rng.uniform(*range_m))
        yaw = math.atan2(axis[1], axis[0]) + math.radians(
            float(rng.uniform(-max_off_axis_deg, max_off_axis_deg))
        )
        z = float(rng.uniform(0.8, 2.5))
        horiz = math.sqrt(max(dist**2 - (z - cam.translation_m[2]) ** 2, 1.0))
        point = cam.translation_m + np.array([horiz * math.cos(yaw), horiz * math.sin(yaw), 0.0])
        point[2] = z
        d_cam = (point - cam.translation_m) @ cam.rotation
        off_axis = math.degrees(math.acos(d_cam[2] / np.linalg.norm(d_cam)))
        px = cam.camera.project(d_cam[None])[0]
        if off_axis <= max_off_axis_deg and np.all(np.isfinite(px)) and cam.camera.in_image(px[None])[0]:
            return LampScene(name, (float(point[0]), float(point[1]), float(point[2])), colour)
    raise RuntimeError(f"no lamp position found in camera {name!r}")
