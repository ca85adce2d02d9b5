"""Siren ranging beyond 50 m: the far ranger (issue 25, item 2).

The siren networks (:mod:`~makeway.perceive.audio.siren_model`) place a siren mostly by how loud it
arrives, and were trained on sirens within 100 m: a siren 150–300 m away is put at 35–80 m, and
with emitted levels varying by 25 dB between sirens, loudness cannot tell a quiet near siren from a
loud far one. The far ranger is a small network that sits *behind* them and reads what changes
with distance but not with loudness, over the last few seconds:

* **Spectral shape** of the window (:func:`spectrum_row`): the capsules' mean power in
  :data:`N_BANDS` log-spaced bands over :data:`SPECTRUM_HZ`, each relative to the siren band's
  (500–1800 Hz) power, and each band's *tonality* (its strongest bin over its mean log level, dB: how
  far the siren's harmonics stand above the noise there). Air absorbs high frequencies faster
  (≈ 10 dB more at 8 kHz than at 1 kHz per 100 m) and the road reflection's comb moves its first
  notch down with distance (≈ 3.7 kHz at 100 m, 7.4 kHz at 200 m for a siren at 1.5 m), so far
  sirens lose their upper harmonics; a louder siren does not. Bands stop below 8 kHz: real street
  recordings (the simulator's noise ingredients) hold nothing above it, and a cue that rests on
  the noise missing there would not survive a real street.
* **Level** of the window in the siren band (dB SPL at the array) and the networks' own outputs:
  ln distance, its σ when they give one, and the siren logit.
* **Trend over** :data:`HISTORY_S` (3 s) of windows (:class:`FarTracker`): the slope and spread
  of the level and of the networks' ln distance, the bearing rate (a far siren's bearing hardly
  moves, a near one sweeps), and the mean spectral shape over the history (averaging the noise
  down).

From that row (:attr:`FarTracker.feature_names`) the network gives ``ln distance``, ``ln σ`` (the
spread of the ln distance error it expects: ±1σ is ``distance · e^(±σ)``, fitted by Gaussian
negative log-likelihood) and ``far_logit``: P(distance > :data:`FAR_BOUNDARY_M`). It is trained by
``makeway audio train-far`` (:mod:`makeway.train.far_range`) on simulated training-split scenes out
to 400 m (``makeway audio simulate --far-start``); model card ``docs/model_card_siren_net.md``,
"Far ranger".

**In use** (opt-in: ``SirenListener(far_ranger=...)``, ``--far-ranger`` on ``makeway audio
listen``): the listener feeds every window to a :class:`FarTracker`, and each siren it reports
carries ``far_probability`` and ``distance_sigma`` (:class:`~makeway.messages.SirenSource`); the
distance becomes the far ranger's (where ``far_probability ≥`` :data:`FAR_DISTANCE_PROBABILITY`,
which validation set to 0: everywhere). A source with ``far_probability ≥``
:data:`FAR_CALL_PROBABILITY` is *far*: the listener reports no approaching/receding call for it
(the trend classifier was trained within 100 m) and the siren track
(:class:`~makeway.fuse.siren_track.SirenTrackFusion`) treats the fix as beyond ranging (bearing
only; the last approach call stands). Both thresholds were chosen on validation scenes (seeds 77 +
78), never on held-out ones.

The rows depend on the siren networks that feed them: the shipped far ranger was trained on the
default stack's outputs (detector, localizer, :data:`~makeway.perceive.audio.siren_model
.DEFAULT_SIREN_RANGERS`), named in its metadata (``networks``).
"""

from __future__ import annotations

import functools
import json
import math
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import fft as sp_fft

from makeway.errors import InputError
from makeway.onnx_models import open_makeway_onnx
from makeway.perceive.audio.features import BAND_HZ

__all__ = [
    "DEFAULT_FAR_RANGER",
    "FAR_BOUNDARY_M",
    "FAR_CALL_PROBABILITY",
    "FAR_DISTANCE_PROBABILITY",
    "FarEstimate",
    "FarRanger",
    "FarTracker",
    "spectrum_row",
]

