"""The per-frame CNN (SPEC §1): torchvision-compatible ResNet-18, focal loss, augmentation, training,
ONNX export, the ONNX Runtime classifier and the classify train/export/eval commands."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from conftest import require_module

torch = require_module("torch")

from makeway.cli.main import app  # noqa: E402
from makeway.errors import InputError  # noqa: E402
from makeway.perceive.vision.cnn_classifier import OnnxCropClassifier  # noqa: E402
from makeway.perceive.vision.ev_classifier import EVTrackClassifier, load_crop_classifier  # noqa: E402
from makeway.sense.crops import CropSet, write_crop_folder  # noqa: E402
from makeway.train.cnn import (  # noqa: E402
    DEFAULT_BOX_JITTER,
    Augment,
    CNNClassifier,
    SmallCNNPixels,
    export_onnx,
    focal_loss,
    load_checkpoint,
    load_pretrained,
    preprocess,
    resnet18_binary,
    small_cnn,
)

runner = CliRunner()

# torchvision.models.resnet18().state_dict() key names, in order (fc there has 1000 outputs, here 1).
_TORCHVISION_RESNET18_KEYS = [
    "conv1.weight",
    "bn1.weight",
    "bn1.bias",
    "bn1.running_mean",
    "bn1.running_var",
    "bn1.num_batches_tracked",
    "layer1.0.conv1.weight",
    "layer1.0.bn1.weight",
    "layer1.0.bn1.bias",
    "layer1.0.bn1.running_mean",
    "layer1.0.bn1.running_var",
    "layer1.0.bn1.num_batches_tracked",
    "layer1.0.conv2.weight",
    "layer1.0.bn2.weight",
    "layer1.0.bn2.bias",
    "layer1.0.bn2.running_mean",
    "layer1.0.bn2.running_var",
    "layer1.0.bn2.num_batches_tracked",
    "layer1.1.conv1.weight",
    "layer1.1.bn1.weight",
    "layer1.1.bn1.bias",
    "layer1.1.bn1.running_mean",
    "layer1.1.bn1.running_var",
    "layer1.1.bn1.num_batches_tracked",
    "layer1.1.conv2.weight",
    "layer1.1.bn2.weight",
    "layer1.1.bn2.bias",
    "layer1.1.bn2.running_mean",
    "layer1.1.bn2.running_var",
    "layer1.1.bn2.num_batches_tracked",
    "layer2.0.conv1.weight",
    "layer2.0.bn1.weight",
    "layer2.0.bn1.bias",
    "layer2.0.bn1.running_mean",
    "layer2.0.bn1.running_var",
    "layer2.0.bn1.num_batches_tracked",
    "layer2.0.conv2.weight",
    "layer2.0.bn2.weight",
    "layer2.0.bn2.bias",
    "layer2.0.bn2.running_mean",
    "layer2.0.bn2.running_var",
    "layer2.0.bn2.num_batches_tracked",
    "layer2.0.downsample.0.weight",
    "layer2.0.downsample.1.weight",
    "layer2.0.downsample.1.bias",
    "layer2.0.downsample.1.running_mean",
    "layer2.0.downsample.1.running_var",
    "layer2.0.downsample.1.num_batches_tracked",
    "layer2.1.conv1.weight",
    "layer2.1.bn1.weight",
    "layer2.1.bn1.bias",
    "layer2.1.bn1.running_mean",
    "layer2.1.bn1.running_var",
    "layer2.1.bn1.num_batches_tracked",
    "layer2.1.conv2.weight",
    "layer2.1.bn2.weight",
    "layer2.1.bn2.bias",
    "layer2.1.bn2.running_mean",
    "layer2.1.bn2.running_var",
    "layer2.1.bn2.num_batches_tracked",
    "layer3.0.conv1.weight",
    "layer3.0.bn1.weight",
    "layer3.0.bn1.bias",
    "layer3.0.bn1.running_mean",
    "layer3.0.bn1.running_var",
    "layer3.0.bn1.num_batches_tracked",
    "layer3.0.conv2.weight",
    "layer3.0.bn2.weight",
    "layer3.0.bn2.bias",
    "layer3.0.bn2.running_mean",
    "layer3.0.bn2.running_var",
    "layer3.0.bn2.num_batches_tracked",
    "layer3.0.downsample.0.weight",
    "layer3.0.downsample.1.weight",
    "layer3.0.downsample.1.bias",
    "layer3.0.downsample.1.running_mean",
    "layer3.0.downsample.1.running_var",
    "layer3.0.downsample.1.num_batches_tracked",
    "layer3.1.conv1.weight",
    "layer3.1.bn1.weight",
    "layer3.1.bn1.bias",
    "layer3.1.bn1.running_mean",
    "layer3.1.bn1.running_var",
    "layer3.1.bn1.num_batches_tracked",
    "layer3.1.conv2.weight",
    "layer3.1.bn2.weight",
    "layer3.1.bn2.bias",
    "layer3.1.bn2.running_mean",
    "layer3.1.bn2.running_var",
    "layer3.1.bn2.num_batches_tracked",
    "layer4.0.conv1.weight",
    "layer4.0.bn1.weight",
    "layer4.0.bn1.bias",
    "layer4.0.bn1.running_mean",
    "layer4.0.bn1.running_var",
    "layer4.0.bn1.num_batches_tracked",
    "layer4.0.conv2.weight",
    "layer4.0.bn2.weight",
    "layer4.0.bn2.bias",
    "layer4.0.bn2.running_mean",
    "layer4.0.bn2.running_var",
    "layer4.0.bn2.num_batches_tracked",
    "layer4.0.downsample.0.weight",
    "layer4.0.downsample.1.weight",
    "layer4.0.downsample.1.bias",
    "layer4.0.downsample.1.running_mean",
    "layer4.0.downsample.1.running_var",
    "layer4.0.downsample.1.num_batches_tracked",
    "layer4.1.conv1.weight",
    "layer4.1.bn1.weight",
    "layer4.1.bn1.bias",
    "layer4.1.bn1.running_mean",
    "layer4.1.bn1.running_var",
    "layer4.1.bn1.num_batches_tracked",
    "layer4.1.conv2.weight",
    "layer4.1.bn2.weight",
    "layer4.1.bn2.bias",
    "layer4.1.bn2.running_mean",
    "layer4.1.bn2.running_var",
    "layer4.1.bn2.num_batches_tracked",
    "fc.weight",
    "fc.bias",
]

_SIZE, _WIDTH = 32, 4  # the tiny model of these tests


def _last_json(output: str) -> dict[str, Any]:
    line = [ln for ln in output.strip().splitlines() if ln.startswith("{")][-1]
    result: dict[str, Any] = json.loads(line)
    return result


@pytest.fixture(scope="module")
def subset(ev_crops: CropSet) -> CropSet:
    """48 real crops of ev_crops, both labels (24 + 24), in a fixed order."""
    pos = np.flatnonzero(ev_crops.labels == 1)[:24]
    neg = np.flatnonzero(ev_crops.labels == 0)[:24]
    return ev_crops.subset(np.sort(np.concatenate([pos, neg])))


@pytest.fixture(scope="module")
def tiny(subset: CropSet) -> CNNClassifier:
    """A ResNet-18 (width 4, 32 px) trained one epoch on the subset."""
    clf = CNNClassifier(
        "resnet18", input_size=_SIZE, width=_WIDTH, epochs=1, batch_size=16, lr=1e-3, num_threads=1
    )
    return clf.fit(subset.load_images(_SIZE), subset.labels, training="48 ev_crops")


@pytest.fixture(scope="module")
def tiny_onnx(tiny: CNNClassifier, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tiny.export_onnx(tmp_path_factory.mktemp("cnn") / "tiny.onnx")


# ---------------------------------------------------------------------------------------- networks


def test_resnet18_keys_match_torchvision() -> None:
    model = resnet18_binary()
    state = model.state_dict()
    assert len(_TORCHVISION_RESNET18_KEYS) == 122
    assert list(state) == _TORCHVISION_RESNET18_KEYS
    assert tuple(state["conv1.weight"].shape) == (64, 3, 7, 7)
    assert tuple(state["layer4.1.conv2.weight"].shape) == (512, 512, 3, 3)
    assert tuple(state["layer2.0.downsample.0.weight"].shape) == (128, 64, 1, 1)
    assert tuple(state["fc.weight"].shape) == (1, 512)
    # torchvision's ResNet-18 has 11,689,512 parameters, 513,000 of them in its 1000-way fc
    assert sum(p.numel() for p in model.parameters()) == 11_689_512 - 513_000 + 513
    narrow = resnet18_binary(width=16)
    assert list(narrow.state_dict()) == _TORCHVISION_RESNET18_KEYS
    assert tuple(narrow.state_dict()["fc.weight"].shape) == (1, 128)
    assert narrow(torch.zeros(2, 3, 64, 64)).shape == (2, 1)


def test_load_pretrained(tmp_path: Path) -> None:
    donor = resnet18_binary()
    imagenet = {k: v.clone() for k, v in donor.state_dict().items() if not k.startswith("fc.")}
    imagenet["fc.weight"] = torch.randn(1000, 512)
    imagenet["fc.bias"] = torch.randn(1000)
    good = tmp_path / "resnet18.pth"
    torch.save({f"module.{k}": v for k, v in imagenet.items()}, good)  # DataParallel prefix too
    model = resnet18_binary()
    fc_before = model.fc.weight.detach().clone()
    loaded = load_pretrained(model, good)
    assert len(loaded) == 120 and "fc.weight" not in loaded
    assert torch.equal(model.layer3[1].conv2.weight, donor.layer3[1].conv2.weight)
    assert torch.equal(model.bn1.running_var, donor.bn1.running_var)
    assert torch.equal(model.fc.weight, fc_before)

    garbage = tmp_path / "garbage.pth"
    garbage.write_bytes(b"not a torch file at all")
    with pytest.raises(InputError, match=r"garbage\.pth.*not a readable torch state dict"):
        load_pretrained(resnet18_binary(), garbage)
    partial = tmp_path / "partial.pth"
    torch.save({"conv1.weight": imagenet["conv1.weight"]}, partial)
    with pytest.raises(InputError, match=r"partial\.pth.*missing bn1\.weight"):
        load_pretrained(resnet18_binary(), partial)
    with pytest.raises(InputError, match="width 16; ImageNet weights need width 64"):
        load_pretrained(resnet18_binary(width=16), good)
    with pytest.raises(InputError, match="not found"):
        load_pretrained(resnet18_binary(), tmp_path / "nowhere.pth")


def test_small_cnn_shape() -> None:
    model = small_cnn(input_size=128)
    convs = [m for m in model.features if isinstance(m, torch.nn.Conv2d)]
    pools = [m for m in model.features if isinstance(m, torch.nn.MaxPool2d)]
    assert [c.out_channels for c in convs] == [16, 32, 64] and len(pools) == 3
    assert model.dense.in_features == 64 * 16 * 16 and model.out.out_features == 1
    assert model(torch.zeros(3, 3, 128, 128)).shape == (3, 1)


# ------------------------------------------------------------------------------------ loss, augment


def test_focal_loss_hand_cases() -> None:
    ln2 = math.log(2.0)
    zero = torch.tensor([0.0])
    # p = 0.5 for a positive: (1 - 0.5)² · ln 2
    assert float(focal_loss(zero, torch.tensor([1.0]))) == pytest.approx(0.25 * ln2, rel=1e-6)
    # a negative given p = 0.75: p_t = 0.25, (0.75)² · ln 4
    logit = torch.tensor([math.log(3.0)])
    assert float(focal_loss(logit, torch.tensor([0.0]))) == pytest.approx(0.5625 * math.log(4.0), rel=1e-6)
    # gamma 0 is the cross-entropy; alpha weights positives α, negatives 1 − α; the mean over a batch
    assert float(focal_loss(zero, torch.tensor([1.0]), gamma=0.0)) == pytest.approx(ln2, rel=1e-6)
    both = focal_loss(torch.tensor([0.0, 0.0]), torch.tensor([1.0, 0.0]), gamma=0.0, alpha=0.25)
    assert float(both) == pytest.approx((0.25 * ln2 + 0.75 * ln2) / 2, rel=1e-6)
    # a confident right answer costs (almost) nothing, far less than under the cross-entropy
    sure = torch.tensor([6.0])
    assert (
        float(focal_loss(sure, torch.tensor([1.0])))
        < 1e-7
        < float(focal_loss(sure, torch.tensor([1.0]), 0.0))
    )


def test_augment_keeps_shapes_and_labels(subset: CropSet) -> None:
    x = preprocess(subset.load_images(_SIZE), _SIZE)  # the network input: normalised RGB
    unit = torch.from_numpy(subset.load_images(_SIZE)[..., ::-1].copy()).permute(0, 3, 1, 2).float() / 255
    labels = torch.from_numpy(subset.labels).float()
    gen = torch.Generator().manual_seed(0)
    out = Augment()(unit, labels, gen)
    assert out.shape == unit.shape == x.shape == (48, 3, _SIZE, _SIZE) and out.dtype == torch.float32
    assert abs(float(x.mean())) < 1.0 and torch.allclose(x[:, 0], (unit[:, 0] - 0.485) / 0.229, atol=1e-5)
    assert float(out.min()) >= 0.0 and float(out.max()) <= 1.0
    assert torch.equal(labels, torch.from_numpy(subset.labels).float())  # labels untouched
    assert not torch.allclose(out, unit)
    # box jitter alone moves positives only; negatives come back exactly (identity resampling)
    only_jitter = Augment(geometric=False, photometric=False)(unit, labels, gen)
    neg, pos = labels == 0, labels == 1
    assert torch.allclose(only_jitter[neg], unit[neg], atol=1e-6)
    assert float((only_jitter[pos] - unit[pos]).abs().mean()) > 0.01
    off = Augment(box_jitter=None, geometric=False, photometric=False)(unit, labels, gen)
    assert torch.equal(off, unit)
    assert DEFAULT_BOX_JITTER.n > 0 and all(s > 0 for s in DEFAULT_BOX_JITTER.std)


def test_sampling_options() -> None:
    clf = CNNClassifier(pos_oversample=2, neg_downsample=5)
    labels = np.array([1] * 10 + [0] * 50)
    idx = clf._epoch_indices(labels, np.random.default_rng(0))
    assert np.sum(labels[idx] == 1) == 20 and np.sum(labels[idx] == 0) == 10
    assert len(set(idx[labels[idx] == 0].tolist())) == 10


# ------------------------------------------------------------------------------- train and export


def test_one_epoch_on_real_crops(tiny: CNNClassifier, subset: CropSet, tmp_path: Path) -> None:
    assert len(tiny.history) == 1
    row = tiny.history[0]
    assert np.isfinite(row["train_loss"]) and np.isfinite(row["val_loss"]) and row["lr"] == 1e-3
    p = tiny.predict_proba(subset.load_images(_SIZE))
    assert p.shape == (48,) and np.all((p >= 0) & (p <= 1))
    ckpt = tiny.save(tmp_path / "tiny.pt")
    again = load_checkpoint(ckpt)
    assert (again.arch, again.input_size, again.width, again.training) == (
        "resnet18",
        _SIZE,
        _WIDTH,
        "48 ev_crops",
    )
    np.testing.assert_allclose(again.predict_proba(subset.load_images(_SIZE)), p, atol=1e-6)
    # seeded: the same run gives the same weights
    twin = CNNClassifier(
        "resnet18", input_size=_SIZE, width=_WIDTH, epochs=1, batch_size=16, lr=1e-3, num_threads=1
    )
    twin.fit(subset.load_images(_SIZE), subset.labels)
    np.testing.assert_allclose(twin.predict_proba(subset.load_images(_SIZE)), p, atol=1e-5)


def test_onnx_round_trip(tiny: CNNClassifier, tiny_onnx: Path, subset: CropSet) -> None:
    images = subset.load_images(224)  # the runtime resizes like load_images does
    ort_clf = OnnxCropClassifier(tiny_onnx, num_threads=1)
    assert ort_clf.input_size == _SIZE and ort_clf.threshold == 0.5 and ort_clf.arch == "resnet18"
    assert ort_clf.metadata["channel_order"] == "RGB" and ort_clf.training == "48 ev_crops"
    p_ort = ort_clf.predict_proba(images)
    p_torch = tiny.predict_proba(images)
    assert p_ort.shape == (48,)
    np.testing.assert_allclose(p_ort, p_torch, atol=1e-4)
    assert np.array_equal(ort_clf.predict(images), (p_ort >= 0.5).astype(np.int64))
    assert ort_clf.predict_proba(images[:0]).shape == (0,)
    # batch sizes are dynamic: one crop gives what it gave in the batch of 48
    np.testing.assert_allclose(ort_clf.predict_proba(images[5:6]), p_ort[5:6], atol=1e-5)
    assert isinstance(load_crop_classifier(tiny_onnx, threshold=0.3), OnnxCropClassifier)


def test_track_classifier_wraps_the_onnx_model(tiny_onnx: Path, subset: CropSet) -> None:
    from makeway.messages import Box, Track

    frame = np.zeros((240, 320, 3), dtype=np.uint8)
    frame[40:200, 60:220] = subset.load_images(160)[0]
    tracks = [Track(track_id=1, box=Box(60, 40, 220, 200)), Track(track_id=2, box=Box(5, 5, 12, 12))]
    model = OnnxCropClassifier(tiny_onnx, num_threads=1)
    obs = EVTrackClassifier(model).classify(frame, tracks, 3, 0.1)
    # the wrapper reports what the model says on the track's crop (10 % context, the model's size)
    from makeway.perceive.vision.crops import crops_for_tracks

    crops, kept = crops_for_tracks(frame, [tracks[0].box], margin=0.1, size=model.input_size)
    assert kept.tolist() == [0]
    assert obs[0].probability == pytest.approx(float(model.predict_proba(crops)[0]), abs=1e-6)
    assert obs[1].probability is None  # 7 px wide: no judgement


def test_onnx_errors(tmp_path: Path, tiny_onnx: Path, data_root: Path) -> None:
    import onnx

    garbage = tmp_path / "garbage.onnx"
    garbage.write_bytes(b"\x00\x01 definitely not protobuf" * 10)
    with pytest.raises(InputError, match=r"garbage\.onnx.*not an ONNX model"):
        OnnxCropClassifier(garbage)
    with pytest.raises(InputError, match="not found"):
        OnnxCropClassifier(tmp_path / "nowhere.onnx")
    with pytest.raises(InputError, match="metadata lacks"):
        OnnxCropClassifier(data_root / "models" / "yolox_nano.onnx")  # an ONNX model, not ours
    proto = onnx.load(str(tiny_onnx))
    for entry in proto.metadata_props:
        if entry.key == "input_size":
            entry.value = "48"
    wrong = tmp_path / "wrong_size.onnx"
    onnx.save(proto, str(wrong))
    with pytest.raises(InputError, match=r"wrong_size\.onnx.*expected one input \(n, 3, 48, 48\)"):
        OnnxCropClassifier(wrong)
    with pytest.raises(ValueError, match="uint8 BGR"):
        OnnxCropClassifier(tiny_onnx).predict_proba(np.zeros((2, 32, 32), dtype=np.uint8))


def test_export_onnx_metadata(tmp_path: Path) -> None:
    import onnx

    path = export_onnx(
        small_cnn(input_size=32, width=4), tmp_path / "s.onnx", 32, threshold=0.4, arch="small_cnn"
    )
    meta = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    assert meta["input_size"] == "32" and float(meta["threshold"]) == 0.4 and meta["layout"] == "NCHW"
    assert [float(v) for v in meta["mean"].split(",")] == [0.485, 0.456, 0.406]
    clf = OnnxCropClassifier(path)
    assert clf.predict_proba(np.zeros((3, 50, 40, 3), dtype=np.uint8)).shape == (3,)


def test_small_cnn_study_adapter(subset: CropSet) -> None:
    from makeway.perceive.vision.features import pixels
    from makeway.train.classical import CLASSIFIERS, compatible, make_classifier

    assert "small_cnn" in CLASSIFIERS and compatible("pixels", "small_cnn")
    assert not compatible("hog", "small_cnn") and compatible("hog", "svm")
    est = make_classifier("small_cnn", n_jobs=1, seed=0)
    assert isinstance(est, SmallCNNPixels)
    est.clf.epochs = 1
    few = np.r_[np.flatnonzero(subset.labels == 1)[:12], np.flatnonzero(subset.labels == 0)[:12]]
    x = pixels(subset.load_images(128)[few])
    est.fit(x, subset.labels[few])
    proba = est.predict_proba(x)
    assert proba.shape == (24, 2) and np.allclose(proba.sum(axis=1), 1.0)
    assert set(np.unique(est.predict(x)).tolist()) <= {0, 1}
    with pytest.raises(ValueError, match="pixels"):
        est.fit(np.zeros((4, 10)), np.array([0, 1, 0, 1]))


# ------------------------------------------------------------------------------------------- CLI


def test_cli_train_export_eval(tmp_path: Path, subset: CropSet, data_root: Path, tiny: CNNClassifier) -> None:
    folder = tmp_path / "crops"
    images = subset.load_images(64)
    write_crop_folder(
        folder,
        ((f"c{i:03d}.jpg", images[i], int(subset.labels[i]), f"g{i // 2}") for i in range(len(subset))),
    )
    out = tmp_path / "m.onnx"
    args = ["classify", "train", "--arch", "resnet18", "--data", str(folder), "--out", str(out)]
    r = runner.invoke(
        app, [*args, "--epochs", "1", "--input-size", "32", "--width", "4", "--threads", "1", "-q"]
    )
    assert r.exit_code == 0, r.output
    assert out.is_file() and out.with_suffix(".pt").is_file()
    assert OnnxCropClassifier(out).input_size == 32

    ckpt = tiny.save(tmp_path / "tiny.pt")
    exported = tmp_path / "exported.onnx"
    r = runner.invoke(app, ["classify", "export", str(ckpt), "--out", str(exported), "--threshold", "0.4"])
    assert r.exit_code == 0, r.output
    assert OnnxCropClassifier(exported).threshold == pytest.approx(0.4)

    r = runner.invoke(
        app, ["classify", "eval", "--data", str(data_root / "vision" / "ev_crops"), "--model", str(exported)]
    )
    assert r.exit_code == 0, r.output
    metrics = _last_json(r.output)
    assert metrics["n"] == 250 and 0.0 <= metrics["accuracy"] <= 1.0

    bad = tmp_path / "bad.onnx"
    bad.write_text("nope")
    r = runner.invoke(app, ["classify", "eval", "--data", str(folder), "--model", str(bad)])
    assert r.exit_code == 2 and "bad.onnx" in r.output
    r = runner.invoke(app, ["classify", "export", str(bad), "--out", str(tmp_path / "x.onnx")])
    assert r.exit_code == 2 and "not a readable torch checkpoint" in r.output


@pytest.mark.parametrize(
    ("name", "size", "min_accuracy", "min_max_f1"),
    [
        ("fast", 64, 0.83, 0.80),  # the 64 px small CNN, distilled: 0.852 when shipped (model card)
        ("fastest", 32, 0.76, 0.70),  # the 32 px one, the latency-target model: 0.792 when shipped
    ],
)
def test_shipped_cnn_on_the_holdout(
    ev_crops: CropSet, name: str, size: int, min_accuracy: float, min_max_f1: float
) -> None:
    """The shipped small CNNs (``--classifier fast|fastest``) on the committed held-out part."""
    from makeway.eval.classification import threshold_metrics
    from makeway.perceive.vision.ev_classifier import FAST_MODEL, FASTEST_MODEL, SHIPPED_MODELS
    from makeway.sense.crops import holdout_split, read_holdout

    path = SHIPPED_MODELS[name]
    assert path == {"fast": FAST_MODEL, "fastest": FASTEST_MODEL}[name] and path.stat().st_size <= 5_000_000
    clf = load_crop_classifier(path, num_threads=2)
    assert isinstance(clf, OnnxCropClassifier) and clf.input_size == size
    test = ev_crops.subset(holdout_split(ev_crops, read_holdout())[1])
    probs = clf.predict_proba(test.load_images(clf.input_size, cache=False))
    y = test.labels.astype(bool)
    assert np.mean((probs >= clf.threshold) == y) >= min_accuracy
    assert threshold_metrics(probs, y)["max_f1"] >= min_max_f1


# ------------------------------------------------------------------------------------ distillation


def test_validation_split_keeps_teacher_crops_in_training() -> None:
    from makeway.train.cnn import validation_split

    labels = np.array([1, 0] * 20)
    groups = np.arange(40) // 2
    labelled = np.arange(40) < 24
    tr, va = validation_split(labels, groups, 0.25, 0, labelled=labelled)
    assert len(va) > 0 and np.all(va < 24)  # validation: labelled crops only
    assert set(range(24, 40)) <= set(tr.tolist()) and not set(tr.tolist()) & set(va.tolist())
    assert sorted([*tr.tolist(), *va.tolist()]) == list(range(40))
    for g in np.unique(groups[va]):
        assert not np.any(groups[tr] == g)  # groups never straddle
    tr, va = validation_split(labels, groups, 0.0, 0)
    assert len(tr) == 40 and len(va) == 0


def test_teacher_targets_leave_out_copies_of_held_out_crops(ev_crops: CropSet, tmp_path: Path) -> None:
    """Distillation data: the teacher's probabilities on a pool; a pool crop that copies a held-out
    crop (here: one copied in, one mirrored in) is left out."""
    import cv2

    from makeway.sense.crops import EV_CROPS_HOLDOUT, holdout_split, read_holdout
    from makeway.train.cnn import teacher_targets

    _, test_idx = holdout_split(ev_crops, read_holdout(EV_CROPS_HOLDOUT))
    held = ev_crops.subset(test_idx[:20])
    pool = tmp_path / "pool"
    pool.mkdir()
    assert ev_crops.root is not None
    unlabelled = sorted((ev_crops.root / "unlabelled").glob("*.jpg"))[:10]
    for p in unlabelled:
        (pool / p.name).write_bytes(p.read_bytes())
    copies = held.load_images(224, cache=False)
    cv2.imwrite(str(pool / "copy_a.jpg"), copies[3])
    cv2.imwrite(str(pool / "copy_b.jpg"), copies[7][:, ::-1])
    (pool / "broken.jpg").write_bytes(b"not an image")
    images, probs, labels, note = teacher_targets([pool], "fastest", 32, [held], progress=False)
    assert images.shape == (len(unlabelled), 32, 32, 3) and images.dtype == np.uint8
    assert probs.shape == labels.shape == (len(unlabelled),)
    assert np.all((probs >= 0) & (probs <= 1)) and np.array_equal(labels, (probs >= 0.5).astype(np.int64))
    assert "2 near-duplicates of held-out crops" in note and "1 unreadable" in note

    clf = CNNClassifier("small_cnn", input_size=32, width=4, epochs=1, batch_size=16, lr=1e-3, num_threads=1)
    few = ev_crops.subset(np.arange(24))
    x = np.concatenate([few.load_images(32), images])
    y = np.concatenate([few.labels, labels])
    soft = np.concatenate([np.full(24, np.nan), probs])
    clf.fit(x, y, np.arange(len(y)) // 2, soft_targets=soft)
    assert np.isfinite(clf.history[0]["train_loss"])
    with pytest.raises(ValueError, match="soft targets"):
        clf.fit(x, y, soft_targets=np.full(len(y), 2.0))
