"""Training of the lit-light detector (issue 23 item 6): data, network, loss, training loop, ONNX export.

**Data** (:func:`load_split`): every label file ``src/makeway/data/lights/*.csv`` (read with
:func:`makeway.train.light_labels.read_labels`), checked frames only. Frames are letterboxed to the
network's input (:func:`makeway.perceive.vision.light_cnn.letterbox`, 640×384 by default) when loaded.
The split is by source (:data:`SPLITS`): no clip is in two splits; the ``ambulance_yolo`` images are
train except those listed in ``src/makeway/data/ambulance_yolo_held_out.txt``, which are test. A
label file of an unknown source is left out (and named in the run's log).

**Networks** (:func:`build_net`, ``TrainConfig.arch``): seed 004's colour-attention block
(:class:`ColourAttention`: HSV masks of the emergency colours, ``x' = x + x·mask``, on the image
before the backbone; a switch turns it off for the ablation), then

* ``yolox`` (:class:`YoloxLightNet`, the default): YOLOX-nano's stem, ``dark2`` (stride 4) and
  ``dark3`` (stride 8) with their COCO weights (COCO has traffic lights and cars), run as a
  trainable module (:class:`makeway.train.onnx_graph.OnnxGraph`) and fine-tuned at a lower
  learning rate; ``dark3`` upsampled ×2 plus ``dark2`` feed the head;
* ``small`` (:class:`LightNet`): a small convolutional backbone from scratch down to stride 16 with
  a top-down path back to stride 4;

and a CenterNet-style head at stride 4: a centre heat map (one class: lit emergency light; the
colour is read from the pixels at runtime, :func:`makeway.perceive.vision.light_cnn.box_colour`),
the box's log width and height, and the centre's sub-cell offset.

**Loss**: the penalty-reduced focal loss of CenterNet on the heat map (Gaussian targets around each
box centre, σ from the box size), L1 on log size and offset at the centre cells.

**Training** (:func:`train`): random square crops (``TrainConfig.crop``) of the letterboxed frames —
half centred near a labelled light, a quarter on a labelled hard negative (a rejected proposal:
paint, tail lights, signs), a quarter anywhere — optionally with real lit-lamp patches of the
training frames pasted in (``paste``), through :func:`makeway.train.light_augment.augment` (with the
day → night change ``night_lamps``); AdamW, one-cycle learning rate, a fixed number of steps. When
the validation split has lit lights, the step with the best validation F1 (checked every
``eval_every`` steps, at the best threshold of :data:`THRESHOLDS`) is kept with that threshold as
the operating point; otherwise (or when no check reaches ``TrainConfig.min_val_tp`` true positives)
the last step and the fixed ``TrainConfig.threshold``.
"""

from __future__ import annotations

import copy
import json
import math
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as nnf
from torch import nn

from makeway.atomic import atomic_path
from makeway.errors import InputError
from makeway.perceive.vision.light_cnn import LIGHTS_ONNX_FORMAT, decode
from makeway.perceive.vision.light_colour import WIDE_HSV
from makeway.train.cnn import write_onnx_metadata
from makeway.train.light_augment import AugmentConfig, augment, lamp_patches, paste_lamps
from makeway.train.light_split import SPLITS, LightFrame, label_files, load_split, split_of

__all__ = [
    "ARCHS",
    "ATTENTION_HSV",
    "SPLITS",
    "ColourAttention",
    "LightFrame",
    "LightNet",
    "TrainConfig",
    "YoloxLightNet",
    "best_f1_threshold",
    "build_net",
    "export_onnx",
    "label_files",
    "load_split",
    "split_of",
    "train",
]

#: HSV ranges (OpenCV units: H 0–179, S, V 0–255) of the colour-attention mask per colour: blue, red
#: (with the magenta band and the orange edge of a red bloom), amber, and white — a near-white
#: clipped core, which is how the centre of a lit bulb looks.
ATTENTION_HSV: dict[str, list[tuple[int, int, int, int]]] = {
    "blue": list(WIDE_HSV["blue"]),
    "red": list(WIDE_HSV["red"]),
    "amber": list(WIDE_HSV["amber"]),
    "white": [(0, 179, 0, 245)],
}


