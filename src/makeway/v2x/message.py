"""The emergency-vehicle alert as an ETSI DENM "emergency vehicle approaching" (cause code 95).

The wire format is the Decentralized Environmental Notification Message of ETSI EN 302 637-3
V1.3.1 — ASN.1 module ``DENM-PDU-Descriptions`` version 2 with the common data dictionary
``ITS-Container`` of ETSI TS 102 894-2 V1.3.1 (version 2), as pycrate compiles them
(``pycrate_asn1dir.ITS_DENM_3``) — in unaligned PER (UPER), DENM's transfer syntax. pycrate
(LGPL, used as a library) is the reference codec (:func:`encode_alert_reference`,
:func:`decode_alert_reference`); :func:`encode_alert` and :func:`decode_alert` are a small exact
writer and reader of our fixed profile, 65–75 times faster than pycrate (measured in
``benchmarks/bench_v2x.py``: pycrate's encoding alone took the loopback latency's p99 past 5 ms),
that produce exactly pycrate's bytes and accept exactly the bytes pycrate produces for an
:class:`Alert` (the tests cross-check them, byte for byte, over random alerts, every field's
extremes and every bit flipped).

The profile (what an :class:`Alert` fills; any other DENM is refused as "not this profile"):

* ``header``: protocolVersion 2, messageID denm (1), stationID = the signer's station id;
* ``management``: actionID (originatingStationID = stationID, sequenceNumber = the alert's
  sequence), detectionTime, referenceTime (= generation time), eventPosition (latitude,
  longitude, the 95 % position-confidence ellipse, altitude unavailable), stationType
  roadSideUnit (15); termination, relevance and validity absent (validity: the standard's
  default 600 s; a car applies its own freshness window, :mod:`makeway.v2x.security`);
* ``situation``: informationQuality, eventType {causeCode 95, subCauseCode} — the sub-cause is
  EmergencyVehicleApproachingSubCauseCode: 0 unavailable, 1 emergency vehicle approaching,
  2 prioritized vehicle approaching, which are J2735 ResponseType's ``notInUseOrNotEquipped``,
  ``emergency`` and ``nonEmergency`` with the same numbers (:class:`ResponseType`). J2735's
  pursuit, stationary, slowMoving and stopAndGoMovement have no place in this DENM version and
  are not carried;
* ``location``: eventSpeed and eventPositionHeading with their confidences, one empty trace
  (``traces`` is mandatory, SIZE(1..7));
* ``alacarte``: only ``roadWorks.lightBarSirenInUse`` — DENM V1.3.1 has no emergency container
  (that is CAM's), and RoadWorksContainerExtended's LightBarSirenInUse (bit 0 light bar, bit 1
  siren; all its other fields optional and absent) is the only place the message set defines for
  these flags in a DENM; CAM's EmergencyContainer uses the same data element.

Units are the ETSI ones, so an :class:`Alert` holds exactly what is on the wire: latitude and
longitude in 1e-7 degree (WGS-84), heading in 0.1 degree clockwise from WGS-84 north (always
given: this profile refuses 3601, unavailable), speed in 0.01 m/s (16383 unavailable),
confidence-ellipse semi-axes in cm (4094 out of range, 4095 unavailable), heading/speed
confidence in 0.1 degree / 0.01 m/s (1..127; 126 out of range, 127 unavailable).
:meth:`Alert.from_physical` quantizes physical values (rounding to the nearest unit); nothing is
lost after that.

Time. TimestampIts counts milliseconds elapsed since 2004-01-01T00:00:00.000Z UTC, leap seconds
included (TAI time since that instant; IEEE 1609.2's Time64 counts the same in microseconds). An
:class:`Alert` holds times as Unix milliseconds (UTC, no leap seconds), so the conversion adds the
leap seconds inserted between 2004 and the instant (:data:`LEAP_SECONDS`: end of 2005, end of
2008, mid 2012, mid 2015, end of 2016; 5 since 2017). The map is one-to-one both ways; the 1000
TimestampIts values that fall inside an inserted leap second (23:59:60) have no Unix time and are
refused. Times before 2004 or after TimestampIts' 42 bits (year 2143) are out of range. A leap
second announced after this table was written would need a new entry.

Sequence. DENM's SequenceNumber is 16 bits: :meth:`Alert.from_physical` keeps a unit's running
count modulo 65536, and the replay cache compares sequences in serial-number arithmetic.
"""

