"""Framework A's detector: YOLOX-nano fine-tuned to two classes on CPU (seed 001; issue 24, item 3).

**Network.** The whole shipped YOLOX-nano graph becomes torch through
:class:`~makeway.train.onnx_graph.OnnxGraph`, cut at the head's raw per-level tensors
(:data:`YOLOX_HEAD`): the regression and objectness convolutions' outputs (kept with their COCO
weights) and the *input* of the 80-class convolutions. Three new 1×1 convolutions give two class
logits per cell: class 0 = emergency vehicle, class 1 = other vehicle. They start from COCO rows:
class 1 from ``car`` (most of the other vehicles are cars) and class 0 from ``truck`` — on the
training images the shipped detector labels the boxes that match an ambulance ``truck`` more often
than anything else (:func:`coco_class_of_ambulances` counts them; the figure is in the model card).
The backbone and the neck (PAN) stay frozen with their COCO weights; the decoupled head (stems,
class and regression branches, the three prediction convolutions) is trained. That choice is the
CPU budget's: with a frozen neck the neck's outputs of each augmented view are computed once with
ONNX Runtime (:func:`neck_views`) and every epoch runs only the head in torch — a full forward and
backward pass of the network on 2 shared cores took ~2 s per 8 images at 320 px, ~45 min for 12
epochs. The COCO neck already separates trucks, buses and cars; the head learns which of those
boxes are emergency vehicles.

**Loss** as YOLOX: GIoU loss on the decoded boxes (weight 5), BCE on objectness over every cell, BCE
on the class logits of the positive cells with target ``one_hot × IoU``; the sum is divided by the
number of positive cells. **Assignment: SimOTA** (YOLOX's): a ground-truth box's candidates are
the cells whose centre is inside it or within 2.5 strides of its centre; cost = class BCE of
``sqrt(sigmoid(cls)·sigmoid(obj))`` + 3·(−log IoU) + 10⁵ unless the cell is both inside the box and
near its centre; each box takes its ``k`` cheapest cells, ``k`` = the sum of its 10 best IoUs
(at least 1); a cell claimed by several boxes stays with the cheapest.

**Data** (:func:`build_dataset`): ``ambulance_yolo/valid`` minus the committed held-out images
(:data:`HELD_OUT_FILE`, never trained or tuned on): class 0 from the YOLO
labels; class 1 pseudo-labels from the shipped YOLOX-nano (car, motorcycle, bus, truck, score ≥
0.4, class-agnostic NMS) that do not overlap an ambulance box (IoU ≤ 0.3 and at most half of the
pseudo box inside one). A validation part is taken out by source photo (Roboflow copies share the
stem before ``.rf.``): SHA-256 of ``"fwa-val:" + source`` below :data:`VAL_FRACTION`. Epoch and
operating point are chosen on it only.

**Augmentation** (:func:`augment_sample`): random scale 0.5–1.5 and placement on the 416×416 canvas
(pad 114; boxes less than 40 % visible dropped), horizontal flip, HSV jitter, brightness/contrast
and noise (:func:`~makeway.train.light_augment.photometric`), Gaussian blur and JPEG
re-compression.

:func:`train_framework_a` trains, keeps the epoch with the best validation mAP50, picks the
operating point (the ``ev_score`` threshold with the best F1 on validation) and exports
(:func:`export_ev_detector`) the file :class:`~makeway.perceive.vision.ev_detector.EVDetector`
reads. The weights derive from YOLOX-nano (Megvii, Apache-2.0).
"""

from __future__ import annotations

import hashlib
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
import torch.nn.functional as nnf
from torch import nn

from makeway.errors import InputError
from makeway.sense.crops import AMBULANCE_YOLO_HELD_OUT

__all__ = [
    "INPUT_SIZE",
    "TRAIN_PARTS",
    "VAL_FRACTION",
    "YOLOX_HEAD",
    "EVDetNet",
    "Sample",
    "TrainResult",
    "augment_sample",
    "build_dataset",
    "coco_class_of_ambulances",
    "draw_view",
    "export_ev_detector",
    "giou",
    "letterbox",
    "mosaic_sample",
    "simota_assign",
    "train_framework_a",
    "yolox_loss",
]

INPUT_SIZE = 416
#: What :func:`train_framework_a` trains: ``head`` (backbone and neck frozen, their outputs cached;
#: the CPU budget) or ``full`` (every layer, freshly augmented views every epoch; a GPU's budget).
TRAIN_PARTS = ("head", "full")
STRIDES = (8, 16, 32)
VAL_FRACTION = 0.2
#: The committed held-out images of ``ambulance_yolo/valid`` (the file
#: :mod:`makeway.apps.evaluate_detector` scores on): never read by training.
HELD_OUT_FILE = AMBULANCE_YOLO_HELD_OUT
_PAD = 114.0
_COCO_CAR, _COCO_TRUCK = 2, 7

#: Tensor names in YOLOX-nano's ONNX graph (the Megvii export on disk) per level (stride 8, 16, 32):
#: ``cls_feat`` the input of ``head.cls_preds.k``, ``reg`` and ``obj`` the raw outputs of
#: ``head.reg_preds.k`` / ``head.obj_preds.k`` (before the graph's sigmoid and concatenation),
#: ``cls_w`` the 80-class convolution's weight name; ``neck``: the PAN outputs (the head's inputs,
#: ``pan3``/``pan4``/``pan5`` of :mod:`makeway.perceive.vision.backbone`).
YOLOX_HEAD: dict[str, Any] = {
    "cls_feat": ("input.631", "input.703", "input.775"),
    "reg": ("onnx::Concat_1062", "onnx::Concat_1104", "onnx::Concat_1146"),
    "obj": ("onnx::Sigmoid_1063", "onnx::Sigmoid_1105", "onnx::Sigmoid_1147"),
    "cls_w": ("head.cls_preds.0", "head.cls_preds.1", "head.cls_preds.2"),
    "neck": ("input.471", "input.531", "input.591"),
}


# ----------------------------------------------------------------------------------------- network


