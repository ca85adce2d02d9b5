"""The contract between pipeline stages: small frozen dataclasses in SI units.

Data flows sense → perceive → track → fuse → decide → plan → control (SPEC §7). Each stage consumes
and produces only the types below, so a stage can be replaced, replayed from a log or simulated
without touching its neighbours (the Apollo module/proto split, with dataclasses instead of protobuf).

Conventions, stated once here and nowhere else:

* **Image frame.** Pixels, origin at the top-left corner of the image, ``x`` to the right, ``y`` down.
  A :class:`Box` is ``(x1, y1)`` top-left to ``(x2, y2)`` bottom-right, floats, ``x2 >= x1``.
* **Vehicle frame** (later stages): metres, ``x`` forward, ``y`` left, ``z`` up, origin on the
  ground under the centre of the rear axle; angles counter-clockwise from ``x`` in radians.
* **Time.** Seconds (``time_s``) since the start of the stream; ``frame_index`` counts from 0.
* **Probabilities** are in ``[0, 1]``; ``None`` means "no valid judgement this frame" (for example a
  crop too small to classify), which the smoother skips rather than counting as negative.

Audio (``SirenObservation``), decision (``YieldDecision``), path and control messages
(``ControlCommand``, ``VehicleState``) and the fused belief (``EVBelief``) live here too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np

# --------------------------------------------------------------------------------------------- image


@dataclass(frozen=True, slots=True)
class Box:
    """An axis-aligned box in image pixels (see the module docstring for the frame)."""

    x1: float
    y1: float
    x2: float
    y2: float

    @classmethod
    def from_xywh(cls, x: float, y: float, w: float, h: float) -> Box:
        """Build from top-left corner and size, as MOTChallenge files store boxes."""
        return cls(float(x), float(y), float(x) + float(w), float(y) + float(h))

    @property
    def width(self) -> float:
        return self.x2 - self.x1

    @property
    def height(self) -> float:
        return self.y2 - self.y1

    @property
    def area(self) -> float:
        return max(0.0, self.width) * max(0.0, self.height)

    @property
    def center(self) -> tuple[float, float]:
        return (0.5 * (self.x1 + self.x2), 0.5 * (self.y1 + self.y2))

    def to_xywh(self) -> tuple[float, float, float, float]:
        return (self.x1, self.y1, self.width, self.height)

    def as_array(self) -> np.ndarray:
        """``[x1, y1, x2, y2]`` as float64."""
        return np.array([self.x1, self.y1, self.x2, self.y2], dtype=np.float64)

    def iou(self, other: Box) -> float:
        """Intersection over union with ``other`` (0 when either box is empty)."""
        iw = min(self.x2, other.x2) - max(self.x1, other.x1)
        ih = min(self.y2, other.y2) - max(self.y1, other.y1)
        if iw <= 0 or ih <= 0:
            return 0.0
        inter = iw * ih
        union = self.area + other.area - inter
        return inter / union if union > 0 else 0.0

    def clip(self, width: float, height: float) -> Box:
        """The box clipped to an image of ``width`` × ``height`` pixels."""
        return Box(
            min(max(self.x1, 0.0), width),
            min(max(self.y1, 0.0), height),
            min(max(self.x2, 0.0), width),
            min(max(self.y2, 0.0), height),
        )

    def to_dict(self) -> dict[str, float]:
        return {
            "x1": round(self.x1, 2),
            "y1": round(self.y1, 2),
            "x2": round(self.x2, 2),
            "y2": round(self.y2, 2),
        }


# ------------------------------------------------------------------------------------------- perceive


@dataclass(frozen=True, slots=True)
class Detection:
    """One object found by a detector in one frame.

    ``class_id`` is the detector's 0-based COCO-80 index (car 2, motorcycle 3, bus 5, truck 7);
    ``label`` its readable name. ``score`` is the detector's confidence in ``[0, 1]``.
    """

    box: Box
    score: float
    class_id: int = -1
    label: str = "object"


@dataclass(frozen=True, slots=True)
class LightDetection:
    """One lit emergency light found in one image (pixels of that image, see :class:`Box`).

    ``colour`` is one of ``blue``, ``red``, ``amber``, ``white``; ``score`` the detector's
    confidence in ``[0, 1]``; ``frame`` the 0-based frame index in its video (0 for a still image).
    """

    box: Box
    colour: str
    score: float
    frame: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {
            "frame": self.frame,
            "box": self.box.to_dict(),
            "colour": self.colour,
            "score": round(self.score, 4),
        }


@dataclass(frozen=True, slots=True)
class EVObservation:
    """A per-frame judgement that one tracked vehicle is an active emergency vehicle (SPEC §1).

    ``probability`` is P(active EV with a lit light in this frame); ``None`` when the frame gave no
    valid judgement (crop outside the image, too small, occluded …). ``source`` names the producer
    (``"vision"``, ``"simulated"``, …).
    """

    track_id: int
    frame_index: int
    time_s: float
    probability: float | None
    source: str = "vision"


# ---------------------------------------------------------------------------------------------- track


@dataclass(frozen=True, slots=True)
class Track:
    """A confirmed object track from the SORT tracker (SPEC §2).

    ``box`` is the Kalman-filtered box after this frame's update. ``velocity_px`` is the filtered
    centre velocity in pixels per frame ``(du, dv)``. ``hits`` counts associated detections,
    ``hit_streak`` consecutive ones, ``age`` the frames since birth, ``time_since_update`` the frames
    since the last association (0 for a track returned by ``Sort.update``).
    """

    track_id: int
    box: Box
    score: float = 1.0
    class_id: int = -1
    label: str = "object"
    hits: int = 1
    hit_streak: int = 1
    age: int = 1
    time_since_update: int = 0
    velocity_px: tuple[float, float] = (0.0, 0.0)


class EVState(StrEnum):
    """What the output smoother says about one track (SPEC §1)."""

    WARMING_UP = "warming_up"  # fewer than ``min_frames`` valid judgements so far
    INACTIVE = "inactive"
    ACTIVE = "active"


@dataclass(frozen=True, slots=True)
class EVTrackState:
    """The smoothed belief that a track is an active emergency vehicle (SPEC §1).

    ``positive_fraction`` is the share of the buffered valid judgements at or above the per-frame
    threshold; ``n_valid`` how many are buffered; ``mean_probability`` their mean.
    """

    track_id: int
    state: EVState
    positive_fraction: float
    n_valid: int
    mean_probability: float

    @property
    def active(self) -> bool:
        return self.state is EVState.ACTIVE


@dataclass(frozen=True, slots=True)
class PerceptionFrame:
    """Everything the vision stages concluded about one video frame; one line of ``tracks.jsonl``.

    ``health`` is the camera's in this frame (``None``: not checked); while it is distrusted the
    tracks are those of the last trusted frame, carried on (the tracker coasts)."""

    frame_index: int
    time_s: float
    tracks: tuple[Track, ...]
    ev_states: tuple[EVTrackState, ...] = field(default=())
    health: SensorHealth | None = None

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict: ``index`` (source frame index), ``time_s``, and per track its box, id,
        score, class and EV state; ``health`` when the camera was distrusted in this frame."""
        ev = {s.track_id: s for s in self.ev_states}
        tracks = []
        for t in self.tracks:
            s = ev.get(t.track_id)
            tracks.append(
                {
                    "id": t.track_id,
                    "box": t.box.to_dict(),
                    "score": round(float(t.score), 4),
                    "class_id": t.class_id,
                    "label": t.label,
                    "hits": t.hits,
                    "state": s.state.value if s is not None else "unclassified",
                    "ev_positive_fraction": round(s.positive_fraction, 4) if s is not None else None,
                    "ev_n_valid": s.n_valid if s is not None else 0,
                }
            )
        out: dict[str, Any] = {"index": self.frame_index, "time_s": round(self.time_s, 4), "tracks": tracks}
        if self.health is not None and not self.health.ok:
            out["health"] = self.health.to_json()
        return out


