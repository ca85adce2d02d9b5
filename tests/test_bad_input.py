"""Bad input and bad output paths end in one line naming the file and the problem, exit code 2, and
nothing half-written (issue 21, items 2–5). Real data, real commands (typer's CliRunner)."""

from __future__ import annotations

import csv
import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from makeway.atomic import check_writable
from makeway.cli.common import print_json_line
from makeway.cli.main import app
from makeway.errors import InputError
from makeway.sense.crops import read_crop_folder
from makeway.sense.recording import write_recording
from makeway.sense.video import VideoReader
from makeway.sim.audio_scenarios import simulate_recording

runner = CliRunner()

CLIP = "highway_cam_no_ev.mp4"  # 320×240, 252 frames at 25 fps, index (moov) first: small and fast


def _one_error_line(r: object, *words: str) -> str:
    """The result exited 2 with one ``error:`` line (it may wrap once) holding every word; no traceback."""
    assert r.exit_code == 2, (r.exit_code, r.output, r.exception)  # type: ignore[attr-defined]
    err = r.stderr  # type: ignore[attr-defined]
    assert "Traceback" not in err and "error:" in err, err
    assert len(err.strip().splitlines()) <= 2, err
    for w in words:
        assert w in err.replace("\n", ""), (w, err)
    return err


def _strict_json(line: str) -> dict:
    def refuse(constant: str) -> None:
        raise ValueError(f"not JSON: {constant}")

    return json.loads(line, parse_constant=refuse)


@pytest.fixture()
def a_file(tmp_path: Path) -> Path:
    f = tmp_path / "file.txt"
    f.write_text("an ordinary file\n")
    return f


# ------------------------------------------------------------------------ item 2: bad output paths


