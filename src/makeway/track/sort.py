"""SORT: Simple Online and Realtime Tracking, our own implementation (SPEC §2).

Each track is a constant-velocity Kalman filter on the state ``[u, v, s, r, u̇, v̇, ṡ]``: box centre
``(u, v)`` in pixels, area ``s`` and aspect ratio ``r = w / h`` (held constant), and the velocities
of the first three. Detections are associated to the tracks' predicted boxes by IoU with the
Hungarian algorithm (:func:`scipy.optimize.linear_sum_assignment`); pairs under ``iou_threshold``
are rejected. A track is reported once it has been updated ``min_hits`` frames in a row (or during
the first ``min_hits`` frames of the stream) and dropped after ``max_age`` frames without a match.

The filter constants follow the SORT paper's set-up: measurement noise ``diag(1, 1, 10, 10)``;
initial covariance 10 on the measured states and 10⁴ on the unobserved velocities; process noise 1
on positions, 10⁻² on velocities and 10⁻⁴ on the area velocity.

Why it is fast: ``F``, ``H``, ``Q``, ``R`` and the initial covariance only ever couple a quantity
with its own velocity, so the 7×7 covariance stays exactly block-diagonal — three 2×2 blocks
``(u, u̇)``, ``(v, v̇)``, ``(s, ṡ)`` and the scalar ``r``. Each track therefore carries 17 floats
and predicts/updates with closed-form scalar gains instead of 7×7 matrix products and a 4×4
inverse. This is the same filter, not an approximation (the tests compare it with the dense
matrix form). With a handful of objects per frame, plain float arithmetic per track beats numpy's
per-call overhead; IoU and the assignment are computed with numpy/scipy on the whole frame.
Public surface (the norfair shape)::

    tracker = Sort(max_age=1, min_hits=3, iou_threshold=0.3)
    tracks = tracker.update(detections)          # list[Detection] -> list[Track]
    boxes, ids = tracker.update_arrays(xyxy, scores)   # the array fast path
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from makeway.messages import Box, Detection, Track

# Filter constants (the SORT paper's set-up); see the module docstring.
_Q_VEL_UV, _Q_VEL_S = 1e-2, 1e-4  # process noise on u̇, v̇ and on ṡ (1 on u, v, s, r)
_R_UV, _R_SR = 1.0, 10.0  # measurement noise on u, v and on s, r
_P0_MEAS, _P0_VEL = 10.0, 1e4  # initial variance of u, v, s, r and of the unobserved velocities


def iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise IoU of boxes ``a: (n, 4)`` and ``b: (m, 4)`` in ``[x1, y1, x2, y2]`` → ``(n, m)``."""
    if len(a) == 0 or len(b) == 0:
        return np.zeros((len(a), len(b)))
    lo = np.maximum(a[:, None, :2], b[None, :, :2])
    hi = np.minimum(a[:, None, 2:], b[None, :, 2:])
    wh = np.maximum(hi - lo, 0.0)
    inter = wh[..., 0] * wh[..., 1]
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    union = area_a[:, None] + area_b[None, :] - inter
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(union > 0, inter / union, 0.0)


