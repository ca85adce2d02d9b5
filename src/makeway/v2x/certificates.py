"""IEEE 1609.2 explicit certificates for makeway's local PKI: one self-signed root per trust store
and the unit certificates it issues.

A certificate is 1609.2-2016's ``CertificateBase`` in COER (pycrate's compile of the standard's
ASN.1, ``pycrate_asn1dir.ITS_IEEE1609_2``, is the codec; certificates are read when a trust store
or a key is loaded, never per message)::

    CertificateBase { version 3, type explicit,
      issuer self sha256 (the root) | sha256AndDigest <the root's HashedId8> (a unit),
      toBeSigned { id name <"makeway local root" | "makeway unit NAME">, cracaId 000000,
                   crlSeries 0, validityPeriod { start Time32, duration hours | years },
                   appPermissions { { psid 37 } }                       (a unit: DENM only)
                   certIssuePermissions { { subjectPermissions all } }  (the root: may issue),
                   verifyKeyIndicator verificationKey ecdsaNistP256 compressed-y-0|1 <x> },
      signature ecdsaNistP256Signature { rSig x-only <r>, sSig <s> } }

The signature is 1609.2's (5.3.1): ECDSA P-256 with SHA-256 over SHA-256(toBeSigned's COER) ‖
SHA-256(the issuer's certificate), where a self-signed certificate's issuer input is the empty
string. A certificate is named by its HashedId8: the last 8 bytes of the SHA-256 of its COER.
``Time32`` counts TAI seconds since 2004-01-01 (leap seconds included); a year of ``duration`` is
31,556,952 s as 1609.2 defines it.

Not here: linkage values, regions, assurance levels, CRL distribution (the revocation list is a
file of HashedId8s, :mod:`makeway.v2x.security`), implicit (ECQV) certificates, and chains longer
than root → unit.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from typing import Any

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.hazmat.primitives.asymmetric.utils import decode_dss_signature, encode_dss_signature

from makeway.v2x.message import _PYCRATE_LOCK as _LOCK  # one lock for every pycrate type object
from makeway.v2x.message import ITS_EPOCH_UNIX_MS, LEAP_SECONDS, unix_ms_to_its_ms

__all__ = [
    "PSID_DEN",
    "Certificate",
    "MalformedCertificateError",
    "issue_certificate",
    "parse_certificate",
]

PSID_DEN = 37
"""The 1609.2 PSID (ITS-AID) of ETSI's Decentralized Environmental Notification service."""
_YEAR_S = 31_556_952  # 1609.2's year: 365.2425 days
_DURATION_S = {
    "microseconds": 1e-6,
    "milliseconds": 1e-3,
    "seconds": 1.0,
    "minutes": 60.0,
    "hours": 3600.0,
    "sixtyHours": 216_000.0,
    "years": float(_YEAR_S),
}
_N = int("FFFFFFFF00000000FFFFFFFFFFFFFFFFBCE6FAADA7179E84F3B9CAC2FC632551", 16)  # P-256 group order


class MalformedCertificateError(ValueError):
    """Bytes that are not a certificate of this profile; the message says what is wrong."""


def _types() -> Any:
    from pycrate_asn1dir import ITS_IEEE1609_2

    return ITS_IEEE1609_2.Ieee1609Dot2


def _time32(unix_s: float) -> int:
    return unix_ms_to_its_ms(math.floor(unix_s) * 1000) // 1000


def _unix_of_time32(t32: int) -> float:
    its_ms = t32 * 1000
    leaps = 0
    for i, u in enumerate(LEAP_SECONDS):  # the same instants counted in TAI since 2004
        if its_ms >= u - ITS_EPOCH_UNIX_MS + 1000 * (i + 1):
            leaps = i + 1
    return (its_ms + ITS_EPOCH_UNIX_MS - 1000 * leaps) / 1000


@dataclass(frozen=True)
class Certificate:
    """One parsed certificate: its COER ``data``, the name in its id, the issuer's HashedId8
    (``None``: self-signed), validity (Unix s), the PSIDs it may sign for, whether it may issue
    certificates, its P-256 verification key, its signature ``(r, s)`` and the COER of its
    toBeSigned part (what the issuer signed)."""

    data: bytes
    name: str
    issuer: bytes | None
    start_s: float
    end_s: float
    psids: tuple[int, ...]
    can_issue: bool
    public_key: ec.EllipticCurvePublicKey
    r: int
    s: int
    tbs: bytes

    @property
    def digest(self) -> bytes:
        """SHA-256 of the certificate's COER (1609.2's hash of a signer identifier input)."""
        return hashlib.sha256(self.data).digest()

    @property
    def hashed_id8(self) -> bytes:
        """The certificate's HashedId8: the last 8 bytes of :attr:`digest`."""
        return self.digest[-8:]

    def issued_by(self, issuer: Certificate) -> bool:
        """Whether ``issuer`` issued this certificate: named as its issuer, allowed to issue, and
        its key verifies the signature (a self-signed certificate: ``issuer`` is itself)."""
        if self.issuer is None:
            if issuer.data != self.data:
                return False
            chained = b""
        else:
            if self.issuer != issuer.hashed_id8 or not issuer.can_issue:
                return False
            chained = issuer.data
        try:
            issuer.public_key.verify(
                encode_dss_signature(self.r, self.s),
                hashlib.sha256(self.tbs).digest() + hashlib.sha256(chained).digest(),
                ec.ECDSA(hashes.SHA256()),
            )
        except InvalidSignature:
            return False
        return True


