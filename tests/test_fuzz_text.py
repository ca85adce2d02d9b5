"""Fuzzing of makeway's text readers (issue 29, item 1): MOT files, YOLO label files, crop and light
label CSVs, path CSVs, the roadside points, pixels and pairs files, the rig's pixel files, the
track-label and holdout lists. Each generated file ends in a result or one ``InputError`` naming it
(:func:`fuzzing.check_reader`). Seeds are real files (the shared data, the shipped data) or files
written by makeway itself."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given

from fuzzing import budget, check_reader, file_contents
from makeway.apps.rig import read_pixel_rows as read_rig_pixels
from makeway.eval.actor_sweep import TRACK_LABELS, read_track_labels
from makeway.plan.path import load_path_csv
from makeway.roadside.calibrate import read_road_points
from makeway.roadside.locate import read_pixel_rows
from makeway.roadside.reference import read_pairs, write_pairs
from makeway.roadside.simulated import SIM_ORIGIN, sim_pairs
from makeway.sense.crops import EV_CROPS_HOLDOUT, read_crop_folder, read_holdout, read_yolo_set
from makeway.sense.motfile import read_mot
from makeway.train.light_labels import read_labels, read_yolo

SHIPPED = Path(EV_CROPS_HOLDOUT).parent


def _head(path: Path, n: int, *, keep_comments: int = 2) -> str:
    """The first ``n`` data lines of a text file, after at most ``keep_comments`` of its comment lines."""
    lines = path.read_text(encoding="utf-8").splitlines()
    comments = [ln for ln in lines if ln.startswith("#")][:keep_comments]
    data = [ln for ln in lines if not ln.startswith("#")][:n]
    return "\n".join(comments + data) + "\n"


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz_text")


def _write(folder: Path, name: str, data: bytes) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_bytes(data)
    return path


# ---------------------------------------------------------------------------------------------- MOT
def test_fuzz_mot(mot15_root: Path, work: Path) -> None:
    seed = _head(mot15_root / "TUD-Campus" / "gt" / "gt.txt", 30)

    @budget()
    @given(data=file_contents(seed), kind=...)
    # found by fuzzing: a frame or id past int64 was cast to garbage (and frame × id overflowed)
    @example(data=b"9223372036854775296,1,399,182,121,229,1\n", kind=True)
    @example(data=b"1,9223372036854775296,399,182,121,229,1\n", kind=True)
    @example(data=b"1,-1,399,182,121,229,1\n9007199254740992,9007199254740991,1,1,5,5,1\n", kind=True)
    # found by fuzzing through `makeway track`: y = 1.15e18 made the box's height 0 (ZeroDivisionError)
    @example(data=b"1,-1,281.9,1.152921504606847e+18,187.4,79.9,0.99\n", kind=False)
    @example(data=b"1,-1,281.9,10,1e-300,1e-300,0.99\n", kind=False)
    def run(data: bytes, kind: bool) -> None:
        path = _write(work / "mot", "gt.txt", data)
        got = check_reader(
            "MOT text", lambda: read_mot(path, kind="gt" if kind else "detection"), inside=path
        )
        if got is not None:
            assert np.isfinite(got.xywh).all() and (got.xywh[:, 2:] > 0).all() and (got.frames >= 1).all()

    run()


# --------------------------------------------------------------------------------------------- YOLO
def test_fuzz_yolo_labels_of_lights(work: Path) -> None:
    seed = "0 0.5 0.5 0.2 0.1\n1 0.25 0.75 0.1 0.05\n0 0.9 0.1 0.05 0.05\n"

    @budget()
    @given(data=file_contents(seed, sep=" "))
    @example(data=b"\x80")  # found by fuzzing: not UTF-8 raised UnicodeDecodeError
    def run(data: bytes) -> None:
        path = _write(work / "yolo_lights", "frame.txt", data)
        got = check_reader("YOLO text (light labels)", lambda: read_yolo(path, 640, 360), inside=path)
        for _cls, box, _vehicle in got or []:
            assert all(isinstance(v, int) for v in box)

    run()


def test_fuzz_yolo_set(data_root: Path, work: Path) -> None:
    valid = data_root / "vision" / "ambulance_yolo" / "valid"
    label = sorted((valid / "labels").iterdir())[0]
    image = valid / "images" / (label.stem + ".jpg")
    root = work / "yolo_set"
    _write(root / "images", image.name, image.read_bytes())
    seed = label.read_text(encoding="utf-8") + "0 0.5 0.5 0.25 0.25\n"

    @budget(0.5)
    @given(data=file_contents(seed, sep=" "))
    def run(data: bytes) -> None:
        _write(root / "labels", label.name, data)
        got = check_reader("YOLO text (detection set)", lambda: read_yolo_set(root), inside=root)
        for item in got or []:
            assert all(np.isfinite([b.x1, b.y1, b.x2, b.y2]).all() for b in item.boxes)

    run()


# --------------------------------------------------------------------------------------- crop CSVs
def test_fuzz_crop_labels(data_root: Path, work: Path) -> None:
    source = data_root / "vision" / "ev_crops"
    seed = _head(source / "labels.csv", 6)
    root = work / "crops"
    for line in seed.splitlines()[1:]:
        name = line.split(",")[0]
        _write(root / "images", name, (source / "images" / name).read_bytes())

    @budget()
    @given(data=file_contents(seed))
    # found by the long run: a name too long for the file system raised OSError; "/" or
    # "/etc/passwd" was looked up outside the folder
    @example(data=b"image,emergency\n" + b"1" * 400 + b",1\n")
    @example(data=b"image,emergency\n/,1\n")
    def run(data: bytes) -> None:
        _write(root, "labels.csv", data)
        got = check_reader("crop labels CSV", lambda: read_crop_folder(root), inside=root)
        if got is not None:
            assert len(got) > 0 and set(np.unique(got.labels)) <= {0, 1}

    run()


def test_fuzz_light_labels(work: Path) -> None:
    seed = _head(SHIPPED / "lights" / "night_ambulance_lights.csv", 12, keep_comments=3)

    @budget()
    @given(data=file_contents(seed))
    def run(data: bytes) -> None:
        path = _write(work / "light_labels", "labels.csv", data)
        check_reader("light label CSV", lambda: read_labels(path), inside=path)

    run()


def test_fuzz_track_labels(work: Path) -> None:
    seed = _head(TRACK_LABELS, 10, keep_comments=1)

    @budget()
    @given(data=file_contents(seed))
    @example(data=b"\x80")  # found by fuzzing: not UTF-8 raised UnicodeDecodeError
    def run(data: bytes) -> None:
        path = _write(work / "track_labels", "labels.csv", data)
        check_reader("track label CSV", lambda: read_track_labels(path), inside=path)

    run()


def test_fuzz_holdout(work: Path) -> None:
    seed = _head(EV_CROPS_HOLDOUT, 8, keep_comments=7)

    @budget()
    @given(data=file_contents(seed, sep=":"))
    def run(data: bytes) -> None:
        path = _write(work / "holdout", "holdout.txt", data)
        got = check_reader("holdout list", lambda: read_holdout(path), inside=path)
        if got is not None:
            assert len(got.names) > 0

    run()


# ---------------------------------------------------------------------------------------- path CSVs
def test_fuzz_path_csv(work: Path) -> None:
    t = np.linspace(0.0, 1.0, 12)
    rows = [f"{30 * a:.3f},{8 * np.sin(3 * a):.3f},{a:.2f}" for a in t]
    seed = "x,y,time\n" + "\n".join(rows) + "\n"

    @budget()
    @given(data=file_contents(seed))
    # found by fuzzing: huge coordinates overflowed the arc length, or gave NaN curvature
    @example(data=seed.replace("0.000,0.000", "8.98846567431158e+307,2.155", 1).encode())
    @example(data=seed.replace("0.000,0.000", "3.6028797018963936e+16,0.000", 1).encode())
    @example(data=b"x,y\n0,0\n1e-300,0\n2e-300,1e-300\n")
    @example(data=b"x,y\n0,0\r1,1\n2,0\n")  # a lone carriage return raised csv.Error
    def run(data: bytes) -> None:
        path = _write(work / "path", "path.csv", data)
        got = check_reader("path CSV", lambda: load_path_csv(path), inside=path)
        if got is not None:
            assert np.isfinite(got.s_m).all() and np.isfinite(got.curvature_1pm).all()

    run()


# -------------------------------------------------------------------------------- roadside CSV files
def test_fuzz_road_points(work: Path) -> None:
    seed = _head(SHIPPED / "intersection_cam_ambulance_points.csv", 14)

    @budget()
    @given(data=file_contents(seed))
    def run(data: bytes) -> None:
        path = _write(work / "points", "points.csv", data)
        check_reader("roadside points CSV", lambda: read_road_points(path), inside=path)

    run()


def test_fuzz_roadside_pixels(work: Path) -> None:
    seed = "u,v\n640,360\n100.5,700\n# a comment\n1279,0\n"
    boxes = "x1,y1,x2,y2\n10,20,110,220\n500,300,560,400\n"
    labelled = "x1,y1,x2,y2,class\n10,20,110,220,car\n500,300,560,400,truck\n"

    @budget()
    @given(data=file_contents(seed) | file_contents(boxes) | file_contents(labelled))
    def run(data: bytes) -> None:
        path = _write(work / "pixels", "pixels.csv", data)
        got = check_reader("roadside pixels CSV", lambda: read_pixel_rows(path), inside=path)
        if got is not None:
            assert np.isfinite(got[1]).all()

    run()


def test_fuzz_pairs(work: Path) -> None:
    pixels, xy = sim_pairs()
    seed_path = work / "pairs_seed.csv"
    write_pairs(seed_path, pixels[:14], xy[:14], SIM_ORIGIN)
    seed = seed_path.read_text(encoding="utf-8")

    @budget()
    @given(data=file_contents(seed))
    def run(data: bytes) -> None:
        path = _write(work / "pairs", "pairs.csv", data)
        check_reader("roadside pairs CSV", lambda: read_pairs(path), inside=path)

    run()


def test_fuzz_rig_pixels(work: Path) -> None:
    seed = "u,v,range_m\n640,360,12.5\n100,700\n# note\n1279.5,0.5,3\n"

    @budget()
    @given(data=file_contents(seed))
    def run(data: bytes) -> None:
        path = _write(work / "rig_pixels", "pixels.csv", data)
        check_reader("rig pixels CSV", lambda: read_rig_pixels(path), inside=path)

    run()


def test_the_harness_reports_hangs_and_stray_exceptions(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """The contract is checked, not assumed: a reader that hangs, raises another type, or refuses
    with an error naming another file fails the check."""
    import time

    import fuzzing

    monkeypatch.setattr(fuzzing, "HANG_S", 0.2)
    monkeypatch.setattr(fuzzing, "COUNTS", fuzzing.defaultdict(fuzzing.Counter))  # keep the real counts clean
    with pytest.raises(fuzzing.ReaderHung):
        check_reader("probe", lambda: time.sleep(3))
    with pytest.raises(KeyError):
        check_reader("probe", lambda: {}["x"])
    with pytest.raises(AssertionError, match="not one line"):
        check_reader("probe", lambda: (_ for _ in ()).throw(ValueError("a\nb")), allowed=(ValueError,))
    with pytest.raises(AssertionError):
        check_reader("probe", lambda: read_mot(tmp_path / "elsewhere.txt"), inside=tmp_path / "mine.txt")
    assert (
        check_reader("probe", lambda: read_mot(tmp_path / "gone.txt"), inside=tmp_path / "gone.txt") is None
    )
    assert fuzzing.COUNTS["probe"] == {"inputs": 5, "uncaught": 4, "rejected": 1}
