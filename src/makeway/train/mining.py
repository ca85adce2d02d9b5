"""Data engine, step one: mine an unlabelled crop pool for review (SPEC §1 "Data engine", seed 000 §3.3.2).

Seed 000 is the Aurora paper on a per-frame EV crop CNN with a per-track output smoother
(``../shared/seeds/000_…``, digested in SPEC §1).

Seed 000 runs the EV classifier over new logs and collects *every* active-EV detection — true or
false positive — as hard samples to label and train on. :func:`mine` does that for a folder of crops
(e.g. ``<shared data>/vision/ev_crops/unlabelled``):

1. :func:`list_pool` lists every file under the pool, recursively (hidden files skipped);
2. :func:`score_pool` reads each with OpenCV, scores it with a crop classifier (anything with
   ``predict_proba`` and ``input_size``, see
   :func:`~makeway.perceive.vision.ev_classifier.load_crop_classifier`) in batches; files OpenCV
   cannot decode are counted and listed, not fatal;
3. :func:`write_review` writes, all-or-nothing per file:

   * ``candidates.csv`` — ``rank,image,probability,emergency``: every image scored at or above the
     threshold, most confident first, ``emergency`` blank for the reviewer (1 = emergency vehicle,
     0 = not — the false positives are the hard negatives worth adding);
   * ``contact_sheet.png`` — the top N thumbnails in a grid with rank and probability;
   * ``labels_template.csv`` — the same images in the crop-folder format ``image,emergency``
     (``image`` relative to the pool): fill the column, copy the images into a crop folder's
     ``images/`` and append the rows to its ``labels.csv`` (:func:`makeway.sense.crops.read_crop_folder`).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from makeway.atomic import atomic_path, write_text_atomic
from makeway.errors import InputError

__all__ = ["MiningResult", "contact_sheet", "list_pool", "mine", "score_pool", "write_review"]


@dataclass
class MiningResult:
    """What :func:`mine` found: scores of every readable image and the unreadable files."""

    pool: Path
    paths: list[Path]  # readable images, in pool order
    probabilities: np.ndarray  # (n,) P(emergency vehicle)
    unreadable: list[Path]
    threshold: float
    outputs: dict[str, Path] = field(default_factory=dict)

    def candidates(self) -> list[tuple[int, Path, float]]:
        """``(rank, path, probability)`` of the images at or above the threshold, most likely first
        (ties keep pool order)."""
        order = np.argsort(-self.probabilities, kind="stable")
        keep = [int(i) for i in order if self.probabilities[i] >= self.threshold]
        return [(r, self.paths[i], float(self.probabilities[i])) for r, i in enumerate(keep, start=1)]

    def summary(self) -> dict[str, Any]:
        """Counts and outputs for the CLI's JSON line."""
        return {
            "pool": str(self.pool),
            "files": len(self.paths) + len(self.unreadable),
            "scored": len(self.paths),
            "unreadable": len(self.unreadable),
            "threshold": self.threshold,
            "candidates": int(np.sum(self.probabilities >= self.threshold)),
            "outputs": {k: str(v) for k, v in self.outputs.items()},
        }


def list_pool(pool: str | Path) -> list[Path]:
    """Every regular, non-hidden file under ``pool`` (recursively), sorted.

    Raises:
        InputError: ``pool`` is not a folder, or holds no files.
    """
    root = Path(pool)
    if not root.is_dir():
        raise InputError(root, "pool folder not found (expected a folder of image crops)")
    files = sorted(
        p
        for p in root.rglob("*")
        if p.is_file() and not any(part.startswith(".") for part in p.relative_to(root).parts)
    )
    if not files:
        raise InputError(root, "pool folder holds no files")
    return files


def _read(path: Path, size: int) -> np.ndarray | None:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR) if cv2.haveImageReader(str(path)) else None
    if image is None or image.size == 0:
        return None
    h, w = image.shape[:2]
    if (h, w) != (size, size):
        interp = cv2.INTER_AREA if h > size or w > size else cv2.INTER_LINEAR
        image = cv2.resize(image, (size, size), interpolation=interp)
    return image


def score_pool(
    files: Sequence[Path],
    classifier: Any,
    *,
    batch: int = 64,
    advance: Callable[[int], Any] | None = None,
) -> tuple[list[Path], np.ndarray, list[Path]]:
    """Score every readable image of ``files``; returns ``(readable, probabilities, unreadable)``.

    Images are resized to ``classifier.input_size`` and scored ``batch`` at a time.
    """
    if batch < 1:
        raise ValueError(f"batch must be >= 1, got {batch}")
    size = int(classifier.input_size)
    readable: list[Path] = []
    unreadable: list[Path] = []
    probs: list[np.ndarray] = []
    pending: list[np.ndarray] = []

    def flush() -> None:
        if pending:
            probs.append(np.asarray(classifier.predict_proba(np.stack(pending)), dtype=np.float64).ravel())
            pending.clear()

    for path in files:
        image = _read(path, size)
        if image is None:
            unreadable.append(path)
        else:
            readable.append(path)
            pending.append(image)
            if len(pending) >= batch:
                flush()
        if advance is not None:
            advance(1)
    flush()
    scores = np.concatenate(probs) if probs else np.empty(0, dtype=np.float64)
    return readable, scores, unreadable


