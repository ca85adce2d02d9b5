"""Signed alerts as IEEE 1609.2 signs them: an ``Ieee1609Dot2Data`` holding ``signedData`` with
ECDSA P-256 / SHA-256, unit certificates issued by a local root, a trust store and a revocation
list on the car.

A signed alert (298 bytes with a unit named ``rsu``; :data:`SIGNED_SIZE` = 155 with the signer
as a digest) is, in COER (IEEE Std 1609.2-2016's ASN.1 module
``Ieee1609Dot2`` version 2.3 as pycrate compiles it, ``pycrate_asn1dir.ITS_IEEE1609_2``)::

    Ieee1609Dot2Data { protocolVersion 3, content signedData {
      hashId sha256,
      tbsData { payload { data Ieee1609Dot2Data { protocolVersion 3,
                                                  content unsecuredData <the DENM, 52 bytes> } },
                headerInfo { psid 37 (DEN), generationTime Time64,
                             generationLocation { latitude, longitude, elevation } } },
      signer certificate { <the unit's certificate> } | digest <HashedId8>,
      signature ecdsaNistP256Signature { rSig x-only <r>, sSig <s> } } }

with the DENM of :mod:`makeway.v2x.message`. ``generationTime`` (TAI µs since 2004-01-01 UTC)
must equal the DENM's referenceTime × 1000 exactly. ``generationLocation`` is where the sender
stood (:class:`GenerationLocation`: a roadside unit's own position; by default the EV's, as when the
EV itself sends), as TS 103 097 asks of every DENM. As 1609.2 (5.3.1) signs: the ECDSA input is
SHA-256(tbsData's COER) ‖ SHA-256(signer identifier input), hashed again with SHA-256 by ECDSA;
``s`` is at most n/2 so that each signature has one encoding. The signer is named by its
HashedId8: the low-order 8 bytes (the last 8) of the SHA-256 of its certificate's encoding. A
unit's station id is the first 4 bytes of its HashedId8 read big-endian; an alert must carry its
signer's station id.

Certificates are 1609.2 explicit certificates (:mod:`makeway.v2x.certificates`): a self-signed
root per trust store and unit certificates it issues for PSID 37; the signer identifier input and
the HashedId8 hash a certificate's COER. By default the signer is the unit's whole certificate, as
ETSI TS 103 097's DENM profile asks: a car holding only the root can check an alert of a unit it
has never heard of (:class:`Verifier` learns such certificates). The digest form (a HashedId8, 8
bytes instead of the certificate's ~150) is kept for units the cars already know. The encoding is
one profile per form: the digest form is :data:`SIGNED_SIZE` bytes, the certificate form that plus
the certificate's length less 6; shorter input, or longer than :data:`MAX_SIGNED_SIZE`, is refused
before any parsing.

Writing (:func:`encode_signed`, :func:`sign_alert`) and reading (:func:`parse_signed`) are exact
codecs of this profile, checked byte for byte against pycrate's (:func:`encode_signed_reference`,
:func:`parse_signed_reference`), which are 50–80 times slower.

On disk (``makeway v2x keygen --out DIR``):

* ``DIR/root.key``, ``DIR/NAME.key`` — private keys (PKCS#8 PEM, mode 0600; never commit them);
* ``DIR/NAME.cert`` — the unit's 1609.2 certificate (COER), issued by the root;
* ``DIR/trust/root.cert`` — the root certificate; ``DIR/trust/units/NAME.cert`` — the unit
  certificates the car accepts (each checked against the root when the store is loaded);
  ``DIR/trust/revoked.txt`` — the revocation list: one HashedId8 in hex per line, ``#`` comments.

:class:`Verifier` rejects, each with a reason: input of the wrong length or not this profile
(including any encoding that is not canonical), an unknown or revoked signer, a signer
certificate not valid at the generation time, a station id that is not the signer's, a bad or
non-canonical signature (so any changed byte), a generation time more than ``max_future_s``
ahead of the car's clock or more than ``max_age_s`` behind it, and a replay (a signer and
sequence already accepted within the freshness window).

Verify on demand: given a ``relevant`` predicate (e.g. :class:`~makeway.v2x.belief.RelevanceArea`,
the EV within a radius of the car), :class:`Verifier` checks the signature only of alerts the car
could act on; the others pass every check that costs no signature and are returned unverified
with the reason :data:`NOT_RELEVANT` (never valid, never in the replay cache). This is the
receiver policy known as verify-on-demand (Krishnan and Weimerskirch, SAE 2011): a car verifies
the messages that could change what it does, not every message in radio range.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cryptography.exceptions import InvalidSignature, UnsupportedAlgorithm
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.hazmat.primitives.asymmetric.utils import decode_dss_signature, encode_dss_signature

from makeway.errors import InputError
from makeway.v2x.certificates import (
    PSID_DEN,
    Certificate,
    MalformedCertificateError,
    issue_certificate,
    parse_certificate,
)
from makeway.v2x.message import (
    _PYCRATE_LOCK,
    ALERT_SIZE,
    SEQUENCE_MODULUS,
    Alert,
    MalformedAlertError,
    decode_alert,
    decode_alert_reference,
    encode_alert,
    encode_alert_reference,
    unix_ms_to_its_ms,
)

__all__ = [
    "DEFAULT_MAX_AGE_S",
    "DEFAULT_MAX_FUTURE_S",
    "DEFAULT_SIGNER_FORM",
    "LEARNT_CERTIFICATES",
    "MAX_CERTIFICATE_SIZE",
    "MAX_SIGNED_SIZE",
    "NOT_RELEVANT",
    "PSID_DEN",
    "SIGNED_SIZE",
    "SIGNER_FORMS",
    "SIGNER_OFFSET",
    "STATION_ID_OFFSET",
    "GenerationLocation",
    "Identity",
    "ReplayCache",
    "SignedAlert",
    "TrustStore",
    "Verdict",
    "Verifier",
    "encode_signed",
    "encode_signed_reference",
    "hashed_id8",
    "keygen",
    "load_identity",
    "parse_signed",
    "parse_signed_reference",
    "revoke",
    "sign_alert",
    "station_id_of",
]

# the profile's COER bytes around the DENM (see the module's notes)
_PREFIX = bytes([0x03, 0x81, 0x00, 0x40, 0x03, 0x80, ALERT_SIZE])
# protocolVersion 3 · signedData · hashId sha256 · payload {data present} · protocolVersion 3 ·
# unsecuredData · its length
_DENM_AT = len(_PREFIX)
# headerInfo {generationTime, generationLocation present} · psid: 1 byte, 37
_HEADER = bytes([0x50, 0x01, PSID_DEN])
_HEADER_AT = _DENM_AT + ALERT_SIZE
_TIME_AT = _HEADER_AT + len(_HEADER)
_LOC_AT = _TIME_AT + 8  # ThreeDLocation: latitude, longitude (4 bytes each, signed), elevation (2)
_TBS = slice(3, _LOC_AT + 10)  # tbsData: payload and headerInfo
_SIGNER_TAG_AT = _LOC_AT + 10  # 0x80: signer digest · 0x81: signer certificate
SIGNER_OFFSET = _SIGNER_TAG_AT + 1
"""Where the signer starts in a signed alert: its HashedId8 (digest form), or the one-element
SequenceOfCertificate, ``01 01`` then the certificate's COER (certificate form)."""
_ONE_CERTIFICATE = b"\x01\x01"  # COER quantity of a SEQUENCE OF: a 1-byte count, 1
STATION_ID_OFFSET = _DENM_AT + 2
"""Where the DENM header's station id (4 bytes, big-endian) starts in a signed alert."""
_SIG_TAGS = bytes([0x80, 0x80])  # ecdsaNistP256Signature · rSig x-only
_SIG_TAGS_AT = SIGNER_OFFSET + 8
_R_AT = _SIG_TAGS_AT + 2
SIGNED_SIZE = _R_AT + 64
"""Bytes of a signed alert whose signer is a digest (155): the shortest signed alert."""
MAX_CERTIFICATE_SIZE = 400
"""The longest signer certificate a car reads (bytes); makeway's certificates are 133 bytes plus
their name (at most 255 bytes)."""
MAX_SIGNED_SIZE = SIGNED_SIZE - 8 + len(_ONE_CERTIFICATE) + MAX_CERTIFICATE_SIZE
"""The longest signed alert a car reads (549 bytes): the certificate form with the longest
certificate."""
SIGNER_FORMS = ("certificate", "digest")
"""How a signed alert names its signer: the whole certificate (TS 103 097's DENM profile; a car
needs only the root to check it) or its HashedId8 (155 bytes; the car must hold the unit's
certificate already, in its trust store or learnt from an earlier alert)."""
DEFAULT_SIGNER_FORM = "certificate"
LEARNT_CERTIFICATES = 4096
"""Unit certificates a :class:`Verifier` remembers after they chained to its root."""
DEFAULT_MAX_AGE_S = 10.0
"""Freshness window (s): older alerts are stale. Alerts repeat at 10 Hz, so a car never needs an
old one; the window also bounds how long the replay cache remembers a sequence number."""
REPLAY_WINDOW = 1024
"""Sequences per signer below its newest that the replay cache tells apart (:class:`ReplayCache`)."""
_WINDOW_MASK = (1 << REPLAY_WINDOW) - 1
DEFAULT_MAX_FUTURE_S = 1.0
"""Clock-skew allowance (s): an alert generated further ahead of the car's clock is rejected."""

