"""Robotics logs in: MCAP files and ROS 2 bag folders as camera, audio and pose sources (issue 28).

:func:`open_log` opens either kind and returns a :class:`LogReader`:

* ``.topics()`` — every topic with its message type, encoding, message count and kind
  (``camera``, ``audio``, ``pose``, ``array`` or ``other``);
* ``.frames(topic)`` — ``(stamp_ns, image_bgr)`` per camera message;
* ``.audio(topic)`` — the whole multichannel audio track of an audio topic (:class:`LogAudio`);
* ``.poses(topic)`` — the ego pose track of a pose/odometry topic (:class:`LogPoses`);
* ``.recording(audio_topic, pose_topic)`` — both as a :class:`~makeway.sense.recording.Recording`
  that the siren stack listens to like a recording folder.

What is read (ROS 2 types by their ``pkg/msg/Type`` names, Foxglove protobuf schemas by theirs):

* camera: ``sensor_msgs/msg/Image`` (encodings ``bgr8``, ``rgb8``, ``mono8``, ``bgra8``,
  ``rgba8``, ``8UC1``, ``8UC3``), ``sensor_msgs/msg/CompressedImage`` (JPEG, PNG, WebP),
  ``foxglove.CompressedImage``, ``foxglove.RawImage`` and ``foxglove.CompressedVideo`` (H.264 in
  Annex B form, one frame per message, no B-frames: Foxglove's rules for the schema; the messages
  are decoded in order, so a strided read still decodes every frame, and messages before the
  first keyframe are skipped). The timestamp is the message header's stamp, or the log time when
  the stamp is zero.
* audio: ``foxglove.RawAudio`` (protobuf) and, in ROS 2 logs, ``makeway_msgs/msg/RawAudio`` — the
  same fields with a ``std_msgs/Header`` (:data:`ROS_RAW_AUDIO_MSGDEF`). Blocks hold interleaved
  little-endian samples, ``pcm-s16`` (Foxglove's format) or ``pcm-f32``, one channel per
  microphone. Each block's stamp is the time of its first sample; a block that starts more than
  half a block after the samples so far end follows a dropout, which is filled with silence.
* the array description: the topic ``<audio topic>/array`` (:data:`ARRAY_SUFFIX`) holds one message
  whose text is the ``array.yaml`` of a recording folder (``sample_rate``, ``mics`` in metres in the
  vehicle frame, optional ``full_scale_db_spl``; :mod:`makeway.sense.recording`): a
  ``std_msgs/msg/String`` in ROS 2 logs, a JSON message (schema ``makeway.ArrayDescription``) in
  Foxglove-profile MCAP files.
* pose: ``nav_msgs/msg/Odometry``, ``geometry_msgs/msg/PoseStamped``, ``foxglove.PoseInFrame``;
  the planar ``x, y`` (m) and yaw (rad, counter-clockwise about z) in the message's frame.

Camera topics of indexed MCAP files are read by the direct path of
:mod:`makeway.sense.mcap_camera` (only the topic's chunks, decompressed once, the image message
parsed in place, the pixels a view of the chunk: a raw frame costs about one decompression).
Other MCAP messages, and camera messages the direct path does not take, are decoded with
``mcap_ros2`` (CDR), with protobuf message classes built from the schema's own
``FileDescriptorSet`` (as Foxglove writes it) and with ``json``; bag folders (SQLite or MCAP
storage) with ``rosbags``. A file that is not a log, a truncated or damaged log, a missing
topic (the message lists the topics there are), a topic of the wrong kind and an unsupported
encoding are each one :class:`~makeway.errors.InputError` naming the log.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import cv2
import numpy as np
import yaml
from mcap.decoder import DecoderFactory as McapDecoderFactory

from makeway.errors import InputError
from makeway.sense.recording import Recording, Trajectory
from makeway.sense.video import VideoInfo

__all__ = [
    "ARRAY_SUFFIX",
    "AUDIO_SCHEMAS",
    "CAMERA_SCHEMAS",
    "POSE_SCHEMAS",
    "ROS_RAW_AUDIO_MSGDEF",
    "LogAudio",
    "LogFrameReader",
    "LogPoses",
    "LogReader",
    "TopicInfo",
    "is_log",
    "open_frame_source",
    "open_log",
    "read_log_recording",
]

MCAP_MAGIC = b"\x89MCAP0\r\n"

CAMERA_SCHEMAS = frozenset(
    {
        "sensor_msgs/msg/Image",
        "sensor_msgs/msg/CompressedImage",
        "foxglove.CompressedImage",
        "foxglove.RawImage",
        "foxglove.CompressedVideo",
    }
)
#: Camera schemas whose messages are frames of one video stream (decoded in order, not alone).
VIDEO_SCHEMAS = frozenset({"foxglove.CompressedVideo"})
#: Video formats of ``foxglove.CompressedVideo`` that are read, with their FFmpeg decoder.
VIDEO_DECODERS = {"h264": "h264"}
AUDIO_SCHEMAS = frozenset({"foxglove.RawAudio", "makeway_msgs/msg/RawAudio"})
POSE_SCHEMAS = frozenset({"nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseStamped", "foxglove.PoseInFrame"})
ARRAY_SCHEMAS = frozenset({"std_msgs/msg/String", "makeway.ArrayDescription"})

#: The array description of audio topic ``T`` is on topic ``T + ARRAY_SUFFIX``.
ARRAY_SUFFIX = "/array"

#: The ROS 2 message definition of ``makeway_msgs/msg/RawAudio``: Foxglove's ``RawAudio`` fields
#: with a ROS header (the stamp is the time of the block's first sample).
ROS_RAW_AUDIO_MSGDEF = """std_msgs/Header header
string format
uint32 sample_rate
uint32 number_of_channels
uint8[] data
"""

_RAW_ENCODINGS = {"bgr8": 3, "rgb8": 3, "8uc3": 3, "mono8": 1, "8uc1": 1, "bgra8": 4, "rgba8": 4}
_PCM: dict[str, np.dtype[Any]] = {"pcm-s16": np.dtype("<i2"), "pcm-f32": np.dtype("<f4")}


def _ros_name(name: str) -> str:
    """``pkg/Type`` → ``pkg/msg/Type`` (ROS 1 style names as some tools write them)."""
    parts = name.split("/")
    return f"{parts[0]}/msg/{parts[1]}" if len(parts) == 2 else name


def _kind(schema: str, topic: str) -> str:
    if schema in CAMERA_SCHEMAS:
        return "camera"
    if schema in AUDIO_SCHEMAS:
        return "audio"
    if schema in POSE_SCHEMAS:
        return "pose"
    if schema in ARRAY_SCHEMAS and topic.endswith(ARRAY_SUFFIX):
        return "array"
    return "other"


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a log: its name, message type (schema name), message encoding (``cdr``,
    ``protobuf``, ``json``), number of messages and kind (``camera``, ``audio``, ``pose``,
    ``array`` or ``other``)."""

    name: str
    schema: str
    encoding: str
    count: int
    kind: str


