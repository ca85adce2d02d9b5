"""The one interface every source of the car's EV belief implements.

A belief source turns what the car's senses receive into an :class:`~makeway.messages.EVBelief`
(the EV's presence, bearing, distance and relation, in the vehicle frame) at the time it would be
published. Siren hearing, vision, V2X and their fusion are all belief sources; the closed loop and a
car's runtime only call :meth:`BeliefSource.update` (the most urgent EV) and
:meth:`BeliefSource.beliefs` (every EV), never ask which kind they hold.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from makeway.messages import EVBelief, VehicleState

__all__ = ["BeliefSource"]


@runtime_checkable
class BeliefSource(Protocol):
    """Publishes the EV belief; called once per control step, in time order."""

    def update(self, time_s: float, ego: VehicleState) -> EVBelief:
        """Advance to ``time_s`` (s) with the ego's state (world frame) and return the belief
        published by then (the latest one whose latency has elapsed)."""
        ...

    def beliefs(self) -> list[EVBelief]:
        """Every EV's belief as of the last :meth:`update` (one per EV the source tells apart; the
        one :meth:`update` returned among them), empty when it perceives none."""
        ...
