"""Audio perception (SPEC §3, issue 4): siren detection and localization from the roof array.

:mod:`makeway.perceive.audio.labels` turns a recording's trajectories into per-window labels.
"""

from makeway.perceive.audio.labels import Labels, label_recording

__all__ = ["Labels", "label_recording"]
