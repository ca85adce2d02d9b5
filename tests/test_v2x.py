"""Signed emergency-vehicle alerts (issue 27 items 3–6): the canonical schema, the attack suite,
the CLI contract, the belief a car forms, and alerts over real zenoh peers on loopback.

Keys are made by the real key generator in temporary folders; the pub/sub test runs the listener
and the sender as separate ``makeway`` processes.
"""

from __future__ import annotations

import json
import math
import os
import random
import subprocess
import sys
import time
from pathlib import Path

import pytest
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.hazmat.primitives.asymmetric.utils import decode_dss_signature
from typer.testing import CliRunner, Result

from conftest import start_car_listener
from makeway.cli.main import app
from makeway.fuse.source import BeliefSource
from makeway.messages import EVRelation, VehicleState
from makeway.v2x.belief import LocalFrame, RelevanceArea, V2XBeliefSource
from makeway.v2x.message import ALERT_SIZE, Alert
from makeway.v2x.security import (
    MAX_SIGNED_SIZE,
    NOT_RELEVANT,
    SIGNED_SIZE,
    Identity,
    TrustStore,
    Verifier,
    encode_signed,
    keygen,
    load_identity,
    parse_signed,
    revoke,
    sign_alert,
)
from makeway.v2x.transport import (
    AlertPublisher,
    AlertSubscriber,
    free_loopback_port,
    open_peer,
    wait_listening,
)

runner = CliRunner()
N_P256 = int("FFFFFFFF00000000FFFFFFFFFFFFFFFFBCE6FAADA7179E84F3B9CAC2FC632551", 16)


