"""``makeway classify …``: emergency-vehicle crop data sets, the classical study, training and scoring
crop classifiers, and mining an unlabelled pool.

Each command parses its options, makes one call into :mod:`makeway.apps.classify` or
:mod:`makeway.train`, and prints. Registered by the main app as
``app.add_typer(classify_app, name="classify")``; also runnable as ``python -m makeway.cli.classify``.
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape
from rich.table import Table

from makeway.cli.common import console, err_console, friendly_errors, new_app, print_json_line
from makeway.errors import InputError

classify_app = new_app(
    "classify",
    "Emergency-vehicle crop classifiers.\n\n"
    "Build crop data sets, compare classical classifiers, train, score, export and mine.",
)
_STUDY_OUT = Path("docs/study")
_AmbulanceLabels = Annotated[
    str,
    typer.Option(
        "--labels",
        help="Label set of ambulance_yolo: corrected (the committed audit's corrections applied, "
        "src/makeway/data/ambulance_yolo_corrections.csv) or original (the export as it is).",
    ),
]


def _split_names(values: list[str] | None, default: list[str]) -> list[str]:
    if not values:
        return default
    return [v.strip() for item in values for v in item.split(",") if v.strip()]


def _command_line() -> str:
    prog = Path(sys.argv[0]).name if sys.argv else "makeway"
    if prog in ("__main__.py", "classify.py"):
        prog = "python -m makeway.cli.classify"
    return " ".join([prog, *(shlex.quote(a) for a in sys.argv[1:])])


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
    """Compare classical crop classifiers.

    Every pair (e.g. HOG features with an SVM) is fitted on the training part and scored on the
    held-out part: on ev_crops the committed held-out names, on any other folder a seeded group split
    (--fraction). Writes OUT/study.md (sorted table) and OUT/study.csv.
    """
    from makeway.apps.classify import run_classical_study

    run = run_classical_study(
        data,
        out,
        features=_split_names(features, []),
        classifiers=_split_names(classifiers, []),
        skip=_split_names(skip, []),
        holdout=holdout,
        fraction=fraction,
        seed=seed,
        threads=threads,
        command=_command_line(),
        progress=not quiet,
    )
    table = Table(title=f"classical study — {run.split} ({run.n_test} test crops)")
    for col in ("feature", "classifier", "accuracy", "F1", "max-F1", "fit s", "predict ms/100"):
        table.add_column(col)
    for r in sorted(run.rows, key=lambda r: -r.accuracy)[:8]:
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
    err_console.print(f"→ {run.md_path}\n→ {run.csv_path}", highlight=False)


# ------------------------------------------------------------------------------------------ holdout
@classify_app.command()
@friendly_errors
def holdout(
    data: Annotated[Path, typer.Option("--data", help="Crop folder: images/ + labels.csv.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Holdout file to write (image names).")],
    fraction: Annotated[float, typer.Option(help="Fraction of crops held out.")] = 0.2,
    seed: Annotated[int, typer.Option(help="Seed of the split.")] = 0,
) -> None:
    """Write a held-out split of a crop folder.

    The file lists the names of about FRACTION of the crops, whole groups (the group column of
    labels.csv, or near-duplicate clusters) at a time, stratified by label. The committed ev_crops
    split was made with: makeway classify holdout --data ../shared/data/vision/ev_crops --out
    src/makeway/data/ev_crops_holdout.txt
    """
    from makeway.apps.classify import write_holdout_split

    n_held, n_crops, n_pos = write_holdout_split(data, out, fraction=fraction, seed=seed)
    err_console.print(f"held out {n_held} of {n_crops} crops ({n_pos} positive) → {out}", highlight=False)


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
    labels: _AmbulanceLabels = "corrected",
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Build a crop folder from a YOLO ambulance set.

    Every labelled ambulance box is a positive; every detected vehicle (car, motorcycle, bus, truck)
    whose IoU with all ambulance boxes is below MAX_IOU, and that lies less than MAX_INSIDE of its
    area inside one, is a negative. Crops are squares around the box with MARGIN context per side,
    SIZE px; boxes under 18 px wide are skipped. labels.csv gets a group column with the source photo,
    so splits keep copies of a photo on one side. The export labels ambulances only, not all of them;
    with --labels corrected (the default) the committed audit's rows relabel the crops of unlabelled
    EVs (ambulance, police, fire; lights on or off) as positives, leave out crops of vehicle parts or
    vehicles mostly outside the image, and add crops of EVs the detector missed (see
    docs/data_card_ambulance_yolo.md). The label means "emergency vehicle", not "lights on".
    """
    from makeway.apps.classify import build_ambulance_crops as build

    counts = build(
        out,
        data,
        ambulance_class=ambulance_class,
        detector=detector,
        model=model,
        score_threshold=score_threshold,
        max_iou=max_iou,
        max_inside=max_inside,
        margin=margin,
        size=size,
        threads=threads,
        progress=not quiet,
        labels=labels,
    )
    err_console.print(
        f"{counts['images']} images: {counts['positive']} EV crops (of {counts['boxes']} labelled boxes; "
        f"narrower than 18 px skipped), {counts['negative']} other-vehicle crops → {counts['crops']} crops "
        f"in {out} ({labels.strip().lower()} labels: {counts['corrected']} crops corrected)",
        highlight=False,
    )


