"""Issue 25: siren ranging over the real range of siren levels — ``audio simulate --siren-level`` and
``--far-start``, the distance uncertainty output of the siren networks, and how the networks'
distances are combined."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from makeway.cli.audio import audio_app
from makeway.eval.siren_labels import label_recording
from makeway.perceive.audio.features import window_batch
from makeway.perceive.audio.siren_features import SirenFeatures
from makeway.perceive.audio.siren_model import (
    DEFAULT_SIREN_LOCALIZER,
    DEFAULT_SIREN_RANGERS,
    LOCALIZER_DISTANCE,
    SIGMA_OUTPUT,
    SIGMA_SCALE_UNRATED,
    SirenModel,
    SirenPrediction,
    combine_distances,
)
from makeway.sense.recording import Recording, read_recording
from makeway.sim.audio_scenarios import (
    AUDIO_SCENARIOS,
    FAR_START,
    SIREN_LEVEL_BOUNDS_DB,
    check_siren_level,
    make_tracks,
    simulate_recording,
)

runner = CliRunner()


# ------------------------------------------------------------------------------------- simulation


def test_cli_simulate_draws_siren_levels_in_the_range(tmp_path: Path, data_root: Path) -> None:
    out = tmp_path / "loud"
    res = runner.invoke(
        audio_app,
        ["simulate", "--out", str(out), "--n", "3", "--duration", "0.8", "--seed", "3", "--split", "train",
         "--no-siren-fraction", "0", "--siren-level", "128,131", "--json", "-q"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert '"siren_level_db": [128.0, 131.0]' in res.output
    levels = []
    for folder in sorted(out.iterdir()):
        rec = read_recording(folder)
        assert rec.meta is not None
        levels += [s["level_db_1m"] for s in rec.meta["sirens"]]
    assert len(levels) >= 3 and all(128.0 <= lv <= 131.0 for lv in levels)
    # the same scenes at the default levels: same draws, only the level differs, and it is quieter
    quiet = tmp_path / "quiet"
    res = runner.invoke(
        audio_app,
        ["simulate", "--out", str(quiet), "--n", "1", "--duration", "0.8", "--seed", "3", "--split", "train",
         "--no-siren-fraction", "0", "-q"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    a, b = read_recording(quiet / "rec_00000"), read_recording(out / "rec_00000")
    assert a.meta is not None and b.meta is not None
    assert 110.0 <= a.meta["sirens"][0]["level_db_1m"] <= 120.0
    assert a.meta["scenario"] == b.meta["scenario"]
    assert a.meta["sirens"][0]["height_m"] == b.meta["sirens"][0]["height_m"]


@pytest.mark.parametrize(
    ("value", "problem"),
    [("120", "LOW,HIGH"), ("loud,louder", "LOW,HIGH"), ("130,120", "LOW <= HIGH"), ("110,1350", "<= 150")],
)
def test_cli_simulate_refuses_bad_siren_levels(tmp_path: Path, value: str, problem: str) -> None:
    out = tmp_path / "never"
    res = runner.invoke(audio_app, ["simulate", "--out", str(out), "--n", "1", "--siren-level", value, "-q"])
    assert res.exit_code == 2
    assert "--siren-level" in res.output and problem in res.output
    assert not out.exists() or not any(out.iterdir())  # checked before anything is simulated


def test_library_checks_siren_levels() -> None:
    assert check_siren_level((105, 140)) == (105.0, 140.0)
    lo, hi = SIREN_LEVEL_BOUNDS_DB
    for bad in ((lo - 1, 120.0), (120.0, hi + 1), (125.0, 115.0), (120.0,), "loud"):
        with pytest.raises(ValueError, match="siren_level_db"):
            check_siren_level(bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="siren_level_db"):
        simulate_recording("crossing", 0.6, seed=1, noise="generated", siren="synth", siren_level_db=(90, 60))


def _distances(far_start: bool, n: int = 40) -> tuple[np.ndarray, list[dict[str, float]]]:
    ds, params = [], []
    for i in range(n):
        tr = make_tracks(AUDIO_SCENARIOS[i % 4], 8.0, np.random.default_rng(i), far_start=far_start)
        rec = Recording(np.zeros((8 * 100, 1), np.float32), 100, np.zeros((1, 3)), tr.ego, tr.evs)
        ds.append(label_recording(rec, max_distance_m=1e9).distance[:, 0])
        params += tr.params
    return np.concatenate(ds), params


def test_far_start_reaches_audible_range_and_keeps_other_draws() -> None:
    near, p_near = _distances(False)
    far, p_far = _distances(True)
    assert np.mean(near > 150) < 0.1 and np.mean(near < 50) > 0.4  # the default: mostly near
    assert np.mean((far > 150) & (far <= 300)) > 0.25 and np.mean(far > 100) > 0.5
    assert np.mean(far < 50) > 0.05  # still some near windows
    for a, b in zip(p_near, p_far, strict=True):
        assert a["scenario"] == b["scenario"]
        speed = "ev_speed_mps" if "ev_speed_mps" in a else "relative_speed_mps"
        assert a[speed] == b[speed]  # only the distances are stretched
        if a["scenario"] == "from_behind":
            lo, hi = FAR_START["from_behind_gap_m"]
            assert 30.0 <= a["gap0_m"] <= 140.0 and lo <= b["gap0_m"] <= hi
    rec = simulate_recording("from_behind", 0.6, seed=2, noise="generated", siren="synth", far_start=True)
    assert rec.meta["far_start"] is True


# ------------------------------------------------------------------------ uncertainty and combination


@pytest.fixture(scope="module")
def sigma_model(
    tmp_path_factory: pytest.TempPathFactory, short_train_recordings: Any
) -> tuple[Path, np.ndarray, dict]:
    """A narrow network with the distance uncertainty head, one epoch on two short recordings."""
    import torch

    from makeway.train.siren import SirenNet, TrainConfig, build_dataset, export_onnx, train_siren_net

    root = tmp_path_factory.mktemp("sigma")
    folders = short_train_recordings(root / "recs", ("same_direction", "crossing"), 60)
    feats = SirenFeatures()
    data = build_dataset(folders, feats, mirror=False)
    with pytest.raises(ValueError, match="log distance"):
        SirenNet(feats.shapes(), width=8, distance_sigma=True)
    cfg = TrainConfig(
        epochs=1, width=8, batch_size=4, threads=1, val_fraction=0.5, distance_loss="log", distance_sigma=True
    )
    torch.manual_seed(0)
    net, history = train_siren_net(data, feats.shapes(), cfg, n_azimuth=feats.config.n_azimuth)
    assert math.isfinite(history[0]["val_sigma_nll"])
    path = export_onnx(net, root / "sigma.onnx", feats.config)
    rec = read_recording(folders[0])
    w = window_batch(rec, label_recording(rec))
    with torch.no_grad():
        f = feats.transform(w)
        outs = net(*[torch.from_numpy(f[s]) for s in net.streams])
    return path, w, {"distance": outs[2].numpy(), "log_sigma": outs[4].numpy()}


def test_uncertainty_output_is_read_when_present(sigma_model: tuple[Path, np.ndarray, dict]) -> None:
    import onnx

    path, w, torch_out = sigma_model
    assert SIGMA_OUTPUT in [o.name for o in onnx.load(str(path)).graph.output]
    pred = SirenModel(path, threads=1).predict(w)
    assert pred.distance_sigma is not None and pred.distance_sigma.shape == (len(w),)
    np.testing.assert_allclose(pred.distance_sigma, np.exp(torch_out["log_sigma"]), rtol=1e-4)
    np.testing.assert_allclose(pred.distance, torch_out["distance"], rtol=1e-4)
    # older files have no such output: no σ, and everything else as before
    old = SirenModel(DEFAULT_SIREN_LOCALIZER, threads=1, localizer=False, ranger=False)
    assert old.predict(w[:2]).distance_sigma is None


def test_combination_rule(sigma_model: tuple[Path, np.ndarray, dict]) -> None:
    path, w, _ = sigma_model
    alone = {
        p: SirenModel(p, threads=1, localizer=False, ranger=False).predict(w)
        for p in (DEFAULT_SIREN_LOCALIZER, *DEFAULT_SIREN_RANGERS, path)
    }
    loc = alone[DEFAULT_SIREN_LOCALIZER]

    def gmean(*preds: SirenPrediction) -> np.ndarray:
        return np.exp(np.mean([np.log(p.distance) for p in preds], axis=0))

    # named rangers join the localizer's distance unless told otherwise; the σ comes from the one
    # member that has it, widened because the localizer has none
    both = SirenModel(threads=1, ranger=[path]).predict(w)
    np.testing.assert_allclose(both.distance, gmean(loc, alone[path]), rtol=1e-5)
    own_sigma = alone[path].distance_sigma
    assert both.distance_sigma is not None and own_sigma is not None
    np.testing.assert_allclose(both.distance_sigma, SIGMA_SCALE_UNRATED * own_sigma, rtol=1e-6)
    only = SirenModel(threads=1, ranger=[path], localizer_distance=False).predict(w)
    np.testing.assert_allclose(only.distance, alone[path].distance, rtol=1e-5)
    assert only.distance_sigma is not None  # every member rated: its own σ, not widened
    np.testing.assert_allclose(only.distance_sigma, own_sigma, rtol=1e-6)
    np.testing.assert_allclose(only.theta, loc.theta, atol=1e-6)  # bearing stays the localizer's
    # the shipped combination follows LOCALIZER_DISTANCE
    shipped = SirenModel(threads=1).predict(w)
    members = [alone[p] for p in DEFAULT_SIREN_RANGERS] + ([loc] if LOCALIZER_DISTANCE else [])
    np.testing.assert_allclose(shipped.distance, gmean(*members), rtol=1e-5)
    # σ of the combination: the RMS over the members that give one
    s1, s2 = np.array([0.2, 0.4]), np.array([0.4, 0.4])
    d, s = combine_distances(
        [
            SirenPrediction(np.zeros(2), np.zeros(2), np.array([10.0, 40.0]), None, s1),
            SirenPrediction(np.zeros(2), np.zeros(2), np.array([40.0, 10.0]), None, s2),
            SirenPrediction(np.zeros(2), np.zeros(2), np.array([20.0, 20.0]), None),
        ]
    )
    np.testing.assert_allclose(d, [20.0, 20.0])
    assert s is not None  # the third member has no σ: the RMS of the other two, widened
    np.testing.assert_allclose(s, SIGMA_SCALE_UNRATED * np.sqrt((s1**2 + s2**2) / 2))
    rated = [
        SirenPrediction(np.zeros(2), np.zeros(2), np.array(dd), None, sg)
        for dd, sg in (([10.0, 40.0], s1), ([40.0, 10.0], s2))
    ]
    d, s = combine_distances(rated)
    np.testing.assert_allclose(d, [20.0, 20.0])
    assert s is not None and SIGMA_SCALE_UNRATED > 1.0
    np.testing.assert_allclose(s, np.sqrt((s1**2 + s2**2) / 2))
    assert combine_distances([SirenPrediction(np.zeros(1), np.zeros(1), np.ones(1), None)])[1] is None


def test_cli_train_refuses_sigma_without_log_loss(tmp_path: Path) -> None:
    res = runner.invoke(
        audio_app,
        ["train", "--data", str(tmp_path), "--out", str(tmp_path / "m.onnx"), "--distance-sigma"],
    )
    assert res.exit_code == 2 and "--distance-sigma needs --distance-loss log" in res.output
    assert not (tmp_path / "m.onnx").exists()
