"""Fuzzing of the robotics-log readers and the data engine's input names (issue 29, item 1).

Logs (:mod:`makeway.sense.logs`): MCAP files (ROS 2 and Foxglove profiles) and ROS 2 bag folders
written by makeway's own writer from a real clip and a simulated roof-array recording, then cut,
byte-flipped, or rebuilt message by message with wrong schemas, odd encodings, bad sizes, a missing
or damaged array description. Every log is read the way the commands read it: :func:`open_log`,
every camera frame, the audio with its array description, the poses,
:func:`read_log_recording` and :class:`LogFrameReader`.

Engine inputs (:mod:`makeway.engine.inputs`): command-line names such as ``x.mp4@3:``, ``@:``,
odd unicode, NUL bytes, names too long for the file system, ``~user`` paths, through
:func:`parse_input` and :func:`expand_inputs`.

Each generated input ends in a result or one ``InputError`` naming the file
(:func:`fuzzing.check_reader`)."""

from __future__ import annotations

import io
import json
import shutil
import struct
from pathlib import Path
from typing import Any

import av
import cv2
import numpy as np
import pytest
import yaml
from hypothesis import example, given, reject
from hypothesis import strategies as st

from fuzzing import NASTY, budget, check_reader, file_contents, mutated_bytes, mutated_yaml
from makeway.engine.inputs import expand_inputs, parse_input
from makeway.errors import InputError
from makeway.sense.log_writer import FoxgloveMcapWriter, Ros2LogWriter, make_test_log
from makeway.sense.logs import LogFrameReader, open_log, read_log_recording
from makeway.sense.recording import write_recording
from makeway.sim.audio_scenarios import simulate_recording

START_NS = 1_700_000_000_000_000_000


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz_logs")


@pytest.fixture(scope="module")
def tiny_clip(video_dir: Path, work: Path) -> Path:
    """The first 3 frames of a real night clip, 64×48, H.264 in MP4."""
    path = work / "tiny.mp4"
    out = io.BytesIO()
    with (
        av.open(str(video_dir / "night_ambulance_lights.mp4")) as src,
        av.open(out, mode="w", format="mp4") as dst,
    ):
        stream = dst.add_stream("libx264", rate=25)
        stream.width, stream.height, stream.pix_fmt = 64, 48, "yuv420p"
        for i, frame in enumerate(src.decode(video=0)):
            if i == 3:
                break
            small = cv2.resize(frame.to_ndarray(format="bgr24"), (64, 48), interpolation=cv2.INTER_AREA)
            dst.mux(stream.encode(av.VideoFrame.from_ndarray(small, format="bgr24")))
        dst.mux(stream.encode(None))
    path.write_bytes(out.getvalue())
    return path


@pytest.fixture(scope="module")
def tiny_recording(work: Path) -> Path:
    """A 0.3 s simulated recording of the 8-capsule roof array (makeway's recording writer)."""
    rec = simulate_recording("crossing", 0.3, seed=5, siren="synth", noise="generated")
    return write_recording(work / "rec", rec)


@pytest.fixture(scope="module")
def seed_logs(tiny_clip: Path, tiny_recording: Path, work: Path) -> dict[str, Path]:
    """One small log per format: MCAP ROS 2 (JPEG, uncompressed chunks, so that byte flips reach
    the messages), MCAP Foxglove (raw images, zstd), ROS 2 bag (SQLite) and ROS 2 bag (MCAP)."""
    made = {}
    for name, fmt, image, compression in [
        ("ros2.mcap", "mcap-ros2", "compressed", "none"),
        ("foxglove.mcap", "mcap-foxglove", "raw", "zstd"),
        ("bag_sqlite", "ros2-bag", "raw", "none"),
        ("bag_mcap", "ros2-bag-mcap", "compressed", "none"),
    ]:
        out = work / "seeds" / name
        out.parent.mkdir(exist_ok=True)
        make_test_log(
            out, video=tiny_clip, recording=tiny_recording, fmt=fmt, image=image,
            compression=compression, start_ns=START_NS, audio_block_s=0.1,
        )  # fmt: skip
        made[name] = out
    return made


