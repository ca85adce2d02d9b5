"""The simulated V2X link's carrier: the bytes of each signed alert travel in memory or over a real
zenoh network on loopback, while the simulation keeps the link's timing.

A closed-loop run is faster than real time, so the network cannot set *when* an alert reaches the
car; the link model does (generation time + ``latency_s``, losses drawn before sending). What the
carrier does is move the bytes: with ``zenoh``, every payload is published by a roadside peer on
its road segment's key (:func:`makeway.v2x.transport.segment_key`) and received by the car's peer,
which subscribed to the segments along its route; the car then verifies exactly the bytes that came
off the network. Before a step hands payloads over, :meth:`Radio.deliver` waits (wall clock, up to
``timeout_s``) until every payload sent so far has arrived, so a run is the same whichever carrier
moves it; a payload that never arrives counts in ``lost``.

Carriers by name: :data:`RADIOS` (``memory``, ``zenoh``).
"""

from __future__ import annotations

import time
import weakref
from collections.abc import Sequence
from typing import Protocol

from makeway.registry import Registry

__all__ = ["RADIOS", "MemoryRadio", "Radio", "ZenohRadio"]


class Radio(Protocol):
    """Moves signed alerts from roadside units (or EVs) to the car.

    ``send`` hands one payload to the carrier on ``segment`` with the simulated time ``deliver_s``
    (s) at which the car may read it; ``deliver`` returns ``(deliver_s, payload)`` pairs due by
    ``now_s``, in delivery order; ``close`` releases the network."""

    lost: int

    def send(self, segment: str, payload: bytes, deliver_s: float) -> None: ...

    def deliver(self, now_s: float) -> list[tuple[float, bytes]]: ...

    def close(self) -> None: ...


class MemoryRadio:
    """The bytes stay in memory (no network): the reference the network carrier must match."""

    def __init__(self, segments: Sequence[str] = ()) -> None:
        self._due: list[tuple[float, bytes]] = []
        self.lost = 0
        self.segments = tuple(segments)

    def send(self, segment: str, payload: bytes, deliver_s: float) -> None:
        self._due.append((deliver_s, payload))

    def deliver(self, now_s: float) -> list[tuple[float, bytes]]:
        due = sorted((p for p in self._due if p[0] <= now_s + 1e-9), key=lambda p: p[0])
        if due:
            self._due = [p for p in self._due if p[0] > now_s + 1e-9]
        return due

    def close(self) -> None:
        self._due.clear()


class ZenohRadio:
    """Two zenoh peers on loopback in this process: the roadside side listens on a free port and
    declares one publisher per segment, the car connects and subscribes to every segment of its
    route (``segments``). Sessions close on :meth:`close` (or when the object is collected)."""

    def __init__(self, segments: Sequence[str], *, timeout_s: float = 5.0) -> None:
        from makeway.v2x.transport import (
            AlertPublisher,
            AlertSubscriber,
            free_loopback_port,
            open_peer,
            wait_listening,
        )

        if not segments:
            raise ValueError("a zenoh radio needs at least one segment to carry")
        self.segments = tuple(segments)
        self.timeout_s = timeout_s
        self.lost = 0
        port = free_loopback_port()
        endpoint = f"tcp/127.0.0.1:{port}"
        self._roadside = open_peer(listen=[endpoint])
        self._car = None
        try:
            wait_listening(port, timeout_s)
            self._car = open_peer(connect=[endpoint])
            # every alert sent is waited for (a simulation step may send a burst): arrival order
            self._subscriber = AlertSubscriber(self._car, self.segments, queue="fifo")
            self._publishers = {s: AlertPublisher(self._roadside, s) for s in self.segments}
            for pub in self._publishers.values():
                if not pub.wait_for_subscribers(timeout_s):
                    raise TimeoutError(f"the car's peer did not subscribe to {pub.key} in {timeout_s:g} s")
        except BaseException:
            self._close_sessions()
            raise
        self._finalizer = weakref.finalize(self, ZenohRadio._close_all, self._roadside, self._car)
        self._sent: dict[bytes, tuple[float, int]] = {}  # payload -> (deliver time, send order)
        self._arrived: list[tuple[float, int, bytes]] = []
        self._count = 0

    @staticmethod
    def _close_all(*sessions: object) -> None:
        for s in sessions:
            if s is not None:
                s.close()  # type: ignore[attr-defined]

    def _close_sessions(self) -> None:
        ZenohRadio._close_all(self._car, self._roadside)

    def send(self, segment: str, payload: bytes, deliver_s: float) -> None:
        if segment not in self._publishers:
            raise ValueError(f"segment {segment!r} is not on the car's route")
        self._sent[payload] = (deliver_s, self._count)
        self._count += 1
        self._publishers[segment].publish(payload)

    def _drain(self) -> None:
        """Collect what the car's peer received; wait until everything sent has arrived."""
        deadline = time.monotonic() + self.timeout_s
        while self._sent:
            left = deadline - time.monotonic()
            if left <= 0:
                self.lost += len(self._sent)
                self._sent.clear()
                return
            for got in self._subscriber.receive(min(left, 0.05)):
                when = self._sent.pop(got.payload, None)
                if when is not None:
                    self._arrived.append((*when, got.payload))
                if not self._sent:
                    break

    def deliver(self, now_s: float) -> list[tuple[float, bytes]]:
        self._drain()
        due = sorted(p for p in self._arrived if p[0] <= now_s + 1e-9)  # by time, then send order
        if due:
            self._arrived = [p for p in self._arrived if p[0] > now_s + 1e-9]
        return [(t, payload) for t, _, payload in due]

    def close(self) -> None:
        self._finalizer()


RADIOS: Registry[type[MemoryRadio] | type[ZenohRadio]] = Registry(
    "radio", {"memory": MemoryRadio, "zenoh": ZenohRadio}
)
"""Carriers of the simulated V2X link by name: ``RADIOS[name](segments)``."""
