"""Alerts over a real network: eclipse-zenoh publish/subscribe, peer to peer (no broker).

Keys are by road segment, ``makeway/v2x/segment/<id>``; a roadside unit publishes on the segment it
watches, a car subscribes to the segments along its route. Each payload is one signed alert
(:mod:`makeway.v2x.security`); zenoh only carries bytes, the car verifies every one.

:func:`peer_config` makes a peer with explicit endpoints and scouting off (no multicast, no gossip),
so it talks to exactly the peers named: one side listens (``tcp/127.0.0.1:PORT``), the others
connect to it. Only loopback endpoints are accepted here.
"""

from __future__ import annotations

import json
import re
import socket
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import zenoh

from makeway.queues import LatestQueue

__all__ = [
    "KEY_PREFIX",
    "AlertPublisher",
    "AlertSubscriber",
    "Received",
    "free_loopback_port",
    "open_peer",
    "peer_config",
    "segment_key",
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
    """Publishes signed alerts on one segment."""

    def __init__(self, session: zenoh.Session, segment: str) -> None:
        self.key = segment_key(segment)
        self._pub = session.declare_publisher(self.key)

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


class AlertSubscriber:
    """Receives payloads on the given segments, in arrival order (zenoh's callback thread stamps the
    receive time and queues them; :meth:`receive` hands them out).

    The queue holds at most ``max_pending`` payloads (:class:`~makeway.queues.LatestQueue`): when
    alerts arrive faster than the listener verifies them, the oldest waiting ones are dropped, never
    the newest, and memory stays bounded (:attr:`dropped` counts them)."""

    def __init__(self, session: zenoh.Session, segments: Sequence[str], max_pending: int = 1024) -> None:
        self._queue: LatestQueue[Received] = LatestQueue(max_pending)
        self._subs = [session.declare_subscriber(segment_key(s), self._on_sample) for s in segments]

    def _on_sample(self, sample: zenoh.Sample) -> None:
        self._queue.put(Received(str(sample.key_expr), sample.payload.to_bytes(), time.time()))

    def receive(self, timeout_s: float) -> Iterator[Received]:
        """Yield payloads as they arrive until ``timeout_s`` (s) passes (``inf``: forever)."""
        deadline = time.monotonic() + timeout_s
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return
            try:
                yield self._queue.get(timeout=min(left, 0.5))
            except TimeoutError:
                continue

    @property
    def dropped(self) -> int:
        """Payloads dropped unread because the queue was full."""
        return self._queue.dropped

    @property
    def pending(self) -> int:
        """Payloads received and not yet handed out."""
        return len(self._queue)

    def close(self) -> None:
        for sub in self._subs:
            sub.undeclare()
