"""One progress bar style for every long-running command (rich)."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator


def _no_progress(n: int = 1) -> None:
    """The ``advance`` of a disabled progress bar."""


@contextlib.contextmanager
def progress_bar(
    description: str, total: int | None, *, enabled: bool = True, unit: str = "frames"
) -> Iterator[Callable[[int], None]]:
    """A rich progress bar showing count, rate, elapsed and remaining time.

    Yields an ``advance(n=1)`` callable; with ``enabled=False`` it is a no-op and nothing prints.
    """
    if not enabled:
        yield _no_progress
        return
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    columns = (
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[rate]}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    with Progress(*columns) as bar:
        task = bar.add_task(description, total=total, rate="")
        start = time.perf_counter()
        done = 0

        def advance(n: int = 1) -> None:
            nonlocal done
            done += n
            rate = done / max(time.perf_counter() - start, 1e-9)
            bar.update(task, advance=n, rate=f"{rate:6.1f} {unit}/s")

        yield advance
