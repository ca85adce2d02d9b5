"""``makeway logs …``: robotics logs (MCAP files, ROS 2 bag folders) — list what one holds, make a
small one from a video and a recording.

Each command parses its options, makes one call into :mod:`makeway.apps.logs`, and prints.
Registered by the main app as ``app.add_typer(logs_app, name="logs")``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from makeway.cli.common import console, friendly_errors, new_app, print_json_line

logs_app = new_app(
    "logs",
    "Robotics logs: MCAP files and ROS 2 bag folders.\n\n"
    "makeway detect and makeway audio listen read a log's camera or audio topic wherever they read a "
    "video or a recording folder; these commands show what a log holds and make small test logs.",
)


@logs_app.command()
@friendly_errors
def info(
    log: Annotated[Path, typer.Argument(help="An MCAP file or a ROS 2 bag folder.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON line instead of a table.")] = False,
) -> None:
    """List a log's topics and how makeway reads each.

    Kinds: camera (images for makeway detect), audio (PCM blocks for makeway audio listen), array
    (the microphone positions of an audio topic), pose (the vehicle's path), other.
    """
    from makeway.apps.logs import log_info

    found = log_info(log)
    if as_json:
        print_json_line(found)
        return
    table = Table(title=f"{log.name} ({found['kind']})")
    for col in ("topic", "type", "encoding", "messages", "kind"):
        table.add_column(col)
    for t in found["topics"]:
        table.add_row(t["topic"], t["type"], t["encoding"], str(t["messages"]), t["kind"])
    console.print(table)


@logs_app.command("make-test")
@friendly_errors
def make_test(
    out: Annotated[
        Path, typer.Argument(help="The log to write: an .mcap file, or a folder for a ROS 2 bag.")
    ],
    video: Annotated[Path | None, typer.Option(help="Video whose frames become the camera topic.")] = None,
    recording: Annotated[
        Path | None,
        typer.Option(
            help="Recording folder whose audio, array and ego path become the audio and pose topics."
        ),
    ] = None,
    fmt: Annotated[
        str,
        typer.Option(
            "--format",
            help="mcap-ros2 (ROS 2 messages in MCAP), mcap-foxglove (Foxglove schemas in MCAP) or "
            "ros2-bag (a ROS 2 bag folder, SQLite storage) or ros2-bag-mcap (MCAP storage).",
        ),
    ] = "mcap-ros2",
    image: Annotated[
        str,
        typer.Option(
            help="Camera messages: compressed (JPEG), raw (uncompressed bgr8 pixels) or video "
            "(H.264 frames, --format mcap-foxglove only)."
        ),
    ] = "compressed",
    max_frames: Annotated[int, typer.Option(min=1, help="At most this many camera frames.")] = 50,
    stride: Annotated[int, typer.Option(min=1, help="Keep every N-th video frame.")] = 1,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON line instead of a table.")] = False,
) -> None:
    """Make a small test log from a video and a recording.

    Topics: /camera/image, /audio/raw with its array on /audio/raw/array, /ego/odom.
    """
    from makeway.sense.log_writer import make_test_log

    written = make_test_log(
        out, video=video, recording=recording, fmt=fmt, image=image, max_frames=max_frames, stride=stride
    )
    if as_json:
        print_json_line(written)
        return
    table = Table(title=f"makeway logs make-test → {out}", show_header=False)
    for topic, n in written["topics"].items():
        table.add_row(topic, f"{n} messages")
    console.print(table)
