"""Robotics logs out: ROS 2 and Foxglove-profile MCAP files and ROS 2 bag folders (issue 28).

Two writers share one small interface (``channel(...)`` then ``write(topic, log_time_ns, msg)``):

* :class:`Ros2LogWriter` writes ROS 2 messages (CDR, serialized with ``rosbags``' type store) into
  an MCAP file (``ros2`` profile, ``ros2msg`` schemas as ``ros2 bag record`` writes them) or into a
  ROS 2 bag folder (``rosbags.rosbag2.Writer``, SQLite storage, message definitions embedded).
* :class:`FoxgloveMcapWriter` writes protobuf messages (schema = the message's
  ``FileDescriptorSet``, encoding ``protobuf``: how Foxglove expects its schemas) and JSON messages
  (schema = a JSON Schema) into an MCAP file, so the file opens in Foxglove with no conversion.

Both write atomically: the log appears at its path only when :meth:`close` succeeds; on an error
(:meth:`abort`, or leaving the ``with`` block by an exception) nothing is left behind.

:func:`make_test_log` turns a video (and optionally a recording folder) into a small real log
with a camera topic, an audio topic with its array description, and an ego pose topic, in any of
the three kinds, for tests, benchmarks and users who want to try the log inputs.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import shutil
import tempfile
from collections.abc import Iterator
from fractions import Fraction
from pathlib import Path
from types import TracebackType
from typing import Any

import cv2
import numpy as np
import yaml

from makeway.atomic import check_writable
from makeway.errors import InputError
from makeway.sense.logs import ARRAY_SUFFIX, ROS_RAW_AUDIO_MSGDEF

__all__ = [
    "CAMERA_IMAGES",
    "CHUNK_COMPRESSIONS",
    "LOG_FORMATS",
    "FoxgloveMcapWriter",
    "H264MessageEncoder",
    "Ros2LogWriter",
    "make_test_log",
]

#: The kinds of log :func:`make_test_log` writes: a ROS 2 MCAP file, a Foxglove-schema MCAP file,
#: a ROS 2 bag folder with SQLite storage (ROS 2 Humble's default), one with MCAP storage (Jazzy's).
LOG_FORMATS = ("mcap-ros2", "mcap-foxglove", "ros2-bag", "ros2-bag-mcap")

#: What a camera message holds: a JPEG image, raw ``bgr8`` pixels, or one frame of an H.264 stream.
CAMERA_IMAGES = ("compressed", "raw", "video")

#: MCAP chunk compressions (the ``mcap`` writer's default is zstd).
CHUNK_COMPRESSIONS = ("zstd", "lz4", "none")


def _mcap_writer(file: Any, compression: str, chunk_size: int = 1024 * 1024) -> Any:
    from mcap.writer import CompressionType
    from mcap.writer import Writer as McapWriter

    if compression not in CHUNK_COMPRESSIONS:
        raise ValueError(
            f"unknown chunk compression {compression!r}; choose from: {', '.join(CHUNK_COMPRESSIONS)}"
        )
    return McapWriter(file, compression=CompressionType[compression.upper()], chunk_size=chunk_size)


def _temp_beside(target: Path, folder: bool) -> Path:
    """A temporary path in ``target``'s folder; a bag folder is staged as ``<tmp>/<target name>``
    (rosbags names its database after the folder, and creates the folder itself)."""
    target.parent.mkdir(parents=True, exist_ok=True)
    if folder:
        stage = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".partial", dir=target.parent))
        return stage / target.name
    fd, name = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=".partial.mcap", dir=target.parent)
    os.close(fd)
    mask = os.umask(0)
    os.umask(mask)
    os.chmod(name, 0o666 & ~mask)  # mkstemp makes it private; the published log should not be
    return Path(name)


def _publish(tmp: Path, target: Path) -> None:
    if tmp.is_dir():
        if target.is_dir():
            shutil.rmtree(target)
        os.replace(tmp, target)
        tmp.parent.rmdir()
    else:
        os.replace(tmp, target)


def _discard(tmp: Path) -> None:
    if tmp.parent.name.endswith(".partial"):
        shutil.rmtree(tmp.parent, ignore_errors=True)
    else:
        tmp.unlink(missing_ok=True)


def ros_time(ns: int) -> tuple[int, int]:
    """``(sec, nanosec)`` of a time in ns."""
    return int(ns // 1_000_000_000), int(ns % 1_000_000_000)


class _AtomicLog:
    """A log written beside its target and moved onto it when finished: subclasses say how to
    finish (:meth:`_finish`) and how to let go of a half-written one (:meth:`_release`)."""

    path: Path
    _tmp: Path

    def _finish(self) -> None:
        raise NotImplementedError

    def _release(self) -> None:
        raise NotImplementedError

    def close(self) -> None:
        """Finish the log and move it onto :attr:`path` (nothing is left on a failure)."""
        try:
            self._finish()
            _publish(self._tmp, self.path)
        except BaseException:
            _discard(self._tmp)
            raise

    def abort(self) -> None:
        """Drop everything written."""
        with contextlib.suppress(Exception):  # the partial log is deleted anyway
            self._release()
        _discard(self._tmp)

    def __enter__(self) -> Any:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


class Ros2LogWriter(_AtomicLog):
    """ROS 2 messages into an MCAP file (``bag=False``) or a ROS 2 bag folder (``bag=True``, with
    ``storage`` ``sqlite3`` or ``mcap``).

    Messages are built with :meth:`msg` (the type store's classes) and written with :meth:`write`;
    :meth:`channel` registers a topic first. Types beyond the standard ROS 2 (Humble) set are
    registered from their ``.msg`` text with :meth:`register` (``makeway_msgs/msg/RawAudio`` is
    registered already). ``compression`` is the MCAP chunk compression (:data:`CHUNK_COMPRESSIONS`),
    ``chunk_size`` the uncompressed bytes after which a chunk is closed (the ``mcap`` writer's
    default: 1 MiB); ``big_endian`` writes big-endian CDR (as recorders on big-endian machines do).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        bag: bool = False,
        compression: str = "zstd",
        storage: str = "sqlite3",
        chunk_size: int = 1024 * 1024,
        big_endian: bool = False,
    ) -> None:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        if storage not in ("sqlite3", "mcap"):
            raise ValueError(f"unknown bag storage {storage!r}; choose from: sqlite3, mcap")
        self.path = Path(path)
        self.bag = bag
        self.big_endian = big_endian
        self.store = get_typestore(Stores.ROS2_HUMBLE)
        self.store.register(get_types_from_msg(ROS_RAW_AUDIO_MSGDEF, "makeway_msgs/msg/RawAudio"))
        self._tmp = _temp_beside(self.path, folder=bag)
        self._channels: dict[str, tuple[Any, str]] = {}
        self._schemas: dict[str, int] = {}
        if bag:
            from rosbags.rosbag2 import StoragePlugin, Writer

            plugin = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}[storage]
            self._bag = Writer(self._tmp, version=8, storage_plugin=plugin)
            self._bag.open()
        else:
            self._file = self._tmp.open("wb")
            self._mcap = _mcap_writer(self._file, compression, chunk_size)
            self._mcap.start(profile="ros2", library="makeway")

    def register(self, msgdef: str, typename: str) -> None:
        """Add the ROS 2 type ``typename`` defined by ``msgdef`` (``.msg`` text)."""
        from rosbags.typesys import get_types_from_msg

        self.store.register(get_types_from_msg(msgdef, typename))

    def msg(self, typename: str, **fields: Any) -> Any:
        """A message object of ``typename`` (``pkg/msg/Type``) with ``fields``."""
        return self.store.types[typename](**fields)

    def header(self, stamp_ns: int, frame_id: str = "") -> Any:
        sec, nsec = ros_time(stamp_ns)
        stamp = self.msg("builtin_interfaces/msg/Time", sec=sec, nanosec=nsec)
        return self.msg("std_msgs/msg/Header", stamp=stamp, frame_id=frame_id)

    def channel(self, topic: str, typename: str) -> None:
        if topic in self._channels:
            return
        if self.bag:
            conn = self._bag.add_connection(topic, typename, typestore=self.store)
            self._channels[topic] = (conn, typename)
            return
        if typename not in self._schemas:
            text, _ = self.store.generate_msgdef(typename, ros_version=2)
            self._schemas[typename] = self._mcap.register_schema(typename, "ros2msg", text.encode())
        cid = self._mcap.register_channel(topic, "cdr", self._schemas[typename])
        self._channels[topic] = (cid, typename)

    def write(self, topic: str, log_time_ns: int, message: Any) -> None:
        """Write ``message`` on ``topic`` (registered with :meth:`channel`) at ``log_time_ns``."""
        handle, typename = self._channels[topic]
        data = bytes(self.store.serialize_cdr(message, typename, little_endian=not self.big_endian))
        if self.bag:
            self._bag.write(handle, int(log_time_ns), data)
        else:
            self._mcap.add_message(handle, int(log_time_ns), data, int(log_time_ns))

    def _finish(self) -> None:
        if self.bag:
            self._bag.close()
        else:
            self._mcap.finish()
            self._file.close()

    def _release(self) -> None:
        if self.bag:
            self._bag.close()
        else:
            self._file.close()


