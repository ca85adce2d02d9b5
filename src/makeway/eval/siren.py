"""Window-level evaluation of a siren detector + localizer on labelled recordings (issue 4, SPEC §3).

:func:`evaluate` auto-labels each recording (0.5 s windows every 0.17 s, sources beyond 100 m
dropped, and windows whose every siren lies beyond 100 m skipped, see
:mod:`~makeway.eval.siren_labels`), runs a method on every window and returns the JSON keys
of ``makeway audio eval``:

* ``recall`` — detected share of the windows with a siren within 100 m; ``false_alarm_rate`` —
  detected share of the windows without; ``accuracy`` — share of windows classified right. All
  fractions in [0, 1]; a detection is a probability ≥ ``threshold`` (0.5).
* ``angle_median_deg`` / ``angle_mean_deg`` — wrapped bearing error (|Δθ| ≤ 180°) against the
  **nearest** present source (by distance), over every window with a siren (whether detected or
  not, as in Table II of seed 002, the Apollo siren detection and localization paper, so the
  detector's misses do not hide localization errors);
  ``distance_median_m`` / ``distance_mean_m`` — absolute distance error; ``null`` for the classical
  baselines, which give no distance.
* ``range_10_50`` — the same keys over the windows whose nearest source lies within 10–50 m (the
  issue's target range); its ``false_alarm_rate`` is over all negative windows (they have no range)
  and its ``accuracy`` over those positives plus all negatives.
* ``by_distance`` — 10 m bins of the nearest source's distance (0–10, …, 90–100): ``n``, ``recall``,
  ``angle_median_deg``, ``angle_mean_deg``.

Plus ``method``, ``recordings``, ``windows``, ``positives``, ``negatives``, ``dropped_windows``
(skipped: sirens only beyond 100 m), ``ms_per_window`` (the
method's wall time per window: detector + bearing), ``smooth``, ``smooth_average`` (``null`` for a
per-window decision), ``recordings_without_calibration``
(recordings whose array does not state ``full_scale_db_spl`` and that were taken at the model's
calibration; :mod:`makeway.sense.recording`, **Calibration**).

**Decision smoothing** (``smooth`` = K > 1): the decision for a window uses the mean of that
window and the K − 1 windows before it in the same recording (:func:`smoothed_probability`; the mean
of their logits unless ``average="probability"``), as a live listener would (``makeway audio listen
--smooth K``): causal, about (K − 1) × 0.17 s of
added latency. Every window of a recording is then run, including those skipped for the metrics, so
the history is the one a live listener has. ``smooth = 1`` (the default) is seed 002's per-window
decision.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from makeway.eval.siren_labels import label_recording
from makeway.messages import SensorHealth
from makeway.perceive.audio.doa import DOA_METHODS, SirenEnergyDetector, wrap_angle
from makeway.perceive.audio.features import window_batch
from makeway.perceive.audio.windows import (
    HOP_S,
    SMOOTH_AVERAGE,
    WINDOW_S,
    StreamSmoother,
    smoothed_probability,
)
from makeway.perceive.health import SwapCheck, audio_health, repair_window
from makeway.sense.recording import Recording, assume_calibration, read_recording

METRIC_KEYS = (
    "recall",
    "false_alarm_rate",
    "accuracy",
    "angle_median_deg",
    "angle_mean_deg",
    "distance_median_m",
    "distance_mean_m",
)
"""The metric keys of ``makeway audio eval`` (also inside ``range_10_50``)."""
RANGE_10_50 = (10.0, 50.0)
BIN_M = 10.0


@dataclass
class WindowResults:
    """Per-window ground truth and outputs, pooled over recordings."""

    siren: list[np.ndarray] = field(default_factory=list)
    theta: list[np.ndarray] = field(default_factory=list)
    distance: list[np.ndarray] = field(default_factory=list)
    prob: list[np.ndarray] = field(default_factory=list)
    theta_hat: list[np.ndarray] = field(default_factory=list)
    distance_hat: list[np.ndarray] = field(default_factory=list)

    def arrays(self) -> dict[str, np.ndarray]:
        def cat(parts: list[np.ndarray], dtype: Any) -> np.ndarray:
            return np.concatenate(parts).astype(dtype) if parts else np.zeros(0, dtype)

        return {
            "siren": cat(self.siren, bool),
            "theta": cat(self.theta, np.float64),
            "distance": cat(self.distance, np.float64),
            "prob": cat(self.prob, np.float64),
            "theta_hat": cat(self.theta_hat, np.float64),
            "distance_hat": cat(self.distance_hat, np.float64),
        }


def _stat(values: np.ndarray, fn: Callable[[np.ndarray], Any], ndigits: int = 3) -> float | None:
    v = values[np.isfinite(values)]
    return round(float(fn(v)), ndigits) if len(v) else None


def _ratio(num: int, den: int) -> float | None:
    return round(num / den, 5) if den else None


def summarize(a: dict[str, np.ndarray], threshold: float = 0.5) -> dict[str, Any]:
    """The metric keys (module docstring) from pooled per-window arrays."""
    pos = a["siren"]
    det = a["prob"] >= threshold
    ang_err = np.degrees(np.abs(wrap_angle(a["theta_hat"] - a["theta"])))
    dist_err = np.abs(a["distance_hat"] - a["distance"])
    n_neg = int((~pos).sum())
    fa = int((det & ~pos).sum())

    def block(sel: np.ndarray) -> dict[str, Any]:
        s_pos = sel & pos
        n_pos = int(s_pos.sum())
        tp = int((det & s_pos).sum())
        correct = tp + (n_neg - fa)
        return {
            "recall": _ratio(tp, n_pos),
            "false_alarm_rate": _ratio(fa, n_neg),
            "accuracy": _ratio(correct, n_pos + n_neg),
            "angle_median_deg": _stat(ang_err[s_pos], np.median),
            "angle_mean_deg": _stat(ang_err[s_pos], np.mean),
            "distance_median_m": _stat(dist_err[s_pos], np.median),
            "distance_mean_m": _stat(dist_err[s_pos], np.mean),
            "positives": n_pos,
        }

    everything = block(np.ones_like(pos))
    lo, hi = RANGE_10_50
    d = a["distance"]
    in_range = pos & (d >= lo) & (d <= hi)
    bins: list[dict[str, Any]] = []
    for k in range(10):
        b_lo, b_hi = k * BIN_M, (k + 1) * BIN_M
        sel = pos & (d >= b_lo) & ((d < b_hi) if k < 9 else (d <= b_hi))
        n = int(sel.sum())
        bins.append(
            {
                "range_m": [b_lo, b_hi],
                "n": n,
                "recall": _ratio(int((det & sel).sum()), n),
                "angle_median_deg": _stat(ang_err[sel], np.median),
                "angle_mean_deg": _stat(ang_err[sel], np.mean),
            }
        )
    out = {k: v for k, v in everything.items() if k != "positives"}
    out["range_10_50"] = block(in_range)
    out["by_distance"] = bins
    out["windows"] = len(pos)
    out["positives"] = int(pos.sum())
    out["negatives"] = n_neg
    return out


WindowEstimator = Callable[[Recording, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]
"""``estimate(recording, windows) -> (prob, theta_hat, distance_hat)``, each ``(n_windows,)``."""


def baseline_estimator(method: str, detector: SirenEnergyDetector | None = None) -> WindowEstimator:
    """A classical method (:data:`~makeway.perceive.audio.doa.DOA_METHODS` name) with ``detector``
    (default: :class:`SirenEnergyDetector` with its shipped constants); no distance (NaN)."""
    bearing = DOA_METHODS[method]

    def estimate(rec: Recording, windows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        det = detector if detector is not None else SirenEnergyDetector(rec.sample_rate)
        prob = det.proba_from_scores(det.scores(windows)) if len(windows) else np.zeros(0)
        theta_hat = np.array([bearing(w, rec.mics, rec.sample_rate) for w in windows])
        return prob, theta_hat, np.full(len(windows), np.nan)

    return estimate


SWAP_EVERY = max(1, round(WINDOW_S / HOP_S))
"""The evaluation's swap check analyses every this many windows (consecutive ones overlap)."""


