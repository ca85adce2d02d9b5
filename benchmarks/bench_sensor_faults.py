"""Sensor faults, measured (issue 29, item 2): each fault of ``makeway.sense.faults`` beside the clean run.

    .venv/bin/python benchmarks/bench_sensor_faults.py [--quick] [--n 20 --seeds 2026 --duration 8]
        [--cache reports/track_probs] [--skip-audio] [--skip-video] [--json FILE]

**Audio** (the siren networks on held-out simulated recordings of the 8-capsule roof array, the
evaluation of ``benchmarks/bench_audio_model.py``: :func:`makeway.eval.siren.evaluate`). Every
recording gets the fault on one capsule, channel ``i mod 8`` for recording ``i`` (so every capsule
is hit as often), and is run twice: as it is, and with the listener's health check and repair
(``makeway audio listen``'s default, :mod:`makeway.perceive.health`). Printed per fault: recall,
false alarms, angle and distance median errors (windows ≤ 100 m and 10–50 m), and how often the
health check flagged the faulted capsule (and, on the clean run, any capsule: false flags). Target
(the issue): one dead capsule of eight costs ≤ 2 points of recall and ≤ 1° of angle median error.
Swapped capsules (recording ``i``: capsule ``i mod 8`` with the opposite capsule of its unit) are
found by :class:`makeway.perceive.health.SwapCheck` over the windows so far: printed, how often the
swapped capsule was flagged and how often put back by re-ordering; a front/back pair mirrors the
scene, which the array (symmetric front to back) cannot attribute to one unit, so it is flagged but
not re-ordered; the left/right swaps (recordings ``i mod 4`` in {1, 3}) are also run alone, with the
clean angle error of the same recordings beside them.
A clock skew or jitter between the audio and the ego pose log (±50 ms) does not reach the networks
(their bearings and distances are in the vehicle frame); it moves the siren's position in the world
frame, where fusion places it, by the ego's motion in that time: printed as the world-position
error it adds (median / 95th percentile over the siren windows).

**Video** (Framework B, detector → SORT → crop classifier → smoother, on the three real EV clips,
per-actor EV recall as ``benchmarks/bench_track_sweep.py`` scores it with
``data/video_track_labels.csv``; actors: the clean run's tracks the smoother can decide, ≥ 6 judged
frames). The clips are run again with 30 % of the frames dropped at random (the tracker coasts over
the gaps, :meth:`makeway.track.sort.Sort.coast`); each clean actor is matched to the faulted run's
track that covers it (IoU ≥ 0.5 on most of the frames both runs have) and is recalled when that
track becomes active (a negative actor so matched is a false positive). Target: recall drops
≤ 5 points. Then a frozen camera and a blackout from the middle of each clip: frames until the
camera health flags it (counting the first faulted frame), and false flags on all five clean clips.

``--quick``: 6 recordings of 6 s, the first 150 frames of each clip.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from makeway.eval.actor_sweep import EV_CLIPS, NO_EV_CLIPS, ClipRecord, actor_predictions, read_track_labels
from makeway.eval.siren import evaluate, model_estimator
from makeway.eval.siren_labels import label_recording
from makeway.jsonable import to_jsonable
from makeway.messages import SensorHealth
from makeway.paths import data_dir
from makeway.perceive.audio.siren_model import DEFAULT_SIREN_MODEL, SirenModel
from makeway.perceive.health import CameraHealth
from makeway.perceive.vision.ev_classifier import DEFAULT_MODEL
from makeway.pipeline.clip_record import cached_clip, cached_record, record_clip
from makeway.progress import progress_bar
from makeway.sense.faults import apply_audio_fault, apply_video_fault
from makeway.sense.recording import Recording, read_recording
from makeway.sense.video import VideoReader
from makeway.sim.audio_scenarios import held_out_folders
from makeway.track.sort import iou_matrix

AUDIO_FAULTS = ("dead_channel", "clipped_channel", "noisy_channel", "swapped_channels")
TARGET_RECALL_DROP = 2.0  # points, one dead capsule of eight
TARGET_ANGLE_WORSE = 1.0  # degrees
TARGET_ACTOR_RECALL_DROP = 5.0  # points, 30 % dropped frames
MIN_JUDGED = 6


def _pct(v: float | None) -> str:
    return "—" if v is None else f"{100 * v:6.2f}"


def _num(v: float | None) -> str:
    return "—" if v is None else f"{v:6.2f}"


def _faulted(recs: list[Recording], fault: str, seed: int) -> list[Recording]:
    out = []
    for i, rec in enumerate(recs):
        params: dict[str, Any] = {"channel": i % rec.n_channels}
        if fault == "swapped_channels":  # the opposite capsule of the same 4-capsule unit
            params["other"] = (i % rec.n_channels) // 4 * 4 + (i % 4 + 2) % 4
        out.append(apply_audio_fault(rec, fault, seed + i, **params))
    return out


def _reorder_rate(
    health: list[SensorHealth], recs: list[Recording], counts: list[int], index: list[int]
) -> float:
    """Share of windows where the swapped capsule was put back by re-ordering (``_faulted``'s pair)."""
    done = n = k = 0
    for r, c, i in zip(recs, counts, index, strict=True):
        ch = i % r.n_channels
        for h in health[k : k + c]:
            done += int(h.reasons[ch] == "swapped" and ch in h.repaired)
            n += 1
        k += c
    return done / n if n else math.nan


def _flag_rate(
    health: list[SensorHealth], recs: list[Recording], counts: list[int], index: list[int] | None = None
) -> tuple[float, float]:
    """(share of windows where the faulted capsule was flagged, share where another one was);
    ``index``: the recordings' numbers in the whole set (the faulted capsule is ``index mod 8``)."""
    hit = other = n = 0
    k = 0
    for pos, c in enumerate(counts):
        i = index[pos] if index is not None else pos
        ch = i % recs[pos].n_channels
        for h in health[k : k + c]:
            hit += int(not h.trusted[ch])
            other += int(
                any(not ok for j, ok in enumerate(h.trusted) if j != ch and h.reasons[j] != "swapped")
            )
            n += 1
        k += c
    return (hit / n if n else math.nan, other / n if n else math.nan)


def world_shift(rec: Recording, faulty: Recording) -> np.ndarray:
    """Per siren window: how far (m) the nearest siren's world position moves when its true
    vehicle-frame position is placed with ``faulty``'s ego pose instead of the true one."""
    lab = label_recording(rec)
    theta, dist = lab.nearest()
    sel = lab.kept & lab.siren
    t = lab.t_end[sel]
    rel = np.stack([dist[sel] * np.cos(theta[sel]), dist[sel] * np.sin(theta[sel])])

    def world(ego: Any) -> np.ndarray:
        x, y = ego.position(t)
        yaw = ego.heading(t)
        c, s = np.cos(yaw), np.sin(yaw)
        return np.stack([x + c * rel[0] - s * rel[1], y + s * rel[0] + c * rel[1]])

    return np.asarray(np.linalg.norm(world(rec.ego) - world(faulty.ego), axis=0))


def audio_part(args: argparse.Namespace, tmp: Path) -> dict[str, Any]:
    t0 = time.perf_counter()
    folders = held_out_folders(None, tmp / "audio", args.n, args.seeds, args.duration)
    recs = [read_recording(f) for f in folders]
    print(
        f"simulated {len(recs)} held-out recordings of {args.duration:g} s "
        f"in {time.perf_counter() - t0:.0f} s "
        f"(load {os.getloadavg()[0]:.1f})"
    )
    model = SirenModel(DEFAULT_SIREN_MODEL, threads=2, localizer=True, ranger=True)
    counts = [int(label_recording(r).kept.sum()) for r in recs]
    rows: dict[str, dict[str, Any]] = {}
    cases: list[tuple[str, str | None, bool]] = [("clean", None, False), ("clean, health check", None, True)]
    for fault in AUDIO_FAULTS:
        cases += [(f"{fault}", fault, False), (f"{fault}, repaired", fault, True)]
    # the swaps the array can attribute (a unit's left and right capsules: recordings i with
    # i mod 4 in {1, 3}); a front/back swap mirrors the scene, which the symmetric array cannot undo
    lr = [i for i in range(len(recs)) if i % 4 in (1, 3)]
    cases += [
        ("clean, left-right subset", None, False),
        ("swapped left-right", "swapped_channels", False),
        ("swapped left-right, re-ordered", "swapped_channels", True),
    ]
    for name, fault, repair in cases:
        data = recs if fault is None else _faulted(recs, fault, args.fault_seed)
        subset = list(range(len(recs)))
        if "left-right" in name:
            subset = lr
            data = [data[i] for i in lr]
        health: list[SensorHealth] = []
        with progress_bar(f"audio: {name}", len(data), unit="rec") as advance:
            res = evaluate(
                data,
                model_estimator(model, repair=repair, health=health if repair else None),
                on_recording=advance,
                name=name,
                threshold=model.threshold,
            )
        row = {k: res[k] for k in ("recall", "false_alarm_rate", "angle_median_deg", "distance_median_m")}
        row["range_10_50"] = {
            k: res["range_10_50"][k] for k in ("recall", "angle_median_deg", "distance_median_m")
        }
        if repair:
            sub_recs, sub_counts = [recs[i] for i in subset], [counts[i] for i in subset]
            hit, other = _flag_rate(health, sub_recs, sub_counts, subset)
            row["flagged_faulted"] = hit if fault is not None else None
            row["flagged_other"] = other
            if fault is None:
                row["flagged_any"] = float(np.mean([not h.ok for h in health])) if health else None
            if fault == "swapped_channels":
                row["reordered"] = _reorder_rate(health, sub_recs, sub_counts, subset)
        rows[name] = row
    print(f"\naudio: {len(recs)} recordings, {sum(counts)} windows ({args.n} per seed, seeds {args.seeds})")
    print(
        f"{'':28s}{'recall':>8s}{'f.alarm':>8s}{'ang med':>8s}{'dist med':>9s} | 10–50 m:"
        f"{'recall':>8s}{'ang med':>8s}{'dist med':>9s} | flagged: faulted, other"
    )
    for name, r in rows.items():
        rr = r["range_10_50"]
        flags = ""
        if "flagged_other" in r:
            hit = r.get("flagged_faulted")
            flags = f"{_pct(hit) if hit is not None else '     —'} %, {_pct(r['flagged_other'])} %"
        print(
            f"{name:28s}{_pct(r['recall']):>8s}{_pct(r['false_alarm_rate']):>8s}"
            f"{_num(r['angle_median_deg']):>8s}{_num(r['distance_median_m']):>9s} |         "
            f"{_pct(rr['recall']):>8s}{_num(rr['angle_median_deg']):>8s}{_num(rr['distance_median_m']):>9s}"
            f" | {flags}"
        )
    clean = rows["clean, health check"]
    for variant in ("dead_channel", "dead_channel, repaired"):
        d = rows[variant]
        drop = 100 * (rows["clean"]["recall"] - d["recall"])
        worse = d["angle_median_deg"] - rows["clean"]["angle_median_deg"]
        print(
            f"one dead capsule of eight ({variant}): recall {drop:+.2f} points lower "
            f"(target ≤ {TARGET_RECALL_DROP:g}), angle median {worse:+.2f}° worse "
            f"(target ≤ {TARGET_ANGLE_WORSE:g}°) — against the clean run without the check"
        )
    sw = rows["swapped_channels, repaired"]
    print(
        f"swapped capsules (all pairs): flagged in {_pct(sw['flagged_faulted'])} % of the windows, put back "
        f"by re-ordering in {_pct(sw['reordered'])} %; clean run: a capsule flagged in "
        f"{_pct(rows['clean, health check']['flagged_any'])} % of the windows"
    )
    lr_rows = [
        rows[k] for k in ("clean, left-right subset", "swapped left-right", "swapped left-right, re-ordered")
    ]
    print(
        "swapped left-right capsules, angle median: clean {:.2f}°, swapped {:.2f}°, re-ordered {:.2f}° "
        "(re-ordered in {} % of the windows)".format(
            *(r["angle_median_deg"] for r in lr_rows), _pct(lr_rows[2]["reordered"]).strip()
        )
    )
    rows["target"] = {"recall_drop_points": TARGET_RECALL_DROP, "angle_median_worse_deg": TARGET_ANGLE_WORSE}
    del clean

    skew: dict[str, Any] = {}
    for fault, params in (("clock_skew", {"offset_s": 0.05}), ("clock_skew", {"offset_s": -0.05})):
        shifts = np.concatenate([world_shift(r, apply_audio_fault(r, fault, 0, **params)) for r in recs])
        skew[f"{fault} {params['offset_s']:+g} s"] = shifts
    skew["clock_jitter ±0.05 s"] = np.concatenate(
        [world_shift(r, apply_audio_fault(r, "clock_jitter", i, jitter_s=0.05)) for i, r in enumerate(recs)]
    )
    print("\naudio ↔ ego pose clock faults: world position of the siren moved by (siren windows)")
    out_skew = {}
    for name, s in skew.items():
        med, p95 = (float(np.median(s)), float(np.percentile(s, 95))) if len(s) else (math.nan, math.nan)
        print(f"  {name:24s} median {med:5.2f} m, p95 {p95:5.2f} m")
        out_skew[name] = {"median_m": med, "p95_m": p95, "windows": len(s)}
    return {"rows": rows, "clock": out_skew, "recordings": len(recs), "windows": sum(counts)}


def _cover(clean: ClipRecord, faulty: ClipRecord) -> dict[int, int | None]:
    """Clean actor → the faulty run's track that covers it (IoU ≥ 0.5) on most of the frames both
    runs have (``None``: none does). Actor-centric, so a faulty track that follows one vehicle
    the clean run split into two tracks covers both."""
    by_frame: dict[int, list[int]] = defaultdict(list)
    for i, f in enumerate(faulty.frame.tolist()):
        by_frame[f].append(i)
    frames_of = set(faulty.frame.tolist())
    votes: dict[int, Counter[int]] = defaultdict(Counter)
    shared: Counter[int] = Counter()
    for i, (f, tid) in enumerate(zip(clean.frame.tolist(), clean.track_id.tolist(), strict=True)):
        if f not in frames_of:  # a dropped frame: nothing to compare
            continue
        shared[tid] += 1
        rows = by_frame[f]
        iou = np.nan_to_num(iou_matrix(clean.boxes[i : i + 1], faulty.boxes[rows]))[0]
        best = int(iou.argmax())
        if iou[best] >= 0.5:
            votes[tid][int(faulty.track_id[rows[best]])] += 1
    out: dict[int, int | None] = {}
    for tid in clean.track_ids:
        top = votes[tid].most_common(1)
        out[tid] = top[0][0] if top and top[0][1] >= 0.5 * shared[tid] else None
    return out


def video_part(args: argparse.Namespace, root: Path) -> dict[str, Any]:
    from makeway.eval.actor_sweep import RECORD_CONFIG
    from makeway.perceive.vision.ev_classifier import EVTrackClassifier, load_crop_classifier

    labels = read_track_labels()
    max_frames = 150 if args.quick else None
    totals = {"clean": [0, 0], "dropped": [0, 0]}  # [recalled, EV actors]
    fps_counts = {"clean": [0, 0], "dropped": [0, 0]}  # [false positives, negative actors]
    per_clip = {}
    for clip in EV_CLIPS:
        video = root / "video" / f"{clip}.mp4"
        clean, hit = cached_clip(video, args.cache, DEFAULT_MODEL, max_frames=max_frames, progress=True)

        def record(video: Path = video) -> ClipRecord:
            clf = EVTrackClassifier(
                load_crop_classifier(DEFAULT_MODEL, num_threads=1),
                margin=RECORD_CONFIG["crop_margin"],
                min_width=RECORD_CONFIG["min_width_px"],
            )
            return record_clip(
                video,
                clf,
                max_frames=max_frames,
                progress=True,
                frame_filter=lambda fr: apply_video_fault(fr, "frame_drop", args.fault_seed, fraction=0.3),
            )

        faulty, _ = cached_record(
            video,
            args.cache,
            record,
            key={"fault": "frame_drop", "fraction": 0.3, "seed": args.fault_seed, "coast": True},
            max_frames=max_frames,
            tag="faults.",
        )
        pred_clean = actor_predictions(clean, 0.5)
        pred_faulty = actor_predictions(faulty, 0.5)
        cover = _cover(clean, faulty)
        found = {t: cover[t] is not None and pred_faulty[cover[t]] for t in clean.track_ids}
        actors = [
            t for t in clean.track_ids if int(np.sum(~np.isnan(clean.probabilities_of(t)))) >= MIN_JUDGED
        ]
        ev = [t for t in actors if labels.label(clip, t)]
        neg = [t for t in actors if not labels.label(clip, t)]
        c_rec = sum(pred_clean[t] for t in ev)
        f_rec = sum(found[t] for t in ev)
        c_fp = sum(pred_clean[t] for t in neg)
        f_fp = sum(found[t] for t in neg)
        totals["clean"][0] += c_rec
        totals["dropped"][0] += f_rec
        totals["clean"][1] += len(ev)
        totals["dropped"][1] += len(ev)
        fps_counts["clean"][0] += c_fp
        fps_counts["dropped"][0] += f_fp
        fps_counts["clean"][1] += len(neg)
        fps_counts["dropped"][1] += len(neg)
        kept = len(set(faulty.frame.tolist()))
        per_clip[clip] = {
            "ev_actors": len(ev),
            "recalled_clean": c_rec,
            "recalled_dropped": f_rec,
            "negative_actors": len(neg),
            "false_positive_clean": c_fp,
            "false_positive_dropped": f_fp,
            "frames_with_tracks_dropped_run": kept,
            "clean_cached": hit,
        }
        print(
            f"{clip:28s} EV actors {len(ev):2d}: recalled clean {c_rec}, 30 % dropped {f_rec}; "
            f"negatives {len(neg):3d}: false positives clean {c_fp}, dropped {f_fp}"
        )
    r_clean = totals["clean"][0] / max(totals["clean"][1], 1)
    r_drop = totals["dropped"][0] / max(totals["dropped"][1], 1)
    print(
        f"per-actor EV recall: clean {100 * r_clean:.1f} % ({totals['clean'][0]}/{totals['clean'][1]}), "
        f"30 % frames dropped {100 * r_drop:.1f} % ({totals['dropped'][0]}/{totals['dropped'][1]}): "
        f"{100 * (r_clean - r_drop):+.1f} points lower (target ≤ {TARGET_ACTOR_RECALL_DROP:g}); "
        f"false positives {fps_counts['clean'][0]} → {fps_counts['dropped'][0]} of {fps_counts['clean'][1]}"
    )

    camera: dict[str, Any] = {}
    for clip in (*EV_CLIPS, *NO_EV_CLIPS):
        video = root / "video" / f"{clip}.mp4"
        res: dict[str, Any] = {}
        for fault in (None, "frozen", "blackout"):
            health = CameraHealth()
            start = None
            first_flag = None
            first_faulted = None
            flags = 0
            n = 0
            with VideoReader(video, max_frames=max_frames) as reader:
                frames: Any = iter(reader)
                mid = reader.info.duration_s / 2 if max_frames is None else max_frames / reader.info.fps / 2
                if fault is not None:
                    frames = apply_video_fault(frames, fault, 0, start_s=mid)
                    start = mid
                for index, t, image in frames:
                    h = health.update(image, t)
                    n += 1
                    if start is not None and t >= start and first_faulted is None:
                        first_faulted = index
                    if not h.ok:
                        if start is None or t < start:
                            flags += 1
                        elif first_flag is None:
                            first_flag = index
            if fault is None:
                res["false_flags"] = flags
                res["frames"] = n
            else:
                res[fault] = {
                    "detected": first_flag is not None,
                    "frames_to_flag": None
                    if first_flag is None or first_faulted is None
                    else first_flag - first_faulted + 1,
                    "false_flags_before": flags,
                }
        camera[clip] = res
        print(
            f"camera health {clip:28s} clean: {res['false_flags']} of {res['frames']} frames flagged; "
            f"frozen flagged after {res['frozen']['frames_to_flag']} frames, "
            f"blackout after {res['blackout']['frames_to_flag']}"
        )
    return {
        "per_clip": per_clip,
        "actor_recall_clean": r_clean,
        "actor_recall_dropped_30pct": r_drop,
        "recall_drop_points": 100 * (r_clean - r_drop),
        "target_drop_points": TARGET_ACTOR_RECALL_DROP,
        "camera_health": camera,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="6 recordings of 6 s, 150 frames per clip")
    ap.add_argument("--n", type=int, default=20, help="held-out recordings per seed")
    ap.add_argument("--seeds", default="2026", help="seeds of the held-out sets (comma-separated)")
    ap.add_argument("--duration", type=float, default=8.0, help="seconds per recording")
    ap.add_argument("--fault-seed", type=int, default=29, help="seed of the faults' random parts")
    ap.add_argument("--cache", type=Path, default=Path("reports/track_probs"), help="clip record cache")
    ap.add_argument("--skip-audio", action="store_true")
    ap.add_argument("--skip-video", action="store_true")
    ap.add_argument("--json", type=Path, default=None, help="also write the results here")
    args = ap.parse_args()
    args.seeds = [int(v) for v in str(args.seeds).split(",") if v.strip()]
    if args.quick:
        args.n, args.duration, args.seeds = 6, 6.0, args.seeds[:1]
    root = data_dir()
    if root is None:
        print("error: shared data not found (set MAKEWAY_DATA)", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        if not args.skip_audio:
            out["audio"] = audio_part(args, Path(tmp))
        if not args.skip_video:
            print()
            out["video"] = video_part(args, root)
    wall = time.perf_counter() - t0
    print(f"\nwall {wall:.0f} s, load average {os.getloadavg()}")
    out["wall_s"] = wall
    if args.json is not None:
        args.json.write_text(json.dumps(to_jsonable(out, digits=4), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
