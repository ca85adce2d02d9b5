"""Image quality that gives a crop's class away, and how to take it out of training data.

In road photos and video, the emergency vehicle is usually the subject: close, large and sharp,
while the other vehicles are small, distant and soft. A classifier trained on such sources learns
"sharp ⇒ EV", and on a source where every crop is sharp (web photos of ordinary cars) it calls
most of them EVs. Measured on the sources of the cross-source protocol
(:mod:`makeway.eval.cross_source`), the median :func:`effective_side` of `road_clips` crops is
48 px for other vehicles and 128 px for EVs, of `ambulance_yolo` crops 96 and 160 px; in
`ev_crops` both are 224 px.

* :func:`effective_side` — the smallest side (px) whose Nyquist frequency keeps 98 % of a crop's
  spectral detail: how much real resolution a crop holds, whatever its stored size.
* :func:`match_positive_quality` — the de-confounding step: each positive crop of a source is
  shrunk to a side drawn from the effective sides of that source's negatives (only ever made
  softer, never sharper), so that within every source both classes have the same distribution of
  sharpness and sharpness no longer tells the class.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = [
    "QUALITY_SIDES",
    "effective_side",
    "match_one_source",
    "match_positive_quality",
    "source_of_groups",
]

#: Sides (px) :func:`effective_side` tries, smallest first.
QUALITY_SIDES: tuple[int, ...] = (24, 32, 48, 64, 96, 128, 160, 224)


def effective_side(
    image: np.ndarray,
    sides: Sequence[int] = QUALITY_SIDES,
    *,
    tolerance: float = 0.02,
    floor_cycles: float = 6.0,
) -> int:
    """The smallest side in ``sides`` (px) whose Nyquist frequency (side / 2 cycles per image)
    leaves less than ``tolerance`` of the crop's detail above it; the largest side when none does.

    Detail is the power of the grey crop's spectrum (Hann-windowed, mean removed) above
    ``floor_cycles`` cycles per image; a frequency counts by the larger of its two components, each
    in cycles per image along its own axis. A crop shrunk to ``s`` px and enlarged back reads
    about ``s`` (bilinear enlargement leaks a little above the Nyquist frequency, so 24–32 px read
    48 px); a sharp close-up photo reads the full side. ``image``: ``uint8`` BGR ``(h, w, 3)`` or
    grey ``(h, w)``, at the size the model reads (e.g. 224 × 224).

    Raises:
        ValueError: not a 2-D or 3-channel image, or no sides.
    """
    import cv2

    if not sides:
        raise ValueError("no sides to try")
    if image.ndim == 3 and image.shape[2] == 3:
        grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    elif image.ndim == 2:
        grey = image
    else:
        raise ValueError(f"expected an (h, w, 3) BGR or (h, w) grey image, got shape {image.shape}")
    h, w = grey.shape
    g = grey.astype(np.float64)
    g = (g - g.mean()) * np.outer(np.hanning(h), np.hanning(w))
    power = np.abs(np.fft.fft2(g)) ** 2
    cycles = np.maximum(np.abs(np.fft.fftfreq(h) * h)[:, None], np.abs(np.fft.fftfreq(w) * w)[None, :])
    detail = float(power[cycles > floor_cycles].sum())
    ordered = sorted(int(s) for s in sides)
    if detail <= 0.0:
        return ordered[0]
    for side in ordered:
        if float(power[cycles > side / 2].sum()) < tolerance * detail:
            return side
    return ordered[-1]


def source_of_groups(groups: Sequence[Any] | np.ndarray | None, n: int) -> np.ndarray:
    """Each crop's source from its group name: the part before the first ``/`` (the convention of
    :func:`makeway.eval.cross_source.merge_sources`), ``""`` for a group without one; all ``""``
    when ``groups`` is ``None``."""
    if groups is None:
        return np.full(n, "", dtype=object)
    names = [str(g) for g in np.asarray(groups).tolist()]
    if len(names) != n:
        raise ValueError(f"{n} crops but {len(names)} groups")
    return np.array([g.split("/", 1)[0] if "/" in g else "" for g in names], dtype=object)


def match_positive_quality(
    images: np.ndarray,
    labels: np.ndarray,
    sources: Sequence[Any] | np.ndarray,
    *,
    seed: int = 0,
    sides: Sequence[int] = QUALITY_SIDES,
) -> tuple[np.ndarray, np.ndarray]:
    """``(images, shrunk_to)``: a copy of ``images`` (``uint8`` ``(n, h, w, 3)``) in which every
    positive crop (label 1) of a source is shrunk to a side drawn at random from the effective
    sides (:func:`effective_side`) of the same source's negatives and enlarged back
    (:func:`~makeway.perceive.vision.ev_classifier.shrink_copies`) — only when
    that side is below its own effective side. ``shrunk_to[i]`` is the side crop ``i`` was shrunk
    to, 0 where it was left as it was; ``sides`` are the sides :func:`effective_side` tries. A
    source without negatives leaves its positives unchanged.

    Raises:
        ValueError: lengths differ, or labels other than 0 and 1.
    """
    from makeway.perceive.vision.ev_classifier import shrink_copies

    x = np.asarray(images)
    y = np.asarray(labels).astype(np.int64).ravel()
    src = np.asarray(sources, dtype=object).ravel()
    if not (len(x) == len(y) == len(src)):
        raise ValueError(f"{len(x)} images, {len(y)} labels and {len(src)} sources")
    if not set(np.unique(y).tolist()) <= {0, 1}:
        raise ValueError("labels must be 0 or 1")
    rng = np.random.default_rng(seed)
    own = np.array([effective_side(im, sides) for im in x])
    out = x.copy()
    used = np.zeros(len(x), dtype=np.int64)
    for name in sorted(set(src.tolist()), key=str):
        mine = src == name
        negative_sides = own[mine & (y == 0)]
        if not len(negative_sides):
            continue
        for i in np.flatnonzero(mine & (y == 1)):
            side = int(rng.choice(negative_sides))
            if side < own[i]:
                out[i] = shrink_copies(x[i : i + 1], side)[0]
                used[i] = side
    return out, used


def match_one_source(images: np.ndarray, labels: np.ndarray, *, seed: int = 0) -> tuple[np.ndarray, str]:
    """:func:`match_positive_quality` for crops of one source: ``(images, note)``, the note saying
    how many positives were softened (for a training log)."""
    out, used = match_positive_quality(images, labels, np.zeros(len(images), dtype=np.int64), seed=seed)
    return out, f"{int((used > 0).sum())} positive crops made as soft as its negatives"
