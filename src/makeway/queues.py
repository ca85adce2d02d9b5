"""Bounded, latest-wins hand-over between a sensor and the stage that reads it (issue 29, item 3).

A streaming stage (the siren listener on a live array, the vision pipeline on a camera, the
roadside node, the car's V2X listener) must never fall further and further behind when input comes
faster than it can work: a queue that grows without bound turns a slow stage into one whose
answers are about the past and whose memory climbs until the process dies. :class:`LatestQueue`
holds at most ``maxsize`` items and, when full, drops the **oldest** to make room, so the newest
input is always kept and ``put`` never blocks the sensor. It counts what it dropped.

:class:`LiveSource` reads a live source this way: a thread takes what the sensor delivers into a
:class:`LatestQueue`, and the consumer takes the next item whenever it is free; :func:`live` runs a
stage over one. :func:`paced` plays a file back on the clock of a live sensor.
Memory stays bounded by ``maxsize`` items and the delay from input to answer by about one
processing time plus the wait of the item (``benchmarks/bench_overload.py`` measures it).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Generic, TypeVar

__all__ = ["LatestQueue", "LiveResult", "LiveSource", "QueueClosedError", "live", "paced"]

T = TypeVar("T")
R = TypeVar("R")


class QueueClosedError(Exception):
    """:meth:`LatestQueue.get` on a closed queue with nothing left in it."""


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
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while not self._items:
                if self._closed:
                    raise QueueClosedError("queue closed")
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    raise TimeoutError("no item within the timeout")
                self._cond.wait(left)
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
