"""``makeway rig …``: the vehicle's cameras — the azimuth of a pixel, and a camera's intrinsics from
chessboard images.

Each command parses its options, makes one call into :mod:`makeway.apps.rig`, and prints. Registered
by the main app as ``app.add_typer(rig_app, name="rig")``; also runnable as ``python -m makeway.cli.rig``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from makeway.cli.common import EXIT_BAD_INPUT, err_console, friendly_errors, new_app, print_json_line

rig_app = new_app(
    "rig",
    "Camera rig: a pixel's azimuth, chessboard calibration.\n\n"
    "A rig file (YAML) lists each camera's model, intrinsics and mounting; 'default' is the shipped rig "
    "of four 180° fisheye cameras (front, left, right, rear).",
)


def _parse_board(text: str) -> tuple[int, int]:
    """``"9x6"`` → ``(9, 6)``, or a ValueError naming the option."""
    try:
        cols, rows = (int(p) for p in text.lower().replace("×", "x").split("x"))
    except ValueError:
        raise ValueError(f"--board takes COLSxROWS inner corners, e.g. 9x6, not {text!r}") from None
    if cols < 2 or rows < 2:
        raise ValueError(f"--board needs at least 2x2 inner corners, not {text!r}")
    return cols, rows


@rig_app.command()
@friendly_errors
def azimuth(
    rig: Annotated[str, typer.Argument(help="Rig file (YAML), or 'default' for the shipped 4-camera rig.")],
    camera: Annotated[
        str, typer.Argument(help="Camera name in the rig (the default rig: front, left, right, rear).")
    ],
    u: Annotated[float | None, typer.Argument(help="Pixel column, 0 at the image's left edge.")] = None,
    v: Annotated[float | None, typer.Argument(help="Pixel row, 0 at the image's top edge.")] = None,
    pixels: Annotated[
        Path | None,
        typer.Option(
            "--pixels", help="CSV file of pixels instead of U V: rows u,v or u,v,range_m (header optional)."
        ),
    ] = None,
    range_m: Annotated[
        float | None,
        typer.Option(
            "--range-m",
            help="With U V: distance (m) along the pixel's ray from the camera; the azimuth is then of "
            "that point, seen from the vehicle origin.",
        ),
    ] = None,
) -> None:
    """Where a camera pixel looks: azimuth and elevation around the car.

    Prints one JSON line per pixel: camera, u, v, [range_m,] azimuth_deg (0 ahead, positive to the
    left, ±180 behind) and elevation_deg (positive up). Without a range, the angles are of the
    pixel's ray; with one, of the point that far along the ray, seen from the vehicle origin (on
    the ground under the rear axle). With --pixels, a bad row is reported on stderr with its line
    number, the other rows are still answered, and the exit code is 2.
    """
    from makeway.apps.rig import azimuth_of_pixels

    rows = azimuth_of_pixels(rig, camera, u=u, v=v, range_m=range_m, pixels=pixels)
    bad = 0
    for row in rows:
        if row.result is not None:
            print_json_line(row.result)
        else:
            bad += 1
            err_console.print(
                f"[bold red]error:[/] {escape(str(row.problem))}", highlight=False, soft_wrap=True
            )
    if bad:
        raise typer.Exit(code=EXIT_BAD_INPUT)


@rig_app.command()
@friendly_errors
def calibrate(
    images: Annotated[list[Path], typer.Argument(help="Images of a flat chessboard, one camera, one size.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Where the camera entry (YAML) goes.")],
    board: Annotated[
        str, typer.Option(help="Inner corners of the board, COLSxROWS (a board of 10x7 squares is 9x6).")
    ] = "9x6",
    square_m: Annotated[float, typer.Option("--square-m", help="Side of one square, metres.")] = 0.025,
    model: Annotated[str, typer.Option(help="Camera model: kannala_brandt (fisheye) or pinhole.")] = (
        "kannala_brandt"
    ),
    name: Annotated[str, typer.Option(help="The camera's name in the written entry.")] = "camera",
) -> None:
    """Estimate a camera's intrinsics from chessboard images.

    Finds the board's inner corners in each image, fits fx, fy, cx, cy (and k1..k4 for the fisheye
    model) to all of them, prints the RMS reprojection error, and writes OUT: a rig file's camera
    entry without its mounting. Add rotation (or yaw_pitch_roll_deg) and translation_m, then list it
    under cameras: in a rig file.
    """
    from makeway.apps.rig import calibrate_camera

    fit = calibrate_camera(images, out, board=_parse_board(board), square_m=square_m, model=model, name=name)
    for path in fit.rejected:
        err_console.print(f"no {board} chessboard found in {path}; skipped", highlight=False, soft_wrap=True)
    cam = fit.camera
    err_console.print(
        f"RMS reprojection error {fit.rms_px:.4f} px over {len(fit.used)} images → {out}",
        highlight=False,
        soft_wrap=True,
    )
    print_json_line(
        {
            "rms_px": fit.rms_px,
            "images_used": len(fit.used),
            "images_skipped": len(fit.rejected),
            **cam.to_dict(),
            "out": str(out),
        }
    )


if __name__ == "__main__":  # pragma: no cover
    rig_app()
