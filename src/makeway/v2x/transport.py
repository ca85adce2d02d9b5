"""Alerts over a real network: eclipse-zenoh publish/subscribe, peer to peer (no broker).

Keys are by road segment, ``makeway/v2x/segment/<id>``; a roadside unit publishes on the segment it
watches, a car subscribes to the segments along its route. Each payload is one signed alert
(:mod:`makeway.v2x.security`); zenoh only carries bytes, the car verifies every one.

:func:`peer_config` makes a peer with explicit endpoints and scouting off (no multicast, no gossip),
so it talks to exactly the peers named: one side listens (``tcp/127.0.0.1:PORT``), the others
connect to it. Only loopback endpoints are accepted here.
"""

from __future__ import annotations

import hashlib
import json
import re
import socket
import time
from collections.abc import Callable, Collection, Hashable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import zenoh

from makeway.queues import KeyedLatestQueue, LatestQueue
from makeway.v2x.security import MAX_SIGNED_SIZE, SIGNED_SIZE, SIGNER_OFFSET, STATION_ID_OFFSET

__all__ = [
    "KEY_PREFIX",
    "AlertPublisher",
    "AlertSubscriber",
    "Received",
    "direct_callback",
    "free_loopback_port",
    "open_peer",
    "peer_config",
    "segment_key",
    "sender_key",
    "wait_listening",
]

KEY_PREFIX = "makeway/v2x/segment"
_SEGMENT = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
_LOOPBACK = re.compile(r"^(tcp|udp)/(127\.\d+\.\d+\.\d+|localhost|\[::1\]):\d{1,5}$")


def segment_key(segment: str) -> str:
    """The zenoh key of a road segment (letters, digits, ``-``, ``_``; 1–64 characters)."""
    if not _SEGMENT.match(segment):
        raise ValueError(f"a segment id is 1-64 letters, digits, '-' or '_', not {segment!r}")
    return f"{KEY_PREFIX}/{segment}"


def peer_config(listen: Sequence[str] = (), connect: Sequence[str] = ()) -> zenoh.Config:
    """A zenoh peer on loopback: listens and connects exactly where told, never scouts."""
    for ep in (*listen, *connect):
        if not _LOOPBACK.match(ep):
            raise ValueError(f"endpoint {ep!r} is not a loopback endpoint like tcp/127.0.0.1:7447")
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    return conf


