"""Crops of tracked vehicles for the per-track EV classifier (SPEC §1).

SPEC §1: the classifier sees a square crop around each tracked vehicle, resized to 224×224, all
actors of a frame in one batch; tracks whose box centre is outside the image or whose (projected)
width is under 18 px get no judgement this frame.

* :func:`square_crop` — the smallest square around a 2D box, grown on every side by ``margin`` ×
  the box's longer side (context), replicate-padded where it leaves the image, resized.
* :func:`crops_for_tracks` — the same for every box of a frame, as one ``(k, size, size, 3)`` batch
  plus the indices of the boxes that got a crop.
* :func:`project_box3d` — a 3D box (8 corners, world frame) through a pinhole camera ``K [R | t]``
  to the square the crop is taken from: centroid of the 8 projected corners, smallest axis-aligned
  square centred there holding all of them.
* :func:`box3d_corners` — the 8 corners of a yawed 3D box (z up), for callers with centre/size boxes.
* :func:`detection_crop_items` — positives from labelled boxes and negatives from detector boxes
  that overlap none of them (``makeway classify build-ambulance-crops``).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import cv2
import numpy as np

from makeway.messages import Box

__all__ = [
    "MIN_CROP_WIDTH_PX",
    "box3d_corners",
    "crops_for_tracks",
    "detection_crop_items",
    "project_box3d",
    "square_crop",
    "square_region",
]

#: SPEC §1: tracks narrower than this (pixels) are skipped.
MIN_CROP_WIDTH_PX = 18.0


def square_region(box: Box, margin: float = 0.1) -> tuple[int, int, int]:
    """``(x0, y0, side)`` in integer pixels of the crop square of ``box`` (may leave the image).

    The square is centred on the box centre; its side is the box's longer side × ``1 + 2·margin``
    (at least 1 px).
    """
    if margin < 0:
        raise ValueError(f"margin must be >= 0, got {margin}")
    side = max(box.width, box.height) * (1.0 + 2.0 * margin)
    cx, cy = box.center
    s = max(1, round(side))
    return round(cx - s / 2.0), round(cy - s / 2.0), s


def square_crop(
    image: np.ndarray,
    box: Box,
    *,
    margin: float = 0.1,
    size: int = 224,
    min_width: float = MIN_CROP_WIDTH_PX,
) -> np.ndarray | None:
    """The square crop of ``box`` resized to ``size``×``size`` (same dtype and channels as ``image``).

    The square (see :func:`square_region`) is filled from the image; where it leaves the image,
    the border pixels are replicated (``cv2.BORDER_REPLICATE``), so a vehicle at the frame edge keeps
    its scale and position in the crop.

    Returns ``None`` when the box is narrower than ``min_width`` pixels (SPEC §1: 18), has no
    area, is not finite, or does not overlap the image.
    """
    if image.ndim not in (2, 3) or image.shape[0] == 0 or image.shape[1] == 0:
        raise ValueError(f"expected an H×W or H×W×C image, got shape {image.shape}")
    if size < 1:
        raise ValueError(f"size must be >= 1, got {size}")
    coords = (box.x1, box.y1, box.x2, box.y2)
    if not all(np.isfinite(coords)) or box.width < min_width or box.width <= 0 or box.height <= 0:
        return None
    h, w = image.shape[:2]
    if box.clip(w, h).area <= 0:
        return None
    x0, y0, s = square_region(box, margin)
    x1, y1 = x0 + s, y0 + s
    ix0, iy0, ix1, iy1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if ix1 <= ix0 or iy1 <= iy0:
        return None
    patch = image[iy0:iy1, ix0:ix1]
    pads = (iy0 - y0, y1 - iy1, ix0 - x0, x1 - ix1)
    if any(pads):
        patch = cv2.copyMakeBorder(patch, *pads, borderType=cv2.BORDER_REPLICATE)
    interp = cv2.INTER_AREA if s > size else cv2.INTER_LINEAR
    return cv2.resize(patch, (size, size), interpolation=interp)


def _as_boxes(boxes: Sequence[Box] | np.ndarray) -> list[Box]:
    if isinstance(boxes, np.ndarray):
        arr = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
        return [Box(*(float(v) for v in row)) for row in arr]
    return list(boxes)


def crops_for_tracks(
    image: np.ndarray,
    boxes: Sequence[Box] | np.ndarray,
    *,
    margin: float = 0.1,
    size: int = 224,
    min_width: float = MIN_CROP_WIDTH_PX,
) -> tuple[np.ndarray, np.ndarray]:
    """Square crops of every box of one frame, batched for one classifier call.

    Args:
        image: the frame, ``H×W×3`` (BGR as decoded).
        boxes: :class:`~makeway.messages.Box` objects or an ``(n, 4)`` array ``x1, y1, x2, y2``.

    Returns:
        ``crops`` ``(k, size, size, 3)`` (``k`` ≤ n, same dtype as ``image``) and ``kept`` ``(k,)``
        ``int64``: the index into ``boxes`` of each crop; boxes :func:`square_crop` rejects are left
        out (their tracks get no judgement this frame).
    """
    items = _as_boxes(boxes)
    channels = image.shape[2:] if image.ndim == 3 else ()
    out = np.empty((len(items), size, size, *channels), dtype=image.dtype)
    kept: list[int] = []
    for i, box in enumerate(items):
        crop = square_crop(image, box, margin=margin, size=size, min_width=min_width)
        if crop is not None:
            out[len(kept)] = crop
            kept.append(i)
    return out[: len(kept)], np.asarray(kept, dtype=np.int64)


def box3d_corners(center: Sequence[float], size: Sequence[float], yaw: float = 0.0) -> np.ndarray:
    """The 8 corners ``(8, 3)`` of a box with ``center`` (x, y, z), ``size`` (length along the
    heading, width, height) and heading ``yaw`` (radians, about +z, counter-clockwise from +x)."""
    length, width, height = (float(v) for v in size)
    sx = np.array([1, 1, 1, 1, -1, -1, -1, -1], dtype=np.float64) * length / 2
    sy = np.array([1, -1, -1, 1, 1, -1, -1, 1], dtype=np.float64) * width / 2
    sz = np.array([1, 1, -1, -1, 1, 1, -1, -1], dtype=np.float64) * height / 2
    c, s = np.cos(yaw), np.sin(yaw)
    x = c * sx - s * sy
    y = s * sx + c * sy
    return np.stack([x, y, sz], axis=1) + np.asarray(center, dtype=np.float64)


def project_box3d(
    corners_world: np.ndarray,
    K: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    image_size: tuple[int, int],
    *,
    min_width: float = MIN_CROP_WIDTH_PX,
    min_depth: float = 1e-3,
) -> Box | None:
    """The crop square of a 3D box seen by a pinhole camera (SPEC §1), or ``None``.

    Conventions: ``R`` (3×3) and ``t`` (3,) map world to camera, ``X_cam = R @ X_world + t``; the
    camera frame is OpenCV's (x right, y down, z forward); ``K`` is the 3×3 intrinsic matrix (undo
    lens distortion before, or use undistorted intrinsics). ``image_size`` is ``(width, height)``.

    The 8 corners are projected; the result is the smallest axis-aligned square centred on the
    centroid of the projected corners that holds all of them.

    Returns ``None`` when any corner is less than ``min_depth`` in front of the camera (behind it or
    on the image plane: its projection would be meaningless), when the centroid falls outside the
    image, or when the projected corners span less than ``min_width`` pixels horizontally.
    """
    pts = np.asarray(corners_world, dtype=np.float64)
    K = np.asarray(K, dtype=np.float64)
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64).reshape(3)
    if pts.shape != (8, 3):
        raise ValueError(f"corners_world must be (8, 3), got {pts.shape}")
    if K.shape != (3, 3) or R.shape != (3, 3):
        raise ValueError(f"K and R must be 3×3, got {K.shape} and {R.shape}")
    cam = pts @ R.T + t
    if not np.all(np.isfinite(cam)) or np.any(cam[:, 2] < min_depth):
        return None
    uvw = cam @ K.T
    uv = uvw[:, :2] / uvw[:, 2:3]
    cu, cv = uv.mean(axis=0)
    width, height = image_size
    if not (0.0 <= cu < width and 0.0 <= cv < height):
        return None
    if np.ptp(uv[:, 0]) < min_width:
        return None
    half = float(np.max(np.abs(uv - (cu, cv))))
    return Box(float(cu - half), float(cv - half), float(cu + half), float(cv + half))


def _inside(box: Box, other: Box) -> float:
    """The fraction of ``box``'s area inside ``other``."""
    iw = min(box.x2, other.x2) - max(box.x1, other.x1)
    ih = min(box.y2, other.y2) - max(box.y1, other.y1)
    return iw * ih / box.area if iw > 0 and ih > 0 and box.area > 0 else 0.0


