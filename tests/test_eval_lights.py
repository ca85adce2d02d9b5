"""Seed 004's lit-light metrics on hand-made cases: one-to-one matching and the vehicle level."""

from __future__ import annotations

import math

import numpy as np
import pytest

from makeway.eval.lights import FrameResult, match_frame, metrics, summarise, vehicle_counts

GT = np.array([[100, 100, 110, 110], [120, 100, 130, 110], [400, 300, 420, 310]], np.float64)
VEH = [1, 1, 2]  # two lamps of vehicle 1, one of vehicle 2


def test_each_ground_truth_is_matched_once_best_score_first() -> None:
    dets = np.array([[100, 100, 110, 110], [101, 100, 111, 110], [120, 100, 130, 110]], np.float64)
    m = match_frame(dets, [0.5, 0.9, 0.7], GT)
    # the 0.9 detection (IoU 0.82) takes GT 0 first; the exact 0.5 one finds it taken: a false positive
    assert m.tolist() == [-1, 0, 1]
    assert match_frame(np.zeros((0, 4)), [], GT).tolist() == []
    assert match_frame(dets, [1, 1, 1], np.zeros((0, 4))).tolist() == [-1, -1, -1]
    # IoU just under 0.5 does not match
    assert match_frame([[100, 100, 110, 105 - 0.1]], [1.0], GT[:1]).tolist() == [-1]


def test_a_vehicle_is_found_by_one_of_its_lamps_and_stray_lamps_on_it_are_not_false() -> None:
    dets = np.array([[100, 100, 110, 110], [112, 100, 118, 110]], np.float64)  # lamp + a glow between
    found, false, n = vehicle_counts(dets, [0.9, 0.8], GT, VEH)
    assert (found, false, n) == (1, 0, 2)


def test_far_unmatched_detections_group_into_false_vehicles() -> None:
    # two nearby boxes far from every vehicle → one false vehicle; another far away → a second
    dets = np.array([[10, 10, 16, 16], [20, 10, 26, 16], [600, 10, 606, 16]], np.float64)
    assert vehicle_counts(dets, [1, 1, 1], GT, VEH) == (0, 2, 2)
    assert vehicle_counts(dets, [1, 1, 1], np.zeros((0, 4)), []) == (0, 2, 0)


def test_metrics_pool_frames_and_negative_frames_add_false_positives() -> None:
    pos = FrameResult("clip", "0", GT, VEH, GT[:2].copy(), np.array([0.9, 0.8]), 5.0)
    neg = FrameResult("clip", "1", np.zeros((0, 4)), [], np.array([[10, 10, 20, 20.0]]), np.array([0.6]), 7.0)
    m = metrics([pos, neg])
    assert (m.tp, m.detections, m.gt_boxes) == (2, 3, 3)
    assert m.array_precision == pytest.approx(2 / 3) and m.array_recall == pytest.approx(2 / 3)
    assert (m.found_vehicles, m.false_vehicles, m.gt_vehicles) == (1, 1, 2)
    assert m.vehicle_precision == pytest.approx(0.5) and m.vehicle_recall == pytest.approx(0.5)
    assert (m.negative_frames, m.fp_frames) == (1, 1)
    assert m.ms_mean == pytest.approx(6.0)
    # mAP: ranking 0.9 TP, 0.8 TP, 0.6 FP against 3 GT → AP50 = 2/3
    assert m.map50 == pytest.approx(2 / 3)
    # a score threshold above the false positive removes it from P/R but not from mAP's ranking
    m2 = metrics([pos, neg], score_threshold=0.7)
    assert m2.array_precision == 1.0 and m2.fp_frames == 0 and m2.map50 == pytest.approx(2 / 3)


def test_summary_per_source_and_worst_is_json_safe() -> None:
    a = FrameResult("night", "0", GT, VEH, GT.copy(), np.ones(3), 1.0)
    b = FrameResult("day", "0", GT, VEH, GT[:1].copy(), np.ones(1), 3.0)
    c = FrameResult("empty", "0", np.zeros((0, 4)), [], np.zeros((0, 4)), np.zeros(0), 2.0)
    s = summarise([a, b, c])
    assert s["night"]["array_recall"] == 1.0 and s["day"]["array_recall"] == pytest.approx(1 / 3)
    assert s["empty"]["array_precision"] is None  # undefined, not NaN
    assert s["worst"]["array_recall"] == pytest.approx(1 / 3)
    assert s["worst"]["worst_source"]["array_recall"] == "day"
    assert s["worst"]["ms_mean"] == 3.0
    assert all(not (isinstance(v, float) and math.isnan(v)) for v in s["all"].values())
