"""Lateral control: seed 003's feed-forward + feedback steering, its gain design, and two baselines.

Seed 003 is the project report of seed 001's work, which adds the complete feedback law and the
field-test figures (``../shared/seeds/003_…``, digested in SPEC §6).

**Feed-forward + feedback** (SPEC §6, seed 003). On every call the ``N`` path points nearest the
vehicle are fitted by a line or an arc (:mod:`makeway.plan.curvefit`), which gives the errors
``e_lat``, ``θ̃`` (yaw error), ``θ̃̇`` (yaw-rate error) and the signed curvature ``κ = 1/R``. Then::

    δ_ff = L/R + (m/L)(b/C_f − a/C_r)·v_x²/R          (signed with κ: positive for a left turn)
    δ_fb = −k_e·e_lat − k_θ·θ̃ − k_ω·θ̃̇
    δ_β  = k_θ·θ̃_ss,   θ̃_ss = (−b + m a v_x²/(L C_r))·κ
    δ    = δ_ff + δ_fb + δ_β

``δ_ff`` is the steady-state steering of the linear bicycle model on a circle of radius ``R`` (``C_f``,
``C_r`` per axle, as in :mod:`makeway.vehicle`). ``δ_β`` is not in seed 003: cornering steadily,
the car's heading differs from the path tangent by its sideslip angle, so ``θ̃`` settles at
``θ̃_ss ≠ 0`` and seed 003's ``−k_θ·θ̃`` then holds a lateral error ``k_θ θ̃_ss / k_e`` (on
R = 100 m at 15 m/s with the default gains: 1.8 cm). Feeding back ``θ̃ − θ̃_ss`` instead (Rajamani, *Vehicle
Dynamics and Control*, §3.2, the ``e2_ss`` term) removes it; ``sideslip_compensation=False`` gives
seed 003's law exactly.

**Window.** The fit uses ``n_points`` path points about ``point_spacing_m`` apart (a stride over
denser paths), centred on the nearest one by default — seed 003's "N nearest points" — because a
window that starts at the nearest point fits an arc that lies ahead of the car and makes the
feed-forward early (a larger peak error on the quintic lane change of the tests). The spacing matters because
of the line test: with 10 points 0.5 m apart every arc flatter than R ≈ 125 m is called a line
(sagitta under 2 cm) and the feed-forward is lost; 1 m apart, that limit is R ≈ 500 m.

**Gain design.** The feedback has a fixed structure: three gains on three measured errors. Seed 003
does not say how it tuned them; here they come from a structured (static output-feedback) LQR on
the path-error dynamics of the bicycle model (Rajamani, *Vehicle Dynamics and Control*, §3.2) with
the steering actuator lag as a fifth state::

    x = [e_lat, ė_lat, θ̃, θ̃̇, δ],   u = δ_cmd,   y = C x = [e_lat, θ̃, θ̃̇],   u = −K y

    ė_lat = v_y + v_x θ̃,   θ̃̇ = r − v_x κ,   δ̇ = (δ_cmd − δ)/τ_δ

and ``(v_y, r)`` eliminated through the single-track model. For ``A_cl = A − B K C`` the cost
``J(K) = E ∫ (xᵀQx + uᵀRu) dt = trace(P X₀)`` over initial states with covariance ``X₀`` has ``P``
from the Lyapunov equation ``A_clᵀP + P A_cl + Q + CᵀKᵀRKC = 0`` and the gradient
``∂J/∂K = 2 (R K C − BᵀP) Λ Cᵀ`` with ``A_cl Λ + Λ A_clᵀ + X₀ = 0`` (Levine & Athans 1970).
``J`` is minimised with BFGS from a stabilising start; unstable candidates are rejected (infinite
cost). Unlike state-feedback LQR the optimum depends on ``X₀``, so it is part of the design.

Weights (Bryson's rule, ``1/(acceptable value)²``): ``e_lat`` 0.02 m, ``θ̃`` 0.05 rad, ``θ̃̇`` 0.2 rad/s,
``δ_cmd`` 0.05 rad. ``X₀``: standard deviations 0.5 m, 0.2 m/s, 0.05 rad, 0.05 rad/s, 0.01 rad — a
lane-change-sized offset. One triple per speed on a grid; :meth:`GainSchedule.gains` interpolates
linearly and clamps outside the grid.

**Residual delay.** A steering transport delay is taken out of the loop by
:mod:`makeway.control.delay`, which predicts over a *nominal* delay (0.15 s); a real one may be
0.1–0.2 s. The gains are therefore designed on the error model with a residual delay of
``DESIGN_RESIDUAL_DELAY_S`` = 0.05 s in front of the actuator (first-order Padé,
:func:`path_error_model`), so that the loop they close on the design model stays stable for up to
±0.05 s of delay the prediction did not cover (checked: slowest pole of the design model with a
0.05 s residual delay −0.46 s⁻¹ at 30 m/s; a design without the Padé state, ``e_lat`` weighted
0.03 m, was unstable above 16 m/s with that residual delay, and CommonRoad's multi-body BMW went
into a growing weave with a real 0.2 s delay). At 13 m/s
this gives ``k_e`` 0.82 rad/m, ``k_θ`` 2.63, ``k_ω`` 0.40 s; the undelayed loop's slowest pole is
−1.6 s⁻¹ over 5–30 m/s.

Why these weights (the design model alone decides them). The yaw error a car holds on an arc is
its sideslip angle, which depends on its tyres — the least certain part of any car model; the
feedback turns a yaw-reference error ``Δθ`` into a lateral offset ``(k_θ/k_e)·Δθ``. Seed-003-like
weights (``e_lat`` 0.1 m, ``θ̃`` 0.02 rad, ``θ̃̇`` 0.1 rad/s, no residual delay) had ``k_θ/k_e`` = 7.6 m at
13 m/s: 1.5 mrad of sideslip the design model does not share cost 1 cm, and the lateral error
converged with a time constant near 1 s. Weighting ``e_lat`` more and ``θ̃`` less brings the ratio to
3.2 m; it also lowers the design car's own figure (seed003, linear plant, no delay: max |e_lat|
0.012 m instead of 0.014 m). Results on CommonRoad's cars: ``benchmarks/bench_robust_pull_over.py``.

**Baselines** on the same interface (δ, errors, nearest index), their errors computed the same way:

* :class:`Stanley` (Hoffmann et al. 2007): ``δ = −θ̃ − atan(k·e_front/(k_soft + v_x))`` with the
  cross-track error of the front axle;
* :class:`PurePursuit` (Coulter 1992): steer the rear axle onto a circle through the path point one
  look-ahead distance away, ``δ = atan(2 L sin α / ℓ_d)``.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property, lru_cache
from typing import Any, Protocol

import numpy as np
from scipy.linalg import solve_continuous_lyapunov
from scipy.optimize import minimize

from makeway.messages import ReferencePath, TrackingErrors, VehicleState
from makeway.plan.curvefit import ArcFit, LineFit, fit_local, tracking_errors, window
from makeway.registry import Registry
from makeway.vehicle import VehicleParams, lateral_dynamics_matrices

__all__ = [
    "DEFAULT_DESIGN_SPEEDS_MPS",
    "DESIGN_RESIDUAL_DELAY_S",
    "LATERAL_CONTROLLERS",
    "FeedforwardFeedback",
    "GainSchedule",
    "LateralController",
    "PurePursuit",
    "Stanley",
    "default_gains",
    "design_gains",
    "path_error_model",
]

DEFAULT_DESIGN_SPEEDS_MPS: tuple[float, ...] = tuple(float(v) for v in range(5, 31))
# Bryson weights: acceptable e_lat, ė_lat, θ̃, θ̃̇, δ (None: not weighted) and δ_cmd
_DEFAULT_STATE_SCALES: tuple[float | None, ...] = (0.02, None, 0.05, 0.2, None)
_DEFAULT_INPUT_SCALE = 0.05
# standard deviations of the initial error state (m, m/s, rad, rad/s, rad)
_DEFAULT_X0_STD: tuple[float, ...] = (0.5, 0.2, 0.05, 0.05, 0.01)
DESIGN_RESIDUAL_DELAY_S = 0.05
"""Steering transport delay the gains are designed to tolerate beyond what the delay compensation
predicts (s): the compensation assumes a nominal 0.15 s for a real 0.1–0.2 s (module docstring)."""


class LateralController(Protocol):
    """What every lateral controller offers: a steering command, the errors, the nearest index."""

    def steer(
        self, state: VehicleState, path: ReferencePath, hint: int | None = None
    ) -> tuple[float, TrackingErrors, int]: ...


# ------------------------------------------------------------------------------------------ design


def path_error_model(
    params: VehicleParams, vx: float, residual_delay_s: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(A, B, C)`` of the path-error model (module docstring) at speed ``vx``: state
    ``[e_lat, ė_lat, θ̃, θ̃̇, δ]``, input ``δ_cmd``, output ``[e_lat, θ̃, θ̃̇]``.

    With ``residual_delay_s`` > 0 a first-order Padé approximation of that transport delay sits
    between ``δ_cmd`` and the actuator, ``(1 − sT/2)/(1 + sT/2)``, as a sixth state ``z``
    (``ż = (2/T)(δ_cmd − z)``, the delayed command ``2z − δ_cmd``)."""
    A2, B2 = lateral_dynamics_matrices(params, vx)
    tau = params.steer_time_constant_s
    # with v_y = ė − v_x θ̃ and r = θ̃̇ (+ v_x κ, a constant that the feed-forward cancels):
    # ë = v̇_y + v_x θ̃̇,  θ̃̈ = ṙ
    A = np.zeros((5, 5))
    A[0, 1] = 1.0
    A[1, 1] = A2[0, 0]
    A[1, 2] = -A2[0, 0] * vx
    A[1, 3] = A2[0, 1] + vx
    A[1, 4] = B2[0, 0]
    A[2, 3] = 1.0
    A[3, 1] = A2[1, 0]
    A[3, 2] = -A2[1, 0] * vx
    A[3, 3] = A2[1, 1]
    A[3, 4] = B2[1, 0]
    A[4, 4] = -1.0 / tau
    B = np.zeros((5, 1))
    B[4, 0] = 1.0 / tau
    C = np.zeros((3, 5))
    C[0, 0] = C[1, 2] = C[2, 3] = 1.0
    if residual_delay_s <= 0.0:
        return A, B, C
    rate = 2.0 / residual_delay_s
    Ad = np.zeros((6, 6))
    Ad[:5, :5] = A
    Ad[:5, 5:] = 2.0 * B
    Ad[5, 5] = -rate
    Bd = np.zeros((6, 1))
    Bd[:5] = -B
    Bd[5, 0] = rate
    Cd = np.zeros((3, 6))
    Cd[:, :5] = C
    return Ad, Bd, Cd


