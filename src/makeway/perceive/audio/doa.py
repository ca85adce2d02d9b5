"""Classical siren baselines of issue 4: three bearing estimators and a band-energy siren detector.

Every bearing estimator has the signature ``estimate(window, mics, sample_rate) -> bearing_rad``:
``window (channels, samples)``, ``mics (channels, 3)`` capsule positions in the vehicle frame (x
forward, y left, z up), result in the vehicle frame, 0 straight ahead, positive to the left, in
(−π, π]. All work in the siren band :data:`~makeway.perceive.audio.features.BAND_HZ` (500–1800 Hz)
and assume a far-field source in the ground plane (the siren sits within a metre of the capsules'
height, so at 10 m the elevation is below 6°). None estimates distance.

* ``gccphat`` — Apollo-style: GCC-PHAT time difference for every capsule pair, then a grid search
  (1°) over the bearing for the least (truncated) squares fit of the measured delays to the
  far-field ones. PHAT whitening alone gives the many noise-only bins as much weight as the few siren
  harmonics; as in the simulator tests, only bins whose cross-power stands :data:`GCC_SELECT_DB`
  (10 dB) above the band's median enter. The 16 pairs across the two units (0.9 m apart) fix the
  lateral angle; the 12 short pairs inside the units (4–6 cm) break the front/back ambiguity that
  the cross pairs leave.
* ``srp`` / ``normmusic`` — pyroomacoustics' SRP-PHAT and NormMUSIC on the 8 capsules projected on
  the ground plane: STFT of 512 points (hop 256, Hann), 360-point azimuth grid (1°),
  ``freq_range=[500, 1800]``, one source.

:class:`SirenEnergyDetector` scores a window by how much of its energy lies in the siren band, how
tonal it is there, and how smoothly its dominant in-band peak moves (a siren sweeps or steps; noise
peaks jump about); a logistic with two constants, fitted on training windows, maps the score to a
probability.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.fft import irfft, next_fast_len, rfft
from scipy.optimize import minimize

from makeway.perceive.audio.features import BAND_HZ, frame_params, power_spectrogram
from makeway.perceive.audio.geometry import capsule_pairs, pair_delays
from makeway.physics import SPEED_OF_SOUND
from makeway.registry import Registry

DoaMethod = Callable[[np.ndarray, np.ndarray, int], float]

GCC_SELECT_DB = 10.0
"""GCC-PHAT keeps the bins whose cross-power stands this far above the in-band median."""
GCC_OUTLIER_SAMPLES = 2.0
"""Delay residuals are truncated at this many samples in the bearing fit (a wrong peak counts once)."""
GRID_DEG = 1.0
STFT_NFFT = 512
STFT_HOP = 256


def wrap_angle(a: np.ndarray | float) -> np.ndarray:
    """Angle(s) wrapped to (−π, π]."""
    return np.asarray(-((-np.asarray(a, dtype=np.float64) + np.pi) % (2.0 * np.pi) - np.pi))


def _azimuth_grid() -> np.ndarray:
    return np.deg2rad(np.arange(0.0, 360.0, GRID_DEG))


def _check(window: np.ndarray, mics: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    w = np.asarray(window, dtype=np.float64)
    m = np.asarray(mics, dtype=np.float64)
    if w.ndim != 2 or m.ndim != 2 or m.shape[1] != 3 or w.shape[0] != m.shape[0]:
        raise ValueError(
            f"window must be (channels, samples) and mics (channels, 3); got {w.shape} and {m.shape}"
        )
    if w.shape[0] < 2:
        raise ValueError("a bearing needs at least two capsules")
    return w, m


# ------------------------------------------------------------------------------------------ GCC-PHAT


def gcc_phat_delays(
    window: np.ndarray,
    sample_rate: int,
    pairs: np.ndarray,
    max_lags: np.ndarray,
    band: tuple[float, float] = BAND_HZ,
) -> tuple[np.ndarray, np.ndarray]:
    """Delay (samples) of channel ``i`` relative to ``j`` for each pair ``(i, j)``, and its weight.

    GCC-PHAT on the selected bins (see the module docstring), peak searched within ``±max_lags``
    and refined by a parabola. The weight is the peak height relative to a perfect coherence (1);
    a pair with no selected bin gets weight 0.
    """
    # zero-padding by the largest lag is enough to keep the searched lags free of circular wrap
    n = next_fast_len(window.shape[1] + int(max_lags.max()) + 1, real=True)
    spec = rfft(window, n=n, axis=1)
    f = np.fft.rfftfreq(n, 1.0 / sample_rate)
    sel = np.flatnonzero((f >= band[0]) & (f <= band[1]))
    cross = spec[pairs[:, 0]][:, sel] * np.conj(spec[pairs[:, 1]][:, sel])
    mag = np.abs(cross)
    keep = mag > 10.0 ** (GCC_SELECT_DB / 10.0) * np.median(mag, axis=1, keepdims=True)
    phat = np.where(keep, cross / np.maximum(mag, 1e-30), 0.0)
    full = np.zeros((len(pairs), n // 2 + 1), dtype=np.complex128)
    full[:, sel] = phat
    cc = irfft(full, n=n, axis=1)
    n_keep = keep.sum(axis=1)
    delays = np.zeros(len(pairs))
    weights = np.zeros(len(pairs))
    for p in range(len(pairs)):
        if n_keep[p] == 0:
            continue
        lag = int(max_lags[p])
        seg = np.concatenate([cc[p, -lag:], cc[p, : lag + 1]])
        k = int(np.argmax(seg))
        frac = 0.0
        if 0 < k < len(seg) - 1:
            y0, y1, y2 = seg[k - 1], seg[k], seg[k + 1]
            den = y0 - 2.0 * y1 + y2
            frac = float(np.clip(0.5 * (y0 - y2) / den, -0.5, 0.5)) if den < 0 else 0.0
        delays[p] = k - lag + frac
        weights[p] = max(float(seg[k]) * n / (2.0 * n_keep[p]), 0.0)
    return delays, weights


@functools.lru_cache(maxsize=8)
def _gcc_geometry(mics_key: bytes, n_ch: int, sample_rate: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    mics = np.frombuffer(mics_key, dtype=np.float64).reshape(n_ch, 3)
    pairs = capsule_pairs(n_ch)
    d = mics[pairs[:, 0], :2] - mics[pairs[:, 1], :2]
    max_lags = np.ceil(np.hypot(d[:, 0], d[:, 1]) / SPEED_OF_SOUND * sample_rate).astype(np.int64) + 2
    expected = pair_delays(mics, pairs, _azimuth_grid()).T * sample_rate  # (grid, pairs) in samples
    return pairs, max_lags, expected


def gccphat_bearing(window: np.ndarray, mics: np.ndarray, sample_rate: int) -> float:
    """Apollo-style pairwise GCC-PHAT bearing (see the module docstring)."""
    w, m = _check(window, mics)
    pairs, max_lags, expected = _gcc_geometry(np.ascontiguousarray(m).tobytes(), len(m), int(sample_rate))
    delays, weights = gcc_phat_delays(w, int(sample_rate), pairs, max_lags)
    if not weights.any():
        weights = np.ones_like(weights)
    resid = np.minimum((expected - delays[None, :]) ** 2, GCC_OUTLIER_SAMPLES**2)
    cost = resid @ weights
    return float(wrap_angle(_azimuth_grid()[int(np.argmin(cost))]))


# ------------------------------------------------------------------------------- pyroomacoustics


def stft(window: np.ndarray, nfft: int = STFT_NFFT, hop: int = STFT_HOP) -> np.ndarray:
    """``(channels, nfft // 2 + 1, snapshots)`` STFT with a periodic Hann window (pyroomacoustics' X)."""
    n = window.shape[1]
    if n < nfft:
        raise ValueError(f"window of {n} samples is shorter than the STFT ({nfft})")
    frames = np.lib.stride_tricks.sliding_window_view(window, nfft, axis=1)[:, ::hop, :]
    spec = rfft(frames * (np.hanning(nfft + 1)[:-1]), axis=2)
    return np.ascontiguousarray(np.transpose(spec, (0, 2, 1)))


@functools.lru_cache(maxsize=8)
def _pra_doa(name: str, mics_key: bytes, n_ch: int, sample_rate: int) -> Any:
    import pyroomacoustics as pra  # heavy; only the classical baselines need it

    mics = np.frombuffer(mics_key, dtype=np.float64).reshape(n_ch, 3)
    return pra.doa.algorithms[name](
        mics[:, :2].T.copy(),
        sample_rate,
        STFT_NFFT,
        c=SPEED_OF_SOUND,
        num_src=1,
        azimuth=_azimuth_grid(),
        dim=2,
    )


def _pra_bearing(name: str, window: np.ndarray, mics: np.ndarray, sample_rate: int) -> float:
    w, m = _check(window, mics)
    doa = _pra_doa(name, np.ascontiguousarray(m).tobytes(), len(m), int(sample_rate))
    doa.locate_sources(stft(w), num_src=1, freq_range=[BAND_HZ[0], BAND_HZ[1]])
    return float(wrap_angle(float(np.asarray(doa.azimuth_recon).reshape(-1)[0])))


def srp_bearing(window: np.ndarray, mics: np.ndarray, sample_rate: int) -> float:
    """pyroomacoustics SRP-PHAT bearing (see the module docstring)."""
    return _pra_bearing("SRP", window, mics, sample_rate)


def normmusic_bearing(window: np.ndarray, mics: np.ndarray, sample_rate: int) -> float:
    """pyroomacoustics NormMUSIC bearing (see the module docstring)."""
    return _pra_bearing("NormMUSIC", window, mics, sample_rate)


DOA_METHODS: Registry[DoaMethod] = Registry(
    "bearing estimator", {"gccphat": gccphat_bearing, "srp": srp_bearing, "normmusic": normmusic_bearing}
)
"""The classical bearing estimators by name (``makeway audio eval --baseline NAME``)."""


# ---------------------------------------------------------------------------------- siren detector

DETECTOR_CHANNELS = (0, 4)
"""The detector looks at one capsule per unit (L-front, R-front) and averages their spectra."""
PEAK_STEP_BINS = 4
"""A dominant in-band peak that moves at most this many bins (≈ 94 Hz at 48 kHz) per 10 ms frame is
continuous: a siren sweeps by less (a yelp sweeps ~1 kHz in ~0.15 s), noise peaks jump about."""
CONTINUITY_WEIGHT_DB = 10.0
# The defaults are SirenEnergyDetector.fit on 6 simulated training recordings of 8 s (seed 1000, all
# scenarios, real ingredients); refit with SirenEnergyDetector.fit or ``makeway audio eval --fit DIR``.
DEFAULT_SLOPE = 0.2782
DEFAULT_OFFSET = 22.88


def detector_cues(window: np.ndarray, sample_rate: int) -> tuple[float, float, float]:
    """``(band_ratio_db, tonality_db, continuity)`` of one window ``(channels, samples)``.

    * band ratio: energy in 500–1800 Hz over the energy above 50 Hz, in dB (≤ 0);
    * tonality: per frame, the strongest in-band bin over the in-band median, in dB, averaged;
    * continuity: share of consecutive frames whose strongest in-band bin moves ≤ :data:`PEAK_STEP_BINS`.
    """
    w = np.asarray(window, dtype=np.float64)
    chans = [c for c in DETECTOR_CHANNELS if c < w.shape[0]] or [0]
    power = power_spectrogram(w[chans], sample_rate).mean(axis=0)  # (bins, frames)
    _, _, n_fft = frame_params(sample_rate)
    f = np.fft.rfftfreq(n_fft, 1.0 / sample_rate)
    band = (f >= BAND_HZ[0]) & (f <= BAND_HZ[1])
    broad = f >= 50.0
    e_band = float(power[band].sum())
    e_all = float(power[broad].sum())
    ratio_db = 10.0 * math.log10(max(e_band, 1e-30) / max(e_all, 1e-30))
    inband = power[band]
    peak = inband.max(axis=0)
    med = np.median(inband, axis=0)
    tonality_db = float(np.mean(10.0 * np.log10(np.maximum(peak, 1e-30) / np.maximum(med, 1e-30))))
    arg = np.argmax(inband, axis=0)
    continuity = float(np.mean(np.abs(np.diff(arg)) <= PEAK_STEP_BINS)) if len(arg) > 1 else 0.0
    return ratio_db, tonality_db, continuity


def detector_score(window: np.ndarray, sample_rate: int) -> float:
    """One score per window: band ratio + tonality (dB) + 10 dB × continuity."""
    ratio_db, tonality_db, continuity = detector_cues(window, sample_rate)
    return ratio_db + tonality_db + CONTINUITY_WEIGHT_DB * continuity


def _sigmoid(z: np.ndarray) -> np.ndarray:
    return np.asarray(0.5 * (1.0 + np.tanh(0.5 * z)))


class SirenEnergyDetector:
    """Band-energy / periodicity siren detector: ``p = σ(slope · (score − offset))``.

    scikit-learn style: ``fit(windows, labels)`` fits ``slope`` and ``offset`` by logistic regression
    on the window scores (a tiny L2 penalty on the slope keeps separable data finite);
    ``predict_proba(windows)`` gives ``(n, 2)`` = [P(no siren), P(siren)]; ``predict`` thresholds at
    0.5. ``windows`` is ``(n, channels, samples)`` (or one ``(channels, samples)`` window).
    """

    def __init__(
        self, sample_rate: int = 48_000, slope: float = DEFAULT_SLOPE, offset: float = DEFAULT_OFFSET
    ) -> None:
        self.sample_rate = int(sample_rate)
        self.slope = float(slope)
        self.offset = float(offset)

    def __repr__(self) -> str:
        return f"SirenEnergyDetector(slope={self.slope:.4g}, offset={self.offset:.4g})"

    def scores(self, windows: np.ndarray) -> np.ndarray:
        w = np.asarray(windows)
        if w.ndim == 2:
            w = w[None]
        if w.ndim != 3:
            raise ValueError(f"windows must be (n, channels, samples); got {w.shape}")
        return np.array([detector_score(x, self.sample_rate) for x in w])

    def fit(self, windows: np.ndarray, labels: np.ndarray) -> SirenEnergyDetector:
        return self.fit_scores(self.scores(windows), labels)

    def fit_scores(self, scores: np.ndarray, labels: np.ndarray) -> SirenEnergyDetector:
        """Fit on precomputed :meth:`scores` (lets a caller score once and fit several times)."""
        s = np.asarray(scores, dtype=np.float64)
        y = np.asarray(labels, dtype=bool).astype(np.float64)
        if s.shape != y.shape or len(s) == 0:
            raise ValueError("need one label per window, and at least one window")
        if y.min() == y.max():
            raise ValueError("fitting the detector needs windows with and without a siren")
        mu, sd = float(s.mean()), float(s.std()) or 1.0
        z = (s - mu) / sd

        def loss(p: np.ndarray) -> tuple[float, np.ndarray]:
            a, b = p
            t = a * (z - b)
            q = _sigmoid(t)
            # log-loss written with logaddexp for stability
            val = float(np.mean(np.logaddexp(0.0, t) - y * t)) + 1e-3 * a * a
            g = q - y
            return val, np.array([np.mean(g * (z - b)) + 2e-3 * a, -a * np.mean(g)])

        res = minimize(loss, np.array([2.0, 0.0]), jac=True, method="BFGS")
        a, b = (float(v) for v in res.x)
        self.slope = a / sd
        self.offset = mu + b * sd
        return self

    def predict_proba(self, windows: np.ndarray) -> np.ndarray:
        p = self.proba_from_scores(self.scores(windows))
        return np.stack([1.0 - p, p], axis=1)

    def proba_from_scores(self, scores: np.ndarray) -> np.ndarray:
        return _sigmoid(self.slope * (np.asarray(scores, dtype=np.float64) - self.offset))

    def predict(self, windows: np.ndarray) -> np.ndarray:
        return np.asarray(self.predict_proba(windows)[:, 1] >= 0.5)


def siren_energy_detector(
    window: np.ndarray, sample_rate: int, detector: SirenEnergyDetector | None = None
) -> float:
    """Siren probability of one ``(channels, samples)`` window (default constants unless ``detector``)."""
    det = detector if detector is not None else SirenEnergyDetector(sample_rate)
    return float(det.proba_from_scores(np.array([detector_score(window, sample_rate)]))[0])
