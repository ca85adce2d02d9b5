"""Far-field geometry of a horizontal microphone array: capsule pairs and their steering delays.

Frame: the array's own (vehicle) frame, x forward, y left, z up, metres; bearings are azimuths in
radians, 0 ahead, counter-clockwise (positive to the left). A plane wave arriving from azimuth ``φ``
(unit vector ``u = (cos φ, sin φ)``) reaches the capsule nearer the source first, so the arrival-time
difference of capsule ``i`` relative to ``j`` is ``τ_ij = −(m_i − m_j)·u / c`` (seconds), with
``c`` the speed of sound of :mod:`makeway.physics`. Elevation is ignored (the sources are near the
array's height at the distances that matter).
"""

from __future__ import annotations

import numpy as np

from makeway.physics import SPEED_OF_SOUND

__all__ = ["capsule_pairs", "pair_delays"]


def capsule_pairs(n_channels: int) -> np.ndarray:
    """Every unordered capsule pair ``(i, j)``, ``i < j``, as an ``(n(n−1)/2, 2)`` int64 array."""
    return np.array([(i, j) for i in range(n_channels) for j in range(i + 1, n_channels)], dtype=np.int64)


def pair_delays(mics: np.ndarray, pairs: np.ndarray, azimuths_rad: np.ndarray) -> np.ndarray:
    """Far-field arrival-time difference ``τ_ij`` (s) of each pair for each azimuth: ``(pairs, azimuths)``.

    Args:
        mics: ``(channels, ≥2)`` capsule positions in metres (only x and y are used).
        pairs: ``(pairs, 2)`` capsule indices, as :func:`capsule_pairs` gives.
        azimuths_rad: bearings in radians (module docstring).
    """
    m = np.asarray(mics, dtype=np.float64)
    az = np.asarray(azimuths_rad, dtype=np.float64)
    u = np.stack([np.cos(az), np.sin(az)], axis=1)
    d = m[pairs[:, 0], :2] - m[pairs[:, 1], :2]
    return -(d @ u.T) / SPEED_OF_SOUND
