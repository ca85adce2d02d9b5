"""Vision perception: COCO vehicle detectors and emergency-vehicle crop classifiers.

* :data:`DETECTORS` — the vehicle detectors by name (``yolox_nano``, ``nanodet_m``), ONNX Runtime;
* :func:`load_crop_classifier` — a shipped crop classifier by name (:data:`SHIPPED_MODELS`) or a file;
  :class:`EVTrackClassifier` judges every track of a frame with it (a :class:`TrackClassifier`).
"""

from makeway.perceive.vision.cnn_classifier import OnnxCropClassifier
from makeway.perceive.vision.detectors import (
    COCO_CLASSES,
    DETECTORS,
    VEHICLE_CLASSES,
    Detector,
    NanoDetM,
    YoloxNano,
    nms,
    resolve_model_path,
)
from makeway.perceive.vision.ev_classifier import (
    SHIPPED_MODELS,
    CropClassifier,
    EVCropClassifier,
    EVTrackClassifier,
    TrackClassifier,
    load_crop_classifier,
)

__all__ = [
    "COCO_CLASSES",
    "DETECTORS",
    "SHIPPED_MODELS",
    "VEHICLE_CLASSES",
    "CropClassifier",
    "Detector",
    "EVCropClassifier",
    "EVTrackClassifier",
    "NanoDetM",
    "OnnxCropClassifier",
    "TrackClassifier",
    "YoloxNano",
    "load_crop_classifier",
    "nms",
    "resolve_model_path",
]
