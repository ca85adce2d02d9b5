"""Lit emergency-light labels: proposals, contact sheets, the label file and its YOLO export.

The data engine for the lit-light detector (issue 23, item 4). A person labels a clip in four steps:

1. :func:`propose_video` finds candidate lit-light boxes on every frame from three cues — *colour*
   (HSV masks per colour, :data:`DEFAULT_HSV`), *brightness* (a saturated, near-white core ringed by
   a coloured halo, which is how a lit bulb looks to a camera at night) and *flashing* (the same
   region's coloured brightness switching on and off within a window of about 0.25–1 s) — and
   merges them into boxes (:func:`propose`, :func:`flash_score`).
2. :func:`contact_sheets` draws the frames in PNG grids with numbered boxes so that every frame can be
   checked by eye.
3. The person corrects the label file (:func:`write_labels`, :func:`read_labels`): deletes false
   proposals (keeping them as ``negative`` rows: hard negatives), adds missed lights, sets colours and
   vehicle ids, and marks each frame ``checked``.
4. :func:`export_yolo` writes YOLO txt files plus an ABLDataset-style ``test_id`` grouping folder.

Label rules (seed 004, ABLDataset): a box covers only the lit part of an emergency light; adjacent
bulbs sharing one glow are one box, bulbs with dark background between them are separate boxes;
brake, tail and head lights, traffic lights, signs and reflections are never positives.

The label file is CSV, one file per source (video or image folder)::

    # source: night_ambulance_lights.mp4
    # width: 1280
    # height: 720
    frame,checked,kind,x1,y1,x2,y2,colour,vehicle,note
    12,1,light,640,210,668,226,blue,0,
    12,1,negative,300,400,330,420,red,,tail light
    13,1,frame,,,,,,,

``frame`` is the 0-based decoded frame index (or, for image folders, the image's file name);
``checked`` is 1 when a person has looked at the whole frame and its rows are right, 0 otherwise
(every row of a frame carries the same flag); ``kind`` is ``light`` (a lit emergency light: box,
colour and vehicle required), ``negative`` (a rejected proposal or other lit non-emergency light:
box required, colour optional) or ``frame`` (a frame with no boxes, to record that it was seen).
Boxes are integer pixels ``x1,y1`` (top-left, inclusive) to ``x2,y2`` (exclusive) in the source
image, ``0 <= x1 < x2 <= width``, ``0 <= y1 < y2 <= height``. An image folder whose images differ in
size (``# source: ambulance_yolo/valid/images``, a folder under the data root's ``vision/``) writes
``# width: 0`` and ``# height: 0``, meaning "per image": the reader then checks only that boxes are
non-empty and non-negative, and :func:`iter_label_frames` checks them against each image's size when
it opens the image. ``vehicle`` is an integer id unique
within the source: the same physical vehicle keeps its id across frames.
"""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from makeway.errors import InputError
from makeway.perceive.vision.light_colour import (
    COLOURS,
    Proposal,
    ProposalConfig,
    flash_score,
    lit_maps,
    propose,
)

#: Row kinds of the label file.
KINDS: tuple[str, ...] = ("light", "negative", "frame")

HEADER: tuple[str, ...] = ("frame", "checked", "kind", "x1", "y1", "x2", "y2", "colour", "vehicle", "note")


@dataclass(frozen=True)
class LabelRow:
    """One row of a label file (see the module docstring); ``line`` is its 1-based line number."""

    frame: str
    checked: bool
    kind: str
    box: tuple[int, int, int, int] | None
    colour: str
    vehicle: int | None
    note: str = ""
    line: int = 0


