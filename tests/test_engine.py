"""The data engine on Dask (issue 28, items 3 and 5): a real 2-worker cluster on loopback mines real
clip slices, a simulated array recording and road images; reruns resume; a bad input is listed while
the rest completes; an unreachable scheduler is one line, exit 2."""

from __future__ import annotations

import csv
import json
import logging
import shutil
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from makeway.apps.audio import simulate_recordings
from makeway.apps.engine import labelled_crop_folder
from makeway.cli.main import app
from makeway.engine.cluster import mine_inputs
from makeway.engine.inputs import expand_inputs, parse_input
from makeway.engine.mine import DONE_FILE, MineConfig
from makeway.errors import InputError
from makeway.sense.crops import read_crop_folder
from makeway.v2x.transport import free_loopback_port

FAST = MineConfig(classifier="fast", every=2)


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def inputs(
    video_dir: Path, data_root: Path, tmp_path_factory: pytest.TempPathFactory
) -> dict[str, Path | str]:
    """Two 8-frame slices of a real clip, a 2 s simulated 8-channel recording, 3 real road images
    and a video cut after its first 30 kB (damaged)."""
    root = tmp_path_factory.mktemp("engine_inputs")
    simulate_recordings(root / "recs", 1, duration_s=2.0, seed=5, no_siren_fraction=0.0, progress=False)
    images = root / "images"
    images.mkdir()
    for p in sorted((data_root / "vision" / "ambulance_yolo" / "valid" / "images").glob("*.jpg"))[:3]:
        shutil.copy(p, images / p.name)
    clip = video_dir / "night_ambulance_lights.mp4"
    damaged = root / "damaged.mp4"
    damaged.write_bytes(clip.read_bytes()[:30_000])
    return {
        "a": f"{clip}@100:108",
        "b": f"{clip}@200:208",
        "rec": root / "recs" / "rec_00000",
        "images": images,
        "damaged": damaged,
    }


def test_input_names(video_dir: Path, tmp_path: Path) -> None:
    clip = video_dir / "night_ambulance_lights.mp4"
    inp = parse_input(f"{clip}@10:20")
    assert (inp.kind, inp.start, inp.end) == ("video", 10, 20)
    assert inp.input_id.startswith("night_ambulance_lights.mp4_10-20_")
    assert parse_input(clip).input_id != inp.input_id
    with pytest.raises(InputError, match="empty frame range"):
        parse_input(f"{clip}@20:10")
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(InputError, match="not an input the engine knows"):
        parse_input(tmp_path / "notes.txt")
    found, problems = expand_inputs([clip, tmp_path / "missing.mp4"], segment_frames=100)
    assert [(i.start, i.end) for i in found] == [(0, 100), (100, 200), (200, 288)]
    assert len(problems) == 1 and "no such file" in problems[0][1]


def test_two_worker_cluster_mines_resumes_and_lists_the_bad_input(
    inputs: dict[str, Path | str], tmp_path: Path
) -> None:
    from distributed import LocalCluster

    out = tmp_path / "mined"
    names = [inputs["a"], inputs["b"], inputs["rec"], inputs["images"], inputs["damaged"]]
    with LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
        silence_logs=logging.ERROR,
    ) as cluster:
        address = cluster.scheduler_address
        assert address.startswith("tcp://127.0.0.1:")
        run = mine_inputs(names, out, config=FAST, scheduler=address, progress=False)
        assert run.workers == 2 and run.inputs == 5
        assert (run.done, run.skipped, run.failed) == (4, 0, 1)
        assert len({t["worker_pid"] for t in run.tasks if t["status"] == "done"}) == 2  # both workers ran
        assert all(t["cpu_s"] > 0 and t["seconds"] > 0 for t in run.tasks if t["status"] == "done")
        assert run.timing["tasks_s"] > 0 and run.task_cpu_s > 0
        failures = _rows(out / "failures.csv")
        assert [f["input"] for f in failures] == [str(inputs["damaged"])]
        assert "damaged" in failures[0]["error"] and len(failures[0]["error"].splitlines()) == 1

        samples = _rows(out / "samples.csv")
        vision = [s for s in samples if s["kind"] != "recording"]
        audio = [s for s in samples if s["kind"] == "recording"]
        assert vision and audio  # the ambulance clip and images give crops; the siren recording snippets
        for s in samples:
            p, t = float(s["probability"]), float(s["threshold"])
            assert s["reason"] == ("active" if p >= t else "near") and p >= t - FAST.band
            assert (out / "inputs" / s["media"]).is_file()
        probs = [float(s["probability"]) for s in vision]
        assert probs == sorted(probs, reverse=True)
        clip_rows = [s for s in vision if s["kind"] == "video"]
        assert all(100 <= int(s["frame"]) < 108 or 200 <= int(s["frame"]) < 208 for s in clip_rows)
        assert {s["input"] for s in clip_rows} <= {inputs["a"], inputs["b"]}
        cand = _rows(out / "candidates.csv")
        assert [c["image"] for c in cand] == [s["media"] for s in vision]
        assert (out / "contact_sheet.png").stat().st_size > 0 and (out / "audio_contact_sheet.png").is_file()
        assert [r["image"] for r in _rows(out / "labels_template.csv")] == [s["media"] for s in vision]
        summary = json.loads((out / "engine.json").read_text())
        assert summary["samples"] == len(samples) and summary["failed"] == 1

        # resumable: a rerun skips every finished input and reproduces the same samples
        again = mine_inputs(names, out, config=FAST, scheduler=address, progress=False)
        assert (again.done, again.skipped, again.failed) == (0, 4, 1)
        assert _rows(out / "samples.csv") == samples
        # an input whose marker is gone (interrupted) is mined again, the others are not
        first = next(p for p in (out / "inputs").iterdir() if p.name.startswith("night"))
        (first / DONE_FILE).unlink()
        third = mine_inputs(names, out, config=FAST, scheduler=address, progress=False)
        assert (third.done, third.skipped) == (1, 3)
        assert _rows(out / "samples.csv") == samples
        # other settings do not count as done
        other = mine_inputs([inputs["a"]], tmp_path / "other", config=FAST, scheduler=address, progress=False)
        assert other.done == 1


