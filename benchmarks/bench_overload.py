"""Overload (issue 29, item 3): streaming stages fed faster than they run, through the bounded
latest-wins hand-over (``makeway.queues.live``, a ``LatestQueue`` of one item).

    .venv/bin/python benchmarks/bench_overload.py [--minutes 10] [--stages siren,vision,rsu,listener]
        [--rates 0.5,1,2,10] [--baseline-s 20] [--listener-pending 1024]
        [--listener-queue per_sender|fifo] [--listener-per-sender 2] [--listener-units 20]
        [--listener-evs 3] [--json FILE]

For each stage, its processing time is measured first (median of 15 inputs, nothing else
running); then a paced source hands it input at each of ``--rates`` times the rate it can
process: 0.5× is the unloaded reference, 2× and 10× the overloads of the issue. Each overload runs
``--minutes`` (the others one minute at most). Measured: latency from the moment an input arrives
to the moment its answer is out (p50, p99), the share of inputs dropped, and the process's
resident memory (RSS) sampled every second while it runs: its drift from the first sample after
warm-up (the first 10 % of the run) to the last, its spread (max − min) over the median, and its
peak growth over the first sample. Target (the
issue): at 10× the input rate, p99 latency ≤ 2× the unloaded p99, memory flat (± 5 %).

An unbounded FIFO (the same code with a queue that never drops) runs ``--baseline-s`` seconds at
10× beside it as the anchor: what the stage did before, falling behind without end (its latency
and memory grow with the backlog; the run stops when the source does). Each input is a fresh
buffer, as a sensor delivers it.

Stages (real data, real models):

* ``siren`` — :class:`makeway.perceive.audio.stream.SirenListener` with the shipped networks (one
  thread) on 0.5 s windows of a simulated 8-capsule recording made of a real siren clip and
  real street noise (``makeway audio listen``'s per-window step, health check included);
* ``vision`` — :class:`makeway.pipeline.video.VisionPipeline` (YOLOX-nano, one thread → SORT →
  crop classifier → smoother) on frames of the real clip ``fire_trucks_red_lights.mp4``;
* ``rsu`` — the roadside unit's per-frame step (``makeway rsu run``): the vision pipeline on the
  pole camera's clip ``intersection_cam_ambulance.mp4`` with its shipped calibration, the
  :class:`makeway.roadside.node.RoadsideNode` road filters, and the alerts due on its clock signed;
* ``listener`` — the car's V2X listener (``makeway v2x listen``): signed alerts of
  ``--listener-units`` roadside units and ``--listener-evs`` emergency vehicles (each its own
  identity from one local root), interleaved, sent by another process over a real zenoh network on
  loopback into an :class:`makeway.v2x.transport.AlertSubscriber` (its own bounded queue of
  ``--listener-pending`` alerts: ``--listener-queue per_sender``, the default, keeps each sender's
  two newest and serves the senders in turn; ``fifo`` is the arrival-order queue it had before),
  each verified (signature, certificate chain, freshness, replay). Its processing time is one
  verification; the latency runs from the alert's arrival (zenoh's receive stamp) to its verdict.
  The sender catches up in bursts when its clock runs ahead, as a radio delivers. At 10× the
  verification rate each sender sends thousands of alerts per second, far above a real unit's
  10 Hz: that is what an overload of this size means with this many senders.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Literal, cast

import numpy as np

from makeway.jsonable import to_jsonable
from makeway.paths import data_dir
from makeway.queues import live

TARGET_P99_RATIO = 2.0
TARGET_MEMORY_PCT = 5.0
PAGE = os.sysconf("SC_PAGE_SIZE")


def rss_mb() -> float:
    """This process's resident memory, MB (from /proc/self/statm)."""
    with open("/proc/self/statm", encoding="ascii") as fh:
        return int(fh.read().split()[1]) * PAGE / 1e6


class MemorySampler:
    """Samples RSS every ``period_s`` on a thread until stopped."""

    def __init__(self, period_s: float = 1.0) -> None:
        self.samples: list[tuple[float, float]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(period_s,), daemon=True)

    def _run(self, period_s: float) -> None:
        t0 = time.monotonic()
        while not self._stop.is_set():
            self.samples.append((time.monotonic() - t0, rss_mb()))
            self._stop.wait(period_s)

    def __enter__(self) -> MemorySampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def looped_at(items: list[Any], rate_hz: float, seconds: float, count: list[int]) -> Iterator[Any]:
    """``(k, copy of items[k mod n])`` at ``rate_hz`` for ``seconds`` (a sensor delivering fresh
    buffers on its clock); ``count[0]`` follows how many were delivered."""
    period = 1.0 / rate_hz
    t0 = time.monotonic()
    k = 0
    while True:
        due = t0 + k * period
        if due - t0 >= seconds:
            return
        wait = due - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        yield k, items[k % len(items)].copy()  # a sensor hands out a new buffer each time
        k += 1
        count[0] = k


