"""Bounds on false alarms, on real negatives (issue 22): the shipped siren detector on held-out real
street recordings, ``makeway detect`` with its defaults on the two clips without an emergency
vehicle, and closed-loop drives with no EV through held-out real street noise.

Each test is a short slice of what a benchmark measures at length; the bound is the benchmark's
figure with a stated margin, so a detector that starts firing on traffic fails here first.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from makeway.cli.main import app
from makeway.eval.siren_mono import check_file, mono_files
from makeway.perceive.audio.siren_model import SirenModel
from makeway.perceive.audio.windows import HOP_S, LISTEN_SMOOTH
from makeway.pipeline.closed_loop import run_scenario
from makeway.pipeline.siren_perception import SirenPerceptionConfig
from makeway.sim.live_array import LiveAudioConfig
from makeway.sim.scenarios import SCENARIOS

runner = CliRunner()


@pytest.fixture(scope="module")
def siren_model() -> SirenModel:
    return SirenModel(threads=2)


def test_siren_detector_on_held_out_real_street_recordings(data_root: Path, siren_model: SirenModel) -> None:
    """Every real street recording without a siren whose group never entered training (noise4,
    traffic-4, traffic-6 less its siren span: 105 s), rendered 25 m from the array at 75 dB(A) — a
    loud street — and decided by the listener's rule (0.5 s windows every 0.17 s, logit mean of 8).

    Benchmark (``bench_audio_real.py --sweep 65,70,75,80,85 --smooth 8``, docs/results.md): 0.87 %
    of windows flagged at 75 dB(A) over all 12 street recordings, against issue 4's ≤ 1 % target;
    on these three whole recordings it flags 6 of 610 windows (0.98 %, all in traffic-6's harmonic
    horn). Bound: ≤ 2 % of windows, i.e. ≤ 424 flagged windows per hour of audio.
    """
    files = [f for f in mono_files(data_root) if f.kind == "street_noise" and not f.seen_in_training]
    assert sorted(f.path.stem for f in files) == ["noise4", "traffic-4", "traffic-6"]
    rows = [
        check_file(
            f, siren_model, np.random.default_rng(0), level_dba=75.0, max_windows=1000, smooth=LISTEN_SMOOTH
        )
        for f in files
    ]
    windows = sum(r["windows"] for r in rows)
    flagged = sum(r["detected"] for r in rows)
    hours = windows * HOP_S / 3600.0  # one window decided every HOP_S of audio
    assert windows >= 600  # the whole recordings, not the benchmark's first 15 s of each
    assert flagged / windows <= 0.02, rows
    assert flagged / hours <= 0.02 * 3600.0 / HOP_S, rows


@pytest.mark.parametrize("clip", ["traffic_no_ev", "highway_cam_no_ev"])
def test_detect_defaults_flag_no_ev_on_the_no_ev_clips(video_dir: Path, tmp_path: Path, clip: str) -> None:
    """``makeway detect`` with its defaults (the accurate crop head on) over the whole clip: no
    track ever becomes an active EV (the clips hold none: data README, video_track_labels.csv).

    Benchmark (``bench_track_sweep.py``, docs/results.md "per-actor"): over the five clips the
    default head and smoother leave 4 false active actors of 120 negatives, white coaches and a
    black SUV beside the EVs; on these two clips this command turns none of its 32 and 49 tracks
    active (measured for this test). Bound: 0, with no margin, since one false active EV on an empty
    road is one needless yield.
    """
    out = tmp_path / clip
    r = runner.invoke(
        app, ["detect", str(video_dir / f"{clip}.mp4"), "--out", str(out), "--no-video", "--json", "-q"]
    )
    assert r.exit_code == 0, r.output
    summary = json.loads(r.stdout.strip().splitlines()[-1])
    assert summary["frames"] >= 250 and summary["ms_per_frame"]["classify"] > 0  # whole clip, head on
    states = [
        t["state"]
        for line in (out / "tracks.jsonl").read_text().splitlines()
        for t in json.loads(line)["tracks"]
    ]
    assert states and "unclassified" not in states  # every track was judged
    assert summary["active_ev_tracks"] == [] and "active" not in states


def test_closed_loop_no_ev_through_real_street_noise(siren_model: SirenModel) -> None:
    """Six 20 s ``no_ev`` drives (scene seeds 100–105) heard through held-out real street recordings:
    how often the car yields to nothing.

    Benchmark (``bench_closed_loop_siren.py --no-ev-runs 80``, docs/results.md): 6 false yields in
    80 drives, 13.5 per hour, with the listener flagging 0.24 % of windows; of seeds 100–119 only
    seed 112 yields. Bound on these 120 s: ≤ 1 false yield (30 per hour; 13.5 per hour gives 0.45
    expected) and ≤ 1 % of windows flagged (4× the benchmark's rate).
    """
    quiet = SCENARIOS["no_ev"]()
    false_yields, windows, flagged = 0, 0, 0
    for seed in range(100, 106):
        cfg = SirenPerceptionConfig(audio=LiveAudioConfig(seed=seed, noise="real"), model=siren_model)
        res = run_scenario(quiet, perception=cfg)
        assert res.metrics["collision"] is False
        false_yields += sum(1 for _, _, to, _ in res.transitions if to == "moving_over")
        windows += len(res.siren)
        flagged += sum(o.is_siren for o, _ in res.siren)
    assert windows >= 6 * 100  # a decision every 0.17 s over 6 × 20 s
    assert false_yields <= 1
    assert flagged / windows <= 0.01