def _descriptor_set(message_class: Any) -> bytes:
    """The serialized ``FileDescriptorSet`` of ``message_class``'s file and all its imports."""
    from google.protobuf import descriptor_pb2

    fds = descriptor_pb2.FileDescriptorSet()
    seen: set[str] = set()

    def add(fd: Any) -> None:
        if fd.name in seen:
            return
        seen.add(fd.name)
        for dep in fd.dependencies:
            add(dep)
        proto = descriptor_pb2.FileDescriptorProto()
        fd.CopyToProto(proto)
        fds.file.append(proto)

    add(message_class.DESCRIPTOR.file)
    return fds.SerializeToString()


class FoxgloveMcapWriter(_AtomicLog):
    """Foxglove-schema messages (protobuf) and JSON messages into an MCAP file, atomically.

    :meth:`write` takes a protobuf message (its schema registered on first use) and
    :meth:`write_json` a JSON-ready dict (its schema given with :meth:`json_channel`). Timestamps in
    the messages themselves are set by the caller; ``log_time_ns`` orders the file. ``compression``
    is the chunk compression (:data:`CHUNK_COMPRESSIONS`), ``chunk_size`` the uncompressed bytes
    after which a chunk is closed.
    """

    def __init__(self, path: str | Path, *, compression: str = "zstd", chunk_size: int = 1024 * 1024) -> None:
        self.path = Path(path)
        self._tmp = _temp_beside(self.path, folder=False)
        self._file = self._tmp.open("wb")
        self._mcap = _mcap_writer(self._file, compression, chunk_size)
        self._mcap.start(profile="", library="makeway")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self.counts: dict[str, int] = {}

    def _channel(self, topic: str, schema: str, encoding: str, data: bytes, msg_encoding: str) -> int:
        cid = self._channels.get(topic)
        if cid is None:
            if schema not in self._schemas:
                self._schemas[schema] = self._mcap.register_schema(schema, encoding, data)
            cid = self._mcap.register_channel(topic, msg_encoding, self._schemas[schema])
            self._channels[topic] = cid
        return cid

    def write(self, topic: str, log_time_ns: int, message: Any) -> None:
        """Write the protobuf ``message`` on ``topic``."""
        name = message.DESCRIPTOR.full_name
        cid = self._channels.get(topic)
        if cid is None:
            cid = self._channel(topic, name, "protobuf", _descriptor_set(type(message)), "protobuf")
        self._mcap.add_message(cid, int(log_time_ns), message.SerializeToString(), int(log_time_ns))
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def json_channel(self, topic: str, schema_name: str, json_schema: dict[str, Any]) -> None:
        """Register ``topic`` as JSON messages of ``schema_name`` described by ``json_schema``."""
        self._channel(topic, schema_name, "jsonschema", json.dumps(json_schema).encode(), "json")

    def write_json(self, topic: str, log_time_ns: int, obj: Any) -> None:
        """Write the JSON-ready ``obj`` on ``topic`` (registered with :meth:`json_channel`)."""
        from makeway.jsonable import to_jsonable

        data = json.dumps(to_jsonable(obj), separators=(",", ":"), allow_nan=False).encode()
        self._mcap.add_message(self._channels[topic], int(log_time_ns), data, int(log_time_ns))
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def metadata(self, name: str, data: dict[str, str]) -> None:
        self._mcap.add_metadata(name, data)

    def _finish(self) -> None:
        self._mcap.finish()
        self._file.close()

    def _release(self) -> None:
        self._file.close()


