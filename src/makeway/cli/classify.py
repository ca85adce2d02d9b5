"""``makeway classify …``: crop data sets and the classical classifier study (issue 3, SPEC §1–2).

Commands:

* ``study --data DIR`` — every feature × classifier of SPEC §2 on a crop folder; writes
  ``OUT/study.md`` and ``OUT/study.csv``. On ``ev_crops`` it evaluates on the committed held-out
  part (``makeway/data/ev_crops_holdout.txt``); on any other folder on a seeded 20 % group split.
* ``holdout --data DIR --out FILE`` — write a held-out split file (how the committed one was made)::

      makeway classify holdout --data ../shared/data/vision/ev_crops \\
          --out src/makeway/data/ev_crops_holdout.txt

* ``build-ambulance-crops --out DIR`` — a crop folder from a YOLO ambulance set
  (default ``<shared data>/vision/ambulance_yolo/valid``): every labelled ambulance box is a
  positive; every YOLOX-nano vehicle detection (car, motorcycle, bus, truck) whose IoU with all
  ambulance boxes is below 0.1 (and that is not mostly — half its area or more — inside one, such
  as a detection of an ambulance's light bar) is a negative. Crops are squares around the box with
  10 % context per side, 224×224, boxes under 18 px wide skipped (SPEC §1). ``labels.csv`` gets a ``group``
  column with the source photo (Roboflow copies of one photo share it), so splits keep a photo on
  one side. Caveat: some ambulances in that set are unlabelled and come out as negatives when the
  detector finds them; the label means "ambulance", not "lights on"::

      makeway classify build-ambulance-crops --out ../work/ambulance_crops

* ``train --data DIR [--data DIR2 ...] [--out FILE]`` — train the EV crop classifier head
  (:class:`~makeway.perceive.vision.ev_classifier.EVCropClassifier`: pooled YOLOX-nano + NanoDet-m
  backbone features of each crop and its mirror image + standardised logistic regression) and
  write it as ``.npz`` (default: the shipped ``makeway/models/ev_head_logreg.npz``). On ev_crops
  only the training part is used, and the held-out metrics are printed as a JSON line.
  ``--arch resnet18|small_cnn|yolox_ft|nanodet_ft`` trains a CNN of SPEC §1 instead
  (:mod:`makeway.train.cnn`, torch; ``--input-size``, ``--width``, ``--epochs``, ``--lr``,
  ``--pretrained FILE``, …; ``yolox_ft`` / ``nanodet_ft`` is a detector's backbone itself, linear
  probe then fine-tuned,
  :mod:`makeway.train.onnx_graph`): writes ``OUT.onnx`` + the checkpoint
  ``OUT.pt`` and scores the held-out part through ONNX Runtime.
* ``export CHECKPOINT --out FILE.onnx`` — export a CNN checkpoint to ONNX (dynamic batch axis,
  preprocessing and threshold in the metadata) for
  :class:`~makeway.perceive.vision.cnn_classifier.OnnxCropClassifier`.
* ``mine POOL [--model FILE] [--out DIR] [--top N] [--threshold T]`` — data engine: score an
  unlabelled pool, write the predicted EVs ranked for review (``candidates.csv``,
  ``contact_sheet.png``, ``labels_template.csv``; see :mod:`makeway.train.mining`).
* ``eval --data DIR [--model FILE] [--plot FILE.png]`` — score a head ``.npz`` or a CNN ``.onnx``
  (default: the shipped head) on a crop folder; on ev_crops only the committed held-out part.
  ``--plot`` writes the precision–recall curve with the operating point and max-F1 marked. Prints
  one JSON line last: accuracy, precision, recall, f1, max_f1, p_at_r80, n.

Registered by the main app as ``app.add_typer(classify_app, name="classify")``; also runnable as
``python -m makeway.cli.classify``.
"""

from __future__ import annotations

import os
import platform
import shlex
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer
from rich.table import Table

from makeway.cli.common import console, err_console, friendly_errors, new_app, print_json_line
from makeway.errors import InputError

classify_app = new_app(
    "classify", "Emergency-vehicle crop classifiers: data sets, held-out split, the classical study."
)
_STUDY_OUT = Path("docs/study")


def _split_names(values: list[str] | None, default: list[str]) -> list[str]:
    if not values:
        return default
    return [v.strip() for item in values for v in item.split(",") if v.strip()]


