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

**Swapped capsules** (:class:`SwapCheck`, over a few seconds): two capsules wired the wrong way
round hear nothing unusual on their own; only the array's geometry gives them away. Each analysed
window's GCC-PHAT cross-correlations (every capsule pair, 300–6000 Hz) are steered over a grid of
source positions around the array (SRP-PHAT, :data:`SWAP_GRID_DEG` × :data:`SWAP_GRID_RANGES_M`)
for the wiring as stated and for every wiring with two capsules exchanged; the best steered power
of each wiring is summed over the windows (forgetting with :data:`SWAP_FORGET` per window). A swap
is reported once a swapped wiring beats the stated one by :data:`SWAP_MARGIN` per window on
average, after at least :data:`SWAP_MIN_WINDOWS` windows. Wirings that a symmetry of the array
turns into each other (a mirror or rotation mapping the capsules onto themselves) explain every
sound equally well, each for a mirrored source: on the reference roof array (two units of four
capsules, mirror-symmetric front to back) the exchange of a unit's front and back capsules cannot
be told from the same exchange on the other unit. Then the capsules of all of them are reported and
nothing is re-ordered; a unique swap is repaired by exchanging the two channels back
(:meth:`SwapCheck.repair`).

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
    "SWAP_FORGET",
    "SWAP_GRID_DEG",
    "SWAP_GRID_RANGES_M",
    "SWAP_MARGIN",
    "SWAP_MIN_WINDOWS",
    "CameraHealth",
    "SwapCheck",
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
SWAP_GRID_DEG = 2.0
"""Bearing step (degrees) of the source positions the swap check steers to."""
SWAP_GRID_RANGES_M = (3.0, 8.0, 20.0, 60.0)
"""Source distances (m) the swap check steers to (a near source's curved wavefront matters across
the 0.9 m between the roof units)."""
SWAP_BAND_HZ = (300.0, 6000.0)
"""The band the swap check's cross-correlations use (a siren's harmonics and road noise)."""
SWAP_MARGIN = 0.25
"""A swapped wiring must beat the stated one by this much steered power per window on average
(steered power: the sum over capsule pairs of GCC-PHAT values, each at most 1)."""
SWAP_MIN_WINDOWS = 4
"""Windows (0.5 s each, not overlapping) the swap check needs before it reports anything."""
SWAP_FORGET = 0.95
"""Weight kept per window by the swap check's sums (a memory of about 20 windows, 10 s)."""
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
    for k, (ok, why) in enumerate(zip(health.trusted, health.reasons, strict=True)):
        if ok or why == "swapped":  # SwapCheck re-orders swapped channels; a rebuild would lose them
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


def _array_symmetries(mics: np.ndarray, tol: float = 1e-3) -> list[tuple[int, ...]]:
    """The permutations ``sigma`` of the capsules for which a plane isometry maps capsule ``k`` onto
    capsule ``sigma[k]`` for every ``k`` (the identity included), from the planar positions."""
    p = np.asarray(mics, dtype=np.float64)[:, :2]
    n = len(p)
    if n < 2:
        return [tuple(range(n))]
    c = p.mean(axis=0)
    q = p - c
    # an isometry mapping the set onto itself fixes the centroid: try the rotations and reflections
    # about it that take capsule 0 onto each capsule
    out: set[tuple[int, ...]] = set()
    r0 = float(np.hypot(*q[0]))
    for target in range(n):
        if abs(float(np.hypot(*q[target])) - r0) > tol:
            continue
        a0, a1 = math.atan2(q[0, 1], q[0, 0]), math.atan2(q[target, 1], q[target, 0])
        rot = a1 - a0
        refl = a1 + a0  # reflection across the line at angle refl / 2 maps angle a0 to a1
        for m in (
            np.array([[math.cos(rot), -math.sin(rot)], [math.sin(rot), math.cos(rot)]]),
            np.array([[math.cos(refl), math.sin(refl)], [math.sin(refl), -math.cos(refl)]]),
        ):
            moved = q @ m.T
            d = np.linalg.norm(moved[:, None, :] - q[None, :, :], axis=-1)
            sigma = d.argmin(axis=1)
            if np.all(d[np.arange(n), sigma] < tol) and len(set(sigma.tolist())) == n:
                out.add(tuple(int(v) for v in sigma))
    out.add(tuple(range(n)))
    return sorted(out)