@dataclass
class LabelFile:
    """A parsed label file: the source it labels, the image size and its rows in file order."""

    path: Path
    source: str
    width: int
    height: int
    rows: list[LabelRow]

    @property
    def per_image(self) -> bool:
        """Whether the image size is per image (``width``/``height`` 0 in the header)."""
        return self.width == 0 and self.height == 0

    def frames(self) -> dict[str, list[LabelRow]]:
        """Frame key → its rows, in first-appearance order."""
        out: dict[str, list[LabelRow]] = {}
        for row in self.rows:
            out.setdefault(row.frame, []).append(row)
        return out

    def counts(self) -> dict[str, object]:
        """Frames (all, checked, checked positive, checked negative), boxes per colour and vehicles,
        over checked frames only; plus hard negatives (``negative`` rows on checked frames)."""
        frames = self.frames()
        checked = {k: v for k, v in frames.items() if v[0].checked}
        positive = [k for k, v in checked.items() if any(r.kind == "light" for r in v)]
        lights = [r for v in checked.values() for r in v if r.kind == "light"]
        return {
            "frames": len(frames),
            "checked_frames": len(checked),
            "positive_frames": len(positive),
            "negative_frames": len(checked) - len(positive),
            "boxes": len(lights),
            "boxes_per_colour": {c: sum(r.colour == c for r in lights) for c in COLOURS},
            "vehicles": len({r.vehicle for r in lights}),
            "hard_negatives": sum(r.kind == "negative" for v in checked.values() for r in v),
        }


def propose_video(
    path: str | Path,
    config: ProposalConfig | None = None,
    *,
    stride: int = 1,
    window_s: float = 0.6,
    max_frames: int | None = None,
) -> tuple[list[Proposal], int, int, list[int]]:
    """Proposals for every ``stride``-th frame of a video, with the flashing cue.

    A proposal gains the ``flash`` cue (and 0.5 on its score) when :func:`flash_score` counts at least
    one on↔off change of its region in its colour within the ``window_s`` seconds of frames centred on
    it. Returns ``(proposals, width, height, frame indices read)``.
    """
    from makeway.sense.video import VideoReader

    cfg = config or ProposalConfig()
    colour_index = {c: i for i, c in enumerate(cfg.colours)}
    per_frame: dict[int, list[Proposal]] = {}
    maps: dict[int, np.ndarray] = {}
    with VideoReader(path, max_frames=max_frames) as reader:
        fps, width, height = reader.info.fps, reader.info.width, reader.info.height
        for index, _t, frame in reader:
            maps[index] = lit_maps(frame, cfg)
            if index % stride == 0:
                per_frame[index] = propose(frame, cfg, frame=index)
    half = max(1, round(window_s * fps / 2))
    out: list[Proposal] = []
    for index, props in per_frame.items():
        window = [maps[i] for i in range(index - half, index + half + 1) if i in maps]
        for p in props:
            if p.colour in colour_index and flash_score(window, p, colour_index[p.colour]) >= 1:
                p = Proposal(p.frame, *p.box, p.colour, round(p.score + 0.5, 4), (*p.cues, "flash"))
            out.append(p)
    return out, width, height, sorted(per_frame)


# ------------------------------------------------------------------------------------------ label file
def proposals_to_rows(
    proposals: Iterable[Proposal], frames: Iterable[int], *, keys: Sequence[str] | None = None
) -> list[LabelRow]:
    """Unchecked label rows from proposals: each proposal a ``light`` row with vehicle 0 (to be
    corrected by a person), and a ``frame`` row for each frame without proposals. The frame key is
    the frame index, or ``keys[index]`` (an image name) when ``keys`` is given."""
    by_frame: dict[int, list[Proposal]] = {}
    for p in proposals:
        by_frame.setdefault(p.frame, []).append(p)
    rows = []
    for f in frames:
        props = by_frame.get(f, [])
        key = keys[f] if keys is not None else str(f)
        if not props:
            rows.append(LabelRow(key, False, "frame", None, "", None))
        for p in props:
            note = "+".join(p.cues) + f" {p.score:.2f}"
            rows.append(LabelRow(key, False, "light", p.box, p.colour, 0, note))
    return rows


def write_labels(path: str | Path, source: str, width: int, height: int, rows: Iterable[LabelRow]) -> None:
    """Write a label file (format in the module docstring), atomically."""
    from makeway.atomic import atomic_path

    lines = [f"# source: {source}", f"# width: {width}", f"# height: {height}"]
    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        fh.write("\n".join(lines) + "\n")
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(HEADER)
        for r in rows:
            box = [str(v) for v in r.box] if r.box else ["", "", "", ""]
            vehicle = "" if r.vehicle is None else str(r.vehicle)
            w.writerow([r.frame, int(r.checked), r.kind, *box, r.colour, vehicle, r.note])


_META = re.compile(r"#\s*(source|width|height)\s*:\s*(.*?)\s*$")