def test_labels_flow_back_as_a_crop_folder(inputs: dict[str, Path | str], tmp_path: Path) -> None:
    out = tmp_path / "mined"
    run = mine_inputs([inputs["images"]], out, config=FAST, workers=1, progress=False)
    assert run.done == 1 and run.vision_samples >= 2
    template = _rows(out / "labels_template.csv")
    labels = tmp_path / "labels.csv"
    rows = ["image,emergency"] + [f"{r['image']},{k % 2}" for k, r in enumerate(template[:-1])]
    labels.write_text("\n".join([*rows, f"{template[-1]['image']},"]) + "\n")
    counts = labelled_crop_folder(out, labels, tmp_path / "crops")
    assert counts["labelled"] == len(template) - 1 and counts["unreviewed"] == 1
    crops = read_crop_folder(tmp_path / "crops")
    assert len(crops) == len(template) - 1 and crops.n_positive == counts["positive"]
    bad = tmp_path / "bad.csv"
    bad.write_text(f"image,emergency\n{template[0]['image']},yes\n")
    with pytest.raises(InputError, match="line 2: emergency must be 0, 1 or blank"):
        labelled_crop_folder(out, bad, tmp_path / "crops2")
    assert not (tmp_path / "crops2").exists()


def test_cli_unreachable_scheduler_is_one_line_exit_2(inputs: dict[str, Path | str], tmp_path: Path) -> None:
    port = free_loopback_port()
    t0 = time.perf_counter()
    result = CliRunner().invoke(
        app,
        [
            "engine",
            "mine",
            str(inputs["a"]),
            "--out",
            str(tmp_path / "o"),
            "--scheduler",
            f"tcp://127.0.0.1:{port}",
        ],
    )
    assert result.exit_code == 2
    assert time.perf_counter() - t0 < 30
    err = result.stderr if hasattr(result, "stderr") else result.output
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "no Dask scheduler answered" in lines[0]
    assert not (tmp_path / "o" / "inputs").exists()


def test_cli_local_cluster_bad_input_exit_2(inputs: dict[str, Path | str], tmp_path: Path) -> None:
    out = tmp_path / "o"
    result = CliRunner().invoke(
        app,
        [
            "engine",
            "mine",
            str(inputs["b"]),
            str(tmp_path / "nope.mp4"),
            "--out",
            str(out),
            "--workers",
            "1",
            "--classifier",
            "fast",
            "--quiet",
            "--json",
        ],
    )
    assert result.exit_code == 2
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    assert summary["done"] == 1 and summary["failed"] == 1 and summary["workers"] == 1
    assert "nope.mp4: no such file or folder" in summary["failures"][0]["error"]


def test_a_robotics_log_is_mined_like_its_video_and_recording(
    inputs: dict[str, Path | str], video_dir: Path, tmp_path: Path
) -> None:
    """An MCAP log holding a clip's raw frames and a recording's audio is one input of kind ``log``:
    its camera gives the same crops as the video's frames, its audio the recording's snippets."""
    from makeway.engine.mine import run_input
    from makeway.sense.log_writer import make_test_log

    clip = video_dir / "night_ambulance_lights.mp4"
    log = tmp_path / "drive.mcap"
    make_test_log(log, video=clip, recording=inputs["rec"], image="raw", max_frames=8)
    inp = parse_input(log)
    assert inp.kind == "log"
    with pytest.raises(InputError, match="frame range"):
        parse_input(f"{log}@0:4")
    record = run_input(inp, FAST, tmp_path / "mined")
    assert record["status"] == "done", record.get("error")
    rows = _rows(tmp_path / "mined" / inp.input_id / "samples.csv")
    video_rows = [r for r in rows if r["media"].startswith("crops/camera_image/")]
    audio_rows = [r for r in rows if r["media"].startswith("audio/audio_raw/")]
    assert video_rows and audio_rows

    ref = run_input(parse_input(f"{clip}@0:8"), FAST, tmp_path / "ref")
    ref_rows = _rows(tmp_path / "ref" / ref["id"] / "samples.csv")
    key = lambda r: (r["frame"], r["track"])  # noqa: E731
    assert sorted(map(key, video_rows)) == sorted(map(key, ref_rows))
    for a, b in zip(sorted(video_rows, key=key), sorted(ref_rows, key=key), strict=True):
        assert float(a["probability"]) == pytest.approx(float(b["probability"]), abs=1e-4)
    rec = run_input(parse_input(inputs["rec"]), FAST, tmp_path / "ref")
    rec_rows = _rows(tmp_path / "ref" / rec["id"] / "samples.csv")
    assert sorted(r["frame"] for r in audio_rows) == sorted(r["frame"] for r in rec_rows)

    audio_only = tmp_path / "audio_only.mcap"
    make_test_log(audio_only, recording=inputs["rec"], audio_topic="/mic")
    record = run_input(parse_input(audio_only), FAST, tmp_path / "mined")
    assert record["status"] == "done" and record["samples"] == len(rec_rows)