@pytest.fixture(scope="module")
def keys(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    """A root with a good unit and a revoked unit, and an outsider under another root."""
    d = tmp_path_factory.mktemp("keys")
    good = keygen(d / "ours", "rsu")
    bad = keygen(d / "ours", "stolen")
    revoke(d / "ours" / "trust", d / "ours" / "stolen.cert")
    outsider = keygen(d / "theirs", "rsu")
    return {"dir": d, "good": good, "revoked": bad, "outsider": outsider, "trust": d / "ours" / "trust"}


def _alert(ident: Identity, seq: int, t: float, **kw: object) -> Alert:
    args: dict = dict(lat_deg=48.137, lon_deg=11.575, heading_deg=30.0, speed_mps=16.7) | kw
    return Alert.from_physical(station_id=ident.station_id, generation_time_s=t, sequence=seq, **args)


# ------------------------------------------------------------------------------------------ schema
# the DENM and 1609.2 encodings against pycrate: tests/test_v2x_denm.py


# ---------------------------------------------------------------------------------- attack suite
def _attacks(keys: dict, now: float, form: str = "certificate") -> dict[str, list[bytes]]:
    """Messages no car may act on, with the signer named as ``form`` says."""
    good: Identity = keys["good"]  # type: ignore[assignment]

    def signed(ident: Identity, seq: int, t: float) -> bytes:
        return sign_alert(_alert(ident, seq, t), ident, signer=form)

    fresh = signed(good, 100, now)
    rng = random.Random(5)
    forger = ec.generate_private_key(ec.SECP256R1())  # signs as the real unit would, wrong key
    r, s = decode_dss_signature(
        forger.sign(parse_signed(fresh).tbs + good.cert_hash, ec.ECDSA(hashes.SHA256()))
    )
    named = good.cert if form == "certificate" else good.signer
    forged = encode_signed(_alert(good, 100, now), named, r, min(s, N_P256 - s))
    r0, s0 = int.from_bytes(fresh[-64:-32], "big"), int.from_bytes(fresh[-32:], "big")
    tampered = []
    for i in range(len(fresh)):
        for mask in (0x01, 0x80, 0xFF):
            b = bytearray(fresh)
            b[i] ^= mask
            tampered.append(bytes(b))
    return {
        "forged": [forged],
        "malleated (r, n-s)": [fresh[:-32] + (N_P256 - s0).to_bytes(32, "big")],
        "zero signature": [fresh[:-64] + bytes(64), fresh[:-64] + r0.to_bytes(32, "big") + bytes(32)],
        "every byte tampered": tampered,
        "wrong signer": [signed(keys["outsider"], 1, now)],
        "revoked": [signed(keys["revoked"], 1, now)],
        "stale": [signed(good, 102, now - 60.0)],
        "future": [signed(good, 103, now + 30.0)],
        "truncated": [fresh[:n] for n in range(len(fresh))],
        "appended": [fresh + b"\x00", fresh + fresh[-66:]],
        "oversized": [fresh + bytes(MAX_SIGNED_SIZE + 1 - len(fresh)), fresh + bytes(1000)],
        "random bytes": [
            rng.randbytes(rng.choice([SIGNED_SIZE, len(fresh), rng.randrange(600)])) for _ in range(3000)
        ],
        # a real alert, signer and time with a random signature: reaches the signature check
        "random signature": [fresh[:-64] + rng.randbytes(64) for _ in range(300)],
        # the signed structure around random DENM bytes
        "random DENM": [fresh[:7] + rng.randbytes(ALERT_SIZE) + fresh[7 + ALERT_SIZE :] for _ in range(300)],
    }


@pytest.mark.parametrize("form", ["certificate", "digest"])
def test_attack_suite_rejects_every_attack_and_no_valid_alert(keys: dict, form: str) -> None:
    """Every attack is rejected with a reason (a fresh verifier for each, so none is rejected merely as
    a replay), no valid alert is rejected, nothing raises; the signer named by its certificate and by
    its digest."""
    store = TrustStore.load(keys["trust"])
    now = time.time()
    good: Identity = keys["good"]
    valid = [sign_alert(_alert(good, seq, now - seq * 0.1), good, signer=form) for seq in range(1, 51)]
    verifier = Verifier(store)
    assert [verifier.verify(m, now).reason for m in valid] == ["ok"] * 50

    expected_reason = {
        "forged": "bad signature",
        "malleated (r, n-s)": "bad signature",
        "wrong signer": "unknown signer",
        "revoked": "revoked signer",
        "stale": "stale",
        "future": "future",
        "oversized": "oversized",
    }
    for name, messages in _attacks(keys, now, form).items():
        for m in messages:
            verdict = Verifier(store).verify(m, now)
            assert not verdict.valid, name
            assert verdict.reason and not verdict.reason.startswith("replay"), (name, verdict.reason)
            if name in expected_reason:
                assert verdict.reason.startswith(expected_reason[name]), (name, verdict.reason)
            if len(m) < SIGNED_SIZE:  # cut inside the certificate form, it may still look like one
                assert verdict.reason.startswith("truncated"), (name, verdict.reason)

    replayed = Verifier(store)
    assert replayed.verify(valid[0], now).valid
    assert replayed.verify(valid[0], now + 0.5).reason.startswith("replay")
    # a unit that is not under the root at all is refused when the store loads, not trusted
    assert keys["outsider"].signer not in store.units


def test_generation_time_bounds(keys: dict) -> None:
    """Just inside the clock-skew allowance and the freshness window: accepted; just outside: not."""
    store, good, now = TrustStore.load(keys["trust"]), keys["good"], time.time()
    v = Verifier(store, max_age_s=2.0, max_future_s=0.5)
    assert v.verify(sign_alert(_alert(good, 1, now + 0.4), good), now).valid
    assert v.verify(sign_alert(_alert(good, 2, now - 1.9), good), now).valid
    assert v.verify(sign_alert(_alert(good, 3, now + 0.6), good), now).reason.startswith("future")
    assert v.verify(sign_alert(_alert(good, 4, now - 2.1), good), now).reason.startswith("stale")


def test_relevance_checks_come_before_the_signature(keys: dict) -> None:
    """A stale, future or replayed message is refused on its fields before any ECDSA work: with its
    signature broken it is still refused for being stale / future / a replay, and a broken signature
    on a fresh, new message is refused as a bad signature and leaves no trace in the replay cache."""
    store, good, now = TrustStore.load(keys["trust"]), keys["good"], time.time()

    def broken(m: bytes) -> bytes:
        return m[:-1] + bytes([m[-1] ^ 0x01])

    v = Verifier(store)
    ok = sign_alert(_alert(good, 7, now), good)
    assert v.verify(ok, now).valid
    assert v.verify(broken(ok), now).reason.startswith("replay")
    assert v.verify(broken(sign_alert(_alert(good, 8, now - 60.0), good)), now).reason.startswith("stale")
    assert v.verify(broken(sign_alert(_alert(good, 9, now + 60.0), good)), now).reason.startswith("future")
    fresh = sign_alert(_alert(good, 10, now), good)
    assert v.verify(broken(fresh), now).reason == "bad signature"
    assert v.verify(fresh, now).valid  # the forged copy did not take sequence 10


def test_verify_on_demand_checks_signatures_of_nearby_evs_only(keys: dict) -> None:
    """With a relevance area of 1 km around the car, an alert placing the EV 0.02° of latitude
    (2.2 km) north is returned unverified as not relevant — even with a broken signature, so no
    ECDSA work was spent on it — and leaves no trace in the replay cache; one 0.005° (556 m) north
    is verified. Stale and replayed messages are still refused first, whatever their distance."""
    store, good, now = TrustStore.load(keys["trust"]), keys["good"], time.time()
    area = RelevanceArea(1000.0, 48.137, 11.575)
    v = Verifier(store, relevant=area)

    def broken(m: bytes) -> bytes:
        return m[:-1] + bytes([m[-1] ^ 0x01])

    far = sign_alert(_alert(good, 20, now, lat_deg=48.157), good)
    assert area.distance_m(parse_signed(far).alert) == pytest.approx(2224.0, abs=5.0)
    assert v.verify(broken(far), now).reason == NOT_RELEVANT
    verdict = v.verify(far, now)
    assert verdict.reason == NOT_RELEVANT and not verdict.valid and verdict.alert is not None
    assert len(v.replay) == 0
    near = sign_alert(_alert(good, 21, now, lat_deg=48.142), good)
    assert v.verify(broken(near), now).reason == "bad signature"
    assert v.verify(near, now).valid
    assert v.verify(
        broken(sign_alert(_alert(good, 22, now - 60.0, lat_deg=48.157), good)), now
    ).reason.startswith("stale")
    assert v.verify(broken(near), now).reason.startswith("replay")
    # the car moves north: the far EV is now 1.1 km away, then 0.6 km → verified
    area.move_to(48.147, 11.575)
    assert v.verify(far, now).reason == NOT_RELEVANT
    area.move_to(48.152, 11.575)
    assert v.verify(far, now).valid
    # no position known: everything is relevant (the safe side)
    assert RelevanceArea(1000.0)(parse_signed(far).alert)
    for bad in (0.0, -5.0, math.inf, math.nan):
        with pytest.raises(ValueError, match="radius_m"):
            RelevanceArea(bad)
    with pytest.raises(ValueError, match="both"):
        RelevanceArea(1000.0, 48.0)
    with pytest.raises(ValueError, match="WGS-84"):
        area.move_to(91.0, 0.0)


# ------------------------------------------------------------------------------------------ belief
def test_local_frame_distances_match_the_ellipsoid() -> None:
    """0.001° of longitude on the equator is a·π/180·0.001 = 111.3195 m east; 0.001° of latitude at
    the equator is the meridian's radius of curvature a(1−e²)·π/180·0.001 = 110.574 m north."""
    f = LocalFrame(0.0, 0.0)
    east, north = f.to_local(0.0, 0.001)
    assert east == pytest.approx(111.3195, abs=1e-3) and abs(north) < 1e-3
    east, north = f.to_local(0.001, 0.0)
    assert north == pytest.approx(110.574, abs=1e-2) and abs(east) < 1e-3
    assert LocalFrame.yaw_from_heading(0.0) == pytest.approx(math.pi / 2)  # north is +y
    assert LocalFrame.yaw_from_heading(90.0) == pytest.approx(0.0)  # east is +x


def test_belief_from_alerts_puts_the_ev_behind_and_approaching() -> None:
    """An EV 200 m south of a northbound car, also northbound at 20 m/s: behind, approaching, at
    200 m; 0.5 s later the alert is moved on by 10 m; after the hold time the belief drops; an alert
    saying neither siren nor lights is no active EV."""
    lat0, lon0 = 52.52, 13.405
    frame = LocalFrame(lat0, lon0)
    dlat = 200.0 / frame.to_local(lat0 + 0.01, lon0)[1] * 0.01  # 200 m south, by the frame's own scale
    src = V2XBeliefSource(frame, hold_s=1.0)
    assert isinstance(src, BeliefSource)
    ego = VehicleState(time_s=0.0, x_m=0.0, y_m=0.0, yaw_rad=math.pi / 2, vx_mps=10.0)
    t0 = 1_764_000_000.0
    src.receive(
        Alert.from_physical(
            station_id=1,
            generation_time_s=t0,
            sequence=1,
            lat_deg=lat0 - dlat,
            lon_deg=lon0,
            heading_deg=0.0,
            speed_mps=20.0,
        )
    )
    b = src.update(t0, ego)
    assert b.detected and b.source == "v2x" and b.relation == EVRelation.BEHIND and b.approaching
    assert b.rel_x_m == pytest.approx(-200.0, abs=0.05) and abs(b.rel_y_m) < 0.05
    assert src.update(t0 + 0.5, ego).rel_x_m == pytest.approx(-190.0, abs=0.05)
    assert not src.update(t0 + 1.2, ego).detected
    quiet = V2XBeliefSource(frame)
    quiet.receive(
        Alert.from_physical(
            station_id=2,
            generation_time_s=t0,
            sequence=1,
            lat_deg=lat0,
            lon_deg=lon0,
            heading_deg=0.0,
            speed_mps=5.0,
            siren=False,
            lights=False,
        )
    )
    assert not quiet.update(t0, ego).detected


# --------------------------------------------------------------------------------------------- CLI
def test_cli_contract(tmp_path: Path) -> None:
    """keygen → alert → verify, with the exit codes: 0 all valid, 1 any rejected (in order, with a
    reason), 2 only when a file cannot be read; the replay cache carries across runs."""
    res = runner.invoke(app, ["v2x", "keygen", "--out", str(tmp_path / "k")])
    assert res.exit_code == 0, res.output
    trust = tmp_path / "k" / "trust"
    assert (trust / "root.cert").is_file() and (tmp_path / "k" / "rsu.key").is_file()
    assert oct((tmp_path / "k" / "rsu.key").stat().st_mode & 0o777) == "0o600"
    assert not any(b"PRIVATE KEY" in p.read_bytes() for p in trust.rglob("*") if p.is_file())

    def invoke_alert(name: str, *extra: str) -> Result:
        flags = ["--lat", "48.1", "--lon", "11.5", "--heading-deg", "90", "--speed-mps", "12"]
        key = ["--key", str(tmp_path / "k" / "rsu.key")]
        return runner.invoke(app, ["v2x", "alert", *key, *flags, "--out", str(tmp_path / name), *extra])

    def alert(name: str, *extra: str) -> Path:
        res = invoke_alert(name, *extra)
        assert res.exit_code == 0, res.output
        return tmp_path / name

    a, b = alert("a.msg"), alert("b.msg", "--no-siren")
    stale = alert("stale.msg", "--generation-time", str(time.time() - 3600))
    digest = alert("digest.msg", "--signer", "digest")
    assert digest.stat().st_size == SIGNED_SIZE < a.stat().st_size <= MAX_SIGNED_SIZE
    bad_form = invoke_alert("never.msg", "--signer", "name")
    assert bad_form.exit_code == 2 and "--signer" in bad_form.stderr and not (tmp_path / "never.msg").exists()
    garbage = tmp_path / "garbage.msg"
    garbage.write_bytes(b"not an alert at all")

    res = runner.invoke(app, ["v2x", "verify", str(a), str(b), str(digest), "--trust", str(trust)])
    rows = [json.loads(line) for line in res.stdout.splitlines()]
    assert res.exit_code == 0 and [r["valid"] for r in rows] == [True, True, True]
    assert [r["sequence"] for r in rows] == [1, 2, 4] and rows[1]["siren"] is False
    assert rows[0]["lat_deg"] == 48.1 and rows[0]["speed_mps"] == 12.0

    res = runner.invoke(app, ["v2x", "verify", str(a), str(stale), str(garbage), "--trust", str(trust)])
    rows = [json.loads(line) for line in res.stdout.splitlines()]
    assert res.exit_code == 1
    assert [r["file"] for r in rows] == [str(a), str(stale), str(garbage)]
    assert [r["valid"] for r in rows] == [True, False, False]
    assert rows[1]["reason"].startswith("stale") and rows[2]["reason"].startswith("truncated")

    res = runner.invoke(app, ["v2x", "verify", str(a), str(tmp_path / "missing.msg"), "--trust", str(trust)])
    assert res.exit_code == 2 and res.stdout == "" and "missing.msg" in res.stderr

    res = runner.invoke(app, ["v2x", "verify", str(a), "--trust", str(tmp_path / "nowhere")])
    assert res.exit_code == 2 and len(res.stderr.strip().splitlines()) == 1 and "nowhere" in res.stderr

    cache = tmp_path / "replay.json"
    first = runner.invoke(app, ["v2x", "verify", str(b), "--trust", str(trust), "--replay-cache", str(cache)])
    again = runner.invoke(app, ["v2x", "verify", str(b), "--trust", str(trust), "--replay-cache", str(cache)])
    assert first.exit_code == 0 and again.exit_code == 1
    assert json.loads(again.stdout)["reason"].startswith("replay")

    revoke(trust, tmp_path / "k" / "rsu.cert")
    res = runner.invoke(app, ["v2x", "verify", str(a), "--trust", str(trust)])
    assert res.exit_code == 1 and json.loads(res.stdout)["reason"] == "revoked signer"


# ---------------------------------------------------------------------------------------- pub/sub
@pytest.mark.parametrize("store", ["units", "root only"])
def test_alerts_over_zenoh_between_two_processes(tmp_path: Path, store: str) -> None:
    """A car process listens on loopback, a unit process sends a forged alert and then N signed ones:
    all arrive in order and verify, the forged one is rejected and never reaches the belief. With a
    trust store holding only the root, the car learns the unit from the certificate its alerts carry."""
    ident = keygen(tmp_path / "k", "rsu")
    if store == "root only":
        import shutil

        shutil.rmtree(tmp_path / "k" / "trust" / "units")
    outsider = keygen(tmp_path / "other", "rsu")
    now, n = time.time(), 30
    files = [tmp_path / "forged.msg"]
    files[0].write_bytes(sign_alert(_alert(outsider, 1, now), outsider))
    for seq in range(1, n + 1):
        f = tmp_path / f"{seq:03d}.msg"
        f.write_bytes(
            sign_alert(
                _alert(load_identity(tmp_path / "k" / "rsu.key"), seq, now + seq * 0.01, speed_mps=0.0), ident
            )
        )
        files.append(f)
    port = free_loopback_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1] / "src")}
    car = start_car_listener(
        tmp_path / "k" / "trust",
        "a7-km12",
        endpoint,
        count=n + 1,
        duration_s=40,
        ego_lat=48.137,
        ego_lon=11.574,
    )
    try:
        wait_listening(port, 20.0)
        sender = subprocess.run(
            [
                sys.executable,
                "-m",
                "makeway",
                "v2x",
                "send",
                *map(str, files),
                "--segment",
                "a7-km12",
                "--connect",
                endpoint,
                "--rate-hz",
                "100",
            ],
            capture_output=True,
            text=True,
            env=env,
            timeout=40,
        )
        assert sender.returncode == 0, sender.stderr
        assert json.loads(sender.stdout)["subscriber_found"] is True
        out, err = car.communicate(timeout=40)
    finally:
        car.kill()
    assert car.returncode == 0, err
    rows = [json.loads(line) for line in out.splitlines()]
    alerts, summary = rows[:-1], rows[-1]["summary"]
    assert summary == {
        "received": n + 1,
        "valid": n,
        "rejected": 1,
        "not_relevant": 0,
        "reasons": {"unknown signer": 1},
        "dropped_unread": 0,
    }
    assert alerts[0]["valid"] is False and alerts[0]["belief"]["detected"] is False
    assert [r["sequence"] for r in alerts[1:]] == list(range(1, n + 1))
    assert all(r["valid"] and r["key"] == "makeway/v2x/segment/a7-km12" for r in alerts[1:])
    last = alerts[-1]["belief"]
    assert last["detected"] and last["source"] == "v2x"
    # the EV stands 0.001° of longitude east: 111.3195 m · cos(48.137°) = 74.3 m on the sphere, to the
    # right of the northbound car (vehicle frame: x forward, y left)
    assert last["distance_m"] == pytest.approx(74.3, abs=0.5)
    assert last["rel_y_m"] == pytest.approx(-74.3, abs=0.5) and abs(last["rel_x_m"]) < 0.5