def siren_stage() -> tuple[Callable[[Any], Any], list[Any]]:
    from makeway.perceive.audio.siren_model import DEFAULT_SIREN_MODEL, SirenModel
    from makeway.perceive.audio.stream import SirenListener, listen_windows
    from makeway.sim.audio_scenarios import simulate_recording

    rec = simulate_recording("from_behind", 8.0, seed=11, siren="real", noise="real", data_root=data_dir())
    model = SirenModel(DEFAULT_SIREN_MODEL, threads=1, localizer=True, ranger=True)
    listener = SirenListener(rec.mics, rec.sample_rate, model=model, full_scale_db_spl=rec.full_scale_db_spl)
    win = listener.window_samples
    windows = [np.ascontiguousarray(rec.audio[s : s + win].T) for s in listen_windows(rec)]

    def step(item: Any) -> Any:
        k, w = item
        return listener.step(w, 0.17 * k + 0.5)

    return step, windows


def vision_stage() -> tuple[Callable[[Any], Any], list[Any]]:
    from makeway.perceive.vision.detectors import DETECTORS
    from makeway.perceive.vision.ev_classifier import DEFAULT_MODEL, EVTrackClassifier, load_crop_classifier
    from makeway.pipeline.video import VisionPipeline
    from makeway.sense.video import VideoReader

    root = data_dir()
    assert root is not None
    with VideoReader(root / "video" / "fire_trucks_red_lights.mp4", max_frames=120) as reader:
        frames = [image for _, _, image in reader]
    det = DETECTORS["yolox_nano"](None, score_threshold=0.3, class_agnostic=True, num_threads=1)
    clf = EVTrackClassifier(load_crop_classifier(DEFAULT_MODEL, num_threads=1))
    pipe = VisionPipeline(det, classifier=clf)

    def step(item: Any) -> Any:
        k, image = item
        return pipe.process(image, k, k / 30.0)

    return step, frames


def rsu_stage() -> tuple[Callable[[Any], Any], list[Any]]:
    """The roadside unit's per-frame step (``makeway rsu run``): the vision pipeline on the pole
    camera's frame, the node's road filters, the alerts due on its clock signed."""
    import tempfile

    from makeway.perceive.vision.detectors import DETECTORS
    from makeway.perceive.vision.ev_classifier import DEFAULT_MODEL, EVTrackClassifier, load_crop_classifier
    from makeway.pipeline.video import VisionPipeline
    from makeway.roadside.node import RoadsideNode, sign_report
    from makeway.roadside.transform import read_transform_calibration
    from makeway.sense.rig import default_rig_path
    from makeway.sense.video import VideoReader
    from makeway.v2x.security import keygen

    root = data_dir()
    assert root is not None
    with VideoReader(root / "video" / "intersection_cam_ambulance.mp4", max_frames=120) as reader:
        frames = [image for _, _, image in reader]
    camera = read_transform_calibration(default_rig_path().parent / "intersection_cam_ambulance.yaml")
    identity = keygen(Path(tempfile.mkdtemp(prefix="bench-overload-")), "rsu")
    det = DETECTORS["yolox_nano"](None, score_threshold=0.3, class_agnostic=True, num_threads=1)
    pipe = VisionPipeline(
        det, classifier=EVTrackClassifier(load_crop_classifier(DEFAULT_MODEL, num_threads=1))
    )
    node = RoadsideNode(camera)
    sequence = [1]

    def step(item: Any) -> Any:
        k, image = item
        frame = pipe.process(image, k, k / 30.0)
        node.update(frame)
        out = []
        for report in node.due_alerts(frame.time_s):
            out.append(sign_report(report, identity, sequence[0], time.time())[1])
            sequence[0] += 1
        return out

    return step, frames


STAGES = {"siren": siren_stage, "vision": vision_stage, "rsu": rsu_stage}


