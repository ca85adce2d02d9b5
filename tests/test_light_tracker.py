"""The light tracker and its flash cue (makeway.track.lights): synthetic lamps with a known pattern,
the flashing lights of the real night ambulance clip, the steady lights of a no-EV clip, and the
lights evidence / active rules of Framework B."""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np
import pytest

from makeway.messages import Box, LightDetection, Track
from makeway.perceive.vision.lights import DEFAULT_LIGHT_DETECTOR
from makeway.sense.video import VideoReader
from makeway.track.lights import (
    SATURATED,
    LightTrack,
    LightTracker,
    active_probability,
    build_light_detector,
    flash_stats,
    vehicle_light_evidence,
)

FPS = 25.0


def _lamps(n: int, blink_hz: float) -> list[np.ndarray]:
    """Dark frames with a steady blue lamp at (40, 60) and a blue lamp blinking at ``blink_hz``
    (50 % duty) at (120, 60)."""
    frames = []
    for i in range(n):
        img = np.full((120, 160, 3), 20, np.uint8)
        cv2.circle(img, (40, 60), 6, (255, 90, 0), -1)
        if (i / FPS * blink_hz) % 1.0 < 0.5:
            cv2.circle(img, (120, 60), 6, (255, 90, 0), -1)
        frames.append(img)
    return frames


def _run(frames: list[np.ndarray], with_frames: bool = True) -> dict[int, list[LightTrack]]:
    det = build_light_detector(DEFAULT_LIGHT_DETECTOR, "eu")
    tracker = LightTracker()
    out: dict[int, list[LightTrack]] = defaultdict(list)
    for i, img in enumerate(frames):
        for lt in tracker.update(det.detect(img, i), i / FPS, img if with_frames else None):
            out[lt.track_id].append(lt)
    return out


def _by_position(tracks: dict[int, list[LightTrack]], x: float) -> list[LightTrack]:
    (tid,) = [t for t, h in tracks.items() if abs(h[0].box.center[0] - x) < 10]
    return tracks[tid]


def test_flash_stats_counts_changes_and_frequency() -> None:
    times = [i / FPS for i in range(50)]
    on = [(t * 2.0) % 1.0 < 0.5 for t in times]  # 2 Hz, 50 % duty, 2 s
    k, hz, duty = flash_stats(times, on)
    assert k == 7 and hz == pytest.approx(2.0, abs=0.05) and duty == pytest.approx(0.52, abs=0.03)
    assert flash_stats(times, [True] * 50) == (0, 0.0, 1.0)
    assert flash_stats([], []) == (0, 0.0, 0.0)


@pytest.mark.parametrize("with_frames", [True, False])
def test_steady_lamp_is_not_flashing_and_a_2hz_lamp_is(with_frames: bool) -> None:
    tracks = _run(_lamps(75, 2.0), with_frames)
    steady = _by_position(tracks, 40)
    blink = _by_position(tracks, 120)  # one track through the off phases (gaps of 0.25 s)
    assert len(steady) == 75 and not any(lt.flashing for lt in steady)
    assert steady[-1].transitions == 0 and steady[-1].duty == 1.0
    late = blink[-25:]  # the last second: the 1.5 s window is full
    assert all(lt.flashing for lt in late)
    assert all(lt.flash_hz == pytest.approx(2.0, abs=0.3) for lt in late)
    assert all(0.3 < lt.duty < 0.7 for lt in late)
    assert not blink[0].flashing  # not before an on/off cycle has been seen


def test_a_lamp_on_a_moving_vehicle_follows_it_through_its_off_phases() -> None:
    """A van drives right at 16 px a frame (400 px/s) with a blue roof lamp blinking at 2 Hz. On
    its own the tracker loses the lamp at every off phase (the lamp is 9 lamp sizes away when it
    comes back) and never calls it flashing; given the van's track it keeps one lamp track, reads
    the level where the lamp now is, and calls it flashing at 2 Hz once its window is full."""
    det = build_light_detector(DEFAULT_LIGHT_DETECTOR, "eu")
    frames, vans = [], []
    for i in range(75):
        img = np.full((160, 1320, 3), 20, np.uint8)
        x = 20 + 16 * i
        cv2.rectangle(img, (x, 60), (x + 80, 140), (90, 90, 90), -1)  # the van, dark grey
        if (i / FPS * 2.0) % 1.0 < 0.5:
            cv2.circle(img, (x + 40, 66), 5, (255, 90, 0), -1)  # the lamp on its roof
        frames.append(img)
        vans.append(Track(7, Box(x, 60, x + 80, 140)))
    for follow in (False, True):
        tracker = LightTracker()
        history: dict[int, list[LightTrack]] = defaultdict(list)
        for i, img in enumerate(frames):
            lights = tracker.update(det.detect(img, i), i / FPS, img, vehicles=[vans[i]] if follow else None)
            for lt in lights:
                history[lt.track_id].append(lt)
        if not follow:
            assert len(history) >= 6 and not any(lt.flashing for h in history.values() for lt in h)
            continue
        (lamp,) = history.values()
        assert len(lamp) == 75
        late = lamp[-25:]
        assert all(lt.flashing and lt.flash_hz == pytest.approx(2.0, abs=0.3) for lt in late)
        assert all(abs(lt.box.center[0] - (vans[-25 + k].box.x1 + 40)) < 3 for k, lt in enumerate(late))