def test_check_writable(tmp_path: Path, a_file: Path) -> None:
    assert check_writable(tmp_path / "new" / "deeper", folder=True) == tmp_path / "new" / "deeper"
    assert not (tmp_path / "new").exists()  # only checked, nothing created
    assert check_writable(tmp_path, folder=True) == tmp_path
    assert check_writable(a_file, folder=False) == a_file  # an existing file may be replaced
    with pytest.raises(InputError, match="is a file, not a folder") as info:
        check_writable(a_file / "out" / "x.png", folder=False)
    assert info.value.path == a_file / "out" / "x.png"
    with pytest.raises(InputError, match="exists and is a file"):
        check_writable(a_file, folder=True)
    with pytest.raises(InputError, match="is a folder"):
        check_writable(tmp_path, folder=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.txt"]  # the probe left nothing


def test_check_writable_where_nothing_can_be_made() -> None:
    # /proc takes no new files even for root (as whom CI runs, and for whom a read-only folder made
    # with chmod would not stop writing)
    with pytest.raises(InputError, match="cannot be written"):
        check_writable("/proc/makeway_out/run", folder=True)


def test_detect_bad_out(video_dir: Path, a_file: Path) -> None:
    clip = str(video_dir / CLIP)
    r = runner.invoke(app, ["detect", clip, "--out", str(a_file / "out"), "--no-video", "-q"])
    _one_error_line(r, "file.txt/out", "is a file, not a folder")
    r = runner.invoke(app, ["detect", clip, "--out", str(a_file), "--no-video", "-q"])
    _one_error_line(r, "file.txt", "output folder is needed")
    assert a_file.read_text() == "an ordinary file\n"


def test_track_bad_out(mot15_root: Path, tmp_path: Path, a_file: Path) -> None:
    det = str(mot15_root / "TUD-Campus" / "det" / "det.txt")
    r = runner.invoke(app, ["track", "--mot-det", det, "--out", str(a_file / "tracks.txt")])
    _one_error_line(r, "tracks.txt", "is a file, not a folder")
    r = runner.invoke(app, ["track", "--mot-det", det, "--out", str(tmp_path)])
    _one_error_line(r, "is a folder")


def test_simulate_bad_out_is_checked_first(tmp_path: Path, a_file: Path) -> None:
    # the output is checked before anything is read or run: a missing --path is not even reached
    missing = tmp_path / "no_path.csv"
    r = runner.invoke(app, ["simulate", "--out", str(a_file / "run"), "--path", str(missing)])
    _one_error_line(r, "file.txt/run", "is a file, not a folder")
    assert r.stdout == ""


def test_audio_simulate_bad_out(a_file: Path) -> None:
    r = runner.invoke(app, ["audio", "simulate", "--out", str(a_file / "recs"), "--n", "1", "-q"])
    _one_error_line(r, "file.txt/recs", "is a file, not a folder")
    r = runner.invoke(app, ["audio", "simulate", "--out", str(a_file), "--n", "1", "-q"])
    _one_error_line(r, "file.txt", "output folder is needed")


@pytest.fixture(scope="module")
def short_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 0.7 s simulated recording of the roof array (synthesized siren, generated street noise)."""
    rec = simulate_recording("crossing", 0.7, seed=1, siren="synth", noise="generated")
    return write_recording(tmp_path_factory.mktemp("rec") / "rec_short", rec)


def test_audio_listen_bad_plot_and_jsonl(short_recording: Path, a_file: Path) -> None:
    rec = str(short_recording)
    r = runner.invoke(app, ["audio", "listen", rec, "--baseline", "gccphat", "--plot", str(a_file / "p.png")])
    _one_error_line(r, "p.png", "is a file, not a folder")
    assert r.stdout == ""  # checked before listening: no message was printed
    r = runner.invoke(app, ["audio", "listen", rec, "--baseline", "gccphat", "--jsonl", str(a_file.parent)])
    _one_error_line(r, "is a folder")
    r = runner.invoke(app, ["audio", "listen", rec, "--baseline", "gccphat"])
    assert r.exit_code == 0, r.output  # the same recording is fine: 0.7 s holds one 0.5 s window
    assert len([_strict_json(line) for line in r.stdout.splitlines()]) == 2  # windows at 0 and 0.17 s


def test_audio_eval_data_is_a_file(a_file: Path) -> None:
    r = runner.invoke(app, ["audio", "eval", "--data", str(a_file), "--baseline", "gccphat", "-q"])
    _one_error_line(r, "file.txt", "is a file")


# ------------------------------------------------------------------ item 3: truncated, damaged video


@pytest.fixture(scope="module")
def damaged_clips(video_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    data = (video_dir / CLIP).read_bytes()
    folder = tmp_path_factory.mktemp("damaged")
    cut = folder / "cut.mp4"
    cut.write_bytes(data[:200_000])  # `head -c 200000`: the index is first, so it opens
    zeroed = bytearray(data)
    mid = len(data) // 2
    zeroed[mid : mid + 20_000] = bytes(20_000)
    holed = folder / "zeroed.mp4"
    holed.write_bytes(bytes(zeroed))
    return {"cut": cut, "zeroed": holed}


@pytest.mark.parametrize("kind", ["cut", "zeroed"])
def test_detect_damaged_video_fails_and_leaves_nothing(
    damaged_clips: dict[str, Path], tmp_path: Path, kind: str
) -> None:
    clip = damaged_clips[kind]
    out = tmp_path / "out" / "run"
    r = runner.invoke(app, ["detect", str(clip), "--out", str(out), "--stride", "3", "-q"])
    err = _one_error_line(r, clip.name, "truncated or damaged after frame", "of 252")
    frames = int(err.replace("\n", "").split("after frame ")[1].split()[0])
    # the file holds fewer bytes than the clip: decoding stops well inside it
    assert 20 < frames < 200
    assert not (tmp_path / "out").exists()  # no output folder (nor its parent made for it)
    assert r.stdout == ""


def test_detect_clean_clip_and_a_limit_pass(
    video_dir: Path, damaged_clips: dict[str, Path], tmp_path: Path
) -> None:
    out = tmp_path / "clean"
    r = runner.invoke(
        app, ["detect", str(video_dir / CLIP), "--out", str(out), "--stride", "3", "--json", "-q"]
    )
    assert r.exit_code == 0, r.output
    summary = _strict_json(r.stdout.strip().splitlines()[-1])
    assert summary["frames"] == 84  # source frames 0, 3, …, 249 of 252
    assert (out / "tracks.jsonl").is_file() and (out / "summary.json").is_file()
    # --max-frames stops on purpose: the frames asked for are all there, so a cut file passes
    r = runner.invoke(
        app, ["detect", str(damaged_clips["cut"]), "--out", str(tmp_path / "head"), "--max-frames", "5", "-q"]
    )
    assert r.exit_code == 0, r.output


def test_reader_check_complete(video_dir: Path, damaged_clips: dict[str, Path]) -> None:
    # a clean clip that decodes 282 of the 288 frames its container lists, its last one at
    # (288 - 1) / 25 s = 11.48 s: nothing is missing in time, so it is not reported
    with VideoReader(video_dir / "night_ambulance_lights.mp4", stride=8) as reader:
        for _ in reader:
            pass
        assert reader.reached_end and reader.info.frame_count == 288
        assert reader.last_time_s == pytest.approx(11.48, abs=0.05)
        reader.check_complete()
    with VideoReader(damaged_clips["cut"]) as reader:
        n = sum(1 for _ in reader)  # iteration itself stays quiet …
        with pytest.raises(InputError, match=f"after frame {n} of 252") as info:
            reader.check_complete()  # … the check names the file and how far it got
        assert info.value.path == damaged_clips["cut"]


# ------------------------------------------------------------------- item 4: strict JSON from mot-eval


def test_mot_eval_empty_ground_truth_prints_strict_json(mot15_root: Path, tmp_path: Path) -> None:
    gt = tmp_path / "gt.txt"
    gt.write_text("")
    tracks = mot15_root / "TUD-Campus" / "gt" / "gt.txt"  # any real boxes will do as the tracker output
    r = runner.invoke(app, ["mot-eval", str(gt), str(tracks)])
    assert r.exit_code == 0, r.output
    metrics = _strict_json(r.stdout.strip())
    n_boxes = sum(1 for line in tracks.read_text().splitlines() if line.strip())
    assert metrics["num_gt"] == 0 and metrics["tp"] == 0
    assert metrics["fp"] == metrics["num_hyp"] == n_boxes  # every box is a false positive
    assert metrics["mota"] is None and metrics["recall"] is None  # 0/0: undefined, printed as null


def test_print_json_line_is_strict(capsys: pytest.CaptureFixture[str]) -> None:
    print_json_line({"a": float("nan"), "b": [np.float32(0.25), float("inf")], "c": np.int64(3), "d": 0.1})
    out = capsys.readouterr().out
    assert _strict_json(out) == {"a": None, "b": [0.25, None], "c": 3, "d": 0.1}
    assert out.count("\n") == 1


# ---------------------------------------------------------- item 5: short recording, truncated crops


def test_audio_listen_shorter_than_a_window(short_recording: Path, tmp_path: Path) -> None:
    from makeway.sense.recording import read_recording

    rec = read_recording(short_recording)
    cut = dataclasses.replace(rec, audio=rec.audio[: int(0.3 * rec.sample_rate)])
    folder = write_recording(tmp_path / "rec_cut", cut)
    r = runner.invoke(app, ["audio", "listen", str(folder), "--baseline", "gccphat"])
    _one_error_line(r, "audio.flac", "0.3 s long", "shorter than one 0.5 s listening window")
    assert r.stdout == ""


def _crop_folder(root: Path, source: Path, names: list[str], labels: dict[str, str]) -> Path:
    (root / "images").mkdir(parents=True)
    for name in names:
        (root / "images" / name).write_bytes((source / "images" / name).read_bytes())
    with (root / "labels.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["image", "emergency"])
        w.writerows([name, labels[name]] for name in names)
    return root


def test_classify_eval_names_a_truncated_crop_and_scores_the_rest(data_root: Path, tmp_path: Path) -> None:
    source = data_root / "vision" / "ev_crops"
    with (source / "labels.csv").open() as fh:
        labels = {row["image"]: row["emergency"] for row in csv.DictReader(fh)}
    names = sorted(labels)[:7]
    folder = _crop_folder(tmp_path / "crops", source, names, labels)
    bad = folder / "images" / names[3]
    data = bad.read_bytes()
    bad.write_bytes(data[: len(data) // 2])  # `head -c`: OpenCV would still decode it (grey lower half)
    with pytest.raises(InputError, match="truncated JPEG") as info:
        read_crop_folder(folder).load_images(32)
    assert info.value.path == bad

    r = runner.invoke(app, ["classify", "eval", "--data", str(folder), "--model", "fastest"])
    assert r.exit_code == 0, r.output
    skipped = [line for line in r.stderr.splitlines() if line.startswith("skipped:")]
    assert len(skipped) == 1 and names[3] in skipped[0] and "truncated JPEG" in skipped[0]
    metrics = _strict_json(r.stdout.strip().splitlines()[-1])
    assert metrics["n"] == 6 and metrics["skipped"] == [str(bad)]

    # bytes after the end-of-image marker are not damage: decoders ignore them
    padded = folder / "images" / names[0]
    padded.write_bytes(padded.read_bytes() + b"\x00" * 64)
    assert read_crop_folder(folder).subset([0]).load_images(32).shape == (1, 32, 32, 3)

    only_bad = _crop_folder(tmp_path / "only_bad", folder, [names[3]], labels)
    r = runner.invoke(app, ["classify", "eval", "--data", str(only_bad), "--model", "fastest"])
    assert r.exit_code == 2 and "none of its 1 crops can be read" in r.stderr
    assert names[3] in r.stderr
