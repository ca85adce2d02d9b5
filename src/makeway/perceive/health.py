"""Sensor health from the data itself (issue 29, item 2): which microphone capsules and cameras a
perception stage can trust, as a :class:`~makeway.messages.SensorHealth`, and the repair that lets
the stage keep working on what is left.

**Microphone array** (:func:`audio_health`, one window ``(channels, samples)`` at a time). Every
channel is compared with the others of its window:

* ``dead`` — RMS more than :data:`DEAD_BELOW_DB` (20 dB) below the median channel's: a capsule of
  the same array, centimetres from its neighbours, never hears that much less;
* ``clipped`` — more than :data:`~makeway.sense.recording.CLIP_FRACTION` of the samples at full
  scale (:data:`~makeway.sense.recording.CLIP_LEVEL`), the recording format's own rule;
* ``loud`` — RMS more than :data:`LOUD_ABOVE_DB` (20 dB) above the median channel's: a gain set
  wrong, whose windows are distorted even where they do not reach full scale;
* ``uncorrelated`` — the capsule no longer hears what its neighbours (capsules within
  :data:`NEIGHBOUR_M`) hear: its peak normalised cross-correlation with them (high-passed at
  :data:`CORRELATION_HIGHPASS_HZ`, lags up to the pair's spacing over the speed of sound) lies
  :data:`CORRELATION_DROP` below what the healthy pairs of the window reach (its own noise: wind on
  one capsule, a broken shield). A capsule without neighbours is never called uncorrelated.

:func:`repair_window` rebuilds each distrusted channel as the mean of the two trusted capsules
whose midpoint lies nearest to it (on the reference array: the two side capsules of the same unit,
3 cm from the missing one), so the siren networks, trained on eight capsules, keep eight inputs
with the right level and nearly the right delays. ``benchmarks/bench_sensor_faults.py`` measures it
against leaving the channel as it is.

**Camera** (:class:`CameraHealth`, frame by frame): ``frozen`` once :data:`FROZEN_FRAMES`
consecutive images are identical pixel for pixel (a stuck driver repeats one buffer; a real scene,
even a still one, changes by sensor noise and compression; a frame rate conversion repeats a frame
once, not four times), ``black`` when the mean grey level is below :data:`BLACK_MEAN` and its spread
below :data:`BLACK_STD` (a night scene has lights and a lit road; a dark sensor has neither).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy.signal import butter, sosfiltfilt

from makeway.messages import SensorHealth
from makeway.physics import SPEED_OF_SOUND
from makeway.sense.recording import CLIP_FRACTION, CLIP_LEVEL

__all__ = [
    "BLACK_MEAN",
    "BLACK_STD",
    "CORRELATION_DROP",
    "DEAD_BELOW_DB",
    "FROZEN_FRAMES",
    "LOUD_ABOVE_DB",
    "NEIGHBOUR_M",
    "CameraHealth",
    "audio_health",
    "repair_window",
]

DEAD_BELOW_DB = 20.0
"""A channel this many dB below the median channel's RMS is dead."""
LOUD_ABOVE_DB = 20.0
"""A channel this many dB above the median channel's RMS is too loud (its gain is wrong)."""
NEIGHBOUR_M = 0.1
"""Capsules closer than this (m) are neighbours whose signals must correlate."""
CORRELATION_HIGHPASS_HZ = 200.0
"""The correlation check ignores what lies below this (rumble and wind, which are not shared)."""
CORRELATION_DROP = 0.35
"""A capsule whose correlation with its neighbours lies this far below the window's healthy pairs'
(median of the pairs between the other capsules) is uncorrelated."""
FROZEN_FRAMES = 5
"""This many identical consecutive images make a camera frozen."""
BLACK_MEAN = 8.0
"""Mean grey level (0–255) below which an image may be black …"""
BLACK_STD = 6.0
"""… when its grey levels also spread less than this."""


@functools.lru_cache(maxsize=8)
def _highpass_sos(sample_rate: int) -> np.ndarray:
    return np.asarray(butter(2, CORRELATION_HIGHPASS_HZ, btype="highpass", fs=sample_rate, output="sos"))


def _neighbours(mics: np.ndarray) -> list[list[int]]:
    m = np.asarray(mics, dtype=np.float64)[:, :2]
    d = np.linalg.norm(m[:, None, :] - m[None, :, :], axis=-1)
    return [[j for j in range(len(m)) if j != i and d[i, j] < NEIGHBOUR_M] for i in range(len(m))]


def _peak_correlation(a: np.ndarray, b: np.ndarray, max_lag: int) -> float:
    """The largest normalised cross-correlation of ``a`` and ``b`` over lags in ``±max_lag``."""
    # element-wise products, not np.dot: a multithreaded BLAS spends more time waking its threads
    # than a 24 000-sample product takes
    na, nb = float(np.sqrt((a * a).sum())), float(np.sqrt((b * b).sum()))
    if na <= 0.0 or nb <= 0.0:
        return 0.0
    best = -1.0
    n = len(a)
    for lag in range(-max_lag, max_lag + 1):
        if lag >= 0:
            c = float((a[lag:] * b[: n - lag]).sum())
        else:
            c = float((a[: n + lag] * b[-lag:]).sum())
        best = max(best, c)
    return best / (na * nb)


