"""Plane geometry of vehicle footprints: oriented rectangles and the gap between two of them.

Frame: any right-handed planar frame (the simulator's world frame in practice), metres and radians.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["rect_distance", "rectangle_corners"]


def rectangle_corners(x: float, y: float, yaw: float, length: float, width: float) -> np.ndarray:
    """The 4 corners ``(4, 2)`` of a ``length × width`` rectangle centred at ``(x, y)``, long side
    along ``yaw`` (rad, counter-clockwise from the frame's x axis); metres, in that frame."""
    c, s = math.cos(yaw), math.sin(yaw)
    hl, hw = 0.5 * length, 0.5 * width
    # body-frame corners (±hl, ±hw) rotated by yaw, then moved to (x, y) (front left first)
    lc, ls, wc, ws = hl * c, hl * s, hw * c, hw * s
    return np.array(
        [
            [lc - ws + x, ls + wc + y],
            [lc + ws + x, ls - wc + y],
            [-lc + ws + x, -ls - wc + y],
            [-lc - ws + x, -ls + wc + y],
        ]
    )


def _rectangles_overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Separating-axis test for two convex quadrilaterals."""
    for poly in (a, b):
        for i in range(4):
            edge = poly[(i + 1) % 4] - poly[i]
            axis = np.array([-edge[1], edge[0]])
            pa, pb = a @ axis, b @ axis
            if pa.max() < pb.min() or pb.max() < pa.min():
                return False
    return True


def _points_to_edges(p: np.ndarray, q: np.ndarray) -> float:
    """Smallest distance from the corners ``p (4, 2)`` to the edges of rectangle ``q``."""
    a = q
    ab = np.roll(q, -1, axis=0) - q  # (4, 2) edges
    ap = p[:, None, :] - a[None, :, :]  # (4 points, 4 edges, 2)
    t = np.clip((ap * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0.0, 1.0)
    d = ap - t[..., None] * ab
    return float(np.sqrt((d * d).sum(-1)).min())


def _extent(corners: list[list[float]]) -> tuple[float, float, float]:
    """The larger side of the corners' axis-aligned bounding box, and their mean ``(x, y)``."""
    xs = [c[0] for c in corners]
    ys = [c[1] for c in corners]
    return max(max(xs) - min(xs), max(ys) - min(ys)), sum(xs) / len(xs), sum(ys) / len(ys)


def rect_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Gap between two rectangles (0 when they touch or overlap)."""
    # the far-apart test on the corners as Python floats (the closed loop asks every 10 ms)
    size_a, xa, ya = _extent(a.tolist())
    size_b, xb, yb = _extent(b.tolist())
    reach = size_a + size_b
    centre_gap = math.hypot(xa - xb, ya - yb)
    if centre_gap > reach:  # far apart: the gap is at least this (exact enough for metrics)
        return centre_gap - 0.5 * reach
    if _rectangles_overlap(a, b):
        return 0.0
    return min(_points_to_edges(a, b), _points_to_edges(b, a))