DEFAULT_FAR_RANGER = Path(__file__).resolve().parents[2] / "models" / "siren_far_ranger.onnx"
"""The shipped far ranger (opt-in; model card ``docs/model_card_siren_net.md``, "Far ranger")."""
FAR_BOUNDARY_M = 100.0
"""``far_logit`` is P(distance > this); also the boundary of the far/near call (issue 25)."""
FAR_CALL_PROBABILITY = 0.5
"""A source whose far probability reaches this is *far* (module docstring). Chosen on validation
scenes (seeds 77 + 78, training-split ingredients, EVs out to ~300 m, 110–135 dB at 1 m;
``benchmarks/bench_audio_far_range.py --split train --seeds 77,78``) as the threshold of 0.3–0.8
with the most far/near calls right at 10–300 m: 87.4 % (0.4: 86.1 %, 0.6: 86.8 %)."""
FAR_DISTANCE_PROBABILITY = 0.0
"""At or above this far probability the far ranger's distance replaces the networks' (module
docstring). Chosen on the same validation scenes as the switch of 0, 0.3, 0.5, 0.7 or never with
the lowest mean over the four distance bands of the median relative error: 0, i.e. the far
ranger's distance everywhere (32.5 % against 35.5–37.5 % for the others and 56 % for the networks
alone), so the reported σ is always that of the reported distance."""
SPECTRUM_HZ = (350.0, 7600.0)
"""Frequencies of the spectral-shape bands (Hz; below the 8 kHz of the street recordings)."""
N_BANDS = 16
"""Log-spaced spectral-shape bands over :data:`SPECTRUM_HZ`."""
HISTORY_S = 3.0
"""Span (s) of windows the trend features are formed over."""
MIN_TREND_WINDOWS = 3
"""A slope needs at least this many windows in the history."""
LOG_FLOOR = 1e-20


@dataclass(frozen=True)
class FarEstimate:
    """The far ranger's answer for one window: ``distance_m`` (m, ground plane), ``sigma`` (σ of
    ln distance: ±1σ is ``distance · e^(±σ)``) and ``far_probability`` = P(distance >
    :data:`FAR_BOUNDARY_M`)."""

    distance_m: float
    sigma: float
    far_probability: float


FRAME = 4096
"""FFT frame (samples; 85 ms, 11.7 Hz bins at 48 kHz) of the spectral shape: the window's whole
frames are averaged (Welch), over all capsules."""


