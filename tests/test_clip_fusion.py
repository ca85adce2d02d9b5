"""Lights and siren on one clip, fused per second (issue 26 item 6): the combination rule on
hand-made streams, the sound-track reader on made and real clips, a real clip through the library
function, and ``makeway detect`` with and without sound."""

from __future__ import annotations

import json
from pathlib import Path

import av
import numpy as np
import pytest
from typer.testing import CliRunner

from makeway.cli.main import app
from makeway.decide.clip_seconds import decide_seconds, whole_seconds
from makeway.decide.duty import DUTY_PRESETS
from makeway.errors import InputError
from makeway.eval.clip_seconds import read_clip_seconds, score_seconds
from makeway.fuse.clip_seconds import FrameLights, SirenTimeline, fuse_clip
from makeway.pipeline.clip_sound import run_clip
from makeway.sense.clip_audio import has_audio, read_clip_audio

runner = CliRunner()
FPS = 10.0


def _frames(lit: list[bool], fps: float = FPS) -> list[FrameLights]:
    return [FrameLights(i / fps, 0.8 if x else 0.0) for i, x in enumerate(lit)]


def _siren(probs: list[float], hop: float = 0.25, threshold: float = 0.8) -> SirenTimeline:
    return SirenTimeline(np.arange(1, len(probs) + 1) * hop, np.array(probs), threshold)


def _decide(
    lit: list[bool], siren: SirenTimeline | None, n: int, duty: str = "audible_and_visual"
) -> list[str]:
    frames = _frames(lit)
    return [
        s.decision for s in decide_seconds(fuse_clip(frames, siren), frames, siren, n, DUTY_PRESETS[duty])
    ]


# ------------------------------------------------------------------------------ the combination rule
def test_siren_and_lights_yield_siren_alone_prepares() -> None:
    # 4 s: lights in seconds 0-1 only (held for 1 s after the last, to 2.9 s), a siren throughout
    lit = [True] * 20 + [False] * 20
    siren = _siren([0.95] * 16)
    assert _decide(lit, siren, 4) == ["yield", "yield", "yield", "prepare"]
    # the same under the UK preset: a siren alone is a yield
    assert _decide(lit, siren, 4, "uk") == ["yield"] * 4


def test_lights_alone_need_two_unbroken_seconds() -> None:
    lit = [True] * 40
    assert _decide(lit, None, 4) == ["none", "none", "yield", "yield"]
    # a gap shorter than the 1 s hold does not break the run
    short_gap = [True] * 15 + [False] * 5 + [True] * 20
    assert _decide(short_gap, None, 4) == ["none", "none", "yield", "yield"]
    # lights 0-0.9 s (held to 1.9 s), none until 2.5 s: the count restarts and reaches 2 s at 4.5 s
    long_gap = [True] * 10 + [False] * 15 + [True] * 35
    assert _decide(long_gap, None, 6) == ["none", "none", "none", "none", "yield", "yield"]
    # Germany: lights alone only prepare
    assert _decide(lit, None, 4, "germany") == ["none", "none", "prepare", "prepare"]


def test_nothing_or_a_quiet_siren_is_none() -> None:
    siren = _siren([0.5, 0.79, 0.2, 0.0] * 3)  # below the 0.8 threshold everywhere
    decided = decide_seconds(fuse_clip(_frames([False] * 30), siren), _frames([False] * 30), siren, 3)
    assert [s.decision for s in decided] == ["none"] * 3
    # the per-second probability is the highest decided in the second; no siren heard
    assert [s.siren_probability for s in decided] == [0.79, 0.79, 0.79]
    assert all(s.siren is False and not s.lights and s.frames == 10 for s in decided)