def free_loopback_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now (the OS picks it), for an endpoint
    like ``tcp/127.0.0.1:PORT``."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_listening(port: int, timeout_s: float) -> None:
    """Return once something accepts TCP connections on 127.0.0.1:``port``; raise ``TimeoutError``
    after ``timeout_s`` seconds (wall clock) otherwise."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.05)
    raise TimeoutError(f"nothing listens on 127.0.0.1:{port} after {timeout_s:g} s")


def open_peer(listen: Sequence[str] = (), connect: Sequence[str] = ()) -> zenoh.Session:
    """Open a session with :func:`peer_config`; close it with ``session.close()``."""
    return zenoh.open(peer_config(listen, connect))


class AlertPublisher:
    """Publishes signed alerts on one segment.

    By default a put waits when zenoh's transmit queue is full (``CongestionControl.BLOCK``): an
    alert is a few hundred bytes a few times a second, and a unit must never lose its own alert to
    a local queue. ``drop_when_congested=True`` restores zenoh's default (drop the put), which the
    overload benchmarks use to play a flooding sender that does not care what arrives."""

    def __init__(self, session: zenoh.Session, segment: str, drop_when_congested: bool = False) -> None:
        self.key = segment_key(segment)
        congestion = zenoh.CongestionControl.DROP if drop_when_congested else zenoh.CongestionControl.BLOCK
        self._pub = session.declare_publisher(self.key, congestion_control=congestion)

    @property
    def congestion_control(self) -> zenoh.CongestionControl:
        """What a put does when zenoh's transmit queue is full: ``BLOCK`` (wait) or ``DROP``."""
        return self._pub.congestion_control

    def wait_for_subscribers(self, timeout_s: float = 10.0) -> bool:
        """Wait until a subscriber matches this key (True) or ``timeout_s`` passes (False)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            status = self._pub.matching_status  # a MatchingStatus at run time (the stub says bool)
            if bool(getattr(status, "matching", status)):
                return True
            time.sleep(0.01)
        return False

    def publish(self, payload: bytes) -> None:
        self._pub.put(payload)

    def close(self) -> None:
        self._pub.undeclare()


@dataclass(frozen=True, slots=True)
class Received:
    """One payload: the key it came on and the receive time (Unix s, the car's clock)."""

    key: str
    payload: bytes
    time_s: float


def sender_key(key: str, payload: bytes, known_signers: Collection[bytes] | None = None) -> Hashable:
    """The queue key of a payload received on zenoh key ``key``, read from the envelope before any
    check of the signature: ``(key, signer HashedId8)``, where the signer is the one the payload
    *claims*. Payloads that cannot be a signed alert (wrong length or first byte, a station id that
    is not the claimed signer's) share the key ``(key, "malformed")``; when ``known_signers`` is
    given, a claimed signer outside it (unknown or revoked: the verifier will reject it) shares
    ``(key, "unknown")``, so made-up signer ids cannot create keys without end."""
    n = len(payload)
    if not SIGNED_SIZE <= n <= MAX_SIGNED_SIZE or payload[0] != 3:  # 1609.2 protocol version 3
        return (key, "malformed")
    if n == SIGNED_SIZE:  # the digest form
        signer = bytes(payload[SIGNER_OFFSET : SIGNER_OFFSET + 8])
    else:  # the certificate form: the certificate's HashedId8
        signer = hashlib.sha256(payload[SIGNER_OFFSET + 2 : n - 66]).digest()[-8:]
    if payload[STATION_ID_OFFSET : STATION_ID_OFFSET + 4] != signer[:4]:  # the station must be the signer's
        return (key, "malformed")
    if known_signers is not None and signer not in known_signers:
        return (key, "unknown")
    return (key, signer)


def direct_callback(fn: Callable[[zenoh.Sample], Any]) -> Any:
    """A zenoh subscriber handler that runs ``fn`` on zenoh's own receive thread.

    Given a plain function, zenoh-python starts a Python thread per subscriber and hands each sample
    over to it. A car subscribed to 20 segments then has 20 such threads, and on a host running
    many cars they contend for the interpreter. Called directly, a sample costs about half the CPU
    and no thread is added (figures: docs/results.md, "V2X alerts", load). ``fn`` must therefore be
    short and never block (here: stamp, copy the bytes, queue). Falls back to the plain function
    where the installed zenoh has no ``indirect`` option."""
    try:
        return zenoh.handlers.Callback(fn, indirect=False)
    except (AttributeError, TypeError):  # an eclipse-zenoh without the (unstable) option
        return fn


class AlertSubscriber:
    """Receives payloads on the given segments (zenoh's receive thread stamps the receive time and
    queues them; :meth:`receive` hands them out), through a bounded queue that never blocks zenoh.

    ``queue="per_sender"`` (the default, what a car runs): a
    :class:`~makeway.queues.KeyedLatestQueue` keyed by :func:`sender_key` (segment and the signer
    the payload claims) that keeps each sender's ``per_sender`` newest payloads and serves the
    senders in turn. An alert is a state repeated at 10 Hz, so an older one from the same sender is
    stale once a newer one waits: under overload the listener verifies every sender's newest alerts
    and its delay stays about one round of the senders waiting, not a backlog. At most
    ``max_pending`` payloads wait (``max_pending // per_sender`` senders; a new sender arriving at a
    full queue drops the one waiting longest).

    ``queue="fifo"``: a :class:`~makeway.queues.LatestQueue` of ``max_pending`` payloads in arrival
    order, dropping the oldest when full; for a consumer that must see every payload of a burst
    (a loss count, a simulation that replays every alert it sent).

    Forgery and flooding (per-sender queue). The key is read before the signature is checked, so
    anyone who can publish on a segment can claim a real unit's signer id (it is in every alert
    that unit sends). What that attacker can and cannot do:

    * it cannot delay or displace another sender's alerts: each key gets one turn per round, and
      a key's flood only pushes out that key's own older payloads;
    * made-up signer ids do not multiply keys when ``known_signers`` is given (the trust store's
      units, minus revoked ones): they all share one key per segment; nor do malformed payloads;
    * it **can** hide the claimed unit's genuine alerts: a genuine alert is verified only if fewer
      than ``per_sender`` payloads claiming the same signer arrive after it before the key's turn.
      With ``per_sender = 2`` that means two forged payloads per turn of that key (a turn comes
      about every (senders waiting) × (verification time), ~0.1 ms per sender here); a flood of
      tens of thousands per second against one unit denies that unit's alerts while it lasts. The
      forged payloads themselves are still all rejected by the verifier, and a FIFO queue under
      the same flood would lose the genuine alert too (pushed out by the flood's volume), along
      with every other unit's. Telling the genuine alert from the forged ones takes the signature
      check, which is exactly the work that is overloaded.
    """

    def __init__(
        self,
        session: zenoh.Session,
        segments: Sequence[str],
        max_pending: int = 1024,
        *,
        queue: Literal["per_sender", "fifo"] = "per_sender",
        per_sender: int = 2,
        known_signers: Collection[bytes] | None = None,
    ) -> None:
        if queue not in ("per_sender", "fifo"):
            raise ValueError(f"queue is 'per_sender' or 'fifo', not {queue!r}")
        self.queue_policy = queue
        self._known = None if known_signers is None else {bytes(s) for s in known_signers}
        self._fifo: LatestQueue[Received] | None = None
        self._keyed: KeyedLatestQueue[Hashable, Received] | None = None
        if queue == "fifo":
            self._fifo = LatestQueue(max_pending)
        else:
            self._keyed = KeyedLatestQueue(max(1, max_pending // per_sender), per_sender)
        self._subs = [
            session.declare_subscriber(segment_key(s), direct_callback(self._on_sample)) for s in segments
        ]

    def add_known_signer(self, signer: bytes) -> None:
        """Give ``signer`` (a HashedId8) a queue key of its own from now on: for a unit the car
        learnt from a verified alert that carried its certificate (it was queued under the shared
        ``"unknown"`` key until then). No effect without ``known_signers``."""
        if self._known is not None:
            self._known.add(bytes(signer))

    def _on_sample(self, sample: zenoh.Sample) -> None:
        got = Received(str(sample.key_expr), sample.payload.to_bytes(), time.time())
        if self._keyed is not None:
            self._keyed.put(sender_key(got.key, got.payload, self._known), got)
        else:
            assert self._fifo is not None
            self._fifo.put(got)

    def _get(self, timeout: float) -> Received:
        if self._keyed is not None:
            return self._keyed.get(timeout=timeout)
        assert self._fifo is not None
        return self._fifo.get(timeout=timeout)

    def receive(self, timeout_s: float) -> Iterator[Received]:
        """Yield payloads as they are served until ``timeout_s`` (s) passes (``inf``: forever)."""
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return
            try:
                yield self._get(min(left, 0.5))
            except TimeoutError:
                continue

    @property
    def dropped(self) -> int:
        """Payloads dropped unread (pushed out by newer ones, see the class)."""
        q = self._keyed if self._keyed is not None else self._fifo
        assert q is not None
        return q.dropped

    @property
    def pending(self) -> int:
        """Payloads received and not yet handed out."""
        q = self._keyed if self._keyed is not None else self._fifo
        assert q is not None
        return len(q)

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()