_N = int("FFFFFFFF00000000FFFFFFFFFFFFFFFFBCE6FAADA7179E84F3B9CAC2FC632551", 16)  # P-256 group order
_HALF_N = _N // 2


_LAT_RANGE = (-900_000_000, 900_000_001)  # 1609.2 NinetyDegreeInt, 1e-7 degrees; the top: unavailable
_LON_RANGE = (-1_799_999_999, 1_800_000_001)  # OneEightyDegreeInt; the top: unavailable
_ELEVATION_FLOOR_M = -409.5  # 1609.2 Elevation: decimetres above −409.5 m, 0 … 65535


@dataclass(frozen=True, slots=True)
class GenerationLocation:
    """Where a signed alert was generated (1609.2 ``ThreeDLocation``): WGS-84 latitude and longitude
    in 1e-7 degrees and the elevation as 1609.2 codes it (decimetres above −409.5 m)."""

    lat_e7: int
    lon_e7: int
    elevation_dm: int = 4095  # 0 m

    def __post_init__(self) -> None:
        if not _LAT_RANGE[0] <= self.lat_e7 <= _LAT_RANGE[1]:
            raise ValueError(f"generation latitude {self.lat_e7} outside 1609.2's range {_LAT_RANGE}")
        if not _LON_RANGE[0] <= self.lon_e7 <= _LON_RANGE[1]:
            raise ValueError(f"generation longitude {self.lon_e7} outside 1609.2's range {_LON_RANGE}")
        if not 0 <= self.elevation_dm <= 0xFFFF:
            raise ValueError(f"generation elevation code {self.elevation_dm} outside 0 … 65535")

    @classmethod
    def from_degrees(cls, lat_deg: float, lon_deg: float, elevation_m: float = 0.0) -> GenerationLocation:
        """From WGS-84 degrees and metres (rounded to 1e-7 degrees and 0.1 m)."""
        for name, v, top in (("latitude", lat_deg, 90.0), ("longitude", lon_deg, 180.0)):
            if not -top <= v <= top:
                raise ValueError(f"generation {name} {v!r} is not in −{top:g} … {top:g} degrees")
        if not _ELEVATION_FLOOR_M <= elevation_m <= _ELEVATION_FLOOR_M + 0xFFFF / 10:
            raise ValueError(f"generation elevation {elevation_m!r} m outside 1609.2's −409.5 … 6144.0 m")
        return cls(round(lat_deg * 1e7), round(lon_deg * 1e7), round((elevation_m - _ELEVATION_FLOOR_M) * 10))

    @classmethod
    def of_event(cls, alert: Alert) -> GenerationLocation:
        """The EV's own position (the DENM's event position) at 0 m: the default sender location.
        (DENM's longitude may be −180°, which 1609.2 writes as +180°: the same meridian.)"""
        return cls(alert.lat_e7, 1_800_000_000 if alert.lon_e7 == -1_800_000_000 else alert.lon_e7)

    @property
    def lat_deg(self) -> float:
        return self.lat_e7 / 1e7

    @property
    def lon_deg(self) -> float:
        return self.lon_e7 / 1e7

    @property
    def elevation_m(self) -> float:
        return self.elevation_dm / 10 + _ELEVATION_FLOOR_M

    def to_coer(self) -> bytes:
        """The 10 bytes of COER: latitude and longitude as signed 4-byte integers, elevation 2 bytes."""
        return (
            self.lat_e7.to_bytes(4, "big", signed=True)
            + self.lon_e7.to_bytes(4, "big", signed=True)
            + self.elevation_dm.to_bytes(2, "big")
        )

    @classmethod
    def from_coer(cls, data: bytes) -> GenerationLocation:
        """The inverse of :meth:`to_coer`; :class:`MalformedAlertError` for values outside 1609.2's ranges."""
        try:
            return cls(
                int.from_bytes(data[0:4], "big", signed=True),
                int.from_bytes(data[4:8], "big", signed=True),
                int.from_bytes(data[8:10], "big"),
            )
        except ValueError as exc:
            raise MalformedAlertError(str(exc)) from None

    def to_json(self) -> dict[str, float]:
        return {
            "generation_lat_deg": self.lat_deg,
            "generation_lon_deg": self.lon_deg,
            "generation_elevation_m": round(self.elevation_m, 1),
        }