# -------------------------------------------------------------------------------------- train/eval
def _log(line: str) -> None:
    """One progress line on stderr."""
    err_console.print(line, highlight=False)


def _print_held_out(held_out: list[tuple[Path, dict[str, Any]]], how: str) -> None:
    """Each held-out score: a line on stderr naming the folder, then its JSON line."""
    for folder, metrics in held_out:
        err_console.print(f"held-out metrics on {folder.name} ({how}):", highlight=False)
        print_json_line(metrics)


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
            "(a detector's backbone fine-tuned after a linear probe; --input-size a multiple of 32), "
            "effnet_ft (EfficientNet-Lite0's tail fine-tuned from its ImageNet package; writes a "
            ".npz delta)."
        ),
    ] = "logreg",
    pretrained: Annotated[
        Path | None, typer.Option(help="torchvision ResNet-18 state dict (.pth) to start from (resnet18).")
    ] = None,
    epochs: Annotated[int, typer.Option(min=1, help="CNNs: most epochs.")] = 30,
    input_size: Annotated[int, typer.Option(min=16, help="CNNs: crop side in pixels.")] = 64,
    width: Annotated[int, typer.Option(min=1, help="CNNs: channels of the first stage.")] = 16,
    lr: Annotated[float, typer.Option(help="CNNs: Adam learning rate.")] = 1e-4,
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
    match_quality: Annotated[
        bool,
        typer.Option(
            "--match-quality",
            help="First make each --data folder's EV crops as soft as its other vehicles (in road "
            "footage the EV is usually the sharpest vehicle, which a model would learn instead).",
        ),
    ] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Train an EV crop classifier.

    By default a logistic head on pooled detector-backbone features (written as .npz); with --arch
    a CNN written as .onnx with its .pt checkpoint: resnet18 or small_cnn trained from scratch (or
    resnet18 from --pretrained), yolox_ft or nanodet_ft a detector's own backbone fine-tuned after a
    linear probe. With --unlabelled, a CNN also learns a teacher's judgements of unlabelled crops.
    On ev_crops, and on the crops of ambulance_yolo (classify build-ambulance-crops), only the
    training part (the complement of the committed held-out part) is used, and the held-out metrics
    are printed (one JSON line per held-out part)."""
    if arch != "logreg":
        from makeway.train.cnn import train_crop_cnn

        run = train_crop_cnn(
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
            unlabelled=unlabelled,
            teacher=teacher,
            match_quality=match_quality,
            progress=not quiet,
            log=_log,
        )
        _print_held_out(run.held_out, "committed holdout, ONNX Runtime")
        return
    from makeway.perceive.vision.backbone import DEFAULT_BLOCKS, FeatureBlock
    from makeway.perceive.vision.ev_classifier import EVCropClassifier
    from makeway.train.ev_head import train_ev_head

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
    run = train_ev_head(clf, data, out, match_quality=match_quality, log=_log)
    _print_held_out(run.held_out, "committed holdout")


@classify_app.command("train-detector")
@friendly_errors
def train_detector(
    out: Annotated[Path, typer.Argument(help="The EV detector to write (.onnx).")],
    data: Annotated[
        Path,
        typer.Option(
            "--data", help="ambulance_yolo/valid (YOLO images/ + labels/); its held-out part is never read."
        ),
    ],
    epochs: Annotated[int, typer.Option(min=1, help="Passes over the augmented images.")] = 8,
    views: Annotated[
        int, typer.Option(min=1, help="Augmented copies of each training image (made once).")
    ] = 8,
    batch_size: Annotated[int, typer.Option(min=1, help="Images per step.")] = 16,
    lr: Annotated[float, typer.Option(help="AdamW learning rate of the detector's head.")] = 1e-3,
    head_lr: Annotated[float, typer.Option(help="AdamW learning rate of the new class layers.")] = 5e-3,
    train_size: Annotated[
        int, typer.Option(min=64, help="Square training image side in pixels, a multiple of 32.")
    ] = 320,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    threads: Annotated[
        int, typer.Option(min=1, help="Torch and ONNX Runtime threads (1 is fastest on a busy machine).")
    ] = 1,
    yolox_model: Annotated[
        Path | None, typer.Option(help="yolox_nano.onnx to start from (default: the shared models folder).")
    ] = None,
    max_minutes: Annotated[
        float | None, typer.Option(min=0.1, help="Stop after the epoch that passes this many minutes.")
    ] = None,
    part: Annotated[
        str,
        typer.Option(
            help="head: train the head on the frozen backbone's cached outputs (CPU); "
            "full: train every layer on fresh views each epoch (meant for a GPU)."
        ),
    ] = "head",
    device: Annotated[str, typer.Option(help="Torch device of --part full: cpu or cuda.")] = "cpu",
    labels: _AmbulanceLabels = "original",
    mosaic: Annotated[
        float, typer.Option(min=0.0, max=1.0, help="Share of training views that are mosaics of four photos.")
    ] = 0.0,
    workers: Annotated[int, typer.Option(min=0, help="--part full: processes drawing augmented views.")] = 0,
    val_every: Annotated[int, typer.Option(min=1, help="--part full: validate every N epochs.")] = 1,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Train the EV / other-vehicle detector.

    Starts from the YOLOX-nano COCO detector and learns two classes, emergency vehicle (the
    labelled boxes) and other vehicle (the COCO detector's cars, motorcycles, buses and trucks that
    are not an EV). With --part head the backbone stays as it is and only the head is trained
    (about 5 minutes on 2 CPU cores); --part full trains every layer on fresh augmented views each
    epoch (the shipped detector: 50 epochs, 5 minutes on one GPU with --device cuda; about half an
    hour on 2 CPU cores). A part of the training photos picks the best epoch and the operating
    point; the committed held-out images are never read. Prints the validation figures as one JSON
    line. Score the result with makeway evaluate-detector --framework a --model OUT.
    """
    from makeway.train.framework_a import train_framework_a

    if train_size % 32:
        raise typer.BadParameter("must be a multiple of 32", param_hint="--train-size")
    run = train_framework_a(
        data,
        out,
        epochs=epochs,
        views=views,
        batch=batch_size,
        lr=lr,
        head_lr=head_lr,
        train_size=train_size,
        seed=seed,
        threads=threads,
        model_path=yolox_model,
        max_minutes=max_minutes,
        progress=not quiet,
        log=_log,
        part=part,
        device=device,
        labels=labels,
        mosaic=mosaic,
        workers=workers,
        val_every=val_every,
    )
    print_json_line(
        {
            "model": str(run.path),
            "best_epoch": run.best_epoch,
            "threshold": run.threshold,
            "validation": run.val,
            "data": run.counts,
            "ambulance_coco_classes": run.ambulance_coco_classes,
            "minutes": run.seconds / 60.0,
        }
    )


