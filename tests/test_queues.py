"""Issue 29, item 3: the bounded latest-wins queue drops the oldest input and keeps the newest, its
memory is bounded, a stage fed through it keeps up, and the car's V2X subscriber uses it."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest

from makeway.queues import LatestQueue, QueueClosedError, live
from makeway.v2x.transport import AlertPublisher, AlertSubscriber, free_loopback_port, open_peer


def test_full_queue_drops_the_oldest() -> None:
    q: LatestQueue[int] = LatestQueue(3)
    assert [q.put(k) for k in range(5)] == [None, None, None, 0, 1]
    assert len(q) == 3 and q.dropped == 2 and q.put_count == 5
    assert [q.get(), q.get(), q.get()] == [2, 3, 4]  # oldest first among the kept
    with pytest.raises(TimeoutError):
        q.get(timeout=0.01)
    q.put(7)
    q.close()
    assert q.get() == 7  # a closed queue is drained first
    with pytest.raises(QueueClosedError):
        q.get()
    with pytest.raises(QueueClosedError):
        q.put(8)
    with pytest.raises(ValueError, match="maxsize"):
        LatestQueue(0)


def test_fast_producer_slow_consumer() -> None:
    """A producer 1000 items ahead of a consumer that needs 1 ms per item: the queue never holds
    more than its bound, the consumer ends on the newest item, and what it sees is in order."""
    q: LatestQueue[int] = LatestQueue(4)
    n = 1000
    high = [0]

    def produce() -> None:
        for k in range(n):
            q.put(k)
            high[0] = max(high[0], len(q))
        q.close()

    got: list[int] = []
    producer = threading.Thread(target=produce)
    producer.start()
    while True:
        try:
            got.append(q.get(timeout=5.0))
        except QueueClosedError:
            break
        time.sleep(0.001)
    producer.join()
    assert high[0] <= 4
    assert got[-1] == n - 1  # the newest is never dropped
    assert got == sorted(got) and len(set(got)) == len(got)
    assert q.dropped == n - len(got) > 0


def test_live_stage_keeps_up_with_a_faster_source() -> None:
    """Input every 1 ms, a stage needing 10 ms: each answer is about an input at most about one
    processing time old (plus scheduling), not about one from the start of the run."""

    def source():  # a sensor delivering on its own clock
        for k in range(300):
            time.sleep(0.001)
            yield k

    def stage(k: int) -> int:
        time.sleep(0.01)
        return 2 * k

    out = list(live(source(), stage))
    assert [r.result for r in out] == [2 * r.item for r in out]
    items = [r.item for r in out]
    assert items == sorted(items) and items[-1] == 299
    assert out[-1].dropped == 300 - len(out) > 100
    lat = sorted(r.latency_s for r in out)
    assert lat[len(lat) // 2] < 0.1  # an unbounded FIFO would reach ~2 s by the end


def test_live_hands_on_a_source_error() -> None:
    def source():
        yield 1
        raise OSError("camera unplugged")

    with pytest.raises(OSError, match="unplugged"):
        list(live(source(), lambda k: k))


def test_v2x_subscriber_drops_the_oldest_when_flooded() -> None:
    port = free_loopback_port()
    car = open_peer(listen=[f"tcp/127.0.0.1:{port}"])
    unit = open_peer(connect=[f"tcp/127.0.0.1:{port}"])
    try:
        sub = AlertSubscriber(car, ["flood"], max_pending=5, queue="fifo")
        pub = AlertPublisher(unit, "flood")
        assert pub.wait_for_subscribers(10.0)
        for k in range(50):  # nobody reads while they arrive
            pub.publish(b"payload %d" % k)
        deadline = time.monotonic() + 10.0
        while sub.dropped < 45 and time.monotonic() < deadline:
            time.sleep(0.01)
        got = [r.payload for r in sub.receive(0.3)]
        pub.close()
        sub.close()
    finally:
        unit.close()
        car.close()
    assert sub.dropped == 45
    assert got == [b"payload %d" % k for k in range(45, 50)]


def test_v2x_subscriber_calls_back_on_zenohs_own_thread() -> None:
    """A car subscribes to 20 segments without a Python thread per subscriber (zenoh-python's
    default hand-over: with 10 cars in a process, 200 threads contending for the interpreter let
    the verify queues back up in ``bench_v2x_load.py``), and still receives on every segment."""
    port = free_loopback_port()
    car = open_peer(listen=[f"tcp/127.0.0.1:{port}"])
    unit = open_peer(connect=[f"tcp/127.0.0.1:{port}"])
    segments = [f"seg-{k:02d}" for k in range(20)]
    try:
        before = threading.active_count()
        sub = AlertSubscriber(car, segments, queue="fifo")
        assert threading.active_count() == before
        pubs = [AlertPublisher(unit, s) for s in segments]
        assert all(p.wait_for_subscribers(10.0) for p in pubs)
        for k, p in enumerate(pubs):
            p.publish(b"payload %d" % k)
        got = []
        for r in sub.receive(10.0):
            got.append(r)
            if len(got) == len(segments):
                break
        assert threading.active_count() == before
        for p in pubs:
            p.close()
        sub.close()
    finally:
        unit.close()
        car.close()
    assert sorted((r.key.rsplit("/", 1)[1], r.payload) for r in got) == [
        (s, b"payload %d" % k) for k, s in enumerate(segments)
    ]


def test_video_pipeline_as_a_live_camera(video_dir: Path) -> None:
    """``run_video(realtime=True)``: frames come on the video's clock; whatever the pipeline could not
    take in time is dropped oldest first, the newest frame is always processed, in order."""
    from makeway.pipeline.video import run_video

    seen: list[int] = []
    summary = run_video(
        video_dir / "fire_trucks_red_lights.mp4",
        None,
        max_frames=45,
        write_video=False,
        detector_workers=1,
        progress=False,
        realtime=True,
        on_frame=lambda f: seen.append(f.frame_index),
    )
    assert summary.frames + summary.dropped_frames == 45
    assert seen == sorted(seen) and seen[-1] == 44
    assert summary.video_seconds == pytest.approx(45 / summary.fps, rel=1e-3)
    assert summary.realtime_factor <= 1.1  # paced: never faster than the camera


def test_listener_as_a_live_array(data_root: Path) -> None:
    """``listen(realtime=True)``: a window every hop of wall time through the latest-wins queue; the
    messages are in time order and the last one is about the newest audio."""
    from makeway.perceive.audio.stream import listen, listen_windows
    from makeway.sim.audio_scenarios import simulate_recording

    rec = simulate_recording("from_behind", 2.5, seed=2, siren="real", noise="real", data_root=data_root)
    starts = listen_windows(rec)
    t0 = time.monotonic()
    messages = list(listen(rec, realtime=True, hop_s=0.17))
    wall = time.monotonic() - t0
    assert wall >= (len(starts) - 1) * 0.17 * 0.95  # paced on the array's clock
    t_end = [m["t_end"] for m in messages]
    assert t_end == sorted(t_end) and len(messages) <= len(starts)
    assert t_end[-1] == pytest.approx((starts[-1] + round(0.5 * rec.sample_rate)) / rec.sample_rate)