def _command_line() -> str:
    prog = Path(sys.argv[0]).name if sys.argv else "makeway"
    if prog in ("__main__.py", "classify.py"):
        prog = "python -m makeway.cli.classify"
    return " ".join([prog, *(shlex.quote(a) for a in sys.argv[1:])])


def _versions() -> str:
    out = []
    for mod in ("sklearn", "xgboost", "skimage", "cv2"):
        try:
            out.append(f"{mod} {__import__(mod).__version__}")
        except ImportError:
            continue
    return ", ".join(out)


# -------------------------------------------------------------------------------------------- study
@classify_app.command()
@friendly_errors
def study(
    data: Annotated[
        Path, typer.Option("--data", help="Crop folder: images/ + labels.csv (image,emergency).")
    ],
    out: Annotated[Path, typer.Option("--out", "-o", help="Where study.md and study.csv go.")] = _STUDY_OUT,
    features: Annotated[
        list[str] | None, typer.Option(help="Features, repeated or comma-separated (default: all).")
    ] = None,
    classifiers: Annotated[
        list[str] | None, typer.Option(help="Classifiers, repeated or comma-separated (default: all).")
    ] = None,
    skip: Annotated[
        list[str] | None,
        typer.Option(
            help="FEATURE:CLASSIFIER pairs not to run (repeat or comma-separate), e.g. pixels:adaboost."
        ),
    ] = None,
    holdout: Annotated[
        Path | None,
        typer.Option(
            help="Holdout file to evaluate on (default: the committed ev_crops one when it matches)."
        ),
    ] = None,
    fraction: Annotated[float, typer.Option(help="Held-out fraction when splitting here.")] = 0.2,
    seed: Annotated[int, typer.Option(help="Seed of the split and of the classifiers.")] = 0,
    threads: Annotated[int, typer.Option(min=1, help="Threads for classifiers that use several.")] = 1,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Run the classical study (SPEC §2): features × classifiers, fitted on the training part and
    scored on the held-out part; writes OUT/study.md (sorted table) and OUT/study.csv."""
    from makeway.perceive.vision.features import FEATURES
    from makeway.sense.crops import (
        EV_CROPS_HOLDOUT,
        holdout_split,
        read_crop_folder,
        read_holdout,
        split_holdout,
    )
    from makeway.train.classical import CLASSIFIERS, StudyRow, compatible, run_study, write_study

    feats = _split_names(features, list(FEATURES))
    clfs = _split_names(classifiers, list(CLASSIFIERS))
    skipped: list[tuple[str, str]] = []
    for pair in _split_names(skip, []):
        feat, sep, clf = pair.partition(":")
        if not sep or feat not in FEATURES or clf not in CLASSIFIERS:
            raise ValueError(f"--skip takes FEATURE:CLASSIFIER with registered names, got {pair!r}")
        skipped.append((feat, clf))
    n_runs = sum(1 for f in feats for c in clfs if (f, c) not in skipped and compatible(f, c))
    crops = read_crop_folder(data)
    if holdout is not None:
        train_idx, test_idx = holdout_split(crops, read_holdout(holdout))
        split = f"holdout {holdout.name}"
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
        f"Command: `{_command_line()}`",
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
        progress=not quiet,
        on_row=partial,
        skip=skipped,
    )
    md_path, csv_path = write_study(rows, out, notes=notes)
    table = Table(title=f"classical study — {split} ({len(test_set)} test crops)")
    for col in ("feature", "classifier", "accuracy", "F1", "max-F1", "fit s", "predict ms/100"):
        table.add_column(col)
    for r in sorted(rows, key=lambda r: -r.accuracy)[:8]:
        table.add_row(
            r.feature,
            r.classifier,
            f"{r.accuracy:.3f}",
            f"{r.f1:.3f}",
            f"{r.max_f1:.3f}",
            f"{r.fit_s:.1f}",
            f"{r.predict_ms_per_100:.1f}",
        )
    console.print(table)
    err_console.print(f"→ {md_path}\n→ {csv_path}", highlight=False)


# ------------------------------------------------------------------------------------------ holdout
@classify_app.command()
@friendly_errors
def holdout(
    data: Annotated[Path, typer.Option("--data", help="Crop folder: images/ + labels.csv.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Holdout file to write (image names).")],
    fraction: Annotated[float, typer.Option(help="Fraction of crops held out.")] = 0.2,
    seed: Annotated[int, typer.Option(help="Seed of the split.")] = 0,
) -> None:
    """Write a held-out split: the names of about FRACTION of the crops, whole groups (or
    near-duplicate clusters) at a time, stratified by label."""
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
    n_pos = int(crops.labels[test_idx].sum())
    err_console.print(
        f"held out {len(test_idx)} of {len(crops)} crops ({n_pos} positive) → {out}", highlight=False
    )


# ---------------------------------------------------------------------------- build-ambulance-crops
@classify_app.command("build-ambulance-crops")
@friendly_errors
def build_ambulance_crops(
    out: Annotated[Path, typer.Option("--out", "-o", help="Crop folder to write (images/ + labels.csv).")],
    data: Annotated[
        Path | None,
        typer.Option("--data", help="YOLO set (default: <shared data>/vision/ambulance_yolo/valid)."),
    ] = None,
    ambulance_class: Annotated[int, typer.Option(help="YOLO class id of the ambulance boxes.")] = 0,
    detector: Annotated[str, typer.Option(help="Vehicle detector: yolox_nano or nanodet_m.")] = "yolox_nano",
    model: Annotated[Path | None, typer.Option(help="ONNX weights for the detector.")] = None,
    score_threshold: Annotated[float, typer.Option(help="Detector score threshold.")] = 0.3,
    max_iou: Annotated[
        float, typer.Option(help="A detection is a negative below this IoU with all ambulances.")
    ] = 0.1,
    max_inside: Annotated[
        float, typer.Option(help="…and lies less than this fraction of its area inside one.")
    ] = 0.5,
    margin: Annotated[
        float, typer.Option(help="Context per side, as a fraction of the box's longer side.")
    ] = 0.1,
    size: Annotated[int, typer.Option(min=8, help="Crop side in pixels.")] = 224,
    threads: Annotated[int, typer.Option(min=1, help="Detector threads.")] = 1,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Build a crop folder from a YOLO ambulance set: ambulance boxes → positives, detector vehicles
    that overlap no ambulance (IoU < MAX_IOU) → negatives; group = source photo."""
    import cv2

    from makeway.paths import data_dir
    from makeway.perceive.vision.crops import detection_crop_items
    from makeway.perceive.vision.detectors import DETECTORS
    from makeway.progress import progress_bar
    from makeway.sense.crops import read_yolo_set, roboflow_source, write_crop_folder

    if data is None:
        base = data_dir()
        if base is None:
            raise InputError(
                "../shared/data", "shared data folder not found; pass --data or set MAKEWAY_DATA"
            )
        data = base / "vision" / "ambulance_yolo" / "valid"
    images = read_yolo_set(data)
    det = DETECTORS[detector](
        model, score_threshold=score_threshold, class_agnostic=True, num_threads=threads
    )
    counts = {"positive": 0, "negative": 0, "boxes": 0}

    def items(advance: Callable[[int], Any]) -> Iterator[tuple[str, np.ndarray, int, str | None]]:
        for item in images:
            image = cv2.imread(str(item.path), cv2.IMREAD_COLOR)
            if image is None:
                raise InputError(item.path, "OpenCV could not decode this image")
            positives = item.boxes_of(ambulance_class)
            counts["boxes"] += len(positives)
            boxes, _, _ = det.detect_arrays(image)
            group = roboflow_source(item.path.stem)
            for tag, crop, label in detection_crop_items(
                image, positives, boxes, max_iou=max_iou, max_inside=max_inside, margin=margin, size=size
            ):
                counts["positive" if label else "negative"] += 1
                yield f"{item.path.stem}_{tag}.jpg", crop, label, group
            advance(1)

    with progress_bar("crops from images", len(images), enabled=not quiet, unit="images") as adv:
        n = write_crop_folder(out, items(adv))
    err_console.print(
        f"{len(images)} images: {counts['positive']} ambulance crops (of {counts['boxes']} boxes; "
        f"narrower than 18 px skipped), {counts['negative']} other-vehicle crops → {n} crops in {out}",
        highlight=False,
    )


# -------------------------------------------------------------------------------------- train/eval
def _ev_crops_split(crops: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """``(train_idx, test_idx)`` when ``crops`` is the ev_crops set of the committed holdout."""
    from makeway.sense.crops import EV_CROPS_HOLDOUT, holdout_split, read_holdout

    if not EV_CROPS_HOLDOUT.is_file():
        return None
    committed = read_holdout(EV_CROPS_HOLDOUT)
    if not committed.matches(crops):
        return None
    return holdout_split(crops, committed)


def _metrics(probs: np.ndarray, labels: np.ndarray, threshold: float) -> dict[str, Any]:
    from makeway.eval.classification import precision_recall_f1, threshold_metrics

    y = np.asarray(labels).astype(bool)
    pred = probs >= threshold
    prf = precision_recall_f1(int(np.sum(pred & y)), int(np.sum(pred & ~y)), int(np.sum(~pred & y)))
    thr = threshold_metrics(probs, y, recall_at=0.8)
    return {
        "accuracy": round(float(np.mean(pred == y)), 4),
        "precision": round(float(prf["precision"]), 4),
        "recall": round(float(prf["recall"]), 4),
        "f1": round(float(prf["f1"]), 4),
        "max_f1": round(float(thr["max_f1"]), 4),
        "p_at_r80": round(float(thr["precision_at_recall_0.8"]), 4),
        "n": int(len(y)),
    }


def _teacher_targets(
    pools: list[Path], teacher: str, input_size: int, held_out: list[Any], progress: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """Distillation data: the crops of unlabelled ``pools`` at ``input_size`` with the ``teacher``'s
    probabilities (soft targets) and decisions, leaving out crops that are near-duplicates of a
    held-out crop (they would leak the test set into training). Returns ``(images, probabilities,
    labels, description)``."""
    from makeway.perceive.vision.ev_classifier import load_crop_classifier
    from makeway.progress import progress_bar
    from makeway.sense.crops import CropSet, near_duplicates_of
    from makeway.train.mining import list_pool, score_pool

    files = [f for pool in pools for f in list_pool(pool)]  # every pool checked before any work
    model = load_crop_classifier(teacher)
    with progress_bar(
        "teacher on the unlabelled crops", len(files), enabled=progress, unit="crops"
    ) as advance:
        paths, probs, unreadable = score_pool(files, model, advance=advance)
    crops = CropSet(paths=tuple(paths), labels=np.zeros(len(paths), dtype=np.int64))
    reference = [test.load_images(64, cache=False) for test in held_out]
    leak = (
        near_duplicates_of(crops.load_images(64, cache=False), np.concatenate(reference))
        if reference and len(crops)
        else np.zeros(len(crops), dtype=bool)
    )
    keep = np.flatnonzero(~leak)
    labels = (probs[keep] >= model.threshold).astype(np.int64)
    where = ", ".join("/".join(p.parts[-2:]) for p in pools)
    note = (
        f"unlabelled {where}: {len(keep)} crops with soft targets from the "
        f"teacher {teacher} ({int(labels.sum())} judged EV; {int(leak.sum())} near-duplicates of held-out "
        f"crops and {len(unreadable)} unreadable files left out)"
    )
    err_console.print(note, highlight=False)
    images = crops.subset(keep).load_images(input_size, cache=False)
    return images, probs[keep].astype(np.float64), labels, note


def _train_cnn(
    data: list[Path],
    out: Path,
    *,
    arch: str,
    threshold: float,
    seed: int,
    pretrained: Path | None,
    epochs: int,
    input_size: int,
    width: int,
    lr: float,
    min_lr: float,
    patience: int,
    batch_size: int,
    box_jitter: bool,
    pos_oversample: int,
    neg_downsample: int,
    threads: int,
    progress: bool,
    unlabelled: list[Path] | None = None,
    teacher: str = "default",
) -> None:
    """``classify train --arch resnet18|small_cnn|yolox_ft|nanodet_ft``: fit, write OUT (.onnx) + its .pt
    checkpoint, score the committed ev_crops holdout through ONNX Runtime (torch imported here only)."""
    from makeway.perceive.vision.cnn_classifier import OnnxCropClassifier
    from makeway.sense.crops import near_duplicate_groups, read_crop_folder
    from makeway.train.cnn import ARCHS, Augment, CNNClassifier

    if arch not in ARCHS:
        raise ValueError(f"unknown --arch {arch!r}; choose logreg, {', '.join(ARCHS)}")
    onnx_path = out if out.suffix.lower() == ".onnx" else out.with_suffix(".onnx")
    ckpt_path = onnx_path.with_suffix(".pt")
    clf = CNNClassifier(
        arch,
        input_size=input_size,
        width=width,
        epochs=epochs,
        batch_size=batch_size,
        lr=lr,
        min_lr=min_lr,
        patience=patience,
        augment=None if box_jitter else Augment(box_jitter=None),
        pos_oversample=pos_oversample,
        neg_downsample=neg_downsample,
        threshold=threshold,
        pretrained=pretrained,
        num_threads=threads,
        seed=seed,
    )
    sets = [(folder, read_crop_folder(folder)) for folder in data]  # all read before any work
    xs: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    gs: list[np.ndarray] = []
    parts: list[str] = []
    held: list[tuple[Any, Path]] = []
    for k, (folder, crops) in enumerate(sets):
        split = _ev_crops_split(crops)
        if split is not None:
            held.append((crops.subset(split[1]), folder))
            crops = crops.subset(split[0])
            what = "training part (committed holdout excluded)"
        else:
            what = "all"
        err_console.print(f"{folder.name}: {what}, {len(crops)} crops ({crops.n_positive} positive)")
        parts.append(f"{folder.name}: {what}, {len(crops)} crops, {crops.n_positive} positive")
        images = crops.load_images(input_size, cache=False)
        groups = crops.groups if crops.groups is not None else near_duplicate_groups(images)
        xs.append(images)
        ys.append(crops.labels)
        gs.append(np.asarray([f"{k}:{g}" for g in groups]))
    soft: np.ndarray | None = None
    if unlabelled:
        soft = np.concatenate([np.full(len(y), np.nan) for y in ys])
        pool_images, pool_probs, pool_labels, note = _teacher_targets(
            unlabelled, teacher, input_size, [test for test, _ in held], progress
        )
        xs.append(pool_images)
        ys.append(pool_labels)
        gs.append(np.asarray([f"pool:{i}" for i in range(len(pool_labels))]))
        soft = np.concatenate([soft, pool_probs])
        parts.append(note)

    def show(row: dict[str, float]) -> None:
        if progress:
            err_console.print(
                "  ".join(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}" for k, v in row.items()),
                highlight=False,
            )

    clf.fit(
        np.concatenate(xs),
        np.concatenate(ys),
        np.concatenate(gs),
        soft_targets=soft,
        training="; ".join(parts),
        progress=progress,
        on_epoch=show,
    )
    clf.save(ckpt_path)
    clf.export_onnx(onnx_path)
    err_console.print(
        f"{len(clf.history)} epochs; checkpoint → {ckpt_path}; ONNX → {onnx_path} "
        f"({onnx_path.stat().st_size} bytes)",
        highlight=False,
    )
    runtime = OnnxCropClassifier(onnx_path, num_threads=threads)
    for test_set, folder in held:
        probs = runtime.predict_proba(test_set.load_images(runtime.input_size, cache=False))
        err_console.print(
            f"held-out metrics on {folder.name} (committed holdout, ONNX Runtime):", highlight=False
        )
        print_json_line(_metrics(probs, test_set.labels, runtime.threshold))


@classify_app.command()
@friendly_errors
def train(
    data: Annotated[
        list[Path],
        typer.Option("--data", help="Crop folder(s): images/ + labels.csv; repeat for several."),
    ],
    out: Annotated[
        Path | None,
        typer.Option(
            "--out",
            "-o",
            help="logreg: head .npz (default: the shipped model). CNNs: model .onnx (checkpoint .pt "
            "beside it) (default: ev_cnn_<arch>.onnx).",
        ),
    ] = None,
    threshold: Annotated[float, typer.Option(help="Decision threshold stored with the model.")] = 0.5,
    seed: Annotated[int, typer.Option(help="Seed (logreg: of the inner CV that picks C).")] = 0,
    arch: Annotated[
        str,
        typer.Option(
            help="logreg (pooled backbone features, --block, + logistic head); CNNs: resnet18, "
            "small_cnn, or yolox_ft / nanodet_ft "
            "(a detector's backbone fine-tuned after a linear probe; --input-size a multiple of 32)."
        ),
    ] = "logreg",
    pretrained: Annotated[
        Path | None, typer.Option(help="torchvision ResNet-18 state dict (.pth) to start from (resnet18).")
    ] = None,
    epochs: Annotated[int, typer.Option(min=1, help="CNNs: most epochs.")] = 30,
    input_size: Annotated[int, typer.Option(min=16, help="CNNs: crop side in pixels.")] = 64,
    width: Annotated[int, typer.Option(min=1, help="CNNs: channels of the first stage.")] = 16,
    lr: Annotated[float, typer.Option(help="CNNs: Adam learning rate (SPEC §1: 1e-4).")] = 1e-4,
    min_lr: Annotated[float, typer.Option(help="CNNs: stop when the plateau schedule goes below.")] = 1e-5,
    patience: Annotated[
        int, typer.Option(min=0, help="CNNs: epochs without a better validation loss before halving the lr.")
    ] = 3,
    batch_size: Annotated[int, typer.Option(min=2, help="CNNs: crops per step.")] = 32,
    box_jitter: Annotated[
        bool, typer.Option(help="CNNs: positive-only box-jitter re-cropping (fitted normals).")
    ] = True,
    pos_oversample: Annotated[int, typer.Option(min=1, help="CNNs: copies of each positive per epoch.")] = 1,
    neg_downsample: Annotated[int, typer.Option(min=1, help="CNNs: keep 1/N of negatives per epoch.")] = 1,
    threads: Annotated[int, typer.Option(min=1, help="CNNs: torch threads.")] = 2,
    block: Annotated[
        list[str] | None,
        typer.Option(
            help="logreg: feature block backbone@size:layer,layer (repeat; backbones efficientnet_lite0, "
            "yolox_nano, nanodet_m). Default: yolox_nano@160:dark3,dark4,dark5,pan5 and "
            "nanodet_m@224:stage2,stage3,stage4; the imagenet head uses "
            "efficientnet_lite0@224:stage6,head,logits.",
        ),
    ] = None,
    flip: Annotated[
        bool, typer.Option(help="logreg: train on mirror images too; judge a crop by it and its mirror.")
    ] = True,
    shrink: Annotated[
        list[int] | None,
        typer.Option(
            help="logreg: also train on every crop shrunk to this width in px and enlarged back, as "
            "distant vehicles look in video (repeat, e.g. --shrink 32 --shrink 64).",
        ),
    ] = None,
    unlabelled: Annotated[
        list[Path] | None,
        typer.Option(
            help="CNNs: folder of unlabelled crops (repeat) trained on the --teacher's probabilities "
            "(distillation); crops copying a held-out crop are left out.",
        ),
    ] = None,
    teacher: Annotated[
        str,
        typer.Option(help="CNNs: the model judging --unlabelled: default|fast|fastest or a file."),
    ] = "default",
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Train an EV crop classifier: the detector-backbone features + logistic head (default) or a CNN of
    SPEC §1 (``--arch resnet18|small_cnn``: trained from scratch, or from ``--pretrained``;
    ``--arch yolox_ft``: the COCO detector's backbone fine-tuned).

    On ev_crops only the training part (the complement of the committed holdout) is used, and the
    held-out metrics are printed (one JSON line last)."""
    if arch != "logreg":
        _train_cnn(
            data,
            out if out is not None else Path(f"ev_cnn_{arch}.onnx"),
            arch=arch,
            threshold=threshold,
            seed=seed,
            pretrained=pretrained,
            epochs=epochs,
            input_size=input_size,
            width=width,
            lr=lr,
            min_lr=min_lr,
            patience=patience,
            batch_size=batch_size,
            box_jitter=box_jitter,
            pos_oversample=pos_oversample,
            neg_downsample=neg_downsample,
            threads=threads,
            progress=not quiet,
            unlabelled=unlabelled,
            teacher=teacher,
        )
        return
    from makeway.perceive.vision.backbone import DEFAULT_BLOCKS, FeatureBlock
    from makeway.perceive.vision.ev_classifier import DEFAULT_MODEL, EVCropClassifier
    from makeway.sense.crops import near_duplicate_groups, read_crop_folder

    target = out if out is not None else DEFAULT_MODEL
    if unlabelled:
        raise typer.BadParameter(
            "distillation is for the CNN archs (--arch small_cnn, …)", param_hint="--unlabelled"
        )
    try:
        blocks = [FeatureBlock.parse(b) for b in block] if block else list(DEFAULT_BLOCKS)
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--block") from None
    try:
        clf = EVCropClassifier(blocks=blocks, flip=flip, threshold=threshold, seed=seed, shrink=shrink or ())
    except ValueError as exc:
        raise typer.BadParameter(str(exc), param_hint="--shrink") from None
    sets = [(folder, read_crop_folder(folder)) for folder in data]  # all read before any work
    xs: list[np.ndarray] = []
    xms: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    gs: list[np.ndarray] = []
    parts: list[str] = []
    held: list[tuple[Any, Path]] = []
    for folder, crops in sets:
        split = _ev_crops_split(crops)
        if split is not None:
            train_idx, test_idx = split
            held.append((crops.subset(test_idx), folder))
            crops = crops.subset(train_idx)
            what = "training part (committed holdout excluded)"
        else:
            what = "all"
        err_console.print(f"{folder.name}: {what}, {len(crops)} crops ({crops.n_positive} positive)")
        parts.append(f"{folder.name}: {what}, {len(crops)} crops, {crops.n_positive} positive")
        images = crops.load_images(clf.input_size, cache=False)
        # near-duplicates stay in one inner-CV fold (as the holdout keeps them on one side)
        groups = np.char.add(f"{len(gs)}:", near_duplicate_groups(images).astype(str))
        x, x_mirrored, y, g = clf.training_features(images, crops.labels, groups)
        xs.append(x)
        if x_mirrored is not None:
            xms.append(x_mirrored)
        ys.append(y)
        gs.append(g)
    if clf.shrink:
        parts.append(f"each crop also shrunk to {', '.join(f'{w} px' for w in clf.shrink)} and enlarged back")
    clf.fit_features(
        np.concatenate(xs),
        np.concatenate(ys),
        x_mirrored=np.concatenate(xms) if xms else None,
        groups=np.concatenate(gs),
        training="; ".join(parts),
    )
    clf.save(target)
    err_console.print(f"C = {clf.C:g}; head → {target} ({target.stat().st_size} bytes)", highlight=False)
    for test_set, folder in held:
        probs = clf.predict_proba(test_set.load_images(clf.input_size, cache=False))
        err_console.print(f"held-out metrics on {folder.name} (committed holdout):", highlight=False)
        print_json_line(_metrics(probs, test_set.labels, clf.threshold))


@classify_app.command("eval")
@friendly_errors
def eval_cmd(
    data: Annotated[Path, typer.Option("--data", help="Crop folder: images/ + labels.csv (any image size).")],
    model: Annotated[
        str,
        typer.Option(
            "--model", help="default|fast|fastest|imagenet (shipped models) or a head .npz / CNN .onnx."
        ),
    ] = "default",
    plot: Annotated[
        Path | None,
        typer.Option(
            "--plot", help="Also write the precision-recall curve (operating point, max-F1) as PNG."
        ),
    ] = None,
) -> None:
    """Score an EV crop classifier (a head .npz or a CNN .onnx) on a crop folder; prints one JSON
    line last.

    On ev_crops only the committed held-out part is scored. A crop that cannot be read (corrupt,
    truncated) is named on stderr ("skipped: FILE: problem"), left out and listed under "skipped";
    the rest is scored."""
    from makeway.atomic import check_writable
    from makeway.perceive.vision.ev_classifier import SHIPPED_MODELS, load_crop_classifier
    from makeway.sense.crops import read_crop_folder

    if plot is not None:
        check_writable(plot, folder=False)
    clf = load_crop_classifier(model)
    crops = read_crop_folder(data)
    split = _ev_crops_split(crops)
    if split is not None:
        crops = crops.subset(split[1])
        err_console.print(
            f"ev_crops: scoring the committed held-out part only ({len(crops)} crops)", highlight=False
        )
    else:
        err_console.print(f"scoring all {len(crops)} crops of {data}", highlight=False)
    skipped: list[str] = []  # a bad crop is named and left out; the rest is scored
    crops, images = crops.load_readable(clf.input_size, on_bad=lambda e: skipped.append(_skip_line(e)))
    probs = clf.predict_proba(images)
    if plot is not None:
        from makeway.viz.pr_plot import plot_pr_curve

        name = Path(SHIPPED_MODELS.get(model.strip().lower(), model)).name
        what = "held-out part" if split is not None else "all crops"
        plot_pr_curve(
            probs, crops.labels, plot, threshold=clf.threshold, title=f"{name} on {data.name} ({what})"
        )
        err_console.print(f"PR curve → {plot}", highlight=False)
    print_json_line({**_metrics(probs, crops.labels, clf.threshold), "skipped": skipped})


def _skip_line(exc: InputError) -> str:
    """Print ``skipped: FILE: problem`` (one line on stderr); return the file."""
    err_console.print(f"[yellow]skipped:[/] {exc}", highlight=False, soft_wrap=True)
    return str(exc.path)


# -------------------------------------------------------------------------------------------- mine
@classify_app.command()
@friendly_errors
def mine(
    pool: Annotated[Path, typer.Argument(help="Folder of unlabelled crops (searched recursively).")],
    model: Annotated[
        str,
        typer.Option(
            "--model", help="default|fast|fastest|imagenet (shipped models) or a head .npz / CNN .onnx."
        ),
    ] = "default",
    out: Annotated[
        Path,
        typer.Option("--out", "-o", help="Where candidates.csv, contact_sheet.png, labels_template.csv go."),
    ] = Path("makeway_out/mine"),
    top: Annotated[int, typer.Option(min=0, help="Thumbnails on the contact sheet.")] = 64,
    threshold: Annotated[
        float | None,
        typer.Option(
            min=0.0, max=1.0, help="Keep images at or above this probability (default: the model's)."
        ),
    ] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Data engine (seed 000 §3.3.2): score an unlabelled pool and write every predicted EV — true or
    false positive — ranked for review: OUT/candidates.csv (rank, image, probability, blank
    emergency), OUT/contact_sheet.png (top N) and OUT/labels_template.csv (image,emergency, ready to
    fill and append to a crop folder). Unreadable files are skipped and counted. One JSON line last."""
    from makeway.perceive.vision.ev_classifier import load_crop_classifier
    from makeway.train.mining import mine as mine_pool

    clf = load_crop_classifier(model)
    result = mine_pool(pool, clf, out, top=top, threshold=threshold, progress=not quiet)
    summary = result.summary()
    if result.unreadable:
        shown = ", ".join(str(p.relative_to(pool)) for p in result.unreadable[:5])
        more = f" and {len(result.unreadable) - 5} more" if len(result.unreadable) > 5 else ""
        err_console.print(
            f"skipped {len(result.unreadable)} file(s) OpenCV cannot read: {shown}{more}", highlight=False
        )
    err_console.print(
        f"{summary['scored']} images scored, {summary['candidates']} at p >= {result.threshold:g} → {out}",
        highlight=False,
    )
    print_json_line(summary)


@classify_app.command("export")
@friendly_errors
def export_cmd(
    checkpoint: Annotated[
        Path, typer.Argument(help="CNN checkpoint .pt written by `classify train --arch …`.")
    ],
    out: Annotated[Path, typer.Option("--out", "-o", help="ONNX file to write.")],
    threshold: Annotated[
        float | None, typer.Option(help="Decision threshold to store (default: the checkpoint's).")
    ] = None,
) -> None:
    """Export a CNN checkpoint to ONNX (dynamic batch axis; input size, threshold and preprocessing in
    the metadata), then load it back through ONNX Runtime as a check."""
    from makeway.perceive.vision.cnn_classifier import OnnxCropClassifier
    from makeway.train.cnn import load_checkpoint

    clf = load_checkpoint(checkpoint)
    if threshold is not None:
        if not 0.0 < threshold < 1.0:
            raise ValueError(f"--threshold must be in (0, 1), got {threshold}")
        clf.threshold = float(threshold)
    clf.export_onnx(out)
    runtime = OnnxCropClassifier(out)
    err_console.print(
        f"{clf.arch} (input {clf.input_size}, width {clf.width}) → {out} ({out.stat().st_size} bytes, "
        f"threshold {runtime.threshold:g})",
        highlight=False,
    )


if __name__ == "__main__":
    classify_app()
