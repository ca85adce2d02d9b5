"""Vision perception: COCO vehicle detectors (SPEC §2, Framework B: detector of class vehicle → SORT)."""

from makeway.perceive.vision.detectors import (
    COCO_CLASSES,
    DETECTORS,
    VEHICLE_CLASSES,
    Detector,
    NanoDetM,
    YoloxNano,
    create_detector,
    nms,
    resolve_model_path,
)

__all__ = [
    "COCO_CLASSES",
    "DETECTORS",
    "VEHICLE_CLASSES",
    "Detector",
    "NanoDetM",
    "YoloxNano",
    "create_detector",
    "nms",
    "resolve_model_path",
]
