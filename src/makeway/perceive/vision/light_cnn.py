"""The learned lit-light detector at runtime: an ONNX heat-map network run by ONNX Runtime (no torch).

The network (trained by :mod:`makeway.train.lights`) takes one frame letterboxed to a fixed input size
(:func:`letterbox`: scaled to fit, aspect kept, anchored top-left, padded with black) as RGB
``float32`` ``(1, 3, H, W)`` in ``[0, 1]``. Inside the graph, the colour-attention block of seed 004
multiplies up the pixels in the HSV ranges of the emergency colours (``x' = x + x·mask``) before the
backbone. It returns three maps at stride ``s`` (the file's metadata): ``heat`` ``(1, 1, H/s, W/s)``, the
probability that a lit light is centred in each cell, already reduced to its local 3×3 maxima (others
0); ``size`` ``(1, 2, H/s, W/s)``, the box's ``ln(width), ln(height)`` in input pixels; and ``offset``
``(1, 2, H/s, W/s)``, the centre's sub-cell position in cells.

:func:`decode` turns the maps into boxes in the source frame's pixels. The network has one class, "lit
emergency light"; each box's colour is read from the frame's pixels around it (:func:`box_colour`), so
that the jurisdiction's colour set (``colours``) filters detections without retraining.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from makeway.errors import InputError
from makeway.messages import Box, LightDetection
from makeway.onnx_models import model_metadata, smoke_run
from makeway.perceive.vision.light_colour import WIDE_HSV, colour_masks

__all__ = [
    "LIGHTS_ONNX_FORMAT",
    "CnnLightDetector",
    "box_colour",
    "decode",
    "default_lights_model",
    "letterbox",
]

#: ``makeway.format`` metadata of a lit-light detector ONNX file.
LIGHTS_ONNX_FORMAT = "makeway-lights-det-1"

_REQUIRED_META = ("makeway.format", "input_width", "input_height", "stride")


def default_lights_model() -> Path:
    """The shipped detector, ``src/makeway/models/lights_det.onnx``."""
    return Path(__file__).resolve().parents[2] / "models" / "lights_det.onnx"


def check_frame(frame_bgr: Any) -> np.ndarray:
    """``frame_bgr`` when it is a ``uint8`` ``(H, W, 3)`` array, else ``ValueError`` saying what it is."""
    if not isinstance(frame_bgr, np.ndarray):
        raise ValueError(f"expected a uint8 BGR image H×W×3 (numpy array), got {type(frame_bgr).__name__}")
    if frame_bgr.ndim != 3 or frame_bgr.shape[2] != 3 or frame_bgr.dtype != np.uint8:
        raise ValueError(f"expected a uint8 BGR image H×W×3, got {frame_bgr.dtype} {frame_bgr.shape}")
    if frame_bgr.shape[0] < 8 or frame_bgr.shape[1] < 8:
        raise ValueError(
            f"image too small for the lights detector: {frame_bgr.shape[1]}×{frame_bgr.shape[0]}"
        )
    return frame_bgr


def letterbox(frame_bgr: np.ndarray, width: int, height: int) -> tuple[np.ndarray, float]:
    """The frame scaled by ``s = min(width/W, height/H)`` into a black ``height × width`` canvas at its
    top-left corner; returns ``(canvas, s)``: a source pixel ``p`` lands at ``p·s``."""
    h, w = frame_bgr.shape[:2]
    s = min(width / w, height / h)
    nw, nh = max(1, min(width, round(w * s))), max(1, min(height, round(h * s)))
    interp = cv2.INTER_AREA if s < 1 else cv2.INTER_LINEAR
    resized = cv2.resize(frame_bgr, (nw, nh), interpolation=interp)
    canvas = np.zeros((height, width, 3), np.uint8)
    canvas[:nh, :nw] = resized
    return canvas, s


def to_input(canvas_bgr: np.ndarray) -> np.ndarray:
    """A letterboxed BGR canvas as the network input: RGB float32 ``(1, 3, H, W)`` in ``[0, 1]``."""
    rgb = canvas_bgr[..., ::-1].astype(np.float32) / 255.0
    return np.ascontiguousarray(rgb.transpose(2, 0, 1)[None])


def decode(
    heat: np.ndarray,
    size: np.ndarray,
    offset: np.ndarray,
    *,
    stride: int,
    scale: float,
    threshold: float,
    max_detections: int = 100,
    image_size: tuple[int, int] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Boxes ``(n, 4)`` (source pixels, ``x1, y1, x2, y2``) and scores ``(n,)`` of the peaks of one
    image's maps (``heat`` ``(h, w)`` of local maxima, ``size`` and ``offset`` ``(2, h, w)``) scoring at
    least ``threshold``, best first, at most ``max_detections``; ``scale`` is the letterbox factor,
    ``image_size`` ``(W, H)`` clips the boxes to the source image."""
    ys, xs = np.nonzero(heat >= threshold)
    scores = heat[ys, xs]
    order = np.argsort(-scores, kind="stable")[:max_detections]
    ys, xs, scores = ys[order], xs[order], scores[order]
    cx = (xs + offset[0, ys, xs]) * stride
    cy = (ys + offset[1, ys, xs]) * stride
    bw = np.exp(np.clip(size[0, ys, xs], -3.0, 6.0))
    bh = np.exp(np.clip(size[1, ys, xs], -3.0, 6.0))
    boxes = np.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], -1).astype(np.float64) / scale
    if image_size is not None and len(boxes):
        boxes[:, [0, 2]] = np.clip(boxes[:, [0, 2]], 0, image_size[0])
        boxes[:, [1, 3]] = np.clip(boxes[:, [1, 3]], 0, image_size[1])
    return boxes.reshape(-1, 4), scores.astype(np.float64)


