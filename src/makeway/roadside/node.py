"""The roadside node's core: vision tracks on a pole camera → EVs on the road → signed alerts.

Each frame's :class:`~makeway.messages.PerceptionFrame` (Framework B: boxes, track ids and the
per-track EV state the pipeline reports, whichever rule flagged it) goes to :meth:`RoadsideNode.update`.
Every track's box is located on the road by its ground-contact point (bottom centre,
:func:`~makeway.roadside.transform.box_ground_pixel`) through the calibrated
:class:`~makeway.roadside.transform.RoadCamera`, pushed farther along the viewing direction to aim
at the footprint's centre — half the typical length of the track's detector class
(:func:`~makeway.roadside.transform.typical_length_m`), or a fixed ``behind_m`` — and filtered by a
constant-velocity Kalman filter in the road frame (state ``x, y, v_x, v_y``: metres, m/s;
:func:`makeway.fuse.kalman.cv_predict`). The measurement noise comes from the pixel noise of the
contact point (``contact_sigma`` × box height, pixels) carried through the camera: the road-plane
Jacobian of the pixel, so far vehicles, where a pixel spans metres, weigh less.

:meth:`RoadsideNode.due_alerts` is called with the video time; on each tick of the alert clock
(``rate_hz``) it returns one :class:`EVReport` per track the pipeline currently flags as an active EV
with a settled filter (at least ``min_updates`` located boxes): position predicted to the tick time,
east/north in the road frame and WGS-84 through the calibration's origin, heading (degrees clockwise
from the road frame's ``+y``, taken as north) and speed from the filter's velocity, and their 1-σ
uncertainties. :func:`sign_report` turns a report into a signed alert
(:mod:`makeway.v2x.message`, :mod:`makeway.v2x.security`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from makeway.fuse.kalman import cv_predict
from makeway.messages import PerceptionFrame
from makeway.roadside.transform import RoadCamera, box_ground_pixel, typical_length_m
from makeway.v2x.message import Alert
from makeway.v2x.security import GenerationLocation, Identity, sign_alert

__all__ = ["EVReport", "RoadFilter", "RoadsideNode", "camera_location", "sign_report"]

#: White acceleration noise of the road-frame filter (m/s², per axis): urban driving and braking.
ACCEL_NOISE_MPS2 = 3.0
#: Pixel noise of a box's ground-contact point, as a fraction of the box height.
CONTACT_SIGMA = 0.05
#: Tracks not updated for this long (s) are dropped.
STALE_S = 1.0


@dataclass(frozen=True)
class EVReport:
    """One active EV at ``time_s`` (video seconds): road frame ``x_m``, ``y_m``; WGS-84 ``lat_deg``,
    ``lon_deg`` (``None`` without an origin); ``heading_deg`` clockwise from the road frame's north;
    ``speed_mps``; 1-σ ``position_sigma_m`` (the larger axis of the position covariance),
    ``speed_sigma_mps`` and ``heading_sigma_deg`` (``None`` while the EV is too slow for a heading)."""

    track_id: int
    time_s: float
    x_m: float
    y_m: float
    lat_deg: float | None
    lon_deg: float | None
    heading_deg: float
    speed_mps: float
    position_sigma_m: float
    speed_sigma_mps: float
    heading_sigma_deg: float | None

    def to_json(self) -> dict[str, Any]:
        return dict(self.__dict__)


class RoadFilter:
    """Constant-velocity Kalman filter of one vehicle on the road (``x, y, v_x, v_y``; m, m/s)."""

    def __init__(self, xy: np.ndarray, cov_xy: np.ndarray, time_s: float, initial_speed_sigma: float = 10.0):
        self.state = np.array([xy[0], xy[1], 0.0, 0.0])
        self.cov = np.zeros((4, 4))
        self.cov[:2, :2] = cov_xy
        self.cov[2, 2] = self.cov[3, 3] = initial_speed_sigma**2
        self.time_s = time_s
        self.updates = 1

    def predicted(self, time_s: float) -> tuple[np.ndarray, np.ndarray]:
        """State and covariance predicted to ``time_s`` (not stored)."""
        dt = max(0.0, time_s - self.time_s)
        s, c = cv_predict(self.state, self.cov, dt, ACCEL_NOISE_MPS2)
        return s, c

    def update(self, xy: np.ndarray, cov_xy: np.ndarray, time_s: float) -> None:
        """Predict to ``time_s`` and take a road-point measurement with covariance ``cov_xy`` (m²)."""
        s, c = self.predicted(time_s)
        h = np.zeros((2, 4))
        h[0, 0] = h[1, 1] = 1.0
        innov = xy - h @ s
        sk = h @ c @ h.T + cov_xy
        gain = c @ h.T @ np.linalg.inv(sk)
        self.state = s + gain @ innov
        self.cov = (np.eye(4) - gain @ h) @ c
        self.cov = 0.5 * (self.cov + self.cov.T)
        self.time_s = time_s
        self.updates += 1


class RoadsideNode:
    """Tracks on the pole camera → EV reports on the alert clock (module docstring).

    Args:
        camera: the calibrated camera (its ``origin`` gives WGS-84; without one, lat/lon are None).
        rate_hz: alert rate while an EV is active.
        behind_m: metres pushed beyond the near-face road point; ``None`` (default): half the
            typical length of each track's detector class.
        min_updates: located boxes a track needs before it is reported.
        max_range_m: boxes located farther than this from the pole's foot (m) are ignored: beyond
            the calibrated area a pixel spans many metres.
    """

    def __init__(
        self,
        camera: RoadCamera,
        *,
        rate_hz: float = 10.0,
        behind_m: float | None = None,
        min_updates: int = 3,
        max_range_m: float = 150.0,
    ) -> None:
        if not (rate_hz > 0 and math.isfinite(rate_hz)):
            raise ValueError(f"rate must be a positive number of Hz, not {rate_hz}")
        self.camera = camera
        self.period_s = 1.0 / rate_hz
        self.behind_m = behind_m
        self.min_updates = min_updates
        self.max_range_m = max_range_m
        self.filters: dict[int, RoadFilter] = {}
        self.active: set[int] = set()
        self._next_tick: float | None = None

    def _measure(self, box: np.ndarray, label: str) -> tuple[np.ndarray, np.ndarray] | None:
        """A box ``x1, y1, x2, y2`` (pixels) of a vehicle of detector class ``label`` → its road
        point and that point's covariance (m²), or None off the road or beyond ``max_range_m``."""
        px = box_ground_pixel(box)
        sigma = max(1.0, CONTACT_SIGMA * float(box[3] - box[1]))
        nudged = px + np.array([[0.0, 0.0], [sigma, 0.0], [0.0, sigma]])
        behind = 0.5 * float(typical_length_m(label)) if self.behind_m is None else self.behind_m
        pts = self.camera.locate(nudged, behind_m=behind)
        if not np.isfinite(pts).all():
            return None
        if np.linalg.norm(pts[0] - self.camera.position_m[:2]) > self.max_range_m:
            return None
        jac = np.stack([pts[1] - pts[0], pts[2] - pts[0]], axis=1)  # metres per sigma
        return pts[0], jac @ jac.T + np.eye(2) * 0.05**2

    def update(self, frame: PerceptionFrame) -> None:
        """Take one frame's tracks and EV states."""
        t = frame.time_s
        for track in frame.tracks:
            m = self._measure(track.box.as_array(), track.label)
            if m is None:
                continue
            f = self.filters.get(track.track_id)
            if f is None:
                self.filters[track.track_id] = RoadFilter(m[0], m[1], t)
            else:
                f.update(m[0], m[1], t)
        self.active = {s.track_id for s in frame.ev_states if s.active}
        for tid in [k for k, f in self.filters.items() if t - f.time_s > STALE_S]:
            del self.filters[tid]

    def due_alerts(self, time_s: float) -> list[EVReport]:
        """Reports for every tick of the alert clock up to ``time_s`` (video seconds) not yet
        reported; empty while no flagged track has a settled filter."""
        out: list[EVReport] = []
        if self._next_tick is None:
            self._next_tick = time_s
        while self._next_tick <= time_s + 1e-9:
            tick = self._next_tick
            self._next_tick = tick + self.period_s
            for tid in sorted(self.active):
                f = self.filters.get(tid)
                if f is not None and f.updates >= self.min_updates:
                    out.append(self._report(tid, f, tick))
        return out

    def _report(self, track_id: int, f: RoadFilter, time_s: float) -> EVReport:
        s, c = f.predicted(time_s)
        vx, vy = float(s[2]), float(s[3])
        speed = math.hypot(vx, vy)
        heading = math.degrees(math.atan2(vx, vy)) % 360.0  # clockwise from +y (north)
        pos_sigma = math.sqrt(float(np.linalg.eigvalsh(c[:2, :2]).max()))
        vel_cov = c[2:, 2:]
        if speed > 1e-6:
            u = np.array([vx, vy]) / speed
            speed_sigma = math.sqrt(float(u @ vel_cov @ u))
            n = np.array([-u[1], u[0]])
            cross = math.sqrt(float(n @ vel_cov @ n))
            heading_sigma: float | None = math.degrees(math.atan2(cross, speed)) if speed > cross else None
        else:
            speed_sigma = math.sqrt(float(np.linalg.eigvalsh(vel_cov).max()))
            heading_sigma = None
        lat = lon = None
        if self.camera.origin is not None:
            la, lo, _ = self.camera.origin.to_geodetic(s[:2])
            lat, lon = float(la), float(lo)
        return EVReport(
            track_id=track_id,
            time_s=time_s,
            x_m=float(s[0]),
            y_m=float(s[1]),
            lat_deg=lat,
            lon_deg=lon,
            heading_deg=heading,
            speed_mps=speed,
            position_sigma_m=pos_sigma,
            speed_sigma_mps=speed_sigma,
            heading_sigma_deg=heading_sigma,
        )