def _consume(path: Path) -> dict[str, Any]:
    """Read everything in the log ``path`` the way makeway's commands do; a summary of what came out."""
    got: dict[str, Any] = {"frames": 0, "audio": 0, "poses": 0}
    with open_log(path) as log:
        topics = log.topics()
        for name, info in topics.items():
            if info.kind == "camera":
                for _, _, image in log.frames(name):
                    assert image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3
                    got["frames"] += 1
            elif info.kind == "audio":
                audio = log.audio(name)
                assert audio.samples.ndim == 2 and audio.sample_rate > 0
                assert audio.mics is None or audio.mics.shape == (audio.samples.shape[1], 3)
                got["audio"] += audio.samples.shape[0]
            elif info.kind == "pose":
                poses = log.poses(name)
                got["poses"] += len(poses.t_ns)
        cameras = [t for t, i in topics.items() if i.kind == "camera"]
        audios = [t for t, i in topics.items() if i.kind == "audio"]
    if len(cameras) == 1:
        with LogFrameReader(path, stride=2) as reader:
            assert reader.info.fps > 0 and reader.info.width > 0
            got["frame_reader"] = sum(1 for _ in reader)
    if len(audios) == 1:
        rec = read_log_recording(path)
        assert rec.audio.ndim == 2 and rec.audio.shape[1] == len(rec.mics)
        got["recording_s"] = rec.duration_s
    return got


# --------------------------------------------------------------------------------- bytes mutated
def test_fuzz_mcap_bytes(seed_logs: dict[str, Path], work: Path) -> None:
    """An MCAP file (ROS 2 or Foxglove profile) cut short, byte-flipped, spliced or replaced."""
    seeds = {k: seed_logs[k].read_bytes() for k in ("ros2.mcap", "foxglove.mcap")}

    @budget(0.5)
    @given(pick=st.sampled_from(sorted(seeds)), data=st.data())
    def run(pick: str, data: st.DataObject) -> None:
        raw = data.draw(file_contents(seeds[pick], "binary"))
        folder = work / "mcap_bytes"
        folder.mkdir(exist_ok=True)
        path = folder / "log.mcap"
        path.write_bytes(raw)
        check_reader("robotics log (MCAP bytes)", lambda: _consume(path), inside=path)

    run()


def test_damaged_logs_found_by_the_long_fuzz_run(seed_logs: dict[str, Path], work: Path) -> None:
    """Regressions: a bag whose metadata.yaml lacks a topic's message count raised ``TypeError``
    from rosbags (its metadata is read lazily); a compressed image with no bytes made OpenCV
    assert (``cv2.error``)."""
    bag = work / "regress_bag"
    shutil.copytree(seed_logs["bag_sqlite"], bag)
    meta = yaml.safe_load((bag / "metadata.yaml").read_text(encoding="utf-8"))
    meta["rosbag2_bagfile_information"]["topics_with_message_count"][0]["message_count"] = None
    (bag / "metadata.yaml").write_text(yaml.safe_dump(meta), encoding="utf-8")
    with pytest.raises(InputError, match="is not a readable ROS 2 bag"):
        _consume(bag)

    path = work / "regress_empty_jpeg.mcap"
    with Ros2LogWriter(path, compression="none") as w:
        w.channel("/camera/image", "sensor_msgs/msg/CompressedImage")
        msg = w.msg(
            "sensor_msgs/msg/CompressedImage",
            header=w.header(START_NS),
            format="jpeg",
            data=np.zeros(0, np.uint8),
        )
        w.write("/camera/image", START_NS, msg)
    with pytest.raises(InputError, match="message 0 on /camera/image: the jpeg image does not decode"):
        _consume(path)


def test_fuzz_bag_folder(seed_logs: dict[str, Path], work: Path) -> None:
    """A ROS 2 bag folder with its metadata.yaml mutated as YAML, or its storage file (SQLite or
    MCAP) mutated byte-wise, or removed."""
    folder = work / "bag"

    @budget(0.5)
    @given(
        pick=st.sampled_from(["bag_sqlite", "bag_mcap"]),
        part=st.sampled_from(["meta", "storage"]),
        data=st.data(),
    )
    def run(pick: str, part: str, data: st.DataObject) -> None:
        shutil.rmtree(folder, ignore_errors=True)
        shutil.copytree(seed_logs[pick], folder)
        if part == "meta":
            meta = folder / "metadata.yaml"
            meta.write_bytes(data.draw(file_contents(meta.read_text(encoding="utf-8"), "yaml")))
        else:
            storage = next(p for p in folder.iterdir() if p.name != "metadata.yaml")
            if data.draw(st.integers(0, 9)) == 0:
                storage.unlink()
            else:
                storage.write_bytes(data.draw(mutated_bytes(storage.read_bytes())))
        check_reader(f"robotics log (ROS 2 bag {part})", lambda: _consume(folder), inside=folder)

    run()