class EVDetNet(nn.Module):
    """YOLOX-nano with a 2-class head (module docstring). Input raw BGR 0–255 ``(n, 3, H, W)``,
    ``H, W`` multiples of 32. :meth:`forward` returns per level ``(reg, obj_logit, cls_logits)``
    shaped ``(n, 4, h, w)``, ``(n, 1, h, w)``, ``(n, 2, h, w)``."""

    def __init__(self, graph: Any, cls_weight: Sequence[torch.Tensor], cls_bias: Sequence[torch.Tensor]):
        super().__init__()
        self.graph = graph
        self.cls = nn.ModuleList()
        for w, b in zip(cls_weight, cls_bias, strict=True):
            conv = nn.Conv2d(w.shape[1], 2, 1)
            assert conv.bias is not None
            with torch.no_grad():
                conv.weight.copy_(w)
                conv.bias.copy_(b)
            self.cls.append(conv)

    def forward(self, x: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
        return self._levels(self.graph(x))

    def head(self, neck: Sequence[torch.Tensor]) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
        """The same outputs from the neck's three feature maps (:data:`YOLOX_HEAD` ``neck``): only
        the head runs (what training does on cached neck features)."""
        names = YOLOX_HEAD["neck"]
        return self._levels(self.graph.forward_from(dict(zip(names, neck, strict=True))))

    def _levels(self, outs: list[torch.Tensor]) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
        feats, regs, objs = outs[0:3], outs[3:6], outs[6:9]
        return [(r, o, conv(f)) for f, r, o, conv in zip(feats, regs, objs, self.cls, strict=True)]

    @classmethod
    def from_yolox(cls, model_path: str | Path | None = None) -> EVDetNet:
        """Build from the YOLOX-nano ONNX file (searched as the detectors search theirs).

        Raises:
            InputError: the file is missing or is not the YOLOX-nano graph :data:`YOLOX_HEAD` names.
        """
        import onnx
        from onnx import numpy_helper

        from makeway.perceive.vision.backbone import prune_to_tensors
        from makeway.perceive.vision.detectors import resolve_model_path
        from makeway.train.onnx_graph import OnnxGraph

        path = resolve_model_path("yolox_nano.onnx", model_path)
        try:
            full = onnx.load(str(path))
        except Exception as exc:
            raise InputError(path, f"not a valid ONNX model ({type(exc).__name__})") from None
        inits = {i.name: numpy_helper.to_array(i) for i in full.graph.initializer}
        try:
            rows = (_COCO_TRUCK, _COCO_CAR)
            weights = [torch.from_numpy(inits[f"{n}.weight"][list(rows)].copy()) for n in YOLOX_HEAD["cls_w"]]
            biases = [torch.from_numpy(inits[f"{n}.bias"][list(rows)].copy()) for n in YOLOX_HEAD["cls_w"]]
            tensors = [*YOLOX_HEAD["cls_feat"], *YOLOX_HEAD["reg"], *YOLOX_HEAD["obj"]]
            graph = OnnxGraph(prune_to_tensors(full, tensors), tensors)
        except (KeyError, ValueError) as exc:
            raise InputError(path, f"not the YOLOX-nano graph Framework A is built on ({exc})") from None
        return cls(graph, weights, biases)


def _flatten(levels: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]) -> torch.Tensor:
    """Per-level outputs → ``(n, cells, 7)`` raw ``reg(4), obj_logit, cls_logits(2)``."""
    return torch.cat([torch.cat(lv, dim=1).flatten(2) for lv in levels], dim=2).transpose(1, 2)


class _Export(nn.Module):
    """The exported graph: YOLOX's output layout with two classes (scores sigmoid)."""

    def __init__(self, net: EVDetNet) -> None:
        super().__init__()
        self.net = net

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        raw = _flatten(self.net(x))
        return torch.cat([raw[..., :4], torch.sigmoid(raw[..., 4:])], dim=2)


