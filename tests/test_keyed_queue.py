"""Issue 29, item 3, for the car's V2X listener: the per-sender latest-wins queue
(:class:`makeway.queues.KeyedLatestQueue`) keeps each key's newest items, serves the keys in turn,
stays bounded and closes like :class:`~makeway.queues.LatestQueue`; through the real zenoh
subscriber, a flood of forged alerts claiming one unit's id cannot displace another unit's alert
(it does displace the claimed unit's, the residual risk the subscriber documents)."""

from __future__ import annotations

import dataclasses
import hashlib
import threading
import time

import pytest
import zenoh
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.hazmat.primitives.asymmetric.utils import decode_dss_signature

from makeway.queues import KeyedLatestQueue, QueueClosedError
from makeway.v2x.message import Alert
from makeway.v2x.security import (
    SIGNED_SIZE,
    STATION_ID_OFFSET,
    Identity,
    TrustStore,
    Verifier,
    encode_signed,
    keygen,
    parse_signed,
    sign_alert,
)
from makeway.v2x.transport import (
    AlertPublisher,
    AlertSubscriber,
    free_loopback_port,
    open_peer,
    sender_key,
)


def test_newest_per_key_wins() -> None:
    q: KeyedLatestQueue[str, int] = KeyedLatestQueue(max_keys=8, per_key=1)
    assert [q.put("a", k) for k in range(5)] == [0, 1, 1, 1, 1]
    assert len(q) == 1 and q.superseded == 4 and q.dropped == 4 and q.put_count == 5
    assert q.get() == 4  # the newest of the key
    two: KeyedLatestQueue[str, int] = KeyedLatestQueue(max_keys=8, per_key=2)
    for k in range(5):
        two.put("a", k)
    assert len(two) == 2 and two.dropped == 3
    assert [two.get(), two.get()] == [3, 4]  # the two newest, oldest first


def test_keys_served_in_turn_oldest_first() -> None:
    """The key waiting longest is served first; a key with items left goes behind the others, so a
    busy key gets one turn per round."""
    q: KeyedLatestQueue[str, str] = KeyedLatestQueue(max_keys=8, per_key=2)
    for key, item in [("A", "A1"), ("B", "B1"), ("A", "A2"), ("C", "C1"), ("A", "A3")]:
        q.put(key, item)
    assert q.keys_waiting == 3 and q.dropped == 1  # A1 superseded by A2, A3
    assert [q.get() for _ in range(4)] == ["A2", "B1", "C1", "A3"]
    assert len(q) == 0 and q.keys_waiting == 0


def test_key_bound_drops_the_key_waiting_longest() -> None:
    q: KeyedLatestQueue[str, str] = KeyedLatestQueue(max_keys=2, per_key=2)
    q.put("A", "A1")
    q.put("A", "A2")
    q.put("B", "B1")
    assert q.put("C", "C1") == 2  # A and its two items go
    assert q.evicted == 2 and q.superseded == 0 and len(q) == 2 and q.keys_waiting == 2
    assert [q.get(), q.get()] == ["B1", "C1"]
    with pytest.raises(ValueError, match="max_keys"):
        KeyedLatestQueue(0)
    with pytest.raises(ValueError, match="per_key"):
        KeyedLatestQueue(4, per_key=0)


def test_close_drains_then_raises() -> None:
    q: KeyedLatestQueue[str, int] = KeyedLatestQueue(4)
    with pytest.raises(TimeoutError):
        q.get(timeout=0.01)
    q.put("a", 7)
    q.close()
    assert q.closed
    assert q.get() == 7  # a closed queue is drained first
    with pytest.raises(QueueClosedError):
        q.get()
    with pytest.raises(QueueClosedError):
        q.put("a", 8)


def test_close_wakes_a_waiting_getter() -> None:
    q: KeyedLatestQueue[str, int] = KeyedLatestQueue(4)
    woke: list[str] = []

    def wait() -> None:
        try:
            q.get()
        except QueueClosedError:
            woke.append("closed")

    t = threading.Thread(target=wait)
    t.start()
    time.sleep(0.05)
    q.close()
    t.join(2.0)
    assert woke == ["closed"]