def test_belief_holds_through_ten_percent_packet_loss(keys: dict) -> None:
    """Alerts repeat at 10 Hz over real zenoh peers on loopback; 10 % of them (seeded) are dropped
    between the transport and the belief; the belief, sampled every 10 ms, never lapses.

    Why it must hold: with ``hold_s`` = 1.0 s and a 0.1 s period, a lapse needs a gap of more than
    1.0 s between delivered alerts, i.e. at least 10 consecutive drops (9 leave exactly 1.0 s, which
    the hold covers). With independent drops at p = 0.1 a given alert starts such a run with
    probability 0.1^10 = 1e-10, so over the 3,000 alerts here (5 minutes) a lapse has probability
    ≤ 3e-7 (≤ 3.6e-6 per hour of repeats). The control — the same drops with ``hold_s`` = 0.15 s,
    shorter than the 0.2 s gap a single drop leaves — must lapse once per run of consecutive drops,
    counted from the drop mask alone, which shows the sampling sees every gap."""
    ident, store = keys["good"], TrustStore.load(keys["trust"])
    n, period, p_drop = 3000, 0.1, 0.1
    t0 = float(int(time.time()))
    rng = random.Random(2710)
    drop = [rng.random() < p_drop for _ in range(n)]
    runs = sum(d and (k == 0 or not drop[k - 1]) for k, d in enumerate(drop))
    assert 0.08 < sum(drop) / n < 0.12

    port = free_loopback_port()
    car = open_peer(listen=[f"tcp/127.0.0.1:{port}"])
    unit = open_peer(connect=[f"tcp/127.0.0.1:{port}"])
    try:
        sub = AlertSubscriber(car, ["loss"], queue="fifo")  # every alert, in order
        pub = AlertPublisher(unit, "loss")
        assert pub.wait_for_subscribers(10.0)
        payloads: list[bytes] = []
        batch = 100  # publish in batches and wait for each, so zenoh's own congestion control never drops
        for start in range(0, n, batch):
            for k in range(start, start + batch):
                pub.publish(sign_alert(_alert(ident, k, t0 + k * period), ident))
            for got in sub.receive(10.0):
                payloads.append(got.payload)
                if len(payloads) == start + batch:
                    break
        pub.close()
        sub.close()
    finally:
        unit.close()
        car.close()
    assert len(payloads) == n  # the transport itself lost nothing

    frame = LocalFrame(48.137, 11.575)
    ego = VehicleState(time_s=t0, x_m=0.0, y_m=0.0, yaw_rad=0.0, vx_mps=10.0)
    verifier = Verifier(store)
    held, control = V2XBeliefSource(frame, hold_s=1.0), V2XBeliefSource(frame, hold_s=0.15)
    lapses_held, lapses_control, was_detected = 0, 0, True
    started = False
    for k, payload in enumerate(payloads):
        t_k = t0 + k * period
        v = verifier.verify(payload, t_k + 0.001)
        assert v.valid and v.alert is not None and v.alert.sequence == k, v.reason
        if not drop[k]:
            held.receive(v.alert)
            control.receive(v.alert)
            started = True
        if not started:
            continue
        for j in range(10):
            t = t_k + j * 0.01
            lapses_held += not held.update(t, ego).detected
            detected = control.update(t, ego).detected
            lapses_control += was_detected and not detected
            was_detected = detected
    assert lapses_held == 0
    leading = next(k for k, d in enumerate(drop) if not d) > 0  # drops before the first delivered alert
    assert lapses_control == runs - leading


