"""WGS-84 geodetic coordinates ↔ a local east-north-up (ENU) tangent frame, in metres.

The conversion is exact on the WGS-84 ellipsoid (semi-major axis ``a = 6 378 137 m``, flattening
``f = 1/298.257223563``): geodetic ``(lat, lon, h)`` → Earth-centred Earth-fixed (ECEF) → rotated into
the tangent frame at the origin ``(lat0, lon0, h0)``: ``x`` east, ``y`` north, ``z`` up (along the
ellipsoid normal at the origin), metres. The inverse goes ENU → ECEF → geodetic with Bowring's
formula refined by fixed-point iterations (sub-millimetre within Earth's atmosphere).

Over a road corridor (hundreds of metres) the frame is a metric plane: the ellipsoid drops below the
tangent plane by ``d²/2R`` (8 mm at 320 m), which the road-frame methods ignore by using ``z = 0``.
Latitudes and longitudes are degrees; heights are ellipsoidal, metres. (pyproj, which does the same,
is not a dependency of makeway.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["WGS84_A", "WGS84_E2", "WGS84_F", "LocalFrame", "ecef_from_geodetic", "geodetic_from_ecef"]

WGS84_A = 6378137.0  #: semi-major axis, metres
WGS84_F = 1.0 / 298.257223563  #: flattening
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)  #: first eccentricity squared
_B = WGS84_A * (1.0 - WGS84_F)  # semi-minor axis
_EP2 = WGS84_E2 / (1.0 - WGS84_E2)  # second eccentricity squared


def ecef_from_geodetic(lat_deg: Any, lon_deg: Any, h_m: Any = 0.0) -> np.ndarray:
    """Geodetic latitude, longitude (degrees) and ellipsoidal height (m) → ECEF ``(..., 3)`` metres."""
    lat, lon = np.radians(np.asarray(lat_deg, np.float64)), np.radians(np.asarray(lon_deg, np.float64))
    h = np.asarray(h_m, np.float64)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)  # prime-vertical radius of curvature
    x = (n + h) * np.cos(lat) * np.cos(lon)
    y = (n + h) * np.cos(lat) * np.sin(lon)
    z = (n * (1.0 - WGS84_E2) + h) * np.sin(lat)
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def geodetic_from_ecef(ecef: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ECEF ``(..., 3)`` metres → latitude, longitude (degrees), ellipsoidal height (m).

    Bowring's parametric-latitude start, then three fixed-point refinements of the latitude.
    """
    p = np.asarray(ecef, np.float64)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    r = np.hypot(x, y)
    beta = np.arctan2(_B * z, WGS84_A * r)
    lat = np.arctan2(z + _EP2 * _B * np.sin(beta) ** 3, r - WGS84_E2 * WGS84_A * np.cos(beta) ** 3)
    for _ in range(3):
        beta = np.arctan2((1.0 - WGS84_F) * np.sin(lat), np.cos(lat))
        lat = np.arctan2(z + _EP2 * _B * np.sin(beta) ** 3, r - WGS84_E2 * WGS84_A * np.cos(beta) ** 3)
    n = WGS84_A / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
    cos_lat = np.cos(lat)
    h = np.where(
        np.abs(cos_lat) > 1e-9,
        r / np.where(cos_lat == 0, 1.0, cos_lat) - n,
        np.abs(z) - n * (1.0 - WGS84_E2),
    )
    return np.degrees(lat), np.degrees(np.arctan2(y, x)), h


@dataclass(frozen=True)
class LocalFrame:
    """The ENU tangent frame at ``(lat0_deg, lon0_deg, h0_m)``: ``x`` east, ``y`` north, ``z`` up, m."""

    lat0_deg: float
    lon0_deg: float
    h0_m: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lat0_deg) and -90.0 <= self.lat0_deg <= 90.0):
            raise ValueError(f"origin latitude must lie in [-90, 90] degrees, not {self.lat0_deg}")
        if not (math.isfinite(self.lon0_deg) and -180.0 <= self.lon0_deg <= 360.0):
            raise ValueError(f"origin longitude must lie in [-180, 360] degrees, not {self.lon0_deg}")
        if not math.isfinite(self.h0_m):
            raise ValueError(f"origin height must be finite, not {self.h0_m}")

    @property
    def _rotation(self) -> np.ndarray:
        """Rows: east, north, up unit vectors in ECEF."""
        la, lo = math.radians(self.lat0_deg), math.radians(self.lon0_deg)
        sl, cl, so, co = math.sin(la), math.cos(la), math.sin(lo), math.cos(lo)
        return np.array([[-so, co, 0.0], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]])

    @property
    def _origin_ecef(self) -> np.ndarray:
        return ecef_from_geodetic(self.lat0_deg, self.lon0_deg, self.h0_m)

    def to_enu(self, lat_deg: Any, lon_deg: Any, h_m: Any = None) -> np.ndarray:
        """Latitude, longitude (degrees), height (m; default the origin's) → ENU ``(..., 3)`` metres."""
        h = self.h0_m if h_m is None else h_m
        return (ecef_from_geodetic(lat_deg, lon_deg, h) - self._origin_ecef) @ self._rotation.T

    def to_geodetic(self, enu: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """ENU ``(..., 3)`` metres (or ``(..., 2)``: on the tangent plane, ``z = 0``) → latitude,
        longitude (degrees) and ellipsoidal height (m)."""
        p = np.asarray(enu, np.float64)
        if p.shape[-1] == 2:
            p = np.concatenate([p, np.zeros((*p.shape[:-1], 1))], axis=-1)
        return geodetic_from_ecef(p @ self._rotation + self._origin_ecef)
