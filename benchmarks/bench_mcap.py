"""Reading a camera topic from a robotics log vs reading the same frames from the mp4 (issue 28).

The first ``--frames`` frames of a shared clip are written, in a temporary folder, as the logs a
fleet records (:func:`makeway.sense.log_writer.make_test_log`): JPEG frames
(``sensor_msgs/msg/CompressedImage`` in an MCAP file, ``foxglove.CompressedImage`` in a
Foxglove-profile MCAP file, and in a ROS 2 bag folder with SQLite storage) and uncompressed
``bgr8`` frames (``sensor_msgs/msg/Image`` and ``foxglove.RawImage`` in MCAP, ``Image`` in a
SQLite bag), and H.264 frames as a camera's encoder streams them (``foxglove.CompressedVideo``, at
the mp4's bit rate, no B-frames). MCAP chunks are
zstd-compressed, as the ``mcap`` writer does by default; the raw ROS 2 frames also with lz4 and
with uncompressed chunks (zstd decompression of 2.7 MB per 1280×720 frame is what raw frames
cost). Each source is then read whole, the way ``makeway detect`` reads it (open, then every frame
as a BGR image: :class:`makeway.sense.video.VideoReader` for the mp4,
:class:`makeway.sense.logs.LogFrameReader` for the logs, whose MCAP camera topics take the direct
path of :mod:`makeway.sense.mcap_camera`), ``--reps`` times in rotating order. One more row reads
the raw zstd log the same way through the ``mcap`` reader and the ``mcap_ros2`` decoder (the path
before the direct one), and the CPU time of each stage of both paths is split out for that log.

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
from makeway.sense.logs import LogFrameReader, LogReader, open_log
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
    ("mcap-foxglove", "raw", "zstd", "MCAP, Foxglove RawImage (bgr8), zstd chunks"),
    ("ros2-bag", "raw", "none", "ROS 2 bag (SQLite), Image (bgr8)"),
    ("mcap-foxglove", "video", "zstd", "MCAP, Foxglove CompressedVideo (H.264)"),
)
RAW_ZSTD = "MCAP, ROS 2 Image (bgr8), zstd chunks"
GENERAL = "  the same, by mcap's own reader + mcap_ros2"


def _read_general(path: Path) -> int:
    """What :class:`LogFrameReader` does (first frame, 50 stamps, then every frame), through the
    ``mcap`` reader and the ``mcap_ros2`` decoder: the path before the direct one."""
    with open_log(path) as log:
        topic = log.only_topic("camera")
        next(iter(LogReader.frames(log, topic, max_frames=1)))
        LogReader.stamps(log, topic, 50)
        return sum(1 for _ in LogReader.frames(log, topic))


def stage_split(path: Path) -> dict[str, dict[str, float]]:
    """CPU ms per frame of each stage of reading the camera topic of ``path`` (one message per
    chunk), by the ``mcap`` reader + ``mcap_ros2`` and by the direct path."""
    import zstandard
    from mcap.data_stream import ReadDataStream
    from mcap.reader import make_reader
    from mcap.records import Chunk, Message
    from mcap.stream_reader import breakup_chunk
    from mcap_ros2.decoder import DecoderFactory

    general = dict.fromkeys(("chunk read", "zstd decompression", "records out of the chunk (copies)",
                             "CDR deserialisation", "image (numpy view, reshape)"), 0.0)  # fmt: skip
    direct = dict.fromkeys(("chunk read", "zstd decompression into a numpy buffer",
                            "message parse in place", "image (numpy view, reshape)"), 0.0)  # fmt: skip
    n = 0
    with open_log(path) as log:
        topic = log.only_topic("camera")
        schema = log.topic(topic).schema
        with path.open("rb") as f:
            summary = make_reader(f).get_summary()
            assert summary is not None
            ch = next(c for c in summary.channels.values() if c.topic == topic)
            decode = DecoderFactory().decoder_for("cdr", summary.schemas[ch.schema_id])
            assert decode is not None
            for ci in summary.chunk_indexes:
                c0 = time.process_time()
                f.seek(ci.chunk_start_offset + 9)
                chunk = Chunk.read(ReadDataStream(f))
                c1 = time.process_time()
                zstandard.decompress(chunk.data, chunk.uncompressed_size)
                c2 = time.process_time()
                records = [r for r in breakup_chunk(chunk) if isinstance(r, Message)]
                c3 = time.process_time()
                msgs = [decode(r.data) for r in records]
                c4 = time.process_time()
                for m in msgs:
                    log._image(m, schema, topic, 0)
                c5 = time.process_time()
                for key, dt in zip(
                    general, (c1 - c0, c2 - c1, c3 - c2 - (c2 - c1), c4 - c3, c5 - c4), strict=True
                ):
                    general[key] += dt
                n += len(msgs)
        index = log._camera_index(topic)
        for c, chunk_index in enumerate(index.chunks):  # each chunk once, then its messages
            c0 = time.process_time()
            index._chunk_record(chunk_index)
            c1 = time.process_time()
            records = index.records(chunk_index)
            c2 = time.process_time()
            mine = [(k, int(e[0]), int(e[2])) for k, e in enumerate(index.entries) if int(e[1]) == c]
            msgs = [index._parse(index._message(chunk_index, records, o, t)) for _, t, o in mine]
            c3 = time.process_time()
            for (k, _, _), msg in zip(mine, msgs, strict=True):
                log._image(msg, schema, topic, k)
            c4 = time.process_time()
            for key, dt in zip(direct, (c1 - c0, c2 - c1 - (c1 - c0), c3 - c2, c4 - c3), strict=True):
                direct[key] += dt
    return {
        "mcap + mcap_ros2": {k: 1000.0 * v / n for k, v in general.items()},
        "direct path": {k: 1000.0 * v / len(index) for k, v in direct.items()},
    }


def _timed(read: Callable[[], int]) -> tuple[float, float, int]:
    w0, c0 = time.perf_counter(), time.process_time()
    n = read()
    return time.perf_counter() - w0, time.process_time() - c0, n


def _codec(path: Path) -> str:
    """The video stream's codec as FFmpeg names it (``h264``, ``mpeg4`` …)."""
    import av

    with av.open(str(path)) as container:
        return str(container.streams.video[0].codec_context.name)


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
    mp4_label = f"mp4 ({_codec(clip)})"

    with tempfile.TemporaryDirectory(prefix="bench_mcap.") as tmp:
        logs: dict[str, Path] = {}
        sizes: dict[str, int] = {mp4_label: clip.stat().st_size}
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

        readers: dict[str, Callable[[], int]] = {mp4_label: read_mp4}
        for label, path in logs.items():
            readers[label] = reader_of(path)
            if label == RAW_ZSTD:
                readers[GENERAL] = lambda p=path: _read_general(p)  # type: ignore[misc]
                sizes[GENERAL] = sizes[label]
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

        stages = stage_split(logs[RAW_ZSTD])

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

    base_w = statistics.median(wall[mp4_label])
    base_c = statistics.median(cpu[mp4_label])
    print(f"{args.clip}: {args.frames} frames, {args.reps} reps; load average {os.getloadavg()} (2 cores)")
    print(f"{'source':46s} {'MB':>7s} {'wall ms/f':>9s} {'ratio':>6s} {'CPU ms/f':>9s} {'ratio':>6s}  target")
    rows = []
    for name in names:
        w, c = statistics.median(wall[name]), statistics.median(cpu[name])
        rw, rc = w / base_w, c / base_c
        ok = "ok" if rc <= TARGET_RATIO else "MISSED"
        print(
            f"{name:46s} {sizes[name] / 1e6:7.1f} {w:9.2f} {rw:6.2f} {c:9.2f} {rc:6.2f}  "
            f"{'' if name.startswith(('mp4', ' ')) else f'CPU ratio <= {TARGET_RATIO:.2f} {ok}'}"
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
    for path_name, split in stages.items():
        total = sum(split.values())
        parts = ", ".join(f"{k} {v:.2f}" for k, v in split.items())
        print(f"stages of {RAW_ZSTD}, {path_name}: {total:.2f} CPU ms/frame = {parts}")
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
                    "raw_zstd_stage_cpu_ms_per_frame": stages,
                }
            )
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