# ----------------------------------------------------------------------------------------- network
def _hsv_cv(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """RGB ``(n, 3, h, w)`` in [0, 1] → OpenCV-unit H (0–180), S (0–255), V (0–255), each
    ``(n, 1, h, w)``, with ONNX-exportable ops (max, min, where, division)."""
    r, g, b = x[:, 0:1], x[:, 1:2], x[:, 2:3]
    v = torch.maximum(torch.maximum(r, g), b)
    mn = torch.minimum(torch.minimum(r, g), b)
    d = v - mn
    s = d / torch.clamp(v, min=1e-6)  # 0 where v = 0 (then d = 0)
    dd = torch.clamp(d, min=1e-6)
    h_r = 60.0 * (g - b) / dd
    h_g = 120.0 + 60.0 * (b - r) / dd
    h_b = 240.0 + 60.0 * (r - g) / dd
    h = torch.where(v == r, h_r, torch.where(v == g, h_g, h_b))
    h = torch.where(h < 0, h + 360.0, h)
    h = h * (d > 0).to(h.dtype)
    return h / 2.0, s * 255.0, v * 255.0


class ColourAttention(nn.Module):
    """Seed 004's colour attention: ``x' = x + x·mask``, ``mask`` 1 where a pixel's HSV falls in any
    range of the chosen colours (:data:`ATTENTION_HSV`), else 0. Input and output RGB ``(n, 3, h, w)``
    in [0, 1] (the output up to 2). ``enabled=False`` passes ``x`` through (the ablation)."""

    def __init__(self, colours: Sequence[str] = ("blue", "red", "white"), enabled: bool = True) -> None:
        super().__init__()
        bad = [c for c in colours if c not in ATTENTION_HSV]
        if bad:
            raise ValueError(f"unknown attention colours {bad}; choose from {', '.join(ATTENTION_HSV)}")
        self.colours = tuple(colours)
        self.enabled = bool(enabled)
        ranges = [r for c in self.colours for r in ATTENTION_HSV[c]]
        self.register_buffer("ranges", torch.tensor(ranges, dtype=torch.float32).reshape(-1, 4))

    def mask(self, x: torch.Tensor) -> torch.Tensor:
        """The attention mask ``(n, 1, h, w)``: 1.0 inside the colour ranges, else 0.0."""
        h, s, v = _hsv_cv(x)
        # compare in integer-like units as OpenCV does (its H, S, V are rounded to whole numbers)
        h, s, v = torch.round(h), torch.round(s), torch.round(v)
        m: torch.Tensor | None = None
        ranges: torch.Tensor = self.ranges  # type: ignore[assignment]
        for i in range(ranges.shape[0]):
            lo, hi, smin, vmin = ranges[i, 0], ranges[i, 1], ranges[i, 2], ranges[i, 3]
            inside = ((h >= lo) & (h <= hi) & (s >= smin) & (v >= vmin)).to(x.dtype)
            m = inside if m is None else torch.maximum(m, inside)
        assert m is not None
        return m

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.enabled:
            return x
        return x + x * self.mask(x)


def _cbr(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, stride, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True)
    )


