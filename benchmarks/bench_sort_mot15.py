"""SORT on MOT15: accuracy on TUD-Campus + TUD-Stadtmitte and speed on all 11 train sequences.

Compares makeway's SORT with the reference SORT (abewley/sort, packaged on PyPI as ``sort-track``;
GPL, installed by ``make bench-sort`` into the venv, never vendored) on the same detections, in
the same process, alternating rounds so machine noise hits both alike. Prints each figure next to
its anchor and target, and one JSON line last.

    make bench-sort            # or: .venv/bin/python benchmarks/bench_sort_mot15.py [--rounds 5]

Targets (issue "Foundation"): MOTA ≥ 69.5 % and IDF1 ≥ 70.5 % on TUD (the reference scores 69.6 /
70.5); speed ≥ 5× the reference's frames per second over the 5500 frames.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable

import numpy as np

from makeway.eval.mot import MotCounts, combine, evaluate_mot
from makeway.paths import data_dir
from makeway.pipeline.mot import track_mot
from makeway.sense.motfile import MotData, read_mot

ACCURACY_SEQS = ("TUD-Campus", "TUD-Stadtmitte")
PAPER_MOTA, PAPER_IDF1 = 0.696, 0.705  # reference SORT on TUD with the same detections (issue text)
SPEED_TARGET = 5.0


def reference_sort() -> type | None:
    try:
        from sort.tracker import SortTracker  # type: ignore[import-not-found]
    except ImportError:
        return None
    return SortTracker  # type: ignore[no-any-return]


def track_reference(dets: MotData, tracker_cls: type) -> MotData:
    """The reference SORT over one sequence (it wants [x1, y1, x2, y2, score, class] rows)."""
    tracker = tracker_cls(max_age=1, min_hits=3, iou_threshold=0.3)
    xyxy = dets.xyxy
    frames: list[int] = []
    ids: list[int] = []
    boxes: list[np.ndarray] = []
    for f, rows in dets.by_frame():
        arr = np.concatenate([xyxy[rows], dets.conf[rows, None], np.zeros((len(rows), 1))], axis=1)
        out = tracker.update(arr if len(rows) else np.empty((0, 6)), None)
        for r in out:
            frames.append(f)
            ids.append(int(r[4]))
            boxes.append(r[:4])
    b = np.array(boxes).reshape(-1, 4)
    xywh = np.concatenate([b[:, :2], b[:, 2:] - b[:, :2]], axis=1)
    return MotData(np.array(frames, dtype=np.int64), np.array(ids, dtype=np.int64), xywh, np.ones(len(b)))


def timed(fn: Callable[[MotData], MotData], seqs: list[MotData]) -> float:
    t0 = time.perf_counter()
    for d in seqs:
        fn(d)
    return time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=5, help="alternating timing rounds (best is kept)")
    args = ap.parse_args()

    root = data_dir()
    if root is None:
        print("error: shared data not found (set MAKEWAY_DATA)", file=sys.stderr)
        return 2
    mot = root / "mot15" / "train"
    ref_cls = reference_sort()
    if ref_cls is None:
        print("error: the reference SORT is not installed; run `make bench-sort`", file=sys.stderr)
        return 2

    # ---------------------------------------------------------------- accuracy
    ours_c: list[MotCounts] = []
    ref_c: list[MotCounts] = []
    for seq in ACCURACY_SEQS:
        dets = read_mot(mot / seq / "det" / "det.txt")
        gt = read_mot(mot / seq / "gt" / "gt.txt", kind="gt")
        ours_c.append(evaluate_mot(gt, track_mot(dets)))
        ref_c.append(evaluate_mot(gt, track_reference(dets, ref_cls)))
    ours, ref = combine(ours_c), combine(ref_c)
    print("SORT accuracy on TUD-Campus + TUD-Stadtmitte (IoU ≥ 0.5)")
    print(f"{'':10s} {'makeway':>9s} {'reference':>10s} {'paper':>7s} {'target':>7s}")
    print(
        f"{'MOTA %':10s} {100 * ours.mota:9.2f} {100 * ref.mota:10.2f} {100 * PAPER_MOTA:7.1f} {'≥ 69.5':>7s}"
    )
    print(
        f"{'IDF1 %':10s} {100 * ours.idf1:9.2f} {100 * ref.idf1:10.2f} {100 * PAPER_IDF1:7.1f} {'≥ 70.5':>7s}"
    )
    print(f"{'MOTP %':10s} {100 * ours.motp:9.2f} {100 * ref.motp:10.2f}")
    print(f"{'ID sw.':10s} {ours.idsw:9d} {ref.idsw:10d}")

    # ------------------------------------------------------------------- speed
    seq_dirs = sorted(p for p in mot.iterdir() if (p / "det" / "det.txt").exists())
    seqs = [read_mot(p / "det" / "det.txt") for p in seq_dirs]
    n_frames = sum(d.num_frames for d in seqs)
    best_ours = best_ref = float("inf")
    for _ in range(max(1, args.rounds)):
        best_ours = min(best_ours, timed(track_mot, seqs))
        best_ref = min(best_ref, timed(lambda d: track_reference(d, ref_cls), seqs))
    fps_ours, fps_ref = n_frames / best_ours, n_frames / best_ref
    ratio = fps_ours / fps_ref
    print(f"\nSORT speed on {len(seqs)} MOT15 train sequences ({n_frames} frames, detections only)")
    print(f"makeway   {fps_ours:9.0f} frames/s")
    print(f"reference {fps_ref:9.0f} frames/s")
    print(f"ratio     {ratio:9.2f}×   (target ≥ {SPEED_TARGET:.0f}×)")

    ok = ours.mota >= 0.695 and round(100 * ours.idf1, 1) >= 70.5 and ratio >= SPEED_TARGET
    result = {
        "mota": round(ours.mota, 5),
        "idf1": round(ours.idf1, 5),
        "motp": round(ours.motp, 5),
        "id_switches": ours.idsw,
        "ref_mota": round(ref.mota, 5),
        "ref_idf1": round(ref.idf1, 5),
        "frames": n_frames,
        "fps": round(fps_ours, 1),
        "ref_fps": round(fps_ref, 1),
        "speed_ratio": round(ratio, 2),
        "targets_met": ok,
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
