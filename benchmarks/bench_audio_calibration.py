"""How much the siren networks depend on the array's calibration (issue 4; recording format,
``full_scale_db_spl`` in ``array.yaml``).

    .venv/bin/python benchmarks/bench_audio_calibration.py [--data DIR ...] [--n 30 --seeds 2026,2027]
        [--gains -12,-6,-3,3,6,12] [--model FILE] [--json FILE]

A real array is more or less sensitive than the simulator's (a digital RMS of 1.0 = 135 dB SPL, the
scale every shipped network was trained at). Each held-out recording (``--data`` folders, or ``--n``
per seed simulated from the test-split groups, like ``bench_audio_model.py``) is re-recorded in
memory by an array ``g`` dB more sensitive: samples × 10^(g/20), clipped at full scale as an ADC
would. Then the shipped networks (detector — or ``--model`` — with the shipped localizer and ranger)
run twice on it:

* **stated** — ``full_scale_db_spl = 135 − g`` is known (``array.yaml`` states it, or
  ``--full-scale-db-spl``): the windows are brought back to the networks' scale;
* **not stated** — taken at the networks' 135 dB SPL, i.e. every level reads ``g`` dB off.

Printed beside the anchor (the recordings as simulated, ``g = 0``): recall and false alarms per
window, angle and distance errors at 10–50 m, and the median ratio of the distances given to the
anchor's (how far the estimate moves). The anchor's figures are those of ``bench_audio_model.py`` on
the same recordings.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from makeway.eval.siren import evaluate, model_estimator
from makeway.perceive.audio.siren_model import DEFAULT_SIREN_LOCALIZER, DEFAULT_SIREN_RANGERS, SirenModel
from makeway.progress import progress_bar
from makeway.sense.recording import REFERENCE_FULL_SCALE_DB_SPL, Recording, read_recording
from makeway.sim.audio_scenarios import held_out_folders

COLUMNS = (
    ("recall", "recall", True),
    ("false_alarm_rate", "false alarms", True),
    ("angle_median_deg", "angle med", False),
    ("distance_median_m", "dist med", False),
    ("distance_mean_m", "dist mean", False),
)


def rerecord(rec: Recording, gain_db: float, stated: bool) -> tuple[Recording, float]:
    """``rec`` as an array ``gain_db`` more sensitive would record it (clipped at full scale), with
    its calibration stated or not; also the share of samples that clipped."""
    x = rec.audio * np.float32(10.0 ** (gain_db / 20.0))
    clipped = float(np.mean(np.abs(x) >= 1.0))
    full_scale = REFERENCE_FULL_SCALE_DB_SPL - gain_db if stated else None
    return replace(rec, audio=np.clip(x, -1.0, 1.0), full_scale_db_spl=full_scale), clipped


def _fmt(v: Any, pct: bool) -> str:
    if v is None:
        return "—"
    return f"{100 * v:.2f} %" if pct else f"{v:.2f}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--data", type=Path, action="append", default=None, help="held-out recordings (repeatable)"
    )
    ap.add_argument("--n", type=int, default=30, help="recordings per seed to simulate without --data")
    ap.add_argument("--seeds", default="2026,2027", help="seeds of the simulated held-out sets, pooled")
    ap.add_argument("--gains", default="-12,-6,-3,3,6,12", help="array sensitivity offsets, dB")
    ap.add_argument("--model", type=Path, default=None, help="detector (default: the shipped one)")
    ap.add_argument("--json", type=Path, default=None, help="also write every result to this JSON file")
    args = ap.parse_args()
    gains = [float(v) for v in args.gains.split(",") if v.strip()]

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        seeds = [int(v) for v in args.seeds.split(",") if v.strip()]
        folders = held_out_folders(args.data, tmp, args.n, seeds)
        if not args.data:
            print(f"simulated {len(folders)} held-out recordings in {time.perf_counter() - t0:.0f} s")
        recs = [read_recording(f) for f in folders]
        if args.model is None:
            model = SirenModel(threads=2)
        else:
            model = SirenModel(
                args.model, threads=2, localizer=DEFAULT_SIREN_LOCALIZER, ranger=DEFAULT_SIREN_RANGERS
            )
        print(f"model: {model!r}, trained at {model.full_scale_db_spl:g} dB SPL full scale")

        def run(name: str, items: list[Recording]) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
            arrays: dict[str, np.ndarray] = {}
            with progress_bar(name, len(items), unit="rec") as advance:
                res = evaluate(
                    items,
                    model_estimator(model),
                    on_recording=advance,
                    name=name,
                    threshold=model.threshold,
                    arrays=arrays,
                )
            return res, arrays

        anchor, anchor_arrays = run("as simulated (0 dB)", recs)
        rows: list[tuple[str, dict[str, Any], float, float]] = [("as simulated (0 dB)", anchor, 1.0, 0.0)]
        d = anchor_arrays["distance"]
        near = anchor_arrays["siren"] & (d >= 10) & (d <= 50)
        results: dict[str, Any] = {"anchor": anchor}
        for g in gains:
            for stated in (True, False):
                name = f"{g:+g} dB, {'stated' if stated else 'not stated'}"
                pairs = [rerecord(r, g, stated) for r in recs]
                res, arrays = run(name, [p[0] for p in pairs])
                ratio = float(np.median(arrays["distance_hat"][near] / anchor_arrays["distance_hat"][near]))
                clipped = float(np.mean([p[1] for p in pairs]))
                rows.append((name, res, ratio, clipped))
                results[name] = {**res, "distance_ratio_to_anchor": ratio, "clipped_share": clipped}

    print(
        f"\n{len(recs)} held-out recordings, {anchor['windows']} windows "
        f"({anchor['range_10_50']['positives']} with a siren in 10–50 m, {anchor['negatives']} without); "
        f"threshold {model.threshold:.3f}; figures at 10–50 m (false alarms over all negatives)"
    )
    head = "".join(f"{h:>14s}" for _, h, _ in COLUMNS)
    print(f"{'array sensitivity, calibration':32s}{head}{'dist × anchor':>15s}{'clipped':>10s}")
    for name, res, ratio, clipped in rows:
        r = res["range_10_50"]
        cells = "".join(f"{_fmt(r.get(k), p):>14s}" for k, _, p in COLUMNS)
        print(f"{name:32s}{cells}{ratio:>15.3f}{100 * clipped:>9.3f}%")
    print(
        "\nanchor: the '0 dB' row (the recordings as simulated, at the networks' own scale); "
        "'stated' rows should match it, 'not stated' rows show what a wrong calibration costs"
    )
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