@dataclass(frozen=True, eq=False)
class GainSchedule:
    """Feedback gains per design speed and the closed-loop eigenvalues of the error model there.

    ``eigenvalues`` has one row of five (complex) eigenvalues per speed, those of the loop without
    the residual delay; ``cost`` is ``J`` per speed (of the design with it).
    """

    speeds_mps: np.ndarray
    k_e: np.ndarray
    k_theta: np.ndarray
    k_omega: np.ndarray
    eigenvalues: np.ndarray
    cost: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def gains(self, vx: float) -> tuple[float, float, float]:
        """``(k_e, k_θ, k_ω)`` at ``vx``: linear between design speeds, clamped outside (the same
        arithmetic as ``np.interp``, without its per-call cost: the controller asks every 10 ms)."""
        v = float(vx)
        xs, rows = self._table
        n = len(xs)
        if v != v:  # NaN in, NaN out
            return v, v, v
        j = bisect_right(xs, v) - 1
        if j < 0:
            return rows[0]
        if j >= n - 1:
            return rows[n - 1]
        x0 = xs[j]
        if v == x0:
            return rows[j]
        lo, hi = rows[j], rows[j + 1]
        dx, u = xs[j + 1] - x0, v - x0
        return (
            (hi[0] - lo[0]) / dx * u + lo[0],
            (hi[1] - lo[1]) / dx * u + lo[1],
            (hi[2] - lo[2]) / dx * u + lo[2],
        )

    @cached_property
    def _table(self) -> tuple[list[float], list[tuple[float, float, float]]]:
        """The design speeds and the gains at each, as Python floats."""
        speeds = np.asarray(self.speeds_mps, dtype=float).tolist()
        gains = np.column_stack([self.k_e, self.k_theta, self.k_omega]).astype(float).tolist()
        return speeds, [(a, b, c) for a, b, c in gains]

    def max_real_eigenvalue(self) -> float:
        """The slowest closed-loop eigenvalue's real part over all design speeds."""
        return float(np.max(self.eigenvalues.real))