# ------------------------------------------------------------------------------ test logs from data


def _array_yaml(sample_rate: int, mics: np.ndarray, full_scale_db_spl: float | None) -> dict[str, Any]:
    spec: dict[str, Any] = {"sample_rate": int(sample_rate), "mics": [[float(v) for v in m] for m in mics]}
    if full_scale_db_spl is not None:
        spec["full_scale_db_spl"] = float(full_scale_db_spl)
    return spec


def _quat(yaw: float) -> tuple[float, float, float, float]:
    return 0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)


def _video_frames(video: Path, max_frames: int | None, stride: int) -> Iterator[tuple[float, np.ndarray]]:
    from makeway.sense.video import VideoReader

    with VideoReader(video, stride=stride, max_frames=max_frames) as reader:
        for _, t_s, frame in reader:
            yield t_s, frame


def make_test_log(
    out: str | Path,
    *,
    video: str | Path | None = None,
    recording: str | Path | None = None,
    fmt: str = "mcap-ros2",
    image: str = "compressed",
    max_frames: int | None = 50,
    stride: int = 1,
    jpeg_quality: int = 90,
    start_ns: int = 1_700_000_000_000_000_000,
    camera_topic: str = "/camera/image",
    audio_topic: str = "/audio/raw",
    pose_topic: str = "/ego/odom",
    audio_block_s: float = 0.1,
    compression: str = "zstd",
) -> dict[str, Any]:
    """Write a log ``out`` from the frames of ``video`` and/or the audio and ego path of the
    recording folder ``recording`` (:mod:`makeway.sense.recording`).

    ``fmt`` is one of :data:`LOG_FORMATS`. The camera topic holds ``sensor_msgs/msg/CompressedImage``
    (JPEG, ``image="compressed"``) or ``sensor_msgs/msg/Image`` (``bgr8``, ``image="raw"``) in ROS 2
    logs, ``foxglove.CompressedImage`` or ``foxglove.RawImage`` in Foxglove MCAP files, and in
    Foxglove MCAP files also ``foxglove.CompressedVideo`` (``image="video"``: H.264 as a camera's
    encoder streams it, :class:`H264MessageEncoder`, at the source video's bit rate). The audio
    goes out in ``audio_block_s`` blocks of interleaved ``pcm-s16`` (``makeway_msgs/msg/RawAudio`` or
    ``foxglove.RawAudio``) with the array description on ``<audio_topic>/array``; the ego path as
    ``nav_msgs/msg/Odometry`` or ``foxglove.PoseInFrame`` at its logged rate. Times are
    ``start_ns`` + the source's time; ``compression`` is the MCAP chunk compression
    (:data:`CHUNK_COMPRESSIONS`; a bag folder is written uncompressed). Returns what was written
    (topics, message counts, path).

    Raises:
        InputError: the video or recording cannot be read, or ``out`` cannot be written (nothing is
            left behind).
        ValueError: unknown ``fmt`` or ``image``, or neither source given.
    """
    if fmt not in LOG_FORMATS:
        raise ValueError(f"unknown log format {fmt!r}; choose from: {', '.join(LOG_FORMATS)}")
    if compression not in CHUNK_COMPRESSIONS:
        raise ValueError(
            f"unknown chunk compression {compression!r}; choose from: {', '.join(CHUNK_COMPRESSIONS)}"
        )
    if image not in CAMERA_IMAGES:
        raise ValueError(f"image must be one of {', '.join(CAMERA_IMAGES)}, got {image!r}")
    if image == "video" and fmt != "mcap-foxglove":
        raise ValueError("image='video' (foxglove.CompressedVideo) is written to mcap-foxglove logs only")
    if video is None and recording is None:
        raise ValueError("give a video, a recording, or both")
    target = Path(out)
    bag = fmt.startswith("ros2-bag")
    check_writable(target, folder=bag)
    if bag and target.exists() and any(target.iterdir()) and not (target / "metadata.yaml").is_file():
        raise InputError(target, "is a non-empty folder that is not a ROS 2 bag; choose another")
    rec = None
    if recording is not None:
        from makeway.sense.recording import read_recording

        rec = read_recording(recording)
    if video is not None:
        from makeway.sense.video import probe_video

        probe_video(video)  # a bad video fails before anything is written
    counts: dict[str, int] = {}
    writer: Ros2LogWriter | FoxgloveMcapWriter
    if fmt == "mcap-foxglove":
        writer = FoxgloveMcapWriter(target, compression=compression)
    else:
        storage = "mcap" if fmt == "ros2-bag-mcap" else "sqlite3"
        writer = Ros2LogWriter(target, bag=bag, compression=compression, storage=storage)
    with writer:
        if video is not None:
            counts[camera_topic] = _write_camera(
                writer, Path(video), camera_topic, image, max_frames, stride, jpeg_quality, start_ns
            )
        if rec is not None:
            counts.update(_write_recording(writer, rec, audio_topic, pose_topic, start_ns, audio_block_s))
    return {"log": str(target), "format": fmt, "image": image, "topics": counts}