@functools.lru_cache(maxsize=8)
def _band_edges(sample_rate: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Bin index edges of the :data:`N_BANDS` bands and of the siren band for an ``n``-point rFFT."""
    f = np.fft.rfftfreq(n, 1.0 / sample_rate)
    hz = np.geomspace(SPECTRUM_HZ[0], min(SPECTRUM_HZ[1], 0.48 * sample_rate), N_BANDS + 1)
    return np.searchsorted(f, hz), np.searchsorted(f, np.array(BAND_HZ))


@functools.lru_cache(maxsize=4)
def _hann(n: int) -> np.ndarray:
    return np.hanning(n).astype(np.float32)


def spectrum_row(window: np.ndarray, sample_rate: int) -> np.ndarray:
    """The spectral-shape features of ``window (channels, samples)`` (module docstring):
    :data:`N_BANDS` band levels relative to the siren band's, then :data:`N_BANDS` tonalities (dB:
    the band's strongest bin over its mean log level).
    The power spectrum is the mean over the capsules and over the window's last whole frames of
    :data:`FRAME` samples (one shorter frame for a window shorter than that)."""
    x = np.atleast_2d(np.asarray(window, dtype=np.float32))
    n = x.shape[-1]
    if n < 256:
        raise ValueError(f"a window of {n} samples is too short for the far ranger's spectrum")
    frame = min(FRAME, n)
    k = n // frame
    frames = x[:, n - k * frame :].reshape(x.shape[0], k, frame)
    spec = sp_fft.rfft(frames * _hann(frame), axis=-1)
    power = (spec.real**2 + spec.imag**2).mean(axis=(0, 1))
    edges, ref = _band_edges(int(sample_rate), frame)
    ref_db = 10.0 * math.log10(max(float(power[ref[0] : ref[1]].mean()), LOG_FLOOR))
    lo, hi = edges[:-1], np.maximum(edges[1:], edges[:-1] + 1)
    width = (hi - lo).astype(np.float64)
    db = 10.0 * np.log10(np.maximum(power[: hi[-1]], LOG_FLOOR))
    mean_power = np.add.reduceat(power[: hi[-1]], lo) / width
    shape = 10.0 * np.log10(np.maximum(mean_power, LOG_FLOOR)) - ref_db
    # tonality: the band's strongest bin over its mean log level (a geometric mean: the noise floor)
    tonal = np.maximum.reduceat(db, lo) - np.add.reduceat(db, lo) / width
    return np.concatenate([shape, tonal])


def _slope(t: np.ndarray, y: np.ndarray) -> float:
    tc = t - t.mean()
    den = float(tc @ tc)
    return float(tc @ (y - y.mean())) / den if den > 0 else 0.0


class FarTracker:
    """The far ranger's feature rows, window by window (module docstring): call :meth:`observe`
    with every window of a stream in time order, with the siren networks' outputs for it; it keeps
    :data:`HISTORY_S` of history. :meth:`reset` forgets it."""

    window_names = (
        *(f"shape_{k}" for k in range(N_BANDS)),
        *(f"tonal_{k}" for k in range(N_BANDS)),
        "level_db_spl",
        "log_distance",
        "sigma",
        "has_sigma",
        "siren_logit",
    )

    def __init__(self, history_s: float = HISTORY_S) -> None:
        if history_s <= 0:
            raise ValueError(f"history_s must be > 0, got {history_s}")
        self.history_s = float(history_s)
        self.reset()

    @property
    def feature_names(self) -> list[str]:
        """The columns of a feature row, in order."""
        hist = [f"mean_{n}" for n in self.window_names[: 2 * N_BANDS]]
        trend = [
            "level_slope_db_s",
            "level_std_db",
            "log_distance_slope",
            "log_distance_std",
            "log_distance_mean",
            "bearing_rate_rad_s",
            "bearing_std_rad",
            "history_s",
        ]
        return [*self.window_names, *hist, *trend]

    def reset(self) -> FarTracker:
        """Forget the history."""
        self.history_: deque[tuple[float, np.ndarray, float]] = deque()  # (time, window row, bearing)
        return self

    def observe(
        self,
        window: np.ndarray,
        sample_rate: int,
        time_s: float,
        *,
        level_db_spl: float,
        distance_m: float,
        bearing_rad: float,
        siren_probability: float,
        sigma: float | None = None,
    ) -> np.ndarray:
        """The feature row of the window ``(channels, samples)`` ending at ``time_s`` (s), given its
        level in the siren band (dB SPL) and the networks' distance (m), bearing (rad), siren
        probability and σ of ln distance (``None`` when they give none)."""
        t = float(time_s)
        p = min(max(float(siren_probability), 1e-6), 1.0 - 1e-6)
        log_d = math.log(max(float(distance_m), 1.0)) if math.isfinite(distance_m) else 0.0
        own = np.concatenate(
            [
                spectrum_row(window, sample_rate),
                [
                    float(level_db_spl),
                    log_d,
                    0.0 if sigma is None else float(sigma),
                    0.0 if sigma is None else 1.0,
                    math.log(p / (1.0 - p)),
                ],
            ]
        )
        self.history_.append((t, own, float(bearing_rad)))
        while self.history_ and self.history_[0][0] <= t - self.history_s:
            self.history_.popleft()
        times = np.array([h[0] for h in self.history_])
        rows = np.array([h[1] for h in self.history_])
        bearing = np.unwrap(np.array([h[2] for h in self.history_]))
        n_spec = 2 * N_BANDS
        level, logd = rows[:, n_spec], rows[:, n_spec + 1]
        if len(times) >= MIN_TREND_WINDOWS:
            trend = [
                _slope(times, level),
                float(level.std()),
                _slope(times, logd),
                float(logd.std()),
                float(logd.mean()),
                abs(_slope(times, bearing)),
                float(bearing.std()),
            ]
        else:
            trend = [0.0, 0.0, 0.0, 0.0, log_d, 0.0, 0.0]
        span = float(times[-1] - times[0]) if len(times) > 1 else 0.0
        return np.concatenate([own, rows[:, :n_spec].mean(axis=0), trend, [span]]).astype(np.float32)


class FarRanger:
    """The trained far ranger (module docstring) in ONNX Runtime, with its own :class:`FarTracker`.

    Args:
        path: the ``.onnx`` file written by ``makeway audio train-far`` (default:
            :data:`DEFAULT_FAR_RANGER`).
        threads: ONNX Runtime intra-op threads (``None``: all cores).

    Raises:
        InputError: the file is missing, not ONNX, not a far ranger, or reads other features.
    """

    def __init__(self, path: str | Path | None = None, *, threads: int | None = 1) -> None:
        self.path = Path(path) if path is not None else DEFAULT_FAR_RANGER
        self.session, meta = open_makeway_onnx(
            self.path,
            "siren_far_ranger",
            threads=threads,
            missing_hint="train one with `makeway audio train-far`",
        )
        self.tracker = FarTracker()
        try:
            names = json.loads(meta["feature_names"])
            self.far_boundary_m = float(meta.get("far_boundary_m", FAR_BOUNDARY_M))
            self.networks: list[str] = list(json.loads(meta.get("networks", "[]")))
        except (KeyError, ValueError, TypeError) as exc:
            raise InputError(
                self.path, f"malformed far ranger metadata ({type(exc).__name__}: {exc})"
            ) from None
        if names != self.tracker.feature_names:
            raise InputError(
                self.path,
                f"this far ranger reads {len(names)} features that differ from the "
                f"{len(self.tracker.feature_names)} this version makes (train it again with "
                "`makeway audio train-far`)",
            )
        self.metadata: dict[str, str] = dict(meta)
        self._input = self.session.get_inputs()[0].name

    def __repr__(self) -> str:
        return f"FarRanger({self.path.name}, far_boundary_m={self.far_boundary_m:g})"

    def reset(self) -> FarRanger:
        """Forget the history (a new stream)."""
        self.tracker.reset()
        return self

    def run_rows(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(distance_m, sigma, far_probability)`` for feature rows ``(n, n_features)``."""
        x = np.ascontiguousarray(
            np.asarray(rows, dtype=np.float32).reshape(-1, len(self.tracker.feature_names))
        )
        log_d, log_sigma, far_logit = self.session.run(None, {self._input: x})
        distance = np.exp(np.asarray(log_d, dtype=np.float64))
        sigma = np.exp(np.asarray(log_sigma, dtype=np.float64))
        prob = 1.0 / (1.0 + np.exp(-np.asarray(far_logit, dtype=np.float64)))
        return distance, sigma, prob

    def update(
        self,
        window: np.ndarray,
        sample_rate: int,
        time_s: float,
        *,
        level_db_spl: float,
        distance_m: float,
        bearing_rad: float,
        siren_probability: float,
        sigma: float | None = None,
    ) -> FarEstimate:
        """Feed one window (:meth:`FarTracker.observe`) and return the far ranger's estimate for it."""
        row = self.tracker.observe(
            window,
            sample_rate,
            time_s,
            level_db_spl=level_db_spl,
            distance_m=distance_m,
            bearing_rad=bearing_rad,
            siren_probability=siren_probability,
            sigma=sigma,
        )
        d, s, p = self.run_rows(row[None])
        return FarEstimate(float(d[0]), float(s[0]), float(p[0]))


def combined_distance(
    network_m: np.ndarray,
    far_m: np.ndarray,
    far_probability: np.ndarray,
    threshold: float = FAR_DISTANCE_PROBABILITY,
) -> np.ndarray:
    """The distance the listener reports with a far ranger: the far ranger's where its far
    probability reaches ``threshold``, the networks' elsewhere."""
    return np.where(np.asarray(far_probability) >= threshold, far_m, network_m)


def far_metadata(meta: dict[str, Any]) -> dict[str, str]:
    """``meta`` as ONNX metadata strings (JSON for anything that is not a string)."""
    return {k: v if isinstance(v, str) else json.dumps(v) for k, v in meta.items()}
