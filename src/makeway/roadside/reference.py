"""Location-reference pixel → road: a thin-plate spline through pixel ↔ GNSS pairs.

A car with an RTK GNSS receiver drives the corridor while the roadside camera detects it; each frame
gives a pair: the ground-contact pixel of its box (bottom centre, :func:`~makeway.roadside.transform.
box_ground_pixel`) and its WGS-84 latitude/longitude. As long as the camera stays put, the same pixel
means the same road position next time (seed 001, appendix B.2). The pairs are converted to the road
frame (:class:`~makeway.roadside.geodesy.LocalFrame`: ENU metres at the reference origin) and
interpolated with scipy's :class:`~scipy.interpolate.RBFInterpolator`: thin-plate spline kernel, a
linear polynomial tail, and a little smoothing (the pairs are noisy). Pixels enter in units of
100 px. Because the GNSS antenna reports the car's own position, the map learns the offset from the
box's bottom edge to a car's centre as well — for vehicles the size of the probe car. A vehicle of
another length ``L`` (e.g. :func:`~makeway.roadside.transform.typical_length_m` of its detector
class) is moved ``(L − probe_length_m)/2`` farther along the road as the image sees it: the
direction the map takes a pixel when it moves up the image (:meth:`LocationReference.locate`).

No camera model is needed, but the map is only good inside the region the drive covered:
:meth:`LocationReference.inside` says whether a pixel lies in the convex hull of the pairs' pixels.
Its held-out error (:func:`kfold_errors`) is the error to expect there.

The pairs file (CSV; ``#`` lines are comments)::

    # origin: 30.6280 -96.4818 0.0        (optional: the road frame's origin, lat lon [height_m])
    u,v,lat,lon
    612.4,402.0,30.62853311,-96.48176620
    ...

Without an ``origin`` line the origin is the mean of the pairs' latitudes and longitudes.
:func:`read_pairs` raises :class:`~makeway.errors.InputError` naming the file and the problem: no
header with ``u, v, lat, lon``, a row that is not four numbers (with its line number), a latitude or
longitude out of range, fewer than :data:`MIN_PAIRS` pairs, or pixels (or positions) on one line.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.interpolate import RBFInterpolator
from scipy.spatial import Delaunay

from makeway.errors import InputError
from makeway.roadside.geodesy import LocalFrame

__all__ = [
    "DEFAULT_PROBE_LENGTH_M",
    "MIN_PAIRS",
    "LocationReference",
    "Pairs",
    "kfold_errors",
    "load_reference",
    "read_pairs",
    "write_pairs",
]

#: Fewest pairs a reference is fitted from (a thin-plate spline with a linear tail needs 3; a map
#: over a whole corridor needs many more — 10 is the floor, a drive gives hundreds).
MIN_PAIRS = 10
#: Pixels are divided by this before the spline (so ``smoothing`` is in sensible units).
PIXEL_SCALE = 100.0
#: Default length (m) of the calibration drive's probe car: a mid-size car.
DEFAULT_PROBE_LENGTH_M = 4.5
#: Pixels up the image over which :meth:`LocationReference.locate` reads the road direction.
_UP_PX = 4.0
#: Default smoothing of the spline (scipy's ``smoothing``; 0 interpolates every pair exactly).
DEFAULT_SMOOTHING = 1e-3
_COLLINEAR = 1e-3  # smallest/largest singular value of the centred points below which they are on a line


@dataclass(frozen=True)
class Pairs:
    """Pixel ↔ road pairs: ``pixels`` ``(n, 2)``, ``xy`` ``(n, 2)`` road-frame metres, the frame's
    ``origin``, and the ``source`` file (named in errors)."""

    pixels: np.ndarray
    xy: np.ndarray
    origin: LocalFrame
    source: Path


def _check_spread(points: np.ndarray, what: str, fail: Any) -> None:
    centred = points - points.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    if sv[0] == 0 or sv[1] / sv[0] < _COLLINEAR:
        raise fail(f"the pairs' {what} lie on one line; the map needs pairs spread across the road")


def check_pairs(pixels: np.ndarray, xy: np.ndarray, source: str | Path) -> None:
    """InputError naming ``source`` when the pairs cannot make a map: fewer than :data:`MIN_PAIRS`,
    non-finite values, or pixels or positions on one line."""

    def fail(problem: str) -> InputError:
        return InputError(source, problem)

    if len(pixels) < MIN_PAIRS:
        raise fail(f"has {len(pixels)} pixel/position pairs; at least {MIN_PAIRS} are needed")
    if not (np.isfinite(pixels).all() and np.isfinite(xy).all()):
        raise fail("has a pixel or position that is not a finite number")
    _check_spread(pixels, "pixels", fail)
    _check_spread(xy, "positions", fail)


def read_pairs(path: str | Path) -> Pairs:
    """Read and check a pairs file (module docstring: layout)."""
    path = Path(path)

    def fail(problem: str) -> InputError:
        return InputError(path, problem)

    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        raise fail("pairs file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise fail(f"cannot be read as a pairs CSV ({exc})") from None
    origin_vals: list[float] | None = None
    body: list[tuple[int, str]] = []
    for n, line in enumerate(lines, start=1):
        text = line.strip()
        if text.startswith("#"):
            comment = text[1:].strip()
            if comment.lower().startswith("origin:"):
                try:
                    origin_vals = [float(p) for p in comment.split(":", 1)[1].replace(",", " ").split()]
                except ValueError:
                    origin_vals = []
                if len(origin_vals) not in (2, 3):
                    raise fail(f"line {n}: origin must be '# origin: LAT LON [HEIGHT_M]'")
        elif text:
            body.append((n, text))
    if not body:
        raise fail("has no header and no pairs; expected a header u,v,lat,lon and one pair per row")
    header = [h.strip().lower() for h in next(csv.reader([body[0][1]]))]
    if not {"u", "v", "lat", "lon"} <= set(header):
        raise fail(f"line {body[0][0]}: the header must name the columns u, v, lat, lon, not {body[0][1]!r}")
    cols = [header.index(c) for c in ("u", "v", "lat", "lon")]
    rows: list[list[float]] = []
    for n, text in body[1:]:
        cells = next(csv.reader([text]))
        try:
            vals = [float(cells[c]) for c in cols]
        except (ValueError, IndexError):
            raise fail(f"line {n}: expected numbers for u, v, lat, lon, got {text!r}") from None
        if not all(math.isfinite(v) for v in vals):
            raise fail(f"line {n}: a value is not finite: {text!r}")
        if not (-90.0 <= vals[2] <= 90.0 and -180.0 <= vals[3] <= 360.0):
            raise fail(f"line {n}: latitude {vals[2]:g} or longitude {vals[3]:g} is out of range")
        rows.append(vals)
    data = np.array(rows, np.float64).reshape(-1, 4)
    if len(data) < MIN_PAIRS:
        raise fail(f"has {len(data)} pixel/position pairs; at least {MIN_PAIRS} are needed")
    try:
        if origin_vals is not None:
            origin = LocalFrame(*origin_vals)
        else:
            origin = LocalFrame(float(data[:, 2].mean()), float(data[:, 3].mean()))
    except ValueError as exc:
        raise fail(str(exc)) from None
    xy = origin.to_enu(data[:, 2], data[:, 3])[:, :2]
    check_pairs(data[:, :2], xy, path)
    return Pairs(data[:, :2], xy, origin, path)


def write_pairs(path: str | Path, pixels: Any, xy: Any, origin: LocalFrame) -> None:
    """Write pixel ↔ road-frame pairs as a pairs file (positions converted to WGS-84 lat/lon)."""
    px, p = np.asarray(pixels, np.float64), np.asarray(xy, np.float64)
    lat, lon, _ = origin.to_geodetic(p)
    lines = [f"# origin: {origin.lat0_deg:.9f} {origin.lon0_deg:.9f} {origin.h0_m:g}", "u,v,lat,lon"]
    lines += [f"{u:.3f},{v:.3f},{a:.9f},{b:.9f}" for (u, v), a, b in zip(px, lat, lon, strict=True)]
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


@dataclass
class LocationReference:
    """The thin-plate-spline map pixel → road frame fitted to ``pixels`` ``(n, 2)`` and ``xy``
    ``(n, 2)`` metres; ``origin`` is the road frame's WGS-84 origin; ``probe_length_m`` the length
    of the calibration drive's car (m), whose centre the pairs' positions are."""

    pixels: np.ndarray
    xy: np.ndarray
    origin: LocalFrame
    smoothing: float = DEFAULT_SMOOTHING
    probe_length_m: float = DEFAULT_PROBE_LENGTH_M
    _rbf: RBFInterpolator = field(init=False, repr=False)
    _hull: Delaunay = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.pixels = np.asarray(self.pixels, np.float64)
        self.xy = np.asarray(self.xy, np.float64)
        self._rbf = _fit(self.pixels, self.xy, self.smoothing)
        self._hull = Delaunay(self.pixels)

    def locate(self, pixels: Any, length_m: Any = None) -> np.ndarray:
        """Pixels ``(..., 2)`` → road points ``(..., 2)`` (``x`` east, ``y`` north, metres).

        ``length_m`` (metres, scalar or one per pixel): the length of the vehicle whose box's bottom
        centre each pixel is; its centre is then ``(length_m − probe_length_m)/2`` farther along the
        direction the map moves as the pixel moves :data:`_UP_PX` up the image (away from the
        camera, along the road as it is seen). ``None``: vehicles the probe car's size."""
        px = np.asarray(pixels, np.float64)
        flat = px.reshape(-1, 2)
        xy = self._rbf(flat / PIXEL_SCALE)
        if length_m is not None:
            extra = 0.5 * (np.broadcast_to(np.asarray(length_m, np.float64), px.shape[:-1]).reshape(-1)
                           - self.probe_length_m)  # fmt: skip
            away = self._rbf((flat - [0.0, _UP_PX]) / PIXEL_SCALE) - xy
            norm = np.linalg.norm(away, axis=1, keepdims=True)
            xy = xy + extra[:, None] * np.divide(away, norm, out=np.zeros_like(away), where=norm > 0)
        return xy.reshape(px.shape)

    def inside(self, pixels: Any) -> np.ndarray:
        """Whether each pixel ``(..., 2)`` lies inside the convex hull of the pairs' pixels."""
        px = np.asarray(pixels, np.float64)
        return (self._hull.find_simplex(px.reshape(-1, 2)) >= 0).reshape(px.shape[:-1])

    def save(self, file: Any, **extra: Any) -> None:
        """Write the pairs, origin and smoothing (plus ``extra`` scalars) as an ``.npz`` file
        (``file``: a path or a binary file object)."""
        o = self.origin
        arrays: dict[str, Any] = {k: np.asarray(v) for k, v in extra.items()}
        np.savez(
            file,
            pixels=self.pixels,
            xy=self.xy,
            origin=np.array([o.lat0_deg, o.lon0_deg, o.h0_m]),
            smoothing=np.array(self.smoothing),
            probe_length_m=np.array(self.probe_length_m),
            **arrays,
        )


