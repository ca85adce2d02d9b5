"""Lights and siren on the real clips with sound, per second (issue 26 item 6).

Each of the four shared road clips with a sound track (``night_ambulance_lights``,
``fire_trucks_red_lights``, ``intersection_cam_ambulance``, ``traffic_no_ev``) is run as
``makeway detect`` runs it by default (:func:`makeway.pipeline.clip_sound.run_clip`: YOLOX-nano →
SORT → the ``lights+crop`` rule with the shipped crop head and the ``eu`` colours → smoother; the
siren detector on the mono track rendered at 70 dB(A); the ``audible_and_visual`` duty), and every
whole second is scored against ``src/makeway/data/clip_seconds.csv`` ("active EV": a siren audible
or lit emergency lights visible):

* **siren alone** — the listener heard a siren in the second;
* **lights alone** (the anchor: today's ``makeway detect``) — a track was an active EV in a frame
  of the second;
* **fused: yield** — the duty's decision in the second is ``yield`` (siren and lights; lights alone
  after 2 s);
* **fused: yield or prepare** — the car at least slows down (a siren alone prepares).

Per clip and over all clips: TP / FP / FN / TN, precision, recall, F1; the key negative check is
that no second of ``traffic_no_ev`` is active. Also each sense against its own truth column (siren
seconds, lights seconds). Prints one JSON line last. The load average is printed beside the wall
time (the machine is shared).

    .venv/bin/python benchmarks/bench_clip_fusion.py
    .venv/bin/python benchmarks/bench_clip_fusion.py --level-dba 75 --json-only
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from makeway.eval.clip_seconds import CLIP_SECONDS, pooled, read_clip_seconds, score_seconds
from makeway.eval.siren_mono import LEVEL_DBA
from makeway.jsonable import to_jsonable
from makeway.paths import data_dir
from makeway.perceive.vision.ev_classifier import EVTrackClassifier, load_crop_classifier
from makeway.pipeline.clip_sound import run_clip

CLIPS = ("night_ambulance_lights", "fire_trucks_red_lights", "intersection_cam_ambulance", "traffic_no_ev")
NEGATIVE_CLIP = "traffic_no_ev"
ROWS = (
    ("siren alone", "siren"),
    ("lights alone (today's detect; anchor)", "lights"),
    ("fused: yield", "yield"),
    ("fused: yield or prepare", "act"),
)


def predictions(decisions: list, kind: str) -> list[bool]:
    if kind == "siren":
        return [bool(d.siren) for d in decisions]
    if kind == "lights":
        return [d.lights for d in decisions]
    if kind == "yield":
        return [d.decision == "yield" for d in decisions]
    return [d.decision in ("yield", "prepare") for d in decisions]


def fmt(v: object) -> str:
    return "—" if v is None else f"{v:.3f}" if isinstance(v, float) else str(v)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=None, help="shared data root (default: found)")
    ap.add_argument("--truth", type=Path, default=CLIP_SECONDS)
    ap.add_argument("--level-dba", type=float, default=LEVEL_DBA, help="siren render level, dB(A)")
    ap.add_argument("--clips", default=",".join(CLIPS))
    ap.add_argument("--json-only", action="store_true")
    args = ap.parse_args()
    root = args.data if args.data is not None else data_dir()
    if root is None or not (root / "video").is_dir():
        print("the shared data (with video/) was not found; give --data", file=sys.stderr)
        return 2
    truth = read_clip_seconds(args.truth)
    clips = [c for c in args.clips.split(",") if c]
    track_classifier = EVTrackClassifier(load_crop_classifier("default"), every=1)
    results: dict[str, dict] = {}
    per_second: dict[str, list[dict]] = {}
    t0 = time.perf_counter()
    for clip in clips:
        run = run_clip(
            root / "video" / f"{clip}.mp4",
            None,
            audio=True,
            level_dba=args.level_dba,
            classifier=track_classifier,
            rule="lights+crop",
            write_video=False,
            progress=not args.json_only,
        )
        rows = truth[clip]
        if len(run.decisions) != len(rows):
            print(f"{clip}: {len(run.decisions)} seconds decided, {len(rows)} labelled", file=sys.stderr)
            return 1
        active = [r.active_ev for r in rows]
        block = {name: score_seconds(predictions(run.decisions, kind), active) for name, kind in ROWS}
        block["siren vs siren truth"] = score_seconds(
            predictions(run.decisions, "siren"), [r.siren for r in rows]
        )
        block["lights vs lights truth"] = score_seconds(
            predictions(run.decisions, "lights"), [r.lights for r in rows]
        )
        results[clip] = block
        per_second[clip] = [d.to_dict() for d in run.decisions]
        track_classifier = EVTrackClassifier(track_classifier.classifier, every=1)  # fresh per clip
    wall = time.perf_counter() - t0
    load = os.getloadavg()
    names = [n for n, _ in ROWS] + ["siren vs siren truth", "lights vs lights truth"]
    overall = {n: pooled({c: results[c][n] for c in clips}) for n in names}
    negative_active = (
        {n: results[NEGATIVE_CLIP][n]["fp"] for n, _ in ROWS} if NEGATIVE_CLIP in results else None
    )
    if not args.json_only:
        for clip in [*clips, "all clips"]:
            block = results[clip] if clip != "all clips" else overall
            print(f"\n{clip}  (active EV per second; truth: {args.truth.name})")
            print(f"  {'sense':42s} {'TP/FP/FN/TN':>13s} {'P':>6s} {'R':>6s} {'F1':>6s}")
            for n in names:
                b = block[n]
                counts = f"{b['tp']}/{b['fp']}/{b['fn']}/{b['tn']}"
                prf = " ".join(f"{fmt(b[k]):>6s}" for k in ("precision", "recall", "f1"))
                print(f"  {n:42s} {counts:>13s} {prf}")
        if negative_active is not None:
            print(
                f"\n{NEGATIVE_CLIP}: active seconds (target 0): "
                + ", ".join(f"{n} {v}" for n, v in negative_active.items())
            )
        print("anchor: lights alone = today's `makeway detect` (rule lights+crop, colours eu)")
        loads = " ".join(f"{x:.2f}" for x in load)
        print(f"wall {wall:.1f} s for {len(clips)} clips; load average {loads}")
    out = {
        "truth": str(args.truth),
        "level_dba": args.level_dba,
        "clips": results,
        "all": overall,
        "negative_clip_active_seconds": negative_active,
        "per_second": per_second,
        "wall_s": round(wall, 1),
        "loadavg": [round(x, 2) for x in load],
    }
    print(json.dumps(to_jsonable(out), separators=(",", ":")))
    return 0


if __name__ == "__main__":
    sys.exit(main())
