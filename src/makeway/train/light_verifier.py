"""Training of the lit-light verifier of ``LIGHT_DETECTORS["verified"]`` (XGBoost and onnxmltools live
here only: ``pip install makeway[train]``).

**Rows.** Every checked frame of a split (:func:`makeway.train.light_split.load_split`, source pixels)
runs through the stage-1 proposals of :func:`makeway.perceive.vision.light_verify.proposals` (every
colour); a proposal whose IoU with a labelled lit light is ≥ 0.5 is a positive, every other proposal a
negative (the labelled hard negatives are such proposals). With ``label_positives`` the labelled boxes
themselves are added as extra positives (train split only).

**Model.** Gradient-boosted trees (:data:`XGB_PARAMS`) fitted on the train split; the operating
threshold is the one of :data:`THRESHOLDS` that maximises the lower of array precision and recall of
the full detector (NMS included) on the validation split, which is used for nothing else (ties go
to the lowest threshold: when the validation frames give no true positive at all, that is
:data:`THRESHOLDS`' first). The
booster is exported to ONNX (onnxmltools) with the feature names, threshold and figures in its
metadata, read by :class:`makeway.perceive.vision.light_verify.LightVerifier`.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from makeway.eval.detection import box_iou_matrix
from makeway.eval.lights import FrameResult, metrics
from makeway.perceive.vision.light_colour import COLOURS
from makeway.perceive.vision.light_verify import (
    DEFAULT_VERIFIER_MODEL,
    FEATURE_NAMES,
    nms,
    proposals,
    verifier_features,
)

__all__ = ["THRESHOLDS", "XGB_PARAMS", "fit_verifier", "train_light_verifier", "verifier_rows"]

XGB_PARAMS: dict[str, Any] = {
    "n_estimators": 300,
    "max_depth": 6,
    "learning_rate": 0.08,
    "subsample": 0.8,
    "colsample_bytree": 0.6,
    "tree_method": "hist",
}
"""The booster's settings."""
THRESHOLDS = (0.01, 0.02, 0.03, *(round(float(x), 2) for x in np.arange(0.05, 0.96, 0.05)))
"""Operating thresholds tried on the validation split (ties: the lowest, which favours recall)."""
ONNX_OPSET = 15


def verifier_rows(
    split: str,
    data_root: str | Path,
    *,
    label_positives: bool = False,
    advance: Callable[[int], Any] | None = None,
) -> dict[str, Any]:
    """Feature rows of one split: ``x`` (n, F), ``y`` (n,) bool, ``frame`` (n,) frame index, and per
    frame ``frames`` (source, key, gt boxes, vehicles) and ``boxes`` of its proposals (module
    docstring; the extra label positives carry frame index -1 so they never enter an evaluation)."""
    from makeway.train.light_split import load_split

    frames, _ = load_split(split, data_root, input_size=None)
    xs: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    fi: list[np.ndarray] = []
    info: list[tuple[str, str, np.ndarray, list[int]]] = []
    boxes: list[np.ndarray] = []
    colours: list[list[str]] = []
    for k, f in enumerate(frames):
        props = proposals(f.image, COLOURS)
        b = np.array([p["box"] for p in props], np.float64).reshape(-1, 4)
        x = verifier_features(f.image, props)
        y = np.zeros(len(props), bool)
        if len(f.boxes) and len(props):
            y = box_iou_matrix(b, f.boxes).max(axis=1) >= 0.5
        xs.append(x)
        ys.append(y)
        fi.append(np.full(len(props), k))
        info.append((f.source, f.key, f.boxes, list(f.vehicles)))
        boxes.append(b)
        colours.append([p["colour"] for p in props])
        if label_positives and len(f.boxes):
            extra = [
                {
                    "box": tuple(int(round(v)) for v in bb),
                    "colour": c,
                    "score": 0.0,
                    "cues": set(),
                    "configs": set(),
                }
                for bb, c in zip(f.boxes, f.colours, strict=True)
            ]
            xs.append(verifier_features(f.image, extra))
            ys.append(np.ones(len(extra), bool))
            fi.append(np.full(len(extra), -1))
        if advance is not None:
            advance(1)
    return {
        "x": np.concatenate(xs) if xs else np.zeros((0, len(FEATURE_NAMES)), np.float32),
        "y": np.concatenate(ys) if ys else np.zeros(0, bool),
        "frame": np.concatenate(fi) if fi else np.zeros(0, np.int64),
        "frames": info,
        "boxes": boxes,
        "colours": colours,
    }


def fit_verifier(x: np.ndarray, y: np.ndarray, *, seed: int = 0, threads: int = 2) -> Any:
    """An :class:`xgboost.XGBClassifier` (:data:`XGB_PARAMS`) fitted to predict ``y``."""
    import xgboost as xgb

    y = np.asarray(y, bool)
    if len(np.unique(y)) < 2:
        raise ValueError("the training proposals hold only one class")
    clf = xgb.XGBClassifier(**XGB_PARAMS, random_state=seed, n_jobs=threads, eval_metric="logloss")
    return clf.fit(np.asarray(x, np.float32), y)