def _fit(pixels: np.ndarray, xy: np.ndarray, smoothing: float) -> RBFInterpolator:
    return RBFInterpolator(
        pixels / PIXEL_SCALE, xy, kernel="thin_plate_spline", smoothing=smoothing, degree=1
    )


def load_reference(path: str | Path) -> LocationReference:
    """A reference saved by :meth:`LocationReference.save`; InputError when it is not one."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "reference file not found")
    try:
        with np.load(path, allow_pickle=False) as z:
            pixels, xy, origin, smoothing = (z[k] for k in ("pixels", "xy", "origin", "smoothing"))
            probe = z["probe_length_m"] if "probe_length_m" in z.files else np.array(DEFAULT_PROBE_LENGTH_M)
    except Exception as exc:  # zipfile, numpy and the OS raise several types on a damaged file
        raise InputError(
            path, f"is not a location reference from 'fit-reference' ({type(exc).__name__}: {exc})"
        ) from None
    if any(a.dtype.kind not in "fiu" for a in (pixels, xy, origin, smoothing, probe)):
        raise InputError(path, "is not a location reference: its arrays must hold numbers")
    if pixels.ndim != 2 or pixels.shape[1:] != (2,) or xy.shape != pixels.shape or origin.shape != (3,):
        raise InputError(path, "is not a location reference: pixels/xy must be (n, 2), origin 3 numbers")
    if smoothing.shape != () or not (np.isfinite(smoothing) and smoothing >= 0):
        raise InputError(path, "is not a location reference: smoothing must be one number >= 0")
    if probe.shape != () or not (np.isfinite(probe) and probe > 0):
        raise InputError(path, "is not a location reference: probe_length_m must be one number > 0")
    check_pairs(pixels, xy, path)
    try:
        frame = LocalFrame(*(float(v) for v in origin))
    except ValueError as exc:
        raise InputError(path, str(exc)) from None
    try:
        ref = LocationReference(pixels, xy, frame, float(smoothing), float(probe))
        finite = bool(np.isfinite(ref.locate(pixels)).all())
    except (ValueError, RuntimeError) as exc:  # a singular fit (LinAlgError), a degenerate hull (Qhull)
        raise InputError(path, f"its pairs make no map ({type(exc).__name__})") from None
    if not finite:
        raise InputError(path, "its pairs make no finite map (numbers too large?)")
    return ref


def kfold_errors(
    pixels: Any, xy: Any, *, folds: int = 5, smoothing: float = DEFAULT_SMOOTHING, seed: int = 0
) -> np.ndarray:
    """Held-out error (metres) of every pair: the pairs are shuffled (``seed``) into ``folds`` parts;
    each part is located by a spline fitted to the others and compared with its recorded position."""
    px, p = np.asarray(pixels, np.float64), np.asarray(xy, np.float64)
    if folds < 2 or folds > len(px):
        raise ValueError(f"folds must lie in 2…{len(px)} (the number of pairs), not {folds}")
    order = np.random.default_rng(seed).permutation(len(px))
    err = np.empty(len(px))
    for part in np.array_split(order, folds):
        train = np.setdiff1d(order, part)
        rbf = _fit(px[train], p[train], smoothing)
        err[part] = np.linalg.norm(rbf(px[part] / PIXEL_SCALE) - p[part], axis=1)
    return err