# -------------------------------------------------------------------------------------------- health


@dataclass(frozen=True, slots=True)
class SensorHealth:
    """Which channels of one sensor a perception stage trusts at ``time_s`` (s), computed from the data.

    ``sensor`` names it (``"audio"`` for the microphone array, ``"camera"`` for a camera);
    ``trusted`` holds one flag per channel (a microphone capsule, in the array's channel order; one
    entry for a camera) and ``reasons`` one word per channel: ``"ok"`` or what is wrong (``"dead"``,
    ``"clipped"``, ``"loud"``, ``"uncorrelated"``, ``"swapped"`` for a microphone; ``"frozen"``,
    ``"black"`` for a camera).
    ``repaired`` lists the channels the stage rebuilt from their neighbours before using the data
    (see :mod:`makeway.perceive.health`). Consumers (fusion, the decision) read :attr:`trust`.
    """

    time_s: float
    sensor: str
    trusted: tuple[bool, ...]
    reasons: tuple[str, ...]
    repaired: tuple[int, ...] = ()

    @property
    def ok(self) -> bool:
        """Every channel trusted."""
        return all(self.trusted)

    @property
    def trust(self) -> float:
        """The share of trusted channels, in ``[0, 1]`` (1 for a sensor with no channel listed)."""
        return sum(self.trusted) / len(self.trusted) if self.trusted else 1.0

    def faults(self) -> tuple[str, ...]:
        """One short text per distrusted channel: ``"audio:3 dead"``, ``"camera:0 frozen"``."""
        pairs = enumerate(zip(self.trusted, self.reasons, strict=True))
        return tuple(f"{self.sensor}:{k} {why}" for k, (ok, why) in pairs if not ok)

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict: ``trust`` and, per distrusted channel, its index and reason."""
        return {
            "sensor": self.sensor,
            "trust": round(self.trust, 4),
            "distrusted": {
                str(k): r for k, (ok, r) in enumerate(zip(self.trusted, self.reasons, strict=True)) if not ok
            },
            "repaired": list(self.repaired),
        }


# --------------------------------------------------------------------------------------------- audio


@dataclass(frozen=True, slots=True)
class SirenSource:
    """One siren heard in an audio window, vehicle frame (SPEC §3).

    ``bearing_rad`` (0 ahead, positive to the left); ``distance_m`` in the ground plane, ``None`` when
    the producer gives none (a classical bearing, or a further source found by time–frequency
    assignment); ``approaching`` ``None`` when undecided, ``approach_probability`` P(approaching)
    when a trained estimator gave one. ``distance_sigma``: the σ of ln distance (±1σ is
    ``distance · e^(±σ)``) when the producer states one (the far ranger, rangers with an
    uncertainty output), else ``None``. With the far ranger (opt-in,
    :mod:`makeway.perceive.audio.far_range`): ``far_probability`` P(distance > 100 m), else ``None``.
    """

    bearing_rad: float
    distance_m: float | None = None
    approaching: bool | None = None
    approach_probability: float | None = None
    far_probability: float | None = None
    distance_sigma: float | None = None


@dataclass(frozen=True, slots=True)
class SirenObservation:
    """What the siren listener concluded about the audio window ending at ``t_end`` (s); one line of
    ``makeway audio listen --jsonl``.

    ``probability`` is this window's, ``smoothed_probability`` the listener's decision value and
    ``is_siren`` the decision. ``sources`` lists the sirens heard, nearest first (empty without a
    siren). ``level_db_spl`` is the window's level in the siren band (500–1800 Hz) at the array,
    power-averaged over the capsules, ``None`` when unknown. ``health`` says which capsules the
    listener trusted in this window (``None``: not checked).
    """

    t_end: float
    is_siren: bool
    probability: float
    smoothed_probability: float
    sources: tuple[SirenSource, ...] = ()
    level_db_spl: float | None = None
    health: SensorHealth | None = None

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict (the ``listen`` message; bearings also in degrees; ``health`` only
        when the listener checked its channels and distrusted one)."""
        out: dict[str, Any] = {
            "t_end": round(self.t_end, 6),
            "is_siren": self.is_siren,
            "probability": round(self.probability, 6),
            "smoothed_probability": round(self.smoothed_probability, 6),
            "level_db_spl": None if self.level_db_spl is None else round(self.level_db_spl, 2),
            "sources": [
                {
                    "bearing_rad": round(s.bearing_rad, 6),
                    "bearing_deg": round(math.degrees(s.bearing_rad), 3),
                    "distance_m": None if s.distance_m is None else round(s.distance_m, 2),
                    "approaching": s.approaching,
                    "approach_probability": (
                        None if s.approach_probability is None else round(s.approach_probability, 4)
                    ),
                }
                for s in self.sources
            ],
        }
        for s, src in zip(self.sources, out["sources"], strict=True):
            if s.far_probability is not None:  # only with the far ranger (opt-in)
                src["far_probability"] = round(s.far_probability, 4)
            if s.distance_sigma is not None:
                src["distance_sigma"] = round(s.distance_sigma, 4)
        if self.health is not None and not self.health.ok:
            out["health"] = self.health.to_json()
        return out


