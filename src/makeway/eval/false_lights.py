"""How often makeway's lights detector reports a lit emergency light where none is lit: false light
events per hour on real footage without an active emergency vehicle (issue 26 item 1: the
simulated cameras' false lights, :class:`makeway.sim.cameras.CameraFigures`, calibrated to the
detector).

**Stretches** (:data:`NEGATIVE_STRETCHES`): clips, from their first frame to a last one, that show
no lit emergency light — the two clips without an emergency vehicle, and the first 571 frames of
``intersection_cam_ambulance`` (19 s before the ambulance comes into view; the lit-light labels
check every 6th of them, ``docs/data_card_lights.md``). Each carries its role for the lights
detectors: ``test`` and ``validation`` sources were never trained on, a ``training`` source was.

**What is counted.** Frames are read at about ``rate_hz`` (every ``round(fps / rate_hz)``-th frame,
as the simulated cameras publish at 10 Hz), each frame's detections go to a
:class:`~makeway.track.lights.LightTracker` (with the frame, so the flash cue is measured), and:

* ``boxes`` — detections over all frames read;
* ``events`` — light tracks: a *false light event* starts with a detection the tracker cannot give
  to a live track and ends when the tracker drops it; ``durations_s`` from each event's first to
  its last detection (0 for a light seen in one frame);
* ``flashing_events`` — events the flash cue called flashing at least once (the lights rule of
  Framework B needs that; the fusion's light observations do not).

:func:`poisson_rate_interval` turns a count over a time into a rate per hour with its exact
(Garwood) confidence interval: a few seconds of footage bound the rate only loosely.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from scipy.stats import chi2

from makeway.perceive.vision.lights import LightDetector
from makeway.sense.video import VideoReader, probe_video
from makeway.track.lights import LightTracker

__all__ = [
    "NEGATIVE_STRETCHES",
    "FalseLightCount",
    "NegativeStretch",
    "count_false_lights",
    "poisson_rate_interval",
    "pooled",
]


@dataclass(frozen=True)
class NegativeStretch:
    """Frames ``0 … last_frame`` (``None``: to the end) of ``clip`` (``<data>/video/<clip>.mp4``)
    with no lit emergency light, by day; ``role`` is the clip's part in the lights detectors'
    training (``test``, ``validation`` or ``training``)."""

    clip: str
    last_frame: int | None
    role: str


#: The real footage without a lit emergency light (module docstring).
NEGATIVE_STRETCHES = (
    NegativeStretch("highway_cam_no_ev", None, "test"),
    NegativeStretch("intersection_cam_ambulance", 570, "validation"),
    NegativeStretch("traffic_no_ev", None, "training"),
)


@dataclass
class FalseLightCount:
    """What :func:`count_false_lights` found on one stretch (module docstring); ``seconds`` of
    footage covered by the ``frames`` read."""

    stretch: NegativeStretch
    seconds: float
    frames: int
    boxes: int = 0
    events: int = 0
    flashing_events: int = 0
    durations_s: list[float] = field(default_factory=list)


def poisson_rate_interval(events: int, hours: float, confidence: float = 0.95) -> tuple[float, float]:
    """Exact (Garwood) two-sided interval of a Poisson rate per hour from ``events`` seen in
    ``hours``: ``(χ²(α/2; 2k)/2, χ²(1 − α/2; 2k + 2)/2) / hours``, the lower end 0 for ``k = 0``.

    Raises:
        ValueError: a negative count, a time not above 0, or a confidence outside (0, 1).
    """
    if events < 0 or not hours > 0 or not 0 < confidence < 1:
        raise ValueError(
            f"need events >= 0, hours > 0 and 0 < confidence < 1, got {events}, {hours}, {confidence}"
        )
    alpha = 1.0 - confidence
    low = 0.0 if events == 0 else float(chi2.ppf(alpha / 2, 2 * events)) / 2
    high = float(chi2.ppf(1 - alpha / 2, 2 * events + 2)) / 2
    return low / hours, high / hours


def count_false_lights(
    video: str | Path,
    stretch: NegativeStretch,
    detector: LightDetector,
    *,
    rate_hz: float = 10.0,
    tracker: LightTracker | None = None,
) -> FalseLightCount:
    """Run ``detector`` and a light tracker over ``stretch`` of ``video`` at about ``rate_hz`` and
    count its lights, every one false by the stretch's definition (module docstring).

    Raises:
        InputError: the video cannot be read (:class:`~makeway.sense.video.VideoReader`).
        ValueError: ``rate_hz`` not above 0.
    """
    if not rate_hz > 0:
        raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
    tracker = tracker if tracker is not None else LightTracker()
    stride = max(1, round(probe_video(video).fps / rate_hz))
    seen: dict[int, list[float]] = {}  # track id → first and last detection time
    flashing: set[int] = set()
    count = FalseLightCount(stretch=stretch, seconds=0.0, frames=0)
    with VideoReader(video, stride=stride) as reader:
        for index, time_s, frame in reader:
            if stretch.last_frame is not None and index > stretch.last_frame:
                break
            detections = detector.detect(frame, index)
            count.frames += 1
            count.boxes += len(detections)
            for track in tracker.update(detections, time_s, frame):
                if track.detected:
                    span = seen.setdefault(track.track_id, [time_s, time_s])
                    span[1] = time_s
                if track.flashing:
                    flashing.add(track.track_id)
        fps = reader.info.fps
    count.seconds = count.frames * stride / fps
    count.events = len(seen)
    count.flashing_events = len(flashing & set(seen))
    count.durations_s = sorted(round(b - a, 3) for a, b in seen.values())
    return count


def pooled(counts: Sequence[FalseLightCount]) -> tuple[int, float]:
    """Events and hours over ``counts`` together."""
    return sum(c.events for c in counts), sum(c.seconds for c in counts) / 3600.0