def detection_crop_items(
    image: np.ndarray,
    positive_boxes: Sequence[Box],
    detector_boxes: np.ndarray | Sequence[Box],
    *,
    max_iou: float = 0.1,
    max_inside: float = 0.5,
    margin: float = 0.1,
    size: int = 224,
    min_width: float = MIN_CROP_WIDTH_PX,
) -> Iterator[tuple[str, np.ndarray, int]]:
    """Labelled crops of one image: ``("p<k>", crop, 1)`` per positive box and ``("n<k>", crop, 0)`` per
    detector box whose IoU with every positive box is below ``max_iou`` and that lies less than
    ``max_inside`` (fraction of its own area) inside any positive box — a small detection on a part of
    a labelled vehicle (its light bar, its rear) has a low IoU but is no negative.

    ``k`` is the index of the box in its input list, so names are stable; boxes
    :func:`square_crop` rejects (too small, off-image) are skipped.
    """
    for k, box in enumerate(positive_boxes):
        crop = square_crop(image, box, margin=margin, size=size, min_width=min_width)
        if crop is not None:
            yield f"p{k}", crop, 1
    for k, box in enumerate(_as_boxes(detector_boxes)):
        if any(box.iou(p) >= max_iou or _inside(box, p) >= max_inside for p in positive_boxes):
            continue
        crop = square_crop(image, box, margin=margin, size=size, min_width=min_width)
        if crop is not None:
            yield f"n{k}", crop, 0
