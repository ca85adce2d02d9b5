"""Pixel → road for a roadside camera (issue 27 item 1), on the simulated traffic camera whose
geometry and vehicle positions are known, and the WGS-84 ↔ ENU conversion against published values."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from makeway.cli.main import app
from makeway.errors import InputError
from makeway.roadside.geodesy import LocalFrame
from makeway.roadside.reference import LocationReference, kfold_errors, read_pairs, write_pairs
from makeway.roadside.simulated import SIM_ORIGIN, sim_observations, sim_pairs, sim_road_camera
from makeway.roadside.transform import (
    box_ground_pixel,
    read_transform_calibration,
    typical_length_m,
    write_transform_calibration,
)
from makeway.sim.traffic import TrafficConfig

runner = CliRunner()


# ------------------------------------------------------------------------------------------ geodesy
def test_enu_matches_published_lengths_of_a_degree() -> None:
    # Lengths of a degree on WGS-84: at the equator a degree of longitude is a·π/180 = 111 319.491 m;
    # at 45° the standard series give 111 131.779 m of latitude and 78 846.806 m of longitude (series
    # good to ~3 cm per degree). 0.001° is short enough that chord and arc agree to micrometres.
    assert LocalFrame(0.0, 0.0).to_enu(0.0, 0.001)[0] == pytest.approx(111.319491, abs=2e-6)
    north = LocalFrame(45.0, 7.0).to_enu(45.001, 7.0)
    east = LocalFrame(45.0, 7.0).to_enu(45.0, 7.001)
    assert north[1] == pytest.approx(111.131779, abs=2e-5) and abs(north[0]) < 1e-6
    assert east[0] == pytest.approx(78.846806, abs=5e-5)


def test_enu_round_trip() -> None:
    frame = LocalFrame(30.628, -96.4818, 50.0)
    lat, lon, h = frame.to_geodetic(frame.to_enu([30.63, 30.61], [-96.49, -96.47], [60.0, 40.0]))
    np.testing.assert_allclose(lat, [30.63, 30.61], atol=1e-10)
    np.testing.assert_allclose(lon, [-96.49, -96.47], atol=1e-10)
    np.testing.assert_allclose(h, [60.0, 40.0], atol=1e-4)


# ------------------------------------------------------------------------------ transformation-based
def test_back_projection_inverts_the_simulators_projection() -> None:
    """A road point projected by the simulator's own camera comes back to itself."""
    from makeway.sim.traffic import Camera

    sim = Camera.from_config(TrafficConfig())
    pts = np.array([[-5.25, 25.0, 0.0], [1.75, 60.0, 0.0], [5.25, 100.0, 0.0], [-1.75, 180.0, 0.0]])
    pixels, _ = sim.project(pts)
    np.testing.assert_allclose(sim_road_camera().locate(pixels), pts[:, :2], atol=1e-6)


def test_bottom_centre_beats_the_box_centre_on_simulated_vehicles() -> None:
    """Seed 001's tall-object bias: the box centre lies above the road and lands beyond the vehicle."""
    cam = sim_road_camera()
    obs = sim_observations(TrafficConfig(seed=1))
    assert len(obs.boxes) > 500
    err = {
        p: np.linalg.norm(cam.locate(box_ground_pixel(obs.boxes, p)) - obs.truth_xy, axis=1)
        for p in ("bottom_centre", "centre")
    }
    # the bottom edge is the footprint's near edge: about half a car length (2.25 m) short
    assert 1.5 < np.median(err["bottom_centre"]) < 3.5
    assert np.median(err["centre"]) > 1.8 * np.median(err["bottom_centre"])
    # the centre overshoots (lands farther from the pole), the bottom centre falls short
    rng = {p: np.hypot(*(cam.locate(box_ground_pixel(obs.boxes, p)) - cam.position_m[:2]).T) for p in err}
    assert np.median(rng["centre"] - obs.range_m) > 2.0 and np.median(rng["bottom_centre"] - obs.range_m) < 0
    # aiming half a car length behind the near edge recovers the cars' centres
    cars = obs.kind == "car"
    aimed = np.linalg.norm(cam.locate(box_ground_pixel(obs.boxes[cars]), 2.25) - obs.truth_xy[cars], axis=1)
    assert np.median(aimed) < 0.7