def grid_of(height: int, width: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Cell ``(column, row)`` ``(cells, 2)`` and stride ``(cells,)`` in the output's order."""
    from makeway.perceive.vision.detectors import _grid

    xy, st = _grid(height, width, 0.0)
    return torch.from_numpy(np.array(xy)), torch.from_numpy(np.array(st))


def decode_boxes(raw: torch.Tensor, xy: torch.Tensor, stride: torch.Tensor) -> torch.Tensor:
    """``(..., cells, 4)`` raw regression → ``x1, y1, x2, y2`` network pixels."""
    centre = (raw[..., 0:2] + xy) * stride[:, None]
    half = 0.5 * torch.exp(raw[..., 2:4].clamp(max=10.0)) * stride[:, None]
    return torch.cat([centre - half, centre + half], dim=-1)


# ------------------------------------------------------------------------------- loss, assignment


def giou(a: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Element-wise ``(iou, giou)`` of two ``(n, 4)`` xyxy box sets."""
    lt = torch.maximum(a[:, :2], b[:, :2])
    rb = torch.minimum(a[:, 2:], b[:, 2:])
    inter = (rb - lt).clamp(min=0).prod(dim=1)
    area_a = (a[:, 2:] - a[:, :2]).clamp(min=0).prod(dim=1)
    area_b = (b[:, 2:] - b[:, :2]).clamp(min=0).prod(dim=1)
    union = area_a + area_b - inter + 1e-9
    iou = inter / union
    hull = (torch.maximum(a[:, 2:], b[:, 2:]) - torch.minimum(a[:, :2], b[:, :2])).clamp(min=0).prod(dim=1)
    return iou, iou - (hull - union) / (hull + 1e-9)


def _pair_iou(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    lt = torch.maximum(a[:, None, :2], b[None, :, :2])
    rb = torch.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = (rb - lt).clamp(min=0).prod(dim=2)
    area_a = (a[:, 2:] - a[:, :2]).clamp(min=0).prod(dim=1)
    area_b = (b[:, 2:] - b[:, :2]).clamp(min=0).prod(dim=1)
    return inter / (area_a[:, None] + area_b[None, :] - inter + 1e-9)


def _no_match(cells: int, device: torch.device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    return (
        torch.zeros(cells, dtype=torch.bool, device=device),
        torch.zeros(0, dtype=torch.long, device=device),
        torch.zeros(0, device=device),
    )


@torch.no_grad()
def simota_assign(
    boxes: torch.Tensor,
    obj_logit: torch.Tensor,
    cls_logit: torch.Tensor,
    gt: torch.Tensor,
    gt_cls: torch.Tensor,
    xy: torch.Tensor,
    stride: torch.Tensor,
    *,
    radius: float = 2.5,
    top_iou: int = 10,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """SimOTA for one image (module docstring).

    Args:
        boxes: ``(cells, 4)`` decoded predictions; ``obj_logit`` ``(cells,)``; ``cls_logit``
            ``(cells, C)``; ``gt`` ``(g, 4)`` xyxy; ``gt_cls`` ``(g,)`` int; ``xy``/``stride``: the
            grid (:func:`grid_of`).

    Returns:
        ``(fg, matched, iou)``: the positive-cell mask ``(cells,)``, the ground-truth index of each
        positive cell and its prediction's IoU with it (both ``(n_fg,)``).
    """
    cells, dev = boxes.shape[0], boxes.device
    if gt.shape[0] == 0:
        return _no_match(cells, dev)
    centre = (xy + 0.5) * stride[:, None]  # (cells, 2)
    in_box = (
        (centre[None, :, 0] > gt[:, None, 0])
        & (centre[None, :, 0] < gt[:, None, 2])
        & (centre[None, :, 1] > gt[:, None, 1])
        & (centre[None, :, 1] < gt[:, None, 3])
    )
    gc = 0.5 * (gt[:, :2] + gt[:, 2:])
    r = radius * stride[None, :]
    in_ctr = ((centre[None, :, 0] - gc[:, None, 0]).abs() < r) & (
        (centre[None, :, 1] - gc[:, None, 1]).abs() < r
    )
    cand = (in_box | in_ctr).any(dim=0)
    idx = torch.nonzero(cand).flatten()
    if idx.numel() == 0:
        return _no_match(cells, dev)
    ious = _pair_iou(gt, boxes[idx])  # (g, c)
    n_cls = cls_logit.shape[1]
    p = (torch.sigmoid(cls_logit[idx]) * torch.sigmoid(obj_logit[idx])[:, None]).sqrt()  # (c, C)
    target = nnf.one_hot(gt_cls.long(), n_cls).float()  # (g, C)
    p_ = p[None].expand(gt.shape[0], -1, -1)
    t_ = target[:, None, :].expand(-1, idx.numel(), -1)
    cls_cost = nnf.binary_cross_entropy(p_.clamp(1e-6, 1 - 1e-6), t_, reduction="none").sum(dim=2)
    both = in_box[:, idx] & in_ctr[:, idx]
    cost = cls_cost + 3.0 * -torch.log(ious + 1e-8) + 1e5 * (~both).float()
    k = torch.topk(ious, min(top_iou, idx.numel()), dim=1).values.sum(dim=1).int().clamp(min=1)
    match = torch.zeros_like(cost, dtype=torch.bool)
    for g in range(gt.shape[0]):
        kk = int(min(int(k[g]), idx.numel()))
        match[g, torch.topk(cost[g], kk, largest=False).indices] = True
    multi = match.sum(dim=0) > 1
    if multi.any():
        best = cost[:, multi].argmin(dim=0)
        match[:, multi] = False
        match[best, torch.nonzero(multi).flatten()] = True
    pos = match.any(dim=0)
    fg = torch.zeros(cells, dtype=torch.bool, device=dev)
    fg[idx[pos]] = True
    matched = match[:, pos].float().argmax(dim=0)
    return fg, matched, ious[matched, torch.nonzero(pos).flatten()]


def yolox_loss(
    raw: torch.Tensor,
    targets: Sequence[tuple[torch.Tensor, torch.Tensor]],
    xy: torch.Tensor,
    stride: torch.Tensor,
    *,
    box_weight: float = 5.0,
) -> tuple[torch.Tensor, dict[str, float]]:
    """YOLOX's loss over a batch (module docstring).

    Args:
        raw: ``(n, cells, 7)`` (:func:`_flatten` of the network's output).
        targets: per image ``(boxes (g, 4) xyxy network pixels, classes (g,))``.

    Returns:
        The scalar loss and its parts (``box``, ``obj``, ``cls``, ``n_fg``) as floats.
    """
    boxes = decode_boxes(raw[..., :4], xy, stride)
    obj_t = torch.zeros(raw.shape[:2], device=raw.device)
    box_losses, cls_losses = [], []
    n_fg = 0
    for i, (gt, gt_cls) in enumerate(targets):
        fg, matched, iou = simota_assign(
            boxes[i].detach(), raw[i, :, 4].detach(), raw[i, :, 5:].detach(), gt, gt_cls, xy, stride
        )
        if not fg.any():
            continue
        obj_t[i, fg] = 1.0
        n_fg += int(fg.sum())
        _, g = giou(boxes[i, fg], gt[matched])
        box_losses.append((1.0 - g).sum())
        cls_t = nnf.one_hot(gt_cls[matched].long(), raw.shape[2] - 5).float() * iou[:, None]
        cls_losses.append(nnf.binary_cross_entropy_with_logits(raw[i, fg, 5:], cls_t, reduction="sum"))
    norm = max(n_fg, 1)
    obj = nnf.binary_cross_entropy_with_logits(raw[..., 4], obj_t, reduction="sum") / norm
    box = torch.stack(box_losses).sum() / norm if box_losses else raw.sum() * 0.0
    cls = torch.stack(cls_losses).sum() / norm if cls_losses else raw.sum() * 0.0
    total = box_weight * box + obj + cls
    parts = {"box": float(box.detach()), "obj": float(obj.detach()), "cls": float(cls.detach())}
    return total, {**parts, "n_fg": float(n_fg)}


# --------------------------------------------------------------------------------------------- data


@dataclass
class Sample:
    """One training image: ``image`` BGR ``uint8``; ``boxes`` ``(g, 4)`` xyxy pixels; ``classes``
    ``(g,)`` (0 EV, 1 other vehicle); ``source`` the Roboflow source photo; ``name`` the file."""

    image: np.ndarray
    boxes: np.ndarray
    classes: np.ndarray
    source: str
    name: str


def in_validation(source: str, fraction: float = VAL_FRACTION) -> bool:
    """Whether a source photo goes to Framework A's validation part (module docstring)."""
    digest = hashlib.sha256(f"fwa-val:{source}".encode()).digest()
    return int.from_bytes(digest[:8], "big") / 2.0**64 < fraction


def _overlaps(
    boxes: np.ndarray, amb: np.ndarray, iou_max: float = 0.3, inside_max: float = 0.5
) -> np.ndarray:
    """Which of ``boxes`` overlap one of the ambulance boxes ``amb`` (IoU > ``iou_max`` or more
    than ``inside_max`` of the box inside one)."""
    if len(amb) == 0 or len(boxes) == 0:
        return np.zeros(len(boxes), bool)
    lt = np.maximum(boxes[:, None, :2], amb[None, :, :2])
    rb = np.minimum(boxes[:, None, 2:], amb[None, :, 2:])
    inter = np.clip(rb - lt, 0, None).prod(axis=2)
    a = np.clip(boxes[:, 2:] - boxes[:, :2], 0, None).prod(axis=1)
    b = np.clip(amb[:, 2:] - amb[:, :2], 0, None).prod(axis=1)
    iou = inter / (a[:, None] + b[None, :] - inter + 1e-9)
    inside = inter / (a[:, None] + 1e-9)
    return np.asarray(((iou > iou_max) | (inside > inside_max)).any(axis=1))


def build_dataset(
    data: str | Path,
    *,
    pseudo_threshold: float = 0.4,
    model_path: str | Path | None = None,
    threads: int | None = None,
    progress: bool = True,
    labels: str = "original",
) -> tuple[list[Sample], list[Sample], dict[str, int]]:
    """``(train, validation, counts)`` from the YOLO set ``data`` (module docstring); the committed
    held-out images are left out before anything is read. ``labels``: the class-0 label set
    (:data:`~makeway.sense.label_corrections.LABEL_SETS`): ``corrected`` applies the committed audit
    of ``ambulance_yolo`` (EVs the export left unlabelled become class 0, not pseudo-labelled other
    vehicles; ``counts["ev_boxes_corrected"]`` counts the boxes it changed).

    Raises:
        InputError: the folder is not a YOLO set, or lacks the committed held-out images (it is not
            ``ambulance_yolo/valid``).
    """
    from makeway.perceive.vision.detectors import VEHICLE_CLASSES, YoloxNano
    from makeway.progress import progress_bar
    from makeway.sense.crops import read_holdout, read_yolo_set, roboflow_source
    from makeway.sense.label_corrections import LabelSet

    truth_set = LabelSet(labels)
    data = Path(data)
    if not data.is_dir():
        raise InputError(data, "YOLO folder not found (expected images/ and labels/)")
    all_images = read_yolo_set(data)
    held = set(read_holdout(HELD_OUT_FILE).names)
    missing = held - {img.path.name for img in all_images}
    if missing:
        raise InputError(
            data,
            f"{len(missing)} of the {len(held)} committed held-out images of ambulance_yolo/valid are not "
            f"here (e.g. {sorted(missing)[0]!r}): this is not the set Framework A is trained on",
        )
    images = [img for img in all_images if img.path.name not in held]
    det = YoloxNano(model_path, score_threshold=pseudo_threshold, classes=VEHICLE_CLASSES,
                    class_agnostic=True, num_threads=threads)  # fmt: skip
    train: list[Sample] = []
    val: list[Sample] = []
    counts = {"images": 0, "ev_boxes": 0, "ev_boxes_corrected": 0, "pseudo_boxes": 0, "pseudo_dropped": 0}
    with progress_bar("pseudo-labelling vehicles", len(images), enabled=progress, unit="images") as bar:
        for item in images:
            image = cv2.imread(str(item.path), cv2.IMREAD_COLOR)
            if image is None:
                raise InputError(item.path, "OpenCV could not decode this image")
            truth = truth_set.boxes(item.path.stem, item.boxes_of(0))
            amb = np.asarray([[b.x1, b.y1, b.x2, b.y2] for b in truth], np.float32).reshape(-1, 4)
            vb, _, _ = det.detect_arrays(image)
            drop = _overlaps(vb, amb)
            other = vb[~drop]
            boxes = np.concatenate([amb, other]).astype(np.float32)
            classes = np.concatenate([np.zeros(len(amb)), np.ones(len(other))]).astype(np.int64)
            source = roboflow_source(item.path.stem)
            sample = Sample(image, boxes, classes, source, item.path.name)
            (val if in_validation(source) else train).append(sample)
            counts["images"] += 1
            counts["ev_boxes"] += len(amb)
            counts["pseudo_boxes"] += len(other)
            counts["pseudo_dropped"] += int(drop.sum())
            bar()
    counts["ev_boxes_corrected"] = truth_set.changed
    counts["train_images"], counts["val_images"] = len(train), len(val)
    counts["train_sources"] = len({s.source for s in train})
    counts["val_sources"] = len({s.source for s in val})
    return train, val, counts


def coco_class_of_ambulances(
    samples: Sequence[Sample], model_path: str | Path | None = None
) -> dict[str, int]:
    """How the shipped YOLOX-nano labels the ambulance boxes of ``samples``: for each class-0 box,
    the COCO vehicle class of the best-scoring detection at IoU ≥ 0.5 (score ≥ 0.1), counted by
    name (``none`` when nothing matches). The evidence for starting class 0 from ``truck``."""
    from makeway.eval.detection import box_iou_matrix
    from makeway.perceive.vision.detectors import COCO_CLASSES, VEHICLE_CLASSES, YoloxNano

    det = YoloxNano(model_path, score_threshold=0.1, classes=VEHICLE_CLASSES)
    out: dict[str, int] = {}
    for s in samples:
        amb = s.boxes[s.classes == 0]
        if not len(amb):
            continue
        boxes, scores, ids = det.detect_arrays(s.image)
        iou = box_iou_matrix(amb, boxes) if len(boxes) else np.zeros((len(amb), 0))
        for row in iou:
            ok = np.flatnonzero(row >= 0.5)
            name = "none" if not ok.size else COCO_CLASSES[int(ids[ok[np.argmax(scores[ok])]])]
            out[name] = out.get(name, 0) + 1
    return out


def letterbox(image: np.ndarray, size: int = INPUT_SIZE) -> tuple[np.ndarray, float]:
    """The runtime's input: resized to fit ``size`` keeping the aspect, top-left on a ``size``² canvas
    of 114; returns the canvas and the scale."""
    h, w = image.shape[:2]
    r = min(size / h, size / w)
    nw, nh = min(size, max(1, round(w * r))), min(size, max(1, round(h * r)))
    canvas = np.full((size, size, 3), 114, np.uint8)
    canvas[:nh, :nw] = cv2.resize(image, (nw, nh), interpolation=cv2.INTER_LINEAR)
    return canvas, r


def _visible(boxes: np.ndarray, classes: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Boxes moved onto a ``size``² canvas, clipped to it; those less than 40 % visible or under
    2 px a side are dropped with their classes."""
    area = np.clip(boxes[:, 2:] - boxes[:, :2], 0, None).prod(axis=1)
    clipped = np.clip(boxes, 0, size)
    vis = np.clip(clipped[:, 2:] - clipped[:, :2], 0, None).prod(axis=1)
    keep = (vis >= 0.4 * np.maximum(area, 1e-9)) & ((clipped[:, 2:] - clipped[:, :2]) >= 2).all(axis=1)
    return clipped[keep], classes[keep]


def augment_sample(
    sample: Sample, rng: np.random.Generator, size: int = INPUT_SIZE, scale: tuple[float, float] = (0.5, 1.5)
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One augmented ``size``² training image with its boxes and classes (module docstring)."""
    from makeway.train.light_augment import photometric

    img = sample.image
    h, w = img.shape[:2]
    r = min(size / h, size / w) * float(rng.uniform(*scale))
    nw, nh = max(8, round(w * r)), max(8, round(h * r))
    resized = cv2.resize(img, (nw, nh), interpolation=cv2.INTER_AREA if r < 1 else cv2.INTER_LINEAR)
    # placement: offset of the resized image on the canvas (negative: the image is cropped)
    ox = int(rng.integers(min(0, size - nw), max(0, size - nw) + 1))
    oy = int(rng.integers(min(0, size - nh), max(0, size - nh) + 1))
    canvas: np.ndarray = np.full((size, size, 3), 114, np.uint8)
    x0, y0 = max(ox, 0), max(oy, 0)
    x1, y1 = min(ox + nw, size), min(oy + nh, size)
    canvas[y0:y1, x0:x1] = resized[y0 - oy : y1 - oy, x0 - ox : x1 - ox]
    boxes, classes = _visible(sample.boxes * r + np.array([ox, oy, ox, oy], np.float32), sample.classes, size)
    if rng.random() < 0.5:
        canvas = np.ascontiguousarray(canvas[:, ::-1])
        boxes = boxes.copy()
        boxes[:, [0, 2]] = size - boxes[:, [2, 0]]
    if rng.random() < 0.7:  # HSV jitter
        hsv = cv2.cvtColor(canvas, cv2.COLOR_BGR2HSV).astype(np.float32)
        hsv[..., 0] = (hsv[..., 0] + rng.uniform(-5, 5)) % 180
        hsv[..., 1] *= rng.uniform(0.6, 1.4)
        hsv[..., 2] *= rng.uniform(0.6, 1.4)
        canvas = cv2.cvtColor(np.clip(hsv, 0, 255).astype(np.uint8), cv2.COLOR_HSV2BGR)
    if rng.random() < 0.3:
        canvas = photometric(canvas, rng)
    if rng.random() < 0.2:
        k = int(rng.choice([3, 5]))
        canvas = cv2.GaussianBlur(canvas, (k, k), 0)
    if rng.random() < 0.3:
        ok, enc = cv2.imencode(".jpg", canvas, [cv2.IMWRITE_JPEG_QUALITY, int(rng.integers(25, 90))])
        dec = cv2.imdecode(enc, cv2.IMREAD_COLOR) if ok else None
        if dec is not None:
            canvas = dec
    return canvas, boxes.astype(np.float32), classes


def mosaic_sample(
    samples: Sequence[Sample], rng: np.random.Generator, size: int = INPUT_SIZE
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """YOLOX's mosaic, simplified: four augmented views (:func:`augment_sample`) tiled on a
    ``2·size`` square, scaled by a random 0.5–1.0 and cut to a random ``size``² window (boxes less
    than 40 % visible dropped). Teaches small and cut-off vehicles from few photos."""
    if len(samples) != 4:
        raise ValueError(f"a mosaic takes 4 samples, got {len(samples)}")
    big = np.full((2 * size, 2 * size, 3), 114, np.uint8)
    parts_b, parts_c = [], []
    for k, s in enumerate(samples):
        img, b, c = augment_sample(s, rng, size)
        ox, oy = (k % 2) * size, (k // 2) * size
        big[oy : oy + size, ox : ox + size] = img
        parts_b.append(b + np.array([ox, oy, ox, oy], np.float32))
        parts_c.append(c)
    f = float(rng.uniform(0.5, 1.0))
    side = round(2 * size * f)
    small = cv2.resize(big, (side, side), interpolation=cv2.INTER_AREA)
    x0 = int(rng.integers(0, side - size + 1))
    y0 = int(rng.integers(0, side - size + 1))
    canvas = np.ascontiguousarray(small[y0 : y0 + size, x0 : x0 + size])
    boxes = np.concatenate(parts_b) * (side / (2 * size)) - np.array([x0, y0, x0, y0], np.float32)
    boxes, classes = _visible(boxes, np.concatenate(parts_c), size)
    return canvas, boxes.astype(np.float32), classes


def draw_view(
    samples: Sequence[Sample], i: int, rng: np.random.Generator, size: int, mosaic: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One training view of ``samples[i]``: with probability ``mosaic`` a mosaic of it and three
    other samples drawn at random (:func:`mosaic_sample`), else :func:`augment_sample` of it alone
    (``mosaic`` 0 draws nothing extra from ``rng``)."""
    if mosaic > 0.0 and rng.random() < mosaic:
        others = rng.choice(len(samples), 3)
        group = [samples[i], *(samples[int(k)] for k in others)]
        order = rng.permutation(4)
        return mosaic_sample([group[int(k)] for k in order], rng, size)
    return augment_sample(samples[i], rng, size)


class _OnlineViews(torch.utils.data.Dataset[tuple[np.ndarray, np.ndarray, np.ndarray]]):
    """Freshly augmented training views for the full fine-tune: item ``i`` of epoch ``epoch`` is a
    view of sample ``i`` (a mosaic with it and three random others, with probability ``mosaic``),
    drawn from a generator seeded by ``(seed, epoch, i)`` — the same views whatever the workers."""

    def __init__(self, samples: Sequence[Sample], size: int, seed: int, mosaic: float) -> None:
        self.samples, self.size, self.seed, self.mosaic = list(samples), size, seed, mosaic
        self.epoch = 0

    def __len__(self) -> int:
        return len(self.samples)

    def __getitem__(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        rng = np.random.default_rng([self.seed, self.epoch, i])
        return draw_view(self.samples, i, rng, self.size, self.mosaic)


def _collate(items: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> tuple[torch.Tensor, list[Any]]:
    images = _to_tensor([it[0] for it in items])
    return images, [(torch.from_numpy(it[1]), torch.from_numpy(it[2])) for it in items]


def _to_tensor(images: Sequence[np.ndarray]) -> torch.Tensor:
    return torch.from_numpy(np.stack(images).transpose(0, 3, 1, 2).astype(np.float32))


# ----------------------------------------------------------------------------------- validation


def _predict(net: EVDetNet, images: Sequence[np.ndarray], batch: int = 8) -> list[np.ndarray]:
    """``(cells, 7)`` exported-layout outputs of letterboxed images (eval mode, no grad), on the
    device the network's weights are on."""
    wrapped = _Export(net)
    device = next(net.parameters()).device
    out: list[np.ndarray] = []
    net.eval()
    with torch.no_grad():
        for i in range(0, len(images), batch):
            out.extend(wrapped(_to_tensor(images[i : i + batch]).to(device)).cpu().numpy())
    return out


def _predict_from_neck(net: EVDetNet, neck: Sequence[np.ndarray], batch: int = 16) -> list[np.ndarray]:
    """As :func:`_predict` from cached neck features (:func:`neck_features`)."""
    out: list[np.ndarray] = []
    net.eval()
    with torch.no_grad():
        for i in range(0, len(neck[0]), batch):
            raw = _flatten(net.head([torch.from_numpy(n[i : i + batch].astype(np.float32)) for n in neck]))
            out.extend(torch.cat([raw[..., :4], torch.sigmoid(raw[..., 4:])], dim=2).numpy())
    return out


def validate(
    net: EVDetNet, samples: Sequence[Sample], neck: Sequence[np.ndarray] | None = None
) -> dict[str, Any]:
    """mAP50 on ``samples`` (class-0 boxes, ranking ``ev_score``, the runtime's 416 px letterbox) and
    the F1-best operating point; ``neck``: the samples' letterboxed neck features when cached."""
    from makeway.eval.detection import detection_metrics, precision_recall
    from makeway.perceive.vision.detectors import _grid
    from makeway.perceive.vision.ev_detector import decode_ev_output

    boxed = [letterbox(s.image) for s in samples]
    preds = _predict(net, [b[0] for b in boxed]) if neck is None else _predict_from_neck(net, neck)
    gxy, gst = _grid(INPUT_SIZE, INPUT_SIZE, 0.0)
    boxes, ranks, gts = [], [], []
    for (_, r), pred, s in zip(boxed, preds, samples, strict=True):
        b, _, ev, _ = decode_ev_output(pred, gxy, gst, score_threshold=0.05, nms_iou=0.45)
        boxes.append(b / r)
        ranks.append(ev)
        gts.append(s.boxes[s.classes == 0])
    m = detection_metrics(boxes, ranks, gts)
    best = {"f1": -1.0, "threshold": 0.5, "precision": float("nan"), "recall": float("nan")}
    for t in np.round(np.arange(0.05, 0.91, 0.025), 3):
        p, rc, _, _, _ = precision_recall(boxes, ranks, gts, score_threshold=float(t))
        if np.isfinite(p) and np.isfinite(rc) and p + rc > 0:
            f1 = 2 * p * rc / (p + rc)
            if f1 > best["f1"]:
                best = {"f1": f1, "threshold": float(t), "precision": p, "recall": rc}
    return {"map50": m.map50, "map50_95": m.map50_95, **best}


# ------------------------------------------------------------------------------------ neck cache


def neck_session(model_path: str | Path | None = None, threads: int | None = None) -> Any:
    """An ONNX Runtime session of YOLOX-nano pruned to its neck outputs (:data:`YOLOX_HEAD`
    ``neck``), any batch and size; the frozen part of :class:`EVDetNet`, run at ONNX Runtime's speed."""
    import onnx
    import onnxruntime as ort

    from makeway.perceive.vision.backbone import prune_to_tensors
    from makeway.perceive.vision.detectors import resolve_model_path

    path = resolve_model_path("yolox_nano.onnx", model_path)
    model = prune_to_tensors(onnx.load(str(path)), list(YOLOX_HEAD["neck"]))
    opts = ort.SessionOptions()
    if threads is not None:
        opts.intra_op_num_threads = int(threads)
        opts.inter_op_num_threads = 1
    opts.log_severity_level = 3
    return ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])


def neck_features(session: Any, images: Sequence[np.ndarray], batch: int = 8) -> list[np.ndarray]:
    """The three neck maps ``(n, C, h, w)`` (float16, to halve the cache) of same-size BGR images."""
    name = session.get_inputs()[0].name
    parts: list[list[np.ndarray]] = [[], [], []]
    for i in range(0, len(images), batch):
        outs = session.run(None, {name: _to_tensor(images[i : i + batch]).numpy()})
        for k, o in enumerate(outs):
            parts[k].append(o.astype(np.float16))
    return [np.concatenate(p) for p in parts]


def neck_views(
    session: Any,
    samples: Sequence[Sample],
    views: int,
    rng: np.random.Generator,
    size: int,
    *,
    progress: bool = True,
    mosaic: float = 0.0,
) -> tuple[list[np.ndarray], list[tuple[np.ndarray, np.ndarray]]]:
    """``views`` augmented views (:func:`draw_view`; ``mosaic`` the share of mosaics) of every
    sample through the frozen network: the neck maps of all views and their ``(boxes, classes)``
    targets."""
    from makeway.progress import progress_bar

    feats: list[list[np.ndarray]] = [[], [], []]
    targets: list[tuple[np.ndarray, np.ndarray]] = []
    total = views * len(samples)
    with progress_bar(
        "augmented views through the frozen network", total, enabled=progress, unit="images"
    ) as bar:
        for _ in range(views):
            for i in range(0, len(samples), 32):
                items = [
                    draw_view(samples, j, rng, size, mosaic) for j in range(i, min(i + 32, len(samples)))
                ]
                for k, f in enumerate(neck_features(session, [it[0] for it in items])):
                    feats[k].append(f)
                targets.extend((it[1], it[2]) for it in items)
                bar(len(items))
    return [np.concatenate(f) for f in feats], targets


# ------------------------------------------------------------------------------------------ train


@dataclass
class TrainResult:
    """What :func:`train_framework_a` did: the exported file, the chosen epoch and threshold, the
    validation figures, the data counts, the training wall time and per-epoch history."""

    path: Path
    best_epoch: int
    threshold: float
    val: dict[str, Any]
    counts: dict[str, int]
    seconds: float
    history: list[dict[str, float]] = field(default_factory=list)
    ambulance_coco_classes: dict[str, int] = field(default_factory=dict)


def export_ev_detector(net: EVDetNet, path: str | Path, *, threshold: float, training: str = "") -> Path:
    """Write ``net`` as the ONNX file :class:`~makeway.perceive.vision.ev_detector.EVDetector` reads
    (input ``images`` declared ``[1, 3, 416, 416]``, a graph that runs any multiple of 32; output
    ``[1, cells, 7]``; metadata),
    all or nothing."""
    from makeway.atomic import atomic_path
    from makeway.perceive.vision.ev_detector import EV_DET_CLASSES, EV_DET_FORMAT, EV_DET_KIND
    from makeway.train.cnn import write_onnx_metadata

    path = Path(path)
    wrapped = _Export(net).eval()
    dummy = torch.full((1, 3, INPUT_SIZE, INPUT_SIZE), _PAD)
    with atomic_path(path) as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            wrapped,
            (dummy,),
            str(tmp),
            input_names=["images"],
            output_names=["output"],
            dynamic_axes={"images": {2: "height", 3: "width"}, "output": {1: "cells"}},
            opset_version=17,
            dynamo=False,
        )
        import onnx

        proto = onnx.load(str(tmp))
        # Declared 416×416 (what a plain session runs); the graph itself takes any multiple of 32
        # and the runtime relaxes these dims for 16:9 frames.
        dims = proto.graph.input[0].type.tensor_type.shape.dim
        dims[2].dim_value = dims[3].dim_value = INPUT_SIZE
        proto.graph.output[0].type.tensor_type.shape.dim[1].dim_value = sum(
            (INPUT_SIZE // s) ** 2 for s in STRIDES
        )
        onnx.save(proto, str(tmp))
        write_onnx_metadata(
            tmp,
            {
                "makeway_model": EV_DET_KIND,
                "makeway.format": EV_DET_FORMAT,
                "classes": ",".join(EV_DET_CLASSES),
                "threshold": repr(float(threshold)),
                "input_size": str(INPUT_SIZE),
                "channel_order": "BGR",
                "scale": "1",
                "pad_value": "114",
                "letterbox": "top-left",
                "strides": ",".join(str(s) for s in STRIDES),
                "training": training,
                "license": "weights derived from Megvii YOLOX-nano (Apache-2.0)",
            },
        )
    return path


def train_framework_a(
    data: str | Path,
    out: str | Path,
    *,
    epochs: int = 8,
    views: int = 8,
    batch: int = 16,
    train_size: int = 320,
    lr: float = 1e-3,
    head_lr: float = 5e-3,
    seed: int = 0,
    threads: int = 1,
    model_path: str | Path | None = None,
    max_minutes: float | None = None,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
    part: str = "head",
    device: str = "cpu",
    labels: str = "original",
    mosaic: float = 0.0,
    workers: int = 0,
    val_every: int = 1,
) -> TrainResult:
    """Fine-tune Framework A's detector on ``data`` (``ambulance_yolo/valid``) and export it to
    ``out`` (module docstring).

    ``mosaic``: the share of training views that are mosaics (:func:`draw_view`; both parts).
    ``part="full"`` trains every layer (:func:`_fit_full`): each epoch draws fresh augmented views
    in ``workers`` processes, on
    torch ``device`` (``cuda`` for a GPU); AdamW at ``lr`` for the pretrained layers and
    ``head_lr`` for the new class layers, warm-up over the first epoch, cosine decay; validation
    every ``val_every`` epochs. ``labels``: the class-0 label set (:func:`build_dataset`).

    ``part="head"`` (the default): ``views`` augmented views of each training image
    (``train_size``² px; the random scale 0.5–1.5 covers the runtime's 416) go once through the
    frozen backbone and neck (:func:`neck_views`); each epoch then trains the head on all of them
    in random order. AdamW (weight decay 5e-4; the new class convolutions at ``head_lr``),
    warm-up over the first epoch, then cosine decay.
    Validation (at the runtime's 416 px) after every epoch; the best epoch's weights are exported
    with the F1-best ``ev_score`` threshold as the operating point. ``max_minutes`` stops after the
    epoch that passes it.

    Raises:
        InputError: bad data folder or YOLOX-nano file (checked before training starts); ``out``
            not writable.
    """
    from makeway.atomic import check_writable
    from makeway.progress import progress_bar

    say = log or (lambda _line: None)
    out = Path(out)
    check_writable(out, folder=False)
    if train_size < 64 or train_size % 32:
        raise ValueError(f"train_size must be a multiple of 32 of at least 64, got {train_size}")
    if part not in TRAIN_PARTS:
        raise ValueError(f"unknown part {part!r}; one of {', '.join(TRAIN_PARTS)}")
    if not 0.0 <= mosaic <= 1.0:
        raise ValueError(f"mosaic must be a share in [0, 1], got {mosaic}")
    dev = torch.device(device)
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {device!r} asked for, but torch sees no CUDA device")
    torch.set_num_threads(max(1, int(threads)))
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    start = time.perf_counter()
    net = EVDetNet.from_yolox(model_path)
    train, val, counts = build_dataset(
        data, model_path=model_path, threads=threads, progress=progress, labels=labels
    )
    if not train or not val:
        raise InputError(data, "too few source photos for a training and a validation part")
    coco = coco_class_of_ambulances(train, model_path)
    say(f"data: {counts}; ambulance boxes as COCO classes: {coco}")
    if part == "full":
        net.to(dev)
        fit = _fit_full(
            net, train, val, epochs=epochs, batch=batch, size=train_size, lr=lr, head_lr=head_lr,
            seed=seed, workers=workers, mosaic=mosaic, val_every=val_every, max_minutes=max_minutes,
            progress=progress, say=say, start=start,
        )  # fmt: skip
        best, best_epoch, full_history = fit
        net.to("cpu")
        training = (
            f"framework_a full fine-tune of YOLOX-nano: epochs={epochs} best_epoch={best_epoch} "
            f"batch={batch} size={train_size} lr={lr} head_lr={head_lr} mosaic={mosaic} labels={labels} "
            f"seed={seed} device={dev.type}; val mAP50={best['map50']:.4f} P={best['precision']:.4f} "
            f"R={best['recall']:.4f} at ev_score>={best['threshold']:g}"
        )
        export_ev_detector(net, out, threshold=float(best["threshold"]), training=training)
        seconds = time.perf_counter() - start
        threshold = float(best["threshold"])
        return TrainResult(out, best_epoch, threshold, best, counts, seconds, full_history, coco)
    session = neck_session(model_path, threads)
    val_neck = neck_features(session, [letterbox(s.image)[0] for s in val])
    feats, targets = neck_views(session, train, views, rng, train_size, progress=progress, mosaic=mosaic)
    say(f"cached {len(targets)} augmented views; {(time.perf_counter() - start) / 60:.1f} min")
    neck_keys = set(_neck_param_keys(net, model_path))
    for key, param in net.graph.weights.items():
        param.requires_grad_(key not in neck_keys)
    head = list(net.cls.parameters())
    body = [p for p in net.graph.parameters() if p.requires_grad]
    opt = torch.optim.AdamW([{"params": body, "lr": lr}, {"params": head, "lr": head_lr}], weight_decay=5e-4)
    n = len(targets)
    steps_per_epoch = max(1, n // batch)
    total = epochs * steps_per_epoch
    base = [g["lr"] for g in opt.param_groups]
    xy, st = grid_of(train_size, train_size)
    best = validate(net, val, val_neck)
    say(f"before training: validation mAP50 {best['map50']:.3f}")
    best_state = {k: t.detach().clone() for k, t in net.state_dict().items()}
    best_epoch = 0
    history: list[dict[str, float]] = []
    step = 0
    with progress_bar("training Framework A's head", total, enabled=progress, unit="steps") as bar:
        for epoch in range(1, epochs + 1):
            net.train()
            order = rng.permutation(n)
            sums = {"loss": 0.0, "box": 0.0, "obj": 0.0, "cls": 0.0}
            for b in range(steps_per_epoch):
                idx = np.sort(order[b * batch : (b + 1) * batch])
                x = [torch.from_numpy(f[idx].astype(np.float32)) for f in feats]
                tg = [(torch.from_numpy(targets[i][0]), torch.from_numpy(targets[i][1])) for i in idx]
                _step(net, opt, base, (step, total, steps_per_epoch), net.head(x), tg, (xy, st), sums)
                step += 1
                bar()
            v = validate(net, val, val_neck)
            row = _epoch_row(epoch, sums, steps_per_epoch, v, (time.perf_counter() - start) / 60.0, say)
            history.append(row)
            if v["map50"] > best["map50"]:
                best, best_epoch = v, epoch
                best_state = {k: t.detach().clone() for k, t in net.state_dict().items()}
            if max_minutes is not None and row["minutes"] > max_minutes:
                say(f"stopping after epoch {epoch}: over {max_minutes} min")
                break
    net.load_state_dict(best_state)
    training = (
        f"framework_a head on frozen YOLOX-nano neck: epochs={epochs} best_epoch={best_epoch} "
        f"views={views} batch={batch} size={train_size} lr={lr} head_lr={head_lr} labels={labels} "
        f"seed={seed}; "
        f"val mAP50={best['map50']:.4f} P={best['precision']:.4f} R={best['recall']:.4f} "
        f"at ev_score>={best['threshold']:g}"
    )
    export_ev_detector(net, out, threshold=float(best["threshold"]), training=training)
    return TrainResult(
        out, best_epoch, float(best["threshold"]), best, counts, time.perf_counter() - start, history, coco
    )


def _step(
    net: EVDetNet,
    opt: torch.optim.Optimizer,
    base: Sequence[float],
    when: tuple[int, int, int],
    levels: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]],
    targets: Sequence[tuple[torch.Tensor, torch.Tensor]],
    grid: tuple[torch.Tensor, torch.Tensor],
    sums: dict[str, float],
) -> None:
    """One AdamW step on YOLOX's loss of ``levels`` (the network's output for a batch) at ``when`` =
    ``(step, total steps, steps per epoch)``: learning rates ``base`` × warm-up over the first epoch
    × cosine decay; gradients clipped to norm 10; the loss and its parts added to ``sums``.
    ``grid``: the cells' ``(xy, stride)`` (:func:`grid_of`)."""
    step, total, per_epoch = when
    warm = min(1.0, (step + 1) / per_epoch)
    for g, lr0 in zip(opt.param_groups, base, strict=True):
        g["lr"] = lr0 * warm * 0.5 * (1 + np.cos(np.pi * step / max(total, 1)))
    loss, parts = yolox_loss(_flatten(levels), targets, *grid)
    opt.zero_grad()
    loss.backward()
    nn.utils.clip_grad_norm_(net.parameters(), 10.0)
    opt.step()
    sums["loss"] += float(loss.detach())
    for k in ("box", "obj", "cls"):
        sums[k] += parts[k]


def _epoch_row(
    epoch: int,
    sums: dict[str, float],
    steps: int,
    v: dict[str, Any],
    minutes: float,
    say: Callable[[str], None],
) -> dict[str, float]:
    """The history row of an epoch (mean losses, validation figures, minutes so far), also said."""
    row = {"epoch": float(epoch), **{k: x / steps for k, x in sums.items()}}
    row.update({f"val_{k}": float(v[k]) for k in ("map50", "precision", "recall", "threshold")})
    row["minutes"] = minutes
    say(
        f"epoch {epoch}: loss {row['loss']:.3f} (box {row['box']:.3f} obj {row['obj']:.3f} "
        f"cls {row['cls']:.3f}); validation mAP50 {v['map50']:.3f}, P {v['precision']:.3f} "
        f"R {v['recall']:.3f} at {v['threshold']:.3f}; {minutes:.1f} min"
    )
    return row


def _fit_full(
    net: EVDetNet,
    train: Sequence[Sample],
    val: Sequence[Sample],
    *,
    epochs: int,
    batch: int,
    size: int,
    lr: float,
    head_lr: float,
    seed: int,
    workers: int,
    mosaic: float,
    val_every: int,
    max_minutes: float | None,
    progress: bool,
    say: Callable[[str], None],
    start: float,
) -> tuple[dict[str, Any], int, list[dict[str, float]]]:
    """Train every layer of ``net`` (on the device its weights are on) on fresh views each epoch;
    leaves the best validated weights in ``net``. Returns ``(best validation, best epoch,
    history)``."""
    from makeway.progress import progress_bar

    dev = next(net.parameters()).device
    for param in net.graph.weights.values():
        param.requires_grad_(True)
    if len(train) < batch:
        raise ValueError(f"batches of {batch} images, only {len(train)} training images: lower --batch-size")
    views = _OnlineViews(train, size, seed, mosaic)
    gen = torch.Generator().manual_seed(seed)
    loader = torch.utils.data.DataLoader(
        views, batch_size=batch, shuffle=True, drop_last=True, num_workers=max(0, int(workers)),
        collate_fn=_collate, generator=gen, persistent_workers=False,
    )  # fmt: skip
    opt = torch.optim.AdamW(
        [
            {"params": list(net.graph.parameters()), "lr": lr},
            {"params": list(net.cls.parameters()), "lr": head_lr},
        ],
        weight_decay=5e-4,
    )
    steps_per_epoch = max(1, len(views) // batch)
    total = epochs * steps_per_epoch
    base = [g["lr"] for g in opt.param_groups]
    xy, st = (t.to(dev) for t in grid_of(size, size))
    best = validate(net, val)
    say(f"before training: validation mAP50 {best['map50']:.3f}")
    best_state = {k: t.detach().clone() for k, t in net.state_dict().items()}
    best_epoch, step = 0, 0
    history: list[dict[str, float]] = []
    with progress_bar("training Framework A (every layer)", total, enabled=progress, unit="steps") as bar:
        for epoch in range(1, epochs + 1):
            views.epoch = epoch
            net.train()
            sums = {"loss": 0.0, "box": 0.0, "obj": 0.0, "cls": 0.0}
            for images, targets in loader:
                tg = [(b.to(dev), c.to(dev)) for b, c in targets]
                levels = net(images.to(dev))
                _step(net, opt, base, (step, total, steps_per_epoch), levels, tg, (xy, st), sums)
                step += 1
                bar()
            minutes = (time.perf_counter() - start) / 60.0
            over = max_minutes is not None and minutes > max_minutes
            if epoch % max(1, val_every) and epoch != epochs and not over:
                continue
            v = validate(net, val)
            history.append(_epoch_row(epoch, sums, steps_per_epoch, v, minutes, say))
            if v["map50"] > best["map50"]:
                best, best_epoch = v, epoch
                best_state = {k: t.detach().clone() for k, t in net.state_dict().items()}
            if over:
                say(f"stopping after epoch {epoch}: over {max_minutes} min")
                break
    net.load_state_dict(best_state)
    return best, best_epoch, history


def _neck_param_keys(net: EVDetNet, model_path: str | Path | None) -> list[str]:
    """Parameter keys of :attr:`EVDetNet.graph` that belong to the backbone and neck (frozen)."""
    import onnx

    from makeway.perceive.vision.backbone import prune_to_tensors
    from makeway.perceive.vision.detectors import resolve_model_path

    model = prune_to_tensors(
        onnx.load(str(resolve_model_path("yolox_nano.onnx", model_path))), list(YOLOX_HEAD["neck"])
    )
    names = {i.name for i in model.graph.initializer}
    return [net.graph.param_key(name) for name in names if net.graph.param_key(name)]
