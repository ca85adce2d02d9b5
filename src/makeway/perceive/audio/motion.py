"""Approaching or receding siren from the level trend and the Doppler shift (issue 4, item 3).

:class:`ApproachEstimator` is fed consecutive (overlapping) windows of a stream. From each window it
keeps the 25 ms / 10 ms frames that are newer than the ones it already has, and for each such frame
two numbers, on the mean power spectrum of one capsule per unit (L-front, R-front):

* the in-band level, ``10·log10`` of the summed power in 500–1800 Hz (dB);
* the dominant in-band peak frequency (Hz).

Over the last ``history_s`` (2.5 s) of frames it forms two cues.

**Level trend** (the main cue). The slope ``s`` (dB/s) of a least-squares line through the level.
A point source at range ``r`` changing at ``ṙ`` gives ``s = −(20 / ln 10)·ṙ / r ≈ −8.69·ṙ/r``: an EV
closing at 10 m/s from 50 m raises the level by ~1.7 dB/s. Rising means approaching. The level of
a sweeping siren also depends on its pitch — ground-reflection interference, the siren's own
spectrum — by up to tens of dB over a wail, so the line is fitted jointly with a quadratic in
``log(pitch)`` (``level ≈ a + s·t + b·lp + c·lp²``) and only ``s`` is kept, so the sweep's own
level changes do not pass for a trend (see docs/results.md, section "Approaching / receding").

**Doppler shift** (tie-breaker only). The siren's own wail/yelp sweeps move the instantaneous peak
frequency by an octave, far more than the Doppler shift (±3 % at 10 m/s), and the absolute shift is
unknown because the siren's pitch is. What is usable is the *slow* change of the mean pitch: the
sweep period ``P`` is estimated from the autocorrelation of the peak-frequency track (0.1–1.25 s;
the whole half-history when there is no clear period), the mean peak frequency is taken over the
largest whole number of periods at the start and at the end of the history, and the relative change
``δ = f_end / f_start − 1`` is the Doppler trend. A falling pitch (δ < 0) means the range rate went
up, i.e. the EV passed and now recedes; a rising pitch means it turned towards us.

**Decision rule, with hysteresis** (state ``None`` = undecided, ``True`` = approaching,
``False`` = receding):

1. fewer than ``min_history_s`` (1 s) of frames: keep the state (``None`` at the start);
2. ``s ≥ on_db_s`` (0.6 dB/s) → approaching; ``s ≤ −on_db_s`` → receding (from any state);
3. otherwise a decided state is kept while the slope does not go against it by more than
   ``off_db_s`` (0.2 dB/s), and falls back to ``None`` when it does;
4. when the result of 1–3 is ``None`` and ``|δ| ≥ doppler_min`` (1 %) with a slope that does not
   contradict it by more than ``off_db_s``, the Doppler trend decides (falling pitch → receding).

:meth:`ApproachEstimator.update` also returns ``range_rate_hint``: ``ṙ/r`` in 1/s from the level
slope (``−s / 8.69``, negative when approaching). Without a distance estimate this relative rate
(the inverse of the time to reach the array) is the only range rate the audio gives.

**Distance trend** (:class:`TrendApproach`, the listener's default with the siren network). With
the network's distance in every window, the slope of ln distance over a few seconds *is* ``ṙ/r``.
Those slopes and the two cues above go through a small trained classifier, which tells
approaching from receding in more windows than the level/Doppler rule alone (see docs/results.md,
section "Approaching / receding"). :data:`APPROACH_METHODS` names both.
"""

from __future__ import annotations

import json
import math
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from makeway.errors import InputError
from makeway.onnx_models import open_makeway_onnx
from makeway.perceive.audio.features import BAND_HZ, frame_params, power_spectrogram
from makeway.perceive.audio.siren_model import DEFAULT_SIREN_RANGERS, ranger_set_name
from makeway.registry import Registry

