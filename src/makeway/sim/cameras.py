"""The car's cameras in the simulated world: what the lights detector on the 4-camera fisheye rig
reports about lit emergency lights (SPEC §7; issue 26 item 1).

No images are rendered. :class:`CameraSense` turns the world's truth into the
:class:`~makeway.messages.LightObservation` messages the lights detector would publish, frame by
frame at ``rate_hz``, with the imperfections that matter for the decision (figures in
:class:`CameraFigures`, each with its source):

* **field of view** — the light (at ``light_height_m`` above the road, at the EV's centre) must
  project into the image of at least one camera of the rig (:mod:`makeway.sense.rig`; the default
  rig's four fisheyes see all round);
* **occlusion** — the line of sight from the vehicle origin to the light, on the road plane, must not
  cross the body (a rectangle) of any other vehicle in the world: a truck between the car and the EV
  hides it, another EV too. Bodies are taken as taller than the light (trucks, vans, EVs);
* **flash pattern** — each EV's light bar flashes at its own frequency (drawn from ``flash_hz``) with
  duty ``flash_duty`` and a random phase: a frame sees it only in an on-phase;
* **recall against distance** — in an on-phase a frame detects the light with the probability of the
  field figures for day or night (linear between the tabulated distances, 0 beyond the last);
* **azimuth** — the true azimuth from the vehicle origin plus Gaussian noise ``azimuth_sigma_deg``;
* **range** — from the light's box size: the true range times ``1 + N(0, range_sigma_frac)`` (at least
  ``range_sigma_min_m`` of spread) up to ``range_max_m``; ``None`` beyond (the box is a few pixels);
* **false lights** — brake lights, traffic lights and reflections that pass the detector's flash check
  now and then: Poisson events at ``false_lights_per_hour``, each lasting a duration drawn from
  ``false_light_duration_s`` at a fixed azimuth in the front camera's view (``±false_light_azimuth_deg``),
  detected in a frame with probability ``false_light_frame_prob``, no range.

Deterministic for a seed.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from makeway.frames import to_vehicle_frame
from makeway.messages import LightObservation, VehicleState
from makeway.registry import Registry
from makeway.sense.rig import Rig, load_rig
from makeway.sim.world import EVTruth, SimWorld

__all__ = ["CAMERA_FIGURES", "CameraFigures", "CameraSense", "line_of_sight_blocked", "makeway_figures"]


@dataclass(frozen=True)
class CameraFigures:
    """The camera model's figures (module docstring), with their sources.

    Recall against distance (per frame, the fraction of frames in which a lit light is detected):

    * ``recall_distances_m`` with ``recall_day`` / ``recall_night``: seed 004's static field test
      (its Table IV: a small blue beacon around a 4-fisheye car, every 15° of azimuth; ~100 % to
      20–30 m by day, ~100 % to 40–50 m at night, nothing beyond 70 m by day and 90 m at night).
      The seed's beacon is smaller than a full light bar, so these figures are conservative;
    * ``detector_recall_day`` / ``detector_recall_night``: makeway's own lights detector measured on
      real frames at the same distances, **to be plugged in** once measured (issue 26 item 1); when
      set they replace the seed's figures.

    Other figures: ``azimuth_sigma_deg`` 2° (seed 004: mean azimuth error under 2°); ``rate_hz`` the
    detector's frame rate; ``latency_s`` from frame to message; ``light_height_m`` the light bar's
    height; ``range_*`` the box-size ranging (an assumption: a 1.5 m light bar is ~20 px wide at
    40 m in the rig's fisheyes, below which its width says little); ``flash_hz`` and ``flash_duty``
    the light bars' flash pattern (typical bars flash 1.5–2.5 times a second, lit about half the
    time); ``probability`` the detector's score range on true lights. False lights:
    ``false_lights_per_hour`` is an **assumption** (one a minute of driving: seed 004 gives no
    rate, and no hours of negatives exist here — ``detector_false_lights_per_hour`` is the field for
    a detector's measured rate, :mod:`makeway.eval.false_lights`), with the event duration,
    per-frame detection probability, azimuth spread and score range of such a light.
    """

    recall_distances_m: tuple[float, ...] = (10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0)
    recall_day: tuple[float, ...] = (1.0, 1.0, 0.983, 0.634, 0.229, 0.064, 0.0, 0.0, 0.0)
    recall_night: tuple[float, ...] = (1.0, 1.0, 1.0, 0.992, 0.931, 0.593, 0.312, 0.014, 0.0)
    recall_source: str = "seed 004, static field test (Table IV)"
    detector_recall_day: tuple[float, ...] | None = None
    detector_recall_night: tuple[float, ...] | None = None
    azimuth_sigma_deg: float = 2.0
    rate_hz: float = 10.0
    latency_s: float = 0.1
    light_height_m: float = 1.9
    range_sigma_frac: float = 0.2
    range_sigma_min_m: float = 1.0
    range_max_m: float = 40.0
    flash_hz: tuple[float, float] = (1.5, 2.5)
    flash_duty: float = 0.5
    probability: tuple[float, float] = (0.7, 0.95)
    false_lights_per_hour: float = 60.0
    detector_false_lights_per_hour: float | None = None
    false_light_duration_s: tuple[float, float] = (0.2, 1.0)
    false_light_frame_prob: float = 0.6
    false_light_azimuth_deg: float = 40.0
    false_light_probability: tuple[float, float] = (0.5, 0.8)

    def __post_init__(self) -> None:
        n = len(self.recall_distances_m)
        tables = [self.recall_day, self.recall_night, self.detector_recall_day, self.detector_recall_night]
        if any(t is not None and len(t) != n for t in tables):
            raise ValueError("every recall table needs one value per distance in recall_distances_m")
        if any(t is not None and not all(0.0 <= v <= 1.0 for v in t) for t in tables):
            raise ValueError("recall values must lie in [0, 1]")
        if self.rate_hz <= 0 or self.latency_s < 0 or not 0.0 < self.flash_duty <= 1.0:
            raise ValueError("rate_hz > 0, latency_s >= 0 and 0 < flash_duty <= 1 are needed")

    def recall(self, distance_m: float, night: bool) -> float:
        """The per-frame probability of detecting a lit light ``distance_m`` away (by day or night):
        the detector's figures when set, else seed 004's."""
        if night:
            table = self.detector_recall_night or self.recall_night
        else:
            table = self.detector_recall_day or self.recall_day
        return float(np.interp(distance_m, self.recall_distances_m, table, left=table[0], right=0.0))

    @property
    def false_rate_per_hour(self) -> float:
        """False lights per hour: the detector's measured figure when set, else the assumption."""
        if self.detector_false_lights_per_hour is not None:
            return self.detector_false_lights_per_hour
        return self.false_lights_per_hour


def makeway_figures() -> CameraFigures:
    """The camera model with makeway's own lights detector by day (``verified``, the default of
    ``makeway lights``), as measured on real frames by ``benchmarks/bench_camera_figures.py``: the
    share of lit frames in which it puts a box on the ambulance of ``intersection_cam_ambulance``
    (a calibrated day camera), at the distance the rig's fisheyes would see the lamps as large —
    35.3 % at 6–10 m (68 frames), 2.5 % at 10–14 m (40), 0 % at 14–18 m (4), with its small-lamp
    verifier. Nearer than 8 m the 8 m figure holds; beyond 18 m nothing was measured and nothing
    is assumed seen. False lights by day: 123 per hour, the detector's rate on the day footage
    without a lit emergency light that no detector was trained on (29 s of two clips, one event:
    95 % interval 3–687 per hour; ``benchmarks/bench_false_lights.py``,
    :mod:`makeway.eval.false_lights`). The night table stays seed 004's (no calibrated night clip;
    on the night clip, at a few metres, the detector finds the ambulance in 88 % of frames); at
    night the detector puts about 10 boxes on every frame whose light bar is dark, which this
    model does not carry (its false lights are day figures)."""
    seed = CameraFigures()
    grid = (8.0, 12.0, 16.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0)

    def on_grid(table: tuple[float, ...]) -> tuple[float, ...]:
        return tuple(float(v) for v in np.interp(grid, seed.recall_distances_m, table))

    return CameraFigures(
        recall_distances_m=grid,
        recall_day=on_grid(seed.recall_day),
        recall_night=on_grid(seed.recall_night),
        detector_recall_day=(0.353, 0.025, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        detector_false_lights_per_hour=123.0,
        recall_source="day: makeway's verified lights detector on intersection_cam_ambulance "
        "(benchmarks/bench_camera_figures.py); night: seed 004, static field test (Table IV)",
    )


CAMERA_FIGURES: Registry[Callable[[], CameraFigures]] = Registry(
    "camera figures", {"seed004": CameraFigures, "makeway": makeway_figures}
)
"""The simulated cameras' figures by name: ``seed004`` (the default: seed 004's field test, a
detector that reaches issue 23's targets would do about this well) and ``makeway`` (today's lights
detector by day, :func:`makeway_figures`)."""


def line_of_sight_blocked(
    x0: float, y0: float, x1: float, y1: float, bodies: tuple[EVTruth, ...] | list[EVTruth]
) -> bool:
    """Whether the segment ``(x0, y0)–(x1, y1)`` (world frame, m) crosses the rectangle of any body
    (Liang–Barsky clipping in each body's own frame)."""
    for b in bodies:
        c, s = math.cos(b.heading_rad), math.sin(b.heading_rad)
        ax, ay = x0 - b.x_m, y0 - b.y_m
        bx, by = x1 - b.x_m, y1 - b.y_m
        p0 = (c * ax + s * ay, -s * ax + c * ay)
        p1 = (c * bx + s * by, -s * bx + c * by)
        d = (p1[0] - p0[0], p1[1] - p0[1])
        t0, t1 = 0.0, 1.0
        inside = True
        for k, half in ((0, 0.5 * b.length_m), (1, 0.5 * b.width_m)):
            for p, q in ((-d[k], p0[k] + half), (d[k], half - p0[k])):
                if p == 0.0:
                    if q < 0.0:
                        inside = False
                elif p < 0.0:
                    t0 = max(t0, q / p)
                else:
                    t1 = min(t1, q / p)
        if inside and t0 <= t1:
            return True
    return False


class CameraSense:
    """Light observations of the world's EVs from the camera rig, frame by frame (module docstring).

    Call :meth:`observe` at every frame time (``1/rate_hz`` apart) with the ego's state (world frame)
    and the world; it returns the frame's observations, stamped with the frame's time, in the
    vehicle frame at that state.
    """

    def __init__(
        self, figures: CameraFigures | None = None, *, rig: Rig | None = None, seed: int = 0
    ) -> None:
        self.figures = figures if figures is not None else CameraFigures()
        self.rig = rig if rig is not None else load_rig("default")
        self._rng = np.random.default_rng(np.random.SeedSequence([seed, 4004]))
        self._flash: dict[int, tuple[float, float]] = {}  # per EV key: frequency, phase
        f = self.figures
        self._next_false_s = self._draw_gap()
        self._false: tuple[float, float, float] | None = None  # until, azimuth, probability
        self._az_sigma = math.radians(f.azimuth_sigma_deg)
        self.false_events = 0  # false lights started so far

    def _draw_gap(self) -> float:
        rate = self.figures.false_rate_per_hour
        return math.inf if rate <= 0 else float(self._rng.exponential(3600.0 / rate))

    def in_view(self, rel_x: float, rel_y: float, height_m: float | None = None) -> bool:
        """Whether a point at ``(rel_x, rel_y)`` (vehicle frame, m) and ``height_m`` above the road
        projects into any camera's image."""
        z = self.figures.light_height_m if height_m is None else height_m
        p = np.array([rel_x, rel_y, z])
        for cam in self.rig.cameras:
            pc = cam.rotation.T @ (p - cam.translation_m)
            px = cam.camera.project(pc)
            if np.all(np.isfinite(px)) and bool(cam.camera.in_image(px)):
                return True
        return False

    def _lit(self, key: int, time_s: float) -> bool:
        f = self.figures
        if key not in self._flash:
            self._flash[key] = (float(self._rng.uniform(*f.flash_hz)), float(self._rng.uniform()))
        hz, phase = self._flash[key]
        return (time_s * hz + phase) % 1.0 < f.flash_duty

    def observe(self, time_s: float, ego: VehicleState, world: SimWorld) -> list[LightObservation]:
        """The lights detected in the frame taken at ``time_s`` (s)."""
        f = self.figures
        rng = self._rng
        out: list[LightObservation] = []
        evs = world.all_evs()
        for k, ev in enumerate(evs):
            if not ev.lights or not self._lit(k, time_s):
                continue
            dx, dy = ev.x_m - ego.x_m, ev.y_m - ego.y_m
            dist = math.hypot(dx, dy)
            if rng.random() >= f.recall(dist, world.night):
                continue
            rel_x, rel_y = (float(v) for v in to_vehicle_frame(dx, dy, ego.yaw_rad))
            if not self.in_view(rel_x, rel_y):
                continue
            others = [o for j, o in enumerate(evs) if j != k] + list(world.traffic)
            if line_of_sight_blocked(ego.x_m, ego.y_m, ev.x_m, ev.y_m, others):
                continue
            az = math.atan2(rel_y, rel_x) + self._az_sigma * float(rng.standard_normal())
            rng_m: float | None = None
            rng_sigma: float | None = None
            if dist <= f.range_max_m:
                rng_sigma = max(f.range_sigma_frac * dist, f.range_sigma_min_m)
                rng_m = max(1.0, dist + rng_sigma * float(rng.standard_normal()))
            out.append(
                LightObservation(
                    time_s=time_s,
                    azimuth_rad=math.atan2(math.sin(az), math.cos(az)),
                    azimuth_sigma_rad=self._az_sigma,
                    range_m=rng_m,
                    range_sigma_m=rng_sigma,
                    probability=float(rng.uniform(*f.probability)),
                )
            )
        # false lights
        if self._false is None and time_s >= self._next_false_s:
            dur = float(rng.uniform(*f.false_light_duration_s))
            az = math.radians(float(rng.uniform(-f.false_light_azimuth_deg, f.false_light_azimuth_deg)))
            self._false = (time_s + dur, az, float(rng.uniform(*f.false_light_probability)))
            self.false_events += 1
        if self._false is not None:
            until, az, p = self._false
            if time_s >= until:
                self._false = None
                self._next_false_s = time_s + self._draw_gap()
            elif rng.random() < f.false_light_frame_prob:
                noisy = az + self._az_sigma * float(rng.standard_normal())
                out.append(LightObservation(time_s, noisy, self._az_sigma, None, None, p))
        return out
