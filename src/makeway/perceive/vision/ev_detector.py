"""Framework A's one-stage EV detector on ONNX Runtime (seed 001; issue 24, items 3–5).

Seed 001 compares two ways to see an emergency vehicle: **Framework A**, one detector whose classes
are "emergency vehicle" and "other vehicle", its boxes tracked by SORT; and **Framework B**, a vehicle
detector → SORT → a crop classifier per track (:mod:`makeway.pipeline.video`). This module runs A's
network, ``ev_det_yolox.onnx``: YOLOX-nano fine-tuned to two classes
(:mod:`makeway.train.framework_a`; data, split and figures in ``docs/model_card_ev_det.md``). No
torch at run time.

**Model file.** Input ``images`` ``[1, 3, H, W]`` raw BGR 0–255, ``H`` and ``W`` multiples of 32
(416×416 for a square image), the frame letterboxed to the top-left with pad value 114 — exactly
YOLOX-nano's convention (:class:`~makeway.perceive.vision.detectors.YoloxNano`). Output
``[1, n, 7]``, one row per grid cell (strides 8, 16, 32, row-major per level): ``x, y, w, h``
(undecoded: ``cx = (x + column)·s``, ``w = exp(w)·s``), objectness, and the two class scores
``c0`` (emergency vehicle) and ``c1`` (other vehicle), all three already sigmoid. Its metadata
carries ``makeway_model = ev_detector``, ``makeway.format`` (:data:`EV_DET_FORMAT`), the class
names and the operating point ``threshold``.

**Scores of a box.** The detector finds vehicles, whatever their kind: a cell's vehicle score is
``obj · max(c0, c1)``; cells at or above ``score_threshold`` are decoded and merged by
class-agnostic NMS (one box per vehicle, so a vehicle never comes out once as EV and once as
other). Each kept box then carries

* ``ev_score = obj · c0`` — the confidence that it is an emergency vehicle (ranks boxes for AP; the
  operating point is ``ev_score ≥ threshold``, chosen on validation images when training);
* ``p_ev = c0 / (c0 + c1)`` — class 0's share of the two class scores, the detector's P(EV) given
  that the box is a vehicle. This is what the video pipeline feeds the per-track smoother in place
  of Framework B's crop classifier probability.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import cv2
import numpy as np

from makeway.errors import InputError
from makeway.perceive.vision.detectors import _check_image, _grid, nms

__all__ = [
    "EV_DET_CLASSES",
    "EV_DET_FILE",
    "EV_DET_FORMAT",
    "EV_DET_KIND",
    "EVDetections",
    "EVDetector",
    "decode_ev_output",
]

#: The file shipped with the package.
EV_DET_FILE = Path(__file__).resolve().parents[2] / "models" / "ev_det_yolox.onnx"
#: ``makeway_model`` metadata value of the model file.
EV_DET_KIND = "ev_detector"
#: ``makeway.format`` metadata value: the layout of input and output described above.
EV_DET_FORMAT = "yolox-2class/1"
#: Class ids of the network's two class scores.
EV_DET_CLASSES: tuple[str, str] = ("emergency vehicle", "other vehicle")

_PAD_VALUE = 114
_PRE_NMS_TOP_K = 1000


@dataclass(frozen=True)
class EVDetections:
    """Vehicles found in one frame: ``boxes`` ``(n, 4)`` float32 ``x1, y1, x2, y2`` image pixels,
    ``scores`` ``(n,)`` vehicle score ``obj·max(c0, c1)`` (descending), ``ev_scores`` ``(n,)``
    ``obj·c0`` and ``p_ev`` ``(n,)`` ``c0 / (c0 + c1)`` (module docstring)."""

    boxes: np.ndarray
    scores: np.ndarray
    ev_scores: np.ndarray
    p_ev: np.ndarray

    def __len__(self) -> int:
        return int(self.scores.shape[0])


def decode_ev_output(
    pred: np.ndarray,
    grid_xy: np.ndarray,
    grid_stride: np.ndarray,
    *,
    score_threshold: float,
    nms_iou: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Decode one image's ``(n, 7)`` output in network pixels: ``(boxes, scores, ev_scores, p_ev)``
    after the vehicle-score threshold and class-agnostic NMS (module docstring). Shared by the
    runtime and the training's validation, so both score the same boxes."""
    pred = np.asarray(pred, dtype=np.float32)
    obj = pred[:, 4]
    cls = pred[:, 5:7]
    vehicle = obj * cls.max(axis=1)
    cand = np.flatnonzero(vehicle >= score_threshold)
    if cand.size > _PRE_NMS_TOP_K:
        cand = cand[np.argpartition(-vehicle[cand], _PRE_NMS_TOP_K)[:_PRE_NMS_TOP_K]]
    if cand.size == 0:
        empty = np.zeros(0, np.float32)
        return np.zeros((0, 4), np.float32), empty, empty.copy(), empty.copy()
    rows = pred[cand]
    stride = grid_stride[cand, None]
    centre = (rows[:, 0:2] + grid_xy[cand]) * stride
    half = 0.5 * np.exp(np.minimum(rows[:, 2:4], 10.0)) * stride
    boxes = np.concatenate([centre - half, centre + half], axis=1)
    scores = vehicle[cand]
    keep = nms(boxes, scores, nms_iou)
    c = cls[cand][keep]
    ev = (obj[cand][keep] * c[:, 0]).astype(np.float32)
    p_ev = (c[:, 0] / np.maximum(c[:, 0] + c[:, 1], 1e-12)).astype(np.float32)
    return boxes[keep].astype(np.float32), scores[keep].astype(np.float32), ev, p_ev