def hashed_id8(cert: Certificate) -> bytes:
    """1609.2's HashedId8 of a certificate: the low-order (last) 8 bytes of SHA-256 over its COER."""
    return cert.hashed_id8


def station_id_of(signer: bytes) -> int:
    """The station id bound to a signer: the first 4 bytes of its HashedId8, big-endian."""
    return int.from_bytes(signer[:4], "big")


# ------------------------------------------------------------------------------------------- keys
@dataclass(frozen=True)
class Identity:
    """A unit's signing key, its certificate, HashedId8 and station id."""

    key: ec.EllipticCurvePrivateKey
    cert: Certificate
    signer: bytes
    station_id: int

    @property
    def cert_hash(self) -> bytes:
        """SHA-256 of the certificate's COER: 1609.2's hash of the signer identifier input."""
        return self.cert.digest


def _write_private(path: Path, key: ec.EllipticCurvePrivateKey) -> None:
    pem = key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )
    # all-or-nothing and private from the first byte: a temporary file made 0600 beside it, renamed
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(pem)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _write_public(path: Path, data: bytes) -> None:
    from makeway.atomic import atomic_path

    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def keygen(out: str | Path, name: str = "rsu", *, days: int = 365) -> Identity:
    """Create (or reuse) the local root in ``out`` and issue a new unit identity ``name``.

    Writes ``out/NAME.key``, ``out/NAME.cert`` and ``out/trust/units/NAME.cert``; the first call
    also writes ``out/root.key``, ``out/trust/root.cert`` and an empty ``out/trust/revoked.txt``.
    An existing ``NAME.key`` is an error (a key is never overwritten). Certificates are valid from
    five minutes ago: the unit's for ``days``, the root's for ten years.
    """
    if not name or not all(c.isalnum() or c in "-_" for c in name):
        raise ValueError(f"--name takes letters, digits, '-' and '_', not {name!r}")
    out = Path(out)
    if (out / f"{name}.key").exists():
        raise InputError(out / f"{name}.key", "already exists; pick another --name or folder")
    trust = out / "trust"
    (trust / "units").mkdir(parents=True, exist_ok=True)
    if (trust / _OLD_ROOT).exists():
        raise InputError(trust / _OLD_ROOT, _OLD_FORMAT)
    root_key_path, root_cert = out / "root.key", trust / "root.cert"
    if root_key_path.exists() != root_cert.exists():
        raise InputError(out, "has only one of root.key and trust/root.cert; use a fresh folder")
    start = time.time() - 300.0
    if root_key_path.exists():
        root_key = _load_private(root_key_path)
        root = _load_cert(root_cert)
    else:
        root_key = ec.generate_private_key(ec.SECP256R1())
        root = issue_certificate(
            "makeway local root",
            root_key.public_key(),
            root_key,
            issuer=None,
            start_s=start,
            days=3650,
            can_issue=True,
        )
        _write_public(root_cert, root.data)
        _write_private(root_key_path, root_key)
    revoked = trust / "revoked.txt"
    if not revoked.exists():
        _write_public(revoked, b"# revoked signers: one HashedId8 (16 hex digits) per line\n")
    key = ec.generate_private_key(ec.SECP256R1())
    cert = issue_certificate(
        f"makeway unit {name}", key.public_key(), root_key, issuer=root, start_s=start, days=days
    )
    # each file atomic; the key last, so that a run stopped part-way can simply be repeated
    _write_public(out / f"{name}.cert", cert.data)
    _write_public(trust / "units" / f"{name}.cert", cert.data)
    _write_private(out / f"{name}.key", key)
    signer = hashed_id8(cert)
    return Identity(key, cert, signer, station_id_of(signer))


