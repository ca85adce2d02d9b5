"""The car's side: verified alerts → the EV belief (source ``"v2x"``).

Frames: alerts carry WGS-84 latitude/longitude and a heading clockwise from true north. The car's
world frame here is a local tangent plane (east-north-up) at a reference latitude/longitude:
``x`` east, ``y`` north, in metres, yaw counter-clockwise from east. :class:`LocalFrame` goes through
Earth-centred coordinates on the WGS-84 ellipsoid (heights 0), so it is exact on the plane's tangent
point and its distortion grows with distance (about 1 cm at 1 km); a car re-centres it on its route
every few kilometres. The ego's :class:`~makeway.messages.VehicleState` is in that frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from makeway.fuse.relation import classify_relation
from makeway.messages import EVBelief, VehicleState
from makeway.v2x.message import Alert

__all__ = ["DEFAULT_RELEVANCE_M", "LocalFrame", "RelevanceArea", "V2XBeliefSource"]

_A = 6378137.0  # WGS-84 semi-major axis (m)
_F = 1 / 298.257223563
_E2 = _F * (2 - _F)


def _ecef(lat_deg: float, lon_deg: float) -> tuple[float, float, float]:
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    n = _A / math.sqrt(1 - _E2 * math.sin(lat) ** 2)
    return (
        n * math.cos(lat) * math.cos(lon),
        n * math.cos(lat) * math.sin(lon),
        n * (1 - _E2) * math.sin(lat),
    )


@dataclass(frozen=True)
class LocalFrame:
    """East-north plane tangent to the WGS-84 ellipsoid at (``lat0_deg``, ``lon0_deg``)."""

    lat0_deg: float
    lon0_deg: float

    def to_local(self, lat_deg: float, lon_deg: float) -> tuple[float, float]:
        """WGS-84 degrees → (east, north) metres."""
        x0, y0, z0 = _ecef(self.lat0_deg, self.lon0_deg)
        x, y, z = _ecef(lat_deg, lon_deg)
        dx, dy, dz = x - x0, y - y0, z - z0
        lat0, lon0 = math.radians(self.lat0_deg), math.radians(self.lon0_deg)
        east = -math.sin(lon0) * dx + math.cos(lon0) * dy
        north = (
            -math.sin(lat0) * math.cos(lon0) * dx - math.sin(lat0) * math.sin(lon0) * dy + math.cos(lat0) * dz
        )
        return east, north

    @staticmethod
    def yaw_from_heading(heading_deg: float) -> float:
        """Heading (degrees clockwise from north) → yaw (rad, counter-clockwise from east)."""
        yaw = math.radians(90.0 - heading_deg)
        return math.atan2(math.sin(yaw), math.cos(yaw))


DEFAULT_RELEVANCE_M = 1000.0
"""Radius (m) of :class:`RelevanceArea` by default: an EV at 30 m/s needs 33 s to cover it, more
than the lead at which a car starts to clear a corridor for it; DENM's own relevance classes stop
at "less than 1,000 m" before jumping to 5 km."""


class RelevanceArea:
    """Which alerts a car could act on, for verify on demand
    (:class:`~makeway.v2x.security.Verifier`'s ``relevant``): an alert is relevant when the EV it
    describes is within ``radius_m`` (m, on the tangent plane at the car) of the car's position, or
    when the car's position is not known (then everything is relevant: the safe side).

    The car calls :meth:`move_to` with its WGS-84 position as it drives (re-centring the plane each
    time; the plane's distortion is about 1 cm at 1 km). The distance is to the EV where the alert
    places it, not where it will be: the radius is the lead.
    """

    def __init__(
        self,
        radius_m: float = DEFAULT_RELEVANCE_M,
        lat_deg: float | None = None,
        lon_deg: float | None = None,
    ) -> None:
        if not radius_m > 0.0 or not math.isfinite(radius_m):
            raise ValueError(f"radius_m must be a positive number of metres, not {radius_m!r}")
        self.radius_m = radius_m
        self._frame: LocalFrame | None = None
        if (lat_deg is None) != (lon_deg is None):
            raise ValueError("give both lat_deg and lon_deg, or neither")
        if lat_deg is not None and lon_deg is not None:
            self.move_to(lat_deg, lon_deg)

    def move_to(self, lat_deg: float, lon_deg: float) -> None:
        """The car is now at (``lat_deg``, ``lon_deg``), WGS-84 degrees."""
        if not (-90.0 <= lat_deg <= 90.0 and -180.0 <= lon_deg <= 180.0):
            raise ValueError(f"not a WGS-84 position: lat {lat_deg!r}, lon {lon_deg!r}")
        self._frame = LocalFrame(lat_deg, lon_deg)

    def distance_m(self, alert: Alert) -> float:
        """Distance (m) from the car to the EV the alert places; NaN when the car's position is unknown."""
        if self._frame is None:
            return math.nan
        east, north = self._frame.to_local(alert.lat_deg, alert.lon_deg)
        return math.hypot(east, north)

    def __call__(self, alert: Alert) -> bool:
        d = self.distance_m(alert)
        return math.isnan(d) or d <= self.radius_m


class V2XBeliefSource:
    """Publishes the EV belief from verified alerts (implements
    :class:`~makeway.fuse.source.BeliefSource`).

    Feed it alerts that passed :class:`~makeway.v2x.security.Verifier` with :meth:`receive`; never a
    rejected one. :meth:`update` uses the newest alert generated at or before ``time_s`` and at most
    ``hold_s`` old (alerts repeat at 10 Hz, so a few lost ones do not drop the belief), moves the EV
    along its heading at its speed to ``time_s``, and expresses it in the ego's vehicle frame.
    ``time_s`` is on the alerts' clock (Unix seconds on a car; a simulation sends alerts stamped on
    its own clock). An EV whose alert says neither siren nor lights is not an active EV.
    """

    def __init__(self, frame: LocalFrame, *, hold_s: float = 1.0) -> None:
        self.frame = frame
        self.hold_s = hold_s
        self._alerts: dict[int, Alert] = {}  # newest alert per station
        self._beliefs: list[EVBelief] = []

    def receive(self, alert: Alert) -> None:
        """Take one verified alert (older ones from the same station are ignored)."""
        old = self._alerts.get(alert.station_id)
        if old is None or alert.generation_time_ms > old.generation_time_ms:
            self._alerts[alert.station_id] = alert

    def update(self, time_s: float, ego: VehicleState | None) -> EVBelief:
        """The belief at ``time_s`` for the ego at ``ego`` (local frame); with ``ego=None`` (position
        unknown) only presence, siren and lights, the position fields NaN."""
        live = [
            a
            for a in self._alerts.values()
            if 0.0 <= time_s - a.generation_time_s <= self.hold_s and (a.siren or a.lights)
        ]
        self._beliefs = []
        if not live:
            return EVBelief.nothing(time_s, source="v2x")
        if ego is None:
            return EVBelief(
                time_s=time_s,
                detected=True,
                confidence=1.0,
                lights=any(a.lights for a in live),
                siren=any(a.siren for a in live),
                source="v2x",
            )
        best: EVBelief | None = None
        for a in live:
            b = self._belief(a, time_s, ego)
            self._beliefs.append(b)
            if best is None or b.distance_m < best.distance_m:
                best = b
        assert best is not None
        return best

    def beliefs(self) -> list[EVBelief]:
        """Every live station's belief as of the last :meth:`update` with a known ego."""
        return list(self._beliefs)

    def _belief(self, a: Alert, time_s: float, ego: VehicleState) -> EVBelief:
        ex, ey = self.frame.to_local(a.lat_deg, a.lon_deg)
        yaw = self.frame.yaw_from_heading(a.heading_deg)
        speed = a.speed_mps or 0.0
        dt = time_s - a.generation_time_s
        ex += speed * dt * math.cos(yaw)
        ey += speed * dt * math.sin(yaw)
        dx, dy = ex - ego.x_m, ey - ego.y_m
        c, s = math.cos(ego.yaw_rad), math.sin(ego.yaw_rad)
        rel_x, rel_y = c * dx + s * dy, -s * dx + c * dy
        # range rate: relative velocity (world frame) along the line of sight
        ego_vx = ego.vx_mps * c - ego.vy_mps * s
        ego_vy = ego.vx_mps * s + ego.vy_mps * c
        rvx, rvy = speed * math.cos(yaw) - ego_vx, speed * math.sin(yaw) - ego_vy
        distance = math.hypot(rel_x, rel_y)
        range_rate = (dx * rvx + dy * rvy) / distance if distance > 1e-6 else 0.0
        return EVBelief(
            time_s=time_s,
            detected=True,
            confidence=1.0,
            relation=classify_relation(rel_x, rel_y, yaw - ego.yaw_rad),
            rel_x_m=rel_x,
            rel_y_m=rel_y,
            distance_m=distance,
            bearing_rad=math.atan2(rel_y, rel_x),
            approaching=range_rate < 0.0,
            lights=a.lights,
            siren=a.siren,
            source="v2x",
        )