def _lqr_cost(
    k: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray, X0: np.ndarray
) -> tuple[float, np.ndarray]:
    K = k.reshape(1, -1)
    A_cl = A - B @ K @ C
    if np.max(np.linalg.eigvals(A_cl).real) >= -1e-6:
        return math.inf, np.zeros_like(k)
    P = solve_continuous_lyapunov(A_cl.T, -(Q + C.T @ K.T @ R @ K @ C))
    Lam = solve_continuous_lyapunov(A_cl, -X0)
    grad = 2.0 * (R @ K @ C - B.T @ P) @ Lam @ C.T
    return float(np.trace(P @ X0)), grad.ravel()


def _is_stable(k: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray) -> bool:
    return bool(np.max(np.linalg.eigvals(A - B @ k.reshape(1, -1) @ C).real) < -1e-6)


def design_gains(
    params: VehicleParams,
    speeds_mps: np.ndarray | Sequence[float] = DEFAULT_DESIGN_SPEEDS_MPS,
    *,
    state_scales: tuple[float | None, ...] = _DEFAULT_STATE_SCALES,
    input_scale: float = _DEFAULT_INPUT_SCALE,
    x0_std: tuple[float, ...] = _DEFAULT_X0_STD,
    residual_delay_s: float = DESIGN_RESIDUAL_DELAY_S,
) -> GainSchedule:
    """Structured LQR gains ``(k_e, k_θ, k_ω)`` per speed (module docstring).

    ``state_scales``/``input_scale`` are Bryson scales of ``[e_lat, ė_lat, θ̃, θ̃̇, δ]``/``δ_cmd``
    (``None``: state not weighted); ``x0_std`` the initial-state standard deviations;
    ``residual_delay_s`` the transport delay (s) the design model carries in front of its actuator
    (module docstring; 0: none).
    """
    speeds = np.asarray(speeds_mps, dtype=float).ravel()
    if speeds.size == 0 or np.any(speeds <= 0.0) or np.any(np.diff(speeds) <= 0.0):
        raise ValueError("speeds_mps must be positive and increasing")
    scales = list(state_scales)
    x0 = list(x0_std)
    if residual_delay_s > 0.0:  # the Padé state: not weighted, started like δ
        scales.append(None)
        x0.append(x0[-1])
    Q = np.diag([0.0 if s is None else 1.0 / s**2 for s in scales])
    R = np.array([[1.0 / input_scale**2]])
    X0 = np.diag(np.asarray(x0, dtype=float) ** 2)
    starts = [np.array(g) for g in ((0.1, 0.5, 0.05), (0.05, 0.3, 0.02), (0.2, 1.0, 0.1), (0.02, 0.2, 0.0))]
    previous: np.ndarray | None = None
    rows_k, rows_eig, costs = [], [], []
    for vx in speeds:
        A, B, C = path_error_model(params, float(vx), residual_delay_s)
        candidates = ([previous] if previous is not None else []) + starts
        k0 = next((c for c in candidates if _is_stable(c, A, B, C)), None)
        if k0 is None:
            raise RuntimeError(f"no stabilising start for the gain design at {vx:.1f} m/s")
        res = minimize(
            _lqr_cost, k0, args=(A, B, C, Q, R, X0), jac=True, method="BFGS", options={"gtol": 1e-6}
        )
        k = res.x if np.isfinite(res.fun) and _is_stable(res.x, A, B, C) else k0
        cost, _ = _lqr_cost(k, A, B, C, Q, R, X0)
        rows_k.append(k)
        # the eigenvalues of the loop without the residual delay (the compensated nominal loop)
        A0, B0, C0 = path_error_model(params, float(vx))
        rows_eig.append(np.linalg.eigvals(A0 - B0 @ k.reshape(1, -1) @ C0))
        costs.append(cost)
        previous = k
    K = np.array(rows_k)
    return GainSchedule(
        speeds_mps=speeds,
        k_e=K[:, 0].copy(),
        k_theta=K[:, 1].copy(),
        k_omega=K[:, 2].copy(),
        eigenvalues=np.array(rows_eig),
        cost=np.array(costs),
    )


