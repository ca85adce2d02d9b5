"""A seeded traffic scene as a fixed roadside camera sees it, with emergency vehicles (SPEC §1–2).

``makeway demo`` needs something real to track and classify on a fresh clone, with no data and no
weights. This module simulates it: a straight road with ``lanes_per_direction`` lanes each way, seen
from a camera on a pole beside the road (a roadside unit of seed 001, the thesis on
infrastructure-enabled autonomy, SPEC §5), vehicles of four COCO classes driving through it, and one
or two emergency vehicles (EVs) with flashing light bars. Per frame it produces three things:

* **Ground truth**: every vehicle's box clipped to the image, its id, class, visibility, and whether
  it is an EV whose light is lit this frame (the per-frame label of seed 000).
* **A simulated detector**: the true boxes with size-proportional Gaussian jitter, missed with a
  probability that grows as the vehicle gets smaller and more occluded, a little class confusion,
  and a few false positives on the road surface.
* **A simulated crop classifier** (seed 000's per-frame CNN): for each detection, P(active EV with a
  lit bulb in this frame). High for an EV in a lit frame, lower in the dark part of its flash
  cycle, noisy (more so on small crops), with bursts of confident false positives on some ordinary
  vehicles (brake and tail lights, the "difficult negatives" of seed 000's Fig. 1), and ``None``
  for crops narrower than ``cls_min_width_px`` (18 px, which SPEC §1 skips).

**Geometry.** World frame: metres, ``x`` across the road (to the right as seen from the camera),
``y`` along it away from the camera, ``z`` up; the road's centre line is ``x = 0``. The camera is a
pinhole at ``(camera_offset_m, 0, camera_height_m)``, turned ``camera_yaw_deg`` towards the road and
pitched ``camera_pitch_deg`` down, with focal length from ``hfov_deg``. Each vehicle is a cuboid on
the ground; its box is the bounding box of its eight projected corners, so vehicles grow and speed
up in the image as they come nearer the bottom. Traffic drives on the right: vehicles on ``x < 0``
approach the camera, those on ``x > 0`` drive away. Lane 0 is the inner (fast) lane.

**Traffic.** Arrivals per lane are a Poisson stream with a minimum headway; each vehicle has a
desired speed around its lane's speed and follows its leader with a time-gap rule, so vehicles in a
lane never drive through each other. The scene is run for ``warmup_s`` before frame 0 so the road is
already busy when the video starts. Arrivals in an EV's lane are held back shortly before it so the
EV has a free road.

**Emergency lights.** A light bar with a red and a blue half, alternating at ``flash_hz``: red lit
for ``duty/2`` of the period, dark, blue lit for ``duty/2``, dark. A frame is "lights on" when
either half is lit at the frame's time.

**Occlusion.** A vehicle's visibility is the share of its (unclipped) box that is inside the image
and not covered by the box of a vehicle nearer the camera (sampled on a 12 × 12 grid).

Everything comes from ``np.random.SeedSequence(seed)``, with separate streams for traffic, detector
and classifier, so changing a detector setting leaves the traffic unchanged.

    scene = simulate_scene(TrafficConfig(seed=0))
    for frame in scene.frames:
        detections = [d.detection for d in frame.detections]
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from makeway.messages import Box, Detection
from makeway.sense.motfile import MotData

# ------------------------------------------------------------------------------------------ classes

#: COCO-80 class ids (0-based) of the vehicle classes the simulator uses.
COCO_IDS: dict[str, int] = {"car": 2, "motorcycle": 3, "bus": 5, "truck": 7}


@dataclass(frozen=True)
class VehicleKind:
    """Size and look of one kind of vehicle: a cuboid ``length × width × height`` in metres."""

    name: str
    label: str  # the COCO class a detector would call it
    length_m: float
    width_m: float
    height_m: float
    colours_bgr: tuple[tuple[int, int, int], ...]

    @property
    def class_id(self) -> int:
        return COCO_IDS[self.label]


_CAR_COLOURS = (
    (235, 235, 235),  # white
    (190, 190, 190),  # silver
    (40, 40, 40),  # black
    (110, 110, 110),  # grey
    (120, 60, 20),  # dark blue
    (40, 40, 170),  # red
    (60, 110, 60),  # green
    (70, 150, 200),  # beige
)

#: The ordinary vehicle kinds, by name.
VEHICLE_KINDS: dict[str, VehicleKind] = {
    "car": VehicleKind("car", "car", 4.5, 1.8, 1.5, _CAR_COLOURS),
    "motorcycle": VehicleKind("motorcycle", "motorcycle", 2.1, 0.8, 1.5, ((30, 30, 30), (40, 40, 160))),
    "truck": VehicleKind("truck", "truck", 8.0, 2.5, 3.3, ((230, 230, 230), (60, 140, 200), (150, 90, 40))),
    "bus": VehicleKind("bus", "bus", 12.0, 2.55, 3.2, ((40, 170, 230), (200, 200, 200), (60, 60, 180))),
}

#: Emergency vehicle kinds, by name.
EV_KINDS: dict[str, VehicleKind] = {
    "police": VehicleKind("police", "car", 4.9, 1.9, 1.55, ((245, 245, 245),)),
    "ambulance": VehicleKind("ambulance", "truck", 6.5, 2.3, 2.8, ((240, 240, 240),)),
    "fire": VehicleKind("fire", "truck", 10.0, 2.5, 3.3, ((30, 30, 200),)),
}


@dataclass(frozen=True)
class EVSpec:
    """One emergency vehicle of the scene.

    Args:
        kind: a key of :data:`EV_KINDS` (``police``, ``ambulance``, ``fire``).
        approaching: drives towards the camera (enters small, far away) or away from it (enters
            large at the bottom of the image).
        lane: lane index in its direction, 0 = inner (fast) lane.
        entry_s: when it enters the road section (s); it is left out when this is past the end.
        speed_mps: desired speed.
        flash_hz: light bar cycles per second (one red and one blue flash per cycle).
    """

    kind: str = "police"
    approaching: bool = True
    lane: int = 0
    entry_s: float = 1.0
    speed_mps: float = 20.0
    flash_hz: float = 2.0


_DEFAULT_EVS = (
    EVSpec("police", approaching=True, lane=0, entry_s=1.0, speed_mps=20.0, flash_hz=2.0),
    EVSpec("ambulance", approaching=False, lane=0, entry_s=8.0, speed_mps=17.0, flash_hz=3.0),
)


@dataclass(frozen=True)
class TrafficConfig:
    """Everything :func:`simulate_scene` needs; the defaults give a 20 s urban arterial scene.

    Camera: a 1280×720, 25 fps camera with a 50° horizontal field of view on a 10 m pole 9.5 m
    right of the road's centre line, turned 10° towards the road and pitched 11° down (a roadside
    unit as in seed 001; the road surface is in view from ~21 m ahead to the horizon).

    Road and traffic: two 3.5 m lanes each way over 220 m, inner lanes 16 m/s (58 km/h), outer
    13 m/s, 400 vehicles per hour per lane (light urban traffic: 12–24 vehicles seen in 20 s,
    15 with seed 0), at least 1.8 s between arrivals, desired speeds spread ±7 %, and a class mix
    of 68 % cars, 10 % motorcycles, 14 % trucks, 8 % buses. Emergency vehicles: a police car
    approaching at 20 m/s from t = 1 s (lights 2 Hz) and an ambulance driving away at 17 m/s from
    t = 8 s (3 Hz); a bulb is lit 70 % of each flash cycle.

    Ground truth counts (MOTChallenge "consider" flag) for boxes at least 10 px high and 25 %
    visible; smaller or more hidden vehicles are kept with the flag 0.

    Detector: box edges jittered with σ = 3 % of the box size; 3 % base miss rate; detection
    probability 50 % at 10.5 px box height and at 35 % visibility (logistic in both); 0.25 false
    positives per frame; 4 % class confusion. Scores rise with size and visibility.

    Classifier (logits, then a sigmoid): +3.0 for an EV in a lit frame (less when small or
    occluded), −1.0 in a dark frame, −3.5 for an ordinary vehicle, +1.0 during a brake-light glint;
    Gaussian noise σ = 1.0, up to 2.0 on crops narrower than 48 px; 12 % of approaching and 25 % of
    receding ordinary vehicles have glints, a two-state Markov chain per frame (start 0.07, stop
    0.3: on ~19 % of frames, in bursts of ~3 frames).
    """

    seed: int = 0
    duration_s: float = 20.0
    fps: float = 25.0
    # camera
    width: int = 1280
    height: int = 720
    hfov_deg: float = 50.0
    camera_height_m: float = 10.0
    camera_offset_m: float = 9.5
    camera_yaw_deg: float = 10.0
    camera_pitch_deg: float = 11.0
    # road and traffic
    lanes_per_direction: int = 2
    lane_width_m: float = 3.5
    lane_speeds_mps: tuple[float, ...] = (16.0, 13.0)
    road_length_m: float = 220.0
    flow_per_lane_per_h: float = 400.0
    min_headway_s: float = 1.8
    speed_spread: float = 0.07
    class_mix: tuple[tuple[str, float], ...] = (
        ("car", 0.68),
        ("motorcycle", 0.10),
        ("truck", 0.14),
        ("bus", 0.08),
    )
    warmup_s: float = 16.0
    # emergency vehicles
    evs: tuple[EVSpec, ...] = _DEFAULT_EVS
    ev_light_duty: float = 0.7
    ev_clear_s: float = 6.0
    # ground truth
    gt_min_height_px: float = 10.0
    gt_min_visibility: float = 0.25
    # detector
    det_jitter: float = 0.03
    det_miss_base: float = 0.03
    det_height50_px: float = 10.5
    det_height_softness_px: float = 2.0
    det_visibility50: float = 0.35
    det_visibility_softness: float = 0.07
    det_fp_per_frame: float = 0.25
    det_class_confusion: float = 0.04
    # classifier
    cls_min_width_px: float = 18.0
    cls_logit_lit: float = 3.0
    cls_logit_dark: float = -1.0
    cls_logit_normal: float = -3.5
    cls_logit_glint: float = 1.0
    cls_noise: float = 1.0
    cls_small_noise: float = 1.0
    cls_small_width_px: float = 48.0
    cls_distractor_approaching: float = 0.12
    cls_distractor_receding: float = 0.25
    cls_glint_start: float = 0.07
    cls_glint_stop: float = 0.3

    def __post_init__(self) -> None:
        if self.duration_s <= 0 or self.fps <= 0:
            raise ValueError(f"duration_s and fps must be > 0, got {self.duration_s}, {self.fps}")
        if self.width < 16 or self.height < 16:
            raise ValueError(f"image must be at least 16×16, got {self.width}×{self.height}")
        if len(self.lane_speeds_mps) < self.lanes_per_direction:
            raise ValueError("lane_speeds_mps needs one speed per lane of a direction")
        for ev in self.evs:
            if ev.kind not in EV_KINDS:
                raise ValueError(f"unknown EV kind {ev.kind!r}; known: {', '.join(EV_KINDS)}")
            if not 0 <= ev.lane < self.lanes_per_direction:
                raise ValueError(f"EV lane {ev.lane} outside 0…{self.lanes_per_direction - 1}")
        if not 0.0 < self.ev_light_duty <= 1.0:
            raise ValueError(f"ev_light_duty must lie in (0, 1], got {self.ev_light_duty}")

    @property
    def num_frames(self) -> int:
        return int(round(self.duration_s * self.fps))


# ------------------------------------------------------------------------------------------- camera


@dataclass(frozen=True)
class Camera:
    """A pinhole camera over the ground plane; see the module docstring for the frames."""

    width: int
    height: int
    focal_px: float
    position: tuple[float, float, float]
    yaw_rad: float
    pitch_rad: float

    @classmethod
    def from_config(cls, c: TrafficConfig) -> Camera:
        focal = 0.5 * c.width / math.tan(math.radians(0.5 * c.hfov_deg))
        return cls(
            c.width,
            c.height,
            focal,
            (c.camera_offset_m, 0.0, c.camera_height_m),
            math.radians(c.camera_yaw_deg),
            math.radians(c.camera_pitch_deg),
        )

    @property
    def axes(self) -> np.ndarray:
        """Rows: the camera's right, down and forward unit vectors in the world frame."""
        sy, cy = math.sin(self.yaw_rad), math.cos(self.yaw_rad)
        sp, cp = math.sin(self.pitch_rad), math.cos(self.pitch_rad)
        right = (cy, sy, 0.0)  # yaw turns the view towards -x (the road), counter-clockwise
        forward = (-sy * cp, cy * cp, -sp)
        down = (sy * sp, -cy * sp, -cp)
        return np.array([right, down, forward])

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points ``(..., 3)`` → pixels ``(..., 2)`` and depths ``(...)`` (metres).

        Pixels of points at or behind the camera plane are meaningless; check the depth.
        """
        cam = (np.asarray(points, dtype=np.float64) - np.array(self.position)) @ self.axes.T
        depth = cam[..., 2]
        safe = np.where(depth > 1e-6, depth, 1e-6)
        u = 0.5 * self.width + self.focal_px * cam[..., 0] / safe
        v = 0.5 * self.height + self.focal_px * cam[..., 1] / safe
        return np.stack([u, v], axis=-1), depth

    @property
    def horizon_v(self) -> float:
        """Image row of the horizon."""
        return 0.5 * self.height - self.focal_px * math.tan(self.pitch_rad)


# ------------------------------------------------------------------------------------------- scene


@dataclass(frozen=True)
class Actor:
    """One vehicle of the scene (constant over its life)."""

    actor_id: int
    kind: VehicleKind
    is_ev: bool
    approaching: bool
    lane: int
    lane_x_m: float
    colour_bgr: tuple[int, int, int]
    distractor: bool = False  # has bursty brake/tail-light glints that fool the classifier
    flash_hz: float = 0.0
    flash_phase: float = 0.0  # fraction of a cycle at t = 0

    @property
    def class_id(self) -> int:
        return self.kind.class_id

    @property
    def label(self) -> str:
        return self.kind.label

    def light_phase(self, time_s: float, duty: float) -> int:
        """0 = dark, 1 = red half lit, 2 = blue half lit (always 0 for an ordinary vehicle)."""
        if not self.is_ev:
            return 0
        phase = (time_s * self.flash_hz + self.flash_phase) % 1.0
        if phase < 0.5 * duty:
            return 1
        if 0.5 <= phase < 0.5 + 0.5 * duty:
            return 2
        return 0


@dataclass(frozen=True)
class TruthBox:
    """Ground truth for one vehicle in one frame.

    ``box`` is clipped to the image; ``full_box`` is not. ``considered`` is the MOTChallenge
    "consider" flag: false for vehicles under ``gt_min_height_px`` or ``gt_min_visibility``.
    ``lights_on`` is the per-frame classifier label: an EV with a lit bulb in this frame.
    """

    actor_id: int
    box: Box
    full_box: Box
    class_id: int
    label: str
    is_ev: bool
    lights_on: bool
    light_phase: int
    visibility: float
    occlusion: float  # share of the in-image part hidden by nearer vehicles
    considered: bool
    depth_m: float
    position_m: tuple[float, float]  # (x, y) of the cuboid's ground centre


@dataclass(frozen=True)
class SimDetection:
    """One simulated detection, what produced it, and the simulated classifier's output on its crop.

    ``actor_id`` is -1 for a false positive. ``ev_probability`` is ``None`` when the crop is too
    small to classify.
    """

    detection: Detection
    actor_id: int
    ev_probability: float | None


@dataclass(frozen=True)
class SimFrame:
    """Ground truth, detections and classifier outputs of one frame."""

    index: int
    time_s: float
    truth: tuple[TruthBox, ...]
    detections: tuple[SimDetection, ...]


@dataclass
class Scene:
    """A simulated scene: per-frame lists, the actors, the camera, and the ground truth as MOT rows."""

    config: TrafficConfig
    camera: Camera
    actors: dict[int, Actor]
    frames: list[SimFrame]
    gt: MotData
    fps: float = field(init=False)
    width: int = field(init=False)
    height: int = field(init=False)

    def __post_init__(self) -> None:
        self.fps = self.config.fps
        self.width = self.config.width
        self.height = self.config.height

    @property
    def num_frames(self) -> int:
        return len(self.frames)

    @property
    def ev_ids(self) -> list[int]:
        """Ids of the emergency vehicles that appear in the ground truth."""
        seen = {t.actor_id for f in self.frames for t in f.truth}
        return sorted(a for a, actor in self.actors.items() if actor.is_ev and a in seen)

    @property
    def visible_ids(self) -> list[int]:
        """Ids of every vehicle with at least one considered ground-truth box."""
        return sorted({t.actor_id for f in self.frames for t in f.truth if t.considered})


# ----------------------------------------------------------------------------------------- traffic


@dataclass
class _Moving:
    """A vehicle while it is on the road: distance driven along its lane and speed."""

    actor: Actor
    desired_mps: float
    s_m: float = 0.0
    speed_mps: float = 0.0

    def y(self, road_length_m: float) -> float:
        half = 0.5 * self.actor.kind.length_m
        if self.actor.approaching:
            return road_length_m + half - self.s_m
        return half + 1.0 + self.s_m

    def gone(self, road_length_m: float) -> bool:
        return self.s_m > road_length_m + self.actor.kind.length_m + 1.0


def _lane_x(c: TrafficConfig, approaching: bool, lane: int) -> float:
    offset = (lane + 0.5) * c.lane_width_m
    return -offset if approaching else offset


def _arrivals(c: TrafficConfig, rng: np.random.Generator, start_s: float) -> list[tuple[float, bool, int]]:
    """Ordinary vehicles' ``(time, approaching, lane)`` arrivals: Poisson with a minimum headway."""
    rate = c.flow_per_lane_per_h / 3600.0
    extra = max(1.0 / rate - c.min_headway_s, 1e-3) if rate > 0 else math.inf
    out: list[tuple[float, bool, int]] = []
    for approaching in (True, False):
        for lane in range(c.lanes_per_direction):
            blocked = [
                (ev.entry_s - c.ev_clear_s, ev.entry_s + c.min_headway_s)
                for ev in c.evs
                if ev.approaching == approaching and ev.lane == lane
            ]
            t = start_s + float(rng.exponential(extra)) if math.isfinite(extra) else math.inf
            while t < c.duration_s:
                if not any(lo <= t <= hi for lo, hi in blocked):
                    out.append((t, approaching, lane))
                t += c.min_headway_s + float(rng.exponential(extra))
    out.sort()
    return out


