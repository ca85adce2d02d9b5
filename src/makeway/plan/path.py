"""Reference paths: roads, lateral offsets and the pull-over manoeuvre (SPEC §6).

SPEC §6 asks the car to leave its lane for the right-hand edge with a one-lane change, clear of any
intersection, and stop. The field system replayed a recorded path; this module generates one.

Conventions (those of :mod:`makeway.messages`, world frame):

* Points in metres on the road plane, in the direction of travel. ``s_m`` is the arc length from the
  first point (cumulative chord length for paths built from points, the exact arc length for the
  generated roads; at 0.5 m spacing they differ by parts per million).
* ``heading_rad`` is counter-clockwise from +x, wrapped to [−π, π].
* ``curvature_1pm`` is signed: positive when the path turns left (counter-clockwise).
* Lateral offsets are along the left normal ``(−sin θ, cos θ)``: positive left, negative right (the
  right-hand edge of a right-hand-traffic road is at a negative offset).
* ``stop_s_m`` is measured along the path that carries it.

All functions are pure: they return new :class:`~makeway.messages.ReferencePath` objects and never
change their inputs.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from makeway.atomic import atomic_path
from makeway.errors import InputError
from makeway.messages import ReferencePath

__all__ = [
    "MIN_TRANSITION_M",
    "curved_road",
    "load_path_csv",
    "make_path",
    "min_transition_m",
    "nearest_index",
    "offset_path",
    "point_at",
    "pull_over_path",
    "save_path_csv",
    "straight_road",
]

MIN_TRANSITION_M = 15.0
"""No lane change is planned shorter than this, however slow the car (see :func:`min_transition_m`)."""

_DUPLICATE_TOL_M = 1e-9  # consecutive points closer than this are one point
_GAUSS_T, _GAUSS_W = np.polynomial.legendre.leggauss(32)  # nodes on [−1, 1] for clothoid integrals


# ------------------------------------------------------------------------------------------ from points


def make_path(x: ArrayLike, y: ArrayLike, *, stop_s_m: float | None = None) -> ReferencePath:
    """A reference path through the points ``(x, y)`` in the world frame (SPEC §6).

    Consecutive duplicate points are dropped. ``s`` is the cumulative chord length. Heading comes from
    the tangent ``(x', y')`` by central differences on the (possibly uneven) ``s`` grid, one-sided at
    the two ends. Curvature is ``κ = (x'y'' − y'x'')/(x'² + y'²)^1.5`` with the three-point
    second-order derivatives on the uneven grid (the end points copy their neighbour), then lightly
    smoothed with a ``[1, 2, 1]/4`` kernel. Points on a straight line give κ = 0 to rounding and
    points on a circle of radius R give a constant 1/R (error ≈ (Δs/R)²/4), because the smoothing
    keeps constant and linearly varying curvature unchanged.

    Args:
        x, y: one-dimensional point coordinates in metres, in the direction of travel.
        stop_s_m: where the vehicle must stop, along this path (``None``: no stop).

    Raises:
        ValueError: the arrays differ in shape or are not one-dimensional, hold NaN or inf, there
            are fewer than 3 distinct points, or ``stop_s_m`` is not within the path.
    """
    xa = np.asarray(x, dtype=np.float64)
    ya = np.asarray(y, dtype=np.float64)
    if xa.ndim != 1 or xa.shape != ya.shape:
        raise ValueError(f"x and y must be 1-D arrays of one length, got shapes {xa.shape} and {ya.shape}")
    if not (np.all(np.isfinite(xa)) and np.all(np.isfinite(ya))):
        raise ValueError("path points must be finite (found NaN or inf)")
    if len(xa) > 1:
        step = np.hypot(np.diff(xa), np.diff(ya))
        keep = np.concatenate(([True], step > _DUPLICATE_TOL_M))
        xa, ya = xa[keep], ya[keep]
    if len(xa) < 3:
        raise ValueError(f"a path needs at least 3 distinct points, got {len(xa)}")
    s = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(xa), np.diff(ya)))))
    stop = _check_stop(stop_s_m, float(s[-1]))
    heading, curvature = _heading_curvature(xa, ya, s)
    return ReferencePath(xa, ya, s, heading, curvature, stop_s_m=stop)


def _check_stop(stop_s_m: float | None, length_m: float) -> float | None:
    if stop_s_m is None:
        return None
    stop = float(stop_s_m)
    if not math.isfinite(stop) or stop < 0.0 or stop > length_m * (1 + 1e-12) + 1e-9:
        raise ValueError(f"stop_s_m={stop_s_m} is not within the path [0, {length_m:.3f}] m")
    return min(stop, length_m)


def _heading_curvature(x: np.ndarray, y: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Heading and smoothed curvature of points ``x, y`` at arc lengths ``s`` (at least 3 points)."""
    dx = np.gradient(x, s, edge_order=1)  # central (uneven-grid, second order) inside, one-sided at ends
    dy = np.gradient(y, s, edge_order=1)
    heading = np.arctan2(dy, dx)

    h1 = s[1:-1] - s[:-2]  # spacing behind each interior point
    h2 = s[2:] - s[1:-1]  # and ahead of it
    denom = h1 * h2 * (h1 + h2)
    ddx = 2.0 * (h1 * x[2:] - (h1 + h2) * x[1:-1] + h2 * x[:-2]) / denom
    ddy = 2.0 * (h1 * y[2:] - (h1 + h2) * y[1:-1] + h2 * y[:-2]) / denom
    vx, vy = dx[1:-1], dy[1:-1]
    inner = (vx * ddy - vy * ddx) / np.power(vx * vx + vy * vy, 1.5)
    kappa = np.concatenate(([inner[0]], inner, [inner[-1]]))
    padded = np.pad(kappa, 1, mode="edge")
    smooth = 0.25 * padded[:-2] + 0.5 * padded[1:-1] + 0.25 * padded[2:]
    return heading, smooth