@lru_cache(maxsize=8)
def default_gains(params: VehicleParams) -> GainSchedule:
    """:func:`design_gains` with its defaults, computed once per parameter set."""
    return design_gains(params)


# ----------------------------------------------------------------------------------- controllers


def _stride(path: ReferencePath, point_spacing_m: float | None) -> int:
    """Path points to step per window point so that they lie about ``point_spacing_m`` apart."""
    if point_spacing_m is None or len(path) < 2:
        return 1
    ds = float(path.s_m[-1] - path.s_m[0]) / (len(path) - 1)
    return max(1, round(point_spacing_m / ds)) if ds > 0.0 else 1


def _fit_errors(
    state: VehicleState,
    path: ReferencePath,
    hint: int | None,
    n_points: int,
    line_tolerance_m: float,
    point_spacing_m: float | None = None,
    ahead: bool = True,
    cache: dict[bytes, LineFit | ArcFit] | None = None,
) -> tuple[TrackingErrors, int, LineFit | ArcFit]:
    xs, ys, index = window(
        path,
        state.x_m,
        state.y_m,
        n_points=n_points,
        hint=hint,
        ahead=ahead,
        stride=_stride(path, point_spacing_m),
    )
    fit: LineFit | ArcFit | None = None
    key = b""
    if cache is not None:
        # the same window points give the same fit: look it up by the points' bytes
        key = xs.tobytes() + ys.tobytes()
        fit = cache.get(key)
    if fit is None:
        fit = fit_local(xs, ys, line_tolerance_m=line_tolerance_m)
        if cache is not None:
            if len(cache) >= _FIT_CACHE_SIZE:
                cache.pop(next(iter(cache)))
            cache[key] = fit
    errors = tracking_errors(fit, state.x_m, state.y_m, state.yaw_rad, state.yaw_rate_radps, state.vx_mps)
    return errors, index, fit