class LightNet(nn.Module):
    """Colour attention → backbone (strides 2, 4, 8, 16) → top-down path to stride 4 → heads.

    Input RGB ``(n, 3, H, W)`` in [0, 1] (``H``, ``W`` multiples of 16). Outputs (training form):
    heat-map logits ``(n, 1, H/4, W/4)``, log size ``(n, 2, …)`` (ln px of the input) and offset
    ``(n, 2, …)`` (cells)."""

    stride = 4

    def __init__(
        self,
        width: int = 16,
        attention: bool = True,
        attention_colours: Sequence[str] = ("blue", "red", "white"),
    ) -> None:
        super().__init__()
        w = width
        self.attention = ColourAttention(attention_colours, enabled=attention)
        self.stem = _cbr(3, w, 2)  # /2
        self.s4 = nn.Sequential(_cbr(w, 2 * w, 2), _cbr(2 * w, 2 * w))  # /4
        self.s8 = nn.Sequential(_cbr(2 * w, 4 * w, 2), _cbr(4 * w, 4 * w))  # /8
        self.s16 = nn.Sequential(_cbr(4 * w, 6 * w, 2), _cbr(6 * w, 6 * w))  # /16
        self.lat8 = nn.Conv2d(4 * w, 6 * w, 1)
        self.up8 = _cbr(6 * w, 4 * w)
        self.lat4 = nn.Conv2d(2 * w, 4 * w, 1)
        self.up4 = _cbr(4 * w, 2 * w)
        self.head = _cbr(2 * w, 2 * w)
        self.heat = nn.Conv2d(2 * w, 1, 1)
        self.size = nn.Conv2d(2 * w, 2, 1)
        self.offset = nn.Conv2d(2 * w, 2, 1)
        assert self.heat.bias is not None and self.size.bias is not None
        nn.init.constant_(self.heat.bias, -4.6)  # start at p ≈ 0.01 (CenterNet)
        nn.init.constant_(self.size.bias, math.log(8.0))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        x = self.attention(x)
        f2 = self.stem(x)
        f4 = self.s4(f2)
        f8 = self.s8(f4)
        f16 = self.s16(f8)
        p8 = self.up8(nnf.interpolate(f16, scale_factor=2.0, mode="nearest") + self.lat8(f8))
        p4 = self.up4(nnf.interpolate(p8, scale_factor=2.0, mode="nearest") + self.lat4(f4))
        h = self.head(p4)
        return self.heat(h), self.size(h), torch.sigmoid(self.offset(h))


class YoloxLightNet(nn.Module):
    """Colour attention → YOLOX-nano's stem, ``dark2`` (stride 4) and ``dark3`` (stride 8) with their
    COCO weights (:class:`~makeway.train.onnx_graph.OnnxGraph`, fine-tuned) → ``dark3`` upsampled ×2
    plus ``dark2`` → CenterNet head at stride 4 (as :class:`LightNet`).

    Input RGB ``(n, 3, H, W)`` in [0, 1] (``H``, ``W`` multiples of 8); the attention block acts on
    it, then the image is turned into what YOLOX expects (BGR 0–255; attended pixels up to 510).
    Outputs as :class:`LightNet`. ``model_path``: the YOLOX-nano ONNX file (default: found like the
    detectors' files, ``yolox_nano.onnx``)."""

    stride = 4

    def __init__(
        self,
        head_width: int = 48,
        attention: bool = True,
        attention_colours: Sequence[str] = ("blue", "red", "white"),
        model_path: str | Path | None = None,
    ) -> None:
        from makeway.perceive.vision.backbone import BACKBONES, load_pruned_backbone
        from makeway.perceive.vision.detectors import resolve_model_path
        from makeway.train.onnx_graph import OnnxGraph

        super().__init__()
        spec = BACKBONES["yolox_nano"]
        path = resolve_model_path(spec.filename, model_path)
        names = [spec.layers["dark2"], spec.layers["dark3"]]
        model = load_pruned_backbone(spec, path, names, 416)
        try:
            self.backbone = OnnxGraph(model, names)
        except ValueError as exc:
            raise InputError(path, str(exc)) from None
        hw = head_width
        self.attention = ColourAttention(attention_colours, enabled=attention)
        self.lat8 = _cbr(64, hw)
        self.lat4 = nn.Conv2d(32, hw, 1)
        self.up4 = _cbr(hw, hw)
        self.head = _cbr(hw, hw)
        self.heat = nn.Conv2d(hw, 1, 1)
        self.size = nn.Conv2d(hw, 2, 1)
        self.offset = nn.Conv2d(hw, 2, 1)
        assert self.heat.bias is not None and self.size.bias is not None
        nn.init.constant_(self.heat.bias, -4.6)
        nn.init.constant_(self.size.bias, math.log(8.0))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        x = self.attention(x)
        d2, d3 = self.backbone(x.flip(1) * 255.0)
        p4 = self.up4(nnf.interpolate(self.lat8(d3), scale_factor=2.0, mode="nearest") + self.lat4(d2))
        h = self.head(p4)
        return self.heat(h), self.size(h), torch.sigmoid(self.offset(h))