def test_streams_merge_in_time_and_lights_are_held_briefly() -> None:
    frames = [FrameLights(0.0, 0.9), FrameLights(0.1, 0.9)]  # the camera stops after 0.1 s
    siren = SirenTimeline(np.array([0.3, 0.5, 1.2]), np.array([0.9, 0.9, 0.9]), 0.8)
    beliefs = fuse_clip(frames, siren)
    assert [b.time_s for b in beliefs] == [0.0, 0.1, 0.3, 0.5, 1.2]
    assert [b.lights for b in beliefs] == [True, True, True, True, False]  # held for 1 s
    assert [b.siren for b in beliefs] == [False, False, True, True, True]  # none before 1st decision
    assert beliefs[2].sources == ("light", "siren") and beliefs[-1].sources == ("siren",)
    assert all(b.source == "clip" for b in beliefs)
    with pytest.raises(ValueError):
        fuse_clip([FrameLights(1.0), FrameLights(0.5)])
    # a siren decision below the threshold does not end the hold of the last one above it
    dips = SirenTimeline(np.array([0.5, 0.9, 1.4, 1.6]), np.array([0.9, 0.1, 0.1, 0.1]), 0.8)
    assert [b.siren for b in fuse_clip([], dips)] == [True, True, True, False]
    with pytest.raises(ValueError):
        SirenTimeline(np.array([0.5, 0.4]), np.array([0.1, 0.2]), 0.8)
    assert whole_seconds(10.0) == 10 and whole_seconds(11.28) == 11 and whole_seconds(0.4) == 0


def test_score_seconds_counts_and_leaves_out_unsure() -> None:
    s = score_seconds([True, True, False, False, True], [True, False, True, False, None])
    assert (s["tp"], s["fp"], s["fn"], s["tn"], s["unsure"]) == (1, 1, 1, 1, 1)
    assert s["precision"] == 0.5 and s["recall"] == 0.5 and s["f1"] == 0.5
    assert score_seconds([False], [False])["precision"] is None


def test_shipped_ground_truth(tmp_path: Path) -> None:
    truth = read_clip_seconds()
    assert {c: len(r) for c, r in truth.items()} == {
        "night_ambulance_lights": 11,
        "fire_trucks_red_lights": 10,
        "intersection_cam_ambulance": 27,
        "traffic_no_ev": 10,
    }
    assert not any(r.active_ev or r.siren or r.lights for r in truth["traffic_no_ev"])
    for rows in truth.values():  # active_ev is "siren or lights" wherever both are known
        for r in rows:
            if r.siren is not None and r.lights is not None:
                assert r.active_ev == (r.siren or r.lights)
    bad = tmp_path / "seconds.csv"
    text = Path(read_clip_seconds.__globals__["CLIP_SECONDS"]).read_text(encoding="utf-8")
    bad.write_text(text.replace("traffic_no_ev,3,0,0,0", "traffic_no_ev,3,maybe,0,0"), encoding="utf-8")
    with pytest.raises(InputError, match=r"seconds\.csv:\d+"):
        read_clip_seconds(bad)


# ------------------------------------------------------------------------------------- sound tracks
def _make_clip(path: Path, audio: str | None, seconds: float = 1.6) -> Path:
    """A small H.264 clip (moving grey frames) with a clean AAC tone track, a track of garbage
    packets (``"corrupt"``), or none."""
    out = av.open(str(path), "w", format="mp4")
    v = out.add_stream("libx264", rate=25)
    v.width, v.height, v.pix_fmt = 160, 128, "yuv420p"
    a = out.add_stream("aac", rate=44100) if audio else None
    if a is not None:
        a.layout = "stereo"
    for i in range(int(seconds * 25)):
        img = np.full((128, 160, 3), (i * 7) % 255, np.uint8)
        for p in v.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
            out.mux(p)
    for p in v.encode(None):
        out.mux(p)
    if a is not None:
        t = np.arange(int(seconds * 44100)) / 44100
        tone = np.stack([0.2 * np.sin(2 * np.pi * 800 * t)] * 2).astype(np.float32)
        rng = np.random.default_rng(0)
        packets = []
        for k in range(0, tone.shape[1], 1024):
            f = av.AudioFrame.from_ndarray(
                np.ascontiguousarray(tone[:, k : k + 1024]), format="fltp", layout="stereo"
            )
            f.sample_rate, f.pts = 44100, k
            packets += a.encode(f)
        packets += a.encode(None)
        for p in packets:
            if audio == "corrupt":
                q = av.Packet(bytes(rng.integers(0, 256, p.size, dtype=np.uint8)))
                q.pts, q.dts, q.time_base, q.stream = p.pts, p.dts, p.time_base, a
                p = q
            out.mux(p)
    out.close()
    return path