def _pick_kind(c: TrafficConfig, rng: np.random.Generator) -> VehicleKind:
    names = [n for n, _ in c.class_mix]
    weights = np.array([w for _, w in c.class_mix], dtype=np.float64)
    return VEHICLE_KINDS[names[int(rng.choice(len(names), p=weights / weights.sum()))]]


def _corners(x: float, y: float, kind: VehicleKind) -> np.ndarray:
    """The eight corners ``(8, 3)`` of a vehicle cuboid centred on ground point ``(x, y)``.

    Corner ``4·top + 2·(right) + (far)``: bottom then top; ``-x`` then ``+x``; ``-y`` then ``+y``.
    """
    hw, hl, h = 0.5 * kind.width_m, 0.5 * kind.length_m, kind.height_m
    return np.array([[x + sx * hw, y + sy * hl, z] for z in (0.0, h) for sx in (-1, 1) for sy in (-1, 1)])


def _visibility(
    full: np.ndarray, depth: np.ndarray, width: int, height: int, k: int = 12
) -> tuple[np.ndarray, np.ndarray]:
    """Per box: share of the box inside the image and not under a nearer box; and occlusion share."""
    n = len(full)
    vis = np.zeros(n)
    occ = np.zeros(n)
    t = (np.arange(k) + 0.5) / k
    for i in range(n):
        x1, y1, x2, y2 = full[i]
        gx = (x1 + t * (x2 - x1))[None, :].repeat(k, 0).ravel()
        gy = (y1 + t * (y2 - y1))[:, None].repeat(k, 1).ravel()
        inside = (gx >= 0) & (gx < width) & (gy >= 0) & (gy < height)
        covered = np.zeros_like(inside)
        for j in np.flatnonzero(depth < depth[i]):
            a = full[j]
            covered |= (gx >= a[0]) & (gx <= a[2]) & (gy >= a[1]) & (gy <= a[3])
        n_in = int(inside.sum())
        vis[i] = float((inside & ~covered).sum()) / (k * k)
        occ[i] = float((inside & covered).sum()) / n_in if n_in else 1.0
    return vis, occ


