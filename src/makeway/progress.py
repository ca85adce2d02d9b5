"""One progress bar style for every long-running command (rich)."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from typing import Any


class Progress:
    """Handle yielded by :func:`progress_bar`: call it to advance, :meth:`finish` at a short end."""

    def __init__(self, bar: Any = None, task: Any = None, unit: str = "frames") -> None:
        self._bar = bar
        self._task = task
        self._unit = unit
        self._start = time.perf_counter()
        self.done = 0

    def __call__(self, n: int = 1) -> None:
        self.done += n
        if self._bar is not None:
            rate = self.done / max(time.perf_counter() - self._start, 1e-9)
            self._bar.update(self._task, advance=n, rate=f"{rate:6.1f} {self._unit}/s")

    def finish(self) -> None:
        """Mark the bar complete at the count reached (a container's frame count can overstate)."""
        if self._bar is not None:
            self._bar.update(self._task, total=self.done, completed=self.done)


@contextlib.contextmanager
def progress_bar(
    description: str, total: int | None, *, enabled: bool = True, unit: str = "frames"
) -> Iterator[Progress]:
    """A rich progress bar on stderr showing count, rate, elapsed and remaining time.

    Yields a :class:`Progress`; call it (``advance(n=1)``) per item. With ``enabled=False`` it
    counts silently. When the work ends in an exception the bar is erased, so the error's one line
    stands alone on stderr.
    """
    if not enabled:
        yield Progress(unit=unit)
        return
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )
    from rich.progress import Progress as RichProgress

    columns = (
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[rate]}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    from rich.console import Console

    # on stderr: stdout stays for the JSON lines the commands print
    with RichProgress(*columns, console=Console(stderr=True)) as bar:
        task = bar.add_task(description, total=total, rate="")
        try:
            yield Progress(bar, task, unit)
        except BaseException:
            # erase the bar when it stops, below (a terminal), or print nothing more (a log file)
            bar.update(task, visible=False)
            bar.live.transient = True
            if not bar.console.is_terminal:
                bar.console.quiet = True
            raise
