"""Vision perception: COCO vehicle detectors (SPEC §2, Framework B: detector of class vehicle → SORT)
and the ONNX crop CNN (SPEC §1)."""

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

__all__ = [
    "COCO_CLASSES",
    "DETECTORS",
    "VEHICLE_CLASSES",
    "Detector",
    "NanoDetM",
    "OnnxCropClassifier",
    "YoloxNano",
    "nms",
    "resolve_model_path",
]