from __future__ import annotations

import bisect
import calendar
import threading
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

__all__ = [
    "ALERT_SIZE",
    "CAUSE_EMERGENCY_VEHICLE_APPROACHING",
    "ITS_EPOCH_UNIX_MS",
    "LEAP_SECONDS",
    "Alert",
    "MalformedAlertError",
    "ResponseType",
    "decode_alert",
    "decode_alert_reference",
    "encode_alert",
    "encode_alert_reference",
    "its_ms_to_unix_ms",
    "unix_ms_to_its_ms",
]

CAUSE_EMERGENCY_VEHICLE_APPROACHING = 95
PROTOCOL_VERSION = 2
MESSAGE_ID_DENM = 1
STATION_TYPE_RSU = 15
ALERT_SIZE = 52
"""Bytes of one alert's DENM in this profile (414 bits of UPER and 2 padding bits)."""

HEADING_UNAVAILABLE = 3601
SPEED_UNAVAILABLE = 16383
AXIS_OUT_OF_RANGE = 4094
AXIS_UNAVAILABLE = 4095
CONFIDENCE_OUT_OF_RANGE = 126
CONFIDENCE_UNAVAILABLE = 127
SEQUENCE_MODULUS = 1 << 16
_ITS_MAX = (1 << 42) - 1
_U32 = (1 << 32) - 1

ITS_EPOCH_UNIX_MS = calendar.timegm((2004, 1, 1, 0, 0, 0)) * 1000
"""2004-01-01T00:00:00Z in Unix milliseconds: TimestampIts 0."""

LEAP_SECONDS = tuple(
    calendar.timegm((y, m, 1, 0, 0, 0)) * 1000
    for y, m in ((2006, 1), (2009, 1), (2012, 7), (2015, 7), (2017, 1))
)
"""The UTC midnights (Unix ms) right after each leap second inserted since 2004 (IERS Bulletin C)."""
# the same instants as TimestampIts values: a leap second's 1000 ms lie just below each
_LEAP_ITS = tuple(u - ITS_EPOCH_UNIX_MS + 1000 * (i + 1) for i, u in enumerate(LEAP_SECONDS))


class ResponseType(IntEnum):
    """What the vehicle is doing: DENM's EmergencyVehicleApproachingSubCauseCode, numbered as
    SAE J2735's ResponseType values of the same meaning."""

    NOT_IN_USE = 0  # DENM unavailable / J2735 notInUseOrNotEquipped
    EMERGENCY = 1  # DENM emergencyVehicleApproaching / J2735 emergency
    NON_EMERGENCY = 2  # DENM prioritizedVehicleApproaching / J2735 nonEmergency


class MalformedAlertError(ValueError):
    """Bytes that are not an alert of this profile, or a field out of its range; the message
    says which."""


def unix_ms_to_its_ms(unix_ms: int) -> int:
    """TimestampIts (ms since 2004-01-01 UTC, leap seconds counted) of a Unix time in ms."""
    leaps = bisect.bisect_right(LEAP_SECONDS, unix_ms)
    return unix_ms - ITS_EPOCH_UNIX_MS + 1000 * leaps


def its_ms_to_unix_ms(its_ms: int) -> int:
    """The Unix time (ms) of a TimestampIts; :class:`MalformedAlertError` inside a leap second."""
    leaps = bisect.bisect_right(_LEAP_ITS, its_ms)
    if leaps < len(_LEAP_ITS) and its_ms >= _LEAP_ITS[leaps] - 1000:
        raise MalformedAlertError(f"TimestampIts {its_ms} falls inside a leap second")
    return its_ms + ITS_EPOCH_UNIX_MS - 1000 * leaps


def _sigma_to_confidence(sigma: float | None, factor: float, unit: float, top: int) -> int:
    """A 95 % confidence value in ``unit`` from a standard deviation (``factor`` σ); ``top``
    (out of range) when too large, ``top + 1`` (unavailable) for ``None``."""
    if sigma is None:
        return top + 1
    if not sigma >= 0.0:
        raise MalformedAlertError(f"a standard deviation must be >= 0, not {sigma}")
    value = max(1, round(sigma * factor / unit))
    return min(value, top)


