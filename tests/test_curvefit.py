"""Local line/arc fit and tracking errors (SPEC §6 "Curve fit and errors"; signs in messages.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from makeway.messages import ReferencePath
from makeway.plan.curvefit import (
    ArcFit,
    LineFit,
    fit_circle,
    fit_local,
    nearest_point,
    tracking_errors,
    window,
    wrap_angle,
)
from makeway.plan.path import make_path


def _path(x: np.ndarray, y: np.ndarray) -> ReferencePath:
    """A ReferencePath from points (the planner's own constructor)."""
    return make_path(x, y)


def _arc(
    xc: float, yc: float, r: float, start: float, sweep: float, n: int = 10
) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points on a circle from angle ``start`` over ``sweep`` (positive: counter-clockwise)."""
    t = start + np.linspace(0.0, sweep, n)
    return xc + r * np.cos(t), yc + r * np.sin(t)


# ------------------------------------------------------------------------------------------ circle


@pytest.mark.parametrize(
    ("xc", "yc", "r", "sweep"),
    [(0.0, 0.0, 10.0, 1.0), (350.0, -1200.0, 100.0, 0.1), (-5e3, 2e3, 1000.0, 0.01), (3.0, 4.0, 5.0, 6.0)],
)
def test_fit_circle_exact(xc: float, yc: float, r: float, sweep: float) -> None:
    x, y = _arc(xc, yc, r, 0.3, sweep)
    fx, fy, fr = fit_circle(x, y)
    assert fr == pytest.approx(r, rel=1e-7)
    assert fx == pytest.approx(xc, abs=1e-6 * r)
    assert fy == pytest.approx(yc, abs=1e-6 * r)


def test_fit_circle_noisy_within_one_percent() -> None:
    rng = np.random.default_rng(3)
    for r in (30.0, 100.0):
        x, y = _arc(20.0, -40.0, r, -0.5, 25.0 / r * 2.0, n=40)  # 50 m of arc
        x = x + rng.normal(0.0, 0.01, x.size)
        y = y + rng.normal(0.0, 0.01, y.size)
        _, _, fr = fit_circle(x, y)
        assert abs(fr / r - 1.0) < 0.01


def test_fit_circle_rejects_collinear_and_too_few() -> None:
    with pytest.raises(ValueError):
        fit_circle(np.arange(5.0), 2.0 * np.arange(5.0) + 1.0)
    with pytest.raises(ValueError):
        fit_circle(np.array([0.0, 1.0]), np.array([0.0, 1.0]))


# -------------------------------------------------------------------------------------------- lines


@pytest.mark.parametrize("heading_deg", [0.0, 30.0, 90.0, 135.0, 180.0, -90.0, -150.0])
def test_fit_local_exact_line_any_orientation(heading_deg: float) -> None:
    h = math.radians(heading_deg)
    t = np.linspace(0.0, 9.0, 10)
    x, y = 12.0 + t * math.cos(h), -7.0 + t * math.sin(h)
    fit = fit_local(x, y)
    assert isinstance(fit, LineFit)
    assert fit.ux == pytest.approx(math.cos(h), abs=1e-12)
    assert fit.uy == pytest.approx(math.sin(h), abs=1e-12)
    assert wrap_angle(fit.heading_rad - h) == pytest.approx(0.0, abs=1e-12)
    # a point on the line has no error; one 0.3 m to the left of travel has +0.3
    left = (-math.sin(h), math.cos(h))
    on = tracking_errors(fit, 15.0 * math.cos(h) + 12.0, 15.0 * math.sin(h) - 7.0, h, 0.0, 10.0)
    assert on.e_lat == pytest.approx(0.0, abs=1e-9)
    off = tracking_errors(fit, 12.0 + 0.3 * left[0], -7.0 + 0.3 * left[1], h, 0.0, 10.0)
    assert off.e_lat == pytest.approx(0.3, abs=1e-9)
    assert off.yaw_error == pytest.approx(0.0, abs=1e-12)
    assert off.kind == "line"
    assert off.curvature_1pm == 0.0


def test_line_slope_intercept_and_seed_formula() -> None:
    x = np.linspace(0.0, 9.0, 10)
    fit = fit_local(x, 2.0 * x + 1.0)
    assert isinstance(fit, LineFit)
    m, c = fit.slope_intercept
    assert (m, c) == (pytest.approx(2.0), pytest.approx(1.0))
    # travel along +x: seed 003's e_lat = (y − m x − c)/√(1 + m²)
    err = tracking_errors(fit, 1.0, 4.0, math.atan(2.0), 0.0, 10.0)
    assert err.e_lat == pytest.approx((4.0 - 2.0 - 1.0) / math.sqrt(5.0))
    assert err.e_lat == pytest.approx(0.4472136, abs=1e-7)
    # the same line travelled along −x: the same point is now on the right
    back = fit_local(x[::-1], (2.0 * x + 1.0)[::-1])
    assert tracking_errors(back, 1.0, 4.0, 0.0, 0.0, 10.0).e_lat == pytest.approx(-0.4472136, abs=1e-7)


def test_vertical_line() -> None:
    y = np.linspace(0.0, 9.0, 10)
    fit = fit_local(np.full(10, 2.0), y)
    assert isinstance(fit, LineFit)
    with pytest.raises(ValueError):
        _ = fit.slope_intercept
    # travel +y: left is −x, so x = 1.5 is 0.5 m left
    err = tracking_errors(fit, 1.5, 7.0, math.pi / 2 + 0.05, 0.0, 10.0)
    assert err.e_lat == pytest.approx(0.5)
    assert err.yaw_error == pytest.approx(0.05)


def test_travel_in_minus_x_signs_and_wrapping() -> None:
    x = np.linspace(10.0, 1.0, 10)  # travel along −x, θ_R = π
    fit = fit_local(x, np.zeros(10))
    err = tracking_errors(fit, 5.0, 0.3, math.pi - 0.1, 0.02, 10.0)
    assert err.e_lat == pytest.approx(-0.3)  # y = +0.3 is to the RIGHT when heading −x
    assert err.yaw_error == pytest.approx(-0.1)
    assert err.yaw_rate_error == pytest.approx(0.02)
    # heading just past −π is the same direction: the error wraps instead of jumping by 2π
    err = tracking_errors(fit, 5.0, 0.0, -math.pi + 0.1, 0.0, 10.0)
    assert err.yaw_error == pytest.approx(0.1)


def test_near_line_within_tolerance_is_a_line_beyond_is_an_arc() -> None:
    x = np.linspace(0.0, 9.0, 10)
    bump = 0.015 * np.sin(np.pi * x / 9.0)
    assert isinstance(fit_local(x, bump, line_tolerance_m=0.02), LineFit)
    assert isinstance(fit_local(x, 2.0 * bump, line_tolerance_m=0.02), ArcFit)


def test_s_bend_in_window_is_a_line_not_a_tiny_circle() -> None:
    x = np.linspace(-9.0, 9.0, 10)
    y = 1e-3 * x**3  # inflection at the middle; 0.73 m off the chord at the ends
    fit = fit_local(x, y)
    assert isinstance(fit, LineFit)


# --------------------------------------------------------------------------------------------- arcs


def test_left_turn_arc_signs() -> None:
    # counter-clockwise circle centred (0, 100), R = 100, starting at the origin heading +x
    x, y = _arc(0.0, 100.0, 100.0, -math.pi / 2, 0.2)
    fit = fit_local(x, y)
    assert isinstance(fit, ArcFit)
    assert fit.turn == 1
    assert fit.radius == pytest.approx(100.0, rel=1e-8)
    assert fit.curvature_1pm == pytest.approx(0.01, rel=1e-8)
    # 0.5 m inside the circle = left of the path: e_lat = R − d = +0.5 (seed 003's formula)
    err = tracking_errors(fit, 0.0, 0.5, 0.02, 0.12, 10.0)
    assert err.e_lat == pytest.approx(0.5, abs=1e-6)
    assert err.yaw_error == pytest.approx(0.02, abs=1e-9)  # θ_R = 0 at the projection
    assert err.yaw_rate_error == pytest.approx(0.12 - 10.0 * 0.01, abs=1e-9)
    assert err.kind == "arc"
    assert err.radius_m == pytest.approx(100.0, rel=1e-8)


def test_right_turn_arc_signs() -> None:
    # clockwise circle centred (0, −100) through the origin heading +x: a right turn
    x, y = _arc(0.0, -100.0, 100.0, math.pi / 2, -0.2)
    fit = fit_local(x, y)
    assert isinstance(fit, ArcFit)
    assert fit.turn == -1
    assert fit.curvature_1pm == pytest.approx(-0.01, rel=1e-8)
    # 0.5 m left of the path is OUTSIDE a right turn: e_lat = −(R − d) = +0.5
    err = tracking_errors(fit, 0.0, 0.5, 0.0, -0.1, 10.0)
    assert err.e_lat == pytest.approx(0.5, abs=1e-6)
    assert err.yaw_error == pytest.approx(0.0, abs=1e-9)
    assert err.yaw_rate_error == pytest.approx(0.0, abs=1e-9)  # −0.1 − 10·(−0.01)
    # 0.5 m to the right (inside): negative
    assert tracking_errors(fit, 0.0, -0.5, 0.0, 0.0, 10.0).e_lat == pytest.approx(-0.5, abs=1e-6)


def test_arc_points_ahead_of_the_vehicle() -> None:
    # the window lies a quarter turn ahead; the vehicle is where the arc starts, heading along it
    x, y = _arc(0.0, 100.0, 100.0, 0.0, 0.3)  # starting at (100, 100), heading +y
    fit = fit_local(x, y)
    assert isinstance(fit, ArcFit)
    phi = -0.01  # 1 m before the first point, on the circle
    err = tracking_errors(
        fit, 100.0 * math.cos(phi), 100.0 + 100.0 * math.sin(phi), math.pi / 2 + phi, 0.1, 10.0
    )
    assert err.e_lat == pytest.approx(0.0, abs=1e-6)
    assert err.yaw_error == pytest.approx(0.0, abs=1e-7)
    assert err.yaw_rate_error == pytest.approx(0.0, abs=1e-9)
    # the vehicle behind the window, 0.2 m right (outside the left turn)
    err = tracking_errors(fit, 100.2, 95.0, math.pi / 2 + 0.03, 0.1, 10.0)
    assert err.e_lat == pytest.approx(100.0 - math.hypot(100.2, 95.0 - 100.0), abs=1e-6)
    assert err.e_lat < 0.0


def test_noisy_arc_is_an_arc_with_radius_within_one_percent() -> None:
    rng = np.random.default_rng(7)
    x, y = _arc(-30.0, 60.0, 60.0, -1.0, -0.6, n=30)  # clockwise: right turn, 36 m of arc
    x = x + rng.normal(0.0, 0.005, x.size)
    y = y + rng.normal(0.0, 0.005, y.size)
    fit = fit_local(x, y)
    assert isinstance(fit, ArcFit)
    assert fit.turn == -1
    assert abs(fit.radius / 60.0 - 1.0) < 0.01


# ------------------------------------------------------------------------------------------- window


def test_window_ahead_centred_stride_and_ends() -> None:
    x = np.arange(0.0, 100.0, 0.5)
    path = _path(x, np.zeros_like(x))
    xs, _, i0 = window(path, 20.1, 0.4, n_points=10)
    assert i0 == 40
    np.testing.assert_allclose(xs, x[40:50])
    xs, _, _ = window(path, 20.1, 0.4, n_points=10, ahead=False)
    np.testing.assert_allclose(xs, x[35:45])
    xs, _, _ = window(path, 20.1, 0.4, n_points=10, stride=2)
    np.testing.assert_allclose(xs, x[40:59:2])
    # near the end the window is shifted back so it keeps its points
    xs, _, i0 = window(path, 120.0, 0.0, n_points=10)
    assert i0 == len(x) - 1
    assert xs.size == 10 and xs[-1] == x[-1]
    xs, _, i0 = window(path, -3.0, 0.0, n_points=10, ahead=False)
    assert i0 == 0
    np.testing.assert_allclose(xs, x[:10])


def test_nearest_point_with_hint_matches_global_search() -> None:
    s = np.arange(0.0, 600.0, 0.5)
    path = _path(s, 5.0 * np.sin(s / 40.0))
    rng = np.random.default_rng(0)
    for _ in range(50):
        k = int(rng.integers(0, len(s)))
        px, py = path.x_m[k] + rng.normal(0, 0.3), path.y_m[k] + rng.normal(0, 0.3)
        expect = nearest_point(path, px, py)
        for hint in (k, max(k - 30, 0), min(k + 100, len(s) - 1), 0):
            assert nearest_point(path, px, py, hint) == expect


def test_wrap_angle() -> None:
    assert wrap_angle(math.pi) == math.pi
    assert wrap_angle(-math.pi) == math.pi
    assert wrap_angle(3.0 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert wrap_angle(-7.0) == pytest.approx(-7.0 + 2.0 * math.pi)