@dataclass
class LogAudio:
    """An audio topic read whole: ``samples (n, channels)`` float32 in full-scale units (int16 ÷
    32768), ``sample_rate`` Hz, ``start_ns`` the stamp of the first sample (ns), ``mics
    (channels, 3)`` the capsule positions from the array description (m, vehicle frame) or
    ``None`` when the log has none, ``full_scale_db_spl`` the array's calibration (``None``: not
    stated)."""

    samples: np.ndarray
    sample_rate: int
    start_ns: int
    mics: np.ndarray | None = None
    full_scale_db_spl: float | None = None

    @property
    def duration_s(self) -> float:
        return self.samples.shape[0] / float(self.sample_rate)


@dataclass
class LogPoses:
    """A pose topic read whole: ``t_ns`` stamps (ns), planar ``x``, ``y`` (m) and ``yaw`` (rad) in
    the messages' frame (``frame_id``)."""

    t_ns: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    frame_id: str = ""


def _yaw(q: Any) -> float:
    """Yaw (rad) of a quaternion with fields ``x, y, z, w``."""
    x, y, z, w = float(q.x), float(q.y), float(q.z), float(q.w)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _stamp_ns(msg: Any, log_time_ns: int) -> int:
    """The message's own stamp (ROS ``header.stamp`` or Foxglove ``timestamp``), else the log time."""
    header = getattr(msg, "header", None)
    if header is not None:
        stamp = header.stamp
        ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    else:
        ts = getattr(msg, "timestamp", None)
        ns = int(ts.seconds) * 1_000_000_000 + int(ts.nanos) if ts is not None else 0
    return ns if ns > 0 else log_time_ns


def _own_stamp(msg: Any, log_time_ns: int) -> int:
    """:func:`_stamp_ns` of a message parsed in place (:class:`~makeway.sense.mcap_camera.ImageMessage`)
    or decoded the general way."""
    stamp = getattr(msg, "stamp_ns", None)
    if stamp is None:
        return _stamp_ns(msg, log_time_ns)
    return int(stamp) if stamp > 0 else log_time_ns


def _bytes(data: Any) -> np.ndarray:
    """A message's byte payload (``bytes`` from mcap_ros2 and protobuf, a uint8 array from rosbags)."""
    if isinstance(data, bytes | bytearray | memoryview):
        return np.frombuffer(data, dtype=np.uint8)
    return np.asarray(data, dtype=np.uint8).reshape(-1)


