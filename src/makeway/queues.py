"""Bounded, latest-wins hand-over between a sensor and the stage that reads it (issue 29, item 3).

A streaming stage (the siren listener on a live array, the vision pipeline on a camera, the
roadside node, the car's V2X listener) must never fall further and further behind when input comes
faster than it can work: a queue that grows without bound turns a slow stage into one whose
answers are about the past and whose memory climbs until the process dies. :class:`LatestQueue`
holds at most ``maxsize`` items and, when full, drops the **oldest** to make room, so the newest
input is always kept and ``put`` never blocks the sensor. It counts what it dropped.

:class:`KeyedLatestQueue` is the same hand-over for inputs that are repeated states of several
senders (V2X alerts: each unit repeats its state at 10 Hz): it keeps each key's newest few items
and serves the keys in turn, so one sender's flood neither delays nor displaces another's input.

:class:`LiveSource` reads a live source this way: a thread takes what the sensor delivers into a
:class:`LatestQueue`, and the consumer takes the next item whenever it is free; :func:`live` runs a
stage over one. :func:`paced` plays a file back on the clock of a live sensor.
Memory stays bounded by ``maxsize`` items and the delay from input to answer by about one
processing time plus the wait of the item (``benchmarks/bench_overload.py`` measures it).
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable, Hashable, Iterable, Iterator
from dataclasses import dataclass
from typing import Generic, TypeVar

__all__ = [
    "KeyedLatestQueue",
    "LatestQueue",
    "LiveResult",
    "LiveSource",
    "QueueClosedError",
    "live",
    "paced",
]

T = TypeVar("T")
R = TypeVar("R")
K = TypeVar("K", bound=Hashable)


class QueueClosedError(Exception):
    """:meth:`LatestQueue.get` on a closed queue with nothing left in it."""


def _wait_ready(
    cond: threading.Condition, ready: Callable[[], bool], closed: Callable[[], bool], timeout: float | None
) -> None:
    """With ``cond`` held: wait until ``ready()``, up to ``timeout`` seconds (``None``: for ever).
    Raises :class:`QueueClosedError` when ``closed()`` and nothing is ready, :class:`TimeoutError`
    when the time is up."""
    deadline = None if timeout is None else time.monotonic() + timeout
    while not ready():
        if closed():
            raise QueueClosedError("queue closed")
        left = None if deadline is None else deadline - time.monotonic()
        if left is not None and left <= 0:
            raise TimeoutError("no item within the timeout")
        cond.wait(left)


class LatestQueue(Generic[T]):
    """A thread-safe FIFO of at most ``maxsize`` items that drops the oldest when full.

    :meth:`put` never blocks; :attr:`dropped` counts the items pushed out unread, :attr:`put_count`
    every item put. :meth:`get` waits for an item (``timeout`` in seconds; ``TimeoutError`` when it
    passes) and raises :class:`QueueClosedError` once the queue is closed and empty.
    """

    def __init__(self, maxsize: int = 1) -> None:
        if maxsize < 1:
            raise ValueError(f"maxsize must be >= 1, got {maxsize}")
        self.maxsize = int(maxsize)
        self._items: deque[T] = deque()
        self._cond = threading.Condition()
        self._closed = False
        self.dropped = 0
        self.put_count = 0

    def put(self, item: T) -> T | None:
        """Add ``item``; return the oldest item when it had to make room (else ``None``)."""
        with self._cond:
            if self._closed:
                raise QueueClosedError("put on a closed queue")
            out = None
            if len(self._items) >= self.maxsize:
                out = self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            self.put_count += 1
            self._cond.notify()
            return out

    def get(self, timeout: float | None = None) -> T:
        """The oldest item held, waiting up to ``timeout`` seconds (``None``: for ever)."""
        with self._cond:
            _wait_ready(self._cond, lambda: bool(self._items), lambda: self._closed, timeout)
            return self._items.popleft()

    def close(self) -> None:
        """No more items will come: waiting getters wake up (they drain what is left first)."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    @property
    def closed(self) -> bool:
        return self._closed

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)