# ------------------------------------------------------------------------------------- lights / v2x


@dataclass(frozen=True, slots=True)
class LightObservation:
    """One lit emergency light seen by the camera rig at ``time_s`` (s), vehicle frame.

    ``azimuth_rad`` (0 ahead, positive to the left) with standard deviation ``azimuth_sigma_rad``;
    ``range_m`` in the ground plane (from box size or elevation) with ``range_sigma_m``, ``None``
    when the rig gives none. ``probability`` is the detector's P(active EV light) in ``[0, 1]``.
    """

    time_s: float
    azimuth_rad: float
    azimuth_sigma_rad: float = math.radians(1.5)
    range_m: float | None = None
    range_sigma_m: float | None = None
    probability: float = 1.0


@dataclass(frozen=True, slots=True)
class VehicleBearing:
    """One camera's vehicle track (Framework B: detector → SORT) seen as a direction at ``time_s``
    (s), vehicle frame: the obstacle a fused EV belief can be linked to
    (:class:`~makeway.fuse.obstacles.ObstacleLinker`).

    ``azimuth_rad`` (0 ahead, positive to the left) of the ray through the box centre, from the
    camera centre ``camera_xy_m`` (vehicle frame, metres); ``azimuth_sigma_rad`` its standard
    deviation, widened by the box's angular width (a siren or light bar can sit anywhere on the
    body); ``half_width_rad`` half that angular width. ``active`` is the crop classifier's smoothed
    verdict on the track (``None``: none ran or it is still warming up).
    """

    camera: str
    track_id: int
    time_s: float
    azimuth_rad: float
    azimuth_sigma_rad: float
    half_width_rad: float = 0.0
    camera_xy_m: tuple[float, float] = (0.0, 0.0)
    active: bool | None = None

    @property
    def obstacle_id(self) -> str:
        """``camera/track_id``: the track's name across cameras (ids are per camera)."""
        return f"{self.camera}/{self.track_id}"


