"""The per-frame EV crop CNN of SPEC §1 (seed 000) and the seeds' small CNN (SPEC §2), in plain PyTorch.

Imported only by training / export code (``makeway classify train|export|study``); the runtime
runs the exported ONNX file through :class:`~makeway.perceive.vision.cnn_classifier.OnnxCropClassifier`.

**Networks** (:data:`ARCHS`):

* :func:`resnet18_binary` — ResNet-18 (7×7/2 stem, max-pool, four stages of two basic blocks) →
  global average pool → ``fc`` with one output; sigmoid at export. Parameter and buffer names are
  torchvision's (``conv1``, ``bn1``, ``layer1.0.conv1`` … ``layer4.1.bn2``, ``layerN.0.downsample.0/.1``,
  ``fc``), so :func:`load_pretrained` loads an ImageNet ``resnet18`` state dict (all but ``fc``)
  where a user has one. ``width`` is the channel count of the first stage (torchvision: 64; the
  stages have ``width·(1, 2, 4, 8)``): smaller widths trade accuracy for latency. Here there are
  no pretrained weights; the models are trained from scratch.
* :func:`small_cnn` — the seeds' CNN of the classifier study: three blocks of 3×3 conv + ReLU +
  2×2 max-pool, a dense ReLU layer, one sigmoid unit (logit here; sigmoid at export).
* ``yolox_ft`` / ``nanodet_ft`` — a COCO detector's own backbone, fine-tuned
  (:func:`makeway.train.onnx_graph.backbone_crop_net`).

**Input**: RGB ``float32`` ``(n, 3, S, S)``, ``(pixel / 255 - mean) / std`` with ImageNet's
mean/std (:data:`MEAN_RGB`, :data:`STD_RGB`; what torchvision's pretrained weights expect). The
ONNX file states this in its metadata (:func:`export_onnx`).

**Training** (:class:`CNNClassifier`, SPEC §1): focal loss (:func:`focal_loss`), Adam (lr 1e-4,
weight decay 0), :class:`torch.optim.lr_scheduler.ReduceLROnPlateau` on the validation loss, stop
when the learning rate falls below a floor (or after ``epochs``); the weights of the epoch with the
lowest validation loss are kept. The validation part is split off the *training* data by source
group (the crop folder's ``group`` column, else near-duplicate clusters,
:func:`makeway.sense.crops.split_holdout`) — never from the committed ev_crops holdout.

**Augmentation** (:class:`Augment`, on whole batches in torch):

* geometric, every crop: horizontal flip (p = 0.5), scale ×U(0.9, 1.1), shift ±5 % of the side;
* photometric, every crop: brightness ×U(0.75, 1.25), contrast ×U(0.75, 1.25), saturation
  ×U(0.7, 1.3), per-channel gains ×U(0.93, 1.07) (a mild hue/white-balance shift that keeps red
  stays red and blue stays blue);
* box jitter, positives only (SPEC §1): a box parameter vector ``(dx, dy, dw, dh)`` is drawn from
  independent normals (:class:`BoxJitter`) and the crop is re-cut around the perturbed box — the
  crop is taken to hold its box with 10 % context per side (as our crops are cut), the box centre
  moves by ``dx·w, dy·h`` and its size scales by ``exp(dw), exp(dh)``; pixels outside the original
  crop repeat its border. The normals are **fitted** (:func:`fit_box_jitter`) to the errors of
  YOLOX-nano detections against the labelled ambulance boxes of ``ambulance_yolo/valid`` (each
  labelled box matched to its best detection with IoU ≥ 0.5; ``dx = (cx_det − cx)/w``,
  ``dy = (cy_det − cy)/h``, ``dw = ln(w_det/w)``, ``dh = ln(h_det/h)``) — the box error the
  deployed detector → tracker → crop chain really makes. :data:`DEFAULT_BOX_JITTER` holds the fit.
* options of the seed's recipe: ``pos_oversample=2`` (each positive twice per epoch, each with its
  own jitter), ``neg_downsample=5`` (a fresh fifth of the negatives each epoch). On ev_crops (41 %
  positive) they are off by default; the seed's 1:5 ratio came from rare positives.
"""

from __future__ import annotations

import copy
import math
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as nnf
from torch import nn

from makeway.atomic import atomic_path
from makeway.errors import InputError
from makeway.perceive.vision.cnn_classifier import ONNX_FORMAT
from makeway.train.ev_head import CropTrainingRun

__all__ = [
    "ARCHS",
    "DEFAULT_BOX_JITTER",
    "MEAN_RGB",
    "ONNX_FORMAT",
    "STD_RGB",
    "Augment",
    "BasicBlock",
    "BoxJitter",
    "CNNClassifier",
    "ResNet18Binary",
    "SmallCNN",
    "SmallCNNPixels",
    "build_model",
    "export_checkpoint",
    "export_onnx",
    "fit_box_jitter",
    "focal_loss",
    "load_checkpoint",
    "load_pretrained",
    "preprocess",
    "resnet18_binary",
    "small_cnn",
    "teacher_targets",
    "train_crop_cnn",
    "validation_split",
]

#: ImageNet mean / std of RGB pixels scaled to [0, 1] (what torchvision's pretrained weights expect).
MEAN_RGB = (0.485, 0.456, 0.406)
STD_RGB = (0.229, 0.224, 0.225)

_CHECKPOINT_FORMAT = "makeway-ev-cnn-checkpoint/1"


# ------------------------------------------------------------------------------------------ networks


def _conv3x3(cin: int, cout: int, stride: int = 1) -> nn.Conv2d:
    return nn.Conv2d(cin, cout, kernel_size=3, stride=stride, padding=1, bias=False)


class BasicBlock(nn.Module):
    """ResNet basic block (two 3×3 convs + identity or 1×1 projection), torchvision's names."""

    def __init__(self, cin: int, cout: int, stride: int = 1) -> None:
        super().__init__()
        self.conv1 = _conv3x3(cin, cout, stride)
        self.bn1 = nn.BatchNorm2d(cout)
        self.relu = nn.ReLU(inplace=True)
        self.conv2 = _conv3x3(cout, cout)
        self.bn2 = nn.BatchNorm2d(cout)
        self.downsample: nn.Module | None = None
        if stride != 1 or cin != cout:
            self.downsample = nn.Sequential(
                nn.Conv2d(cin, cout, kernel_size=1, stride=stride, bias=False), nn.BatchNorm2d(cout)
            )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.relu(out + identity)


