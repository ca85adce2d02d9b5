"""``makeway lights`` (makeway.apps.lights) on real clips and image folders, its bad-input contract,
and ``makeway detect``'s default lights+crop rule."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import pytest
import yaml
from typer.testing import CliRunner

from makeway.cli.main import app

runner = CliRunner()
CLIP = "traffic_no_ev.mp4"  # 640×360, 30 fps


def _rig(tmp_path: Path, width: int = 640, height: int = 360, **extra: object) -> Path:
    """A one-camera pinhole rig looking straight ahead (fx 500 px)."""
    cam = {
        "name": "dash",
        "model": "pinhole",
        "width": width,
        "height": height,
        "fx": 500.0,
        "fy": 500.0,
        "cx": width / 2,
        "cy": height / 2,
        "yaw_pitch_roll_deg": [0.0, 0.0, 0.0],
        "translation_m": [2.0, 0.0, 1.2],
        **extra,
    }
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump({"cameras": [cam]}), encoding="utf-8")
    return path


def _lines(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_lights_video_writes_video_jsonl_and_azimuths(video_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    rig = _rig(tmp_path)
    r = runner.invoke(
        app,
        [
            *("lights", str(video_dir / CLIP), "--out", str(out), "--rig", str(rig), "--camera", "dash"),
            # the rules box every coloured lamp of this no-EV clip: plenty of boxes to check the plumbing
            *("--colours", "us", "--detector", "colour", "--max-frames", "40", "--json", "-q"),
        ],
    )
    assert r.exit_code == 0, r.output
    summary = json.loads(r.stdout.strip().splitlines()[-1])
    assert summary["frames"] == 40 and summary["kind"] == "video" and summary["camera"] == "dash"
    assert summary["colours"] == ["red", "blue", "white"]
    lines = _lines(out / "lights.jsonl")
    assert [ln["frame"] for ln in lines] == list(range(40))
    assert lines[1]["time_s"] == pytest.approx(1 / 30, abs=1e-3)
    lights = [light for ln in lines for light in ln["lights"]]
    assert len(lights) == summary["light_detections"] > 40
    half_fov = math.degrees(math.atan(320 / 500))
    for light in lights:
        assert {"track_id", "box", "colour", "score", "flash_hz", "duty", "flashing"} <= set(light)
        assert light["colour"] in ("red", "blue", "white") and 0 <= light["score"] <= 1
        u = 0.5 * (light["box"]["x1"] + light["box"]["x2"])
        az = light["azimuth_deg"]
        assert abs(az) <= half_fov + 1e-6 and (az > 0) == (u < 320)  # positive to the left
        assert abs(light["elevation_deg"]) < 40
    cap = cv2.VideoCapture(str(out / "annotated.mp4"))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 40 and int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)) == 640
    cap.release()
    assert json.loads((out / "summary.json").read_text())["light_tracks"] == summary["light_tracks"]


def test_lights_image_folder_and_default_output(video_dir: Path, tmp_path: Path, monkeypatch) -> None:
    images = tmp_path / "frames"
    images.mkdir()
    cap = cv2.VideoCapture(str(video_dir / "night_ambulance_lights.mp4"))
    for i in range(3):
        ok, frame = cap.read()
        assert ok
        cv2.imwrite(str(images / f"f{i}.jpg"), frame)
    cap.release()
    (images / "notes.txt").write_text("not an image")
    monkeypatch.chdir(tmp_path)
    r = runner.invoke(app, ["lights", str(images), "-q"])
    assert r.exit_code == 0, r.output
    out = tmp_path / "makeway_out" / "frames_lights"  # the default output folder
    lines = _lines(out / "lights.jsonl")
    assert [ln["image"] for ln in lines] == ["f0.jpg", "f1.jpg", "f2.jpg"]
    assert all(ln["lights"] for ln in lines)  # the night clip's lights are found in each frame
    assert all(
        light["flash_hz"] is None and light["track_id"] is None for ln in lines for light in ln["lights"]
    )
    assert sorted(p.name for p in (out / "annotated").iterdir()) == ["f0.jpg", "f1.jpg", "f2.jpg"]


def _fails(args: list[str], needle: str) -> None:
    r = runner.invoke(app, ["lights", *args, "-q"])
    assert r.exit_code == 2, r.output
    text = " ".join(r.output.split())
    assert needle in text, text
    assert len(r.output.strip().splitlines()) <= 3  # one message (rich may wrap it)


def test_lights_bad_input_one_line_exit_2_nothing_written(video_dir: Path, tmp_path: Path) -> None:
    clip = str(video_dir / CLIP)
    out = tmp_path / "o"
    _fails([str(tmp_path / "missing.mp4"), "--out", str(out)], "not found")
    corrupt = tmp_path / "corrupt.mp4"
    corrupt.write_bytes(b"\x00\x01not a video" * 100)
    _fails([str(corrupt), "--out", str(out)], "corrupt.mp4")
    empty = tmp_path / "empty"
    empty.mkdir()
    _fails([str(empty), "--out", str(out)], "has no images")
    _fails([clip, "--out", str(out), "--rig", "default", "--camera", "roof"], "has no camera 'roof'")
    _fails([clip, "--out", str(out), "--camera", "front"], "frames are 640×360")  # default rig: 1280×960
    _fails([clip, "--out", str(out), "--rig", "default"], "--camera is needed")
    bad_rig = _rig(tmp_path)
    doc = yaml.safe_load(bad_rig.read_text())
    del doc["cameras"][0]["fx"]
    bad_rig.write_text(yaml.safe_dump(doc))
    _fails([clip, "--out", str(out), "--rig", str(bad_rig), "--camera", "dash"], "fx")
    _fails([clip, "--out", str(out), "--colours", "purple"], "unknown colour set")
    _fails([clip, "--out", str(out), "--detector", "yolo9000"], "yolo9000")
    a_file = tmp_path / "file"
    a_file.write_text("x")
    _fails([clip, "--out", str(a_file / "sub")], "file")
    assert not out.exists() and not (a_file.parent / "sub").exists()


def test_detect_default_rule_flags_the_flashing_ambulance(video_dir: Path, tmp_path: Path) -> None:
    """``makeway detect`` with its defaults (rule lights+crop, colours us): the lit ambulance
    (track 13 of the label file) becomes active within the clip's first 3 s, and every
    ``tracks.jsonl`` line lists the frame's lights."""
    out = tmp_path / "night"
    clip = video_dir / "night_ambulance_lights.mp4"
    r = runner.invoke(
        app, ["detect", str(clip), "-o", str(out), "--max-frames", "75", "--no-video", "--json", "-q"]
    )
    assert r.exit_code == 0, r.output
    summary = json.loads(r.stdout.strip().splitlines()[-1])
    assert summary["rule"] == "lights+crop" and summary["ms_per_frame"]["lights"] > 0
    assert 13 in summary["active_ev_tracks"]
    lines = _lines(out / "tracks.jsonl")
    assert all("lights" in ln for ln in lines)
    flashing = [light for ln in lines for light in ln["lights"] if light["flashing"]]
    assert flashing and all(0.75 <= light["flash_hz"] <= 8.0 for light in flashing)
    assert all(light["colour"] in ("red", "blue") for ln in lines for light in ln["lights"])
    r = runner.invoke(app, ["detect", str(clip), "-o", str(tmp_path / "x"), "--classifier", "none", "-q"])
    assert r.exit_code == 2 and "needs a classifier" in " ".join(r.output.split())
    r = runner.invoke(app, ["detect", str(clip), "-o", str(tmp_path / "y"), "--rule", "vibes", "-q"])
    assert r.exit_code == 2 and "unknown rule" in r.output
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


def test_lights_default_detector_is_quiet_on_a_no_ev_clip(video_dir: Path, tmp_path: Path) -> None:
    """`makeway lights` reviews footage with the verified detector: few boxes where no EV is lit."""
    out = tmp_path / "quiet"
    r = runner.invoke(
        app, ["lights", str(video_dir / CLIP), "--out", str(out), "--max-frames", "20", "--json", "-q"]
    )
    assert r.exit_code == 0, r.output
    summary = json.loads(r.stdout.strip().splitlines()[-1])
    assert summary["detector"] == "verified" and summary["frames"] == 20
    assert summary["light_detections"] <= 10
