"""Reference paths and the pull-over manoeuvre (SPEC §6): geometry, intersection rules and CSV files."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from makeway.errors import InputError
from makeway.messages import ReferencePath
from makeway.plan.path import (
    curved_road,
    load_path_csv,
    make_path,
    min_transition_m,
    nearest_index,
    offset_path,
    point_at,
    pull_over_path,
    save_path_csv,
    straight_road,
)


def lateral_offsets(path: ReferencePath, base: ReferencePath) -> np.ndarray:
    """Signed offset of each path point from the base point of the same index (left positive)."""
    nx, ny = -np.sin(base.heading_rad), np.cos(base.heading_rad)
    return (path.x_m - base.x_m) * nx + (path.y_m - base.y_m) * ny


def quintic(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return 10 * u**3 - 15 * u**4 + 6 * u**5


# ------------------------------------------------------------------------------------------ make_path


def test_straight_points_have_zero_curvature_and_constant_heading() -> None:
    s = np.concatenate(([0.0], np.cumsum(np.random.default_rng(1).uniform(0.2, 1.5, 80))))
    h = 0.7
    p = make_path(3.0 + s * math.cos(h), -2.0 + s * math.sin(h))
    assert np.max(np.abs(p.curvature_1pm)) < 1e-9
    np.testing.assert_allclose(p.heading_rad, h, atol=1e-12)
    np.testing.assert_allclose(p.s_m, s, atol=1e-9)


def test_straight_road_is_exactly_straight() -> None:
    road = straight_road(100.0, start=(5.0, 1.0), heading_rad=-2.0, spacing_m=0.5)
    assert len(road) == 201
    assert np.all(road.curvature_1pm == 0.0)
    assert np.all(road.heading_rad == road.heading_rad[0])
    assert road.heading_rad[0] == pytest.approx(-2.0)
    assert road.s_m[-1] == pytest.approx(100.0)
    assert road.x_m[-1] == pytest.approx(5.0 + 100 * math.cos(-2.0))
    numeric = make_path(road.x_m, road.y_m)
    assert np.max(np.abs(numeric.curvature_1pm)) < 1e-9


@pytest.mark.parametrize("clockwise", [False, True])
def test_circle_points_have_curvature_one_over_r(clockwise: bool) -> None:
    R = 30.0
    t = np.linspace(0.0, 1.5, 150) ** 1.2  # uneven spacing
    sign = -1.0 if clockwise else 1.0
    p = make_path(R * np.cos(sign * t), R * np.sin(sign * t))
    np.testing.assert_allclose(p.curvature_1pm, sign / R, rtol=0.01)
    # heading is the tangent: perpendicular to the radius, in the direction of travel
    expected = sign * t + sign * math.pi / 2
    err = np.angle(np.exp(1j * (p.heading_rad - expected)))
    assert np.max(np.abs(err)) < 0.01


def test_make_path_drops_consecutive_duplicates_and_rejects_bad_input() -> None:
    p = make_path([0, 1, 1, 2, 2, 2, 3], [0, 0, 0, 0, 0, 0, 0], stop_s_m=2.5)
    assert len(p) == 4
    np.testing.assert_allclose(p.s_m, [0, 1, 2, 3])
    assert p.stop_s_m == 2.5
    with pytest.raises(ValueError, match="3 distinct"):
        make_path([0, 1, 1], [0, 0, 0])
    with pytest.raises(ValueError, match="finite"):
        make_path([0, 1, float("nan")], [0, 0, 0])
    with pytest.raises(ValueError, match="shape"):
        make_path([0, 1, 2], [0, 0])
    with pytest.raises(ValueError, match="stop_s_m"):
        make_path([0, 1, 2], [0, 0, 0], stop_s_m=5.0)


# ---------------------------------------------------------------------------------------- curved_road


def test_curved_road_arc_has_radius_r_on_the_left() -> None:
    R = 50.0
    road = curved_road(40.0, R, math.pi / 2, after_m=30.0, spacing_m=0.5)
    arc = (road.s_m > 40.0) & (road.s_m < 40.0 + R * math.pi / 2)
    # arc points lie on the circle centred (40, R)
    np.testing.assert_allclose(np.hypot(road.x_m[arc] - 40.0, road.y_m[arc] - R), R, atol=1e-9)
    np.testing.assert_allclose(road.curvature_1pm[arc], 1.0 / R)
    numeric = make_path(road.x_m, road.y_m)
    inner = arc & (road.s_m > 42.0) & (road.s_m < 40.0 + R * math.pi / 2 - 2.0)
    np.testing.assert_allclose(numeric.curvature_1pm[inner], 1.0 / R, rtol=0.01)
    assert road.heading_rad[-1] == pytest.approx(math.pi / 2)
    assert road.x_m[-1] == pytest.approx(40.0 + R)
    assert road.y_m[-1] == pytest.approx(R + 30.0)
    right = curved_road(40.0, R, math.pi / 2, left=False)
    assert right.y_m[-1] == pytest.approx(-R)
    assert np.min(right.curvature_1pm) == pytest.approx(-1.0 / R)


def test_clothoid_ramps_curvature_linearly() -> None:
    R, L = 60.0, 25.0
    road = curved_road(20.0, R, math.radians(60), after_m=20.0, clothoid_m=L, spacing_m=0.5)
    entry = (road.s_m >= 20.0) & (road.s_m <= 20.0 + L)
    np.testing.assert_allclose(road.curvature_1pm[entry], (road.s_m[entry] - 20.0) / (R * L), atol=1e-12)
    # the points agree with that curvature: numerical curvature from the points is the same ramp
    numeric = make_path(road.x_m, road.y_m)
    inside = (road.s_m > 21.0) & (road.s_m < 19.0 + L)
    slope, _ = np.polyfit(road.s_m[inside], numeric.curvature_1pm[inside], 1)
    assert slope == pytest.approx(1.0 / (R * L), rel=0.01)
    assert np.max(np.abs(numeric.curvature_1pm - road.curvature_1pm)) < 2e-4
    # curvature-continuous: no step anywhere, unlike the same curve without clothoids
    assert np.max(np.abs(np.diff(road.curvature_1pm))) < 1.01 * 0.5 / (R * L)
    plain = curved_road(20.0, R, math.radians(60), after_m=20.0)
    assert np.max(np.abs(np.diff(plain.curvature_1pm))) == pytest.approx(1.0 / R)
    assert road.heading_rad[-1] == pytest.approx(math.radians(60))
    with pytest.raises(ValueError, match="clothoid"):
        curved_road(10.0, 20.0, 0.5, clothoid_m=15.0)


# ---------------------------------------------------------------------------------------- offset_path


def test_offset_straight_line_right_is_parallel_at_the_distance() -> None:
    base = straight_road(80.0, heading_rad=0.4)
    side = offset_path(base, -3.5)
    d = lateral_offsets(side, base)
    np.testing.assert_allclose(d, -3.5, atol=1e-9)
    # right of the direction of travel: cross(tangent, point − base) < 0
    t = np.array([math.cos(0.4), math.sin(0.4)])
    v = np.array([side.x_m[10] - base.x_m[10], side.y_m[10] - base.y_m[10]])
    assert t[0] * v[1] - t[1] * v[0] == pytest.approx(-3.5)
    np.testing.assert_allclose(side.heading_rad, 0.4, atol=1e-12)
    assert np.max(np.abs(side.curvature_1pm)) < 1e-9
    assert side.s_m[-1] == pytest.approx(80.0)


def test_offset_arc_changes_radius_and_maps_stop() -> None:
    R = 40.0
    base = curved_road(10.0, R, math.pi / 2, after_m=10.0)
    base = ReferencePath(base.x_m, base.y_m, base.s_m, base.heading_rad, base.curvature_1pm, stop_s_m=50.0)
    side = offset_path(base, -3.5)  # outside of a left turn: larger radius, longer path
    arc = (base.s_m > 12.0) & (base.s_m < 10.0 + R * math.pi / 2 - 2.0)
    np.testing.assert_allclose(side.curvature_1pm[arc], 1.0 / (R + 3.5), rtol=0.01)
    assert side.s_m[-1] == pytest.approx(20.0 + (R + 3.5) * math.pi / 2, rel=1e-4)
    assert side.stop_s_m is not None
    x, y, _ = point_at(side, side.stop_s_m)
    bx, by, _ = point_at(base, 50.0)
    assert math.hypot(x - bx, y - by) == pytest.approx(3.5, abs=1e-3)
    with pytest.raises(ValueError, match="centre of a curve"):
        offset_path(base, 45.0)
    with pytest.raises(ValueError, match="one value per point"):
        offset_path(base, np.zeros(3))


# ------------------------------------------------------------------------------------ lane change size


def test_min_transition_closed_form_matches_the_quintic() -> None:
    D, T = 3.0, 40.0
    s = np.linspace(0.0, T, 100001)
    d = D * quintic(s / T)
    dd = np.gradient(np.gradient(d, s), s)
    assert np.max(np.abs(dd)) == pytest.approx(10 / math.sqrt(3) * D / T**2, rel=1e-4)
    v, a = 13.4, 2.0
    t = min_transition_m(v, -3.0, a)
    assert v * v * 10 / math.sqrt(3) * 3.0 / t**2 == pytest.approx(a)
    assert min_transition_m(2.0, -3.0) == 15.0
    assert min_transition_m(0.0, -3.0) == 15.0
    with pytest.raises(ValueError):
        min_transition_m(10.0, -3.0, 0.0)


# -------------------------------------------------------------------------------------- pull_over_path


@pytest.mark.parametrize("curved", [False, True])
def test_pull_over_reaches_offset_smoothly_within_lateral_accel(curved: bool) -> None:
    v, a_max, D = 13.4, 2.0, -3.0
    T = min_transition_m(v, D, a_max)
    if curved:
        base = curved_road(30.0, 300.0, math.radians(40), after_m=150.0, clothoid_m=40.0)
    else:
        base = straight_road(300.0)
    start = 25.0
    path = pull_over_path(base, start_s_m=start, offset_m=D, transition_m=T, stop_s_m=200.0)
    d = lateral_offsets(path, base)
    before, after = base.s_m <= start, base.s_m >= start + T
    np.testing.assert_allclose(d[before], 0.0, atol=1e-9)
    np.testing.assert_allclose(d[after], D, atol=1e-9)
    np.testing.assert_allclose(d, D * quintic((base.s_m - start) / T), atol=1e-9)
    # curvature-continuous: neighbouring points differ by no more than the quintic's κ' allows
    ds = float(np.max(np.diff(path.s_m)))
    jerk_bound = 60 * abs(D) / T**3 * ds + float(np.max(np.abs(np.diff(base.curvature_1pm))))
    dk = np.abs(np.diff(path.curvature_1pm))
    assert np.max(dk) < 1.1 * jerk_bound
    peak = abs(D) * 10 / math.sqrt(3) / T**2  # a cubic lane change would step by about this at its ends
    assert np.max(dk) < 0.15 * peak
    # lateral acceleration of the lane change itself (the road's own v²/R removed) within the bound
    road_kappa = base.curvature_1pm / (1 - d * base.curvature_1pm)  # the base offset by d
    lat = v * v * np.abs(path.curvature_1pm - road_kappa)
    assert np.max(lat) <= 1.01 * a_max
    assert np.max(lat) > 0.9 * a_max  # and the bound is tight: the transition is no longer than needed
    # the stop is where asked (no intersection), measured along the returned path
    assert path.stop_s_m is not None
    x, y, _ = point_at(path, path.stop_s_m)
    k = nearest_index(base, x, y)
    assert base.s_m[k] == pytest.approx(200.0, abs=0.5)


def test_stop_moves_back_before_intersection_with_clearance() -> None:
    base = straight_road(300.0)
    for asked in (120.0, 110.0, 133.0):  # inside, at the start, just after the end (rear still in)
        path = pull_over_path(
            base,
            start_s_m=10.0,
            offset_m=-3.0,
            transition_m=40.0,
            stop_s_m=asked,
            intersections=[(110.0, 130.0)],
            clearance_m=5.0,
        )
        assert path.stop_s_m is not None
        x, y, _ = point_at(path, path.stop_s_m)
        assert x == pytest.approx(105.0, abs=1e-6)
        assert y == pytest.approx(-3.0, abs=1e-9)  # stopped at the edge
    # a stop clear of the zone stays put; a stop in the zone of an earlier intersection too moves back
    far = pull_over_path(base, start_s_m=10.0, offset_m=-3.0, transition_m=40.0, stop_s_m=140.0,
                         intersections=[(110.0, 130.0)])  # fmt: skip
    assert far.stop_s_m is not None and point_at(far, far.stop_s_m)[0] == pytest.approx(140.0)
    two = pull_over_path(base, start_s_m=10.0, offset_m=-3.0, transition_m=40.0, stop_s_m=150.0,
                         intersections=[(150.0, 160.0), (110.0, 140.0)])  # fmt: skip
    assert two.stop_s_m is not None and point_at(two, two.stop_s_m)[0] == pytest.approx(105.0)


def test_lane_change_moved_out_of_intersection() -> None:
    base = straight_road(300.0)

    def plan(earliest: float | None) -> np.ndarray:
        path = pull_over_path(
            base,
            start_s_m=10.0,
            offset_m=-3.0,
            transition_m=40.0,
            stop_s_m=150.0,
            intersections=[(45.0, 60.0)],  # keep-out zone (40, 65) with the 5 m clearance
            clearance_m=5.0,
            earliest_start_s_m=earliest,
        )
        return lateral_offsets(path, base)

    d = plan(None)  # cannot start earlier than start_s_m: starts after the zone
    assert np.all(np.abs(d[base.s_m <= 65.0]) < 1e-9)  # in lane through the intersection and clearance
    assert np.all(np.abs(d[base.s_m >= 105.0] + 3.0) < 1e-9)
    assert 0.0 > d[base.s_m == 66.0][0] > -3.0
    d = plan(0.0)  # allowed to start earlier: finishes before the zone
    assert np.all(np.abs(d[base.s_m >= 40.0] + 3.0) < 1e-9)
    assert d[base.s_m == 1.0][0] < 0.0


def test_intersection_right_ahead_stops_in_lane() -> None:
    base = straight_road(300.0)
    path = pull_over_path(
        base, start_s_m=10.0, offset_m=-3.0, transition_m=40.0, stop_s_m=45.0, intersections=[(40.0, 55.0)]
    )
    np.testing.assert_array_equal(path.x_m, base.x_m)
    np.testing.assert_array_equal(path.y_m, base.y_m)
    assert path.stop_s_m == pytest.approx(35.0)


def test_start_inside_intersection_clears_it_then_pulls_over() -> None:
    base = straight_road(300.0)
    path = pull_over_path(
        base, start_s_m=50.0, offset_m=-3.0, transition_m=40.0, stop_s_m=55.0, intersections=[(40.0, 60.0)]
    )
    d = lateral_offsets(path, base)
    assert np.all(np.abs(d[base.s_m <= 65.0]) < 1e-9)
    assert path.stop_s_m is not None
    x, y, _ = point_at(path, path.stop_s_m)
    assert x == pytest.approx(105.0, abs=1e-6)  # after the change that starts past the zone (35, 65)
    assert y == pytest.approx(-3.0, abs=1e-9)


def test_stop_never_before_lane_change_ends_and_none_means_no_stop() -> None:
    base = straight_road(200.0)
    path = pull_over_path(base, start_s_m=20.0, offset_m=-3.0, transition_m=30.0, stop_s_m=25.0)
    assert path.stop_s_m is not None
    assert point_at(path, path.stop_s_m)[:2] == pytest.approx((50.0, -3.0))
    free = pull_over_path(base, start_s_m=20.0, offset_m=-3.0, transition_m=30.0, stop_s_m=None)
    assert free.stop_s_m is None
    assert free.y_m[-1] == pytest.approx(-3.0)
    short = pull_over_path(base, start_s_m=180.0, offset_m=-3.0, transition_m=30.0, stop_s_m=190.0)
    np.testing.assert_array_equal(short.y_m, base.y_m)  # cannot finish the change: stop in lane
    assert short.stop_s_m == pytest.approx(190.0)
    with pytest.raises(ValueError, match="no stop position"):
        pull_over_path(base, start_s_m=190.0, offset_m=-3.0, transition_m=30.0, stop_s_m=195.0,
                       intersections=[(185.0, 199.0)])  # fmt: skip


# ------------------------------------------------------------------------------------------------ CSV


def test_csv_round_trip(tmp_path: Path) -> None:
    road = curved_road(20.0, 40.0, 1.0, after_m=20.0, clothoid_m=10.0)
    out = tmp_path / "sub" / "path.csv"
    save_path_csv(out, road)
    assert out.read_text(encoding="utf-8").splitlines()[0] == "s,x,y,heading,curvature"
    assert [p.name for p in out.parent.iterdir()] == ["path.csv"]  # no temporary left behind
    back = load_path_csv(out)
    np.testing.assert_array_equal(back.x_m, road.x_m)
    np.testing.assert_array_equal(back.y_m, road.y_m)
    np.testing.assert_allclose(back.s_m, road.s_m, atol=1e-3)  # chord vs exact arc length
    again = make_path(road.x_m, road.y_m)  # heading and curvature are recomputed from the points
    np.testing.assert_array_equal(back.curvature_1pm, again.curvature_1pm)
    np.testing.assert_array_equal(back.heading_rad, again.heading_rad)
    np.testing.assert_allclose(back.curvature_1pm, road.curvature_1pm, atol=1e-3)


def test_csv_columns_any_order_with_extras(tmp_path: Path) -> None:
    f = tmp_path / "rec.csv"
    f.write_text("time, Y ,X,speed\n0,0,0,1\n\n1,0,1,1\n2,1,2,1\n3,2,3,1\n", encoding="utf-8")
    p = load_path_csv(f)
    np.testing.assert_allclose(p.x_m, [0, 1, 2, 3])
    np.testing.assert_allclose(p.y_m, [0, 0, 1, 2])


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        (b"x,y\n0,0\n1,\xff\xfe\n", "not UTF-8"),
        (b"", "empty"),
        (b"east,north\n0,0\n1,0\n2,0\n", "no column x or y in the header (found: 'east', 'north')"),
        (b"x,z\n0,0\n1,0\n2,0\n", "no column y in the header (found: 'x', 'z')"),
        (b"x,y\n0,0\n1,zero\n2,0\n", "line 3: column y value 'zero' is not a number"),
        (b"x,y\n0,0\n1,0\nnan,0\n", "line 4: column x value 'nan' is not finite"),
        (b"x,y\n0,0\n1,0\n2,inf\n", "line 4: column y value 'inf' is not finite"),
        (b"x,y\n0,0\n1,0\n1,0\n", "at least 3 distinct points"),
        (b"x,y\n0,0\n1\n", "line 3: 1 fields"),
    ],
)
def test_csv_errors_name_the_file(tmp_path: Path, content: bytes, needle: str) -> None:
    f = tmp_path / "bad_path.csv"
    f.write_bytes(content)
    with pytest.raises(InputError) as err:
        load_path_csv(f)
    assert err.value.path == f
    assert "bad_path.csv" in str(err.value)
    assert needle in err.value.problem


def test_csv_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"missing\.csv: file not found"):
        load_path_csv(tmp_path / "missing.csv")


# -------------------------------------------------------------------------------------------- look-ups


def test_nearest_index_with_and_without_hint_agree_on_a_curve() -> None:
    road = curved_road(50.0, 30.0, math.radians(170), after_m=50.0, clothoid_m=15.0)
    rng = np.random.default_rng(7)
    for k in rng.integers(0, len(road), 40):
        x = road.x_m[k] + rng.normal(0, 0.8)
        y = road.y_m[k] + rng.normal(0, 0.8)
        full = nearest_index(road, x, y)
        assert abs(full - k) <= 8
        assert nearest_index(road, x, y, hint=int(k) + int(rng.integers(-60, 60)), window=100) == full
    # where a hairpin passes close to itself, the hint keeps the match on the branch the car is on
    a = np.arange(0.0, 50.0, 0.5)
    turn = np.linspace(-math.pi / 2, math.pi / 2, 20)[1:-1]
    xs = np.concatenate((a, 50.0 + 1.5 * np.cos(turn), a[::-1]))
    ys = np.concatenate((np.zeros_like(a), 1.5 + 1.5 * np.sin(turn), np.full_like(a, 3.0)))
    hairpin = make_path(xs, ys)
    on_a = 50  # (25, 0) on the outbound branch; the car drifted 1.6 m left, nearer the return branch
    assert hairpin.y_m[nearest_index(hairpin, 25.0, 1.6)] == 3.0
    assert nearest_index(hairpin, 25.0, 1.6, hint=on_a, window=20) == on_a


def test_point_at_interpolates_and_unwraps_heading() -> None:
    road = straight_road(10.0, start=(1.0, 2.0))
    assert point_at(road, 3.25) == pytest.approx((4.25, 2.0, 0.0))
    assert point_at(road, -5.0) == pytest.approx((1.0, 2.0, 0.0))  # clamped
    # heading crosses ±π on a left turn that starts heading west-ish
    t = np.linspace(-0.3, 0.3, 61)
    p = make_path(np.cos(t + math.pi / 2) * 20, np.sin(t + math.pi / 2) * 20)  # heading ≈ π + t
    _, _, h = point_at(p, float(p.s_m[30]) + 0.01)
    assert abs(abs(h) - math.pi) < 0.01