# --------------------------------------------------------------------------------------- generated roads


def straight_road(
    length_m: float,
    *,
    start: tuple[float, float] = (0.0, 0.0),
    heading_rad: float = 0.0,
    spacing_m: float = 0.5,
) -> ReferencePath:
    """A straight lane centre line of ``length_m`` from ``start`` along ``heading_rad`` (SPEC §6).

    Points are evenly spaced, at most ``spacing_m`` apart (at least 3 points); curvature is 0 and the
    heading constant (wrapped to [−π, π]).

    Raises:
        ValueError: ``length_m`` or ``spacing_m`` not positive and finite.
    """
    _positive("length_m", length_m)
    _positive("spacing_m", spacing_m)
    n = max(3, math.ceil(length_m / spacing_m - 1e-9) + 1)
    s = np.linspace(0.0, float(length_m), n)
    h = math.atan2(math.sin(heading_rad), math.cos(heading_rad))
    x = float(start[0]) + s * math.cos(h)
    y = float(start[1]) + s * math.sin(h)
    return ReferencePath(x, y, s, np.full(n, h), np.zeros(n))


def curved_road(
    straight_m: float,
    radius_m: float,
    angle_rad: float,
    *,
    after_m: float = 0.0,
    spacing_m: float = 0.5,
    left: bool = True,
    clothoid_m: float = 0.0,
) -> ReferencePath:
    """A road from the origin along +x: straight, a curve of ``radius_m``, then straight (SPEC §6).

    The curve turns the heading by ``angle_rad`` in total (to the left when ``left``, else to the
    right). With ``clothoid_m > 0`` it enters and leaves through clothoids of that length, in which
    the curvature ramps linearly between 0 and ±1/R, so the road is curvature-continuous as real
    roads are; each clothoid turns ``clothoid_m/(2R)``, and the constant-radius arc between them turns
    the rest, ``angle_rad − clothoid_m/R``. With ``clothoid_m = 0`` the curvature steps at the ends of
    the arc. Heading and curvature are exact (analytic), ``s`` is the exact arc length and points are
    evenly spaced at most ``spacing_m`` apart.

    Raises:
        ValueError: a length or the radius negative/not finite, ``angle_rad`` not positive, or the
            clothoids turning more than ``angle_rad``.
    """
    _positive("radius_m", radius_m)
    _positive("angle_rad", angle_rad)
    _positive("spacing_m", spacing_m)
    for name, value in (("straight_m", straight_m), ("after_m", after_m), ("clothoid_m", clothoid_m)):
        _non_negative(name, value)
    arc_m = radius_m * angle_rad - clothoid_m  # each clothoid turns clothoid_m/(2R)
    if arc_m < -1e-9:
        raise ValueError(
            f"clothoids of {clothoid_m} m on radius {radius_m} m turn {clothoid_m / radius_m:.3f} rad, "
            f"more than angle_rad={angle_rad:.3f}"
        )
    k = (1.0 if left else -1.0) / radius_m
    segments = [
        (float(straight_m), 0.0, 0.0),
        (float(clothoid_m), 0.0, k),
        (max(arc_m, 0.0), k, k),
        (float(clothoid_m), k, 0.0),
        (float(after_m), 0.0, 0.0),
    ]
    segments = [seg for seg in segments if seg[0] > 0.0]
    total = sum(seg[0] for seg in segments)
    n = max(3, math.ceil(total / spacing_m - 1e-9) + 1)
    s = np.linspace(0.0, total, n)
    x, y, heading, curvature = (np.empty(n) for _ in range(4))
    x0 = y0 = th0 = 0.0
    s0 = 0.0
    for i, (length, k0, k1) in enumerate(segments):
        last = i == len(segments) - 1
        mask = (s >= s0) & ((s <= s0 + length) if last else (s < s0 + length))
        u = s[mask] - s0
        x[mask], y[mask], heading[mask], curvature[mask] = _segment(x0, y0, th0, length, k0, k1, u)
        ex, ey, eth, _ = _segment(x0, y0, th0, length, k0, k1, np.array([length]))
        x0, y0, th0 = float(ex[0]), float(ey[0]), float(eth[0])
        s0 += length
    heading = np.arctan2(np.sin(heading), np.cos(heading))
    return ReferencePath(x, y, s, heading, curvature)