class _VideoDecoder:
    """Decoder of one pass over a video camera topic (``foxglove.CompressedVideo``): every message
    in order, one frame each, as BGR ``uint8``. One decoder thread: the CPU cost is what is
    compared with reading an mp4, and one-in-one-out keeps message and frame aligned."""

    def __init__(self, path: Path, topic: str) -> None:
        self.path = path
        self.topic = topic
        self.decoded = 0
        self._ctx: Any = None
        self._format = ""

    def decode(self, msg: Any, index: int) -> np.ndarray | None:
        """The frame of message ``index``; ``None`` for a delta frame before the first keyframe.

        Raises:
            InputError: an unsupported format, a change of format, or a frame that does not
                decode after the stream started.
        """
        import av

        where = f"message {index} on {self.topic}"
        fmt = str(msg.format).lower()
        if fmt not in VIDEO_DECODERS:
            raise InputError(
                self.path, f"{where}: unsupported video format {msg.format!r} ({', '.join(VIDEO_DECODERS)})"
            )
        if self._ctx is None:
            self._ctx = av.CodecContext.create(VIDEO_DECODERS[fmt], "r")
            self._ctx.thread_count = 1
            self._format = fmt
        elif fmt != self._format:
            raise InputError(self.path, f"{where}: video format changes from {self._format} to {fmt}")
        payload = bytes(_bytes(msg.data))
        try:
            frames = self._ctx.decode(av.Packet(payload)) if payload else []
        except av.error.FFmpegError:
            frames = []
        if not frames:
            if self.decoded == 0:
                return None  # no keyframe yet: a recording may start inside a group of pictures
            raise InputError(self.path, f"{where}: the {fmt} frame does not decode (damaged)")
        self.decoded += 1
        frame = frames[-1]
        if frame.format.name == "yuv420p" and frame.width % 2 == 0 and frame.height % 2 == 0:
            # OpenCV's I420 → BGR (BT.601, limited range: what an mp4 read through OpenCV gives)
            # costs about half of FFmpeg's own conversion.
            return cv2.cvtColor(frame.to_ndarray(), cv2.COLOR_YUV2BGR_I420)
        image: np.ndarray = frame.to_ndarray(format="bgr24")
        return image