def _load_private(path: Path) -> ec.EllipticCurvePrivateKey:
    try:
        key = serialization.load_pem_private_key(path.read_bytes(), password=None)
    except OSError as exc:
        raise InputError(path, f"cannot be read ({exc.strerror})") from None
    except (ValueError, TypeError, UnsupportedAlgorithm):  # the last: a key of an unknown type
        raise InputError(path, "is not an unencrypted PEM private key") from None
    if not isinstance(key, ec.EllipticCurvePrivateKey) or key.curve.name != "secp256r1":
        raise InputError(path, "is not a P-256 (secp256r1) key")
    return key


_OLD_ROOT = "root.pem"
_OLD_FORMAT = (
    "is an X.509 certificate of a makeway before 1609.2 certificates; make new keys and a new trust "
    "store with makeway v2x keygen"
)


def _load_cert(path: Path) -> Certificate:
    """The 1609.2 certificate in ``path`` (COER), parsed; one :class:`InputError` naming the file
    for anything else."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(path, f"cannot be read ({exc.strerror})") from None
    if data.startswith(b"-----BEGIN"):
        raise InputError(path, _OLD_FORMAT)
    try:
        return parse_certificate(data)
    except MalformedCertificateError as exc:
        raise InputError(path, f"is not a 1609.2 certificate of makeway's profile: {exc}") from None


def load_identity(key_path: str | Path) -> Identity:
    """A unit's key file and the certificate beside it (``NAME.key`` → ``NAME.cert``)."""
    key_path = Path(key_path)
    key = _load_private(key_path)
    cert_path = key_path.with_suffix(".cert")
    if not cert_path.exists() and key_path.with_suffix(".crt").exists():
        raise InputError(key_path.with_suffix(".crt"), _OLD_FORMAT)
    cert = _load_cert(cert_path)
    if cert.public_key.public_numbers() != key.public_key().public_numbers():
        raise InputError(cert_path, f"does not certify the key in {key_path.name}")
    if PSID_DEN not in cert.psids:
        raise InputError(cert_path, f"does not allow signing DENMs (PSID {PSID_DEN})")
    signer = hashed_id8(cert)
    return Identity(key, cert, signer, station_id_of(signer))


def _signed_type() -> Any:
    from pycrate_asn1dir import ITS_IEEE1609_2

    return ITS_IEEE1609_2.Ieee1609Dot2


def _tbs_value(denm: bytes, time64_us: int, location: GenerationLocation) -> dict[str, Any]:
    return {
        "payload": {"data": {"protocolVersion": 3, "content": ("unsecuredData", denm)}},
        "headerInfo": {
            "psid": PSID_DEN,
            "generationTime": time64_us,
            "generationLocation": {
                "latitude": location.lat_e7,
                "longitude": location.lon_e7,
                "elevation": location.elevation_dm,
            },
        },
    }


def _signing_input(tbs: bytes, cert_hash: bytes) -> bytes:
    """1609.2's ECDSA input: Hash(tbsData's COER) ‖ Hash(signer identifier input)."""
    return hashlib.sha256(tbs).digest() + cert_hash


def sign_alert(
    alert: Alert,
    identity: Identity,
    location: GenerationLocation | None = None,
    *,
    signer: str = DEFAULT_SIGNER_FORM,
) -> bytes:
    """The signed alert (COER), generated at ``location`` (the sender's position; ``None``: the EV's,
    :meth:`GenerationLocation.of_event`), its signer named as ``signer`` says (:data:`SIGNER_FORMS`:
    ``"certificate"``, the default, carries the unit's whole certificate; ``"digest"`` its
    HashedId8, :data:`SIGNED_SIZE` bytes in all). The alert's station id must be the signer's."""
    if alert.station_id != identity.station_id:
        raise ValueError(f"alert station id {alert.station_id} is not the signer's ({identity.station_id})")
    if signer not in SIGNER_FORMS:
        raise ValueError(f"signer must be one of {SIGNER_FORMS}, not {signer!r}")
    named: bytes | Certificate = identity.cert if signer == "certificate" else identity.signer
    unsigned = encode_signed(alert, named, 0, 0, location)
    der = identity.key.sign(_signing_input(unsigned[_TBS], identity.cert_hash), ec.ECDSA(hashes.SHA256()))
    r, s = decode_dss_signature(der)
    return unsigned[:-64] + r.to_bytes(32, "big") + min(s, _N - s).to_bytes(32, "big")


def _signer_field(signer: bytes | Certificate) -> bytes:
    if isinstance(signer, Certificate):
        if len(signer.data) > MAX_CERTIFICATE_SIZE:
            raise ValueError(f"a signer certificate has at most {MAX_CERTIFICATE_SIZE} bytes")
        return b"\x81" + _ONE_CERTIFICATE + signer.data
    if len(signer) != 8:
        raise ValueError(f"a HashedId8 has 8 bytes, not {len(signer)}")
    return b"\x80" + signer


def encode_signed(
    alert: Alert, signer: bytes | Certificate, r: int, s: int, location: GenerationLocation | None = None
) -> bytes:
    """The signed alert's bytes with a given signer — a HashedId8 (8 bytes: the digest form) or a
    :class:`~makeway.v2x.certificates.Certificate` (the certificate form) —, signature ``(r, s)``
    (each 0 … 2²⁵⁶ − 1) and generation location (``None``: the EV's): the profile's fixed bytes with
    the fields in place, the same bytes as pycrate's encoder (:func:`encode_signed_reference`).
    :func:`sign_alert` computes a real signature; this also builds the forgeries of attack suites."""
    named = _signer_field(signer)
    time64 = unix_ms_to_its_ms(alert.generation_time_ms) * 1000
    where = GenerationLocation.of_event(alert) if location is None else location
    return b"".join(
        (
            _PREFIX,
            encode_alert(alert),
            _HEADER,
            time64.to_bytes(8, "big"),
            where.to_coer(),
            named,
            _SIG_TAGS,
            r.to_bytes(32, "big"),
            s.to_bytes(32, "big"),
        )
    )