def test_two_producers_one_consumer() -> None:
    """Two producer threads on 3 keys each, 20,000 items, a consumer that cannot keep up: the queue
    never holds more than its bound, each key's items come out in order, each key's newest item is
    delivered, and every item put is either delivered or counted as dropped."""
    q: KeyedLatestQueue[str, tuple[str, int]] = KeyedLatestQueue(max_keys=6, per_key=2)
    n = 20_000
    high = [0]

    def produce(keys: list[str]) -> None:
        for k in range(n):
            key = keys[k % len(keys)]
            q.put(key, (key, k))
            high[0] = max(high[0], len(q))

    producers = [
        threading.Thread(target=produce, args=(keys,)) for keys in (["a", "b", "c"], ["d", "e", "f"])
    ]
    for t in producers:
        t.start()
    got: list[tuple[str, int]] = []

    def close_when_done() -> None:
        for t in producers:
            t.join()
        q.close()

    closer = threading.Thread(target=close_when_done)
    closer.start()
    while True:
        try:
            got.append(q.get(timeout=10.0))
        except QueueClosedError:
            break
        if len(got) % 10 == 0:
            time.sleep(0.0005)  # slower than the producers
    closer.join()
    assert high[0] <= 12
    assert len(got) + q.dropped == q.put_count == 2 * n
    assert q.dropped > 0 and q.evicted == 0  # 6 keys never exceed max_keys
    by_key: dict[str, list[int]] = {}
    for key, k in got:
        by_key.setdefault(key, []).append(k)
    assert sorted(by_key) == list("abcdef")
    for key, seq in by_key.items():
        assert seq == sorted(seq) and len(set(seq)) == len(seq)
        assert seq[-1] == max(k for k in range(n) if k % 3 == "abcdef".index(key) % 3)  # newest kept


# ------------------------------------------------------------------ forged floods over real zenoh
def _alert(ident: Identity, seq: int, t: float) -> Alert:
    return Alert.from_physical(
        station_id=ident.station_id,
        generation_time_s=t,
        sequence=seq,
        lat_deg=48.137,
        lon_deg=11.575,
        heading_deg=90.0,
        speed_mps=13.0,
    )


def _forged(claimed: Identity, attacker: Identity, seq: int, t: float) -> bytes:
    """An alert claiming ``claimed``'s station and signer id, signed with the attacker's own key."""
    alert = _alert(claimed, seq, t)
    tbs = parse_signed(encode_signed(alert, claimed.signer, 1, 1)).tbs  # what the claimed unit signs
    signing_input = hashlib.sha256(tbs).digest() + claimed.cert_hash  # IEEE 1609.2's ECDSA input
    r, s = decode_dss_signature(attacker.key.sign(signing_input, ec.ECDSA(hashes.SHA256())))
    n = int("FFFFFFFF00000000FFFFFFFFFFFFFFFFBCE6FAADA7179E84F3B9CAC2FC632551", 16)
    return encode_signed(alert, claimed.signer, r, min(s, n - s))