#: Network architectures of :class:`TrainConfig` ``arch``.
ARCHS = ("yolox", "small")


def build_net(cfg: TrainConfig) -> nn.Module:
    """The untrained network of ``cfg.arch``: ``yolox`` (:class:`YoloxLightNet`, COCO-pretrained
    backbone) or ``small`` (:class:`LightNet` from scratch)."""
    if cfg.arch == "yolox":
        return YoloxLightNet(cfg.head_width, cfg.attention, cfg.attention_colours)
    if cfg.arch == "small":
        return LightNet(cfg.width, cfg.attention, cfg.attention_colours)
    raise ValueError(f"unknown arch {cfg.arch!r}; choose from {', '.join(ARCHS)}")


class _Deploy(nn.Module):
    """The exported form: sigmoid heat reduced to its 3×3 local maxima, size, offset."""

    def __init__(self, net: nn.Module) -> None:
        super().__init__()
        self.net = net

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        logits, size, offset = self.net(x)
        heat = torch.sigmoid(logits)
        peak = nnf.max_pool2d(heat, 3, 1, 1)
        heat = heat * (heat >= peak).to(heat.dtype)
        return heat, size, offset


def deploy_outputs(net: nn.Module, x: torch.Tensor) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the exported ONNX returns for ``x``, computed in torch (numpy arrays)."""
    with torch.no_grad():
        heat, size, offset = _Deploy(net.eval())(x)
    return heat.numpy(), size.numpy(), offset.numpy()


# ----------------------------------------------------------------------------------------- targets
def make_targets(
    boxes: np.ndarray, height: int, width: int, stride: int = 4
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """CenterNet targets for one image of ``height × width`` input pixels: heat ``(1, h, w)``
    (Gaussians, 1 at each centre cell), size ``(2, h, w)`` (ln w, ln h), offset ``(2, h, w)`` and the
    centre-cell mask ``(1, h, w)``; ``h = height/stride``, ``w = width/stride``."""
    h, w = height // stride, width // stride
    heat = np.zeros((1, h, w), np.float32)
    size = np.zeros((2, h, w), np.float32)
    off = np.zeros((2, h, w), np.float32)
    mask = np.zeros((1, h, w), np.float32)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    for x1, y1, x2, y2 in boxes:
        bw, bh = max(x2 - x1, 1.0), max(y2 - y1, 1.0)
        cx, cy = (x1 + x2) / 2 / stride, (y1 + y2) / 2 / stride
        ix, iy = min(int(cx), w - 1), min(int(cy), h - 1)
        if ix < 0 or iy < 0:
            continue
        sigma = max(0.6, math.sqrt(bw * bh) / stride / 4.0)
        g = np.exp(-((xx - ix) ** 2 + (yy - iy) ** 2) / (2 * sigma**2))
        heat[0] = np.maximum(heat[0], g)
        heat[0, iy, ix] = 1.0
        size[:, iy, ix] = (math.log(bw), math.log(bh))
        off[:, iy, ix] = (cx - ix, cy - iy)
        mask[0, iy, ix] = 1.0
    return heat, size, off, mask


def focal_loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """CenterNet's penalty-reduced focal loss (α 2, β 4), normalised by the number of centres."""
    p = torch.sigmoid(logits).clamp(1e-4, 1 - 1e-4)
    pos = target.eq(1).float()
    neg = 1 - pos
    pos_loss = -torch.log(p) * (1 - p) ** 2 * pos
    neg_loss = -torch.log(1 - p) * p**2 * (1 - target) ** 4 * neg
    n = pos.sum().clamp(min=1.0)
    return (pos_loss.sum() + neg_loss.sum()) / n


