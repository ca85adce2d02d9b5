"""Siren range cues that do not depend on how loud the siren is (issue 25, item 1).

The siren networks place a siren by the level it arrives at, against a prior of the emitted level;
real sirens differ by 20 dB and more, which is a factor 10 in distance. Two cues read the distance
from the *shape* of what arrives instead:

**Ground reflection** (:func:`reflection_delay`). The road mirrors the siren: each capsule hears
the direct sound and, ``τ`` later, the sound reflected once off the ground,

    τ(d) = (√(d² + (h_s + h_m)²) − √(d² + (h_s − h_m)²)) / c  ≈  2·h_s·h_m / (c·d)  (d ≫ h),

for the horizontal distance ``d`` (m, ground plane, vehicle frame), the siren's height ``h_s`` and
the array's height ``h_m`` (m above the road) and the speed of sound ``c``
(:data:`makeway.physics.SPEED_OF_SOUND`). τ does not depend on loudness: about 0.68 ms at 20 m and
0.27 ms at 50 m for ``h_s`` = 1.5 m and the reference roof array at 1.55 m. The two paths sum to a
comb filter: the received power spectrum is the siren's times ``1 + ρ² + 2ρ·cos(2π f τ)`` (ρ: the
road's reflection coefficient, 0.7–0.9 for asphalt, times the small spreading loss of the longer
path), with maxima at ``f = k/τ``. The cue reads τ from that comb (:func:`siren_bins`,
:func:`comb_scores`): the capsules' power spectra are averaged (they all sit at the roof's height,
so they share the comb, while wind noise is independent per capsule) in 43 ms frames; in each frame
only the siren's harmonic peaks are kept — local maxima standing ≥ 6 dB over the local noise floor,
level and frequency refined by a parabola — so that the gaps between harmonics, which would make a
plain cepstrum or autocorrelation peak at the pitch period, never enter. Each frame's peak levels
(dB) lose their straight-line trend in log-frequency (the siren's own harmonic envelope), and the
residuals of all frames are correlated with ``cos(2π f τ)`` over a grid of τ in 0.1–1.5 ms: a
cepstrum restricted to the siren's harmonics that also uses the comb's known phase (a positive
reflection coefficient puts maxima, not notches, at ``k/τ``). The best delay's normalized
correlation (``score``) says how clear the comb is.

Within one frame the harmonics sample the comb only every ``f₀``, so ``τ`` and ``k/f₀ ± τ`` fit
alike; a sweeping siren (wail, yelp) moves ``f₀`` across the stretch and the true delay wins, a
steady two-tone or fixed tone leaves such aliases standing. :class:`ReflectionDelay` therefore keeps
the local maxima that reach half the best score as ``candidates``, for another cue to choose among.
A moving siren also changes τ within the stretch (20 m/s at 20 m: τ changes by half in a second).

**Distance from τ** (:func:`distance_from_delay`, :func:`reflection_distance`): the array height
is known (``array.yaml``: the mean ``z`` of the capsules); the siren's height is not. It enters
as a prior range (default 1.0–2.0 m, a car-roof or grille speaker): the point estimate uses its
middle, the interval its ends. Since ``d ≈ 2·h_s·h_m/(c·τ)`` is proportional to ``h_s``, a
1.0–2.0 m prior alone leaves ±33 % in distance, however clean τ is.

**Air-absorption spectral tilt** (:func:`spectral_tilt`): air absorbs high frequencies faster
(ISO 9613-1 at 20 °C, 50 % RH: ≈ 0.005 dB/m at 1 kHz, 0.03 dB/m at 4 kHz, 0.1 dB/m at 8 kHz).
The same siren bins' levels are regressed on the absorption coefficient ``α(f)`` (dB/m): the
slope, negated, is a distance in metres if the siren's own spectrum is flat in ``α``. It is not:
harmonic envelopes differ between sirens by tens of dB across 1–8 kHz, which in this slope is
hundreds of metres (measured in ``benchmarks/bench_audio_range_cues.py``), against the 40 m the
cue would have to resolve at 10–50 m; and the ground-reflection comb, whose shape changes with
distance, projects onto ``α(f)`` by tens of metres more. With no reflection the slope does follow
the distance for one and the same siren (``tests/test_range_cues.py``).

Inputs are full-scale samples ``(n, M)`` of the array (vehicle frame: x forward, y left, z up,
origin on the ground under the rear axle; :mod:`makeway.sense.recording`), times in seconds,
delays in seconds, distances in metres.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.ndimage import maximum_filter, median_filter

from makeway.errors import InputError
from makeway.physics import SPEED_OF_SOUND
from makeway.sense.recording import Recording

__all__ = [
    "BAND_HZ",
    "FRAME_S",
    "MIN_ARRAY_HEIGHT_M",
    "MIN_SCORE",
    "SIREN_HEIGHT_PRIOR_M",
    "TAU_RANGE_S",
    "ReflectionDelay",
    "SirenBins",
    "SpectralTilt",
    "array_height_m",
    "check_array_audio",
    "comb_scores",
    "distance_from_delay",
    "reflection_delay",
    "reflection_distance",
    "reflection_tau",
    "siren_bins",
    "spectral_tilt",
]

BAND_HZ = (400.0, 8000.0)
"""Frequencies the cues read (Hz): the siren's harmonics, below the 8 kHz of 16 kHz material."""
FRAME_S = 2048 / 48_000
"""Analysis frame (s): 43 ms, 23 Hz bins at 48 kHz; hop half a frame."""
FLOOR_BINS_HZ = 950.0
"""Width of the running median that estimates each frame's noise floor (Hz)."""
SIREN_ABOVE_FLOOR_DB = 6.0
"""A spectral peak counts as the siren's when it stands this far above the local noise floor
(6, 10 and 14 dB compared on validation scenes of training-split ingredients: 6 dB gave the most
delays within 10 % and the lowest distance error; ``bench_audio_range_cues.py --above-floor``)."""
MIN_PEAKS_PER_FRAME = 4
MIN_PEAKS = 24
"""Fewer siren peaks than this in a stretch: no cue."""
TAU_RANGE_S = (0.1e-3, 1.5e-3)
"""Delays searched (s): 1.5 ms is a siren at ~9 m, 0.1 ms one at ~130 m (h_s = 1.5 m, h_m = 1.55 m)."""
TAU_STEP_S = 2e-6
MIN_SCORE = 0.15
"""Normalized correlation below which no comb is reported. Only a floor: 99 % of the siren stretches
at 10–50 m pass it, and so do 75 % of 1 s stretches of street scenes with no siren (their own
low sources leave combs too; median score 0.41 on validation scenes), so the cue means something
only where the detector has found a siren, and ``score`` does not tell a right delay from an alias
(``benchmarks/bench_audio_range_cues.py``)."""
SIREN_HEIGHT_PRIOR_M = (1.0, 2.0)
"""Prior range of the siren speaker's height above the road (m)."""
MIN_ARRAY_HEIGHT_M = 0.3
"""An array whose mean capsule height is lower than this states no usable height (z = 0 is the
road): the reflection delay would be too short to read."""


