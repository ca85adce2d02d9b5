"""Corrections to a YOLO set's EV labels, and the two label sets they give (issue 24, "data is part of
the work").

The ``ambulance_yolo`` export labels ambulances only, and not all of them; makeway's EV is an
ambulance, a police vehicle or a fire engine, lights on or off. A by-eye audit of every crop of
``makeway classify build-ambulance-crops`` and every held-out image
(``docs/data_card_ambulance_yolo.md``) is committed as rows of
``makeway/data/ambulance_yolo_corrections.csv`` (:data:`CORRECTIONS_FILE`)::

    image,x1,y1,x2,y2,was,label,kind,note

* ``image`` — the image's file stem; ``x1,y1,x2,y2`` — the box in that image's pixels (x right,
  y down, origin top-left);
* ``was`` — ``labelled`` (a class-0 box of the original labels) or ``unlabelled``;
* ``label`` — ``ev`` (an emergency vehicle), ``not_ev`` (a vehicle that is none) or ``drop`` (no fair
  crop: a part of a vehicle, or a vehicle mostly outside the image);
* ``kind`` — one of :data:`KINDS`; ``note`` — free text. ``#`` lines are comments.

A row *matches* a box of its image when their IoU is at least :data:`MATCH_IOU`.

**Label sets** (:data:`LABEL_SETS`): ``original`` is the export as it is; ``corrected`` applies the
rows. On ground-truth boxes (:func:`corrected_boxes`): an ``ev`` row that matches no box adds its box,
a ``not_ev`` row removes the boxes it matches, a ``drop`` row changes nothing. On labelled crops
(:func:`correct_crop_items`): the crop whose source box a row matches gets label 1 (``ev``) or 0
(``not_ev``) or is left out (``drop``); an ``ev`` row that matches no crop's box adds a crop of its
box.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from makeway.errors import InputError
from makeway.messages import Box

__all__ = [
    "CORRECTIONS_FILE",
    "KINDS",
    "LABELS",
    "LABEL_SETS",
    "MATCH_IOU",
    "LabelCorrection",
    "LabelSet",
    "check_label_set",
    "correct_crop_items",
    "corrected_boxes",
    "corrections_by_image",
    "read_corrections",
]

#: The committed corrections of ``ambulance_yolo/valid`` (module docstring).
CORRECTIONS_FILE = Path(__file__).resolve().parents[1] / "data" / "ambulance_yolo_corrections.csv"
#: The label sets a command can score against.
LABEL_SETS = ("original", "corrected")
#: What a row says its box is.
LABELS = ("ev", "not_ev", "drop")
#: The kinds of vehicle (or of problem) a row names.
KINDS = ("ambulance", "police", "fire", "ev_unknown", "ev_part", "cut_off", "vehicle")
#: Lowest IoU at which a row's box is the same object as a labelled or detected box.
MATCH_IOU = 0.5
_COLUMNS = ("image", "x1", "y1", "x2", "y2", "was", "label", "kind", "note")


@dataclass(frozen=True)
class LabelCorrection:
    """One row of a corrections file: ``box`` (pixels) in image ``image`` (file stem) is ``label``
    (:data:`LABELS`) of ``kind`` (:data:`KINDS`); ``was`` says whether the original labels had it;
    ``row`` is its line number in the file."""

    image: str
    box: Box
    was: str
    label: str
    kind: str
    note: str
    row: int


def check_label_set(labels: str) -> str:
    """``labels`` normalised (stripped, lower case).

    Raises:
        ValueError: not one of :data:`LABEL_SETS`.
    """
    name = labels.strip().lower()
    if name not in LABEL_SETS:
        raise ValueError(f"unknown label set {labels!r}; one of {', '.join(LABEL_SETS)}")
    return name


def read_corrections(path: str | Path = CORRECTIONS_FILE) -> list[LabelCorrection]:
    """The rows of a corrections file (module docstring), in file order.

    Raises:
        InputError: the file is missing or unreadable, a column is missing, or a row is malformed —
            one line naming the file and the row (a field count, an empty image, a coordinate
            that is no finite number, a box with no area, an unknown ``was``/``label``/``kind``, or
            a box listed twice for one image).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "label corrections file not found")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot be read as a label corrections CSV ({exc})") from None
    numbered = [(n, ln) for n, ln in enumerate(text.splitlines(), start=1) if not ln.lstrip().startswith("#")]
    numbered = [(n, ln) for n, ln in numbered if ln.strip()]
    if not numbered:
        raise InputError(path, f"no header; expected {','.join(_COLUMNS)}")
    header = [c.strip().lower() for c in next(csv.reader([numbered[0][1]]))]
    missing = [c for c in _COLUMNS if c not in header]
    if missing:
        raise InputError(
            path,
            f"line {numbered[0][0]}: missing column(s) {', '.join(missing)}; expected {','.join(_COLUMNS)}",
        )
    at = {c: header.index(c) for c in _COLUMNS}
    out: list[LabelCorrection] = []
    seen: set[tuple[str, tuple[float, ...]]] = set()
    for n, line in numbered[1:]:
        fields = next(csv.reader(io.StringIO(line)), [])
        if len(fields) != len(header):
            raise InputError(path, f"row {n}: {len(fields)} fields, the header has {len(header)}")

        def value(column: str, fields: list[str] = fields) -> str:
            return fields[at[column]].strip()

        image = value("image")
        if not image:
            raise InputError(path, f"row {n}: empty image name")
        coords: list[float] = []
        for c in ("x1", "y1", "x2", "y2"):
            try:
                v = float(value(c))
            except ValueError:
                raise InputError(path, f"row {n}: {c} must be a number (pixels), got {value(c)!r}") from None
            if not math.isfinite(v):
                raise InputError(path, f"row {n}: {c} must be a finite number (pixels), got {value(c)!r}")
            coords.append(v)
        box = Box(*coords)
        if box.width <= 0 or box.height <= 0:
            raise InputError(path, f"row {n}: the box has no area (x1 < x2 and y1 < y2 needed)")
        was, label, kind = value("was").lower(), value("label").lower(), value("kind").lower()
        if was not in ("labelled", "unlabelled"):
            raise InputError(path, f"row {n}: was must be labelled or unlabelled, got {value('was')!r}")
        if label not in LABELS:
            raise InputError(
                path, f"row {n}: label must be one of {', '.join(LABELS)}, got {value('label')!r}"
            )
        if kind not in KINDS:
            raise InputError(path, f"row {n}: kind must be one of {', '.join(KINDS)}, got {value('kind')!r}")
        key = (image, tuple(round(v, 1) for v in coords))
        if key in seen:
            raise InputError(
                path,
                f"row {n}: image {image!r} has this box ({', '.join(f'{v:g}' for v in coords)}) twice",
            )
        seen.add(key)
        out.append(LabelCorrection(image, box, was, label, kind, value("note"), n))
    return out


