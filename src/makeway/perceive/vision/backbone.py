"""Crop features from the COCO detector's own network: YOLOX-nano feature maps, pooled (issue 3).

A transfer route that needs no ImageNet weights: the YOLOX-nano detector already on disk
(:class:`~makeway.perceive.vision.detectors.YoloxNano`) learnt vehicle appearance on COCO. Its ONNX
graph is rewritten with the ``onnx`` package so that chosen intermediate tensors become the graph's
outputs (the detection head is pruned away), with a symbolic batch and height/width, and every crop
— resized to a square of ``input_size`` pixels, raw BGR 0–255 as YOLOX expects — goes through it in
batches. Each chosen feature map ``(C, h, w)`` is pooled to a vector:

* global average and global max per channel (``2C``);
* with ``grid=2`` also the average of each 2×2 quadrant per channel (``4C`` more, quadrants in
  row-major order).

The vectors of the layers are concatenated in the order given → ``(n, d)`` ``float32``.

Layers (names of :data:`LAYERS`; any tensor name of the graph is accepted too):

========  ==========  ====  ======================================================================
name      tensor      C     what
========  ==========  ====  ======================================================================
dark3     input.175   64    backbone (CSPDarknet) stage 3 output, stride 8 — the FPN's input
dark4     input.283   128   backbone stage 4 output, stride 16
dark5     input.359   256   backbone stage 5 output (after SPP + CSP), stride 32
pan3      input.471   64    PAN output at stride 8 (input of the detection head)
pan4      input.531   128   PAN output at stride 16
pan5      input.591   256   PAN output at stride 32
========  ==========  ====  ======================================================================

The default, ``("dark4", "dark5", "pan5")`` at ``input_size=160`` with global pooling only
(``d = 2 × (128 + 256 + 256) = 1280``), was chosen by 5-fold cross-validation (grouped by
near-duplicate clusters) of a standardised logistic regression on the *training* part of the
ev_crops holdout split only (996 crops; the held-out part was not looked at). CV accuracy at the
best of C ∈ {0.001, 0.01, 0.1}, global pooling:

========================  ======  ======  ======
layers                    160 px  224 px  320 px
========================  ======  ======  ======
dark3 + dark4 + dark5     0.889   0.883   0.890
pan3 + pan4 + pan5        0.843   0.855   –
dark5                     0.849   0.853   –
dark4 + dark5             0.884   0.883   –
dark4 + dark5 + pan5      0.894   0.885   0.892
all six                   0.895   0.886   –
========================  ======  ======  ======

(± about 0.015 between folds.) The 2×2 quadrant averages (``grid=2``) moved CV accuracy by
−0.01…+0.01 and 320 px by at most +0.01 at 5–10× the time, so neither is the default. On 2 CPU
cores the three default layers cost about 0.3 s per 100 crops at 160 px (0.45 s at 224 px).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from makeway.errors import InputError
from makeway.perceive.vision.detectors import resolve_model_path

__all__ = ["DEFAULT_LAYERS", "LAYERS", "BackboneFeatures", "load_pruned_yolox", "prune_to_tensors"]

#: Short names of the useful YOLOX-nano tensors (see the module docstring).
LAYERS: dict[str, str] = {
    "dark3": "input.175",
    "dark4": "input.283",
    "dark5": "input.359",
    "pan3": "input.471",
    "pan4": "input.531",
    "pan5": "input.591",
}

#: The layers chosen by cross-validation on the training part (module docstring).
DEFAULT_LAYERS: tuple[str, ...] = ("dark4", "dark5", "pan5")

_MODEL_FILENAME = "yolox_nano.onnx"
_CHUNK = 16  # on 2 cores, 16 crops a run is ~10 % faster than 64 (cache)


def prune_to_tensors(model: Any, tensors: Sequence[str]) -> Any:
    """Rewrite a single-input ONNX ``model`` in place so that ``tensors`` are its outputs.

    Only the nodes (and initializers) the tensors depend on are kept — for YOLOX-nano the detection
    head goes away — and the input gets a symbolic batch, height and width (axes 0, 2, 3). Shared
    by :class:`BackboneFeatures` and the fine-tuned crop network of :mod:`makeway.train.onnx_graph`.

    Raises:
        ValueError: the graph has several inputs, or no node produces one of ``tensors``.
    """
    import onnx

    graph = model.graph
    if len(graph.input) != 1:
        raise ValueError(f"expected a graph with one input, found {len(graph.input)}")
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


def load_pruned_yolox(model_path: Path, layers: Sequence[str]) -> Any:
    """The YOLOX-nano ONNX model at ``model_path`` pruned to ``layers`` (names of :data:`LAYERS` or
    tensor names), for :class:`BackboneFeatures` and :func:`makeway.train.onnx_graph.yolox_crop_net`.

    Raises:
        InputError: the file is not a valid ONNX model, or not the graph this module knows.
    """
    import onnx

    try:
        model = onnx.load(str(model_path))
    except Exception as exc:  # protobuf decode errors come in several types
        raise InputError(model_path, f"not a valid ONNX model ({type(exc).__name__}: {exc})") from exc
    try:
        return prune_to_tensors(model, [LAYERS.get(name, name) for name in layers])
    except ValueError as exc:
        raise InputError(
            model_path,
            f"not the YOLOX-nano graph this extractor knows: {exc} (known layers: {', '.join(LAYERS)})",
        ) from None


class BackboneFeatures:
    """Pooled YOLOX-nano feature maps of crops (module docstring).

    Args:
        model_path: ``yolox_nano.onnx`` or a folder holding it; ``None`` searches
            :func:`makeway.paths.models_candidates` (as the detectors do).
        layers: names of :data:`LAYERS` or tensor names of the graph, in output order.
        input_size: side of the square network input, a multiple of 32.
        grid: ``1`` global average + max per channel; ``2`` adds the 2×2 quadrant averages.
        num_threads: ONNX Runtime intra-op threads; ``None`` uses ``os.cpu_count()``.

    Raises:
        InputError: the model is missing (the message lists where it looked), is not a valid ONNX
            model, or lacks a requested tensor.
        ValueError: an argument is out of range.

    Not thread-safe in the sense that one session serves all calls; ONNX Runtime itself allows
    concurrent ``run`` calls.
    """

    def __init__(
        self,
        model_path: str | Path | None = None,
        *,
        layers: Sequence[str] = DEFAULT_LAYERS,
        input_size: int = 160,
        grid: int = 1,
        num_threads: int | None = None,
    ) -> None:
        if input_size < 32 or input_size % 32:
            raise ValueError(f"input_size must be a positive multiple of 32, got {input_size}")
        if grid not in (1, 2):
            raise ValueError(f"grid must be 1 or 2, got {grid}")
        if num_threads is not None and num_threads < 1:
            raise ValueError(f"num_threads must be >= 1, got {num_threads}")
        if not layers:
            raise ValueError("layers must name at least one tensor")
        self.layers = tuple(layers)
        self.input_size = int(input_size)
        self.grid = int(grid)
        self.num_threads = int(num_threads) if num_threads is not None else (os.cpu_count() or 1)
        self.model_path = resolve_model_path(_MODEL_FILENAME, model_path)
        self._tensors = [LAYERS.get(name, name) for name in self.layers]
        self._session, self._channels = self._build_session()

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(model_path={str(self.model_path)!r}, layers={self.layers}, "
            f"input_size={self.input_size}, grid={self.grid}, num_threads={self.num_threads})"
        )

    @property
    def dim(self) -> int:
        """Length of one feature vector."""
        per_channel = 2 + (4 if self.grid == 2 else 0)
        return per_channel * sum(self._channels)

    # --------------------------------------------------------------------------------- session

    def _build_session(self) -> tuple[Any, list[int]]:
        import onnxruntime as ort

        model = load_pruned_yolox(self.model_path, self.layers)
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
        return session, [int(o.shape[1]) for o in outs]

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
        return out

    def _pool(self, fmap: np.ndarray) -> np.ndarray:
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
