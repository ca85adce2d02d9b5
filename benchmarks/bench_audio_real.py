"""Real-data check of the siren network (issue 4, item 5): siren vs no siren on the real mono files.

    .venv/bin/python benchmarks/bench_audio_real.py [--model FILE] [--level 70] [--include-train-clips]
        [--sweep 65,70,75,80] [--smooth 8 [--average logit|probability]] [--json FILE]

Every real mono file (street recordings with and without siren, ambulance + traffic mixtures, the
test-split siren clips) is rendered as a static source 25 m from the roof array at 70 dB(A) and
scored window by window (0.5 s every 0.5 s); see :mod:`makeway.eval.siren_mono`. Prints recall and
false alarms per kind of material, for all files and for the files whose group never entered
training, beside the simulated held-out figures' targets (recall ≥ 99.5 %, false alarms ≤ 1 %).

``--sweep`` repeats the check at several levels and prints one line per level: a detector that
keys on loudness rather than on the siren's pattern shows it at once (its false alarms on street
noise climb with the level).

``--smooth K`` scores the live listener's rule instead of the single window: windows every 0.17 s,
each decided on the mean of it and the K − 1 before it (``makeway audio listen --smooth K``; the
listener's default is the logit mean of 8 windows, ``--average`` picks the mean).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from makeway.eval.siren_mono import LEVEL_DBA, mono_check, mono_files
from makeway.paths import data_dir
from makeway.perceive.audio.siren_model import DEFAULT_SIREN_MODEL, SirenModel
from makeway.perceive.audio.windows import SMOOTH_AVERAGE
from makeway.progress import progress_bar


def _pct(v: float | None) -> str:
    return "—" if v is None else f"{100 * v:.2f} %"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", type=Path, default=DEFAULT_SIREN_MODEL)
    ap.add_argument("--level", type=float, default=LEVEL_DBA, help="A-weighted level at the array, dB")
    ap.add_argument("--include-train-clips", action="store_true")
    ap.add_argument("--sweep", default="", help="comma-separated levels (dB(A)) for a level sweep")
    ap.add_argument(
        "--smooth",
        type=int,
        default=1,
        help="decide on the mean of K windows cut every 0.17 s, as 'audio listen --smooth K' does "
        "(default 1: each 0.5 s window alone, every 0.5 s)",
    )
    ap.add_argument("--average", default=SMOOTH_AVERAGE, help="with --smooth: logit or probability")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    root = data_dir()
    if root is None:
        raise SystemExit("the shared data folder was not found (set MAKEWAY_DATA)")
    model = SirenModel(args.model, threads=2)
    n = len(mono_files(root, include_train_clips=args.include_train_clips))
    with progress_bar("real mono files", n, unit="file") as advance:
        res = mono_check(
            model,
            root,
            level_dba=args.level,
            include_train_clips=args.include_train_clips,
            advance=advance,
            smooth=args.smooth,
            average=args.average,
        )
    s = res["summary"]
    rule = (
        "0.5 s windows every 0.5 s, each alone"
        if args.smooth == 1
        else f"0.5 s windows every 0.17 s, {args.average} mean of {args.smooth}"
    )
    print(f"\n{model!r}; static source 25 m away at {args.level:g} dB(A); {rule}")
    print(f"{'':22s}{'files':>7s}{'siren win':>11s}{'recall':>10s}{'other win':>11s}{'false al.':>11s}")
    rows = [(f"kind: {k}", b) for k, b in s["by_kind"].items()]
    rows += [("all files", s["all"]), ("unseen groups only", s["unseen"])]
    for name, b in rows:
        print(
            f"{name:22s}{b['files']:7d}{b['siren_windows']:11d}{_pct(b['recall']):>10s}"
            f"{b['no_siren_windows']:11d}{_pct(b['false_alarm_rate']):>11s}"
        )
    print(f"{'target (simulated)':22s}{'':18s}{'>= 99.5 %':>10s}{'':11s}{'<= 1 %':>11s}")
    print("\nper file (siren files with the lowest rate, every no-siren file with a false alarm):")
    for r in sorted((r for r in res["files"] if r["siren"]), key=lambda r: r["rate"] or 0)[:8]:
        print(f"  {r['file']:45s} siren     {r['detected']:3d}/{r['windows']:3d}")
    for r in res["files"]:
        if not r["siren"] and r["detected"]:
            print(f"  {r['file']:45s} no siren  {r['detected']:3d}/{r['windows']:3d} false alarms")
    if args.sweep:
        levels = [float(v) for v in args.sweep.split(",") if v.strip()]
        res["sweep"] = []
        with progress_bar("level sweep", n * len(levels), unit="file") as advance:
            for level in levels:
                out = mono_check(
                    model,
                    root,
                    level_dba=level,
                    include_train_clips=args.include_train_clips,
                    advance=advance,
                    smooth=args.smooth,
                    average=args.average,
                )
                res["sweep"].append({"level_dba": level, **out["summary"]["all"]})
        print(f"\nlevel sweep (all files): {'level':>8s}{'recall':>10s}{'false al.':>11s}")
        for row in res["sweep"]:
            print(
                f"{'':25s}{row['level_dba']:8g}{_pct(row['recall']):>10s}{_pct(row['false_alarm_rate']):>11s}"
            )
    if args.json is not None:
        args.json.write_text(json.dumps(res, indent=1))
    print(json.dumps(s["all"]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
