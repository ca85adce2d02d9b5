"""Per-actor smoother sweep on the real clips, beside seed 000's Table 3 (issue 3, SPEC §1).

Framework B (YOLOX-nano → SORT → shipped EV crop head) runs once per clip; every track's per-frame
probability is cached under ``--cache`` (``makeway.pipeline.clip_record.cached_clip``), so reruns only
replay the smoother. Actors are SORT tracks labelled by the committed
``src/makeway/data/video_track_labels.csv``; an actor is predicted positive when the smoother marks
it active on at least one frame (see ``makeway.eval.actor_sweep``). Prints, for the raw per-frame
decisions (no smoother) and T ∈ {0, 0.3, 0.5, 0.7}, per-actor precision / recall / F1 / accuracy and
the % change against T = 0 next to seed 000's Table 3, then one JSON line.

    .venv/bin/python benchmarks/bench_track_sweep.py               # all five clips, every frame
    .venv/bin/python benchmarks/bench_track_sweep.py --every 1,2,3 # also judging every 2nd / 3rd frame
    .venv/bin/python benchmarks/bench_track_sweep.py --sheets reports/track_sheets  # labelling aid
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np

from makeway.eval.actor_sweep import (
    EV_CLIPS,
    NO_EV_CLIPS,
    SEED000_TABLE3,
    TRACK_LABELS,
    ClipRecord,
    SweepRow,
    read_track_labels,
    relative_change,
    sweep,
)
from makeway.jsonable import to_jsonable
from makeway.messages import Box
from makeway.paths import data_dir
from makeway.perceive.vision.crops import square_crop
from makeway.perceive.vision.ev_classifier import DEFAULT_MODEL
from makeway.pipeline.clip_record import cached_clip
from makeway.sense.video import VideoReader


def _fmt(x: float) -> str:
    return "  n/a" if math.isnan(x) else f"{x:.3f}"


def _pct(x: float) -> str:
    return "   n/a" if math.isnan(x) else f"{x:+6.1f}"


def write_sheets(video: Path, rec: ClipRecord, out_dir: Path, per_sheet: int = 48) -> list[Path]:
    """Labelling aid: one thumbnail per track (its frame of largest box), id and life span printed."""
    best: dict[int, tuple[float, int, np.ndarray]] = {}
    for tid in rec.track_ids:
        sel = np.flatnonzero(rec.track_id == tid)
        areas = (rec.boxes[sel, 2] - rec.boxes[sel, 0]) * (rec.boxes[sel, 3] - rec.boxes[sel, 1])
        j = sel[int(np.argmax(areas))]
        best[tid] = (float(areas.max()), int(rec.frame[j]), rec.boxes[j])
    wanted: dict[int, list[int]] = {}
    for tid, (_, f, _) in best.items():
        wanted.setdefault(f, []).append(tid)
    thumbs: dict[int, np.ndarray] = {}
    with VideoReader(video) as reader:
        for index, _, image in reader:
            for tid in wanted.get(index, []):
                x1, y1, x2, y2 = (float(v) for v in best[tid][2])
                thumb = square_crop(image, Box(x1, y1, x2, y2), margin=0.1, size=200, min_width=0)
                if thumb is None:
                    continue
                sel = rec.track_id == tid
                probs = rec.probability[sel]
                life = f"f{int(rec.frame[sel].min())}-{int(rec.frame[sel].max())}"
                mean_p = float(np.nanmean(probs)) if np.any(~np.isnan(probs)) else float("nan")
                for k, text in enumerate((f"#{tid} {life}", f"p~{mean_p:.2f} w{int(x2 - x1)}")):
                    cv2.putText(thumb, text, (3, 16 + 18 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3)
                    cv2.putText(
                        thumb, text, (3, 16 + 18 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1
                    )
                thumbs[tid] = thumb
    ids = sorted(thumbs)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for s in range(0, len(ids), per_sheet):
        chunk = ids[s : s + per_sheet]
        cols = 8
        rows = -(-len(chunk) // cols)
        sheet = np.zeros((rows * 200, cols * 200, 3), np.uint8)
        for k, tid in enumerate(chunk):
            r, c = divmod(k, cols)
            sheet[r * 200 : (r + 1) * 200, c * 200 : (c + 1) * 200] = thumbs[tid]
        path = out_dir / f"{rec.clip}_{s // per_sheet}.png"
        cv2.imwrite(str(path), sheet)
        paths.append(path)
    return paths


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--clips", default=",".join((*EV_CLIPS, *NO_EV_CLIPS)), help="clip stems in <data>/video/"
    )
    ap.add_argument("--cache", type=Path, default=Path("reports/track_probs"), help="probability cache")
    ap.add_argument(
        "--head", type=Path, default=DEFAULT_MODEL, help="crop classifier (.npz head or .onnx CNN)"
    )
    ap.add_argument(
        "--single-view", action="store_true", help="head judges each crop without its mirror image"
    )
    ap.add_argument("--labels", type=Path, default=TRACK_LABELS)
    ap.add_argument("--every", default="1", help="judge each track every k-th frame; comma list")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument(
        "--min-judged",
        default="1,6",
        help="actor sets: tracks with at least N judged frames (6 = those the smoother can decide)",
    )
    ap.add_argument("--record-only", action="store_true", help="only fill the cache")
    ap.add_argument("--sheets", type=Path, default=None, help="also write per-track thumbnail sheets here")
    args = ap.parse_args()

    root = data_dir()
    if root is None:
        print("error: shared data not found (set MAKEWAY_DATA)", file=sys.stderr)
        return 2
    records = []
    for clip in [c.strip() for c in args.clips.split(",") if c.strip()]:
        video = root / "video" / f"{clip}.mp4"
        rec, hit = cached_clip(
            video,
            args.cache,
            args.head,
            max_frames=args.max_frames,
            progress=True,
            single_view=args.single_view,
        )
        n_valid = int(np.sum(~np.isnan(rec.probability)))
        print(
            f"{clip:28s} {rec.frames:4d} frames, {len(rec.track_ids):3d} tracks, {n_valid:5d} judged "
            f"track-frames{' (cached)' if hit else ''}"
        )
        if args.sheets is not None:
            for p in write_sheets(video, rec, args.sheets):
                print(f"  sheet → {p}")
        records.append(rec)
    if args.record_only:
        return 0

    labels = read_track_labels(args.labels)
    out: dict[str, object] = {"clips": [r.clip for r in records]}
    for min_judged in [int(k) for k in args.min_judged.split(",")]:
        for every in [int(k) for k in args.every.split(",")]:
            rows, thr = sweep(records, labels, every=every, min_judged=min_judged)
            out[f"min_judged_{min_judged}_every_{every}"] = _report(rows, thr, min_judged, every)
    print(json.dumps(to_jsonable(out, digits=4)))
    return 0


def _report(rows: list[SweepRow], thr: dict[str, float], min_judged: int, every: int) -> dict[str, object]:
    base = next(r for r in rows if r.threshold == 0.0 and r.setting.startswith("smoother"))
    n_act, n_pos = base.n, base.tp + base.fn
    print(
        f"\nper-actor results: {n_act} tracks with >= {min_judged} judged frame(s), {n_pos} labelled EV; "
        f"classifier judging every {every} frame(s) per track"
    )
    print(
        f"{'setting':26s} {'TP':>4s} {'FP':>4s} {'FN':>4s} {'TN':>4s}  {'prec':>5s} {'rec':>5s} "
        f"{'F1':>5s} {'acc':>5s} | %Δ P / R / F1 vs T=0  | seed 000 Table 3"
    )
    table = []
    for r in rows:
        per_frame = r.setting == "per frame"
        dp, dr, df = (math.nan,) * 3 if per_frame else relative_change(r, base)
        ref = SEED000_TABLE3.get(r.threshold) if r.setting.startswith("smoother") else None
        ref_s = f"{ref[0]:+6.2f} / {ref[1]:+6.2f} / {ref[2]:+6.2f}" if ref else ""
        delta = " " * 22 if per_frame else f"{_pct(dp)} /{_pct(dr)} /{_pct(df)}"
        print(
            f"{r.setting:26s} {r.tp:4d} {r.fp:4d} {r.fn:4d} {r.tn:4d}  {_fmt(r.precision)} "
            f"{_fmt(r.recall)} {_fmt(r.f1)} {_fmt(r.accuracy)} | {delta} | {ref_s}"
        )
        table.append({**asdict(r), "pct_change_vs_T0": [dp, dr, df]})
    print(
        f"per-frame max-F1 {_fmt(thr['max_f1'])} (threshold {thr['max_f1_threshold']:.3f}), "
        f"precision at recall 0.8 {_fmt(thr['precision_at_recall_0.8'])}"
    )
    return {
        "actors": n_act,
        "positive_actors": n_pos,
        "rows": table,
        "per_frame_max_f1": thr["max_f1"],
        "per_frame_p_at_r80": thr["precision_at_recall_0.8"],
    }


if __name__ == "__main__":
    sys.exit(main())
