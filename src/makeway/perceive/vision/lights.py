"""Lit emergency-light detectors: one interface, a registry, and the colour sets per jurisdiction.

A light detector takes one BGR frame (``uint8``, H×W×3, OpenCV order) and returns the lit emergency
lights it sees as :class:`~makeway.messages.LightDetection` boxes in that frame's pixels. Detectors are
registered in :data:`LIGHT_DETECTORS` (``LIGHT_DETECTORS["colour"](colours=("blue", "white"))``);
each factory accepts ``colours``, the set of emergency-light colours that count in the jurisdiction
(:data:`COLOUR_SETS`), and detections of other colours are never returned.

``colour`` is the rule-based finder of :mod:`makeway.perceive.vision.light_colour` (colour masks and
bright cores with a coloured halo): no training, a baseline and the labelling tool's proposer.
``cnn`` is the learned heat-map detector with seed 004's colour attention
(:mod:`makeway.perceive.vision.light_cnn`, ONNX Runtime; trained by ``makeway lights-train``).
``verified`` is two-stage: the rule finder's proposals (wide hue ranges, several settings) scored by
a learned verifier, gradient-boosted trees in ONNX (:mod:`makeway.perceive.vision.light_verify`;
trained by ``makeway lights-train --verifier``) that also read where each proposal sits relative to
the frame's vehicle boxes (YOLOX-nano; a caller that has the boxes passes them, see
:class:`VehicleContextLightDetector`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np

from makeway.messages import Box, LightDetection
from makeway.perceive.vision.light_cnn import CnnLightDetector
from makeway.perceive.vision.light_colour import COLOURS, HSV_PRESETS, ProposalConfig, propose
from makeway.perceive.vision.light_verify import VerifiedLightDetector
from makeway.registry import Registry

__all__ = [
    "COLOUR_SETS",
    "DEFAULT_LIGHT_DETECTOR",
    "LIGHT_DETECTORS",
    "REVIEW_LIGHT_DETECTOR",
    "CnnLightDetector",
    "ColourLightDetector",
    "LightDetector",
    "VehicleContextLightDetector",
    "VerifiedLightDetector",
    "colour_set",
]

#: Emergency-light colours per jurisdiction. ``eu`` (the default, as seed 004): blue, and the bluish
#: white of blue LEDs; ``us``: red, blue and white; ``uk_amber`` adds amber (recovery and
#: highway-authority vehicles); ``all``: every colour the labels know.
COLOUR_SETS: dict[str, tuple[str, ...]] = {
    "eu": ("blue", "white"),
    "us": ("red", "blue", "white"),
    "uk_amber": ("blue", "amber", "white"),
    "all": COLOURS,
}


def colour_set(spec: str | Sequence[str]) -> tuple[str, ...]:
    """A colour set from a preset name of :data:`COLOUR_SETS` or from colour names (a sequence, or a
    comma-separated string such as ``"blue,red"``); ``ValueError`` naming the unknown entry."""
    if isinstance(spec, str):
        if spec in COLOUR_SETS:
            return COLOUR_SETS[spec]
        names = [c.strip() for c in spec.split(",") if c.strip()]
    else:
        names = list(spec)
    bad = [c for c in names if c not in COLOURS]
    if bad or not names:
        raise ValueError(
            f"unknown colour set {spec!r}: use a preset ({', '.join(COLOUR_SETS)}) "
            f"or colours from {', '.join(COLOURS)}"
        )
    return tuple(dict.fromkeys(names))


class LightDetector(Protocol):
    """What every registered light detector offers."""

    colours: tuple[str, ...]

    def detect(self, frame_bgr: np.ndarray, frame: int = 0) -> list[LightDetection]:
        """Lit emergency lights in one BGR frame, in its pixels."""
        ...


@runtime_checkable
class VehicleContextLightDetector(Protocol):
    """A light detector that may read the frame's vehicle boxes (``uses_vehicles``): a caller that
    has already detected the vehicles passes them (boxes, scores, COCO class ids, as
    :meth:`~makeway.perceive.vision.detectors.Detector.detect_arrays` returns them) instead of
    letting the detector find them again."""

    colours: tuple[str, ...]
    uses_vehicles: bool

    def detect(
        self,
        frame_bgr: np.ndarray,
        frame: int = 0,
        *,
        vehicles: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    ) -> list[LightDetection]:
        """Lit emergency lights in one BGR frame, in its pixels, given its vehicle boxes if known."""
        ...


LIGHT_DETECTORS: Registry[type[LightDetector]] = Registry("light detector")
LIGHT_DETECTORS.register("cnn")(CnnLightDetector)
LIGHT_DETECTORS.register("verified")(VerifiedLightDetector)

#: The detector the real-time video pipeline (``makeway detect``'s lights rules) uses when none is
#: named: the fastest.
DEFAULT_LIGHT_DETECTOR = "colour"

#: The detector ``makeway lights`` uses when none is named: the most accurate on the held-out
#: labels (docs/results.md), about 4× slower than the rules — a person reviewing footage wants few
#: false boxes more than speed.
REVIEW_LIGHT_DETECTOR = "verified"


@LIGHT_DETECTORS.register("colour")
class ColourLightDetector:
    """Rule-based lit-light finder (:func:`~makeway.perceive.vision.light_colour.propose`).

    ``colours`` is the jurisdiction's colour set (a :data:`COLOUR_SETS` name or colour names);
    ``hue`` a hue-range preset of :data:`~makeway.perceive.vision.light_colour.HSV_PRESETS`;
    ``min_score`` drops weaker boxes (score: mean brightness of the lit pixels times the fraction of
    the box they fill, 0–1).
    """

    def __init__(
        self, colours: str | Sequence[str] = "eu", *, hue: str = "default", min_score: float = 0.0
    ) -> None:
        self.colours = colour_set(colours)
        if hue not in HSV_PRESETS:
            raise ValueError(f"unknown hue preset {hue!r}; choose from: {', '.join(HSV_PRESETS)}")
        self.config = ProposalConfig(colours=self.colours, hsv=dict(HSV_PRESETS[hue]))
        self.min_score = float(min_score)

    def detect(self, frame_bgr: np.ndarray, frame: int = 0) -> list[LightDetection]:
        if frame_bgr.ndim != 3 or frame_bgr.shape[2] != 3 or frame_bgr.dtype != np.uint8:
            raise ValueError(f"expected a uint8 BGR image H×W×3, got {frame_bgr.dtype} {frame_bgr.shape}")
        return [
            LightDetection(Box(p.x1, p.y1, p.x2, p.y2), p.colour, min(1.0, p.score), frame)
            for p in propose(frame_bgr, self.config, frame=frame)
            if p.score >= self.min_score and p.colour in self.colours
        ]