@dataclass(frozen=True, slots=True)
class Alert:
    """One emergency-vehicle alert in DENM units (see the module's notes).

    ``detection_time_ms`` (Unix ms) defaults to the generation time; ``semi_major_cm``,
    ``semi_minor_cm`` and ``semi_major_orientation`` (0.1 degree from north) are the 95 %
    position-confidence ellipse, ``heading_confidence`` (0.1 degree) and ``speed_confidence``
    (0.01 m/s) the 95 % bounds, ``information_quality`` DENM's 0 (unavailable) … 7 (highest).
    """

    station_id: int
    generation_time_ms: int
    sequence: int
    lat_e7: int
    lon_e7: int
    heading_decideg: int
    speed_cms: int
    siren: bool
    lights: bool
    response_type: ResponseType = ResponseType.EMERGENCY
    detection_time_ms: int | None = None
    semi_major_cm: int = AXIS_UNAVAILABLE
    semi_minor_cm: int = AXIS_UNAVAILABLE
    semi_major_orientation: int = HEADING_UNAVAILABLE
    heading_confidence: int = CONFIDENCE_UNAVAILABLE
    speed_confidence: int = CONFIDENCE_UNAVAILABLE
    information_quality: int = 0

    def __post_init__(self) -> None:
        if self.detection_time_ms is None:  # one value for "detected when generated"
            object.__setattr__(self, "detection_time_ms", self.generation_time_ms)

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
        detection_time_s: float | None = None,
        position_sigma_m: float | None = None,
        heading_sigma_deg: float | None = None,
        speed_sigma_mps: float | None = None,
        information_quality: int = 0,
    ) -> Alert:
        """An alert from physical values: times in Unix seconds (detection defaults to
        generation), WGS-84 degrees, heading in degrees clockwise from true north (any value;
        wrapped to [0, 360)), speed in m/s (``None``: unavailable; above
        163.82 m/s kept at that), ``sequence`` any running count ≥ 0 (kept modulo 65536), and the
        standard deviations of an isotropic position (m), the heading (degree) and the speed (m/s),
        turned into DENM's 95 % confidences (ellipse semi-axes 2.448 σ, others 1.96 σ; ``None``:
        unavailable). Values are rounded to the DENM units; out-of-range values raise
        :class:`MalformedAlertError`."""
        if heading_deg != heading_deg or abs(heading_deg) == float("inf"):
            raise MalformedAlertError(f"heading must be finite, not {heading_deg}")
        heading = round((heading_deg % 360.0) * 10.0) % 3600
        if speed_mps is None:
            speed = SPEED_UNAVAILABLE
        else:
            if not speed_mps >= 0.0:
                raise MalformedAlertError(f"speed must be >= 0 m/s, not {speed_mps}")
            speed = min(round(speed_mps * 100.0), SPEED_UNAVAILABLE - 1)
        if sequence < 0:
            raise MalformedAlertError(f"sequence must be >= 0, not {sequence}")
        axis = _sigma_to_confidence(position_sigma_m, 2.4477, 0.01, AXIS_OUT_OF_RANGE)
        alert = Alert(
            station_id=station_id,
            generation_time_ms=_ms(generation_time_s, "generation time"),
            sequence=sequence % SEQUENCE_MODULUS,
            lat_e7=_e7(lat_deg, "latitude"),
            lon_e7=_e7(lon_deg, "longitude"),
            heading_decideg=heading,
            speed_cms=speed,
            siren=siren,
            lights=lights,
            response_type=ResponseType(response_type),
            detection_time_ms=None if detection_time_s is None else _ms(detection_time_s, "detection time"),
            semi_major_cm=axis,
            semi_minor_cm=axis,
            semi_major_orientation=0 if axis != AXIS_UNAVAILABLE else HEADING_UNAVAILABLE,
            heading_confidence=_sigma_to_confidence(heading_sigma_deg, 1.96, 0.1, CONFIDENCE_OUT_OF_RANGE),
            speed_confidence=_sigma_to_confidence(speed_sigma_mps, 1.96, 0.01, CONFIDENCE_OUT_OF_RANGE),
            information_quality=information_quality,
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
        return self.heading_decideg / 10.0

    @property
    def speed_mps(self) -> float | None:
        """Speed in m/s, or ``None`` when the sender marked it unavailable."""
        return None if self.speed_cms == SPEED_UNAVAILABLE else self.speed_cms / 100.0

    def to_json(self) -> dict[str, Any]:
        """The decoded fields in physical units (what ``makeway v2x verify`` prints)."""

        def conf(value: int, unit: float, top: int) -> float | None:
            return None if value >= top else round(value * unit, 6)

        assert self.detection_time_ms is not None
        return {
            "station_id": self.station_id,
            "generation_time_s": self.generation_time_s,
            "detection_time_s": self.detection_time_ms / 1000.0,
            "sequence": self.sequence,
            "lat_deg": self.lat_deg,
            "lon_deg": self.lon_deg,
            "heading_deg": self.heading_deg,
            "speed_mps": self.speed_mps,
            "siren": self.siren,
            "lights": self.lights,
            "response_type": self.response_type.name.lower(),
            "cause_code": CAUSE_EMERGENCY_VEHICLE_APPROACHING,
            "sub_cause_code": int(self.response_type),
            "position_semi_major_95_m": conf(self.semi_major_cm, 0.01, AXIS_OUT_OF_RANGE),
            "position_semi_minor_95_m": conf(self.semi_minor_cm, 0.01, AXIS_OUT_OF_RANGE),
            "heading_95_deg": conf(self.heading_confidence, 0.1, CONFIDENCE_OUT_OF_RANGE),
            "speed_95_mps": conf(self.speed_confidence, 0.01, CONFIDENCE_OUT_OF_RANGE),
            "information_quality": self.information_quality,
        }


def _ms(t_s: float, name: str) -> int:
    if not abs(t_s) < 1e13:  # also NaN
        raise MalformedAlertError(f"{name} must be a finite Unix time, not {t_s}")
    return round(t_s * 1000.0)


def _e7(deg: float, name: str) -> int:
    if not abs(deg) <= 180.0:  # also NaN; the exact range is checked on the integer
        raise MalformedAlertError(f"{name} out of range: {deg}")
    return round(deg * 1e7)


_MIN_UNIX_MS = ITS_EPOCH_UNIX_MS
_MAX_UNIX_MS = its_ms_to_unix_ms(_ITS_MAX)


def _check(a: Alert) -> None:
    """Raise :class:`MalformedAlertError` naming the first field outside its range."""
    checks = (
        ("station id", 0 <= a.station_id <= _U32),
        ("generation time (2004 … 2143)", _MIN_UNIX_MS <= a.generation_time_ms <= _MAX_UNIX_MS),
        ("detection time (2004 … 2143)", _MIN_UNIX_MS <= (a.detection_time_ms or 0) <= _MAX_UNIX_MS),
        ("sequence", 0 <= a.sequence < SEQUENCE_MODULUS),
        ("latitude", -900_000_000 <= a.lat_e7 <= 900_000_000),
        ("longitude", -1_800_000_000 <= a.lon_e7 <= 1_800_000_000),
        ("heading", 0 <= a.heading_decideg <= 3599),  # this profile always has one
        ("speed", 0 <= a.speed_cms <= SPEED_UNAVAILABLE),
        ("response type", 0 <= int(a.response_type) <= 2),
        ("semi-major confidence", 0 <= a.semi_major_cm <= AXIS_UNAVAILABLE),
        ("semi-minor confidence", 0 <= a.semi_minor_cm <= AXIS_UNAVAILABLE),
        (
            "semi-major orientation",
            0 <= a.semi_major_orientation <= 3599 or a.semi_major_orientation == HEADING_UNAVAILABLE,
        ),
        ("heading confidence", 1 <= a.heading_confidence <= CONFIDENCE_UNAVAILABLE),
        ("speed confidence", 1 <= a.speed_confidence <= CONFIDENCE_UNAVAILABLE),
        ("information quality", 0 <= a.information_quality <= 7),
    )
    for name, ok in checks:
        if not ok:
            raise MalformedAlertError(f"{name} out of range")


# ------------------------------------------------------------------------------ pycrate (reference)
_PYCRATE_LOCK = threading.Lock()  # pycrate's type objects hold the value being coded: one at a time


def _denm_type() -> Any:
    from pycrate_asn1dir import ITS_DENM_3

    return ITS_DENM_3.DENM_PDU_Descriptions.DENM


def _denm_value(a: Alert) -> dict[str, Any]:
    assert a.detection_time_ms is not None
    return {
        "header": {
            "protocolVersion": PROTOCOL_VERSION,
            "messageID": MESSAGE_ID_DENM,
            "stationID": a.station_id,
        },
        "denm": {
            "management": {
                "actionID": {"originatingStationID": a.station_id, "sequenceNumber": a.sequence},
                "detectionTime": unix_ms_to_its_ms(a.detection_time_ms),
                "referenceTime": unix_ms_to_its_ms(a.generation_time_ms),
                "eventPosition": {
                    "latitude": a.lat_e7,
                    "longitude": a.lon_e7,
                    "positionConfidenceEllipse": {
                        "semiMajorConfidence": a.semi_major_cm,
                        "semiMinorConfidence": a.semi_minor_cm,
                        "semiMajorOrientation": a.semi_major_orientation,
                    },
                    "altitude": {"altitudeValue": 800001, "altitudeConfidence": "unavailable"},
                },
                "stationType": STATION_TYPE_RSU,
            },
            "situation": {
                "informationQuality": a.information_quality,
                "eventType": {
                    "causeCode": CAUSE_EMERGENCY_VEHICLE_APPROACHING,
                    "subCauseCode": int(a.response_type),
                },
            },
            "location": {
                "eventSpeed": {"speedValue": a.speed_cms, "speedConfidence": a.speed_confidence},
                "eventPositionHeading": {
                    "headingValue": a.heading_decideg,
                    "headingConfidence": a.heading_confidence,
                },
                "traces": [[]],
            },
            # LightBarSirenInUse ::= BIT STRING {lightBarActivated (0), sirenActivated (1)} (SIZE(2))
            "alacarte": {"roadWorks": {"lightBarSirenInUse": ((a.lights << 1) | a.siren, 2)}},
        },
    }


def encode_alert_reference(alert: Alert) -> bytes:
    """The alert's DENM in UPER (:data:`ALERT_SIZE` bytes), encoded by pycrate: the reference
    :func:`encode_alert` is tested against, byte for byte. About 0.2–0.3 ms."""
    _check(alert)
    value = _denm_value(alert)
    with _PYCRATE_LOCK:
        denm = _denm_type()
        denm.set_val(value)
        data: bytes = denm.to_uper()
    if len(data) != ALERT_SIZE:  # the profile fixes every length; a change here is a bug
        raise AssertionError(f"DENM of {len(data)} bytes, the profile has {ALERT_SIZE}")
    return data


def decode_alert_reference(data: bytes) -> Alert:
    """Decode with pycrate and map back onto an :class:`Alert`; the reference
    :func:`decode_alert` is tested against. Slow (about 0.1 ms); same errors and checks."""
    try:
        with _PYCRATE_LOCK:
            denm = _denm_type()
            denm.from_uper(data)
            v = denm.get_val()
            again = denm.to_uper()
    except Exception as exc:  # pycrate raises several unrelated types on bad input
        raise MalformedAlertError(f"not a DENM ({type(exc).__name__})") from None
    if again != bytes(data):
        raise MalformedAlertError("not canonical: the bytes differ from their re-encoding")
    try:
        h, d = v["header"], v["denm"]  # pycrate's value tree: a missing part raises KeyError
        m, s, loc = d["management"], d["situation"], d["location"]
        pos, ell = m["eventPosition"], m["eventPosition"]["positionConfidenceEllipse"]
        bits, nbits = d["alacarte"]["roadWorks"]["lightBarSirenInUse"]
        alert = Alert(
            station_id=h["stationID"],
            generation_time_ms=its_ms_to_unix_ms(m["referenceTime"]),
            sequence=m["actionID"]["sequenceNumber"],
            lat_e7=pos["latitude"],
            lon_e7=pos["longitude"],
            heading_decideg=loc["eventPositionHeading"]["headingValue"],
            speed_cms=loc["eventSpeed"]["speedValue"],
            siren=bool(bits & 1),
            lights=bool(bits & 2),
            response_type=ResponseType(s["eventType"]["subCauseCode"]),
            detection_time_ms=its_ms_to_unix_ms(m["detectionTime"]),
            semi_major_cm=ell["semiMajorConfidence"],
            semi_minor_cm=ell["semiMinorConfidence"],
            semi_major_orientation=ell["semiMajorOrientation"],
            heading_confidence=loc["eventPositionHeading"]["headingConfidence"],
            speed_confidence=loc["eventSpeed"]["speedConfidence"],
            information_quality=s["informationQuality"],
        )
        _check(alert)
    except (KeyError, ValueError, TypeError) as exc:  # an absent part or a value outside the profile
        raise MalformedAlertError(f"not this DENM profile ({exc})") from None
    if _denm_value(alert) != v or nbits != 2:  # an optional part present, or another fixed value
        raise MalformedAlertError("not this DENM profile")
    return alert


# ----------------------------------------------------------------------------- the fast reader
# The profile's UPER bits, most significant first: (name, width, fixed value or None: a field).
# Constrained integers take the bits of their range (value − lower bound); a SEQUENCE with an
# extension marker starts with one bit (0: no extension), then one bit per optional component.
_LAYOUT: tuple[tuple[str, int, int | None], ...] = (
    ("protocolVersion", 8, PROTOCOL_VERSION),
    ("messageID", 8, MESSAGE_ID_DENM),
    ("stationID", 32, None),
    ("denm: situation, location, alacarte present", 3, 0b111),
    ("management: extension, 5 optionals absent", 6, 0),
    ("originatingStationID", 32, None),
    ("sequenceNumber", 16, None),
    ("detectionTime", 42, None),
    ("referenceTime", 42, None),
    ("latitude", 31, None),  # −900000000 … 900000001
    ("longitude", 32, None),  # −1800000000 … 1800000001
    ("semiMajorConfidence", 12, None),
    ("semiMinorConfidence", 12, None),
    ("semiMajorOrientation", 12, None),
    ("altitudeValue: unavailable", 20, 800001 + 100000),
    ("altitudeConfidence: unavailable", 4, 15),
    ("stationType: roadSideUnit", 8, STATION_TYPE_RSU),
    ("situation: extension, linkedCause, eventHistory", 3, 0),
    ("informationQuality", 3, None),
    ("eventType: extension", 1, 0),
    ("causeCode", 8, CAUSE_EMERGENCY_VEHICLE_APPROACHING),
    ("subCauseCode", 8, None),
    ("location: extension, eventSpeed, heading, roadType", 4, 0b0110),
    ("speedValue", 14, None),
    ("speedConfidence", 7, None),  # 1 … 127
    ("headingValue", 12, None),
    ("headingConfidence", 7, None),  # 1 … 127
    ("traces: one path", 3, 0),
    ("pathHistory: no points", 6, 0),
    ("alacarte: extension, only roadWorks", 7, 0b0000100),
    ("roadWorks: only lightBarSirenInUse", 9, 0b100000000),
    ("lightBarSirenInUse", 2, None),
    ("padding", 2, 0),
)


def _compile_layout() -> tuple[int, int, dict[str, tuple[int, int]]]:
    total = sum(w for _, w, _ in _LAYOUT)
    if total != 8 * ALERT_SIZE:
        raise AssertionError(f"layout of {total} bits")
    mask = value = 0
    fields: dict[str, tuple[int, int]] = {}
    left = total
    for name, width, fixed in _LAYOUT:
        left -= width
        if fixed is None:
            fields[name] = (left, (1 << width) - 1)
        else:
            mask |= ((1 << width) - 1) << left
            value |= fixed << left
    return mask, value, fields


_FIXED_MASK, _FIXED_VALUE, _FIELDS = _compile_layout()
_PADDING = (1 << _LAYOUT[-1][1]) - 1  # the last bits: padding to a whole byte
_F = {name: shift for name, (shift, _) in _FIELDS.items()}
_M = {name: m for name, (_, m) in _FIELDS.items()}


def encode_alert(alert: Alert) -> bytes:
    """The alert's DENM in UPER (:data:`ALERT_SIZE` bytes): the profile's fixed bits with the
    alert's fields put in place; the same bytes as pycrate's encoder
    (:func:`encode_alert_reference`), about 70 times faster."""
    _check(alert)
    assert alert.detection_time_ms is not None
    f = _F
    n = (
        _FIXED_VALUE
        | alert.station_id << f["stationID"]
        | alert.station_id << f["originatingStationID"]
        | alert.sequence << f["sequenceNumber"]
        | unix_ms_to_its_ms(alert.detection_time_ms) << f["detectionTime"]
        | unix_ms_to_its_ms(alert.generation_time_ms) << f["referenceTime"]
        | (alert.lat_e7 + 900_000_000) << f["latitude"]
        | (alert.lon_e7 + 1_800_000_000) << f["longitude"]
        | alert.semi_major_cm << f["semiMajorConfidence"]
        | alert.semi_minor_cm << f["semiMinorConfidence"]
        | alert.semi_major_orientation << f["semiMajorOrientation"]
        | alert.information_quality << f["informationQuality"]
        | int(alert.response_type) << f["subCauseCode"]
        | alert.speed_cms << f["speedValue"]
        | (alert.speed_confidence - 1) << f["speedConfidence"]
        | alert.heading_decideg << f["headingValue"]
        | (alert.heading_confidence - 1) << f["headingConfidence"]
        | (alert.lights << 1 | alert.siren) << f["lightBarSirenInUse"]
    )
    return n.to_bytes(ALERT_SIZE, "big")


def decode_alert(data: bytes) -> Alert:
    """Parse exactly :data:`ALERT_SIZE` bytes of this profile's DENM; anything else (another
    length, any fixed bit or padding changed, a value outside its type or the profile, a time
    inside a leap second) raises :class:`MalformedAlertError`. Accepts exactly the encodings
    :func:`encode_alert` produces, so re-encoding a decoded alert gives the same bytes."""
    if len(data) != ALERT_SIZE:
        raise MalformedAlertError(f"DENM is {len(data)} bytes, this profile's has {ALERT_SIZE}")
    n = int.from_bytes(data, "big")
    if n & _FIXED_MASK != _FIXED_VALUE:
        if (n & _FIXED_MASK ^ _FIXED_VALUE) == n & _PADDING:  # decodes, but re-encodes otherwise
            raise MalformedAlertError("not canonical: UPER padding bits set")
        raise MalformedAlertError("not this DENM profile (a fixed field differs)")
    f, m = _F, _M
    station = (n >> f["stationID"]) & m["stationID"]
    if (n >> f["originatingStationID"]) & m["originatingStationID"] != station:
        raise MalformedAlertError("not this DENM profile (actionID's station is not the header's)")
    lights_siren = (n >> f["lightBarSirenInUse"]) & 3
    sub_cause = (n >> f["subCauseCode"]) & 0xFF
    if sub_cause > 2:
        raise MalformedAlertError(f"sub-cause code {sub_cause} is not one of this profile's (0, 1, 2)")
    # the ranges :func:`_check` tests that the field widths do not already bound (a 31-bit
    # latitude holds more than −90° … 90°; a 12-bit heading more than 0 … 359.9°; …)
    lat = ((n >> f["latitude"]) & m["latitude"]) - 900_000_000
    lon = ((n >> f["longitude"]) & m["longitude"]) - 1_800_000_000
    heading = (n >> f["headingValue"]) & 0xFFF
    orientation = (n >> f["semiMajorOrientation"]) & 0xFFF
    heading_conf = ((n >> f["headingConfidence"]) & 0x7F) + 1
    speed_conf = ((n >> f["speedConfidence"]) & 0x7F) + 1
    if lat > 900_000_000:
        raise MalformedAlertError("latitude out of range")
    if lon > 1_800_000_000:
        raise MalformedAlertError("longitude out of range")
    if heading > 3599:
        raise MalformedAlertError("heading out of range")
    if orientation > 3599 and orientation != HEADING_UNAVAILABLE:
        raise MalformedAlertError("semi-major orientation out of range")
    if heading_conf > CONFIDENCE_UNAVAILABLE:
        raise MalformedAlertError("heading confidence out of range")
    if speed_conf > CONFIDENCE_UNAVAILABLE:
        raise MalformedAlertError("speed confidence out of range")
    return Alert(
        station,
        its_ms_to_unix_ms((n >> f["referenceTime"]) & m["referenceTime"]),
        (n >> f["sequenceNumber"]) & 0xFFFF,
        lat,
        lon,
        heading,
        (n >> f["speedValue"]) & 0x3FFF,
        bool(lights_siren & 1),
        bool(lights_siren & 2),
        ResponseType(sub_cause),
        its_ms_to_unix_ms((n >> f["detectionTime"]) & m["detectionTime"]),
        (n >> f["semiMajorConfidence"]) & 0xFFF,
        (n >> f["semiMinorConfidence"]) & 0xFFF,
        orientation,
        heading_conf,
        speed_conf,
        (n >> f["informationQuality"]) & 7,
    )
