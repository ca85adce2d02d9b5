"""Which labelled lit-light frames are train, validation and test, and loading them (no torch).

Every label file ``src/makeway/data/lights/*.csv`` is read with
:func:`makeway.train.light_labels.read_labels`; only checked frames count. The split is by source
(:data:`SPLITS`): no clip is in two splits; the ``ambulance_yolo`` images are train except those listed
in ``src/makeway/data/ambulance_yolo_held_out.txt``, which are test (reported as the source
``ambulance_yolo_held_out``). A label file whose source is not in :data:`SPLITS` is left out and
named. :func:`load_split` letterboxes the frames to the detector's input size
(:func:`makeway.perceive.vision.light_cnn.letterbox`) and scales the boxes with them.
"""

from __future__ import annotations

import glob
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from makeway.perceive.vision.light_cnn import letterbox
from makeway.sense.crops import AMBULANCE_YOLO_HELD_OUT

__all__ = [
    "HELD_OUT_FILE",
    "LABEL_DIR",
    "SPLITS",
    "LightFrame",
    "held_out_images",
    "label_files",
    "load_split",
    "source_name",
    "split_of",
]

_PKG = Path(__file__).resolve().parents[1]
LABEL_DIR = _PKG / "data" / "lights"
HELD_OUT_FILE = AMBULANCE_YOLO_HELD_OUT

#: Source (label file stem, or ``ambulance_yolo`` for the image folder) → split. ``ambulance_yolo``
#: images go to test when held out, else to train.
SPLITS: dict[str, str] = {
    "fire_trucks_red_lights": "train",
    "traffic_no_ev": "train",
    "ambulance_yolo": "train",
    "intersection_cam_ambulance": "val",
    "night_ambulance_lights": "test",
    "highway_cam_no_ev": "test",
}


# ----------------------------------------------------------------------------------------- data
@dataclass
class LightFrame:
    """One checked labelled frame, letterboxed: ``image`` BGR ``(H, W, 3)`` at the network's input
    size, ``boxes`` ``(n, 4)`` lit lights and ``negatives`` ``(m, 4)`` hard negatives in its pixels
    (source pixels × ``scale``), ``colours`` and ``vehicles`` per light; ``source`` names the split
    source (``ambulance_yolo_held_out`` for the held-out images), ``key`` the frame."""

    source: str
    key: str
    image: np.ndarray
    scale: float
    boxes: np.ndarray
    negatives: np.ndarray
    colours: list[str] = field(default_factory=list)
    vehicles: list[int] = field(default_factory=list)


def label_files(label_dir: str | Path | None = None) -> list[Path]:
    """Every ``*.csv`` label file of ``label_dir`` (default: the package's ``data/lights``), sorted."""
    root = Path(label_dir) if label_dir is not None else LABEL_DIR
    return sorted(Path(p) for p in glob.glob(str(root / "*.csv")))


def held_out_images(path: str | Path | None = None) -> set[str]:
    """Image names of ``ambulance_yolo/valid`` that must never be trained or tuned on."""
    p = Path(path) if path is not None else HELD_OUT_FILE
    if not p.is_file():
        return set()
    return {
        s.strip() for s in p.read_text(encoding="utf-8").splitlines() if s.strip() and not s.startswith("#")
    }


def source_name(source: str) -> str:
    """The split key of a label file's ``source``: the video stem, or ``ambulance_yolo`` for an image
    folder under it."""
    if source.split("/")[0] == "ambulance_yolo":
        return "ambulance_yolo"
    return Path(source).stem


def split_of(source: str, key: str, held_out: set[str]) -> tuple[str | None, str]:
    """``(split, report source)`` of one frame: split ``train``/``val``/``test`` or None (unknown
    source); the report source is the source name, ``ambulance_yolo_held_out`` for held-out images."""
    name = source_name(source)
    split = SPLITS.get(name)
    if name == "ambulance_yolo":
        if Path(key).name in held_out:
            return "test", "ambulance_yolo_held_out"
        return "train", name
    return split, name


def load_split(
    split: str,
    data_root: str | Path,
    *,
    label_dir: str | Path | None = None,
    input_size: tuple[int, int] | None = (640, 384),
    keep_images: bool = True,
    progress: Callable[[str], None] | None = None,
) -> tuple[list[LightFrame], list[str]]:
    """The checked frames of one split (``train``, ``val``, ``test``) from every label file, and the
    label files left out because their source is not in :data:`SPLITS`. Frames are letterboxed to
    ``input_size`` ``(width, height)``, or kept as decoded (scale 1) when it is None. With
    ``keep_images`` False the frames carry no pixels (labels only; ``image`` is an empty array)."""
    from makeway.train.light_labels import iter_label_frames, read_labels

    held = held_out_images()
    out: list[LightFrame] = []
    unknown: list[str] = []
    for path in label_files(label_dir):
        lf = read_labels(path)
        frames = lf.frames()
        wanted = {}
        for key, rows in frames.items():
            if not rows or not rows[0].checked:
                continue
            sp, name = split_of(lf.source, key, held)
            if sp is None:
                if str(path) not in unknown:
                    unknown.append(str(path))
                continue
            if sp == split:
                wanted[key] = name
        if not wanted:
            continue
        if progress is not None:
            progress(f"{path.name}: {len(wanted)} frames")
        iterator: Any
        if keep_images:
            iterator = iter_label_frames(lf, data_root, keys=wanted)
        else:
            iterator = ((k, None) for k in sorted(wanted))
        for key, img in iterator:
            rows = frames[key]
            if img is not None and input_size is not None:
                canvas, s = letterbox(img, *input_size)
            elif img is not None:
                canvas, s = img, 1.0
            else:
                canvas, s = np.zeros((0, 0, 3), np.uint8), 1.0
            lights = [r for r in rows if r.kind == "light" and r.box is not None]
            negs = [r for r in rows if r.kind == "negative" and r.box is not None]
            out.append(
                LightFrame(
                    source=wanted[key],
                    key=key,
                    image=canvas,
                    scale=s,
                    boxes=np.array([r.box for r in lights], np.float64).reshape(-1, 4) * s,
                    negatives=np.array([r.box for r in negs], np.float64).reshape(-1, 4) * s,
                    colours=[str(r.colour) for r in lights],
                    vehicles=[int(r.vehicle or 0) for r in lights],
                )
            )
    return out, unknown