def _sigmoid(x: float) -> float:
    return 1.0 / (1.0 + math.exp(-x)) if x >= 0 else math.exp(x) / (1.0 + math.exp(x))


# --------------------------------------------------------------------------------------- simulation


def simulate_scene(config: TrafficConfig | None = None) -> Scene:
    """Simulate ``config.duration_s`` seconds of traffic and what a detector and classifier report.

    Deterministic: the same config (seed included) gives the same scene.
    """
    c = config if config is not None else TrafficConfig()
    camera = Camera.from_config(c)
    ss = np.random.SeedSequence(c.seed)
    rng_traffic, rng_det, rng_cls = (np.random.default_rng(s) for s in ss.spawn(3))
    dt = 1.0 / c.fps
    n_warm = int(round(c.warmup_s * c.fps))
    start_s = -n_warm * dt

    # --- who enters when --------------------------------------------------------------------------
    entries: list[tuple[float, Actor, float]] = []  # (time, actor, desired speed)
    next_id = 1
    for t_arr, approaching, lane in _arrivals(c, rng_traffic, start_s):
        kind = _pick_kind(c, rng_traffic)
        colour = kind.colours_bgr[int(rng_traffic.integers(len(kind.colours_bgr)))]
        p_distractor = c.cls_distractor_approaching if approaching else c.cls_distractor_receding
        distractor = bool(rng_traffic.random() < p_distractor)
        speed = c.lane_speeds_mps[lane] * (1.0 + c.speed_spread * float(np.clip(rng_traffic.normal(), -2, 2)))
        if kind.name == "bus" or kind.name == "truck":
            speed *= 0.95
        actor = Actor(
            next_id, kind, False, approaching, lane, _lane_x(c, approaching, lane), colour, distractor
        )
        entries.append((t_arr, actor, speed))
        next_id += 1
    for ev in c.evs:
        if ev.entry_s >= c.duration_s:
            continue
        kind = EV_KINDS[ev.kind]
        actor = Actor(
            next_id,
            kind,
            True,
            ev.approaching,
            ev.lane,
            _lane_x(c, ev.approaching, ev.lane),
            kind.colours_bgr[0],
            flash_hz=ev.flash_hz,
            flash_phase=float(rng_traffic.random()),
        )
        entries.append((ev.entry_s, actor, ev.speed_mps))
        next_id += 1
    entries.sort(key=lambda e: (e[0], e[1].actor_id))
    actors = {a.actor_id: a for _, a, _ in entries}

    # --- drive ----------------------------------------------------------------------------------
    on_road: list[_Moving] = []
    glint: dict[int, bool] = {}
    pending = list(entries)
    frames: list[SimFrame] = []
    gt_rows: list[tuple[int, int, float, float, float, float, float]] = []
    n_total = n_warm + c.num_frames
    s0_m, gap_s, accel, brake = 4.0, 1.2, 2.5, 6.0
    for step in range(n_total):
        t = start_s + step * dt
        while pending and pending[0][0] <= t:
            _, actor, speed = pending.pop(0)
            on_road.append(_Moving(actor, speed, speed_mps=speed))
        # car following per lane: leader = the vehicle ahead that has driven further
        for m in on_road:
            target = m.desired_mps
            leaders = [
                o.s_m - 0.5 * (o.actor.kind.length_m + m.actor.kind.length_m) - m.s_m
                for o in on_road
                if o is not m
                and o.actor.approaching == m.actor.approaching
                and o.actor.lane == m.actor.lane
                and o.s_m > m.s_m
            ]
            if leaders:
                gap = min(leaders)
                target = min(target, max(0.0, (gap - s0_m) / gap_s))
            m.speed_mps += float(np.clip(target - m.speed_mps, -brake * dt, accel * dt))
        for m in on_road:
            m.s_m += m.speed_mps * dt
        on_road = [m for m in on_road if not m.gone(c.road_length_m)]
        # brake/tail-light glints: a two-state Markov chain per distractor
        for m in on_road:
            if m.actor.distractor:
                aid = m.actor.actor_id
                on = glint.get(aid, False)
                glint[aid] = (
                    (rng_cls.random() >= c.cls_glint_stop) if on else (rng_cls.random() < c.cls_glint_start)
                )
        if step < n_warm:
            continue
        index = step - n_warm
        time_s = index * dt
        truth = _truth(c, camera, on_road, time_s)
        for tb in truth:
            x, y, w, h = tb.box.to_xywh()
            gt_rows.append((index + 1, tb.actor_id, x, y, w, h, 1.0 if tb.considered else 0.0))
        dets = _detect(c, camera, truth, actors, glint, rng_det, rng_cls)
        frames.append(SimFrame(index, time_s, tuple(truth), tuple(dets)))

    if gt_rows:
        arr = np.array(gt_rows, dtype=np.float64)
        gt = MotData(
            arr[:, 0].astype(np.int64), arr[:, 1].astype(np.int64), arr[:, 2:6].copy(), arr[:, 6].copy()
        )
    else:
        gt = MotData(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 4)), np.zeros(0))
    return Scene(c, camera, actors, frames, gt)