@pytest.fixture(scope="module")
def made_clips(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("clips")
    return {
        k: _make_clip(d / f"{k}.mp4", None if k == "silent" else k) for k in ("good", "corrupt", "silent")
    }


def test_reader_downmixes_and_resamples(made_clips: dict[str, Path], video_dir: Path) -> None:
    clip = read_clip_audio(made_clips["good"], 48000)
    assert (clip.channels, clip.source_rate, clip.sample_rate) == (2, 44100, 48000)
    assert abs(clip.duration_s - 1.6) < 0.06
    spec = np.abs(np.fft.rfft(clip.samples[4800:-4800]))
    peak = np.fft.rfftfreq(len(clip.samples) - 9600, 1 / 48000)[int(np.argmax(spec))]
    assert abs(peak - 800) < 5  # the tone keeps its pitch through 44.1 → 48 kHz
    assert not has_audio(made_clips["silent"]) and not has_audio(video_dir / "highway_cam_no_ev.mp4")
    with pytest.raises(InputError, match="has no audio stream"):
        read_clip_audio(made_clips["silent"], 48000)
    with pytest.raises(InputError, match="audio stream cannot be decoded"):
        read_clip_audio(made_clips["corrupt"], 48000)
    real = read_clip_audio(video_dir / "traffic_no_ev.mp4", 48000)  # mp3 in an mp4, stereo
    assert real.codec.startswith("mp3") and real.channels == 2 and abs(real.duration_s - 10.0) < 0.05


# -------------------------------------------------------------------------------- real clip, library
def test_real_clip_through_the_library(video_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "night"
    run = run_clip(
        video_dir / "night_ambulance_lights.mp4",
        out,
        rule="lights",
        max_frames=50,  # 2 s of video, and the first 2 s of the sound track
        write_video=False,
        progress=False,
    )
    assert run.audio is not None and run.audio["channels"] == 2 and run.audio["source_rate_hz"] == 44100
    # a decision every 0.17 s from the end of the first 0.5 s window, until 2 s
    assert run.siren is not None and len(run.siren) == 9 and run.siren.time_s[-1] <= 2.0
    lines = [json.loads(x) for x in (out / "seconds.jsonl").read_text().splitlines()]
    assert [x["second"] for x in lines] == [0, 1]
    assert all(isinstance(x["siren_probability"], float) and x["frames"] == 25 for x in lines)
    # the wailing siren is heard within the first two seconds (measured 0.99 in second 1)
    assert max(x["siren_probability"] for x in lines) >= run.siren.threshold
    assert any(x["decision"] in ("yield", "prepare") for x in lines)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["seconds"]["seconds"] == 2 and summary["seconds"]["audio"]["codec"] == "aac"
    assert sum(summary["seconds"]["decisions"].values()) == 2
    assert summary["outputs"]["seconds"] == str(out / "seconds.jsonl")


# ------------------------------------------------------------------------------------------- the CLI
def test_detect_without_sound_keeps_working(video_dir: Path, tmp_path: Path) -> None:
    clip = str(video_dir / "highway_cam_no_ev.mp4")
    out = tmp_path / "o"
    args = ["detect", clip, "--out", str(out), "--max-frames", "30", "--rule", "lights", "--no-video", "-q"]
    r = runner.invoke(app, [*args, "--json"])
    assert r.exit_code == 0, r.output
    summary = json.loads(r.stdout.strip().splitlines()[-1])
    assert summary["seconds"]["audio"] is None and summary["seconds"]["siren_seconds"] is None
    lines = [json.loads(x) for x in (out / "seconds.jsonl").read_text().splitlines()]
    assert len(lines) == 1 and lines[0]["siren_probability"] is None and lines[0]["decision"] == "none"
    # asking for sound on a clip without any: one clear line, nothing written
    r = runner.invoke(app, ["detect", clip, "--out", str(tmp_path / "x"), "--audio", "-q"])
    assert r.exit_code == 2 and "has no audio stream" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()


def test_detect_with_a_corrupt_sound_track(made_clips: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "bad"
    r = runner.invoke(
        app, ["detect", str(made_clips["corrupt"]), "--out", str(out), "--rule", "lights", "-q"]
    )
    assert r.exit_code == 2, r.output
    err = r.stderr.strip()
    assert err.startswith("error: ") and len(err.splitlines()) == 1 and "Traceback" not in err
    assert "corrupt.mp4" in err and "audio stream cannot be decoded" in err
    assert not out.exists()
    # the pictures are fine: without the sound the clip runs
    r = runner.invoke(
        app,
        [
            "detect",
            str(made_clips["corrupt"]),
            "--out",
            str(out),
            "--rule",
            "lights",
            "--no-audio",
            "--no-video",
            "-q",
        ],
    )
    assert r.exit_code == 0, r.output
    assert (out / "seconds.jsonl").is_file()
