"""The alert's wire format against pycrate's ETSI DENM and IEEE 1609.2 codecs (issue 27 item 3):
every field round-trips, the exact profile writers produce pycrate's bytes and the readers agree
with pycrate's decoders, and what pycrate refuses (or re-encodes differently) the readers refuse.
"""

from __future__ import annotations

import calendar
import random
import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from makeway.v2x.message import (
    ALERT_SIZE,
    ITS_EPOCH_UNIX_MS,
    LEAP_SECONDS,
    Alert,
    MalformedAlertError,
    ResponseType,
    decode_alert,
    decode_alert_reference,
    encode_alert,
    encode_alert_reference,
    its_ms_to_unix_ms,
    unix_ms_to_its_ms,
)
from makeway.v2x.security import (
    SIGNED_SIZE,
    SIGNER_OFFSET,
    STATION_ID_OFFSET,
    GenerationLocation,
    Identity,
    TrustStore,
    Verifier,
    encode_signed,
    encode_signed_reference,
    keygen,
    parse_signed,
    parse_signed_reference,
    sign_alert,
)

_T_MIN = ITS_EPOCH_UNIX_MS
_T_MAX = its_ms_to_unix_ms((1 << 42) - 1)


def _alerts() -> st.SearchStrategy[Alert]:
    """Any alert of the profile, every field over its whole range."""
    return st.builds(
        Alert,
        station_id=st.integers(0, 2**32 - 1),
        generation_time_ms=st.integers(_T_MIN, _T_MAX),
        sequence=st.integers(0, 65535),
        lat_e7=st.integers(-900_000_000, 900_000_000),
        lon_e7=st.integers(-1_800_000_000, 1_800_000_000),
        heading_decideg=st.integers(0, 3599),
        speed_cms=st.integers(0, 16383),
        siren=st.booleans(),
        lights=st.booleans(),
        response_type=st.sampled_from(list(ResponseType)),
        detection_time_ms=st.integers(_T_MIN, _T_MAX),
        semi_major_cm=st.integers(0, 4095),
        semi_minor_cm=st.integers(0, 4095),
        semi_major_orientation=st.integers(0, 3599) | st.just(3601),
        heading_confidence=st.integers(1, 127),
        speed_confidence=st.integers(1, 127),
        information_quality=st.integers(0, 7),
    )


def _extremes() -> list[Alert]:
    low = Alert(
        0,
        _T_MIN,
        0,
        -900_000_000,
        -1_800_000_000,
        0,
        0,
        False,
        False,
        ResponseType.NOT_IN_USE,
        _T_MIN,
        0,
        0,
        0,
        1,
        1,
        0,
    )
    high = Alert(
        2**32 - 1, _T_MAX, 65535, 900_000_000, 1_800_000_000, 3599, 16383, True, True,
        ResponseType.NON_EMERGENCY, _T_MAX, 4095, 4095, 3601, 127, 127, 7,
    )  # fmt: skip
    return [low, high]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(a=_alerts())
def test_denm_round_trips_and_agrees_with_pycrate(a: Alert) -> None:
    """The exact writer gives pycrate's bytes; the exact reader and pycrate's reader give the same
    alert back (pycrate's also checks that the bytes are its own re-encoding)."""
    data = encode_alert(a)
    assert data == encode_alert_reference(a)
    assert len(data) == ALERT_SIZE
    assert decode_alert(data) == a == decode_alert_reference(data)


def test_field_extremes_round_trip() -> None:
    for a in _extremes():
        data = encode_alert(a)
        assert data == encode_alert_reference(a)
        assert decode_alert(data) == a == decode_alert_reference(data)
        assert encode_alert(decode_alert(data)) == data