_HUE_COLOURS = ("blue", "red", "amber")


def box_colour(frame_bgr: np.ndarray, box: Sequence[float], *, min_pixels: int = 2) -> str:
    """The colour of a lit light from the frame's pixels: the box grown by half its size (at least
    2 px) per side is searched for pixels in the HSV ranges of blue, red and amber
    (:data:`~makeway.perceive.vision.light_colour.WIDE_HSV`: a lit bulb's core clips to white and its
    colour shows in the halo); the colour with most pixels wins when it has at least ``min_pixels``,
    else ``white``."""
    h, w = frame_bgr.shape[:2]
    x1, y1, x2, y2 = (float(v) for v in box)
    gx, gy = max(2.0, 0.5 * (x2 - x1)), max(2.0, 0.5 * (y2 - y1))
    a, b = max(0, int(x1 - gx)), max(0, int(y1 - gy))
    c, d = min(w, int(np.ceil(x2 + gx))), min(h, int(np.ceil(y2 + gy)))
    if c <= a or d <= b:
        return "white"
    masks = colour_masks(frame_bgr[b:d, a:c], {k: WIDE_HSV[k] for k in _HUE_COLOURS})
    counts = {k: int(m.sum()) for k, m in masks.items()}
    best = max(_HUE_COLOURS, key=lambda k: counts[k])
    return best if counts[best] >= min_pixels else "white"