def test_replay_cache_is_a_window_per_signer(tmp_path: Path) -> None:
    """Each signer's accepted sequences in a sliding window: duplicates and out-of-window
    sequences count as seen, late arrivals inside the window are accepted once, idle signers are
    forgotten, and the size does not grow with the number of alerts."""
    from makeway.v2x.security import REPLAY_WINDOW, ReplayCache

    a, b = b"\x01" * 8, b"\x02" * 8
    cache = ReplayCache()
    for q in range(0, 50_000, 1):  # 50,000 alerts of one unit (83 min at 10 Hz), and a second unit
        cache.add(a, q, 1_000 + q * 100)
    cache.add(b, 7, 5_000_000)
    assert cache.signers == 2 and len(cache) == REPLAY_WINDOW + 1
    assert cache.seen(a, 49_999) and cache.seen(a, 49_999 - REPLAY_WINDOW + 1)
    assert cache.seen(a, 49_999 - REPLAY_WINDOW)  # too far behind to tell: a replay
    assert not cache.seen(a, 50_000) and not cache.seen(b, 8) and not cache.seen(b"\x03" * 8, 0)
    # a late alert inside the window: new once, seen after
    cache.add(a, 50_010, 6_001_000)
    assert not cache.seen(a, 50_005)
    cache.add(a, 50_005, 6_000_500)
    assert cache.seen(a, 50_005) and not cache.seen(a, 50_006)
    # save and load keep exactly the remembered pairs
    path = tmp_path / "replay.json"
    cache.save(path)
    again = ReplayCache.load(path)
    assert len(again) == len(cache) and again.signers == 2
    for q in (50_010, 50_005, 49_999, 50_006, 50_011):
        assert again.seen(a, q) == cache.seen(a, q)
    # a signer whose newest alert is stale is forgotten: a unit that restarted its count is heard
    cache.prune(oldest_ms=5_500_000)
    assert cache.signers == 1 and not cache.seen(b, 7)
    cache.prune(oldest_ms=7_000_000)
    assert cache.signers == 0 and not cache.seen(a, 0)
    # DENM sequence numbers are 16 bits: across the wrap, 0 follows 65535 and the window goes on
    for k in range(65_530, 65_536 + 6):
        assert not cache.seen(a, k % 65_536)
        cache.add(a, k % 65_536, 8_000_000 + k)
    assert cache.seen(a, 65_535) and cache.seen(a, 3) and not cache.seen(a, 6) and len(cache) == 12
    cache.save(path)
    wrapped = ReplayCache.load(path)
    assert [wrapped.seen(a, q) for q in (65_529, 65_530, 5, 6)] == [False, True, True, False]


