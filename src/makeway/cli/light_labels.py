"""``makeway light-labels …``: label lit emergency lights in a clip — proposals, contact sheets,
checking a label file, YOLO export.

Each command parses its options, calls :mod:`makeway.train.light_labels`, and prints. Registered by the
main app as ``app.add_typer(light_labels_app, name="light-labels")``.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from makeway.cli.common import console, friendly_errors, new_app, print_json_line

light_labels_app = new_app(
    "light-labels",
    "Label lit emergency lights for training.\n\n"
    "Workflow: `propose VIDEO LABELS.csv` → optionally `tracklets VIDEO LABELS.csv DIR` → "
    "`sheets VIDEO LABELS.csv DIR` → look at every sheet, "
    "correct the CSV by hand and set checked=1 → `check LABELS.csv` → `export LABELS.csv... DIR`. "
    "The CSV format and the labelling rules are in docs/data_card_lights.md.",
)


@light_labels_app.command()
@friendly_errors
def propose(
    video: Annotated[Path, typer.Argument(help="Road video.")],
    out: Annotated[Path, typer.Argument(help="Label file to write (CSV, all frames unchecked).")],
    stride: Annotated[int, typer.Option(min=1, help="Propose on every N-th frame (flashing uses all).")] = 1,
    colours: Annotated[
        str, typer.Option(help="Comma-separated colours to propose: blue, red, amber.")
    ] = "blue,red",
    window_s: Annotated[float, typer.Option(min=0.1, help="Flash window (s) centred on each frame.")] = 0.6,
    hue: Annotated[
        str,
        typer.Option(help="HSV ranges: 'default', or 'wide' (red also magenta/pink 141-179, amber from 11)."),
    ] = "default",
) -> None:
    """Propose lit-light boxes on every N-th frame.

    Cues: colour (HSV masks), bright cores with a coloured halo, flashing.

    Each proposal becomes an unchecked 'light' row (vehicle 0, its cues and score in the note); a
    frame without proposals gets a 'frame' row. The file is a starting point for a person to correct.
    """
    from makeway.perceive.vision.light_colour import COLOURS, HSV_PRESETS, ProposalConfig
    from makeway.train.light_labels import proposals_to_rows, propose_video, write_labels

    chosen = tuple(c.strip() for c in colours.split(",") if c.strip())
    bad = [c for c in chosen if c not in COLOURS or c == "white"]
    if bad or not chosen:
        raise ValueError(f"--colours takes blue, red, amber; not {colours!r}")
    if hue not in HSV_PRESETS:
        raise ValueError(f"--hue takes {', '.join(HSV_PRESETS)}; not {hue!r}")
    config = ProposalConfig(colours=chosen, hsv=dict(HSV_PRESETS[hue]))
    props, width, height, frames = propose_video(video, config, stride=stride, window_s=window_s)
    write_labels(out, video.name, width, height, proposals_to_rows(props, frames))
    console.print(f"{len(props)} proposals on {len(frames)} frames → {out}", highlight=False)


@light_labels_app.command()
@friendly_errors
def sheets(
    video: Annotated[Path, typer.Argument(help="The video the label file labels.")],
    labels: Annotated[Path, typer.Argument(help="Label file (CSV).")],
    out: Annotated[Path, typer.Argument(help="Folder for the PNG contact sheets.")],
    columns: Annotated[int, typer.Option(min=1, help="Frames per sheet row.")] = 2,
    rows: Annotated[int, typer.Option(min=1, help="Rows per sheet.")] = 3,
    scale: Annotated[float, typer.Option(min=0.05, max=2.0, help="Frame scale on the sheet.")] = 0.5,
    labelled_only: Annotated[
        bool, typer.Option("--labelled-only", help="Only frames that have rows in the label file.")
    ] = True,
) -> None:
    """Draw frames with numbered boxes in PNG grids.

    For checking every frame by eye.

    Lights are drawn in their colour with '#n vV' (row number within the frame, vehicle id),
    negatives in grey with an 'x'; each frame is captioned with its index, counts and checked state.
    """
    from makeway.sense.video import VideoReader
    from makeway.train.light_labels import contact_sheets, read_labels

    lab = read_labels(labels)
    keys = set(lab.frames())

    def frames() -> Iterator[tuple[str, np.ndarray]]:
        with VideoReader(video) as reader:
            for index, _t, frame in reader:
                if not labelled_only or str(index) in keys:
                    yield str(index), frame

    paths = contact_sheets(frames(), lab, out, columns=columns, rows_per_sheet=rows, scale=scale)
    console.print(f"{len(paths)} sheets → {out}", highlight=False)


@light_labels_app.command()
@friendly_errors
def check(
    labels: Annotated[list[Path], typer.Argument(help="Label files (CSV).")],
    as_json: Annotated[bool, typer.Option("--json", help="Print the counts as one JSON line.")] = False,
) -> None:
    """Validate label files and count what they hold.

    Counts: frames, boxes per colour, vehicles, hard negatives.

    A malformed row, a box outside the image or an unknown colour ends with one line naming
    file:line and the problem, exit code 2. Counts cover checked frames only.
    """
    from makeway.train.light_labels import read_labels

    counts = {str(p): read_labels(p).counts() for p in labels}
    if as_json:
        print_json_line(counts)
        return
    for name, c in counts.items():
        per_colour = c["boxes_per_colour"]
        assert isinstance(per_colour, dict)
        colours = ", ".join(f"{k} {v}" for k, v in per_colour.items() if v)
        console.print(
            f"{name}: {c['checked_frames']} of {c['frames']} frames checked "
            f"({c['positive_frames']} with lit lights, {c['negative_frames']} without), "
            f"{c['boxes']} boxes ({colours or 'none'}), {c['vehicles']} vehicles, "
            f"{c['hard_negatives']} hard negatives",
            highlight=False,
            soft_wrap=True,
        )


@light_labels_app.command()
@friendly_errors
def export(
    labels: Annotated[list[Path], typer.Argument(help="Label files (CSV).")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder (labels/, test_id/, classes.txt).")],
    single_class: Annotated[
        bool, typer.Option("--single-class", help="One class 'lit_light' instead of one per colour.")
    ] = False,
) -> None:
    """Export checked frames as YOLO txt plus test_id.

    The test_id folder groups boxes by vehicle, as in ABLDataset.

    Image stems are '<video stem>_<frame:06d>' for video frames; a checked frame without lights gets
    an empty file. Classes follow COLOURS (blue, red, amber, white) unless --single-class.
    """
    from makeway.train.light_labels import export_yolo, read_labels

    files = [read_labels(p) for p in labels]
    counts = export_yolo(files, out, single_class=single_class)
    console.print(f"{counts['images']} images, {counts['boxes']} boxes → {out}", highlight=False)


@light_labels_app.command()
@friendly_errors
def tracklets(
    video: Annotated[Path, typer.Argument(help="The video the label file labels.")],
    labels: Annotated[Path, typer.Argument(help="Label file (CSV), e.g. fresh proposals.")],
    out: Annotated[Path, typer.Argument(help="Folder for tracklets.csv and the PNG thumbnail sheets.")],
    min_length: Annotated[int, typer.Option(min=1, help="Draw tracklets of at least N boxes.")] = 3,
    max_gap: Annotated[int, typer.Option(min=1, help="Close a tracklet after N frames without a box.")] = 8,
) -> None:
    """Link boxes across frames into tracklets.

    Draws one thumbnail per tracklet, to accept or reject a light once for many frames. Writes
    OUT/tracklets.csv (tracklet, frame, n: the box's number on the contact sheets) and
    OUT/tracklets_NNN.png (thumbnails captioned with the tracklet number, colour initial and length).
    """
    from makeway.sense.video import VideoReader
    from makeway.train.light_labels import link_tracklets, read_labels, tracklet_sheets

    lab = read_labels(labels)
    tracks = link_tracklets(lab, max_gap=max_gap)
    out.mkdir(parents=True, exist_ok=True)
    lines = ["tracklet,frame,n"] + [f"{i},{k},{n}" for i, t in enumerate(tracks) for k, n in t]
    (out / "tracklets.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    keys = {k for t in tracks if len(t) >= min_length for k, _n in t}

    def frames() -> Iterator[tuple[str, np.ndarray]]:
        with VideoReader(video) as reader:
            for index, _t, frame in reader:
                if str(index) in keys:
                    yield str(index), frame

    paths = tracklet_sheets(frames(), lab, tracks, out, min_length=min_length)
    console.print(f"{len(tracks)} tracklets, {len(paths)} sheets → {out}", highlight=False)
