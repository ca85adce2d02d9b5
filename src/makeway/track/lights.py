"""Lit-light tracking, the temporal flash cue, and the lights evidence of Framework B's "active" rule.

:class:`LightTracker` follows the lit lights a light detector returns frame by frame (boxes in image
pixels, see :class:`~makeway.messages.LightDetection`). Detections are associated to live tracks
of the same colour by centre distance: the cost is the distance between box centres divided by the
larger of the two boxes' sizes (``max(w, h)``, at least ``min_size_px``), gated at ``gate`` and at a
size ratio of ``max_size_ratio``, and the assignment is the Hungarian one
(:func:`scipy.optimize.linear_sum_assignment`). Lights are small and move little between frames, so
IoU gating (SORT's) would drop them; a track keeps its last box while unmatched and survives gaps up
to ``max_gap_s`` seconds — a flashing lamp vanishes from the detector in its off phase.

**Flash cue.** Per track and frame the tracker measures the *level* of its region, a square around
the track's centre whose half-side is the largest box size the track has had (at least
``min_size_px``): the number of pixels lit in the track's colour, with the HSV ranges of
:data:`~makeway.perceive.vision.light_colour.DEFAULT_HSV` relaxed by ``relax_s`` in saturation and
``relax_v`` in value (for ``white``: near-white cores, value ≥ 245 − ``relax_v``), so that a lamp at
the detector's threshold does not flicker. The lamp is *on* in a frame when the level is at least
``min_level`` pixels and ``on_ratio`` of the track's peak level in the window, *off* when it is
below ``min_level`` or at most ``off_ratio`` of that peak; frames in between keep the last state.
Without the frame (``frame_bgr=None``) the level is the box area while the detector sees the light
and 0 otherwise. Over the last ``window_s`` seconds the on/off states give

* ``transitions``: the number of on↔off changes;
* ``flash_hz``: ``(k − 1) / (2 (t_k − t_1))`` from the times ``t_1 … t_k`` of the ``k ≥ 2`` changes
  (one on/off cycle holds two changes), 0.0 with fewer;
* ``duty``: the fraction of the window's frames that are on;
* ``flashing``: a peak level of at least ``min_peak_px``, at least ``min_transitions`` changes,
  ``flash_hz`` in ``[min_hz, max_hz]``, and the duty strictly between 0.05 and 0.95.

A steady light (brake light, street lamp, traffic light, headlight) stays on: no changes, not
flashing. Times are in seconds from the frame times the caller passes.

**Following vehicles.** Given the frame's vehicle tracks (``update(..., vehicles=...)``, Framework B's
SORT tracks), a light seen inside a vehicle's box, or in a band of ``anchor_band`` box heights above
it, is anchored to that vehicle (the smallest such box) at its relative place ``(u, v)`` in the box.
In the next frame with that vehicle, before association, the light's box moves so that its centre
sits at the same relative place in the vehicle's new box: the camera's and the vehicle's motion no
longer break the track, and in its off phase the level is read where the lamp now is. The video
pipeline does not pass its tracks (on the shared clips it did not help; docs/results.md, "Lit lights
in the video pipeline").

**Lights evidence** (:func:`vehicle_light_evidence`) and the **active rules**
(:func:`active_probability`) turn light tracks into per-frame votes for Framework B's vehicle
tracks: a flashing emergency-coloured light in the upper part of a vehicle's box or just above it.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from makeway.messages import Box, LightDetection, Track
from makeway.perceive.vision.light_colour import DEFAULT_HSV
from makeway.perceive.vision.lights import LIGHT_DETECTORS, LightDetector

__all__ = [
    "ACTIVE_RULES",
    "SATURATED",
    "LightTrack",
    "LightTracker",
    "active_probability",
    "build_light_detector",
    "flash_stats",
    "vehicle_light_evidence",
]

#: Colours that are emergency colours by themselves; ``white`` counts only when flashing.
SATURATED = ("blue", "red", "amber")


def build_light_detector(name: str, colours: str | Sequence[str]) -> LightDetector:
    """The registered light detector ``name`` for the colour set ``colours`` (every registered
    factory takes ``colours``; an unknown name raises the registry's error listing the known ones)."""
    factory: Any = LIGHT_DETECTORS[name]
    detector: LightDetector = factory(colours=colours)
    return detector


@dataclass(frozen=True, slots=True)
class LightTrack:
    """One tracked lit light after a frame (image pixels; times in seconds).

    ``detected`` says the detector saw it in this frame (else ``box`` is the last seen box);
    ``score`` is the last detection's score; ``age_s`` the time since the track began; ``on`` its
    on/off state in this frame; ``flash_hz``, ``duty``, ``transitions`` and ``flashing`` the flash
    cue over the tracker's window (module docstring).
    """

    track_id: int
    box: Box
    colour: str
    score: float
    detected: bool
    on: bool
    age_s: float
    flash_hz: float
    duty: float
    transitions: int
    flashing: bool

    def to_dict(self) -> dict[str, object]:
        """JSON-ready: id, box, colour, score and the flash cue (finite numbers only)."""
        return {
            "track_id": self.track_id,
            "box": self.box.to_dict(),
            "colour": self.colour,
            "score": round(float(self.score), 4),
            "detected": self.detected,
            "on": self.on,
            "flash_hz": round(float(self.flash_hz), 3),
            "duty": round(float(self.duty), 3),
            "transitions": self.transitions,
            "flashing": self.flashing,
        }


def flash_stats(times_s: Sequence[float], on: Sequence[bool]) -> tuple[int, float, float]:
    """``(transitions, flash_hz, duty)`` of an on/off sequence sampled at ``times_s`` (seconds).

    ``transitions`` counts on↔off changes; ``flash_hz`` is ``(k − 1) / (2 (t_k − t_1))`` over the
    times of the ``k`` changes (0.0 when ``k < 2``); ``duty`` is the on fraction of the samples.
    """
    if not on:
        return 0, 0.0, 0.0
    changes = [times_s[i] for i in range(1, len(on)) if on[i] != on[i - 1]]
    duty = sum(1 for x in on if x) / len(on)
    k = len(changes)
    if k < 2 or changes[-1] <= changes[0]:
        return k, 0.0, duty
    return k, (k - 1) / (2.0 * (changes[-1] - changes[0])), duty


class _Light:
    """A live light track's state (internal)."""

    __slots__ = (
        "anchor",
        "box",
        "colour",
        "first_s",
        "history",
        "id",
        "last_seen_s",
        "peak",
        "score",
        "seen",
        "size",
        "state",
    )

    def __init__(self, track_id: int, det: LightDetection, t_s: float) -> None:
        self.id = track_id
        self.box = det.box
        self.colour = det.colour
        self.score = det.score
        self.first_s = t_s
        self.last_seen_s = t_s
        self.seen = True
        self.state = True
        self.peak = 0.0
        self.size = max(det.box.width, det.box.height)
        self.history: deque[tuple[float, float, bool]] = deque()  # (t, level, on)
        self.anchor: tuple[int, float, float] | None = None  # (vehicle track id, u, v) in its box


class LightTracker:
    """Follows lit lights over frames and measures their flash pattern (module docstring).

    Args:
        window_s: length (s) of the window the flash cue is measured over.
        max_gap_s: a track unmatched for longer than this (s) ends.
        gate: largest centre distance, in units of the larger box size, for a match.
        min_size_px: smallest box size (px) used to scale distances.
        on_ratio, off_ratio: level fractions of the window's peak for on / off (hysteresis).
        min_level: levels (lit pixels) below this are off whatever the peak.
        min_transitions: on↔off changes within the window for ``flashing``.
        min_hz, max_hz: the flash frequency band (Hz) for ``flashing``.
        max_size_ratio: largest ratio of box sizes (``max(w, h)``) for a match.
        min_peak_px: smallest peak level (lit pixels) in the window for ``flashing``.
        relax_v, relax_s: how far the level's HSV ranges are relaxed in value and saturation.
        anchor_band: how far above a vehicle's box (in box heights) a light is still anchored to it.
        hsv: HSV ranges per colour for the level (default
            :data:`~makeway.perceive.vision.light_colour.DEFAULT_HSV`).
    """

    def __init__(
        self,
        *,
        window_s: float = 1.5,
        max_gap_s: float = 0.6,
        gate: float = 1.5,
        min_size_px: float = 6.0,
        on_ratio: float = 0.5,
        off_ratio: float = 0.25,
        min_level: float = 1.0,
        min_transitions: int = 3,
        min_hz: float = 0.75,
        max_hz: float = 8.0,
        max_size_ratio: float = 2.5,
        min_peak_px: int = 6,
        relax_v: int = 40,
        relax_s: int = 30,
        hsv: dict[str, list[tuple[int, int, int, int]]] | None = None,
        anchor_band: float = 0.3,
    ) -> None:
        if window_s <= 0 or max_gap_s < 0:
            raise ValueError(f"window_s must be > 0 and max_gap_s >= 0, got {window_s}, {max_gap_s}")
        if not 0.0 <= off_ratio <= on_ratio <= 1.0:
            raise ValueError(f"need 0 <= off_ratio <= on_ratio <= 1, got {off_ratio}, {on_ratio}")
        if not 0.0 < min_hz <= max_hz:
            raise ValueError(f"need 0 < min_hz <= max_hz, got {min_hz}, {max_hz}")
        self.window_s = float(window_s)
        self.max_gap_s = float(max_gap_s)
        self.gate = float(gate)
        self.min_size_px = float(min_size_px)
        self.on_ratio = float(on_ratio)
        self.off_ratio = float(off_ratio)
        self.min_level = float(min_level)
        self.min_transitions = int(min_transitions)
        self.min_hz = float(min_hz)
        self.max_hz = float(max_hz)
        self.max_size_ratio = float(max_size_ratio)
        self.min_peak_px = int(min_peak_px)
        self.relax_v = int(relax_v)
        self.relax_s = int(relax_s)
        self.hsv = dict(hsv if hsv is not None else DEFAULT_HSV)
        self.anchor_band = float(anchor_band)
        self._tracks: list[_Light] = []
        self._next_id = 1

    def reset(self) -> None:
        """Forget every track (ids start again at 1)."""
        self._tracks.clear()
        self._next_id = 1

    # ------------------------------------------------------------------------------- association
    def _associate(self, dets: Sequence[LightDetection]) -> list[tuple[int, int]]:
        if not dets or not self._tracks:
            return []
        tb = np.array([[t.box.x1, t.box.y1, t.box.x2, t.box.y2] for t in self._tracks], np.float64)
        db = np.array([[d.box.x1, d.box.y1, d.box.x2, d.box.y2] for d in dets], np.float64)
        tc = 0.5 * (tb[:, :2] + tb[:, 2:])
        dc = 0.5 * (db[:, :2] + db[:, 2:])
        ts = np.maximum(np.max(tb[:, 2:] - tb[:, :2], axis=1), self.min_size_px)
        ds = np.maximum(np.max(db[:, 2:] - db[:, :2], axis=1), self.min_size_px)
        dist = np.linalg.norm(dc[:, None, :] - tc[None, :, :], axis=2)
        cost = dist / np.maximum(ds[:, None], ts[None, :])
        same = np.array([[d.colour == t.colour for t in self._tracks] for d in dets], bool)
        ratio = np.maximum(ds[:, None], ts[None, :]) / np.minimum(ds[:, None], ts[None, :])
        cost = np.where(same & (cost <= self.gate) & (ratio <= self.max_size_ratio), cost, 1e6)
        rows, cols = linear_sum_assignment(cost)
        return [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if cost[r, c] < 1e6]

    # ------------------------------------------------------------------------------------- level
    def _level(self, hsv_img: np.ndarray | None, frame_bgr: np.ndarray, light: _Light) -> float:
        h, w = frame_bgr.shape[:2]
        cx, cy = light.box.center
        half = max(light.size, self.min_size_px)
        x1, y1 = max(0, int(cx - half)), max(0, int(cy - half))
        x2, y2 = min(w, int(np.ceil(cx + half))), min(h, int(np.ceil(cy + half)))
        if x2 <= x1 or y2 <= y1:
            return 0.0
        crop = (
            hsv_img[y1:y2, x1:x2]
            if hsv_img is not None
            else cv2.cvtColor(np.ascontiguousarray(frame_bgr[y1:y2, x1:x2]), cv2.COLOR_BGR2HSV)
        )
        hh, ss, vv = crop[..., 0], crop[..., 1], crop[..., 2]
        if light.colour == "white":
            mask = (vv >= 245 - self.relax_v) & (ss <= 80 + self.relax_s)
        else:
            mask = np.zeros(hh.shape, bool)
            for h_lo, h_hi, s_min, v_min in self.hsv.get(light.colour, []):
                mask |= (
                    (hh >= h_lo)
                    & (hh <= h_hi)
                    & (ss >= max(0, s_min - self.relax_s))
                    & (vv >= max(0, v_min - self.relax_v))
                )
        return float(np.count_nonzero(mask))

    # ---------------------------------------------------------------------------------- vehicles
    def _follow(self, vehicles: Sequence[Track]) -> None:
        """Move every anchored light with its vehicle (module docstring)."""
        boxes = {v.track_id: v.box for v in vehicles}
        for t in self._tracks:
            if t.anchor is None or t.anchor[0] not in boxes:
                continue
            b = boxes[t.anchor[0]]
            cx, cy = t.box.center
            dx = b.x1 + t.anchor[1] * b.width - cx
            dy = b.y1 + t.anchor[2] * b.height - cy
            t.box = Box(t.box.x1 + dx, t.box.y1 + dy, t.box.x2 + dx, t.box.y2 + dy)

    def _anchor(self, vehicles: Sequence[Track]) -> None:
        """Anchor each light seen this frame to the smallest vehicle box it is in or just above."""
        for t in self._tracks:
            if not t.seen:
                continue
            cx, cy = t.box.center
            best: tuple[float, Track] | None = None
            for v in vehicles:
                b = v.box
                if b.width <= 0 or b.height <= 0:
                    continue
                inside = b.x1 <= cx <= b.x2 and b.y1 - self.anchor_band * b.height <= cy <= b.y2
                if inside and (best is None or b.area < best[0]):
                    best = (b.area, v)
            if best is None:
                t.anchor = None
            else:
                b = best[1].box
                t.anchor = (best[1].track_id, (cx - b.x1) / b.width, (cy - b.y1) / b.height)

    # ------------------------------------------------------------------------------------ update
    def update(
        self,
        detections: Iterable[LightDetection],
        time_s: float,
        frame_bgr: np.ndarray | None = None,
        hsv: np.ndarray | None = None,
        vehicles: Sequence[Track] | None = None,
    ) -> list[LightTrack]:
        """Add one frame's detections (at ``time_s`` seconds, frames in time order); return every
        live track.

        ``frame_bgr`` (the frame the detections came from) lets the tracker read each track's region
        level, so that a lamp the detector misses while it is lit still counts as on; without it
        the on/off signal is the detections alone. ``hsv`` may pass the frame already converted to
        HSV (OpenCV units) to save the per-region conversions. ``vehicles`` (this frame's vehicle
        tracks, image pixels) lets lights follow their vehicle (module docstring).
        """
        dets = list(detections)
        if vehicles is not None:
            self._follow(vehicles)
        matches = self._associate(dets)
        matched_d = {d for d, _ in matches}
        for t in self._tracks:
            t.seen = False
        for d, k in matches:
            t = self._tracks[k]
            t.box, t.score, t.seen, t.last_seen_s = dets[d].box, dets[d].score, True, time_s
            t.size = max(t.size, dets[d].box.width, dets[d].box.height)
        self._tracks = [t for t in self._tracks if t.seen or time_s - t.last_seen_s <= self.max_gap_s]
        for i, det in enumerate(dets):
            if i not in matched_d:
                self._tracks.append(_Light(self._next_id, det, time_s))
                self._next_id += 1
        if vehicles is not None:
            self._anchor(vehicles)
        if hsv is None and frame_bgr is not None and len(self._tracks) > 16:
            hsv = cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2HSV)  # one conversion beats many crops
        out = []
        for t in self._tracks:
            if frame_bgr is not None:
                level = self._level(hsv, frame_bgr, t)
            else:  # detections only: the box's area while seen
                level = t.box.area if t.seen else 0.0
            while t.history and t.history[0][0] < time_s - self.window_s:
                t.history.popleft()
            peak = max([level, *(lv for _, lv, _ in t.history)])
            if (frame_bgr is None and t.seen) or (level >= self.min_level and level >= self.on_ratio * peak):
                t.state = True
            elif level < self.min_level or level <= self.off_ratio * peak:
                t.state = False
            t.history.append((time_s, level, t.state))
            times = [h[0] for h in t.history]
            states = [h[2] for h in t.history]
            k, hz, duty = flash_stats(times, states)
            flashing = (
                peak >= self.min_peak_px
                and k >= self.min_transitions
                and self.min_hz <= hz <= self.max_hz
                and 0.05 < duty < 0.95
            )
            out.append(
                LightTrack(
                    t.id, t.box, t.colour, t.score, t.seen, t.state, time_s - t.first_s, hz, duty, k, flashing
                )
            )
        return out


