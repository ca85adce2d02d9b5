"""``makeway rsu …``: the roadside unit — a pole camera's video → EVs on the road → signed alerts —
and the hand calibration of its camera from road landmarks.

Each command parses its options, makes one call into :mod:`makeway.apps.rsu`, and prints one JSON
line. Registered by the main app as ``rsu``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from makeway.cli.common import friendly_errors, new_app, print_json_line

rsu_app = new_app(
    "rsu",
    "Roadside unit: a pole camera that warns cars of EVs.\n\n"
    "run: the video pipeline (vehicles detected, tracked and judged) on the camera's video; "
    "tracks the pipeline flags as active EVs are located on "
    "the road through the camera's calibration, filtered for heading and speed, and sent as signed "
    "alerts (zenoh on loopback and/or a log). calibrate: fit the camera to road landmarks.",
)

_ENDPOINT_HELP = "zenoh endpoint (loopback only), e.g. tcp/127.0.0.1:7447; repeat for several."


@rsu_app.command("run")
@friendly_errors
def run(
    video: Annotated[
        Path, typer.Argument(help="The pole camera's video, or a log (MCAP file, ROS 2 bag folder).")
    ],
    calib: Annotated[Path, typer.Option("--calib", help="Camera calibration (YAML) with a WGS-84 origin.")],
    key: Annotated[Path, typer.Option("--key", help="Unit key (NAME.key from makeway v2x keygen).")],
    publish: Annotated[
        bool, typer.Option("--publish/--no-publish", help="Publish the alerts over zenoh.")
    ] = True,
    rate_hz: Annotated[float, typer.Option(min=0.1, help="Alerts per second while an EV is active.")] = 10.0,
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="Write OUT/alerts.bin, OUT/alerts.jsonl and OUT/summary.json."),
    ] = None,
    segment: Annotated[str, typer.Option(help="Road segment id (key makeway/v2x/segment/ID).")] = "rsu-1",
    connect: Annotated[list[str] | None, typer.Option("--connect", help=_ENDPOINT_HELP)] = None,
    listen: Annotated[list[str] | None, typer.Option("--listen", help=_ENDPOINT_HELP)] = None,
    wait_s: Annotated[
        float, typer.Option(min=0.0, help="Wait this long (s) for a subscriber before the first frame.")
    ] = 5.0,
    max_frames: Annotated[int | None, typer.Option(min=1, help="Stop after this many frames.")] = None,
    stride: Annotated[int, typer.Option(min=1, help="Process every N-th frame.")] = 1,
    classifier: Annotated[
        str,
        typer.Option(help="EV crop classifier: default, general, fast, fastest, imagenet or a model file."),
    ] = "default",
    siren: Annotated[bool, typer.Option("--siren/--no-siren", help="Siren flag of the alerts.")] = False,
    topic: Annotated[
        str | None,
        typer.Option(help="Camera topic when VIDEO is a log (MCAP file or ROS 2 bag folder)."),
    ] = None,
    mcap: Annotated[
        Path | None,
        typer.Option(
            help="Also write the run to an MCAP file that opens in Foxglove: the camera, the boxes, "
            "the tracks and every alert made."
        ),
    ] = None,
    realtime: Annotated[
        bool,
        typer.Option(
            "--realtime",
            help="Play the video as a live camera: when the unit falls behind, the oldest "
            "waiting frame is dropped, never the newest.",
        ),
    ] = False,
) -> None:
    """Run the roadside unit on a video.

    Inputs (video, calibration, key, output folder) are checked before the first frame; a bad one is
    one error line, exit code 2. Prints one JSON line: frames, EV tracks reported, alerts made,
    alerts per second, subscriber found, outputs.
    """
    from makeway.apps.rsu import run_rsu

    print_json_line(
        run_rsu(
            video,
            calib,
            key,
            publish=publish,
            segment=segment,
            connect=connect,
            listen=listen,
            wait_s=wait_s,
            rate_hz=rate_hz,
            out=out,
            max_frames=max_frames,
            stride=stride,
            classifier=classifier,
            siren=siren,
            topic=topic,
            mcap=mcap,
            realtime=realtime,
        )
    )


@rsu_app.command("calibrate")
@friendly_errors
def calibrate(
    points: Annotated[Path, typer.Argument(help="Landmarks CSV: u,v,x_m,y_m rows (+ vanishing,u,v,dx,dy).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Where to write the calibration (YAML).")],
    width: Annotated[int, typer.Option(min=1, help="Image width (pixels).")] = 1280,
    height: Annotated[int, typer.Option(min=1, help="Image height (pixels).")] = 720,
    model: Annotated[str, typer.Option(help="kannala_brandt (focal + k1) or pinhole.")] = "kannala_brandt",
    origin_lat: Annotated[
        float | None, typer.Option(help="WGS-84 latitude of the road frame's origin.")
    ] = None,
    origin_lon: Annotated[
        float | None, typer.Option(help="WGS-84 longitude of the road frame's origin.")
    ] = None,
) -> None:
    """Fit a pole camera to road landmarks and write its calibration.

    Prints one JSON line: RMS reprojection error (px), the landmarks' leave-one-out held-out error
    (median, 95th percentile, max; m) and the camera's summary.
    """
    from makeway.apps.rsu import calibrate_camera

    if (origin_lat is None) != (origin_lon is None):
        raise ValueError("--origin-lat and --origin-lon go together")
    origin = None if origin_lat is None or origin_lon is None else (origin_lat, origin_lon)
    print_json_line(calibrate_camera(points, out, width=width, height=height, model=model, origin=origin))
