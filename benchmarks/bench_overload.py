"""Overload (issue 29, item 3): streaming stages fed faster than they run, through the bounded
latest-wins hand-over (``makeway.queues.live``, a ``LatestQueue`` of one item).

    .venv/bin/python benchmarks/bench_overload.py [--minutes 10] [--stages siren,vision]
        [--rates 0.5,1,2,10] [--baseline-s 20] [--json FILE]

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
  crop classifier → smoother) on frames of the real clip ``fire_trucks_red_lights.mp4``.
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
from typing import Any

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


STAGES = {"siren": siren_stage, "vision": vision_stage}


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
    rss = [m for _, m in mem.samples]
    warm = rss[max(1, len(rss) // 10) :] or rss
    arr = np.asarray(lat) * 1000.0
    return {
        "rate_hz": rate_hz,
        "seconds": seconds,
        "inputs": delivered[0],
        "processed": len(lat),
        "dropped": dropped,
        "latency_p50_ms": float(np.percentile(arr, 50)) if len(arr) else None,
        "latency_p99_ms": float(np.percentile(arr, 99)) if len(arr) else None,
        "rss_first_mb": warm[0],
        "rss_last_mb": warm[-1],
        "rss_drift_pct": 100.0 * (warm[-1] - warm[0]) / warm[0],
        "rss_spread_pct": 100.0 * (max(warm) - min(warm)) / statistics.median(warm),
        "rss_peak_growth_pct": 100.0 * (max(warm) - warm[0]) / warm[0],
        "load": os.getloadavg(),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, default=10.0, help="length of each overloaded run")
    ap.add_argument("--stages", default="siren,vision", help=f"comma-separated: {', '.join(STAGES)}")
    ap.add_argument("--rates", default="0.5,1,2,10", help="input rates, times the processing rate")
    ap.add_argument("--baseline-s", type=float, default=20.0, help="unbounded FIFO run at 10× (0: none)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    if data_dir() is None:
        print("error: shared data not found (set MAKEWAY_DATA)", file=sys.stderr)
        return 2
    rates = [float(v) for v in args.rates.split(",") if v.strip()]
    out: dict[str, Any] = {}
    for name in [s.strip() for s in args.stages.split(",") if s.strip()]:
        step, items = STAGES[name]()
        times = []
        for k in range(20):
            t0 = time.perf_counter()
            step((k, items[k % len(items)]))
            times.append(time.perf_counter() - t0)
        proc_s = statistics.median(times[5:])
        print(
            f"\n{name}: {1000 * proc_s:.1f} ms per input unloaded → {1 / proc_s:.1f} inputs/s "
            f"(load {os.getloadavg()[0]:.1f})"
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
            )

        for rate in rates:
            seconds = 60.0 * args.minutes if rate >= 2 else min(60.0 * args.minutes, 60.0)
            r = run_rate(step, items, rate / proc_s, seconds)
            rows[f"{rate:g}x"] = r
            show(f"{rate:g}×", r)
        if args.baseline_s > 0:
            r = run_rate(step, items, 10.0 / proc_s, args.baseline_s, maxsize=10**9)
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
