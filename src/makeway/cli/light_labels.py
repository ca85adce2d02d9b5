"""``makeway light-labels …``: label lit emergency lights in a clip — proposals, contact sheets,
checking a label file, YOLO export.

Each command parses its options, calls :mod:`makeway.train.light_labels`, and prints. Registered by the
main app as ``app.add_typer(light_labels_app, name="light-labels")``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from makeway.cli.common import console, friendly_errors, new_app, print_json_line

light_labels_app = new_app(
    "light-labels",
    "Label lit emergency lights for training.\n\n"
    "Workflow: `propose VIDEO|IMAGE_FOLDER LABELS.csv` → optionally `tracklets VIDEO LABELS.csv DIR` → "
    "`sheets VIDEO|IMAGE_FOLDER LABELS.csv DIR` → look at every sheet, "
    "correct the CSV by hand and set checked=1 → `check LABELS.csv` → `export LABELS.csv... DIR`. "
    "The CSV format and the labelling rules are in docs/data_card_lights.md.",
)


DataOption = Annotated[
    Path | None, typer.Option("--data", help="Shared data folder (default: $MAKEWAY_DATA or ../shared/data).")
]


def _data_root(data: Path | None) -> Path | None:
    from makeway.paths import data_dir

    return data if data is not None else data_dir()


@light_labels_app.command()
@friendly_errors
def propose(
    source: Annotated[Path, typer.Argument(help="Road video, or a folder of images.")],
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
    names: Annotated[
        Path | None,
        typer.Option(
            help="Image folders: a text file of image names (one per line, '#' comments) to propose on."
        ),
    ] = None,
    data: DataOption = None,
) -> None:
    """Propose lit-light boxes on a video's frames or a folder's images.

    Cues: colour (HSV masks), bright cores with a coloured halo, flashing (videos only).

    Each proposal becomes an unchecked 'light' row (vehicle 0, its cues and score in the note); a
    frame without proposals gets a 'frame' row. An image folder's frames are its image names, its
    source is its path under the data folder's vision/, and its size is per image (width/height 0).
    The file is a starting point for a person to correct.
    """
    from makeway.errors import InputError
    from makeway.perceive.vision.light_colour import COLOURS, HSV_PRESETS, ProposalConfig
    from makeway.train.light_labels import propose_to_file

    chosen = tuple(c.strip() for c in colours.split(",") if c.strip())
    bad = [c for c in chosen if c not in COLOURS or c == "white"]
    if bad or not chosen:
        raise ValueError(f"--colours takes blue, red, amber; not {colours!r}")
    if hue not in HSV_PRESETS:
        raise ValueError(f"--hue takes {', '.join(HSV_PRESETS)}; not {hue!r}")
    wanted: list[str] | None = None
    if names is not None:
        try:
            lines = names.read_text(encoding="utf-8").splitlines()
        except OSError as exc:
            raise InputError(names, f"cannot read the list of names ({exc})") from None
        wanted = [s.strip() for s in lines if s.strip() and not s.lstrip().startswith("#")]
    config = ProposalConfig(colours=chosen, hsv=dict(HSV_PRESETS[hue]))
    counts = propose_to_file(
        source, out, config, stride=stride, window_s=window_s, names=wanted, data_root=_data_root(data)
    )
    console.print(f"{counts['proposals']} proposals on {counts['frames']} frames → {out}", highlight=False)


def _tile(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--tile takes WIDTHxHEIGHT in pixels, e.g. 480x480; not {text!r}") from None
    if w < 16 or h < 16:
        raise ValueError(f"--tile must be at least 16x16, not {text!r}")
    return w, h


@light_labels_app.command()
@friendly_errors
def sheets(
    source: Annotated[Path, typer.Argument(help="The video or image folder the label file labels.")],
    labels: Annotated[Path, typer.Argument(help="Label file (CSV).")],
    out: Annotated[Path, typer.Argument(help="Folder for the PNG contact sheets.")],
    columns: Annotated[int, typer.Option(min=1, help="Frames per sheet row.")] = 2,
    rows: Annotated[int, typer.Option(min=1, help="Rows per sheet.")] = 3,
    scale: Annotated[float, typer.Option(min=0.05, max=2.0, help="Frame scale on the sheet.")] = 0.5,
    tile: Annotated[
        str | None, typer.Option(help="Fit each frame into a WIDTHxHEIGHT tile instead of scaling it.")
    ] = None,
    labelled_only: Annotated[
        bool, typer.Option("--labelled-only/--all", help="Only frames that have rows in the label file.")
    ] = True,
) -> None:
    """Draw frames with numbered boxes in PNG grids.

    For checking every frame by eye.

    Lights are drawn in their colour with '#n vV' (row number within the frame, vehicle id),
    negatives in grey with an 'x'; each frame is captioned with its key, counts and checked state.
    """
    from makeway.train.light_labels import contact_sheets, iter_label_frames, read_labels

    lab = read_labels(labels)
    fit = _tile(tile)
    frames = iter_label_frames(lab, None, source=source, every=not labelled_only)
    paths = contact_sheets(frames, lab, out, columns=columns, rows_per_sheet=rows, scale=scale, tile=fit)
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
    data: DataOption = None,
) -> None:
    """Export checked frames as YOLO txt plus test_id.

    The test_id folder groups boxes by vehicle, as in ABLDataset.

    Image stems are '<video stem>_<frame:06d>' for video frames and the image's stem for image
    folders (normalised by each image's size); a checked frame without lights gets an empty
    file. Classes follow COLOURS (blue, red, amber, white) unless --single-class.
    """
    from makeway.train.light_labels import export_yolo, read_labels

    files = [read_labels(p) for p in labels]
    counts = export_yolo(files, out, single_class=single_class, data_root=_data_root(data))
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
    from makeway.atomic import write_text_atomic
    from makeway.train.light_labels import iter_label_frames, link_tracklets, read_labels, tracklet_sheets

    lab = read_labels(labels)
    tracks = link_tracklets(lab, max_gap=max_gap)
    out.mkdir(parents=True, exist_ok=True)
    lines = ["tracklet,frame,n"] + [f"{i},{k},{n}" for i, t in enumerate(tracks) for k, n in t]
    write_text_atomic(out / "tracklets.csv", "\n".join(lines) + "\n")
    keys = {k for t in tracks if len(t) >= min_length for k, _n in t}
    frames = iter_label_frames(lab, None, keys=keys, source=video)
    paths = tracklet_sheets(frames, lab, tracks, out, min_length=min_length)
    console.print(f"{len(tracks)} tracklets, {len(paths)} sheets → {out}", highlight=False)
