"""False light events of a lights detector on real footage without a lit emergency light
(``makeway.eval.false_lights``; issue 26 item 1)."""

from __future__ import annotations

from pathlib import Path

import pytest

from makeway.eval.false_lights import (
    NEGATIVE_STRETCHES,
    NegativeStretch,
    count_false_lights,
    poisson_rate_interval,
    pooled,
)
from makeway.track.lights import build_light_detector


def test_poisson_interval_matches_the_exact_tables() -> None:
    # Garwood's exact 95 % limits: k = 0 → (0, 3.689), k = 2 → (0.242, 7.225), per unit of time
    assert poisson_rate_interval(0, 1.0) == pytest.approx((0.0, 3.689), abs=1e-3)
    assert poisson_rate_interval(2, 1.0) == pytest.approx((0.2422, 7.2247), abs=1e-3)
    low, high = poisson_rate_interval(2, 0.5)  # the same count in half the time: twice the rate
    assert (low, high) == pytest.approx((0.4844, 14.449), abs=2e-3)
    with pytest.raises(ValueError):
        poisson_rate_interval(1, 0.0)
    with pytest.raises(ValueError):
        poisson_rate_interval(-1, 1.0)


def test_the_colour_rules_on_the_highway_clip_count_consistent_events(video_dir: Path) -> None:
    """The rule-based ``colour`` detector boxes lit things everywhere on the no-EV highway clip
    (real frames): every box is false there, the events are the tracks it makes of them, and the
    stretch's last frame and the reading rate are kept."""
    stretch = NegativeStretch("highway_cam_no_ev", 40, "test")
    detector = build_light_detector("colour", "all")
    count = count_false_lights(video_dir / "highway_cam_no_ev.mp4", stretch, detector, rate_hz=12.5)
    assert count.frames == 21  # 25 fps read every 2nd frame, frames 0 … 40
    assert count.seconds == pytest.approx(21 * 2 / 25)
    assert count.boxes > count.events > 0
    assert len(count.durations_s) == count.events and min(count.durations_s) >= 0.0
    assert max(count.durations_s) <= count.seconds and 0 <= count.flashing_events <= count.events
    events, hours = pooled([count, count])
    assert events == 2 * count.events and hours == pytest.approx(2 * count.seconds / 3600)


def test_the_stretches_name_real_clips(video_dir: Path) -> None:
    assert {s.role for s in NEGATIVE_STRETCHES} == {"test", "validation", "training"}
    for stretch in NEGATIVE_STRETCHES:
        assert (video_dir / f"{stretch.clip}.mp4").is_file()
