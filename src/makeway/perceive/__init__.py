"""Perception (SPEC §7: sense → **perceive** → track): per-frame judgements.

``makeway.perceive.vision`` holds the COCO vehicle detectors (SPEC §2); audio perception joins it
as ``makeway.perceive.audio``.
"""
