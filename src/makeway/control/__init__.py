"""Lateral and longitudinal control (SPEC §6): seed 003's feed-forward + feedback steering with
structured-LQR gains, Stanley and pure-pursuit baselines, and a comfort-limited stop controller.

Seed 003 is the project report of seed 001's work, which adds the complete feedback law and the
field-test figures (``../shared/seeds/003_…``, digested in SPEC §6).

``LATERAL_CONTROLLERS`` names the lateral controllers for the CLI and the metrics, all with
``steer(state, path, hint) -> (δ, TrackingErrors, nearest index)``.
"""

from makeway.control.lateral import (
    LATERAL_CONTROLLERS,
    FeedforwardFeedback,
    GainSchedule,
    LateralController,
    PurePursuit,
    Stanley,
    default_gains,
    design_gains,
    path_error_model,
)
from makeway.control.longitudinal import LongitudinalController

__all__ = [
    "LATERAL_CONTROLLERS",
    "FeedforwardFeedback",
    "GainSchedule",
    "LateralController",
    "LongitudinalController",
    "PurePursuit",
    "Stanley",
    "default_gains",
    "design_gains",
    "path_error_model",
]
