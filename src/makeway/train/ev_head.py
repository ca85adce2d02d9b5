"""Training of the EV crop classifier head (:class:`~makeway.perceive.vision.ev_classifier.EVCropClassifier`):
pooled detector-backbone features of each crop (and its mirror image) + standardised logistic
regression, written as ``.npz``. No torch needed."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from makeway.eval.classification import operating_point_metrics
from makeway.perceive.vision.ev_classifier import DEFAULT_MODEL, EVCropClassifier
from makeway.sense.crops import committed_split, near_duplicate_groups, read_crop_folder

__all__ = ["CropTrainingRun", "train_ev_head"]


@dataclass(frozen=True)
class CropTrainingRun:
    """What a crop classifier training wrote (``model``; a CNN's ``checkpoint`` too) and its scores on
    the committed ev_crops holdout of each training folder that is ev_crops: ``held_out`` as
    ``(folder, metrics)`` pairs (:func:`~makeway.eval.classification.operating_point_metrics`)."""

    model: Path
    checkpoint: Path | None
    held_out: list[tuple[Path, dict[str, Any]]]


def train_ev_head(
    clf: EVCropClassifier,
    data: Sequence[str | Path],
    out: str | Path | None = None,
    *,
    log: Callable[[str], None] | None = None,
) -> CropTrainingRun:
    """Fit the head ``clf`` (its feature blocks, mirror and shrink settings as constructed) on the crop
    folders ``data`` and save it to ``out`` (default: the shipped head's path). On ev_crops only the
    training part is used (the committed holdout is left out) and the held-out part is scored
    afterwards. Near-duplicate crops stay in one fold of the inner cross-validation that picks the
    regularisation C. ``log`` receives a line per folder and one for the file written.

    Raises:
        InputError: a crop folder cannot be read (all are read before any work), or ``out`` cannot be
            written.
    """

    def say(line: str) -> None:
        if log is not None:
            log(line)

    target = Path(out) if out is not None else DEFAULT_MODEL
    sets = [(Path(folder), read_crop_folder(folder)) for folder in data]  # all read before any work
    xs: list[np.ndarray] = []
    xms: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    gs: list[np.ndarray] = []
    parts: list[str] = []
    held: list[tuple[Any, Path]] = []
    for folder, crops in sets:
        split = committed_split(crops)
        if split is not None:
            train_idx, test_idx = split
            held.append((crops.subset(test_idx), folder))
            crops = crops.subset(train_idx)
            what = "training part (committed holdout excluded)"
        else:
            what = "all"
        say(f"{folder.name}: {what}, {len(crops)} crops ({crops.n_positive} positive)")
        parts.append(f"{folder.name}: {what}, {len(crops)} crops, {crops.n_positive} positive")
        images = crops.load_images(clf.input_size, cache=False)
        # near-duplicates stay in one inner-CV fold (as the holdout keeps them on one side)
        groups = np.char.add(f"{len(gs)}:", near_duplicate_groups(images).astype(str))
        x, x_mirrored, y, g = clf.training_features(images, crops.labels, groups)
        xs.append(x)
        if x_mirrored is not None:
            xms.append(x_mirrored)
        ys.append(y)
        gs.append(g)
    if clf.shrink:
        parts.append(f"each crop also shrunk to {', '.join(f'{w} px' for w in clf.shrink)} and enlarged back")
    clf.fit_features(
        np.concatenate(xs),
        np.concatenate(ys),
        x_mirrored=np.concatenate(xms) if xms else None,
        groups=np.concatenate(gs),
        training="; ".join(parts),
    )
    clf.save(target)
    say(f"C = {clf.C:g}; head → {target} ({target.stat().st_size} bytes)")
    scores = []
    for test_set, folder in held:
        probs = clf.predict_proba(test_set.load_images(clf.input_size, cache=False))
        scores.append((folder, operating_point_metrics(probs, test_set.labels, clf.threshold)))
    return CropTrainingRun(model=target, checkpoint=None, held_out=scores)
