"""The per-frame EV crop CNN at run time: an exported ONNX file through ONNX Runtime (SPEC §1; no torch).

:class:`OnnxCropClassifier` reads a model written by ``makeway classify train --arch resnet18|small_cnn``
or ``makeway classify export`` (:func:`makeway.train.cnn.export_onnx`). The file says how to feed
it in its ``metadata_props``: ``makeway.format`` = ``ev_cnn/1``, ``input_size``, ``threshold``,
``channel_order`` (``RGB``/``BGR``), ``layout`` (``NCHW``), ``scale`` and per-channel ``mean`` /
``std``: ``x = (pixel · scale − mean) / std``. Input ``(n, 3, S, S)`` float32 with a dynamic batch
axis, output ``(n,)`` (or ``(n, 1)``) P(emergency vehicle).

It has the public API of :class:`~makeway.perceive.vision.ev_classifier.EVCropClassifier` that the
pipeline uses — :attr:`input_size`, :attr:`threshold`, :meth:`predict_proba`, :meth:`predict`,
:meth:`load` — so :class:`~makeway.perceive.vision.ev_classifier.EVTrackClassifier` wraps it:
all crops of a frame go through one ``session.run``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from makeway.errors import InputError
from makeway.onnx_models import model_metadata, smoke_run

__all__ = ["ONNX_FORMAT", "OnnxCropClassifier"]

#: ``makeway.format`` of the ONNX files this classifier reads.
ONNX_FORMAT = "ev_cnn/1"

_REQUIRED = ("makeway.format", "input_size", "threshold", "channel_order", "mean", "std", "scale")


def _floats(text: str, n: int, what: str) -> np.ndarray:
    values = np.array([float(v) for v in text.split(",")], dtype=np.float32)
    if values.shape != (n,) or not np.all(np.isfinite(values)):
        raise ValueError(f"{what} must be {n} comma-separated numbers, got {text!r}")
    return values


class OnnxCropClassifier:
    """EV crop classifier over an ONNX CNN (module docstring).

    :attr:`max_batch` (default 128 crops) bounds one ONNX Runtime call of :meth:`predict_proba`.

    Args:
        path: the ``.onnx`` file.
        threshold: decision threshold of :meth:`predict` (``None``: the one stored in the file).
        num_threads: ONNX Runtime intra-op threads (``None``: ONNX Runtime's default, all cores).
        model: the serialized ONNX model, when it is built in memory (e.g. a fine-tuned delta
            applied to installed weights); ``path`` then only names it.

    Raises:
        InputError: the file is missing, not an ONNX model ONNX Runtime can load, lacks the
            metadata above, or its input / output shapes are not those of a crop classifier.
        ValueError: ``threshold`` is not in (0, 1).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        threshold: float | None = None,
        num_threads: int | None = None,
        model: bytes | None = None,
    ) -> None:
        import onnxruntime as ort

        self.path = Path(path)
        self.max_batch = 128
        if model is None and not self.path.is_file():
            raise InputError(
                self.path, "ONNX crop classifier not found (export one: makeway classify export)"
            )
        if num_threads is not None and num_threads < 1:
            raise ValueError(f"num_threads must be >= 1, got {num_threads}")
        self.num_threads = num_threads
        options = ort.SessionOptions()
        if num_threads is not None:
            options.intra_op_num_threads = int(num_threads)
            options.inter_op_num_threads = 1
        try:
            self._session = ort.InferenceSession(
                model if model is not None else str(self.path),
                sess_options=options,
                providers=["CPUExecutionProvider"],
            )
        except Exception as exc:  # onnxruntime raises its own types on a garbage file
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise InputError(self.path, f"not an ONNX model ONNX Runtime can load ({first})") from None
        meta: dict[str, str] = model_metadata(self._session, self.path)
        missing = [k for k in _REQUIRED if k not in meta]
        if missing:
            raise InputError(
                self.path,
                f"not a makeway crop-classifier ONNX: metadata lacks {', '.join(missing)} "
                "(export with `makeway classify export`)",
            )
        if meta["makeway.format"] != ONNX_FORMAT:
            raise InputError(
                self.path, f"format {meta['makeway.format']!r}; this makeway reads {ONNX_FORMAT}"
            )
        try:
            self.input_size = int(meta["input_size"])
            stored = float(meta["threshold"])
            self.channel_order = meta["channel_order"].strip().upper()
            if self.channel_order not in ("RGB", "BGR"):
                raise ValueError(f"channel_order must be RGB or BGR, got {self.channel_order!r}")
            if meta.get("layout", "NCHW").strip().upper() != "NCHW":
                raise ValueError(f"layout must be NCHW, got {meta['layout']!r}")
            scale = float(meta["scale"])
            mean = _floats(meta["mean"], 3, "mean")
            std = _floats(meta["std"], 3, "std")
            if np.any(std <= 0) or not np.isfinite(scale) or scale <= 0 or self.input_size < 1:
                raise ValueError("std, scale and input_size must be positive")
        except ValueError as exc:
            raise InputError(self.path, f"malformed crop-classifier metadata ({exc})") from None
        inputs, outputs = self._session.get_inputs(), self._session.get_outputs()
        shape = list(inputs[0].shape) if len(inputs) == 1 else []
        if len(inputs) != 1 or len(shape) != 4 or shape[1] != 3 or shape[2:] != [self.input_size] * 2:
            found = ", ".join(f"{i.name}{list(i.shape)}" for i in inputs)
            raise InputError(
                self.path,
                f"expected one input (n, 3, {self.input_size}, {self.input_size}); found {found or 'none'}",
            )
        out_shape = list(outputs[0].shape) if len(outputs) == 1 else []
        if len(outputs) != 1 or not (len(out_shape) == 1 or (len(out_shape) == 2 and out_shape[1] == 1)):
            found = ", ".join(f"{o.name}{list(o.shape)}" for o in outputs)
            raise InputError(self.path, f"expected one output (n,) of probabilities; found {found or 'none'}")
        probs = smoke_run(self._session, self.path)[0]
        if np.asarray(probs).size != 2:  # the smoke run's batch of two crops
            raise InputError(self.path, f"gives {np.asarray(probs).shape} for 2 crops, not 2 probabilities")
        self._input_name = inputs[0].name
        # x = (p·scale − mean)/std = p·a − b, per channel
        self._a = (scale / std).astype(np.float32).reshape(1, 3, 1, 1)
        self._b = (mean / std).astype(np.float32).reshape(1, 3, 1, 1)
        self.metadata = meta
        self.arch = meta.get("arch", "")
        self.training = meta.get("training", "")
        if threshold is None and not 0.0 < stored < 1.0:
            raise InputError(
                self.path, f"malformed crop-classifier metadata (threshold {stored} not in (0, 1))"
            )
        chosen = stored if threshold is None else float(threshold)
        if not 0.0 < chosen < 1.0:
            raise ValueError(f"threshold must be in (0, 1), got {chosen}")
        self.threshold = chosen

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}({self.path.name!r}, arch={self.arch!r}, input_size={self.input_size}, "
            f"threshold={self.threshold:g})"
        )

    @classmethod
    def load(cls, path: str | Path, **kwargs: Any) -> OnnxCropClassifier:
        """Same as the constructor (mirrors :meth:`EVCropClassifier.load`)."""
        return cls(path, **kwargs)

    def preprocess(self, images: np.ndarray) -> np.ndarray:
        """uint8 BGR crops ``(n, H, W, 3)`` → the network input ``(n, 3, S, S)`` float32.

        Crops of another size are resized (area interpolation when shrinking, bilinear when
        enlarging — as :meth:`makeway.sense.crops.CropSet.load_images` does).
        """
        arr = np.asarray(images)
        if arr.ndim != 4 or arr.shape[3] != 3 or arr.dtype != np.uint8:
            raise ValueError(f"expected uint8 BGR images (n, H, W, 3), got {arr.dtype} {arr.shape}")
        s = self.input_size
        if arr.shape[1:3] != (s, s):
            resized = np.empty((len(arr), s, s, 3), dtype=np.uint8)
            for i, image in enumerate(arr):
                shrink = image.shape[0] > s or image.shape[1] > s
                resized[i] = cv2.resize(
                    image, (s, s), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR
                )
            arr = resized
        if self.channel_order == "RGB":
            arr = arr[..., ::-1]
        x = arr.transpose(0, 3, 1, 2).astype(np.float32)
        x *= self._a
        x -= self._b
        return x

    def run(self, x: np.ndarray) -> np.ndarray:
        """One ONNX Runtime call on a preprocessed batch ``(n, 3, S, S)`` → probabilities ``(n,)``."""
        out = self._session.run(None, {self._input_name: np.ascontiguousarray(x, dtype=np.float32)})[0]
        return np.asarray(out, dtype=np.float64).reshape(len(x))

    def predict_proba(self, images: np.ndarray) -> np.ndarray:
        """P(emergency vehicle) ``(n,)`` of uint8 BGR crops ``(n, H, W, 3)``, in batches of at most
        :attr:`max_batch` crops (one ONNX Runtime call each: the network's activations grow with the
        batch, so a folder of thousands of crops at 224 px in one call would need tens of GB)."""
        n = len(images)
        if n == 0:
            return np.empty(0, dtype=np.float64)
        step = max(1, int(self.max_batch))
        return np.concatenate([self.run(self.preprocess(images[i : i + step])) for i in range(0, n, step)])

    def predict(self, images: np.ndarray) -> np.ndarray:
        """0/1 ``(n,)``: probability at or above :attr:`threshold`."""
        return (self.predict_proba(images) >= self.threshold).astype(np.int64)