class SwapCheck:
    """Finds two exchanged capsule channels of an array from the sound itself (module docstring).

    ``mics (channels, 3)`` the capsule positions (m) as the array states them, ``sample_rate`` Hz.
    Feed every window in time order to :meth:`update` (windows overlapping the last one analysed are
    skipped when ``t_end`` is given); :attr:`swapped` holds the verdict: ``()`` when the wiring as
    stated explains the sound best (or too little has been heard), else the pairs of channels found
    exchanged — one pair, or several that the array's symmetry cannot tell apart (then
    :attr:`ambiguous` is true). :meth:`repair` applies the verdict to one window and its health.
    """

    def __init__(self, mics: np.ndarray, sample_rate: int) -> None:
        self.mics = np.asarray(mics, dtype=np.float64)
        self.sample_rate = int(sample_rate)
        n = len(self.mics)
        self.pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
        self.hypotheses: list[tuple[int, ...]] = [tuple(range(n))]
        for a, b in self.pairs:
            perm = list(range(n))
            perm[a], perm[b] = b, a
            self.hypotheses.append(tuple(perm))
        az = np.deg2rad(np.arange(0.0, 360.0, SWAP_GRID_DEG))
        ranges = np.asarray(SWAP_GRID_RANGES_M)
        grid = np.stack([np.outer(ranges, np.cos(az)).ravel(), np.outer(ranges, np.sin(az)).ravel()], 1)
        centre = self.mics[:, :2].mean(axis=0)
        # propagation delay (samples) from each grid point to each capsule
        self._delay = (
            np.linalg.norm(grid[:, None, :] + centre - self.mics[None, :, :2], axis=-1)
            / SPEED_OF_SOUND
            * self.sample_rate
        )
        # wirings a symmetry maps onto each other: sigma ∘ h for every symmetry sigma
        symmetries = _array_symmetries(self.mics)
        index = {h: k for k, h in enumerate(self.hypotheses)}
        self._lag_cache: dict[tuple[int, int], np.ndarray] = {}
        self._twins = [
            sorted({index[t] for s in symmetries if (t := tuple(s[v] for v in h)) in index})
            for h in self.hypotheses
        ]
        self.reset()

    def reset(self) -> None:
        """Forget what was heard."""
        self._sum = np.zeros(len(self.hypotheses))
        self._weight = 0.0
        self.windows = 0
        self._last_end: float | None = None
        self.swapped: tuple[tuple[int, int], ...] = ()
        self.ambiguous = False
        self.margin = 0.0
        """The best swapped wiring's lead over the stated one, steered power per window."""

    def _lags(self, n: int, up: int) -> np.ndarray:
        """Per wiring, the index into the stacked pair correlations of every grid point's delay:
        ``(wirings, grid points, pairs)``, cached per window length."""
        key = (n, up)
        if key not in self._lag_cache:
            i = np.array([a for a, _ in self.pairs])
            j = np.array([b for _, b in self.pairs])
            out = np.empty((len(self.hypotheses), len(self._delay), len(self.pairs)), dtype=np.int64)
            for k, h in enumerate(self.hypotheses):
                perm = np.asarray(h)
                lag = np.rint((self._delay[:, perm[i]] - self._delay[:, perm[j]]) * up).astype(np.int64)
                out[k] = lag % (n * up) + np.arange(len(self.pairs)) * (n * up)
            self._lag_cache = {key: out}
        return self._lag_cache[key]

    def _scores(self, window: np.ndarray) -> np.ndarray:
        x = np.asarray(window, dtype=np.float64)
        n = x.shape[1]
        up = 2  # the cross-correlations are evaluated at half a sample
        spec = np.fft.rfft(x, axis=1)
        f = np.fft.rfftfreq(n, 1.0 / self.sample_rate)
        band = (f >= SWAP_BAND_HZ[0]) & (f <= SWAP_BAND_HZ[1])
        bins = max(int(band.sum()), 1)
        i = [a for a, _ in self.pairs]
        j = [b for _, b in self.pairs]
        cross = spec[i] * np.conj(spec[j])
        cross = np.where(band, cross / np.maximum(np.abs(cross), 1e-30), 0.0)
        # GCC-PHAT of every pair, scaled so that a perfectly coherent pair peaks at 1
        corr = np.fft.irfft(cross, n=n * up, axis=1).ravel() * (n * up / (2.0 * bins))
        return np.asarray(corr[self._lags(n, up)].sum(axis=2).max(axis=1))

    def update(self, window: np.ndarray, t_end: float | None = None, window_s: float = 0.5) -> bool:
        """Analyse ``window (channels, samples)`` ending at ``t_end`` (s), unless it overlaps the
        last window analysed (``window_s`` long); returns whether it was analysed."""
        if t_end is not None and self._last_end is not None and t_end - self._last_end < window_s - 1e-6:
            return False
        x = np.asarray(window, dtype=np.float64)
        if x.shape[0] != len(self.mics) or x.shape[1] < 64 or not np.all(np.isfinite(x)):
            return False
        self._last_end = t_end
        self._sum = SWAP_FORGET * self._sum + self._scores(x)
        self._weight = SWAP_FORGET * self._weight + 1.0
        self.windows += 1
        self._decide()
        return True

    def _decide(self) -> None:
        mean = self._sum / self._weight
        best = int(np.argmax(mean))
        self.margin = float(mean[1:].max() - mean[0]) if len(mean) > 1 else 0.0
        self.swapped, self.ambiguous = (), False
        if self.windows < SWAP_MIN_WINDOWS or best == 0 or self.margin < SWAP_MARGIN:
            return
        members = [k for k in self._twins[best] if k > 0] or [best]
        self.swapped = tuple(self.pairs[k - 1] for k in members)
        self.ambiguous = len(members) > 1

    def repair(self, window: np.ndarray, health: SensorHealth) -> tuple[np.ndarray, SensorHealth]:
        """``window`` with a unique swap undone (the two channels exchanged back), and ``health``
        with the swapped capsules marked ``"swapped"`` (listed as repaired when re-ordered)."""
        if not self.swapped:
            return window, health
        trusted, reasons = list(health.trusted), list(health.reasons)
        for a, b in self.swapped:
            for k in (a, b):
                trusted[k], reasons[k] = False, "swapped"
        repaired = tuple(health.repaired)
        if not self.ambiguous:
            a, b = self.swapped[0]
            window = np.array(window, dtype=np.float64)
            window[[a, b]] = window[[b, a]]
            repaired = tuple(sorted({*repaired, a, b}))
        return window, SensorHealth(health.time_s, health.sensor, tuple(trusted), tuple(reasons), repaired)


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
