"""Multi-object tracking metrics: CLEAR MOT (MOTA, MOTP) and identity metrics (IDF1) (SPEC §2).

A ground-truth box and a tracker box may match when their IoU is at least ``iou_threshold`` (0.5,
the MOTChallenge rule).

**CLEAR MOT** (Bernardin & Stiefelhagen 2008), frame by frame: a ground-truth object keeps last
frame's tracker id if that pairing is still valid; the rest are paired by the Hungarian algorithm on
``1 − IoU``. An identity switch is counted when an object is matched to a tracker id other than the
one it was last matched to (at any earlier frame). ``MOTA = 1 − (FN + FP + IDSW) / GT``;
``MOTP`` is the mean IoU of matched pairs (the MOTChallenge convention; higher is better).

**Identity metrics** (Ristani et al. 2016): ground-truth and tracker trajectories are paired one to
one, globally, to maximise the number of frames in which the pair overlaps (IDTP). Then
``IDF1 = 2·IDTP / (GT + HYP)``, ``IDP = IDTP / HYP``, ``IDR = IDTP / GT``.

**Mostly tracked / lost**: ground-truth trajectories matched in ≥ 80 % / ≤ 20 % of their frames.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import asdict, dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix

from makeway.sense.motfile import MotData
from makeway.track.sort import iou_matrix


@dataclass(frozen=True)
class MotCounts:
    """Raw counts for one or more sequences; metrics are derived so that sums stay exact."""

    num_frames: int = 0
    num_gt: int = 0
    num_hyp: int = 0
    tp: int = 0
    fp: int = 0
    fn: int = 0
    idsw: int = 0
    iou_sum: float = 0.0
    idtp: int = 0
    num_gt_ids: int = 0
    mostly_tracked: int = 0
    mostly_lost: int = 0

    def __add__(self, other: MotCounts) -> MotCounts:
        a, b = asdict(self), asdict(other)
        return MotCounts(**{k: a[k] + b[k] for k in a})

    @property
    def mota(self) -> float:
        return 1.0 - (self.fn + self.fp + self.idsw) / self.num_gt if self.num_gt else float("nan")

    @property
    def motp(self) -> float:
        return self.iou_sum / self.tp if self.tp else float("nan")

    @property
    def idf1(self) -> float:
        denom = self.num_gt + self.num_hyp
        return 2.0 * self.idtp / denom if denom else float("nan")

    @property
    def idp(self) -> float:
        return self.idtp / self.num_hyp if self.num_hyp else float("nan")

    @property
    def idr(self) -> float:
        return self.idtp / self.num_gt if self.num_gt else float("nan")

    @property
    def precision(self) -> float:
        return self.tp / (self.tp + self.fp) if (self.tp + self.fp) else float("nan")

    @property
    def recall(self) -> float:
        return self.tp / self.num_gt if self.num_gt else float("nan")

    def summary(self) -> dict[str, float | int]:
        """Metrics as a flat JSON-ready dict (rates as fractions, not percent)."""
        return {
            "mota": round(self.mota, 6),
            "motp": round(self.motp, 6),
            "idf1": round(self.idf1, 6),
            "idp": round(self.idp, 6),
            "idr": round(self.idr, 6),
            "precision": round(self.precision, 6),
            "recall": round(self.recall, 6),
            "id_switches": self.idsw,
            "fp": self.fp,
            "fn": self.fn,
            "tp": self.tp,
            "num_gt": self.num_gt,
            "num_hyp": self.num_hyp,
            "num_frames": self.num_frames,
            "gt_ids": self.num_gt_ids,
            "mostly_tracked": self.mostly_tracked,
            "mostly_lost": self.mostly_lost,
        }


def evaluate_mot(gt: MotData, hyp: MotData, iou_threshold: float = 0.5) -> MotCounts:
    """CLEAR MOT and identity counts of tracker output ``hyp`` against ground truth ``gt``.

    Ground-truth rows whose 7th column is 0 ("do not consider") are ignored.
    """
    gt = gt.select(gt.conf != 0)
    num_frames = max(gt.num_frames, hyp.num_frames)
    gt_xyxy, hyp_xyxy = gt.xyxy, hyp.xyxy
    gt_uids, gt_idx = np.unique(gt.ids, return_inverse=True)
    hyp_uids, hyp_idx = np.unique(hyp.ids, return_inverse=True)

    last_match: dict[int, int] = {}  # gt id -> tracker id it was last matched to
    tp = fp = fn = idsw = 0
    iou_sum = 0.0
    matched_per_gt = np.zeros(len(gt_uids), dtype=np.int64)
    # identity overlaps: (gt trajectory, hyp trajectory) pairs with IoU >= threshold in a frame
    ov_rows: list[np.ndarray] = []
    ov_cols: list[np.ndarray] = []

    # frames where neither file has a row change no count (and keep every last match): skipped
    either = np.union1d(gt.frames_with_rows(), hyp.frames_with_rows())
    gt_frames = gt.by_frame(only=either)
    hyp_frames = hyp.by_frame(only=either)
    for (_, gi), (_, hi) in zip(gt_frames, hyp_frames, strict=True):
        n_g, n_h = len(gi), len(hi)
        if n_h == 0:
            fn += n_g
            continue
        if n_g == 0:
            fp += n_h
            continue
        iou = iou_matrix(gt_xyxy[gi], hyp_xyxy[hi])
        valid = iou >= iou_threshold
        r, c = np.nonzero(valid)
        ov_rows.append(gt_idx[gi][r])
        ov_cols.append(hyp_idx[hi][c])

        g_ids = gt.ids[gi]
        h_ids = hyp.ids[hi]
        g_free = np.ones(n_g, dtype=bool)
        h_free = np.ones(n_h, dtype=bool)
        pairs: list[tuple[int, int]] = []
        # 1) keep last frame's pairings that are still valid
        h_pos = {int(h): j for j, h in enumerate(h_ids)}
        for i, g in enumerate(g_ids):
            j = h_pos.get(last_match.get(int(g), -(10**12)))
            if j is not None and h_free[j] and valid[i, j]:
                pairs.append((i, j))
                g_free[i] = h_free[j] = False
        # 2) Hungarian on the remainder
        gi_free, hi_free = np.flatnonzero(g_free), np.flatnonzero(h_free)
        if len(gi_free) and len(hi_free):
            sub = iou[np.ix_(gi_free, hi_free)]
            cost = np.where(sub >= iou_threshold, 1.0 - sub, 1e6)
            rr, cc = linear_sum_assignment(cost)
            for a, b in zip(rr, cc, strict=True):
                if cost[a, b] < 1e6:
                    i, j = int(gi_free[a]), int(hi_free[b])
                    g, h = int(g_ids[i]), int(h_ids[j])
                    if g in last_match and last_match[g] != h:
                        idsw += 1
                    pairs.append((i, j))
        for i, j in pairs:
            last_match[int(g_ids[i])] = int(h_ids[j])
            iou_sum += float(iou[i, j])
            matched_per_gt[gt_idx[gi[i]]] += 1
        tp += len(pairs)
        fn += n_g - len(pairs)
        fp += n_h - len(pairs)

    # identity: global max-overlap one-to-one pairing of trajectories
    idtp = 0
    if ov_rows and len(gt_uids) and len(hyp_uids):
        rows = np.concatenate(ov_rows)
        cols = np.concatenate(ov_cols)
        if len(rows):
            overlap = coo_matrix(
                (np.ones(len(rows)), (rows, cols)), shape=(len(gt_uids), len(hyp_uids))
            ).toarray()
            ri, ci = linear_sum_assignment(-overlap)
            idtp = int(overlap[ri, ci].sum())

    gt_len = np.bincount(gt_idx, minlength=len(gt_uids)) if len(gt_uids) else np.zeros(0)
    ratio = matched_per_gt / np.maximum(gt_len, 1)
    return MotCounts(
        num_frames=num_frames,
        num_gt=len(gt),
        num_hyp=len(hyp),
        tp=tp,
        fp=fp,
        fn=fn,
        idsw=idsw,
        iou_sum=iou_sum,
        idtp=idtp,
        num_gt_ids=len(gt_uids),
        mostly_tracked=int((ratio >= 0.8).sum()),
        mostly_lost=int((ratio <= 0.2).sum()),
    )


def combine(counts: Iterable[MotCounts]) -> MotCounts:
    """Sum the counts of several sequences (metrics of the sum, as MOTChallenge's overall row)."""
    total = MotCounts()
    for c in counts:
        total = total + c
    return total
