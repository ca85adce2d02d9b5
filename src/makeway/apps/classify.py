"""``makeway classify …``: emergency-vehicle crop data sets, the classical study, and scoring a crop
classifier.

Each function here is one command's work; it reads every input before it writes anything and
returns what the command prints. Training lives in :mod:`makeway.train` (``train.ev_head``,
``train.cnn``).
"""

from __future__ import annotations

import os
import platform
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from makeway.errors import InputError

if TYPE_CHECKING:
    from makeway.sense.crops import CropSet

__all__ = [
    "CROSS_SOURCES",
    "CropEvaluation",
    "CrossSourceRun",
    "StudyRun",
    "build_ambulance_crops",
    "built_cross_sources",
    "cross_source_evaluation",
    "evaluate_crop_classifier",
    "run_classical_study",
    "write_holdout_split",
]


def _versions() -> str:
    """The versions of the study's libraries that are installed, e.g. ``sklearn 1.5.0, cv2 4.10.0``."""
    out = []
    for mod in ("sklearn", "xgboost", "skimage", "cv2"):
        try:
            out.append(f"{mod} {__import__(mod).__version__}")
        except ImportError:
            continue
    return ", ".join(out)


@dataclass(frozen=True)
class StudyRun:
    """What :func:`run_classical_study` did: its ``rows``, the ``split`` name, the test crops
    ``n_test`` and the two files written (``study.md``, ``study.csv``)."""

    rows: list[Any]
    split: str
    n_test: int
    md_path: Path
    csv_path: Path


def run_classical_study(
    data: str | Path,
    out: str | Path,
    *,
    features: Sequence[str] | None = None,
    classifiers: Sequence[str] | None = None,
    skip: Sequence[str] = (),
    holdout: str | Path | None = None,
    fraction: float = 0.2,
    seed: int = 0,
    threads: int = 1,
    command: str = "",
    progress: bool = True,
) -> StudyRun:
    """The classical study: every feature × classifier of :mod:`makeway.train.classical` (default: all
    registered) fitted on the training part of the crop folder ``data`` and scored on its held-out
    part; ``skip`` lists ``FEATURE:CLASSIFIER`` pairs not to run. The held-out part is the names in
    ``holdout`` when given, else the committed ev_crops holdout when ``data`` is that set, else a
    ``fraction`` split by group (or near-duplicate cluster) with ``seed``. Writes ``OUT/study.md``
    (sorted table, with the data, split, machine and ``command`` as notes) and ``OUT/study.csv``,
    rewritten after every pair so an interrupted run keeps what is done.

    Raises:
        ValueError: a ``skip`` entry that is not ``FEATURE:CLASSIFIER`` with registered names.
        InputError: the crop folder or the holdout cannot be read.
    """
    from makeway.perceive.vision.features import FEATURES
    from makeway.sense.crops import (
        EV_CROPS_HOLDOUT,
        holdout_split,
        read_crop_folder,
        read_holdout,
        split_holdout,
    )
    from makeway.train.classical import CLASSIFIERS, StudyRow, compatible, run_study, write_study

    feats = list(features) if features else list(FEATURES)
    clfs = list(classifiers) if classifiers else list(CLASSIFIERS)
    skipped: list[tuple[str, str]] = []
    for pair in skip:
        feat, sep, clf = pair.partition(":")
        if not sep or feat not in FEATURES or clf not in CLASSIFIERS:
            raise ValueError(f"--skip takes FEATURE:CLASSIFIER with registered names, got {pair!r}")
        skipped.append((feat, clf))
    n_runs = sum(1 for f in feats for c in clfs if (f, c) not in skipped and compatible(f, c))
    crops = read_crop_folder(data)
    if holdout is not None:
        train_idx, test_idx = holdout_split(crops, read_holdout(holdout))
        split = f"holdout {Path(holdout).name}"
        how = f"the held-out names listed in `{holdout}`"
    else:
        committed = read_holdout(EV_CROPS_HOLDOUT) if EV_CROPS_HOLDOUT.is_file() else None
        if committed is not None and committed.matches(crops):
            train_idx, test_idx = holdout_split(crops, committed)
            split = "ev_crops holdout"
            how = (
                "the committed ev_crops holdout (`src/makeway/data/ev_crops_holdout.txt`: "
                f"{committed.meta.get('method', 'group split')})"
            )
        else:
            train_idx, test_idx = split_holdout(crops, fraction=fraction, seed=seed)
            by = "the folder's group column" if crops.groups is not None else "near-duplicate clusters"
            split = f"group split {fraction:g} seed {seed}"
            how = f"a {fraction:.0%} split by {by}, stratified by label, seed {seed}"
    train_set, test_set = crops.subset(train_idx), crops.subset(test_idx)
    notes = [
        f"Data: `{data}` — {len(crops)} crops, {crops.n_positive} positive (emergency vehicle).",
        f"Train: {len(train_set)} crops ({train_set.n_positive} positive); test: {len(test_set)} crops "
        f"({test_set.n_positive} positive), {how}. Nothing was tuned on the test part.",
        "Accuracy, precision, recall and F1 at each classifier's own decision rule; max-F1 and precision "
        "at recall 0.8 (P@R0.8) over thresholds of its score. Times: fit on the whole training part; "
        "predict and feature extraction per 100 test crops (one batch), "
        f"{threads} thread(s) on {os.cpu_count()} CPU(s) ({platform.machine()}), {_versions()}.",
        f"Command: `{command}`",
    ]
    if skipped:
        notes.append(f"Not run (too slow for this machine): {', '.join(f'{f} × {c}' for f, c in skipped)}.")
    rows: list[StudyRow] = []

    def partial(row: StudyRow) -> None:  # keep what is done if a long run is interrupted
        rows.append(row)
        write_study(rows, out, notes=[*notes, f"(partial: {len(rows)} of {n_runs} done)"])

    run_study(
        train_set,
        test_set,
        feats,
        clfs,
        split=split,
        n_jobs=threads,
        seed=seed,
        progress=progress,
        on_row=partial,
        skip=skipped,
    )
    md_path, csv_path = write_study(rows, out, notes=notes)
    return StudyRun(rows, split, len(test_set), md_path, csv_path)