def test_every_bit_flip_agrees_with_pycrate() -> None:
    """Each of the 416 bits of two DENMs flipped: the fast reader accepts exactly when pycrate's
    reader accepts it as this profile (decoded, re-encoded to the same bytes, in range), with the
    same alert."""
    accepted = 0
    for a in [*_extremes()[1:], _physical(7, 1764000000.5, 3)]:
        base = encode_alert(a)
        for bit in range(8 * ALERT_SIZE):
            b = bytearray(base)
            b[bit // 8] ^= 0x80 >> (bit % 8)
            mine = _try(decode_alert, bytes(b))
            ref = _try(decode_alert_reference, bytes(b))
            assert mine == ref, (bit, mine, ref)
            accepted += mine is not None
    assert accepted > 300  # most flips land in a field and stay in range: the comparison ran


def test_random_bytes_are_refused_like_pycrate() -> None:
    rng = random.Random(31)
    base = encode_alert(_physical(9, 1_764_000_000.0, 1))
    for k in range(400):
        if k % 2:
            data = rng.randbytes(ALERT_SIZE)
        else:  # a real DENM with a few bytes replaced: more of them get past the fixed fields
            b = bytearray(base)
            for _ in range(rng.randint(1, 3)):
                b[rng.randrange(ALERT_SIZE)] = rng.randrange(256)
            data = bytes(b)
        assert _try(decode_alert, data) == _try(decode_alert_reference, data)
    for n in (0, 1, ALERT_SIZE - 1, ALERT_SIZE + 1):
        with pytest.raises(MalformedAlertError):
            decode_alert(base[:n] if n < ALERT_SIZE else base + b"\x00")


def test_the_fields_sit_where_the_etsi_types_put_them() -> None:
    """Read back with pycrate's own value tree: the ETSI units, the 2004 epoch with the five leap
    seconds since, station type RSU, cause 95, the light bar and siren bits."""
    from pycrate_asn1dir import ITS_DENM_3

    a = Alert.from_physical(
        station_id=7,
        generation_time_s=1_700_000_000.25,
        sequence=65536 + 9,
        lat_deg=-33.8688,
        lon_deg=151.2093,
        heading_deg=-90.0,
        speed_mps=13.4,
        siren=False,
        lights=True,
        position_sigma_m=1.0,
        heading_sigma_deg=2.0,
        speed_sigma_mps=0.5,
    )
    denm = ITS_DENM_3.DENM_PDU_Descriptions.DENM
    denm.from_uper(encode_alert(a))
    v = denm.get_val()
    assert v["header"] == {"protocolVersion": 2, "messageID": 1, "stationID": 7}
    m = v["denm"]["management"]
    assert m["actionID"] == {"originatingStationID": 7, "sequenceNumber": 9}  # 16 bits: the count wraps
    assert m["referenceTime"] == 1_700_000_000_250 - 1_072_915_200_000 + 5000  # 5 leap seconds
    assert m["stationType"] == 15
    pos = m["eventPosition"]
    assert (pos["latitude"], pos["longitude"]) == (-338_688_000, 1_512_093_000)
    assert pos["positionConfidenceEllipse"]["semiMajorConfidence"] == 245  # 2.4477 σ in cm
    s = v["denm"]["situation"]["eventType"]
    assert (s["causeCode"], s["subCauseCode"]) == (95, 1)
    loc = v["denm"]["location"]
    assert loc["eventPositionHeading"] == {"headingValue": 2700, "headingConfidence": 39}
    assert loc["eventSpeed"] == {"speedValue": 1340, "speedConfidence": 98}
    assert v["denm"]["alacarte"]["roadWorks"]["lightBarSirenInUse"] == (0b10, 2)  # light bar on
    with pytest.raises(MalformedAlertError):
        _physical(1, 1_000.0, 0)  # before 2004: no TimestampIts
    with pytest.raises(MalformedAlertError):
        Alert.from_physical(
            station_id=1,
            generation_time_s=1.7e9,
            sequence=0,
            lat_deg=91.0,
            lon_deg=0.0,
            heading_deg=0,
            speed_mps=1,
        )


def test_timestamps_count_leap_seconds_exactly_both_ways() -> None:
    """TimestampIts is TAI ms since 2004-01-01 UTC: 1000 ms more after each leap second; Unix →
    ITS → Unix is the identity around every leap second, and the 1000 ITS values inside one are
    refused."""
    assert LEAP_SECONDS[-1] == calendar.timegm((2017, 1, 1, 0, 0, 0)) * 1000
    assert unix_ms_to_its_ms(ITS_EPOCH_UNIX_MS) == 0
    assert unix_ms_to_its_ms(calendar.timegm((2020, 1, 1, 0, 0, 0)) * 1000) == (
        calendar.timegm((2020, 1, 1, 0, 0, 0)) * 1000 - ITS_EPOCH_UNIX_MS + 5000
    )
    for leap in LEAP_SECONDS:
        for d in range(-1500, 1500, 7):
            assert its_ms_to_unix_ms(unix_ms_to_its_ms(leap + d)) == leap + d
        after = unix_ms_to_its_ms(leap)
        assert after - unix_ms_to_its_ms(leap - 1) == 1001  # 23:59:59.999 → 00:00:00.000 spans 1.001 s
        for inside in (after - 1000, after - 500, after - 1):
            with pytest.raises(MalformedAlertError, match="leap second"):
                its_ms_to_unix_ms(inside)


# ------------------------------------------------------------------------------ 1609.2 signed data
@pytest.fixture(scope="module")
def unit(tmp_path_factory: pytest.TempPathFactory) -> tuple[Identity, TrustStore]:
    d = tmp_path_factory.mktemp("denm_keys")
    ident = keygen(d, "rsu")
    return ident, TrustStore.load(d / "trust")


@pytest.mark.parametrize("form", ["certificate", "digest"])
def test_signed_alert_is_ieee1609dot2_signed_data(unit: tuple[Identity, TrustStore], form: str) -> None:
    """pycrate reads the message as Ieee1609Dot2Data: signedData, sha256, psid 37, Time64 = the
    DENM's reference time in µs, the signer the unit's certificate (by default) or its HashedId8,
    an ECDSA P-256 signature over SHA-256(tbsData) ‖ SHA-256(certificate) that verifies; the
    offsets the transport reads hold the signer and the station id."""
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.hazmat.primitives.asymmetric.utils import encode_dss_signature
    from pycrate_asn1dir import ITS_IEEE1609_2

    ident, _ = unit
    a = _physical(ident.station_id, time.time(), 42)
    data = sign_alert(a, ident, signer=form)
    assert len(data) == (SIGNED_SIZE if form == "digest" else SIGNED_SIZE - 8 + 2 + len(ident.cert.data))
    t = ITS_IEEE1609_2.Ieee1609Dot2.Ieee1609Dot2Data
    t.from_oer(data)
    v = t.get_val()
    assert v["protocolVersion"] == 3 and v["content"][0] == "signedData"
    sd = v["content"][1]
    assert sd["hashId"] == "sha256"
    if form == "digest":
        assert sd["signer"] == ("digest", ident.signer)
    else:
        kind, certs = sd["signer"]
        assert kind == "certificate" and len(certs) == 1
        ITS_IEEE1609_2.Ieee1609Dot2.Certificate.set_val(certs[0])
        assert ITS_IEEE1609_2.Ieee1609Dot2.Certificate.to_oer() == ident.cert.data
    hi = sd["tbsData"]["headerInfo"]
    assert hi == {
        "psid": 37,
        "generationTime": unix_ms_to_its_ms(a.generation_time_ms) * 1000,
        # by default the sender stood where the EV is, at 0 m (1609.2: decimetres above −409.5 m)
        "generationLocation": {"latitude": a.lat_e7, "longitude": a.lon_e7, "elevation": 4095},
    }
    assert sd["tbsData"]["payload"]["data"]["content"] == ("unsecuredData", encode_alert(a))
    tbs_type = ITS_IEEE1609_2.Ieee1609Dot2.ToBeSignedData
    tbs_type.set_val(sd["tbsData"])
    tbs = tbs_type.to_oer()
    import hashlib

    der = ident.cert.data  # the 1609.2 certificate's COER
    assert ident.signer == hashlib.sha256(der).digest()[-8:]  # HashedId8: the low-order 8 bytes
    r = int.from_bytes(sd["signature"][1]["rSig"][1], "big")
    s = int.from_bytes(sd["signature"][1]["sSig"], "big")
    ident.key.public_key().verify(
        encode_dss_signature(r, s),
        hashlib.sha256(tbs).digest() + hashlib.sha256(der).digest(),
        ec.ECDSA(hashes.SHA256()),
    )
    if form == "digest":
        assert data[SIGNER_OFFSET : SIGNER_OFFSET + 8] == ident.signer
    else:
        assert data[SIGNER_OFFSET : SIGNER_OFFSET + 2] == b"\x01\x01"  # a sequence of one certificate
        assert data[SIGNER_OFFSET + 2 : -66] == ident.cert.data
    assert parse_signed(data).signer == ident.signer
    assert int.from_bytes(data[STATION_ID_OFFSET : STATION_ID_OFFSET + 4], "big") == ident.station_id
    assert parse_signed(data) == parse_signed_reference(data)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    a=_alerts(),
    r=st.integers(0, 2**256 - 1),
    s=st.integers(0, 2**256 - 1),
    signer=st.binary(min_size=8, max_size=8),
)
def test_signed_reader_agrees_with_pycrate(a: Alert, r: int, s: int, signer: bytes) -> None:
    data = encode_signed(a, signer, r, s)
    assert data == encode_signed_reference(a, signer, r, s)
    assert parse_signed(data) == parse_signed_reference(data)
    assert parse_signed(data).alert == a


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    a=_alerts(),
    where=st.builds(
        GenerationLocation,
        lat_e7=st.integers(-900_000_000, 900_000_001),
        lon_e7=st.integers(-1_799_999_999, 1_800_000_001),
        elevation_dm=st.integers(0, 65535),
    ),
)
def test_generation_location_round_trips_as_pycrate_writes_it(a: Alert, where: GenerationLocation) -> None:
    """Where the sender stood (1609.2 ThreeDLocation, over its whole range including "unavailable"):
    the exact writer and reader agree with pycrate byte for byte and value for value."""
    data = encode_signed(a, b"\x01" * 8, 5, 7, where)
    assert data == encode_signed_reference(a, b"\x01" * 8, 5, 7, where)
    assert parse_signed(data).location == where == parse_signed_reference(data).location


