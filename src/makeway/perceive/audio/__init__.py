"""Audio perception (SPEC §3): sirens from the 8-capsule roof array.

* :class:`SirenModel` — the shipped siren networks (detection, bearing, distance) on ONNX Runtime;
* :class:`SirenListener` / :func:`listen` — the per-window listening rule (smoothed decision,
  further sirens, approaching/receding) that ``makeway audio listen`` and the car run;
* registries: :data:`DOA_METHODS` (classical bearing estimators), :data:`APPROACH_METHODS`;
* :mod:`~makeway.perceive.audio.windows` — how audio is cut into windows and decisions smoothed.

Labels and scoring of recordings live in :mod:`makeway.eval` (``siren_labels``, ``siren``).
"""

from __future__ import annotations

import importlib
from typing import Any

# the face is loaded on first use (PEP 562): importing one light module of the package (the window
# rule, say) does not pull in ONNX Runtime and SciPy's signal processing
_WHERE = {
    "DOA_METHODS": "doa",
    "SirenEnergyDetector": "doa",
    "APPROACH_METHODS": "motion",
    "ApproachEstimator": "motion",
    "TrendApproach": "motion",
    "SourceSeparator": "multisource",
    "SirenModel": "siren_model",
    "SirenPrediction": "siren_model",
    "SirenListener": "stream",
    "listen": "stream",
    "HOP_S": "windows",
    "LISTEN_SMOOTH": "windows",
    "WINDOW_S": "windows",
    "smoothed_probability": "windows",
    "window_starts": "windows",
}

__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