def _truth(c: TrafficConfig, camera: Camera, on_road: list[_Moving], time_s: float) -> list[TruthBox]:
    """Project every vehicle; keep those with a box inside the image."""
    if not on_road:
        return []
    positions = [(m.actor.lane_x_m, m.y(c.road_length_m)) for m in on_road]
    corners = np.stack([_corners(x, y, m.actor.kind) for (x, y), m in zip(positions, on_road, strict=True)])
    px, depth = camera.project(corners)  # (n, 8, 2), (n, 8)
    centre_depth = camera.project(np.array([[x, y, 0.0] for x, y in positions]))[1]
    ok = depth.min(axis=1) > 0.5
    full = np.concatenate([px.min(axis=1), px.max(axis=1)], axis=1)
    clipped = full.copy()
    clipped[:, [0, 2]] = np.clip(clipped[:, [0, 2]], 0, c.width)
    clipped[:, [1, 3]] = np.clip(clipped[:, [1, 3]], 0, c.height)
    ok &= (clipped[:, 2] - clipped[:, 0] >= 2.0) & (clipped[:, 3] - clipped[:, 1] >= 2.0)
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        return []
    vis, occ = _visibility(full[idx], centre_depth[idx], c.width, c.height)
    out = []
    for k, i in enumerate(idx):
        actor = on_road[i].actor
        phase = actor.light_phase(time_s, c.ev_light_duty)
        box = Box(*(float(v) for v in clipped[i]))
        out.append(
            TruthBox(
                actor_id=actor.actor_id,
                box=box,
                full_box=Box(*(float(v) for v in full[i])),
                class_id=actor.class_id,
                label=actor.label,
                is_ev=actor.is_ev,
                lights_on=phase != 0,
                light_phase=phase,
                visibility=float(vis[k]),
                occlusion=float(occ[k]),
                considered=bool(box.height >= c.gt_min_height_px and vis[k] >= c.gt_min_visibility),
                depth_m=float(centre_depth[i]),
                position_m=positions[i],
            )
        )
    out.sort(key=lambda tb: tb.actor_id)
    return out


