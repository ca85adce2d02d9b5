"""The "verified" lit-light detector: the shipped verifier loads and scores, keeps true lights and drops
hard negatives on real labelled test frames, honours the colour set, rejects bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from makeway.errors import InputError
from makeway.eval.detection import box_iou_matrix
from makeway.perceive.vision.light_cnn import default_lights_model
from makeway.perceive.vision.light_verify import (
    CONTEXT_FEATURE_NAMES,
    DEFAULT_SMALL_VERIFIER_MODEL,
    DEFAULT_VERIFIER_MODEL,
    FEATURE_NAMES,
    LightVerifier,
    context_features,
    nms,
    proposals,
    vehicle_detector,
    verifier_features,
)
from makeway.perceive.vision.lights import LIGHT_DETECTORS
from makeway.train.light_labels import iter_label_frames, read_labels
from makeway.train.light_split import LABEL_DIR


def _frames(data_root: Path, n: int = 6) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``(image, lit-light boxes, hard-negative boxes)`` of the first ``n`` checked frames of the
    test clip night_ambulance_lights that have both."""
    lf = read_labels(LABEL_DIR / "night_ambulance_lights.csv")
    frames = lf.frames()
    keys = [
        k
        for k, rows in frames.items()
        if rows[0].checked
        and any(r.kind == "light" and r.box for r in rows)
        and any(r.kind == "negative" and r.box for r in rows)
    ][::10][:n]
    out = []
    for key, img in iter_label_frames(lf, data_root, keys=keys):
        rows = frames[key]
        gt = np.array([r.box for r in rows if r.kind == "light" and r.box], float).reshape(-1, 4)
        neg = np.array([r.box for r in rows if r.kind == "negative" and r.box], float).reshape(-1, 4)
        out.append((img, gt, neg))
    return out


@pytest.fixture(scope="module")
def frames(data_root: Path) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    got = _frames(data_root)
    assert len(got) >= 4
    return got


def test_shipped_verifier_loads_and_scores_probabilities() -> None:
    assert DEFAULT_VERIFIER_MODEL.is_file()
    assert DEFAULT_VERIFIER_MODEL.stat().st_size <= 5_000_000
    v = LightVerifier()
    assert 0.0 < v.threshold < 1.0
    assert v.feature_names[: len(FEATURE_NAMES)] == FEATURE_NAMES
    assert v.uses_vehicles and v.feature_names[:200] == FEATURE_NAMES + CONTEXT_FEATURE_NAMES
    assert v.uses_appearance and v.appearance is not None
    assert v.feature_names[200:] == v.appearance.feature_names and len(v.feature_names) == 208
    x = np.random.default_rng(0).random((7, len(v.feature_names)), dtype=np.float32)
    p = v.score(x)
    assert p.shape == (7,) and np.all((p >= 0) & (p <= 1))
    assert v.score(np.zeros((0, len(v.feature_names)), np.float32)).shape == (0,)


def test_keeps_most_true_lights_and_drops_most_hard_negatives(frames) -> None:
    v = LightVerifier()
    vehicles = vehicle_detector(1)
    kept_true = n_true = kept_neg = n_neg = 0
    for img, gt, neg in frames:
        props = proposals(img)
        feats = verifier_features(img, props)
        assert feats.shape == (len(props), len(FEATURE_NAMES)) and np.isfinite(feats).all()
        boxes = np.array([p["box"] for p in props], float).reshape(-1, 4)
        ctx = context_features(boxes, [p["colour"] for p in props], vehicles.detect_arrays(img))
        assert v.appearance is not None
        prob = v.score(np.concatenate([feats, ctx, v.appearance.transform(img, boxes)], axis=1))
        iou_gt = box_iou_matrix(boxes, gt).max(axis=1) if len(gt) else np.zeros(len(boxes))
        iou_neg = box_iou_matrix(boxes, neg).max(axis=1) if len(neg) else np.zeros(len(boxes))
        true = iou_gt >= 0.5
        hard = (iou_neg >= 0.5) & ~true
        kept_true += int((prob[true] >= v.threshold).sum())
        n_true += int(true.sum())
        kept_neg += int((prob[hard] >= v.threshold).sum())
        n_neg += int(hard.sum())
    assert n_true >= 10 and n_neg >= 10
    assert kept_true / n_true >= 0.6, (kept_true, n_true)
    assert kept_neg / n_neg <= 0.4  # "most" dropped at the shipped threshold


