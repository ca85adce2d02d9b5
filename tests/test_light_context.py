"""Vehicle-box context of lit-light proposals (``context_features``): constructed boxes with known
answers, and one real night frame through YOLOX-nano and the verified detector."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from conftest import require_module
from makeway.perceive.vision.light_verify import (
    CONTEXT_FEATURE_NAMES,
    FEATURE_NAMES,
    LightVerifier,
    VerifiedLightDetector,
    context_features,
    proposals,
    vehicle_detector,
)
from makeway.train.light_labels import iter_label_frames, read_labels
from makeway.train.light_split import LABEL_DIR

COL = {n: i for i, n in enumerate(CONTEXT_FEATURE_NAMES)}
CAR, TRUCK = 2, 7


def _veh(*boxes: tuple[float, float, float, float, float, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    arr = np.array(boxes, np.float64).reshape(-1, 6)
    return arr[:, :4], arr[:, 4], arr[:, 5].astype(np.int64)


def test_place_in_the_vehicle_box() -> None:
    # one car 200 × 100 px; a blue lamp on the roof centre, a red one at the lower left corner, a
    # red one level with the blue one, and a lamp far outside the car
    veh = _veh((100, 100, 300, 200, 0.9, CAR))
    boxes = np.array([[195, 105, 205, 111], [110, 180, 120, 190], [230, 104, 240, 112], [500, 500, 510, 510]])
    colours = ["blue", "red", "red", "amber"]
    f = context_features(boxes, colours, veh)
    assert f.shape == (4, len(CONTEXT_FEATURE_NAMES)) and f.dtype == np.float32
    roof, tail, level, far = f
    assert roof[COL["veh_any"]] == 1 and roof[COL["veh_inside"]] == 1 and roof[COL["veh_n_inside"]] == 1
    assert roof[COL["veh_y"]] == pytest.approx(0.08) and roof[COL["veh_x"]] == pytest.approx(0.5)
    assert roof[COL["veh_xc"]] == pytest.approx(0.0, abs=1e-6)
    assert tail[COL["veh_y"]] == pytest.approx(0.85) and tail[COL["veh_xc"]] == pytest.approx(0.85)
    assert roof[COL["veh_log_w"]] == pytest.approx(math.log(200 / 10))
    assert roof[COL["veh_log_h"]] == pytest.approx(math.log(100 / 6))
    assert roof[COL["veh_aspect"]] == pytest.approx(math.log(2.0))
    assert roof[COL["veh_score"]] == pytest.approx(0.9) and roof[COL["veh_car"]] == 1
    assert roof[COL["veh_truck"]] == 0 and roof[COL["veh_dist"]] == 0
    # three proposals share the car: one blue, two red; red and blue both there
    assert roof[COL["share_log_n"]] == pytest.approx(math.log(4.0))
    assert roof[COL["share_blue"]] == pytest.approx(1 / 3) and roof[COL["share_red"]] == pytest.approx(2 / 3)
    assert roof[COL["share_red_blue"]] == 1
    # the blue roof lamp has a red partner at its height; the low red one has none (the blue is high)
    assert roof[COL["share_partner"]] == 1 and level[COL["share_partner"]] == 1
    assert tail[COL["share_partner"]] == 0
    # far outside: its distance in car heights, no share
    assert far[COL["veh_inside"]] == 0
    gap = math.hypot(505 - 300, 505 - 200) / 100
    assert far[COL["veh_dist"]] == pytest.approx(gap, rel=1e-5)
    assert far[COL["share_log_n"]] == 0 and far[COL["share_red_blue"]] == 0
    assert far[COL["veh_y"]] == pytest.approx(4.05)


def test_smallest_box_hosts_and_lamps_above_a_box() -> None:
    # a truck box holding a car box: a lamp in both belongs to the car; a lamp just above the car
    # (outside every box) is described against the nearest box, with a negative height
    veh = _veh((0, 0, 1000, 1000, 0.5, TRUCK), (400, 500, 600, 600, 0.8, CAR))
    boxes = np.array([[490, 510, 500, 520], [495, 1010, 505, 1020]])
    f = context_features(boxes, ["blue", "blue"], veh)
    assert f[0, COL["veh_n_inside"]] == 2 and f[0, COL["veh_car"]] == 1
    assert f[0, COL["veh_y"]] == pytest.approx(0.15)
    above = context_features(np.array([[495, 480, 505, 490]]), ["blue"], _veh((400, 500, 600, 600, 0.8, CAR)))
    assert above[0, COL["veh_inside"]] == 0 and above[0, COL["veh_y"]] == pytest.approx(-0.15)
    assert above[0, COL["veh_dist"]] == pytest.approx(0.15)


def test_no_vehicle_and_peers() -> None:
    boxes = np.array([[10, 10, 20, 20]])
    for veh in (None, _veh()):
        f = context_features(boxes, ["red"], veh)
        assert f[0, COL["veh_any"]] == 0 and f[0, COL["veh_dist"]] == 10 and f[0, COL["veh_inside"]] == 0
    assert context_features(np.zeros((0, 4)), [], _veh((0, 0, 5, 5, 1, CAR))).shape == (0, len(COL))
    # a labelled box described among other proposals (the peers), not among itself
    veh = _veh((0, 0, 100, 100, 0.7, CAR))
    peers = np.array([[10, 10, 14, 14], [60, 12, 64, 16], [40, 80, 44, 84]])
    f = context_features(boxes, ["blue"], veh, peer_boxes=peers, peer_colours=["red", "red", "white"])
    assert f[0, COL["share_log_n"]] == pytest.approx(math.log(4.0))
    assert f[0, COL["share_white"]] == pytest.approx(1 / 3) and f[0, COL["share_red_blue"]] == 0
    assert f[0, COL["share_partner"]] == 1
    with pytest.raises(ValueError, match="one colour per box"):
        context_features(boxes, ["blue"], veh, peer_boxes=peers, peer_colours=["red"])


@pytest.fixture(scope="module")
def night_frame(data_root: Path) -> tuple[np.ndarray, list]:
    """The first checked night-clip frame with at least 3 labelled lamps, and its label rows."""
    lf = read_labels(LABEL_DIR / "night_ambulance_lights.csv")
    frames = lf.frames()
    key = next(
        k for k, rows in frames.items() if rows[0].checked and sum(r.kind == "light" for r in rows) >= 3
    )
    _, img = next(iter(iter_label_frames(lf, data_root, keys=[key])))
    return img, frames[key]


def test_real_night_frame(night_frame) -> None:
    """One labelled frame of the night clip: YOLOX-nano finds the ambulance, the labelled lamps lie
    in or just above a vehicle box, and every context value is finite."""
    img, rows = night_frame
    veh = vehicle_detector(1).detect_arrays(img)
    assert len(veh[0]) >= 1
    gt = np.array([r.box for r in rows if r.kind == "light" and r.box], np.float64)
    props = proposals(img)
    pb = np.array([p["box"] for p in props], np.float64)
    f = context_features(
        gt, ["blue"] * len(gt), veh, peer_boxes=pb, peer_colours=[p["colour"] for p in props]
    )
    assert np.isfinite(f).all() and f.shape == (len(gt), len(CONTEXT_FEATURE_NAMES))
    near = (f[:, COL["veh_inside"]] == 1) | (f[:, COL["veh_dist"]] < 0.5)
    assert near.mean() >= 0.5, f[:, [COL["veh_inside"], COL["veh_dist"], COL["veh_y"]]]
    assert len(FEATURE_NAMES) + len(CONTEXT_FEATURE_NAMES) == 200


def test_context_model_reads_given_or_own_vehicle_boxes(night_frame, tmp_path: Path) -> None:
    """A verifier exported with the context columns says so (``uses_vehicles``); the detector gives
    the same lights whether the caller hands it the frame's vehicle boxes or it finds them itself,
    and other boxes change its scores; a model without them ignores what it is given."""
    require_module("xgboost")
    from makeway.train.light_verifier import _export, fit_verifier

    img, _ = night_frame
    rng = np.random.default_rng(0)
    width = len(FEATURE_NAMES) + len(CONTEXT_FEATURE_NAMES)
    x = rng.normal(size=(400, width)).astype(np.float32)
    y = x[:, len(FEATURE_NAMES) + COL["veh_y"]] < 0.3  # "lit" = high in a vehicle box
    path = tmp_path / "ctx.onnx"
    _export(fit_verifier(x, y, threads=1), path, {"threshold": "0.5"})
    assert LightVerifier(path).uses_vehicles
    det = VerifiedLightDetector("all", model=path, threshold=0.0)
    assert det.uses_vehicles
    own = det.detect(img, 5)
    given = det.detect(img, 5, vehicles=vehicle_detector(1).detect_arrays(img))
    assert own and [(d.box, d.score) for d in own] == [(d.box, d.score) for d in given]
    nowhere = det.detect(img, 5, vehicles=(np.zeros((0, 4)), np.zeros(0), np.zeros(0, np.int64)))
    assert sorted(d.score for d in nowhere) != sorted(d.score for d in own)
    plain = tmp_path / "plain.onnx"
    _export(fit_verifier(x[:, : len(FEATURE_NAMES)], y, threads=1), plain, {"threshold": "0.5"})
    det_plain = VerifiedLightDetector("all", model=plain, threshold=0.0)
    assert not det_plain.uses_vehicles
    a = det_plain.detect(img, 1)
    b = det_plain.detect(img, 1, vehicles=(np.zeros((0, 4)), np.zeros(0), np.zeros(0, np.int64)))
    assert [(d.box, d.score) for d in a] == [(d.box, d.score) for d in b]


def test_video_pipeline_hands_its_vehicle_boxes_to_the_light_detector(
    data_root: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``makeway detect``'s pipeline with the ``verified`` light detector: the shipped verifier reads
    the vehicle context and gets the boxes the pipeline already found — its own vehicle pass never
    runs — and lights are still found on the night clip."""
    from makeway.pipeline.video import run_video

    def own_pass(self: VerifiedLightDetector, frame_bgr: np.ndarray) -> None:
        raise AssertionError("the light detector ran a second vehicle detector")

    monkeypatch.setattr(VerifiedLightDetector, "vehicles", own_pass)
    detect = VerifiedLightDetector.detect
    given: list[bool] = []
    found: list[int] = []

    def recorded(
        self: VerifiedLightDetector, frame_bgr: np.ndarray, frame: int = 0, *, vehicles: Any = None
    ) -> list[Any]:
        given.append(vehicles is not None and len(vehicles[0]) > 0)
        out = detect(self, frame_bgr, frame, vehicles=vehicles)
        found.append(len(out))
        return out

    monkeypatch.setattr(VerifiedLightDetector, "detect", recorded)
    s = run_video(
        data_root / "video" / "night_ambulance_lights.mp4",
        None,
        max_frames=4,
        write_video=False,
        progress=False,
        rule="lights",
        light_detector="verified",
        light_colours="us",
        detector_workers=1,
    )
    assert s.frames == 4 and len(given) == 4 and all(given) and sum(found) > 0


def test_context_detector_fails_at_construction_without_vehicle_weights(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The shipped verifier reads the vehicle context; with no YOLOX-nano weights anywhere it is
    refused when built (one error naming the file), not on the first frame — and building it does not
    load a vehicle detector (a pipeline hands it its own boxes)."""
    from makeway.errors import InputError
    from makeway.perceive.vision import detectors

    det = VerifiedLightDetector("eu")
    assert det.uses_vehicles and det._vehicle_detector is None
    monkeypatch.setattr(detectors, "models_candidates", lambda: [tmp_path])
    with pytest.raises(InputError, match=r"yolox_nano\.onnx"):
        VerifiedLightDetector("eu")
