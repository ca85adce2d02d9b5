"""Hand calibration of a fixed roadside camera from road-plane landmarks.

Input: a points file — pixels ``(u, v)`` of landmarks on the road surface (ends of lane-marking
dashes, stop lines, kerb corners) with their road-frame coordinates ``(x_m, y_m)`` in metres
(``z = 0`` on the road; the frame of :mod:`makeway.roadside.transform`). Output: a
:class:`~makeway.roadside.transform.RoadCamera` — ``K``, one radial distortion term, and the pose
``[R|t]`` — that maps those pixels onto the road.

The fit (:func:`fit_road_camera`) is a nonlinear least-squares over the reprojection error
(pixels) of the landmarks: unknown rotation (3), camera centre (3), a single focal length
``f = fx = fy`` (pixels, square pixels) and, for the ``kannala_brandt`` model, its first
coefficient ``k1`` (``k2..k4 = 0``); the principal point is the image centre. It starts from
several focal lengths, each with the pose decomposed from the road-plane homography, and keeps the
best. :func:`leave_one_out_errors` refits without each point in turn and locates the held-out
pixel on the road with the refitted camera: the distance to its stated coordinates (metres) is its
held-out error.

The points file (CSV, ``#`` comments, a header line ``u,v,x_m,y_m``)::

    # u, v: pixels (origin top-left); x_m, y_m: road frame, metres
    u,v,x_m,y_m
    205,616,0.00,0.00
    ...
    # optional: where road lines of direction (dx, dy) meet in the image
    vanishing,1150,105,0,1
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy.optimize import least_squares

from makeway.errors import InputError
from makeway.roadside.csvfile import data_lines
from makeway.roadside.geodesy import LocalFrame
from makeway.roadside.transform import RoadCamera
from makeway.sense.camera import KannalaBrandtCamera, PinholeCamera

__all__ = [
    "MIN_POINTS",
    "VANISHING_SIGMA_PX",
    "RoadPoints",
    "fit_road_camera",
    "leave_one_out_errors",
    "read_road_points",
]

#: Fewest landmarks a fit accepts (8 unknowns; a hand calibration should have well over this).
MIN_POINTS = 8
_FOCAL_STARTS = (0.5, 0.7, 1.0, 1.4, 2.0)  # × image width
_FAR_M = 1e5  # a road point this far along a direction images as its vanishing point
#: Weight of a vanishing point in the fit: the pixel error it is given (its position is a judgement).
VANISHING_SIGMA_PX = 5.0


@dataclass(frozen=True)
class RoadPoints:
    """Landmarks: ``pixels`` ``(n, 2)`` and their road coordinates ``xy`` ``(n, 2)`` metres;
    ``vanishing`` ``(m, 4)``: vanishing points ``u, v`` of road directions ``dx, dy``."""

    pixels: np.ndarray
    xy: np.ndarray
    vanishing: np.ndarray


def read_road_points(path: str | Path) -> RoadPoints:
    """Read a points file (module docstring); InputError names the file and the line otherwise."""
    path = Path(path)
    rows: list[list[float]] = []
    vps: list[list[float]] = []
    header_seen = False
    for n, text, cells in data_lines(path, "points"):
        if not header_seen and cells == ["u", "v", "x_m", "y_m"]:
            header_seen = True
            continue
        vanishing = cells[0] == "vanishing"
        try:
            vals = [float(c) for c in cells[1:]] if vanishing else [float(c) for c in cells]
        except ValueError:
            raise InputError(path, f"line {n}: expected u,v,x_m,y_m numbers, got {text!r}") from None
        if vanishing:
            if len(vals) != 4 or not np.isfinite(vals).all() or vals[2] == vals[3] == 0:
                raise InputError(path, f"line {n}: expected vanishing,u,v,dx,dy (a direction), got {text!r}")
            vps.append(vals)
            continue
        if len(vals) != 4 or not np.isfinite(vals).all():
            raise InputError(path, f"line {n}: expected 4 finite numbers u,v,x_m,y_m, got {text!r}")
        rows.append(vals)
    if len(rows) < MIN_POINTS:
        raise InputError(path, f"has {len(rows)} points; a camera fit needs at least {MIN_POINTS}")
    data = np.array(rows, np.float64)
    return RoadPoints(data[:, :2], data[:, 2:], np.array(vps, np.float64).reshape(-1, 4))


def _project(params: np.ndarray, world: np.ndarray, cx: float, cy: float, model: str) -> np.ndarray:
    """Road points ``(n, 3)`` → pixels with params ``rvec(3), centre(3), f, k1``."""
    rot = cv2.Rodrigues(params[:3])[0]  # road → camera
    tvec = -rot @ params[3:6]
    f = params[6]
    k = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    if model == "kannala_brandt":
        d = np.array([params[7], 0.0, 0.0, 0.0])
        out = cv2.fisheye.projectPoints(world.reshape(-1, 1, 3), params[:3].reshape(3, 1), tvec, k, d)[0]
    else:
        out = cv2.projectPoints(world, params[:3], tvec, k, None)[0]
    return np.asarray(out, np.float64).reshape(-1, 2)


def _starts(pixels: np.ndarray, world: np.ndarray, width: int, cx: float, cy: float) -> list[np.ndarray]:
    """Initial poses: the road-plane homography decomposed for several focal lengths."""
    h, _ = cv2.findHomography(world[:, :2], pixels)
    out = []
    for scale in _FOCAL_STARTS:
        f = scale * width
        k = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
        m = np.linalg.solve(k, h)
        lam = 1.0 / np.linalg.norm(m[:, 0])
        r1, r2, t = lam * m[:, 0], lam * m[:, 1], lam * m[:, 2]
        if t[2] < 0:  # the road must lie in front of the camera
            r1, r2, t = -r1, -r2, -t
        u, _, vt = np.linalg.svd(np.stack([r1, r2, np.cross(r1, r2)], axis=1))
        rot = u @ vt
        if np.linalg.det(rot) < 0:
            continue
        centre = -rot.T @ t
        out.append(np.r_[cv2.Rodrigues(rot)[0].ravel(), centre, f, 0.0])
    return out


def fit_road_camera(
    pixels: Any,
    xy: Any,
    width: int,
    height: int,
    *,
    model: str = "kannala_brandt",
    origin: LocalFrame | None = None,
    vanishing: Any = None,
    vanishing_sigma_px: float = VANISHING_SIGMA_PX,
) -> tuple[RoadCamera, float]:
    """Fit a camera (module docstring) to landmark ``pixels`` ``(n, 2)`` and their road coordinates
    ``xy`` ``(n, 2)`` metres in a ``width`` × ``height`` image; the camera and the RMS reprojection
    error of the landmarks (pixels). ``model``: ``kannala_brandt`` (``f`` and ``k1``) or ``pinhole``
    (``f``). ``vanishing``: optional rows ``(u, v, dx, dy)`` — the pixel where road lines of
    horizontal direction ``(dx, dy)`` (road frame) meet — each weighted as a landmark with
    ``vanishing_sigma_px`` of error; it pins the camera's tilt where the landmarks alone leave it loose."""
    if model not in ("kannala_brandt", "pinhole"):
        raise ValueError(f"model must be kannala_brandt or pinhole, not {model!r}")
    px = np.asarray(pixels, np.float64)
    road = np.asarray(xy, np.float64)
    if px.shape != road.shape or px.ndim != 2 or px.shape[1] != 2 or len(px) < MIN_POINTS:
        raise ValueError(f"need at least {MIN_POINTS} pixel/road pairs of shape (n, 2)")
    world = np.c_[road, np.zeros(len(road))]
    cx, cy = 0.5 * width, 0.5 * height
    n_params = 8 if model == "kannala_brandt" else 7

    vp = np.zeros((0, 4)) if vanishing is None else np.asarray(vanishing, np.float64).reshape(-1, 4)

    def residual(p: np.ndarray) -> np.ndarray:
        full = p if n_params == 8 else np.r_[p, 0.0]
        out = (_project(full, world, cx, cy, model) - px).ravel()
        if len(vp):
            d = vp[:, 2:] / np.linalg.norm(vp[:, 2:], axis=1, keepdims=True)
            far = np.c_[full[3:5] + _FAR_M * d, np.zeros(len(d))]
            seen = (_project(full, far, cx, cy, model) - vp[:, :2]) / vanishing_sigma_px
            out = np.r_[out, seen.ravel()]
        return out

    best = None
    for start in _starts(px, world, width, cx, cy):
        try:
            r = least_squares(residual, start[:n_params], method="trf", max_nfev=4000)
        except (cv2.error, ValueError):
            continue
        if r.x[5] > 0 and r.x[6] > 0 and (best is None or r.cost < best.cost):
            best = r
    if best is None:
        raise ValueError("no camera fits these points (is the road in front of and below the camera?)")
    p = best.x if n_params == 8 else np.r_[best.x, 0.0]
    rot_wc = cv2.Rodrigues(p[:3])[0]
    f = float(p[6])
    if model == "kannala_brandt":
        camera: PinholeCamera | KannalaBrandtCamera = KannalaBrandtCamera(
            width, height, f, f, cx, cy, (float(p[7]), 0.0, 0.0, 0.0)
        )
    else:
        camera = PinholeCamera(width, height, f, f, cx, cy)
    rms = float(math.sqrt(np.mean(best.fun[: 2 * len(px)] ** 2)))
    return RoadCamera(camera, rot_wc.T.copy(), p[3:6].copy(), origin), rms


def leave_one_out_errors(
    pixels: Any, xy: Any, width: int, height: int, *, model: str = "kannala_brandt", vanishing: Any = None
) -> np.ndarray:
    """Held-out error (metres) of each point: refit without it (same ``model`` and ``vanishing``),
    locate its pixel on the road, and measure the distance to its road coordinates."""
    px = np.asarray(pixels, np.float64)
    road = np.asarray(xy, np.float64)
    err = np.empty(len(px))
    for i in range(len(px)):
        keep = np.arange(len(px)) != i
        cam, _ = fit_road_camera(px[keep], road[keep], width, height, model=model, vanishing=vanishing)
        err[i] = float(np.linalg.norm(cam.locate(px[i]) - road[i]))
    return err
