"""Camera vehicle tracks as directions in the vehicle frame (issue 26 item 2: the obstacles a fused
EV belief is linked to, as an audio event carries an obstacle id).

:func:`vehicle_bearings` turns one camera's SORT tracks (Framework B: detector → SORT → crop
classifier → smoother) into :class:`~makeway.messages.VehicleBearing` messages through the rig's
camera model (:mod:`makeway.sense.rig`; pinhole or Kannala–Brandt fisheye): the azimuth of the ray
through the box centre, and the box's angular half-width from the rays through its left and right
edges at the centre row. The azimuth's standard deviation combines ``pixel_sigma_px`` of box
jitter with the spread of a point drawn uniformly across the box (half-width / √3): where on the
body the siren or the light bar sits is not known. Boxes are clipped to the image; a box whose
centre lies beyond the lens model's field gives no bearing.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np

from makeway.messages import EVState, EVTrackState, Track, VehicleBearing
from makeway.sense.rig import Rig

__all__ = ["vehicle_bearings"]


def _azimuths(rays: np.ndarray) -> np.ndarray:
    return np.arctan2(rays[..., 1], rays[..., 0])


def vehicle_bearings(
    rig: Rig,
    camera: str,
    tracks: Iterable[Track],
    time_s: float,
    ev_states: Sequence[EVTrackState] = (),
    pixel_sigma_px: float = 2.0,
) -> list[VehicleBearing]:
    """The tracks of camera ``camera`` of ``rig`` at ``time_s`` (s) as vehicle-frame bearings
    (module docstring); ``ev_states`` (the smoother's output for the same frame) sets each
    bearing's ``active``. An unknown camera raises :class:`~makeway.errors.InputError`."""
    if not (math.isfinite(pixel_sigma_px) and pixel_sigma_px >= 0):
        raise ValueError(f"pixel_sigma_px must be finite and >= 0, not {pixel_sigma_px}")
    cam = rig.camera(camera)
    width, height = float(cam.camera.width), float(cam.camera.height)
    tracks = list(tracks)
    if not tracks:
        return []
    state = {s.track_id: s.state for s in ev_states}
    boxes = np.array([[t.box.x1, t.box.y1, t.box.x2, t.box.y2] for t in tracks], dtype=np.float64)
    x1 = np.clip(boxes[:, 0], 0.0, width)
    x2 = np.clip(boxes[:, 2], 0.0, width)
    yc = np.clip(0.5 * (boxes[:, 1] + boxes[:, 3]), 0.0, height)
    xc = 0.5 * (x1 + x2)
    jitter = np.clip(xc + pixel_sigma_px, 0.0, width)
    px = np.stack(
        [np.stack([u, yc], axis=-1) for u in (xc, x1, x2, jitter)], axis=0
    )  # (4, n, 2): centre, left, right, centre + jitter
    az = _azimuths(cam.ray_vehicle(px))  # NaN where a pixel lies beyond the lens model's field
    tx, ty = float(cam.translation_m[0]), float(cam.translation_m[1])
    out: list[VehicleBearing] = []
    for i, t in enumerate(tracks):
        centre = az[0, i]
        if not math.isfinite(centre):
            continue
        edges = [abs(math.remainder(float(e) - centre, math.tau)) for e in az[1:3, i] if math.isfinite(e)]
        half = max(edges) if edges else 0.0
        jit = az[3, i]
        s_px = abs(math.remainder(float(jit) - centre, math.tau)) if math.isfinite(jit) else 0.0
        st = state.get(t.track_id)
        active = None if st is None or st is EVState.WARMING_UP else st is EVState.ACTIVE
        out.append(
            VehicleBearing(
                camera=camera,
                track_id=t.track_id,
                time_s=time_s,
                azimuth_rad=centre,
                azimuth_sigma_rad=math.hypot(s_px, half / math.sqrt(3.0)),
                half_width_rad=half,
                camera_xy_m=(tx, ty),
                active=active,
            )
        )
    return out
