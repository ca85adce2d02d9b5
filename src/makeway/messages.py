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
(``ControlCommand``, ``VehicleState``) are added here by the issues that introduce those stages.
"""

from __future__ import annotations

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
    """Everything the vision stages concluded about one video frame; one line of ``tracks.jsonl``."""

    frame_index: int
    time_s: float
    tracks: tuple[Track, ...]
    ev_states: tuple[EVTrackState, ...] = field(default=())

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict: ``index`` (source frame index), ``time_s``, and per track its box, id,
        score, class and EV state."""
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
        return {"index": self.frame_index, "time_s": round(self.time_s, 4), "tracks": tracks}
