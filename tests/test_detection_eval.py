"""Detection metrics (hand-computed cases) and ``makeway evaluate-detector`` on real images of
``ambulance_yolo`` (issue 24, item 4)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from conftest import yolo_subset
from makeway.apps.evaluate_detector import HELD_OUT_FILE, BoxJudgements, held_out_by_hash, score_judgements
from makeway.cli.main import app
from makeway.eval.detection import (
    COCO_IOU_THRESHOLDS,
    average_precision,
    box_iou_matrix,
    detection_metrics,
    match_detections,
    precision_recall,
)
from makeway.sense.crops import read_holdout, read_yolo_set, roboflow_source

runner = CliRunner()


def _b(*rows: list[float]) -> np.ndarray:
    return np.asarray(rows, dtype=np.float64).reshape(-1, 4)


# ------------------------------------------------------------------------------------------- metrics


def test_iou_of_overlapping_squares() -> None:
    # 2×2 squares offset by (1, 1): intersection 1, union 4 + 4 - 1 = 7
    iou = box_iou_matrix(_b([0, 0, 2, 2]), _b([1, 1, 3, 3], [5, 5, 6, 6], [0, 0, 2, 2]))
    np.testing.assert_allclose(iou, [[1 / 7, 0.0, 1.0]])


def test_ap_of_a_ranked_list_is_the_area_under_the_precision_envelope() -> None:
    # two ground-truth boxes; ranked detections hit, miss, hit: precision 1, 1/2, 2/3 at recall
    # 1/2, 1/2, 1. The envelope is 1 up to recall 1/2 and 2/3 beyond: AP = 1/2 + 1/2 · 2/3 = 5/6.
    gt = [_b([0, 0, 10, 10], [20, 0, 30, 10])]
    dets = [_b([0, 0, 10, 10], [50, 50, 60, 60], [20, 0, 30, 10])]
    scores = [np.array([0.9, 0.8, 0.7])]
    m = detection_metrics(dets, scores, gt)
    assert m.map50 == pytest.approx(5 / 6)
    assert m.n_boxes == 2 and m.n_detections == 3 and m.n_images == 1
    # AP depends on the ranking only, not on the score values
    m2 = detection_metrics(dets, [np.array([0.3, 0.2, 0.1])], gt)
    assert m2.map50 == pytest.approx(5 / 6)
    # the miss ranked last instead: precision 1 all the way to recall 1
    assert detection_metrics(dets, [np.array([0.9, 0.1, 0.7])], gt).map50 == pytest.approx(1.0)
    # direct: the same list as true-positive flags
    assert average_precision(np.array([True, False, True]), 2) == pytest.approx(5 / 6)
    assert average_precision(np.array([False, True]), 1) == pytest.approx(0.5)
    assert average_precision(np.zeros(0, dtype=bool), 3) == 0.0
    assert np.isnan(average_precision(np.array([False]), 0))


def test_each_ground_truth_box_is_matched_once() -> None:
    gt = [_b([0, 0, 10, 10])]
    dets = [_b([0, 0, 10, 10], [0, 0, 10, 10])]
    p, r, tp, n_det, n_gt = precision_recall(dets, [np.array([0.9, 0.8])], gt)
    assert (p, r, tp, n_det, n_gt) == (0.5, 1.0, 1, 2, 1)


def test_matching_takes_detections_by_score_and_the_best_free_box() -> None:
    # A = [0,0,10,10], B = [4,0,14,10]. d1 (0.9) sits on A (IoU 1). d2 (0.8) = [1,0,11,10] overlaps A
    # most (IoU 90/110 = 0.818) but A is taken; with B its IoU is 70/130 = 0.538: a match at 0.5
    # (COCO's rule: the best box still free), none at 0.55.
    gt = [_b([0, 0, 10, 10], [4, 0, 14, 10])]
    dets = [_b([1, 0, 11, 10], [0, 0, 10, 10])]  # input order differs from score order
    scores, tp = match_detections(dets, [np.array([0.8, 0.9])], gt, (0.5, 0.55))
    np.testing.assert_array_equal(scores, [0.9, 0.8])
    np.testing.assert_array_equal(tp, [[True, True], [True, False]])
    # the other way round, d2 first takes A and d1 (IoU 90/110 with A, 60/140 with B) finds no free box
    _, tp = match_detections(dets, [np.array([0.9, 0.8])], gt, (0.5,))
    np.testing.assert_array_equal(tp, [[True, False]])


def test_map50_95_of_one_box_at_iou_081() -> None:
    # IoU 81/100 = 0.81: a hit at the 7 thresholds 0.50 … 0.80, a miss at 0.85, 0.90, 0.95
    m = detection_metrics([_b([0, 0, 10, 8.1])], [np.array([0.5])], [_b([0, 0, 10, 10])])
    assert len(COCO_IOU_THRESHOLDS) == 10 and COCO_IOU_THRESHOLDS[-1] == 0.95
    assert m.map50 == pytest.approx(1.0)
    assert m.map50_95 == pytest.approx(0.7)


def test_classes_without_ground_truth_leave_the_mean() -> None:
    # class 0 found perfectly (AP 1); class 2 detected where it is not (AP 0); class 1 only detected,
    # never labelled (no AP): mAP50 = (1 + 0) / 2
    gt = [_b([0, 0, 10, 10], [20, 20, 30, 30])]
    gt_cls = [np.array([0, 2])]
    dets = [_b([0, 0, 10, 10], [50, 50, 60, 60], [70, 70, 80, 80])]
    det_cls = [np.array([0, 1, 2])]
    m = detection_metrics(dets, [np.array([0.9, 0.8, 0.7])], gt, pred_classes=det_cls, gt_classes=gt_cls)
    assert m.ap50[0] == 1.0 and m.ap50[2] == 0.0 and np.isnan(m.ap50[1])
    assert m.map50 == pytest.approx(0.5)


def test_precision_recall_at_a_score_threshold_across_images() -> None:
    # image 1: a hit (0.9) and a miss (0.4); image 2: a hit (0.6), and a box nobody found
    gt = [_b([0, 0, 10, 10]), _b([0, 0, 10, 10], [40, 40, 50, 50])]
    dets = [_b([0, 0, 10, 10], [20, 20, 30, 30]), _b([0, 0, 10, 10])]
    scores = [np.array([0.9, 0.4]), np.array([0.6])]
    assert precision_recall(dets, scores, gt, score_threshold=0.5)[:2] == (1.0, pytest.approx(2 / 3))
    assert precision_recall(dets, scores, gt)[:2] == (pytest.approx(2 / 3), pytest.approx(2 / 3))
    p, r, *_ = precision_recall(dets, scores, gt, score_threshold=0.95)
    assert np.isnan(p) and r == 0.0


def test_framework_b_scores_rank_by_product_and_operate_on_the_classifier() -> None:
    # the ambulance A: detector 0.9, P(EV) 0.6; a car B: detector 0.2, P(EV) 0.9; a bus C: P(EV) 0.3.
    # Ranked by product (0.54, 0.18, 0.24) A comes first: AP 1. Ranked by P(EV) alone B comes first:
    # precision 1/2 at recall 1, AP 0.5. At the threshold 0.5, A and B are EV detections: P 1/2, R 1.
    judged = [
        BoxJudgements(
            boxes=_b([0, 0, 100, 80], [200, 0, 300, 80], [400, 0, 500, 80]),
            det_scores=np.array([0.9, 0.2, 0.8]),
            probs=np.array([0.6, 0.9, 0.3]),
            gt=_b([0, 0, 100, 80]),
            seconds=0.01,
        )
    ]
    product = score_judgements(judged, 0.5, "product")
    alone = score_judgements(judged, 0.5, "classifier")
    assert product["map50"] == pytest.approx(1.0) and alone["map50"] == pytest.approx(0.5)
    for out in (product, alone):
        assert out["precision"] == 0.5 and out["recall"] == 1.0 and out["n_detections"] == 2


# --------------------------------------------------------------------------------------------- split


def test_committed_held_out_file_follows_the_hash_rule(ambulance_dir: Path) -> None:
    names = sorted(p.name for p in (ambulance_dir / "images").iterdir())
    committed = read_holdout(HELD_OUT_FILE)
    assert list(committed.names) == [n for n in names if held_out_by_hash(Path(n).stem)]
    assert 0.15 < len(committed.names) / len(names) < 0.3
    held = {roboflow_source(Path(n).stem) for n in committed.names}
    rest = {roboflow_source(Path(n).stem) for n in names if n not in set(committed.names)}
    assert not held & rest, "copies of one source photo on both sides"


# ----------------------------------------------------------------------------------------------- CLI


# three photos with one large, clearly visible labelled ambulance each (checked by eye; the third
# also shows parked cars)
STEMS = [
    "0009_jpg.rf.57b34231535de22443800ce18496f706",
    "0022_jpg.rf.cb893467345630b42489d08eb5623329",
    "0024_jpg.rf.2ff4c9029ae75191110dabd1c0158339",
]


def test_evaluate_detector_on_real_images(ambulance_dir: Path, tmp_path: Path) -> None:
    folder = yolo_subset(ambulance_dir, tmp_path / "set", STEMS)
    n_boxes = sum(len(im.boxes_of(0)) for im in read_yolo_set(folder))
    r = runner.invoke(app, ["evaluate-detector", "--data", str(folder), "--classifier", "fast"])
    assert r.exit_code == 0, r.output
    out = json.loads(r.stdout.strip().splitlines()[-1])
    for key in ("map50", "map50_95", "precision", "recall", "n_images", "n_boxes", "ms_per_image"):
        assert key in out, key
    assert out["framework"] == "b" and out["classifier"] == "fast"
    assert out["n_images"] == len(STEMS) and out["n_boxes"] == n_boxes
    # the ambulances are large and clear: found and ranked first (boxes in the wrong frame or scale
    # would score 0)
    assert out["map50"] >= 0.9 and out["recall"] >= 2 / 3
    assert out["map50_95"] <= out["map50"]
    assert out["ms_per_image"] > 0


def test_bad_input_is_one_line_naming_the_file(ambulance_dir: Path, tmp_path: Path) -> None:
    missing = tmp_path / "nowhere"
    r = runner.invoke(app, ["evaluate-detector", "--data", str(missing)])
    assert r.exit_code == 2 and str(missing) in r.stderr and len(r.stderr.strip().splitlines()) == 1

    folder = yolo_subset(ambulance_dir, tmp_path / "bad", STEMS[:1])
    label = folder / "labels" / f"{STEMS[0]}.txt"
    label.write_text(label.read_text().rstrip("\n") + "\n0 0.5 0.5 0.2\n")  # 4 fields on line 2
    r = runner.invoke(app, ["evaluate-detector", "--data", str(folder), "--classifier", "fast"])
    assert r.exit_code == 2, r.output
    assert label.name in r.stderr and "line 2" in r.stderr and len(r.stderr.strip().splitlines()) == 1

    # the held-out split belongs to ambulance_yolo/valid, not to a folder of two of its images
    folder = yolo_subset(ambulance_dir, tmp_path / "two", STEMS)
    r = runner.invoke(
        app, ["evaluate-detector", "--data", str(folder), "--split", "held_out", "--classifier", "fast"]
    )
    assert r.exit_code == 2 and "--split all" in r.stderr, r.output