def write_holdout_split(
    data: str | Path, out: str | Path, *, fraction: float = 0.2, seed: int = 0
) -> tuple[int, int, int]:
    """Write a held-out split of the crop folder ``data`` to ``out``: the names of about ``fraction``
    of the crops, whole groups (the ``group`` column, else near-duplicate clusters) at a time,
    stratified by label, with how it was made in the header. Returns ``(held out, crops, held-out
    positives)``.

    Raises:
        InputError: the crop folder cannot be read, or ``out`` cannot be written.
    """
    from makeway.sense.crops import read_crop_folder, split_holdout, write_holdout

    crops = read_crop_folder(data)
    _, test_idx = split_holdout(crops, fraction=fraction, seed=seed)
    if crops.groups is not None:
        method = "split by the group column of labels.csv"
    else:
        method = (
            "split by near-duplicate clusters (grey 32x32 thumbnails, mirror-aware correlation >= 0.85 "
            "or identical 8x8 average hash; makeway.sense.crops.near_duplicate_groups)"
        )
    meta = {
        "method": f"{method}, stratified by label",
        "fraction": f"{fraction:g}",
        "seed": str(seed),
        "command": (
            f"makeway classify holdout --data {data} --out {out} --fraction {fraction:g} --seed {seed}"
        ),
    }
    write_holdout(out, crops, test_idx, meta=meta)
    return len(test_idx), len(crops), int(crops.labels[test_idx].sum())