def _classify(
    c: TrafficConfig,
    width_px: float,
    truth: TruthBox | None,
    actor: Actor | None,
    glinting: bool,
    rng: np.random.Generator,
) -> float | None:
    """The simulated per-frame crop classifier: P(active EV with a lit bulb in this frame)."""
    if width_px < c.cls_min_width_px:
        return None
    small = float(
        np.clip((c.cls_small_width_px - width_px) / (c.cls_small_width_px - c.cls_min_width_px), 0, 1)
    )
    sigma = c.cls_noise + c.cls_small_noise * small
    if truth is None or actor is None:  # a false-positive detection: road surface, shadow, sign
        mean = c.cls_logit_normal
    elif actor.is_ev and truth.lights_on:
        mean = c.cls_logit_lit - 2.5 * truth.occlusion - 1.5 * small
    elif actor.is_ev:
        mean = c.cls_logit_dark
    elif glinting:
        mean = c.cls_logit_glint
    else:
        mean = c.cls_logit_normal
    return _sigmoid(mean + sigma * float(rng.normal()))


def _detect(
    c: TrafficConfig,
    camera: Camera,
    truth: list[TruthBox],
    actors: dict[int, Actor],
    glint: dict[int, bool],
    rng: np.random.Generator,
    rng_cls: np.random.Generator,
) -> list[SimDetection]:
    """The simulated detector (and classifier) on one frame."""
    out: list[SimDetection] = []
    labels = list(COCO_IDS)
    for tb in truth:
        b = tb.box
        in_image = tb.visibility / max(1.0 - tb.occlusion, 1e-6)  # share of the full box inside the image
        p_size = _sigmoid((b.height - c.det_height50_px) / c.det_height_softness_px)
        p_vis = _sigmoid(((1.0 - tb.occlusion) - c.det_visibility50) / c.det_visibility_softness)
        p_trunc = min(1.0, in_image / 0.2)
        p_det = (1.0 - c.det_miss_base) * p_size * p_vis * p_trunc
        u = rng.random()
        jit = rng.normal(size=4)
        score_noise = float(rng.normal())
        confuse = rng.random()
        if u >= p_det:
            continue
        w, h = b.width, b.height
        x1 = b.x1 + c.det_jitter * w * jit[0]
        x2 = b.x2 + c.det_jitter * w * jit[1]
        y1 = b.y1 + c.det_jitter * h * jit[2]
        y2 = b.y2 + c.det_jitter * h * jit[3]
        box = _valid_box(x1, y1, x2, y2, c.width, c.height)
        if box is None:
            continue
        label = tb.label
        if confuse < c.det_class_confusion:
            label = labels[int(rng.integers(len(labels)))]
        score = float(np.clip(0.35 + 0.6 * p_det + 0.06 * score_noise, 0.05, 0.99))
        actor = actors[tb.actor_id]
        prob = _classify(c, box.width, tb, actor, glint.get(tb.actor_id, False), rng_cls)
        out.append(SimDetection(Detection(box, score, COCO_IDS[label], label), tb.actor_id, prob))
    # false positives: car-sized boxes somewhere on the road surface
    for _ in range(int(rng.poisson(c.det_fp_per_frame))):
        half_road = c.lanes_per_direction * c.lane_width_m
        x = float(rng.uniform(-half_road - 1.0, half_road + 1.0))
        y = float(rng.uniform(20.0, 120.0))
        scale = float(rng.uniform(0.5, 1.2))
        px, depth = camera.project(_corners(x, y, VEHICLE_KINDS["car"]))
        if depth.min() <= 0.5:
            continue
        (u1, v1), (u2, v2) = px.min(axis=0), px.max(axis=0)
        cu, cv, hw, hh = 0.5 * (u1 + u2), 0.5 * (v1 + v2), 0.5 * scale * (u2 - u1), 0.5 * scale * (v2 - v1)
        box = _valid_box(cu - hw, cv - hh, cu + hw, cv + hh, c.width, c.height)
        if box is None:
            continue
        score = float(rng.uniform(0.3, 0.55))
        prob = _classify(c, box.width, None, None, False, rng_cls)
        out.append(SimDetection(Detection(box, score, COCO_IDS["car"], "car"), -1, prob))
    return out