def audio_health(window: np.ndarray, mics: np.ndarray, sample_rate: int, time_s: float = 0.0) -> SensorHealth:
    """Which capsules of ``window (channels, samples)`` (full-scale units) to trust (module
    docstring); ``mics (channels, 3)`` their positions in metres, ``time_s`` the window's time."""
    x = np.asarray(window, dtype=np.float64)
    n_ch = x.shape[0]
    reasons = ["ok"] * n_ch
    rms = np.sqrt(np.mean(x**2, axis=1))
    floor = float(np.median(rms)) * 10.0 ** (-DEAD_BELOW_DB / 20.0)
    ceiling = float(np.median(rms)) * 10.0 ** (LOUD_ABOVE_DB / 20.0)
    clipped = np.mean(np.abs(x) >= CLIP_LEVEL, axis=1) > CLIP_FRACTION
    for k in range(n_ch):
        if rms[k] <= floor or rms[k] == 0.0:
            reasons[k] = "dead"
        elif clipped[k]:
            reasons[k] = "clipped"
        elif rms[k] > ceiling:
            reasons[k] = "loud"
    neighbours = _neighbours(mics)
    if any(neighbours):
        hp = sosfiltfilt(_highpass_sos(int(sample_rate)), x, axis=1)
        pos = np.asarray(mics, dtype=np.float64)
        corr: dict[tuple[int, int], float] = {}
        for i in range(n_ch):
            for j in neighbours[i]:
                if j > i:
                    spacing = float(np.linalg.norm(pos[i, :2] - pos[j, :2]))
                    lag = math.ceil(spacing / SPEED_OF_SOUND * sample_rate) + 1
                    corr[(i, j)] = corr[(j, i)] = _peak_correlation(hp[i], hp[j], lag)
        for k in range(n_ch):
            if reasons[k] != "ok" or not neighbours[k]:
                continue
            own = float(np.median([corr[(k, j)] for j in neighbours[k]]))
            others = [
                c
                for (i, j), c in corr.items()
                if i < j and k not in (i, j) and reasons[i] == reasons[j] == "ok"
            ]
            if others and own < float(np.median(others)) - CORRELATION_DROP:
                reasons[k] = "uncorrelated"
    trusted = tuple(r == "ok" for r in reasons)
    return SensorHealth(float(time_s), "audio", trusted, tuple(reasons))


def repair_window(
    window: np.ndarray, mics: np.ndarray, health: SensorHealth
) -> tuple[np.ndarray, tuple[int, ...]]:
    """``window (channels, samples)`` with every distrusted channel rebuilt from two trusted ones
    (module docstring), and the channels rebuilt. A channel with no trusted pair left is kept."""
    if health.ok:
        return window, ()
    x = np.array(window, dtype=np.float64)
    pos = np.asarray(mics, dtype=np.float64)[:, :2]
    good = [k for k, ok in enumerate(health.trusted) if ok]
    repaired: list[int] = []
    for k, ok in enumerate(health.trusted):
        if ok:
            continue
        best: tuple[float, int, int] | None = None
        for a_i, a in enumerate(good):
            for b in good[a_i + 1 :]:
                d = float(np.linalg.norm(0.5 * (pos[a] + pos[b]) - pos[k]))
                if d < NEIGHBOUR_M and (best is None or d < best[0]):
                    best = (d, a, b)
        if best is not None:
            x[k] = 0.5 * (x[best[1]] + x[best[2]])
            repaired.append(k)
    return x, tuple(repaired)


class CameraHealth:
    """Frame-by-frame health of one camera (module docstring): :meth:`update` with each image."""

    def __init__(self, frozen_frames: int = FROZEN_FRAMES) -> None:
        if frozen_frames < 2:
            raise ValueError(f"frozen_frames must be >= 2, got {frozen_frames}")
        self.frozen_frames = int(frozen_frames)
        self.reset()

    def reset(self) -> None:
        """Forget the previous images."""
        self._last: np.ndarray | None = None
        self._repeats = 0

    def update(self, image: np.ndarray, time_s: float = 0.0) -> SensorHealth:
        """The camera's health after ``image`` (BGR or grey, uint8) taken at ``time_s`` (s)."""
        img = np.asarray(image)
        if self._last is not None and self._last.shape == img.shape and np.array_equal(self._last, img):
            self._repeats += 1
        else:
            self._repeats = 0
            self._last = img.copy()
        grey = img.mean(axis=2) if img.ndim == 3 else img.astype(np.float64)
        reason = "ok"
        if self._repeats + 1 >= self.frozen_frames:
            reason = "frozen"
        elif float(grey.mean()) < BLACK_MEAN and float(grey.std()) < BLACK_STD:
            reason = "black"
        return SensorHealth(float(time_s), "camera", (reason == "ok",), (reason,))