class CnnLightDetector:
    """Lit emergency lights from the learned heat-map network (ONNX Runtime, CPU).

    ``colours``: the jurisdiction's colour set (a ``COLOUR_SETS`` name or colour names); detections of
    other colours are dropped. ``model``: the ONNX file (default: the shipped
    ``models/lights_det.onnx``). ``threshold``: the least peak score kept (default: the file's
    ``threshold`` metadata, chosen at training). ``num_threads``: ONNX Runtime intra-op threads.
    """

    def __init__(
        self,
        colours: str | Sequence[str] = "eu",
        *,
        model: str | Path | None = None,
        threshold: float | None = None,
        num_threads: int | None = None,
        max_detections: int = 100,
    ) -> None:
        import onnxruntime as ort

        from makeway.perceive.vision.lights import colour_set

        self.colours = colour_set(colours)
        self.path = Path(model) if model is not None else default_lights_model()
        if not self.path.is_file():
            raise InputError(
                self.path, "lights detector model not found (train one with `makeway lights-train`)"
            )
        options = ort.SessionOptions()
        options.log_severity_level = 3
        if num_threads is not None:
            options.intra_op_num_threads = int(num_threads)
            options.inter_op_num_threads = 1
        try:
            self._session = ort.InferenceSession(
                str(self.path), sess_options=options, providers=["CPUExecutionProvider"]
            )
        except Exception as exc:  # onnxruntime raises its own types on a garbage file
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise InputError(self.path, f"not an ONNX model ONNX Runtime can load ({first})") from None
        meta = model_metadata(self._session, self.path)
        missing = [k for k in _REQUIRED_META if k not in meta]
        if missing or meta.get("makeway.format") != LIGHTS_ONNX_FORMAT:
            raise InputError(
                self.path,
                f"not a makeway lights-detector ONNX (format {meta.get('makeway.format')!r}, "
                f"want {LIGHTS_ONNX_FORMAT}; missing {', '.join(missing) or 'nothing'})",
            )
        self.metadata = meta
        try:
            self.input_width = int(meta["input_width"])
            self.input_height = int(meta["input_height"])
            self.stride = int(meta["stride"])
            stored = float(meta.get("threshold", "0.3"))
            if min(self.input_width, self.input_height, self.stride) < 1 or not 0.0 < stored < 1.0:
                raise ValueError("sizes and stride must be positive, the threshold in (0, 1)")
        except ValueError as exc:
            raise InputError(self.path, f"malformed lights-detector metadata ({exc})") from None
        self.threshold = stored if threshold is None else float(threshold)
        if not 0.0 < self.threshold < 1.0:
            raise ValueError(f"threshold must be in (0, 1), got {self.threshold}")
        outputs = dict(
            zip(
                [o.name for o in self._session.get_outputs()],
                smoke_run(self._session, self.path),
                strict=True,
            )
        )
        want = (self.input_height // self.stride, self.input_width // self.stride)
        shapes = {k: getattr(outputs.get(k), "shape", None) for k in ("heat", "size", "offset")}
        if any(v is None or len(v) != 4 or tuple(v[2:]) != want for v in shapes.values()):
            raise InputError(self.path, f"outputs {shapes} do not match a {want[1]}×{want[0]} heat map")
        self.attention = meta.get("attention", "")
        self.max_detections = int(max_detections)
        self._input = self._session.get_inputs()[0].name
        self._outputs = ["heat", "size", "offset"]
        self.last_ms = 0.0

    def __repr__(self) -> str:
        return f"CnnLightDetector({self.path.name}, colours={self.colours}, threshold={self.threshold:.2f})"

    def raw(self, frame_bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """All peaks of one frame regardless of colour: ``(boxes (n, 4) source pixels, scores (n,),
        letterbox scale)``, thresholded at ``self.threshold``."""
        frame_bgr = check_frame(frame_bgr)
        canvas, s = letterbox(frame_bgr, self.input_width, self.input_height)
        heat, size, offset = self._session.run(self._outputs, {self._input: to_input(canvas)})
        boxes, scores = decode(
            heat[0, 0],
            size[0],
            offset[0],
            stride=self.stride,
            scale=s,
            threshold=self.threshold,
            max_detections=self.max_detections,
            image_size=(frame_bgr.shape[1], frame_bgr.shape[0]),
        )
        return boxes, scores, s

    def detect(self, frame_bgr: np.ndarray, frame: int = 0) -> list[LightDetection]:
        """Lit emergency lights of the jurisdiction's colours in one BGR frame (its pixels)."""
        t0 = time.perf_counter()
        boxes, scores, _ = self.raw(frame_bgr)
        out = []
        for box, score in zip(boxes, scores, strict=True):
            if box[2] - box[0] <= 0 or box[3] - box[1] <= 0:
                continue
            colour = box_colour(frame_bgr, box)
            if colour in self.colours:
                out.append(LightDetection(Box(*(float(v) for v in box)), colour, float(score), frame))
        self.last_ms = (time.perf_counter() - t0) * 1000.0
        return out