@dataclass(frozen=True, slots=True)
class V2XObservation:
    """One emergency vehicle's alert at ``time_s`` (s), world frame (the car's local plane).

    Position ``(x_m, y_m)`` with isotropic standard deviation ``position_sigma_m``; ``heading_rad``
    (yaw, counter-clockwise from +x) with ``heading_sigma_rad``; ``speed_mps`` with
    ``speed_sigma_mps``. ``verified`` says the alert passed signature, trust and freshness checks
    (fusion ignores any other); ``siren``/``lights`` what the alert says is on.
    """

    time_s: float
    station_id: int
    x_m: float
    y_m: float
    heading_rad: float
    speed_mps: float
    verified: bool
    position_sigma_m: float = 2.0
    heading_sigma_rad: float = math.radians(5.0)
    speed_sigma_mps: float = 1.0
    siren: bool = True
    lights: bool = True


# ------------------------------------------------------------------------------- decide / plan / control
#
# World frame: metres, x and y on the road plane (right-handed, z up), yaw counter-clockwise from +x.
# Vehicle frame as in the module docstring (x forward, y left). Steering angle δ is the front-wheel
# angle, positive to the left (counter-clockwise). Lateral error ``e_lat`` is positive when the vehicle
# is to the LEFT of the reference path (looking along the direction of travel); ``yaw_error`` =
# θ − θ_R and ``yaw_rate_error`` = θ̇ − v_x·κ_R with κ_R = 1/R signed (positive for a left turn), so
# that a positive error is corrected by a negative (rightward) steering term (SPEC §6).


@dataclass(frozen=True, slots=True)
class VehicleState:
    """The ego vehicle at one instant (SPEC §6 single-track model), world frame.

    ``vx_mps``/``vy_mps`` are the longitudinal/lateral velocities in the vehicle frame,
    ``steer_rad`` the actual front-wheel angle, ``ax_mps2`` the longitudinal acceleration.
    """

    time_s: float
    x_m: float
    y_m: float
    yaw_rad: float
    vx_mps: float
    vy_mps: float = 0.0
    yaw_rate_radps: float = 0.0
    steer_rad: float = 0.0
    ax_mps2: float = 0.0


@dataclass(frozen=True, slots=True)
class ControlCommand:
    """What the controllers ask of the actuators: front-wheel angle and longitudinal acceleration."""

    time_s: float
    steer_rad: float
    accel_mps2: float


@dataclass(frozen=True, slots=True)
class TrackingErrors:
    """Errors of the vehicle against the locally fitted reference (SPEC §6; signs above).

    ``kind`` is ``"line"`` or ``"arc"``; ``curvature_1pm`` is κ_R = 1/R (0 for a line, signed).
    """

    e_lat: float
    yaw_error: float
    yaw_rate_error: float
    curvature_1pm: float
    kind: str

    @property
    def radius_m(self) -> float:
        return 1.0 / self.curvature_1pm if self.curvature_1pm != 0.0 else float("inf")


