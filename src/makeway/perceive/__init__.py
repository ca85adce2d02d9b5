"""Perception (SPEC §7: sense → **perceive** → track): turn raw frames into detections.

``makeway.perceive.vision`` holds the COCO vehicle detectors (SPEC §2).
"""

from makeway.perceive.vision import (
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
