"""How the siren stack cuts audio into windows and smooths its per-window decision (SPEC §3).

The audio is cut into windows of :data:`WINDOW_S` every :data:`HOP_S`, starting at the first sample;
a window that would run past the end is not made. A listener decides on the mean of the logits of
the last :data:`LISTEN_SMOOTH` windows (:func:`smoothed_probability` over a whole recording; the
streaming form is :class:`~makeway.track.smoother.StreamSmoother`).
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

from makeway.track.smoother import StreamSmoother

__all__ = [
    "HOP_S",
    "LISTEN_SMOOTH",
    "SMOOTH_AVERAGE",
    "WINDOW_S",
    "WindowGrid",
    "smoothed_probability",
    "window_starts",
]

WINDOW_S = 0.5
"""Length of one analysis window, s."""
HOP_S = 0.17
"""Time between the starts of consecutive windows, s."""
LISTEN_SMOOTH = 8
"""Windows whose probabilities a live listener averages for its decision by default (``makeway
audio listen``, :func:`~makeway.perceive.audio.stream.listen`), as the mean of their logits
(:data:`SMOOTH_AVERAGE`). Chosen on validation recordings (training-split ingredients, never trained
on): the count with the highest recall at ≤ 1 % false alarms per window at the detector's stored
threshold, provided recall and false alarms on the real mono check do not get worse (see
docs/results.md, section "Siren detection, bearing and distance")."""
SMOOTH_AVERAGE = "logit"
"""How the smoothed windows are averaged by default: the mean of their logits
(:class:`~makeway.track.smoother.StreamSmoother`), or ``"probability"``: the mean of their
probabilities."""


class WindowGrid(Protocol):
    """Where a recording's windows start (``start``, samples), how long they are (``window``,
    samples), at which ``sample_rate`` (Hz); ``len()`` is the number of windows."""

    @property
    def start(self) -> np.ndarray: ...

    @property
    def window(self) -> int: ...

    @property
    def sample_rate(self) -> int: ...

    def __len__(self) -> int: ...


def window_starts(
    n_samples: int, sample_rate: int, window_s: float = WINDOW_S, hop_s: float = HOP_S
) -> np.ndarray:
    """First sample of every full window of ``window_s`` every ``hop_s`` in ``n_samples`` samples."""
    if window_s <= 0 or hop_s <= 0:
        raise ValueError("window_s and hop_s must be positive")
    win = round(window_s * sample_rate)
    if n_samples < win:
        return np.zeros(0, dtype=np.int64)
    count = int(math.floor((n_samples - win) / (hop_s * sample_rate) + 1e-9)) + 1
    return np.round(np.arange(count) * hop_s * sample_rate).astype(np.int64)


def smoothed_probability(prob: np.ndarray, smooth: int, average: str = SMOOTH_AVERAGE) -> np.ndarray:
    """The causal smoothed probability of each window over consecutive windows of one recording:
    a :class:`~makeway.track.smoother.StreamSmoother` of ``smooth`` windows (``average``: the mean
    of their logits, the default, or of their probabilities) run over ``prob``."""
    smoother = StreamSmoother(smooth, average)
    p = np.asarray(prob, dtype=np.float64)
    if smooth == 1:
        return p.copy()
    return np.array([smoother.update(float(v)) for v in p], dtype=np.float64)
