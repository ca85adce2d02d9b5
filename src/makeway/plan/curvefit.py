"""Local curve fit of a reference path and the tracking errors against it (SPEC §6, seed 003).

Seed 003 is the project report of seed 001's work, which adds the complete feedback law and the
field-test figures (``../shared/seeds/003_…``, digested in SPEC §6).

Seed 003's controller does not use the path's stored heading and curvature directly: it takes the
``N`` path points nearest the vehicle, decides whether they form a straight line or an arc, fits that
primitive, and measures the vehicle against it. This module does exactly that:

* :func:`window` picks the ``N`` points (from the nearest one, going ahead along the path);
* :func:`fit_local` calls them a :class:`LineFit` when every point is within ``line_tolerance_m``
  of the chord from the first to the last point, otherwise an :class:`ArcFit` from
  :func:`fit_circle`;
* :func:`tracking_errors` turns the fit and the vehicle state into :class:`TrackingErrors`.

**Circle fit.** The algebraic least-squares circle minimises
``J = Σ (R² − (x_i − x_c)² − (y_i − y_c)²)²``. Expanding, each residual is linear in
``(x_c, y_c, c)`` with ``c = R² − x_c² − y_c²``::

    2 x_i x_c + 2 y_i y_c + c − (x_i² + y_i²)

so the minimiser is one linear least-squares solve (the "Kåsa" fit). The data are shifted to their
centroid and scaled by their RMS spread first, so the 3×3 problem stays well conditioned when the
points sit far from the origin (world coordinates of hundreds of metres) or span only a few metres.

**Signs** (``messages.py``): ``e_lat`` is positive when the vehicle is LEFT of the path looking along
the direction of travel; ``yaw_error = θ − θ_R`` wrapped to ``(−π, π]``;
``yaw_rate_error = θ̇ − v_x·κ_R`` with ``κ_R`` signed, positive for a left turn.

* Arc: seed 003 writes ``e_lat = R − √((X_v − X_c)² + (Y_v − Y_c)²)``, which is right for a LEFT
  turn (centre on the left, so being inside the circle means being left of the path). For a right
  turn the centre is on the right and the sign flips; in general ``e_lat = turn·(R − d)`` with
  ``turn = +1`` for a left (counter-clockwise) arc and ``−1`` for a right (clockwise) one.
* Line: the signed distance to the left of the travel direction ``u``,
  ``e_lat = (p − p_0)·n`` with ``n = (−u_y, u_x)``; for travel along ``+x`` this is seed 003's
  ``(y_v − m x_v − c)/√(1 + m²)``, for travel along ``−x`` its negative.
* ``θ_R`` is the direction of travel of the fitted primitive at the vehicle's projection onto it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from makeway.messages import ReferencePath, TrackingErrors

__all__ = [
    "ArcFit",
    "LineFit",
    "fit_circle",
    "fit_local",
    "nearest_point",
    "tracking_errors",
    "window",
    "wrap_angle",
]


def wrap_angle(angle_rad: float) -> float:
    """``angle_rad`` wrapped to ``(−π, π]``."""
    wrapped = math.remainder(angle_rad, 2.0 * math.pi)  # in [−π, π]
    return math.pi if wrapped == -math.pi else wrapped


@dataclass(frozen=True)
class LineFit:
    """A straight line through ``(x0, y0)`` with unit direction ``(ux, uy)`` along the travel."""

    x0: float
    y0: float
    ux: float
    uy: float

    @property
    def heading_rad(self) -> float:
        """Direction of travel, counter-clockwise from ``+x``."""
        return math.atan2(self.uy, self.ux)

    @property
    def slope_intercept(self) -> tuple[float, float]:
        """``(m, c)`` of ``y = m x + c``; ``ValueError`` for a vertical line."""
        if abs(self.ux) < 1e-12:
            raise ValueError("a vertical line has no slope-intercept form")
        m = self.uy / self.ux
        return m, self.y0 - m * self.x0


@dataclass(frozen=True)
class ArcFit:
    """A circle with centre ``(xc, yc)`` and ``radius``, travelled counter-clockwise (``turn = +1``,
    a left turn) or clockwise (``turn = −1``, a right turn)."""

    xc: float
    yc: float
    radius: float
    turn: int

    @property
    def curvature_1pm(self) -> float:
        """Signed curvature ``turn / R`` (positive for a left turn)."""
        return self.turn / self.radius


def fit_circle(xs: np.ndarray, ys: np.ndarray) -> tuple[float, float, float]:
    """Algebraic least-squares circle ``(xc, yc, R)`` through the points (module docstring).

    Needs at least three points that are not collinear; ``ValueError`` otherwise.
    """
    x = np.asarray(xs, dtype=float).ravel()
    y = np.asarray(ys, dtype=float).ravel()
    if x.shape != y.shape or x.size < 3:
        raise ValueError("fit_circle needs at least three (x, y) points of equal count")
    mx, my = float(x.mean()), float(y.mean())
    u, v = x - mx, y - my
    scale = float(np.sqrt(np.mean(u * u + v * v)))
    if not scale > 0.0:
        raise ValueError("fit_circle: all points coincide")
    u /= scale
    v /= scale
    design = np.column_stack([2.0 * u, 2.0 * v, np.ones_like(u)])
    rhs = u * u + v * v
    sol, _, rank, sv = np.linalg.lstsq(design, rhs, rcond=None)
    if rank < 3 or sv[-1] < 1e-9 * sv[0]:
        raise ValueError("fit_circle: points are collinear (no finite circle)")
    uc, vc, c = (float(t) for t in sol)
    r2 = c + uc * uc + vc * vc
    if not r2 > 0.0:
        raise ValueError("fit_circle: degenerate fit")
    return mx + uc * scale, my + vc * scale, math.sqrt(r2) * scale


def _turn_direction(x: np.ndarray, y: np.ndarray, xc: float, yc: float) -> int:
    """+1 when the points go counter-clockwise around ``(xc, yc)``, −1 clockwise."""
    rx, ry = x - xc, y - yc
    swept = float(np.sum(rx[:-1] * ry[1:] - ry[:-1] * rx[1:]))
    return 1 if swept >= 0.0 else -1


def fit_local(xs: np.ndarray, ys: np.ndarray, *, line_tolerance_m: float = 0.02) -> LineFit | ArcFit:
    """A :class:`LineFit` when every point lies within ``line_tolerance_m`` of the chord from the
    first to the last point, otherwise the least-squares :class:`ArcFit`. Point order is the
    direction of travel.

    The line is the total-least-squares line of the points (the chord itself when they are exactly
    collinear), directed from the first point towards the last. The line is also returned when the
    circle misses the points by more than the line does (an inflection inside the window, where
    the algebraic fit returns a small circle through the S), as seed 003's "fits a straight line
    better".
    """
    x = np.asarray(xs, dtype=float).ravel()
    y = np.asarray(ys, dtype=float).ravel()
    if x.shape != y.shape or x.size < 2:
        raise ValueError("fit_local needs at least two (x, y) points of equal count")
    cx, cy = float(x[-1] - x[0]), float(y[-1] - y[0])
    chord = math.hypot(cx, cy)
    if not chord > 0.0:
        raise ValueError("fit_local: first and last points coincide")
    ux, uy = cx / chord, cy / chord
    deviation = np.abs((x - x[0]) * uy - (y - y[0]) * ux)
    if x.size < 3 or float(deviation.max()) <= line_tolerance_m:
        return _fit_line(x, y, ux, uy)
    line = _fit_line(x, y, ux, uy)
    try:
        xc, yc, radius = fit_circle(x, y)
    except ValueError:
        return line
    # Seed 003 takes the line when "the data fits a straight line better": an S-bend (inflection
    # inside the window) gives a small circle that misses the points worse than the line does.
    arc_residual = float(np.max(np.abs(np.hypot(x - xc, y - yc) - radius)))
    line_residual = float(np.max(np.abs((x - line.x0) * line.uy - (y - line.y0) * line.ux)))
    if arc_residual >= line_residual:
        return line
    return ArcFit(xc=xc, yc=yc, radius=radius, turn=_turn_direction(x, y, xc, yc))


def _fit_line(x: np.ndarray, y: np.ndarray, ux: float, uy: float) -> LineFit:
    """Total-least-squares line, directed like the chord ``(ux, uy)``."""
    mx, my = float(x.mean()), float(y.mean())
    if x.size >= 3:
        pts = np.column_stack([x - mx, y - my])
        _, _, vt = np.linalg.svd(pts, full_matrices=False)
        dx, dy = float(vt[0, 0]), float(vt[0, 1])
        if dx * ux + dy * uy < 0.0:
            dx, dy = -dx, -dy
        ux, uy = dx, dy
    norm = math.hypot(ux, uy)
    return LineFit(x0=mx, y0=my, ux=ux / norm, uy=uy / norm)


def nearest_point(path: ReferencePath, x: float, y: float, hint: int | None = None) -> int:
    """Index of the path point nearest ``(x, y)``; with ``hint``, searched first in a band of points
    around it (the whole path when the nearest lies on the band's edge)."""
    n = len(path)
    if n == 0:
        raise ValueError("empty path")
    px, py = path.x_m, path.y_m
    if hint is not None and n > 200:
        lo = max(0, int(hint) - 50)
        hi = min(n, int(hint) + 150)
        d2 = (px[lo:hi] - x) ** 2 + (py[lo:hi] - y) ** 2
        k = int(np.argmin(d2))
        if (k > 0 or lo == 0) and (k < hi - lo - 1 or hi == n):
            return lo + k
    return int(np.argmin((px - x) ** 2 + (py - y) ** 2))


def window(
    path: ReferencePath,
    x: float,
    y: float,
    *,
    n_points: int = 10,
    hint: int | None = None,
    ahead: bool = True,
    stride: int = 1,
) -> tuple[np.ndarray, np.ndarray, int]:
    """The ``n_points`` path points the fit uses, and the index of the point nearest ``(x, y)``.

    With ``ahead`` the window starts at the nearest point and goes ahead along the path (shifted back
    near the path's end so it keeps ``n_points``); otherwise it is centred on the nearest point.
    ``stride`` takes every ``stride``-th path point (a window of the same length in metres whatever
    the path's resolution). ``hint`` (the last nearest index) narrows the search.
    """
    n = len(path)
    if n_points < 2:
        raise ValueError("n_points must be at least 2")
    if stride < 1:
        raise ValueError("stride must be at least 1")
    i0 = nearest_point(path, x, y, hint)
    stride = max(1, min(stride, (n - 1) // (n_points - 1))) if n > n_points else 1
    span = min((n_points - 1) * stride + 1, n)
    start = i0 if ahead else i0 - span // 2
    start = max(0, min(start, n - span))
    sl = slice(start, start + span, stride)
    return np.asarray(path.x_m[sl], dtype=float), np.asarray(path.y_m[sl], dtype=float), i0


def tracking_errors(
    fit: LineFit | ArcFit, x: float, y: float, yaw: float, yaw_rate: float, vx: float
) -> TrackingErrors:
    """Errors of a vehicle at ``(x, y)`` with heading ``yaw``, yaw rate and speed ``vx`` against the
    fitted primitive (signs in the module docstring)."""
    if isinstance(fit, LineFit):
        e_lat = (x - fit.x0) * -fit.uy + (y - fit.y0) * fit.ux
        theta_ref = fit.heading_rad
        kappa = 0.0
        kind = "line"
    else:
        rx, ry = x - fit.xc, y - fit.yc
        d = math.hypot(rx, ry)
        e_lat = fit.turn * (fit.radius - d)
        # tangent along the travel at the projection: the radius turned by +90° (left) or −90° (right)
        theta_ref = math.atan2(ry, rx) + fit.turn * 0.5 * math.pi if d > 0.0 else yaw
        kappa = fit.curvature_1pm
        kind = "arc"
    return TrackingErrors(
        e_lat=float(e_lat),
        yaw_error=wrap_angle(yaw - theta_ref),
        yaw_rate_error=float(yaw_rate - vx * kappa),
        curvature_1pm=float(kappa),
        kind=kind,
    )
