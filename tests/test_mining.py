"""Data engine: ``makeway classify mine`` over a real unlabelled crop pool (issue 3, seed 000 §3.3.2)."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from makeway.cli.main import app
from makeway.errors import InputError
from makeway.perceive.vision.ev_classifier import DEFAULT_MODEL, load_crop_classifier
from makeway.sense.crops import read_crop_folder
from makeway.train.mining import list_pool, mine


@pytest.fixture(scope="module")
def pool(data_root: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """24 real unlabelled crops (some in a subfolder), a corrupt JPEG, a text file and a hidden file."""
    src = sorted((data_root / "vision" / "ev_crops" / "unlabelled").glob("*.jpg"))[:24]
    root = tmp_path_factory.mktemp("pool")
    (root / "sub").mkdir()
    for i, p in enumerate(src):
        shutil.copy(p, root / ("sub" if i % 3 == 0 else "") / p.name)
    (root / "broken.jpg").write_bytes(b"\xff\xd8\xff\xe0 not really a jpeg")
    (root / "notes.txt").write_text("hello")
    (root / ".DS_Store").write_bytes(b"\0")
    return root


def test_mine_library(pool: Path, tmp_path: Path) -> None:
    clf = load_crop_classifier(DEFAULT_MODEL)
    res = mine(pool, clf, tmp_path / "out", top=10, threshold=0.3, progress=False)
    assert len(list_pool(pool)) == 26  # hidden file skipped
    assert len(res.paths) == 24 and sorted(p.name for p in res.unreadable) == ["broken.jpg", "notes.txt"]
    with (tmp_path / "out" / "candidates.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    probs = [float(r["probability"]) for r in rows]
    assert list(rows[0]) == ["rank", "image", "probability", "emergency"]
    assert probs == sorted(probs, reverse=True) and all(p >= 0.3 for p in probs)
    assert len(rows) == int(np.sum(res.probabilities >= 0.3)) > 0
    assert [int(r["rank"]) for r in rows] == list(range(1, len(rows) + 1))
    assert all(r["emergency"] == "" for r in rows)
    assert any(r["image"].startswith("sub/") for r in rows) or not any(
        p.parent.name == "sub" and q >= 0.3 for p, q in zip(res.paths, res.probabilities, strict=True)
    )
    sheet = cv2.imread(str(tmp_path / "out" / "contact_sheet.png"))
    n_cells = min(10, len(rows))
    assert sheet is not None and sheet.shape[0] % 128 == 0 and sheet.shape[1] == 128 * min(8, n_cells)
    # the template, once filled, is a valid crop folder
    with (tmp_path / "out" / "labels_template.csv").open() as fh:
        template = list(csv.reader(fh))
    assert template[0] == ["image", "emergency"] and [t[0] for t in template[1:]] == [
        r["image"] for r in rows
    ]
    folder = tmp_path / "reviewed"
    (folder / "images").mkdir(parents=True)
    lines = ["image,emergency"]
    for name, _ in template[1:]:
        flat = name.replace("/", "_")
        shutil.copy(pool / name, folder / "images" / flat)
        lines.append(f"{flat},1")
    (folder / "labels.csv").write_text("\n".join(lines) + "\n")
    assert len(read_crop_folder(folder)) == len(rows)


def test_mine_cli(pool: Path, tmp_path: Path) -> None:
    out = tmp_path / "cli"
    res = CliRunner().invoke(app, ["classify", "mine", str(pool), "--out", str(out), "--top", "4", "-q"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.output.strip().splitlines()[-1])
    assert summary["files"] == 26 and summary["scored"] == 24 and summary["unreadable"] == 2
    assert summary["threshold"] == 0.5
    assert "skipped 2 file(s)" in res.output
    assert {Path(p).name for p in summary["outputs"].values()} == {
        "candidates.csv",
        "contact_sheet.png",
        "labels_template.csv",
    }
    res = CliRunner().invoke(app, ["classify", "mine", str(tmp_path / "nowhere"), "--out", str(out)])
    assert res.exit_code == 2 and "pool folder not found" in res.output


def test_load_crop_classifier_rejects_unknown(tmp_path: Path) -> None:
    p = tmp_path / "model.pkl"
    p.write_bytes(b"x")
    with pytest.raises(InputError, match="unknown crop classifier format"):
        load_crop_classifier(p)
