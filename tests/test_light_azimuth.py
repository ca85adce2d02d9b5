"""Azimuth of a rendered lit lamp through the rig with the light detector in the loop."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from makeway.eval.light_azimuth import LampScene, random_scene, render_lamp_scene, score_scene
from makeway.perceive.vision.lights import LIGHT_DETECTORS
from makeway.sense.rig import load_rig
from makeway.train.light_labels import iter_label_frames, read_labels

LABELS = Path(__file__).resolve().parents[1] / "src" / "makeway" / "data" / "lights"


def test_rendered_lamps_are_found_and_placed_within_a_degree(data_root: Path) -> None:
    rig = load_rig("default")
    lab = read_labels(LABELS / "night_ambulance_lights.csv")
    dark = [
        k for k, rows in lab.frames().items() if rows[0].checked and not any(r.kind == "light" for r in rows)
    ]
    backgrounds = [img for _, img in iter_label_frames(lab, data_root, keys=dark[:3])]
    detector = LIGHT_DETECTORS["colour"](colours=("blue",))  # type: ignore[call-arg]
    rng = np.random.default_rng(3)
    results = []
    for i in range(8):
        scene = random_scene(rig, rng, range_m=(5.0, 20.0))
        results.append(score_scene(scene, rig, render_lamp_scene(scene, rig, backgrounds[i % 3]), detector))
    found = [r for r in results if r.found]
    assert len(found) >= 6
    assert float(np.median([r.ray_error_deg for r in found])) < 1.0
    assert {r.camera for r in results} <= set(rig.names)


def test_a_lamp_straight_ahead_of_the_front_camera_has_azimuth_zero(data_root: Path) -> None:
    rig = load_rig("default")
    front = rig.camera("front")
    ahead = front.rotation @ np.array([0.0, 0.0, 1.0])
    point = front.translation_m + 10.0 * ahead
    scene = LampScene("front", (float(point[0]), float(point[1]), float(point[2])))
    image = render_lamp_scene(scene, rig, np.full((720, 1280, 3), 30, np.uint8))
    res = score_scene(scene, rig, image, LIGHT_DETECTORS["colour"](colours=("blue",)))  # type: ignore[call-arg]
    assert res.found and res.ray_error_deg is not None and res.ray_error_deg < 0.2
