"""Issue 4, item 3: approaching/receding from the trend of the network's distance
(:class:`TrendApproach`), its scoring, its training command, and ``audio listen --approach``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from makeway.cli.audio import audio_app
from makeway.errors import InputError
from makeway.eval.siren_approach import MIN_RANGE_RATE_MPS, approach_report, approach_windows
from makeway.eval.siren_labels import label_recording
from makeway.perceive.audio.features import window_batch
from makeway.perceive.audio.motion import (
    APPROACH_METHODS,
    DEFAULT_APPROACH_MODEL,
    MIN_RECEDING_WINDOWS,
    TREND_HORIZONS_S,
    ApproachEstimator,
    TrendApproach,
)
from makeway.perceive.audio.siren_model import DEFAULT_SIREN_MODEL, SirenModel
from makeway.perceive.audio.stream import default_approach, listen
from makeway.sense.recording import Recording, write_recording
from makeway.sim.audio_scenarios import simulate_recording
from makeway.sim.siren import load_siren_sources, split_sources


@pytest.fixture(scope="module")
def pass_rec(data_root: Path) -> Recording:
    """A held-out-split recording (test siren and noise groups): an EV closing from behind that
    overtakes the car, so both phases are in it."""
    from makeway.sim.acoustics import load_street_noise_sources

    sirens = split_sources(load_siren_sources(data_root), "test")
    noise = split_sources(load_street_noise_sources(data_root), "test")
    return simulate_recording(
        "from_behind", 12.0, seed=3, siren="real", siren_pool=sirens, noise_pool=noise, data_root=data_root
    )


@pytest.fixture(scope="module")
def networks() -> SirenModel:
    return SirenModel(threads=1)


def test_nearest_range_rate_matches_the_labels(pass_rec: Recording) -> None:
    labels = label_recording(pass_rec)
    rate = labels.nearest_range_rate()
    present = labels.present[:, 0]
    np.testing.assert_array_equal(rate[present], labels.range_rate[present, 0])
    assert np.isnan(rate[~present]).all()
    # the EV closes in, then passes and recedes
    assert (rate[present] < -MIN_RANGE_RATE_MPS).any() and (rate[present] > MIN_RANGE_RATE_MPS).any()


def test_trend_features_read_the_slope_of_log_distance(pass_rec: Recording) -> None:
    """Distances shrinking as 50·exp(−0.2 t) give a slope of exactly −0.2 /s over every span once
    enough siren windows are in it; windows not decided siren stay out of the history."""
    labels = label_recording(pass_rec)
    batch = window_batch(pass_rec, labels)
    est = TrendApproach(model=None)
    names = est.feature_names
    assert len(names) == 2 * len(TREND_HORIZONS_S) + 4
    rows = []
    for i in range(len(labels)):
        t = float(labels.t_end[i])
        rows.append(
            est.observe(
                batch[i], pass_rec.sample_rate, t, distance_m=50 * math.exp(-0.2 * t), is_siren=i != 5
            )
        )
        if i == 7:  # window 5 was not decided siren: it is not part of any slope
            assert [h for h, _ in est.history_] == [labels.t_end[k] for k in (0, 1, 2, 3, 4, 6, 7)]
    rows = np.array(rows)
    assert rows.shape == (len(labels), len(names)) and rows.dtype == np.float32
    assert not rows[:2, 0:8:2].any() and not rows[:2, 1:8:2].any()  # fewer than 3 siren windows: no slope
    late = rows[-1]
    np.testing.assert_allclose(late[0:8:2], -0.2, atol=1e-4)
    assert late[1:8:2].all()
    assert late[names.index("log_distance")] == pytest.approx(math.log(50) - 0.2 * labels.t_end[-1], abs=1e-4)
    assert late[names.index("has_level_slope")] == 1.0
    assert all(t > labels.t_end[-1] - max(TREND_HORIZONS_S) for t, _ in est.history_)
    est.reset()
    assert not est.history_ and est.features_ is None and est.level.state_ is None


def test_trend_approach_settings_and_model_errors(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="positive spans"):
        TrendApproach(model=None, horizons=())
    with pytest.raises(ValueError, match="min_windows"):
        TrendApproach(model=None, min_windows=1)
    for bad in (-1, 2.5, True, "6", None):
        with pytest.raises(ValueError, match="min_receding_windows must be a whole number"):
            TrendApproach(model=None, min_receding_windows=bad)  # type: ignore[arg-type]
    assert TrendApproach(model=None, min_receding_windows=np.int64(0)).min_receding_windows == 0
    with pytest.raises(ValueError, match="no classifier"):
        TrendApproach(model=None).predict_proba(np.zeros((1, 12)))
    with pytest.raises(InputError, match="approach model not found"):
        TrendApproach(tmp_path / "none.onnx")
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not an onnx file")
    with pytest.raises(InputError, match="not a readable ONNX model"):
        TrendApproach(junk)
    with pytest.raises(InputError, match="not a makeway siren approach model"):
        TrendApproach(DEFAULT_SIREN_MODEL)
    with pytest.raises(InputError, match="reads the features"):
        TrendApproach(DEFAULT_APPROACH_MODEL, horizons=(1.0, 2.0))
    assert set(APPROACH_METHODS) == {"level", "trend"}
    assert APPROACH_METHODS["level"] is ApproachEstimator
    with pytest.raises(ValueError, match="unknown approach method 'doppler'"):
        APPROACH_METHODS["doppler"]


def test_approach_report_counts_undecided_as_wrong() -> None:
    arrays = {
        "scored": np.array([True, True, True, True, True, False]),
        "approaching": np.array([True, False, True, False, True, True]),
        "range_rate": np.array([-2.0, 4.0, -12.0, 5.0, -7.0, -0.5]),
        "scenario": np.array(["a", "a", "b", "b", "b", "b"]),
    }
    state = np.array([1.0, 1.0, np.nan, 0.0, 0.0, 0.0])
    rep = approach_report(arrays, state)
    assert rep["windows"] == 5 and rep["correct"] == 0.4 and rep["decided"] == 0.8
    assert rep["accuracy_decided"] == 0.5 and rep["approaching_share"] == 0.6
    # of the 3 approaching windows one was called receding (one undecided); of 2 receding, one approaching
    assert rep["receding_when_approaching"] == pytest.approx(1 / 3, abs=1e-4)
    assert rep["approaching_when_receding"] == 0.5
    assert rep["by_scenario"]["a"]["correct"] == 0.5 and rep["by_scenario"]["b"]["decided"] == pytest.approx(
        2 / 3, abs=1e-4
    )
    bands = rep["by_speed_mps"]
    assert list(bands) == ["1-3", "3-6", "6-10", "10-inf"]
    assert [b["windows"] for b in bands.values()] == [1, 2, 1, 1] and bands["3-6"]["correct"] == 0.5


def test_shipped_classifier_tells_the_pass_by(pass_rec: Recording, networks: SirenModel) -> None:
    """On a held-out-split pass-by the shipped classifier is right in most scored windows, in both
    phases, and at least as often as the level/Doppler rule."""
    trend = TrendApproach()
    arrays = approach_windows(pass_rec, networks, trend)
    state, prob = trend.decide(arrays["features"])
    rep, level = approach_report(arrays, state), approach_report(arrays, arrays["level_state"])
    assert rep["windows"] >= 25
    assert rep["correct"] >= 0.8 and rep["correct"] >= level["correct"]
    sel, truth = arrays["scored"], arrays["approaching"]
    for phase in (truth, ~truth):  # the approach, and the recession after the overtake
        assert (sel & phase).sum() >= 10 and (state[sel & phase] == truth[sel & phase]).mean() >= 0.8
    assert ((prob >= 0) & (prob <= 1)).all()
    # streaming gives the same decisions, one window at a time, inside the listener's messages
    # (without the early receding calls withheld: the batch rows do not know the history's length)
    msgs = list(listen(pass_rec, model=networks, approach=TrendApproach(min_receding_windows=0)))
    for i in np.flatnonzero(sel):
        src = msgs[i]["sources"][0]
        if np.isnan(state[i]):  # no cue yet
            assert src["approaching"] is None and src["approach_probability"] is None
        else:
            assert src["approaching"] == bool(state[i])
            assert src["approach_probability"] == pytest.approx(prob[i], abs=1e-4)


def test_listen_picks_the_estimator(networks: SirenModel) -> None:
    est = default_approach(networks)
    assert isinstance(est, TrendApproach)
    assert est.min_receding_windows == MIN_RECEDING_WINDOWS == 6
    assert isinstance(default_approach(None), ApproachEstimator)


def _stream(
    est: TrendApproach, log_rate: float, n: int = 24
) -> list[tuple[int, bool | None, bool, float | None]]:
    """Feed ``n`` listener windows (0.5 s, hop 0.17 s) of quiet noise, each a siren window whose
    network distance is ``40·exp(log_rate·t)``; per window ``(siren windows in the history, the
    call, withheld_, probability_)``."""
    rng = np.random.default_rng(7)
    sr = 16000
    out = []
    for i in range(n):
        t = 0.5 + 0.17 * i
        window = 0.01 * rng.standard_normal((4, sr // 2))
        approaching, _ = est.update(window, sr, t, distance_m=40.0 * math.exp(log_rate * t), is_siren=True)
        out.append((len(est.history_), approaching, est.withheld_, est.probability_))
    return out


def test_trend_approach_withholds_early_receding_calls() -> None:
    """A receding call is None (undecided, no probability) until 6 siren windows are in the history,
    then given; the same estimator with ``min_receding_windows=0`` calls it at once. (On this noise
    the classifier calls the first windows with a slope approaching, then receding from the fifth.)"""
    held, free = _stream(TrendApproach(), 0.3), _stream(TrendApproach(min_receding_windows=0), 0.3)
    for (n, call, withheld, p), (n0, call0, withheld0, p0) in zip(held, free, strict=True):
        assert n == n0 and not withheld0
        assert withheld == (call0 is False and n < MIN_RECEDING_WINDOWS)
        if withheld:  # undecided, without a probability
            assert call is None and p is None
        else:  # anything else as without the rule (an approaching call among the first windows too)
            assert (call, p) == (call0, p0)
    assert any(w for _, _, w, _ in held)  # the classifier did call it receding early, and was held back
    assert [c for n, c, _, _ in held if n >= MIN_RECEDING_WINDOWS][-1] is False
    first = next(i for i, (_, c, _, _) in enumerate(held) if c is False)
    assert held[first][0] == MIN_RECEDING_WINDOWS


def test_trend_approach_does_not_delay_approaching_calls() -> None:
    held, free = _stream(TrendApproach(), -0.3), _stream(TrendApproach(min_receding_windows=0), -0.3)
    assert held == free
    assert any(c is True and n < MIN_RECEDING_WINDOWS for n, c, _, _ in held)
    assert not any(w for _, _, w, _ in held)


def test_cli_train_approach_and_listen_approach(tmp_path: Path) -> None:
    recs = tmp_path / "recs"
    for i, scenario in enumerate(["from_behind", "opposite_direction", "crossing"]):
        rec = simulate_recording(scenario, 5.0, seed=40 + i, siren="synth", noise="generated")
        write_recording(recs / f"rec_{i:05d}", rec)
    out = tmp_path / "m" / "approach.onnx"
    runner = CliRunner()
    res = runner.invoke(
        audio_app, ["train-approach", "--data", str(recs), "--val", str(recs), "--out", str(out)]
    )
    assert res.exit_code == 0, res.output
    result = json.loads(res.stdout.strip().splitlines()[-1])
    assert result["training"]["windows"] > 20 and result["training"]["recordings"] == 3
    val = result["validation"]
    for name in ("trend", "level"):  # a window counts as correct only when a call was made
        assert val[name]["correct"] <= val[name]["decided"]
    # validated on the recordings it was trained on, the classifier must have learned them (0.93
    # when written) and beat the untrained level/Doppler rule on them (0.32)
    assert val["trend"]["correct"] >= 0.8 and val["trend"]["correct"] > val["level"]["correct"]
    trained = TrendApproach(out)
    assert json.loads(trained.session_.get_modelmeta().custom_metadata_map["training"])["recordings"] == 3
    assert [p.name for p in out.parent.iterdir()] == ["approach.onnx"]  # nothing half-written beside it

    res = runner.invoke(audio_app, ["eval", "--data", str(recs), "--approach", "--json", "-q"])
    assert res.exit_code == 0, res.output
    scored = json.loads(res.stdout.strip().splitlines()[-1])["approach"]
    assert scored["min_range_rate_mps"] == MIN_RANGE_RATE_MPS and scored["trend"]["windows"] > 20
    assert set(scored["trend"]) >= {
        "correct",
        "decided",
        "receding_when_approaching",
        "by_scenario",
        "by_speed_mps",
    }
    assert scored["trend"]["windows"] == scored["level"]["windows"]
    res = runner.invoke(audio_app, ["eval", "--data", str(recs), "--approach", "--baseline", "srp"])
    assert res.exit_code == 2 and "--approach scores the network's" in res.output

    folder = recs / "rec_00000"
    for approach, has_probability in (("trend", True), ("level", False)):
        res = runner.invoke(audio_app, ["listen", str(folder), "--approach", approach])
        assert res.exit_code == 0, res.output
        firsts = [m["sources"][0] for m in map(json.loads, res.stdout.splitlines()) if m["sources"]]
        assert firsts and all(
            (s["approach_probability"] is not None) == has_probability
            for s in firsts
            if s["approaching"] is not None
        )
    res = runner.invoke(audio_app, ["listen", str(folder), "--approach", "trend", "--baseline", "gccphat"])
    assert res.exit_code == 2 and "--approach trend reads the network's distances" in res.output
    res = runner.invoke(audio_app, ["listen", str(folder), "--approach", "bogus"])
    assert res.exit_code == 2 and "unknown approach method 'bogus'" in res.output
    res = runner.invoke(audio_app, ["train-approach", "--data", str(tmp_path / "nothing")])
    assert res.exit_code == 2
    quiet = tmp_path / "quiet"  # no siren: nothing to learn from, and no file written
    write_recording(
        quiet / "rec_00000", simulate_recording("none", 3.0, seed=5, siren="synth", noise="generated")
    )
    res = runner.invoke(
        audio_app, ["train-approach", "--data", str(quiet), "--out", str(tmp_path / "q.onnx")]
    )
    assert res.exit_code == 2 and "only one class" in res.output and not (tmp_path / "q.onnx").exists()