# ------------------------------------------------------------------------- messages rebuilt (ROS 2)
_uint32 = st.one_of(
    st.sampled_from([0, 1, 2, 3, 8, 48, 64, 192, 16000, 2**31, 2**32 - 1]), st.integers(0, 2**32 - 1)
)
_text = st.one_of(st.sampled_from(NASTY), st.text(max_size=12))
_CAMERA_TYPES = ["sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/Image"]
_OTHER_TYPES = ["std_msgs/msg/String", "nav_msgs/msg/Odometry", "makeway_msgs/msg/RawAudio",
                "geometry_msgs/msg/PoseStamped", "std_msgs/msg/Int32"]  # fmt: skip


def _camera_msg(w: Ros2LogWriter, data: st.DataObject, stamp: int, jpeg: bytes) -> tuple[str, Any]:
    header = w.header(stamp, "camera")
    if data.draw(st.booleans()):
        fmt = data.draw(st.one_of(st.sampled_from(["jpeg", "png", "jpg; rgb8", "webp", "bmp"]), _text))
        payload = data.draw(st.one_of(st.just(jpeg), mutated_bytes(jpeg), st.binary(max_size=64)))
        return "sensor_msgs/msg/CompressedImage", w.msg(
            "sensor_msgs/msg/CompressedImage", header=header, format=fmt,
            data=np.frombuffer(payload, np.uint8),
        )  # fmt: skip
    enc = data.draw(st.one_of(st.sampled_from(["bgr8", "rgb8", "mono8", "rgba8", "16UC1", "yuv422"]), _text))
    height, width = data.draw(_uint32), data.draw(_uint32)
    step = data.draw(st.one_of(_uint32, st.just(min(width * 3, 2**32 - 1))))
    size = data.draw(st.one_of(st.integers(0, 4096), st.just(min(step * height, 1 << 16))))
    return "sensor_msgs/msg/Image", w.msg(
        "sensor_msgs/msg/Image", header=header, height=height, width=width, encoding=enc,
        is_bigendian=0, step=step, data=np.zeros(size, np.uint8),
    )  # fmt: skip


def _audio_msg(w: Ros2LogWriter, data: st.DataObject, stamp: int, pcm: bytes) -> Any:
    fmt = data.draw(st.one_of(st.sampled_from(["pcm-s16", "pcm-f32", "PCM-S16", "mulaw"]), _text))
    payload = data.draw(st.one_of(st.just(pcm), mutated_bytes(pcm), st.binary(max_size=64)))
    return w.msg(
        "makeway_msgs/msg/RawAudio", header=w.header(stamp, "base_link"), format=fmt,
        sample_rate=data.draw(st.one_of(st.just(16000), _uint32)),
        number_of_channels=data.draw(st.one_of(st.just(8), _uint32)),
        data=np.frombuffer(payload, np.uint8),
    )  # fmt: skip


def test_fuzz_log_messages(tiny_clip: Path, tiny_recording: Path, work: Path) -> None:
    """A ROS 2 log rebuilt message by message: each topic possibly of a wrong type (a camera topic
    holding strings, an audio topic holding odometry …), images with odd formats, encodings and
    sizes, audio blocks with odd formats, rates, channel counts and lengths, the array description
    missing, of a wrong type or mutated as YAML, stamps out of order; written as MCAP or a bag."""
    with av.open(str(tiny_clip)) as src:
        image = next(src.decode(video=0)).to_ndarray(format="bgr24")
    jpeg = cv2.imencode(".jpg", image)[1].tobytes()
    spec_text = (tiny_recording / "array.yaml").read_text(encoding="utf-8")
    pcm = (np.random.default_rng(0).normal(0, 3000, (160, 8))).astype("<i2").tobytes()
    folder = work / "messages"

    @budget(0.5)
    @given(data=st.data())
    def run(data: st.DataObject) -> None:
        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir()
        bag = data.draw(st.integers(0, 3)) == 0
        path = folder / ("log" if bag else "log.mcap")
        try:
            _write_messages(Ros2LogWriter(path, bag=bag, compression="none"), data, jpeg, spec_text, pcm)
        except (ValueError, TypeError, OverflowError, struct.error):
            reject()  # a value the writer cannot serialize (not the reader's concern)
        check_reader("robotics log (ROS 2 messages)", lambda: _consume(path), inside=path)

    run()


