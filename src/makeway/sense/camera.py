"""Camera intrinsics: pixel ↔ ray for a pinhole camera and a Kannala–Brandt fisheye.

Frames and units:

* **Camera frame** (OpenCV axes): ``x`` right, ``y`` down, ``z`` forward along the optical axis;
  points in any length unit (only their direction matters), rays are unit vectors.
* **Pixels**: ``(u, v)``, ``u`` to the right and ``v`` down, in the image frame of
  :mod:`makeway.messages` (origin at the image's top-left); as in OpenCV, the centre of the top-left
  pixel is ``(0, 0)``. A pixel counts as in the image when ``0 ≤ u ≤ width`` and ``0 ≤ v ≤ height``
  (every pixel centre and a box edge at the image border). ``fx``, ``fy``, ``cx``, ``cy`` are in
  pixels, OpenCV's camera matrix ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` (no skew).

Models (looked up by name in :data:`CAMERA_MODELS`):

* ``pinhole`` — ``u = fx·X/Z + cx``, ``v = fy·Y/Z + cy``; no lens distortion (``k`` is ignored).
  Points with ``Z ≤ 0`` have no image.
* ``kannala_brandt`` — the 4-coefficient fisheye model in the convention of OpenCV's
  ``cv2.fisheye`` (Kannala & Brandt, IEEE TPAMI 28(8), 2006): a ray at angle ``θ`` from the optical
  axis lands at the normalised radius ``θ_d = θ·(1 + k1·θ² + k2·θ⁴ + k3·θ⁶ + k4·θ⁸)``, in the ray's own
  azimuth around the axis. Unlike OpenCV's projection (which works on ``X/Z`` and so only for
  ``Z > 0``), rays beyond 90° — present in a 180° lens's image corners — are handled.

Inversion (pixel → ray) of the fisheye polynomial is done here rather than by
``cv2.fisheye.undistortPoints``, which clamps ``θ_d`` at ``π/2`` and so cannot reach the rim of a
180° lens: Newton's method started from a tabulated inverse and kept inside a bracket (a step that
would leave the bracket is replaced by bisection). The model is used only where ``θ_d(θ)`` rises
strictly: from 0 to :attr:`KannalaBrandtCamera.theta_max` (the first ``θ`` where the derivative
vanishes, at most ``π``). Rays beyond it project to NaN, and pixels whose radius lies beyond
``θ_d(theta_max)`` unproject to NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from makeway.registry import Registry

__all__ = ["CAMERA_MODELS", "Camera", "KannalaBrandtCamera", "PinholeCamera"]

#: Camera models by the name a rig file gives in ``model:``; each entry is called with
#: ``(width, height, fx, fy, cx, cy, k)``.
CAMERA_MODELS: Registry[type[Camera]] = Registry("camera model")

_TABLE_SIZE = 2048  # samples of θ_d(θ) for the Newton start (start error ~1e-7 rad)
_NEWTON_MAX_ITER = 60  # bisection fallback halves the bracket: 60 steps reach machine precision
_NEWTON_TOL = 4e-15  # rad; a step this small is rounding (θ ≤ π)


@dataclass(frozen=True)
class Camera:
    """Intrinsics shared by every model: image size (pixels), focal lengths and principal point
    (pixels), and the model's distortion coefficients ``k`` (4 values; unused by the pinhole)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    k: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)

    model = "camera"  # the registry name, set by each model

    def __post_init__(self) -> None:
        if len(self.k) != 4:
            raise ValueError(f"k needs 4 coefficients, not {len(self.k)}")
        object.__setattr__(self, "k", tuple(float(c) for c in self.k))
        if not (self.width > 0 and self.height > 0):
            raise ValueError(f"image size must be positive, not {self.width}×{self.height}")
        if not (self.fx > 0 and self.fy > 0 and math.isfinite(self.fx) and math.isfinite(self.fy)):
            raise ValueError(f"focal lengths must be positive and finite, not fx={self.fx}, fy={self.fy}")

    @property
    def matrix(self) -> np.ndarray:
        """OpenCV's 3×3 camera matrix (pixels)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def in_image(self, pixels: Any) -> np.ndarray:
        """Whether each pixel ``(..., 2)`` lies in the image, ``0 ≤ u ≤ width``, ``0 ≤ v ≤ height``."""
        px = np.asarray(pixels, dtype=np.float64)
        u, v = px[..., 0], px[..., 1]
        return (u >= 0) & (u <= self.width) & (v >= 0) & (v <= self.height)

    def project(self, points_cam: Any) -> np.ndarray:
        """Points (or directions) ``(..., 3)`` in the camera frame → pixels ``(..., 2)``; NaN where
        the model gives the point no image."""
        raise NotImplementedError

    def unproject(self, pixels: Any) -> np.ndarray:
        """Pixels ``(..., 2)`` → unit rays ``(..., 3)`` in the camera frame; NaN where the model has
        no ray for the pixel."""
        raise NotImplementedError

    def theta_of_pixel(self, pixels: Any) -> np.ndarray:
        """Angle (rad) between each pixel's ray and the optical axis; NaN where there is no ray."""
        rays = self.unproject(pixels)
        return np.arctan2(np.hypot(rays[..., 0], rays[..., 1]), rays[..., 2])

    @property
    def image_theta_max(self) -> float:
        """The largest angle (rad) from the optical axis that a pixel of the image sees: at a corner,
        as the angle grows with the normalised radius; the model's own limit where a corner lies
        beyond it."""
        corners = [[0.0, 0.0], [self.width, 0.0], [0.0, self.height], [self.width, self.height]]
        theta = self.theta_of_pixel(corners)
        return self.theta_max if np.isnan(theta).any() else float(theta.max())

    @property
    def theta_max(self) -> float:
        """The largest angle (rad) from the optical axis the model covers (the pinhole: just under
        π/2)."""
        return math.pi / 2

    def to_dict(self) -> dict[str, Any]:
        """The intrinsics as a rig file's camera entry states them (without name and extrinsics)."""
        return {
            "model": self.model,
            "width": int(self.width),
            "height": int(self.height),
            "fx": float(self.fx),
            "fy": float(self.fy),
            "cx": float(self.cx),
            "cy": float(self.cy),
            "k": [float(c) for c in self.k],
        }

    def _normalised(self, pixels: Any) -> tuple[np.ndarray, np.ndarray]:
        px = np.asarray(pixels, dtype=np.float64)
        if px.shape[-1:] != (2,):
            raise ValueError(f"pixels must have shape (..., 2), not {px.shape}")
        return (px[..., 0] - self.cx) / self.fx, (px[..., 1] - self.cy) / self.fy

    def _to_pixels(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.stack([self.fx * x + self.cx, self.fy * y + self.cy], axis=-1)


def _points(points_cam: Any) -> np.ndarray:
    p = np.asarray(points_cam, dtype=np.float64)
    if p.shape[-1:] != (3,):
        raise ValueError(f"points must have shape (..., 3), not {p.shape}")
    return p


@CAMERA_MODELS.register("pinhole")
@dataclass(frozen=True)
class PinholeCamera(Camera):
    """An ideal pinhole camera (no distortion; ``k`` is ignored)."""

    model = "pinhole"

    def project(self, points_cam: Any) -> np.ndarray:
        p = _points(points_cam)
        z = np.where(p[..., 2] > 0, p[..., 2], np.nan)
        return self._to_pixels(p[..., 0] / z, p[..., 1] / z)

    def unproject(self, pixels: Any) -> np.ndarray:
        x, y = self._normalised(pixels)
        ray = np.stack([x, y, np.ones_like(x)], axis=-1)
        return ray / np.linalg.norm(ray, axis=-1, keepdims=True)


@CAMERA_MODELS.register("kannala_brandt")
@dataclass(frozen=True)
class KannalaBrandtCamera(Camera):
    """A fisheye lens in the 4-coefficient Kannala–Brandt model (OpenCV ``cv2.fisheye`` convention)."""

    model = "kannala_brandt"
    _theta_table: np.ndarray = field(init=False, repr=False, compare=False)
    _theta_d_table: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        super().__post_init__()
        theta = np.linspace(0.0, self.theta_max, _TABLE_SIZE)
        object.__setattr__(self, "_theta_table", theta)
        object.__setattr__(self, "_theta_d_table", self.theta_d(theta))

    @property
    def theta_max(self) -> float:
        """The largest angle from the optical axis (rad) the model covers: the first zero of
        ``dθ_d/dθ`` (beyond it the polynomial folds back), at most ``π``."""
        k1, k2, k3, k4 = self.k
        # dθ_d/dθ = 1 + 3k1·s + 5k2·s² + 7k3·s³ + 9k4·s⁴ with s = θ²
        roots = np.roots([9 * k4, 7 * k3, 5 * k2, 3 * k1, 1.0]) if any(self.k) else np.array([])
        s = [r.real for r in roots if abs(r.imag) <= 1e-12 * max(1.0, abs(r)) and r.real > 0]
        return min(math.pi, math.sqrt(min(s))) if s else math.pi

    @property
    def theta_d_max(self) -> float:
        """The largest normalised radius the model reaches, ``θ_d(theta_max)``."""
        return float(self.theta_d(self.theta_max))

    def theta_d(self, theta: Any) -> np.ndarray:
        """The distorted normalised radius ``θ_d`` for angles ``theta`` (rad) from the optical axis."""
        t = np.asarray(theta, dtype=np.float64)
        k1, k2, k3, k4 = self.k
        t2 = t * t
        return t * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))

    def _dtheta_d(self, t: np.ndarray) -> np.ndarray:
        k1, k2, k3, k4 = self.k
        t2 = t * t
        return 1.0 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))

    def theta(self, theta_d: Any) -> np.ndarray:
        """Invert :meth:`theta_d`: the angle (rad) for each normalised radius; NaN outside
        ``[0, theta_d_max]``. Newton's method from the tabulated inverse, safeguarded by a bracket."""
        td = np.asarray(theta_d, dtype=np.float64)
        out = np.full(td.shape, np.nan)
        table_t, table_d = self._theta_table, self._theta_d_table
        # a radius rounding a hair past the fold (a ray at exactly theta_max, projected) still counts
        ok = (td >= 0) & (td <= table_d[-1] * (1.0 + 1e-12))
        target = np.minimum(td[ok], table_d[-1])
        i = np.clip(np.searchsorted(table_d, target), 1, len(table_d) - 1)
        lo, hi = table_t[i - 1], table_t[i]
        d0, d1 = table_d[i - 1], table_d[i]
        th = lo + (target - d0) * (hi - lo) / (d1 - d0)
        active = np.arange(th.size)  # elements still moving; converged ones drop out
        with np.errstate(divide="ignore", invalid="ignore"):
            for _ in range(_NEWTON_MAX_ITER):
                t, goal, a, b = th[active], target[active], lo[active], hi[active]
                g = self.theta_d(t) - goal
                a = np.where(g < 0, t, a)
                b = np.where(g > 0, t, b)
                new = t - g / self._dtheta_d(t)
                new = np.where((new >= a) & (new <= b), new, 0.5 * (a + b))
                th[active] = new
                moving = np.abs(new - t) > _NEWTON_TOL
                lo[active], hi[active] = a, b
                active = active[moving]
                if active.size == 0:
                    break
        out[ok] = th
        return out

    def project(self, points_cam: Any) -> np.ndarray:
        p = _points(points_cam)
        r = np.hypot(p[..., 0], p[..., 1])
        theta = np.arctan2(r, p[..., 2])
        td = np.where(theta <= self.theta_max, self.theta_d(theta), np.nan)
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(r > 0, td / r, 0.0)
        scale = np.where(np.isnan(td), np.nan, scale)
        return self._to_pixels(p[..., 0] * scale, p[..., 1] * scale)

    def unproject(self, pixels: Any) -> np.ndarray:
        x, y = self._normalised(pixels)
        td = np.hypot(x, y)
        theta = self.theta(td)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(td > 0, np.sin(theta) / td, 1.0)
        return np.stack([x * s, y * s, np.cos(theta)], axis=-1)
