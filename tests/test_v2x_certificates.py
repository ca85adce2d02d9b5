"""IEEE 1609.2 certificates of makeway's local PKI (issue 27 item 4): what keygen writes, read back by
pycrate as 1609.2 structures; chains that do not hold are refused; an older X.509 store gets a clear
error. Keys come from the real key generator in temporary folders."""

from __future__ import annotations

import calendar
import time
from pathlib import Path

import pytest
from cryptography.hazmat.primitives.asymmetric import ec

from makeway.errors import InputError
from makeway.v2x.certificates import Certificate, issue_certificate, parse_certificate
from makeway.v2x.security import TrustStore, keygen, load_identity


def test_keygen_writes_a_1609_2_root_and_unit(tmp_path: Path) -> None:
    """The root is self-signed and may issue; the unit is issued by the root's HashedId8, may sign
    DENMs (PSID 37) for 365 days from five minutes ago; pycrate reads both as CertificateBase."""
    from pycrate_asn1dir import ITS_IEEE1609_2

    before = time.time()
    ident = keygen(tmp_path / "k", "rsu")
    root = parse_certificate((tmp_path / "k" / "trust" / "root.cert").read_bytes())
    unit = parse_certificate((tmp_path / "k" / "rsu.cert").read_bytes())
    assert (tmp_path / "k" / "trust" / "units" / "rsu.cert").read_bytes() == unit.data == ident.cert.data
    assert root.issuer is None and root.can_issue and root.issued_by(root) and root.psids == ()
    assert unit.issuer == root.hashed_id8 and unit.issued_by(root) and not unit.can_issue
    assert unit.psids == (37,) and ident.signer == unit.hashed_id8
    assert before - 302 <= unit.start_s <= before - 298
    assert unit.end_s - unit.start_s == 365 * 86400
    assert root.end_s - root.start_s == 10 * 31_556_952  # 3,650 days > 65,535 h: whole 1609.2 years
    t = ITS_IEEE1609_2.Ieee1609Dot2.CertificateBase
    t.from_oer(unit.data)
    v = t.get_val()
    assert (v["version"], v["type"], v["issuer"]) == (3, "explicit", ("sha256AndDigest", root.hashed_id8))
    assert v["toBeSigned"]["id"] == ("name", "makeway unit rsu")
    assert v["toBeSigned"]["appPermissions"] == [{"psid": 37}]
    assert v["toBeSigned"]["validityPeriod"]["duration"] == ("hours", 365 * 24)
    key = v["toBeSigned"]["verifyKeyIndicator"]
    assert key[0] == "verificationKey" and key[1][0] == "ecdsaNistP256"
    assert key[1][1][0] in ("compressed-y-0", "compressed-y-1")


def test_time32_counts_tai_seconds_since_2004() -> None:
    """2020-01-01T00:00:00Z is 504,921,600 s of UTC after 2004 plus the 5 leap seconds since:
    Time32 504,921,605; read back, the same Unix second."""
    from pycrate_asn1dir import ITS_IEEE1609_2

    unix = float(calendar.timegm((2020, 1, 1, 0, 0, 0)))
    key = ec.generate_private_key(ec.SECP256R1())
    cert = issue_certificate("t", key.public_key(), key, issuer=None, start_s=unix, days=1, can_issue=True)
    t = ITS_IEEE1609_2.Ieee1609Dot2.CertificateBase
    t.from_oer(cert.data)
    assert t.get_val()["toBeSigned"]["validityPeriod"]["start"] == 504_921_605
    assert cert.start_s == unix
    with pytest.raises(ValueError, match="2004"):
        issue_certificate("t", key.public_key(), key, issuer=None, start_s=0.0, days=1)


def _reissue(cert: Certificate, *, r: int | None = None) -> bytes:
    """``cert`` with another signature r (a broken signature), re-encoded by pycrate."""
    from pycrate_asn1dir import ITS_IEEE1609_2

    t = ITS_IEEE1609_2.Ieee1609Dot2.CertificateBase
    t.from_oer(cert.data)
    v = t.get_val()
    v["signature"][1]["rSig"] = ("x-only", (r or 1).to_bytes(32, "big"))
    t.set_val(v)
    data: bytes = t.to_oer()
    return data


def test_units_that_do_not_chain_to_the_root_are_refused(tmp_path: Path) -> None:
    """Unit certificates in units/ are kept only when this root issued them for PSID 37: one from
    another root, one with a broken signature and a root certificate dropped in as a unit are
    refused with a reason; the good unit stays."""
    keygen(tmp_path / "ours", "rsu")
    keygen(tmp_path / "theirs", "rsu")
    units = tmp_path / "ours" / "trust" / "units"
    (units / "other.cert").write_bytes((tmp_path / "theirs" / "rsu.cert").read_bytes())
    good = parse_certificate((units / "rsu.cert").read_bytes())
    (units / "broken.cert").write_bytes(_reissue(good))
    (units / "root_again.cert").write_bytes((tmp_path / "ours" / "trust" / "root.cert").read_bytes())
    store = TrustStore.load(tmp_path / "ours" / "trust")
    assert set(store.units) == {good.hashed_id8}
    reasons = {Path(p).name: why for p, why in store.refused}
    assert reasons == {
        "broken.cert": "not issued by this root",
        "other.cert": "not issued by this root",
        "root_again.cert": "not issued by this root",
    }


def test_an_x509_store_from_an_older_makeway_is_one_clear_error(tmp_path: Path) -> None:
    """A trust store or unit identity in the X.509 PEM files of earlier makeway versions is refused
    with one line naming the file and what to do (make new keys), never a parse error."""
    trust = tmp_path / "old" / "trust"
    trust.mkdir(parents=True)
    (trust / "root.pem").write_bytes(b"-----BEGIN CERTIFICATE-----\nMIIB\n-----END CERTIFICATE-----\n")
    with pytest.raises(InputError, match="keygen") as info:
        TrustStore.load(trust)
    assert info.value.path == trust / "root.pem"
    with pytest.raises(InputError, match="keygen"):
        keygen(tmp_path / "old", "rsu")
    ident = keygen(tmp_path / "new", "rsu")
    assert ident.cert.name == "makeway unit rsu"
    (tmp_path / "new" / "rsu.cert").rename(tmp_path / "new" / "rsu.crt")
    with pytest.raises(InputError, match="keygen") as info:
        load_identity(tmp_path / "new" / "rsu.key")
    assert info.value.path == tmp_path / "new" / "rsu.crt"