# ----------------------------------------------------------------------------------------- training
@dataclass
class TrainConfig:
    """Settings of :func:`train`. ``arch`` the network (:data:`ARCHS`); ``steps`` optimiser steps of
    ``batch`` crops of ``crop`` px; ``attention`` switches the colour-attention block (False: the
    ablation); ``threads`` torch threads; ``eval_every`` steps between validation checks (when val
    has lights); ``backbone_lr`` the pretrained backbone's learning rate as a fraction of ``lr``;
    ``paste``, ``night_lamps``, ``swap_red_blue``, ``night`` the probabilities of those
    augmentations (:mod:`makeway.train.light_augment`); ``threshold`` the operating threshold used
    when validation cannot choose one: it has no lit lights, or no check reaches ``min_val_tp``
    true positives (a choice resting on a handful of matches is noise)."""

    arch: str = "yolox"
    steps: int = 1500
    batch: int = 8
    crop: int = 256
    lr: float = 2e-3
    backbone_lr: float = 0.3
    weight_decay: float = 1e-4
    width: int = 16
    head_width: int = 48
    attention: bool = True
    attention_colours: tuple[str, ...] = ("blue", "red", "white")
    input_width: int = 640
    input_height: int = 384
    threads: int = 1
    seed: int = 0
    eval_every: int = 250
    threshold: float = 0.3
    swap_red_blue: float = 0.0
    night: float = 0.0
    paste: float = 0.0
    night_lamps: float = 0.0
    min_val_tp: int = 10


