"""Choosing the verifier's operating threshold by grouped cross-validation over the training sources:
photo copies and clips stay in one fold, out-of-fold scores come from models that never saw the
group, and the threshold maximises min(precision, recall) of the full detector."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import require_module
from makeway.eval.lights import FrameResult
from makeway.train.light_split import LightFrame
from makeway.train.light_verifier import (
    THRESHOLDS,
    choose_threshold,
    detector_results,
    frame_group,
    grouped_folds,
    out_of_fold,
    shrunk_frame,
    verifier_rows,
)


def test_frame_groups_keep_photo_copies_and_clips_together() -> None:
    a = frame_group("ambulance_yolo", "valid/images/0002_jpg.rf.c61edce7.jpg")
    b = frame_group("ambulance_yolo", "0002_jpg.rf.ffff0000.jpg")
    c = frame_group("ambulance_yolo", "0003_jpg.rf.c61edce7.jpg")
    assert a == b != c
    assert frame_group("fire_trucks_red_lights", "12") == frame_group("fire_trucks_red_lights", "300")


def test_shrunk_copies_scale_their_boxes_and_stay_in_their_frames_group() -> None:
    """The training frames' shrunk copies (``makeway lights-train --verifier --scales``): the image
    and every box shrink by the factor, a bright lamp stays where its box says, and the copy's key
    keeps it in the cross-validation group of the frame it came from."""
    img = np.zeros((100, 200, 3), np.uint8)
    img[40:48, 120:136] = (255, 60, 0)  # a blue lamp, 16 × 8 px
    f = LightFrame(
        "ambulance_yolo",
        "0002_jpg.rf.c61edce7.jpg",
        img,
        1.0,
        np.array([[120.0, 40.0, 136.0, 48.0]]),
        np.array([[0.0, 0.0, 10.0, 10.0]]),
        ["blue"],
        [1],
    )
    half = shrunk_frame(f, 0.5)
    assert half.image.shape == (50, 100, 3) and half.key == "0002_jpg.rf.c61edce7.jpg@0.5"
    assert np.allclose(half.boxes, [[60, 20, 68, 24]]) and np.allclose(half.negatives, [[0, 0, 5, 5]])
    x1, y1, x2, y2 = half.boxes[0].astype(int)
    assert half.image[y1:y2, x1:x2, 0].min() == 255 and half.image[:, :50].max() == 0
    assert frame_group(half.source, half.key) == frame_group(f.source, f.key)
    clip = LightFrame("fire_trucks_red_lights", "12", img, 1.0, np.zeros((0, 4)), np.zeros((0, 4)))
    assert frame_group("fire_trucks_red_lights", shrunk_frame(clip, 0.35).key) == "fire_trucks_red_lights"
    with pytest.raises(ValueError, match="shrink factor"):
        shrunk_frame(f, 1.5)
    with pytest.raises(ValueError, match="scales"):
        verifier_rows("train", ".", scales=(1.0, 0.0))


def test_grouped_folds_are_balanced_and_never_split_a_group() -> None:
    groups = ["clip"] * 50 + [f"photo{i // 2}" for i in range(60)] + ["other"] * 20
    fold = grouped_folds(groups, 4)
    assert set(fold.tolist()) == {0, 1, 2, 3}
    for g in set(groups):
        assert len(set(fold[[i for i, x in enumerate(groups) if x == g]].tolist())) == 1
    sizes = np.bincount(fold)
    assert sizes.max() == 50 and sizes.min() >= 20  # the big clip alone; photos spread over the rest
    assert np.array_equal(fold, grouped_folds(groups, 4))  # deterministic
    with pytest.raises(ValueError, match="groups cannot fill"):
        grouped_folds(["a", "a", "b"], 3)


def _rows(n_frames: int, rng: np.random.Generator) -> tuple[dict, np.ndarray]:
    """Synthetic verifier rows: per frame 1 true lamp proposal and 9 others; feature 0 separates
    them with noise. Returns the rows and the true-lamp flags."""
    xs, ys, fr, boxes, frames = [], [], [], [], []
    for k in range(n_frames):
        gt = np.array([[10.0, 10.0, 20.0, 20.0]])
        b = np.array([[10, 10, 20, 20], *[[40 + 12 * j, 40, 50 + 12 * j, 50] for j in range(9)]], float)
        y = np.array([True] + [False] * 9)
        x = rng.normal(size=(10, 3)).astype(np.float32)
        x[:, 0] += 3.5 * y
        xs.append(x)
        ys.append(y)
        fr.append(np.full(10, k))
        boxes.append(b)
        src = "clip" if k < n_frames // 3 else "ambulance_yolo"
        frames.append((src, f"{k // 2}_jpg.rf.{k}.jpg", gt, [1]))
    frame = np.concatenate(fr)
    rows = {
        "x": np.concatenate(xs),
        "y": np.concatenate(ys),
        "frame": frame,
        "origin": frame.copy(),
        "frames": frames,
        "boxes": boxes,
    }
    return rows, rows["y"]


def test_out_of_fold_scores_and_the_threshold_they_choose() -> None:
    require_module("xgboost")
    rows, y = _rows(60, np.random.default_rng(0))
    oof = out_of_fold(rows, 3, threads=1)
    assert oof.shape == y.shape and np.all((oof >= 0) & (oof <= 1))
    # out-of-fold scores still rank true lamps above the rest (the signal is real, not memorised)
    assert oof[y].mean() > oof[~y].mean() + 0.4
    t, score = choose_threshold(lambda t: detector_results(rows, oof, t))
    assert t in THRESHOLDS and t > THRESHOLDS[0]  # every proposal kept is not the best trade-off
    assert score > 0.7


def test_choose_threshold_prefers_balance_and_breaks_ties_low() -> None:
    gt = np.array([[0.0, 0.0, 10.0, 10.0], [20.0, 0.0, 30.0, 10.0]])
    # two true detections scoring 0.9 and 0.6, one false at 0.3: threshold 0.35–0.6 gives P = R = 1
    boxes = np.array([[0, 0, 10, 10], [20, 0, 30, 10], [50, 50, 60, 60]], float)
    scores = np.array([0.9, 0.6, 0.3])

    def at(t: float) -> list[FrameResult]:
        keep = scores >= t
        return [FrameResult("s", "0", gt, [1, 1], boxes[keep], scores[keep])]

    t, score = choose_threshold(at)
    assert score == 1.0 and t == 0.35  # the lowest candidate above the false box's 0.3
    # no true positive anywhere: the lowest candidate, score 0
    t0, s0 = choose_threshold(lambda t: [FrameResult("s", "0", gt, [1, 1], boxes[2:], scores[2:])])
    assert t0 == THRESHOLDS[0] and s0 == 0.0


def test_box_targets_invert_refine_boxes() -> None:
    from makeway.perceive.vision.light_verify import refine_boxes
    from makeway.train.light_verifier import box_targets

    rows, _ = _rows(3, np.random.default_rng(1))
    rows["boxes"][0] = rows["boxes"][0] + np.array([1.0, -1.0, 3.0, 1.0])  # true lamp box off by a bit
    t = box_targets(rows, min_iou=0.3)
    near = ~np.isnan(t[:, 0])
    assert near.sum() == 3  # one proposal per frame near its label; the far ones get NaN
    for k in range(3):
        sel = np.flatnonzero((rows["frame"] == k) & near)
        moved = refine_boxes(rows["boxes"][k][[0]], t[sel], (100, 100))
        assert np.allclose(moved, rows["frames"][k][2])


def test_refine_boxes_clips_to_the_frame_and_keeps_a_pixel() -> None:
    from makeway.perceive.vision.light_verify import refine_boxes

    b = np.array([[0.0, 0.0, 10.0, 10.0], [90.0, 40.0, 100.0, 50.0]])
    out = refine_boxes(b, np.array([[-1.0, -1.0, 0.2, 0.0], [0.0, 0.0, 9.0, -2.0]]), (100, 60))
    assert out[0].tolist() == [0.0, 0.0, 12.0, 10.0]
    # offsets clip at ±1.5 box sizes; x2 clips at the frame's width; y2 < y1 is kept 1 px high
    assert out[1, 2] == 100.0 and out[1, 3] - out[1, 1] >= 1.0


def test_exported_verifier_with_box_refiner_runs_in_onnx_runtime(tmp_path) -> None:
    require_module("xgboost")
    from pathlib import Path

    from makeway.perceive.vision.light_verify import FEATURE_NAMES, LightVerifier
    from makeway.train.light_verifier import _export, fit_refiner, fit_verifier, predict_offsets

    rng = np.random.default_rng(2)
    x = rng.normal(size=(300, len(FEATURE_NAMES))).astype(np.float32)
    y = x[:, 0] > 0.5
    t = np.stack([0.1 * x[:, 1], -0.1 * x[:, 2], 0.05 * x[:, 3], np.zeros(300)], axis=1)
    clf = fit_verifier(x, y, threads=1)
    ref = fit_refiner(x, t, threads=1)
    path = Path(tmp_path) / "v.onnx"
    _export(clf, path, {"threshold": "0.4"}, refiner=ref)
    v = LightVerifier(path)
    assert v.refines_boxes and v.threshold == 0.4
    p, off = v.score_and_offsets(x[:20])
    assert np.allclose(p, clf.predict_proba(x[:20])[:, 1], atol=1e-4)
    assert off is not None and np.allclose(off, predict_offsets(ref, x[:20]), atol=1e-4)
    plain = Path(tmp_path) / "plain.onnx"
    _export(clf, plain, {"threshold": "0.4"})
    assert not LightVerifier(plain).refines_boxes and LightVerifier(plain).score_and_offsets(x[:3])[1] is None


def test_bagged_verifier_is_the_mean_of_its_boosters(tmp_path) -> None:
    """Boosters fitted with several seeds export as one ONNX graph whose probability is their mean
    (what ``makeway lights-train --verifier --bag N`` ships); one booster in a list exports as it is."""
    require_module("xgboost")
    from pathlib import Path

    from makeway.perceive.vision.light_verify import FEATURE_NAMES, LightVerifier
    from makeway.train.light_verifier import _export, fit_verifier

    rng = np.random.default_rng(3)
    x = rng.normal(size=(300, len(FEATURE_NAMES))).astype(np.float32)
    y = x[:, 0] + 0.5 * rng.normal(size=300) > 0.3
    boosters = [fit_verifier(x, y, seed=s, threads=1) for s in range(3)]
    each = np.array([b.predict_proba(x[:25])[:, 1] for b in boosters])
    assert np.ptp(each, axis=0).max() > 1e-3  # the seeds do give different boosters
    path = Path(tmp_path) / "bag.onnx"
    _export(boosters, path, {"threshold": "0.3"})
    v = LightVerifier(path)
    assert v.threshold == 0.3 and np.allclose(v.score(x[:25]), each.mean(axis=0), atol=1e-5)
    one = Path(tmp_path) / "one.onnx"
    _export(boosters[:1], one, {"threshold": "0.3"})
    assert np.allclose(LightVerifier(one).score(x[:25]), each[0], atol=1e-5)
