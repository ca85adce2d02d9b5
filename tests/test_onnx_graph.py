"""The detector backbones as trainable torch modules (issue 3's fine-tuning transfer route)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from conftest import require_module

torch = require_module("torch")

from makeway.errors import InputError  # noqa: E402
from makeway.perceive.vision.backbone import BackboneFeatures  # noqa: E402
from makeway.perceive.vision.cnn_classifier import OnnxCropClassifier  # noqa: E402
from makeway.sense.crops import CropSet  # noqa: E402
from makeway.train.cnn import CNNClassifier, preprocess  # noqa: E402
from makeway.train.onnx_graph import OnnxGraph, backbone_crop_net, yolox_crop_net  # noqa: E402

_SIZE = 64


@pytest.fixture(scope="module")
def crops(ev_crops: CropSet) -> CropSet:
    """32 real crops of ev_crops (16 + 16), in a fixed order."""
    pos = np.flatnonzero(ev_crops.labels == 1)[:16]
    neg = np.flatnonzero(ev_crops.labels == 0)[:16]
    return ev_crops.subset(np.sort(np.concatenate([pos, neg])))


def test_torch_graph_matches_onnx_runtime(crops: CropSet, data_root: Path) -> None:
    """Same pooled features as the frozen extractor (ONNX Runtime) on real crops."""
    images = crops.load_images(_SIZE)[:6]
    reference = BackboneFeatures(data_root / "models", input_size=_SIZE, num_threads=1).transform(images)
    net = yolox_crop_net(_SIZE, data_root / "models").eval()
    with torch.no_grad():
        ours = net.features(preprocess(images, _SIZE)).numpy()
    assert ours.shape == reference.shape == (6, 1280)
    np.testing.assert_allclose(ours, reference, rtol=1e-3, atol=2e-3)


def test_linear_probe_then_fine_tune_and_export(crops: CropSet, tmp_path: Path, data_root: Path) -> None:
    images, labels = crops.load_images(_SIZE), crops.labels
    net = yolox_crop_net(_SIZE, data_root / "models")
    x = preprocess(images, _SIZE)
    net.linear_probe(x, labels)
    net.eval()
    with torch.no_grad():
        probe_acc = float(((net(x).reshape(-1) > 0).numpy() == labels.astype(bool)).mean())
    assert probe_acc >= 0.9  # a linear model on 1280 features fits 32 training crops
    norm_mean = net.norm.running_mean.clone()
    net.train()
    assert net.backbone.training and not net.norm.training  # the probe's statistics stay put

    clf = CNNClassifier("yolox_ft", input_size=_SIZE, epochs=1, batch_size=16, lr=1e-5, num_threads=1)
    clf.fit(images, labels, training="32 ev_crops")
    assert len(clf.history) == 1 and np.isfinite(clf.history[0]["train_loss"])
    onnx_path = clf.export_onnx(tmp_path / "ft.onnx")
    runtime = OnnxCropClassifier(onnx_path, num_threads=1)
    np.testing.assert_allclose(runtime.predict_proba(images), clf.predict_proba(images), atol=1e-4)
    assert torch.equal(norm_mean, net.norm.running_mean)


def test_errors(tmp_path: Path, data_root: Path) -> None:
    with pytest.raises(ValueError, match="multiple of 32"):
        yolox_crop_net(100, data_root / "models")
    garbage = tmp_path / "yolox_nano.onnx"
    garbage.write_bytes(b"not protobuf at all" * 20)
    with pytest.raises(InputError, match=r"yolox_nano\.onnx"):
        yolox_crop_net(64, garbage)
    from onnx import TensorProto, helper

    graph = helper.make_graph(
        [helper.make_node("Softmax", ["x"], ["y"])],
        "g",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 3, 4, 4])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 3, 4, 4])],
    )
    with pytest.raises(ValueError, match="not supported by OnnxGraph: Softmax"):
        OnnxGraph(helper.make_model(graph), ["y"])
    with pytest.raises(ValueError, match="unknown backbone"):
        backbone_crop_net("resnet50", 64)


def test_nanodet_backbone_matches_onnx_runtime_and_trains(crops: CropSet, data_root: Path) -> None:
    """NanoDet-m's ShuffleNetV2 (LeakyRelu, Split, channel-shuffle Reshape/Transpose) in torch gives the
    frozen extractor's features, at a batch and size the export was not made for, and trains."""
    images = crops.load_images(_SIZE)[:6]
    reference = BackboneFeatures(
        data_root / "models", backbone="nanodet_m", input_size=_SIZE, num_threads=1
    ).transform(images)
    net = backbone_crop_net("nanodet_m", _SIZE, data_root / "models").eval()
    with torch.no_grad():
        ours = net.features(preprocess(images, _SIZE)).numpy()
    assert ours.shape == reference.shape == (6, 2 * (116 + 232 + 464))
    np.testing.assert_allclose(ours, reference, rtol=1e-3, atol=2e-3)
    clf = CNNClassifier("nanodet_ft", input_size=_SIZE, epochs=1, batch_size=16, lr=1e-5, num_threads=1)
    clf.fit(crops.load_images(_SIZE), crops.labels, training="32 ev_crops")
    assert len(clf.history) == 1 and np.isfinite(clf.history[0]["train_loss"])
