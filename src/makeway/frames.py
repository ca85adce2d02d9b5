"""World frame → vehicle frame (the conventions of :mod:`makeway.messages`: x forward, y left)."""

from __future__ import annotations

from typing import TypeVar

import numpy as np

F = TypeVar("F", float, np.ndarray)


def to_vehicle_frame(dx: F, dy: F, yaw: F) -> tuple[F, F]:
    """A world-frame offset ``(dx, dy)`` from the vehicle, seen from a vehicle heading ``yaw``
    (rad): ``(forward, left)``. Floats or arrays (element-wise)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return c * dx + s * dy, -s * dx + c * dy