_FIT_CACHE_SIZE = 32
"""Local fits a controller remembers (the path's window moves one point every few control periods,
and the delay compensation fits two windows per period: the one of the state predicted 0.15 s
ahead, which the present state reaches some 10–20 windows later)."""


class _LocalFitController:
    """What the three controllers share: the local fit and the errors (so all report alike).

    ``n_points`` path points about ``point_spacing_m`` apart (``None``: consecutive path points),
    centred on the nearest one (or from it onwards with ``ahead``), fitted with ``line_tolerance_m``.
    """

    def __init__(
        self,
        params: VehicleParams,
        *,
        n_points: int = 10,
        line_tolerance_m: float = 0.02,
        point_spacing_m: float | None = 1.0,
        ahead: bool = False,
    ) -> None:
        self.params = params
        self.n_points = n_points
        self.line_tolerance_m = line_tolerance_m
        self.point_spacing_m = point_spacing_m
        self.ahead = ahead
        self._fits: dict[bytes, LineFit | ArcFit] = {}

    def _errors(
        self, state: VehicleState, path: ReferencePath, hint: int | None
    ) -> tuple[TrackingErrors, int, LineFit | ArcFit]:
        return _fit_errors(
            state,
            path,
            hint,
            self.n_points,
            self.line_tolerance_m,
            self.point_spacing_m,
            self.ahead,
            self._fits,
        )

    def errors(
        self, state: VehicleState, path: ReferencePath, hint: int | None = None
    ) -> tuple[TrackingErrors, int]:
        """The errors of ``state`` against ``path`` as :meth:`steer` measures them, and the nearest
        index, without steering (e.g. of the true state while the controller steers on an
        estimate)."""
        errors, index, _ = self._errors(state, path, hint)
        return errors, index


