"""Video reading (makeway.sense.video), H.264 writing and frame annotation (makeway.viz) on real clips."""

from __future__ import annotations

import math
from pathlib import Path

import av
import cv2
import numpy as np
import pytest

from makeway.errors import InputError
from makeway.messages import Box, EVState, EVTrackState, PerceptionFrame, Track
from makeway.sense import video as video_mod
from makeway.sense.video import DEFAULT_FPS, VideoInfo, VideoReader, probe_video
from makeway.viz import PALETTE, STATE_COLOURS, H264Writer, draw_frame, partial_path_for, track_colour

# name: (width, height, fps)
CLIPS: dict[str, tuple[int, int, float]] = {
    "night_ambulance_lights.mp4": (1280, 720, 25.0),
    "fire_trucks_red_lights.mp4": (640, 352, 30.0),
    "intersection_cam_ambulance.mp4": (1280, 720, 30000 / 1001),
    "traffic_no_ev.mp4": (640, 360, 30.0),
    "highway_cam_no_ev.mp4": (320, 240, 25.0),
}


@pytest.fixture(scope="module")
def night(video_dir: Path) -> Path:
    return video_dir / "night_ambulance_lights.mp4"


@pytest.fixture(scope="module")
def night_frames(night: Path) -> list[np.ndarray]:
    with VideoReader(night, max_frames=30) as reader:
        return [frame.copy() for _, _, frame in reader]


# ---------------------------------------------------------------------------------------------- read


@pytest.mark.parametrize("name", sorted(CLIPS))
def test_probe_every_clip(video_dir: Path, name: str) -> None:
    width, height, fps = CLIPS[name]
    info = probe_video(video_dir / name)
    assert isinstance(info, VideoInfo)
    assert info.path == video_dir / name
    assert (info.width, info.height) == (width, height)
    assert info.fps == pytest.approx(fps, rel=1e-3)
    assert not info.fps_assumed
    assert 100 < info.frame_count < 2000
    assert info.duration_s == pytest.approx(info.frame_count / info.fps)
    assert 5.0 < info.duration_s < 60.0


def test_night_clip_metadata(night: Path) -> None:
    info = probe_video(night)
    assert info.duration_s == pytest.approx(11.5, abs=0.2)


def test_stride_and_max_frames(night: Path) -> None:
    with VideoReader(night) as reader:
        every = _take(reader, 28)
    with VideoReader(night, stride=3, max_frames=10) as reader:
        got = list(reader)
        assert reader.frames_yielded == 10
        assert reader.frames_read == 28  # 0 … 27: the last yielded frame is index 27
    assert [i for i, _, _ in got] == list(range(0, 30, 3))
    for i, t, frame in got:
        assert t == pytest.approx(i / 25.0)
        assert frame.dtype == np.uint8 and frame.shape == (720, 1280, 3)
        assert np.array_equal(frame, every[i][2]), f"strided frame {i} differs from the plain read"


def test_one_decoder_thread_gives_the_same_frames(night: Path) -> None:
    """A data-engine worker decodes on one thread; the frames must not change."""
    with VideoReader(night, stride=2, max_frames=8) as reader:
        plain = [f.copy() for _, _, f in reader]
    with VideoReader(night, stride=2, max_frames=8, threads=1) as reader:
        one = [f.copy() for _, _, f in reader]
        again = [f.copy() for _, _, f in reader]  # a second pass reopens with the same setting
    assert len(plain) == len(one) == len(again) == 8
    for a, b, c in zip(plain, one, again, strict=True):
        assert np.array_equal(a, b) and np.array_equal(a, c)


def _take(reader: VideoReader, n: int) -> list[tuple[int, float, np.ndarray]]:
    out = []
    for i, t, f in reader:
        out.append((i, t, f.copy()))
        if len(out) == n:
            break
    return out


def test_whole_clip_and_second_pass(video_dir: Path) -> None:
    path = video_dir / "highway_cam_no_ev.mp4"
    with VideoReader(path, stride=4) as reader:
        first = [i for i, _, _ in reader]
        read_first = reader.frames_read
        second = [i for i, _, _ in reader]
        info = reader.info
    assert first == second
    assert first == list(range(0, 4 * len(first), 4))
    # The container's count is an estimate; the decoded count must be close to it.
    assert abs(read_first - info.frame_count) <= 0.05 * info.frame_count
    assert first[-1] / info.fps == pytest.approx(info.duration_s, abs=0.5)


def test_bad_arguments(night: Path) -> None:
    for kwargs in ({"stride": 0}, {"stride": -2}, {"max_frames": 0}, {"max_frames": -1}, {"threads": 0}):
        with pytest.raises(ValueError):
            VideoReader(night, **kwargs)  # type: ignore[arg-type]


def _assert_input_error(path: Path, *words: str) -> None:
    with pytest.raises(InputError) as info:
        VideoReader(path)
    err = info.value
    message = str(err)
    assert err.path == path
    assert path.name in message
    assert any(w in message for w in words), message