def associate(iou: np.ndarray, iou_threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """Match detections (rows) to tracks (columns) on an IoU matrix.

    When the thresholded matrix is already a one-to-one matching it is used directly; otherwise the
    Hungarian algorithm maximises the total IoU. Matches under ``iou_threshold`` are rejected.

    Returns:
        ``(det_idx, trk_idx)``: the matched pairs, as two index arrays of equal length.
    """
    if iou.size == 0:
        empty = np.zeros(0, dtype=np.intp)
        return empty, empty
    above = iou > iou_threshold
    if above.sum(axis=1).max() <= 1 and above.sum(axis=0).max() <= 1:
        rows, cols = np.nonzero(above)
        return rows, cols
    rows, cols = linear_sum_assignment(-iou)
    keep = iou[rows, cols] >= iou_threshold
    return rows[keep], cols[keep]


class _BoxFilter:
    """One track: its Kalman state, the covariance blocks, and SORT's bookkeeping counters.

    ``x`` holds 17 floats: ``u, v, s, r, u̇, v̇, ṡ``; the variances ``P_uu, P_vv, P_ss, P_rr``; the
    covariances ``P_uu̇, P_vv̇, P_ssṡ``; and the velocity variances ``P_u̇u̇, P_v̇v̇, P_ṡṡ``.
    """

    __slots__ = (
        "age",
        "class_id",
        "hit_streak",
        "hits",
        "label",
        "score",
        "time_since_update",
        "track_id",
        "x",
    )

    def __init__(self, box: list[float], track_id: int, score: float, class_id: int, label: str) -> None:
        x1, y1, x2, y2 = box
        w, h = x2 - x1, y2 - y1
        p0, pv0 = _P0_MEAS, _P0_VEL
        self.x = [x1 + 0.5 * w, y1 + 0.5 * h, w * h, w / h, 0.0, 0.0, 0.0]
        self.x += [p0, p0, p0, p0, 0.0, 0.0, 0.0, pv0, pv0, pv0]
        self.track_id = track_id
        self.score = score
        self.class_id = class_id
        self.label = label
        self.age = self.hits = self.hit_streak = self.time_since_update = 0

    def predict(self) -> None:
        """x ← F x, P ← F P Fᵀ + Q, one 2×2 block at a time."""
        u, v, s, r, du, dv, ds, puu, pvv, pss, prr, cu, cv, cs, qu, qv, qs = self.x
        if s + ds <= 0:  # never let the area go negative
            ds = 0.0
        self.x = [
            u + du, v + dv, s + ds, r, du, dv, ds,
            puu + 2.0 * cu + qu + 1.0, pvv + 2.0 * cv + qv + 1.0, pss + 2.0 * cs + qs + 1.0, prr + 1.0,
            cu + qu, cv + qv, cs + qs,
            qu + _Q_VEL_UV, qv + _Q_VEL_UV, qs + _Q_VEL_S,
        ]  # fmt: skip
        self.age += 1
        if self.time_since_update > 0:
            self.hit_streak = 0
        self.time_since_update += 1

    def correct(self, box: list[float]) -> None:
        """Kalman update with a detection ``[x1, y1, x2, y2]``; scalar gains per block."""
        x1, y1, x2, y2 = box
        w, h = x2 - x1, y2 - y1
        u, v, s, r, du, dv, ds, puu, pvv, pss, prr, cu, cv, cs, qu, qv, qs = self.x
        su, sv, ss, sr = puu + _R_UV, pvv + _R_UV, pss + _R_SR, prr + _R_SR  # innovation variances
        ku, kv, ks, kr = puu / su, pvv / sv, pss / ss, prr / sr  # gains on u, v, s, r
        gu, gv, gs = cu / su, cv / sv, cs / ss  # gains on u̇, v̇, ṡ
        iu, iv, i_s = x1 + 0.5 * w - u, y1 + 0.5 * h - v, w * h - s  # innovations
        self.x = [
            u + ku * iu, v + kv * iv, s + ks * i_s, r + kr * (w / h - r),
            du + gu * iu, dv + gv * iv, ds + gs * i_s,
            (1.0 - ku) * puu, (1.0 - kv) * pvv, (1.0 - ks) * pss, (1.0 - kr) * prr,
            (1.0 - ku) * cu, (1.0 - kv) * cv, (1.0 - ks) * cs,
            qu - gu * cu, qv - gv * cv, qs - gs * cs,
        ]  # fmt: skip
        self.time_since_update = 0
        self.hits += 1
        self.hit_streak += 1

    def box(self) -> tuple[float, float, float, float]:
        """``[x1, y1, x2, y2]`` of the current state; NaN when ``s·r`` is not positive."""
        x = self.x
        sr = x[2] * x[3]
        if sr <= 0 or x[2] <= 0:
            nan = float("nan")
            return (nan, nan, nan, nan)
        half_w = 0.5 * math.sqrt(sr)
        half_h = 0.25 * x[2] / half_w
        return (x[0] - half_w, x[1] - half_h, x[0] + half_w, x[1] + half_h)


class Sort:
    """Multi-object tracker on 2D boxes (SPEC §2); see the module docstring.

    Args:
        max_age: frames a track survives without a matched detection (default 1).
        min_hits: consecutive matched frames before a track is reported (default 3).
        iou_threshold: minimum IoU for a detection–track match (default 0.3).
    """

    def __init__(self, max_age: int = 1, min_hits: int = 3, iou_threshold: float = 0.3) -> None:
        if max_age < 0:
            raise ValueError(f"max_age must be >= 0, got {max_age}")
        if min_hits < 0:
            raise ValueError(f"min_hits must be >= 0, got {min_hits}")
        if not 0.0 <= iou_threshold <= 1.0:
            raise ValueError(f"iou_threshold must lie in [0, 1], got {iou_threshold}")
        self.max_age = max_age
        self.min_hits = min_hits
        self.iou_threshold = iou_threshold
        self.reset()

    def reset(self) -> None:
        """Forget every track and restart ids at 1."""
        self.frame_count = 0
        self._next_id = 1
        self._tracks: list[_BoxFilter] = []

    def __len__(self) -> int:
        """Number of live tracks (reported or not)."""
        return len(self._tracks)

    @property
    def live_ids(self) -> list[int]:
        """Ids of every live track, reported or not (to forget per-track state kept elsewhere)."""
        return [t.track_id for t in self._tracks]

    # ------------------------------------------------------------------------------------------ api
    def update(self, detections: Sequence[Detection]) -> list[Track]:
        """Advance one frame with this frame's detections; return the tracks confirmed now.

        Call once per frame, with an empty list when nothing was detected.
        """
        boxes = [[d.box.x1, d.box.y1, d.box.x2, d.box.y2] for d in detections]
        scores = [d.score for d in detections]
        classes = [d.class_id for d in detections]
        labels = [d.label for d in detections]
        return [
            Track(
                track_id=t.track_id,
                box=Box(*t.box()),
                score=t.score,
                class_id=t.class_id,
                label=t.label,
                hits=t.hits,
                hit_streak=t.hit_streak,
                age=t.age,
                time_since_update=t.time_since_update,
                velocity_px=(t.x[4], t.x[5]),
            )
            for t in self._step(boxes, scores, classes, labels)
        ]

    def skip(self, frames: int) -> None:
        """Advance ``frames`` frames in which nothing was detected: the same as that many
        ``update([])`` calls (none of which confirms a track), but once every track has aged out the
        rest of the gap only counts frames, so a gap of any length costs at most ``max_age + 1``
        steps."""
        n = max(0, int(frames))
        while n > 0 and self._tracks:
            self._step([], [], [], None)
            n -= 1
        self.frame_count += n

    def coast(self, steps: int = 1) -> None:
        """Carry every track ``steps`` frames forward on its motion model for frames that never
        arrived (dropped by the camera or the transport): no association, and the lost frames do not
        count as misses, so a gap does not end a track that ``max_age`` would keep."""
        for _ in range(max(0, int(steps))):
            for t in self._tracks:
                age, streak, since = t.age, t.hit_streak, t.time_since_update
                t.predict()
                t.age, t.hit_streak, t.time_since_update = age, streak, since

    def update_arrays(
        self, boxes: np.ndarray, scores: np.ndarray | None = None, class_ids: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Array fast path of :meth:`update`.

        Args:
            boxes: ``(n, 4)`` detections as ``[x1, y1, x2, y2]``.
            scores: ``(n,)`` detection scores (default 1).
            class_ids: ``(n,)`` class ids (default -1).

        Returns:
            ``(boxes (m, 4), ids (m,))`` of the tracks confirmed this frame.
        """
        box_list = np.asarray(boxes, dtype=np.float64).reshape(-1, 4).tolist()
        n = len(box_list)
        sc = [1.0] * n if scores is None else np.asarray(scores, dtype=np.float64).tolist()
        cl = [-1] * n if class_ids is None else np.asarray(class_ids, dtype=np.int64).tolist()
        out = self._step(box_list, sc, cl, None)
        return (
            np.array([t.box() for t in out], dtype=np.float64).reshape(-1, 4),
            np.array([t.track_id for t in out], dtype=np.int64),
        )

    # ------------------------------------------------------------------------------------ internals
    def _step(
        self, boxes: list[list[float]], scores: list[float], classes: list[int], labels: list[str] | None
    ) -> list[_BoxFilter]:
        """Predict, associate, correct, spawn, prune; return the tracks confirmed this frame."""
        self.frame_count += 1
        tracks = self._tracks
        for t in tracks:
            t.predict()
        predicted = [t.box() for t in tracks]
        if any(math.isnan(b[0]) for b in predicted):  # degenerate filters are dropped, as in SORT
            keep = [k for k, b in enumerate(predicted) if not math.isnan(b[0])]
            tracks = [tracks[k] for k in keep]
            predicted = [predicted[k] for k in keep]
        det_free = [True] * len(boxes)
        if tracks and boxes:
            iou = iou_matrix(np.array(boxes), np.array(predicted))
            for d, k in zip(*associate(iou, self.iou_threshold), strict=True):
                t = tracks[k]
                t.correct(boxes[d])
                t.score = scores[d]
                t.class_id = classes[d]
                if labels is not None:
                    t.label = labels[d]
                det_free[d] = False
        for d, free in enumerate(det_free):
            if free:
                label = labels[d] if labels is not None else "object"
                tracks.append(_BoxFilter(boxes[d], self._next_id, scores[d], classes[d], label))
                self._next_id += 1
        early = self.frame_count <= self.min_hits
        confirmed = [
            t for t in tracks if t.time_since_update < 1 and (early or t.hit_streak >= self.min_hits)
        ]
        self._tracks = [t for t in tracks if t.time_since_update <= self.max_age]
        return confirmed