def detector_results(rows: dict[str, Any], prob: np.ndarray, threshold: float) -> list[FrameResult]:
    """What the full detector returns per frame when its verifier gives ``prob`` per row of
    ``rows`` and keeps those ≥ ``threshold`` (then NMS)."""
    out = []
    for k, (source, key, gt, veh) in enumerate(rows["frames"]):
        sel = np.flatnonzero(rows["frame"] == k)
        p = prob[sel]
        b = rows["boxes"][k]
        keep = np.flatnonzero(p >= threshold)
        kept = keep[nms(b[keep], p[keep])] if len(keep) else keep
        out.append(FrameResult(source, key, gt, veh, b[kept], p[kept]))
    return out


def _export(clf: Any, path: Path, meta_extra: dict[str, Any]) -> None:
    import onnx
    from onnxmltools import convert_xgboost
    from onnxmltools.convert.common.data_types import FloatTensorType

    from makeway.atomic import atomic_path

    onx = convert_xgboost(
        clf,
        initial_types=[("features", FloatTensorType([None, len(FEATURE_NAMES)]))],
        target_opset=ONNX_OPSET,
    )
    meta = {
        "makeway_model": "light_verifier",
        "format_version": "1",
        "feature_names": json.dumps(FEATURE_NAMES),
    }
    meta.update({k: v if isinstance(v, str) else json.dumps(v) for k, v in meta_extra.items()})
    for k, v in meta.items():
        e = onx.metadata_props.add()
        e.key, e.value = k, v
    with atomic_path(path) as tmp:
        onnx.save(onx, str(tmp))


def train_light_verifier(
    out: str | Path | None = None,
    *,
    data_root: str | Path | None = None,
    label_positives: bool = True,
    seed: int = 0,
    progress: bool = True,
) -> dict[str, Any]:
    """Train the verifier on the train split, pick its threshold on the validation split and write
    it as ONNX to ``out`` (default: the shipped ``models/lights_verifier.onnx``). Returns the counts,
    the threshold, the validation figures (all frames and worst source) and the seconds taken.

    Raises:
        InputError: no shared data folder, or ``out``'s folder does not exist.
    """
    from makeway.errors import InputError
    from makeway.eval.lights import summarise
    from makeway.paths import data_dir
    from makeway.progress import progress_bar
    from makeway.train.light_split import load_split

    target = Path(out) if out is not None else DEFAULT_VERIFIER_MODEL
    if not target.parent.is_dir():
        raise InputError(target, "its folder does not exist")
    root = Path(data_root) if data_root is not None else data_dir()
    if root is None or not Path(root).is_dir():
        raise InputError(str(data_root), "shared data folder not found (set MAKEWAY_DATA)")
    t0 = time.perf_counter()
    rows = {}
    for split in ("train", "val"):
        n = len(load_split(split, root, keep_images=False)[0])
        with progress_bar(f"{split} proposals", n, enabled=progress, unit="frame") as advance:
            rows[split] = verifier_rows(
                split, root, label_positives=label_positives and split == "train", advance=advance
            )
    tr, va = rows["train"], rows["val"]
    clf = fit_verifier(tr["x"], tr["y"], seed=seed)
    prob = clf.predict_proba(va["x"])[:, 1]
    best: tuple[float, float] = (-1.0, 0.5)
    for t in THRESHOLDS:
        m = metrics(detector_results(va, prob, t))
        p, r = m.array_precision, m.array_recall
        val = min(p, r) if np.isfinite(p) and np.isfinite(r) else 0.0
        if val > best[0]:
            best = (val, t)
    threshold = best[1]
    summ = summarise(detector_results(va, prob, threshold))
    keys = ("array_precision", "array_recall", "vehicle_precision", "vehicle_recall")
    figures = {k: summ["all"][k] for k in keys}
    train_recall = float(tr["y"][tr["frame"] >= 0].sum())
    result = {
        "model": str(target),
        "train_rows": len(tr["y"]),
        "train_positives": int(tr["y"].sum()),
        "train_proposal_positives": int(train_recall),
        "val_rows": len(va["y"]),
        "val_positives": int(va["y"].sum()),
        "threshold": threshold,
        "validation": figures,
        "params": XGB_PARAMS,
        "seed": seed,
        "label_positives": label_positives,
    }
    _export(
        clf,
        target,
        {"threshold": str(threshold), "training": {k: v for k, v in result.items() if k != "model"}},
    )
    result["seconds"] = round(time.perf_counter() - t0, 1)
    result["size_bytes"] = target.stat().st_size
    return result
