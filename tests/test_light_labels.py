"""Lit-light labelling tool: proposals on drawn frames with known lights, the label reader's refusals
(one line naming file:line), and the YOLO + test_id export read back to the same boxes."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from makeway.errors import InputError
from makeway.perceive.vision.light_colour import Proposal, ProposalConfig, flash_score, lit_maps, propose
from makeway.train.light_labels import (
    LabelRow,
    export_yolo,
    image_name,
    link_tracklets,
    read_labels,
    read_yolo,
    write_labels,
)

W, H = 320, 240


def _iou(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> float:
    ix = max(0, min(a[2], b[2]) - max(a[0], b[0]))
    iy = max(0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = ix * iy
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


def _night() -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.integers(5, 30, (H, W, 3)).astype(np.uint8)  # dark, grey noise


def _lamp(img: np.ndarray, box: tuple[int, int, int, int], bgr: tuple[int, int, int], core: bool) -> None:
    """A lit bulb: a saturated rectangle of the colour, optionally with a clipped white centre."""
    x1, y1, x2, y2 = box
    img[y1:y2, x1:x2] = bgr
    if core:
        img[y1 + 3 : y2 - 3, x1 + 3 : x2 - 3] = (255, 255, 255)


def test_proposals_find_drawn_lights_with_their_colours() -> None:
    img = _night()
    blue, red = (40, 60, 60, 74), (200, 100, 216, 114)
    _lamp(img, blue, (255, 40, 20), core=True)  # BGR blue with a white core
    _lamp(img, red, (20, 20, 255), core=False)
    cv2.rectangle(img, (120, 150), (150, 170), (230, 230, 230), -1)  # a white headlight: not proposed
    props = propose(img, ProposalConfig())
    assert len(props) == 2
    by_colour = {p.colour: p for p in props}
    assert _iou(by_colour["blue"].box, blue) > 0.9 and "core" in by_colour["blue"].cues
    assert _iou(by_colour["red"].box, red) > 0.9 and "core" not in by_colour["red"].cues


def test_adjacent_bulbs_in_one_glow_are_one_box_and_separate_ones_two() -> None:
    img = _night()
    _lamp(img, (40, 60, 60, 72), (255, 40, 20), core=False)
    _lamp(img, (62, 60, 82, 72), (255, 40, 20), core=False)  # 2 px gap: one glow
    _lamp(img, (200, 60, 220, 72), (255, 40, 20), core=False)  # far away: its own box
    boxes = sorted(p.box for p in propose(img, ProposalConfig(merge_px=3)))
    assert boxes == [(40, 60, 82, 72), (200, 60, 220, 72)]


def test_a_bright_core_in_a_large_bloom_is_boxed_by_itself() -> None:
    # a blue light at night: its bloom (80x60 px, 6 % of the frame) is too large to be a light box,
    # but the clipped white core inside it is the lit part and is proposed alone
    img = _night()
    img[80:140, 100:180] = (255, 60, 30)
    img[107:113, 135:145] = (255, 255, 255)
    props = propose(img, ProposalConfig())
    assert [(p.box, p.colour, p.cues) for p in props] == [((135, 107, 145, 113), "blue", ("core",))]


def test_tiny_and_huge_coloured_regions_are_not_lights() -> None:
    img = _night()
    img[10:12, 10:12] = (255, 40, 20)  # 4 px speck
    img[100:240, 0:320] = (20, 20, 255)  # a red wall covering 58 % of the frame
    assert propose(img, ProposalConfig()) == []


def test_flash_counts_on_off_changes_and_not_a_steady_light() -> None:
    cfg = ProposalConfig()
    lit, dark = _night(), _night()
    box = (80, 80, 104, 96)
    _lamp(lit, box, (255, 40, 20), core=False)
    steady = [lit] * 8
    flashing = [lit, lit, dark, dark, lit, lit, dark, dark]  # 3 changes
    p = Proposal(0, *box, "blue", 1.0, ("colour",))
    blue = cfg.colours.index("blue")
    assert flash_score([lit_maps(f, cfg) for f in steady], p, blue) == 0
    assert flash_score([lit_maps(f, cfg) for f in flashing], p, blue) == 3


def _write(tmp: Path, body: str, width: int = 640, height: int = 360) -> Path:
    path = tmp / "labels.csv"
    path.write_text(
        f"# source: clip.mp4\n# width: {width}\n# height: {height}\n"
        "frame,checked,kind,x1,y1,x2,y2,colour,vehicle,note\n" + body,
        encoding="utf-8",
    )
    return path


@pytest.mark.parametrize(
    ("body", "line", "words"),
    [
        ("3,1,light,10,10,20,20,purple,0,\n", 5, "unknown colour 'purple'"),
        ("3,1,light,10,10,700,20,blue,0,\n", 5, "outside the 640x360 image"),
        ("3,1,light,10,10,20,20,blue,0,\n3,1,light,10,10,20\n", 6, "expected 10 fields"),
        ("3,1,light,10,10,20,20,blue,0,\n4,0,light,30,10,20,20,blue,1,\n", 6, "empty or outside"),
        ("3,1,light,10,10,20,20,blue,,\n", 5, "vehicle id"),
        ("3,yes,frame,,,,,,,\n", 5, "checked must be 0 or 1"),
        ("3,1,light,10,10,20,20,blue,0,\n3,0,light,30,10,40,20,red,0,\n", 6, "checked on line 5"),
        ("x,1,frame,,,,,,,\n", 5, "frame index"),
        ("3,1,light,1.5,10,20,20,blue,0,\n", 5, "must be integers"),
    ],
)
def test_reader_names_file_line_and_problem(tmp_path: Path, body: str, line: int, words: str) -> None:
    path = _write(tmp_path, body)
    with pytest.raises(InputError) as err:
        read_labels(path)
    message = str(err.value)
    assert message.startswith(f"{path}:{line}: ") and words in message and "\n" not in message


def test_reader_needs_the_image_size(tmp_path: Path) -> None:
    path = tmp_path / "l.csv"
    path.write_text("# source: c.mp4\nframe,checked,kind,x1,y1,x2,y2,colour,vehicle,note\n", encoding="utf-8")
    with pytest.raises(InputError, match=r"l\.csv:2: missing '# width"):
        read_labels(path)


def test_yolo_export_round_trip_keeps_boxes_colours_and_vehicles(tmp_path: Path) -> None:
    rows = [
        LabelRow("7", True, "light", (101, 50, 133, 66), "blue", 0),
        LabelRow("7", True, "light", (140, 52, 170, 66), "red", 0),
        LabelRow("7", True, "light", (600, 300, 640, 360), "blue", 1),  # touches the bottom-right edge
        LabelRow("7", True, "negative", (10, 300, 30, 310), "red", None, "tail light"),
        LabelRow("8", True, "frame", None, "", None),
        LabelRow("9", False, "light", (5, 5, 15, 15), "amber", 2),  # unchecked: not exported
    ]
    write_labels(tmp_path / "c.csv", "clip.mp4", 640, 360, rows)
    labels = read_labels(tmp_path / "c.csv")
    assert labels.counts()["positive_frames"] == 1 and labels.counts()["negative_frames"] == 1
    counts = export_yolo([labels], tmp_path / "yolo")
    assert counts == {"images": 2, "boxes": 3}
    name = image_name("clip.mp4", "7")
    assert name == "clip_000007"
    back = read_yolo(
        tmp_path / "yolo/labels" / f"{name}.txt", 640, 360, tmp_path / "yolo/test_id" / f"{name}.txt"
    )
    assert back == [(0, (101, 50, 133, 66), 0), (1, (140, 52, 170, 66), 0), (0, (600, 300, 640, 360), 1)]
    assert (tmp_path / "yolo/labels/clip_000008.txt").read_text() == ""  # a negative image
    assert not (tmp_path / "yolo/labels/clip_000009.txt").exists()


LABELS = Path(__file__).resolve().parents[1] / "src" / "makeway" / "data" / "lights"


def test_shipped_label_files_read_and_keep_the_rules() -> None:
    """The committed labels pass the reader, and what they say is consistent with their sources: the
    no-EV clips have no light at all, and the night clip's lights are blue or red, on checked frames
    with a vehicle id (docs/data_card_lights.md)."""
    files = {p.stem: read_labels(p) for p in sorted(LABELS.glob("*.csv"))}
    assert {"night_ambulance_lights", "traffic_no_ev", "highway_cam_no_ev", "fire_trucks_red_lights"} <= set(
        files
    )
    for stem in ("traffic_no_ev", "highway_cam_no_ev"):
        counts = files[stem].counts()
        assert counts["boxes"] == 0 and counts["checked_frames"] == counts["frames"] >= 60
    night = files["night_ambulance_lights"]
    assert (night.width, night.height) == (1280, 720)
    lights = [r for r in night.rows if r.kind == "light" and r.checked]
    assert len(lights) >= 150 and {"blue", "red"} <= {r.colour for r in lights}
    assert all(r.vehicle is not None and r.vehicle >= 1 for r in lights)
    fire = files["fire_trucks_red_lights"]
    assert (fire.width, fire.height) == (640, 352)
    fire_lights = [r for r in fire.rows if r.kind == "light" and r.checked]
    assert len(fire_lights) >= 100 and {"blue", "red"} <= {r.colour for r in fire_lights}
    assert {1, 2} <= {r.vehicle for r in fire_lights}  # the fire truck and the ambulance
    for labels in files.values():  # every checked light of every clip has a vehicle id
        assert all(
            r.vehicle is not None and r.vehicle >= 1 for r in labels.rows if r.kind == "light" and r.checked
        )


def test_wide_hue_preset_proposes_magenta_as_red_and_orange_glow_as_amber() -> None:
    """A lit pink lamp (OpenCV hue 155) falls between the default red and blue ranges and is red under
    ``wide``; an orange glow (hue 12) is past the default red range (0-7) and is amber under ``wide``
    with amber proposed. Default settings propose neither."""
    from makeway.perceive.vision.light_colour import HSV_PRESETS, ProposalConfig, propose

    frame = np.zeros((120, 200, 3), np.uint8)
    hsv = np.zeros((20, 20, 3), np.uint8)
    hsv[...] = (155, 200, 230)
    frame[20:40, 20:40] = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)
    hsv[...] = (12, 200, 230)
    frame[60:80, 120:140] = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)
    default = propose(frame, ProposalConfig())
    wide = propose(frame, ProposalConfig(colours=("blue", "red", "amber"), hsv=dict(HSV_PRESETS["wide"])))
    assert default == []
    assert [(p.box, p.colour) for p in wide] == [((20, 20, 40, 40), "red"), ((120, 60, 140, 80), "amber")]


def test_cli_check_reports_a_bad_row_in_one_line(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from makeway.cli.main import app

    path = _write(tmp_path, "3,1,light,10,10,20,20,green,0,\n")
    result = CliRunner().invoke(app, ["light-labels", "check", str(path)], terminal_width=200)
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and f"{path}:5" in lines[0] and "unknown colour 'green'" in lines[0]


def test_cli_export_writes_yolo_and_test_id(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from makeway.cli.main import app

    night = LABELS / "night_ambulance_lights.csv"
    result = CliRunner().invoke(app, ["light-labels", "export", str(night), "-o", str(tmp_path / "y")])
    assert result.exit_code == 0, result.output
    counts = read_labels(night).counts()
    names = sorted(p.name for p in (tmp_path / "y" / "labels").glob("*.txt"))
    assert len(names) == counts["checked_frames"]
    assert sorted(p.name for p in (tmp_path / "y" / "test_id").glob("*.txt")) == names
    boxes = sum(len(p.read_text().splitlines()) for p in (tmp_path / "y" / "labels").glob("*.txt"))
    assert boxes == counts["boxes"]


def test_tracklets_link_a_moving_light_across_a_gap_and_keep_colours_apart(tmp_path: Path) -> None:
    rows = []
    for f in (0, 2, 4, 8):  # frame 6 missing: the light is off in a flash gap
        rows.append(LabelRow(str(f), False, "light", (100 + 5 * f, 50, 110 + 5 * f, 58), "blue", 0))
        rows.append(LabelRow(str(f), False, "light", (112 + 5 * f, 50, 122 + 5 * f, 58), "red", 0))
    rows.append(LabelRow("4", False, "light", (500, 300, 510, 310), "blue", 0))  # a one-frame reflection
    rows.append(LabelRow("20", False, "light", (160, 50, 170, 58), "blue", 0))  # too late to join
    write_labels(tmp_path / "t.csv", "clip.mp4", 640, 360, rows)
    tracks = link_tracklets(read_labels(tmp_path / "t.csv"), max_gap=6)
    assert tracks == [
        [("0", 0), ("2", 0), ("4", 0), ("8", 0)],
        [("0", 1), ("2", 1), ("4", 1), ("8", 1)],
        [("4", 2)],
        [("20", 0)],
    ]


def test_label_frames_decode_the_labelled_frames_of_a_clip(data_root: Path) -> None:
    from makeway.train.light_labels import iter_label_frames

    lab = read_labels(LABELS / "night_ambulance_lights.csv")
    got = list(iter_label_frames(lab, data_root, keys=["0", "4", "10"]))
    assert [k for k, _ in got] == ["0", "4", "10"]
    assert all(img.shape == (lab.height, lab.width, 3) for _, img in got)
    assert not np.array_equal(got[0][1], got[2][1])


def test_label_frames_name_a_missing_image(tmp_path: Path) -> None:
    from makeway.train.light_labels import LabelFile, iter_label_frames

    (tmp_path / "vision" / "set").mkdir(parents=True)
    lab = LabelFile(tmp_path / "x.csv", "set", 0, 0, [LabelRow("a.jpg", True, "frame", None, "", None)])
    with pytest.raises(InputError, match=r"a\.jpg"):
        list(iter_label_frames(lab, tmp_path))


# ------------------------------------------------------------------------------------------ image folders
YOLO_VALID = "ambulance_yolo/valid/images"


def _folder_of_two_sizes(root: Path) -> Path:
    """``root/vision/set`` with a 200×100 and a 80×120 image (black, one lit blue square each)."""
    folder = root / "vision" / "set"
    folder.mkdir(parents=True)
    wide = np.zeros((100, 200, 3), np.uint8)
    wide[40:52, 150:170] = (255, 80, 0)
    tall = np.zeros((120, 80, 3), np.uint8)
    tall[10:22, 10:30] = (255, 80, 0)
    cv2.imwrite(str(folder / "wide.png"), wide)
    cv2.imwrite(str(folder / "tall.png"), tall)
    return folder


def test_per_image_size_reads_and_rejects_negative_boxes(tmp_path: Path) -> None:
    head = "# source: set\n# width: 0\n# height: 0\nframe,checked,kind,x1,y1,x2,y2,colour,vehicle,note\n"
    good = tmp_path / "good.csv"
    good.write_text(head + "a.png,1,light,900,10,920,20,blue,1,\n", encoding="utf-8")
    lab = read_labels(good)
    assert lab.per_image and lab.rows[0].box == (900, 10, 920, 20)  # checked against the image later
    for n, row in enumerate(("a.png,1,light,-1,10,20,20,blue,1,\n", "a.png,1,light,30,10,20,20,blue,1,\n")):
        bad = tmp_path / f"bad{n}.csv"
        bad.write_text(head + row, encoding="utf-8")
        with pytest.raises(InputError, match=rf"bad{n}\.csv:5: .*empty or negative"):
            read_labels(bad)
    half = tmp_path / "half.csv"
    half.write_text(head.replace("# height: 0", "# height: 360"), encoding="utf-8")
    with pytest.raises(InputError, match="both 0"):
        read_labels(half)


def test_label_frames_check_boxes_against_each_image(tmp_path: Path) -> None:
    from makeway.train.light_labels import iter_label_frames

    _folder_of_two_sizes(tmp_path)
    rows = [
        LabelRow("wide.png", True, "light", (150, 40, 170, 52), "blue", 1),
        LabelRow("tall.png", True, "light", (10, 10, 90, 22), "blue", 2),  # 90 > 80: outside
    ]
    write_labels(tmp_path / "l.csv", "set", 0, 0, rows)
    lab = read_labels(tmp_path / "l.csv")
    got = iter_label_frames(lab, tmp_path, keys=["wide.png"])
    assert [(k, img.shape) for k, img in got] == [("wide.png", (100, 200, 3))]
    with pytest.raises(InputError) as err:
        list(iter_label_frames(lab, tmp_path))
    message = str(err.value)
    assert message.startswith(f"{tmp_path / 'l.csv'}:6: frame tall.png: ") and "80x120" in message
    from makeway.train.light_labels import LabelFile

    empty = LabelFile(tmp_path / "e.csv", "set", 0, 0, [])
    every = [k for k, _ in iter_label_frames(empty, None, source=tmp_path / "vision" / "set", every=True)]
    assert every == ["tall.png", "wide.png"]


def test_export_normalises_each_image_by_its_own_size(tmp_path: Path) -> None:
    _folder_of_two_sizes(tmp_path)
    rows = [
        LabelRow("wide.png", True, "light", (150, 40, 170, 52), "blue", 1),
        LabelRow("tall.png", True, "light", (10, 10, 30, 22), "blue", 2),
    ]
    write_labels(tmp_path / "l.csv", "set", 0, 0, rows)
    lab = read_labels(tmp_path / "l.csv")
    with pytest.raises(InputError, match="data root"):
        export_yolo([lab], tmp_path / "y")
    assert not (tmp_path / "y").exists()  # nothing half-written
    assert export_yolo([lab], tmp_path / "y", data_root=tmp_path) == {"images": 2, "boxes": 2}
    assert (tmp_path / "y/labels/wide.txt").read_text() == "0 0.800000 0.460000 0.100000 0.120000\n"
    assert (tmp_path / "y/labels/tall.txt").read_text() == "0 0.250000 0.133333 0.250000 0.100000\n"
    assert read_yolo(tmp_path / "y/labels/tall.txt", 80, 120) == [(0, (10, 10, 30, 22), None)]


def test_cli_proposes_and_draws_sheets_on_an_image_folder(data_root: Path, tmp_path: Path) -> None:
    """`propose` on the real ambulance_yolo folder limited to three names writes a per-image file
    whose source is the folder under vision/; `sheets` draws those images; `export` writes them."""
    from typer.testing import CliRunner

    from makeway.cli.main import app

    folder = data_root / "vision" / YOLO_VALID
    names = sorted(p.name for p in folder.glob("*.jpg"))[:3]
    (tmp_path / "names.txt").write_text("# three\n" + "\n".join(names) + "\n", encoding="utf-8")
    out = tmp_path / "p.csv"
    args = ["light-labels", "propose", str(folder), str(out), "--names", str(tmp_path / "names.txt")]
    result = CliRunner().invoke(app, [*args, "--colours", "blue,red,amber", "--hue", "wide"])
    assert result.exit_code == 0, result.output
    lab = read_labels(out)
    assert (lab.source, lab.width, lab.height) == (YOLO_VALID, 0, 0)
    assert list(lab.frames()) == names and not any(r.checked for r in lab.rows)
    result = CliRunner().invoke(
        app, ["light-labels", "sheets", str(folder), str(out), str(tmp_path / "s"), "--tile", "320x240"]
    )
    assert result.exit_code == 0, result.output
    sheet = cv2.imread(str(tmp_path / "s" / "sheet_000.png"))
    assert sheet.shape == (3 * 240, 2 * 320, 3)
    checked = [
        LabelRow(r.frame, True, r.kind, r.box, r.colour, 1 if r.kind == "light" else None) for r in lab.rows
    ]
    write_labels(out, lab.source, 0, 0, checked)
    result = CliRunner().invoke(app, ["light-labels", "export", str(out), "-o", str(tmp_path / "y")])
    assert result.exit_code == 0, result.output
    assert sorted(p.stem for p in (tmp_path / "y/labels").glob("*.txt")) == sorted(
        Path(n).stem for n in names
    )


def test_ambulance_yolo_labels_cover_the_folder_and_fit_their_images(data_root: Path) -> None:
    """The shipped ambulance_yolo/valid labels: one row group per image of the folder, per-image sizes,
    and every box of a checked positive image inside that image (docs/data_card_lights.md)."""
    from makeway.train.light_labels import folder_images, iter_label_frames

    lab = read_labels(LABELS / "ambulance_yolo.csv")
    assert (lab.source, lab.per_image) == (YOLO_VALID, True)
    assert set(lab.frames()) == set(folder_images(data_root / "vision" / YOLO_VALID))
    counts = lab.counts()
    assert counts["positive_frames"] >= 50 and counts["negative_frames"] >= 300
    positive = [k for k, v in lab.frames().items() if v[0].checked and any(r.kind == "light" for r in v)]
    assert len(list(iter_label_frames(lab, data_root, keys=positive))) == len(positive)
