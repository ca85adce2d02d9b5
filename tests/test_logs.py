"""Issue 28, items 1, 2 and 5: robotics logs in (MCAP, ROS 2 bags) and Foxglove-ready MCAP out.

The logs are made here, in tmp_path, from a shared clip and a recording simulated from the shared
siren and street recordings, with the same libraries a fleet uses (mcap, rosbags, the Foxglove
protobuf schemas); they are read back with independent decoders (mcap_ros2 for CDR in MCAP).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from makeway.cli.main import app
from makeway.errors import InputError
from makeway.perceive.audio.stream import listen
from makeway.sense.log_writer import LOG_FORMATS, Ros2LogWriter, make_test_log
from makeway.sense.logs import open_log, read_log_recording
from makeway.sense.recording import Recording, read_recording, write_recording
from makeway.sense.video import VideoReader
from makeway.sim.audio_scenarios import simulate_recording

runner = CliRunner()
N_FRAMES = 6
START_NS = 1_700_000_000_000_000_000
CLIP = "night_ambulance_lights.mp4"


@pytest.fixture(scope="module")
def rec_dir(data_root: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 3 s roof-array recording: a real recorded siren closing from behind in real street noise."""
    rec = simulate_recording("from_behind", 3.0, seed=3, siren="real", noise="real", data_root=data_root)
    return write_recording(tmp_path_factory.mktemp("rec") / "rec", rec)


@pytest.fixture(scope="module")
def clip(video_dir: Path) -> Path:
    return video_dir / CLIP


@pytest.fixture(scope="module")
def video_frames(clip: Path) -> list[np.ndarray]:
    with VideoReader(clip, max_frames=N_FRAMES) as reader:
        return [f for _, _, f in reader]