def test_verify_reads_no_more_than_one_alert_of_a_file(keys: dict, tmp_path: Path) -> None:
    """A 4 GiB (sparse) file is refused as oversized from its size, without being read; a valid
    alert beside it still verifies, and the exit code is 1 (a rejection, not bad input)."""
    big = tmp_path / "big.msg"
    with big.open("wb") as f:
        f.truncate(4 << 30)
    ok = tmp_path / "ok.msg"
    ok.write_bytes(sign_alert(_alert(keys["good"], 1, time.time()), keys["good"]))
    res = runner.invoke(app, ["v2x", "verify", str(big), str(ok), "--trust", str(keys["trust"])])
    assert res.exit_code == 1, res.output
    rows = [json.loads(line) for line in res.stdout.splitlines()]
    assert rows[0]["reason"] == f"oversized: {4 << 30} bytes, a signed alert has at most {MAX_SIGNED_SIZE}"
    assert not rows[0]["valid"] and rows[1]["valid"]


def test_listen_refuses_verify_on_demand_without_the_cars_position(keys: dict) -> None:
    """`makeway vehicle listen --relevance-m` needs --ego-lat/--ego-lon: one line, exit 2, before
    anything is opened."""
    res = runner.invoke(
        app, ["vehicle", "listen", "--trust", str(keys["trust"]), "--segment", "a7", "--relevance-m", "1000"]
    )
    assert res.exit_code == 2
    assert "--relevance-m needs the car's position" in res.output