def _write_messages(
    writer: Ros2LogWriter, data: st.DataObject, jpeg: bytes, spec_text: str, pcm: bytes
) -> None:
    with writer as w:
        camera_type = data.draw(st.sampled_from(_CAMERA_TYPES + _OTHER_TYPES[:1]))
        audio_type = data.draw(st.sampled_from(["makeway_msgs/msg/RawAudio"] * 3 + _OTHER_TYPES))
        array = data.draw(st.sampled_from(["yaml", "yaml", "missing", "wrong type", "empty"]))
        for n in range(data.draw(st.integers(0, 3))):
            stamp = START_NS + data.draw(st.sampled_from([n * 40_000_000, 0, -START_NS + 1, 2**40]))
            if camera_type in _CAMERA_TYPES:
                typename, msg = _camera_msg(w, data, stamp, jpeg)
                if typename != camera_type:
                    continue
            else:
                msg = w.msg(camera_type, data=data.draw(_text))
            w.channel("/camera/image", camera_type)
            w.write("/camera/image", stamp, msg)
        if array == "yaml":
            w.channel("/audio/raw/array", "std_msgs/msg/String")
            text = data.draw(file_contents(spec_text, "yaml")).decode("utf-8", "replace")
            w.write("/audio/raw/array", START_NS, w.msg("std_msgs/msg/String", data=text))
        elif array == "wrong type":
            w.channel("/audio/raw/array", "std_msgs/msg/Int32")
            w.write("/audio/raw/array", START_NS, w.msg("std_msgs/msg/Int32", data=7))
        elif array == "empty":
            w.channel("/audio/raw/array", "std_msgs/msg/String")
        w.channel("/audio/raw", audio_type)
        for n in range(data.draw(st.integers(0, 3))):
            stamp = START_NS + data.draw(st.sampled_from([n * 10_000_000, n * 300_000_000, 0, 2**40]))
            if audio_type == "makeway_msgs/msg/RawAudio":
                w.write("/audio/raw", stamp, _audio_msg(w, data, stamp, pcm))
            elif audio_type == "std_msgs/msg/String":
                w.write("/audio/raw", stamp, w.msg(audio_type, data=data.draw(_text)))
        if data.draw(st.booleans()):
            w.channel("/ego/pose", "geometry_msgs/msg/PoseStamped")
            for n in range(data.draw(st.integers(0, 2))):
                m = w.msg
                v = data.draw(st.floats())
                pose = m(
                    "geometry_msgs/msg/Pose",
                    position=m("geometry_msgs/msg/Point", x=v, y=0.0, z=0.0),
                    orientation=m("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=v, w=1.0),
                )
                stamp = START_NS + n * 100_000_000
                w.write(
                    "/ego/pose",
                    stamp,
                    m("geometry_msgs/msg/PoseStamped", header=w.header(stamp, "world"), pose=pose),
                )


# ------------------------------------------------------------------- Foxglove JSON array description
def test_fuzz_foxglove_array_description(tiny_recording: Path, work: Path) -> None:
    """A Foxglove MCAP file whose JSON array description is any JSON value: the real one with keys
    removed or of the wrong type (``sample_rate: "abc"``, ``full_scale_db_spl: [1]``, NaN …), or
    missing."""
    spec = yaml.safe_load((tiny_recording / "array.yaml").read_text(encoding="utf-8"))
    spec_text = json.dumps(
        {k: spec[k] for k in ("sample_rate", "mics") if k in spec} | {"full_scale_db_spl": 120.0}
    )
    pcm = (np.random.default_rng(1).normal(0, 3000, (160, 8))).astype("<i2").tobytes()
    folder = work / "foxglove_array"
    rate = int(spec["sample_rate"])

    @budget(0.5)
    @given(doc=st.one_of(mutated_yaml(spec_text), st.none()))
    @example(doc=b'{"sample_rate": "abc", "mics": []}')
    def run(doc: bytes | None) -> None:
        from foxglove_schemas_protobuf.RawAudio_pb2 import RawAudio

        shutil.rmtree(folder, ignore_errors=True)
        folder.mkdir()
        path = folder / "log.mcap"
        with FoxgloveMcapWriter(path, compression="none") as w:
            if doc is not None:
                try:
                    obj = yaml.safe_load(doc)
                except yaml.YAMLError:
                    obj = doc.decode("utf-8", "replace")
                w.json_channel("/audio/raw/array", "makeway.ArrayDescription", {"type": "object"})
                w.write_json("/audio/raw/array", START_NS, obj)
            for n in range(2):
                amsg = RawAudio(format="pcm-s16", sample_rate=rate, number_of_channels=8, data=pcm)
                amsg.timestamp.FromNanoseconds(START_NS + n * 10_000_000)
                w.write("/audio/raw", START_NS + n * 10_000_000, amsg)
        check_reader("robotics log (array description JSON)", lambda: _consume(path), inside=path)

    run()


# ---------------------------------------------------------------------------------- engine inputs
_SLICES = st.one_of(
    st.sampled_from(["", "@", "@:", "@3:", "@0:", "@3:2", "@2:3", "@0:0", "@:5", "@-1:", "@3:-1", "@1:2:3",
                     "@99999999999999999999:", "@3:99999999999999999999", "@٣:", "@３:", "@3:\n", "@@3:"]),
    st.builds(lambda a, b: f"@{a}:{b}", st.integers(0, 2**70),
              st.one_of(st.just(""), st.integers(0, 2**70).map(str))),
    st.text(max_size=8).map(lambda t: "@" + t),
)  # fmt: skip


def test_fuzz_engine_input_names(
    tiny_clip: Path, tiny_recording: Path, seed_logs: dict[str, Path], work: Path
) -> None:
    """Command-line names for ``engine mine``: each real input kind (a video, a recording folder,
    an MCAP file, a bag folder, an image folder) and things that are none (an empty file, an empty
    folder, a text file named .mp4), with frame ranges well or badly formed, odd unicode, NUL bytes,
    very long names, ``~user``; one name at a time through :func:`parse_input`, and lists through
    :func:`expand_inputs` (which reports every bad name and keeps the rest)."""
    root = work / "engine"
    root.mkdir()
    shutil.copy(tiny_clip, root / "x.mp4")
    shutil.copytree(tiny_recording, root / "rec")
    shutil.copy(seed_logs["ros2.mcap"], root / "log.mcap")
    shutil.copytree(seed_logs["bag_sqlite"], root / "bag")
    (root / "images").mkdir()
    cv2.imwrite(str(root / "images" / "a.jpg"), np.zeros((8, 8, 3), np.uint8))
    (root / "empty.mp4").write_bytes(b"")
    (root / "text.mp4").write_text("not a video\n")
    (root / "empty_dir").mkdir()
    (root / "x.mp4@3:").write_bytes(b"")  # a file whose name looks like a frame range
    bases = ["x.mp4", "rec", "log.mcap", "bag", "images", "empty.mp4", "text.mp4", "empty_dir", "x.mp4@3:",
             "missing.mp4", "", ".", "..", "~", "~nobody_here_", "é.mp4", "x.mp4\x00", "a" * 300, "a/" * 2100,
             "x.mp4/"]  # fmt: skip
    name_st = st.one_of(
        st.builds(lambda b, s, absolute: (str(root / b) if absolute and b and b[0] != "~" else b) + s,
                  st.sampled_from(bases), _SLICES, st.booleans()),
        st.text(max_size=30),
    )  # fmt: skip

    @budget()
    @given(names=st.lists(name_st, min_size=1, max_size=4), segment=st.sampled_from([None, 1, 2, 1000]))
    @example(names=["x.mp4\x00@3:"], segment=None)
    @example(names=["~nobody_here_/x.mp4"], segment=None)
    def run(names: list[str], segment: int | None) -> None:
        for name in names:
            got = check_reader("engine input name", lambda name=name: parse_input(name))  # type: ignore[misc]
            if got is not None:
                assert got.path.exists() and (got.end is None or got.end > got.start)

        def expand() -> tuple[list[Any], list[tuple[str, str]]]:
            return expand_inputs(names, segment_frames=segment)

        inputs, problems = check_reader("engine input list", expand) or ([], [])
        assert len(problems) <= len(names)
        assert all("\n" not in why for _, why in problems)
        assert len({i.input_id for i in inputs}) == len(inputs)

    run()