def test_generation_location_from_degrees_and_its_limits() -> None:
    """A roadside unit at 48.1371234° N, 11.5754321° E, 519.4 m: 1e-7 degrees and decimetres above
    −409.5 m; values outside 1609.2's ranges are refused when built and when read."""
    g = GenerationLocation.from_degrees(48.1371234, 11.5754321, 519.4)
    assert (g.lat_e7, g.lon_e7, g.elevation_dm) == (481_371_234, 115_754_321, 9289)
    assert g.elevation_m == pytest.approx(519.4) and g.to_json()["generation_lat_deg"] == pytest.approx(
        48.1371234
    )
    assert GenerationLocation.from_coer(g.to_coer()) == g
    for bad in ((91.0, 0.0, 0.0), (0.0, 181.0, 0.0), (0.0, 0.0, -500.0), (0.0, 0.0, 7000.0)):
        with pytest.raises(ValueError):
            GenerationLocation.from_degrees(*bad)
    with pytest.raises(MalformedAlertError, match="latitude"):
        GenerationLocation.from_coer((900_000_002).to_bytes(4, "big", signed=True) + bytes(6))
    with pytest.raises(MalformedAlertError, match="longitude"):
        GenerationLocation.from_coer(bytes(4) + (-1_800_000_000).to_bytes(4, "big", signed=True) + bytes(2))


