"""How the siren stack cuts audio into windows and smooths its per-window decision (SPEC §3).

The audio is cut into windows of :data:`WINDOW_S` every :data:`HOP_S`, starting at the first sample;
a window that would run past the end is not made. A listener decides on the mean of the logits of
the last :data:`LISTEN_SMOOTH` windows (:func:`smoothed_probability` over a whole recording; the
streaming form is :class:`StreamSmoother`).
"""

from __future__ import annotations

import math
from collections import deque
from typing import Protocol

import numpy as np

__all__ = [
    "HOP_S",
    "LISTEN_SMOOTH",
    "SMOOTH_AVERAGE",
    "SMOOTH_AVERAGES",
    "WINDOW_S",
    "StreamSmoother",
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
(:class:`StreamSmoother`), or ``"probability"``: the mean of their
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
    a :class:`StreamSmoother` of ``smooth`` windows (``average``: the mean
    of their logits, the default, or of their probabilities) run over ``prob``."""
    smoother = StreamSmoother(smooth, average)
    p = np.asarray(prob, dtype=np.float64)
    if smooth == 1:
        return p.copy()
    return np.array([smoother.update(float(v)) for v in p], dtype=np.float64)


SMOOTH_AVERAGES = ("logit", "probability")
"""How :class:`StreamSmoother` averages: the mean of the logits, or of the probabilities."""


class StreamSmoother:
    """Causal mean of the last ``window`` probabilities of one stream (no track ids).

    ``update(p)`` adds one probability and returns the mean over the buffer (fewer values at the
    start). With ``average="logit"`` the mean is taken in the logit domain,
    ``sigmoid(mean(logit(p_i)))``: each window weighs by its evidence (log-odds), as if the windows
    were independent judgements, whereas a probability mean treats 0.3 and 0.001 as nearly the same
    "no" and 0.9 and 0.9999 as nearly the same "yes". Probabilities are clipped to
    ``[eps, 1 - eps]`` first so that 0 and 1 stay finite. ``average="probability"`` is the plain
    mean, as :class:`~makeway.track.smoother.TrackSmoother` reports it (``mean_probability``).
    Used for the siren decision over 0.5 s windows
    (:class:`~makeway.perceive.audio.stream.SirenListener`; the choice of the logit mean:
    docs/results.md, section "Siren detection, bearing and distance").
    """

    def __init__(self, window: int, average: str = "logit", eps: float = 1e-12) -> None:
        if window < 1:
            raise ValueError(f"window must be >= 1, got {window}")
        if average not in SMOOTH_AVERAGES:
            raise ValueError(f"unknown average {average!r}; choose from {', '.join(SMOOTH_AVERAGES)}")
        self.window = int(window)
        self.average = average
        self.eps = float(eps)
        self._values: deque[float] = deque(maxlen=self.window)

    def reset(self) -> None:
        """Forget the history."""
        self._values.clear()

    def update(self, probability: float) -> float:
        """Add one probability; return the smoothed probability (class docstring)."""
        p = float(probability)
        if self.window == 1:  # no history: the probability itself, exactly
            return p
        if self.average == "probability":
            self._values.append(p)
            return sum(self._values) / len(self._values)
        p = min(max(p, self.eps), 1.0 - self.eps)
        self._values.append(math.log(p / (1.0 - p)))
        z = sum(self._values) / len(self._values)
        return 1.0 / (1.0 + math.exp(-z))
