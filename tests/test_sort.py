"""SORT (SPEC §2): filter equivalence, track lifecycle, and accuracy on real MOT15 detections."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from makeway.eval.mot import combine, evaluate_mot
from makeway.messages import Box, Detection
from makeway.pipeline.mot import track_mot
from makeway.sense.motfile import MotData, read_mot
from makeway.track.sort import Sort, _BoxFilter, associate, iou_matrix


class DenseKalman:
    """The textbook 7-state filter with full matrices, to check the block-diagonal one against."""

    def __init__(self, z: np.ndarray) -> None:
        self.F = np.eye(7)
        self.F[0, 4] = self.F[1, 5] = self.F[2, 6] = 1.0
        self.H = np.eye(4, 7)
        self.R = np.diag([1.0, 1.0, 10.0, 10.0])
        self.Q = np.diag([1.0, 1.0, 1.0, 1.0, 1e-2, 1e-2, 1e-4])
        self.P = np.diag([10.0, 10.0, 10.0, 10.0, 1e4, 1e4, 1e4])
        self.x = np.zeros(7)
        self.x[:4] = z

    def predict(self) -> None:
        if self.x[2] + self.x[6] <= 0:
            self.x[6] = 0.0
        self.x = self.F @ self.x
        self.P = self.F @ self.P @ self.F.T + self.Q

    def update(self, z: np.ndarray) -> None:
        S = self.H @ self.P @ self.H.T + self.R
        K = self.P @ self.H.T @ np.linalg.inv(S)
        self.x = self.x + K @ (z - self.H @ self.x)
        ikh = np.eye(7) - K @ self.H
        self.P = ikh @ self.P @ ikh.T + K @ self.R @ K.T  # Joseph form


def _z(box: list[float]) -> np.ndarray:
    w, h = box[2] - box[0], box[3] - box[1]
    return np.array([box[0] + w / 2, box[1] + h / 2, w * h, w / h])


def test_block_filter_equals_dense_kalman() -> None:
    rng = np.random.default_rng(0)
    box = [100.0, 50.0, 140.0, 130.0]
    fast = _BoxFilter(box, 1, 1.0, 2, "car")
    dense = DenseKalman(_z(box))
    for step in range(60):
        fast.predict()
        dense.predict()
        if step % 7 != 3:  # some frames without a detection
            jitter = rng.normal(0, 2.0, 4)
            b = [box[0] + 3 * step + jitter[0], box[1] + step + jitter[1], box[2] + 3.5 * step, box[3] + step]
            fast.correct(b)
            dense.update(_z(b))
        np.testing.assert_allclose(fast.x[:7], dense.x, rtol=1e-9, atol=1e-7)
        P = dense.P
        np.testing.assert_allclose(fast.x[7:11], np.diag(P)[:4], rtol=1e-9)
        np.testing.assert_allclose(fast.x[11:14], [P[0, 4], P[1, 5], P[2, 6]], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(fast.x[14:17], np.diag(P)[4:], rtol=1e-9)
        off_block = P.copy()
        for i, j in [(0, 4), (1, 5), (2, 6)]:
            off_block[i, j] = off_block[j, i] = 0.0
        np.testing.assert_allclose(off_block - np.diag(np.diag(P)), 0.0, atol=1e-9)


def test_iou_matrix_and_associate() -> None:
    a = np.array([[0, 0, 10, 10], [20, 20, 30, 30]], dtype=float)
    b = np.array([[0, 0, 10, 10], [5, 0, 15, 10], [100, 100, 110, 110]], dtype=float)
    iou = iou_matrix(a, b)
    np.testing.assert_allclose(iou[0], [1.0, 50 / 150, 0.0])
    np.testing.assert_allclose(iou[1], [0.0, 0.0, 0.0])
    assert iou_matrix(a[:0], b).shape == (0, 3)
    dets, trks = associate(iou, 0.3)
    assert dets.tolist() == [0] and trks.tolist() == [0]
    # ambiguous case goes through the Hungarian algorithm and keeps the best total IoU
    amb = np.array([[0.9, 0.8], [0.85, 0.1]])
    dets, trks = associate(amb, 0.3)
    assert sorted(zip(dets.tolist(), trks.tolist(), strict=True)) == [(0, 1), (1, 0)]
    assert Box(0, 0, 10, 10).iou(Box(5, 0, 15, 10)) == pytest.approx(50 / 150)


def _moving(frame: int, x0: float, vx: float) -> Detection:
    return Detection(Box(x0 + vx * frame, 100, x0 + vx * frame + 40, 180), 0.9, 2, "car")


def test_lifecycle_min_hits_and_stable_id() -> None:
    tracker = Sort(max_age=1, min_hits=3, iou_threshold=0.3)
    reported: dict[int, list[int]] = {}
    for f in range(30):
        dets = [_moving(f, 0, 4.0)]
        if f >= 10:  # a second car appears at frame 10
            dets.append(_moving(f, 400, -3.0))
        for t in tracker.update(dets):
            reported.setdefault(t.track_id, []).append(f)
    assert set(reported) == {1, 2}
    # the first three frames of the stream are reported at once (SORT's start-up rule) …
    assert reported[1] == list(range(30))
    # … later tracks only after min_hits consecutive updates following the birth frame
    assert reported[2][0] == 13 and reported[2] == list(range(13, 30))


def test_gap_within_max_age_keeps_id() -> None:
    tracker = Sort(max_age=2, min_hits=1, iou_threshold=0.3)
    ids = []
    for f in range(20):
        dets = [] if f in (8, 9) else [_moving(f, 0, 2.0)]
        out = tracker.update(dets)
        ids.extend(t.track_id for t in out)
    assert set(ids) == {1}
    tracker = Sort(max_age=1, min_hits=1, iou_threshold=0.3)
    ids = []
    for f in range(20):
        dets = [] if f in (8, 9) else [_moving(f, 0, 2.0)]
        ids.extend(t.track_id for t in tracker.update(dets))
    assert set(ids) == {1, 2}  # two missed frames exceed max_age=1: a new id


def test_velocity_and_box_converge() -> None:
    tracker = Sort(min_hits=1)
    for f in range(40):
        out = tracker.update([_moving(f, 0, 5.0)])
    (t,) = out
    assert t.velocity_px[0] == pytest.approx(5.0, abs=0.05)
    assert t.box.x1 == pytest.approx(5.0 * 39, abs=0.5)
    assert t.label == "car" and t.class_id == 2 and t.score == pytest.approx(0.9)


def test_arrays_path_matches_objects_path(mot15_root: Path) -> None:
    dets = read_mot(mot15_root / "TUD-Campus" / "det" / "det.txt")
    a, b = Sort(), Sort()
    xyxy = dets.xyxy
    for _, rows in dets.by_frame():
        boxes, ids = a.update_arrays(xyxy[rows], dets.conf[rows])
        objs = b.update(
            [
                Detection(Box(*map(float, r)), float(c))
                for r, c in zip(xyxy[rows], dets.conf[rows], strict=True)
            ]
        )
        assert sorted(ids.tolist()) == sorted(t.track_id for t in objs)
        by_id = {t.track_id: t.box.as_array() for t in objs}
        for box, i in zip(boxes, ids, strict=True):
            np.testing.assert_allclose(box, by_id[int(i)])


def test_invalid_parameters() -> None:
    with pytest.raises(ValueError, match="max_age"):
        Sort(max_age=-1)
    with pytest.raises(ValueError, match="iou_threshold"):
        Sort(iou_threshold=1.5)


def test_mot15_tud_accuracy(mot15_root: Path) -> None:
    """TUD-Campus + TUD-Stadtmitte: the reference SORT scores MOTA 69.6 % / IDF1 70.5 % there."""
    counts = []
    for seq in ("TUD-Campus", "TUD-Stadtmitte"):
        dets = read_mot(mot15_root / seq / "det" / "det.txt")
        gt = read_mot(mot15_root / seq / "gt" / "gt.txt", kind="gt")
        hyp = track_mot(dets)
        assert hyp.num_frames <= dets.num_frames
        counts.append(evaluate_mot(gt, hyp))
    total = combine(counts)
    assert total.mota >= 0.695
    assert round(total.idf1 * 100, 1) >= 70.5
    assert total.motp > 0.7
    assert total.idsw <= 20


def test_skip_equals_empty_updates_and_a_gap_of_any_length_is_cheap(mot15_root: Path) -> None:
    """``Sort.skip(n)`` leaves the tracker exactly as ``n`` empty updates would, and tracking a
    detection file whose frames jump by billions takes as long as its rows."""
    dets = read_mot(mot15_root / "TUD-Campus" / "det" / "det.txt")
    a, b = Sort(max_age=3), Sort(max_age=3)
    for f, rows in dets.by_frame():
        if f == 20:
            for _ in range(7):
                a.update_arrays(np.zeros((0, 4)))
            b.skip(7)
        ra = a.update_arrays(dets.xyxy[rows], dets.conf[rows])
        rb = b.update_arrays(dets.xyxy[rows], dets.conf[rows])
        assert np.array_equal(ra[1], rb[1]) and np.allclose(ra[0], rb[0])
    assert a.frame_count == b.frame_count

    far = MotData(
        np.concatenate([dets.frames, dets.frames + 2**42]),
        np.concatenate([dets.ids, dets.ids]),
        np.concatenate([dets.xywh, dets.xywh]),
        np.concatenate([dets.conf, dets.conf]),
    )
    tracks = track_mot(far)
    near = track_mot(dets)
    first = tracks.frames <= dets.num_frames
    assert np.array_equal(tracks.frames[first], near.frames) and np.allclose(tracks.xywh[first], near.xywh)
    assert (tracks.frames[~first] - 2**42).min() >= 1 and len(tracks) > len(near)