def build_ambulance_crops(
    out: str | Path,
    data: str | Path | None = None,
    *,
    ambulance_class: int = 0,
    detector: str = "yolox_nano",
    model: str | Path | None = None,
    score_threshold: float = 0.3,
    max_iou: float = 0.1,
    max_inside: float = 0.5,
    margin: float = 0.1,
    size: int = 224,
    threads: int = 1,
    progress: bool = True,
    labels: str = "corrected",
    corrections: str | Path | None = None,
) -> dict[str, int]:
    """A crop folder (``images/`` + ``labels.csv`` with a ``group`` column: the source photo) at
    ``out`` from the YOLO ambulance set ``data`` (default ``<shared data>/vision/ambulance_yolo/valid``).
    Every labelled box of ``ambulance_class`` is a positive; every ``detector`` vehicle whose IoU with
    all ambulance boxes is below ``max_iou`` and that lies less than ``max_inside`` of its area inside
    one is a negative. Crops are ``size`` × ``size`` px squares around the box with ``margin`` (of the
    box's longer side) of context per side; boxes under 18 px wide are skipped.

    ``labels="corrected"`` then applies the rows of ``corrections`` (default the committed
    :data:`~makeway.sense.label_corrections.CORRECTIONS_FILE`) to each image's crops
    (:func:`~makeway.sense.label_corrections.correct_crop_items`: relabelled, left out, or added as
    ``<stem>_c<k>`` crops); ``"original"`` keeps the export's labels.

    Returns the counts: ``images``, ``boxes`` (labelled ambulances), ``positive``, ``negative``,
    ``crops`` (written) and ``corrected`` (crops a correction row relabelled, left out or added).

    Raises:
        InputError: the data folder is not found, an image cannot be decoded, or the corrections file
            is malformed (nothing is written).
        UnknownNameError: an unknown detector (lists the known ones).
        ValueError: an unknown label set.
    """
    from functools import partial

    import cv2

    from makeway.messages import Box
    from makeway.paths import require_data_dir
    from makeway.perceive.vision.crops import detection_crop_items, square_crop
    from makeway.perceive.vision.detectors import DETECTORS
    from makeway.progress import progress_bar
    from makeway.sense.crops import read_yolo_set, roboflow_source, write_crop_folder
    from makeway.sense.label_corrections import (
        CORRECTIONS_FILE,
        LabelCorrection,
        check_label_set,
        correct_crop_items,
        corrections_by_image,
        read_corrections,
    )

    if data is None:
        data = require_data_dir() / "vision" / "ambulance_yolo" / "valid"
    fixes: dict[str, list[LabelCorrection]] = {}
    if check_label_set(labels) == "corrected":
        fixes = corrections_by_image(read_corrections(corrections or CORRECTIONS_FILE))
    images = read_yolo_set(data)
    det = DETECTORS[detector](
        model, score_threshold=score_threshold, class_agnostic=True, num_threads=threads
    )
    counts = {"images": len(images), "positive": 0, "negative": 0, "boxes": 0, "corrected": 0}

    def items(advance: Callable[[int], Any]) -> Iterator[tuple[str, np.ndarray, int, str | None]]:
        for item in images:
            image = cv2.imread(str(item.path), cv2.IMREAD_COLOR)
            if image is None:
                raise InputError(item.path, "OpenCV could not decode this image")
            positives = item.boxes_of(ambulance_class)
            counts["boxes"] += len(positives)
            boxes, _, _ = det.detect_arrays(image)
            group = roboflow_source(item.path.stem)
            found = list(
                detection_crop_items(
                    image, positives, boxes, max_iou=max_iou, max_inside=max_inside, margin=margin, size=size
                )
            )
            rows = fixes.get(item.path.stem, [])
            if rows:
                source = {f"p{k}": b for k, b in enumerate(positives)}
                source.update({f"n{k}": Box(*(float(v) for v in b[:4])) for k, b in enumerate(boxes)})
                before = {tag: label for tag, _, label in found}
                found = list(
                    correct_crop_items(
                        found, source, rows, partial(square_crop, image, margin=margin, size=size)
                    )
                )
                after = {tag: label for tag, _, label in found}
                counts["corrected"] += sum(
                    1 for t in before.keys() | after.keys() if before.get(t) != after.get(t)
                )
            for tag, crop, label in found:
                counts["positive" if label else "negative"] += 1
                yield f"{item.path.stem}_{tag}.jpg", crop, label, group
            advance(1)

    with progress_bar("crops from images", len(images), enabled=progress, unit="images") as adv:
        counts["crops"] = write_crop_folder(out, items(adv))
    return counts


