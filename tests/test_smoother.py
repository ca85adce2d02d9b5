"""Per-track output smoother (SPEC §1) and the one-stream smoother of the siren decision (issue 4)."""

from __future__ import annotations

import math

import pytest

from makeway.messages import EVObservation, EVState
from makeway.perceive.audio.windows import StreamSmoother
from makeway.track.smoother import TrackSmoother


def obs(track: int, frame: int, p: float | None) -> EVObservation:
    return EVObservation(track, frame, frame / 25, p)


def test_warms_up_then_votes() -> None:
    s = TrackSmoother()  # 25 / 6 / 0.5
    states = []
    for f in range(5):
        states = s.update([obs(1, f, 0.9)], alive_track_ids=[1])
    assert states[0].state is EVState.WARMING_UP and states[0].n_valid == 5
    (st,) = s.update([obs(1, 5, 0.9)], alive_track_ids=[1])
    assert st.active and st.n_valid == 6 and st.positive_fraction == 1.0


def test_strictly_greater_than_threshold() -> None:
    s = TrackSmoother(window=10, min_frames=4, threshold=0.5)
    for f, p in enumerate([0.9, 0.1, 0.9, 0.1]):
        (st,) = s.update([obs(7, f, p)])
    assert st.positive_fraction == 0.5 and st.state is EVState.INACTIVE  # 50 % is not > 50 %
    (st,) = s.update([obs(7, 4, 0.95)])
    assert st.active


def test_ring_buffer_forgets_old_frames_and_skips_invalid() -> None:
    s = TrackSmoother(window=5, min_frames=3, threshold=0.5)
    for f in range(5):
        s.update([obs(2, f, 0.99)])
    for f in range(5, 8):
        (st,) = s.update([obs(2, f, None)])  # invalid frames do not count
    assert st.active and st.n_valid == 5
    for f in range(8, 11):
        (st,) = s.update([obs(2, f, 0.01)])
    assert st.n_valid == 5 and st.positive_fraction == pytest.approx(0.4) and not st.active


def test_forgets_dead_tracks_and_reports_new_ones() -> None:
    s = TrackSmoother()
    s.update([obs(1, 0, 0.9), obs(2, 0, 0.2)], alive_track_ids=[1, 2])
    states = s.update([], alive_track_ids=[2, 3])
    assert [x.track_id for x in states] == [2, 3]
    assert s.track_ids == [2]
    assert states[1].state is EVState.WARMING_UP and states[1].n_valid == 0


@pytest.mark.parametrize("t", [0.0, 0.3, 0.5, 0.7])
def test_threshold_sweep(t: float) -> None:
    s = TrackSmoother(window=25, min_frames=6, threshold=t)
    pattern = [0.9, 0.9, 0.1, 0.9, 0.1, 0.1, 0.9, 0.1, 0.9, 0.1]  # 50 % positives
    for f, p in enumerate(pattern):
        (st,) = s.update([obs(1, f, p)])
    assert st.active is (t < 0.5)


def test_bad_parameters() -> None:
    with pytest.raises(ValueError, match="min_frames"):
        TrackSmoother(window=5, min_frames=6)
    with pytest.raises(ValueError, match="threshold"):
        TrackSmoother(threshold=1.0)


def test_stream_smoother_logit_mean() -> None:
    s = StreamSmoother(3)  # the mean of the logits by default
    assert s.update(0.9) == pytest.approx(0.9)
    # 0.9 and 0.1 cancel in the logit domain
    assert s.update(0.1) == pytest.approx(0.5)
    # one near-certain "no" outweighs two clear "yes" windows: logits 2.2, 2.2, -9.2
    s.reset()
    s.update(0.9)
    s.update(0.9)
    z = (2 * math.log(9) + math.log(1e-4 / (1 - 1e-4))) / 3
    assert s.update(1e-4) == pytest.approx(1 / (1 + math.exp(-z)))
    # the buffer keeps the last 3: after three 0.8s the old windows are gone
    for _ in range(3):
        out = s.update(0.8)
    assert out == pytest.approx(0.8)
    # 0 and 1 stay finite
    assert 0.0 < s.update(0.0) < 1.0 and 0.0 < s.update(1.0) < 1.0


def test_stream_smoother_probability_mean_and_single_window() -> None:
    s = StreamSmoother(2, average="probability")
    assert [s.update(p) for p in (0.9, 0.1, 0.5)] == pytest.approx([0.9, 0.5, 0.3])
    one = StreamSmoother(1)
    assert [one.update(p) for p in (0.3, 1.0, 0.0)] == [0.3, 1.0, 0.0]  # exactly each window
    with pytest.raises(ValueError, match="window must be >= 1"):
        StreamSmoother(0)
    with pytest.raises(ValueError, match="unknown average 'max'"):
        StreamSmoother(3, average="max")
