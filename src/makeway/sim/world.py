"""What the simulated world shows the car's sensors at the current step."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["EVTruth", "SimWorld"]


@dataclass(frozen=True)
class EVTruth:
    """The true state of one vehicle at one instant (world frame): an emergency vehicle, or with
    ``lights`` and ``siren`` off any other vehicle (a truck that hides one).

    ``length_m``/``width_m`` size its body (a rectangle centred on ``(x_m, y_m)`` along
    ``heading_rad``); ``v2x`` says it broadcasts alerts, ``station_id`` under which id.
    """

    time_s: float
    x_m: float
    y_m: float
    heading_rad: float
    speed_mps: float
    lights: bool
    siren: bool
    length_m: float = 6.0
    width_m: float = 2.2
    v2x: bool = False
    station_id: int = 0


@dataclass
class SimWorld:
    """The world's state that simulated sensors read.

    ``ev``: the scenario's first emergency vehicle (``None``: none); ``evs``: every emergency
    vehicle (``ev`` first); ``traffic``: the other vehicles (they hide what lies behind them from the
    cameras); ``night``: whether it is dark (the cameras see lit lights farther). The closed loop
    writes it every step before it asks the belief source; a simulated sensor holds a reference and
    reads it in its ``update``.
    """

    ev: EVTruth | None = None
    evs: tuple[EVTruth, ...] = ()
    traffic: tuple[EVTruth, ...] = ()
    night: bool = False

    def all_evs(self) -> tuple[EVTruth, ...]:
        """Every emergency vehicle: ``evs``, or ``(ev,)`` when only ``ev`` was set."""
        if self.evs:
            return self.evs
        return (self.ev,) if self.ev is not None else ()
