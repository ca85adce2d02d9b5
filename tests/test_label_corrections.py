"""The committed ``ambulance_yolo`` label corrections: the file parses and fits the real photos,
malformed rows are refused in one line naming the file and the row, and applying the file changes
exactly the listed crops and ground-truth boxes (real photos, real YOLOX-nano)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from conftest import yolo_subset
from makeway.apps.classify import build_ambulance_crops
from makeway.cli.main import app
from makeway.errors import InputError
from makeway.sense.crops import read_yolo_set
from makeway.sense.label_corrections import (
    CORRECTIONS_FILE,
    KINDS,
    LABELS,
    MATCH_IOU,
    check_label_set,
    corrected_boxes,
    corrections_by_image,
    read_corrections,
)

runner = CliRunner()
HEADER = "image,x1,y1,x2,y2,was,label,kind,note"
GOOD = "0005_jpg.rf.44faa3143231e53a063975b070d866f0,373.1,391.9,543.0,559.6,unlabelled,ev,ambulance,van"


def _labels(folder: Path) -> dict[str, int]:
    with (folder / "labels.csv").open(newline="") as f:
        return {r["image"]: int(r["emergency"]) for r in csv.DictReader(f)}


def test_committed_file_parses_and_fits_the_photos(ambulance_dir: Path) -> None:
    rows = read_corrections(CORRECTIONS_FILE)
    assert len(rows) == 52
    assert {r.label for r in rows} <= set(LABELS) and {r.kind for r in rows} <= set(KINDS)
    # the audit found no labelled box that is not an EV: ev and drop rows only
    assert sum(r.label == "ev" for r in rows) == 39 and sum(r.label == "drop" for r in rows) == 13
    photos = {im.path.stem: im for im in read_yolo_set(ambulance_dir)}
    for r in rows:
        im = photos[r.image]  # every row names a photo of the set
        assert 0 <= r.box.x1 < r.box.x2 <= im.width and 0 <= r.box.y1 < r.box.y2 <= im.height, r.row
        # an "ev" row of an unlabelled EV does not repeat a labelled box; "labelled" rows do match one
        best = max((r.box.iou(b) for b in im.boxes_of(0)), default=0.0)
        assert (best >= MATCH_IOU) == (r.was == "labelled"), r.row


@pytest.mark.parametrize(
    ("line", "says"),
    [
        (GOOD + ",extra", "10 fields"),
        (GOOD.replace("373.1", "left"), "x1 must be a number"),
        (GOOD.replace("373.1", "nan"), "finite"),
        (GOOD.replace("543.0", "300.0"), "no area"),
        (GOOD.replace(",ev,", ",maybe,"), "label must be one of ev, not_ev, drop"),
        (GOOD.replace(",ambulance,", ",tank,"), "kind must be one of"),
        (GOOD.replace(",unlabelled,", ",perhaps,"), "was must be labelled or unlabelled"),
        (GOOD.replace("0005_jpg.rf.44faa3143231e53a063975b070d866f0", " "), "empty image name"),
        (GOOD, "twice"),
    ],
)
def test_a_malformed_row_is_refused_in_one_line(tmp_path: Path, line: str, says: str) -> None:
    path = tmp_path / "fix.csv"
    path.write_text(f"# a comment\n{HEADER}\n{GOOD}\n{line}\n", encoding="utf-8")
    with pytest.raises(InputError) as err:
        read_corrections(path)
    message = str(err.value)
    assert str(path) in message and "row 4" in message and says in message
    assert len(message.splitlines()) == 1


def test_a_missing_column_or_file_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "fix.csv"
    path.write_text("image,x1,y1,x2,y2,label\n", encoding="utf-8")
    with pytest.raises(InputError, match="missing column"):
        read_corrections(path)
    with pytest.raises(InputError, match="not found"):
        read_corrections(tmp_path / "none.csv")
    with pytest.raises(ValueError, match="original, corrected"):
        check_label_set("fixed")


def test_applying_changes_exactly_the_listed_crops(ambulance_dir: Path, tmp_path: Path) -> None:
    rows = read_corrections()
    by_image = corrections_by_image(rows)
    plain = ["0009_jpg.rf.57b34231535de22443800ce18496f706", "0022_jpg.rf.cb893467345630b42489d08eb5623329"]
    folder = yolo_subset(ambulance_dir, tmp_path / "set", sorted(by_image) + plain)
    before = build_ambulance_crops(tmp_path / "orig", folder, progress=False, labels="original")
    after = build_ambulance_crops(tmp_path / "corr", folder, progress=False, labels="corrected")
    old, new = _labels(tmp_path / "orig"), _labels(tmp_path / "corr")
    changed = {k for k in old.keys() | new.keys() if old.get(k) != new.get(k)}
    assert len(changed) == len(rows) == after["corrected"] and before["corrected"] == 0
    # each change belongs to a row of its photo and goes the row's way
    per_image: dict[str, list[str]] = {}
    for name in changed:
        stem = name.rsplit("_", 1)[0]
        per_image.setdefault(stem, []).append(name)
    assert {s: len(v) for s, v in per_image.items()} == {s: len(v) for s, v in by_image.items()}
    for stem, names in per_image.items():
        want = sorted(r.label for r in by_image[stem])
        got = sorted("drop" if n not in new else ("ev" if new[n] == 1 else "not_ev") for n in names)
        assert got == want, stem
        assert all(old.get(n) != 1 or n not in new for n in names)  # no positive was made negative
    assert not any(name.startswith(tuple(plain)) for name in changed)
    n_ev = sum(r.label == "ev" for r in rows)
    assert after["positive"] == before["positive"] + n_ev - 1  # one labelled box dropped
    assert after["crops"] == before["crops"] + 9 - 13  # 9 EVs without a crop added, 13 crops dropped


def test_held_out_ground_truth_gains_the_unlabelled_evs(ambulance_dir: Path) -> None:
    from makeway.apps.evaluate_detector import select_split

    by_image = corrections_by_image(read_corrections())
    held = select_split(read_yolo_set(ambulance_dir), "held_out", ambulance_dir)
    old = sum(len(im.boxes_of(0)) for im in held)
    new = [corrected_boxes(im.boxes_of(0), by_image.get(im.path.stem, [])) for im in held]
    assert (old, sum(len(b) for b in new)) == (161, 175)
    for im, boxes in zip(held, new, strict=True):
        assert boxes[: len(im.boxes_of(0))] == im.boxes_of(0)  # labelled boxes kept, in order


def test_evaluate_detector_reports_the_label_set(ambulance_dir: Path, tmp_path: Path) -> None:
    stems = [
        "0229_jpg.rf.c4d6ba6dc91c69092a78a3dbce174dfd",  # a fire engine beside a labelled ambulance
        "0009_jpg.rf.57b34231535de22443800ce18496f706",  # no correction
    ]
    folder = yolo_subset(ambulance_dir, tmp_path / "set", stems)
    out = {}
    for labels in ("original", "corrected"):
        r = runner.invoke(
            app, ["evaluate-detector", "--data", str(folder), "--framework", "a", "--labels", labels]
        )
        assert r.exit_code == 0, r.output
        out[labels] = json.loads(r.stdout.strip().splitlines()[-1])
        assert out[labels]["labels"] == labels
    assert out["corrected"]["n_boxes"] == out["original"]["n_boxes"] + 1
    assert (out["original"]["boxes_corrected"], out["corrected"]["boxes_corrected"]) == (0, 1)
    r = runner.invoke(app, ["evaluate-detector", "--data", str(folder), "--labels", "fixed"])
    assert r.exit_code == 2 and "original, corrected" in r.stderr and len(r.stderr.strip().splitlines()) == 1