def encode_signed_reference(
    alert: Alert, signer: bytes | Certificate, r: int, s: int, location: GenerationLocation | None = None
) -> bytes:
    """:func:`encode_signed` done by pycrate (UPER for the DENM, COER for the 1609.2 structure):
    the reference the exact writer is tested against. About 0.5 ms."""
    denm = encode_alert_reference(alert)
    with _PYCRATE_LOCK:
        types = _signed_type()
        if isinstance(signer, Certificate):
            types.Certificate.from_oer(signer.data)
            named: tuple[str, Any] = ("certificate", [types.Certificate.get_val()])
        else:
            named = ("digest", signer)
    value = {
        "protocolVersion": 3,
        "content": (
            "signedData",
            {
                "hashId": "sha256",
                "tbsData": _tbs_value(
                    denm,
                    unix_ms_to_its_ms(alert.generation_time_ms) * 1000,
                    GenerationLocation.of_event(alert) if location is None else location,
                ),
                "signer": named,
                "signature": (
                    "ecdsaNistP256Signature",
                    {"rSig": ("x-only", r.to_bytes(32, "big")), "sSig": s.to_bytes(32, "big")},
                ),
            },
        ),
    }
    with _PYCRATE_LOCK:
        types = _signed_type()
        types.Ieee1609Dot2Data.set_val(value)
        data: bytes = types.Ieee1609Dot2Data.to_oer()
    return data


@dataclass(frozen=True, slots=True)
class SignedAlert:
    """A signed alert's parts: the alert, 1609.2's generationTime (µs), the signer's HashedId8,
    the signature ``(r, s)``, the bytes of tbsData (what was signed), where it was generated, and
    the signer's certificate (COER) when the alert carries it (``None``: the digest form)."""

    alert: Alert
    time64_us: int
    signer: bytes
    r: int
    s: int
    tbs: bytes
    location: GenerationLocation
    certificate: bytes | None = None


def parse_signed(data: bytes, *, check_certificate: bool = True) -> SignedAlert:
    """Read one signed alert of this profile; :class:`MalformedAlertError` for anything else
    (another length, another structure, option or tag, a non-canonical encoding, a DENM outside
    :mod:`makeway.v2x.message`'s profile, a generationTime that is not the DENM's referenceTime, a
    signer sequence of other than one certificate). The signature is not checked here, nor whether
    the certificate chains to anything. ``check_certificate=False`` leaves a carried certificate's
    own encoding unread (the bytes between the signer's header and the signature are taken as it):
    :class:`Verifier` reads it only for an alert that passed every cheaper check."""
    n = len(data)
    if not SIGNED_SIZE <= n <= MAX_SIGNED_SIZE:
        raise MalformedAlertError(f"{n} bytes, a signed alert has {SIGNED_SIZE} … {MAX_SIGNED_SIZE}")
    data = bytes(data)
    if data[:_DENM_AT] != _PREFIX or data[_HEADER_AT:_TIME_AT] != _HEADER or data[-66:-64] != _SIG_TAGS:
        raise MalformedAlertError("not a 1609.2 signed DENM of this profile")
    certificate: bytes | None = None
    if data[_SIGNER_TAG_AT] == 0x80 and n == SIGNED_SIZE:
        signer = data[SIGNER_OFFSET:_SIG_TAGS_AT]
    elif data[_SIGNER_TAG_AT] == 0x81 and data[SIGNER_OFFSET : SIGNER_OFFSET + 2] == _ONE_CERTIFICATE:
        certificate = data[SIGNER_OFFSET + 2 : -66]
        if check_certificate:
            try:
                cert = parse_certificate(certificate)
            except MalformedCertificateError as exc:
                raise MalformedAlertError(f"signer certificate: {exc}") from None
            if cert.data != certificate:  # a certificate followed by more bytes
                raise MalformedAlertError("not a 1609.2 signed DENM of this profile")
        signer = hashlib.sha256(certificate).digest()[-8:]
    else:
        raise MalformedAlertError("not a 1609.2 signed DENM of this profile")
    alert = decode_alert(data[_DENM_AT:_HEADER_AT])
    time64 = int.from_bytes(data[_TIME_AT:_LOC_AT], "big")
    if time64 != unix_ms_to_its_ms(alert.generation_time_ms) * 1000:
        raise MalformedAlertError("generationTime is not the DENM's reference time")
    return SignedAlert(
        alert,
        time64,
        signer,
        int.from_bytes(data[-64:-32], "big"),
        int.from_bytes(data[-32:], "big"),
        data[_TBS],
        GenerationLocation.from_coer(data[_LOC_AT:_SIGNER_TAG_AT]),
        certificate,
    )