@pytest.fixture(scope="module")
def logs(clip: Path, rec_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[tuple[str, str], Path]:
    """Every log format × image kind, from the clip and the recording."""
    root = tmp_path_factory.mktemp("logs")
    made = {}
    for fmt in LOG_FORMATS:
        for image in ("compressed", "raw"):
            out = root / (f"{fmt}_{image}" + ("" if fmt.startswith("ros2-bag") else ".mcap"))
            make_test_log(
                out,
                video=clip,
                recording=rec_dir,
                fmt=fmt,
                image=image,
                max_frames=N_FRAMES,
                start_ns=START_NS,
            )
            made[(fmt, image)] = out
    return made


# ----------------------------------------------------------------------------------------- logs in


@pytest.mark.parametrize("fmt", LOG_FORMATS)
def test_topics_and_kinds(logs: dict[tuple[str, str], Path], fmt: str) -> None:
    with open_log(logs[(fmt, "compressed")]) as log:
        topics = log.topics()
    assert {t: i.kind for t, i in topics.items()} == {
        "/camera/image": "camera",
        "/audio/raw": "audio",
        "/audio/raw/array": "array",
        "/ego/odom": "pose",
    }
    assert topics["/camera/image"].count == N_FRAMES
    assert topics["/audio/raw"].count == 30  # 3 s in 0.1 s blocks
    expected = "foxglove.CompressedImage" if fmt == "mcap-foxglove" else "sensor_msgs/msg/CompressedImage"
    assert topics["/camera/image"].schema == expected


@pytest.mark.parametrize("fmt", LOG_FORMATS)
@pytest.mark.parametrize("image", ["compressed", "raw"])
def test_camera_frames_are_the_video_frames(
    logs: dict[tuple[str, str], Path], video_frames: list[np.ndarray], fmt: str, image: str
) -> None:
    with open_log(logs[(fmt, image)]) as log:
        frames = list(log.frames("/camera/image"))
    assert [i for i, _, _ in frames] == list(range(N_FRAMES))
    # stamps: the video's frame times (25 fps) from the start
    np.testing.assert_array_equal(
        [s for _, s, _ in frames], [START_NS + k * 40_000_000 for k in range(N_FRAMES)]
    )
    for (_, _, got), want in zip(frames, video_frames, strict=True):
        assert got.shape == want.shape and got.dtype == np.uint8
        if image == "raw":
            np.testing.assert_array_equal(got, want)
        else:  # exactly the JPEG the writer made of the frame, and close to the frame
            jpeg = cv2.imdecode(
                cv2.imencode(".jpg", want, [cv2.IMWRITE_JPEG_QUALITY, 90])[1], cv2.IMREAD_COLOR
            )
            np.testing.assert_array_equal(got, jpeg)
            assert cv2.PSNR(got, want) > 30.0


def test_stride_and_max_frames(logs: dict[tuple[str, str], Path]) -> None:
    with open_log(logs[("ros2-bag", "compressed")]) as log:
        assert [i for i, _, _ in log.frames("/camera/image", stride=2, max_frames=2)] == [0, 2]


@pytest.mark.parametrize("fmt", LOG_FORMATS)
def test_audio_array_and_ego_path_round_trip(
    logs: dict[tuple[str, str], Path], rec_dir: Path, fmt: str
) -> None:
    rec = read_recording(rec_dir)
    got = read_log_recording(logs[(fmt, "compressed")])  # the only audio and pose topics
    assert got.sample_rate == rec.sample_rate and got.audio.shape == rec.audio.shape
    assert np.abs(got.audio - rec.audio).max() <= 1.0 / 32768  # pcm-s16 quantization
    np.testing.assert_allclose(got.mics, rec.mics)
    assert got.full_scale_db_spl == rec.full_scale_db_spl
    np.testing.assert_allclose(got.ego.t, rec.ego.t, atol=1e-9)
    np.testing.assert_allclose(got.ego.x, rec.ego.x, atol=1e-9)
    np.testing.assert_allclose(got.ego.y, rec.ego.y, atol=1e-9)
    np.testing.assert_allclose(np.unwrap(got.ego.yaw), np.unwrap(rec.ego.yaw), atol=1e-9)


def test_listening_to_a_log_hears_what_the_recording_holds(
    logs: dict[tuple[str, str], Path], rec_dir: Path
) -> None:
    want = list(listen(read_recording(rec_dir)))
    got = list(listen(read_log_recording(logs[("ros2-bag", "compressed")])))
    assert len(got) == len(want) > 0 and any(m["is_siren"] for m in want)
    assert [m["is_siren"] for m in got] == [m["is_siren"] for m in want]
    np.testing.assert_allclose([m["probability"] for m in got], [m["probability"] for m in want], atol=2e-3)
    for g, w in zip(got, want, strict=True):
        for gs, ws in zip(g["sources"], w["sources"], strict=True):
            assert abs(np.angle(np.exp(1j * (gs["bearing_rad"] - ws["bearing_rad"])))) < np.radians(2.0)


def _detect(args: list[str]) -> list[dict[str, Any]]:
    r = runner.invoke(app, ["detect", *args, "--rule", "crop", "--classifier", "fastest", "--no-video", "-q"])
    assert r.exit_code == 0, (r.output, r.exception)
    out = Path(args[args.index("-o") + 1])
    return [json.loads(line) for line in (out / "tracks.jsonl").read_text().splitlines()]


def test_detect_on_a_raw_camera_log_equals_detect_on_the_video(
    logs: dict[tuple[str, str], Path], clip: Path, tmp_path: Path
) -> None:
    on_video = _detect([str(clip), "-o", str(tmp_path / "v"), "--max-frames", str(N_FRAMES)])
    on_log = _detect([str(logs[("mcap-ros2", "raw")]), "--topic", "/camera/image", "-o", str(tmp_path / "l")])
    assert len(on_log) == N_FRAMES and on_log == on_video
    assert any(line["tracks"] for line in on_log)
    summary = json.loads((tmp_path / "l" / "summary.json").read_text())
    assert summary["topic"] == "/camera/image" and summary["frames"] == N_FRAMES and summary["fps"] == 25.0


# ---------------------------------------------------------------------------------------- logs out


def _read_mcap(path: Path) -> tuple[dict[str, tuple[str, str]], dict[str, list[tuple[int, bytes]]]]:
    """Topic → (schema name, schema encoding) and topic → [(log time, data)], read with mcap alone."""
    from mcap.reader import make_reader

    channels: dict[str, tuple[str, str]] = {}
    messages: dict[str, list[tuple[int, bytes]]] = {}
    with path.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            channels[channel.topic] = (schema.name, schema.encoding)
            messages.setdefault(channel.topic, []).append((message.log_time, message.data))
    return channels, messages


def _check_common(messages: dict[str, list[tuple[int, bytes]]]) -> None:
    for topic, msgs in messages.items():
        times = [t for t, _ in msgs]
        assert times == sorted(times), f"{topic}: timestamps not monotonic"


def test_detect_writes_a_foxglove_mcap(logs: dict[tuple[str, str], Path], tmp_path: Path) -> None:
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
    from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations

    out = tmp_path / "run.mcap"
    lines = _detect(
        [str(logs[("mcap-foxglove", "compressed")]), "-o", str(tmp_path / "d"), "--mcap", str(out)]
    )
    channels, messages = _read_mcap(out)
    assert channels == {
        "/camera/image": ("foxglove.CompressedImage", "protobuf"),
        "/camera/annotations": ("foxglove.ImageAnnotations", "protobuf"),
        "/perception/tracks": ("makeway.PerceptionFrame", "jsonschema"),
    }
    assert {t: len(m) for t, m in messages.items()} == dict.fromkeys(channels, N_FRAMES)
    _check_common(messages)
    # the log's own clock is kept
    assert [t for t, _ in messages["/camera/image"]] == [START_NS + k * 40_000_000 for k in range(N_FRAMES)]
    for k, line in enumerate(lines):
        img = CompressedImage.FromString(messages["/camera/image"][k][1])
        assert img.format == "jpeg" and cv2.imdecode(
            np.frombuffer(img.data, np.uint8), cv2.IMREAD_COLOR
        ).shape == (
            720,
            1280,
            3,
        )
        ann = ImageAnnotations.FromString(messages["/camera/annotations"][k][1])
        assert len(ann.points) == len(line["tracks"]) == len(ann.texts)
        for pa, track in zip(ann.points, line["tracks"], strict=True):
            assert len(pa.points) == 4 and pa.points[0].x == pytest.approx(track["box"]["x1"], abs=1e-3)
        assert json.loads(messages["/perception/tracks"][k][1]) == line


def test_listen_on_a_log_writes_a_foxglove_mcap(logs: dict[tuple[str, str], Path], tmp_path: Path) -> None:
    from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    out, jsonl = tmp_path / "listen.mcap", tmp_path / "listen.jsonl"
    r = runner.invoke(
        app,
        ["audio", "listen", str(logs[("mcap-ros2", "compressed")]), "--audio-topic", "/audio/raw",
         "--pose-topic", "/ego/odom", "--jsonl", str(jsonl), "--mcap", str(out)],
    )  # fmt: skip
    assert r.exit_code == 0, (r.output, r.exception)
    hops = [json.loads(line) for line in jsonl.read_text().splitlines()]
    channels, messages = _read_mcap(out)
    assert channels == {
        "/array/mics": ("foxglove.SceneUpdate", "protobuf"),
        "/tf": ("foxglove.FrameTransform", "protobuf"),
        "/siren/detection": ("makeway.SirenMessage", "jsonschema"),
        "/siren/sources": ("foxglove.SceneUpdate", "protobuf"),
    }
    _check_common(messages)
    assert len(messages["/siren/detection"]) == len(hops) == len(messages["/siren/sources"])
    assert len(SceneUpdate.FromString(messages["/array/mics"][0][1]).entities[0].spheres) == 8
    rec = read_log_recording(logs[("mcap-ros2", "compressed")])
    for (t_ns, data), (_, scene), hop in zip(
        messages["/siren/detection"], messages["/siren/sources"], hops, strict=True
    ):
        assert json.loads(data) == hop and t_ns == START_NS + round(hop["t_end"] * 1e9)
        arrows = SceneUpdate.FromString(scene).entities[0].arrows
        assert len(arrows) == len(hop["sources"])
        for arrow, src in zip(arrows, hop["sources"], strict=True):
            q = arrow.pose.orientation
            assert 2 * np.arctan2(q.z, q.w) == pytest.approx(src["bearing_rad"], abs=1e-6)
    tf = FrameTransform.FromString(messages["/tf"][-1][1])
    x, y = rec.ego.position(hops[-1]["t_end"])
    assert (tf.parent_frame_id, tf.child_frame_id) == ("world", "base_link")
    assert tf.translation.x == pytest.approx(float(x)) and tf.translation.y == pytest.approx(float(y))


def test_simulate_writes_a_foxglove_mcap(tmp_path: Path) -> None:
    from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    from makeway.apps.simulate import simulate

    out = tmp_path / "sim.mcap"
    result, scenario, files = simulate("seed003", mcap=out)
    assert files["mcap"] == str(out)
    channels, messages = _read_mcap(out)
    assert channels == {
        "/ego/trajectory": ("foxglove.PosesInFrame", "protobuf"),
        "/plan/path": ("foxglove.PosesInFrame", "protobuf"),
        "/tf": ("foxglove.FrameTransform", "protobuf"),
        "/scene": ("foxglove.SceneUpdate", "protobuf"),
        "/perception/belief": ("makeway.EVBelief", "jsonschema"),
        "/decide/yield": ("makeway.YieldState", "jsonschema"),
    }
    _check_common(messages)
    n = len(messages["/tf"])
    assert n == pytest.approx(scenario.duration_s * 20, abs=1)
    assert len(messages["/plan/path"]) == len(result.paths)
    states = [json.loads(d)["state"] for _, d in messages["/decide/yield"]]
    assert states[0] == "no_ev" and "moving_over" in states  # seed 003: the car pulls over
    beliefs = [json.loads(d) for _, d in messages["/perception/belief"]]
    assert any(b["detected"] for b in beliefs) and len(beliefs) == n
    scene = SceneUpdate.FromString(messages["/scene"][-1][1])
    assert {e.id for e in scene.entities} >= {"ego", "ev"}
    path = PosesInFrame.FromString(messages["/plan/path"][-1][1])
    np.testing.assert_allclose([p.position.x for p in path.poses], result.paths[-1][1])


# --------------------------------------------------------------------------------------- bad input


def _one_error_line(r: Any, *needles: str) -> str:
    assert r.exit_code == 2, (r.exit_code, r.output, r.exception)
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, r.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def test_truncated_mcap_is_one_line_and_leaves_nothing(
    logs: dict[tuple[str, str], Path], tmp_path: Path
) -> None:
    src = logs[("mcap-ros2", "compressed")]
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(src.read_bytes()[: src.stat().st_size // 2])
    with pytest.raises(InputError, match="truncated or damaged"):
        open_log(cut)
    r = runner.invoke(
        app, ["detect", str(cut), "-o", str(tmp_path / "out"), "--mcap", str(tmp_path / "o.mcap")]
    )
    _one_error_line(r, str(cut), "truncated or damaged")
    assert not (tmp_path / "out").exists() and not (tmp_path / "o.mcap").exists()
    r = runner.invoke(app, ["audio", "listen", str(cut)])
    _one_error_line(r, "truncated or damaged")


def test_damaged_bag_and_not_a_log(logs: dict[tuple[str, str], Path], tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    shutil.copytree(logs[("ros2-bag", "compressed")], bag)
    (db,) = bag.glob("*.db3")
    db.write_bytes(db.read_bytes()[:4096])
    r = runner.invoke(app, ["logs", "info", str(bag)])
    _one_error_line(r, str(bag), "ROS 2 bag")
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not a log at all")
    _one_error_line(runner.invoke(app, ["logs", "info", str(junk)]), "not an MCAP file")


def test_missing_topic_lists_the_topics(logs: dict[tuple[str, str], Path], clip: Path) -> None:
    log = logs[("ros2-bag", "raw")]
    line = _one_error_line(runner.invoke(app, ["detect", str(log), "--topic", "/front"]), "/front")
    assert "/camera/image (sensor_msgs/msg/Image)" in line
    _one_error_line(runner.invoke(app, ["detect", str(log), "--topic", "/audio/raw"]), "not a camera")
    _one_error_line(runner.invoke(app, ["audio", "listen", str(log), "--audio-topic", "/mic"]), "/audio/raw")
    _one_error_line(runner.invoke(app, ["detect", str(clip), "--topic", "/camera/image"]), "not an MCAP file")


def test_unsupported_encoding_and_missing_array(rec_dir: Path, tmp_path: Path) -> None:
    path = tmp_path / "depth.mcap"
    with Ros2LogWriter(path) as w:
        w.channel("/depth", "sensor_msgs/msg/Image")
        data = np.zeros(4 * 4 * 2, np.uint8)
        w.write(
            "/depth",
            1,
            w.msg("sensor_msgs/msg/Image", header=w.header(1), height=4, width=4, encoding="16UC1",
                  is_bigendian=0, step=8, data=data),
        )  # fmt: skip
    _one_error_line(runner.invoke(app, ["detect", str(path), "-o", str(tmp_path / "o")]), "16UC1")
    assert not (tmp_path / "o").exists()
    # an audio topic without its array description: the siren stack cannot localize
    rec: Recording = read_recording(rec_dir)
    noarr = tmp_path / "noarr.mcap"
    with Ros2LogWriter(noarr) as w:
        w.channel("/mic", "makeway_msgs/msg/RawAudio")
        pcm = np.round(rec.audio[:4800] * 32767).astype("<i2")
        w.write(
            "/mic",
            1,
            w.msg("makeway_msgs/msg/RawAudio", header=w.header(1), format="pcm-s16",
                  sample_rate=rec.sample_rate, number_of_channels=8, data=pcm.view(np.uint8).reshape(-1)),
        )  # fmt: skip
    _one_error_line(runner.invoke(app, ["audio", "listen", str(noarr)]), "no array description")


def test_failed_log_writing_leaves_nothing(rec_dir: Path, tmp_path: Path) -> None:
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"\x00" * 100)
    for fmt in LOG_FORMATS:
        out = tmp_path / f"x_{fmt}"
        with pytest.raises(InputError):
            make_test_log(out, video=bad, recording=rec_dir, fmt=fmt)
        assert list(tmp_path.glob("x_*")) == [] and list(tmp_path.glob(".x_*")) == []


@pytest.mark.parametrize("bag", [False, True])
def test_an_error_while_writing_leaves_no_log(tmp_path: Path, bag: bool) -> None:
    out = tmp_path / ("bag" if bag else "log.mcap")
    with pytest.raises(RuntimeError, match="midway"), Ros2LogWriter(out, bag=bag) as w:
        w.channel("/chatter", "std_msgs/msg/String")
        w.write("/chatter", 1, w.msg("std_msgs/msg/String", data="hello"))
        raise RuntimeError("midway")
    assert list(tmp_path.iterdir()) == []


def test_a_dropped_audio_block_becomes_silence(rec_dir: Path, tmp_path: Path) -> None:
    rec = read_recording(rec_dir)
    path = tmp_path / "dropout.mcap"
    block = 4800  # 0.1 s at 48 kHz
    pcm = np.round(rec.audio[: 10 * block] * 32767).astype("<i2")
    with Ros2LogWriter(path) as w:
        w.channel("/mic", "makeway_msgs/msg/RawAudio")
        for k in (0, 1, 2, 4, 5, 6, 7, 8, 9):  # block 3 was lost
            stamp = START_NS + k * 100_000_000
            w.write(
                "/mic",
                stamp,
                w.msg("makeway_msgs/msg/RawAudio", header=w.header(stamp), format="pcm-s16",
                      sample_rate=rec.sample_rate, number_of_channels=8,
                      data=pcm[k * block : (k + 1) * block].view(np.uint8).reshape(-1)),
            )  # fmt: skip
    with open_log(path) as log:
        audio = log.audio("/mic")
    assert audio.samples.shape == (10 * block, 8) and audio.start_ns == START_NS
    assert not audio.samples[3 * block : 4 * block].any()
    np.testing.assert_array_equal(audio.samples[4 * block :], pcm[4 * block :] / 32768.0)


def test_rsu_runs_on_a_camera_log_and_writes_its_alerts_to_mcap(video_dir: Path, tmp_path: Path) -> None:
    """The pole camera's clip while the ambulance, lights on, pulls up (as tests/test_rsu.py), as a
    ROS 2 MCAP log: the roadside unit reads it by topic and writes its alerts beside the camera."""
    from makeway.v2x.security import keygen

    calib = (
        Path(__file__).resolve().parents[1] / "src" / "makeway" / "data" / "intersection_cam_ambulance.yaml"
    )
    log = tmp_path / "pole.mcap"
    cap = cv2.VideoCapture(str(video_dir / "intersection_cam_ambulance.mp4"))
    cap.set(cv2.CAP_PROP_POS_FRAMES, 590)
    with Ros2LogWriter(log) as w:
        w.channel("/pole/image", "sensor_msgs/msg/CompressedImage")
        for k in range(40):
            ok, frame = cap.read()
            assert ok
            stamp = START_NS + k * 40_000_000
            jpeg = cv2.imencode(".jpg", frame)[1].reshape(-1)
            w.write("/pole/image", stamp, w.msg("sensor_msgs/msg/CompressedImage", header=w.header(stamp),
                                                format="jpeg", data=jpeg))  # fmt: skip
    cap.release()
    keygen(tmp_path / "k", "rsu")
    out, mcap = tmp_path / "out", tmp_path / "rsu.mcap"
    r = runner.invoke(
        app,
        ["rsu", "run", str(log), "--topic", "/pole/image", "--calib", str(calib), "--key",
         str(tmp_path / "k" / "rsu.key"), "--no-publish", "--out", str(out), "--mcap", str(mcap),
         "--classifier", "fastest"],
    )  # fmt: skip
    assert r.exit_code == 0, (r.output, r.exception)
    result = json.loads(r.stdout.strip().splitlines()[-1])
    assert result["frames"] == 40 and result["outputs"]["mcap"] == str(mcap)
    rows = [json.loads(line) for line in (out / "alerts.jsonl").read_text().splitlines()]
    channels, messages = _read_mcap(mcap)
    assert len(messages["/camera/image"]) == 40
    _check_common(messages)
    alerts = [json.loads(d) for _, d in messages.get("/v2x/alerts", [])]
    assert len(alerts) == len(rows) == result["alerts"] > 0
    for alert, row in zip(alerts, rows, strict=True):  # the MCAP's JSON keeps 6 significant digits
        assert alert.keys() == row.keys()
        assert alert == {k: pytest.approx(v, rel=1e-5) if isinstance(v, float) else v for k, v in row.items()}
    assert channels["/v2x/alerts"] == ("makeway.V2XAlert", "jsonschema")
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    assert channels["/roadside/evs"] == ("foxglove.SceneUpdate", "protobuf")
    assert len(messages["/roadside/evs"]) == len(rows)
    for (_, data), row in zip(messages["/roadside/evs"], rows, strict=True):
        (entity,) = SceneUpdate.FromString(data).entities
        assert entity.id == f"ev_{row['track_id']}" and entity.frame_id == "road"
        pos = entity.cubes[0].pose.position
        assert (pos.x, pos.y) == pytest.approx((row["x_m"], row["y_m"]))


def test_logs_commands_make_and_list_a_log(clip: Path, rec_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "made"
    r = runner.invoke(
        app,
        ["logs", "make-test", str(out), "--video", str(clip), "--recording", str(rec_dir), "--format",
         "ros2-bag-mcap", "--max-frames", "3", "--json"],
    )  # fmt: skip
    assert r.exit_code == 0, (r.output, r.exception)
    made = json.loads(r.stdout)
    assert made["topics"]["/camera/image"] == 3 and (out / "metadata.yaml").is_file()
    r = runner.invoke(app, ["logs", "info", str(out), "--json"])
    assert r.exit_code == 0, (r.output, r.exception)
    info = json.loads(r.stdout)
    assert info["kind"] == "ros2 bag"
    assert {t["topic"]: (t["messages"], t["kind"]) for t in info["topics"]} == {
        topic: (n, kind)
        for (topic, n), kind in zip(made["topics"].items(), ("camera", "array", "audio", "pose"), strict=True)
    }


def test_two_camera_topics_need_a_name(clip: Path, tmp_path: Path) -> None:
    path = tmp_path / "two.mcap"
    with Ros2LogWriter(path) as w:
        for topic in ("/front/image", "/rear/image"):
            w.channel(topic, "sensor_msgs/msg/CompressedImage")
            jpeg = cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))[1].reshape(-1)
            w.write(
                topic,
                1,
                w.msg("sensor_msgs/msg/CompressedImage", header=w.header(1), format="jpeg", data=jpeg),
            )
    line = _one_error_line(runner.invoke(app, ["detect", str(path)]), "2 camera topics")
    assert "/front/image" in line and "/rear/image" in line


def test_lights_on_a_raw_camera_log_equals_lights_on_the_video(
    logs: dict[tuple[str, str], Path], clip: Path, tmp_path: Path
) -> None:
    def run(source: Path, out: Path, *extra: str) -> list[str]:
        r = runner.invoke(
            app, ["lights", str(source), "-o", str(out), "--detector", "colour", "--no-video", "-q", *extra]
        )
        assert r.exit_code == 0, (r.output, r.exception)
        return (out / "lights.jsonl").read_text().splitlines()

    on_video = run(clip, tmp_path / "v", "--max-frames", str(N_FRAMES))
    on_log = run(logs[("ros2-bag", "raw")], tmp_path / "l", "--topic", "/camera/image")
    assert len(on_log) == N_FRAMES and on_log == on_video
    assert any(json.loads(line)["lights"] for line in on_log)  # the ambulance's blue lights are seen


# ------------------------------------------------------------ cameras: the direct path vs mcap's own


def _both_paths(log: Any, topic: str, **kw: Any) -> list[tuple[int, int, np.ndarray]]:
    """The frames of ``topic`` by the direct path, checked equal (index, stamp, every byte) to the
    frames the ``mcap`` reader and its decoders give (:meth:`LogReader.frames`)."""
    from makeway.sense.logs import LogReader

    if log.kind == "mcap":
        assert log.reads_directly(topic)
    else:
        assert log._parses_in_place(topic)
    fast = list(log.frames(topic, **kw))
    if log.kind == "mcap":
        assert log._camera_index(topic).decoded_generally == 0  # every message was parsed in place
    general = list(LogReader.frames(log, topic, **kw))
    assert [(i, s) for i, s, _ in fast] == [(i, s) for i, s, _ in general]
    for (_, _, a), (_, _, b) in zip(fast, general, strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype == np.uint8
        np.testing.assert_array_equal(a, b)
    assert log.stamps(topic) == LogReader.stamps(log, topic)
    assert log.stamps(topic, 2) == LogReader.stamps(log, topic, 2)
    return fast


@pytest.fixture(scope="module")
def crops(video_frames: list[np.ndarray]) -> list[np.ndarray]:
    """Small real images: 96×64 crops of the clip's frames (where the ambulance's lights are)."""
    return [np.ascontiguousarray(f[300:364, 600:696]) for f in video_frames]


# frame k is logged at START_NS + ORDER[k] * 40 ms: log times out of write order inside chunks
ORDER = [0, 2, 1, 3, 5, 4]
PAD = 5  # bytes of padding after each row of the padded topic


def _ros_raw(w: Ros2LogWriter, stamp: int, image: np.ndarray, encoding: str, pad: int = 0) -> Any:
    h, w_px = image.shape[:2]
    ch = 1 if image.ndim == 2 else image.shape[2]
    rows = np.full((h, w_px * ch + pad), 0xA5, np.uint8)  # the padding holds bytes, not zeros
    rows[:, : w_px * ch] = image.reshape(h, -1)
    return w.msg("sensor_msgs/msg/Image", header=w.header(stamp, "cam"), height=h, width=w_px,
                 encoding=encoding, is_bigendian=0, step=w_px * ch + pad, data=rows.reshape(-1))  # fmt: skip


@pytest.mark.parametrize("big_endian", [False, True])
@pytest.mark.parametrize("compression", ["zstd", "lz4", "none", "bag"])
def test_direct_path_equals_mcap_on_ros2_images(
    crops: list[np.ndarray], tmp_path: Path, compression: str, big_endian: bool
) -> None:
    """bgr8, rgb8, mono8, row padding and JPEG topics interleaved with another topic in small
    chunks, log times out of order, one topic without header stamps: the direct path gives what
    mcap_ros2 decodes (in a ROS 2 bag: what rosbags deserializes), every byte, in the same order."""
    bag = compression == "bag"
    path = tmp_path / ("bag" if bag else "ros2.mcap")
    with Ros2LogWriter(
        path, bag=bag, compression="zstd" if bag else compression, chunk_size=40_000, big_endian=big_endian
    ) as w:
        for topic, typename in [("/bgr", "sensor_msgs/msg/Image"), ("/rgb", "sensor_msgs/msg/Image"),
                                ("/mono", "sensor_msgs/msg/Image"), ("/padded", "sensor_msgs/msg/Image"),
                                ("/nostamp", "sensor_msgs/msg/Image"),
                                ("/jpeg", "sensor_msgs/msg/CompressedImage"),
                                ("/chatter", "std_msgs/msg/String")]:  # fmt: skip
            w.channel(topic, typename)
        for k, image in enumerate(crops):
            t = START_NS + ORDER[k] * 40_000_000
            w.write("/chatter", t, w.msg("std_msgs/msg/String", data=f"frame {k}"))
            w.write("/bgr", t, _ros_raw(w, t, image, "bgr8"))
            w.write("/rgb", t, _ros_raw(w, t, image[:, :, ::-1], "rgb8"))
            w.write("/mono", t, _ros_raw(w, t, cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), "mono8"))
            w.write("/padded", t, _ros_raw(w, t, image, "bgr8", pad=PAD))
            w.write("/nostamp", t, _ros_raw(w, 0, image, "bgr8"))
            jpeg = cv2.imencode(".jpg", image)[1].reshape(-1)
            w.write("/jpeg", t, w.msg("sensor_msgs/msg/CompressedImage", header=w.header(t), format="jpeg",
                                      data=jpeg))  # fmt: skip
    order = sorted(range(len(crops)), key=lambda k: ORDER[k])  # log-time order
    with open_log(path) as log:
        for topic in ("/bgr", "/rgb", "/padded", "/nostamp"):
            frames = _both_paths(log, topic)
            assert [s for _, s, _ in frames] == [START_NS + k * 40_000_000 for k in range(len(crops))]
            for (_, _, got), k in zip(frames, order, strict=True):
                np.testing.assert_array_equal(got, crops[k])
        for (_, _, got), k in zip(_both_paths(log, "/mono"), order, strict=True):
            gray = cv2.cvtColor(crops[k], cv2.COLOR_BGR2GRAY)
            np.testing.assert_array_equal(got, cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR))
        _both_paths(log, "/jpeg")
        _both_paths(log, "/padded", stride=2, max_frames=2)
        if bag:  # rosbags hands out read-only bytes; its own deserializer's frames are read-only too
            return
        # frames are writable arrays of their own: drawing on one changes no other frame
        first, second = (f for _, _, f in log.frames("/bgr", max_frames=2))
        first[:] = 0
        np.testing.assert_array_equal(second, crops[order[1]])


def test_direct_path_equals_mcap_on_foxglove_images(crops: list[np.ndarray], tmp_path: Path) -> None:
    from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

    from makeway.sense.log_writer import FoxgloveMcapWriter

    path = tmp_path / "foxglove.mcap"
    with FoxgloveMcapWriter(path, chunk_size=40_000) as w:
        for k, image in enumerate(crops):
            t = START_NS + ORDER[k] * 40_000_000
            gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
            padded = np.full((64, 96 * 3 + PAD), 0x5A, np.uint8)
            padded[:, : 96 * 3] = image.reshape(64, -1)
            raws = [
                ("/bgr", "bgr8", image, 96 * 3),
                ("/rgb", "rgb8", image[:, :, ::-1].copy(), 96 * 3),
                ("/mono", "mono8", gray, 96),
                ("/padded", "bgr8", padded, 96 * 3 + PAD),
            ]
            for topic, enc, data, step in raws:
                msg = RawImage(
                    frame_id="cam", width=96, height=64, encoding=enc, step=step, data=data.tobytes()
                )
                if topic != "/mono":  # /mono carries no timestamp: its frames take the log time
                    msg.timestamp.FromNanoseconds(t + 7)
                w.write(topic, t, msg)
            jpeg = CompressedImage(
                frame_id="cam", format="jpeg", data=cv2.imencode(".jpg", image)[1].tobytes()
            )
            jpeg.timestamp.FromNanoseconds(t)
            w.write("/jpeg", t, jpeg)
    order = sorted(range(len(crops)), key=lambda k: ORDER[k])
    with open_log(path) as log:
        for topic in ("/bgr", "/rgb", "/padded"):
            frames = _both_paths(log, topic)
            assert [s for _, s, _ in frames] == [START_NS + k * 40_000_000 + 7 for k in range(len(crops))]
            for (_, _, got), k in zip(frames, order, strict=True):
                np.testing.assert_array_equal(got, crops[k])
        mono = _both_paths(log, "/mono")
        assert [s for _, s, _ in mono] == [START_NS + k * 40_000_000 for k in range(len(crops))]
        _both_paths(log, "/jpeg")


@pytest.mark.parametrize("fmt", ["mcap-ros2", "mcap-foxglove"])
@pytest.mark.parametrize("image", ["compressed", "raw"])
def test_direct_path_equals_mcap_on_the_test_logs(
    logs: dict[tuple[str, str], Path], fmt: str, image: str
) -> None:
    with open_log(logs[(fmt, image)]) as log:
        assert len(_both_paths(log, "/camera/image")) == N_FRAMES


def test_an_unindexed_mcap_is_read_by_mcap_itself(crops: list[np.ndarray], tmp_path: Path) -> None:
    """A file written without chunks has no chunk index: the ``mcap`` reader reads it."""
    from mcap.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    path = tmp_path / "plain.mcap"
    with path.open("wb") as f:
        writer = Writer(f, use_chunking=False)
        writer.start(profile="ros2", library="test")
        text, _ = store.generate_msgdef("sensor_msgs/msg/Image", ros_version=2)
        sid = writer.register_schema("sensor_msgs/msg/Image", "ros2msg", text.encode())
        cid = writer.register_channel("/bgr", "cdr", sid)
        for k, image in enumerate(crops):
            t = START_NS + k * 40_000_000
            sec, nsec = divmod(t, 1_000_000_000)
            header = store.types["std_msgs/msg/Header"](
                stamp=store.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id="cam"
            )
            msg = store.types["sensor_msgs/msg/Image"](
                header=header, height=64, width=96, encoding="bgr8", is_bigendian=0, step=288,
                data=image.reshape(-1),
            )  # fmt: skip
            writer.add_message(cid, t, bytes(store.serialize_cdr(msg, "sensor_msgs/msg/Image")), t)
        writer.finish()
    with open_log(path) as log:
        assert not log.reads_directly("/bgr")
        frames = list(log.frames("/bgr"))
    for (_, _, got), want in zip(frames, crops, strict=True):
        np.testing.assert_array_equal(got, want)


def _rewrite(src: Path, dst: Path, flag: int | None = None, **writer_options: Any) -> None:
    """Copy the MCAP ``src`` to ``dst`` with the ``mcap`` writer's ``writer_options``, each message's
    encapsulation kind byte set to ``flag`` (``None``: as it is)."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with src.open("rb") as f, dst.open("wb") as out:
        writer = Writer(out, **writer_options)
        writer.start(profile="ros2", library="test")
        ids: dict[int, int] = {}
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.id not in ids:
                sid = writer.register_schema(schema.name, schema.encoding, schema.data)
                ids[channel.id] = writer.register_channel(channel.topic, channel.message_encoding, sid)
            data = bytearray(message.data)
            if flag is not None:
                data[1] = flag
            writer.add_message(ids[channel.id], message.log_time, bytes(data), message.publish_time)
        writer.finish()


def test_a_message_the_direct_path_does_not_parse_goes_to_mcap_ros2(
    crops: list[np.ndarray], tmp_path: Path
) -> None:
    """Messages flagged as a CDR parameter list (encapsulation kind 3), which mcap_ros2 reads as
    plain little-endian CDR and the in-place parser leaves alone, come out as mcap_ros2 decodes them;
    a file without statistics in its summary is still read directly."""
    src = tmp_path / "src.mcap"
    with Ros2LogWriter(src) as w:
        w.channel("/bgr", "sensor_msgs/msg/Image")
        for k, image in enumerate(crops):
            t = START_NS + k * 40_000_000
            w.write("/bgr", t, _ros_raw(w, t, image, "bgr8"))
    nostats = tmp_path / "nostats.mcap"
    _rewrite(src, nostats, use_statistics=False)
    with open_log(nostats) as log:
        assert log.topics()["/bgr"].count == len(crops)
        _both_paths(log, "/bgr")
    path = tmp_path / "pl.mcap"
    _rewrite(src, path, flag=3)
    with open_log(path) as log:
        frames = list(log.frames("/bgr"))
        assert log.reads_directly("/bgr") and log._camera_index("/bgr").decoded_generally == len(crops)
        assert log.stamps("/bgr") == [START_NS + k * 40_000_000 for k in range(len(crops))]
    for (_, _, got), want in zip(frames, crops, strict=True):
        np.testing.assert_array_equal(got, want)


def _chunk_offsets(path: Path) -> list[tuple[int, int]]:
    from mcap.reader import make_reader

    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return [(c.chunk_start_offset, c.chunk_length) for c in summary.chunk_indexes]


def test_a_damaged_chunk_is_one_line(logs: dict[tuple[str, str], Path], tmp_path: Path) -> None:
    """Zeros over the middle of the third frame's zstd chunk (the summary intact, so the log opens):
    reading the frames stops at it with one line naming the log; nothing is written."""
    src = logs[("mcap-ros2", "raw")]
    data = bytearray(src.read_bytes())
    start, length = _chunk_offsets(src)[2]
    mid = start + length // 2
    data[mid : mid + 65536] = bytes(65536)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    with open_log(bad) as log:
        assert log.reads_directly("/camera/image")
        with pytest.raises(InputError, match="truncated or damaged") as err:
            list(log.frames("/camera/image"))
    assert "\n" not in str(err.value) and str(bad) in str(err.value)
    r = runner.invoke(app, ["detect", str(bad), "-o", str(tmp_path / "out"), "--no-video", "-q"])
    _one_error_line(r, str(bad), "truncated or damaged")
    assert not (tmp_path / "out").exists()
    # a chunk whose records do not match the message index (the index points into the pixels)
    data = bytearray(src.read_bytes())
    start, _ = _chunk_offsets(src)[0]
    data[start] = 0x07  # not a chunk opcode
    bad.write_bytes(bytes(data))
    with open_log(bad) as log, pytest.raises(InputError, match="not a chunk record"):
        list(log.frames("/camera/image"))


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_corrupted_logs_read_or_fail_in_one_line(
    crops: list[np.ndarray], tmp_path: Path, compression: str
) -> None:
    """Flipped bits, overwritten bytes and cuts anywhere in a small camera log: reading it gives
    frames or one InputError line, never another exception."""
    from makeway.sense.logs import LogFrameReader

    path = tmp_path / "small.mcap"
    with Ros2LogWriter(path, compression=compression, chunk_size=20_000) as w:
        w.channel("/cam", "sensor_msgs/msg/Image")
        w.channel("/chatter", "std_msgs/msg/String")
        for k, image in enumerate(crops):
            t = START_NS + k * 40_000_000
            w.write("/chatter", t, w.msg("std_msgs/msg/String", data="x" * k))
            w.write("/cam", t, _ros_raw(w, t, image[:32, :48], "bgr8"))
    data = path.read_bytes()
    rng = np.random.default_rng(28)
    bad = tmp_path / "bad.mcap"
    failed = 0
    for trial in range(45):
        d = bytearray(data)
        if trial % 3 == 0:
            i = int(rng.integers(0, len(d)))
            d[i] ^= 1 << int(rng.integers(0, 8))
        elif trial % 3 == 1:
            i = int(rng.integers(0, len(d) - 8))
            d[i : i + 8] = rng.integers(0, 256, 8, dtype=np.uint8).tobytes()
        else:
            d = d[: int(rng.integers(0, len(d)))]
        bad.write_bytes(bytes(d))
        try:
            with LogFrameReader(bad) as reader:
                for _ in reader:
                    pass
        except InputError as err:
            assert "\n" not in str(err) and str(bad) in str(err)
            failed += 1
    assert 0 < failed < 45


def test_chunks_that_overlap_in_time_come_out_in_log_time_order(
    crops: list[np.ndarray], tmp_path: Path
) -> None:
    """Two frames a chunk, logged 0 3 | 1 4 | 2 5: every chunk overlaps the others in time; the
    frames come out in log-time order, as the mcap reader merges them."""
    path = tmp_path / "overlap.mcap"
    logged = [0, 3, 1, 4, 2, 5]
    with Ros2LogWriter(path, chunk_size=30_000) as w:
        w.channel("/bgr", "sensor_msgs/msg/Image")
        for k, image in enumerate(crops):
            t = START_NS + logged[k] * 40_000_000
            w.write("/bgr", t, _ros_raw(w, t, image, "bgr8"))
    assert len(_chunk_offsets(path)) == 3
    with open_log(path) as log:
        frames = _both_paths(log, "/bgr")
        _both_paths(log, "/bgr", stride=2)
    for (_, _, got), k in zip(frames, np.argsort(logged), strict=True):
        np.testing.assert_array_equal(got, crops[k])


# ------------------------------------------------------------------- H.264 video camera topics


@pytest.fixture(scope="module")
def video_log(clip: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """30 frames of the clip as foxglove.CompressedVideo (H.264, a keyframe every 25 frames)."""
    out = tmp_path_factory.mktemp("video") / "video.mcap"
    written = make_test_log(
        out, video=clip, fmt="mcap-foxglove", image="video", max_frames=30, start_ns=START_NS
    )
    assert written["topics"] == {"/camera/image": 30}
    return out


def test_video_topic_decodes_to_the_clip_frames(video_log: Path, clip: Path) -> None:
    with VideoReader(clip, max_frames=30) as reader:
        want = [f.copy() for _, _, f in reader]
    with open_log(video_log) as log:
        assert log.topics()["/camera/image"].schema == "foxglove.CompressedVideo"
        assert log.topics()["/camera/image"].kind == "camera"
        frames = list(log.frames("/camera/image"))
        strided = list(log.frames("/camera/image", stride=4, max_frames=5))
    assert [i for i, _, _ in frames] == list(range(30))
    assert [s for _, s, _ in frames] == [START_NS + k * 40_000_000 for k in range(30)]
    for (_, _, got), frame in zip(frames, want, strict=True):
        assert got.shape == frame.shape and got.dtype == np.uint8
        assert cv2.PSNR(got, frame) > 30.0  # lossy at the mp4's own bit rate, but the same picture
    # a strided read decodes every frame and hands out the same images as the full read
    assert [i for i, _, _ in strided] == [0, 4, 8, 12, 16]
    for i, _, got in strided:
        np.testing.assert_array_equal(got, frames[i][2])


def test_video_log_drives_detect_like_the_clip(video_log: Path, tmp_path: Path) -> None:
    r = runner.invoke(app, ["detect", str(video_log), "-o", str(tmp_path / "out"), "--json", "--no-video"])
    assert r.exit_code == 0, (r.output, r.exception)
    summary = json.loads(r.stdout.strip().splitlines()[-1])
    assert summary["frames"] == 30


def test_video_topic_faults_are_one_line(clip: Path, tmp_path: Path) -> None:
    from foxglove_schemas_protobuf.CompressedVideo_pb2 import CompressedVideo

    from makeway.sense.log_writer import FoxgloveMcapWriter, H264MessageEncoder

    with VideoReader(clip, max_frames=8) as reader:
        images = [f.copy() for _, _, f in reader]
    enc = H264MessageEncoder(images[0].shape[1], images[0].shape[0], 25.0, keyframe_s=100.0)
    units = [u for im in images for u in enc.encode(im)] + enc.flush()
    assert len(units) == len(images)

    def write(path: Path, payloads: list[tuple[str, bytes]]) -> Path:
        with FoxgloveMcapWriter(path) as w:
            for k, (fmt, data) in enumerate(payloads):
                msg = CompressedVideo(frame_id="cam", format=fmt, data=data)
                msg.timestamp.FromNanoseconds(START_NS + k * 40_000_000)
                w.write("/cam", START_NS + k * 40_000_000, msg)
        return path

    # a recording that starts inside a group of pictures: the frames before a keyframe are skipped
    # and, with no keyframe at all, nothing decodes: one line
    no_key = write(tmp_path / "nokey.mcap", [("h264", d) for _, d in units[1:]])
    _one_error_line(runner.invoke(app, ["detect", str(no_key), "-o", str(tmp_path / "o1")]), "no keyframe")
    # an unknown codec name: one line naming it
    vp = write(tmp_path / "vp9.mcap", [("vp9", d) for _, d in units])
    _one_error_line(runner.invoke(app, ["detect", str(vp), "-o", str(tmp_path / "o2")]), "vp9", "h264")
    # the keyframe intact, a later frame replaced by garbage: damaged, on its message
    bad = [("h264", d) for _, d in units]
    bad[3] = ("h264", b"\x00\x00\x00\x01" + bytes(range(7, 250)))
    with open_log(write(tmp_path / "bad.mcap", bad)) as log, pytest.raises(InputError, match="message 3"):
        list(log.frames("/cam"))
    for name in ("o1", "o2"):
        assert not (tmp_path / name).exists()


def test_video_is_foxglove_only(clip: Path, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="mcap-foxglove"):
        make_test_log(tmp_path / "x.mcap", video=clip, fmt="mcap-ros2", image="video")
    assert not (tmp_path / "x.mcap").exists()
