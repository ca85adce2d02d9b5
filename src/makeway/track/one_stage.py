"""One SORT over a one-stage EV detector's boxes (Framework A of seed 001; issue 24, item 3).

Seed 001 argues that a detector with the classes "emergency vehicle" and "other vehicle", tracked
per class, restarts a track whenever its class flips. Here all vehicles go through one tracker,
whatever their class, and the class and P(EV) of each frame's detection ride along with the track.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from makeway.messages import Box, Detection, Track
from makeway.perceive.vision.ev_detector import EV_DET_CLASSES
from makeway.track.sort import Sort

__all__ = ["track_one_stage"]


def track_one_stage(tracker: Sort, arrays: tuple[np.ndarray, ...]) -> tuple[list[Track], dict[int, float]]:
    """One SORT step over a one-stage EV detector's boxes (Framework A): all vehicles in one
    tracker, whatever their class, so a class flip does not end a track.

    ``arrays`` is ``(boxes, scores, class_ids, p_ev)``. Returns the confirmed tracks — with the
    class (0 emergency vehicle, 1 other vehicle) and score of the detection SORT associated with
    each this frame — and ``{track_id: p_ev}`` of that detection. The association is SORT's own:
    each detection enters the tracker with its index as class id, read back from the track.
    """
    boxes, scores, class_ids, p_ev = arrays[:4]
    detections = [
        Detection(box=Box(*b), score=float(sc), class_id=k, label="vehicle")
        for k, (b, sc) in enumerate(zip(boxes.tolist(), scores.tolist(), strict=True))
    ]
    tracks: list[Track] = []
    probs: dict[int, float] = {}
    for t in tracker.update(detections):
        k = t.class_id
        cls = int(class_ids[k])
        tracks.append(replace(t, class_id=cls, label=EV_DET_CLASSES[cls]))
        probs[t.track_id] = float(p_ev[k])
    return tracks, probs