class EVDetector:
    """Framework A's EV detector (module docstring) on one ONNX Runtime session.

    Args:
        model_path: the ``.onnx`` file; ``None`` uses the shipped ``ev_det_yolox.onnx``.
        score_threshold: minimum vehicle score ``obj·max(c0, c1)`` of a box (``[0, 1]``).
        nms_iou: IoU above which a lower-scoring box is suppressed (class-agnostic).
        num_threads: ONNX Runtime intra-op threads; ``None`` uses every core.
        input_size: long side of the network input in pixels (multiple of 32; the model was
            trained at 416).
        fit_aspect: shape the input to the frame (short side rounded up to a multiple of 32)
            instead of a square: a 16:9 frame runs at 416×256.

    Attributes:
        threshold: the operating point on ``ev_score`` stored in the model (``ev_score ≥ threshold``
            is called an EV).

    Raises:
        InputError: the file is missing, not ONNX, not an EV detector of this format (metadata),
            or does not run.
        ValueError: an argument is out of range.

    Not thread-safe (one input buffer per instance).
    """

    name: ClassVar[str] = "ev_det_yolox"

    def __init__(
        self,
        model_path: str | Path | None = None,
        *,
        score_threshold: float = 0.3,
        nms_iou: float = 0.45,
        num_threads: int | None = None,
        input_size: int = 416,
        fit_aspect: bool = True,
    ) -> None:
        from makeway.onnx_models import open_makeway_onnx

        if not 0.0 <= score_threshold <= 1.0:
            raise ValueError(f"score_threshold must be in [0, 1], got {score_threshold}")
        if not 0.0 < nms_iou <= 1.0:
            raise ValueError(f"nms_iou must be in (0, 1], got {nms_iou}")
        if input_size < 32 or input_size % 32:
            raise ValueError(f"input_size must be a positive multiple of 32, got {input_size}")
        self.model_path = Path(model_path) if model_path is not None else EV_DET_FILE
        self._session, self.metadata = open_makeway_onnx(
            self.model_path,
            EV_DET_KIND,
            threads=num_threads,
            missing_hint="pass the Framework A model file (makeway classify train-detector writes one)",
        )
        fmt = self.metadata.get("makeway.format", "")
        if fmt != EV_DET_FORMAT:
            raise InputError(
                self.model_path,
                f"EV detector format {fmt!r} is not the one this runtime reads ({EV_DET_FORMAT})",
            )
        try:
            self.threshold = float(self.metadata["threshold"])
        except (KeyError, ValueError):
            raise InputError(self.model_path, "EV detector metadata lacks a numeric 'threshold'") from None
        out = self._session.get_outputs()
        if len(out) != 1 or len(out[0].shape) != 3 or out[0].shape[2] != 7:
            raise InputError(self.model_path, "EV detector output must be one [1, cells, 7] tensor")
        self._input_name = self._session.get_inputs()[0].name
        self.score_threshold = float(score_threshold)
        self.nms_iou = float(nms_iou)
        self.input_size = int(input_size)
        self.fit_aspect = bool(fit_aspect)
        self._blobs: dict[tuple[int, int], np.ndarray] = {}
        self._threads = num_threads
        if self.fit_aspect or self.input_size != 416:
            self._session = self._relaxed_session()

    def _relaxed_session(self) -> Any:
        """A session on the same file with symbolic input height and width (the graph runs any
        multiple of 32; the file declares 416×416, which the load check ran)."""
        import onnx
        import onnxruntime as ort

        model = onnx.load(str(self.model_path))
        dims = model.graph.input[0].type.tensor_type.shape.dim
        for axis, name in ((2, "height"), (3, "width")):
            dims[axis].ClearField("dim_value")
            dims[axis].dim_param = name
        out = model.graph.output[0].type.tensor_type.shape.dim[1]
        out.ClearField("dim_value")
        out.dim_param = "cells"
        del model.graph.value_info[:]
        opts = ort.SessionOptions()
        if self._threads is not None:
            opts.intra_op_num_threads = int(self._threads)
            opts.inter_op_num_threads = 1
        opts.log_severity_level = 3
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        return ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])

    def __repr__(self) -> str:
        return (
            f"EVDetector(model_path={str(self.model_path)!r}, score_threshold={self.score_threshold}, "
            f"threshold={self.threshold})"
        )

    def _blob_for(self, nh: int, nw: int) -> np.ndarray:
        if self.fit_aspect:
            shape = (-(-nh // 32) * 32, -(-nw // 32) * 32)
        else:
            shape = (self.input_size, self.input_size)
        blob = self._blobs.get(shape)
        if blob is None:
            blob = self._blobs[shape] = np.empty((1, 3, *shape), dtype=np.float32)
        return blob

    def raw(self, image_bgr: np.ndarray) -> tuple[np.ndarray, float, float, tuple[int, int]]:
        """The network's ``(n, 7)`` output for one frame, the letterbox scales ``(sx, sy)`` from
        image to network pixels, and the network input's ``(height, width)``."""
        image = _check_image(image_bgr)
        h, w = image.shape[:2]
        r = min(self.input_size / h, self.input_size / w)
        nw = min(self.input_size, max(1, round(w * r)))
        nh = min(self.input_size, max(1, round(h * r)))
        resized = cv2.resize(image, (nw, nh), interpolation=cv2.INTER_LINEAR)
        blob = self._blob_for(nh, nw)
        blob.fill(_PAD_VALUE)
        blob[0, :, :nh, :nw] = resized.transpose(2, 0, 1)
        (pred,) = self._session.run(None, {self._input_name: blob})
        return pred[0], nw / w, nh / h, (int(blob.shape[2]), int(blob.shape[3]))

    def detect(self, image_bgr: np.ndarray) -> EVDetections:
        """The vehicles of one ``H×W×3`` ``uint8`` BGR frame with their EV scores (class docstring).

        Raises:
            ValueError: the image is not ``H×W×3`` ``uint8``.
        """
        pred, sx, sy, (ih, iw) = self.raw(image_bgr)
        h, w = image_bgr.shape[:2]
        grid_xy, grid_stride = _grid(ih, iw, 0.0)
        boxes, scores, ev, p_ev = decode_ev_output(
            pred, grid_xy, grid_stride, score_threshold=self.score_threshold, nms_iou=self.nms_iou
        )
        boxes = boxes / np.array([sx, sy, sx, sy], dtype=np.float32)
        np.clip(boxes[:, 0::2], 0.0, w, out=boxes[:, 0::2])
        np.clip(boxes[:, 1::2], 0.0, h, out=boxes[:, 1::2])
        ok = (boxes[:, 2] > boxes[:, 0]) & (boxes[:, 3] > boxes[:, 1])
        return EVDetections(boxes[ok], scores[ok], ev[ok], p_ev[ok])

    def detect_arrays(self, image_bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The video pipeline's fast path (:class:`~makeway.pipeline.video.FrameDetector`):
        ``(boxes, scores, class_ids, p_ev)`` — the COCO detectors' three arrays (vehicle score;
        class id the argmax of the two classes: 0 emergency vehicle where ``c0 ≥ c1``, else 1) and
        the per-box P(EV) the smoother is fed."""
        d = self.detect(image_bgr)
        return d.boxes, d.scores, np.where(d.p_ev >= 0.5, 0, 1).astype(np.int64), d.p_ev
