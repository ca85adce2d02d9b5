"""The constant-velocity Kalman prediction the EV tracks share (world frame, metres, seconds)."""

from __future__ import annotations

import numpy as np

__all__ = ["cv_predict", "range_sigma_m"]


def cv_predict(
    state: np.ndarray, cov: np.ndarray, dt: float, accel_noise_mps2: float
) -> tuple[np.ndarray, np.ndarray]:
    """Constant-velocity prediction by ``dt`` (s) of states ``(…, 4)`` and covariances ``(…, 4, 4)``
    (world frame ``x, y, v_x, v_y``) under white acceleration noise (m/s², per axis)."""
    f = np.eye(4)
    f[0, 2] = f[1, 3] = dt
    q1 = accel_noise_mps2**2 * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])
    q = np.zeros((4, 4))
    q[np.ix_([0, 2], [0, 2])] = q1
    q[np.ix_([1, 3], [1, 3])] = q1
    return state @ f.T, f @ cov @ f.T + q


def range_sigma_m(distance_m: float, log_sigma: float | None, fraction: float, floor_m: float) -> float:
    """Standard deviation (m) of a ranged fix at ``distance_m`` along the line of sight: ``d·σ``
    when the sense states ``log_sigma``, the σ of its ln distance (first order: ±1σ of ``ln d`` is
    ±``d·σ`` metres), otherwise the configured ``fraction·d``; never below ``floor_m``."""
    share = fraction if log_sigma is None or not log_sigma > 0 else float(log_sigma)
    return max(share * distance_m, floor_m)