def _write_camera(
    writer: Ros2LogWriter | FoxgloveMcapWriter,
    video: Path,
    topic: str,
    image: str,
    max_frames: int | None,
    stride: int,
    quality: int,
    start_ns: int,
) -> int:
    if image == "video":
        assert isinstance(writer, FoxgloveMcapWriter)
        return _write_video(writer, video, topic, max_frames, stride, start_ns)
    n = 0
    if isinstance(writer, Ros2LogWriter):
        writer.channel(
            topic, "sensor_msgs/msg/CompressedImage" if image == "compressed" else "sensor_msgs/msg/Image"
        )
    for t_s, frame in _video_frames(video, max_frames, stride):
        stamp = start_ns + int(round(t_s * 1e9))
        if isinstance(writer, Ros2LogWriter):
            header = writer.header(stamp, "camera")
            if image == "compressed":
                data = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, quality])[1].reshape(-1)
                msg = writer.msg("sensor_msgs/msg/CompressedImage", header=header, format="jpeg", data=data)
            else:
                h, w = frame.shape[:2]
                msg = writer.msg(
                    "sensor_msgs/msg/Image",
                    header=header,
                    height=h,
                    width=w,
                    encoding="bgr8",
                    is_bigendian=0,
                    step=w * 3,
                    data=np.ascontiguousarray(frame).reshape(-1),
                )
            writer.write(topic, stamp, msg)
        else:
            from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
            from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

            if image == "compressed":
                jpeg = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, quality])[1].tobytes()
                pmsg: Any = CompressedImage(frame_id="camera", format="jpeg", data=jpeg)
            else:
                h, w = frame.shape[:2]
                pmsg = RawImage(
                    frame_id="camera", width=w, height=h, encoding="bgr8", step=w * 3, data=frame.tobytes()
                )
            pmsg.timestamp.FromNanoseconds(stamp)
            writer.write(topic, stamp, pmsg)
        n += 1
    return n