def parse_signed_reference(data: bytes) -> SignedAlert:
    """:func:`parse_signed` done by pycrate (COER and UPER decoders, then a re-encoding that must
    give the same bytes); the reference the exact reader is tested against. About 1 ms."""
    try:
        with _PYCRATE_LOCK:
            types = _signed_type()
            types.Ieee1609Dot2Data.from_oer(bytes(data))
            v = types.Ieee1609Dot2Data.get_val()
            again = types.Ieee1609Dot2Data.to_oer()
    except Exception as exc:  # pycrate raises several unrelated types on bad input
        raise MalformedAlertError(f"not an Ieee1609Dot2Data ({type(exc).__name__})") from None
    if not SIGNED_SIZE <= len(data) <= MAX_SIGNED_SIZE:
        raise MalformedAlertError(f"{len(data)} bytes, a signed alert has {SIGNED_SIZE} … {MAX_SIGNED_SIZE}")
    if again != bytes(data):
        raise MalformedAlertError("not canonical: the bytes differ from their re-encoding")
    try:
        kind, sd = v["content"]
        tbs = sd["tbsData"]
        inner_kind, denm = tbs["payload"]["data"]["content"]
        sig_kind, sig = sd["signature"]
        r_kind, r = sig["rSig"]
        signer_kind, signer = sd["signer"]
        ok = (
            v["protocolVersion"] == 3
            and kind == "signedData"
            and sd["hashId"] == "sha256"
            and set(tbs["payload"]) == {"data"}
            and tbs["payload"]["data"]["protocolVersion"] == 3
            and inner_kind == "unsecuredData"
            and set(tbs["headerInfo"]) == {"psid", "generationTime", "generationLocation"}
            and tbs["headerInfo"]["psid"] == PSID_DEN
            and (signer_kind == "digest" or (signer_kind == "certificate" and len(signer) == 1))
            and sig_kind == "ecdsaNistP256Signature"
            and r_kind == "x-only"
        )
    except (KeyError, TypeError, ValueError):
        ok = False
    if not ok:
        raise MalformedAlertError("not a 1609.2 signed DENM of this profile")
    alert = decode_alert_reference(denm)
    time64 = tbs["headerInfo"]["generationTime"]
    if time64 != unix_ms_to_its_ms(alert.generation_time_ms) * 1000:
        raise MalformedAlertError("generationTime is not the DENM's reference time")
    loc = tbs["headerInfo"]["generationLocation"]
    try:
        location = GenerationLocation(loc["latitude"], loc["longitude"], loc["elevation"])
    except ValueError as exc:
        raise MalformedAlertError(str(exc)) from None
    with _PYCRATE_LOCK:
        types = _signed_type()
        types.ToBeSignedData.set_val(tbs)
        tbs_bytes = types.ToBeSignedData.to_oer()
        certificate: bytes | None = None
        if signer_kind == "certificate":
            types.Certificate.set_val(signer[0])
            certificate = types.Certificate.to_oer()
    if certificate is not None:
        try:
            parse_certificate(certificate)  # this profile's certificate, not any 1609.2 one
        except MalformedCertificateError as exc:
            raise MalformedAlertError(f"signer certificate: {exc}") from None
        signer = hashlib.sha256(certificate).digest()[-8:]
    return SignedAlert(
        alert,
        time64,
        signer,
        int.from_bytes(r, "big"),
        int.from_bytes(sig["sSig"], "big"),
        tbs_bytes,
        location,
        certificate,
    )


# ---------------------------------------------------------------------------------------- trust
@dataclass
class TrustStore:
    """What a car trusts: unit certificates issued by the root, minus the revoked ones.

    ``units`` maps HashedId8 → (public key, start and end of validity as Unix s, SHA-256 of the
    certificate's COER);
    ``refused`` lists unit certificate files that did not chain to the root or may not sign
    DENMs, with the reason.
    """

    root: Certificate
    units: dict[bytes, tuple[ec.EllipticCurvePublicKey, float, float, bytes]]
    revoked: set[bytes]
    refused: list[tuple[str, str]] = field(default_factory=list)

    @staticmethod
    def load(trust_dir: str | Path) -> TrustStore:
        """Read ``root.cert``, ``units/*.cert`` and ``revoked.txt`` from ``trust_dir``."""
        trust_dir = Path(trust_dir)
        if not (trust_dir / "root.cert").is_file():
            if (trust_dir / _OLD_ROOT).is_file():
                raise InputError(trust_dir / _OLD_ROOT, _OLD_FORMAT)
            raise InputError(
                trust_dir, "is not a trust store (no root.cert; make one with makeway v2x keygen)"
            )
        root = _load_cert(trust_dir / "root.cert")
        if not (root.issuer is None and root.can_issue and root.issued_by(root)):
            raise InputError(
                trust_dir / "root.cert", "is not a self-signed root allowed to issue certificates"
            )
        units: dict[bytes, tuple[ec.EllipticCurvePublicKey, float, float, bytes]] = {}
        refused: list[tuple[str, str]] = []
        for path in sorted((trust_dir / "units").glob("*.cert")):
            cert = _load_cert(path)
            if cert.issuer is None or not cert.issued_by(root):
                refused.append((str(path), "not issued by this root"))
                continue
            if PSID_DEN not in cert.psids:
                refused.append((str(path), f"not allowed to sign DENMs (PSID {PSID_DEN})"))
                continue
            units[cert.hashed_id8] = (cert.public_key, cert.start_s, cert.end_s, cert.digest)
        return TrustStore(root, units, _read_revoked(trust_dir / "revoked.txt"), refused)