def test_signed_reader_refuses_what_pycrate_refuses(unit: tuple[Identity, TrustStore]) -> None:
    """Every bit of a signed alert flipped, and random bytes: the exact reader and pycrate (with the
    profile's checks and the re-encoding) accept the same messages with the same parts."""
    ident, _ = unit
    base = sign_alert(_physical(ident.station_id, 1_764_000_000.0, 5), ident)
    rng = random.Random(8)
    cases = []
    for bit in range(0, 8 * SIGNED_SIZE, 3):
        b = bytearray(base)
        b[bit // 8] ^= 0x80 >> (bit % 8)
        if bit // 8 == 5:  # the inner content's CHOICE tag: pycrate then reads the DENM as another
            assert _try(parse_signed, bytes(b)) is None  # alternative and runs out of memory after 20 s
            continue
        cases.append(bytes(b))
    # the profile's first 7 bytes, then random: random tags there send pycrate the same way
    cases += [base[:7] + rng.randbytes(SIGNED_SIZE - 7) for _ in range(100)]
    cases += [base[:-1], base + b"\x00", b""]
    accepted = 0
    for data in cases:
        mine, ref = _try(parse_signed, data), _try(parse_signed_reference, data)
        assert mine == ref, data.hex()
        accepted += mine is not None
    assert accepted > 100


def test_a_non_canonical_encoding_is_refused(unit: tuple[Identity, TrustStore]) -> None:
    """Bytes that decode but differ from their re-encoding are refused: a Time64 that is not the
    DENM's reference time, padding bits set, a psid in a longer length form."""
    ident, store = unit
    now = time.time()
    good = sign_alert(_physical(ident.station_id, now, 77), ident)
    v = Verifier(store)
    bad = bytearray(good)
    bad[7 + ALERT_SIZE - 1] |= 0x01  # the DENM's last padding bit
    assert v.verify(bytes(bad), now).reason == "malformed: not canonical: UPER padding bits set"
    with pytest.raises(MalformedAlertError, match="canonical"):
        decode_alert_reference(bytes(bad[7 : 7 + ALERT_SIZE]))
    bad = bytearray(good)
    bad[69] ^= 0x01  # Time64's last byte: 1 µs off the reference time
    assert v.verify(bytes(bad), now).reason.startswith("malformed: generationTime")
    assert v.verify(good, now).valid


def _physical(station: int, t: float, seq: int) -> Alert:
    return Alert.from_physical(
        station_id=station,
        generation_time_s=t,
        sequence=seq,
        lat_deg=48.137,
        lon_deg=11.575,
        heading_deg=30.0,
        speed_mps=16.7,
    )


def _try(fn: object, data: bytes) -> object:
    try:
        return fn(data)  # type: ignore[operator]
    except MalformedAlertError:
        return None


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(a=_alerts(), r=st.integers(0, 2**256 - 1), s=st.integers(0, 2**256 - 1))
def test_certificate_signer_agrees_with_pycrate(
    unit: tuple[Identity, TrustStore], a: Alert, r: int, s: int
) -> None:
    """The certificate form (signer: a sequence of one certificate, TS 103 097's DENM profile): the
    exact writer and reader agree with pycrate byte for byte and part for part."""
    ident, _ = unit
    data = encode_signed(a, ident.cert, r, s)
    assert data == encode_signed_reference(a, ident.cert, r, s)
    mine = parse_signed(data)
    assert mine == parse_signed_reference(data)
    assert mine.certificate == ident.cert.data and mine.signer == ident.signer and mine.alert == a


def test_certificate_signer_reader_refuses_what_pycrate_refuses(unit: tuple[Identity, TrustStore]) -> None:
    """Every third bit of a certificate-form alert flipped, the certificate cut or padded: the exact
    reader (which also reads the carried certificate) and pycrate accept the same messages."""
    ident, _ = unit
    base = sign_alert(_physical(ident.station_id, 1_764_000_000.0, 6), ident)
    cases = []
    for bit in range(0, 8 * len(base), 3):
        if bit // 8 == 5:  # the inner content's CHOICE tag (see the digest-form test)
            continue
        b = bytearray(base)
        b[bit // 8] ^= 0x80 >> (bit % 8)
        cases.append(bytes(b))
    cert_at = SIGNER_OFFSET + 2
    cases += [
        base[:cert_at] + base[cert_at + 1 :],
        base[:-66] + b"\x00" + base[-66:],
        base[:-1],
        base + b"\x00",
    ]
    accepted = 0
    for data in cases:
        mine, ref = _try(parse_signed, data), _try(parse_signed_reference, data)
        assert mine == ref, data.hex()
        accepted += mine is not None
    assert accepted > 50