def test_missing_file_and_folder(tmp_path: Path) -> None:
    _assert_input_error(tmp_path / "nope.mp4", "no such file")
    folder = tmp_path / "clip.mp4"
    folder.mkdir()
    _assert_input_error(folder, "folder")


def test_not_a_video(tmp_path: Path) -> None:
    junk = tmp_path / "random_bytes.mp4"
    junk.write_bytes(np.random.default_rng(0).integers(0, 256, 50_000, dtype=np.uint8).tobytes())
    _assert_input_error(junk, "cannot be opened", "no frame decodes")
    text = tmp_path / "notes.mp4"
    text.write_text("this is a text file, not a video\n" * 100)
    _assert_input_error(text, "cannot be opened", "no frame decodes")
    empty = tmp_path / "empty.mp4"
    empty.write_bytes(b"")
    _assert_input_error(empty, "cannot be opened", "no frame decodes")
    with pytest.raises(InputError):
        probe_video(junk)


@pytest.mark.parametrize(
    "name",
    [
        "night_ambulance_lights.mp4",  # index (moov) first: opens, but no frame decodes
        "fire_trucks_red_lights.mp4",  # index last: does not open at all
    ],
)
def test_truncated_mp4(video_dir: Path, tmp_path: Path, name: str) -> None:
    cut = tmp_path / f"cut_{name}"
    cut.write_bytes((video_dir / name).read_bytes()[:20_000])
    _assert_input_error(cut, "cannot be opened", "no frame decodes")


def test_truncated_mid_stream_stops_quietly(video_dir: Path, tmp_path: Path) -> None:
    src = video_dir / "highway_cam_no_ev.mp4"  # index first, small frames
    cut = tmp_path / "half.mp4"
    data = src.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    with VideoReader(cut) as reader:
        n = sum(1 for _ in reader)
        assert n == reader.frames_read == reader.frames_yielded
        assert 10 < n < reader.info.frame_count


class _NoFpsCapture:
    """A real capture whose frame rate reads as ``fps`` (to test the fallback)."""

    def __init__(self, path: Path, fps: float) -> None:
        self._cap = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
        self._fps = fps

    def get(self, prop: int) -> float:
        return self._fps if prop == cv2.CAP_PROP_FPS else float(self._cap.get(prop))

    def __getattr__(self, name: str) -> object:
        return getattr(self._cap, name)


@pytest.mark.parametrize("bad_fps", [0.0, math.nan, -1.0])
def test_missing_fps_falls_back(video_dir: Path, monkeypatch: pytest.MonkeyPatch, bad_fps: float) -> None:
    monkeypatch.setattr(video_mod, "_open_capture", lambda p, threads=None: _NoFpsCapture(p, bad_fps))
    with VideoReader(video_dir / "traffic_no_ev.mp4", stride=5, max_frames=3) as reader:
        assert reader.info.fps == DEFAULT_FPS
        assert reader.info.fps_assumed
        assert [(i, t) for i, t, _ in reader] == [(0, 0.0), (5, 0.2), (10, 0.4)]


# --------------------------------------------------------------------------------------------- write


def _tracks_for(index: int) -> PerceptionFrame:
    tracks = (
        Track(3, Box(420.0 + index, 250.0, 760.0 + index, 560.0), 0.91, 7, "truck"),
        Track(7, Box(860.0, 330.0, 1180.0, 470.0), 0.74, 2, "car"),
        Track(12, Box(100.0, 420.0, 400.0, 600.0), 0.66, 2, "car"),
    )
    states = (
        EVTrackState(3, EVState.ACTIVE, 0.8, 10, 0.7),
        EVTrackState(7, EVState.INACTIVE, 0.1, 12, 0.1),
    )
    return PerceptionFrame(index, index / 25.0, tracks, states)


def test_writer_round_trip(night_frames: list[np.ndarray], tmp_path: Path) -> None:
    out = tmp_path / "sub" / "annotated.mp4"
    written = [draw_frame(f, _tracks_for(i), fps_text="50.0 fps") for i, f in enumerate(night_frames)]
    with H264Writer(out, 25.0, 1280, 720) as writer:
        assert partial_path_for(out).exists() and not out.exists()
        for frame in written:
            writer.write(frame)
    assert out.is_file() and not partial_path_for(out).exists()
    assert writer.frames_written == 30

    with av.open(str(out)) as container:
        stream = container.streams.video[0]
        assert stream.codec_context.name == "h264"
        assert stream.average_rate == 25
        decoded = [fr.to_ndarray(format="bgr24") for fr in container.decode(stream)]
    assert len(decoded) == 30
    assert decoded[0].shape == (720, 1280, 3)
    diffs = [np.abs(a.astype(np.int16) - b).mean() for a, b in zip(decoded, written, strict=True)]
    assert max(diffs) < 4.0, diffs