def test_alert_carries_where_the_unit_stands(keys: dict, tmp_path: Path) -> None:
    """`v2x alert --unit-lat/--unit-lon/--unit-height-m` signs 1609.2's generation location (the unit),
    `verify` reads it back; without them it is the EV's position at 0 m; half a position or a height
    outside 1609.2's range is refused with exit 2 and no file."""
    key = str(keys["dir"] / "ours" / "rsu.key")
    base = ["v2x", "alert", "--key", key, "--lat", "48.137", "--lon", "11.575", "--heading-deg", "30"]
    base += ["--speed-mps", "12"]
    res = runner.invoke(
        app,
        [
            *base,
            "--out",
            str(tmp_path / "u.msg"),
            *("--unit-lat", "48.1372", "--unit-lon", "11.5741"),
            *("--unit-height-m", "521.3"),
        ],
    )
    assert res.exit_code == 0, res.output
    made = json.loads(res.stdout)
    assert (made["generation_lat_deg"], made["generation_lon_deg"]) == (48.1372, 11.5741)
    res = runner.invoke(app, [*base, "--out", str(tmp_path / "e.msg")])
    assert res.exit_code == 0, res.output
    res = runner.invoke(
        app,
        ["v2x", "verify", str(tmp_path / "u.msg"), str(tmp_path / "e.msg"), "--trust", str(keys["trust"])],
    )
    assert res.exit_code == 0, res.output
    unit, ev = (json.loads(line) for line in res.stdout.splitlines())
    assert (unit["generation_lat_deg"], unit["generation_lon_deg"], unit["generation_elevation_m"]) == (
        48.1372,
        11.5741,
        521.3,
    )
    assert (ev["generation_lat_deg"], ev["generation_lon_deg"], ev["generation_elevation_m"]) == (
        48.137,
        11.575,
        0.0,
    )
    for extra, words in (
        (["--unit-lat", "48.1"], "go together"),
        (["--unit-lat", "48.1", "--unit-lon", "11.5", "--unit-height-m", "9000"], "elevation"),
    ):
        res = runner.invoke(app, [*base, "--out", str(tmp_path / "bad.msg"), *extra])
        assert res.exit_code == 2 and words in res.output and not (tmp_path / "bad.msg").exists()