def _valid_box(x1: float, y1: float, x2: float, y2: float, width: int, height: int) -> Box | None:
    box = Box(min(x1, x2), min(y1, y2), max(x1, x2), max(y1, y2)).clip(width, height)
    return box if box.width >= 2.0 and box.height >= 2.0 else None


# ---------------------------------------------------------------------------------------- rendering


class SceneRenderer:
    """Draw a synthetic camera image of a scene frame: sky, grass, road, lane marks, vehicles.

    Vehicles are shaded cuboids drawn far to near (so nearer ones hide farther ones, as the
    occlusion model assumes); EVs carry a light bar whose red and blue halves light up with the
    simulated flash pattern. The static background is drawn once and copied per frame.

    Args:
        scene: the simulated scene.
        scale: output size relative to the camera image (0.5 draws at 640×360).
    """

    def __init__(self, scene: Scene, scale: float = 1.0) -> None:
        if scale <= 0:
            raise ValueError(f"scale must be > 0, got {scale}")
        self.scene = scene
        self.scale = float(scale)
        self.width = max(2, int(round(scene.width * scale)))
        self.height = max(2, int(round(scene.height * scale)))
        self._background = self._draw_background()

    # --------------------------------------------------------------------------------- helpers
    def _px(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        px, depth = self.scene.camera.project(points)
        return px * self.scale, depth

    def _poly(self, img: np.ndarray, pts: np.ndarray, colour: tuple[int, int, int]) -> None:
        cv2.fillConvexPoly(img, np.round(pts * 16).astype(np.int32), colour, cv2.LINE_AA, shift=4)

    def _ground_quad(
        self, img: np.ndarray, x1: float, x2: float, y1: float, y2: float, colour: tuple[int, int, int]
    ) -> None:
        pts, depth = self._px(np.array([[x1, y1, 0.0], [x2, y1, 0.0], [x2, y2, 0.0], [x1, y2, 0.0]]))
        if depth.min() > 0.3:
            self._poly(img, pts, colour)

    def _draw_background(self) -> np.ndarray:
        c = self.scene.config
        w, h = self.width, self.height
        img = np.empty((h, w, 3), dtype=np.uint8)
        horizon = int(round(self.scene.camera.horizon_v * self.scale))
        horizon = min(max(horizon, 0), h)
        rows = np.arange(h, dtype=np.float64)[:, None]
        sky_t = np.clip(rows / max(horizon, 1), 0, 1)
        sky = (np.array([235, 200, 150]) * (1 - sky_t) + np.array([250, 230, 205]) * sky_t).astype(np.uint8)
        grass_t = np.clip((rows - horizon) / max(h - horizon, 1), 0, 1)
        grass = (np.array([95, 140, 110]) * (1 - grass_t) + np.array([60, 120, 70]) * grass_t).astype(
            np.uint8
        )
        img[:] = np.where(rows[..., None] < horizon, sky[:, None, :], grass[:, None, :])
        half = c.lanes_per_direction * c.lane_width_m
        far = 3000.0
        self._ground_quad(img, -half - 1.5, half + 1.5, 1.0, far, (150, 150, 150))  # shoulders
        self._ground_quad(img, -half, half, 1.0, far, (95, 95, 95))  # asphalt
        for sgn in (-1, 1):  # solid edge lines
            self._ground_quad(img, sgn * half - 0.1, sgn * half + 0.1, 1.0, far, (235, 235, 235))
        self._ground_quad(img, -0.22, -0.06, 1.0, far, (40, 200, 230))  # double yellow centre line
        self._ground_quad(img, 0.06, 0.22, 1.0, far, (40, 200, 230))
        for k in range(1, c.lanes_per_direction):  # dashed lane lines: 3 m dash, 9 m gap
            for sgn in (-1, 1):
                x = sgn * k * c.lane_width_m
                for y0 in np.arange(2.0, 600.0, 12.0):
                    self._ground_quad(img, x - 0.08, x + 0.08, y0, y0 + 3.0, (230, 230, 230))
        return img

    def _draw_vehicle(self, img: np.ndarray, tb: TruthBox, actor: Actor) -> None:
        kind = actor.kind
        x, y = tb.position_m
        corners = _corners(x, y, kind)
        px, depth = self._px(corners)
        if depth.min() <= 0.5:
            return
        cam = np.array(self.scene.camera.position)
        base = np.array(actor.colour_bgr, dtype=np.float64)
        # faces as corner indices (see _corners: index = 4*z + 2*sx + sy) with outward normals
        faces = (
            ((4, 5, 7, 6), (0.0, 0.0, 1.0), 1.1),  # roof
            ((0, 1, 5, 4), (-1.0, 0.0, 0.0), 0.7),  # left side
            ((2, 3, 7, 6), (1.0, 0.0, 0.0), 0.7),  # right side
            ((0, 2, 6, 4), (0.0, -1.0, 0.0), 0.9),  # near end (towards the camera)
            ((1, 3, 7, 5), (0.0, 1.0, 0.0), 0.9),  # far end
        )
        for idx, normal, shade in faces:
            pts3 = corners[list(idx)]
            if float(np.dot(np.array(normal), cam - pts3.mean(axis=0))) <= 0:
                continue
            b, g, r = (int(v) for v in np.clip(base * shade + 10, 0, 255))
            self._poly(img, px[list(idx)], (b, g, r))
            if normal[1] < 0:  # the end that faces the camera: window band and lamps
                self._end_details(img, corners[list(idx)], facing_front=actor.approaching, kind=kind)
        if actor.is_ev:
            self._light_bar(img, x, y, actor, tb.light_phase)

    def _end_details(
        self, img: np.ndarray, quad: np.ndarray, *, facing_front: bool, kind: VehicleKind
    ) -> None:
        """A dark window band and two lamps on the face towards the camera (quad: bl, br, tr, tl)."""
        bl, br, _tr, tl = quad
        lo, hi = (0.55, 0.9) if kind.name != "motorcycle" else (0.7, 0.95)

        def at(fx: float, fz: float) -> np.ndarray:
            return bl + fx * (br - bl) + fz * (tl - bl)

        window = np.array([at(0.1, lo), at(0.9, lo), at(0.9, hi), at(0.1, hi)])
        px, _ = self._px(window)
        self._poly(img, px, (60, 45, 35))
        lamp = (200, 245, 255) if facing_front else (30, 30, 220)
        for fx in (0.08, 0.78):
            q = np.array([at(fx, 0.2), at(fx + 0.14, 0.2), at(fx + 0.14, 0.32), at(fx, 0.32)])
            px, _ = self._px(q)
            self._poly(img, px, lamp)

    def _light_bar(self, img: np.ndarray, x: float, y: float, actor: Actor, phase: int) -> None:
        kind = actor.kind
        top = kind.height_m
        near_y = y - 0.5 * kind.length_m + 0.25 * kind.length_m
        hw = 0.42 * kind.width_m
        for half, colour, lit in ((-1, (40, 40, 255), phase == 1), (1, (255, 90, 30), phase == 2)):
            xa, xb = (x - hw, x) if half < 0 else (x, x + hw)
            pts = np.array(
                [[xa, near_y, top + 0.22], [xb, near_y, top + 0.22], [xb, near_y, top], [xa, near_y, top]]
            )
            px, depth = self._px(pts)
            if depth.min() <= 0.5:
                continue
            shown = colour if lit else (colour[0] * 35 // 100, colour[1] * 35 // 100, colour[2] * 35 // 100)
            self._poly(img, px, shown)
            if lit:
                centre = px.mean(axis=0)
                radius = max(2, int(round(0.6 * (px[:, 0].max() - px[:, 0].min()))))
                cv2.circle(img, (int(centre[0]), int(centre[1])), radius, colour, 2, cv2.LINE_AA)
                cv2.circle(img, (int(centre[0]), int(centre[1])), max(1, radius // 3), (255, 255, 255), -1)

    # ------------------------------------------------------------------------------------- api
    @property
    def background(self) -> np.ndarray:
        """The empty road (a copy), for plotting trajectories over it."""
        return self._background.copy()

    def render(self, index: int) -> np.ndarray:
        """The synthetic BGR image of frame ``index`` (``height × width × 3`` uint8)."""
        frame = self.scene.frames[index]
        img = self._background.copy()
        for tb in sorted(frame.truth, key=lambda t: -t.depth_m):
            self._draw_vehicle(img, tb, self.scene.actors[tb.actor_id])
        return img