# -------------------------------------------------------------------------------- location reference
def test_location_reference_reaches_half_a_metre_on_cars(tmp_path: Path) -> None:
    pixels, xy = sim_pairs()
    pairs = tmp_path / "pairs.csv"
    write_pairs(pairs, pixels, xy, SIM_ORIGIN)
    read = read_pairs(pairs)  # through lat/lon and back
    np.testing.assert_allclose(read.xy, xy, atol=1e-3)
    ref = LocationReference(read.pixels, read.xy, read.origin)
    obs = sim_observations(TrafficConfig(seed=1))
    cars = obs.select(obs.kind == "car")
    px = box_ground_pixel(cars.boxes)
    inside = ref.inside(px)
    err = np.linalg.norm(ref.locate(px) - cars.truth_xy, axis=1)
    assert inside.mean() > 0.7
    assert np.median(err[inside]) <= 0.5
    # the k-fold held-out error predicts the error on new scenes within a factor of two
    held = kfold_errors(read.pixels, read.xy)
    assert 0.5 * np.median(err[inside]) < np.median(held) < 2.0 * np.median(err[inside])


# ----------------------------------------------------------------------------------- files and CLI
def _yaml(tmp_path: Path) -> Path:
    path = tmp_path / "cam.yaml"
    write_transform_calibration(sim_road_camera(), path)
    return path


def test_calibration_file_round_trip(tmp_path: Path) -> None:
    cam = read_transform_calibration(_yaml(tmp_path))
    assert cam.origin == SIM_ORIGIN
    np.testing.assert_allclose(cam.rotation, sim_road_camera().rotation)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda t: t + "skew: 0\n", "unknown field(s) skew"),
        (lambda t: t.replace("position_m:", "position:"), "missing field(s) position_m"),
        (lambda t: t.replace("- - 0.98", "- - 1.2", 1), "not orthonormal"),
        (lambda t: "model: [", "not valid YAML"),
    ],
)
def test_bad_calibration_is_one_line_exit_2(tmp_path: Path, edit: object, message: str) -> None:
    path = _yaml(tmp_path)
    text = path.read_text()
    assert "- - 0.98" in text  # the rotation's first entry (cos 10°), which the orthonormal case edits
    path.write_text(edit(text))  # type: ignore[operator]
    with pytest.raises(InputError, match=re.escape(str(path))):
        read_transform_calibration(path)
    result = runner.invoke(app, ["roadside", "calibrate-transform", str(path), "--check"])
    assert result.exit_code == 2
    assert message in result.output and result.output.count("\n") == 1


def _pairs_file(tmp_path: Path, n: int, collinear: bool = False) -> Path:
    pixels, xy = sim_pairs()
    pixels, xy = pixels[:n].copy(), xy[:n].copy()
    if collinear:
        pixels[:, 1] = 2.0 * pixels[:, 0] + 7.0
    path = tmp_path / "pairs.csv"
    write_pairs(path, pixels, xy, SIM_ORIGIN)
    return path


@pytest.mark.parametrize(("n", "collinear", "message"), [(8, False, "at least 10"), (40, True, "one line")])
def test_bad_pairs_are_one_line_exit_2_and_write_nothing(
    tmp_path: Path, n: int, collinear: bool, message: str
) -> None:
    pairs = _pairs_file(tmp_path, n, collinear)
    out = tmp_path / "ref.npz"
    result = runner.invoke(app, ["roadside", "fit-reference", str(pairs), "--out", str(out)])
    assert result.exit_code == 2 and message in result.output and str(pairs) in result.output
    assert result.output.count("\n") == 1 and not out.exists()


