"""The roadside unit (``makeway rsu``): the real clip's hand calibration, the node on a real clip
segment → signed alerts that ``makeway v2x verify`` accepts and that a car process on loopback turns
into a V2X belief, and bad inputs refused before the video is processed."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from conftest import start_car_listener
from makeway.apps.rsu import run_rsu
from makeway.cli.main import app
from makeway.errors import InputError
from makeway.roadside.calibrate import fit_road_camera, leave_one_out_errors, read_road_points
from makeway.roadside.node import camera_location
from makeway.roadside.transform import read_transform_calibration
from makeway.v2x.belief import LocalFrame
from makeway.v2x.security import SIGNED_SIZE, keygen
from makeway.v2x.transport import free_loopback_port, wait_listening

DATA = Path(__file__).resolve().parents[1] / "src" / "makeway" / "data"
POINTS = DATA / "intersection_cam_ambulance_points.csv"
CALIB = DATA / "intersection_cam_ambulance.yaml"
CLIP = "intersection_cam_ambulance.mp4"
SEGMENT_START, SEGMENT_FRAMES = 590, 60  # the ambulance pulls up beside the fallen cyclist

runner = CliRunner()


# ------------------------------------------------------------------------------------- calibration
def test_hand_calibration_holds_out_to_a_quarter_metre() -> None:
    """Every landmark, left out of the fit, is located within 0.3 m of its road coordinates (median
    under 0.2 m); the shipped calibration is the fit of the shipped points."""
    p = read_road_points(POINTS)
    assert len(p.pixels) >= 12
    cam, rms = fit_road_camera(p.pixels, p.xy, 1280, 720)
    assert rms < 3.0
    err = leave_one_out_errors(p.pixels, p.xy, 1280, 720)
    assert np.median(err) < 0.2 and err.max() < 0.3
    shipped = read_transform_calibration(CALIB)
    assert shipped.origin is not None
    assert np.abs(shipped.locate(p.pixels) - cam.locate(p.pixels)).max() < 0.01
    assert np.abs(shipped.locate(p.pixels) - p.xy).max() < 0.3


def test_calibration_is_plausible_beyond_its_landmarks() -> None:
    """Checks the fit never saw: a crossing SUV's wheel contacts (frame 127) are a compact SUV's
    wheelbase apart (2.6–3.0 m), and the camera sits a pole's height above the road."""
    cam = read_transform_calibration(CALIB)
    rear, front = cam.locate(np.array([[708.0, 514.0], [893.0, 592.0]]))
    assert 2.6 <= float(np.linalg.norm(front - rear)) <= 3.0
    assert 5.0 <= cam.position_m[2] <= 12.0


def test_points_file_errors_name_the_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("u,v,x_m,y_m\n1,2,3\n", encoding="utf-8")
    with pytest.raises(InputError, match="line 2"):
        read_road_points(bad)
    few = tmp_path / "few.csv"
    few.write_text("u,v,x_m,y_m\n1,2,3,4\n", encoding="utf-8")
    with pytest.raises(InputError, match="at least 8"):
        read_road_points(few)
    res = runner.invoke(app, ["rsu", "calibrate", str(few), "--out", str(tmp_path / "c.yaml")])
    assert res.exit_code == 2 and not (tmp_path / "c.yaml").exists()