@dataclass(frozen=True)
class CropEvaluation:
    """What :func:`evaluate_crop_classifier` scored: ``metrics``
    (:func:`~makeway.eval.classification.operating_point_metrics`), the crops left out as unreadable
    (``skipped``), whether only the committed held-out part was scored (``held_out``), how many crops
    were scored (``n``) and the PR curve written (``plot``, or ``None``)."""

    metrics: dict[str, Any]
    skipped: list[str]
    held_out: bool
    n: int
    plot: Path | None


def evaluate_crop_classifier(
    data: str | Path,
    model: str = "default",
    *,
    plot: str | Path | None = None,
    on_skip: Callable[[InputError], None] | None = None,
    log: Callable[[str], None] | None = None,
) -> CropEvaluation:
    """Score the crop classifier ``model`` (a shipped name — ``default``, ``general``, ``fast``,
    ``fastest``, ``imagenet`` — or a head ``.npz`` / CNN ``.onnx``) on the crop folder ``data`` at its
    own decision threshold; on ev_crops and on the ambulance_yolo crops only the committed held-out
    part is scored (:func:`~makeway.sense.crops.training_split`). A crop that cannot be read is
    left out, passed to ``on_skip`` and listed in ``skipped``; the rest is scored. With ``plot``,
    also writes the precision–recall curve (operating point and max-F1 marked) as PNG. ``log``
    receives a line saying which crops are scored, before they are read, and one naming the plot.

    Raises:
        InputError: the model or the crop folder cannot be read, or ``plot`` cannot be written (checked
            first); an unknown model name lists the shipped ones.
    """
    from makeway.atomic import check_writable
    from makeway.eval.classification import operating_point_metrics
    from makeway.perceive.vision.ev_classifier import SHIPPED_MODELS, load_crop_classifier
    from makeway.sense.crops import ambulance_held_out_split, committed_split, read_crop_folder

    def say(line: str) -> None:
        if log is not None:
            log(line)

    if plot is not None:
        check_writable(plot, folder=False)
    clf = load_crop_classifier(model)
    crops = read_crop_folder(data)
    split, source = committed_split(crops), "ev_crops"
    if split is None:
        split, source = ambulance_held_out_split(crops), "ambulance_yolo"
    if split is not None:
        crops = crops.subset(split[1])
        say(f"{source}: scoring the committed held-out part only ({len(crops)} crops)")
    else:
        say(f"scoring all {len(crops)} crops of {data}")
    skipped: list[str] = []

    def skip(exc: InputError) -> None:
        skipped.append(str(exc.path))
        if on_skip is not None:
            on_skip(exc)

    crops, images = crops.load_readable(clf.input_size, on_bad=skip)
    probs = clf.predict_proba(images)
    if plot is not None:
        from makeway.viz.pr_plot import plot_pr_curve

        name = Path(SHIPPED_MODELS.get(model.strip().lower(), model)).name
        what = "held-out part" if split is not None else "all crops"
        plot_pr_curve(
            probs, crops.labels, plot, threshold=clf.threshold, title=f"{name} on {Path(data).name} ({what})"
        )
        say(f"PR curve → {plot}")
    return CropEvaluation(
        metrics=operating_point_metrics(probs, crops.labels, clf.threshold),
        skipped=skipped,
        held_out=split is not None,
        n=len(crops),
        plot=None if plot is None else Path(plot),
    )


# ------------------------------------------------------------------------------------- cross-source

