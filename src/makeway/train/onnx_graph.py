"""Fine-tuning a COCO detector's backbone on crops: an ONNX graph as a trainable torch module (issue 3).

The issue's transfer route without ImageNet weights (SPEC §1): YOLOX-nano and NanoDet-m (on disk
as ONNX only) learnt vehicle appearance on COCO. :mod:`makeway.perceive.vision.backbone` uses their
feature maps frozen, with a linear head. Here the same pruned graph becomes an
:class:`torch.nn.Module` (:class:`OnnxGraph`) whose convolution weights are
:class:`~torch.nn.Parameter` s, so the whole backbone can be trained on the crops and exported back
to ONNX as one file.

:class:`OnnxGraph` interprets a small set of ONNX operators — exactly those in the two backbones
(``Conv`` with batch-norm folded in, ``Sigmoid``, ``Mul``, ``Add``, ``Concat``, ``Slice`` with
constant bounds (YOLOX's Focus stem), ``MaxPool``, nearest ``Resize``, and for NanoDet's
ShuffleNetV2 ``LeakyRelu``, ``Split`` with sizes and the channel shuffle's constant ``Reshape`` +
``Transpose``) — and raises :class:`ValueError` naming any other. Node order is the graph's (ONNX
requires it to be topological).

:class:`BackboneCropNet` puts it together for :class:`~makeway.train.cnn.CNNClassifier`
(``arch="yolox_ft"`` or ``"nanodet_ft"``, :func:`backbone_crop_net`):

* input: the CNN convention of :mod:`makeway.train.cnn` (RGB, ImageNet mean/std), turned back
  inside the network into what the detector expects (BGR 0–255, NanoDet: normalised by its own
  mean/std), so the exported file runs through
  :class:`~makeway.perceive.vision.cnn_classifier.OnnxCropClassifier` like any other crop CNN;
* the backbone's default layers (YOLOX: ``dark4``, ``dark5``, ``pan5``; NanoDet: ``stage2..4``),
  each pooled by global average and global max → batch norm → dropout → one linear unit (logit),
  started from the frozen features' logistic regression ("linear probe, then fine-tune").
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as nnf
from torch import nn

from makeway.errors import InputError

__all__ = ["SUPPORTED_OPS", "BackboneCropNet", "OnnxGraph", "backbone_crop_net", "yolox_crop_net"]

#: ONNX operator types :class:`OnnxGraph` can run.
SUPPORTED_OPS = frozenset(
    {
        "Conv", "Sigmoid", "Mul", "Add", "Concat", "Slice", "MaxPool", "Resize",
        "LeakyRelu", "Reshape", "Transpose", "Split",
    }
)  # fmt: skip


def _attrs(node: Any) -> dict[str, Any]:
    import onnx

    return {a.name: onnx.helper.get_attribute_value(a) for a in node.attribute}


def _symmetric_pads(pads: Sequence[int], where: str) -> tuple[int, int]:
    pads = list(pads) or [0, 0, 0, 0]
    if pads[:2] != pads[2:]:
        raise ValueError(f"{where}: asymmetric pads {pads} are not supported")
    return int(pads[0]), int(pads[1])


class OnnxGraph(nn.Module):
    """A single-input ONNX graph of :data:`SUPPORTED_OPS` as a trainable module (module docstring).

    Args:
        model: an ``onnx.ModelProto`` (already pruned to ``outputs``,
            :func:`~makeway.perceive.vision.backbone.prune_to_tensors`).
        outputs: tensor names returned by :meth:`forward`, in order.

    Convolution weights and biases become parameters (names: the initializer's, with characters
    torch does not allow in names replaced); every other initializer must be a constant operand
    (slice bounds, resize scales).
    """

    def __init__(self, model: Any, outputs: Sequence[str]) -> None:
        from onnx import numpy_helper

        super().__init__()
        graph = model.graph
        self.input_name = graph.input[0].name
        self.outputs = tuple(outputs)
        consts = {i.name: numpy_helper.to_array(i) for i in graph.initializer}
        self.weights = nn.ParameterDict()
        self._keys: dict[str, str] = {}
        self._steps: list[tuple[str, tuple[str, ...], tuple[str, ...], dict[str, Any]]] = []
        unsupported = sorted({n.op_type for n in graph.node} - SUPPORTED_OPS)
        if unsupported:
            raise ValueError(f"ONNX operators not supported by OnnxGraph: {', '.join(unsupported)}")
        for node in graph.node:
            attrs = _attrs(node)
            where = f"{node.op_type} node {node.name or node.output[0]!r}"
            if node.op_type == "Conv":
                for name in node.input[1:]:
                    self._param(name, consts[name])
                ph, pw = _symmetric_pads(attrs.get("pads", []), where)
                spec = {
                    "stride": tuple(attrs.get("strides", (1, 1))),
                    "padding": (ph, pw),
                    "dilation": tuple(attrs.get("dilations", (1, 1))),
                    "groups": int(attrs.get("group", 1)),
                }
                self._steps.append(("Conv", tuple(node.input), tuple(node.output), spec))
            elif node.op_type == "Slice":
                starts, ends, axes, steps = (
                    consts[name].astype(np.int64).tolist() for name in node.input[1:5]
                )
                spec = {"slices": list(zip(axes, starts, ends, steps, strict=True))}
                self._steps.append(("Slice", (node.input[0],), tuple(node.output), spec))
            elif node.op_type == "MaxPool":
                ph, pw = _symmetric_pads(attrs.get("pads", []), where)
                if attrs.get("ceil_mode", 0):
                    raise ValueError(f"{where}: ceil_mode is not supported")
                spec = {
                    "kernel_size": tuple(attrs["kernel_shape"]),
                    "stride": tuple(attrs.get("strides", (1, 1))),
                    "padding": (ph, pw),
                }
                self._steps.append(("MaxPool", (node.input[0],), tuple(node.output), spec))
            elif node.op_type == "Resize":
                if attrs.get("mode", b"nearest") not in (b"nearest", "nearest"):
                    raise ValueError(f"{where}: only nearest resizing is supported")
                scales = consts[node.input[2]].tolist() if len(node.input) > 2 else []
                if len(scales) != 4 or scales[:2] != [1.0, 1.0] or scales[2] != scales[3]:
                    raise ValueError(f"{where}: only constant equal spatial scales are supported")
                self._steps.append(
                    ("Resize", (node.input[0],), tuple(node.output), {"scale": float(scales[2])})
                )
            elif node.op_type == "Concat":
                self._steps.append(
                    ("Concat", tuple(node.input), tuple(node.output), {"axis": int(attrs["axis"])})
                )
            elif node.op_type == "Reshape":  # 0 copies the input's dim (the batch), as ONNX says
                shape = consts[node.input[1]].astype(np.int64).tolist()
                self._steps.append(("Reshape", (node.input[0],), tuple(node.output), {"shape": shape}))
            elif node.op_type == "Transpose":
                perm = [int(v) for v in attrs["perm"]]
                self._steps.append(("Transpose", (node.input[0],), tuple(node.output), {"perm": perm}))
            elif node.op_type == "Split":
                sizes = [int(v) for v in attrs.get("split", [])]
                if not sizes:
                    raise ValueError(f"{where}: only splits with explicit sizes are supported")
                spec = {"axis": int(attrs.get("axis", 0)), "sizes": sizes}
                self._steps.append(("Split", (node.input[0],), tuple(node.output), spec))
            elif node.op_type == "LeakyRelu":
                spec = {"alpha": float(attrs.get("alpha", 0.01))}
                self._steps.append(("LeakyRelu", (node.input[0],), tuple(node.output), spec))
            else:  # Sigmoid, Mul, Add
                self._steps.append((node.op_type, tuple(node.input), tuple(node.output), {}))

    def _param(self, name: str, value: np.ndarray) -> None:
        key = "".join(c if c.isalnum() or c == "_" else "_" for c in name)
        self.weights[key] = nn.Parameter(torch.from_numpy(np.array(value, dtype=np.float32)))
        self._keys[name] = key

    def param_key(self, name: str) -> str:
        """The key in :attr:`weights` of the ONNX initializer ``name`` (``""`` if it is none)."""
        return self._keys.get(name, "")

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        return self.forward_from({self.input_name: x})

    def forward_from(self, env: dict[str, torch.Tensor]) -> list[torch.Tensor]:
        """Run the graph from known tensors: ``env`` maps tensor names to values (the input, or
        intermediate tensors such as a detector's neck outputs); steps whose inputs are not all
        known are skipped, so starting from intermediate tensors runs only what lies after them.
        Returns :attr:`outputs`."""
        env = dict(env)
        w = self.weights
        for op, inputs, outputs, spec in self._steps:
            data = inputs[:1] if op == "Conv" else inputs
            if any(name and name not in env for name in data):
                continue
            if op == "Split":
                for name, part in zip(
                    outputs, torch.split(env[inputs[0]], spec["sizes"], spec["axis"]), strict=True
                ):
                    env[name] = part
                continue
            if op == "Conv":
                bias = w[self._keys[inputs[2]]] if len(inputs) > 2 and inputs[2] else None
                out = nnf.conv2d(env[inputs[0]], w[self._keys[inputs[1]]], bias, **spec)
            elif op == "Sigmoid":
                out = torch.sigmoid(env[inputs[0]])
            elif op == "Mul":
                out = env[inputs[0]] * env[inputs[1]]
            elif op == "Add":
                out = env[inputs[0]] + env[inputs[1]]
            elif op == "Concat":
                out = torch.cat([env[i] for i in inputs], dim=spec["axis"])
            elif op == "Slice":
                out = env[inputs[0]]
                for axis, start, end, step in spec["slices"]:
                    index = [slice(None)] * out.dim()
                    index[axis] = slice(start, end, step)
                    out = out[tuple(index)]
            elif op == "MaxPool":
                out = nnf.max_pool2d(env[inputs[0]], **spec)
            elif op == "LeakyRelu":
                out = nnf.leaky_relu(env[inputs[0]], spec["alpha"])
            elif op == "Reshape":
                src = env[inputs[0]]
                out = src.reshape([src.shape[i] if d == 0 else d for i, d in enumerate(spec["shape"])])
            elif op == "Transpose":
                out = env[inputs[0]].permute(spec["perm"])
            else:  # Resize
                out = nnf.interpolate(env[inputs[0]], scale_factor=spec["scale"], mode="nearest")
            env[outputs[0]] = out
        return [env[name] for name in self.outputs]


class BackboneCropNet(nn.Module):
    """A detector backbone (trainable) → pooled layers → batch norm → dropout → one logit.

    Input: normalised RGB ``(n, 3, S, S)`` as in :mod:`makeway.train.cnn`; ``S`` a multiple of 32.
    Inside, it is turned back into what the detector expects (BGR 0–255, normalised by the
    backbone's mean and standard deviation where it has them).
    """

    def __init__(
        self,
        graph: OnnxGraph,
        channels: Sequence[int],
        dropout: float = 0.2,
        *,
        bgr_mean: Sequence[float] | None = None,
        bgr_inv_std: Sequence[float] | None = None,
    ) -> None:
        from makeway.train.cnn import MEAN_RGB, STD_RGB

        super().__init__()
        self.backbone = graph
        dim = 2 * int(sum(channels))
        self.norm = nn.BatchNorm1d(dim)
        self.drop = nn.Dropout(dropout)
        self.fc = nn.Linear(dim, 1)
        self.mean: torch.Tensor
        self.std: torch.Tensor
        self.bgr_mean: torch.Tensor
        self.bgr_inv_std: torch.Tensor
        self.register_buffer("mean", torch.tensor(MEAN_RGB).view(1, 3, 1, 1) * 255.0)
        self.register_buffer("std", torch.tensor(STD_RGB).view(1, 3, 1, 1) * 255.0)
        self.register_buffer("bgr_mean", torch.tensor(list(bgr_mean or (0.0, 0.0, 0.0))).view(1, 3, 1, 1))
        self.register_buffer(
            "bgr_inv_std", torch.tensor(list(bgr_inv_std or (1.0, 1.0, 1.0))).view(1, 3, 1, 1)
        )

    def train(self, mode: bool = True) -> BackboneCropNet:
        """As :meth:`torch.nn.Module.train`, but the head's batch norm keeps the statistics
        :meth:`linear_probe` set (it stays in eval mode)."""
        super().train(mode)
        self.norm.eval()
        return self

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """Pooled backbone features ``(n, 2·ΣC)`` (average then max per layer, the frozen head's)."""
        bgr = (x * self.std + self.mean).flip(1)
        maps = self.backbone((bgr - self.bgr_mean) * self.bgr_inv_std)
        return torch.cat([torch.cat([m.mean(dim=(2, 3)), m.amax(dim=(2, 3))], dim=1) for m in maps], dim=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc(self.drop(self.norm(self.features(x))))

    def linear_probe(self, x: torch.Tensor, labels: np.ndarray, C: float = 0.1, batch: int = 64) -> None:
        """Start the head where the frozen backbone's best linear model is ("linear probe, then
        fine-tune"): batch norm set to the features' mean and variance (identity affine), ``fc`` to a
        logistic regression (inverse regularisation ``C``, the shipped head's) on the standardised
        features of the normalised crops ``x``."""
        from sklearn.linear_model import LogisticRegression

        was_training = self.training
        self.eval()
        with torch.no_grad():
            feats = torch.cat([self.features(x[i : i + batch]) for i in range(0, len(x), batch)])
            mean, var = feats.mean(dim=0), feats.var(dim=0, unbiased=False)
            assert self.norm.running_mean is not None and self.norm.running_var is not None
            self.norm.running_mean.copy_(mean)
            self.norm.running_var.copy_(var)
            self.norm.weight.fill_(1.0)
            self.norm.bias.zero_()
            z = ((feats - mean) / torch.sqrt(var + self.norm.eps)).numpy()
            probe = LogisticRegression(C=C, max_iter=5000).fit(z, np.asarray(labels).ravel())
            self.fc.weight.copy_(torch.from_numpy(probe.coef_.astype(np.float32)))
            self.fc.bias.copy_(torch.from_numpy(probe.intercept_.astype(np.float32)))
        self.train(was_training)


def backbone_crop_net(
    backbone: str = "yolox_nano",
    input_size: int = 160,
    model_path: str | Path | None = None,
    layers: Sequence[str] | None = None,
    dropout: float = 0.2,
) -> BackboneCropNet:
    """:class:`BackboneCropNet` from a registered detector's ONNX file on disk (its COCO weights as
    the start; :data:`~makeway.perceive.vision.backbone.BACKBONES`).

    Raises:
        InputError: the model file is missing or is not the graph the backbone spec knows.
        ValueError: unknown backbone, or ``input_size`` is not a positive multiple of 32.
    """
    from makeway.perceive.vision.backbone import BACKBONES, load_pruned_backbone
    from makeway.perceive.vision.detectors import resolve_model_path

    if backbone not in BACKBONES:
        raise ValueError(f"unknown backbone {backbone!r}; registered: {', '.join(BACKBONES)}")
    if input_size < 32 or input_size % 32:
        raise ValueError(
            f"input_size must be a positive multiple of 32 for a detector backbone, got {input_size}"
        )
    spec = BACKBONES[backbone]
    path = resolve_model_path(spec.filename, model_path)
    names = tuple(layers or spec.default_layers)
    model = load_pruned_backbone(spec, path, names, input_size)
    try:
        graph = OnnxGraph(model, [spec.layers.get(n, n) for n in names])
    except ValueError as exc:
        raise InputError(path, str(exc)) from None
    with torch.no_grad():  # one pass only to read each layer's channel count
        outs = graph(torch.zeros((1, 3, input_size, input_size)))
    return BackboneCropNet(
        graph, [int(o.shape[1]) for o in outs], dropout=dropout, bgr_mean=spec.mean, bgr_inv_std=spec.inv_std
    )


def yolox_crop_net(
    input_size: int = 160,
    model_path: str | Path | None = None,
    layers: Sequence[str] | None = None,
    dropout: float = 0.2,
) -> BackboneCropNet:
    """:func:`backbone_crop_net` of YOLOX-nano (``--arch yolox_ft``)."""
    return backbone_crop_net("yolox_nano", input_size, model_path, layers, dropout)