@classify_app.command("eval")
@friendly_errors
def eval_cmd(
    data: Annotated[Path, typer.Option("--data", help="Crop folder: images/ + labels.csv (any image size).")],
    model: Annotated[
        str,
        typer.Option(
            "--model",
            help="default|general|fast|fastest|imagenet (shipped models) or a head .npz / CNN .onnx.",
        ),
    ] = "default",
    plot: Annotated[
        Path | None,
        typer.Option(
            "--plot", help="Also write the precision-recall curve (operating point, max-F1) as PNG."
        ),
    ] = None,
) -> None:
    """Score an EV crop classifier on a crop folder.

    The classifier is a shipped one or a head .npz / CNN .onnx. Prints one JSON line last: accuracy,
    precision, recall, f1, max_f1, p_at_r80 (precision at recall 0.8), n, skipped. On ev_crops, and
    on the crops of ambulance_yolo (classify build-ambulance-crops), only the committed held-out part
    is scored. A crop that cannot be read (corrupt,
    truncated) is named on stderr ("skipped: FILE: problem"), left out and listed under "skipped";
    the rest is scored."""
    from makeway.apps.classify import evaluate_crop_classifier

    run = evaluate_crop_classifier(data, model, plot=plot, on_skip=_skip_line, log=_log)
    print_json_line({**run.metrics, "skipped": run.skipped})