def issue_certificate(
    name: str,
    public_key: ec.EllipticCurvePublicKey,
    signing_key: ec.EllipticCurvePrivateKey,
    *,
    issuer: Certificate | None,
    start_s: float,
    days: int,
    can_issue: bool = False,
) -> Certificate:
    """A certificate for ``public_key`` named ``name``, valid ``days`` from ``start_s`` (Unix s),
    signed by ``signing_key``: the key of ``issuer``, or ``public_key``'s own for a self-signed root
    (``issuer=None``). A unit (``can_issue=False``) may sign DENMs (PSID 37); a root may issue."""
    if not start_s >= ITS_EPOCH_UNIX_MS / 1000:
        raise ValueError(f"a 1609.2 certificate starts in 2004 or later, not at Unix {start_s!r} s")
    if not 0 < days <= 365 * 60:
        raise ValueError(f"days must be 1 … {365 * 60}, not {days}")
    if len(name.encode("utf-8")) > 255:
        raise ValueError("a certificate name has at most 255 bytes")
    hours = days * 24
    duration = ("hours", hours) if hours <= 0xFFFF else ("years", math.ceil(days * 86400 / _YEAR_S))
    point = public_key.public_bytes(serialization.Encoding.X962, serialization.PublicFormat.CompressedPoint)
    tbs: dict[str, Any] = {
        "id": ("name", name),
        "cracaId": b"\x00\x00\x00",
        "crlSeries": 0,
        "validityPeriod": {"start": _time32(start_s), "duration": duration},
        "verifyKeyIndicator": (
            "verificationKey",
            ("ecdsaNistP256", ("compressed-y-0" if point[0] == 2 else "compressed-y-1", point[1:])),
        ),
    }
    if can_issue:
        tbs["certIssuePermissions"] = [{"subjectPermissions": ("all", 0)}]
    else:
        tbs["appPermissions"] = [{"psid": PSID_DEN}]
    with _LOCK:
        t = _types()
        t.ToBeSignedCertificate.set_val(tbs)
        tbs_bytes: bytes = t.ToBeSignedCertificate.to_oer()
    chained = b"" if issuer is None else issuer.data
    der = signing_key.sign(
        hashlib.sha256(tbs_bytes).digest() + hashlib.sha256(chained).digest(), ec.ECDSA(hashes.SHA256())
    )
    r, s = decode_dss_signature(der)
    value = {
        "version": 3,
        "type": "explicit",
        "issuer": ("self", "sha256") if issuer is None else ("sha256AndDigest", issuer.hashed_id8),
        "toBeSigned": tbs,
        "signature": (
            "ecdsaNistP256Signature",
            {"rSig": ("x-only", r.to_bytes(32, "big")), "sSig": min(s, _N - s).to_bytes(32, "big")},
        ),
    }
    with _LOCK:
        t = _types()
        t.CertificateBase.set_val(value)
        data: bytes = t.CertificateBase.to_oer()
    return parse_certificate(data)


def parse_certificate(data: bytes) -> Certificate:
    """Read one certificate of this profile (module docstring); :class:`MalformedCertificateError`
    for anything else: not COER of a CertificateBase, a non-canonical encoding, another version,
    type, issuer kind, key or signature algorithm, a point not on P-256. The signature is not
    checked here (:meth:`Certificate.issued_by`)."""
    data = bytes(data)
    try:
        with _LOCK:
            t = _types()
            t.CertificateBase.from_oer(data)
            v = t.CertificateBase.get_val()
            again = t.CertificateBase.to_oer()
            t.ToBeSignedCertificate.set_val(v["toBeSigned"])
            tbs_bytes: bytes = t.ToBeSignedCertificate.to_oer()
    except Exception as exc:  # pycrate raises several unrelated types on bad input
        raise MalformedCertificateError(f"not a 1609.2 certificate ({type(exc).__name__})") from None
    if again != data:
        raise MalformedCertificateError("not canonical COER: the bytes differ from their re-encoding")
    try:
        tbs = v["toBeSigned"]
        issuer_kind, issuer_value = v["issuer"]
        id_kind, name = tbs["id"]
        key_kind, (curve, (point_kind, x)) = tbs["verifyKeyIndicator"]
        sig_kind, sig = v["signature"]
        r_kind, r = sig["rSig"]
        dur_kind, dur = tbs["validityPeriod"]["duration"]
        start = tbs["validityPeriod"]["start"]
        psids = tuple(int(p["psid"]) for p in tbs.get("appPermissions", []))
        can_issue = any(g["subjectPermissions"][0] == "all" for g in tbs.get("certIssuePermissions", []))
        ok = (
            v["version"] == 3
            and v["type"] == "explicit"
            and (issuer_kind, issuer_value) != ("self", "sha384")
            and issuer_kind in ("self", "sha256AndDigest")
            and id_kind == "name"
            and key_kind == "verificationKey"
            and curve == "ecdsaNistP256"
            and point_kind in ("compressed-y-0", "compressed-y-1")
            and sig_kind == "ecdsaNistP256Signature"
            and r_kind == "x-only"
        )
    except (KeyError, TypeError, ValueError):
        ok = False
    if not ok:
        raise MalformedCertificateError("not a makeway 1609.2 certificate (explicit, P-256, named)")
    try:
        key = ec.EllipticCurvePublicKey.from_encoded_point(
            ec.SECP256R1(), bytes([2 if point_kind == "compressed-y-0" else 3]) + bytes(x)
        )
    except ValueError:
        raise MalformedCertificateError("its verification key is not a point of P-256") from None
    start_s = _unix_of_time32(int(start))
    return Certificate(
        data=data,
        name=str(name),
        issuer=None if issuer_kind == "self" else bytes(issuer_value),
        start_s=start_s,
        end_s=start_s + _DURATION_S[dur_kind] * int(dur),
        psids=psids,
        can_issue=can_issue,
        public_key=key,
        r=int.from_bytes(r, "big"),
        s=int.from_bytes(sig["sSig"], "big"),
        tbs=tbs_bytes,
    )