# ----------------------------------------------------------------------------------- geometry


def reflection_tau(
    distance_m: np.ndarray | float,
    source_height_m: np.ndarray | float,
    array_height_m: float,
    c: float = SPEED_OF_SOUND,
) -> np.ndarray:
    """Delay (s) of the road-reflected path behind the direct one, for a horizontal ``distance_m``
    between a source at ``source_height_m`` and a capsule at ``array_height_m`` (module docstring)."""
    d = np.asarray(distance_m, dtype=np.float64)
    hs = np.asarray(source_height_m, dtype=np.float64)
    return (np.sqrt(d**2 + (hs + array_height_m) ** 2) - np.sqrt(d**2 + (hs - array_height_m) ** 2)) / c


def distance_from_delay(
    tau_s: np.ndarray | float,
    source_height_m: np.ndarray | float,
    array_height_m: float,
    c: float = SPEED_OF_SOUND,
) -> np.ndarray:
    """The horizontal distance (m) at which the reflection arrives ``tau_s`` behind the direct
    sound: the exact inverse of :func:`reflection_tau`. With ``Δ = c·τ``, ``a − b = 4·h_s·h_m`` and
    ``b = (h_s − h_m)²``: ``d² = ((a − b − Δ²) / (2Δ))² − b``. NaN where no distance gives ``τ``
    (``τ ≤ 0`` or ``c·τ ≥ 2·min(h_s, h_m)``, the delay straight below)."""
    delta = c * np.asarray(tau_s, dtype=np.float64)
    hs = np.asarray(source_height_m, dtype=np.float64)
    four_hh = 4.0 * hs * array_height_m
    b = (hs - array_height_m) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        root = (four_hh - delta**2) / (2.0 * delta)
        d2 = root**2 - b
        ok = (delta > 0) & (delta < 2.0 * np.minimum(hs, array_height_m)) & (d2 >= 0)
        return np.where(ok, np.sqrt(np.where(ok, d2, 0.0)), np.nan)