def test_registry_entry_honours_colours(frames) -> None:
    img = frames[0][0]
    every = LIGHT_DETECTORS["verified"](colours="all", threshold=0.01).detect(img, frame=3)
    assert every and all(d.frame == 3 and 0 <= d.score <= 1 for d in every)
    for colours in (("red",), ("blue",), ("amber", "white")):
        dets = LIGHT_DETECTORS["verified"](colours=colours, threshold=0.01).detect(img)
        assert all(d.colour in colours for d in dets)
    assert LIGHT_DETECTORS["verified"](colours="eu").colours == ("blue", "white")


def test_nms_drops_overlaps_and_boxes_inside_others() -> None:
    boxes = np.array([[0, 0, 10, 10], [1, 1, 11, 11], [2, 2, 6, 6], [20, 20, 30, 30]], float)
    keep = nms(boxes, np.array([0.9, 0.8, 0.7, 0.6]))
    assert keep.tolist() == [0, 3]


def test_bad_input(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not found"):
        LightVerifier(tmp_path / "missing.onnx")
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not onnx")
    with pytest.raises(InputError, match="junk"):
        LightVerifier(junk)
    with pytest.raises(InputError, match="not a light verifier"):
        LightVerifier(default_lights_model())
    v = LightVerifier()
    with pytest.raises(ValueError, match="features"):
        v.score(np.zeros((3, 5), np.float32))
    det = LIGHT_DETECTORS["verified"](colours="all")
    with pytest.raises(ValueError, match="uint8 BGR"):
        det.detect(np.zeros((10, 10), np.uint8))
    with pytest.raises(ValueError, match="unknown colour set"):
        LIGHT_DETECTORS["verified"](colours="purple")
    with pytest.raises(InputError, match="not a small-lamp verifier"):
        LIGHT_DETECTORS["verified"](small_model=DEFAULT_VERIFIER_MODEL)
    with pytest.raises(InputError, match="not found"):
        LIGHT_DETECTORS["verified"](small_model=tmp_path / "missing.onnx")
    import onnx

    for bad in ("abc", "-3", "nan"):
        m = onnx.load(str(DEFAULT_SMALL_VERIFIER_MODEL))
        for prop in m.metadata_props:
            if prop.key == "applies_below_px":
                prop.value = bad
        path = tmp_path / f"small_{bad}.onnx"
        onnx.save(m, str(path))
        with pytest.raises(InputError, match="applies_below_px"):
            LightVerifier(path)


def test_small_lamps_go_to_the_small_lamp_verifier(frames, tmp_path: Path) -> None:
    """Beside the shipped main verifier the shipped small-lamp verifier scores every proposal
    under its size (6 px); proposals of that size are the only ones whose scores change, and
    another main verifier gets no small one."""
    small = LightVerifier(DEFAULT_SMALL_VERIFIER_MODEL)
    assert small.applies_below_px == 6.0 and LightVerifier().applies_below_px is None
    pair = LIGHT_DETECTORS["verified"](colours="all", threshold=0.0)
    alone = LIGHT_DETECTORS["verified"](colours="all", threshold=0.0, small_model=False)
    assert pair.small is not None and alone.small is None
    assert LIGHT_DETECTORS["verified"](model=DEFAULT_VERIFIER_MODEL).small is not None
    other = tmp_path / "main.onnx"
    other.write_bytes(DEFAULT_VERIFIER_MODEL.read_bytes())
    assert LIGHT_DETECTORS["verified"](model=other).small is None
    changed = kept = 0
    for img, _, _ in frames[:3]:
        a = {(d.box.x1, d.box.y1, d.box.x2, d.box.y2): d.score for d in pair.detect(img)}
        b = {(d.box.x1, d.box.y1, d.box.x2, d.box.y2): d.score for d in alone.detect(img)}
        for box in set(a) & set(b):
            side = max(box[2] - box[0], box[3] - box[1])
            if side >= 6.0:
                assert a[box] == pytest.approx(b[box], abs=1e-6)
                kept += 1
            elif abs(a[box] - b[box]) > 1e-6:
                changed += 1
    assert kept > 0 and changed > 0
