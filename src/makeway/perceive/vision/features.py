"""Hand-made crop features of the classical classifier study (SPEC §2, seeds 001/003).

Seeds 001/003 are the thesis on two vision frameworks, roadside units and a pull-over controller,
and the project report of the same work (``../shared/seeds/001_…``, ``003_…``); both hold the
classifier study that SPEC §2 digests.

Every feature takes a batch of ``uint8`` BGR crops ``(n, H, W, 3)`` (as
:meth:`makeway.sense.crops.CropSet.load_images` returns) and gives ``float32`` ``(n, d)``:

=========  ======  ==================================================================================
name       d       what
=========  ======  ==================================================================================
pixels     49152   the crop resized to 128×128, flattened, scaled to [0, 1]
hog        7200    scikit-image HOG of the 128×128 grey crop: 8 orientations, 10×10 px cells,
                   3×3-cell blocks (scikit-image's default; SPEC names none), ``transform_sqrt``,
                   L1 block norm
rgb_hist   32768   3-D colour histogram, 32 bins per channel (OpenCV ``calcHist``; channel order
                   B, G, R as decoded), divided by the pixel count so it sums to 1
hsv8       8       the custom red/blue light vector (:func:`hsv_red_blue`)
yolox      1280    pooled YOLOX-nano feature maps (:mod:`makeway.perceive.vision.backbone`; needs
                   ``yolox_nano.onnx`` and the ``onnx`` package; the extractor is built on first use)
nanodet    1624    pooled NanoDet-m ShuffleNetV2 stages at 224 px (same module; ``nanodet_m_416.onnx``)
=========  ======  ==================================================================================

``hsv8`` per colour *c* of the colour set (default: blue, red): area of the colour's HSV mask and
area of its largest external contour (fractions of the crop area), and the x/y centroid of that
largest contour as fractions of the crop width/height (0 when the colour is absent). Order: the
areas of all colours, then the largest-contour areas, then the centroids colour by colour — for the
default set ``[blue_area, red_area, blue_largest, red_largest, blue_cx, blue_cy, red_cx, red_cy]``.

The colour set is configuration (SPEC §7: light colours differ by jurisdiction):
``{name: [(low_hsv, high_hsv), ...]}`` in OpenCV's HSV (H 0–179 = degrees/2, S and V 0–255); a
colour may need several ranges (red wraps around H = 0). :data:`DEFAULT_LIGHT_COLOURS`:

* blue: H 100–130 (200°–260°), S ≥ 150, V ≥ 100 — saturated, bright blue;
* red: H 0–10 or 170–179 (340°–20°), S ≥ 150, V ≥ 100.

These catch lit beacons but also blue or red paint; the classifiers learn what the mix means.
Amber would be e.g. H 15–30.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from functools import partial
from typing import Any

import cv2
import numpy as np

__all__ = [
    "DEFAULT_LIGHT_COLOURS",
    "FEATURES",
    "HSVRange",
    "compute_features",
    "hog_features",
    "hsv_feature_names",
    "hsv_red_blue",
    "nanodet_backbone",
    "pixels",
    "rgb_histogram",
    "yolox_backbone",
]

HSVRange = tuple[tuple[int, int, int], tuple[int, int, int]]

#: The default light colours of :func:`hsv_red_blue` (see the module docstring).
DEFAULT_LIGHT_COLOURS: dict[str, list[HSVRange]] = {
    "blue": [((100, 150, 100), (130, 255, 255))],
    "red": [((0, 150, 100), (10, 255, 255)), ((170, 150, 100), (179, 255, 255))],
}

_STUDY_SIZE = 128  # SPEC §2: pixels and HOG on 128×128 crops


def _check_batch(images: np.ndarray) -> np.ndarray:
    arr = np.asarray(images)
    if arr.ndim != 4 or arr.shape[3] != 3 or arr.dtype != np.uint8:
        raise ValueError(f"expected uint8 BGR images (n, H, W, 3), got {arr.dtype} {arr.shape}")
    return arr


def _resize(image: np.ndarray, size: int) -> np.ndarray:
    h, w = image.shape[:2]
    if (h, w) == (size, size):
        return image
    interp = cv2.INTER_AREA if h > size or w > size else cv2.INTER_LINEAR
    return cv2.resize(image, (size, size), interpolation=interp)


def pixels(images: np.ndarray, size: int = _STUDY_SIZE) -> np.ndarray:
    """Raw pixels: each crop resized to ``size``×``size``, flattened (B, G, R interleaved), / 255."""
    arr = _check_batch(images)
    out = np.empty((len(arr), size * size * 3), dtype=np.float32)
    for i, image in enumerate(arr):
        out[i] = _resize(image, size).reshape(-1)
    out /= 255.0
    return out


def hog_features(
    images: np.ndarray,
    *,
    size: int = _STUDY_SIZE,
    orientations: int = 8,
    cell: int = 10,
    block: int = 3,
) -> np.ndarray:
    """HOG of the grey ``size``×``size`` crop (scikit-image; defaults as SPEC §2)."""
    from skimage.feature import hog  # optional dependency (extra "study")

    arr = _check_batch(images)
    rows = []
    for image in arr:
        grey = cv2.cvtColor(_resize(image, size), cv2.COLOR_BGR2GRAY)
        rows.append(
            hog(
                grey,
                orientations=orientations,
                pixels_per_cell=(cell, cell),
                cells_per_block=(block, block),
                block_norm="L1",
                transform_sqrt=True,
                feature_vector=True,
            )
        )
    if not rows:
        return np.empty((0, 0), dtype=np.float32)
    return np.asarray(rows, dtype=np.float32)


def rgb_histogram(images: np.ndarray, bins: int = 32) -> np.ndarray:
    """3-D colour histogram with ``bins`` per channel (``bins³`` values), normalised to sum 1."""
    arr = _check_batch(images)
    out = np.empty((len(arr), bins**3), dtype=np.float32)
    for i, image in enumerate(arr):
        hist = cv2.calcHist([image], [0, 1, 2], None, [bins] * 3, [0, 256] * 3)
        out[i] = hist.reshape(-1) / float(image.shape[0] * image.shape[1])
    return out


def hsv_feature_names(colours: Mapping[str, Sequence[HSVRange]] = DEFAULT_LIGHT_COLOURS) -> list[str]:
    """Column names of :func:`hsv_red_blue` for ``colours``, in output order."""
    names = [f"{c}_area" for c in colours] + [f"{c}_largest_area" for c in colours]
    for c in colours:
        names += [f"{c}_cx", f"{c}_cy"]
    return names


def _colour_mask(hsv: np.ndarray, ranges: Sequence[HSVRange]) -> np.ndarray:
    mask: np.ndarray = np.zeros(hsv.shape[:2], dtype=np.uint8)
    for low, high in ranges:
        mask = cv2.bitwise_or(
            mask, cv2.inRange(hsv, np.array(low, dtype=np.uint8), np.array(high, dtype=np.uint8))
        )
    return mask


def hsv_red_blue(
    images: np.ndarray, colours: Mapping[str, Sequence[HSVRange]] = DEFAULT_LIGHT_COLOURS
) -> np.ndarray:
    """The custom light-colour vector (4 values per colour; 8 for the default blue/red set)."""
    arr = _check_batch(images)
    k = len(colours)
    if k == 0:
        raise ValueError("colours must name at least one colour")
    out = np.zeros((len(arr), 4 * k), dtype=np.float32)
    for i, image in enumerate(arr):
        h, w = image.shape[:2]
        area = float(h * w)
        hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
        for j, ranges in enumerate(colours.values()):
            mask = _colour_mask(hsv, ranges)
            out[i, j] = cv2.countNonZero(mask) / area
            contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            if not contours:
                continue
            areas = [cv2.contourArea(c) for c in contours]
            best = contours[int(np.argmax(areas))]
            out[i, k + j] = max(areas) / area
            m = cv2.moments(best)
            if m["m00"] > 0:
                cx, cy = m["m10"] / m["m00"], m["m01"] / m["m00"]
            else:  # a line or point contour: take its bounding-box centre
                bx, by, bw, bh = cv2.boundingRect(best)
                cx, cy = bx + bw / 2.0, by + bh / 2.0
            out[i, 2 * k + 2 * j] = cx / w
            out[i, 2 * k + 2 * j + 1] = cy / h
    return out


_EXTRACTORS: dict[str, Any] = {}


def _backbone(images: np.ndarray, backbone: str, input_size: int) -> np.ndarray:
    """Pooled feature maps of a detector backbone with its default layers (one cached extractor per
    backbone and process)."""
    arr = _check_batch(images)
    key = f"{backbone}@{input_size}"
    extractor = _EXTRACTORS.get(key)
    if extractor is None:
        from makeway.perceive.vision.backbone import BackboneFeatures

        extractor = _EXTRACTORS[key] = BackboneFeatures(backbone=backbone, input_size=input_size)
    return np.asarray(extractor.transform(arr), dtype=np.float32)


def yolox_backbone(images: np.ndarray) -> np.ndarray:
    """Pooled YOLOX-nano feature maps with the default layers at 160 px."""
    return _backbone(images, "yolox_nano", 160)


def nanodet_backbone(images: np.ndarray) -> np.ndarray:
    """Pooled NanoDet-m ShuffleNetV2 stages at 224 px."""
    return _backbone(images, "nanodet_m", 224)


#: The study's features by name (see the module docstring).
FEATURES: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "pixels": pixels,
    "hog": hog_features,
    "rgb_hist": rgb_histogram,
    "hsv8": partial(hsv_red_blue, colours=DEFAULT_LIGHT_COLOURS),
    "yolox": yolox_backbone,
    "nanodet": nanodet_backbone,
}


def compute_features(name: str, images: np.ndarray) -> np.ndarray:
    """``FEATURES[name](images)``; ``ValueError`` listing the registered names for an unknown one."""
    try:
        fn = FEATURES[name]
    except KeyError:
        raise ValueError(f"unknown feature {name!r}; registered: {', '.join(FEATURES)}") from None
    return fn(images)
