"""PR curve (``pr_curve``, ``plot_pr_curve``, ``makeway classify eval --plot``) on real held-out crops."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from makeway.cli.main import app
from makeway.eval.classification import pr_curve, threshold_metrics
from makeway.viz.pr_plot import plot_pr_curve


def test_pr_curve_agrees_with_threshold_metrics() -> None:
    rng = np.random.default_rng(0)
    y = rng.random(300) < 0.4
    s = np.round(np.where(y, rng.normal(0.65, 0.2, 300), rng.normal(0.4, 0.2, 300)), 2)  # with ties
    c = pr_curve(s, y)
    assert np.all(np.diff(c["threshold"]) < 0) and np.all(np.diff(c["recall"]) >= 0)
    assert c["recall"][-1] == 1.0 and c["precision"][-1] == pytest.approx(y.mean())
    f1 = 2 * c["precision"] * c["recall"] / (c["precision"] + c["recall"])
    m = threshold_metrics(s, y)
    assert f1.max() == pytest.approx(m["max_f1"])
    assert c["precision"][c["recall"] >= 0.8].max() == pytest.approx(m["precision_at_recall_0.8"])
    assert pr_curve(s, np.zeros(300))["recall"].size == 0


def test_plot_pr_curve(tmp_path: Path) -> None:
    y = np.array([1, 0, 1, 1, 0, 0, 1, 0])
    s = np.array([0.9, 0.8, 0.7, 0.6, 0.4, 0.3, 0.2, 0.1])
    out = plot_pr_curve(s, y, tmp_path / "pr.png", threshold=0.5)
    image = cv2.imread(str(out))
    assert image is not None and image.shape[0] > 300 and image.shape[1] > 300
    with pytest.raises(ValueError, match="positive"):
        plot_pr_curve(s, np.zeros(8), tmp_path / "none.png")
    assert not (tmp_path / "none.png").exists()


def test_eval_cli_writes_plot(data_root: Path, tmp_path: Path) -> None:
    plot = tmp_path / "ev_pr.png"
    data = data_root / "vision" / "ev_crops"
    res = CliRunner().invoke(app, ["classify", "eval", "--data", str(data), "--plot", str(plot)])
    assert res.exit_code == 0, res.output
    metrics = json.loads(res.output.strip().splitlines()[-1])
    assert metrics["n"] == 250 and metrics["max_f1"] > 0.7
    assert cv2.imread(str(plot)) is not None