def _sample_crop(frame: LightFrame, crop: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    h, w = frame.image.shape[:2]
    u = rng.random()
    if u < 0.5 and len(frame.boxes):
        b = frame.boxes[rng.integers(len(frame.boxes))]
        cx, cy = (b[0] + b[2]) / 2, (b[1] + b[3]) / 2
        cx += rng.uniform(-0.35, 0.35) * crop
        cy += rng.uniform(-0.35, 0.35) * crop
    elif u < 0.75 and len(frame.negatives):
        b = frame.negatives[rng.integers(len(frame.negatives))]
        cx, cy = (
            (b[0] + b[2]) / 2 + rng.uniform(-0.3, 0.3) * crop,
            (b[1] + b[3]) / 2 + rng.uniform(-0.3, 0.3) * crop,
        )
    else:
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
    x0 = int(np.clip(cx - crop / 2, 0, max(0, w - crop)))
    y0 = int(np.clip(cy - crop / 2, 0, max(0, h - crop)))
    img = np.zeros((crop, crop, 3), np.uint8)
    part = frame.image[y0 : y0 + crop, x0 : x0 + crop]
    img[: part.shape[0], : part.shape[1]] = part
    boxes = frame.boxes - np.array([x0, y0, x0, y0], np.float64)
    if len(boxes):
        cxs, cys = (boxes[:, 0] + boxes[:, 2]) / 2, (boxes[:, 1] + boxes[:, 3]) / 2
        inside = (cxs >= 0) & (cxs < crop) & (cys >= 0) & (cys < crop)
        boxes = boxes[inside]
        boxes[:, [0, 2]] = np.clip(boxes[:, [0, 2]], 0, crop)
        boxes[:, [1, 3]] = np.clip(boxes[:, [1, 3]], 0, crop)
    return img, boxes.reshape(-1, 4)


def _batch(
    frames: Sequence[LightFrame],
    cfg: TrainConfig,
    rng: np.random.Generator,
    aug: AugmentConfig,
    patches: list[tuple[np.ndarray, np.ndarray]] | None = None,
) -> tuple[torch.Tensor, ...]:
    pos = [f for f in frames if len(f.boxes)]
    imgs, heats, sizes, offs, masks = [], [], [], [], []
    for _ in range(cfg.batch):
        pool = pos if (pos and rng.random() < 0.6) else frames
        f = pool[int(rng.integers(len(pool)))]
        img, boxes = _sample_crop(f, cfg.crop, rng)
        if patches and cfg.paste > 0 and rng.random() < cfg.paste:
            img, boxes = paste_lamps(img, boxes, patches, rng)
        img, boxes, _ = augment(img, boxes, rng, aug)
        heat, size, off, mask = make_targets(boxes, cfg.crop, cfg.crop)
        imgs.append(img[..., ::-1].astype(np.float32).transpose(2, 0, 1) / 255.0)
        heats.append(heat)
        sizes.append(size)
        offs.append(off)
        masks.append(mask)
    return tuple(torch.from_numpy(np.stack(a)) for a in (imgs, heats, sizes, offs, masks))


def predict_frames(
    net: nn.Module, frames: Sequence[LightFrame], threshold: float, stride: int = 4
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Boxes (letterboxed input pixels) and scores per frame from the torch network."""
    out = []
    net.eval()
    for f in frames:
        x = torch.from_numpy(f.image[..., ::-1].astype(np.float32).transpose(2, 0, 1)[None] / 255.0)
        heat, size, off = deploy_outputs(net, x)
        out.append(decode(heat[0, 0], size[0], off[0], stride=stride, scale=1.0, threshold=threshold))
    return out


#: Thresholds tried on validation for the operating point (best F1).
THRESHOLDS = tuple(round(0.05 * k, 2) for k in range(1, 19))


def best_f1_threshold(
    preds: Sequence[tuple[np.ndarray, np.ndarray]], gt: Sequence[np.ndarray]
) -> tuple[float, float, float, float, int]:
    """``(F1, threshold, precision, recall, true positives)`` at the threshold of
    :data:`THRESHOLDS` with the best array-level F1 (IoU ≥ 0.5), ties to the highest (the same
    validation detections with the stricter threshold); F1 0, threshold ``nan`` and 0 true
    positives when no threshold has one."""
    from makeway.eval.detection import precision_recall

    best: tuple[float, float, float, float, int] = (0.0, float("nan"), 0.0, 0.0, 0)
    for t in THRESHOLDS:
        p, r, tp, _nd, _ng = precision_recall(
            [b for b, _ in preds], [s for _, s in preds], list(gt), score_threshold=t
        )
        if tp == 0:
            continue
        f1 = 2 * p * r / (p + r)
        if f1 >= best[0]:
            best = (f1, t, p, r, int(tp))
    return best


def _val_f1(net: nn.Module, frames: Sequence[LightFrame]) -> tuple[float, float, float, float, int]:
    preds = predict_frames(net, frames, THRESHOLDS[0])
    return best_f1_threshold(preds, [f.boxes for f in frames])


def train(
    train_frames: Sequence[LightFrame],
    val_frames: Sequence[LightFrame],
    cfg: TrainConfig,
    *,
    progress: Callable[[int, int, float], None] | None = None,
) -> tuple[nn.Module, dict[str, Any]]:
    """Train the network of ``cfg.arch`` (:func:`build_net`; module docstring); returns the model and
    a log dict (config, losses, validation F1 per check with its best threshold, the chosen step and
    threshold, seconds). The operating threshold (``log["threshold"]``) is the best-F1 one on
    validation at the chosen step, or ``cfg.threshold`` when validation has no lit lights or no true
    positive at any threshold."""
    if not train_frames:
        raise InputError("lights labels", "no checked training frames (see docs/data_card_lights.md)")
    if not any(len(f.boxes) for f in train_frames):
        raise InputError("lights labels", "the training split has no lit-light boxes")
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    old_threads = torch.get_num_threads()
    torch.set_num_threads(cfg.threads)
    net = build_net(cfg)
    backbone = [p for n, p in net.named_parameters() if n.startswith("backbone.")]
    rest = [p for n, p in net.named_parameters() if not n.startswith("backbone.")]
    groups = [{"params": rest, "lr": cfg.lr}]
    max_lr = [cfg.lr]
    if backbone:
        groups.append({"params": backbone, "lr": cfg.lr * cfg.backbone_lr})
        max_lr.append(cfg.lr * cfg.backbone_lr)
    opt = torch.optim.AdamW(groups, lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.OneCycleLR(
        opt, max_lr=max_lr, total_steps=max(cfg.steps, 20), pct_start=0.1
    )
    aug = AugmentConfig(p_swap_red_blue=cfg.swap_red_blue, p_night=cfg.night, p_night_lamps=cfg.night_lamps)
    patches = (
        lamp_patches([f.image for f in train_frames], [f.boxes for f in train_frames])
        if cfg.paste > 0
        else None
    )
    val_has_lights = any(len(f.boxes) for f in val_frames)
    log: dict[str, Any] = {
        "config": asdict(cfg),
        "losses": [],
        "val_f1": [],
        "val_has_lights": val_has_lights,
    }
    best = (-1.0, 0, copy.deepcopy(net.state_dict()), float("nan"))
    t0 = time.perf_counter()
    running = 0.0
    try:
        for step in range(1, cfg.steps + 1):
            net.train()
            x, heat_t, size_t, off_t, mask_t = _batch(train_frames, cfg, rng, aug, patches)
            logits, size, off = net(x)
            n = mask_t.sum().clamp(min=1.0)
            loss = (
                focal_loss(logits, heat_t)
                + 0.5 * (torch.abs(size - size_t) * mask_t).sum() / n
                + (torch.abs(off - off_t) * mask_t).sum() / n
            )
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            running = 0.98 * running + 0.02 * float(loss.detach()) if step > 1 else float(loss.detach())
            if step % 50 == 0:
                log["losses"].append([step, round(running, 4)])
            if progress is not None:
                progress(step, cfg.steps, running)
            if val_has_lights and (step % cfg.eval_every == 0 or step == cfg.steps):
                f1, thr, p, r, tp = _val_f1(net, val_frames)
                log["val_f1"].append(
                    [step, round(f1, 4), thr if math.isfinite(thr) else None, round(p, 4), round(r, 4), tp]
                )
                if tp >= cfg.min_val_tp and f1 > best[0]:
                    best = (f1, step, copy.deepcopy(net.state_dict()), thr)
    finally:
        torch.set_num_threads(old_threads)
    if val_has_lights and best[0] > 0:
        net.load_state_dict(best[2])
        log["chosen_step"] = best[1]
        log["threshold"] = best[3]
        log["threshold_from"] = "validation best F1"
    else:  # validation cannot choose: the last step and the fixed threshold
        log["chosen_step"] = cfg.steps
        log["threshold"] = cfg.threshold
        log["threshold_from"] = (
            f"fixed (validation never reached {cfg.min_val_tp} true positives)"
            if val_has_lights
            else "fixed (no validation lights)"
        )
    log["seconds"] = round(time.perf_counter() - t0, 1)
    net.eval()
    return net, log


# ----------------------------------------------------------------------------------------- export
def export_onnx(
    net: nn.Module,
    path: str | Path,
    cfg: TrainConfig,
    *,
    training: str = "",
    opset: int = 17,
    threshold: float | None = None,
) -> Path:
    """Export the deploy form (:class:`_Deploy`) as ONNX: input ``images`` float32
    ``(1, 3, input_height, input_width)`` RGB in [0, 1]; outputs ``heat``, ``size``, ``offset``
    (:mod:`makeway.perceive.vision.light_cnn`). Metadata: ``makeway.format``, ``input_width``,
    ``input_height``, ``stride``, ``threshold`` (``threshold``, else ``cfg.threshold``),
    ``attention`` (the colours, or ``off``), ``arch``, ``training``. Written all-or-nothing."""

    path = Path(path)
    deploy = _Deploy(copy.deepcopy(net).cpu().eval())
    dummy = torch.zeros(1, 3, cfg.input_height, cfg.input_width)
    with atomic_path(path) as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            deploy,
            (dummy,),
            str(tmp),
            input_names=["images"],
            output_names=["heat", "size", "offset"],
            opset_version=opset,
            dynamo=False,
        )
        write_onnx_metadata(
            tmp,
            {
                "makeway.format": LIGHTS_ONNX_FORMAT,
                "input_width": str(cfg.input_width),
                "input_height": str(cfg.input_height),
                "stride": str(LightNet.stride),
                "threshold": repr(float(cfg.threshold if threshold is None else threshold)),
                "arch": cfg.arch,
                "attention": ",".join(cfg.attention_colours) if cfg.attention else "off",
                "channel_order": "RGB",
                "scale": repr(1.0 / 255.0),
                "training": training,
            },
        )
    return path


def log_json(log: dict[str, Any]) -> str:
    """The training log as one JSON line (finite numbers only)."""
    return json.dumps(log, allow_nan=False)
