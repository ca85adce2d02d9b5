"""Issue 4, negatives: the siren spans cut out of the real no-siren street recordings, and the
synthesized non-siren street sounds (distractors) of the simulator."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from makeway.errors import InputError
from makeway.sense.recording import REFERENCE_SAMPLE_RATE
from makeway.sim.acoustics import (
    STREET_NOISE_SIRENS,
    load_street_noise_sources,
    street_noise_siren_spans,
)
from makeway.sim.audio_scenarios import simulate_recording
from makeway.sim.distractors import DISTRACTOR_KINDS, synthesize_distractor
from makeway.sim.siren import cut_spans

SR = REFERENCE_SAMPLE_RATE


def test_cut_spans_removes_samples() -> None:
    x = np.arange(10 * 100, dtype=np.float32)  # 10 s at 100 Hz
    y = cut_spans(x, 100, [(0.0, 2.0), (5.0, 6.0)], unit_rms=False)
    assert len(y) == 700 and y[0] == 200 and 499 in y and 500 not in y and 600 in y
    assert not y.flags.writeable
    z = cut_spans(x, 100, [(0.0, 1.0)])
    assert abs(float(np.sqrt(np.mean(z.astype(np.float64) ** 2))) - 1.0) < 1e-5


def test_shipped_siren_spans_parse() -> None:
    spans = street_noise_siren_spans()
    assert spans["traffic-8"] == ((0.0, 24.0),) and spans["traffic-6"] == ((0.0, 5.0),)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("file,start\ntraffic-8,0\n", "missing end_s, start_s"),
        ("file,start_s,end_s\ntraffic-8,zero,3\n", "line 2: start_s/end_s must be numbers"),
        ("file,start_s,end_s\ntraffic-8,5,3\n", "line 2: needs 0 <= start_s < end_s"),
    ],
)
def test_malformed_siren_spans(tmp_path: Path, text: str, message: str) -> None:
    bad = tmp_path / "spans.csv"
    bad.write_text(text)
    with pytest.raises(InputError, match=message) as err:
        street_noise_siren_spans(bad)
    assert str(bad) in str(err.value)


def test_street_noise_sources_leave_out_the_siren_spans(data_root: Path) -> None:
    assert STREET_NOISE_SIRENS.is_file()
    src = {s.name: s for s in load_street_noise_sources(data_root)}
    t8 = src["traffic-8"]
    assert t8.exclude == ((0.0, 24.0),)
    full = sf.info(t8.path).duration
    assert abs(len(t8.load()) / SR - (full - 24.0)) < 1e-3
    t5 = src["traffic-5"]
    assert t5.exclude == () and abs(len(t5.load()) / SR - sf.info(t5.path).duration) < 1e-3
    # the wail of traffic-8 (700–1750 Hz sweep) is gone: the kept part has no strong tonal peak there
    kept = np.asarray(t8.load()[: 10 * SR], dtype=np.float64)
    spec = np.abs(np.fft.rfft(kept)) ** 2
    f = np.fft.rfftfreq(len(kept), 1 / SR)
    band = spec[(f > 700) & (f < 1750)]
    assert band.max() < 200 * np.median(band)


@pytest.mark.parametrize("kind", DISTRACTOR_KINDS)
def test_distractor_kinds(kind: str) -> None:
    d = synthesize_distractor(kind, 3 * SR, SR, np.random.default_rng(3))
    assert d.kind == kind and d.signal.shape == (3 * SR,) and d.signal.dtype == np.float32
    assert d.active.any() and not d.active.all()
    assert abs(float(np.sqrt(np.mean(d.signal[d.active].astype(np.float64) ** 2))) - 1.0) < 1e-3
    assert np.all(d.signal[~d.active] == 0)


def test_horn_sounds_two_fundamentals() -> None:
    d = synthesize_distractor("horn", 3 * SR, SR, np.random.default_rng(5))
    x = d.signal[d.active].astype(np.float64)
    spec = np.abs(np.fft.rfft(x * np.hanning(len(x))))
    f = np.fft.rfftfreq(len(x), 1 / SR)
    f_low, ratio = d.params["f_low_hz"], d.params["ratio"]
    for f0 in (f_low, f_low * ratio):
        near = (f > f0 - 15) & (f < f0 + 15)
        away = (f > f0 + 40) & (f < f0 + 70)
        assert spec[near].max() > 20 * spec[away].max()


def test_unknown_distractor() -> None:
    with pytest.raises(ValueError, match="unknown distractor 'whistle'"):
        synthesize_distractor("whistle", SR, SR, np.random.default_rng(0))


def test_simulator_adds_distractors_from_their_own_stream(monkeypatch: pytest.MonkeyPatch) -> None:
    import makeway.sim.audio_scenarios as scen

    monkeypatch.setattr(scen, "data_dir", lambda: None)  # generated noise: fast and data-free
    recs = {s: simulate_recording("none", 1.0, seed=s) for s in range(6)}
    assert any(r.meta["distractors"] for r in recs.values()) and any(
        not r.meta["distractors"] for r in recs.values()
    )
    seed = next(s for s, r in recs.items() if r.meta["distractors"])
    with_d = recs[seed]
    without = simulate_recording("none", 1.0, seed=seed, distractors=False)
    assert "distractors" not in without.meta
    for key in ("street_noise", "wind", "ego_speed_mps"):  # every other draw is unchanged
        assert with_d.meta[key] == without.meta[key]
    extra = with_d.audio.astype(np.float64) - without.audio
    assert np.abs(extra).max() > 1e-5
    for d in with_d.meta["distractors"]:
        assert d["kind"] in DISTRACTOR_KINDS and -5.0 <= d["relative_dba"] <= 15.0
        x, y, _ = d["position_vehicle_m"]
        assert 4.9 <= math.hypot(x + 0.9, y) <= 40.1  # around the array centre


def test_street_level_range(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    from typer.testing import CliRunner

    import makeway.sim.audio_scenarios as scen
    from makeway.cli.audio import audio_app

    monkeypatch.setattr(scen, "data_dir", lambda: None)
    rec = simulate_recording("none", 0.8, seed=1, street_dba=(84.0, 84.0), distractors=False)
    assert rec.meta["street_noise"]["level_dba"] == 84.0
    with pytest.raises(ValueError, match="low <= high"):
        simulate_recording("none", 0.8, seed=1, street_dba=(80.0, 70.0))
    res = CliRunner().invoke(
        audio_app, ["simulate", "--out", str(tmp_path / "x"), "--n", "1", "--street-level", "75,60"]
    )
    assert res.exit_code == 2 and "--street-level needs 0 <= LOW <= HIGH" in res.output
    res = CliRunner().invoke(
        audio_app, ["simulate", "--out", str(tmp_path / "x"), "--n", "1", "--siren-pitch", "0.7"]
    )
    assert res.exit_code == 2 and "--siren-pitch takes LOW,HIGH" in res.output
    assert not (tmp_path / "x").exists()


def test_mono_check_leaves_out_the_siren_spans(data_root: Path) -> None:
    from makeway.eval.siren_mono import mono_files

    files = {f.path.stem: f for f in mono_files(data_root) if f.kind == "street_noise"}
    assert files["traffic-8"].exclude == ((0.0, 24.0),) and not files["traffic-8"].siren
    assert files["noise1"].exclude == ()
