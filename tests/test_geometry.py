"""Vehicle footprints (makeway.geometry): corners of a rotated rectangle and the gap between two."""

from __future__ import annotations

import math

import numpy as np
import pytest

from makeway.geometry import rect_distance, rectangle_corners


def test_the_corners_are_the_body_rectangle_rotated_and_moved() -> None:
    rng = np.random.default_rng(7)
    for _ in range(200):
        x, y, yaw = rng.uniform(-500, 500), rng.uniform(-500, 500), rng.uniform(-4, 4)
        length, width = rng.uniform(1, 12), rng.uniform(1, 3)
        rot = np.array([[math.cos(yaw), math.sin(yaw)], [-math.sin(yaw), math.cos(yaw)]])
        body = 0.5 * np.array([[length, width], [length, -width], [-length, -width], [-length, width]])
        expected = body @ rot + np.array([x, y])
        np.testing.assert_allclose(rectangle_corners(x, y, yaw, length, width), expected, rtol=0, atol=1e-12)


def test_gaps_between_rectangles() -> None:
    car = rectangle_corners(0.0, 0.0, 0.0, 4.0, 2.0)  # x in [-2, 2], y in [-1, 1]
    # side by side, 0.5 m apart: the edges' distance
    assert rect_distance(car, rectangle_corners(0.0, 2.5, 0.0, 4.0, 2.0)) == pytest.approx(0.5, abs=1e-12)
    # nose to tail, 1 m apart, the other one turned by 90°: x in [3, 5]
    assert rect_distance(car, rectangle_corners(4.0, 0.0, math.pi / 2, 2.0, 2.0)) == pytest.approx(
        1.0, abs=1e-12
    )
    # overlapping and touching
    assert rect_distance(car, rectangle_corners(1.0, 0.5, 0.3, 4.0, 2.0)) == 0.0
    assert rect_distance(car, rectangle_corners(4.0, 0.0, 0.0, 4.0, 2.0)) == pytest.approx(0.0, abs=1e-12)
    # far apart: the centres' distance less half the two boxes' larger sides (a lower bound)
    far = rectangle_corners(30.0, 40.0, 0.0, 6.0, 2.2)
    assert rect_distance(car, far) == pytest.approx(50.0 - 0.5 * (4.0 + 6.0), abs=1e-12)
    assert rect_distance(car, far) <= 50.0 - 2.0 - 3.0 + 1e-9
