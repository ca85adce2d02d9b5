"""``makeway engine …``: the data engine (issue 28) — mine many inputs on a Dask cluster, and feed
the labels a person wrote on the mined samples back into training.

The mining job is :func:`makeway.engine.cluster.mine_inputs`.
:func:`engine_feedback` closes seed 000's loop: the labels file (the job's ``labels_template.csv``
with the ``emergency`` column filled: 1 = emergency vehicle, 0 = not, blank = not reviewed) becomes a
crop folder (``images/`` + ``labels.csv`` with a ``group`` per input and track), which joins the
training sources of the cross-source protocol (issue 24, :mod:`makeway.eval.cross_source`). The
``head`` recipe (the shipped default classifier's) is fitted leave-one-source-out without and with
the mined crops, and each held-out source is scored both ways: the before/after of the feedback.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from makeway.atomic import atomic_dir, check_writable, write_text_atomic
from makeway.errors import InputError

__all__ = ["FeedbackRun", "engine_feedback", "labelled_crop_folder"]


def _group(image: str) -> str:
    """``<input id>/crops/t7_f000120.jpg`` → ``<input id>#t7`` (one vehicle track of one input);
    an image-folder crop ``<id>/crops/<stem>_d2.jpg`` → ``<id>#<stem>``."""
    parts = Path(image).parts
    stem = Path(image).stem
    track = stem.split("_f")[0] if stem.startswith("t") and "_f" in stem else stem.rsplit("_d", 1)[0]
    return f"{parts[0]}#{track}"


def labelled_crop_folder(mined: str | Path, labels: str | Path, out: str | Path) -> dict[str, int]:
    """Write the crop folder ``out`` from the labels file ``labels`` (``image,emergency``, images
    relative to ``mined/inputs``); blank labels are skipped. Returns the counts ``labelled``,
    ``positive``, ``negative``, ``unreviewed``.

    Raises:
        InputError: the labels file is missing, lacks a column, has a label other than 0, 1 or
            blank (with its line), names an image that is not in ``mined/inputs``, or labels nothing.
    """
    from makeway.sense.crops import write_crop_folder

    src = Path(mined) / "inputs"
    path = Path(labels)
    if not path.is_file():
        raise InputError(path, "labels file not found")
    if not src.is_dir():
        raise InputError(
            Path(mined), "not a mining output (no inputs/ folder); run `makeway engine mine` first"
        )
    rows: list[tuple[str, int]] = []
    unreviewed = 0
    with path.open(newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        missing = {"image", "emergency"} - set(reader.fieldnames or [])
        if missing:
            raise InputError(
                path, f"missing column(s) {', '.join(sorted(missing))} (expected image,emergency)"
            )
        for line, row in enumerate(reader, start=2):
            value = (row["emergency"] or "").strip()
            if value == "":
                unreviewed += 1
                continue
            if value not in ("0", "1"):
                raise InputError(path, f"line {line}: emergency must be 0, 1 or blank, not {value!r}")
            if not (src / row["image"]).is_file():
                raise InputError(path, f"line {line}: {row['image']} is not a mined crop under {src}")
            rows.append((row["image"], int(value)))
    if not rows:
        raise InputError(path, "labels nothing: fill the emergency column (1 = emergency vehicle, 0 = not)")

    import cv2

    def items() -> Any:
        for image, label in rows:
            crop = cv2.imread(str(src / image), cv2.IMREAD_COLOR)
            if crop is None:
                raise InputError(src / image, "OpenCV could not read this mined crop")
            yield image.replace("/", "__"), crop, label, _group(image)

    with atomic_dir(out) as stage:
        write_crop_folder(stage, items())
    pos = sum(label for _, label in rows)
    return {"labelled": len(rows), "positive": pos, "negative": len(rows) - pos, "unreviewed": unreviewed}


@dataclass
class FeedbackRun:
    """What :func:`engine_feedback` measured: per held-out source, the score of the ``head`` recipe
    trained without (``before``) and with (``after``) the mined crops, and the files written."""

    counts: dict[str, int]
    rows: list[dict[str, Any]]
    outputs: dict[str, str] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def engine_feedback(
    mined: str | Path,
    labels: str | Path,
    out: str | Path,
    *,
    held_out: Sequence[str] | None = None,
    cache: str | Path | None = None,
    data: str | Path | None = None,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> FeedbackRun:
    """Turn the labelled mined samples into a crop folder ``OUT/mined_crops`` and report how they
    change the ``head`` recipe on the cross-source protocol (module docstring): ``OUT/feedback.json``
    and ``OUT/feedback.md``. ``held_out`` picks the folds (default: every built-in source).

    Raises:
        InputError: the labels or the mining output are unusable (:func:`labelled_crop_folder`), or
            ``out`` cannot be written (checked first).
    """
    from makeway.apps.classify import CROSS_SOURCES, cross_source_evaluation

    target = check_writable(out, folder=True)
    folds = list(held_out) if held_out else list(CROSS_SOURCES)
    crops = target / "mined_crops"
    counts = labelled_crop_folder(mined, labels, crops)
    common: dict[str, Any] = {"cache": cache, "data": data, "progress": progress, "log": log}
    before = cross_source_evaluation(train=["head"], held_out=folds, sources=list(CROSS_SOURCES), **common)
    after = cross_source_evaluation(
        train=["head"],
        held_out=folds,
        sources=[*CROSS_SOURCES, "mined"],
        extra=[("mined", crops)],
        **common,
    )
    b = {s.source: s for s in before.scores}
    a = {s.source: s for s in after.scores}
    rows = []
    for fold in folds:
        if fold in b and fold in a:
            rows.append(
                {
                    "held_out": fold,
                    "n": b[fold].n,
                    "accuracy_before": b[fold].accuracy,
                    "accuracy_after": a[fold].accuracy,
                    "f1_before": b[fold].f1,
                    "f1_after": a[fold].f1,
                    "recall_before": b[fold].recall,
                    "recall_after": a[fold].recall,
                    "specificity_before": b[fold].specificity,
                    "specificity_after": a[fold].specificity,
                }
            )
    run = FeedbackRun(counts, rows)
    from makeway.jsonable import to_jsonable

    def f(x: float | None) -> str:
        return "—" if x is None else f"{x:.3f}"

    lines = [
        "# Mined samples fed back (cross-source protocol, head recipe)",
        "",
        f"Mined crops labelled: {counts['labelled']} ({counts['positive']} emergency, "
        f"{counts['negative']} not; {counts['unreviewed']} left unreviewed). Each row: the recipe "
        "trained on the other sources, without (before) and with (after) the mined crops, scored on the "
        "held-out source. A held-out source cut from the same footage as the mined inputs is not "
        "independent of them.",
        "",
        "| held-out source | n | accuracy before | after | F1 before | after | recall before | after "
        "| specificity before | after |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['held_out']} | {r['n']} | {f(r['accuracy_before'])} | {f(r['accuracy_after'])} | "
            f"{f(r['f1_before'])} | {f(r['f1_after'])} | {f(r['recall_before'])} | {f(r['recall_after'])} | "
            f"{f(r['specificity_before'])} | {f(r['specificity_after'])} |"
        )
    run.outputs = {
        "crops": str(crops),
        "json": str(target / "feedback.json"),
        "markdown": str(target / "feedback.md"),
    }
    write_text_atomic(target / "feedback.json", json.dumps(to_jsonable(run.to_json()), indent=1) + "\n")
    write_text_atomic(target / "feedback.md", "\n".join(lines) + "\n")
    return run