def model_estimator(
    model: Any,
    source: str | Path | None = None,
    *,
    repair: bool = False,
    health: list[SensorHealth] | None = None,
) -> WindowEstimator:
    """The trained network (:class:`~makeway.perceive.audio.siren_model.SirenModel`); every
    recording's array and sample rate are checked against the model's first, and its windows are
    brought to the model's calibration (``Recording.full_scale_db_spl``). With ``repair``, each
    window's distrusted capsules are rebuilt first, as ``makeway audio listen`` does
    (:func:`~makeway.perceive.health.audio_health`, :func:`~makeway.perceive.health.repair_window`);
    ``health``, when given, receives every window's :class:`~makeway.messages.SensorHealth`."""

    def estimate(rec: Recording, windows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        model.check_array(rec.mics, rec.sample_rate, rec.path or source or "recording")
        if not len(windows):
            return np.zeros(0), np.zeros(0), np.zeros(0)
        if repair or health is not None:
            # as the listener: every window checked on its own, the swap check over the windows
            # so far (every third: the windows overlap, HOP_S apart)
            swap = SwapCheck(rec.mics, rec.sample_rate)
            checked, fixed = [], []
            for i, w in enumerate(windows):
                if i % SWAP_EVERY == 0:
                    swap.update(w)
                h = audio_health(w, rec.mics, rec.sample_rate)
                w, h = swap.repair(w, h)
                checked.append(h)
                fixed.append(repair_window(w, rec.mics, h)[0] if repair else w)
            if health is not None:
                health.extend(checked)
            if repair:
                windows = np.stack(fixed)
        fs = rec.full_scale_db_spl
        preds = [model.predict(windows[i : i + 64], fs) for i in range(0, len(windows), 64)]
        return (
            np.concatenate([p.prob for p in preds]),
            np.concatenate([p.theta for p in preds]),
            np.concatenate([p.distance for p in preds]),
        )

    return estimate


def evaluate(
    recordings: Iterable[Recording | str | Path],
    method: str | WindowEstimator,
    *,
    detector: SirenEnergyDetector | None = None,
    threshold: float = 0.5,
    smooth: int = 1,
    average: str = SMOOTH_AVERAGE,
    on_recording: Callable[[], None] | None = None,
    name: str | None = None,
    arrays: dict[str, np.ndarray] | None = None,
    full_scale_db_spl: float | None = None,
) -> dict[str, Any]:
    """Run ``method`` over every window of every recording, and summarize (module docstring).

    ``method`` is a :data:`~makeway.perceive.audio.doa.DOA_METHODS` name (run with ``detector``,
    see :func:`baseline_estimator`) or any :data:`WindowEstimator` (e.g. :func:`model_estimator`).
    ``smooth`` > 1 decides on the causal mean of that many windows, of their logits or (``average``)
    probabilities (module docstring). ``on_recording`` is called after each recording; ``arrays``,
    when given, receives the pooled per-window arrays (``siren``, ``theta``, ``distance``, ``prob``,
    ``theta_hat``, ``distance_hat``). ``full_scale_db_spl`` is the calibration of the recordings whose
    ``array.yaml`` states none (:mod:`makeway.sense.recording`, **Calibration**); the result's
    ``recordings_without_calibration`` counts those left with none (taken at the model's scale)."""
    StreamSmoother(smooth, average)  # checks both before any recording is read
    estimate = baseline_estimator(method, detector) if isinstance(method, str) else method
    res = WindowResults()
    n_recs = n_windows = n_dropped = n_uncalibrated = 0
    busy = 0.0
    for item in recordings:
        rec = assume_calibration(
            item if isinstance(item, Recording) else read_recording(item), full_scale_db_spl
        )
        n_uncalibrated += int(rec.full_scale_db_spl is None)
        labels = label_recording(rec)
        kept = labels.kept
        run = np.ones_like(kept) if smooth > 1 else kept  # smoothing needs every window's history
        windows = window_batch(rec, labels)[run]
        theta, dist = labels.nearest()
        n_dropped += int((~kept).sum())
        t0 = time.perf_counter()
        prob, theta_hat, distance_hat = estimate(rec, windows)
        busy += time.perf_counter() - t0
        if smooth > 1:
            prob = smoothed_probability(prob, smooth, average)[kept]
            theta_hat, distance_hat = theta_hat[kept], distance_hat[kept]
        res.siren.append(labels.siren[kept])
        res.theta.append(theta[kept])
        res.distance.append(dist[kept])
        res.prob.append(prob)
        res.theta_hat.append(theta_hat)
        res.distance_hat.append(distance_hat)
        n_recs += 1
        n_windows += len(windows)
        if on_recording is not None:
            on_recording()
    label = name if name is not None else (method if isinstance(method, str) else "model")
    out: dict[str, Any] = {"method": label, "recordings": n_recs}
    pooled = res.arrays()
    if arrays is not None:
        arrays.update(pooled)
    out.update(summarize(pooled, threshold))
    out["dropped_windows"] = n_dropped
    out["ms_per_window"] = round(1000.0 * busy / n_windows, 2) if n_windows else None
    out["threshold"] = threshold
    out["smooth"] = smooth
    out["smooth_average"] = average if smooth > 1 else None
    out["recordings_without_calibration"] = n_uncalibrated
    return out


def calibrate_threshold(prob: np.ndarray, siren: np.ndarray, max_false_alarm: float) -> float:
    """The lowest decision threshold (≥ 0.5) whose false-alarm rate on the negatives of
    ``prob``/``siren`` is at most ``max_false_alarm`` — chosen on validation windows, never test."""
    neg = np.sort(np.asarray(prob, dtype=np.float64)[~np.asarray(siren, dtype=bool)])
    if not len(neg):
        return 0.5
    allowed = int(np.floor(max_false_alarm * len(neg)))  # this many negatives may lie at or above it
    t = float(np.nextafter(neg[len(neg) - allowed - 1], 1.0)) if allowed < len(neg) else 0.5
    return max(0.5, t)


def angle_error_deg(theta_hat: float, theta: float) -> float:
    """Wrapped absolute bearing error in degrees (0…180)."""
    return math.degrees(abs(float(wrap_angle(theta_hat - theta))))