class H264MessageEncoder:
    """Encode BGR frames into H.264 access units, one per frame, as ``foxglove.CompressedVideo``
    wants them: Annex B byte stream, no B-frames (each message decodes to exactly its own frame, in
    order), the sequence and picture parameter sets repeated on every keyframe (a reader can start
    at any keyframe), a keyframe every ``keyframe_s`` seconds.

    Args:
        width, height: frame size in pixels (odd sizes are padded to even by replication).
        fps: frame rate (frames/s), for the rate control and the keyframe interval.
        bit_rate: target bit rate (bit/s); ``None``: constant quality (x264 CRF 23).
        keyframe_s: seconds between keyframes.
    """

    def __init__(
        self, width: int, height: int, fps: float, *, bit_rate: int | None = None, keyframe_s: float = 1.0
    ) -> None:
        import av

        from makeway.sense.video import pick_h264_encoder

        self.width, self.height = int(width), int(height)
        self._pad = (self.height % 2, self.width % 2)
        ctx: Any = av.CodecContext.create(pick_h264_encoder(), "w")
        ctx.width = self.width + self._pad[1]
        ctx.height = self.height + self._pad[0]
        ctx.pix_fmt = "yuv420p"
        rate = max(1, round(float(fps)))
        ctx.time_base = Fraction(1, rate)
        ctx.framerate = Fraction(rate, 1)
        ctx.thread_count = 1
        keyint = max(1, round(keyframe_s * float(fps)))
        if ctx.name == "libx264":
            options = {"preset": "veryfast", "tune": "zerolatency"}
            options["x264-params"] = f"bframes=0:keyint={keyint}:min-keyint={keyint}:repeat-headers=1"
            if bit_rate is None:
                options["crf"] = "23"
            ctx.options = options
        ctx.gop_size = keyint
        ctx.max_b_frames = 0
        if bit_rate is not None or ctx.name != "libx264":
            ctx.bit_rate = int(bit_rate or 0.1 * ctx.width * ctx.height * float(fps))
        ctx.open()
        self._ctx = ctx
        self._pts = 0

    def encode(self, frame_bgr: np.ndarray) -> list[tuple[int, bytes]]:
        """Encode one frame; returns the finished access units as ``(frame_number, bytes)`` (one
        per frame with the zero-latency settings; none where an encoder holds frames back)."""
        import av

        if frame_bgr.shape != (self.height, self.width, 3) or frame_bgr.dtype != np.uint8:
            raise ValueError(f"frame must be uint8 {(self.height, self.width, 3)}, got {frame_bgr.shape}")
        if any(self._pad):
            frame_bgr = cv2.copyMakeBorder(frame_bgr, 0, self._pad[0], 0, self._pad[1], cv2.BORDER_REPLICATE)
        i420 = np.ascontiguousarray(cv2.cvtColor(frame_bgr, cv2.COLOR_BGR2YUV_I420), dtype=np.uint8)
        frame = av.VideoFrame.from_ndarray(i420, format="yuv420p")
        frame.pts = self._pts
        self._pts += 1
        return [(int(p.pts), bytes(p)) for p in self._ctx.encode(frame)]

    def flush(self) -> list[tuple[int, bytes]]:
        """The access units still held by the encoder."""
        return [(int(p.pts), bytes(p)) for p in self._ctx.encode(None)]


