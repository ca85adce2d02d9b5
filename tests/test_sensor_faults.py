"""Issue 29, item 2: sensor faults do what they say on real data, the health checks flag the faulted
channel or camera and not the clean ones, and the stages degrade gracefully."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from makeway.fuse.siren_track import SirenTrackFusion
from makeway.messages import Box, Detection, SensorHealth, SirenObservation, SirenSource
from makeway.perceive.audio.features import bandpass
from makeway.perceive.audio.stream import SirenListener, listen_windows
from makeway.perceive.health import (
    FROZEN_FRAMES,
    SWAP_MIN_WINDOWS,
    CameraHealth,
    SwapCheck,
    audio_health,
    repair_window,
)
from makeway.registry import UnknownNameError
from makeway.sense.faults import (
    AUDIO_FAULTS,
    DEAD_FLOOR_RMS,
    VIDEO_FAULTS,
    apply_audio_fault,
    apply_video_fault,
)
from makeway.sense.recording import CLIP_LEVEL, Recording
from makeway.sense.video import VideoReader
from makeway.sim.audio_scenarios import simulate_recording
from makeway.track.sort import Sort


@pytest.fixture(scope="module")
def rec(data_root: Path) -> Recording:
    """A 4 s recording of the roof array: a real siren clip passing, real street noise."""
    return simulate_recording("from_behind", 4.0, seed=5, siren="real", noise="real", data_root=data_root)


@pytest.fixture(scope="module")
def frames(video_dir: Path) -> list[tuple[int, float, np.ndarray]]:
    with VideoReader(video_dir / "fire_trucks_red_lights.mp4", max_frames=60) as reader:
        return list(reader)


def _windows(r: Recording, every: int = 4) -> list[np.ndarray]:
    win = round(0.5 * r.sample_rate)
    return [r.audio[s : s + win].T.astype(np.float64) for s in listen_windows(r)[::every]]


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.asarray(x, dtype=np.float64) ** 2)))


def test_registries_list_every_fault() -> None:
    assert set(AUDIO_FAULTS) == {
        "dead_channel",
        "clipped_channel",
        "swapped_channels",
        "noisy_channel",
        "clock_skew",
        "clock_jitter",
    }
    assert set(VIDEO_FAULTS) == {"frame_drop", "frozen", "blackout", "time_jitter"}
    with pytest.raises(UnknownNameError, match="choose from"):
        AUDIO_FAULTS["melted"]


def test_audio_faults_change_only_their_channel(rec: Recording) -> None:
    before = rec.audio.copy()
    dead = apply_audio_fault(rec, "dead_channel", channel=3)
    assert _rms(dead.audio[:, 3]) == pytest.approx(DEAD_FLOOR_RMS, rel=0.05)
    np.testing.assert_array_equal(np.delete(dead.audio, 3, axis=1), np.delete(before, 3, axis=1))
    np.testing.assert_array_equal(rec.audio, before)  # the input is untouched
    assert dead.meta["faults"] == ["dead_channel:3"]

    hot = apply_audio_fault(rec, "clipped_channel", channel=5)
    assert np.mean(np.abs(hot.audio[:, 5]) >= CLIP_LEVEL) > 0.01
    assert np.abs(hot.audio).max() <= 1.0

    swapped = apply_audio_fault(rec, "swapped_channels", channel=0, other=2)
    np.testing.assert_array_equal(swapped.audio[:, [0, 2]], before[:, [2, 0]])

    noisy = apply_audio_fault(rec, "noisy_channel", seed=1, channel=6, snr_db=0.0)
    assert _rms(noisy.audio[:, 6]) == pytest.approx(math.sqrt(2) * _rms(before[:, 6]), rel=0.05)
    with pytest.raises(ValueError, match="channel 9 does not exist"):
        apply_audio_fault(rec, "dead_channel", channel=9)


def test_clock_faults_move_the_ego_log(rec: Recording) -> None:
    skew = apply_audio_fault(rec, "clock_skew", offset_s=0.05)
    t = rec.ego.t[1:-5]
    np.testing.assert_allclose(skew.ego.position(t)[0], rec.ego.position(t + 0.05)[0], atol=1e-9)
    np.testing.assert_array_equal(skew.audio, rec.audio)
    jit = apply_audio_fault(rec, "clock_jitter", seed=3, jitter_s=0.05)
    assert np.all(np.diff(jit.ego.t) > 0)
    assert np.max(np.abs(jit.ego.t - rec.ego.t)) <= 0.05 + 1e-6
    assert np.max(np.abs(jit.ego.t - rec.ego.t)) > 0.01
    np.testing.assert_array_equal(jit.ego.x, rec.ego.x)


def test_health_trusts_every_clean_capsule(rec: Recording) -> None:
    for w in _windows(rec):
        h = audio_health(w, rec.mics, rec.sample_rate)
        assert h.ok and h.trust == 1.0, h.reasons


@pytest.mark.parametrize(
    ("fault", "params", "channel", "reasons"),
    [
        ("dead_channel", {"channel": 3}, 3, {"dead"}),
        ("clipped_channel", {"channel": 5}, 5, {"clipped", "loud"}),
        ("noisy_channel", {"channel": 1, "snr_db": -6.0}, 1, {"uncorrelated"}),
    ],
)
def test_health_flags_the_faulted_capsule_only(
    rec: Recording, fault: str, params: dict, channel: int, reasons: set[str]
) -> None:
    bad = apply_audio_fault(rec, fault, seed=2, **params)
    windows = _windows(bad)
    flagged = 0
    for w in windows:
        h = audio_health(w, bad.mics, bad.sample_rate)
        others = [ok for k, ok in enumerate(h.trusted) if k != channel]
        assert all(others), h.reasons  # never a clean capsule
        if not h.trusted[channel]:
            assert h.reasons[channel] in reasons
            assert h.faults() == (f"audio:{channel} {h.reasons[channel]}",)
            flagged += 1
    assert flagged >= 0.8 * len(windows)


def test_repair_rebuilds_a_dead_capsule_from_its_neighbours(rec: Recording) -> None:
    dead = apply_audio_fault(rec, "dead_channel", channel=0)
    w_clean = _windows(rec)[2]
    w = _windows(dead)[2]
    h = audio_health(w, dead.mics, dead.sample_rate)
    fixed, rebuilt = repair_window(w, dead.mics, h)
    assert rebuilt == (0,)
    # the side capsules (1, 3) of the same unit, 3 cm away: the level and the waveform come back
    np.testing.assert_array_equal(fixed[0], 0.5 * (w[1] + w[3]))
    assert _rms(fixed[0]) == pytest.approx(_rms(w_clean[0]), rel=0.25)
    # in the siren band the rebuilt capsule is as close to the lost one as its nearest real neighbour
    b = bandpass(np.stack([fixed[0], w_clean[0], w_clean[1]]), rec.sample_rate)
    assert np.corrcoef(b[0], b[1])[0, 1] >= np.corrcoef(b[2], b[1])[0, 1] - 0.05 > 0.5
    np.testing.assert_array_equal(fixed[1:], w[1:])


def test_listener_reports_and_repairs_a_dead_capsule(rec: Recording) -> None:
    dead = apply_audio_fault(rec, "dead_channel", channel=6)
    listener = SirenListener(dead.mics, dead.sample_rate)  # the classical path: no network needed
    win = listener.window_samples
    obs = listener.step(dead.audio[:win].T, win / dead.sample_rate)
    assert obs.health is not None and obs.health.trusted[6] is False and obs.health.repaired == (6,)
    assert obs.to_json()["health"] == {
        "sensor": "audio",
        "trust": 0.875,
        "distrusted": {"6": "dead"},
        "repaired": [6],
    }
    clean = SirenListener(rec.mics, rec.sample_rate).step(rec.audio[:win].T, win / rec.sample_rate)
    assert clean.health is not None and clean.health.ok and "health" not in clean.to_json()


def _swap_verdict(r: Recording) -> SwapCheck:
    check = SwapCheck(r.mics, r.sample_rate)
    n = r.sample_rate // 2
    for k in range(0, r.audio.shape[0] - n + 1, n):  # 0.5 s windows, one after the other
        check.update(r.audio[k : k + n].T, (k + n) / r.sample_rate)
    return check


def test_swap_check_finds_two_swapped_capsules(rec: Recording) -> None:
    """A real siren recorded on the simulated roof array: the clean wiring is kept; a swap of a
    unit's left and right capsules is found and undone; a swap of a unit's front and back capsules
    is found, but the array (mirror-symmetric front to back) cannot say on which unit."""
    clean = _swap_verdict(rec)
    assert clean.windows == 8 and clean.swapped == () and clean.margin < 0.0

    left_right = apply_audio_fault(rec, "swapped_channels", channel=5, other=7)
    check = _swap_verdict(left_right)
    assert check.swapped == ((5, 7),) and not check.ambiguous and check.margin > 0.25
    w = left_right.audio[:24000].T
    fixed, health = check.repair(w, audio_health(w, rec.mics, rec.sample_rate))
    np.testing.assert_array_equal(fixed, rec.audio[:24000].T)
    assert health.reasons == ("ok",) * 5 + ("swapped", "ok", "swapped") and health.repaired == (5, 7)
    # a swapped capsule is not rebuilt from its neighbours: the re-ordered channel is the real one
    np.testing.assert_array_equal(repair_window(fixed, rec.mics, health)[0], fixed)

    front_back = _swap_verdict(apply_audio_fault(rec, "swapped_channels", channel=0, other=2))
    assert front_back.ambiguous and set(front_back.swapped) == {(0, 2), (4, 6)}
    w = rec.audio[:24000].T
    kept, health = front_back.repair(w, audio_health(w, rec.mics, rec.sample_rate))
    assert (
        kept is w
        and health.repaired == ()
        and health.faults() == tuple(f"audio:{k} swapped" for k in (0, 2, 4, 6))
    )


def test_listener_undoes_a_swap_after_a_few_windows(rec: Recording) -> None:
    swapped = apply_audio_fault(rec, "swapped_channels", channel=1, other=3)
    listener = SirenListener(swapped.mics, swapped.sample_rate)
    win = listener.window_samples
    healths = [
        listener.step(swapped.audio[k : k + win].T, (k + win) / swapped.sample_rate).health
        for k in range(0, swapped.audio.shape[0] - win + 1, win)
    ]
    assert all(h is not None for h in healths)
    assert all(h.ok for h in healths[: SWAP_MIN_WINDOWS - 1])  # type: ignore[union-attr]
    assert all(h.faults() == ("audio:1 swapped", "audio:3 swapped") for h in healths[-3:])  # type: ignore[union-attr]
    assert healths[-1].repaired == (1, 3)  # type: ignore[union-attr]


def test_fusion_lowers_confidence_and_names_the_fault() -> None:
    health = SensorHealth(1.0, "audio", (True,) * 6 + (False, True), ("ok",) * 6 + ("dead", "ok"))
    src = (SirenSource(bearing_rad=0.3, distance_m=25.0),)
    healthy = SirenTrackFusion().update(SirenObservation(1.0, True, 0.9, 0.8, src, 80.0), 0.0, 0.0, 0.0)
    degraded = SirenTrackFusion().update(
        SirenObservation(1.0, True, 0.9, 0.8, src, 80.0, health), 0.0, 0.0, 0.0
    )
    assert healthy.sensor_faults == () and healthy.confidence == pytest.approx(0.8)
    assert degraded.sensor_faults == ("audio:6 dead",)
    assert degraded.confidence == pytest.approx(0.8 * 7 / 8)
    assert degraded.rel_x_m == pytest.approx(healthy.rel_x_m)


def test_video_faults(frames: list[tuple[int, float, np.ndarray]]) -> None:
    kept = list(apply_video_fault(iter(frames), "frame_drop", seed=4, fraction=0.3))
    assert 0.15 * len(frames) < len(frames) - len(kept) < 0.45 * len(frames)
    originals = {i: img for i, _, img in frames}
    assert all(np.array_equal(img, originals[i]) for i, _, img in kept)  # survivors keep index and image

    start = frames[20][1]
    frozen = list(apply_video_fault(iter(frames), "frozen", start_s=start))
    assert all(np.array_equal(f[2], frames[20][2]) for f in frozen[20:])
    assert [f[0] for f in frozen] == [f[0] for f in frames]

    dark = list(apply_video_fault(iter(frames), "blackout", start_s=start, duration_s=0.5))
    assert np.array_equal(dark[10][2], frames[10][2])
    assert dark[25][2].mean() < 4.0 and dark[25][2].shape == frames[25][2].shape
    assert np.array_equal(dark[-1][2], frames[-1][2])  # after the blackout

    jittered = list(apply_video_fault(iter(frames), "time_jitter", seed=1, jitter_s=0.05))
    stamps = np.array([t for _, t, _ in jittered])
    assert np.all(np.diff(stamps) > 0)
    assert np.max(np.abs(stamps - np.array([t for _, t, _ in frames]))) <= 0.05 + 1e-6


def test_camera_health(frames: list[tuple[int, float, np.ndarray]]) -> None:
    health = CameraHealth()
    assert all(health.update(img, t).ok for _, t, img in frames)  # a real clip: never flagged

    start = frames[20][1]
    health.reset()
    reasons = [
        health.update(img, t).reasons[0] for _, t, img in apply_video_fault(frames, "frozen", start_s=start)
    ]
    assert reasons[: 20 + FROZEN_FRAMES - 1] == ["ok"] * (20 + FROZEN_FRAMES - 1)
    assert set(reasons[20 + FROZEN_FRAMES - 1 :]) == {"frozen"}

    health.reset()
    dark = apply_video_fault(frames, "blackout", start_s=start)
    reasons = [health.update(img, t).reasons[0] for _, t, img in dark]
    assert reasons[:20] == ["ok"] * 20 and set(reasons[20:]) == {"black"}


def test_tracker_coasts_over_lost_frames() -> None:
    """A box moving 20 px per frame: with ``max_age = 1`` two lost frames end its track unless the
    tracker coasts over them; coasting carries it on and the detection after the gap matches."""

    def det(k: int) -> list[Detection]:
        return [Detection(Box(100.0 + 20 * k, 50.0, 160.0 + 20 * k, 90.0), 0.9, 2, "car")]

    for coast, same_track in ((True, True), (False, False)):
        sort = Sort(max_age=1, min_hits=3, iou_threshold=0.3)
        for k in range(6):
            (track,) = sort.update(det(k))
        if coast:
            sort.coast(2)
        after = sort.update(det(8))
        assert (len(after) == 1 and after[0].track_id == track.track_id) is same_track


def test_vision_pipeline_holds_its_tracks_while_the_camera_is_frozen(
    frames: list[tuple[int, float, np.ndarray]],
) -> None:
    from makeway.perceive.vision.detectors import DETECTORS
    from makeway.pipeline.video import VisionPipeline

    pipe = VisionPipeline(DETECTORS["yolox_nano"](None, class_agnostic=True, num_threads=1))
    stuck_from = 12
    out = [
        pipe.process(img, i, t)
        for i, t, img in apply_video_fault(frames[:24], "frozen", start_s=frames[stuck_from][1])
    ]
    flagged = [f for f in out if f.health is not None and not f.health.ok]
    first = stuck_from + FROZEN_FRAMES - 1
    assert [f.frame_index for f in flagged] == [f[0] for f in frames[first:24]]
    held = out[first - 1]
    assert held.tracks  # the clip has vehicles; they are held, not lost
    for f in flagged:
        assert f.tracks == held.tracks and f.health is not None and f.health.reasons == ("frozen",)
        assert f.to_json()["health"]["distrusted"] == {"0": "frozen"}
    assert all(f.health is not None and f.health.ok and "health" not in f.to_json() for f in out[:first])


def test_camera_health_reaches_the_fused_belief(frames: list[tuple[int, float, np.ndarray]]) -> None:
    """The real vision pipeline on a real clip blacked out for 7 frames: each frame's health goes to
    the multi-EV fusion beside a lit EV seen by the lights detector and announced over V2X; while
    the camera is black the belief names the fault and no longer counts the light sense."""
    from makeway.fuse.multi_ev import FusedBeliefSource
    from makeway.messages import LightObservation, V2XObservation, VehicleState
    from makeway.perceive.vision.detectors import DETECTORS
    from makeway.pipeline.video import VisionPipeline

    pipe = VisionPipeline(DETECTORS["yolox_nano"](None, class_agnostic=True, num_threads=1))
    fusion = FusedBeliefSource()
    ego = VehicleState(0.0, 0.0, 0.0, 0.0, 0.0)
    black = (frames[8][1], frames[15][1] - frames[8][1])
    got = []
    for i, t, img in apply_video_fault(frames[:20], "blackout", start_s=black[0], duration_s=black[1]):
        frame = pipe.process(img, i, t)
        assert frame.health is not None
        fusion.receive(frame.health)
        fusion.receive(LightObservation(t, 0.0, range_m=30.0, range_sigma_m=3.0, probability=0.9))
        fusion.receive(V2XObservation(t, 7, 30.0, 0.0, math.pi, 0.0, verified=True))
        got.append((frame.health.ok, fusion.update(t, ego)))
    assert [ok for ok, _ in got] == [True] * 8 + [False] * 7 + [True] * 5
    for ok, belief in got:
        assert belief.detected and set(belief.sources) == {"light", "v2x"}
        if ok:
            assert belief.sensor_faults == () and belief.confidence == pytest.approx(1 - 0.1 * 0.01)
        else:
            assert belief.sensor_faults == ("camera:0 black",) and belief.confidence == pytest.approx(0.99)