def vehicle_light_evidence(
    vehicles: Sequence[Track],
    lights: Sequence[LightTrack],
    *,
    band: float = 0.25,
    top: float = 0.3,
    side: float = 0.05,
    max_area: float = 0.25,
    colours: Sequence[str] = SATURATED,
) -> dict[int, tuple[bool, bool]]:
    """Per vehicle track id: ``(lit, flashing)`` from the light tracks of the same frame.

    A light can belong to a vehicle box ``(x1, y1, x2, y2)`` of width ``w`` and height ``h`` when
    its centre lies within ``[x1 − side·w, x2 + side·w]`` across and ``[y1 − band·h, y1 + top·h]``
    down (the upper part of the box and a band above it, where light bars and beacons sit; brake
    lights and headlights sit lower) and its box is at most ``max_area`` of the vehicle's (a glow
    covering the vehicle is a reflection, not a lamp). A light inside some vehicle's box belongs
    only to the boxes it is inside; only a light inside none goes to the boxes it is just above (the
    roof bar of a vehicle behind another shows above the front one's roof, inside its own box).
    Only lights of ``colours`` count. ``lit``: such a light is on and detected in this frame;
    ``flashing``: such a light is flashing.
    """
    wanted = set(colours)
    out: dict[int, list[bool]] = {v.track_id: [False, False] for v in vehicles}
    for lt in lights:
        if lt.colour not in wanted or not (lt.flashing or (lt.on and lt.detected)):
            continue
        cx, cy = lt.box.center
        inside: list[int] = []
        above: list[int] = []
        for v in vehicles:
            b = v.box
            w, h = b.width, b.height
            if not (b.x1 - side * w <= cx <= b.x2 + side * w) or lt.box.area > max_area * max(b.area, 1.0):
                continue
            if b.y1 <= cy <= b.y1 + top * h:
                inside.append(v.track_id)
            elif b.y1 - band * h <= cy < b.y1:
                above.append(v.track_id)
        for tid in inside or above:
            out[tid][0] = True
            out[tid][1] = out[tid][1] or lt.flashing
    return {tid: (lit, flashing) for tid, (lit, flashing) in out.items()}


#: Framework B's per-frame "active EV" rules (:func:`active_probability`).
ACTIVE_RULES = ("crop", "lights", "lights+crop")


def active_probability(rule: str, lit: bool, flashing: bool, crop_probability: float | None) -> float | None:
    """The per-frame probability the track smoother gets for one vehicle track under ``rule``
    (``None``: no judgement this frame, the smoother skips it).

    * ``crop``: the crop classifier's probability alone (``None`` when it gave none this frame);
    * ``lights``: 1.0 with a flashing emergency light on or above the box, else 0.0 (a steady light
      is a brake light, a street lamp or a sign as often as a beacon; ``lit`` is not used);
    * ``lights+crop``: with a flashing light, the crop classifier's probability (``None`` when it
      gave none), else 0.0 — the lights say "on", the classifier says "an emergency vehicle", and
      both must hold.
    """
    if rule == "crop":
        return crop_probability
    if rule == "lights":
        return 1.0 if flashing else 0.0
    if rule == "lights+crop":
        if not flashing:
            return 0.0
        return None if crop_probability is None else float(crop_probability)
    raise ValueError(f"unknown active rule {rule!r}; choose from: {', '.join(ACTIVE_RULES)}")