#: The labelled crop sources of the cross-source protocol (issue 24), in report order: ``ev_crops``
#: (web photos), ``ambulance_yolo`` (crops of the Roboflow road photos, :func:`build_ambulance_crops`)
#: and ``road_clips`` (the labelled tracks of the shared road clips,
#: :func:`makeway.pipeline.track_crops.build_track_crops`).
CROSS_SOURCES = ("ev_crops", "ambulance_yolo", "road_clips")

#: Trainers the protocol can fit leave-one-source-out: ``head`` = the shipped ``default`` head's
#: recipe (YOLOX-nano + NanoDet-m backbone features, mirror images, logistic regression);
#: ``effnet_ft`` = EfficientNet-Lite0 fine-tuned at 224 px (:mod:`makeway.train.effnet`; needs torch).
CROSS_SOURCE_TRAINERS = ("head", "effnet_ft")


@dataclass(frozen=True)
class CrossSourceRun:
    """What :func:`cross_source_evaluation` scored: every (model, held-out source) score in order,
    the worst source of each model (by accuracy), and each source's folder and crop counts
    (``sources[name] = {"folder", "n", "positive"}``) and the label set of ``ambulance_yolo``."""

    scores: list[Any]
    worst: dict[str, Any]
    sources: dict[str, dict[str, Any]]
    labels: str = "corrected"


def _cache_key(**parts: Any) -> str:
    import hashlib
    import json

    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:12]


def _file_digest(path: Path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]


