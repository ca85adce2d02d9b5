"""What the simulated world shows the car's sensors at the current step."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["EVTruth", "SimWorld"]


@dataclass(frozen=True)
class EVTruth:
    """The true state of one EV at one instant (world frame)."""

    time_s: float
    x_m: float
    y_m: float
    heading_rad: float
    speed_mps: float
    lights: bool
    siren: bool


@dataclass
class SimWorld:
    """The world's state that simulated sensors read: the EV's true state (``None``: no EV).

    The closed loop writes it every step before it asks the belief source; a simulated sensor
    holds a reference and reads it in its ``update``.
    """

    ev: EVTruth | None = None