class FeedforwardFeedback(_LocalFitController):
    """Seed 003's steering law ``δ = δ_ff + δ_fb`` (module docstring) with scheduled gains.

    With ``sideslip_compensation`` (default) the yaw error is fed back relative to its steady-state
    value on the fitted arc (``δ_β`` in the module docstring); without it the law is seed 003's.
    ``gains`` default to :func:`default_gains` for ``params``.

    Design, in short: the gains ``k_e`` (rad/m), ``k_θ`` (rad/rad) and ``k_ω`` (s) come from the
    structured LQR of the module docstring on the design car alone (``params``, the linear
    single-track model with its 0.1 s steering lag as a state, and a 0.05 s residual transport
    delay as a Padé state), scheduled over 5–30 m/s. The nominal steering delay (0.15 s) is taken
    out by :class:`~makeway.control.delay.DelayCompensated` (``mean`` predictor), which lets this
    law steer on the state predicted over it; the residual term covers a real delay 0.05 s off
    the nominal one. Nothing of the simulated car is used.

    ``max_approach_rad`` (default 0.05 rad, 2.9°; ``None``: linear everywhere) bounds the lateral
    error's term: ``k_e·e_lat`` is clipped to ``±k_θ·max_approach_rad``, so far off the path the law
    steers for a yaw error of at most that angle towards it instead of a steering angle in
    proportion to the offset. Within ``|e_lat| ≤ (k_θ/k_e)·max_approach_rad`` (0.16 m at 13 m/s) the
    law is the linear one the gains were designed for; beyond, the steering the high ``k_e`` asks
    for a 0.5 m offset (0.41 rad at 13 m/s) would meet the actuator's lock and rate limit and the
    loop, linear only on paper, would oscillate.
    """

    def __init__(
        self,
        params: VehicleParams,
        *,
        gains: GainSchedule | None = None,
        n_points: int = 10,
        line_tolerance_m: float = 0.02,
        point_spacing_m: float | None = 1.0,
        ahead: bool = False,
        sideslip_compensation: bool = True,
        max_approach_rad: float | None = 0.05,
    ) -> None:
        super().__init__(
            params,
            n_points=n_points,
            line_tolerance_m=line_tolerance_m,
            point_spacing_m=point_spacing_m,
            ahead=ahead,
        )
        self.gains = gains if gains is not None else default_gains(params)
        self.sideslip_compensation = sideslip_compensation
        self.max_approach_rad = max_approach_rad

    def feedforward(self, curvature_1pm: float, vx: float) -> float:
        """``δ_ff = L/R + (m/L)(b/C_f − a/C_r)·v_x²/R`` with ``1/R`` = the signed curvature."""
        p = self.params
        return p.L * curvature_1pm + p.understeer_gradient * vx * vx * curvature_1pm

    def steady_yaw_error(self, curvature_1pm: float, vx: float) -> float:
        """``θ̃_ss = (−b + m a v_x²/(L C_r))·κ``: the yaw error of the linear bicycle model cornering
        steadily on the arc (minus the CG's sideslip angle)."""
        p = self.params
        return (-p.b_m + p.mass_kg * p.a_m * vx * vx / (p.L * p.cr_npr)) * curvature_1pm

    def steer(
        self, state: VehicleState, path: ReferencePath, hint: int | None = None
    ) -> tuple[float, TrackingErrors, int]:
        errors, index, _ = self._errors(state, path, hint)
        vx = state.vx_mps
        e_lat, yaw_error, yaw_rate_error = errors.e_lat, errors.yaw_error, errors.yaw_rate_error
        k_e, k_theta, k_omega = self.gains.gains(vx)
        delta_ff = self.feedforward(errors.curvature_1pm, vx)
        e_term = k_e * e_lat
        if self.max_approach_rad is not None:  # far off the path: approach it at a bounded angle
            cap = k_theta * self.max_approach_rad
            e_term = min(max(e_term, -cap), cap)
        delta_fb = -e_term - k_theta * yaw_error - k_omega * yaw_rate_error
        delta_beta = 0.0
        if self.sideslip_compensation:
            delta_beta = k_theta * self.steady_yaw_error(errors.curvature_1pm, vx)
        limit = self.params.max_steer_rad
        return min(max(delta_ff + delta_fb + delta_beta, -limit), limit), errors, index