def test_writer_odd_size_and_ntsc_rate(video_dir: Path, tmp_path: Path) -> None:
    with VideoReader(video_dir / "highway_cam_no_ev.mp4", max_frames=10) as reader:
        frames = [f[:239, :319].copy() for _, _, f in reader]
    out = tmp_path / "odd.mp4"
    with H264Writer(out, 30000 / 1001, 319, 239, crf=18) as writer:
        for frame in frames:
            writer.write(frame)
    with av.open(str(out)) as container:
        stream = container.streams.video[0]
        assert stream.average_rate == pytest.approx(30000 / 1001)
        decoded = [fr.to_ndarray(format="bgr24") for fr in container.decode(stream)]
    assert len(decoded) == 10 and decoded[0].shape == (240, 320, 3)
    diff = np.mean(
        [np.abs(a[:239, :319].astype(np.int16) - b).mean() for a, b in zip(decoded, frames, strict=True)]
    )
    assert diff < 3.0


def test_writer_exception_leaves_nothing(night_frames: list[np.ndarray], tmp_path: Path) -> None:
    out = tmp_path / "crash.mp4"
    with pytest.raises(RuntimeError, match="boom"), H264Writer(out, 25.0, 1280, 720) as writer:
        for frame in night_frames[:5]:
            writer.write(frame)
        assert partial_path_for(out).exists()
        raise RuntimeError("boom")
    assert not out.exists()
    assert not partial_path_for(out).exists()
    assert list(tmp_path.iterdir()) == []

    # An older file at the target survives a failed rewrite.
    old = tmp_path / "old.mp4"
    old.write_bytes(b"x")
    with pytest.raises(ValueError), H264Writer(old, 25.0, 1280, 720) as writer:
        writer.write(night_frames[0][:, :640])  # wrong size
    assert old.read_bytes() == b"x"
    assert not partial_path_for(old).exists()


def test_writer_rejects_bad_settings(tmp_path: Path) -> None:
    with pytest.raises(ValueError):
        H264Writer(tmp_path / "a.mp4", 0.0, 64, 64)
    with pytest.raises(av.error.FFmpegError):
        H264Writer(tmp_path / "b.mp4", 25.0, 64, 64, preset="no-such-preset")
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------------ annotate


def test_annotate_colours_and_extent(night_frames: list[np.ndarray]) -> None:
    src = night_frames[10]
    before = src.copy()
    pf = _tracks_for(0)
    out = draw_frame(src, pf, fps_text="50.0 fps", extra_lines=["extra line"])
    assert np.array_equal(src, before), "copy=True must leave the input untouched"
    assert out.shape == src.shape and out.dtype == np.uint8

    # The ACTIVE box (track 3: x 420–760, y 250–560): its outline is bright red.
    red = np.array(STATE_COLOURS[EVState.ACTIVE])
    for x, y in ((420, 400), (760, 400), (600, 560), (590, 252)):
        assert np.array_equal(out[y, x], red), (x, y, out[y, x])
    # The INACTIVE box (track 7: x 860–1180, y 330–470) is green on its outline.
    assert np.array_equal(out[400, 860], np.array(STATE_COLOURS[EVState.INACTIVE]))
    # Track 12 has no EV state: its per-id colour.
    assert np.array_equal(out[520, 100], np.array(track_colour(12)))

    # Changes only near boxes (outline, label bar above) and inside the top-left panel.
    changed = np.any(out != src, axis=2)
    allowed = np.zeros_like(changed)
    allowed[:160, :460] = True  # panel
    for t in pf.tracks:
        b = t.box
        allowed[int(b.y1) - 40 : int(b.y2) + 10, int(b.x1) - 10 : int(b.x2) + 10] = True
    assert not np.any(changed & ~allowed)
    assert changed[8:60, 8:150].mean() > 0.5  # the panel is darkened
    # The middle of a box is untouched (outline only, no fill).
    assert not changed[380:440, 560:620].any()


def test_annotate_in_place_and_helpers(night_frames: list[np.ndarray]) -> None:
    img = night_frames[0].copy()
    out = draw_frame(img, PerceptionFrame(0, 0.0, ()), copy=False)
    assert out is img
    assert track_colour(5) == track_colour(5) and track_colour(5) in PALETTE
    assert track_colour(1) != track_colour(2)
    assert all(c not in PALETTE for c in STATE_COLOURS.values())
    with pytest.raises(ValueError):
        draw_frame(img[:, :, 0], PerceptionFrame(0, 0.0, ()))
    # Boxes off the image or with NaN corners are skipped, not crashed on.
    odd = PerceptionFrame(
        1,
        0.04,
        (
            Track(1, Box(-50, -50, 5000, 5000)),
            Track(2, Box(math.nan, 0, 10, 10)),
            Track(3, Box(2000, 0, 2100, 5)),
        ),
    )
    draw_frame(img, odd)