def reflection_distance(
    tau_s: float,
    array_height_m: float,
    height_prior_m: tuple[float, float] = SIREN_HEIGHT_PRIOR_M,
) -> tuple[float, float, float]:
    """``(distance, low, high)`` in metres from a reflection delay: the distance for a siren at the
    middle of ``height_prior_m`` and the two distances for its ends (module docstring)."""
    lo, hi = height_prior_m
    hs = np.array([0.5 * (lo + hi), lo, hi])
    d = distance_from_delay(tau_s, hs, array_height_m)
    return float(d[0]), float(d[1]), float(d[2])


def array_height_m(mics: np.ndarray | None, path: str | Path) -> float:
    """The array's height above the road (m): the mean ``z`` of ``mics (M, 3)`` (vehicle frame,
    ``array.yaml``). :class:`InputError` naming ``path`` when the array gives none."""
    if mics is None or np.asarray(mics).ndim != 2 or np.asarray(mics).shape[1] != 3 or not len(mics):
        raise InputError(path, "states no microphone positions [x, y, z]: the array height is unknown")
    z = np.asarray(mics, dtype=np.float64)[:, 2]
    h = float(np.mean(z))
    if not math.isfinite(h) or h < MIN_ARRAY_HEIGHT_M:
        raise InputError(
            path,
            f"states no array height: the capsules' mean z is {h:.2f} m (z is metres above the road; "
            f"the ground-reflection cue needs >= {MIN_ARRAY_HEIGHT_M} m)",
        )
    return h


def check_array_audio(rec: Recording) -> float:
    """Check that ``rec`` is an array recording the range cues can read; returns its height (m).

    A mono recording is refused: it comes with no ``array.yaml``, so neither the capsule height
    the reflection delay needs nor capsules to average the wind noise over."""
    path = rec.path or "recording"
    if rec.audio.ndim != 2 or rec.audio.shape[1] < 2:
        raise InputError(
            path, "is mono: the range cues need the microphone array and its height (array.yaml)"
        )
    return array_height_m(rec.mics, path)


# ---------------------------------------------------------------------------------- siren bins


@dataclass(frozen=True)
class SirenBins:
    """The time–frequency bins where a siren stands out, pooled over frames: ``freq_hz``, their
    level ``level_db`` (dB re full scale², capsules' mean power), ``frame`` index, and ``residual_db``
    (the level minus its frame's quadratic trend in log-frequency); ``frames`` the frames analysed."""

    freq_hz: np.ndarray
    level_db: np.ndarray
    frame: np.ndarray
    residual_db: np.ndarray
    frames: int

    def __len__(self) -> int:
        return len(self.freq_hz)