def _segment(
    x0: float, y0: float, th0: float, length: float, k0: float, k1: float, u: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pose and curvature at distances ``u`` into a segment whose curvature goes linearly k0 → k1.

    Straight lines and arcs are evaluated in closed form; clothoids by 32-point Gauss–Legendre
    quadrature of ``(cos θ, sin θ)``, exact to rounding for the heading changes of road clothoids.
    """
    rate = (k1 - k0) / length
    heading = th0 + k0 * u + 0.5 * rate * u * u
    curvature = k0 + rate * u
    if rate == 0.0 and k0 == 0.0:
        return x0 + u * math.cos(th0), y0 + u * math.sin(th0), heading, curvature
    if rate == 0.0:
        x = x0 + (np.sin(heading) - math.sin(th0)) / k0
        y = y0 - (np.cos(heading) - math.cos(th0)) / k0
        return x, y, heading, curvature
    v = 0.5 * u[:, None] * (_GAUSS_T[None, :] + 1.0)  # quadrature nodes on [0, u]
    th = th0 + k0 * v + 0.5 * rate * v * v
    x = x0 + 0.5 * u * (np.cos(th) @ _GAUSS_W)
    y = y0 + 0.5 * u * (np.sin(th) @ _GAUSS_W)
    return x, y, heading, curvature


def _positive(name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{name} must be positive and finite, got {value}")


def _non_negative(name: str, value: float) -> None:
    if not (math.isfinite(value) and value >= 0.0):
        raise ValueError(f"{name} must be non-negative and finite, got {value}")


# -------------------------------------------------------------------------------------------- offsets


def offset_path(base: ReferencePath, offset_m: np.ndarray | float) -> ReferencePath:
    """``base`` moved sideways by ``offset_m`` along its left normal (negative: to the right; SPEC §6).

    ``offset_m`` is one number or one per base point. The points are ``p + d·(−sin θ, cos θ)``; arc
    length, heading and curvature are recomputed from them as in :func:`make_path`. A ``stop_s_m`` on
    the base moves to the same place along the new path (the same fraction between the same points).

    Raises:
        ValueError: a per-point offset of the wrong length, a non-finite offset, or an offset that
            reaches the centre of curvature of the base (``1 − d·κ ≤ 0``: the path would fold back).
    """
    n = len(base)
    d = np.broadcast_to(np.asarray(offset_m, dtype=np.float64), (n,)) if np.ndim(offset_m) == 0 else None
    if d is None:
        d = np.asarray(offset_m, dtype=np.float64)
        if d.shape != (n,):
            raise ValueError(f"offset_m must be a number or have one value per point ({n}), got {d.shape}")
    if not np.all(np.isfinite(d)):
        raise ValueError("offset_m must be finite")
    squeeze = 1.0 - d * base.curvature_1pm
    if np.any(squeeze <= 0.0):
        i = int(np.argmin(squeeze))
        raise ValueError(
            f"offset {d[i]:.2f} m at s={base.s_m[i]:.1f} m reaches the centre of a curve of radius "
            f"{1.0 / abs(base.curvature_1pm[i]):.2f} m"
        )
    x = base.x_m - d * np.sin(base.heading_rad)
    y = base.y_m + d * np.cos(base.heading_rad)
    stop = None
    if base.stop_s_m is not None:
        s_new = np.concatenate(([0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))))
        stop = float(np.interp(base.stop_s_m, base.s_m, s_new))
    return make_path(x, y, stop_s_m=stop)


# ------------------------------------------------------------------------------------------- pull over


def min_transition_m(speed_mps: float, offset_m: float, max_lat_accel: float = 2.0) -> float:
    """The shortest quintic lane change of ``offset_m`` at ``speed_mps`` within ``max_lat_accel``.

    The lateral profile is ``d(u) = D·(10u³ − 15u⁴ + 6u⁵)`` with ``u = s/T``, so
    ``d''(s) = (60·D/T²)·u(1 − u)(1 − 2u)``. That cubic peaks where ``6u² − 6u + 1 = 0``, at
    ``u = 1/2 ∓ √3/6``, with value ``√3/18``; hence ``max|d''| = (10/√3)·|D|/T²``. On a straight base
    the path curvature is ``d''/(1 + d'²)^1.5 ≤ |d''|``, so the peak lateral acceleration
    ``v²·|κ|`` stays within ``a_max`` when ``T ≥ v·√(10·|D|/(√3·a_max))``. The result is never shorter
    than :data:`MIN_TRANSITION_M` (15 m). On a curved base the road's own ``v²/R`` adds to this.

    Raises:
        ValueError: a negative or non-finite speed or offset, or ``max_lat_accel`` not positive.
    """
    _non_negative("speed_mps", speed_mps)
    _positive("max_lat_accel", max_lat_accel)
    if not math.isfinite(offset_m):
        raise ValueError(f"offset_m must be finite, got {offset_m}")
    needed = speed_mps * math.sqrt(10.0 * abs(offset_m) / (math.sqrt(3.0) * max_lat_accel))
    return max(MIN_TRANSITION_M, needed)


def pull_over_path(
    base: ReferencePath,
    *,
    start_s_m: float,
    offset_m: float,
    transition_m: float,
    stop_s_m: float | None,
    intersections: Sequence[tuple[float, float]] = (),
    clearance_m: float = 5.0,
    earliest_start_s_m: float | None = None,
) -> ReferencePath:
    """The pull-over path of SPEC §6: a lane change to the right-hand edge, clear of intersections, and
    a stop.

    The path follows ``base`` up to the start of the lane change, moves sideways to ``offset_m``
    (negative: right) with the quintic smoothstep ``d(u) = offset·(10u³ − 15u⁴ + 6u⁵)``,
    ``u = (s − start)/transition_m`` on the base's arc length — zero lateral slope and zero curvature
    change at both ends, so the path is curvature-continuous on straight bases and on
    curvature-continuous curved ones — and then runs parallel to ``base`` at ``offset_m`` to its end.
    Size ``transition_m`` with :func:`min_transition_m`.

    All arc lengths in the arguments are along ``base``. ``start_s_m`` is where the manoeuvre may begin
    (the caller puts it at or ahead of the car); it is clamped into the path. The returned path's
    ``stop_s_m`` is measured along the returned path.

    Intersections. Each ``(s_start, s_end)`` interval becomes a keep-out zone
    ``(s_start − clearance_m, s_end + clearance_m)`` (overlapping zones merge): the car's reference
    point kept ``clearance_m`` from either end keeps the whole body, plus a margin, out of the
    intersection. Rules, in order:

    1. *Lane change.* The change ``[start, start + transition_m]`` may not overlap a zone. If it does,
       it is started *earlier*, ending at the zone, when that start is not before
       ``earliest_start_s_m`` (default ``start_s_m``: by default never earlier, since the car cannot
       act behind itself) and overlaps no other zone; otherwise *later*, at the zone's far end — the
       car crosses the intersection in its lane and moves over after it. Repeated until clear.
    2. *Stop.* ``stop_s_m`` (clamped into ``[start_s_m, end of base]``) inside a zone moves *back* to
       the zone's near end. If that near end is behind ``start_s_m`` (the car is already in or at the
       intersection), it moves *forward* to the zone's far end instead, clear of the intersection.
    3. *Stop after the change.* A stop that would come before the lane change ends moves forward to
       its end, so the car stops parallel to the edge — when no zone lies in between.
    4. *Stop in lane.* If a zone does lie in between (an intersection right ahead, with no room to
       move over before it), or the base ends before the change would complete, the returned path is
       ``base`` itself, unshifted, with the stop of rule 2: **the car stops in its lane before the
       intersection**. Callers detect this by the path having no lateral offset (its points are the
       base's).

    With ``stop_s_m=None`` only rule 1 applies; if the base ends before the change completes, the
    path simply ends part-way through it.

    Raises:
        ValueError: a non-finite or non-positive ``transition_m``, a negative ``clearance_m``, an
            intersection with ``s_end < s_start``, no stop position clear of intersections on the
            path, or an offset that folds the path (see :func:`offset_path`).
    """
    _positive("transition_m", transition_m)
    _non_negative("clearance_m", clearance_m)
    if not math.isfinite(offset_m):
        raise ValueError(f"offset_m must be finite, got {offset_m}")
    if not math.isfinite(start_s_m):
        raise ValueError(f"start_s_m must be finite, got {start_s_m}")
    s_first, s_last = float(base.s_m[0]), float(base.s_m[-1])
    start = min(max(float(start_s_m), s_first), s_last)
    earliest = start if earliest_start_s_m is None else max(float(earliest_start_s_m), s_first)
    earliest = min(earliest, start)
    zones = _keep_out_zones(intersections, clearance_m)

    lc_start = _place_lane_change(start, float(transition_m), earliest, zones)
    lc_end = lc_start + float(transition_m)

    if stop_s_m is None:
        return _shifted(dataclasses.replace(base, stop_s_m=None), lc_start, transition_m, offset_m)

    if not math.isfinite(stop_s_m):
        raise ValueError(f"stop_s_m must be finite, got {stop_s_m}")
    stop = _clear_stop(min(max(float(stop_s_m), start), s_last), start, s_last, zones)
    if lc_end <= s_last and stop < lc_end and not _overlaps(zones, stop, lc_end):
        stop = lc_end  # rule 3
    if lc_end > s_last or stop < lc_end:  # rule 4: stop in lane before the intersection
        return dataclasses.replace(base, stop_s_m=stop)
    return _shifted(dataclasses.replace(base, stop_s_m=stop), lc_start, transition_m, offset_m)


def _keep_out_zones(
    intersections: Sequence[tuple[float, float]], clearance_m: float
) -> list[tuple[float, float]]:
    """Intersection intervals widened by the clearance on both sides, sorted and merged."""
    raw = []
    for pair in intersections:
        a, b = float(pair[0]), float(pair[1])
        if not (math.isfinite(a) and math.isfinite(b)) or b < a:
            raise ValueError(f"intersection interval {pair} must be finite with s_start <= s_end")
        raw.append((a - clearance_m, b + clearance_m))
    merged: list[tuple[float, float]] = []
    for lo, hi in sorted(raw):
        if merged and lo <= merged[-1][1]:
            merged[-1] = (merged[-1][0], max(merged[-1][1], hi))
        else:
            merged.append((lo, hi))
    return merged


def _overlaps(zones: list[tuple[float, float]], a: float, b: float) -> bool:
    """Whether the closed interval ``[a, b]`` enters the inside of any (open) zone."""
    return any(lo < b and hi > a for lo, hi in zones)


def _place_lane_change(
    start: float, length: float, earliest: float, zones: list[tuple[float, float]]
) -> float:
    """Rule 1 of :func:`pull_over_path`: where the lane change begins."""
    s = start
    for lo, hi in zones:  # sorted by lo; each zone is looked at once, s only grows after the first move
        if not (lo < s + length and hi > s):
            continue
        earlier = lo - length
        if s == start and earlier >= earliest and not _overlaps(zones, earlier, lo):
            return earlier
        s = hi
    return s


def _clear_stop(stop: float, start: float, s_last: float, zones: list[tuple[float, float]]) -> float:
    """Rule 2 of :func:`pull_over_path`: the stop moved out of every keep-out zone."""
    for lo, hi in reversed(zones):  # moving back can only enter zones further back
        if lo < stop < hi and lo >= start:
            stop = lo
    if any(lo < stop < hi for lo, hi in zones):  # the car is already at the intersection: clear it
        for lo, hi in zones:
            if lo < stop < hi:
                stop = hi
        if stop > s_last:
            raise ValueError(
                f"no stop position clear of intersections between s={start:.1f} m and the path end "
                f"s={s_last:.1f} m"
            )
    return stop


def _shifted(base: ReferencePath, lc_start: float, transition_m: float, offset_m: float) -> ReferencePath:
    u = np.clip((base.s_m - lc_start) / transition_m, 0.0, 1.0)
    d = offset_m * u**3 * (10.0 - 15.0 * u + 6.0 * u * u)
    return offset_path(base, d)


# ---------------------------------------------------------------------------------------------- files


#: the largest |x| or |y| a path file may hold, metres: a local frame (10,000 km)
MAX_COORDINATE_M = 1e7


def load_path_csv(path: str | Path) -> ReferencePath:
    """A recorded path from a CSV file with a header naming columns ``x`` and ``y`` (SPEC §6).

    Columns may come in any order and extra ones (``s``, ``heading``, ``time`` …) are ignored; header
    names are matched without surrounding spaces and case. Blank lines are skipped. Arc length,
    heading and curvature are recomputed by :func:`make_path`. A ``stop_s_m`` is not stored in CSV.

    Raises:
        InputError: naming the file, when it is missing, not UTF-8 text, empty, lacks an ``x`` or ``y``
            column (the columns found are listed), has a short row or a non-numeric value (with its
            line number), holds NaN or inf or a coordinate beyond :data:`MAX_COORDINATE_M`, or has
            fewer than 3 distinct points (or points too close to give a heading and curvature).
    """
    p = Path(path)
    if not p.exists():
        raise InputError(p, "file not found")
    if not p.is_file():
        raise InputError(p, "is not a file (expected a CSV with columns x and y)")
    try:
        text = p.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(
            p, f"is not UTF-8 text (byte {exc.start}); expected a CSV with columns x and y"
        ) from exc
    except OSError as exc:
        raise InputError(p, f"cannot be read: {exc.strerror or exc}") from exc
    try:  # newline="": a lone carriage return ends a line, as in a file opened by csv's own rules
        rows = [
            (n, row)
            for n, row in enumerate(csv.reader(io.StringIO(text, newline="")), start=1)
            if any(c.strip() for c in row)
        ]
    except csv.Error as exc:
        raise InputError(p, f"is not a readable CSV ({exc})") from None
    if not rows:
        raise InputError(p, "is empty; expected a header line with columns x and y")
    header_line, header = rows[0]
    names = [c.strip().lower() for c in header]
    missing = [c for c in ("x", "y") if c not in names]
    if missing:
        found = ", ".join(repr(c.strip()) for c in header)
        raise InputError(
            p, f"line {header_line}: no column {' or '.join(missing)} in the header (found: {found})"
        )
    ix, iy = names.index("x"), names.index("y")
    xs: list[float] = []
    ys: list[float] = []
    for line, row in rows[1:]:
        if len(row) <= max(ix, iy):
            raise InputError(
                p, f"line {line}: {len(row)} fields, but column x or y is field {max(ix, iy) + 1}"
            )
        for col, idx, out in (("x", ix, xs), ("y", iy, ys)):
            raw = row[idx].strip()
            try:
                value = float(raw)
            except ValueError:
                raise InputError(p, f"line {line}: column {col} value {raw!r} is not a number") from None
            if not math.isfinite(value):
                raise InputError(p, f"line {line}: column {col} value {raw!r} is not finite")
            if abs(value) > MAX_COORDINATE_M:
                raise InputError(
                    p,
                    f"line {line}: column {col} value {raw!r} is beyond ±{MAX_COORDINATE_M:g} m "
                    "(x and y are metres in a local frame)",
                )
            out.append(value)
    try:
        with np.errstate(divide="raise", over="raise", invalid="raise"):  # points too close, or too far
            return make_path(xs, ys)
    except (ValueError, FloatingPointError) as exc:
        raise InputError(p, f"not a usable path: {exc}") from None


def save_path_csv(path: str | Path, ref: ReferencePath) -> None:
    """Write ``ref`` as CSV with columns ``s,x,y,heading,curvature`` (metres, radians, 1/m), atomically.

    Values are written with Python's shortest round-trip repr, so :func:`load_path_csv` reads the
    same points back. ``stop_s_m`` is not stored.
    """
    lines = ["s,x,y,heading,curvature"]
    cols = (ref.s_m, ref.x_m, ref.y_m, ref.heading_rad, ref.curvature_1pm)
    for values in zip(*(np.asarray(c, dtype=np.float64).tolist() for c in cols), strict=True):
        lines.append(",".join(repr(float(v)) for v in values))
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8")


# ------------------------------------------------------------------------------------------- look-ups


def nearest_index(path: ReferencePath, x: float, y: float, hint: int | None = None, window: int = 200) -> int:
    """Index of the path point nearest to ``(x, y)`` (SPEC §6).

    With ``hint`` (for example last cycle's index in a closed loop), only indices
    ``hint − window … hint + window`` are searched (clamped to the path), which is O(window) and also
    keeps the match on the right branch where a path passes near itself.
    """
    n = len(path)
    lo, hi = 0, n
    if hint is not None:
        h = min(max(int(hint), 0), n - 1)
        w = max(int(window), 0)
        lo, hi = max(0, h - w), min(n, h + w + 1)
    dx = path.x_m[lo:hi] - x
    dy = path.y_m[lo:hi] - y
    return lo + int(np.argmin(dx * dx + dy * dy))


def lateral_offsets(path: ReferencePath, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """Signed lateral offset of each point ``(xs[i], ys[i])`` from ``path`` (left positive, SPEC §6
    sign convention), measured from the nearest path point along its left normal."""
    out = np.empty(len(xs))
    hint: int | None = None
    for i, (x, y) in enumerate(zip(xs, ys, strict=True)):
        hint = nearest_index(path, float(x), float(y), hint)
        h = path.heading_rad[hint]
        out[i] = -math.sin(h) * (x - path.x_m[hint]) + math.cos(h) * (y - path.y_m[hint])
    return out


def point_at(path: ReferencePath, s_m: float) -> tuple[float, float, float]:
    """``(x, y, heading)`` at arc length ``s_m`` by linear interpolation between path points (SPEC §6).

    ``s_m`` outside the path is clamped to its ends. The heading is interpolated on the unwrapped
    headings (no jump at ±π) and returned wrapped to [−π, π].
    """
    s_arr = path.s_m
    n = len(s_arr)
    k = int(np.clip(np.searchsorted(s_arr, s_m, side="right") - 1, 0, n - 2))
    u = min(max((s_m - s_arr[k]) / max(s_arr[k + 1] - s_arr[k], 1e-12), 0.0), 1.0)
    x = float(path.x_m[k] + u * (path.x_m[k + 1] - path.x_m[k]))
    y = float(path.y_m[k] + u * (path.y_m[k + 1] - path.y_m[k]))
    h0 = float(path.heading_rad[k])
    dh = math.atan2(math.sin(path.heading_rad[k + 1] - h0), math.cos(path.heading_rad[k + 1] - h0))
    h = h0 + u * dh  # the short way round: no jump at ±π
    return x, y, math.atan2(math.sin(h), math.cos(h))
