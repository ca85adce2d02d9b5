"""Bearings-only target motion analysis: how far a siren is from the bearings a moving car takes
of it over a few seconds, without its loudness (issue 25, item 1, the third level-free cue).

A siren moving at a constant velocity, heard from a car whose own path is known (odometry), leaves
a sequence of world bearings. The car's path over the window is split into its best straight,
constant-speed line and what is left, ``d(τ)`` (braking, speeding up, turning; ``τ = t − t_last``).
Relative to that line the siren moves at a constant velocity, so its position relative to the car
is ``r₀·(u(β₀) + τ·(ρ̇·u(β₀) + ω·u⊥(β₀))) − d(τ)``: **modified polar coordinates** ``(ln r₀, β₀, ρ̇,
ω)`` — the range, bearing, range rate over range and bearing rate at the last bearing's time, all
relative to the line. They are fitted to the bearings by iteratively reweighted Gauss–Newton
(Huber weights against the localizer's occasional wild bearing; Levenberg damping) with a
Gaussian prior on ``ln r₀``.

**When it can work.** Where the car keeps a straight line at a steady speed, ``d ≡ 0``, and every
``r₀`` fits the bearings equally well (Nardone & Aidala, 1981): the bearings give the direction
and the ratio of range rate to range, never the range. In these coordinates that ignorance stays
in ``ln r₀`` alone, so the fit returns the prior's range with the prior's σ there, and a σ well
below the prior's only where the car's own manoeuvre (or a siren standing still) gave the bearings
a scale. Use the σ: ``range_sigma_m`` is the posterior 1σ of the range.

Frames and units: world frame (m, s, rad), the same for the car's positions and the bearings;
bearings counter-clockwise from the world x axis (a vehicle-frame bearing ``θ`` from the
microphone array becomes ``yaw + θ``).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from makeway.perceive.audio.doa import wrap_angle

__all__ = ["PRIOR_LN_SIGMA", "PRIOR_RANGE_M", "BearingsOnlyFit", "BearingsOnlyRanger", "fit_bearings_only"]

#: The default prior on range: median (m) and σ of ln range (±1σ: 15–110 m).
PRIOR_RANGE_M = 40.0
PRIOR_LN_SIGMA = 1.0


@dataclass(frozen=True)
class BearingsOnlyFit:
    """One bearings-only fit (module docstring) at ``time_s`` (s), world frame.

    ``range_m`` — the emitter's distance from the observer; ``range_sigma_m`` — its posterior 1σ;
    ``ln_range_sigma`` — the posterior σ of ln range (the prior's where the bearings hold no
    scale); ``bearing_rad`` — the fitted bearing; ``rms_rad`` — RMS residual of the bearings with
    full weight; ``n`` — bearings used.
    """

    time_s: float
    range_m: float
    range_sigma_m: float
    ln_range_sigma: float
    bearing_rad: float
    rms_rad: float
    n: int


def _predict(q: np.ndarray, tau: np.ndarray, dev: np.ndarray) -> np.ndarray:
    """Bearings for parameters ``q = (ln r0, β0, ρ̇, ω)`` at offsets ``tau``, the observer's
    deviation from its line ``dev`` (n, 2)."""
    r0 = math.exp(q[0])
    c, s = math.cos(q[1]), math.sin(q[1])
    fx = c + tau * (q[2] * c - q[3] * s)
    fy = s + tau * (q[2] * s + q[3] * c)
    return np.arctan2(r0 * fy - dev[:, 1], r0 * fx - dev[:, 0])


def fit_bearings_only(
    times_s: Sequence[float] | np.ndarray,
    observer_xy_m: Sequence[Sequence[float]] | np.ndarray,
    bearings_rad: Sequence[float] | np.ndarray,
    *,
    sigma_rad: float = math.radians(3.0),
    prior_range_m: float = PRIOR_RANGE_M,
    prior_ln_sigma: float = PRIOR_LN_SIGMA,
    huber: float = 2.0,
    max_iter: int = 30,
) -> BearingsOnlyFit:
    """Fit a constant-velocity emitter to world ``bearings_rad`` taken at ``times_s`` (s) from
    ``observer_xy_m`` (``(n, 2)``, m) and return its range at the last time (module docstring).

    ``sigma_rad``: the bearing noise (the shipped localizer's median error is about 2.6°);
    ``prior_range_m``, ``prior_ln_sigma``: the Gaussian prior on ln range; ``huber``: residuals
    beyond this many ``sigma_rad`` are down-weighted.

    Raises:
        ValueError: fewer than 3 bearings, lengths that differ, times not increasing, non-finite
            values, or a non-positive ``sigma_rad``, ``prior_range_m``, ``prior_ln_sigma`` or
            ``huber``.
    """
    t = np.asarray(times_s, dtype=np.float64).ravel()
    e = np.asarray(observer_xy_m, dtype=np.float64).reshape(-1, 2)
    b = np.asarray(bearings_rad, dtype=np.float64).ravel()
    if not (len(t) == len(e) == len(b)):
        raise ValueError(f"{len(t)} times, {len(e)} observer positions and {len(b)} bearings")
    if len(t) < 3:
        raise ValueError(f"a bearings-only fit needs at least 3 bearings, got {len(t)}")
    if not (np.isfinite(t).all() and np.isfinite(e).all() and np.isfinite(b).all()):
        raise ValueError("times, observer positions and bearings must be finite")
    if np.any(np.diff(t) <= 0):
        raise ValueError("times must be strictly increasing")
    if not (sigma_rad > 0 and prior_range_m > 0 and prior_ln_sigma > 0 and huber > 0):
        raise ValueError("sigma_rad, prior_range_m, prior_ln_sigma and huber must be > 0")
    tau = t - t[-1]
    # the observer's best constant-velocity line through the window, and its deviation from it
    design = np.stack([np.ones_like(tau), tau], axis=1)
    line, *_ = np.linalg.lstsq(design, e, rcond=None)
    dev = e - design @ line
    # a start: the last bearing, the bearings' own rate, the prior's range, no range rate
    unwrapped = b[-1] + wrap_angle(b - b[-1])
    omega0 = float(np.polyfit(tau, unwrapped, 1)[0])
    mu = math.log(prior_range_m)
    info_prior = np.diag([1.0 / prior_ln_sigma**2, 0.0, 0.0, 0.0])

    def evaluate(q_: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        res = wrap_angle(b - _predict(q_, tau, dev)) / sigma_rad
        a = np.abs(res)
        w = np.where(a <= huber, 1.0, huber / np.maximum(a, 1e-12))
        rho = np.where(a <= huber, 0.5 * res * res, huber * a - 0.5 * huber * huber)
        return res, w, float(rho.sum() + 0.5 * ((q_[0] - mu) / prior_ln_sigma) ** 2)

    def jacobian(q_: np.ndarray) -> np.ndarray:
        base = _predict(q_, tau, dev)
        cols = []
        for j, h in enumerate((1e-6, 1e-7, 1e-7, 1e-7)):
            dq = np.zeros(4)
            dq[j] = h
            cols.append(wrap_angle(_predict(q_ + dq, tau, dev) - base) / h)
        return np.stack(cols, axis=1) / sigma_rad

    best: tuple[np.ndarray, float, np.ndarray, np.ndarray] | None = None
    for ln_r in (mu, math.log(10.0), math.log(150.0)):
        q = np.array([ln_r, float(b[-1]), 0.0, omega0])
        res, w, cost = evaluate(q)
        lam = 1e-3
        for _ in range(max_iter):
            jac = jacobian(q)
            info = jac.T @ (w[:, None] * jac) + info_prior
            grad = jac.T @ (w * res) - info_prior @ (q - np.array([mu, 0.0, 0.0, 0.0]))
            accepted = False
            for _ in range(8):
                try:
                    step = np.linalg.solve(info + lam * np.diag(np.diag(info) + 1e-9), grad)
                except np.linalg.LinAlgError:
                    lam *= 10.0
                    continue
                step[0] = float(np.clip(step[0], -1.0, 1.0))  # at most a factor e per step
                res_n, w_n, cost_n = evaluate(q + step)
                if cost_n <= cost:
                    done = cost - cost_n < 1e-10 * max(cost, 1.0) or float(np.abs(step).max()) < 1e-8
                    q, res, w, cost = q + step, res_n, w_n, cost_n
                    lam = max(lam / 10.0, 1e-9)
                    accepted = True
                    break
                lam *= 10.0
            if not accepted or done:
                break
        if best is None or cost < best[1]:
            best = (q, cost, w, res)
    assert best is not None
    q, _, w, res = best
    jac = jacobian(q)
    info = jac.T @ (w[:, None] * jac) + info_prior
    r0 = math.exp(q[0])
    rel0 = r0 * np.array([math.cos(q[1]), math.sin(q[1])]) - dev[-1]
    rng = float(np.hypot(*rel0))
    # d range / d q through rel0 = r0·u(β0) − dev(0): only ln r0 and β0 enter
    u = rel0 / max(rng, 1e-9)
    along = r0 * np.array([math.cos(q[1]), math.sin(q[1])])
    g = np.array([u @ along, u @ np.array([-along[1], along[0]]), 0.0, 0.0])
    try:
        cov = np.linalg.inv(info)
        var_r = float(g @ cov @ g)
        ln_sigma = math.sqrt(max(float(cov[0, 0]), 0.0))
        sigma = math.sqrt(var_r) if var_r >= 0 and math.isfinite(var_r) else math.inf
    except np.linalg.LinAlgError:
        sigma, ln_sigma = math.inf, math.inf
    kept = w >= 1.0
    resid = res[kept] * sigma_rad
    return BearingsOnlyFit(
        time_s=float(t[-1]),
        range_m=rng,
        range_sigma_m=sigma,
        ln_range_sigma=ln_sigma,
        bearing_rad=float(math.atan2(rel0[1], rel0[0])),
        rms_rad=float(np.sqrt(np.mean(resid**2))) if resid.size else math.nan,
        n=len(t),
    )


class BearingsOnlyRanger:
    """A sliding-window bearings-only ranger for one siren: :meth:`update` with each new world
    bearing and the observer's position; it fits the last ``window_s`` seconds
    (:func:`fit_bearings_only`) once it holds ``min_bearings`` of them.

    Args:
        window_s: how many seconds of bearings each fit uses.
        min_bearings: fewest bearings in the window for a fit.
        sigma_rad, prior_range_m, prior_ln_sigma, huber: as :func:`fit_bearings_only`.
    """

    def __init__(
        self,
        window_s: float = 3.0,
        min_bearings: int = 8,
        *,
        sigma_rad: float = math.radians(3.0),
        prior_range_m: float = PRIOR_RANGE_M,
        prior_ln_sigma: float = PRIOR_LN_SIGMA,
        huber: float = 2.0,
    ) -> None:
        if not (window_s > 0 and min_bearings >= 3):
            raise ValueError("window_s must be > 0 and min_bearings >= 3")
        self.window_s = float(window_s)
        self.min_bearings = int(min_bearings)
        self.sigma_rad, self.huber = sigma_rad, huber
        self.prior_range_m, self.prior_ln_sigma = prior_range_m, prior_ln_sigma
        self._history: deque[tuple[float, float, float, float]] = deque()

    def reset(self) -> BearingsOnlyRanger:
        """Forget every bearing (a new siren)."""
        self._history.clear()
        return self

    def update(
        self, time_s: float, observer_xy_m: Sequence[float], bearing_rad: float
    ) -> BearingsOnlyFit | None:
        """Add one bearing (world frame, rad) taken at ``time_s`` (s) from ``observer_xy_m`` (m);
        the fit over the window, or ``None`` while it holds too few bearings. A time not after
        the last one starts the window again."""
        if self._history and time_s <= self._history[-1][0]:
            self._history.clear()
        ox, oy = (float(v) for v in observer_xy_m)
        self._history.append((float(time_s), ox, oy, float(bearing_rad)))
        while self._history and self._history[0][0] < time_s - self.window_s:
            self._history.popleft()
        if len(self._history) < self.min_bearings:
            return None
        h = np.array(self._history)
        return fit_bearings_only(
            h[:, 0],
            h[:, 1:3],
            h[:, 3],
            sigma_rad=self.sigma_rad,
            prior_range_m=self.prior_range_m,
            prior_ln_sigma=self.prior_ln_sigma,
            huber=self.huber,
        )
