"""COCO vehicle detectors on ONNX Runtime: YOLOX-nano and NanoDet-m (SPEC §2).

SPEC §2 (Framework B, the two-stage vision of seeds 001/003, the thesis on two vision frameworks and
its project report: detector of class vehicle → SORT → per-track crop classifier): every frame goes
through a small COCO detector; only the vehicle classes (car 2, motorcycle 3, bus 5, truck 7,
0-based COCO-80) are kept, and the boxes feed the SORT tracker. Two interchangeable models are
registered in :data:`DETECTORS` (in the style of ``pyroomacoustics.doa.algorithms``)::

    det = DETECTORS["yolox_nano"]()              # or DETECTORS["nanodet_m"](model_path)
    boxes, scores, class_ids = det.detect_arrays(frame_bgr)   # the fast path of the pipeline
    detections = det.detect(frame_bgr)                        # list[Detection] for everyone else

Both share one pipeline: letterbox the BGR frame to 416×416 (see below), run the network, decode
only the grid cells whose best allowed class clears ``score_threshold``, clip to the image, then
greedy class-aware NMS in numpy. Grid centres and strides are built once per (input size, centre
offset) and cached. The ONNX Runtime session is created eagerly, so a missing, corrupt or wrong
model raises :class:`~makeway.errors.InputError` at construction, never on the first frame.

Weights are looked up by :func:`resolve_model_path`: an explicit ``model_path`` (the CLI's
``--model``), else each folder of :func:`makeway.paths.models_candidates` (``MAKEWAY_MODELS``, then
``<shared data>/models``) joined with the detector's default file name.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any, ClassVar

import cv2
import numpy as np

from makeway.errors import InputError
from makeway.messages import Box, Detection
from makeway.paths import models_candidates
from makeway.registry import Registry

__all__ = [
    "COCO_CLASSES",
    "DETECTORS",
    "VEHICLE_CLASSES",
    "Detector",
    "NanoDetM",
    "YoloxNano",
    "nms",
    "resolve_model_path",
]

#: The 80 COCO class names in the 0-based order both models were trained with. These are the
#: official COCO-2017 names; the Darknet-style ``coco.names`` next to the weights spells a few of
#: them differently (motorbike, aeroplane, sofa, pottedplant, diningtable, tvmonitor).
COCO_CLASSES: tuple[str, ...] = (
    "person",
    "bicycle",
    "car",
    "motorcycle",
    "airplane",
    "bus",
    "train",
    "truck",
    "boat",
    "traffic light",
    "fire hydrant",
    "stop sign",
    "parking meter",
    "bench",
    "bird",
    "cat",
    "dog",
    "horse",
    "sheep",
    "cow",
    "elephant",
    "bear",
    "zebra",
    "giraffe",
    "backpack",
    "umbrella",
    "handbag",
    "tie",
    "suitcase",
    "frisbee",
    "skis",
    "snowboard",
    "sports ball",
    "kite",
    "baseball bat",
    "baseball glove",
    "skateboard",
    "surfboard",
    "tennis racket",
    "bottle",
    "wine glass",
    "cup",
    "fork",
    "knife",
    "spoon",
    "bowl",
    "banana",
    "apple",
    "sandwich",
    "orange",
    "broccoli",
    "carrot",
    "hot dog",
    "pizza",
    "donut",
    "cake",
    "chair",
    "couch",
    "potted plant",
    "bed",
    "dining table",
    "toilet",
    "tv",
    "laptop",
    "mouse",
    "remote",
    "keyboard",
    "cell phone",
    "microwave",
    "oven",
    "toaster",
    "sink",
    "refrigerator",
    "book",
    "clock",
    "vase",
    "scissors",
    "teddy bear",
    "hair drier",
    "toothbrush",
)

#: car, motorcycle, bus, truck — what SPEC §2 calls "vehicle".
VEHICLE_CLASSES: tuple[int, ...] = (2, 3, 5, 7)

_NUM_CLASSES = len(COCO_CLASSES)
_STRIDES: tuple[int, ...] = (8, 16, 32)
_PAD_VALUE = 114  # letterbox fill, raw BGR 0–255
_PRE_NMS_TOP_K = 1000  # guard against pathological frames; real frames have a few dozen candidates


# ------------------------------------------------------------------------------------------- helpers


def resolve_model_path(filename: str, model_path: str | Path | None) -> Path:
    """The ONNX file to load: ``model_path`` when given, else the first folder holding ``filename``.

    ``model_path`` may be a file or a folder (then ``filename`` inside it is used). Without it, each
    folder of :func:`makeway.paths.models_candidates` is tried in order.

    Raises:
        InputError: nothing was found; the message lists every place that was looked at and how to
            point makeway at the weights (``--model`` or ``MAKEWAY_MODELS``).
    """
    hint = f"pass the .onnx file with --model, or set MAKEWAY_MODELS to the folder that holds {filename}"
    if model_path is not None:
        path = Path(model_path).expanduser()
        if path.is_dir():
            path = path / filename
        if path.is_file():
            return path
        raise InputError(path, f"detector model not found (looked at {path}); {hint}")
    tried = [folder / filename for folder in models_candidates()]
    for cand in tried:
        if cand.is_file():
            return cand
    if tried:
        where = ", ".join(str(p) for p in tried)
    else:
        where = "nowhere: MAKEWAY_MODELS is unset and no shared data folder was found"
    raise InputError(filename, f"detector model not found (looked in: {where}); {hint}")


def nms(boxes: np.ndarray, scores: np.ndarray, iou_threshold: float) -> np.ndarray:
    """Greedy non-maximum suppression.

    Args:
        boxes: ``(n, 4)`` ``x1, y1, x2, y2``.
        scores: ``(n,)``.
        iou_threshold: a box is dropped when its IoU with an already kept, higher-scoring box is
            strictly greater than this.

    Returns:
        The indices of the kept boxes, highest score first (``int64``).
    """
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    scores = np.asarray(scores, dtype=np.float64).reshape(-1)
    if boxes.shape[0] != scores.shape[0]:
        raise ValueError(f"nms: {boxes.shape[0]} boxes but {scores.shape[0]} scores")
    order = np.argsort(-scores, kind="stable")
    x1, y1, x2, y2 = boxes.T
    areas = np.maximum(x2 - x1, 0.0) * np.maximum(y2 - y1, 0.0)
    keep: list[int] = []
    while order.size:
        i = int(order[0])
        keep.append(i)
        rest = order[1:]
        iw = np.minimum(x2[i], x2[rest]) - np.maximum(x1[i], x1[rest])
        ih = np.minimum(y2[i], y2[rest]) - np.maximum(y1[i], y1[rest])
        inter = np.maximum(iw, 0.0) * np.maximum(ih, 0.0)
        union = areas[i] + areas[rest] - inter
        iou = np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)
        order = rest[iou <= iou_threshold]
    return np.asarray(keep, dtype=np.int64)


@functools.lru_cache(maxsize=16)
def _grid(height: int, width: int, offset: float) -> tuple[np.ndarray, np.ndarray]:
    """Cell coordinates ``(n, 2)`` as ``(column + offset, row + offset)`` and their strides ``(n,)``
    for a ``height × width`` network input.

    Levels in stride order 8, 16, 32, each row-major — the order both models emit their cells in.
    The arrays are shared by every detector with the same layout, hence read-only.
    """
    cells: list[np.ndarray] = []
    strides: list[np.ndarray] = []
    for stride in _STRIDES:
        rows, cols = np.mgrid[0 : height // stride, 0 : width // stride]
        cells.append(np.stack([cols.ravel(), rows.ravel()], axis=1) + offset)
        strides.append(np.full(rows.size, stride))
    xy = np.concatenate(cells).astype(np.float32)
    st = np.concatenate(strides).astype(np.float32)
    xy.flags.writeable = False
    st.flags.writeable = False
    return xy, st


def _fmt_shape(shape: Sequence[Any]) -> str:
    return "[" + ", ".join(str(d) for d in shape) + "]"


def _dims_match(found: Sequence[Any], expected: Sequence[int]) -> bool:
    """Whether an ONNX shape matches; symbolic or unknown dims (``str``/``None``) match anything."""
    if len(found) != len(expected):
        return False
    return all(not isinstance(f, int) or f == e for f, e in zip(found, expected, strict=True))


def _check_image(image_bgr: np.ndarray) -> np.ndarray:
    if not isinstance(image_bgr, np.ndarray):
        raise ValueError(f"expected an HxWx3 uint8 BGR image, got {type(image_bgr).__name__}")
    if image_bgr.ndim != 3 or image_bgr.shape[2] != 3 or image_bgr.dtype != np.uint8:
        raise ValueError(
            f"expected an HxWx3 uint8 BGR image, got shape {image_bgr.shape} dtype {image_bgr.dtype}"
        )
    if image_bgr.shape[0] == 0 or image_bgr.shape[1] == 0:
        raise ValueError(f"expected a non-empty HxWx3 uint8 BGR image, got shape {image_bgr.shape}")
    return np.ascontiguousarray(image_bgr)


_EMPTY = (
    np.zeros((0, 4), dtype=np.float32),
    np.zeros((0,), dtype=np.float32),
    np.zeros((0,), dtype=np.int64),
)


# ------------------------------------------------------------------------------------------ detector


class Detector:
    """Base class of the registered COCO detectors.

    SPEC §2 (Framework B: detector of class vehicle → SORT).

    Subclasses set :attr:`name`, :attr:`default_filename` and :attr:`center_offset`, check the
    loaded model's outputs in :meth:`_check_outputs`, fill the input tensor in :meth:`_fill_input`
    and decode the raw outputs in :meth:`_decode`.

    Args:
        model_path: the ``.onnx`` file (or a folder holding :attr:`default_filename`); ``None``
            searches :func:`makeway.paths.models_candidates`.
        score_threshold: minimum score kept (``[0, 1]``).
        nms_iou: IoU above which a lower-scoring box of the same class is suppressed.
        classes: 0-based COCO ids to keep; ``None`` keeps all 80. Each cell keeps only its best
            class among these.
        num_threads: ONNX Runtime intra-op threads; ``None`` uses ``os.cpu_count()``.
        class_agnostic: suppress across classes too. Off by default (class-aware NMS, as SPEC §2
            asks), but note that with class-aware NMS one vehicle sometimes comes out twice, as
            ``car`` and as ``truck``; turn this on when that matters more than the label.
        fit_aspect: for models whose graph does not depend on the input size
            (:attr:`shape_agnostic`), shape the network input to the frame instead of padding it to
            a square: the long side is ``input_size``, the short side the letterboxed size rounded
            up to a multiple of 32. A 16:9 frame then runs at 416×256 instead of 416×416 — 38 %
            fewer pixels, the same detections up to the bottom rows of padding. Needs the ``onnx``
            package to relax the model's declared input shape; falls back to the square input
            when that fails.

    Raises:
        InputError: the model file is missing, not a valid ONNX model, or not the model this
            detector decodes (the message says which shape was expected and which was found).
        ValueError: an argument is out of range.

    Not thread-safe: each instance owns one input buffer; use one detector per thread.
    """

    name: ClassVar[str] = ""
    default_filename: ClassVar[str] = ""
    input_size: ClassVar[int] = 416
    #: Grid cell centre = ``(column + center_offset, row + center_offset) * stride``.
    center_offset: ClassVar[float] = 0.0
    #: Whether the graph runs on any input size that is a multiple of 32 (no size-bound reshapes).
    shape_agnostic: ClassVar[bool] = False

    def __init__(
        self,
        model_path: str | Path | None = None,
        *,
        score_threshold: float = 0.3,
        nms_iou: float = 0.45,
        classes: Sequence[int] | None = VEHICLE_CLASSES,
        num_threads: int | None = None,
        class_agnostic: bool = False,
        fit_aspect: bool = True,
    ) -> None:
        if not 0.0 <= score_threshold <= 1.0:
            raise ValueError(f"score_threshold must be in [0, 1], got {score_threshold}")
        if not 0.0 < nms_iou <= 1.0:
            raise ValueError(f"nms_iou must be in (0, 1], got {nms_iou}")
        if num_threads is not None and num_threads < 1:
            raise ValueError(f"num_threads must be >= 1, got {num_threads}")
        if classes is None:
            self.classes: tuple[int, ...] = tuple(range(_NUM_CLASSES))
        else:
            self.classes = tuple(int(c) for c in classes)
            bad = [c for c in self.classes if not 0 <= c < _NUM_CLASSES]
            if not self.classes or bad:
                raise ValueError(f"classes must be non-empty 0-based COCO ids in 0..79, got {list(classes)}")
        self.score_threshold = float(score_threshold)
        self.nms_iou = float(nms_iou)
        self.class_agnostic = bool(class_agnostic)
        self.num_threads = int(num_threads) if num_threads is not None else (os.cpu_count() or 1)
        # Column selector for the class scores: a slice (no copy) when all 80 classes are kept.
        self._class_cols: slice | np.ndarray = (
            slice(None) if self.classes == tuple(range(_NUM_CLASSES)) else np.asarray(self.classes)
        )
        self._class_ids = np.asarray(self.classes, dtype=np.int64)
        self._grid_xy, self._grid_stride = _grid(self.input_size, self.input_size, self.center_offset)

        self.model_path = resolve_model_path(self.default_filename, model_path)
        self._session = self._load_session()
        self._input_name = self._session.get_inputs()[0].name
        self._blob = np.empty((1, 3, self.input_size, self.input_size), dtype=np.float32)
        self._blobs: dict[tuple[int, int], np.ndarray] = {}
        self.fit_aspect = bool(fit_aspect) and self.shape_agnostic
        if self.fit_aspect:
            self._session = self._relaxed_session()

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(model_path={str(self.model_path)!r}, "
            f"score_threshold={self.score_threshold}, nms_iou={self.nms_iou}, "
            f"classes={self.classes}, num_threads={self.num_threads})"
        )

    # ------------------------------------------------------------------------------ session & checks

    def _session_options(self, ort: Any) -> Any:
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = self.num_threads
        opts.inter_op_num_threads = 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        opts.log_severity_level = 3  # NanoDet's "initializer appears in graph inputs" warnings
        # Idle worker threads sleep instead of spinning, so they do not take the cores from video
        # decoding or another process sharing them (docs/journal.md, "Video pipeline").
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        return opts

    def _load_session(self) -> Any:
        import onnxruntime as ort  # imported here so that `import makeway.perceive` stays cheap

        opts = self._session_options(ort)
        try:
            session = ort.InferenceSession(str(self.model_path), opts, providers=["CPUExecutionProvider"])
        except Exception as exc:  # ORT raises several pybind types (InvalidProtobuf, Fail, ...)
            detail = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            if len(detail) > 200:
                detail = detail[:200] + "…"
            raise InputError(
                self.model_path,
                f"not a valid ONNX model for the {self.name} detector "
                f"(ONNX Runtime could not load it: {detail})",
            ) from exc
        inputs = session.get_inputs()
        expected_in = [1, 3, self.input_size, self.input_size]
        if len(inputs) != 1 or not _dims_match(inputs[0].shape, expected_in):
            found = ", ".join(_fmt_shape(i.shape) for i in inputs) or "none"
            raise InputError(
                self.model_path,
                f"not a {self.name} model: expected one input of shape {_fmt_shape(expected_in)}, "
                f"found {found}",
            )
        self._check_outputs([list(o.shape) for o in session.get_outputs()])
        return session

    def _relaxed_session(self) -> Any:
        """A session on the same model with symbolic input height/width (see ``fit_aspect``).

        The model was already checked by :meth:`_load_session`; only the declared shapes change.
        Returns the square session unchanged when the rewrite is not possible here.
        """
        import onnxruntime as ort

        try:
            import onnx
        except ImportError:
            self.fit_aspect = False
            return self._session
        try:
            model = onnx.load(str(self.model_path))
            dims = model.graph.input[0].type.tensor_type.shape.dim
            for axis, name in ((2, "height"), (3, "width")):
                dims[axis].ClearField("dim_value")
                dims[axis].dim_param = name
            for out in model.graph.output:
                for dim in out.type.tensor_type.shape.dim[1:2]:
                    dim.ClearField("dim_value")
                    dim.dim_param = "cells"
            del model.graph.value_info[:]  # stale intermediate shapes
            opts = self._session_options(ort)
            return ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])
        except Exception:  # any failure: keep the square input, which is known to work
            self.fit_aspect = False
            return self._session

    def _input_for(self, resized: np.ndarray) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
        """The input buffer and the cell grid for a letterboxed image of this size."""
        if not self.fit_aspect:
            return self._blob, (self._grid_xy, self._grid_stride)
        nh, nw = resized.shape[:2]
        shape = (-(-nh // 32) * 32, -(-nw // 32) * 32)
        blob = self._blobs.get(shape)
        if blob is None:
            blob = self._blobs[shape] = np.empty((1, 3, *shape), dtype=np.float32)
        return blob, _grid(shape[0], shape[1], self.center_offset)

    def _check_outputs(self, shapes: list[list[Any]]) -> None:
        raise NotImplementedError

    def _wrong_outputs(self, expected: str, shapes: list[list[Any]]) -> InputError:
        found = ", ".join(_fmt_shape(s) for s in shapes) or "none"
        problem = f"not a {self.name} model: expected outputs {expected}, found {found}"
        return InputError(self.model_path, problem)

    # ---------------------------------------------------------------------------------- pipeline

    def _letterbox(self, image: np.ndarray) -> tuple[np.ndarray, float, float]:
        """Resize keeping the aspect ratio so the image fits ``input_size``; returns the resized
        image and the per-axis scales ``(sx, sy)`` from original to network pixels."""
        h, w = image.shape[:2]
        r = min(self.input_size / h, self.input_size / w)
        nw = min(self.input_size, max(1, round(w * r)))
        nh = min(self.input_size, max(1, round(h * r)))
        resized = cv2.resize(image, (nw, nh), interpolation=cv2.INTER_LINEAR)
        return resized, nw / w, nh / h

    def _fill_input(self, resized: np.ndarray) -> None:
        raise NotImplementedError

    def _decode(self, outputs: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Candidates in network pixels: boxes ``(m, 4)`` xyxy, scores ``(m,)``, class ids ``(m,)``,
        already restricted to ``score >= score_threshold`` and to :attr:`classes`."""
        raise NotImplementedError

    def _best_class(self, class_scores: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Best allowed class per row: ``(score, class_id)``."""
        if class_scores.shape[1] == 1:
            return class_scores[:, 0], np.full(class_scores.shape[0], self._class_ids[0])
        best = class_scores.argmax(axis=1)
        return class_scores[np.arange(class_scores.shape[0]), best], self._class_ids[best]

    def detect_arrays(self, image_bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Detect in one frame: the fast path the video pipeline uses.

        Args:
            image_bgr: ``H×W×3`` ``uint8`` BGR (as OpenCV decodes video).

        Returns:
            ``boxes`` ``(n, 4)`` float32 ``x1, y1, x2, y2`` in image pixels, clipped to the image and
            of positive size; ``scores`` ``(n,)`` float32, descending; ``class_ids`` ``(n,)`` int64
            (0-based COCO).

        Raises:
            ValueError: the image is not ``H×W×3`` ``uint8``.
        """
        image = _check_image(image_bgr)
        h, w = image.shape[:2]
        resized, sx, sy = self._letterbox(image)
        self._blob, (self._grid_xy, self._grid_stride) = self._input_for(resized)
        self._fill_input(resized)
        outputs = self._session.run(None, {self._input_name: self._blob})
        boxes, scores, class_ids = self._decode(outputs)
        if scores.size == 0:
            return _EMPTY[0].copy(), _EMPTY[1].copy(), _EMPTY[2].copy()
        if scores.size > _PRE_NMS_TOP_K:
            top = np.argpartition(-scores, _PRE_NMS_TOP_K)[:_PRE_NMS_TOP_K]
            boxes, scores, class_ids = boxes[top], scores[top], class_ids[top]
        boxes = boxes / np.array([sx, sy, sx, sy], dtype=np.float32)
        np.clip(boxes[:, 0::2], 0.0, w, out=boxes[:, 0::2])
        np.clip(boxes[:, 1::2], 0.0, h, out=boxes[:, 1::2])
        valid = (boxes[:, 2] > boxes[:, 0]) & (boxes[:, 3] > boxes[:, 1])
        boxes, scores, class_ids = boxes[valid], scores[valid], class_ids[valid]
        if self.class_agnostic:
            keep = nms(boxes, scores, self.nms_iou)
        else:
            # Class-aware NMS in one pass: shift each class to its own far-apart copy of the plane.
            shift = (class_ids.astype(np.float64) * (max(w, h) + 1.0))[:, None]
            keep = nms(boxes + shift, scores, self.nms_iou)
        return (
            boxes[keep].astype(np.float32, copy=False),
            scores[keep].astype(np.float32, copy=False),
            class_ids[keep].astype(np.int64, copy=False),
        )

    def detect(self, image_bgr: np.ndarray) -> list[Detection]:
        """Detect in one frame; :class:`~makeway.messages.Detection` objects, highest score first."""
        return self.to_detections(self.detect_arrays(image_bgr))

    @staticmethod
    def to_detections(arrays: tuple[np.ndarray, np.ndarray, np.ndarray]) -> list[Detection]:
        """:meth:`detect_arrays`' ``(boxes, scores, class_ids)`` as :class:`~makeway.messages.Detection`
        objects labelled with their COCO class names."""
        boxes, scores, class_ids = arrays
        return [
            Detection(
                box=Box(b[0], b[1], b[2], b[3]), score=float(s), class_id=int(c), label=COCO_CLASSES[int(c)]
            )
            for b, s, c in zip(boxes.tolist(), scores.tolist(), class_ids.tolist(), strict=True)
        ]


class YoloxNano(Detector):
    """Megvii YOLOX-nano, 416×416 (SPEC §2, Framework B: detector of class vehicle → SORT).

    Input ``[1, 3, 416, 416]`` raw BGR 0–255, letterboxed to the top-left corner with value 114,
    scale ``r = min(416 / h, 416 / w)``. Output ``[1, 3549, 85]``: one row per anchor-free grid
    cell — strides 8, 16, 32 (52², 26², 13² cells), each level row-major — holding
    ``x, y, w, h, objectness, 80 class scores`` (scores already sigmoid). Decode for cell
    ``(gx, gy)`` at stride ``s``::

        cx = (x + gx) * s    cy = (y + gy) * s    w = exp(w) * s    h = exp(h) * s
        score = objectness * class_score

    then divide by the letterbox scale to get original pixels. Cells are pre-filtered on
    objectness (an upper bound of the score) before anything else is computed.

    The graph has no size-bound reshapes, so with ``fit_aspect`` (default) a 16:9 frame runs at
    416×256 (2184 cells) instead of 416×416; the grid follows the input.
    """

    name: ClassVar[str] = "yolox_nano"
    default_filename: ClassVar[str] = "yolox_nano.onnx"
    center_offset: ClassVar[float] = 0.0
    shape_agnostic: ClassVar[bool] = True  # Slice/Resize by scale/Reshape [1, 85, -1] only

    def _check_outputs(self, shapes: list[list[Any]]) -> None:
        n = len(self._grid_stride)
        expected = [1, n, 5 + _NUM_CLASSES]
        if len(shapes) != 1 or not _dims_match(shapes[0], expected):
            raise self._wrong_outputs(_fmt_shape(expected), shapes)

    def _fill_input(self, resized: np.ndarray) -> None:
        nh, nw = resized.shape[:2]
        self._blob.fill(_PAD_VALUE)
        self._blob[0, :, :nh, :nw] = resized.transpose(2, 0, 1)

    def _decode(self, outputs: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        pred = outputs[0][0]
        cand = np.flatnonzero(pred[:, 4] >= self.score_threshold)
        if cand.size == 0:
            return _EMPTY
        rows = pred[cand]
        scores, class_ids = self._best_class(rows[:, 4:5] * rows[:, 5:][:, self._class_cols])
        ok = scores >= self.score_threshold
        if not ok.any():
            return _EMPTY
        rows, scores, class_ids, cand = rows[ok], scores[ok], class_ids[ok], cand[ok]
        stride = self._grid_stride[cand, None]
        centre = (rows[:, 0:2] + self._grid_xy[cand]) * stride
        half = 0.5 * np.exp(rows[:, 2:4]) * stride
        return np.concatenate([centre - half, centre + half], axis=1), scores, class_ids


class NanoDetM(Detector):
    """NanoDet-m, 416×416 (SPEC §2, Framework B: detector of class vehicle → SORT).

    Input ``[1, 3, 416, 416]`` BGR normalised as ``(pixel - mean) / std`` with mean
    ``(103.53, 116.28, 123.675)`` and std ``(57.375, 57.12, 58.395)``. Six outputs, told apart by
    shape (names vary between exports): class scores ``[1, n, 80]`` (already sigmoid) and box
    distributions ``[1, n, 32]`` for ``n`` = 2704, 676, 169 (strides 8, 16, 32, row-major).

    GFL box decode: the 32 values are 4 sides (left, top, right, bottom) × 8 bins; a softmax over
    the bins and the expectation ``Σ p_k · k`` (k = 0..7) times the stride give each side's distance
    from the cell's centre prior ``((column + 0.5) · s, (row + 0.5) · s)``; the box is
    ``(cx - l, cy - t, cx + r, cy + b)``. Only cells whose best allowed class clears the threshold
    are decoded.

    Two choices were settled by agreement with YOLOX-nano's boxes on frames of the shared videos
    (figures: docs/journal.md, "Video pipeline"):

    * **Centre offset +0.5.** With centres at ``(j·s, i·s)`` NanoDet boxes sit up-left of YOLOX's
      by a fraction of a box; at ``(j + 0.5)·s`` they agree.
    * **Letterbox, not plain resize.** Stretching 16:9 to 416×416 agrees less with YOLOX (and
      detects less) than the same top-left letterbox YOLOX uses. The pad value (114 raw, i.e.
      normalised like any pixel) makes no measurable difference.
    """

    name: ClassVar[str] = "nanodet_m"
    # shape_agnostic stays False: its channel shuffles reshape to fixed 52/26/13 grids.
    default_filename: ClassVar[str] = "nanodet_m_416.onnx"
    center_offset: ClassVar[float] = 0.5
    reg_max: ClassVar[int] = 7

    _MEAN = np.array([103.53, 116.28, 123.675], dtype=np.float32)
    _INV_STD = (1.0 / np.array([57.375, 57.12, 58.395], dtype=np.float64)).astype(np.float32)
    _mean_chw = _MEAN.reshape(3, 1, 1)
    _inv_std_chw = _INV_STD.reshape(3, 1, 1)
    _pad = ((_PAD_VALUE - _MEAN) * _INV_STD).reshape(3, 1, 1)  # the letterbox fill, normalised
    _bins = np.arange(reg_max + 1, dtype=np.float32)
    # Output positions of the class-score and box-distribution tensors per level (set on load).
    _cls_order: list[int]
    _reg_order: list[int]

    def _check_outputs(self, shapes: list[list[Any]]) -> None:
        cells = [(self.input_size // s) ** 2 for s in _STRIDES]
        n_reg = 4 * (self.reg_max + 1)
        expected = ", ".join(f"[1, {n}, {_NUM_CLASSES}]" for n in cells) + ", "
        expected += ", ".join(f"[1, {n}, {n_reg}]" for n in cells)
        cls_at: dict[int, int] = {}
        reg_at: dict[int, int] = {}
        for k, shape in enumerate(shapes):
            if len(shape) == 3 and (shape[0] in (1, None) or isinstance(shape[0], str)):
                n, c = shape[1], shape[2]
                if c == _NUM_CLASSES and n in cells:
                    cls_at[n] = k
                elif c == n_reg and n in cells:
                    reg_at[n] = k
        if len(shapes) != 6 or len(cls_at) != 3 or len(reg_at) != 3:
            raise self._wrong_outputs(expected, shapes)
        self._cls_order = [cls_at[n] for n in cells]
        self._reg_order = [reg_at[n] for n in cells]

    def _fill_input(self, resized: np.ndarray) -> None:
        nh, nw = resized.shape[:2]
        self._blob[0] = self._pad
        view = self._blob[0, :, :nh, :nw]
        view[...] = resized.transpose(2, 0, 1)  # uint8 → float32 while copying, then normalise in place
        view -= self._mean_chw
        view *= self._inv_std_chw

    def _decode(self, outputs: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        cols = self._class_cols
        class_scores = np.concatenate([outputs[k][0][:, cols] for k in self._cls_order])
        cand = np.flatnonzero(class_scores.max(axis=1) >= self.score_threshold)
        if cand.size == 0:
            return _EMPTY
        scores, class_ids = self._best_class(class_scores[cand])
        dist = np.concatenate([outputs[k][0] for k in self._reg_order])[cand]
        dist = dist.reshape(-1, 4, self.reg_max + 1)
        dist = np.exp(dist - dist.max(axis=2, keepdims=True))
        sides = (dist @ self._bins) / dist.sum(axis=2)  # (m, 4) expected bin per side
        stride = self._grid_stride[cand, None]
        sides *= stride
        centre = self._grid_xy[cand] * stride
        boxes = np.concatenate([centre - sides[:, :2], centre + sides[:, 2:]], axis=1)
        return boxes, scores, class_ids


DETECTORS: Registry[type[Detector]] = Registry(
    "detector", {YoloxNano.name: YoloxNano, NanoDetM.name: NanoDetM}
)
"""The vehicle detectors by name: ``DETECTORS[name](model_path=None, **kwargs)``."""