DB_PER_NEPER_RANGE = 20.0 / math.log(10.0)
"""Level slope (dB/s) per unit of relative range rate ṙ/r (1/s), with the sign flipped."""
MIN_PERIOD_S = 0.1
MAX_PERIOD_S = 1.25


class ApproachEstimator:
    """Streaming approaching/receding decision (see the module docstring for the rule).

    scikit-learn-like: every setting is an ``__init__`` argument stored under its own name; the
    running state lives in attributes ending with ``_`` and is cleared by :meth:`reset`.
    """

    def __init__(
        self,
        history_s: float = 2.5,
        min_history_s: float = 1.0,
        on_db_s: float = 0.6,
        off_db_s: float = 0.2,
        doppler_min: float = 0.01,
        band: tuple[float, float] = BAND_HZ,
        channels: tuple[int, ...] = (0, 4),
    ) -> None:
        if not 0 < min_history_s <= history_s:
            raise ValueError("need 0 < min_history_s <= history_s")
        if not 0 <= off_db_s <= on_db_s:
            raise ValueError("need 0 <= off_db_s <= on_db_s")
        self.history_s = float(history_s)
        self.min_history_s = float(min_history_s)
        self.on_db_s = float(on_db_s)
        self.off_db_s = float(off_db_s)
        self.doppler_min = float(doppler_min)
        self.band = (float(band[0]), float(band[1]))
        self.channels = tuple(int(c) for c in channels)
        self.reset()

    def __repr__(self) -> str:
        return (
            f"ApproachEstimator(history_s={self.history_s:g}, on_db_s={self.on_db_s:g}, "
            f"off_db_s={self.off_db_s:g}, doppler_min={self.doppler_min:g})"
        )

    def reset(self) -> ApproachEstimator:
        """Forget the history and the decision."""
        self.frames_: deque[tuple[float, float, float]] = deque()  # (time, level_db, peak_hz)
        self.state_: bool | None = None
        self.slope_db_s_: float | None = None
        self.doppler_: float | None = None
        self.probability_: float | None = None  # a rule, not a classifier: never set
        return self

    # ------------------------------------------------------------------------------------- cues

    def _add_frames(self, window: np.ndarray, sample_rate: int, time_s: float) -> None:
        w = np.asarray(window, dtype=np.float64)
        if w.ndim == 1:
            w = w[None]
        if w.ndim != 2 or w.shape[1] == 0:
            raise ValueError(f"window must be (channels, samples); got {w.shape}")
        chans = [c for c in self.channels if c < w.shape[0]] or [0]
        power = power_spectrogram(w[chans], sample_rate).mean(axis=0)  # (bins, frames)
        frame, hop, n_fft = frame_params(sample_rate)
        f = np.fft.rfftfreq(n_fft, 1.0 / sample_rate)
        sel = (f >= self.band[0]) & (f <= self.band[1])
        inband = power[sel]
        level = 10.0 * np.log10(np.maximum(inband.sum(axis=0), 1e-30))
        peak = f[sel][np.argmax(inband, axis=0)]
        start = float(time_s) - w.shape[1] / sample_rate
        times = start + (np.arange(power.shape[1]) * hop + frame / 2.0) / sample_rate
        last = self.frames_[-1][0] if self.frames_ else -math.inf
        # overlapping windows: keep only frames newer than the last one stored (half a hop of slack)
        for t, lv, pk in zip(times, level, peak, strict=True):
            if t > last + 0.5 * hop / sample_rate:
                self.frames_.append((float(t), float(lv), float(pk)))
                last = float(t)
        while self.frames_ and self.frames_[0][0] < last - self.history_s:
            self.frames_.popleft()

    @staticmethod
    def _sweep_period(t: np.ndarray, pitch: np.ndarray) -> float | None:
        """Dominant period (s) of the peak-frequency track from its autocorrelation, or None."""
        if len(t) < 8:
            return None
        dt = float(np.median(np.diff(t)))
        x = pitch - pitch.mean()
        den = float(np.dot(x, x))
        if den <= 0 or dt <= 0:
            return None
        lags = np.arange(max(1, round(MIN_PERIOD_S / dt)), min(len(x) // 2, round(MAX_PERIOD_S / dt)) + 1)
        if len(lags) == 0:
            return None
        ac = np.array([np.dot(x[:-k], x[k:]) / den for k in lags])
        k = int(np.argmax(ac))
        return float(lags[k] * dt) if ac[k] > 0.3 else None

    @staticmethod
    def _level_slope(t: np.ndarray, level: np.ndarray, pitch: np.ndarray) -> float:
        """Level slope (dB/s) with a quadratic in log pitch as nuisance regressors."""
        tc = t - t.mean()
        lp = np.log(np.maximum(pitch, 1.0) / max(float(np.mean(pitch)), 1.0))
        x = np.stack([np.ones_like(tc), tc, lp, lp**2], axis=1)
        return float(np.linalg.lstsq(x, level, rcond=None)[0][1])

    def _doppler(self, t: np.ndarray, pitch: np.ndarray) -> float | None:
        """Relative change of the mean pitch over whole sweep periods, end vs start of the history."""
        span = float(t[-1] - t[0])
        half = 0.5 * span
        period = self._sweep_period(t, pitch)
        length = half if period is None or period > half else math.floor(half / period) * period
        first = pitch[t <= t[0] + length]
        last = pitch[t >= t[-1] - length]
        if len(first) == 0 or len(last) == 0 or first.mean() <= 0:
            return None
        return float(last.mean() / first.mean() - 1.0)

    # ---------------------------------------------------------------------------------- update

    def update(
        self,
        window: np.ndarray,
        sample_rate: int,
        time_s: float,
        *,
        distance_m: float | None = None,
        is_siren: bool = True,
    ) -> tuple[bool | None, float | None]:
        """Feed the window ``(channels, samples)`` that ends at ``time_s``; return
        ``(approaching, range_rate_hint)`` — ``approaching`` None while undecided, the hint ``ṙ/r``
        (1/s, from the level slope) None until there is enough history. ``distance_m`` and
        ``is_siren`` are not used here; they keep the call the same as :meth:`TrendApproach.update`."""
        self._add_frames(window, int(sample_rate), float(time_s))
        if len(self.frames_) < 3:
            return self.state_, None
        arr = np.array(self.frames_)
        t, level, pitch = arr[:, 0], arr[:, 1], arr[:, 2]
        if t[-1] - t[0] < self.min_history_s:
            return self.state_, None
        slope = self._level_slope(t, level, pitch)
        doppler = self._doppler(t, pitch)
        self.slope_db_s_, self.doppler_ = slope, doppler

        state = self.state_
        if slope >= self.on_db_s:
            state = True
        elif slope <= -self.on_db_s:
            state = False
        elif (state is True and slope <= -self.off_db_s) or (state is False and slope >= self.off_db_s):
            state = None
        if state is None and doppler is not None and abs(doppler) >= self.doppler_min:
            vote = doppler > 0
            if (slope if vote else -slope) >= -self.off_db_s:
                state = vote
        self.state_ = state
        return state, -slope / DB_PER_NEPER_RANGE


_MODELS = Path(__file__).resolve().parents[2] / "models"
APPROACH_MODELS: Registry[Path] = Registry(
    "approach classifier",
    {"prior": _MODELS / "siren_approach.onnx", "wide": _MODELS / "siren_approach_wide.onnx"},
)
"""The shipped classifiers of :class:`TrendApproach`, one per ranger set of
:data:`~makeway.perceive.audio.siren_model.SIREN_RANGER_SETS` (same names): each was trained on the
distances of its set (with the localizer's), and reads another set's worse, because the sets err
differently (``makeway audio train-approach --ranger ...``; model card
``docs/model_card_siren_net.md``, "The approach classifier")."""
DEFAULT_APPROACH_MODEL = APPROACH_MODELS[ranger_set_name(DEFAULT_SIREN_RANGERS) or "prior"]
"""The classifier paired with the default rangers
(:data:`~makeway.perceive.audio.siren_model.DEFAULT_SIREN_RANGERS`)."""


def approach_model_for(rangers: Sequence[str | Path]) -> Path:
    """The classifier trained on the distances of the ranger networks ``rangers`` (files): the one of
    :data:`APPROACH_MODELS` paired with that shipped set (compared by file name,
    :func:`~makeway.perceive.audio.siren_model.ranger_set_name`), :data:`DEFAULT_APPROACH_MODEL`
    for any other combination."""
    name = ranger_set_name(rangers)
    return APPROACH_MODELS[name] if name is not None else DEFAULT_APPROACH_MODEL


TREND_HORIZONS_S = (1.0, 1.5, 2.5, 4.0)
"""Spans (s) over which :class:`TrendApproach` fits the slope of the network's log distance."""
MIN_TREND_WINDOWS = 3
"""A slope needs at least this many siren windows within its span."""
MIN_RECEDING_WINDOWS = 6
""":class:`TrendApproach` withholds a *receding* call (``approaching`` None, undecided) until this
many siren windows are in its history (6 windows of the listener's 0.17 s hop: about 1 s of siren,
1.35 s of audio); an approaching call is never held back (issue 26, seed003)."""
HINT_HORIZON_S = 1.5
"""The span whose slope :meth:`TrendApproach.update` returns as the ``ṙ/r`` hint."""


class TrendApproach:
    """Approaching or receding from the *trend of the network's distance*, with the level and
    Doppler cues of :class:`ApproachEstimator` beside it, combined by a trained classifier.

    The siren network (with its localizer and rangers) estimates the nearest siren's distance in
    every window (its accuracy: docs/results.md, "Siren detection, bearing and distance"). One
    window's distance is too noisy to tell
    direction, but its trend over a few seconds is not: for a point source ``d ln r / dt = ṙ / r``,
    negative while the siren comes closer. Each update:

    1. feeds the window to an :class:`ApproachEstimator` (level slope and Doppler trend);
    2. keeps ``(time, ln distance)`` of the windows the listener decided are a siren;
    3. forms the feature row (:attr:`feature_names`): for each span of :data:`TREND_HORIZONS_S`, the
       least-squares slope of ln distance over the siren windows within it and whether there were
       at least ``min_windows`` of them; the level slope and whether there is one; the Doppler
       trend; this window's ln distance;
    4. the classifier (gradient-boosted trees in ONNX; the one paired with the ranger set whose
       distances feed it, :func:`approach_model_for`, default :data:`DEFAULT_APPROACH_MODEL`) turns the
       row into ``probability_`` = P(approaching); ``approaching = probability_ ≥ 0.5``, or None
       while no cue exists yet (no slope and no level slope);
    5. a *receding* call is withheld (``approaching`` None, ``probability_`` None, ``withheld_``
       True) while fewer than ``min_receding_windows`` siren windows are in the history
       (:data:`MIN_RECEDING_WINDOWS`, 6: about 1 s of siren at the listener's 0.17 s hop). An
       approaching call is given at once. At the start of a siren the distance trend has two or
       three noisy points and the level slope the siren's own onset; the classifier then calls a
       siren that is closing in "receding" now and then, and a receding call lets the yield
       decision wait (a receding EV behind is not yielded to), while an undecided one is treated
       as approaching (:func:`~makeway.decide.yield_fsm.needs_yield`): on seed003 (an EV 50 m
       behind) such an early call delayed the stop (issue 26; ``benchmarks/bench_seed003_timeline.py
       --trace``). ``min_receding_windows=0`` turns this off.

    The classifier is trained by ``makeway audio train-approach`` on simulated training-split
    recordings (:mod:`makeway.train.approach`): the truth is the sign of the labelled range rate of
    the nearest siren (SPEC §3 labels), over the windows the listener reports with a siren that is
    moving relative to the car (``|ṙ| ≥ 1 m/s``). ``model=None`` builds the feature rows only
    (what training uses); :meth:`decide` gives the decisions for a batch of rows.
    """

    def __init__(
        self,
        model: str | Path | None = DEFAULT_APPROACH_MODEL,
        *,
        horizons: tuple[float, ...] = TREND_HORIZONS_S,
        min_windows: int = MIN_TREND_WINDOWS,
        min_receding_windows: int = MIN_RECEDING_WINDOWS,
        level: ApproachEstimator | None = None,
        threads: int | None = 1,
    ) -> None:
        """``horizons``: the spans (s) of the distance slopes; ``min_windows``: siren windows a slope
        needs within its span; ``min_receding_windows``: siren windows (count, within the longest
        span) the history must hold before a receding call is given (class docstring, item 5; 0:
        never withheld); ``level``: the level/Doppler estimator (default a new
        :class:`ApproachEstimator`); ``threads``: the classifier's ONNX threads."""
        if not horizons or min(horizons) <= 0:
            raise ValueError(f"horizons must be positive spans in seconds, got {horizons}")
        if min_windows < 2:
            raise ValueError(f"min_windows must be >= 2 (a slope needs two points), got {min_windows}")
        n_receding = min_receding_windows
        if isinstance(n_receding, bool) or not isinstance(n_receding, (int, np.integer)) or n_receding < 0:
            raise ValueError(
                f"min_receding_windows must be a whole number of windows >= 0, got {n_receding!r}"
            )
        self.model = Path(model) if model is not None else None
        self.horizons = tuple(float(h) for h in horizons)
        self.min_windows = int(min_windows)
        self.min_receding_windows = int(min_receding_windows)
        self.level = level if level is not None else ApproachEstimator()
        self.threads = threads
        self.session_: Any = None
        if self.model is not None:
            self.session_ = self._load(self.model)
        self.reset()

    def __repr__(self) -> str:
        name = self.model.name if self.model is not None else None
        return (
            f"TrendApproach(model={name!r}, horizons={self.horizons}, min_windows={self.min_windows}, "
            f"min_receding_windows={self.min_receding_windows})"
        )

    @property
    def feature_names(self) -> list[str]:
        """The columns of a feature row, in order (class docstring)."""
        names: list[str] = []
        for h in self.horizons:
            names += [f"log_distance_slope_{h:g}s", f"has_slope_{h:g}s"]
        return [*names, "level_slope_db_s", "has_level_slope", "doppler", "log_distance"]

    def _load(self, path: Path) -> Any:
        session, meta = open_makeway_onnx(
            path,
            "siren_approach",
            threads=self.threads,
            missing_hint="train one with `makeway audio train-approach`",
        )
        try:
            names = json.loads(meta["feature_names"])
        except (KeyError, ValueError) as exc:
            raise InputError(path, f"malformed approach model metadata ({exc})") from None
        if names != self.feature_names:
            raise InputError(
                path, f"the classifier reads the features {names}, this estimator makes {self.feature_names}"
            )
        return session

    def reset(self) -> TrendApproach:
        """Forget the history and the decision."""
        self.level.reset()
        self.history_: deque[tuple[float, float]] = deque()  # (time, ln distance) of siren windows
        self.state_: bool | None = None
        self.probability_: float | None = None
        self.features_: np.ndarray | None = None
        self.withheld_ = False  # this window's receding call was withheld (class docstring, item 5)
        return self

    def observe(
        self,
        window: np.ndarray,
        sample_rate: int,
        time_s: float,
        *,
        distance_m: float | None = None,
        is_siren: bool = True,
    ) -> np.ndarray:
        """Feed one window (as :meth:`update`) and return its feature row, without deciding."""
        t = float(time_s)
        self.level.update(window, sample_rate, t)
        log_d = (
            math.log(max(float(distance_m), 1.0))
            if distance_m is not None and math.isfinite(distance_m)
            else 0.0
        )
        if is_siren and distance_m is not None and math.isfinite(distance_m):
            self.history_.append((t, log_d))
        while self.history_ and self.history_[0][0] <= t - max(self.horizons):
            self.history_.popleft()
        row: list[float] = []
        hist = np.array(self.history_, dtype=np.float64).reshape(-1, 2)
        for h in self.horizons:
            sel = hist[hist[:, 0] > t - h]
            if len(sel) >= self.min_windows and np.ptp(sel[:, 0]) > 0:
                row += [float(np.polyfit(sel[:, 0], sel[:, 1], 1)[0]), 1.0]
            else:
                row += [0.0, 0.0]
        slope, doppler = self.level.slope_db_s_, self.level.doppler_
        row += [slope if slope is not None else 0.0, float(slope is not None)]
        row += [doppler if doppler is not None else 0.0, log_d]
        self.features_ = np.array(row, dtype=np.float32)
        return self.features_

    def predict_proba(self, rows: np.ndarray) -> np.ndarray:
        """P(approaching) for feature rows ``(n, n_features)``."""
        if self.session_ is None:
            raise ValueError("this TrendApproach has no classifier (model=None): it only makes features")
        x = np.ascontiguousarray(np.asarray(rows, dtype=np.float32).reshape(-1, len(self.feature_names)))
        probabilities = self.session_.run(None, {self.session_.get_inputs()[0].name: x})[1]
        return np.asarray(probabilities, dtype=np.float64)[:, 1]

    def decide(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(approaching, probability)`` for feature rows: ``approaching`` is 1.0 / 0.0, NaN where a
        row has no cue (no distance slope and no level slope)."""
        x = np.asarray(rows, dtype=np.float32).reshape(-1, len(self.feature_names))
        p = self.predict_proba(x)
        has_cue = x[:, 1 : 2 * len(self.horizons) : 2].any(axis=1) | (x[:, 2 * len(self.horizons) + 1] > 0)
        return np.where(has_cue, (p >= 0.5).astype(np.float64), np.nan), p

    def update(
        self,
        window: np.ndarray,
        sample_rate: int,
        time_s: float,
        *,
        distance_m: float | None = None,
        is_siren: bool = True,
    ) -> tuple[bool | None, float | None]:
        """Feed the window ``(channels, samples)`` that ends at ``time_s``, with the network's
        distance for it and the listener's decision; return ``(approaching, range_rate_hint)`` —
        ``approaching`` None while no cue exists, the hint ``ṙ/r`` (1/s) the slope of ln distance
        over :data:`HINT_HORIZON_S` (None without one). ``probability_`` holds P(approaching).
        A receding call is withheld (None) while the history holds fewer than
        ``min_receding_windows`` siren windows (class docstring, item 5; ``withheld_`` says so)."""
        row = self.observe(window, sample_rate, time_s, distance_m=distance_m, is_siren=is_siren)
        state, p = self.decide(row[None])
        self.state_ = None if math.isnan(state[0]) else bool(state[0])
        self.withheld_ = self.state_ is False and len(self.history_) < self.min_receding_windows
        if self.withheld_:
            self.state_ = None
        self.probability_ = None if self.state_ is None else float(p[0])
        k = self.horizons.index(HINT_HORIZON_S) if HINT_HORIZON_S in self.horizons else 0
        hint = float(row[2 * k]) if row[2 * k + 1] > 0 else None
        return self.state_, hint


APPROACH_METHODS: Registry[type[ApproachEstimator] | type[TrendApproach]] = Registry(
    "approach method", {"level": ApproachEstimator, "trend": TrendApproach}
)
"""Approaching/receding estimators by name: ``level`` (level slope and Doppler; needs no network)
and ``trend`` (the network's distance trend and those cues, through a trained classifier)."""
