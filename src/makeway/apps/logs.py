"""``makeway logs …``: look into a robotics log, and make small test logs from a video and a recording."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from makeway.sense.logs import open_log

__all__ = ["log_info"]


def log_info(path: str | Path) -> dict[str, Any]:
    """What the log ``path`` (an MCAP file or a ROS 2 bag folder) holds: its kind and, per topic,
    the message type, encoding, message count and the kind makeway reads it as (``camera``,
    ``audio``, ``pose``, ``array``, ``other``).

    Raises:
        InputError: not a log, or a truncated or damaged one.
    """
    with open_log(path) as log:
        return {
            "log": str(path),
            "kind": log.kind,
            "topics": [
                {
                    "topic": t.name,
                    "type": t.schema,
                    "encoding": t.encoding,
                    "messages": t.count,
                    "kind": t.kind,
                }
                for t in log.topics().values()
            ],
        }