def _read_revoked(path: Path) -> set[bytes]:
    if not path.exists():
        return set()
    out: set[bytes] = set()
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot be read as a revocation list ({exc})") from None
    for i, line in enumerate(text.splitlines(), 1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        try:
            value = bytes.fromhex(text)
        except ValueError:
            value = b""
        if len(value) != 8:
            raise InputError(path, f"line {i}: {text!r} is not a HashedId8 (16 hex digits)")
        out.add(value)
    return out


def revoke(trust_dir: str | Path, cert_path: str | Path) -> str:
    """Add a unit certificate's HashedId8 to ``trust_dir/revoked.txt``; return it in hex."""
    signer = _load_cert(Path(cert_path)).hashed_id8.hex()
    path = Path(trust_dir) / "revoked.txt"
    known = {s.hex() for s in _read_revoked(path)}
    if signer not in known:
        with path.open("a", encoding="utf-8") as f:
            f.write(f"{signer}  # {Path(cert_path).name}\n")
    return signer


# ---------------------------------------------------------------------------------------- replay
class ReplayCache:
    """The sequences each signer has had accepted, for replay detection.

    Sequences increase by one per alert of a station, modulo 65536 (DENM's SequenceNumber), so per
    signer the cache keeps the newest accepted sequence, a bit for each of the
    :data:`REPLAY_WINDOW` sequences below it (set: accepted), and the newest generation time (ms)
    — the sliding window of IPsec's and DTLS's anti-replay checks. "Newer" is serial-number
    arithmetic (RFC 1982): a sequence up to 32767 ahead of the newest, counting across the wrap,
    is newer. Its size is a few hundred bytes per signer, whatever the alert rate (a set of every
    accepted pair within the freshness window grows with the rate: at ten times the usual load the
    listener's memory grew 8 %). A sequence more than the window behind the signer's newest counts
    as seen: it cannot be told from a replay (at 10 Hz it is 100 s old, far beyond the freshness
    window). :meth:`prune` forgets signers whose newest alert is stale; a unit that restarts its
    count is accepted again once that happens. A unit sending over 3,276 alerts/s would wrap
    within the 10 s freshness window, which this cache does not tell apart."""

    def __init__(self, entries: Iterable[tuple[bytes, int, int]] = ()) -> None:
        # signer → [newest sequence, bit k = sequence (newest − k) accepted, newest generation ms]
        self._windows: dict[bytes, list[int]] = {}
        for signer, sequence, generation_ms in entries:
            self.add(signer, sequence, generation_ms)

    def __len__(self) -> int:
        """Accepted (signer, sequence) pairs remembered."""
        return sum(w[1].bit_count() for w in self._windows.values())

    @property
    def signers(self) -> int:
        """Signers with a window."""
        return len(self._windows)

    @staticmethod
    def _ahead(sequence: int, newest: int) -> int:
        """How far ``sequence`` is ahead of ``newest`` (> 0) or behind it (≤ 0), across the wrap."""
        d = (sequence - newest) % SEQUENCE_MODULUS
        return d if d < SEQUENCE_MODULUS // 2 else d - SEQUENCE_MODULUS

    def seen(self, signer: bytes, sequence: int) -> bool:
        """Whether ``signer``'s ``sequence`` was accepted already (or is too far behind to tell)."""
        w = self._windows.get(signer)
        if w is None:
            return False
        ahead = self._ahead(sequence, w[0])
        if ahead > 0:
            return False
        return -ahead >= REPLAY_WINDOW or bool((w[1] >> -ahead) & 1)

    def add(self, signer: bytes, sequence: int, generation_time_ms: int) -> None:
        """Record ``signer``'s accepted ``sequence``, generated at ``generation_time_ms``."""
        w = self._windows.get(signer)
        if w is None:
            self._windows[signer] = [sequence, 1, generation_time_ms]
            return
        ahead = self._ahead(sequence, w[0])
        if ahead > 0:
            w[1] = ((w[1] << ahead) | 1) & _WINDOW_MASK if ahead < REPLAY_WINDOW else 1
            w[0] = sequence
        elif -ahead < REPLAY_WINDOW:
            w[1] |= 1 << -ahead
        w[2] = max(w[2], generation_time_ms)

    def prune(self, oldest_ms: int) -> None:
        """Forget signers whose newest accepted alert was generated before ``oldest_ms``: every
        alert of theirs that the cache holds is stale anyway."""
        self._windows = {k: w for k, w in self._windows.items() if w[2] >= oldest_ms}

    @staticmethod
    def load(path: str | Path) -> ReplayCache:
        """A cache file written by :meth:`save`; a missing file is an empty cache."""
        path = Path(path)
        if not path.exists():
            return ReplayCache()
        try:
            rows = json.loads(path.read_text(encoding="utf-8"))["seen"]
            entries = [(bytes.fromhex(s), q, g) for s, q, g in rows]
            for signer, q, g in entries:  # a HashedId8, a sequence number, a time in ms: whole numbers
                if len(signer) != 8 or not (type(q) is int and 0 <= q < SEQUENCE_MODULUS):
                    raise ValueError("an entry is not [16 hex digits, sequence, generation time ms]")
                if not (type(g) is int and 0 <= g < 2**63):
                    raise ValueError("an entry is not [16 hex digits, sequence, generation time ms]")
            return ReplayCache(entries)
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise InputError(path, f"is not a replay cache ({type(exc).__name__})") from None

    def save(self, path: str | Path) -> None:
        from makeway.atomic import write_text_atomic

        rows = [  # newest first: loading adds them in this order
            [signer.hex(), (w[0] - k) % SEQUENCE_MODULUS, w[2]]
            for signer, w in sorted(self._windows.items())
            for k in range(REPLAY_WINDOW)
            if (w[1] >> k) & 1
        ]
        write_text_atomic(path, json.dumps({"seen": rows}) + "\n")


# ---------------------------------------------------------------------------------------- verify
NOT_RELEVANT = "not relevant: passed the checks that need no signature, not verified (verify on demand)"
"""The :class:`Verdict` reason of an alert the ``relevant`` predicate declined: not an attack, not
accepted; the car simply has no use for it."""


@dataclass(frozen=True, slots=True)
class Verdict:
    """The result of checking one message: ``reason`` is ``"ok"`` when ``valid``."""

    valid: bool
    reason: str
    alert: Alert | None = None
    signer: bytes | None = None
    location: GenerationLocation | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"valid": self.valid, "reason": self.reason}
        if self.signer is not None:
            out["signer"] = self.signer.hex()
        if self.alert is not None:
            out.update(self.alert.to_json())
        if self.location is not None:
            out.update(self.location.to_json())
        return out


