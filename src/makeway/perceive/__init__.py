"""Perception (sense → **perceive** → track): per-frame and per-window judgements.

* :mod:`makeway.perceive.vision` — COCO vehicle detectors (:data:`~makeway.perceive.vision.DETECTORS`)
  and the emergency-vehicle crop classifiers;
* :mod:`makeway.perceive.audio` — siren detection, bearing and distance from the roof array.
"""
