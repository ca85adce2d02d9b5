"""The roadside commands' library calls: check a transformation calibration, fit a location
reference from a pairs file, and locate pixels or boxes with either.

Each function does the whole of one command and returns what it prints (JSON-ready dicts); inputs
are checked first, and a bad one raises :class:`~makeway.errors.InputError` before anything is
written.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from makeway.atomic import atomic_path, write_text_atomic
from makeway.errors import InputError
from makeway.roadside.csvfile import data_lines
from makeway.roadside.reference import (
    DEFAULT_PROBE_LENGTH_M,
    DEFAULT_SMOOTHING,
    LocationReference,
    kfold_errors,
    load_reference,
    read_pairs,
)
from makeway.roadside.transform import (
    RoadCamera,
    box_ground_pixel,
    read_transform_calibration,
    typical_length_m,
)

__all__ = ["check_transform", "fit_reference", "locate_file", "read_pixel_rows", "write_sim_calibration"]


def check_transform(calibration: str | Path) -> dict[str, Any]:
    """Read and check a transformation calibration file; its :meth:`RoadCamera.summary`."""
    return {"calibration": str(calibration), **read_transform_calibration(calibration).summary()}


def write_sim_calibration(out: str | Path) -> dict[str, Any]:
    """Write the simulated traffic camera's calibration (:mod:`makeway.roadside.simulated`) to ``out``;
    its summary."""
    from makeway.roadside.simulated import sim_road_camera

    camera = sim_road_camera()
    write_text_atomic(out, yaml.safe_dump(camera.to_dict(), sort_keys=False))
    return {"calibration": str(out), **camera.summary()}


def fit_reference(
    pairs: str | Path,
    out: str | Path,
    *,
    folds: int = 5,
    smoothing: float = DEFAULT_SMOOTHING,
    probe_length_m: float = DEFAULT_PROBE_LENGTH_M,
) -> dict[str, Any]:
    """Fit a location reference to a pairs file and save it to ``out`` (``.npz``); the number of
    pairs and the ``folds``-fold held-out error (median, 95th percentile, max; metres).
    ``probe_length_m``: the length of the car that drove the pairs (m)."""
    if Path(out).suffix.lower() != ".npz":
        raise ValueError(f"--out must name a .npz file, not {str(out)!r}")
    p = read_pairs(pairs)
    if smoothing < 0:
        raise ValueError(f"--smoothing must be ≥ 0, not {smoothing}")
    if not (probe_length_m > 0 and math.isfinite(probe_length_m)):
        raise ValueError(f"--probe-length-m must be > 0, not {probe_length_m}")
    err = kfold_errors(p.pixels, p.xy, folds=min(folds, len(p.pixels)), smoothing=smoothing)
    stats = {
        "heldout_median_m": float(np.median(err)),
        "heldout_p95_m": float(np.percentile(err, 95)),
        "heldout_max_m": float(err.max()),
    }
    ref = LocationReference(p.pixels, p.xy, p.origin, smoothing, probe_length_m)
    with atomic_path(Path(out)) as tmp, open(tmp, "wb") as fh:
        ref.save(fh, folds=folds, **stats)
    return {
        "pairs": len(p.pixels),
        "out": str(out),
        "folds": folds,
        "smoothing": smoothing,
        "probe_length_m": probe_length_m,
        **stats,
    }


def read_pixel_rows(path: str | Path) -> tuple[np.ndarray, np.ndarray, str, np.ndarray | None]:
    """A CSV of pixels ``u,v``, boxes ``x1,y1,x2,y2`` or boxes with their detector class
    ``x1,y1,x2,y2,class`` (header optional, ``#`` comments) → the numeric rows ``(n, 2 or 4)``, the
    pixels to locate ``(n, 2)`` (a box's bottom centre), ``"pixel"`` or ``"box"``, and the class
    labels ``(n,)`` (``None`` without the column); InputError naming the file and line otherwise."""
    path = Path(path)
    rows: list[list[float]] = []
    labels: list[str] = []
    width = 0
    first = True
    for n, text, cells in data_lines(path, "pixels"):
        labelled = len(cells) == 5
        try:
            vals = [float(c) for c in (cells[:4] if labelled else cells)]
        except ValueError:
            if first:  # a header
                first = False
                continue
            raise InputError(
                path, f"line {n}: expected numbers (u,v or x1,y1,x2,y2[,class]), got {text!r}"
            ) from None
        first = False
        if len(cells) not in (2, 4, 5) or (width and len(cells) != width):
            raise InputError(
                path, f"line {n}: every row must be u,v or every row x1,y1,x2,y2[,class], got {text!r}"
            )
        if not np.isfinite(vals).all():
            raise InputError(path, f"line {n}: a value is not finite: {text!r}")
        if labelled:
            if not cells[4]:
                raise InputError(path, f"line {n}: the class (5th column) is empty: {text!r}")
            labels.append(cells[4].lower())
        width = len(cells)
        rows.append(vals)
    if not rows:
        raise InputError(path, "has no pixels (rows u,v or x1,y1,x2,y2[,class])")
    data = np.array(rows, np.float64)
    names = np.array(labels, dtype=object) if labels else None
    if data.shape[1] == 4:
        return data, box_ground_pixel(data), "box", names
    return data, data, "pixel", None


def locate_file(
    calibration: str | Path, pixels: str | Path, *, behind_m: float = 0.0
) -> list[dict[str, Any]]:
    """Locate every row of a pixels file (:func:`read_pixel_rows`) with a transformation calibration
    (``.yaml``/``.yml``) or a location reference (``.npz``): one dict per row with the pixel used,
    ``x_m``, ``y_m`` (road frame; ``null`` when the ray misses the road) and, when the origin is
    known, ``lat``, ``lon``. ``behind_m`` applies to the transformation method only
    (:meth:`RoadCamera.locate`); the reference reports ``inside`` (the pixel lies in its pairs' hull).

    Boxes with a class column are located at the vehicle's centre: its typical length
    (:func:`~makeway.roadside.transform.typical_length_m`) sets how far beyond the near face — half
    of it for the transformation (``behind_m`` is then ignored), the difference from the probe car's
    for the reference; each row reports the ``length_m`` used."""
    cal = Path(calibration)
    model: RoadCamera | LocationReference
    if cal.suffix.lower() == ".npz":
        model = load_reference(cal)
    elif cal.suffix.lower() in (".yaml", ".yml"):
        model = read_transform_calibration(cal)
    else:
        raise InputError(cal, "must be a transformation calibration (.yaml) or a location reference (.npz)")
    _, px, kind, labels = read_pixel_rows(pixels)
    lengths = None if labels is None else typical_length_m(labels)
    if isinstance(model, RoadCamera):
        bad = ~model.camera.in_image(px)
        if bad.any():
            u, v = px[bad][0]
            raise InputError(
                pixels,
                f"pixel ({u:g}, {v:g}) is outside the {model.camera.width}×"
                f"{model.camera.height} image of {cal}",
            )
        push = behind_m if lengths is None else 0.5 * lengths
        xy, method, inside = model.locate(px, push), "transform", None
    else:
        xy, method, inside = model.locate(px, lengths), "reference", model.inside(px)
    origin = model.origin
    lat = lon = None
    if origin is not None:
        lat, lon, _ = origin.to_geodetic(np.nan_to_num(xy))
    out: list[dict[str, Any]] = []
    for i in range(len(px)):
        hit = bool(np.isfinite(xy[i]).all())
        row: dict[str, Any] = {
            "method": method,
            "input": kind,
            "u": float(px[i, 0]),
            "v": float(px[i, 1]),
            "x_m": float(xy[i, 0]) if hit else None,
            "y_m": float(xy[i, 1]) if hit else None,
        }
        if lat is not None and lon is not None:
            row["lat"] = float(lat[i]) if hit else None
            row["lon"] = float(lon[i]) if hit else None
        if inside is not None:
            row["inside"] = bool(inside[i])
        if labels is not None and lengths is not None:
            row["class"] = str(labels[i])
            row["length_m"] = float(lengths[i])
        out.append(row)
    return out
