"""``makeway evaluate-detector``: an EV detector scored on a YOLO image set (issue 24, item 4).

**Framework B as a detector on images.** The vehicle detector (class-agnostic over the COCO vehicle
classes, its shipped score threshold 0.3) finds the vehicles of an image; each box gets the
pipeline's square crop (10 % of the longer side as context per side; boxes under 18 px wide get no
crop and are dropped, as the pipeline gives them no judgement); the crop classifier gives
``p`` = P(emergency vehicle). Each surviving box is one EV detection.

* **Ranking score** (for AP): ``product`` = detector score × ``p`` (default; a box must both be a
  vehicle and look like an EV), or ``classifier`` = ``p`` alone. The default was chosen on the
  validation part of ``ambulance_yolo`` (docs/results.md, "EV detection on images (Framework B)").
* **Operating point** (precision, recall): the boxes with ``p`` at or above the classifier's own
  threshold — what the video pipeline would call EV on this frame before smoothing.

**Framework A as a detector on images** (``--framework a``, seed 001's one-stage detector;
:mod:`makeway.perceive.vision.ev_detector`): the two-class detector's vehicle boxes (vehicle score
≥ 0.05, class-agnostic NMS) ranked by their ``ev_score`` = objectness × EV class score; the
operating point is ``ev_score`` at or above the threshold stored in the model file (chosen on the
training's validation images, never on the held-out ones).

Ground truth: the boxes of class 0 (ambulance in ``ambulance_yolo``); a detection is correct at
IoU ≥ 0.5 (:mod:`makeway.eval.detection`). With the ``corrected`` label set (the default) the
committed corrections (:mod:`makeway.sense.label_corrections`) are applied per image: unlabelled
EVs (ambulance, police, fire) of the audit get a box, boxes the audit found not to be EVs lose
theirs; ``original`` scores the export's boxes as they are. Rows of images not in the set change
nothing.

**Split.** ``ambulance_yolo`` is a Roboflow export: augmented copies of one photo share the stem
before ``.rf.<hash>`` (:func:`~makeway.sense.crops.roboflow_source`). An image is held out when the
SHA-256 of its source photo's name, read as a number in [0, 1), is below 0.2, so copies never
straddle and the rule needs no seed. The held-out names are committed in
``makeway/data/ambulance_yolo_held_out.txt`` (:data:`HELD_OUT_FILE`) so Framework A is scored on
the same images; ``validation`` is the rest of the set.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from makeway.errors import InputError
from makeway.sense.crops import AMBULANCE_YOLO_HELD_OUT

__all__ = [
    "FRAMEWORKS",
    "HELD_OUT_FILE",
    "HELD_OUT_FRACTION",
    "SCORES",
    "SPLITS",
    "BoxJudgements",
    "evaluate_detector",
    "framework_b_judgements",
    "held_out_by_hash",
    "score_judgements",
    "select_split",
    "write_held_out_file",
]

#: The committed held-out image names of ``ambulance_yolo/valid`` (module docstring).
HELD_OUT_FILE = AMBULANCE_YOLO_HELD_OUT
#: Share of source photos held out by :func:`held_out_by_hash`.
HELD_OUT_FRACTION = 0.2
FRAMEWORKS = ("a", "b")
SPLITS = ("all", "held_out", "validation")
SCORES = ("product", "classifier")
#: Framework A: lowest vehicle score ``obj·max(c0, c1)`` of a box kept for the AP curve.
FRAMEWORK_A_SCORE_THRESHOLD = 0.05


def held_out_by_hash(stem: str, fraction: float = HELD_OUT_FRACTION) -> bool:
    """Whether an image (file stem) belongs to the held-out part: SHA-256 of its source photo's name
    (:func:`~makeway.sense.crops.roboflow_source`), first 8 bytes as a fraction of 2^64, below
    ``fraction``."""
    from makeway.sense.crops import roboflow_source

    digest = hashlib.sha256(roboflow_source(stem).encode("utf-8")).digest()
    return int.from_bytes(digest[:8], "big") / 2.0**64 < fraction


def write_held_out_file(data: str | Path, path: str | Path = HELD_OUT_FILE) -> int:
    """Write the held-out image names (relative to ``images/``, sorted) of the YOLO set ``data`` to
    ``path`` after a ``# key: value`` header; returns how many.

    Raises:
        InputError: the folder is not a YOLO set (names what is missing).
    """
    from makeway.atomic import write_text_atomic
    from makeway.sense.crops import IMAGE_SUFFIXES, names_fingerprint

    images_dir = Path(data) / "images"
    if not images_dir.is_dir():
        raise InputError(images_dir, "missing: a YOLO set holds images/ and labels/")
    names = sorted(p.name for p in images_dir.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    held = [n for n in names if held_out_by_hash(Path(n).stem)]
    header = {
        "what": "held-out images of ambulance_yolo/valid: never train or tune on these",
        "rule": f"sha256(roboflow source photo name)[:8] / 2^64 < {HELD_OUT_FRACTION}",
        "set_fingerprint": names_fingerprint(names),
        "set_size": str(len(names)),
        "held_out": str(len(held)),
    }
    lines = [f"# {k}: {v}" for k, v in header.items()]
    write_text_atomic(path, "\n".join([*lines, *held]) + "\n")
    return len(held)


def select_split(images: Sequence[Any], split: str, data: Path) -> list[Any]:
    """The images (:class:`~makeway.sense.crops.YoloImage`) of ``split``: ``all``, ``held_out`` (the
    committed names) or ``validation`` (the others).

    Raises:
        InputError: ``held_out``/``validation`` on a folder that holds none of the committed
            held-out images or misses some of them (it is not the set the split was made from).
        ValueError: an unknown split name.
    """
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; one of {', '.join(SPLITS)}")
    if split == "all":
        return list(images)
    from makeway.sense.crops import read_holdout

    held = set(read_holdout(HELD_OUT_FILE).names)
    present = {img.path.name for img in images}
    missing = held - present
    if missing:
        raise InputError(
            data,
            f"{len(missing)} of the {len(held)} committed held-out images of ambulance_yolo/valid are not "
            f"here (e.g. {sorted(missing)[0]!r}); --split {split} needs that set, use --split all",
        )
    return [img for img in images if (img.path.name in held) == (split == "held_out")]


@dataclass(frozen=True)
class BoxJudgements:
    """Framework B's view of one image: vehicle ``boxes`` ``(n, 4)`` xyxy pixels, the detector's
    ``det_scores`` ``(n,)`` and the crop classifier's ``probs`` ``(n,)`` = P(EV); boxes too small for a
    crop are left out. ``gt`` ``(m, 4)``: the image's class-0 boxes. ``seconds``: detector + crops +
    classifier wall time."""

    boxes: np.ndarray
    det_scores: np.ndarray
    probs: np.ndarray
    gt: np.ndarray
    seconds: float


def framework_b_judgements(image_bgr: np.ndarray, detector: Any, classifier: Any) -> tuple[np.ndarray, ...]:
    """``(boxes, det_scores, probs)`` of one image: detector boxes → square crops (10 % margin,
    ≥ 18 px wide) → classifier probabilities, all crops in one batch."""
    from makeway.perceive.vision.crops import crops_for_tracks

    boxes, scores, _ = detector.detect_arrays(image_bgr)
    crops, kept = crops_for_tracks(image_bgr, boxes, margin=0.1, size=classifier.input_size)
    probs = classifier.predict_proba(crops) if len(kept) else np.zeros(0)
    return boxes[kept], scores[kept], np.asarray(probs, dtype=np.float64)


def score_judgements(
    judged: Sequence[BoxJudgements], threshold: float, score: str = "product"
) -> dict[str, Any]:
    """The metrics of Framework B's judgements: ``map50``, ``map50_95`` (ranking by ``score``),
    ``precision``/``recall`` at the operating point ``probs >= threshold``, and counts."""
    from makeway.eval.detection import detection_metrics, precision_recall

    if score not in SCORES:
        raise ValueError(f"unknown score {score!r}; one of {', '.join(SCORES)}")
    boxes = [j.boxes for j in judged]
    ranking = [j.probs * j.det_scores if score == "product" else j.probs for j in judged]
    gt = [j.gt for j in judged]
    m = detection_metrics(boxes, ranking, gt)
    chosen = [j.probs >= threshold for j in judged]
    p, r, _, n_det, _ = precision_recall(
        [b[k] for b, k in zip(boxes, chosen, strict=True)],
        [s[k] for s, k in zip(ranking, chosen, strict=True)],
        gt,
    )
    return {
        "map50": m.map50,
        "map50_95": m.map50_95,
        "precision": p,
        "recall": r,
        "n_images": m.n_images,
        "n_boxes": m.n_boxes,
        "n_detections": n_det,
        "score": score,
        "threshold": float(threshold),
    }


def evaluate_detector(
    data: str | Path,
    *,
    framework: str = "b",
    classifier: str | Path = "default",
    split: str = "all",
    score: str = "product",
    detector: str = "yolox_nano",
    model: str | Path | None = None,
    threads: int | None = None,
    max_images: int | None = None,
    judgements: list[BoxJudgements] | None = None,
    labels: str = "corrected",
) -> dict[str, Any]:
    """Score an EV detector on the YOLO set ``data`` against its class-0 boxes (module docstring).

    Returns the JSON fields of the command: ``map50``, ``map50_95``, ``precision``, ``recall``,
    ``n_images``, ``n_boxes``, ``n_detections``, ``framework``, ``classifier``, ``split``, ``score``,
    ``threshold`` (the classifier's), ``ms_per_image`` (detector + crops + classifier, mean wall
    time), ``labels`` (the label set, module docstring) and ``boxes_corrected`` (ground-truth boxes
    added or removed by the corrections in the scored images). ``max_images`` keeps the first
    images of the split (by name); ``judgements``, when a list, receives the per-image
    :class:`BoxJudgements` (to rescore without rerunning).

    With ``framework="a"`` the one-stage EV detector
    (:class:`~makeway.perceive.vision.ev_detector.EVDetector`, ``model`` its file, default the
    shipped one) replaces detector + classifier: its vehicle boxes (vehicle score ≥ 0.05) ranked by
    ``ev_score``, the operating point ``ev_score ≥`` the threshold stored in the model;
    ``classifier`` then reports the model file and ``score`` is ``ev_score``.

    Raises:
        InputError: the folder is not a YOLO set, an image does not decode, a label line or the
            corrections file is malformed (names the file); the split does not fit the folder.
        ValueError: an unknown framework, score, split or label set.
        UnknownNameError: an unknown detector or classifier name.
    """
    import cv2

    from makeway.perceive.vision.detectors import DETECTORS
    from makeway.perceive.vision.ev_classifier import load_crop_classifier
    from makeway.sense.crops import read_yolo_set
    from makeway.sense.label_corrections import LabelSet

    truth_set = LabelSet(labels)
    if framework not in FRAMEWORKS:
        raise ValueError(f"unknown framework {framework!r}; one of {', '.join(FRAMEWORKS)}")
    if score not in SCORES:
        raise ValueError(f"unknown score {score!r}; one of {', '.join(SCORES)}")
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; one of {', '.join(SPLITS)}")
    data = Path(data)
    if not data.is_dir():
        raise InputError(data, "YOLO folder not found (expected images/ and labels/)")
    if framework == "a":
        from makeway.perceive.vision.ev_detector import EVDetector

        ev_det = EVDetector(model, score_threshold=FRAMEWORK_A_SCORE_THRESHOLD, num_threads=threads)
    else:
        det = DETECTORS[detector](model, class_agnostic=True, num_threads=threads)
        clf = load_crop_classifier(classifier, num_threads=threads)
    images = select_split(read_yolo_set(data), split, data)
    if max_images is not None:
        images = images[:max_images]
    judged: list[BoxJudgements] = []
    for item in images:
        image = cv2.imread(str(item.path), cv2.IMREAD_COLOR)
        if image is None:
            raise InputError(item.path, "OpenCV could not decode this image")
        truth = truth_set.boxes(item.path.stem, item.boxes_of(0))
        gt = np.asarray([[b.x1, b.y1, b.x2, b.y2] for b in truth], dtype=np.float64)
        start = time.perf_counter()
        if framework == "a":
            found = ev_det.detect(image)
            boxes, det_scores, probs = found.boxes, found.scores, found.ev_scores.astype(np.float64)
        else:
            boxes, det_scores, probs = framework_b_judgements(image, det, clf)
        seconds = time.perf_counter() - start
        judged.append(BoxJudgements(boxes, det_scores, probs, gt.reshape(-1, 4), seconds))
    if judgements is not None:
        judgements.extend(judged)
    if framework == "a":  # probs hold ev_score: ranked by it alone, operating point on it
        out = score_judgements(judged, float(ev_det.threshold), "classifier")
        out["score"] = "ev_score"
        classifier = str(ev_det.model_path)
    else:
        out = score_judgements(judged, float(clf.threshold), score)
    out.update(
        framework=framework,
        classifier=str(classifier),
        split=split,
        ms_per_image=1000.0 * sum(j.seconds for j in judged) / max(len(judged), 1),
        labels=truth_set.labels,
        boxes_corrected=truth_set.changed,
    )
    return out
