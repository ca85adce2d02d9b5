"""The simulated traffic camera of :mod:`makeway.sim.traffic` as a calibrated roadside camera, and
what it sees: boxes of vehicles with their true road positions, and the pixel ↔ GNSS pairs a
calibration drive would record.

The simulator's world frame (``x`` across the road to the right of the camera, ``y`` along it away
from the camera, ``z`` up, metres) is taken as the road frame: ``x`` east, ``y`` north (the road runs
north); its origin lies at :data:`SIM_ORIGIN` on WGS-84. A vehicle's true position is the centre of
its footprint (``TruthBox.position_m``); its range is the horizontal distance from the foot of the
camera's pole.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from makeway.roadside.geodesy import LocalFrame
from makeway.roadside.transform import RoadCamera, box_ground_pixel
from makeway.sense.camera import PinholeCamera
from makeway.sim.traffic import Camera as SimCamera
from makeway.sim.traffic import TrafficConfig, simulate_scene

__all__ = [
    "CALIBRATION_SEEDS",
    "SIM_ORIGIN",
    "SimObservations",
    "sim_observations",
    "sim_pairs",
    "sim_road_camera",
]

#: Traffic seeds of the simulated calibration drive (scenes without EVs; together they cover every lane).
CALIBRATION_SEEDS = (101, 102, 103)
#: WGS-84 origin given to the simulated road frame (a point on Texas A&M's RELLIS campus, seed 001).
SIM_ORIGIN = LocalFrame(30.6280, -96.4818, 0.0)


def sim_road_camera(
    config: TrafficConfig | None = None, origin: LocalFrame | None = SIM_ORIGIN
) -> RoadCamera:
    """The simulated traffic camera (of ``config``; default the default scene) as a :class:`RoadCamera`."""
    sim = SimCamera.from_config(config if config is not None else TrafficConfig())
    cam = PinholeCamera(sim.width, sim.height, sim.focal_px, sim.focal_px, 0.5 * sim.width, 0.5 * sim.height)
    return RoadCamera(cam, sim.axes.T.copy(), np.array(sim.position, np.float64), origin)


@dataclass(frozen=True)
class SimObservations:
    """Detections of a simulated scene matched to the vehicles they detect (one row each).

    ``boxes`` ``(n, 4)`` pixels ``x1, y1, x2, y2``; ``truth_xy`` ``(n, 2)`` the vehicle's footprint
    centre in the road frame (m); ``range_m`` its horizontal distance from the pole (m); ``kind`` the
    vehicle kind name (car, truck, bus, motorcycle, police, ambulance, fire); ``actor_id``; ``frame``.
    """

    boxes: np.ndarray
    truth_xy: np.ndarray
    range_m: np.ndarray
    kind: np.ndarray
    actor_id: np.ndarray
    frame: np.ndarray

    def select(self, mask: np.ndarray) -> SimObservations:
        """The rows where ``mask`` is true."""
        return SimObservations(*(getattr(self, f)[mask] for f in self.__dataclass_fields__))


def sim_observations(
    config: TrafficConfig, *, max_range_m: float = 100.0, every: int = 1, truth_boxes: bool = False
) -> SimObservations:
    """The simulated detector's boxes (or with ``truth_boxes`` the true boxes) of every vehicle that
    is counted in the ground truth, whose box is not cut by the image border, within ``max_range_m``
    of the pole, on every ``every``-th frame."""
    scene = simulate_scene(config)
    foot = np.array(scene.camera.position[:2])
    rows: list[tuple[tuple[float, ...], tuple[float, float], str, int, int]] = []
    for frame in scene.frames[::every]:
        truth = {t.actor_id: t for t in frame.truth}
        sources = (
            [(t.actor_id, t.box) for t in frame.truth]
            if truth_boxes
            else [(d.actor_id, d.detection.box) for d in frame.detections if d.actor_id >= 0]
        )
        for actor_id, box in sources:
            t = truth.get(actor_id)
            if t is None or not t.considered or t.box != t.full_box:
                continue
            if float(np.hypot(*(np.array(t.position_m) - foot))) > max_range_m:
                continue
            kind = scene.actors[actor_id].kind.name
            rows.append(((box.x1, box.y1, box.x2, box.y2), t.position_m, kind, actor_id, frame.index))
    boxes = np.array([r[0] for r in rows], np.float64).reshape(-1, 4)
    xy = np.array([r[1] for r in rows], np.float64).reshape(-1, 2)
    return SimObservations(
        boxes,
        xy,
        np.hypot(*(xy - foot).T),
        np.array([r[2] for r in rows], dtype=object),
        np.array([r[3] for r in rows], np.int64),
        np.array([r[4] for r in rows], np.int64),
    )


def sim_pairs(
    seeds: Sequence[int] = CALIBRATION_SEEDS,
    *,
    kind: str = "car",
    every: int = 5,
    max_range_m: float = 110.0,
    gnss_sigma_m: float = 0.02,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Pixel ↔ road pairs of a calibration drive: in the default scene without EVs, one per traffic
    ``seeds`` (so every lane is driven), the detector's box bottom centre of every vehicle of ``kind``
    (the probe cars) on every ``every``-th frame, paired with its footprint centre plus GNSS noise
    (σ = ``gnss_sigma_m`` per axis, RTK class; ``seed``). Returns pixels ``(n, 2)`` and road points
    ``(n, 2)`` metres."""
    pixels, xy = [], []
    for s in seeds:
        obs = sim_observations(TrafficConfig(seed=s, evs=()), max_range_m=max_range_m, every=every)
        obs = obs.select(obs.kind == kind)
        pixels.append(box_ground_pixel(obs.boxes))
        xy.append(obs.truth_xy)
    truth = np.concatenate(xy)
    rng = np.random.default_rng(seed)
    return np.concatenate(pixels), truth + rng.normal(0.0, gnss_sigma_m, truth.shape)