@pytest.fixture(scope="module")
def units(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    root = tmp_path_factory.mktemp("keys")
    a, b = keygen(root, "unit_a"), keygen(root, "unit_b")
    evil = keygen(tmp_path_factory.mktemp("evil"), "mallory")  # its own root: not trusted
    return {"a": a, "b": b, "evil": evil, "store": TrustStore.load(root / "trust")}


def test_sender_key_reads_the_claimed_signer(units: dict[str, object]) -> None:
    a, evil = units["a"], units["evil"]
    assert isinstance(a, Identity) and isinstance(evil, Identity)
    t = time.time()
    genuine = sign_alert(_alert(a, 1, t), a)  # the signer's certificate inside
    assert len(genuine) > SIGNED_SIZE
    assert sender_key("k", genuine) == ("k", a.signer)
    assert len(digest := sign_alert(_alert(a, 1, t), a, signer="digest")) == SIGNED_SIZE
    assert sender_key("k", digest) == ("k", a.signer)
    assert sender_key("k", _forged(a, evil, 2, t)) == ("k", a.signer)  # claims are all it can read
    assert sender_key("k", genuine, known_signers={a.signer}) == ("k", a.signer)
    assert sender_key("k", sign_alert(_alert(evil, 1, t), evil), known_signers={a.signer}) == ("k", "unknown")
    assert sender_key("k", genuine[:-1]) == ("k", "malformed")
    assert sender_key("k", b"x" * SIGNED_SIZE) == ("k", "malformed")
    wrong_station = genuine[:STATION_ID_OFFSET] + bytes(4) + genuine[STATION_ID_OFFSET + 4 :]
    assert sender_key("k", wrong_station) == ("k", "malformed")


def test_publisher_waits_rather_than_drops_its_own_alerts() -> None:
    """A unit's publisher blocks on a full transmit queue (zenoh would drop the put by default), so
    the floods below lose nothing on the way even on a busy machine; a flooding sender can opt in
    to dropping."""
    session = open_peer()
    try:
        own = AlertPublisher(session, "own")
        flooder = AlertPublisher(session, "flood", drop_when_congested=True)
        assert own.congestion_control == zenoh.CongestionControl.BLOCK
        assert flooder.congestion_control == zenoh.CongestionControl.DROP
        own.close()
        flooder.close()
    finally:
        session.close()


def _flood(
    units: dict[str, object], payloads: list[bytes], **queue: object
) -> tuple[list[tuple[bytes, bool, str]], int]:
    """Publish ``payloads`` in order over zenoh on loopback while nobody reads, then drain the
    subscriber and verify each: ``([(payload, valid, reason)], dropped)``."""
    store = units["store"]
    assert isinstance(store, TrustStore)
    port = free_loopback_port()
    car = open_peer(listen=[f"tcp/127.0.0.1:{port}"])
    unit = open_peer(connect=[f"tcp/127.0.0.1:{port}"])
    try:
        sub = AlertSubscriber(car, ["flood"], **queue)  # type: ignore[arg-type]
        pub = AlertPublisher(unit, "flood")
        assert pub.wait_for_subscribers(10.0)
        for p in payloads:
            pub.publish(p)
        deadline = time.monotonic() + 10.0
        while sub.dropped + sub.pending < len(payloads) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert sub.dropped + sub.pending == len(payloads)  # all arrived before anyone read
        verifier = Verifier(store)
        out = []
        for got in sub.receive(0.3):
            v = verifier.verify(got.payload, time.time())
            out.append((got.payload, v.valid, v.reason))
        pub.close()
        sub.close()
    finally:
        unit.close()
        car.close()
    return out, sub.dropped


def test_forged_flood_cannot_displace_another_units_alert(units: dict[str, object]) -> None:
    """Unit B's genuine alert, then unit A's, then 400 forged alerts claiming A's id and 400 signed
    by made-up units, all waiting at once. Per-sender queue: B's alert is verified, and so is A's
    second genuine alert that came one forged payload before the end (fewer than ``per_sender``
    after it); every forged one served is rejected; the made-up signers share one key. A FIFO of
    the same size loses both genuine alerts to the flood's volume."""
    a, b, evil, store = units["a"], units["b"], units["evil"], units["store"]
    assert isinstance(a, Identity) and isinstance(b, Identity) and isinstance(evil, Identity)
    assert isinstance(store, TrustStore)
    t = time.time()
    genuine_b = sign_alert(_alert(b, 1, t), b)
    genuine_a1 = sign_alert(_alert(a, 1, t), a)
    genuine_a2 = sign_alert(_alert(a, 2, t + 0.1), a)
    forged_a = [_forged(a, evil, 100 + k, t) for k in range(400)]
    made_up = [sign_alert(_alert(evil, k, t), evil) for k in range(400)]
    flood = [p for pair in zip(forged_a, made_up, strict=True) for p in pair]
    payloads = [genuine_b, genuine_a1, *flood, genuine_a2, _forged(a, evil, 999, t)]
    known = set(store.units) - store.revoked

    served, dropped = _flood(units, payloads, max_pending=64, known_signers=known)
    valid = [p for p, ok, _ in served if ok]
    assert valid == [genuine_b, genuine_a2]
    assert len(served) == 1 + 2 + 2 == len(payloads) - dropped  # keys B, A and "unknown"
    assert all(r.startswith(("bad signature", "unknown signer")) for _, ok, r in served if not ok)
    assert genuine_a1 not in {p for p, _, _ in served}  # the residual risk: a flood on A hides A

    served, _ = _flood(units, payloads, max_pending=64, queue="fifo")
    assert [p for p, ok, _ in served if ok] == [genuine_a2]  # B's alert pushed out by the flood
    assert len(served) == 64

    served, _ = _flood(units, payloads, max_pending=64, per_sender=1, known_signers=known)
    assert [p for p, ok, _ in served if ok] == [genuine_b]  # one slot: the last forged one hides A's


def test_made_up_signers_do_not_evict_real_units(units: dict[str, object]) -> None:
    """Without the trust store's signers each made-up id is a key of its own and, past the bound,
    pushes out the real unit's key; with them, they share one key and the real unit stays."""
    b, evil, store = units["b"], units["evil"], units["store"]
    assert isinstance(b, Identity) and isinstance(evil, Identity) and isinstance(store, TrustStore)
    t = time.time()
    genuine_b = sign_alert(_alert(b, 5, t), b)
    junk = []
    for k in range(40):  # made-up signer ids, station id consistent with each
        fake = bytes([k]) * 8
        alert = dataclasses.replace(_alert(evil, k, t), station_id=int.from_bytes(fake[:4], "big"))
        junk.append(encode_signed(alert, fake, 0, 0))
    payloads = [genuine_b, *junk]
    served, _ = _flood(units, payloads, max_pending=16)  # 8 keys
    assert genuine_b not in {p for p, _, _ in served}
    served, _ = _flood(units, payloads, max_pending=16, known_signers=set(store.units))
    assert [p for p, ok, _ in served if ok] == [genuine_b]
    assert len(served) == 3  # B, then the two newest made-up ones (one shared key)
