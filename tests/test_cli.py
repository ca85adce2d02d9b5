"""The command line: help, exit codes, one-line errors, and nothing written on bad input."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from makeway.cli.main import app

runner = CliRunner()


def test_help_lists_commands() -> None:
    r = runner.invoke(app, ["--help"])
    assert r.exit_code == 0
    for cmd in ("detect", "track", "mot-eval", "demo", "info"):
        assert cmd in r.output
    r = runner.invoke(app, ["detect", "--help"])
    assert r.exit_code == 0 and "--max-frames" in r.output and "--stride" in r.output


def test_track_with_gt_prints_metrics(mot15_root: Path, tmp_path: Path) -> None:
    seq = mot15_root / "TUD-Stadtmitte"
    out = tmp_path / "tracks.txt"
    r = runner.invoke(
        app,
        [
            "track",
            "--mot-det",
            str(seq / "det" / "det.txt"),
            "--out",
            str(out),
            "--gt",
            str(seq / "gt" / "gt.txt"),
        ],
    )
    assert r.exit_code == 0, r.output
    metrics = json.loads(r.stdout.strip().splitlines()[-1])
    assert metrics["mota"] > 0.7 and metrics["idf1"] > 0.7
    first = out.read_text().splitlines()[0].split(",")
    assert len(first) == 10 and first[6:] == ["1", "-1", "-1", "-1"]
    r2 = runner.invoke(app, ["mot-eval", str(seq / "gt" / "gt.txt"), str(out)])
    assert r2.exit_code == 0
    assert json.loads(r2.stdout.strip())["mota"] == metrics["mota"]


def test_track_bad_det_file(tmp_path: Path) -> None:
    bad = tmp_path / "det.txt"
    bad.write_text("1,-1,10,10,abc,5,0.9\n")
    out = tmp_path / "tracks.txt"
    r = runner.invoke(app, ["track", "--mot-det", str(bad), "--out", str(out)])
    assert r.exit_code == 2
    assert "det.txt" in r.stderr and "non-numeric" in r.stderr
    assert len(r.stderr.strip().splitlines()) <= 2  # one message (it may wrap once)
    assert not out.exists()
    r = runner.invoke(app, ["track", "--mot-det", str(tmp_path / "none.txt"), "--out", str(out)])
    assert r.exit_code == 2 and "no such file" in r.stderr


def test_track_bad_gt_writes_nothing(mot15_root: Path, tmp_path: Path) -> None:
    gt = tmp_path / "gt.txt"
    gt.write_text("1,1,0,0,10\n")
    out = tmp_path / "tracks.txt"
    det = mot15_root / "TUD-Campus" / "det" / "det.txt"
    r = runner.invoke(app, ["track", "--mot-det", str(det), "--out", str(out), "--gt", str(gt)])
    assert r.exit_code == 2 and "gt.txt" in r.stderr
    assert not out.exists()


def test_detect_errors(tmp_path: Path, video_dir: Path) -> None:
    out = tmp_path / "out"
    r = runner.invoke(app, ["detect", str(tmp_path / "missing.mp4"), "--out", str(out)])
    assert r.exit_code == 2 and "missing.mp4" in r.stderr and "no such file" in r.stderr
    bad = tmp_path / "clip.mp4"
    bad.write_text("this is not a video")
    r = runner.invoke(app, ["detect", str(bad), "--out", str(out)])
    assert r.exit_code == 2 and "clip.mp4" in r.stderr
    r = runner.invoke(
        app,
        [
            "detect",
            str(video_dir / "traffic_no_ev.mp4"),
            "--out",
            str(out),
            "--model",
            str(tmp_path / "x.onnx"),
        ],
    )
    assert r.exit_code == 2 and "x.onnx" in r.stderr
    r = runner.invoke(app, ["detect", str(video_dir / "traffic_no_ev.mp4"), "--detector", "yolo9000"])
    assert r.exit_code == 2 and "yolox_nano" in r.stderr
    assert not out.exists() or not any(out.iterdir())


def test_detect_json(video_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "o"
    r = runner.invoke(
        app,
        [
            "detect",
            str(video_dir / "highway_cam_no_ev.mp4"),
            "--out",
            str(out),
            "--max-frames",
            "8",
            "--json",
            "-q",
        ],
    )
    assert r.exit_code == 0, r.output
    summary = json.loads(r.stdout.strip().splitlines()[-1])
    assert summary["frames"] == 8 and Path(summary["outputs"]["video"]).exists()


def test_info_runs() -> None:
    r = runner.invoke(app, ["info"])
    assert r.exit_code == 0 and "makeway" in r.output