@dataclass(frozen=True)
class ReferencePath:
    """A reference path for the ego vehicle: points in the world frame along the direction of travel.

    ``s_m`` is the arc length from the first point; ``heading_rad`` and ``curvature_1pm`` (signed,
    positive to the left) are per point. ``stop_s_m`` is where the vehicle must be stopped, if anywhere.
    """

    x_m: np.ndarray
    y_m: np.ndarray
    s_m: np.ndarray
    heading_rad: np.ndarray
    curvature_1pm: np.ndarray
    stop_s_m: float | None = None

    def __len__(self) -> int:
        return len(self.x_m)


class EVRelation(StrEnum):
    """Where an emergency vehicle is relative to the ego vehicle and its road."""

    BEHIND = "behind"  # same direction, coming up from behind
    AHEAD = "ahead"  # same direction, in front
    ONCOMING = "oncoming"  # opposite direction, approaching
    CROSSING = "crossing"  # on a crossing road, towards the intersection ahead
    UNKNOWN = "unknown"  # heard but not placed (e.g. siren only, no bearing)


@dataclass(frozen=True, slots=True)
class EVBelief:
    """The fused belief that an active emergency vehicle is around (input of the yield decision).

    ``detected`` is the smoothed yes/no; ``confidence`` in ``[0, 1]``. Position is relative to the
    ego vehicle in the vehicle frame (``rel_x_m`` forward, ``rel_y_m`` left), with ``distance_m`` and
    ``bearing_rad`` (0 ahead, positive to the left). ``approaching`` is ``None`` when unknown.
    ``lights``/``siren`` say which signals are perceived now. ``source`` names the producer;
    ``sources`` the senses supporting a fused belief (``"siren"``, ``"light"``, ``"v2x"``) and
    ``track_id`` its EV track (``None`` for a single-sense belief). ``sensor_faults`` lists the
    channels the producing stages distrusted (:meth:`SensorHealth.faults`; empty: all healthy).
    ``obstacle_id`` names the camera vehicle track (``camera/track_id``,
    :class:`VehicleBearing`) the EV was linked to (:class:`~makeway.fuse.obstacles.ObstacleLinker`);
    ``None``: not linked.
    """

    time_s: float
    detected: bool
    confidence: float
    relation: EVRelation = EVRelation.UNKNOWN
    rel_x_m: float = float("nan")
    rel_y_m: float = float("nan")
    distance_m: float = float("nan")
    bearing_rad: float = float("nan")
    approaching: bool | None = None
    lights: bool = False
    siren: bool = False
    source: str = "simulated"
    sources: tuple[str, ...] = ()
    track_id: int | None = None
    sensor_faults: tuple[str, ...] = ()
    obstacle_id: str | None = None

    @staticmethod
    def nothing(time_s: float, source: str = "simulated") -> EVBelief:
        """No emergency vehicle perceived at ``time_s``."""
        return EVBelief(time_s=time_s, detected=False, confidence=0.0, source=source)


@dataclass(frozen=True, slots=True)
class RoadContext:
    """What the map says around the ego vehicle, along its reference path (arc length ``s``).

    ``intersections`` are ``(s_start, s_end)`` intervals of the path inside an intersection box;
    ``right_edge_offset_m`` is the lateral distance from the current lane centre to where a stopped
    car's centre should be at the right edge (negative: to the right).
    """

    s_m: float
    lane_width_m: float = 3.5
    right_edge_offset_m: float = -3.0
    intersections: tuple[tuple[float, float], ...] = ()
    speed_limit_mps: float = 13.4


class YieldState(StrEnum):
    """States of the yield decision (SPEC §6)."""

    NO_EV = "no_ev"
    EV_CONFIRMED = "ev_confirmed"
    MOVING_OVER = "moving_over"
    STOPPED_WAITING = "stopped_waiting"
    EV_PASSED = "ev_passed"
    RESUMING = "resuming"


@dataclass(frozen=True, slots=True)
class YieldDecision:
    """What the yield state machine decided at ``time_s``.

    ``pull_over``: move to the right edge; ``stop_s_m``: stop at this arc length (``None``: no stop
    required); ``target_speed_mps``: the speed to hold or approach; ``action`` a short word for logs
    and metrics (``"continue"``, ``"pull_over_and_stop"``, ``"stop_before_intersection"``,
    ``"wait"``, ``"resume"`` …); ``reason`` a sentence for people. ``max_decel_mps2`` (m/s²) and
    ``max_jerk_mps3`` (m/s³): the limits the longitudinal controller may use for this stop, set only
    for a firm stop before an intersection (``None``: the controller's comfort limits).
    """

    time_s: float
    state: YieldState
    action: str
    pull_over: bool
    target_speed_mps: float
    stop_s_m: float | None = None
    reason: str = ""
    max_decel_mps2: float | None = None
    max_jerk_mps3: float | None = None