def test_tracks_end_after_the_gap_and_do_not_jump_across_colours_or_sizes() -> None:
    tracker = LightTracker(max_gap_s=0.2)
    small = LightDetection(Box(10, 10, 14, 14), "blue", 0.9)
    (a,) = tracker.update([small], 0.0)
    big_red = LightDetection(Box(9, 9, 15, 15), "red", 0.9)
    big_blue = LightDetection(Box(0, 0, 30, 30), "blue", 0.9)
    ids = {lt.track_id for lt in tracker.update([big_red, big_blue], 0.04)}
    assert a.track_id in ids and len(ids) == 3  # neither the red box nor the 7× larger one took it over
    tracker.update([], 0.5)
    assert tracker.update([small], 0.54)[0].track_id not in ids  # ended after 0.2 s unmatched


def test_night_ambulance_lights_flash_in_a_plausible_band(video_dir: Path) -> None:
    """The ambulance's light bar and beacons (blue and red) flash in the clip's first 2.4 s; the
    flash frequency of each light flashing for 15 frames or more lies in 0.75–8 Hz (measured over
    the first 100 frames: medians 1.0–5.1 Hz)."""
    det = build_light_detector(DEFAULT_LIGHT_DETECTOR, "us")
    tracker = LightTracker()
    hz: dict[int, list[float]] = defaultdict(list)
    with VideoReader(video_dir / "night_ambulance_lights.mp4", max_frames=60) as reader:
        for index, t_s, image in reader:
            found = [d for d in det.detect(image, index) if d.colour in SATURATED]
            for lt in tracker.update(found, t_s, image):
                if lt.flashing:
                    hz[lt.track_id].append(lt.flash_hz)
    long = {tid: float(np.median(v)) for tid, v in hz.items() if len(v) >= 15}
    assert len(long) >= 3  # several lights flash for more than half a second
    assert all(0.75 <= f <= 8.0 for f in long.values()), long


def test_no_ev_clip_lights_do_not_flash(video_dir: Path) -> None:
    """traffic_no_ev (daylight traffic, no EV; its first 5 s): no blue light ever flashes; red lamps
    (brake lights) flicker into "flashing" only briefly (measured on the whole clip: 97 of 1393
    red/blue track-frames, no track longer than 16 frames), far from the seconds-long flashing of a
    light bar."""
    det = build_light_detector(DEFAULT_LIGHT_DETECTOR, "us")
    tracker = LightTracker()
    flashing: dict[tuple[int, str], int] = defaultdict(int)
    total = 0
    with VideoReader(video_dir / "traffic_no_ev.mp4", max_frames=150) as reader:
        for index, t_s, image in reader:
            found = [d for d in det.detect(image, index) if d.colour in SATURATED]
            for lt in tracker.update(found, t_s, image):
                total += 1
                if lt.flashing:
                    flashing[(lt.track_id, lt.colour)] += 1
    assert total > 250
    assert not any(colour == "blue" for _, colour in flashing)
    assert sum(flashing.values()) <= 0.1 * total
    assert max(flashing.values(), default=0) <= 30  # never flashing for more than a second (30 fps)


def _light(x: float, y: float, colour: str = "blue", flashing: bool = True, size: float = 6) -> LightTrack:
    return LightTrack(1, Box(x, y, x + size, y + size), colour, 0.9, True, True, 1.0, 2.0, 0.5, 4, flashing)


def test_vehicle_light_evidence_roof_band_and_ownership() -> None:
    car = Track(1, Box(100, 100, 200, 200))
    assert vehicle_light_evidence([car], [_light(147, 85)]) == {1: (True, True)}  # just above the roof
    assert vehicle_light_evidence([car], [_light(147, 110)]) == {1: (True, True)}  # upper part
    assert vehicle_light_evidence([car], [_light(147, 170)]) == {1: (False, False)}  # brake-light height
    assert vehicle_light_evidence([car], [_light(147, 40)]) == {1: (False, False)}  # far above
    assert vehicle_light_evidence([car], [_light(147, 110, "white")]) == {1: (False, False)}  # white
    steady_red = _light(147, 110, "red", flashing=False)
    assert vehicle_light_evidence([car], [steady_red]) == {1: (True, False)}
    huge = LightTrack(1, Box(100, 100, 200, 160), "blue", 0.9, True, True, 1.0, 2.0, 0.5, 4, True)
    assert vehicle_light_evidence([car], [huge]) == {1: (False, False)}  # a glow over the car
    # an ambulance behind a car: its roof bar is inside its own box and just above the car's
    front = Track(2, Box(100, 150, 200, 250))
    behind = Track(3, Box(110, 120, 190, 200))
    ev = vehicle_light_evidence([front, behind], [_light(147, 125)])
    assert ev == {2: (False, False), 3: (True, True)}


def test_active_probability_rules() -> None:
    assert active_probability("crop", True, True, 0.3) == 0.3
    assert active_probability("crop", False, False, None) is None
    assert active_probability("lights", True, True, None) == 1.0
    assert active_probability("lights", True, False, 0.9) == 0.0  # steady lights are not enough
    assert active_probability("lights+crop", True, True, 0.8) == 0.8
    assert active_probability("lights+crop", True, True, None) is None
    assert active_probability("lights+crop", True, False, 0.99) == 0.0
    with pytest.raises(ValueError, match="unknown active rule"):
        active_probability("vibes", True, True, 1.0)