class Verifier:
    """Checks signed alerts against a trust store, the car's clock and a replay cache.

    Args:
        store: the car's trust store.
        max_age_s: freshness window (s).
        max_future_s: clock-skew allowance (s).
        replay: pairs already accepted (shared across calls; a new empty cache by default).
        relevant: verify on demand (module docstring): called with the decoded alert after every
            check that needs no signature; when it returns False the signature is not checked and
            the verdict is :data:`NOT_RELEVANT`. ``None`` (the default): every signature is checked.

    A signer is known when its certificate is in the trust store or was learnt: an alert that
    carries its signer's certificate (the certificate form) is checked against the store's root
    once every cheaper check has passed — issued by the root, allowed to sign DENMs, valid at the
    generation time, not revoked — and a certificate that chains is remembered (up to
    :data:`LEARNT_CERTIFICATES`), so later alerts of that unit cost one signature check, in either
    form. A car therefore needs only the root to trust a unit installed after its store was made.
    """

    def __init__(
        self,
        store: TrustStore,
        *,
        max_age_s: float = DEFAULT_MAX_AGE_S,
        max_future_s: float = DEFAULT_MAX_FUTURE_S,
        replay: ReplayCache | None = None,
        relevant: Callable[[Alert], bool] | None = None,
    ) -> None:
        self.store = store
        self.relevant = relevant
        self.max_age_ms = round(max_age_s * 1000)
        self.max_future_ms = round(max_future_s * 1000)
        self.replay = ReplayCache() if replay is None else replay
        self._pruned_ms: int | None = None
        self.learnt: dict[bytes, tuple[ec.EllipticCurvePublicKey, float, float, bytes]] = {}

    def _learn(self, certificate: bytes) -> tuple[ec.EllipticCurvePublicKey, float, float, bytes] | str:
        """The unit entry of a carried certificate that chains to the store's root, or the reason
        it does not."""
        try:
            cert = parse_certificate(certificate)
        except MalformedCertificateError as exc:
            return f"malformed signer certificate: {exc}"
        if cert.data != certificate:
            return "malformed signer certificate: bytes after the certificate"
        if cert.issuer is None or not cert.issued_by(self.store.root):
            return "unknown signer: its certificate was not issued by this store's root"
        if PSID_DEN not in cert.psids:
            return f"signer certificate may not sign DENMs (PSID {PSID_DEN})"
        unit = (cert.public_key, cert.start_s, cert.end_s, cert.digest)
        if len(self.learnt) >= LEARNT_CERTIFICATES:
            del self.learnt[next(iter(self.learnt))]  # the oldest learnt
        self.learnt[cert.hashed_id8] = unit
        return unit

    def verify(self, data: bytes, now_s: float) -> Verdict:
        """Check one message received at ``now_s`` (Unix s, the car's clock); an accepted alert's
        signer and sequence enter the replay cache."""
        n = len(data)
        if n < SIGNED_SIZE:
            return Verdict(False, f"truncated: {n} bytes, a signed alert has at least {SIGNED_SIZE}")
        if n > MAX_SIGNED_SIZE:
            return Verdict(False, f"oversized: {n} bytes, a signed alert has at most {MAX_SIGNED_SIZE}")
        try:
            parsed = parse_signed(data, check_certificate=False)
        except MalformedAlertError as exc:
            return Verdict(False, f"malformed: {exc}")
        alert, signer, r, s, where = parsed.alert, parsed.signer, parsed.r, parsed.s, parsed.location
        unit = self.store.units.get(signer) or self.learnt.get(signer)
        if unit is None and parsed.certificate is None:
            return Verdict(False, "unknown signer", alert, signer, where)
        carried = parsed.certificate
        if unit is not None and carried is not None and hashlib.sha256(carried).digest() != unit[3]:
            # the HashedId8 of a known unit, but another certificate
            return Verdict(False, "unknown signer: another certificate, a known id", alert, signer, where)
        if signer in self.store.revoked:
            return Verdict(False, "revoked signer", alert, signer, where)
        if not (0 < r < _N and 0 < s <= _HALF_N):
            return Verdict(False, "bad signature (not a canonical r, s)", alert, signer, where)
        # relevance checks first (IEEE 1609.2's order): a stale, future, replayed or mislabelled
        # message costs a decode, not an ECDSA verification, so a flood of them cannot starve the
        # alerts that matter. Nothing is recorded until the signature has been checked.
        if alert.station_id != station_id_of(signer):
            return Verdict(False, "station id is not the signer's", alert, signer, where)
        gen_ms = alert.generation_time_ms
        now_ms = round(now_s * 1000)
        if gen_ms > now_ms + self.max_future_ms:
            ahead = (gen_ms - now_ms) / 1000
            return Verdict(False, f"future: generated {ahead:.3f} s ahead of the clock", alert, signer, where)
        if gen_ms < now_ms - self.max_age_ms:
            age = (now_ms - gen_ms) / 1000
            return Verdict(False, f"stale: generated {age:.3f} s ago", alert, signer, where)
        if self._pruned_ms is None or now_ms - self._pruned_ms >= 1000:  # idle signers, once a second
            self.replay.prune(now_ms - self.max_age_ms)
            self._pruned_ms = now_ms
        if self.replay.seen(signer, alert.sequence):
            return Verdict(False, "replay: this signer's sequence was already accepted", alert, signer, where)
        if self.relevant is not None and not self.relevant(alert):
            return Verdict(False, NOT_RELEVANT, alert, signer, where)
        if unit is None:
            assert parsed.certificate is not None
            learnt = self._learn(parsed.certificate)
            if isinstance(learnt, str):
                return Verdict(False, learnt, alert, signer, where)
            unit = learnt
        pub, valid_from, valid_to, cert_hash = unit
        if not valid_from * 1000 <= gen_ms <= valid_to * 1000:
            return Verdict(False, "signer certificate not valid at the generation time", alert, signer, where)
        try:
            pub.verify(
                encode_dss_signature(r, s), _signing_input(parsed.tbs, cert_hash), ec.ECDSA(hashes.SHA256())
            )
        except InvalidSignature:
            return Verdict(False, "bad signature", alert, signer, where)
        self.replay.add(signer, alert.sequence, gen_ms)
        return Verdict(True, "ok", alert, signer, where)