# ------------------------------------------------------------------------------ the car's listener
def _alert_pool(folder: Path, units: int, evs: int, per_sender: int) -> tuple[list[tuple[bytes, float]], int]:
    """Signed alerts of ``units`` roadside units and ``evs`` emergency vehicles, ``per_sender``
    each, interleaved (alert ``k`` is sender ``k mod senders``'s): ``([(bytes, generation time)],
    senders)``, generation times 10 ms apart."""
    from makeway.v2x.message import Alert
    from makeway.v2x.security import keygen, sign_alert

    names = [f"rsu{u:02d}" for u in range(units)] + [f"ev{e}" for e in range(evs)]
    idents = [keygen(folder, name) for name in names]
    t0 = time.time()
    pool = []
    for k in range(per_sender * len(idents)):
        ident = idents[k % len(idents)]
        alert = Alert.from_physical(
            station_id=ident.station_id,
            generation_time_s=t0 + 0.01 * k,
            sequence=k // len(idents) + 1,
            lat_deg=48.137 + 1e-4 * (k % len(idents)),
            lon_deg=11.575,
            heading_deg=90.0,
            speed_mps=13.0,
            siren=True,
            lights=True,
        )
        pool.append((sign_alert(alert, ident), t0 + 0.01 * k))
    return pool, len(idents)


def _publish(
    endpoint: str, segment: str, payloads: list[bytes], rate_hz: float, seconds: float, sent: Any
) -> None:
    """A sender process: ``payloads`` (looped) at ``rate_hz`` for ``seconds``."""
    from makeway.v2x.transport import AlertPublisher, open_peer

    session = open_peer([], [endpoint])
    pub = AlertPublisher(session, segment, drop_when_congested=True)  # a flooding sender
    pub.wait_for_subscribers(10.0)
    t0 = time.monotonic()
    k = 0
    while True:
        now = time.monotonic() - t0
        if now >= seconds:
            break
        due = int(now * rate_hz) + 1  # catch up in a burst when behind, as a radio delivers
        while k < due:
            pub.publish(payloads[k % len(payloads)])
            k += 1
        time.sleep(min(0.002, 1.0 / rate_hz))
        sent.value = k
    sent.value = k
    time.sleep(0.3)
    pub.close()
    session.close()


def run_listener(
    rate_hz: float,
    seconds: float,
    pool: list[tuple[bytes, float]],
    senders: int,
    folder: Path,
    pending: int,
    queue: Literal["per_sender", "fifo"],
    per_sender: int = 2,
) -> dict[str, Any]:
    """The car's V2X listener as ``makeway v2x listen`` runs it: an :class:`AlertSubscriber` (its
    bounded queue of ``pending`` payloads, ``queue`` policy, the trust store's signers known) on a
    real zenoh network on loopback, fed by a sender process at ``rate_hz``, each payload verified
    (:class:`Verifier`: signature, certificate, freshness against the alert's own clock, replay; one
    verifier per sender, whose replay cache is emptied when that sender's alerts start over, as the
    pool of signed alerts is looped). Latency: from the payload's arrival (zenoh's receive stamp) to
    its verdict."""
    import multiprocessing as mp

    from makeway.v2x.security import ReplayCache, TrustStore, Verifier
    from makeway.v2x.transport import AlertSubscriber, free_loopback_port, open_peer, wait_listening

    port = free_loopback_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    session = open_peer([endpoint], [])
    wait_listening(port, 10.0)
    store = TrustStore.load(folder / "trust")
    sub = AlertSubscriber(
        session,
        ["bench"],
        max_pending=pending,
        queue=queue,
        per_sender=per_sender,
        known_signers=set(store.units),
    )
    verifiers = [Verifier(store) for _ in range(senders)]
    index = {data: i for i, (data, _) in enumerate(pool)}
    last = [-1] * senders
    ctx = mp.get_context("spawn")
    sent = ctx.Value("q", 0)
    sender = ctx.Process(
        target=_publish, args=(endpoint, "bench", [b for b, _ in pool], rate_hz, seconds, sent), daemon=True
    )
    lat = LatencyReservoir()  # millions of alerts: a list of floats would grow the process measured
    valid = 0
    sender.start()
    with MemorySampler() as mem:
        for got in sub.receive(seconds + 15.0):
            i = index[got.payload]
            s = i % senders
            if i <= last[s]:  # this sender's alerts started over: their sequence numbers repeat
                verifiers[s].replay = ReplayCache()
            last[s] = i
            valid += verifiers[s].verify(got.payload, pool[i][1] + 0.02).valid
            lat.append(time.time() - got.time_s)
            if not sender.is_alive() and sub.pending == 0:  # the run is over
                break
    sender.join(5.0)
    sub.close()
    session.close()
    return _summary(lat, mem, rate_hz, seconds, int(sent.value), sub.dropped, {"valid": valid})


