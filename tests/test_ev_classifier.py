"""The shipped EV crop classifier head, its storage, CLI and the Framework B hook (issue 3).

Runs on the real crops and clips in ../shared/data (fixture ``data_root``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from makeway.cli.main import app
from makeway.errors import InputError
from makeway.messages import Box, Track
from makeway.perceive.vision.backbone import DEFAULT_BLOCKS
from makeway.perceive.vision.ev_classifier import DEFAULT_MODEL, EVCropClassifier, EVTrackClassifier
from makeway.sense.crops import EV_CROPS_HOLDOUT, CropSet, holdout_split, read_crop_folder, read_holdout

runner = CliRunner()
_KEYS = {"accuracy", "precision", "recall", "f1", "max_f1", "p_at_r80", "n", "skipped"}


@pytest.fixture(scope="module")
def ev_root(data_root: Path) -> Path:
    root = data_root / "vision" / "ev_crops"
    if not root.is_dir():
        pytest.fail(f"{root} missing from the shared data")
    return root


@pytest.fixture(scope="module")
def ev_split(ev_root: Path) -> tuple[CropSet, CropSet]:
    crops = read_crop_folder(ev_root)
    train, test = holdout_split(crops, read_holdout(EV_CROPS_HOLDOUT))
    return crops.subset(train), crops.subset(test)


@pytest.fixture(scope="module")
def shipped() -> EVCropClassifier:
    return EVCropClassifier.load(DEFAULT_MODEL)


def _last_json(output: str) -> dict[str, Any]:
    line = [ln for ln in output.strip().splitlines() if ln.startswith("{")][-1]
    result: dict[str, Any] = json.loads(line)
    return result


def test_save_load_round_trip(ev_split: tuple[CropSet, CropSet], tmp_path: Path) -> None:
    train, test = ev_split
    rng = np.random.default_rng(0)
    small = train.subset(np.sort(rng.choice(len(train), 80, replace=False)))
    clf = EVCropClassifier(Cs=(0.01, 0.1), num_threads=2)
    clf.fit(small.load_images(clf.input_size), small.labels, training="80 crops")
    assert clf.input_size == 224 and clf.flip and clf.coef_ is not None and len(clf.coef_) == clf.dim
    images = test.subset(range(12)).load_images(clf.input_size)
    before = clf.predict_proba(images)
    assert before.shape == (12,) and np.all((before >= 0) & (before <= 1))
    # with flip, a crop and its mirror image get the same probability
    np.testing.assert_allclose(clf.predict_proba(np.ascontiguousarray(images[:, :, ::-1])), before, atol=1e-6)
    clf.mirror_at_test = False  # single view: the crop alone
    single = clf.predict_proba(images)
    np.testing.assert_allclose(single, clf.predict_proba_features(clf.transform(images)), atol=1e-9)
    assert not np.allclose(single, before)
    clf.mirror_at_test = True
    path = clf.save(tmp_path / "head.npz")
    again = EVCropClassifier.load(path)
    assert again.training == "80 crops" and again.blocks == clf.blocks and again.C == clf.C and again.flip
    np.testing.assert_allclose(again.predict_proba(images), before, rtol=1e-6, atol=1e-7)
    assert not list(tmp_path.glob("*.partial*"))  # atomic: no temporary left behind


def test_one_block_without_flip_and_format_1(ev_split: tuple[CropSet, CropSet], tmp_path: Path) -> None:
    """A YOLOX-only head without mirroring; the format-1 file of earlier releases still loads."""
    train, test = ev_split
    small = train.subset(range(0, 400, 5))
    clf = EVCropClassifier(blocks=["yolox_nano@160:dark4,dark5,pan5"], flip=False, Cs=(0.01,), num_threads=2)
    clf.fit(small.load_images(160), small.labels, groups=np.arange(len(small)) // 2)
    assert clf.dim == 1280 and clf.C == 0.01
    images = test.subset(range(6)).load_images(160)
    probs = clf.predict_proba(images)
    mean, scale, coef, intercept = clf._check_fitted()
    old = tmp_path / "format1.npz"
    np.savez(
        old, mean=mean, scale=scale, coef=coef, intercept=intercept, format_version=1,
        layers=np.asarray(["dark4", "dark5", "pan5"]), input_size=160, threshold=0.5, C=0.01, training="x",
    )  # fmt: skip
    again = EVCropClassifier.load(old)
    assert again.blocks == clf.blocks and not again.flip
    np.testing.assert_allclose(again.predict_proba(images), probs, rtol=1e-6, atol=1e-7)
    with pytest.raises(ValueError, match="not 'backbone@size"):
        EVCropClassifier(blocks=["yolox_nano:dark4"])
    with pytest.raises(ValueError, match="unknown backbone"):
        EVCropClassifier(blocks=["resnet@224:layer4"])
    with pytest.raises(ValueError, match="groups"):
        clf.fit_features(np.zeros((4, 3)), np.array([0, 1, 0, 1]), groups=np.arange(3))


def test_shipped_head_on_the_holdout(shipped: EVCropClassifier, ev_split: tuple[CropSet, CropSet]) -> None:
    assert DEFAULT_MODEL.is_file() and DEFAULT_MODEL.stat().st_size < 200_000
    assert shipped.blocks == DEFAULT_BLOCKS and shipped.flip and shipped.input_size == 224
    assert len(shipped.coef_ if shipped.coef_ is not None else []) == shipped.dim == 2 * (704 + 812)
    assert "ev_crops" in shipped.training
    _, test = ev_split
    probs = shipped.predict_proba(test.load_images(shipped.input_size))
    accuracy = float(np.mean((probs >= shipped.threshold) == test.labels.astype(bool)))
    assert accuracy >= 0.9  # measured 0.920 on the 250 held-out crops


def test_cli_eval_on_ev_crops(ev_root: Path) -> None:
    r = runner.invoke(app, ["classify", "eval", "--data", str(ev_root)])
    assert r.exit_code == 0, r.output
    metrics = _last_json(r.output)
    assert set(metrics) == _KEYS
    assert metrics["n"] == 250 and metrics["accuracy"] >= 0.9
    assert "held-out" in r.output


def test_malformed_head_exits_2(ev_root: Path, tmp_path: Path) -> None:
    bad = tmp_path / "broken_head.npz"
    bad.write_bytes(b"not a zip file at all")
    with pytest.raises(InputError, match=r"broken_head\.npz"):
        EVCropClassifier.load(bad)
    r = runner.invoke(app, ["classify", "eval", "--data", str(ev_root), "--model", str(bad)])
    assert r.exit_code == 2 and "broken_head.npz" in r.output
    partial = tmp_path / "partial_head.npz"
    np.savez(partial, mean=np.zeros(3), scale=np.ones(3))
    with pytest.raises(InputError, match=r"partial_head\.npz.*missing"):
        EVCropClassifier.load(partial)
    with pytest.raises(InputError, match="not found"):
        EVCropClassifier.load(tmp_path / "nowhere.npz")


def test_track_classifier_on_a_night_frame(video_dir: Path, shipped: EVCropClassifier) -> None:
    """Frame 24 (0.96 s) of the night clip, boxes as YOLOX-nano puts them there: the lit ambulance
    (track 13 of video_track_labels.csv) is called EV, the white coach beside it (track 1) and a car
    are not. Single frames can go either way (on frame 19 the head swaps the two); the smoother
    over frames is what decides a track (test_pipeline_video)."""
    cap = cv2.VideoCapture(str(video_dir / "night_ambulance_lights.mp4"))
    cap.set(cv2.CAP_PROP_POS_FRAMES, 24)
    ok, frame = cap.read()
    cap.release()
    assert ok
    boxes = [
        Box(652.5, 242.1, 864.9, 472.2),  # the ambulance, blue light on, coming towards the camera
        Box(425.0, 190.8, 644.4, 413.0),  # the white coach on its left
        Box(982.3, 340.2, 1101.2, 407.4),  # a car further back on the right
        Box(600.0, 400.0, 610.0, 420.0),  # 10 px wide: no judgement
        Box(5000.0, 100.0, 5100.0, 200.0),  # off the image
    ]
    tracks = [Track(track_id=i + 1, box=b) for i, b in enumerate(boxes)]
    obs = EVTrackClassifier(shipped).classify(frame, tracks, frame_index=24, time_s=0.96)
    assert [o.track_id for o in obs] == [1, 2, 3, 4, 5]
    assert all(o.frame_index == 24 and o.time_s == 0.96 for o in obs)
    p = [o.probability for o in obs]
    assert p[0] is not None and p[0] >= shipped.threshold  # measured 0.72
    assert p[1] is not None and p[1] < shipped.threshold  # measured 0.14
    assert p[2] is not None and p[2] < shipped.threshold  # measured 0.01
    assert p[3] is None and p[4] is None
    assert EVTrackClassifier(shipped).classify(frame, [], 0, 0.0) == []


def test_detect_with_default_classifier(video_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "night"
    clip = video_dir / "night_ambulance_lights.mp4"
    # no --classifier: the default head; --rule crop: the classifier alone decides (the lights rules
    # are tested in test_lights_app.py)
    args = ["detect", str(clip), "-o", str(out), "--max-frames", "45", "--rule", "crop"]
    r = runner.invoke(app, [*args, "--no-video", "--json", "-q"])
    assert r.exit_code == 0, r.output
    states = [
        t["state"]
        for line in (out / "tracks.jsonl").read_text().splitlines()
        for t in json.loads(line)["tracks"]
    ]
    assert states and all(s != "unclassified" for s in states)
    summary = _last_json(r.output)
    assert summary["ms_per_frame"]["classify"] > 0
    assert 13 in summary["active_ev_tracks"]  # the lit ambulance of the label file is flagged
    off = tmp_path / "off"
    none = ["--classifier", "none", "--rule", "crop", "--no-video", "-q"]
    r = runner.invoke(app, ["detect", str(clip), "-o", str(off), "--max-frames", "45", *none])
    assert r.exit_code == 0, r.output
    states = {
        t["state"]
        for line in (off / "tracks.jsonl").read_text().splitlines()
        for t in json.loads(line)["tracks"]
    }
    assert states == {"unclassified"}  # --classifier none turns the head off
    r = runner.invoke(app, ["detect", str(clip), "-o", str(tmp_path / "x"), "--classifier", str(tmp_path)])
    assert r.exit_code == 2


def test_cli_train_rejects_bad_blocks_and_logreg_distillation(ev_root: Path) -> None:
    r = runner.invoke(app, ["classify", "train", "--data", str(ev_root), "--block", "resnet@224:layer4"])
    assert r.exit_code == 2 and "unknown backbone" in r.output
    r = runner.invoke(app, ["classify", "train", "--data", str(ev_root), "--block", "yolox_nano:dark4"])
    assert r.exit_code == 2 and "backbone@size" in r.output
    r = runner.invoke(app, ["classify", "train", "--data", str(ev_root), "--unlabelled", str(ev_root)])
    assert r.exit_code == 2 and "distillation is for the CNN" in r.output


def test_load_crop_classifiers(tmp_path: Path) -> None:
    from makeway.perceive.vision.cnn_classifier import OnnxCropClassifier
    from makeway.perceive.vision.ev_classifier import FAST_MODEL, load_crop_classifier

    assert isinstance(load_crop_classifier("default"), EVCropClassifier)
    fast = load_crop_classifier(" Fast ")
    assert isinstance(fast, OnnxCropClassifier) and fast.input_size == 64
    assert load_crop_classifier(FAST_MODEL).input_size == 64  # a file works too
    with pytest.raises(InputError, match=r"nowhere\.onnx"):
        load_crop_classifier(tmp_path / "nowhere.onnx")


def test_cli_detect_single_view(video_dir: Path, tmp_path: Path) -> None:
    clip = video_dir / "night_ambulance_lights.mp4"
    args = ["detect", str(clip), "--out", str(tmp_path / "o"), "--max-frames", "4", "--no-video", "-q"]
    args.append("--json")
    r = runner.invoke(app, [*args, "--classifier", "default", "--single-view"])
    assert r.exit_code == 0, r.output
    summary = _last_json(r.output)
    assert summary["frames"] == 4 and summary["ms_per_frame"]["classify"] > 0


def test_imagenet_head_on_the_holdout(ev_split: tuple[CropSet, CropSet]) -> None:
    """The EfficientNet-Lite0 head (``--model imagenet``): the most accurate on still crops."""
    from makeway.perceive.vision.backbone import IMAGENET_BLOCKS
    from makeway.perceive.vision.ev_classifier import IMAGENET_MODEL, load_crop_classifier

    head = load_crop_classifier("imagenet", num_threads=2)
    assert isinstance(head, EVCropClassifier) and head.blocks == IMAGENET_BLOCKS and head.flip
    assert IMAGENET_MODEL.stat().st_size < 200_000
    # stage6 and head (average + max per channel) and the 1000 ImageNet class scores
    assert head.dim == 2 * (320 + 1280) + 1000
    _, test = ev_split
    probs = head.predict_proba(test.load_images(head.input_size))
    accuracy = float(np.mean((probs >= head.threshold) == test.labels.astype(bool)))
    assert accuracy >= 0.93  # measured 0.940 on the 250 held-out crops


def test_general_model_on_the_holdout(ev_split: tuple[CropSet, CropSet]) -> None:
    """``--classifier general``: the fine-tuned EfficientNet-Lite0 delta, applied to the package's
    weights at load time, trained on every source's training part (ev_crops' holdout left out)."""
    from makeway.perceive.vision.cnn_classifier import OnnxCropClassifier
    from makeway.perceive.vision.ev_classifier import GENERAL_MODEL, load_crop_classifier

    clf = load_crop_classifier("general", num_threads=2)
    assert isinstance(clf, OnnxCropClassifier) and clf.input_size == 224 and clf.threshold == 0.5
    assert GENERAL_MODEL.stat().st_size < 5_000_000
    _, test = ev_split
    probs = clf.predict_proba(test.load_images(clf.input_size))
    accuracy = float(np.mean((probs >= clf.threshold) == test.labels.astype(bool)))
    assert accuracy >= 0.88  # measured 0.900 on the 250 held-out crops


def test_shrink_augmentation(ev_split: tuple[CropSet, CropSet], tmp_path: Path) -> None:
    """``shrink``: training copies of each crop as a distant vehicle looks in video."""
    from makeway.perceive.vision.ev_classifier import shrink_copies

    train, test = ev_split
    small = train.subset(range(0, 240, 6))
    images = small.load_images(160)
    far = shrink_copies(images, 24)
    assert far.shape == images.shape and far.dtype == np.uint8

    def sharpness(a: np.ndarray) -> float:
        grey = [cv2.cvtColor(im, cv2.COLOR_BGR2GRAY) for im in a]
        return float(np.mean([cv2.Laplacian(im, cv2.CV_64F).var() for im in grey]))

    assert sharpness(far) < 0.2 * sharpness(images)  # the fine detail is gone
    with pytest.raises(ValueError, match="at least 4"):
        shrink_copies(images, 2)
    with pytest.raises(ValueError, match="at least 4"):
        EVCropClassifier(shrink=(32, 1))
    clf = EVCropClassifier(blocks=["yolox_nano@160:dark5"], shrink=(24, 48), Cs=(0.01,), num_threads=2)
    x, xm, y, g = clf.training_features(images, small.labels, np.arange(len(small)) // 2)
    n = len(small)
    assert x.shape == (3 * n, clf.dim) and xm is not None and xm.shape == x.shape
    assert np.array_equal(y, np.tile(small.labels, 3)) and np.array_equal(g, np.tile(np.arange(n) // 2, 3))
    assert not np.allclose(x[:n], x[n : 2 * n])  # the shrunk copies give other features
    clf.fit(images, small.labels, groups=np.arange(n) // 2)
    probs = clf.predict_proba(test.subset(range(4)).load_images(160))
    assert probs.shape == (4,)
    r = runner.invoke(
        app, ["classify", "train", "--data", str(tmp_path), "--shrink", "2", "--out", str(tmp_path / "h.npz")]
    )
    assert r.exit_code == 2 and "--shrink" in r.output and not (tmp_path / "h.npz").exists()
