"""Issue 4, items 3 and 6: the approaching/receding estimator and streaming ``makeway audio listen``."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from makeway.cli.audio import audio_app
from makeway.eval.siren_labels import label_recording
from makeway.perceive.audio.doa import wrap_angle
from makeway.perceive.audio.features import window_batch
from makeway.perceive.audio.motion import ApproachEstimator
from makeway.perceive.audio.stream import listen
from makeway.perceive.audio.windows import LISTEN_SMOOTH
from makeway.sense.recording import Recording, write_recording
from makeway.sim.audio_scenarios import simulate_recording
from makeway.viz.listen_plot import plot_listen

MESSAGE_KEYS = {"t_end", "is_siren", "probability", "smoothed_probability", "level_db_spl", "sources"}
SOURCE_KEYS = {"bearing_rad", "bearing_deg", "distance_m", "approaching", "approach_probability"}


@pytest.fixture(scope="module")
def pass_rec() -> Recording:
    """An EV closing from behind and overtaking (passes the array at ~7.5 s of 12 s)."""
    return simulate_recording("from_behind", 12.0, seed=3, siren="synth", noise="generated")


@pytest.fixture(scope="module")
def messages(pass_rec: Recording) -> list[dict]:
    return list(listen(pass_rec))


def test_one_message_per_window_with_keys(pass_rec: Recording, messages: list[dict]) -> None:
    labels = label_recording(pass_rec)
    assert len(messages) == len(labels) > 0
    np.testing.assert_allclose([m["t_end"] for m in messages], labels.t_end, atol=1e-6)
    probs = np.clip([m["probability"] for m in messages], 1e-6, 1 - 1e-6)  # as rounded to 6 places
    logits = np.log(probs / (1 - probs))
    k = LISTEN_SMOOTH
    for i, m in enumerate(messages):
        assert set(m) == MESSAGE_KEYS
        # the decision is on the mean logit of this window's and the k - 1 before it
        z = logits[max(0, i - k + 1) : i + 1].mean()
        assert m["smoothed_probability"] == pytest.approx(1 / (1 + np.exp(-z)), abs=1e-4)
        assert 0.0 <= m["probability"] <= 1.0 and m["is_siren"] == (m["smoothed_probability"] >= 0.5)
        assert len(m["sources"]) == (1 if m["is_siren"] else 0)
        for s in m["sources"]:
            assert set(s) == SOURCE_KEYS and s["distance_m"] is None
            assert s["approaching"] in (True, False, None)
            assert s["bearing_deg"] == pytest.approx(math.degrees(s["bearing_rad"]), abs=1e-3)
    json.dumps(messages)  # JSON-ready


def test_smoothing_one_window_is_each_window_alone(pass_rec: Recording, messages: list[dict]) -> None:
    single = list(listen(pass_rec, smooth=1))
    assert [m["probability"] for m in single] == [m["probability"] for m in messages]
    assert all(m["smoothed_probability"] == m["probability"] for m in single)
    assert [m["is_siren"] for m in single] == [m["probability"] >= 0.5 for m in single]
    # averaging can only decide differently where a window and its neighbours disagree
    changed = [
        i for i, (a, b) in enumerate(zip(single, messages, strict=True)) if a["is_siren"] != b["is_siren"]
    ]
    assert len(changed) < 0.2 * len(single)
    # the mean probability of 3 windows, the rule before the logit mean
    plain = list(listen(pass_rec, smooth=3, average="probability"))
    probs = np.array([m["probability"] for m in single])
    for i, m in enumerate(plain):
        assert m["smoothed_probability"] == pytest.approx(probs[max(0, i - 2) : i + 1].mean(), abs=2e-6)
    with pytest.raises(ValueError, match="must be >= 1"):
        next(listen(pass_rec, smooth=0))
    with pytest.raises(ValueError, match="unknown average 'median'"):
        next(listen(pass_rec, average="median"))


def test_bearings_follow_the_labels(pass_rec: Recording, messages: list[dict]) -> None:
    labels = label_recording(pass_rec)
    theta, _ = labels.nearest()
    errs = [
        abs(math.degrees(float(wrap_angle(m["sources"][0]["bearing_rad"] - theta[i]))))
        for i, m in enumerate(messages)
        if m["is_siren"] and labels.siren[i]
    ]
    assert len(errs) >= 0.5 * labels.siren.sum()
    assert np.mean(np.array(errs) <= 15.0) >= 0.6


def test_plot_is_written(pass_rec: Recording, messages: list[dict], tmp_path: Path) -> None:
    out = plot_listen(messages, pass_rec, tmp_path / "sub" / "listen.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in out.parent.iterdir()] == ["listen.png"]


def test_approach_estimator_on_clear_segments(pass_rec: Recording) -> None:
    labels = label_recording(pass_rec)
    batch = window_batch(pass_rec, labels)
    est = ApproachEstimator()
    out = [est.update(batch[w], pass_rec.sample_rate, float(labels.t_end[w])) for w in range(len(labels))]
    assert out[0] == (None, None)  # not enough history yet
    rate = labels.range_rate[:, 0]
    clear = np.abs(rate) > 3.0
    truth = rate < 0
    decided = np.array([a is not None for a, _ in out])
    pred = np.array([bool(a) for a, _ in out])
    acc = np.mean(pred[clear & decided] == truth[clear & decided])
    assert np.sum(clear & decided) >= 0.8 * np.sum(clear)
    assert acc >= 0.8
    # both phases are recognised: the approach early on, the recession at the end
    assert pred[clear & truth & decided].mean() > 0.7 and (~pred[clear & ~truth & decided]).mean() > 0.7
    est.reset()
    assert est.state_ is None and not est.frames_


def test_approach_estimator_checks_settings() -> None:
    with pytest.raises(ValueError):
        ApproachEstimator(history_s=1.0, min_history_s=2.0)
    with pytest.raises(ValueError):
        ApproachEstimator(on_db_s=0.1, off_db_s=0.5)


def test_cli_listen(tmp_path: Path) -> None:
    rec = simulate_recording("crossing", 1.5, seed=1, siren="synth", noise="generated")
    folder = write_recording(tmp_path / "rec", rec)
    runner = CliRunner()
    res = runner.invoke(audio_app, ["listen", str(folder)])
    assert res.exit_code == 0, res.output
    lines = [json.loads(x) for x in res.stdout.splitlines() if x.strip()]
    assert len(lines) == len(label_recording(rec)) and set(lines[0]) == MESSAGE_KEYS
    res = runner.invoke(audio_app, ["listen", str(folder), "--smooth", "1"])
    assert res.exit_code == 0, res.output
    single = [json.loads(x) for x in res.stdout.splitlines() if x.strip()]
    assert all(m["smoothed_probability"] == m["probability"] for m in single)
    res = runner.invoke(audio_app, ["listen", str(folder), "--smooth", "0"])
    assert res.exit_code == 2 and "--smooth" in res.output
    res = runner.invoke(audio_app, ["listen", str(folder), "--average", "median"])
    assert res.exit_code != 0 and "unknown average 'median'" in res.output

    out, png = tmp_path / "o" / "msgs.jsonl", tmp_path / "o" / "plot.png"
    res = runner.invoke(audio_app, ["listen", str(folder), "--jsonl", str(out), "--plot", str(png)])
    assert res.exit_code == 0, res.output
    (summary_line,) = res.stdout.strip().splitlines()  # the progress bar goes to stderr
    summary = json.loads(summary_line)
    assert summary["messages"] == len(lines) and png.exists()
    assert [json.loads(x) for x in out.read_text().splitlines()] == lines

    res = runner.invoke(audio_app, ["listen", str(folder), "--baseline", "gccphat"])  # classical path
    assert res.exit_code == 0, res.output
    base = [json.loads(x) for x in res.stdout.splitlines() if x.strip()]
    assert len(base) == len(lines) and all(s["distance_m"] is None for m in base for s in m["sources"])

    missing = tmp_path / "nope"
    res = runner.invoke(audio_app, ["listen", str(missing)])
    assert res.exit_code == 2 and "nope" in res.output
    res = runner.invoke(audio_app, ["listen", str(folder), "--baseline", "bogus"])
    assert res.exit_code == 2
