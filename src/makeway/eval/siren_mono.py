"""Real-data check of the siren network on the real mono material (issue 4, item 5).

The shared data have no multichannel recording with a known direction, but they do have real mono
audio with and without sirens. Each file is rendered as one **static** point source 25 m from the
roof array at a random bearing (exact delays, 1/r spreading, ground reflection and air absorption of
:func:`~makeway.sim.acoustics.place_fixed_sources`, plus capsule self-noise), scaled to a fixed
A-weighted level at the array (70 dB(A) by default: a busy street, or a siren some 100 m away),
cut into 0.5 s windows every 0.5 s, and scored by the model. With ``smooth`` = K > 1 the windows
come every 0.17 s instead, as ``makeway audio listen`` cuts them, and each is decided on the
smoothed probability of it and the K − 1 before it
(:func:`~makeway.eval.siren.smoothed_probability`): the check then scores the
listener's decision rule, not the single window. Only the *content* is tested here —
real traffic, real sirens heard in real traffic — not the bearing or distance heads.

Material (``<data>/audio``) and its label:

=================================  ========  ==============================================
``street_recordings/traffic-*``,   no siren  the real negatives (some were simulator noise
``noise*``                                   ingredients: see ``seen_in_training``), less the
                                             siren spans of ``STREET_NOISE_SIRENS``
``street_recordings/ambulance*``   siren     sirens in real traffic, never a simulator input
``street_mixtures/*``              siren     ambulance + traffic mixtures, never an input
``siren_clips/*``                  siren     3 s clips from road videos; test-split blocks only
                                             unless ``include_train_clips``
=================================  ========  ==============================================

A file labelled "siren" need not hold a siren in every window (clips cut from videos have pauses),
so for those the per-window detection rate is a lower bound on the recall. Results are reported per
file and per kind, and separately for the files whose source group was held out of training.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from makeway.perceive.audio.siren_model import SirenModel
from makeway.perceive.audio.windows import HOP_S, SMOOTH_AVERAGE, smoothed_probability, window_starts
from makeway.sim.acoustics import (
    FULL_SCALE_PA,
    a_weighted_level_db,
    load_street_noise_sources,
    place_fixed_sources,
    self_noise,
)
from makeway.sim.siren import cut_spans, group_split, load_mono, load_siren_sources

LEVEL_DBA = 70.0
DISTANCE_M = 25.0
SOURCE_HEIGHT_M = 1.0
MAX_WINDOWS = 30


@dataclass(frozen=True)
class MonoFile:
    """One real mono file of the check."""

    path: Path
    kind: str  # "street_noise", "street_siren", "mixture", "clip"
    siren: bool
    group: str
    seen_in_training: bool
    exclude: tuple[tuple[float, float], ...] = ()
    """Spans (s) left out: the sirens found in no-siren street recordings (``STREET_NOISE_SIRENS``)."""


def mono_files(data_root: str | Path, *, include_train_clips: bool = False) -> list[MonoFile]:
    """The files of the check (module docstring), sorted by kind and name."""
    audio = Path(data_root) / "audio"
    out: list[MonoFile] = []
    for src in load_street_noise_sources(data_root):
        seen = group_split(src.group) == "train"
        out.append(MonoFile(src.path, "street_noise", False, src.group, seen, src.exclude))
    for p in sorted((audio / "street_recordings").glob("ambulance*.flac")):
        out.append(MonoFile(p, "street_siren", True, f"street:{p.stem}", False))
    for p in sorted((audio / "street_mixtures").glob("*.flac")):
        out.append(MonoFile(p, "mixture", True, f"mixture:{p.stem}", False))
    for src in load_siren_sources(data_root, kinds=("clip",)):
        seen = group_split(src.group) == "train"
        if seen and not include_train_clips:
            continue
        out.append(MonoFile(src.path, "clip", True, src.group, seen))
    return out


def render_static(
    signal: np.ndarray,
    model: SirenModel,
    rng: np.random.Generator,
    *,
    level_dba: float = LEVEL_DBA,
    distance_m: float = DISTANCE_M,
) -> tuple[np.ndarray, float]:
    """``(audio (n, channels) in full-scale units, bearing_rad)``: ``signal`` (mono, the model's
    sample rate) as a static source at ``distance_m`` and a random bearing (module docstring)."""
    cfg = model.config
    mics = model.mics
    bearing = float(rng.uniform(-math.pi, math.pi))
    centre = mics[:, :2].mean(axis=0)
    pos = np.array(
        [
            [
                centre[0] + distance_m * math.cos(bearing),
                centre[1] + distance_m * math.sin(bearing),
                SOURCE_HEIGHT_M,
            ]
        ]
    )
    n = len(signal)
    pre = round(0.25 * cfg.sample_rate)
    padded = np.concatenate([np.zeros(pre, dtype=np.float64), np.asarray(signal, dtype=np.float64)])
    pa = place_fixed_sources([padded], pos, mics, n, cfg.sample_rate)
    pa *= 10 ** ((level_dba - a_weighted_level_db(pa, cfg.sample_rate)) / 20.0)
    pa += self_noise(n, len(mics), rng)
    return (pa / FULL_SCALE_PA).astype(np.float32), bearing


def check_file(
    item: MonoFile,
    model: SirenModel,
    rng: np.random.Generator,
    *,
    level_dba: float = LEVEL_DBA,
    max_windows: int = MAX_WINDOWS,
    smooth: int = 1,
    average: str = SMOOTH_AVERAGE,
) -> dict[str, Any]:
    """Per-window probabilities of one file; a row of the report. ``max_windows`` 0.5 s windows of
    the file are rendered; with ``smooth`` > 1 they are cut every 0.17 s and decided on the smoothed
    probability (module docstring)."""
    cfg = model.config
    x = load_mono(item.path, cfg.sample_rate, unit_rms=True)
    if item.exclude:
        x = cut_spans(x, cfg.sample_rate, item.exclude)
    win = cfg.n_samples
    n_win = min(len(x) // win, max_windows)
    row: dict[str, Any] = {
        "file": f"{item.path.parent.name}/{item.path.name}",
        "kind": item.kind,
        "siren": item.siren,
        "seen_in_training": item.seen_in_training,
        "windows": n_win,
    }
    if n_win == 0:
        row.update(detected=0, rate=None)
        return row
    audio, _ = render_static(x[: n_win * win], model, rng, level_dba=level_dba)
    if smooth > 1:
        starts = window_starts(n_win * win, cfg.sample_rate, cfg.window_s, HOP_S)
        windows = np.stack([audio[s : s + win].T for s in starts])
        prob = smoothed_probability(model.predict(windows).prob, smooth, average)
        n_win = len(windows)
        row["windows"] = n_win
    else:
        windows = audio[: n_win * win].reshape(n_win, win, -1).transpose(0, 2, 1)
        prob = model.predict(windows).prob
    det = int(np.sum(prob >= model.threshold))
    row.update(detected=det, rate=round(det / n_win, 4), mean_probability=round(float(prob.mean()), 4))
    return row


def summarize_rows(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Window-level detection rates per kind and overall, all files and unseen files only."""

    def block(sel: list[dict[str, Any]]) -> dict[str, Any]:
        pos = [r for r in sel if r["siren"]]
        neg = [r for r in sel if not r["siren"]]
        n_pos = sum(r["windows"] for r in pos)
        n_neg = sum(r["windows"] for r in neg)
        tp = sum(r["detected"] for r in pos)
        fp = sum(r["detected"] for r in neg)
        return {
            "files": len(sel),
            "siren_windows": n_pos,
            "no_siren_windows": n_neg,
            "recall": round(tp / n_pos, 4) if n_pos else None,
            "false_alarm_rate": round(fp / n_neg, 4) if n_neg else None,
            "accuracy": round((tp + n_neg - fp) / (n_pos + n_neg), 4) if n_pos + n_neg else None,
        }

    kinds = sorted({r["kind"] for r in rows})
    return {
        "all": block(rows),
        "unseen": block([r for r in rows if not r["seen_in_training"]]),
        "by_kind": {k: block([r for r in rows if r["kind"] == k]) for k in kinds},
    }


def mono_check(
    model: SirenModel,
    data_root: str | Path,
    *,
    level_dba: float = LEVEL_DBA,
    max_windows: int = MAX_WINDOWS,
    include_train_clips: bool = False,
    seed: int = 0,
    advance: Callable[[int], Any] | None = None,
    smooth: int = 1,
    average: str = SMOOTH_AVERAGE,
) -> dict[str, Any]:
    """Run the check over every file of :func:`mono_files`; ``{"summary", "files"}``. ``smooth``
    and ``average``: the decision rule (:func:`check_file`)."""
    rng = np.random.default_rng(seed)
    rows = []
    for item in mono_files(data_root, include_train_clips=include_train_clips):
        rows.append(
            check_file(
                item,
                model,
                rng,
                level_dba=level_dba,
                max_windows=max_windows,
                smooth=smooth,
                average=average,
            )
        )
        if advance is not None:
            advance(1)
    return {
        "level_dba": level_dba,
        "distance_m": DISTANCE_M,
        "threshold": model.threshold,
        "smooth": smooth,
        "smooth_average": average if smooth > 1 else None,
        "summary": summarize_rows(rows),
        "files": rows,
    }