def camera_location(camera: RoadCamera) -> GenerationLocation | None:
    """Where a pole camera's alerts are generated (1609.2's generationLocation): the camera centre in
    WGS-84, with its ellipsoidal height; ``None`` when the calibration has no WGS-84 origin."""
    if camera.origin is None:
        return None
    lat, lon, h = camera.origin.to_geodetic(np.asarray(camera.position_m, np.float64))
    return GenerationLocation.from_degrees(float(lat), float(lon), float(h))


def sign_report(
    report: EVReport,
    identity: Identity,
    sequence: int,
    generation_time_s: float,
    *,
    siren: bool = False,
    location: GenerationLocation | None = None,
) -> tuple[Alert, bytes]:
    """The alert for ``report`` (lights in use: the vision pipeline flagged the EV active; siren as
    told, a camera cannot hear it) stamped ``generation_time_s`` (Unix s), and its signed bytes,
    generated at ``location`` (the unit's position, :func:`camera_location`; ``None``: the EV's).
    Needs a report with WGS-84 coordinates."""
    if report.lat_deg is None or report.lon_deg is None:
        raise ValueError("the calibration has no WGS-84 origin: alerts need latitude and longitude")
    alert = Alert.from_physical(
        station_id=identity.station_id,
        generation_time_s=generation_time_s,
        sequence=sequence,
        lat_deg=report.lat_deg,
        lon_deg=report.lon_deg,
        heading_deg=report.heading_deg,
        speed_mps=report.speed_mps,
        siren=siren,
        lights=True,
        position_sigma_m=report.position_sigma_m,
        heading_sigma_deg=report.heading_sigma_deg,
        speed_sigma_mps=report.speed_sigma_mps,
    )
    return alert, sign_alert(alert, identity, location)