def built_cross_sources(
    names: Sequence[str],
    data: Path | None,
    cache: Path,
    *,
    labels: str = "corrected",
    every: int = 5,
    threads: int = 1,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> dict[str, CropSet]:
    """The crop sets of the shared sources ``names`` (of :data:`CROSS_SOURCES`), in that order:
    ``ev_crops`` with near-duplicate clusters as groups; ``ambulance_yolo`` (``labels`` =
    ``corrected`` or ``original``) and ``road_clips`` (one crop every ``every`` frames of a labelled
    track) built on first use into ``cache/sources`` (video boxes in ``cache/clip_boxes``). ``data``
    is the shared data folder (needed when ``names`` is not empty).

    Raises:
        InputError: the data folder, the ambulance_yolo set or a labelled road clip is missing.
        ValueError: an unknown label set.
    """
    from makeway.paths import require_data_dir
    from makeway.sense.crops import CropSet, near_duplicate_groups, read_crop_folder
    from makeway.sense.label_corrections import CORRECTIONS_FILE, check_label_set

    def say(line: str) -> None:
        if log is not None:
            log(line)

    labels = check_label_set(labels)
    wanted = [n for n in names if n in CROSS_SOURCES]
    if not wanted:
        return {}
    base, root = require_data_dir(data), cache
    crop_sets: dict[str, CropSet] = {}
    for name in wanted:
        if name == "ev_crops":
            crops = read_crop_folder(base / "vision" / "ev_crops")
            # near-duplicate clusters as groups: kept in one fold of a trainer's inner CV
            images = crops.load_images(64, cache=False)
            groups = near_duplicate_groups(images).astype(str)
            crop_sets[name] = CropSet(crops.paths, crops.labels, groups, crops.root)
        elif name == "ambulance_yolo":
            yolo = base / "vision" / "ambulance_yolo" / "valid"
            if not yolo.is_dir():
                raise InputError(yolo, "ambulance_yolo set not found")
            if labels == "original":  # the key of the original set is kept: its cache stays valid
                key = _cache_key(data=yolo.resolve(), v=1)
            else:
                key = _cache_key(data=yolo.resolve(), v=1, corrections=_file_digest(CORRECTIONS_FILE))
            folder = root / "sources" / f"ambulance_yolo-{key}"
            if not (folder / "labels.csv").is_file():
                say(f"building the ambulance_yolo crops ({labels} labels) → {folder}")
                build_ambulance_crops(folder, yolo, threads=threads, progress=progress, labels=labels)
            crop_sets[name] = read_crop_folder(folder)
        else:  # road_clips
            from makeway.eval.actor_sweep import TRACK_LABELS, read_track_labels
            from makeway.pipeline.track_crops import build_track_crops

            clips = [base / "video" / f"{c}.mp4" for c in read_track_labels(TRACK_LABELS).clips]
            for clip in clips:
                if not clip.is_file():
                    raise InputError(clip, "road clip not found (its tracks are labelled in the package)")
            key = _cache_key(
                clips=[(c.name, c.stat().st_size) for c in clips],
                labels=_file_digest(TRACK_LABELS),
                every=every,
            )
            folder = root / "sources" / f"road_clips-{key}"
            if not (folder / "labels.csv").is_file():
                say(f"building the road-clip track crops → {folder}")
                build_track_crops(
                    folder, clips, cache_dir=root / "clip_boxes", every=every, progress=progress
                )
            crop_sets[name] = read_crop_folder(folder)
    return crop_sets


def cross_source_evaluation(
    models: Sequence[str] = (),
    train: Sequence[str] = (),
    *,
    sources: Sequence[str] | None = None,
    extra: Sequence[tuple[str, str | Path]] = (),
    data: str | Path | None = None,
    cache: str | Path | None = None,
    every: int = 5,
    threads: int = 1,
    held_out: Sequence[str] | None = None,
    input_size: int = 224,
    progress: bool = True,
    on_score: Callable[[Any], None] | None = None,
    log: Callable[[str], None] | None = None,
    labels: str = "corrected",
    match_quality: bool = False,
) -> CrossSourceRun:
    """The cross-source protocol (:mod:`makeway.eval.cross_source`) over the labelled crop sources.

    ``models`` are fixed crop classifiers (shipped names ``default``, ``fast``, ``fastest``,
    ``imagenet`` or head ``.npz`` / CNN ``.onnx`` files), each scored on every source — on
    ``ev_crops`` only its committed held-out part, as the shipped models learnt the rest. ``train``
    names trainers (:data:`CROSS_SOURCE_TRAINERS`), each fitted leave-one-source-out and scored on
    the whole held-out source (``held_out``: only these folds, in this order; default: every
    source; ``input_size``: the ``effnet_ft`` trainer's crop side in px). ``extra`` adds
    ``(name, crop folder)`` sources (e.g. one you labelled; a ``group`` column keeps related crops
    together); ``sources`` picks among
    :data:`CROSS_SOURCES` and those (default: all). ``ambulance_yolo`` and ``road_clips`` are built
    on first use into ``cache`` (default ``~/.cache/makeway/cross_source``; ``every`` = the frame
    step between a track's crops), as are the backbone features of the heads. ``data`` is the
    shared data folder (default: found as :func:`makeway.paths.data_dir` does). ``labels`` is the
    label set of ``ambulance_yolo`` (``corrected``: the committed audit's corrections applied,
    :mod:`makeway.sense.label_corrections`; ``original``: the export as it is); each set is built
    and cached apart. ``match_quality``: the ``train`` recipes first make each source's positive
    crops as soft as its negatives (:mod:`makeway.train.crop_quality`; in road photos and video
    the EV is usually the sharpest vehicle, so sharpness would otherwise tell the class).
    ``on_score`` gets each score when known; ``log`` a line per step.

    Raises:
        InputError: the data folder, a model file or a crop folder is missing or unreadable, or a
            source has no crops (all checked before any long work).
        UnknownNameError: an unknown source, trainer or shipped model name (lists the known ones).
        ValueError: nothing to evaluate, a source named twice, or an unknown label set.
    """
    from makeway.eval.cross_source import leave_one_source_out, score_sources, worst_source
    from makeway.paths import data_dir
    from makeway.perceive.vision.ev_classifier import EVCropClassifier, load_crop_classifier
    from makeway.registry import Registry, UnknownNameError
    from makeway.sense.crops import committed_split, read_crop_folder
    from makeway.sense.label_corrections import CORRECTIONS_FILE, check_label_set, read_corrections
    from makeway.train.ev_head import FeatureCache, cached_head, head_trainer

    def say(line: str) -> None:
        if log is not None:
            log(line)

    if not models and not train:
        raise ValueError("nothing to evaluate: give --model and/or --train")
    labels = check_label_set(labels)
    if labels == "corrected":
        read_corrections(CORRECTIONS_FILE)  # a malformed file fails before any long work
    extra_names = [n for n, _ in extra]
    all_names = [*CROSS_SOURCES, *extra_names]
    if len(set(all_names)) != len(all_names):
        raise ValueError(f"a source is named twice: {', '.join(all_names)}")
    known = Registry("source", {n: n for n in all_names})
    selected = [known[s] for s in sources] if sources is not None else all_names
    if not selected:
        raise ValueError("no sources to evaluate on")
    wanted = [n for n in CROSS_SOURCES if n in selected]
    for name in train:
        if name not in CROSS_SOURCE_TRAINERS:
            raise UnknownNameError("trainer", name, list(CROSS_SOURCE_TRAINERS))
    loaded = [(m, load_crop_classifier(m, num_threads=threads)) for m in models]  # bad files fail here
    extra_sets = [(n, read_crop_folder(folder)) for n, folder in extra if n in selected]
    root = (
        Path(cache).expanduser() if cache is not None else Path.home() / ".cache" / "makeway" / "cross_source"
    )
    base = Path(data).expanduser() if data is not None else data_dir()
    crop_sets = built_cross_sources(
        wanted, base, root, labels=labels, every=every, threads=threads, progress=progress, log=log
    )
    crop_sets.update(extra_sets)
    for name, crops in crop_sets.items():
        if len(crops) == 0:  # pragma: no cover - read_crop_folder refuses empty folders
            raise InputError(crops.root or Path(name), f"source {name!r} has no crops")
    info = {
        n: {"folder": str(c.root) if c.root is not None else None, "n": len(c), "positive": c.n_positive}
        for n, c in crop_sets.items()
    }
    for n, c in crop_sets.items():
        say(f"source {n}: {len(c)} crops, {c.n_positive} positive ({c.root})")

    features_dir = root / "features"
    scores: list[Any] = []
    worst: dict[str, Any] = {}

    def emit(score: Any) -> None:
        scores.append(score)
        if on_score is not None:
            on_score(score)

    fixed_sets = dict(crop_sets)
    if "ev_crops" in fixed_sets:
        split = committed_split(fixed_sets["ev_crops"])
        if split is not None:
            fixed_sets["ev_crops"] = fixed_sets["ev_crops"].subset(split[1])
    for name, clf in loaded:
        model: Any = clf
        if isinstance(clf, EVCropClassifier):
            model = cached_head(clf, features_dir, num_threads=threads, progress=progress)
        say(f"{name}: scoring each source (ev_crops: the committed held-out part)")
        worst[name] = worst_source(score_sources(model, fixed_sets, model=name, on_score=emit))
    folds = None if held_out is None else [known[s] for s in held_out]
    for trainer_name in train:
        label = f"{trainer_name} (leave-one-source-out{', quality matched' if match_quality else ''})"
        trainer: Callable[[CropSet], Any]
        if trainer_name == "effnet_ft":
            from makeway.train.effnet import effnet_crop_trainer

            trainer = effnet_crop_trainer(
                root / "effnet_ft",
                input_size=input_size,
                threads=threads,
                match_quality=match_quality,
                log=log,
            )
        else:
            trainer = head_trainer(
                cache=FeatureCache(folder=features_dir, num_threads=threads, progress=progress),
                match_quality=match_quality,
            )
        worst[label] = worst_source(
            leave_one_source_out(crop_sets, trainer, model=label, held_out=folds, on_score=emit, log=log)
        )
    return CrossSourceRun(scores=scores, worst=worst, sources=info, labels=labels)