# ---------------------------------------------------------------------------------------- the node
@pytest.fixture(scope="module")
def segment(video_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two seconds of the real clip (frames 590–649) while the ambulance, lights on, slows to a stop."""
    out = tmp_path_factory.mktemp("rsu") / "segment.mp4"
    cap = cv2.VideoCapture(str(video_dir / CLIP))
    cap.set(cv2.CAP_PROP_POS_FRAMES, SEGMENT_START)
    writer = cv2.VideoWriter(
        str(out), cv2.VideoWriter_fourcc(*"mp4v"), cap.get(cv2.CAP_PROP_FPS), (1280, 720)
    )
    for _ in range(SEGMENT_FRAMES):
        ok, frame = cap.read()
        assert ok
        writer.write(frame)
    writer.release()
    cap.release()
    return out


def test_node_alerts_verify_and_reach_a_car_process(segment: Path, tmp_path: Path) -> None:
    """The node on the real segment publishes signed alerts at 10 Hz of video time while the pipeline
    flags the ambulance; a car process listening on loopback verifies them and holds a V2X belief
    of an EV about 20 m from the road frame's origin; ``makeway v2x verify`` accepts every logged one."""
    keygen(tmp_path / "k", "rsu")
    port = free_loopback_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    wanted = 3
    car = start_car_listener(
        tmp_path / "k" / "trust",
        "rsu-test",
        endpoint,
        count=wanted,
        duration_s=60,
        ego_lat=59.4370,
        ego_lon=24.7536,
    )
    try:
        wait_listening(port, 20.0)
        summary = run_rsu(
            segment,
            CALIB,
            tmp_path / "k" / "rsu.key",
            publish=True,
            segment="rsu-test",
            connect=[endpoint],
            wait_s=10.0,
            out=tmp_path / "out",
            stride=2,
            progress=False,
        )
        out, err = car.communicate(timeout=60)
    finally:
        car.kill()
    assert summary["subscriber_found"] is True
    assert summary["alerts"] >= wanted and summary["reported_tracks"]
    assert car.returncode == 0, err
    rows = [json.loads(line) for line in out.splitlines()]
    alerts, car_summary = rows[:-1], rows[-1]["summary"]
    assert car_summary == {
        "received": wanted,
        "valid": wanted,
        "rejected": 0,
        "not_relevant": 0,
        "reasons": {},
        "dropped_unread": 0,
    }
    assert all(r["valid"] and r["lights"] and r["key"] == "makeway/v2x/segment/rsu-test" for r in alerts)
    belief = alerts[-1]["belief"]
    assert belief["detected"] and belief["source"] == "v2x" and belief["lights"]
    assert 10.0 < belief["distance_m"] < 40.0

    log = [json.loads(line) for line in (tmp_path / "out" / "alerts.jsonl").read_text().splitlines()]
    blob = (tmp_path / "out" / "alerts.bin").read_bytes()
    size = log[0]["bytes"]  # every alert carries the same unit certificate
    assert size > SIGNED_SIZE and all(r["bytes"] == size for r in log)
    assert len(blob) == len(log) * size and len(log) == summary["alerts"]
    assert [r["sequence"] for r in log] == list(range(log[0]["sequence"], log[0]["sequence"] + len(log)))
    assert np.allclose(np.diff([r["video_time_s"] for r in log]), 0.1, atol=1e-6)  # one track: 10 Hz
    for r in log:  # on the road beside the cyclist, moving (or stopped) with a stated uncertainty
        assert 0.0 < r["x_m"] < 10.0 and 10.0 < r["y_m"] < 30.0
        assert 0.0 < r["position_sigma_m"] < 2.0 and r["speed_mps"] < 15.0
    files = []
    for i in range(len(log)):
        f = tmp_path / f"alert{i:03d}.msg"
        f.write_bytes(blob[i * size : (i + 1) * size])
        files.append(str(f))
    res = runner.invoke(
        app, ["v2x", "verify", *files, "--trust", str(tmp_path / "k" / "trust"), "--max-age-s", "600"]
    )
    assert res.exit_code == 0, res.stdout
    verdicts = [json.loads(line) for line in res.stdout.splitlines()]
    assert all(v["valid"] for v in verdicts)
    for v, r in zip(verdicts, log, strict=True):  # the DENM carries the 95 % position confidence
        assert v["position_semi_major_95_m"] == pytest.approx(2.4477 * r["position_sigma_m"], abs=0.0051)
    # 1609.2's generation location is the pole camera itself, the same in every alert, not the EV
    where = camera_location(read_transform_calibration(CALIB))
    assert where is not None
    for v in verdicts:
        assert (v["generation_lat_deg"], v["generation_lon_deg"]) == (where.lat_deg, where.lon_deg)
        assert v["generation_elevation_m"] == pytest.approx(where.elevation_m, abs=0.05)
    frame = LocalFrame(where.lat_deg, where.lon_deg)
    gaps = [math.hypot(*frame.to_local(v["lat_deg"], v["lon_deg"])) for v in verdicts]
    assert min(gaps) > 5.0 and max(gaps) < 60.0


@pytest.mark.parametrize("case", ["video", "calib", "calib_no_origin", "key"])
def test_bad_inputs_are_one_line_and_exit_2_before_any_frame(
    case: str, segment: Path, tmp_path: Path
) -> None:
    keygen(tmp_path / "k", "rsu")
    video, calib, key = segment, CALIB, tmp_path / "k" / "rsu.key"
    if case == "video":
        video = tmp_path / "missing.mp4"
    elif case == "calib":
        calib = tmp_path / "bad.yaml"
        calib.write_text("model: pinhole\nwidth: [1\n", encoding="utf-8")
    elif case == "calib_no_origin":
        calib = tmp_path / "no_origin.yaml"
        doc = CALIB.read_text(encoding="utf-8").split("origin:")[0]
        calib.write_text(doc, encoding="utf-8")
    else:
        key = tmp_path / "bad.key"
        key.write_text("not a key\n", encoding="utf-8")
    out = tmp_path / "out"
    res = runner.invoke(
        app,
        [
            "rsu",
            "run",
            str(video),
            "--calib",
            str(calib),
            "--key",
            str(key),
            "--no-publish",
            "--out",
            str(out),
        ],
    )
    assert res.exit_code == 2
    assert len(res.output.strip().splitlines()) == 1
    assert not out.exists()