class ResNet18Binary(nn.Module):
    """ResNet-18 → global average pool → FC(1) (a logit). See :func:`resnet18_binary`."""

    def __init__(self, width: int = 64) -> None:
        super().__init__()
        if width < 1:
            raise ValueError(f"width must be >= 1, got {width}")
        self.width = int(width)
        w = self.width
        self.conv1 = nn.Conv2d(3, w, kernel_size=7, stride=2, padding=3, bias=False)
        self.bn1 = nn.BatchNorm2d(w)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(kernel_size=3, stride=2, padding=1)
        self.layer1 = nn.Sequential(BasicBlock(w, w), BasicBlock(w, w))
        self.layer2 = nn.Sequential(BasicBlock(w, 2 * w, 2), BasicBlock(2 * w, 2 * w))
        self.layer3 = nn.Sequential(BasicBlock(2 * w, 4 * w, 2), BasicBlock(4 * w, 4 * w))
        self.layer4 = nn.Sequential(BasicBlock(4 * w, 8 * w, 2), BasicBlock(8 * w, 8 * w))
        self.avgpool = nn.AdaptiveAvgPool2d(1)
        self.fc = nn.Linear(8 * w, 1)
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)
        for m in self.modules():  # zero-init the last BN of each block: each block starts as identity
            if isinstance(m, BasicBlock):
                nn.init.zeros_(m.bn2.weight)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.maxpool(self.relu(self.bn1(self.conv1(x))))
        x = self.layer4(self.layer3(self.layer2(self.layer1(x))))
        return self.fc(torch.flatten(self.avgpool(x), 1))


def resnet18_binary(width: int = 64, pretrained: str | Path | None = None) -> ResNet18Binary:
    """ResNet-18 with a one-logit head (SPEC §1); ``pretrained``: a torchvision ResNet-18 state dict
    file (only with ``width=64``; see :func:`load_pretrained`)."""
    model = ResNet18Binary(width)
    if pretrained is not None:
        load_pretrained(model, pretrained)
    return model


def load_pretrained(model: ResNet18Binary, file: str | Path) -> list[str]:
    """Load a torchvision ResNet-18 state dict (e.g. ImageNet ``resnet18-f37072fd.pth``) into
    ``model``, all but ``fc``; returns the loaded keys.

    Accepts a bare state dict or a dict holding one under ``state_dict`` / ``model``, with or
    without a ``module.`` prefix (DataParallel).

    Raises:
        InputError: the file is missing, not a torch file, not a ResNet-18 state dict (names the
            missing keys), or its shapes do not fit ``model`` (a ``width`` other than 64).
    """
    path = Path(file)
    if not path.is_file():
        raise InputError(path, "pretrained weights not found (expected a torchvision ResNet-18 .pth)")
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # pickle / zip / torch raise many types on a foreign file
        raise InputError(path, f"not a readable torch state dict ({type(exc).__name__}: {exc})") from None
    if isinstance(obj, dict) and not any(isinstance(v, torch.Tensor) for v in obj.values()):
        for key in ("state_dict", "model"):
            if isinstance(obj.get(key), dict):
                obj = obj[key]
                break
    if not isinstance(obj, dict):
        raise InputError(path, f"expected a state dict, found {type(obj).__name__}")
    state = {str(k).removeprefix("module."): v for k, v in obj.items()}
    wanted = {k: v for k, v in model.state_dict().items() if not k.startswith("fc.")}
    missing = [k for k in wanted if k not in state]
    if missing:
        shown = ", ".join(missing[:4]) + (f" … ({len(missing)} in all)" if len(missing) > 4 else "")
        raise InputError(path, f"not a torchvision ResNet-18 state dict: missing {shown}")
    bad = [
        f"{k} {tuple(state[k].shape)} vs {tuple(v.shape)}"
        for k, v in wanted.items()
        if not isinstance(state[k], torch.Tensor) or state[k].shape != v.shape
    ]
    if bad:
        raise InputError(
            path,
            f"shapes do not fit this network (width {model.width}; ImageNet weights need width 64): "
            + "; ".join(bad[:3]),
        )
    model.load_state_dict({k: state[k] for k in wanted}, strict=False)
    return list(wanted)