def siren_bins(
    audio: np.ndarray,
    sample_rate: int,
    band_hz: tuple[float, float] = BAND_HZ,
    above_floor_db: float = SIREN_ABOVE_FLOOR_DB,
) -> SirenBins:
    """The siren's harmonic peaks in ``audio (n, M)`` (full scale, the capsules of one array;
    module docstring): per frame, the local maxima (±2 bins) of the capsules' mean power that stand
    ≥ ``above_floor_db`` over a running median across frequency, in ``band_hz``, their frequency
    and level refined by a parabola through the three bins around each, in frames with at least
    :data:`MIN_PEAKS_PER_FRAME` peaks spanning an octave. The residual removes each frame's
    straight-line trend in log-frequency (the harmonic envelope)."""
    x = np.asarray(audio, dtype=np.float64)
    if x.ndim == 1:
        x = x[:, None]
    frame = max(256, round(FRAME_S * sample_rate))
    hop = frame // 2
    empty = SirenBins(np.zeros(0), np.zeros(0), np.zeros(0, dtype=int), np.zeros(0), 0)
    if x.shape[0] < frame:
        return empty
    window = np.hanning(frame)
    n_frames = 1 + (x.shape[0] - frame) // hop
    idx = np.arange(frame)[None, :] + hop * np.arange(n_frames)[:, None]
    power = np.zeros((n_frames, frame // 2 + 1))
    for m in range(x.shape[1]):
        power += np.abs(np.fft.rfft(x[idx, m] * window, axis=1)) ** 2
    power /= x.shape[1]
    f = np.fft.rfftfreq(frame, 1.0 / sample_rate)
    df = float(f[1])
    sel = (f >= band_hz[0]) & (f <= min(band_hz[1], 0.45 * sample_rate))
    f = f[sel]
    db = 10.0 * np.log10(np.maximum(power[:, sel], 1e-20))
    width = max(5, int(round(FLOOR_BINS_HZ / df)) | 1)
    floor = median_filter(db, size=(1, width), mode="nearest")
    peak = (db == maximum_filter(db, size=(1, 5), mode="nearest")) & (db >= floor + above_floor_db)
    peak[:, 0] = peak[:, -1] = False
    freqs: list[np.ndarray] = []
    levels: list[np.ndarray] = []
    frames: list[np.ndarray] = []
    resid: list[np.ndarray] = []
    for k in range(n_frames):
        i = np.flatnonzero(peak[k])
        if len(i) < MIN_PEAKS_PER_FRAME:
            continue
        a, b, c = db[k, i - 1], db[k, i], db[k, i + 1]
        curv = a - 2.0 * b + c
        p = np.where(curv < 0, 0.5 * (a - c) / np.where(curv < 0, curv, -1.0), 0.0)
        lv = b - 0.25 * (a - c) * p
        fq = f[i] + p * df
        lf = np.log(fq)
        if lf.max() - lf.min() < math.log(2.0):  # less than an octave: no envelope to remove
            continue
        trend = np.polyval(np.polyfit(lf - lf.mean(), lv, 1), lf - lf.mean())
        freqs.append(fq)
        levels.append(lv)
        frames.append(np.full(len(i), k))
        resid.append(lv - trend)
    if not freqs:
        return replace(empty, frames=n_frames)
    return SirenBins(
        np.concatenate(freqs), np.concatenate(levels), np.concatenate(frames), np.concatenate(resid), n_frames
    )


# ---------------------------------------------------------------------------------- reflection


@dataclass(frozen=True)
class ReflectionDelay:
    """A ground-reflection delay read from the array: ``tau_s`` (s; NaN when none was found),
    ``score`` (the comb's normalized correlation at the best delay, −1…1), ``found`` (score ≥ the
    minimum), ``bins`` (siren peaks it rests on) and ``candidates``: the local maxima of the
    correlation over the delays searched that reach half the best score, ``(tau_s, score)``, best
    first — a steady-pitch siren samples the comb only at its harmonics, so ``τ`` and
    ``k/f₀ ± τ`` can fit alike, and another cue (the level) may choose among them."""

    tau_s: float
    score: float
    found: bool
    bins: int
    candidates: tuple[tuple[float, float], ...] = ()


def comb_scores(bins: SirenBins, taus: np.ndarray) -> np.ndarray:
    """The normalized correlation of the siren peaks' residual levels with ``cos(2π f τ)`` for
    each delay of ``taus`` (s): the comb a positive ground reflection ``τ`` late leaves (module
    docstring)."""
    r = np.clip(bins.residual_db, -20.0, 20.0)
    r = r - r.mean()
    rr = float(r @ r)
    out = np.zeros(len(taus))
    if rr <= 0 or not len(taus):
        return out
    step_s = float(taus[1] - taus[0]) if len(taus) > 1 else 0.0
    # cos(2π f τ) over an even grid of τ by complex rotation (one multiply per step)
    step = np.exp(2j * np.pi * bins.freq_hz * step_s)
    z = np.exp(2j * np.pi * bins.freq_hz * float(taus[0]))
    for i in range(len(taus)):
        cz = z.real - z.real.mean()
        out[i] = float(r @ cz) / math.sqrt(max(float(cz @ cz), 1e-12) * rr)
        z = z * step
    return out


def reflection_delay(
    audio: np.ndarray,
    sample_rate: int,
    *,
    tau_range_s: tuple[float, float] = TAU_RANGE_S,
    min_score: float = MIN_SCORE,
    band_hz: tuple[float, float] = BAND_HZ,
    above_floor_db: float = SIREN_ABOVE_FLOOR_DB,
) -> ReflectionDelay:
    """The ground-reflection delay in ``audio (n, M)`` (1–2 s of the array; module docstring);
    ``above_floor_db``: how far a harmonic peak must stand over the noise floor (:func:`siren_bins`)."""
    bins = siren_bins(audio, sample_rate, band_hz, above_floor_db)
    if len(bins) < MIN_PEAKS:
        return ReflectionDelay(math.nan, 0.0, False, len(bins))
    taus = np.arange(tau_range_s[0], tau_range_s[1] + 0.5 * TAU_STEP_S, TAU_STEP_S)
    score = comb_scores(bins, taus)
    best = float(score.max())
    inner = (score[1:-1] >= score[:-2]) & (score[1:-1] >= score[2:]) & (score[1:-1] >= 0.5 * best)
    peaks = [int(i) + 1 for i in np.flatnonzero(inner)]
    for edge in (0, len(score) - 1):
        if score[edge] == best:
            peaks.append(edge)
    cands: list[tuple[float, float]] = []
    for i in sorted(peaks, key=lambda j: -score[j])[:4]:
        tau = float(taus[i])
        if 0 < i < len(taus) - 1:  # parabolic refinement
            a, b, c = score[i - 1], score[i], score[i + 1]
            curv = a - 2 * b + c
            if curv < 0:
                tau += 0.5 * (a - c) / curv * TAU_STEP_S
        cands.append((tau, float(score[i])))
    found = best >= min_score
    return ReflectionDelay(cands[0][0] if found else math.nan, best, found, len(bins), tuple(cands))


# --------------------------------------------------------------------------------- spectral tilt


@dataclass(frozen=True)
class SpectralTilt:
    """The siren bins' level regressed on air absorption: ``distance_m`` = −slope (dB per dB/m,
    i.e. metres) — the distance if the siren's own spectrum were flat in ``α(f)``; ``bins`` used."""

    distance_m: float
    bins: int


def spectral_tilt(
    audio: np.ndarray,
    sample_rate: int,
    absorption_db_per_m: Callable[[np.ndarray], np.ndarray],
    band_hz: tuple[float, float] = BAND_HZ,
) -> SpectralTilt:
    """Air absorption's spectral tilt in ``audio (n, M)`` as a raw distance (module docstring):
    ``level_db ≈ a_frame − d·α(f)``, fitted with one intercept per frame (the siren's level
    changes from frame to frame); NaN with too few siren bins or too narrow a band.
    ``absorption_db_per_m``: ``α(f)`` in dB/m for frequencies in Hz (the simulator's is
    :func:`makeway.sim.acoustics.air_absorption_db_per_m`, ISO 9613-1; a car-side stage may not
    import the simulator, so the curve is passed in)."""
    bins = siren_bins(audio, sample_rate, band_hz)
    if len(bins) < MIN_PEAKS:
        return SpectralTilt(math.nan, len(bins))
    alpha = np.asarray(absorption_db_per_m(bins.freq_hz), dtype=np.float64)
    # remove each frame's mean (its intercept) from both sides
    counts = np.bincount(bins.frame)
    keep = counts[bins.frame] >= 2
    fr = bins.frame[keep]
    a = alpha[keep] - (np.bincount(fr, alpha[keep]) / np.maximum(np.bincount(fr), 1))[fr]
    y = bins.level_db[keep] - (np.bincount(fr, bins.level_db[keep]) / np.maximum(np.bincount(fr), 1))[fr]
    var = float(a @ a)
    if var <= 0:
        return SpectralTilt(math.nan, len(bins))
    return SpectralTilt(-float(a @ y) / var, int(keep.sum()))