def run_rate(
    step: Callable[[Any], Any], items: list[Any], rate_hz: float, seconds: float, maxsize: int = 1
) -> dict[str, Any]:
    lat: list[float] = []
    delivered = [0]
    dropped = 0
    t_end = time.monotonic() + seconds + 1.0
    with MemorySampler() as mem:
        for res in live(looped_at(items, rate_hz, seconds, delivered), step, maxsize=maxsize):
            lat.append(res.latency_s)
            dropped = res.dropped
            if res.done_s > t_end:  # an unbounded queue still holds a backlog: stop there
                break
    return _summary(lat, mem, rate_hz, seconds, delivered[0], dropped)


class LatencyReservoir:
    """Latencies (s) kept in fixed memory: a uniform random sample of at most ``size`` of them
    (reservoir sampling, Vitter's algorithm R), in an array allocated and touched before the run,
    so that millions of alerts do not grow the process the benchmark measures; ``len`` counts all."""

    def __init__(self, size: int = 1 << 20, seed: int = 29) -> None:
        self._buf = np.full(size, np.nan)
        self._rng = np.random.default_rng(seed)
        self._draws = self._rng.random(size)
        self._n = 0

    def append(self, value: float) -> None:
        n, size = self._n, len(self._buf)
        if n < size:
            self._buf[n] = value
        else:
            k = int(self._draws[n % size] * (n + 1))
            if k < size:
                self._buf[k] = value
        self._n = n + 1

    def __len__(self) -> int:
        return self._n

    @property
    def values(self) -> np.ndarray:
        return self._buf[: min(self._n, len(self._buf))]