def test_a_car_holding_only_the_root_learns_units_from_their_certificates(keys: dict, tmp_path: Path) -> None:
    """A trust store with the root and no unit certificates (a unit installed after the car's store
    was made): the unit's digest-form alert is unknown, its certificate-form alert verifies and
    teaches the car the certificate, after which the digest form verifies too. A stale or replayed
    certificate-form alert is refused before its certificate is read; a certificate of another
    root, or one the root issued without the right to sign DENMs, teaches nothing."""
    import shutil

    from makeway.v2x.certificates import issue_certificate
    from makeway.v2x.security import GenerationLocation, encode_signed

    bare = tmp_path / "trust"
    shutil.copytree(keys["trust"], bare)
    shutil.rmtree(bare / "units")
    store = TrustStore.load(bare)
    assert store.units == {}
    good, now = keys["good"], time.time()
    v = Verifier(store)
    assert v.verify(sign_alert(_alert(good, 1, now), good, signer="digest"), now).reason == "unknown signer"
    stale = sign_alert(_alert(good, 2, now - 60.0), good)
    assert v.verify(stale, now).reason.startswith("stale") and v.learnt == {}  # not read
    verdict = v.verify(sign_alert(_alert(good, 3, now), good), now)
    assert verdict.valid and verdict.signer == good.signer and set(v.learnt) == {good.signer}
    assert v.verify(sign_alert(_alert(good, 4, now), good, signer="digest"), now).valid
    assert v.verify(sign_alert(_alert(good, 4, now), good), now).reason.startswith("replay")

    outsider = keys["outsider"]
    refused = v.verify(sign_alert(_alert(outsider, 1, now), outsider), now)
    assert refused.reason == "unknown signer: its certificate was not issued by this store's root"
    # a certificate from the right root without PSID 37 (an issuing certificate)
    import hashlib

    from cryptography.hazmat.primitives import serialization

    root_private = serialization.load_pem_private_key((keys["dir"] / "ours" / "root.key").read_bytes(), None)
    sub_key = ec.generate_private_key(ec.SECP256R1())
    sub = issue_certificate(
        "makeway sub-ca",
        sub_key.public_key(),
        root_private,
        issuer=store.root,
        start_s=now - 10,
        days=1,
        can_issue=True,
    )
    station = int.from_bytes(sub.hashed_id8[:4], "big")
    alert = Alert.from_physical(
        station_id=station,
        generation_time_s=now,
        sequence=1,
        lat_deg=48.1,
        lon_deg=11.5,
        heading_deg=0.0,
        speed_mps=5.0,
    )
    unsigned = encode_signed(alert, sub, 1, 1, GenerationLocation.of_event(alert))
    r, s = decode_dss_signature(
        sub_key.sign(
            hashlib.sha256(parse_signed(unsigned).tbs).digest() + sub.digest, ec.ECDSA(hashes.SHA256())
        )
    )
    msg = encode_signed(alert, sub, r, min(s, N_P256 - s))
    assert v.verify(msg, now).reason == "signer certificate may not sign DENMs (PSID 37)"
    assert set(v.learnt) == {good.signer}
