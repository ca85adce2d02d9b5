"""The false-positive breakdown of the lit-light benchmark puts each false box in the right place."""

from __future__ import annotations

import numpy as np

from makeway.eval.lights import FrameResult, false_positive_breakdown


def test_each_false_box_lands_in_its_category() -> None:
    gt = np.array([[100.0, 100.0, 110.0, 110.0], [130.0, 100.0, 140.0, 110.0], [300.0, 300.0, 320.0, 310.0]])
    boxes = np.array(
        [
            [100, 100, 110, 110],  # true positive: not counted
            [130, 100, 143, 113],  # IoU 100/169 = 0.59 with lamp 2: true positive too
            [300, 296, 312, 314],  # IoU 120/296 = 0.41 with lamp 3 (unmatched): near miss on a missed lamp
            [103, 103, 106, 106],  # inside lamp 1, tiny: on a labelled lamp
            [120, 115, 124, 119],  # between lamps 1 and 2, inside the vehicle region: near the EV
            [600, 50, 640, 90],  # far away, 40 px: elsewhere
            [600, 400, 602, 402],  # below the threshold: not counted
        ],
        float,
    )
    scores = np.array([0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.01])
    colours = ["blue", "blue", "red", "blue", "amber", "red", "red"]
    res = [
        FrameResult("clip", "0", gt, [1, 1, 2], boxes, scores, 0.0, colours),
        FrameResult("clip", "1", np.zeros((0, 4)), [], np.array([[5.0, 5.0, 11.0, 9.0]]), np.array([0.3])),
    ]
    out = false_positive_breakdown(res, score_threshold=0.1)
    assert out["where"] == {
        "near miss": 1,
        "near_miss_on_missed_lamp": 1,
        "on a labelled lamp": 1,
        "near the EV": 1,
        "elsewhere": 1,
        "negative frame": 1,
    }
    assert out["colour"] == {"red": 2, "blue": 1, "amber": 1, "?": 1}
    assert out["size"] == {"<32px": 1, "<4px": 1, "<8px": 2, ">=32px": 1}