def _skip_line(exc: InputError) -> None:
    """Print ``skipped: FILE: problem`` (one line on stderr)."""
    err_console.print(f"[yellow]skipped:[/] {escape(str(exc))}", highlight=False, soft_wrap=True)


# ------------------------------------------------------------------------------------- cross-source
def _named_folder(value: str) -> tuple[str, Path]:
    name, sep, folder = value.partition("=")
    if not sep or not name.strip() or not folder.strip():
        raise typer.BadParameter(f"expected NAME=CROP_FOLDER, got {value!r}", param_hint="--source-dir")
    return name.strip(), Path(folder.strip())


@classify_app.command("cross-source")
@friendly_errors
def cross_source(
    model: Annotated[
        list[str] | None,
        typer.Option(
            "--model",
            help="Fixed classifier(s) to score: default|general|fast|fastest|imagenet or a head .npz / "
            "CNN .onnx (repeat or comma-separate). Default, when --train is not given either: default, "
            "fast, fastest and imagenet.",
        ),
    ] = None,
    train: Annotated[
        list[str] | None,
        typer.Option(
            "--train",
            help="Recipe(s) to retrain leave-one-source-out: head (the default head's), effnet_ft "
            "(EfficientNet-Lite0 fine-tuned; needs torch).",
        ),
    ] = None,
    held_out: Annotated[
        list[str] | None,
        typer.Option("--held-out", help="--train: only these folds (held-out sources), in this order."),
    ] = None,
    input_size: Annotated[int, typer.Option(min=32, help="--train effnet_ft: crop side in pixels.")] = 224,
    source: Annotated[
        list[str] | None,
        typer.Option(
            "--source",
            help="Sources to use: ev_crops, ambulance_yolo, road_clips or a --source-dir name "
            "(default: all; repeat or comma-separate).",
        ),
    ] = None,
    source_dir: Annotated[
        list[str] | None,
        typer.Option(
            "--source-dir", help="A further source: NAME=CROP_FOLDER (images/ + labels.csv; repeat)."
        ),
    ] = None,
    data: Annotated[
        Path | None,
        typer.Option("--data", help="Shared data folder (default: ../shared/data or MAKEWAY_DATA)."),
    ] = None,
    cache: Annotated[
        Path | None,
        typer.Option(
            "--cache", help="Where built sources and backbone features are kept (default ~/.cache/makeway)."
        ),
    ] = None,
    every: Annotated[int, typer.Option(min=1, help="road_clips: one crop every N frames of a track.")] = 5,
    threads: Annotated[int, typer.Option(min=1, help="ONNX Runtime threads.")] = 1,
    labels: _AmbulanceLabels = "corrected",
    match_quality: Annotated[
        bool,
        typer.Option(
            "--match-quality",
            help="--train: first make each source's EV crops as soft as its other vehicles (in road "
            "footage the EV is usually the sharpest vehicle, which a model would learn instead of "
            "the vehicle).",
        ),
    ] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bars.")] = False,
) -> None:
    """Score EV crop classifiers on each unseen source.

    Sources: ev_crops (web photos), ambulance_yolo (crops of the Roboflow road photos: ambulances,
    and YOLOX-found other vehicles; --labels picks the corrected or the original labels) and
    road_clips (crops of the shared road clips' labelled tracks, grouped by track), plus any
    --source-dir. A fixed --model is scored on each source (on ev_crops
    only the committed held-out part); a --train recipe is fitted on all sources but one and scored
    on that one, for each. Prints one JSON line per (model, held-out source) — accuracy, precision,
    recall, f1, specificity, n, positive_share at the model's threshold; a one-class source says so
    and has no precision or F1 — then a summary line with each model's worst source. Sources and
    features are built into the cache on first use.
    """
    from makeway.apps.classify import cross_source_evaluation

    models = _split_names(model, [])
    trains = _split_names(train, [])
    if not models and not trains:
        models = ["default", "fast", "fastest", "imagenet"]
    run = cross_source_evaluation(
        models,
        trains,
        sources=_split_names(source, []) or None,
        extra=[_named_folder(v) for v in source_dir or []],
        data=data,
        cache=cache,
        every=every,
        threads=threads,
        held_out=_split_names(held_out, []) or None,
        input_size=input_size,
        progress=not quiet,
        on_score=lambda score: print_json_line(score.as_dict()),
        log=_log,
        labels=labels,
        match_quality=match_quality,
    )
    print_json_line(
        {
            "summary": "worst held-out source per model (accuracy)",
            "worst": {
                m: {"held_out": w.source, "accuracy": round(w.accuracy, 4)} for m, w in run.worst.items()
            },
            "sources": run.sources,
            "labels": run.labels,
        }
    )