class SmallCNN(nn.Module):
    """The seeds' small CNN (SPEC §2): 3 × (3×3 conv + ReLU + 2×2 max-pool) → dense ReLU → 1 logit."""

    def __init__(
        self, input_size: int = 128, channels: Sequence[int] = (16, 32, 64), hidden: int = 64
    ) -> None:
        super().__init__()
        if len(channels) != 3:
            raise ValueError(f"the small CNN has three conv blocks, got channels {tuple(channels)}")
        if input_size % 8 or input_size < 8:
            raise ValueError(f"input_size must be a multiple of 8, got {input_size}")
        layers: list[nn.Module] = []
        cin = 3
        for cout in channels:
            layers += [nn.Conv2d(cin, cout, 3, padding=1), nn.ReLU(inplace=True), nn.MaxPool2d(2)]
            cin = cout
        self.features = nn.Sequential(*layers)
        side = input_size // 8
        self.dense = nn.Linear(cin * side * side, hidden)
        self.relu = nn.ReLU(inplace=True)
        self.out = nn.Linear(hidden, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = torch.flatten(self.features(x), 1)
        return self.out(self.relu(self.dense(x)))


def small_cnn(input_size: int = 128, width: int = 16, hidden: int = 64) -> SmallCNN:
    """The seeds' small CNN with ``width·(1, 2, 4)`` channels (default 16, 32, 64)."""
    return SmallCNN(input_size, (width, 2 * width, 4 * width), hidden)


#: Network builders by name: ``builder(input_size, width)`` → an ``nn.Module`` returning logits ``(n, 1)``.
ARCHS: dict[str, Callable[[int, int], nn.Module]] = {
    "resnet18": lambda input_size, width: resnet18_binary(width),
    "small_cnn": lambda input_size, width: small_cnn(input_size, width),
    "yolox_ft": lambda input_size, width: _backbone_ft("yolox_nano", input_size),
    "nanodet_ft": lambda input_size, width: _backbone_ft("nanodet_m", input_size),
    "effnet_ft": lambda input_size, width: _effnet_ft(input_size),
}


def _effnet_ft(input_size: int) -> nn.Module:
    from makeway.train.effnet import effnet_binary

    return effnet_binary(input_size)


def _backbone_ft(backbone: str, input_size: int) -> nn.Module:
    from makeway.train.onnx_graph import backbone_crop_net

    return backbone_crop_net(backbone, input_size)


def build_model(arch: str, input_size: int, width: int) -> nn.Module:
    """A fresh network from :data:`ARCHS`; ``ValueError`` listing the names for an unknown one."""
    try:
        builder = ARCHS[arch]
    except KeyError:
        raise ValueError(f"unknown CNN architecture {arch!r}; registered: {', '.join(ARCHS)}") from None
    return builder(input_size, width)


# -------------------------------------------------------------------------------------------- loss


def focal_loss(
    logits: torch.Tensor, targets: torch.Tensor, gamma: float = 2.0, alpha: float | None = None
) -> torch.Tensor:
    """Mean binary focal loss ``−α_t (1 − p_t)^γ ln p_t`` from logits (Lin et al.; SPEC §1).

    ``p_t`` is the probability given to the true class; ``alpha`` weights positives by ``α`` and
    negatives by ``1 − α`` (``None``: no class weight). ``gamma = 0``, ``alpha = None`` is the
    binary cross-entropy.
    """
    logits = logits.reshape(-1)
    targets = targets.reshape(-1).to(logits.dtype)
    ce = nnf.binary_cross_entropy_with_logits(logits, targets, reduction="none")
    p_t = torch.exp(-ce)
    loss = (1.0 - p_t) ** gamma * ce if gamma else ce
    if alpha is not None:
        loss = (alpha * targets + (1.0 - alpha) * (1.0 - targets)) * loss
    return loss.mean()


# ------------------------------------------------------------------------------------ augmentation


@dataclass(frozen=True, slots=True)
class BoxJitter:
    """Independent normals of the box errors ``(dx, dy, dw, dh)`` (module docstring); ``n`` boxes fitted."""

    mean: tuple[float, float, float, float]
    std: tuple[float, float, float, float]
    n: int = 0
    source: str = ""


#: Spreads fitted by :func:`fit_box_jitter` (YOLOX-nano, score ≥ 0.3, class-agnostic) on
#: ``ambulance_yolo/valid``: 577 labelled ambulances matched at IoU ≥ 0.5 gave means
#: ``(dx, dy, dw, dh) = (−0.001, 0.166, 0.017, 0.223)`` and standard deviations
#: ``(0.041, 0.073, 0.074, 0.121)``. The spreads are used as fitted; the means are set to zero:
#: the vertical offset is a trait of that set's labels (its boxes stop above the detector's), and a
#: systematic shift applied to positives only would hand the network a label cue (where the
#: vehicle sits in the crop) that does not exist at run time.
DEFAULT_BOX_JITTER = BoxJitter(
    mean=(0.0, 0.0, 0.0, 0.0),
    std=(0.0409, 0.0733, 0.0737, 0.1211),
    n=577,
    source="yolox_nano vs labelled ambulance boxes of ambulance_yolo/valid, IoU >= 0.5; means zeroed",
)


def fit_box_jitter(
    yolo_root: str | Path,
    *,
    detector: str = "yolox_nano",
    model_path: str | Path | None = None,
    min_iou: float = 0.5,
    class_id: int = 0,
    num_threads: int = 1,
) -> BoxJitter:
    """Fit :class:`BoxJitter` to detector boxes vs labelled boxes of a YOLO set (module docstring).

    Every labelled box of ``class_id`` is matched to the detection (any vehicle class) of highest
    IoU; pairs under ``min_iou`` are dropped (the detector missed it: no crop, nothing to emulate).
    """
    import cv2

    from makeway.perceive.vision.detectors import DETECTORS
    from makeway.sense.crops import read_yolo_set
    from makeway.track.sort import iou_matrix

    det = DETECTORS[detector](model_path, score_threshold=0.3, class_agnostic=True, num_threads=num_threads)
    rows: list[list[float]] = []
    for item in read_yolo_set(yolo_root):
        truth = np.array([[b.x1, b.y1, b.x2, b.y2] for b in item.boxes_of(class_id)], dtype=np.float64)
        if not len(truth):
            continue
        image = cv2.imread(str(item.path), cv2.IMREAD_COLOR)
        if image is None:
            raise InputError(item.path, "OpenCV could not decode this image")
        boxes, _, _ = det.detect_arrays(image)
        if not len(boxes):
            continue
        iou = iou_matrix(truth, boxes.astype(np.float64))
        for i, j in enumerate(np.argmax(iou, axis=1)):
            if iou[i, j] < min_iou:
                continue
            t, d = truth[i], boxes[j].astype(np.float64)
            tw, th, dw, dh = t[2] - t[0], t[3] - t[1], d[2] - d[0], d[3] - d[1]
            rows.append(
                [
                    ((d[0] + d[2]) - (t[0] + t[2])) / 2 / tw,
                    ((d[1] + d[3]) - (t[1] + t[3])) / 2 / th,
                    math.log(dw / tw),
                    math.log(dh / th),
                ]
            )
    if len(rows) < 2:
        raise InputError(Path(yolo_root), f"only {len(rows)} labelled boxes matched a detection; cannot fit")
    arr = np.asarray(rows)
    m = [round(float(v), 4) for v in arr.mean(axis=0)]
    sd = [round(float(v), 4) for v in arr.std(axis=0, ddof=1)]
    return BoxJitter(
        (m[0], m[1], m[2], m[3]),
        (sd[0], sd[1], sd[2], sd[3]),
        len(rows),
        f"{detector} vs labels of {Path(yolo_root).name}, IoU >= {min_iou}",
    )


class Augment:
    """Batch augmentation on normalised-to-[0, 1] RGB tensors ``(n, 3, S, S)`` (module docstring).

    ``box_jitter=None`` turns the positive-only re-cropping off; ``geometric`` / ``photometric``
    toggle the others. ``margin`` is the context per side the crops are assumed to carry.
    """

    def __init__(
        self,
        *,
        box_jitter: BoxJitter | None = DEFAULT_BOX_JITTER,
        geometric: bool = True,
        photometric: bool = True,
        margin: float = 0.1,
        scale: float = 0.1,
        shift: float = 0.05,
    ) -> None:
        self.box_jitter = box_jitter
        self.geometric = geometric
        self.photometric = photometric
        self.margin = float(margin)
        self.scale = float(scale)
        self.shift = float(shift)

    def __call__(self, x: torch.Tensor, labels: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        n = x.shape[0]
        if n == 0:
            return x
        g = generator

        def uniform(lo: float, hi: float, *shape: int) -> torch.Tensor:
            return lo + (hi - lo) * torch.rand(*(shape or (n,)), generator=g)

        hx = torch.ones(n)
        hy = torch.ones(n)
        cx = torch.zeros(n)
        cy = torch.zeros(n)
        if self.box_jitter is not None:
            pos = labels.reshape(-1) > 0.5
            mean = torch.tensor(self.box_jitter.mean, dtype=torch.float32)
            std = torch.tensor(self.box_jitter.std, dtype=torch.float32)
            d = mean + std * torch.randn(n, 4, generator=g)
            box_half = 1.0 / (1.0 + 2.0 * self.margin)  # the box's half-side in crop units [-1, 1]
            cx = torch.where(pos, d[:, 0] * 2 * box_half, cx)
            cy = torch.where(pos, d[:, 1] * 2 * box_half, cy)
            hx = torch.where(pos, torch.exp(d[:, 2]), hx)
            hy = torch.where(pos, torch.exp(d[:, 3]), hy)
        if self.geometric:
            s = uniform(1 - self.scale, 1 + self.scale)
            hx, hy = hx * s, hy * s
            cx = cx + uniform(-self.shift, self.shift) * 2
            cy = cy + uniform(-self.shift, self.shift) * 2
            flip = torch.rand(n, generator=g) < 0.5
            hx = torch.where(flip, -hx, hx)
        if self.box_jitter is not None or self.geometric:
            theta = torch.zeros(n, 2, 3)
            theta[:, 0, 0], theta[:, 0, 2] = hx, cx
            theta[:, 1, 1], theta[:, 1, 2] = hy, cy
            grid = nnf.affine_grid(theta, list(x.shape), align_corners=False)
            x = nnf.grid_sample(x, grid, mode="bilinear", padding_mode="border", align_corners=False)
        if self.photometric:
            x = x * uniform(0.75, 1.25).view(n, 1, 1, 1)
            mean_px = x.mean(dim=(1, 2, 3), keepdim=True)
            x = (x - mean_px) * uniform(0.75, 1.25).view(n, 1, 1, 1) + mean_px
            grey = (0.299 * x[:, 0:1] + 0.587 * x[:, 1:2] + 0.114 * x[:, 2:3]).expand_as(x)
            x = grey + (x - grey) * uniform(0.7, 1.3).view(n, 1, 1, 1)
            x = x * uniform(0.93, 1.07, n, 3).view(n, 3, 1, 1)
            x = x.clamp(0.0, 1.0)
        return x


# ------------------------------------------------------------------------------------ preprocessing


def _resize_batch(images: np.ndarray, size: int) -> np.ndarray:
    import cv2

    arr = np.asarray(images)
    if arr.ndim != 4 or arr.shape[3] != 3 or arr.dtype != np.uint8:
        raise ValueError(f"expected uint8 BGR images (n, H, W, 3), got {arr.dtype} {arr.shape}")
    if arr.shape[1:3] == (size, size):
        return arr
    out = np.empty((len(arr), size, size, 3), dtype=np.uint8)
    for i, image in enumerate(arr):
        shrink = image.shape[0] > size or image.shape[1] > size
        out[i] = cv2.resize(image, (size, size), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    return out


def _to_unit_rgb(images: np.ndarray, size: int) -> torch.Tensor:
    """uint8 BGR ``(n, H, W, 3)`` → float RGB in [0, 1] ``(n, 3, size, size)``."""
    arr = _resize_batch(images, size)[..., ::-1]
    return torch.from_numpy(np.ascontiguousarray(arr.transpose(0, 3, 1, 2))).float().div_(255.0)


_MEAN_T = torch.tensor(MEAN_RGB).view(1, 3, 1, 1)
_STD_T = torch.tensor(STD_RGB).view(1, 3, 1, 1)


def _normalise(x: torch.Tensor) -> torch.Tensor:
    return (x - _MEAN_T) / _STD_T


def preprocess(images: np.ndarray, size: int) -> torch.Tensor:
    """uint8 BGR crops ``(n, H, W, 3)`` → the network input ``(n, 3, size, size)`` (module docstring)."""
    return _normalise(_to_unit_rgb(images, size))


# ----------------------------------------------------------------------------------------- trainer


def validation_split(
    labels: np.ndarray,
    groups: Sequence[Any] | np.ndarray | None,
    fraction: float,
    seed: int,
    *,
    labelled: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``(train_idx, validation_idx)`` for :meth:`CNNClassifier.fit`: ``fraction`` of the crops by
    source group (:func:`makeway.sense.crops.split_holdout`), drawn from the ``labelled`` crops only
    (crops with teacher targets always train). ``fraction = 0``: no validation part."""
    from makeway.sense.crops import CropSet, split_holdout

    y = np.asarray(labels)
    own = np.arange(len(y)) if labelled is None else np.flatnonzero(labelled)
    if fraction <= 0 or groups is None:
        return np.arange(len(y)), np.zeros(0, dtype=np.int64)
    fake = CropSet(paths=tuple(Path(str(i)) for i in own), labels=y[own])
    tr_own, va_own = split_holdout(fake, fraction, seed, groups=np.asarray(groups)[own])
    rest = np.setdiff1d(np.arange(len(y)), own)
    return np.sort(np.concatenate([own[tr_own], rest])).astype(np.int64), own[va_own]


class CNNClassifier:
    """Trainable crop CNN (scikit-learn style; SPEC §1). Images are uint8 BGR ``(n, H, W, 3)``.

    Args:
        arch: ``"resnet18"`` or ``"small_cnn"`` (:data:`ARCHS`).
        input_size: side the crops are resized to.
        width: channels of the first stage (ResNet-18: 64 is torchvision's; small CNN: 16).
        epochs: most epochs (training also stops when the lr reaches ``min_lr``).
        batch_size: crops per step.
        lr, weight_decay: Adam's (SPEC §1: 1e-4, 0).
        lr_factor, patience: :class:`~torch.optim.lr_scheduler.ReduceLROnPlateau` on the validation loss.
        min_lr: the floor: training stops once the lr drops below it.
        gamma, alpha: focal loss (:func:`focal_loss`).
        val_fraction: share of the training groups held out for validation (0: no validation; the
            last epoch's weights are kept and the scheduler watches the training loss).
        augment: the batch augmentation (``None``: none).
        pos_oversample, neg_downsample: seed-recipe sampling options (module docstring).
        threshold: decision threshold stored with the model.
        pretrained: torchvision ResNet-18 state dict file (``resnet18``, ``width=64`` only).
        num_threads: torch intra-op threads while fitting / predicting.
        seed: seeds the weights, the split, the order and the augmentation.
    """

    def __init__(
        self,
        arch: str = "resnet18",
        *,
        input_size: int = 64,
        width: int = 16,
        epochs: int = 30,
        batch_size: int = 32,
        lr: float = 1e-4,
        weight_decay: float = 0.0,
        lr_factor: float = 0.5,
        patience: int = 3,
        min_lr: float = 1e-5,
        gamma: float = 2.0,
        alpha: float | None = None,
        val_fraction: float = 0.15,
        augment: Augment | None = None,
        pos_oversample: int = 1,
        neg_downsample: int = 1,
        threshold: float = 0.5,
        pretrained: str | Path | None = None,
        num_threads: int = 2,
        seed: int = 0,
    ) -> None:
        if arch not in ARCHS:
            raise ValueError(f"unknown CNN architecture {arch!r}; registered: {', '.join(ARCHS)}")
        if not 0.0 < threshold < 1.0:
            raise ValueError(f"threshold must be in (0, 1), got {threshold}")
        if not 0.0 <= val_fraction < 1.0:
            raise ValueError(f"val_fraction must be in [0, 1), got {val_fraction}")
        if pos_oversample < 1 or neg_downsample < 1:
            raise ValueError("pos_oversample and neg_downsample must be >= 1")
        if pretrained is not None and arch != "resnet18":
            raise ValueError("--pretrained loads torchvision ResNet-18 weights: only for --arch resnet18")
        self.arch = arch
        self.input_size = int(input_size)
        self.width = int(width)
        self.epochs = int(epochs)
        self.batch_size = int(batch_size)
        self.lr = float(lr)
        self.weight_decay = float(weight_decay)
        self.lr_factor = float(lr_factor)
        self.patience = int(patience)
        self.min_lr = float(min_lr)
        self.gamma = float(gamma)
        self.alpha = alpha
        self.val_fraction = float(val_fraction)
        self.augment = Augment() if augment is None else augment
        self.pos_oversample = int(pos_oversample)
        self.neg_downsample = int(neg_downsample)
        self.threshold = float(threshold)
        self.pretrained = pretrained
        self.num_threads = int(num_threads)
        self.seed = int(seed)
        self.training = ""
        self.history: list[dict[str, float]] = []
        self.model_: nn.Module | None = None

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(arch={self.arch!r}, input_size={self.input_size}, width={self.width}, "
            f"{'fitted' if self.model_ is not None else 'unfitted'})"
        )

    def new_model(self) -> nn.Module:
        """The untrained network (pretrained backbone loaded when asked)."""
        if self.arch == "resnet18":
            return resnet18_binary(self.width, self.pretrained)
        return build_model(self.arch, self.input_size, self.width)

    # ------------------------------------------------------------------------------------- fit

    def _epoch_indices(self, labels: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        pos = np.flatnonzero(labels == 1)
        neg = np.flatnonzero(labels == 0)
        if self.neg_downsample > 1 and len(neg):
            neg = rng.choice(neg, size=max(1, len(neg) // self.neg_downsample), replace=False)
        idx = np.concatenate([np.repeat(pos, self.pos_oversample), neg])
        return rng.permutation(idx)

    def fit(
        self,
        images: np.ndarray,
        labels: np.ndarray,
        groups: Sequence[Any] | np.ndarray | None = None,
        *,
        soft_targets: np.ndarray | None = None,
        training: str = "",
        progress: bool = False,
        on_epoch: Callable[[dict[str, float]], Any] | None = None,
    ) -> CNNClassifier:
        """Train on crops and 0/1 labels; ``groups`` (source per crop) keep the validation split honest
        (``None``: near-duplicate clusters). ``training`` describes the data (stored on save).

        ``soft_targets`` (distillation): a target probability per crop, NaN where the hard label is
        the target. Crops with a soft target — a teacher's judgement of an unlabelled crop — are
        trained on it (their ``labels``, the teacher's decision, only choose box jitter and
        sampling) and never enter the validation part, which stays labelled crops only."""
        from makeway.progress import progress_bar

        y = np.asarray(labels).astype(np.int64).ravel()
        if len(y) != len(images):
            raise ValueError(f"{len(images)} images but {len(y)} labels")
        if set(np.unique(y).tolist()) != {0, 1}:
            raise ValueError("labels must contain both classes 0 and 1")
        old_threads = torch.get_num_threads()
        torch.set_num_threads(self.num_threads)
        try:
            torch.manual_seed(self.seed)
            gen = torch.Generator().manual_seed(self.seed)
            rng = np.random.default_rng(self.seed)
            target = y.astype(np.float32)
            if soft_targets is not None:
                soft = np.asarray(soft_targets, dtype=np.float32).ravel()
                if len(soft) != len(y):
                    raise ValueError(f"{len(soft)} soft targets for {len(y)} crops")
                if np.any((soft < 0) | (soft > 1)):
                    raise ValueError("soft targets must be probabilities in [0, 1] (or NaN)")
                target = np.where(np.isnan(soft), target, soft)
                labelled = np.isnan(soft)
            else:
                labelled = np.ones(len(y), dtype=bool)
            x_all = _to_unit_rgb(images, self.input_size)
            if self.val_fraction > 0 and groups is None:
                from makeway.sense.crops import near_duplicate_groups

                groups = near_duplicate_groups(_resize_batch(images, 64))
            tr, va = validation_split(y, groups, self.val_fraction, self.seed, labelled=labelled)
            x_tr, y_tr, t_tr = x_all[tr], y[tr], target[tr]
            x_va, y_va = _normalise(x_all[va]), torch.from_numpy(y[va]).float()
            model = self.new_model()
            probe = getattr(model, "linear_probe", None)
            if callable(probe):  # pretrained backbones: start from the best linear head
                probe(_normalise(x_tr), y_tr)
            opt = torch.optim.Adam(model.parameters(), lr=self.lr, weight_decay=self.weight_decay)
            sched = torch.optim.lr_scheduler.ReduceLROnPlateau(
                opt, mode="min", factor=self.lr_factor, patience=self.patience
            )
            best_loss, best_state = math.inf, copy.deepcopy(model.state_dict())
            self.history = []
            n_batches = math.ceil(len(self._epoch_indices(y_tr, np.random.default_rng(0))) / self.batch_size)
            with progress_bar(
                f"training {self.arch}", self.epochs * n_batches, enabled=progress, unit="batches"
            ) as advance:
                for epoch in range(self.epochs):
                    t0 = time.perf_counter()
                    model.train()
                    order = self._epoch_indices(y_tr, rng)
                    total, count = 0.0, 0
                    for start in range(0, len(order), self.batch_size):
                        idx = torch.from_numpy(order[start : start + self.batch_size])
                        if len(idx) < 2:  # BatchNorm needs two samples
                            continue
                        yb = torch.from_numpy(y_tr).float()[idx]
                        xb = _normalise(self.augment(x_tr[idx], yb, gen))
                        loss = focal_loss(model(xb), torch.from_numpy(t_tr)[idx], self.gamma, self.alpha)
                        opt.zero_grad()
                        loss.backward()
                        opt.step()
                        total += float(loss.detach()) * len(idx)
                        count += len(idx)
                        advance(1)
                    row: dict[str, float] = {
                        "epoch": epoch + 1,
                        "lr": opt.param_groups[0]["lr"],
                        "train_loss": total / max(count, 1),
                    }
                    if len(va):
                        logits = self._logits(model, x_va)
                        row["val_loss"] = float(focal_loss(logits, y_va, self.gamma, self.alpha))
                        row["val_accuracy"] = float(((logits.reshape(-1) > 0).float() == y_va).float().mean())
                    watched = row.get("val_loss", row["train_loss"])
                    if not len(va) or watched < best_loss:
                        best_loss, best_state = watched, copy.deepcopy(model.state_dict())
                    row["seconds"] = time.perf_counter() - t0
                    self.history.append(row)
                    if on_epoch is not None:
                        on_epoch(row)
                    sched.step(watched)
                    if opt.param_groups[0]["lr"] < self.min_lr * (1 - 1e-9):
                        break
                advance.finish()
            model.load_state_dict(best_state)
            model.eval()
            self.model_ = model
            self.training = training
        finally:
            torch.set_num_threads(old_threads)
        return self

    @staticmethod
    def _logits(model: nn.Module, x: torch.Tensor, batch: int = 256) -> torch.Tensor:
        model.eval()
        with torch.no_grad():
            if len(x) == 0:
                return torch.zeros(0)
            return torch.cat([model(x[i : i + batch]).reshape(-1) for i in range(0, len(x), batch)])

    # -------------------------------------------------------------------------------- predict

    def _check_fitted(self) -> nn.Module:
        if self.model_ is None:
            raise ValueError("this CNNClassifier is not fitted; call fit() or load()")
        return self.model_

    def predict_proba(self, images: np.ndarray) -> np.ndarray:
        """P(emergency vehicle) ``(n,)`` of uint8 BGR crops (torch; the runtime uses the ONNX file)."""
        model = self._check_fitted()
        old = torch.get_num_threads()
        torch.set_num_threads(self.num_threads)
        try:
            logits = self._logits(model, preprocess(images, self.input_size))
        finally:
            torch.set_num_threads(old)
        return torch.sigmoid(logits).numpy().astype(np.float64)

    def predict(self, images: np.ndarray) -> np.ndarray:
        """0/1 ``(n,)``: probability at or above :attr:`threshold`."""
        return (self.predict_proba(images) >= self.threshold).astype(np.int64)

    # -------------------------------------------------------------------------------- storage

    def config(self) -> dict[str, Any]:
        """What a checkpoint stores besides the weights."""
        return {
            "arch": self.arch,
            "input_size": self.input_size,
            "width": self.width,
            "threshold": self.threshold,
            "training": self.training,
            "history": self.history,
            "hyper": {
                "epochs": self.epochs,
                "batch_size": self.batch_size,
                "lr": self.lr,
                "weight_decay": self.weight_decay,
                "lr_factor": self.lr_factor,
                "patience": self.patience,
                "min_lr": self.min_lr,
                "gamma": self.gamma,
                "alpha": self.alpha,
                "val_fraction": self.val_fraction,
                "pos_oversample": self.pos_oversample,
                "neg_downsample": self.neg_downsample,
                "box_jitter": self.augment.box_jitter is not None,
                "seed": self.seed,
            },
        }

    def save(self, path: str | Path) -> Path:
        """Write a checkpoint (``torch.save`` of the state dict + :meth:`config`), all-or-nothing."""
        model = self._check_fitted()
        path = Path(path)
        payload = {"format": _CHECKPOINT_FORMAT, **self.config(), "state_dict": model.state_dict()}
        with atomic_path(path) as tmp:
            torch.save(payload, tmp)
        return path

    @classmethod
    def load(cls, path: str | Path, **kwargs: Any) -> CNNClassifier:
        """Read a checkpoint written by :meth:`save` (see :func:`load_checkpoint`)."""
        return load_checkpoint(path, **kwargs)

    def export_onnx(self, path: str | Path) -> Path:
        """The model as ONNX (see :func:`export_onnx`)."""
        return export_onnx(
            self._check_fitted(),
            path,
            self.input_size,
            threshold=self.threshold,
            arch=self.arch,
            width=self.width,
            training=self.training,
        )


def load_checkpoint(path: str | Path, **kwargs: Any) -> CNNClassifier:
    """A fitted :class:`CNNClassifier` from a checkpoint; ``kwargs`` go to the constructor.

    Raises:
        InputError: missing file, not a torch file, or not a makeway CNN checkpoint.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "CNN checkpoint not found (train one with `makeway classify train --arch …`)")
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise InputError(path, f"not a readable torch checkpoint ({type(exc).__name__}: {exc})") from None
    if not isinstance(obj, dict) or obj.get("format") != _CHECKPOINT_FORMAT:
        raise InputError(path, f"not a makeway CNN checkpoint (expected format {_CHECKPOINT_FORMAT})")
    try:
        clf = CNNClassifier(
            str(obj["arch"]),
            input_size=int(obj["input_size"]),
            width=int(obj["width"]),
            threshold=float(obj["threshold"]),
            **kwargs,
        )
        model = clf.new_model()
        model.load_state_dict(obj["state_dict"])
    except (KeyError, ValueError, RuntimeError) as exc:
        raise InputError(path, f"malformed CNN checkpoint ({type(exc).__name__}: {exc})") from None
    model.eval()
    clf.model_ = model
    clf.training = str(obj.get("training", ""))
    clf.history = list(obj.get("history", []))
    return clf


class _WithSigmoid(nn.Module):
    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.model(x)).reshape(-1)


def export_onnx(
    model: nn.Module,
    path: str | Path,
    input_size: int,
    *,
    threshold: float = 0.5,
    arch: str = "",
    width: int = 0,
    training: str = "",
    opset: int = 17,
) -> Path:
    """Export ``model`` (logits ``(n, 1)``) + sigmoid as ONNX with a dynamic batch axis.

    Input ``images`` float32 ``(n, 3, S, S)``, output ``probability`` float32 ``(n,)``. The model's
    ``metadata_props`` say how to feed it: ``makeway.format`` (:data:`ONNX_FORMAT`), ``input_size``,
    ``threshold``, ``channel_order`` (RGB), ``layout`` (NCHW), ``scale`` (1/255), ``mean``/``std``
    (comma-separated, per channel after scaling), ``arch``, ``width``, ``training``. Written
    all-or-nothing.
    """

    path = Path(path)
    wrapped = _WithSigmoid(copy.deepcopy(model).cpu().eval())
    dummy = torch.zeros(2, 3, input_size, input_size)
    with atomic_path(path) as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # the TorchScript exporter is "legacy"
        torch.onnx.export(
            wrapped,
            (dummy,),
            str(tmp),
            input_names=["images"],
            output_names=["probability"],
            dynamic_axes={"images": {0: "batch"}, "probability": {0: "batch"}},
            opset_version=opset,
            dynamo=False,
        )
        write_onnx_metadata(
            tmp,
            {
                "makeway.format": ONNX_FORMAT,
                "input_size": str(int(input_size)),
                "threshold": repr(float(threshold)),
                "channel_order": "RGB",
                "layout": "NCHW",
                "scale": repr(1.0 / 255.0),
                "mean": ",".join(repr(v) for v in MEAN_RGB),
                "std": ",".join(repr(v) for v in STD_RGB),
                "arch": arch,
                "width": str(int(width)),
                "training": training,
            },
        )
    return path


def write_onnx_metadata(path: Path, meta: dict[str, str]) -> None:
    """Replace the metadata properties of the ONNX model at ``path`` by ``meta`` (in place)."""
    import onnx

    proto = onnx.load(str(path))
    del proto.metadata_props[:]
    for key, value in meta.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(proto, str(path))


# ------------------------------------------------------------------------------- study adapter


class SmallCNNPixels:
    """The small CNN as a classifier of the classical study (SPEC §2) on the ``pixels`` feature.

    ``fit(x, y)`` / ``predict`` / ``predict_proba`` take the study's flattened 128×128 BGR pixels in
    [0, 1] (``(n, 49152)``, :func:`makeway.perceive.vision.features.pixels`) and reshape them into
    images for a :class:`CNNClassifier` (``arch="small_cnn"``, input 128, the default augmentation
    and schedule, ``epochs`` at most).
    """

    def __init__(self, *, size: int = 128, epochs: int = 15, n_jobs: int = 1, seed: int = 0) -> None:
        self.size = int(size)
        self.clf = CNNClassifier(
            "small_cnn", input_size=self.size, width=16, epochs=epochs, lr=1e-3, num_threads=n_jobs, seed=seed
        )
        self.classes_ = np.array([0, 1])

    def _images(self, x: np.ndarray) -> np.ndarray:
        arr = np.asarray(x, dtype=np.float32)
        if arr.ndim != 2 or arr.shape[1] != self.size * self.size * 3:
            raise ValueError(
                f"small_cnn takes the 'pixels' feature ({self.size}×{self.size}×3 = "
                f"{self.size * self.size * 3} values per crop), got shape {arr.shape}"
            )
        img = np.clip(np.rint(arr * 255.0), 0, 255).astype(np.uint8)
        return img.reshape(len(arr), self.size, self.size, 3)

    def fit(self, x: np.ndarray, y: np.ndarray) -> SmallCNNPixels:
        self.clf.fit(self._images(x), y)
        return self

    def predict_proba(self, x: np.ndarray) -> np.ndarray:
        p = self.clf.predict_proba(self._images(x))
        return np.stack([1.0 - p, p], axis=1)

    def predict(self, x: np.ndarray) -> np.ndarray:
        return (self.predict_proba(x)[:, 1] >= self.clf.threshold).astype(np.int64)


def teacher_targets(
    pools: Sequence[str | Path],
    teacher: str,
    input_size: int,
    held_out: Sequence[Any],
    progress: bool = True,
    *,
    model: Any = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """Distillation data: the crops of the unlabelled folders ``pools`` at ``input_size`` px with the
    ``teacher``'s probabilities (soft targets) and decisions (a shipped crop classifier name or a model
    file), leaving out crops that are near-duplicates of a crop in the held-out sets ``held_out``
    (:class:`~makeway.sense.crops.CropSet`; they would leak the test set into training) and
    unreadable files. ``model`` is the teacher already loaded (default: loaded here). Returns
    ``(images, probabilities, labels, description)``.

    Raises:
        InputError: a pool folder or the teacher cannot be read (every pool is listed before any work).
    """
    from makeway.perceive.vision.ev_classifier import load_crop_classifier
    from makeway.progress import progress_bar
    from makeway.sense.crops import CropSet, near_duplicates_of
    from makeway.train.mining import list_pool, score_pool

    paths_in = [Path(p) for p in pools]
    files = [f for pool in paths_in for f in list_pool(pool)]  # every pool checked before any work
    if model is None:
        model = load_crop_classifier(teacher)
    with progress_bar(
        "teacher on the unlabelled crops", len(files), enabled=progress, unit="crops"
    ) as advance:
        paths, probs, unreadable = score_pool(files, model, advance=advance)
    crops = CropSet(paths=tuple(paths), labels=np.zeros(len(paths), dtype=np.int64))
    reference = [test.load_images(64, cache=False) for test in held_out]
    leak = (
        near_duplicates_of(crops.load_images(64, cache=False), np.concatenate(reference))
        if reference and len(crops)
        else np.zeros(len(crops), dtype=bool)
    )
    keep = np.flatnonzero(~leak)
    labels = (probs[keep] >= model.threshold).astype(np.int64)
    where = ", ".join("/".join(p.parts[-2:]) for p in paths_in)
    note = (
        f"unlabelled {where}: {len(keep)} crops with soft targets from the "
        f"teacher {teacher} ({int(labels.sum())} judged EV; {int(leak.sum())} near-duplicates of held-out "
        f"crops and {len(unreadable)} unreadable files left out)"
    )
    images = crops.subset(keep).load_images(input_size, cache=False)
    return images, probs[keep].astype(np.float64), labels, note


def train_crop_cnn(
    data: Sequence[str | Path],
    out: str | Path,
    *,
    arch: str,
    threshold: float = 0.5,
    seed: int = 0,
    pretrained: str | Path | None = None,
    epochs: int = 30,
    input_size: int = 64,
    width: int = 16,
    lr: float = 1e-4,
    min_lr: float = 1e-5,
    patience: int = 3,
    batch_size: int = 32,
    box_jitter: bool = True,
    pos_oversample: int = 1,
    neg_downsample: int = 1,
    threads: int = 2,
    unlabelled: Sequence[str | Path] | None = None,
    teacher: str = "default",
    match_quality: bool = False,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> CropTrainingRun:
    """Train a CNN crop classifier (``arch`` of :data:`ARCHS`; :class:`CNNClassifier` explains the
    settings: ``input_size`` and ``width`` in px and channels, Adam ``lr`` with a plateau schedule
    stopping below ``min_lr``, positive-only box jitter, over/undersampling) on the crop folders
    ``data``; write ``out`` (``.onnx``; for ``effnet_ft`` a ``.npz`` delta on the package's
    ImageNet weights, :func:`makeway.train.effnet.export_delta`, trained with
    :class:`~makeway.train.effnet.StrongAugment`) and the checkpoint beside it (``.pt``). On ev_crops only the
    training part is used, and the committed held-out part is scored afterwards through ONNX Runtime.
    With ``unlabelled`` crop folders, the ``teacher``'s probabilities on them are trained on too
    (:func:`teacher_targets`). ``match_quality``: each folder's positive crops are first made as
    soft as its negatives (:func:`makeway.train.crop_quality.match_positive_quality`; each folder
    is one source). ``log`` receives a line per data set, per epoch (with ``progress``) and for the
    files written.

    Raises:
        ValueError: an unknown ``arch`` (lists the known ones).
        InputError: a crop folder, the teacher or ``pretrained`` cannot be read (the folders are read
            before any training).
    """
    from makeway.eval.classification import operating_point_metrics
    from makeway.perceive.vision.cnn_classifier import OnnxCropClassifier
    from makeway.sense.crops import near_duplicate_groups, read_crop_folder, training_split

    def say(line: str) -> None:
        if log is not None:
            log(line)

    if arch not in ARCHS:
        raise ValueError(f"unknown --arch {arch!r}; choose logreg, {', '.join(ARCHS)}")
    teacher_model = None
    if unlabelled:  # a bad teacher fails before any crop is read
        from makeway.perceive.vision.ev_classifier import load_crop_classifier

        teacher_model = load_crop_classifier(teacher)
    out = Path(out)
    delta = arch == "effnet_ft"  # shipped as a delta on the package's weights (train.effnet)
    if delta:
        onnx_path = out.with_suffix(".npz")
    else:
        onnx_path = out if out.suffix.lower() == ".onnx" else out.with_suffix(".onnx")
    ckpt_path = onnx_path.with_suffix(".pt")
    augment = None if box_jitter else Augment(box_jitter=None)
    if delta:
        from makeway.train.effnet import StrongAugment

        augment = StrongAugment() if box_jitter else StrongAugment(box_jitter=None)
    clf = CNNClassifier(
        arch,
        input_size=input_size,
        width=width,
        epochs=epochs,
        batch_size=batch_size,
        lr=lr,
        min_lr=min_lr,
        patience=patience,
        augment=augment,
        pos_oversample=pos_oversample,
        neg_downsample=neg_downsample,
        threshold=threshold,
        pretrained=pretrained,
        num_threads=threads,
        seed=seed,
    )
    sets = [(Path(folder), read_crop_folder(folder)) for folder in data]  # all read before any work
    xs: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    gs: list[np.ndarray] = []
    parts: list[str] = []
    held: list[tuple[Any, Path]] = []
    for k, (folder, crops) in enumerate(sets):
        split = training_split(crops)
        if split is not None:
            held.append((crops.subset(split[1]), folder))
            crops = crops.subset(split[0])
            what = "training part (committed holdout excluded)"
        else:
            what = "all"
        say(f"{folder.name}: {what}, {len(crops)} crops ({crops.n_positive} positive)")
        parts.append(f"{folder.name}: {what}, {len(crops)} crops, {crops.n_positive} positive")
        images = crops.load_images(input_size, cache=False)
        groups = crops.groups if crops.groups is not None else near_duplicate_groups(images)
        if match_quality:
            from makeway.train.crop_quality import match_one_source

            images, note = match_one_source(images, crops.labels, seed=seed)
            say(f"{folder.name}: {note}")
            parts[-1] += f", {note}"
        xs.append(images)
        ys.append(crops.labels)
        gs.append(np.asarray([f"{k}:{g}" for g in groups]))
    soft: np.ndarray | None = None
    if unlabelled:
        soft = np.concatenate([np.full(len(y), np.nan) for y in ys])
        pool_images, pool_probs, pool_labels, note = teacher_targets(
            unlabelled, teacher, input_size, [test for test, _ in held], progress, model=teacher_model
        )
        say(note)
        xs.append(pool_images)
        ys.append(pool_labels)
        gs.append(np.asarray([f"pool:{i}" for i in range(len(pool_labels))]))
        soft = np.concatenate([soft, pool_probs])
        parts.append(note)

    def show(row: dict[str, float]) -> None:
        if progress:
            say("  ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()))

    clf.fit(
        np.concatenate(xs),
        np.concatenate(ys),
        np.concatenate(gs),
        soft_targets=soft,
        training="; ".join(parts),
        progress=progress,
        on_epoch=show,
    )
    clf.save(ckpt_path)
    if delta:
        from makeway.perceive.vision.efficientnet_lite import load_effnet_delta
        from makeway.train.effnet import EfficientNetLite0Binary, export_delta

        assert isinstance(clf.model_, EfficientNetLite0Binary)
        export_delta(clf.model_, onnx_path, input_size=input_size, threshold=threshold, training=clf.training)
        runtime = load_effnet_delta(onnx_path, num_threads=threads)
    else:
        clf.export_onnx(onnx_path)
        runtime = OnnxCropClassifier(onnx_path, num_threads=threads)
    say(
        f"{len(clf.history)} epochs; checkpoint → {ckpt_path}; model → {onnx_path} "
        f"({onnx_path.stat().st_size} bytes)"
    )
    scores = []
    for test_set, folder in held:
        probs = runtime.predict_proba(test_set.load_images(runtime.input_size, cache=False))
        scores.append((folder, operating_point_metrics(probs, test_set.labels, runtime.threshold)))
    return CropTrainingRun(model=onnx_path, checkpoint=ckpt_path, held_out=scores)


def export_checkpoint(
    checkpoint: str | Path, out: str | Path, *, threshold: float | None = None
) -> tuple[CNNClassifier, float]:
    """Export the CNN ``checkpoint`` (``.pt``) to ONNX at ``out`` (dynamic batch axis; input size,
    decision ``threshold`` — default: the checkpoint's — and preprocessing in the metadata), then
    load it back through ONNX Runtime as a check. Returns the classifier and the threshold the ONNX
    file states.

    Raises:
        InputError: the checkpoint cannot be read, or ``out`` cannot be written.
        ValueError: ``threshold`` outside (0, 1).
    """
    from makeway.perceive.vision.cnn_classifier import OnnxCropClassifier

    clf = load_checkpoint(checkpoint)
    if threshold is not None:
        if not 0.0 < threshold < 1.0:
            raise ValueError(f"--threshold must be in (0, 1), got {threshold}")
        clf.threshold = float(threshold)
    clf.export_onnx(out)
    return clf, OnnxCropClassifier(out).threshold