def test_cli_fit_and_locate_both_methods(tmp_path: Path) -> None:
    pairs = _pairs_file(tmp_path, 1000)
    ref = tmp_path / "ref.npz"
    fit = runner.invoke(app, ["roadside", "fit-reference", str(pairs), "--out", str(ref)])
    assert fit.exit_code == 0, fit.output
    summary = json.loads(fit.output)
    assert summary["pairs"] > 100 and 0 < summary["heldout_median_m"] < 0.5
    # a car 60 m up the approaching inner lane: its box from the simulator's geometry
    from makeway.sim.traffic import VEHICLE_KINDS, Camera, _corners

    sim = Camera.from_config(TrafficConfig())
    corners, _ = sim.project(_corners(-1.75, 60.0, VEHICLE_KINDS["car"]))
    box = [*corners.min(axis=0), *corners.max(axis=0)]
    boxes = tmp_path / "boxes.csv"
    boxes.write_text("x1,y1,x2,y2\n" + ",".join(f"{v:.2f}" for v in box) + "\n")
    for calib, tol in ((_yaml(tmp_path), 3.0), (ref, 0.6)):
        res = runner.invoke(app, ["roadside", "locate", str(calib), "--pixels", str(boxes)])
        assert res.exit_code == 0, res.output
        row = json.loads(res.output)
        assert math.hypot(row["x_m"] + 1.75, row["y_m"] - 60.0) < tol, row
        lat, lon, _ = SIM_ORIGIN.to_geodetic([row["x_m"], row["y_m"]])
        assert row["lat"] == pytest.approx(float(lat), abs=1e-9) and row["lon"] == pytest.approx(float(lon))


def test_class_length_places_long_vehicles_at_their_centre(tmp_path: Path) -> None:
    """Trucks and buses are longer than the probe car: their centre lies farther beyond the box's
    bottom edge. Their typical length moves both methods' points there (truth: footprint centres)."""
    from makeway.sim.traffic import EV_KINDS, VEHICLE_KINDS

    pixels, xy = sim_pairs()
    ref = LocationReference(pixels, xy, SIM_ORIGIN)
    cam = sim_road_camera()
    obs = sim_observations(TrafficConfig(seed=2))
    long_ = obs.select(np.isin(obs.kind, ["truck", "bus"]))
    labels = [(VEHICLE_KINDS.get(k) or EV_KINDS[k]).label for k in long_.kind]
    length = typical_length_m(labels)
    assert set(length) == {8.0, 12.0}
    px = box_ground_pixel(long_.boxes)
    inside = ref.inside(px)

    def median(est: np.ndarray, mask: np.ndarray | None = None) -> float:
        err = np.linalg.norm(est - long_.truth_xy, axis=1)
        return float(np.median(err if mask is None else err[mask]))

    assert median(ref.locate(px, length), inside) < 0.6 * median(ref.locate(px), inside)
    assert median(cam.locate(px, 0.5 * length)) < 0.5 * median(cam.locate(px, 2.25))
    # a vehicle the probe car's length is not moved; unknown classes count as cars
    np.testing.assert_allclose(ref.locate(px, ref.probe_length_m), ref.locate(px), atol=1e-12)
    assert typical_length_m(["bicycle", "car"]).tolist() == [4.5, 4.5]
    # the probe length travels with the saved reference
    path = tmp_path / "ref.npz"
    LocationReference(pixels, xy, SIM_ORIGIN, probe_length_m=4.0).save(path)
    from makeway.roadside.reference import load_reference

    assert load_reference(path).probe_length_m == 4.0


def test_cli_locate_reads_a_class_column(tmp_path: Path) -> None:
    boxes = tmp_path / "boxes.csv"
    boxes.write_text("x1,y1,x2,y2,class\n600,300,700,380,Truck\n600,300,700,380,car\n")
    res = runner.invoke(app, ["roadside", "locate", str(_yaml(tmp_path)), "--pixels", str(boxes)])
    assert res.exit_code == 0, res.output
    truck, car = (json.loads(line) for line in res.output.splitlines())
    assert (truck["class"], truck["length_m"], car["length_m"]) == ("truck", 8.0, 4.5)
    # same box: the truck's centre is (8 − 4.5)/2 m farther from the camera
    gap = math.hypot(truck["x_m"] - car["x_m"], truck["y_m"] - car["y_m"])
    assert gap == pytest.approx(1.75, abs=1e-6)
    bad = tmp_path / "bad.csv"
    bad.write_text("600,300,700,380,truck\n600,300,700,380\n")
    res = runner.invoke(app, ["roadside", "locate", str(_yaml(tmp_path)), "--pixels", str(bad)])
    assert res.exit_code == 2 and "line 2" in res.stderr