def _summary(
    lat: list[float] | LatencyReservoir,
    mem: MemorySampler,
    rate_hz: float,
    seconds: float,
    inputs: int,
    dropped: int,
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    rss = [m for _, m in mem.samples]
    warm = rss[max(1, len(rss) // 10) :] or rss
    arr = (lat.values if isinstance(lat, LatencyReservoir) else np.asarray(lat)) * 1000.0
    return (extra or {}) | {
        "rate_hz": rate_hz,
        "seconds": seconds,
        "inputs": inputs,
        "processed": len(lat),
        "dropped": dropped,
        "latency_p50_ms": float(np.percentile(arr, 50)) if len(arr) else None,
        "latency_p99_ms": float(np.percentile(arr, 99)) if len(arr) else None,
        "rss_first_mb": warm[0],
        "rss_last_mb": warm[-1],
        "rss_drift_pct": 100.0 * (warm[-1] - warm[0]) / warm[0],
        "rss_spread_pct": 100.0 * (max(warm) - min(warm)) / statistics.median(warm),
        "rss_peak_growth_pct": 100.0 * (max(warm) - warm[0]) / warm[0],
        "rss_each_minute_mb": rss[::60],  # sampled every second: where a growth levels off
        "load": os.getloadavg(),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, default=10.0, help="length of each overloaded run")
    ap.add_argument("--stages", default="siren,vision", help=f"comma-separated: {', '.join(STAGES)}")
    ap.add_argument("--rates", default="0.5,1,2,10", help="input rates, times the processing rate")
    ap.add_argument("--baseline-s", type=float, default=20.0, help="unbounded FIFO run at 10× (0: none)")
    ap.add_argument(
        "--listener-pending", type=int, default=1024, help="the V2X listener's queue (AlertSubscriber)"
    )
    ap.add_argument(
        "--listener-queue", choices=("per_sender", "fifo"), default="per_sender", help="its policy"
    )
    ap.add_argument("--listener-per-sender", type=int, default=2, help="alerts kept per sender")
    ap.add_argument("--listener-units", type=int, default=20, help="roadside units sending alerts")
    ap.add_argument("--listener-evs", type=int, default=3, help="emergency vehicles sending alerts")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    if data_dir() is None:
        print("error: shared data not found (set MAKEWAY_DATA)", file=sys.stderr)
        return 2
    rates = [float(v) for v in args.rates.split(",") if v.strip()]
    out: dict[str, Any] = {}
    for name in [s.strip() for s in args.stages.split(",") if s.strip()]:
        if name == "listener":
            import tempfile

            from makeway.v2x.security import TrustStore, Verifier

            folder = Path(tempfile.mkdtemp(prefix="bench-overload-"))
            pool, senders = _alert_pool(folder, args.listener_units, args.listener_evs, 100)
            verifier = Verifier(TrustStore.load(folder / "trust"))
            times = []
            for data, gen in pool[:300]:
                t0 = time.perf_counter()
                verifier.verify(data, gen + 0.02)
                times.append(time.perf_counter() - t0)

            def run(
                rate_hz: float,
                seconds: float,
                maxsize: int,
                pool: Any = pool,
                senders: int = senders,
                folder: Path = folder,
            ) -> dict[str, Any]:
                if maxsize == 1:  # the listener's own queue
                    queue = cast(Literal["per_sender", "fifo"], args.listener_queue)
                    return run_listener(
                        rate_hz,
                        seconds,
                        pool,
                        senders,
                        folder,
                        args.listener_pending,
                        queue,
                        args.listener_per_sender,
                    )
                return run_listener(rate_hz, seconds, pool, senders, folder, maxsize, "fifo")

        else:
            step, items = STAGES[name]()
            times = []
            for k in range(20):
                t0 = time.perf_counter()
                step((k, items[k % len(items)]))
                times.append(time.perf_counter() - t0)

            def run(
                rate_hz: float, seconds: float, maxsize: int, step: Any = step, items: Any = items
            ) -> dict[str, Any]:
                return run_rate(step, items, rate_hz, seconds, maxsize)

        proc_s = statistics.median(times[5:])
        print(
            f"\n{name}: {1000 * proc_s:.1f} ms per input unloaded → {1 / proc_s:.1f} inputs/s "
            f"(load {os.getloadavg()[0]:.1f})"
        )
        if name == "listener":
            print(
                f"  (the listener's queue: {args.listener_queue}, at most {args.listener_pending} alerts"
                + (f", {args.listener_per_sender} per sender" if args.listener_queue == "per_sender" else "")
                + "; "
                f"{args.listener_units} roadside units + {args.listener_evs} EVs sending)"
            )
        print(
            f"  {'rate':>6s} {'s':>5s} {'inputs':>7s} {'done':>6s} {'dropped':>8s} {'p50 ms':>8s} "
            f"{'p99 ms':>8s} {'RSS MB':>8s} {'drift %':>8s} {'spread %':>9s} {'peak %':>7s} {'load':>5s}"
        )
        rows: dict[str, Any] = {}

        def show(label: str, r: dict[str, Any]) -> None:
            print(
                f"  {label:>6s} {r['seconds']:5.0f} {r['inputs']:7d} {r['processed']:6d} "
                f"{100 * r['dropped'] / max(r['inputs'], 1):7.1f}% {r['latency_p50_ms']:8.1f} "
                f"{r['latency_p99_ms']:8.1f} {r['rss_last_mb']:8.1f} {r['rss_drift_pct']:+8.2f} "
                f"{r['rss_spread_pct']:9.2f} {r['rss_peak_growth_pct']:+7.2f} {r['load'][0]:5.1f}"
                + (f"  valid {100 * r['valid'] / max(r['processed'], 1):.1f} %" if "valid" in r else "")
            )

        for rate in rates:
            seconds = 60.0 * args.minutes if rate >= 2 else min(60.0 * args.minutes, 60.0)
            r = run(rate / proc_s, seconds, 1)
            rows[f"{rate:g}x"] = r
            show(f"{rate:g}×", r)
        if args.baseline_s > 0:
            r = run(10.0 / proc_s, args.baseline_s, 10**9)
            rows["10x_unbounded_fifo"] = r
            show("FIFO", r)
            print("  (FIFO: an unbounded queue at 10×, the anchor)")
        ref = rows.get("0.5x")
        top = rows.get("10x")
        if ref and top:
            ratio = top["latency_p99_ms"] / ref["latency_p99_ms"]
            print(
                f"  at 10×: p99 {top['latency_p99_ms']:.1f} ms = {ratio:.2f}× the unloaded p99 "
                f"(target ≤ {TARGET_P99_RATIO:g}×); memory drift {top['rss_drift_pct']:+.2f} %, spread "
                f"{top['rss_spread_pct']:.2f} % over {top['seconds'] / 60:g} min "
                f"(target ± {TARGET_MEMORY_PCT:g} %)"
            )
            rows["p99_ratio_10x"] = ratio
        out[name] = {"ms_per_input": 1000 * proc_s, "rows": rows}
    print(f"\nload average {os.getloadavg()}")
    if args.json is not None:
        args.json.write_text(json.dumps(to_jsonable(out, digits=4), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
