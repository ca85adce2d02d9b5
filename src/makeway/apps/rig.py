"""What ``makeway rig …`` composes: the azimuth of camera pixels (one, or a CSV file of them) and a
camera's intrinsics from chessboard images, written as a rig file's camera entry.

Frames and units as :mod:`makeway.sense.rig`: azimuth and elevation in degrees in the vehicle frame
(0 ahead, positive left; positive up), ranges in metres along the pixel's ray from the camera.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from makeway.atomic import check_writable, write_text_atomic
from makeway.errors import InputError
from makeway.sense.camera_calibration import ChessboardCalibration, calibrate_chessboards
from makeway.sense.rig import Rig, load_rig

__all__ = ["AzimuthRow", "azimuth_of_pixels", "calibrate_camera", "read_pixel_rows"]

_HEADERS = (["u", "v"], ["u", "v", "range_m"])


@dataclass(frozen=True)
class AzimuthRow:
    """One pixel's answer — ``result`` (camera, u, v, [range_m,] azimuth_deg, elevation_deg) — or,
    for a bad row of a pixel file, ``problem``: one line naming the file, the line and the fault."""

    result: dict[str, Any] | None = None
    problem: str | None = None


@dataclass(frozen=True)
class _PixelRow:
    line: int
    u: float = math.nan
    v: float = math.nan
    range_m: float | None = None
    problem: str | None = None


def read_pixel_rows(path: Path) -> list[_PixelRow]:
    """Rows ``u,v`` or ``u,v,range_m`` of a CSV file (an optional header ``u,v[,range_m]`` first;
    blank lines and ``#`` comments skipped). A malformed row carries its problem instead of values."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(path, "pixel file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot be read as a CSV text file ({exc})") from None
    rows: list[_PixelRow] = []
    first = True
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = [f.strip() for f in line.split(",")]
        if first and [f.lower() for f in fields] in _HEADERS:
            first = False
            continue
        first = False
        if len(fields) not in (2, 3):
            rows.append(_PixelRow(number, problem=f"needs u,v or u,v,range_m, not {len(fields)} fields"))
            continue
        try:
            values = [float(f) for f in fields]
        except ValueError:
            rows.append(_PixelRow(number, problem=f"not numbers: {line!r}"))
            continue
        if not all(math.isfinite(x) for x in values):
            rows.append(_PixelRow(number, problem=f"not finite: {line!r}"))
        elif len(values) == 3 and values[2] <= 0:
            rows.append(_PixelRow(number, problem=f"range_m must be positive, not {fields[2]}"))
        else:
            rows.append(_PixelRow(number, values[0], values[1], values[2] if len(values) == 3 else None))
    if not rows:
        raise InputError(path, "has no pixel rows (expected u,v or u,v,range_m per line)")
    return rows


def azimuth_of_pixels(
    rig: str | Path,
    camera: str,
    *,
    u: float | None = None,
    v: float | None = None,
    range_m: float | None = None,
    pixels: Path | None = None,
) -> list[AzimuthRow]:
    """The azimuth and elevation of one pixel ``(u, v)`` (optionally at ``range_m``) or of every row
    of the CSV file ``pixels``, seen through camera ``camera`` of ``rig`` (a rig file or "default").

    A bad rig, camera name or single pixel raises InputError; a bad row of ``pixels`` becomes a row
    with its ``problem`` and the other rows are still answered, in file order.
    """
    if (pixels is None) == (u is None or v is None):
        raise ValueError("give either a pixel U V or --pixels FILE, not both and not neither")
    if pixels is not None and range_m is not None:
        raise ValueError("--range-m goes with one pixel U V; in a pixel file give it as a third column")
    loaded = load_rig(rig)
    cam = loaded.camera(camera)
    if pixels is None:
        assert u is not None and v is not None
        d = loaded.azimuth(camera, u, v, range_m)
        return [AzimuthRow(_result(camera, u, v, range_m, float(d.azimuth_deg), float(d.elevation_deg)))]
    rows = read_pixel_rows(pixels)
    px = np.array([[r.u, r.v] for r in rows])
    inside = cam.camera.in_image(px)
    with np.errstate(invalid="ignore"):
        has_ray = ~np.isnan(cam.camera.unproject(np.where(inside[:, None], px, 0.0))[:, 0])
    out: list[AzimuthRow] = []
    for row, ok_in, ok_ray in zip(rows, inside, has_ray, strict=True):
        problem = row.problem
        if problem is None and not ok_in:
            problem = (
                f"pixel ({row.u:g}, {row.v:g}) is outside the image of camera {camera!r} "
                f"(0 ≤ u ≤ {cam.camera.width}, 0 ≤ v ≤ {cam.camera.height})"
            )
        elif problem is None and not ok_ray:
            problem = f"pixel ({row.u:g}, {row.v:g}) lies beyond camera {camera!r}'s lens model"
        if problem is not None:
            out.append(AzimuthRow(problem=f"{pixels}:{row.line}: {problem}"))
        else:
            out.append(AzimuthRow(_answer(loaded, camera, row)))
    return out


def _answer(rig: Rig, camera: str, row: _PixelRow) -> dict[str, Any]:
    d = rig.azimuth(camera, row.u, row.v, row.range_m)
    return _result(camera, row.u, row.v, row.range_m, float(d.azimuth_deg), float(d.elevation_deg))


def _result(camera: str, u: float, v: float, range_m: float | None, az: float, el: float) -> dict[str, Any]:
    out: dict[str, Any] = {"camera": camera, "u": u, "v": v}
    if range_m is not None:
        out["range_m"] = range_m
    out["azimuth_deg"] = az
    out["elevation_deg"] = el
    return out


def calibrate_camera(
    images: Sequence[Path],
    out: Path,
    *,
    board: tuple[int, int] = (9, 6),
    square_m: float = 0.025,
    model: str = "kannala_brandt",
    name: str = "camera",
) -> ChessboardCalibration:
    """Fit a camera's intrinsics to chessboard ``images`` and write them to ``out`` (YAML) as a rig
    file's camera entry, with the fit's RMS reprojection error in its header. The entry has no
    extrinsics: add ``rotation`` (or ``yaw_pitch_roll_deg``) and ``translation_m`` before putting it
    under a rig file's ``cameras:``. ``out`` is checked before any work and written all-or-nothing."""
    target = check_writable(out, folder=False)
    fit = calibrate_chessboards(images, board, square_m, model)
    entry = {"name": name, **fit.camera.to_dict()}
    header = (
        f"# Intrinsics of camera {name!r} ({model}) fitted by `makeway rig calibrate` to a "
        f"{board[0]}x{board[1]} chessboard ({square_m * 1000:g} mm squares)\n"
        f"# in {len(fit.used)} of {len(fit.used) + len(fit.rejected)} images; "
        f"RMS reprojection error {fit.rms_px:.4f} px.\n"
        "# Add rotation (or yaw_pitch_roll_deg) and translation_m, then list it under `cameras:` "
        "in a rig file.\n"
    )
    write_text_atomic(target, header + yaml.safe_dump(entry, sort_keys=False, default_flow_style=None))
    return fit