class LogReader:
    """A robotics log opened for reading (use :func:`open_log`); a context manager.

    Subclasses fill the topic table when they open and provide :meth:`_messages` and
    :meth:`close`; the decoding of cameras, audio and poses is shared. ``kind`` says which kind of
    log it is (``mcap`` or ``ros2 bag``).
    """

    kind = "log"

    def __init__(self, path: Path) -> None:
        self.path = path
        self._topics: dict[str, TopicInfo] = {}

    # -------------------------------------------------------------------------------- subclasses

    def _messages(self, topics: Iterable[str]) -> Iterator[tuple[str, int, Any]]:
        """``(topic, log_time_ns, decoded message)`` for ``topics``, in log-time order."""
        raise NotImplementedError

    def close(self) -> None:
        """Release the log; safe to call more than once."""

    # ----------------------------------------------------------------------------------- topics

    def topics(self) -> dict[str, TopicInfo]:
        """Every topic of the log by name."""
        return dict(self._topics)

    def topic(self, name: str, kind: str | None = None) -> TopicInfo:
        """The topic ``name``, checked to be of ``kind``.

        Raises:
            InputError: no such topic (lists the topics there are, of that kind first), or the
                topic is of another kind.
        """
        info = self._topics.get(name)
        if info is None:
            same = [t for t, i in self._topics.items() if kind is None or i.kind == kind]
            listed = ", ".join(f"{t} ({self._topics[t].schema})" for t in same) or "none"
            what = f"{kind} topics" if kind is not None else "topics"
            raise InputError(self.path, f"has no topic {name!r}; its {what}: {listed}")
        if kind is not None and info.kind != kind:
            raise InputError(
                self.path, f"topic {name!r} holds {info.schema}, not a {kind} message type this reader knows"
            )
        return info

    def only_topic(self, kind: str) -> str:
        """The one topic of ``kind`` (for commands run without a topic name).

        Raises:
            InputError: the log has none, or more than one (they are listed).
        """
        names = [t for t, i in self._topics.items() if i.kind == kind]
        if len(names) == 1:
            return names[0]
        if not names:
            listed = ", ".join(f"{t} ({i.schema})" for t, i in self._topics.items()) or "none"
            raise InputError(self.path, f"has no {kind} topic; its topics: {listed}")
        raise InputError(self.path, f"has {len(names)} {kind} topics, name one: {', '.join(names)}")

    # ---------------------------------------------------------------------------------- cameras

    def frames(
        self, topic: str, *, stride: int = 1, max_frames: int | None = None
    ) -> Iterator[tuple[int, int, np.ndarray]]:
        """``(message_index, stamp_ns, image_bgr)`` for every ``stride``-th message of the camera
        ``topic`` (message indices count from 0), at most ``max_frames`` of them.

        Raises:
            InputError: not a camera topic, an unsupported encoding, or an image that does not decode.
        """
        info = self.topic(topic, "camera")
        video = _VideoDecoder(self.path, topic) if info.schema in VIDEO_SCHEMAS else None
        yielded = 0
        for index, (_, log_ns, msg) in enumerate(self._messages([topic])):
            if video is not None:
                image = video.decode(msg, index)  # every frame: the next ones are coded against it
                if image is None or index % stride:
                    continue
            elif index % stride:
                continue
            else:
                image = self._image(msg, info.schema, topic, index)
            yield index, _stamp_ns(msg, log_ns), image
            yielded += 1
            if max_frames is not None and yielded >= max_frames:
                return
        if video is not None and video.decoded == 0:
            raise InputError(self.path, f"no frame of video topic {topic} decodes (no keyframe)")

    def stamps(self, topic: str, limit: int | None = None) -> list[int]:
        """The stamps (ns) of the first ``limit`` messages of ``topic`` (all: ``None``), without
        decoding their images or samples."""
        out: list[int] = []
        for _, log_ns, msg in self._messages([topic]):
            out.append(_stamp_ns(msg, log_ns))
            if limit is not None and len(out) >= limit:
                break
        return out

    def _image(self, msg: Any, schema: str, topic: str, index: int) -> np.ndarray:
        where = f"message {index} on {topic}"
        if schema in ("sensor_msgs/msg/CompressedImage", "foxglove.CompressedImage"):
            fmt = str(msg.format).lower()
            if not any(k in fmt for k in ("jpeg", "jpg", "png", "webp")):
                raise InputError(
                    self.path, f"{where}: unsupported image format {msg.format!r} (jpeg, png, webp)"
                )
            payload = _bytes(msg.data)
            try:  # OpenCV asserts on an empty buffer instead of returning None
                image = cv2.imdecode(payload, cv2.IMREAD_COLOR) if payload.size else None
            except cv2.error:
                image = None
            if image is None:
                raise InputError(self.path, f"{where}: the {msg.format} image does not decode (damaged)")
            return image
        encoding = str(msg.encoding).lower()
        channels = _RAW_ENCODINGS.get(encoding)
        if channels is None:
            raise InputError(
                self.path,
                f"{where}: unsupported raw image encoding {msg.encoding!r} "
                f"(supported: {', '.join(sorted(_RAW_ENCODINGS))})",
            )
        height, width, step = int(msg.height), int(msg.width), int(msg.step)
        data = _bytes(msg.data)
        if height < 1 or width < 1 or step < width * channels or data.size < step * height:
            raise InputError(
                self.path,
                f"{where}: {width}x{height} {encoding} image with step {step} needs {step * height} bytes, "
                f"has {data.size}",
            )
        rows = data[: step * height].reshape(height, step)[:, : width * channels]
        image = rows.reshape(height, width, channels)
        if encoding in ("mono8", "8uc1"):
            return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        if encoding == "rgb8":
            return cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
        if encoding == "bgra8":
            return cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
        if encoding == "rgba8":
            return cv2.cvtColor(image, cv2.COLOR_RGBA2BGR)
        return np.ascontiguousarray(image)

    # ------------------------------------------------------------------------------------ audio

    def audio(self, topic: str) -> LogAudio:
        """Every block of the audio ``topic``, joined, with the array description when there is one.

        Raises:
            InputError: not an audio topic, no messages, an unsupported sample format, blocks
                that change rate or channel count, or an array description that does not fit.
        """
        self.topic(topic, "audio")
        blocks: list[np.ndarray] = []
        rate = channels = filled = 0
        start_ns = 0
        for index, (_, log_ns, msg) in enumerate(self._messages([topic])):
            fmt = str(msg.format).lower()
            dtype = _PCM.get(fmt)
            if dtype is None:
                raise InputError(
                    self.path,
                    f"message {index} on {topic}: unsupported audio format {msg.format!r} (pcm-s16, pcm-f32)",
                )
            r, c = int(msg.sample_rate), int(msg.number_of_channels)
            if index == 0:
                rate, channels, start_ns = r, c, _stamp_ns(msg, log_ns)
                if rate < 1 or channels < 1:
                    raise InputError(self.path, f"{topic}: sample rate {rate} Hz and {channels} channel(s)")
            elif (r, c) != (rate, channels):
                raise InputError(
                    self.path,
                    f"message {index} on {topic}: {c} channel(s) at {r} Hz after {channels} at {rate} Hz",
                )
            raw = _bytes(msg.data)
            if raw.size % (dtype.itemsize * channels):
                raise InputError(
                    self.path, f"message {index} on {topic}: {raw.size} bytes is not whole frames"
                )
            samples = raw.view(dtype).reshape(-1, channels)
            # a dropped block (this one starts more than half a block after the samples so far): silence
            gap = int(round((_stamp_ns(msg, log_ns) - start_ns) * 1e-9 * rate)) - filled
            if index > 0 and gap > max(1, len(samples) // 2):
                blocks.append(np.zeros((gap, channels), np.float32))
                filled += gap
            filled += len(samples)
            blocks.append(
                samples.astype(np.float32) / 32768.0 if fmt == "pcm-s16" else samples.astype(np.float32)
            )
        if not blocks:
            raise InputError(self.path, f"audio topic {topic} holds no messages")
        audio = LogAudio(np.concatenate(blocks, axis=0), rate, start_ns)
        array_topic = topic + ARRAY_SUFFIX
        if array_topic in self._topics:
            self._read_array(array_topic, audio)
        return audio

    def _read_array(self, topic: str, audio: LogAudio) -> None:
        problem = f"array description on {topic}"
        for _, _, msg in self._messages([topic]):
            # a ROS std_msgs/String holds YAML text; a JSON channel decodes to any JSON value
            spec = getattr(msg, "data", msg) if not isinstance(msg, dict) else msg
            if isinstance(spec, str):
                try:
                    spec = yaml.safe_load(spec)
                except yaml.YAMLError as exc:
                    raise InputError(self.path, f"{problem} is not YAML ({_first_line(exc)})") from None
            break
        else:
            return
        if not isinstance(spec, dict) or "mics" not in spec:
            raise InputError(self.path, f"{problem} has no 'mics' list")
        try:
            mics = np.asarray(spec["mics"], dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(self.path, f"{problem}: 'mics' is not a list of [x, y, z]") from None
        if mics.ndim != 2 or mics.shape[1] != 3 or not np.all(np.isfinite(mics)):
            raise InputError(self.path, f"{problem}: 'mics' is not a list of [x, y, z]")
        if len(mics) != audio.samples.shape[1]:
            raise InputError(
                self.path,
                f"{problem} lists {len(mics)} microphone(s), the audio has "
                f"{audio.samples.shape[1]} channel(s)",
            )
        rate = spec.get("sample_rate", audio.sample_rate)
        if isinstance(rate, bool) or not isinstance(rate, int | float) or rate != audio.sample_rate:
            raise InputError(
                self.path, f"{problem} says sample_rate {rate!r}, the audio is {audio.sample_rate} Hz"
            )
        full = spec.get("full_scale_db_spl")
        if full is not None and (
            isinstance(full, bool) or not isinstance(full, int | float) or not math.isfinite(full)
        ):
            raise InputError(self.path, f"{problem}: full_scale_db_spl {full!r} is not a number (dB SPL)")
        audio.mics = mics
        audio.full_scale_db_spl = None if full is None else float(full)

    # ------------------------------------------------------------------------------------ poses

    def poses(self, topic: str) -> LogPoses:
        """Every pose of the pose/odometry ``topic`` (planar part).

        Raises:
            InputError: not a pose topic, or no messages.
        """
        info = self.topic(topic, "pose")
        t, x, y, yaw = [], [], [], []
        frame_id = ""
        for _, log_ns, msg in self._messages([topic]):
            if info.schema == "nav_msgs/msg/Odometry":
                pose = msg.pose.pose
                frame_id = str(msg.header.frame_id)
            else:
                pose = msg.pose
                frame_id = str(msg.header.frame_id) if hasattr(msg, "header") else str(msg.frame_id)
            t.append(_stamp_ns(msg, log_ns))
            x.append(float(pose.position.x))
            y.append(float(pose.position.y))
            yaw.append(_yaw(pose.orientation))
        if not t:
            raise InputError(self.path, f"pose topic {topic} holds no messages")
        return LogPoses(
            np.asarray(t, dtype=np.int64), np.asarray(x), np.asarray(y), np.asarray(yaw), frame_id
        )

    def recording(self, audio_topic: str, pose_topic: str | None = None) -> Recording:
        """The audio topic (with its array description) and the ego poses as a
        :class:`~makeway.sense.recording.Recording` (time 0 = the first audio sample; no siren
        sources: a log does not know them). Without ``pose_topic`` the ego stands at the origin.

        Raises:
            InputError: as :meth:`audio` and :meth:`poses`; the log has no array description.
        """
        audio = self.audio(audio_topic)
        if audio.mics is None:
            raise InputError(
                self.path,
                f"audio topic {audio_topic} has no array description (topic {audio_topic}{ARRAY_SUFFIX}); "
                "the siren stack needs the microphone positions",
            )
        duration = audio.duration_s
        if pose_topic is not None:
            poses = self.poses(pose_topic)
            t = (poses.t_ns - audio.start_ns) / 1e9
            order = np.argsort(t, kind="stable")
            t, keep = np.unique(t[order], return_index=True)
            idx = order[keep]
            ego = Trajectory(t, poses.x[idx], poses.y[idx], poses.yaw[idx])
        else:
            ego = Trajectory(np.array([0.0, duration]), np.zeros(2), np.zeros(2), np.zeros(2))
        return Recording(
            audio.samples,
            audio.sample_rate,
            audio.mics,
            ego,
            [],
            self.path,
            {
                "log": str(self.path),
                "audio_topic": audio_topic,
                "pose_topic": pose_topic,
                "start_ns": audio.start_ns,
            },
            audio.full_scale_db_spl,
        )

    # ------------------------------------------------------------------------------- life cycle

    def __enter__(self) -> LogReader:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


# ------------------------------------------------------------------------------------------ MCAP


class _ProtobufDecoders(McapDecoderFactory):
    """An ``mcap`` decoder factory for ``protobuf`` channels: message classes are built from the
    schema record's serialized ``FileDescriptorSet``."""

    def decoder_for(self, message_encoding: str, schema: Any) -> Any:
        if message_encoding != "protobuf" or schema is None or schema.encoding != "protobuf":
            return None
        from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

        fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
        pool = descriptor_pool.DescriptorPool()
        for fd in fds.file:
            pool.Add(fd)
        cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
        return cls.FromString


class _JsonDecoders(McapDecoderFactory):
    def decoder_for(self, message_encoding: str, schema: Any) -> Any:
        return (lambda data: json.loads(bytes(data))) if message_encoding == "json" else None


class McapLog(LogReader):
    """An MCAP file (any profile: ROS 2 ``cdr`` and Foxglove ``protobuf``/``json`` channels)."""

    kind = "mcap"

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        from mcap.reader import make_reader
        from mcap_ros2.decoder import DecoderFactory

        self._file = path.open("rb")
        self._summary: Any = None
        self._camera_indexes: dict[str, Any] = {}
        self._decoders: list[McapDecoderFactory] = [DecoderFactory(), _ProtobufDecoders(), _JsonDecoders()]
        try:
            reader = make_reader(self._file, decoder_factories=self._decoders)
            try:
                summary = reader.get_summary()
            except Exception:  # a cut-off file ends in message data, not in a summary: scan it below
                summary = None
            counts: dict[int, int] | None = None
            if summary is not None and summary.statistics is not None:
                counts = dict(summary.statistics.channel_message_counts)
            if summary is None or counts is None:
                # no summary (a truncated file has none): scan the whole file, which also checks it
                counts = {}
                channels, schemas = {}, {}
                for schema, channel, _ in self._scan():
                    counts[channel.id] = counts.get(channel.id, 0) + 1
                    channels[channel.id] = channel
                    if schema is not None:
                        schemas[schema.id] = schema
            else:
                channels, schemas = summary.channels, summary.schemas
            self._summary = summary  # None for a file without one: no direct camera path
        except InputError:
            self._file.close()
            raise
        except Exception as exc:
            self._file.close()
            raise InputError(path, f"is not a readable MCAP file ({_first_line(exc)})") from None
        for cid, channel in channels.items():
            schema = schemas.get(channel.schema_id)
            name = (
                _ros_name(schema.name)
                if schema is not None and schema.encoding == "ros2msg"
                else (schema.name if schema is not None else "")
            )
            self._topics[channel.topic] = TopicInfo(
                channel.topic, name, channel.message_encoding, counts.get(cid, 0), _kind(name, channel.topic)
            )

    # ------------------------------------------------ cameras: the direct path (sense.mcap_camera)

    def _camera_index(self, topic: str) -> Any:
        """The direct reader of camera ``topic`` (:func:`makeway.sense.mcap_camera.camera_index`),
        or ``None`` where the general reader must do."""
        if topic not in self._camera_indexes:
            from makeway.sense.mcap_camera import camera_index

            info = self._topics[topic]
            self._camera_indexes[topic] = camera_index(
                self.path, self._file, self._summary, topic, info.schema, self._decoder_of(topic)
            )
        return self._camera_indexes[topic]

    def reads_directly(self, topic: str) -> bool:
        """Whether the camera ``topic`` is read by the direct path (an indexed file, zstd, lz4 or
        uncompressed chunks, a ROS 2 or Foxglove image schema); else the ``mcap`` reader decodes
        it. Both give the same frames."""
        return self.topic(topic, "camera") is not None and self._camera_index(topic) is not None

    def _decoder_of(self, topic: str) -> Any:
        """The general decoder of ``topic``'s messages (``bytes`` → message), made on first use."""
        made: list[Any] = []

        def decode(data: bytes) -> Any:
            if not made:
                summary = self._summary
                channel = next(c for c in summary.channels.values() if c.topic == topic)
                schema = summary.schemas.get(channel.schema_id)
                for factory in self._decoders:
                    decoder = factory.decoder_for(channel.message_encoding, schema)
                    if decoder is not None:
                        made.append(decoder)
                        break
                else:
                    raise ValueError(f"no decoder for {channel.message_encoding} messages")
            return made[0](data)

        return decode

    def frames(
        self, topic: str, *, stride: int = 1, max_frames: int | None = None
    ) -> Iterator[tuple[int, int, np.ndarray]]:
        """As :meth:`LogReader.frames`, by the direct path where the file allows it
        (:meth:`reads_directly`): only the chunks holding the selected messages are read, raw
        images are views of the decompressed chunk (writable; one frame keeps its chunk alive)."""
        info = self.topic(topic, "camera")
        index = self._camera_index(topic)
        if index is None:
            yield from super().frames(topic, stride=stride, max_frames=max_frames)
            return
        n = len(index)
        if max_frames is not None:
            n = min(n, max_frames * stride)
        for k, log_ns, msg in index.messages(iter(range(0, n, stride))):
            yield k, _own_stamp(msg, log_ns), self._image(msg, info.schema, topic, k)

    def stamps(self, topic: str, limit: int | None = None) -> list[int]:
        """As :meth:`LogReader.stamps`; a camera topic read directly decompresses each chunk only
        up to the stamp."""
        info = self._topics.get(topic)
        index = self._camera_index(topic) if info is not None and info.kind == "camera" else None
        if index is None:
            return super().stamps(topic, limit)
        out: list[int] = []
        for k, (log_ns, own) in enumerate(index.stamps(limit)):
            if own is None:  # not where the in-place parser looks: decode the message whole
                _, _, msg = next(index.messages(iter([k])))
                out.append(_own_stamp(msg, log_ns))
            else:
                out.append(own if own > 0 else log_ns)
        return out

    def _scan(self) -> Iterator[tuple[Any, Any, Any]]:
        from mcap.reader import NonSeekingReader  # reads every record in order, so it checks them all

        self._file.seek(0)
        try:
            yield from NonSeekingReader(self._file).iter_messages()
        except Exception as exc:
            raise InputError(self.path, f"is truncated or damaged ({_first_line(exc)})") from None

    def _messages(self, topics: Iterable[str]) -> Iterator[tuple[str, int, Any]]:
        from mcap.reader import make_reader

        self._file.seek(0)
        reader = make_reader(self._file, decoder_factories=self._decoders)
        try:
            for _, channel, message, decoded in reader.iter_decoded_messages(topics=list(topics)):
                yield channel.topic, int(message.log_time), decoded
        except InputError:
            raise
        except Exception as exc:
            raise InputError(self.path, f"is truncated or damaged ({_first_line(exc)})") from None

    def close(self) -> None:
        self._file.close()


# --------------------------------------------------------------------------------- ROS 2 bag folder


class BagLog(LogReader):
    """A ROS 2 bag folder (``metadata.yaml`` + SQLite or MCAP storage), read with ``rosbags``."""

    kind = "ros2 bag"

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        from rosbags.highlevel import AnyReader

        reader = None
        try:
            reader = AnyReader([path])
            reader.open()
            # rosbags reads parts of metadata.yaml lazily: a damaged one fails here, not at open
            for name, info in reader.topics.items():
                schema = _ros_name(info.msgtype or "")
                encoding = info.connections[0].ext.serialization_format if info.connections else "cdr"  # type: ignore[union-attr]
                self._topics[name] = TopicInfo(
                    name, schema, str(encoding), int(info.msgcount), _kind(schema, name)
                )
        except Exception as exc:
            try:
                if reader is not None:
                    reader.close()
            except Exception:  # it did not open: nothing to release
                pass
            raise InputError(path, f"is not a readable ROS 2 bag ({_first_line(exc)})") from None
        self._reader = reader

    def _raw_messages(self, topics: Iterable[str]) -> Iterator[tuple[Any, int, Any]]:
        """``(connection, log_time_ns, serialized bytes)`` for ``topics``, in log-time order."""
        wanted = set(topics)
        conns = [c for c in self._reader.connections if c.topic in wanted]
        try:
            for conn, stamp, raw in self._reader.messages(connections=conns):
                yield conn, int(stamp), raw
        except InputError:
            raise
        except Exception as exc:
            raise InputError(self.path, f"is truncated or damaged ({_first_line(exc)})") from None

    def _deserialize(self, raw: Any, conn: Any) -> Any:
        try:
            return self._reader.deserialize(raw, conn.msgtype)
        except Exception as exc:
            raise InputError(self.path, f"is truncated or damaged ({_first_line(exc)})") from None

    def _messages(self, topics: Iterable[str]) -> Iterator[tuple[str, int, Any]]:
        for conn, stamp, raw in self._raw_messages(topics):
            yield conn.topic, stamp, self._deserialize(raw, conn)

    def _parses_in_place(self, topic: str) -> bool:
        info = self._topics.get(topic)
        return (
            info is not None
            and info.encoding == "cdr"
            and info.schema in ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
        )

    def frames(
        self, topic: str, *, stride: int = 1, max_frames: int | None = None
    ) -> Iterator[tuple[int, int, np.ndarray]]:
        """As :meth:`LogReader.frames`; ROS 2 image messages are parsed in place
        (:func:`makeway.sense.mcap_camera.parse_ros_image`) and the skipped ones not at all."""
        info = self.topic(topic, "camera")
        if not self._parses_in_place(topic):
            yield from super().frames(topic, stride=stride, max_frames=max_frames)
            return
        from makeway.sense.mcap_camera import parse_ros_image

        compressed = info.schema.endswith("CompressedImage")
        yielded = 0
        for index, (conn, log_ns, raw) in enumerate(self._raw_messages([topic])):
            if index % stride:
                continue
            msg: Any = parse_ros_image(raw, compressed)
            if msg is None:
                msg = self._deserialize(raw, conn)
            yield index, _own_stamp(msg, log_ns), self._image(msg, info.schema, topic, index)
            yielded += 1
            if max_frames is not None and yielded >= max_frames:
                return

    def stamps(self, topic: str, limit: int | None = None) -> list[int]:
        """As :meth:`LogReader.stamps`; ROS 2 image stamps are read from the CDR bytes."""
        if not self._parses_in_place(topic):
            return super().stamps(topic, limit)
        from makeway.sense.mcap_camera import ros_stamp

        out: list[int] = []
        for conn, log_ns, raw in self._raw_messages([topic]):
            own = ros_stamp(raw)
            if own is None:
                out.append(_stamp_ns(self._deserialize(raw, conn), log_ns))
            else:
                out.append(own if own > 0 else log_ns)
            if limit is not None and len(out) >= limit:
                break
        return out

    def close(self) -> None:
        self._reader.close()


# ------------------------------------------------------------------------------------------ open


def _first_line(exc: BaseException) -> str:
    if type(exc).__name__ == "EndOfFile":
        return "it ends in the middle of a record"
    text = str(exc).strip().splitlines()
    return (text[0] if text else type(exc).__name__)[:200]


def is_log(path: str | Path) -> bool:
    """Whether ``path`` looks like a robotics log: a file starting with the MCAP magic bytes (or
    named ``*.mcap``), or a folder holding a ROS 2 bag's ``metadata.yaml``."""
    p = Path(path)
    if p.is_dir():
        return (p / "metadata.yaml").is_file()
    if p.suffix.lower() == ".mcap":
        return True
    try:
        with p.open("rb") as f:
            return f.read(len(MCAP_MAGIC)) == MCAP_MAGIC
    except OSError:
        return False


def open_log(path: str | Path) -> LogReader:
    """Open an MCAP file or a ROS 2 bag folder.

    Raises:
        InputError: the path is missing, is neither kind, or is truncated or damaged.
    """
    p = Path(path)
    if not p.exists():
        raise InputError(p, "no such file or folder")
    if p.is_dir():
        if not (p / "metadata.yaml").is_file():
            raise InputError(
                p, "is a folder without metadata.yaml; expected an MCAP file or a ROS 2 bag folder"
            )
        return BagLog(p)
    with p.open("rb") as f:
        head = f.read(len(MCAP_MAGIC))
    if head != MCAP_MAGIC:
        raise InputError(p, "is not an MCAP file (no MCAP magic bytes at the start)")
    return McapLog(p)


class LogFrameReader:
    """A camera topic behind the interface of :class:`~makeway.sense.video.VideoReader`: frames come
    out as ``(message_index, time_s, image_bgr)`` with ``time_s`` from the message stamps, relative
    to the first frame; ``info`` is a :class:`~makeway.sense.video.VideoInfo` whose ``fps`` is the
    median message rate and whose ``frame_count`` is the topic's message count. ``start_ns`` is
    the first frame's stamp (ns), so outputs can keep the log's clock.

    Raises:
        InputError: as :func:`open_log`; the topic is missing or not a camera topic (``topic=None``:
            the log must have exactly one), or its first image does not decode.
    """

    def __init__(
        self, path: str | Path, topic: str | None = None, *, stride: int = 1, max_frames: int | None = None
    ) -> None:
        if isinstance(stride, bool) or not isinstance(stride, int) or stride < 1:
            raise ValueError(f"stride must be an integer >= 1, got {stride!r}")
        self.path = Path(path)
        self.stride = stride
        self.max_frames = max_frames
        self.log = open_log(path)
        try:
            self.topic = topic if topic is not None else self.log.only_topic("camera")
            count = self.log.topic(self.topic, "camera").count
            first: np.ndarray | None = None
            for _, _, image in self.log.frames(self.topic, max_frames=1):  # decodes: a bad image fails now
                first = image
            if first is None:
                raise InputError(self.path, f"camera topic {self.topic} holds no messages")
            stamps = self.log.stamps(self.topic, 50)
        except BaseException:
            self.log.close()
            raise
        steps = np.diff(np.asarray(stamps, dtype=np.float64)) / 1e9
        steps = steps[steps > 0]
        fps = float(1.0 / np.median(steps)) if steps.size else 25.0
        self.start_ns = stamps[0]
        self.info = VideoInfo(
            path=self.path,
            width=int(first.shape[1]),
            height=int(first.shape[0]),
            fps=fps,
            frame_count=count,
            duration_s=count / fps,
            fps_assumed=not steps.size,
        )
        self.frames_read = 0
        self.frames_yielded = 0
        self.reached_end = False

    def __iter__(self) -> Iterator[tuple[int, float, np.ndarray]]:
        self.frames_read = self.frames_yielded = 0
        self.reached_end = False
        for index, stamp, image in self.log.frames(
            self.topic, stride=self.stride, max_frames=self.max_frames
        ):
            self.frames_read = index + 1
            self.frames_yielded += 1
            yield index, (stamp - self.start_ns) / 1e9, image
        self.reached_end = self.max_frames is None or self.frames_yielded < self.max_frames

    def check_complete(self) -> None:
        """Nothing to check beyond decoding: a damaged log raises while it is read."""

    def close(self) -> None:
        self.log.close()

    def __enter__(self) -> LogFrameReader:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


def read_log_recording(
    path: str | Path, audio_topic: str | None = None, pose_topic: str | None = None
) -> Recording:
    """The audio and ego path of the log ``path`` as a :class:`~makeway.sense.recording.Recording`
    (:meth:`LogReader.recording`). ``audio_topic=None``: the log's only audio topic;
    ``pose_topic=None``: its only pose topic when it has exactly one, else the ego stands still.

    Raises:
        InputError: as :func:`open_log` and :meth:`LogReader.recording`.
    """
    with open_log(path) as log:
        audio = audio_topic if audio_topic is not None else log.only_topic("audio")
        if pose_topic is None:
            poses = [t for t, i in log.topics().items() if i.kind == "pose"]
            pose_topic = poses[0] if len(poses) == 1 else None
        return log.recording(audio, pose_topic)


def open_frame_source(
    path: str | Path, topic: str | None = None, *, stride: int = 1, max_frames: int | None = None
) -> Any:
    """A video file's :class:`~makeway.sense.video.VideoReader`, or a log's camera ``topic`` as a
    :class:`LogFrameReader` (both iterate ``(index, time_s, image_bgr)`` and have ``info``,
    ``check_complete()``, ``close()``).

    Raises:
        InputError: as the readers; a ``topic`` given for a file that is not a log.
    """
    from makeway.sense.video import VideoReader

    if is_log(path):
        return LogFrameReader(path, topic, stride=stride, max_frames=max_frames)
    if topic is not None:
        raise InputError(path, "a camera topic was named, but this is not an MCAP file or a ROS 2 bag folder")
    return VideoReader(path, stride=stride, max_frames=max_frames)
