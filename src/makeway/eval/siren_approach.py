"""How well approaching/receding is told, window by window, on labelled recordings (issue 4, item 3).

:func:`approach_windows` runs one recording the way ``makeway audio listen`` does — the siren
network on every 0.5 s window (hop 0.17 s), the listener's decision rule
(:data:`~makeway.eval.siren_labels.LISTEN_SMOOTH` windows, stored threshold) and a
:class:`~makeway.perceive.audio.motion.TrendApproach` fed each window with the network's distance
and that decision — and returns per window:

* ``features`` — the trend estimator's feature rows (what its classifier reads, and is trained on);
* ``level_state`` — the decision of the level/Doppler estimator inside it
  (:class:`~makeway.perceive.audio.motion.ApproachEstimator`: 1 approaching, 0 receding, NaN
  undecided), the anchor;
* ``range_rate`` — the labelled range rate of the nearest siren (m/s), and ``approaching`` its sign;
* ``scored`` — the windows that count: kept by the labeller, a siren within 100 m, the listener
  reports a siren (only then does it say approaching or receding), and the siren moves relative to
  the car by at least :data:`MIN_RANGE_RATE_MPS` (near the closest point of approach the truth
  itself flips).

:func:`approach_report` scores decisions on the scored windows: ``correct`` (the share decided and
right; undecided counts as wrong), ``decided``, ``accuracy_decided``; the two errors apart —
``receding_when_approaching`` (the share of approaching windows called receding: the costly one,
since the yield decision lets a receding EV go, ``makeway.decide.yield_fsm``) and
``approaching_when_receding``; and ``correct`` per scenario and per band of relative speed
(:data:`SPEED_BANDS_MPS`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from makeway.eval.siren import model_estimator
from makeway.eval.siren_labels import label_recording
from makeway.perceive.audio.features import window_batch
from makeway.perceive.audio.motion import TrendApproach
from makeway.perceive.audio.siren_model import SirenModel
from makeway.perceive.audio.windows import LISTEN_SMOOTH, SMOOTH_AVERAGE, smoothed_probability
from makeway.sense.recording import Recording, assume_calibration, read_recording

MIN_RANGE_RATE_MPS = 1.0
"""Windows whose siren moves slower than this relative to the car are not scored."""
SPEED_BANDS_MPS = (1.0, 3.0, 6.0, 10.0, math.inf)
"""Edges of the bands of ``|range rate|`` (m/s) that :func:`approach_report` breaks ``correct`` into."""


def _scenario(rec: Recording) -> str:
    """The simulator's scenario of the recording's first siren (its ``meta.yaml``, read with the
    recording): "none" without a siren, "unknown" when not stated."""
    sirens = rec.meta.get("sirens") or []
    if not sirens:
        return "none" if not rec.sources else "unknown"
    return str(sirens[0].get("scenario", "unknown"))


def approach_windows(
    rec: Recording | str | Path, model: SirenModel, estimator: TrendApproach
) -> dict[str, np.ndarray]:
    """Per-window arrays of one recording (module docstring); ``estimator`` is reset first."""
    rec = rec if isinstance(rec, Recording) else read_recording(rec)
    labels = label_recording(rec)
    windows = window_batch(rec, labels)
    prob, _, distance = model_estimator(model)(rec, windows)
    is_siren = smoothed_probability(prob, LISTEN_SMOOTH, SMOOTH_AVERAGE) >= model.threshold
    estimator.reset()
    rows, level = [], []
    for i in range(len(windows)):
        rows.append(
            estimator.observe(
                windows[i],
                rec.sample_rate,
                float(labels.t_end[i]),
                distance_m=float(distance[i]),
                is_siren=bool(is_siren[i]),
            )
        )
        state = estimator.level.state_
        level.append(np.nan if state is None else float(state))
    rate = labels.nearest_range_rate()
    moving = np.abs(np.nan_to_num(rate)) >= MIN_RANGE_RATE_MPS
    n_feat = len(estimator.feature_names)
    return {
        "features": np.array(rows, dtype=np.float32).reshape(-1, n_feat),
        "level_state": np.array(level, dtype=np.float64),
        "range_rate": rate,
        "approaching": rate < 0,
        "scored": labels.kept & labels.siren & is_siren & moving,
        "scenario": np.full(len(windows), _scenario(rec)),
    }


def approach_recordings(
    folders: Sequence[str | Path],
    model: SirenModel,
    estimator: TrendApproach,
    *,
    full_scale_db_spl: float | None = None,
    advance: Callable[[int], Any] | None = None,
) -> dict[str, np.ndarray]:
    """:func:`approach_windows` of every recording folder, pooled, with ``recording`` (its index)
    added; ``full_scale_db_spl`` is the calibration of recordings that state none
    (:func:`~makeway.sense.recording.assume_calibration`)."""
    parts = []
    for i, folder in enumerate(folders):
        rec = assume_calibration(read_recording(folder), full_scale_db_spl)
        part = approach_windows(rec, model, estimator)
        part["recording"] = np.full(len(part["scored"]), i)
        parts.append(part)
        if advance is not None:
            advance(1)
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]} if parts else {}


def approach_report(arrays: dict[str, np.ndarray], state: np.ndarray) -> dict[str, Any]:
    """Score ``state`` (1 approaching, 0 receding, NaN undecided; per window of ``arrays``) on the
    scored windows (module docstring)."""
    sel = arrays["scored"]
    st = np.asarray(state, dtype=np.float64)[sel]
    truth = arrays["approaching"][sel]
    decided = ~np.isnan(st)
    right = decided & ((st > 0.5) == truth)

    def block(mask: np.ndarray) -> dict[str, Any]:
        n = int(mask.sum())
        n_dec = int((decided & mask).sum())
        return {
            "windows": n,
            "correct": round(float(right[mask].mean()), 4) if n else None,
            "decided": round(n_dec / n, 4) if n else None,
            "accuracy_decided": round(float(right[mask & decided].sum() / n_dec), 4) if n_dec else None,
        }

    def share(num: np.ndarray, den: np.ndarray) -> float | None:
        return round(float(num.sum() / den.sum()), 4) if den.any() else None

    scen = arrays["scenario"][sel]
    speed = np.abs(arrays["range_rate"][sel])
    out = block(np.ones(len(st), dtype=bool))
    out["approaching_share"] = round(float(truth.mean()), 4) if len(truth) else None
    out["receding_when_approaching"] = share(decided & (st < 0.5) & truth, truth)
    out["approaching_when_receding"] = share(decided & (st > 0.5) & ~truth, ~truth)
    out["by_scenario"] = {s: block(scen == s) for s in sorted(set(scen.tolist()))}
    out["by_speed_mps"] = {
        f"{lo:g}-{hi:g}": block((speed >= lo) & (speed < hi))
        for lo, hi in itertools.pairwise(SPEED_BANDS_MPS)
    }
    return out


def approach_scores(arrays: dict[str, np.ndarray], trend: TrendApproach) -> dict[str, dict[str, Any]]:
    """:func:`approach_report` of ``trend``'s classifier (``"trend"``) and of the level/Doppler rule
    inside it (``"level"``, the anchor) on the same windows."""
    return {
        "trend": approach_report(arrays, trend.decide(arrays["features"])[0]),
        "level": approach_report(arrays, arrays["level_state"]),
    }