def contact_sheet(
    paths: Sequence[Path], probabilities: Sequence[float], *, columns: int = 8, thumb: int = 128
) -> np.ndarray:
    """A BGR grid of thumbnails, each captioned ``#rank p=0.97`` (rank = position + 1)."""
    if columns < 1 or thumb < 32:
        raise ValueError("columns must be >= 1 and thumb >= 32")
    n = len(paths)
    cols = max(1, min(columns, n))
    rows = max(1, math.ceil(n / cols))
    sheet = np.full((rows * thumb, cols * thumb, 3), 40, dtype=np.uint8)
    scale = thumb / 128.0
    for k, (path, p) in enumerate(zip(paths, probabilities, strict=True)):
        image = _read(path, thumb)
        if image is None:  # vanished since scoring; leave the cell grey
            continue
        r, c = divmod(k, cols)
        cell = image.copy()
        text = f"#{k + 1} p={p:.2f}"
        cv2.rectangle(cell, (0, 0), (thumb - 1, int(18 * scale)), (0, 0, 0), -1)
        cv2.putText(
            cell, text, (3, int(14 * scale)), cv2.FONT_HERSHEY_SIMPLEX, 0.45 * scale, (255, 255, 255), 1
        )
        sheet[r * thumb : (r + 1) * thumb, c * thumb : (c + 1) * thumb] = cell
    return sheet


def _csv(rows: Sequence[Sequence[Any]]) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerows(rows)
    return buf.getvalue()


def write_review(result: MiningResult, out_dir: str | Path, *, top: int = 64) -> dict[str, Path]:
    """Write ``candidates.csv``, ``contact_sheet.png`` (top ``top``) and ``labels_template.csv``."""
    out = Path(out_dir)
    cands = result.candidates()
    rel = [p.relative_to(result.pool).as_posix() for _, p, _ in cands]
    rows: list[list[Any]] = [["rank", "image", "probability", "emergency"]]
    rows += [[r, name, f"{p:.6f}", ""] for (r, _, p), name in zip(cands, rel, strict=True)]
    paths = {
        "candidates": out / "candidates.csv",
        "contact_sheet": out / "contact_sheet.png",
        "labels_template": out / "labels_template.csv",
    }
    write_text_atomic(paths["candidates"], _csv(rows))
    write_text_atomic(paths["labels_template"], _csv([["image", "emergency"], *([n, ""] for n in rel)]))
    shown = cands[: max(0, top)]
    sheet = contact_sheet([p for _, p, _ in shown], [p for _, _, p in shown])
    with atomic_path(paths["contact_sheet"]) as tmp:
        if not cv2.imwrite(str(tmp), sheet):
            raise OSError(f"{paths['contact_sheet']}: OpenCV could not write the contact sheet")
    result.outputs.update(paths)
    return paths


def mine(
    pool: str | Path,
    classifier: Any,
    out_dir: str | Path,
    *,
    top: int = 64,
    threshold: float | None = None,
    batch: int = 64,
    progress: bool = True,
) -> MiningResult:
    """Score a pool with ``classifier`` and write the review files (module docstring).

    Args:
        pool: folder of crops (searched recursively).
        classifier: crop classifier with ``predict_proba(uint8 BGR (n, s, s, 3))`` and ``input_size``,
            or its name or file (:func:`~makeway.perceive.vision.ev_classifier.load_crop_classifier`).
        out_dir: where the three files go (created).
        top: thumbnails on the contact sheet.
        threshold: candidates are images at or above this probability (default: the classifier's
            own ``threshold``, else 0.5).
        batch: images per classifier call.
        progress: show a progress bar.
    """
    from makeway.progress import progress_bar

    if isinstance(classifier, str | Path):
        from makeway.perceive.vision.ev_classifier import load_crop_classifier

        classifier = load_crop_classifier(classifier)

    thr = float(threshold if threshold is not None else getattr(classifier, "threshold", 0.5))
    if not 0.0 <= thr <= 1.0:
        raise ValueError(f"threshold must lie in [0, 1], got {thr}")
    root = Path(pool)
    files = list_pool(root)
    with progress_bar(f"mine {root.name}", len(files), enabled=progress, unit="images") as adv:
        readable, probs, unreadable = score_pool(files, classifier, batch=batch, advance=adv)
    result = MiningResult(root, readable, probs, unreadable, thr)
    write_review(result, out_dir, top=top)
    return result