def corrections_by_image(rows: Iterable[LabelCorrection]) -> dict[str, list[LabelCorrection]]:
    """The rows grouped by image stem (file order kept within an image)."""
    out: dict[str, list[LabelCorrection]] = {}
    for row in rows:
        out.setdefault(row.image, []).append(row)
    return out


def _best_match(box: Box, candidates: Sequence[Box]) -> int | None:
    """Index of the candidate of highest IoU with ``box`` when that IoU is at least
    :data:`MATCH_IOU`, else ``None``."""
    best, best_iou = None, MATCH_IOU
    for k, c in enumerate(candidates):
        v = box.iou(c)
        if v >= best_iou:
            best, best_iou = k, v
    return best


def corrected_boxes(boxes: Sequence[Box], rows: Sequence[LabelCorrection]) -> list[Box]:
    """An image's ground-truth EV boxes under its correction ``rows`` (module docstring): boxes a
    ``not_ev`` row matches are removed, ``ev`` rows that match no box are added (after the kept
    boxes, in row order), ``drop`` rows change nothing."""
    kept = [b for b in boxes if not any(r.label == "not_ev" and r.box.iou(b) >= MATCH_IOU for r in rows)]
    added = [r.box for r in rows if r.label == "ev" and _best_match(r.box, list(boxes)) is None]
    return kept + added


def correct_crop_items(
    items: Iterable[tuple[str, np.ndarray, int]],
    source_boxes: Mapping[str, Box],
    rows: Sequence[LabelCorrection],
    crop_of: Callable[[Box], np.ndarray | None],
) -> Iterator[tuple[str, np.ndarray, int]]:
    """An image's labelled crops ``(tag, crop, label)`` under its correction ``rows``.

    ``source_boxes[tag]`` is the box each crop was cut around. Each row matches at most one crop (the
    one whose box has the highest IoU ≥ :data:`MATCH_IOU`), and each crop at most one row (the first
    in the file): that crop gets label 1 (``ev``) or 0 (``not_ev``), or is left out (``drop``). Each
    ``ev`` row that matches no crop adds ``("c<k>", crop_of(box), 1)`` (``k``: the row's index among
    the image's rows) when ``crop_of`` gives a crop (``None``: too small or off the image).
    """
    listed = list(items)
    tags = [t for t, _, _ in listed]
    boxes = [source_boxes[t] for t in tags]
    verdict: dict[str, str] = {}
    unmatched: list[tuple[int, LabelCorrection]] = []
    for k, row in enumerate(rows):
        free = [i for i, t in enumerate(tags) if t not in verdict]
        hit = _best_match(row.box, [boxes[i] for i in free])
        if hit is None:
            unmatched.append((k, row))
        else:
            verdict[tags[free[hit]]] = row.label
    for tag, crop, label in listed:
        new = verdict.get(tag)
        if new == "drop":
            continue
        yield tag, crop, (label if new is None else int(new == "ev"))
    for k, row in unmatched:
        if row.label != "ev":
            continue
        added = crop_of(row.box)
        if added is not None:
            yield f"c{k}", added, 1


class LabelSet:
    """The class-0 ground truth of ``ambulance_yolo`` under one label set (:data:`LABEL_SETS`):
    ``original`` leaves every image's boxes as they are, ``corrected`` applies the committed rows
    (:data:`CORRECTIONS_FILE`, or ``path``) image by image; :attr:`changed` counts the boxes added
    or removed so far.

    Raises:
        ValueError: an unknown label set.
        InputError: the corrections file is missing or malformed (names the file).
    """

    def __init__(self, labels: str, path: str | Path = CORRECTIONS_FILE) -> None:
        self.labels = check_label_set(labels)
        self.rows = corrections_by_image(read_corrections(path)) if self.labels == "corrected" else {}
        self.changed = 0

    def boxes(self, stem: str, boxes: Sequence[Box]) -> list[Box]:
        """Image ``stem``'s ground-truth EV boxes under this label set."""
        rows = self.rows.get(stem)
        if not rows:
            return list(boxes)
        fixed = corrected_boxes(boxes, rows)
        self.changed += len(set(fixed) ^ set(boxes))
        return fixed
