"""``makeway roadside …``: where on the road a pixel of a fixed roadside camera is.

Each command parses its options, makes one call into :mod:`makeway.roadside.locate`, and prints JSON
lines. Registered by the main app as ``roadside``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from makeway.cli.common import friendly_errors, new_app, print_json_line

roadside_app = new_app(
    "roadside",
    "Roadside camera: pixel → road position.\n\n"
    "Two methods: transformation-based — a box's bottom centre back-projected through the "
    "calibrated camera onto the road plane (a YAML calibration); location reference — a thin-plate "
    "spline through pixel ↔ GNSS pairs recorded while a car drives the corridor (a CSV of pairs, fitted "
    "into an .npz). Positions are metres east and north of the calibration's origin, and lat/lon.",
)


@roadside_app.command("calibrate-transform")
@friendly_errors
def calibrate_transform(
    calibration: Annotated[
        Path, typer.Argument(help="Calibration file (YAML): camera model, intrinsics, pose.")
    ],
    check: Annotated[
        bool, typer.Option("--check", help="Read and check the file; print its summary.")
    ] = False,
    sim: Annotated[
        bool, typer.Option("--sim", help="Write the simulated traffic camera's calibration to the file.")
    ] = False,
) -> None:
    """Check or write a camera calibration.

    Prints one JSON line: model, image size, camera height, downward tilt, the nearest road distance
    in view and the horizon row. A missing or unknown field, a non-orthonormal rotation or a camera
    that sees no road is one error line, exit code 2.
    """
    from makeway.roadside.locate import check_transform, write_sim_calibration

    if check == sim:
        raise ValueError(
            "give exactly one of --check (read a calibration) and --sim (write the simulated one)"
        )
    print_json_line(write_sim_calibration(calibration) if sim else check_transform(calibration))


@roadside_app.command("fit-reference")
@friendly_errors
def fit_reference(
    pairs: Annotated[Path, typer.Argument(help="Pairs CSV: u,v,lat,lon rows, optional '# origin: LAT LON'.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Where to write the reference (.npz).")],
    folds: Annotated[int, typer.Option(min=2, help="Folds of the held-out error.")] = 5,
    smoothing: Annotated[
        float, typer.Option(min=0.0, help="Spline smoothing (0: through every pair).")
    ] = 1e-3,
    probe_length_m: Annotated[
        float,
        typer.Option(
            "--probe-length-m",
            min=0.5,
            help="Length of the car that drove the pairs (m); other vehicles' centres are placed by "
            "their class's typical length.",
        ),
    ] = 4.5,
) -> None:
    """Fit a location reference to pixel ↔ GNSS pairs.

    A thin-plate spline through the pairs, in metres east and north of their origin.

    Prints one JSON line: the number of pairs and the k-fold held-out error (median, 95th percentile,
    max; metres). Fewer than 10 pairs, pairs on one line or a malformed row is one error line, exit
    code 2, and nothing is written.
    """
    from makeway.roadside.locate import fit_reference as run

    print_json_line(run(pairs, out, folds=folds, smoothing=smoothing, probe_length_m=probe_length_m))


@roadside_app.command()
@friendly_errors
def locate(
    calibration: Annotated[
        Path, typer.Argument(help="A transformation calibration (.yaml) or a location reference (.npz).")
    ],
    pixels: Annotated[
        Path,
        typer.Option(
            "--pixels",
            help="CSV of pixels u,v, boxes x1,y1,x2,y2, or boxes with their detector class "
            "x1,y1,x2,y2,class (car, truck, bus, motorcycle); header optional.",
        ),
    ],
    behind_m: Annotated[
        float,
        typer.Option(
            "--behind-m",
            help="Transformation method: move each point this far farther along the view (e.g. half a "
            "vehicle length, to aim at its centre rather than its near edge).",
        ),
    ] = 0.0,
) -> None:
    """Road positions of pixels or boxes.

    A box is located by its bottom centre, the point where it meets the road. With a class column,
    each box is placed at the vehicle's centre, half its class's typical length beyond its near face.

    Prints one JSON line per row: u, v, x_m, y_m (metres east and north of the origin; null when the
    pixel looks above the horizon), lat and lon when the origin is known, and for a reference whether
    the pixel lies inside the area its pairs cover.
    """
    from makeway.roadside.locate import locate_file

    for row in locate_file(calibration, pixels, behind_m=behind_m):
        print_json_line(row)