def _write_video(
    writer: FoxgloveMcapWriter,
    video: Path,
    topic: str,
    max_frames: int | None,
    stride: int,
    start_ns: int,
) -> int:
    """The frames of ``video`` as ``foxglove.CompressedVideo`` messages (H.264) at the source's bit
    rate (where the container states it)."""
    import av
    from foxglove_schemas_protobuf.CompressedVideo_pb2 import CompressedVideo

    from makeway.sense.video import probe_video

    info = probe_video(video)
    bit_rate = None
    with contextlib.suppress(Exception), av.open(str(video)) as container:
        bit_rate = int(container.streams.video[0].bit_rate or 0) or None
    encoder: H264MessageEncoder | None = None
    stamps: dict[int, int] = {}
    n = 0

    def emit(units: list[tuple[int, bytes]]) -> None:
        nonlocal n
        for pts, data in units:
            stamp = stamps.pop(pts)
            msg = CompressedVideo(frame_id="camera", format="h264", data=data)
            msg.timestamp.FromNanoseconds(stamp)
            writer.write(topic, stamp, msg)
            n += 1

    for k, (t_s, frame) in enumerate(_video_frames(video, max_frames, stride)):
        if encoder is None:
            encoder = H264MessageEncoder(
                frame.shape[1], frame.shape[0], info.fps / stride, bit_rate=bit_rate and bit_rate // stride
            )
        stamps[k] = start_ns + int(round(t_s * 1e9))
        emit(encoder.encode(frame))
    if encoder is not None:
        emit(encoder.flush())
    return n


