"""Bearings-only target motion analysis (makeway.track.bearings_only): exact on an observable
geometry, honest about the scale it cannot see, strict about its input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from makeway.track.bearings_only import PRIOR_LN_SIGMA, PRIOR_RANGE_M, BearingsOnlyRanger, fit_bearings_only

T = np.arange(0.0, 3.0, 1.0 / 6.0)


def _crossing(accel: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Observer along x at 13.4 m/s with ``accel``; an emitter crossing at x = 60 m, 12 m/s."""
    ex = 13.4 * T + 0.5 * accel * T * T
    obs = np.stack([ex, np.zeros_like(T)], axis=1)
    px, py = np.full_like(T, 60.0), -30.0 + 12.0 * T
    bearings = np.arctan2(py - obs[:, 1], px - obs[:, 0])
    return obs, bearings, math.hypot(px[-1] - ex[-1], py[-1])


def test_braking_observer_recovers_the_range_from_exact_bearings() -> None:
    obs, bearings, truth = _crossing(accel=-3.0)
    fit = fit_bearings_only(T, obs, bearings, prior_ln_sigma=1e3)
    assert fit.range_m == pytest.approx(truth, rel=1e-5)
    assert fit.bearing_rad == pytest.approx(bearings[-1], abs=1e-7)
    assert fit.rms_rad < 1e-6 and fit.n == len(T)
    # with the prior, how much the braking tells depends on how sharp the bearings are: at 0.1°
    # it ranges to 1 %, at the localizer's 3° it leaves the prior almost as it was
    sharp = fit_bearings_only(T, obs, bearings, sigma_rad=math.radians(0.1))
    assert sharp.range_m == pytest.approx(truth, rel=0.01) and sharp.ln_range_sigma < 0.15
    assert fit_bearings_only(T, obs, bearings).ln_range_sigma > 0.9 * PRIOR_LN_SIGMA


def test_steady_observer_cannot_see_the_scale_and_says_so() -> None:
    # a constant-velocity observer and emitter: every scaled copy of the track fits the bearings
    obs, bearings, _ = _crossing(accel=0.0)
    fit = fit_bearings_only(T, obs, bearings)
    assert fit.rms_rad < math.radians(0.01)  # the bearings are fitted ...
    # ... but they hold no scale: the range is the prior's, with the prior's σ
    assert fit.range_m == pytest.approx(PRIOR_RANGE_M, rel=1e-3)
    assert fit.ln_range_sigma == pytest.approx(PRIOR_LN_SIGMA, rel=1e-3)
    assert fit_bearings_only(T, obs, bearings, prior_range_m=90.0).range_m == pytest.approx(90.0, rel=1e-3)


def test_an_outlying_bearing_is_down_weighted() -> None:
    obs, bearings, _ = _crossing(accel=-3.0)
    spoiled = bearings.copy()
    spoiled[5] += math.radians(40.0)
    clean = fit_bearings_only(T, obs, bearings).range_m
    robust = fit_bearings_only(T, obs, spoiled).range_m
    plain = fit_bearings_only(T, obs, spoiled, huber=1e9).range_m  # least squares
    assert abs(robust - clean) < 0.5 * abs(plain - clean)


@pytest.mark.parametrize(
    ("times", "obs", "bearings", "message"),
    [
        ([0.0, 1.0], [[0, 0], [1, 0]], [0.1, 0.2], "at least 3"),
        ([0.0, 1.0, 2.0], [[0, 0], [1, 0]], [0.1, 0.2, 0.3], "observer positions"),
        ([0.0, 1.0, 1.0], [[0, 0], [1, 0], [2, 0]], [0.1, 0.2, 0.3], "increasing"),
        ([0.0, 1.0, 2.0], [[0, 0], [1, 0], [2, 0]], [0.1, math.nan, 0.3], "finite"),
    ],
)
def test_bad_input_is_refused(times: list, obs: list, bearings: list, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        fit_bearings_only(times, obs, bearings)


def test_ranger_waits_slides_and_restarts() -> None:
    obs, bearings, truth = _crossing(accel=-3.0)
    ranger = BearingsOnlyRanger(window_s=1.0, min_bearings=5, prior_ln_sigma=1e3)
    fits = [ranger.update(float(t), o, float(b)) for t, o, b in zip(T, obs, bearings, strict=True)]
    assert all(f is None for f in fits[:4]) and fits[4] is not None
    # a 1 s window at 6 Hz holds 7 bearings
    assert fits[-1] is not None and fits[-1].n == 7
    assert fits[-1].range_m == pytest.approx(truth, rel=1e-3)
    # a time that goes back starts a new window
    assert ranger.update(0.0, obs[0], float(bearings[0])) is None
    with pytest.raises(ValueError):
        BearingsOnlyRanger(min_bearings=2)
