"""Audio perception (SPEC §3): sirens from the 8-capsule roof array.

* :class:`SirenModel` — the shipped siren networks (detection, bearing, distance) on ONNX Runtime;
* :class:`SirenListener` / :func:`listen` — the per-window listening rule (smoothed decision,
  further sirens, approaching/receding) that ``makeway audio listen`` and the car run;
* registries: :data:`DOA_METHODS` (classical bearing estimators), :data:`APPROACH_METHODS`;
* :mod:`~makeway.perceive.audio.windows` — how audio is cut into windows and decisions smoothed.

Labels and scoring of recordings live in :mod:`makeway.eval` (``siren_labels``, ``siren``).
"""

from makeway.perceive.audio.doa import DOA_METHODS, SirenEnergyDetector
from makeway.perceive.audio.motion import APPROACH_METHODS, ApproachEstimator, TrendApproach
from makeway.perceive.audio.multisource import SourceSeparator
from makeway.perceive.audio.siren_model import SirenModel, SirenPrediction
from makeway.perceive.audio.stream import SirenListener, listen
from makeway.perceive.audio.windows import HOP_S, LISTEN_SMOOTH, WINDOW_S, smoothed_probability, window_starts

__all__ = [
    "APPROACH_METHODS",
    "DOA_METHODS",
    "HOP_S",
    "LISTEN_SMOOTH",
    "WINDOW_S",
    "ApproachEstimator",
    "SirenEnergyDetector",
    "SirenListener",
    "SirenModel",
    "SirenPrediction",
    "SourceSeparator",
    "TrendApproach",
    "listen",
    "smoothed_probability",
    "window_starts",
]