def read_labels(path: str | Path) -> LabelFile:
    """Read and validate a label file.

    Raises :class:`~makeway.errors.InputError` naming ``file:line`` and the problem for: a missing
    ``width``/``height``/``source`` comment, a wrong header, a row with the wrong number of fields, a
    non-integer frame index for a video source, ``checked`` not 0/1, an unknown kind or colour, a
    missing or non-integer box, a box outside the image or empty (with a per-image size, ``width``
    and ``height`` 0: a negative or empty box), a light without a vehicle id, a
    frame whose rows disagree on ``checked``, a ``frame`` row beside boxes of the same frame.
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(p, "no such label file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(p, f"cannot read the label file ({exc})") from None
    meta: dict[str, str] = {}
    rows: list[LabelRow] = []
    header_seen = False
    lines = text.splitlines()
    for lineno, line in enumerate(lines, 1):
        where = f"{p}:{lineno}"
        if not line.strip():
            continue
        if line.lstrip().startswith("#"):
            m = _META.match(line.strip())
            if m:
                meta[m.group(1)] = m.group(2)
            continue
        fields = next(csv.reader([line]))
        if not header_seen:
            if tuple(f.strip() for f in fields) != HEADER:
                raise InputError(where, f"the header must be {','.join(HEADER)}")
            header_seen = True
            for key in ("source", "width", "height"):
                if key not in meta:
                    raise InputError(where, f"missing '# {key}: ...' comment before the header")
            try:
                width, height = int(meta["width"]), int(meta["height"])
            except ValueError:
                raise InputError(where, "width and height must be integers") from None
            if (width, height) != (0, 0) and (width <= 0 or height <= 0):
                raise InputError(where, "width and height must be positive (or both 0: per image)")
            continue
        rows.append(_parse_row(where, lineno, fields, width, height, meta["source"]))
    if not header_seen:
        raise InputError(p, "no header line (frame,checked,kind,...) — not a label file")
    seen: dict[str, LabelRow] = {}
    kinds: dict[str, set[str]] = {}
    for r in rows:
        first = seen.setdefault(r.frame, r)
        if first.checked != r.checked:
            raise InputError(f"{p}:{r.line}", f"frame {r.frame} is checked on line {first.line} but not here")
        kinds.setdefault(r.frame, set()).add(r.kind)
        if ("frame" in kinds[r.frame] and len(kinds[r.frame]) > 1) or (r.kind == "frame" and r is not first):
            raise InputError(f"{p}:{r.line}", f"frame {r.frame} has a 'frame' row beside other rows")
    return LabelFile(p, meta["source"], width, height, rows)


def _parse_row(where: str, lineno: int, fields: list[str], width: int, height: int, source: str) -> LabelRow:
    if len(fields) != len(HEADER):
        raise InputError(where, f"expected {len(HEADER)} fields ({','.join(HEADER)}), found {len(fields)}")
    frame, checked, kind, *box_s, colour, vehicle_s, note = (f.strip() for f in fields)
    if not frame:
        raise InputError(where, "empty frame")
    if source.lower().endswith((".mp4", ".avi", ".mov", ".mkv", ".webm")) and not frame.isdigit():
        raise InputError(where, f"frame must be a non-negative integer frame index, not {frame!r}")
    if checked not in ("0", "1"):
        raise InputError(where, f"checked must be 0 or 1, not {checked!r}")
    if kind not in KINDS:
        raise InputError(where, f"unknown kind {kind!r} (one of {', '.join(KINDS)})")
    box: tuple[int, int, int, int] | None = None
    if kind == "frame":
        if any(box_s) or colour or vehicle_s:
            raise InputError(where, "a 'frame' row takes no box, colour or vehicle")
    else:
        try:
            x1, y1, x2, y2 = (int(v) for v in box_s)
        except ValueError:
            raise InputError(where, f"box x1,y1,x2,y2 must be integers, not {','.join(box_s)!r}") from None
        if width == 0 and height == 0:
            if not (0 <= x1 < x2 and 0 <= y1 < y2):
                raise InputError(where, f"box ({x1},{y1},{x2},{y2}) is empty or negative")
        elif not (0 <= x1 < x2 <= width and 0 <= y1 < y2 <= height):
            raise InputError(
                where, f"box ({x1},{y1},{x2},{y2}) is empty or outside the {width}x{height} image"
            )
        box = (x1, y1, x2, y2)
        if colour and colour not in COLOURS:
            raise InputError(where, f"unknown colour {colour!r} (one of {', '.join(COLOURS)})")
    vehicle: int | None = None
    if kind == "light":
        if not colour:
            raise InputError(where, "a light needs a colour")
        if not vehicle_s.isdigit():
            raise InputError(where, f"a light needs a non-negative integer vehicle id, not {vehicle_s!r}")
        vehicle = int(vehicle_s)
    elif vehicle_s and kind == "negative":
        raise InputError(where, "a negative takes no vehicle id")
    return LabelRow(frame, checked == "1", kind, box, colour, vehicle, note, lineno)


# ------------------------------------------------------------------------------------------ YOLO export
def source_path(source: str, data_root: str | Path) -> Path:
    """Where a label file's ``source`` lives: a video (``*.mp4`` …) under ``<data_root>/video/``, an
    image folder (such as ``ambulance_yolo/valid/images``) under ``<data_root>/vision/``."""
    root = Path(data_root)
    if Path(source).suffix.lower() in {".mp4", ".avi", ".mov", ".mkv", ".webm"}:
        return root / "video" / source
    return root / "vision" / source


IMAGE_SUFFIXES: tuple[str, ...] = (".jpg", ".jpeg", ".png", ".bmp")


def folder_images(folder: str | Path) -> list[str]:
    """The image file names (``*.jpg``, ``*.jpeg``, ``*.png``, ``*.bmp``) of a folder, sorted."""
    return sorted(q.name for q in Path(folder).iterdir() if q.suffix.lower() in IMAGE_SUFFIXES)


def iter_label_frames(
    labels: LabelFile,
    data_root: str | Path | None,
    *,
    keys: Iterable[str] | None = None,
    source: str | Path | None = None,
    every: bool = False,
) -> Iterator[tuple[str, np.ndarray]]:
    """``(frame key, BGR image)`` for the frames of a label file, in source order.

    The source is ``source`` when given, else the label file's ``source`` resolved under
    ``data_root`` (:func:`source_path`). A video is decoded once, yielding the frames whose index is
    in ``keys`` (default: every frame the label file has rows for; ``every``: all frames); an image
    folder yields each named image (``every``: all images of the folder, sorted by name). With a
    per-image size (``width``/``height`` 0) each box of an image is checked against that image's size.
    A missing source or image, one that cannot be decoded, or a box outside its image raises
    :class:`InputError` naming the file, the frame and the problem.
    """
    from makeway.sense.video import VideoReader

    wanted = set(labels.frames()) if keys is None else set(keys)
    if source is not None:
        path = Path(source)
    elif data_root is not None:
        path = source_path(labels.source, data_root)
    else:
        raise InputError(str(labels.path), "no data root to find the source in")
    if not path.exists():
        raise InputError(str(labels.path), f"source {labels.source!r} not found at {path}")
    by_frame = labels.frames()
    if path.is_dir():
        for key in folder_images(path) if every else sorted(wanted):
            img_path = path / key
            img = cv2.imread(str(img_path), cv2.IMREAD_COLOR)
            if img is None:
                raise InputError(str(img_path), f"frame {key}: missing or not a decodable image")
            _check_boxes_fit(labels, key, by_frame.get(key, []), img.shape[1], img.shape[0])
            yield key, img
        return
    last = max((int(k) for k in wanted if k.isdigit()), default=-1)
    limit = None if every or last < 0 else last + 1
    with VideoReader(path, max_frames=limit) as reader:
        for index, _t, frame in reader:
            if every or str(index) in wanted:
                yield str(index), frame


def _check_boxes_fit(labels: LabelFile, key: str, rows: Sequence[LabelRow], width: int, height: int) -> None:
    for r in rows:
        if r.box is None:
            continue
        x1, y1, x2, y2 = r.box
        if not (0 <= x1 < x2 <= width and 0 <= y1 < y2 <= height):
            raise InputError(
                f"{labels.path}:{r.line}",
                f"frame {key}: box ({x1},{y1},{x2},{y2}) is outside the {width}x{height} image",
            )


def propose_folder(
    folder: str | Path, config: ProposalConfig | None = None, *, names: Sequence[str] | None = None
) -> tuple[list[Proposal], list[str]]:
    """Proposals for each image of a folder (or only the images in ``names``), in name order.

    A proposal's ``frame`` is the index of its image in the returned name list (no flashing cue:
    a still image has no time). An image that is missing or cannot be decoded raises
    :class:`InputError` naming it.
    """
    cfg = config or ProposalConfig()
    root = Path(folder)
    available = folder_images(root)
    if names is not None:
        missing = sorted(set(names) - set(available))
        if missing:
            raise InputError(root / missing[0], f"not an image of the folder ({len(missing)} names missing)")
        chosen = sorted(set(names))
    else:
        chosen = available
    out: list[Proposal] = []
    for i, name in enumerate(chosen):
        img = cv2.imread(str(root / name), cv2.IMREAD_COLOR)
        if img is None:
            raise InputError(root / name, "not a decodable image")
        out.extend(propose(img, cfg, frame=i))
    return out, chosen


def propose_to_file(
    source: str | Path,
    out: str | Path,
    config: ProposalConfig | None = None,
    *,
    stride: int = 1,
    window_s: float = 0.6,
    names: Sequence[str] | None = None,
    data_root: str | Path | None = None,
) -> dict[str, int]:
    """Propose lit lights on a video (every ``stride``-th frame, with the flashing cue) or an image
    folder (each image, or the ``names`` given) and write an unchecked label file to ``out``.

    A video's ``# source`` is its file name; a folder's is its path relative to
    ``<data_root>/vision`` when it lies there (else its absolute path), with ``width``/``height`` 0
    (per image). Returns counts: proposals, frames.
    """
    src = Path(source)
    if not src.exists():
        raise InputError(src, "no such video or image folder")
    if src.is_dir():
        props, keys = propose_folder(src, config, names=names)
        label_source = str(src.resolve())
        if data_root is not None:
            vision = (Path(data_root) / "vision").resolve()
            if src.resolve().is_relative_to(vision):
                label_source = src.resolve().relative_to(vision).as_posix()
        rows = proposals_to_rows(props, range(len(keys)), keys=keys)
        write_labels(out, label_source, 0, 0, rows)
        return {"proposals": len(props), "frames": len(keys)}
    if names is not None:
        raise InputError(src, "a list of image names needs an image folder, not a video")
    vprops, width, height, frames = propose_video(src, config, stride=stride, window_s=window_s)
    write_labels(out, src.name, width, height, proposals_to_rows(vprops, frames))
    return {"proposals": len(vprops), "frames": len(frames)}


def image_name(source: str, frame: str) -> str:
    """The image stem for a frame of a source: ``<source stem>_<frame:06d>`` for a video frame index,
    ``<image stem>`` for an image name."""
    if frame.isdigit():
        return f"{Path(source).stem}_{int(frame):06d}"
    return Path(frame).stem


def export_yolo(
    labels: Sequence[LabelFile],
    out: str | Path,
    *,
    single_class: bool = False,
    data_root: str | Path | None = None,
) -> dict[str, int]:
    """Write the checked frames of ``labels`` in YOLO layout, ABLDataset style.

    ``out/labels/<image>.txt``: one row ``class cx cy w h`` per light (normalised to the image size,
    6 decimals; class = index in :data:`COLOURS`, or 0 for all with ``single_class``); a checked frame
    without lights gets an empty file (a negative image). ``out/test_id/<image>.txt``: the light's
    vehicle id row by row in the same order (ABLDataset's ``test_id`` grouping: rows with equal ids
    belong to the same vehicle). ``out/classes.txt`` names the classes. Unchecked frames are skipped.
    A label file with a per-image size (``width``/``height`` 0) normalises by each image's size, read
    from its source under ``data_root`` (:func:`iter_label_frames`, which also checks the boxes fit).
    Returns counts: images, boxes. The folder appears only when complete; an earlier export at ``out``
    is replaced, another non-empty folder refused.
    """
    from makeway.atomic import atomic_dir

    # built in a temporary folder renamed into place at the end: a bad label file leaves nothing
    with atomic_dir(out, marker="classes.txt") as root:
        (root / "labels").mkdir(parents=True, exist_ok=True)
        (root / "test_id").mkdir(parents=True, exist_ok=True)
        classes = ["lit_light"] if single_class else list(COLOURS)
        (root / "classes.txt").write_text("\n".join(classes) + "\n", encoding="utf-8")
        images = boxes = 0
        for lf in labels:
            frames = lf.frames()
            sizes: dict[str, tuple[int, int]] = {}
            if lf.per_image:
                checked = [k for k, v in frames.items() if v[0].checked]
                if data_root is None and checked:
                    raise InputError(
                        str(lf.path), "per-image sizes (width 0): the export needs the data root"
                    )
                for key, img in iter_label_frames(lf, data_root, keys=checked):
                    sizes[key] = (img.shape[1], img.shape[0])
            for frame, rows in frames.items():
                if not rows[0].checked:
                    continue
                width, height = sizes.get(frame, (lf.width, lf.height))
                name = image_name(lf.source, frame)
                lines, ids = [], []
                for r in rows:
                    if r.kind != "light" or r.box is None:
                        continue
                    x1, y1, x2, y2 = r.box
                    cls = 0 if single_class else COLOURS.index(r.colour)
                    cx, cy = (x1 + x2) / 2 / width, (y1 + y2) / 2 / height
                    bw, bh = (x2 - x1) / width, (y2 - y1) / height
                    lines.append(f"{cls} {cx:.6f} {cy:.6f} {bw:.6f} {bh:.6f}")
                    ids.append(str(r.vehicle))
                (root / "labels" / f"{name}.txt").write_text(
                    "".join(s + "\n" for s in lines), encoding="utf-8"
                )
                (root / "test_id" / f"{name}.txt").write_text(
                    "".join(s + "\n" for s in ids), encoding="utf-8"
                )
                images += 1
                boxes += len(lines)
    return {"images": images, "boxes": boxes}


def read_yolo(
    label_file: str | Path, width: int, height: int, test_id_file: str | Path | None = None
) -> list[tuple[int, tuple[int, int, int, int], int | None]]:
    """Read one YOLO txt file back to pixel boxes: ``(class, (x1, y1, x2, y2), vehicle)`` per row,
    boxes rounded to whole pixels; ``vehicle`` from the matching ``test_id`` file, or None.
    Raises :class:`~makeway.errors.InputError` naming ``file:line`` on a malformed row or when the
    grouping file has a different number of rows."""
    p = Path(label_file)
    out: list[tuple[int, tuple[int, int, int, int], int | None]] = []
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(p, "no such YOLO label file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(p, f"cannot be read as a YOLO label file ({exc})") from None
    for lineno, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        parts = line.split()
        try:
            cls = int(parts[0])
            cx, cy, bw, bh = (float(v) for v in parts[1:])
        except (ValueError, IndexError):
            raise InputError(f"{p}:{lineno}", "expected 'class cx cy w h'") from None
        if not all(math.isfinite(v) and 0 <= v <= 1 for v in (cx, cy, bw, bh)):
            raise InputError(f"{p}:{lineno}", "cx cy w h must be normalised to 0..1")
        box = (
            round((cx - bw / 2) * width),
            round((cy - bh / 2) * height),
            round((cx + bw / 2) * width),
            round((cy + bh / 2) * height),
        )
        out.append((cls, box, None))
    if test_id_file is not None:
        t = Path(test_id_file)
        try:
            ids = [s.strip() for s in t.read_text(encoding="utf-8").splitlines() if s.strip()]
        except (OSError, UnicodeDecodeError) as exc:
            raise InputError(t, f"cannot be read as a vehicle id file ({exc})") from None
        if len(ids) != len(out):
            raise InputError(t, f"{len(ids)} vehicle ids for {len(out)} boxes in {p.name}")
        try:
            out = [(c, b, int(i)) for (c, b, _), i in zip(out, ids, strict=True)]
        except ValueError:
            raise InputError(t, "vehicle ids must be integers") from None
    return out


# ------------------------------------------------------------------------------------------ contact sheets
_DRAW_BGR = {"blue": (255, 160, 0), "red": (0, 0, 255), "amber": (0, 190, 255), "white": (255, 255, 255)}


def draw_boxes(frame_bgr: np.ndarray, rows: Sequence[LabelRow], scale: float) -> np.ndarray:
    """A copy of the frame resized by ``scale`` with the rows' boxes drawn and numbered from 0 in row
    order: lights in their colour (solid), negatives grey; the vehicle id follows the number as
    ``#n vV``."""
    img = cv2.resize(frame_bgr, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    n = 0
    for r in rows:
        if r.box is None:
            continue
        x1, y1, x2, y2 = (int(round(v * scale)) for v in r.box)
        col = _DRAW_BGR.get(r.colour, (200, 200, 200)) if r.kind == "light" else (150, 150, 150)
        pad = 2
        cv2.rectangle(img, (x1 - pad, y1 - pad), (x2 + pad, y2 + pad), col, 1)
        text = str(n) + (f" v{r.vehicle}" if r.kind == "light" and r.vehicle is not None else "")
        if r.kind == "negative":
            text += "x"
        ty = y1 - pad - 3 if y1 > 14 else y2 + pad + 11
        cv2.putText(img, text, (x1, ty), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(img, text, (x1, ty), cv2.FONT_HERSHEY_SIMPLEX, 0.38, col, 1, cv2.LINE_AA)
        n += 1
    return img


def contact_sheets(
    frames: Iterable[tuple[str, np.ndarray]],
    labels: LabelFile,
    out_dir: str | Path,
    *,
    columns: int = 2,
    rows_per_sheet: int = 3,
    scale: float = 0.5,
    tile: tuple[int, int] | None = None,
) -> list[Path]:
    """Write PNG grids of frames with their label rows drawn (:func:`draw_boxes`), each frame
    captioned with its key, its number of lights and negatives and ``checked``/``unchecked``.
    ``frames`` yields ``(frame key, BGR image)``; frames absent from ``labels`` are drawn without
    boxes. Each frame is scaled by ``scale``, or, with ``tile`` (width, height in sheet pixels),
    fitted into that tile keeping its aspect ratio and padded with black (for image folders whose
    images differ in size; without ``tile`` a frame whose size differs from the first is fitted to
    the first's tile). Returns the sheet paths (``sheet_000.png``, … in frame order)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    by_frame = labels.frames()
    per = columns * rows_per_sheet
    paths: list[Path] = []
    batch: list[np.ndarray] = []

    def flush() -> None:
        if not batch:
            return
        h, w = batch[0].shape[:2]
        while len(batch) < per:
            batch.append(np.zeros((h, w, 3), np.uint8))
        grid = np.vstack([np.hstack(batch[r * columns : (r + 1) * columns]) for r in range(rows_per_sheet)])
        path = out / f"sheet_{len(paths):03d}.png"
        cv2.imwrite(str(path), grid)
        paths.append(path)
        batch.clear()

    size = tile
    for key, img in frames:
        rows = by_frame.get(key, [])
        if size is None:
            size = (round(img.shape[1] * scale), round(img.shape[0] * scale))
        fit = min(size[0] / img.shape[1], size[1] / img.shape[0])
        drawn = draw_boxes(img, rows, fit)
        tile_img = np.zeros((size[1], size[0], 3), np.uint8)
        h, w = min(size[1], drawn.shape[0]), min(size[0], drawn.shape[1])
        tile_img[:h, :w] = drawn[:h, :w]
        lights = sum(r.kind == "light" for r in rows)
        negs = sum(r.kind == "negative" for r in rows)
        state = "checked" if rows and rows[0].checked else "unchecked"
        caption = f"{key}  L{lights} N{negs} {state}"
        cv2.rectangle(tile_img, (0, 0), (tile_img.shape[1] - 1, tile_img.shape[0] - 1), (80, 80, 80), 1)
        cv2.putText(tile_img, caption, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(tile_img, caption, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 255, 255), 1, cv2.LINE_AA)
        batch.append(tile_img)
        if len(batch) == per:
            flush()
    flush()
    return paths


# ------------------------------------------------------------------------------------------ tracklets
def link_tracklets(
    labels: LabelFile, *, kinds: tuple[str, ...] = ("light",), max_gap: int = 8, reach_px: float = 25.0
) -> list[list[tuple[str, int]]]:
    """Link the boxes of consecutive frames into tracklets, so a person can accept or reject a light
    once for many frames.

    Frames are taken in index order (video sources); a box joins the open tracklet of the same colour
    whose last box centre is nearest, when closer than ``reach_px`` plus half that box's longer side
    (pixels), each tracklet taking at most one box per frame; a tracklet closes after ``max_gap`` frame
    indices without a box. Returns tracklets as lists of ``(frame key, n)``, where ``n`` numbers the
    frame's boxed rows in file order (the numbers drawn by :func:`draw_boxes`), in order of first box.
    """
    frames = labels.frames()
    keys = sorted(frames, key=lambda k: (not k.isdigit(), int(k) if k.isdigit() else 0, k))
    tracks: list[list[tuple[str, int, LabelRow]]] = []
    open_: list[list[tuple[str, int, LabelRow]]] = []
    for key in keys:
        if key.isdigit():  # close the tracklets whose last box is too many frames back
            open_ = [t for t in open_ if not t[-1][0].isdigit() or int(key) - int(t[-1][0]) <= max_gap]
        boxed = [r for r in frames[key] if r.box is not None]
        rows = [(n, r) for n, r in enumerate(boxed) if r.kind in kinds]
        pairs = []
        for t in open_:
            last = t[-1][2]
            assert last.box is not None
            lx, ly = (last.box[0] + last.box[2]) / 2, (last.box[1] + last.box[3]) / 2
            reach = reach_px + 0.5 * max(last.box[2] - last.box[0], last.box[3] - last.box[1])
            for n, r in rows:
                assert r.box is not None
                if r.colour != last.colour:
                    continue
                d = math.hypot((r.box[0] + r.box[2]) / 2 - lx, (r.box[1] + r.box[3]) / 2 - ly)
                if d < reach:
                    pairs.append((d, id(t), t, n, r))
        pairs.sort(key=lambda p: p[0])
        taken: set[int] = set()
        used: set[int] = set()
        for _d, tid, t, n, r in pairs:
            if tid not in taken and n not in used:
                t.append((key, n, r))
                taken.add(tid)
                used.add(n)
        for n, r in rows:
            if n not in used:
                t = [(key, n, r)]
                tracks.append(t)
                open_.append(t)
    return [[(k, n) for k, n, _r in t] for t in tracks]


def tracklet_sheets(
    frames: Iterable[tuple[str, np.ndarray]],
    labels: LabelFile,
    tracklets: Sequence[Sequence[tuple[str, int]]],
    out_dir: str | Path,
    *,
    min_length: int = 3,
    thumb: int = 128,
    columns: int = 10,
    rows_per_sheet: int = 6,
) -> list[Path]:
    """PNG grids with one zoomed thumbnail per tracklet of at least ``min_length`` boxes: the crop
    around the tracklet's middle box (about three times its size, at least 120 px), box drawn in green,
    captioned ``<tracklet><colour initial> n<length>``. ``frames`` yields ``(frame key, BGR image)``.
    Returns the sheet paths (``tracklets_000.png``, …)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    boxed = {k: [r for r in v if r.box is not None] for k, v in labels.frames().items()}
    need: dict[str, list[tuple[int, LabelRow, int]]] = {}
    for t_id, t in enumerate(tracklets):
        if len(t) >= min_length:
            key, n = t[len(t) // 2]
            need.setdefault(key, []).append((t_id, boxed[key][n], len(t)))
    thumbs: dict[int, np.ndarray] = {}
    for key, img in frames:
        for t_id, r, length in need.get(key, []):
            assert r.box is not None
            x1, y1, x2, y2 = r.box
            cx, cy = (x1 + x2) // 2, (y1 + y2) // 2
            half = max(60, int(1.6 * max(x2 - x1, y2 - y1)))
            ox, oy = max(0, cx - half), max(0, cy - half)
            crop = img[oy : cy + half, ox : cx + half].copy()
            cv2.rectangle(crop, (x1 - ox - 1, y1 - oy - 1), (x2 - ox, y2 - oy), (0, 255, 0), 1)
            crop = cv2.resize(crop, (thumb, thumb))
            text = f"{t_id}{r.colour[:1]} n{length}"
            cv2.putText(crop, text, (2, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 3)
            cv2.putText(crop, text, (2, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 255, 255), 1)
            thumbs[t_id] = crop
    per = columns * rows_per_sheet
    ids = sorted(thumbs)
    paths = []
    for s in range(0, len(ids), per):
        batch = [thumbs[i] for i in ids[s : s + per]]
        batch += [np.zeros((thumb, thumb, 3), np.uint8)] * (per - len(batch))
        grid = np.vstack([np.hstack(batch[r * columns : (r + 1) * columns]) for r in range(rows_per_sheet)])
        path = out / f"tracklets_{s // per:03d}.png"
        cv2.imwrite(str(path), grid)
        paths.append(path)
    return paths
