"""Reading a camera topic from a robotics log vs reading the same frames from the mp4 (issue 28).

The first ``--frames`` frames of a shared clip are written, in a temporary folder, as the logs a
fleet records (:func:`makeway.sense.log_writer.make_test_log`): JPEG frames
(``sensor_msgs/msg/CompressedImage`` in an MCAP file, ``foxglove.CompressedImage`` in a
Foxglove-profile MCAP file, and in a ROS 2 bag folder with SQLite storage) and uncompressed
``bgr8`` frames (``sensor_msgs/msg/Image`` in MCAP). MCAP chunks are zstd-compressed, as the
``mcap`` writer does by default; the raw frames also with lz4 and with uncompressed chunks (zstd
decompression of 2.7 MB per 1280×720 frame is what raw frames cost). Each source is then read
whole, the way ``makeway detect`` reads it (open, then every frame as a BGR image:
:class:`makeway.sense.video.VideoReader` for the mp4, :class:`makeway.sense.logs.LogFrameReader`
for the logs), ``--reps`` times in rotating order.

Prints per source the median wall and CPU milliseconds per frame (CPU: all threads of the process;
FFmpeg decodes H.264 on several threads), their ratio to the mp4's, beside the target (a log costs
≤ 10 % more than the mp4: CPU ratio ≤ 1.10; the CPU time is the cost, the wall time on a shared
2-core machine mostly measures the other processes), the load average, what writing the frames
to a Foxglove MCAP (``makeway detect --mcap``) costs per frame, then one JSON line.

    .venv/bin/python benchmarks/bench_mcap.py
    .venv/bin/python benchmarks/bench_mcap.py --clip traffic_no_ev.mp4 --frames 200 --reps 7
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from makeway.jsonable import to_jsonable
from makeway.messages import PerceptionFrame
from makeway.paths import data_dir
from makeway.sense.log_writer import make_test_log
from makeway.sense.logs import LogFrameReader
from makeway.sense.video import VideoReader
from makeway.viz.foxglove import DetectRecorder

TARGET_RATIO = 1.10
SOURCES = (
    ("mcap-ros2", "compressed", "zstd", "MCAP, ROS 2 CompressedImage (JPEG)"),
    ("mcap-foxglove", "compressed", "zstd", "MCAP, Foxglove CompressedImage (JPEG)"),
    ("ros2-bag", "compressed", "none", "ROS 2 bag (SQLite), CompressedImage (JPEG)"),
    ("mcap-ros2", "raw", "zstd", "MCAP, ROS 2 Image (bgr8), zstd chunks"),
    ("mcap-ros2", "raw", "lz4", "MCAP, ROS 2 Image (bgr8), lz4 chunks"),
    ("mcap-ros2", "raw", "none", "MCAP, ROS 2 Image (bgr8), plain chunks"),
)


def _timed(read: Callable[[], int]) -> tuple[float, float, int]:
    w0, c0 = time.perf_counter(), time.process_time()
    n = read()
    return time.perf_counter() - w0, time.process_time() - c0, n


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--clip", default="night_ambulance_lights.mp4", help="a clip in the shared video folder"
    )
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--reps", type=int, default=5)
    args = parser.parse_args()
    root = data_dir()
    if root is None:
        print("shared data folder not found; set MAKEWAY_DATA", file=sys.stderr)
        return 2
    clip = root / "video" / args.clip

    with tempfile.TemporaryDirectory(prefix="bench_mcap.") as tmp:
        logs: dict[str, Path] = {}
        sizes: dict[str, int] = {"mp4 (H.264)": clip.stat().st_size}
        for fmt, image, compression, label in SOURCES:
            out = Path(tmp) / (
                f"{fmt}_{image}_{compression}" + ("" if fmt.startswith("ros2-bag") else ".mcap")
            )
            make_test_log(
                out, video=clip, fmt=fmt, image=image, max_frames=args.frames, compression=compression
            )
            logs[label] = out
            sizes[label] = sum(p.stat().st_size for p in ([out] if out.is_file() else out.iterdir()))

        def read_mp4() -> int:
            with VideoReader(clip, max_frames=args.frames) as reader:
                return sum(1 for _ in reader)

        def reader_of(path: Path) -> Callable[[], int]:
            def read() -> int:
                with LogFrameReader(path) as reader:
                    return sum(1 for _ in reader)

            return read

        readers: dict[str, Callable[[], int]] = {"mp4 (H.264)": read_mp4}
        readers.update({label: reader_of(path) for label, path in logs.items()})
        names = list(readers)
        wall: dict[str, list[float]] = {k: [] for k in names}
        cpu: dict[str, list[float]] = {k: [] for k in names}
        loads = []
        for rep in range(args.reps):
            for k in range(len(names)):
                name = names[(k + rep) % len(names)]
                w, c, n = _timed(readers[name])
                if n != args.frames:
                    print(f"{name}: read {n} frames, expected {args.frames}", file=sys.stderr)
                    return 1
                wall[name].append(1000.0 * w / n)
                cpu[name].append(1000.0 * c / n)
            loads.append(os.getloadavg()[0])

        # logs out: what ``--mcap`` adds per frame (JPEG, annotations, tracks JSON, zstd chunks)
        with VideoReader(clip, max_frames=args.frames) as reader:
            frames = [(t_s, image) for _, t_s, image in reader]
        record_cpu = []
        for rep in range(args.reps):
            recorder = DetectRecorder(Path(tmp) / f"out{rep}.mcap")
            c0 = time.process_time()
            for k, (t_s, image) in enumerate(frames):
                recorder.frame(int(round(t_s * 1e9)), image, PerceptionFrame(k, t_s, ()))
            recorder.close()
            record_cpu.append(1000.0 * (time.process_time() - c0) / len(frames))

    base_w = statistics.median(wall["mp4 (H.264)"])
    base_c = statistics.median(cpu["mp4 (H.264)"])
    print(f"{args.clip}: {args.frames} frames, {args.reps} reps; load average {os.getloadavg()} (2 cores)")
    print(f"{'source':46s} {'MB':>7s} {'wall ms/f':>9s} {'ratio':>6s} {'CPU ms/f':>9s} {'ratio':>6s}  target")
    rows = []
    for name in names:
        w, c = statistics.median(wall[name]), statistics.median(cpu[name])
        rw, rc = w / base_w, c / base_c
        ok = "ok" if rc <= TARGET_RATIO else "MISSED"
        print(
            f"{name:46s} {sizes[name] / 1e6:7.1f} {w:9.2f} {rw:6.2f} {c:9.2f} {rc:6.2f}  "
            f"{'' if name.startswith('mp4') else f'CPU ratio <= {TARGET_RATIO:.2f} {ok}'}"
        )
        rows.append(
            {
                "source": name,
                "megabytes": sizes[name] / 1e6,
                "wall_ms_per_frame": w,
                "cpu_ms_per_frame": c,
                "wall_ratio_to_mp4": rw,
                "cpu_ratio_to_mp4": rc,
            }
        )
    rec_ms = statistics.median(record_cpu)
    print(
        f"logs out (detect --mcap: JPEG + annotations + tracks): {rec_ms:.2f} CPU ms/frame "
        f"(reading the mp4: {base_c:.2f})"
    )
    print(
        json.dumps(
            to_jsonable(
                {
                    "bench": "mcap_camera_read",
                    "clip": args.clip,
                    "frames": args.frames,
                    "reps": args.reps,
                    "target_ratio": TARGET_RATIO,
                    "load_average_1min_during": loads,
                    "sources": rows,
                    "record_cpu_ms_per_frame": rec_ms,
                }
            )
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