# -------------------------------------------------------------------------------------------- mine
@classify_app.command()
@friendly_errors
def mine(
    pool: Annotated[Path, typer.Argument(help="Folder of unlabelled crops (searched recursively).")],
    model: Annotated[
        str,
        typer.Option(
            "--model",
            help="default|general|fast|fastest|imagenet (shipped models) or a head .npz / CNN .onnx.",
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
    """Find likely EVs in unlabelled crops for review.

    Scores an unlabelled pool and writes every predicted EV — true or false positive — ranked for
    review: OUT/candidates.csv (rank, image, probability, blank
    emergency), OUT/contact_sheet.png (top N) and OUT/labels_template.csv (image,emergency, ready to
    fill and append to a crop folder). Unreadable files are skipped and counted. One JSON line last."""
    from makeway.train.mining import mine as mine_pool

    result = mine_pool(pool, model, out, top=top, threshold=threshold, progress=not quiet)
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
    """Export a CNN checkpoint to ONNX.

    The ONNX file has a dynamic batch axis and the input size, threshold and preprocessing in its
    metadata; it is loaded back through ONNX Runtime as a check.
    """
    from makeway.train.cnn import export_checkpoint

    clf, stored_threshold = export_checkpoint(checkpoint, out, threshold=threshold)
    err_console.print(
        f"{clf.arch} (input {clf.input_size}, width {clf.width}) → {out} ({out.stat().st_size} bytes, "
        f"threshold {stored_threshold:g})",
        highlight=False,
    )


if __name__ == "__main__":
    classify_app()