def _write_recording(
    writer: Ros2LogWriter | FoxgloveMcapWriter,
    rec: Any,
    audio_topic: str,
    pose_topic: str,
    start_ns: int,
    block_s: float,
) -> dict[str, int]:
    counts: dict[str, int] = {}
    spec = _array_yaml(rec.sample_rate, rec.mics, rec.full_scale_db_spl)
    pcm = np.clip(np.round(rec.audio * 32768.0), -32768, 32767).astype("<i2")
    block = max(1, int(round(block_s * rec.sample_rate)))
    array_topic = audio_topic + ARRAY_SUFFIX
    ego = rec.ego
    if isinstance(writer, Ros2LogWriter):
        writer.channel(array_topic, "std_msgs/msg/String")
        writer.channel(audio_topic, "makeway_msgs/msg/RawAudio")
        writer.channel(pose_topic, "nav_msgs/msg/Odometry")
        writer.write(array_topic, start_ns, writer.msg("std_msgs/msg/String", data=yaml.safe_dump(spec)))
    else:
        writer.json_channel(
            array_topic,
            "makeway.ArrayDescription",
            {
                "type": "object",
                "title": "makeway.ArrayDescription",
                "description": "Microphone array: sample rate (Hz), capsule positions (m, vehicle frame) "
                "in channel order, optional calibration (dB SPL at digital RMS 1.0).",
                "properties": {
                    "sample_rate": {"type": "integer"},
                    "mics": {"type": "array", "items": {"type": "array", "items": {"type": "number"}}},
                    "full_scale_db_spl": {"type": "number"},
                },
            },
        )
        writer.write_json(array_topic, start_ns, spec)
    counts[array_topic] = 1
    # audio blocks and poses interleaved in time order
    events: list[tuple[int, int, int]] = []  # (stamp, kind 0 = audio 1 = pose, index)
    for i, s0 in enumerate(range(0, pcm.shape[0], block)):
        events.append((start_ns + int(round(s0 / rec.sample_rate * 1e9)), 0, i))
    for j, t in enumerate(ego.t):
        events.append((start_ns + int(round(float(t) * 1e9)), 1, j))
    events.sort()
    for stamp, kind, i in events:
        if kind == 0:
            data = pcm[i * block : (i + 1) * block]
            if isinstance(writer, Ros2LogWriter):
                msg = writer.msg(
                    "makeway_msgs/msg/RawAudio",
                    header=writer.header(stamp, "base_link"),
                    format="pcm-s16",
                    sample_rate=rec.sample_rate,
                    number_of_channels=rec.n_channels,
                    data=np.ascontiguousarray(data).view(np.uint8).reshape(-1),
                )
                writer.write(audio_topic, stamp, msg)
            else:
                from foxglove_schemas_protobuf.RawAudio_pb2 import RawAudio

                amsg = RawAudio(
                    format="pcm-s16",
                    sample_rate=rec.sample_rate,
                    number_of_channels=rec.n_channels,
                    data=np.ascontiguousarray(data).tobytes(),
                )
                amsg.timestamp.FromNanoseconds(stamp)
                writer.write(audio_topic, stamp, amsg)
            counts[audio_topic] = counts.get(audio_topic, 0) + 1
        else:
            x, y, yaw = float(ego.x[i]), float(ego.y[i]), float(ego.yaw[i])
            qx, qy, qz, qw = _quat(yaw)
            if isinstance(writer, Ros2LogWriter):
                m = writer.msg
                pose = m(
                    "geometry_msgs/msg/Pose",
                    position=m("geometry_msgs/msg/Point", x=x, y=y, z=0.0),
                    orientation=m("geometry_msgs/msg/Quaternion", x=qx, y=qy, z=qz, w=qw),
                )
                cov = np.zeros(36)
                zero = m("geometry_msgs/msg/Vector3", x=0.0, y=0.0, z=0.0)
                odom = m(
                    "nav_msgs/msg/Odometry",
                    header=writer.header(stamp, "world"),
                    child_frame_id="base_link",
                    pose=m("geometry_msgs/msg/PoseWithCovariance", pose=pose, covariance=cov),
                    twist=m(
                        "geometry_msgs/msg/TwistWithCovariance",
                        twist=m("geometry_msgs/msg/Twist", linear=zero, angular=zero),
                        covariance=cov,
                    ),
                )
                writer.write(pose_topic, stamp, odom)
            else:
                from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame

                p = PoseInFrame(frame_id="world")
                p.timestamp.FromNanoseconds(stamp)
                p.pose.position.x, p.pose.position.y = x, y
                p.pose.orientation.x, p.pose.orientation.y = qx, qy
                p.pose.orientation.z, p.pose.orientation.w = qz, qw
                writer.write(pose_topic, stamp, p)
            counts[pose_topic] = counts.get(pose_topic, 0) + 1
    return counts