class Stanley(_LocalFitController):
    """Stanley steering: ``δ = −θ̃ − atan(k·e_front/(k_soft + v_x))``, ``e_front`` the front axle's
    lateral error against the same local fit (positive: left of the path)."""

    def __init__(
        self,
        params: VehicleParams,
        *,
        k: float = 2.5,
        k_soft: float = 1.0,
        **fit: Any,
    ) -> None:
        super().__init__(params, **fit)  # n_points, line_tolerance_m, point_spacing_m, ahead
        self.k = k
        self.k_soft = k_soft

    def steer(
        self, state: VehicleState, path: ReferencePath, hint: int | None = None
    ) -> tuple[float, TrackingErrors, int]:
        errors, index, fit = self._errors(state, path, hint)
        a = self.params.a_m
        xf = state.x_m + a * math.cos(state.yaw_rad)
        yf = state.y_m + a * math.sin(state.yaw_rad)
        front = tracking_errors(fit, xf, yf, state.yaw_rad, state.yaw_rate_radps, state.vx_mps)
        v = max(state.vx_mps, 0.0)
        delta = -front.yaw_error - math.atan(self.k * front.e_lat / (self.k_soft + v))
        limit = self.params.max_steer_rad
        return min(max(delta, -limit), limit), errors, index


class PurePursuit(_LocalFitController):
    """Pure pursuit from the rear axle with look-ahead ``ℓ_d = max(min_lookahead_m, t_la·v_x)``."""

    def __init__(
        self,
        params: VehicleParams,
        *,
        lookahead_time_s: float = 0.8,
        min_lookahead_m: float = 4.0,
        **fit: Any,
    ) -> None:
        super().__init__(params, **fit)  # n_points, line_tolerance_m, point_spacing_m, ahead
        self.lookahead_time_s = lookahead_time_s
        self.min_lookahead_m = min_lookahead_m

    def steer(
        self, state: VehicleState, path: ReferencePath, hint: int | None = None
    ) -> tuple[float, TrackingErrors, int]:
        errors, index, _ = self._errors(state, path, hint)
        p = self.params
        cos_y, sin_y = math.cos(state.yaw_rad), math.sin(state.yaw_rad)
        xr, yr = state.x_m - p.b_m * cos_y, state.y_m - p.b_m * sin_y
        lookahead = max(self.min_lookahead_m, self.lookahead_time_s * max(state.vx_mps, 0.0))
        tx, ty = self._target(path, index, xr, yr, lookahead)
        dx, dy = tx - xr, ty - yr
        ld = math.hypot(dx, dy)
        if ld < 1e-6:
            return 0.0, errors, index
        alpha = math.atan2(dy, dx) - state.yaw_rad
        delta = math.atan2(2.0 * p.L * math.sin(alpha), ld)
        return float(np.clip(delta, -p.max_steer_rad, p.max_steer_rad)), errors, index

    @staticmethod
    def _target(
        path: ReferencePath, start: int, xr: float, yr: float, lookahead: float
    ) -> tuple[float, float]:
        """First point at ``lookahead`` from the rear axle going ahead from ``start`` (interpolated
        between path points; the path's end extended along its last heading when it runs out)."""
        px, py = path.x_m, path.y_m
        n = len(path)
        prev_d = math.hypot(px[start] - xr, py[start] - yr)
        for j in range(start + 1, n):
            d = math.hypot(px[j] - xr, py[j] - yr)
            if d >= lookahead:
                # solve |p(t) − r| = ℓ for t in [0, 1] on the segment j−1 → j
                ax, ay = px[j - 1] - xr, py[j - 1] - yr
                sx, sy = px[j] - px[j - 1], py[j] - py[j - 1]
                qa = sx * sx + sy * sy
                qb = 2.0 * (ax * sx + ay * sy)
                qc = ax * ax + ay * ay - lookahead * lookahead
                disc = max(qb * qb - 4.0 * qa * qc, 0.0)
                t = (-qb + math.sqrt(disc)) / (2.0 * qa) if qa > 0.0 else 1.0
                t = min(max(t, 0.0), 1.0)
                return float(px[j - 1] + t * sx), float(py[j - 1] + t * sy)
            prev_d = d
        heading = float(path.heading_rad[-1])
        extra = max(lookahead - prev_d, 0.0)
        return float(px[-1] + extra * math.cos(heading)), float(py[-1] + extra * math.sin(heading))


LATERAL_CONTROLLERS: Registry[type] = Registry(
    "lateral controller", {"ffb": FeedforwardFeedback, "stanley": Stanley, "pure_pursuit": PurePursuit}
)
"""Lateral controllers by name: ``LATERAL_CONTROLLERS[name](params)``."""