class KeyedLatestQueue(Generic[K, T]):
    """A thread-safe hand-over that keeps, for each key, its ``per_key`` newest items.

    Made for state messages repeated by several senders (a V2X alert is one unit's state, repeated
    at 10 Hz): once a newer item of a key is waiting, an older one of the same key is stale, so
    :meth:`put` drops the key's oldest item when the key already holds ``per_key``. Keys are served
    in turn: :meth:`get` takes the oldest item of the key that has waited longest, and a key that
    still holds items goes to the back of the line, so a key flooded with items gets one turn per
    round like every other key and cannot delay or displace them. At most ``max_keys`` keys wait at
    once; a new key arriving at a full queue drops the key that has waited longest, with its items.
    Memory is bounded by ``max_keys × per_key`` items; the delay of an item by about one round of
    the waiting keys.

    :attr:`dropped` counts every item pushed out unread (:attr:`superseded` those pushed out by a
    newer item of their own key, :attr:`evicted` those dropped with their key), :attr:`put_count`
    every item put. :meth:`get` waits for an item (``timeout`` in seconds; ``TimeoutError`` when it
    passes) and raises :class:`QueueClosedError` once the queue is closed and empty, as
    :meth:`LatestQueue.get`.

    ``per_key`` > 1 is for keys that a third party can claim (a V2X alert's signer id is read
    before its signature is checked): an item that turns out forged then does not hide the
    genuine one queued just before it, unless ``per_key`` or more newer items of the same key
    arrive before the key's turn (see :class:`makeway.v2x.transport.AlertSubscriber`).
    """

    def __init__(self, max_keys: int = 256, per_key: int = 1) -> None:
        if max_keys < 1:
            raise ValueError(f"max_keys must be >= 1, got {max_keys}")
        if per_key < 1:
            raise ValueError(f"per_key must be >= 1, got {per_key}")
        self.max_keys = int(max_keys)
        self.per_key = int(per_key)
        self._keys: OrderedDict[K, deque[T]] = OrderedDict()  # in serving order
        self._size = 0
        self._cond = threading.Condition()
        self._closed = False
        self.superseded = 0
        self.evicted = 0
        self.put_count = 0

    @property
    def dropped(self) -> int:
        """Items dropped unread: superseded by a newer item of their key, or evicted with it."""
        return self.superseded + self.evicted

    def put(self, key: K, item: T) -> int:
        """Add ``item`` under ``key``; return how many items this dropped (0, or more)."""
        with self._cond:
            if self._closed:
                raise QueueClosedError("put on a closed queue")
            dropped = 0
            held = self._keys.get(key)
            if held is None:
                if len(self._keys) >= self.max_keys:
                    _, gone = self._keys.popitem(last=False)
                    self.evicted += len(gone)
                    self._size -= len(gone)
                    dropped += len(gone)
                held = self._keys[key] = deque()
            elif len(held) >= self.per_key:
                held.popleft()
                self.superseded += 1
                self._size -= 1
                dropped += 1
            held.append(item)
            self._size += 1
            self.put_count += 1
            self._cond.notify()
            return dropped

    def get(self, timeout: float | None = None) -> T:
        """The oldest item of the key that has waited longest, waiting up to ``timeout`` seconds
        (``None``: for ever)."""
        with self._cond:
            _wait_ready(self._cond, lambda: bool(self._keys), lambda: self._closed, timeout)
            key, held = self._keys.popitem(last=False)
            item = held.popleft()
            self._size -= 1
            if held:  # its newer items wait for the key's next turn, behind the others
                self._keys[key] = held
            return item

    def close(self) -> None:
        """No more items will come: waiting getters wake up (they drain what is left first)."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def keys_waiting(self) -> int:
        """How many keys hold items now."""
        with self._cond:
            return len(self._keys)

    def __len__(self) -> int:
        with self._cond:
            return self._size


class LiveSource(Generic[T]):
    """A live ``source`` read on a background thread into a :class:`LatestQueue` of ``maxsize``; iterate
    to get ``(arrived_s, item)`` (``time.monotonic()`` seconds) as the consumer gets to them. Items
    that arrive while the consumer is busy and the queue is full push out the oldest waiting one
    (:attr:`dropped`). Iteration ends when the source ends (after what is queued); an error in the
    source is raised there. :meth:`close` stops reading early."""

    def __init__(self, source: Iterable[T], maxsize: int = 1) -> None:
        self._queue: LatestQueue[tuple[float, T]] = LatestQueue(maxsize)
        self._error: list[BaseException] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._read, args=(iter(source),), name="live-source", daemon=True
        )
        self._thread.start()

    def _read(self, source: Iterator[T]) -> None:
        try:
            for item in source:
                if self._stop.is_set():
                    return
                self._queue.put((time.monotonic(), item))
        except BaseException as exc:  # handed to the consumer
            self._error.append(exc)
        finally:
            self._queue.close()

    @property
    def dropped(self) -> int:
        """Items dropped unread so far."""
        return self._queue.dropped

    def __iter__(self) -> Iterator[tuple[float, T]]:
        while True:
            try:
                yield self._queue.get()
            except QueueClosedError:
                break
        self._thread.join(timeout=1.0)
        if self._error:
            raise self._error[0]

    def close(self) -> None:
        """Stop reading the source (the reader thread ends at its next item)."""
        self._stop.set()


@dataclass(frozen=True, slots=True)
class LiveResult(Generic[T, R]):
    """One processed input: the ``item``, the stage's ``result``, when the input arrived and when
    the answer was ready (``time.monotonic()`` seconds), and how many inputs had been dropped by
    then."""

    item: T
    result: R
    arrived_s: float
    done_s: float
    dropped: int

    @property
    def latency_s(self) -> float:
        """Input arrival to answer, seconds."""
        return self.done_s - self.arrived_s


def live(source: Iterable[T], stage: Callable[[T], R], *, maxsize: int = 1) -> Iterator[LiveResult[T, R]]:
    """Run ``stage`` over a live ``source`` without ever falling behind (module docstring): the
    source is read as a :class:`LiveSource` and each result is yielded as the stage finishes it."""
    feed = LiveSource(source, maxsize)
    try:
        for arrived, item in feed:
            result = stage(item)
            yield LiveResult(item, result, arrived, time.monotonic(), feed.dropped)
    finally:
        feed.close()


def paced(source: Iterable[T], rate_hz: float) -> Iterator[T]:
    """``source``'s items delivered on a clock of ``rate_hz`` (a file played back as a live sensor
    would deliver it: item ``k`` not before ``k / rate_hz`` seconds after the first)."""
    if not rate_hz > 0:
        raise ValueError(f"rate_hz must be positive, got {rate_hz}")
    t0 = time.monotonic()
    for k, item in enumerate(source):
        wait = t0 + k / rate_hz - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        yield item
