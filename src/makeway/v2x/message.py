"""The emergency-vehicle alert and its binary schema (``MWV2`` version 1).

The fields are those of ETSI's DENM "emergency vehicle approaching" (cause code 95) with the CAM
emergency container's light bar and siren flags, or SAE J2735's EmergencyVehicleAlert (sirenUse,
lightsUse, responseType, position, heading, speed, time). The encoding is our own, fixed-size and
big-endian; units follow J2735 where it has them:

=======  ====  ==============  ==============================================================
offset   size  field           meaning
=======  ====  ==============  ==============================================================
0        4     magic           ``b"MWV2"``
4        1     version         1
5        1     message type    1 = emergency-vehicle alert
6        1     cause code      95 (ETSI DENM emergency vehicle approaching)
7        1     sub-cause code  1 (emergency vehicle approaching)
8        4     station id      unsigned; the signer's station id (see :mod:`makeway.v2x.security`)
12       8     generation time unsigned, milliseconds since the Unix epoch (UTC)
20       4     sequence        unsigned, increases by one per alert of a station
24       4     latitude        signed, 1e-7 degree (WGS-84), -900000000 … 900000000
28       4     longitude       signed, 1e-7 degree (WGS-84), -1800000000 … 1800000000
32       2     heading         unsigned, 0.0125 degree clockwise from true north, 0 … 28799
34       2     speed           unsigned, 0.02 m/s, 0 … 8190 (8191: unavailable)
36       1     flags           bit 0 siren in use, bit 1 lights in use; other bits 0
37       1     response type   J2735 ResponseType, 0 … 6 (:class:`ResponseType`)
=======  ====  ==============  ==============================================================

The encoding is canonical: :func:`decode_alert` accepts exactly the bytes :func:`encode_alert`
produces (every range and reserved bit is checked), so re-encoding a decoded alert gives the same
bytes, and one alert has one byte string to sign. Physical values are quantized on construction
(:meth:`Alert.from_physical`); an :class:`Alert` holds the integer units.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

__all__ = [
    "ALERT_SIZE",
    "CAUSE_EMERGENCY_VEHICLE_APPROACHING",
    "MAGIC",
    "SCHEMA_VERSION",
    "Alert",
    "MalformedAlertError",
    "ResponseType",
    "decode_alert",
    "encode_alert",
]

MAGIC = b"MWV2"
SCHEMA_VERSION = 1
MESSAGE_TYPE_ALERT = 1
CAUSE_EMERGENCY_VEHICLE_APPROACHING = 95
SUB_CAUSE_APPROACHING = 1
SPEED_UNAVAILABLE = 8191

_FORMAT = struct.Struct(">4sBBBBIQIiiHHBB")
ALERT_SIZE = _FORMAT.size  # 38 bytes
_FLAG_SIREN = 0x01
_FLAG_LIGHTS = 0x02
_U32 = 2**32 - 1
_U64 = 2**64 - 1


class ResponseType(IntEnum):
    """SAE J2735 ResponseType: what the emergency vehicle is doing."""

    NOT_IN_USE = 0
    EMERGENCY = 1
    NON_EMERGENCY = 2
    PURSUIT = 3
    STATIONARY = 4
    SLOW_MOVING = 5
    STOP_AND_GO = 6


class MalformedAlertError(ValueError):
    """Bytes that are not a version-1 alert, or a field out of its range; the message says which."""


@dataclass(frozen=True, slots=True)
class Alert:
    """One emergency-vehicle alert in wire units (see the module's table)."""

    station_id: int
    generation_time_ms: int
    sequence: int
    lat_e7: int
    lon_e7: int
    heading_units: int
    speed_units: int
    siren: bool
    lights: bool
    response_type: ResponseType = ResponseType.EMERGENCY

    @staticmethod
    def from_physical(
        *,
        station_id: int,
        generation_time_s: float,
        sequence: int,
        lat_deg: float,
        lon_deg: float,
        heading_deg: float,
        speed_mps: float | None,
        siren: bool = True,
        lights: bool = True,
        response_type: ResponseType = ResponseType.EMERGENCY,
    ) -> Alert:
        """An alert from physical values: time in Unix seconds, WGS-84 degrees, heading in degrees
        clockwise from true north (any value; wrapped to [0, 360)), speed in m/s (``None``:
        unavailable). Values are rounded to the wire units; out-of-range values raise
        :class:`MalformedAlertError`."""
        heading_units = round((heading_deg % 360.0) / 0.0125) % 28800
        if speed_mps is None:
            speed_units = SPEED_UNAVAILABLE
        else:
            if not speed_mps >= 0.0:
                raise MalformedAlertError(f"speed must be >= 0 m/s, not {speed_mps}")
            speed_units = min(round(speed_mps / 0.02), 8190)
        alert = Alert(
            station_id=station_id,
            generation_time_ms=round(generation_time_s * 1000.0),
            sequence=sequence,
            lat_e7=round(lat_deg * 1e7),
            lon_e7=round(lon_deg * 1e7),
            heading_units=heading_units,
            speed_units=speed_units,
            siren=siren,
            lights=lights,
            response_type=ResponseType(response_type),
        )
        _check(alert)
        return alert

    @property
    def generation_time_s(self) -> float:
        """Generation time, seconds since the Unix epoch (UTC)."""
        return self.generation_time_ms / 1000.0

    @property
    def lat_deg(self) -> float:
        return self.lat_e7 / 1e7

    @property
    def lon_deg(self) -> float:
        return self.lon_e7 / 1e7

    @property
    def heading_deg(self) -> float:
        """Heading, degrees clockwise from true north, in [0, 360)."""
        return self.heading_units * 0.0125

    @property
    def speed_mps(self) -> float | None:
        """Speed in m/s, or ``None`` when the sender marked it unavailable."""
        return None if self.speed_units == SPEED_UNAVAILABLE else self.speed_units * 0.02

    def to_json(self) -> dict[str, Any]:
        """The decoded fields in physical units (what ``makeway v2x verify`` prints)."""
        return {
            "station_id": self.station_id,
            "generation_time_s": self.generation_time_s,
            "sequence": self.sequence,
            "lat_deg": self.lat_deg,
            "lon_deg": self.lon_deg,
            "heading_deg": self.heading_deg,
            "speed_mps": self.speed_mps,
            "siren": self.siren,
            "lights": self.lights,
            "response_type": self.response_type.name.lower(),
            "cause_code": CAUSE_EMERGENCY_VEHICLE_APPROACHING,
        }


def _check(a: Alert) -> None:
    """Raise :class:`MalformedAlertError` naming the first field outside its range."""
    checks = (
        ("station id", 0 <= a.station_id <= _U32),
        ("generation time", 0 <= a.generation_time_ms <= _U64),
        ("sequence", 0 <= a.sequence <= _U32),
        ("latitude", -900_000_000 <= a.lat_e7 <= 900_000_000),
        ("longitude", -1_800_000_000 <= a.lon_e7 <= 1_800_000_000),
        ("heading", 0 <= a.heading_units <= 28799),
        ("speed", 0 <= a.speed_units <= SPEED_UNAVAILABLE),
        ("response type", 0 <= int(a.response_type) <= 6),
    )
    for name, ok in checks:
        if not ok:
            raise MalformedAlertError(f"{name} out of range")


def encode_alert(alert: Alert) -> bytes:
    """The alert's canonical bytes (:data:`ALERT_SIZE` long)."""
    _check(alert)
    flags = (_FLAG_SIREN if alert.siren else 0) | (_FLAG_LIGHTS if alert.lights else 0)
    return _FORMAT.pack(
        MAGIC,
        SCHEMA_VERSION,
        MESSAGE_TYPE_ALERT,
        CAUSE_EMERGENCY_VEHICLE_APPROACHING,
        SUB_CAUSE_APPROACHING,
        alert.station_id,
        alert.generation_time_ms,
        alert.sequence,
        alert.lat_e7,
        alert.lon_e7,
        alert.heading_units,
        alert.speed_units,
        flags,
        int(alert.response_type),
    )


def decode_alert(data: bytes) -> Alert:
    """Parse exactly :data:`ALERT_SIZE` bytes; anything else raises :class:`MalformedAlertError`."""
    if len(data) != ALERT_SIZE:
        raise MalformedAlertError(f"alert body is {len(data)} bytes, expected {ALERT_SIZE}")
    magic, version, mtype, cause, sub, station, gen, seq, lat, lon, heading, speed, flags, resp = (
        _FORMAT.unpack(data)
    )
    if magic != MAGIC:
        raise MalformedAlertError("not a makeway alert (bad magic)")
    if version != SCHEMA_VERSION:
        raise MalformedAlertError(f"unsupported schema version {version}")
    if mtype != MESSAGE_TYPE_ALERT:
        raise MalformedAlertError(f"unknown message type {mtype}")
    if cause != CAUSE_EMERGENCY_VEHICLE_APPROACHING or sub != SUB_CAUSE_APPROACHING:
        raise MalformedAlertError(f"unexpected cause code {cause}/{sub}")
    if flags & ~(_FLAG_SIREN | _FLAG_LIGHTS):
        raise MalformedAlertError("reserved flag bits set")
    if resp > 6:
        raise MalformedAlertError("response type out of range")
    alert = Alert(
        station_id=station,
        generation_time_ms=gen,
        sequence=seq,
        lat_e7=lat,
        lon_e7=lon,
        heading_units=heading,
        speed_units=speed,
        siren=bool(flags & _FLAG_SIREN),
        lights=bool(flags & _FLAG_LIGHTS),
        response_type=ResponseType(resp),
    )
    _check(alert)
    return alert
