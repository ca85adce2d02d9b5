"""Training of the lit-light verifier of ``LIGHT_DETECTORS["verified"]`` (XGBoost and onnxmltools live
here only: ``pip install makeway[train]``).

**Rows.** Every checked frame of a split (:func:`makeway.train.light_split.load_split`, source pixels)
runs through the stage-1 proposals of :func:`makeway.perceive.vision.light_verify.proposals` (every
colour); a proposal whose IoU with a labelled lit light is ≥ 0.5 is a positive, every other proposal a
negative (the labelled hard negatives are such proposals). With ``label_positives`` the labelled boxes
themselves are added as extra positives (train split only).

**Model.** Gradient-boosted trees (:data:`XGB_PARAMS`) fitted on the train split. **Operating
threshold**: the one of :data:`THRESHOLDS` that maximises the lower of array precision and recall of
the full detector (NMS included) over the train split's *out-of-fold* scores (:func:`out_of_fold`:
:data:`CV_FOLDS` folds grouped by clip and by photo, :func:`frame_group`, each fold scored by trees
that never saw it) pooled with the validation split's scores (ties go to the lowest threshold). The
validation clip alone cannot choose: its 5-px lamps give no true positive at any threshold. The
booster is exported to ONNX (onnxmltools) with the feature names, threshold and figures in its
metadata, read by :class:`makeway.perceive.vision.light_verify.LightVerifier`.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from makeway.eval.detection import box_iou_matrix
from makeway.eval.lights import FrameResult, metrics
from makeway.perceive.vision.light_colour import COLOURS
from makeway.perceive.vision.light_verify import (
    APPEARANCE_PREFIX,
    CONTEXT_FEATURE_NAMES,
    DEFAULT_VERIFIER_MODEL,
    FEATURE_NAMES,
    ProposalAppearance,
    Vehicles,
    context_features,
    nms,
    proposals,
    verifier_features,
)
from makeway.train.light_split import LightFrame

__all__ = [
    "CV_FOLDS",
    "CV_NEGATIVES",
    "IGNORED_CONTEXT_FEATURES",
    "IGNORED_FEATURES",
    "THRESHOLDS",
    "XGB_PARAMS",
    "choose_threshold",
    "detector_results",
    "fit_verifier",
    "frame_group",
    "grouped_folds",
    "out_of_fold",
    "shrunk_frame",
    "train_light_verifier",
    "verifier_rows",
]

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
IGNORED_FEATURES: tuple[str, ...] = (
    "cx",
    "cy",
    "w_rel",
    "h_rel",
    "frame_v",
    "frame_v99",
    "log_n",
    *(n for n in FEATURE_NAMES if n.startswith(("pv_", "ps_"))),
)
"""Features the trees may not use (zeroed before fitting, so never split on; the detector still
computes them): the place in the frame, the size relative to the frame, the frame's brightness and
proposal count, and the 8×8 context patches. They let the trees tell the training *sources* apart
— a frame size, a camera, a time of day — which does not transfer: without them the grouped
cross-validation (out of fold, train split) rose from min(P, R) 0.240 to 0.281 and AP50 from 0.130
to 0.179."""
IGNORED_CONTEXT_FEATURES: tuple[str, ...] = (
    "veh_aspect",
    "veh_score",
    "veh_car",
    "veh_motorcycle",
    "veh_bus",
    "veh_truck",
    "share_log_n",
    *(f"share_{c}" for c in COLOURS),
)
"""Vehicle-context columns the trees may not use either (with ``vehicle_context``): the vehicle's
class, score and shape, and the count and colour mix of the proposals sharing its box. The trees
keep where the lamp sits in or near its vehicle (inside, distance, height and side, size ratios)
and whether a red/blue bar partner shares the box at its height. Chosen by grouped
cross-validation over the training sources and validation (docs/model_card_lights.md): with every
context column the cross-validated min(P, R) fell below the model without context (0.268 against
0.281); with these left out it rose to 0.299 (AP50 0.179 → 0.200)."""
CV_FOLDS = 4
"""Grouped cross-validation folds over the train split that choose the operating threshold."""
REFINE_PARAMS: dict[str, Any] = {
    "n_estimators": 200,
    "max_depth": 5,
    "learning_rate": 0.08,
    "subsample": 0.8,
    "colsample_bytree": 0.6,
    "tree_method": "hist",
}
"""The box refiner's regressors' settings."""
REFINE_MIN_IOU = 0.3
"""Proposals at least this close (IoU) to a labelled light teach the box refiner."""
CV_NEGATIVES = 0.25
"""Fraction of the negative rows each cross-validation fold is fitted on (inverse-weighted)."""


def feature_names_for(width: int) -> tuple[str, ...]:
    """The column names of feature rows ``width`` wide: the proposal's own (:data:`FEATURE_NAMES`),
    those followed by the vehicle context (:data:`CONTEXT_FEATURE_NAMES`), or both followed by
    ``width − 200`` appearance columns (``app_0`` …, :class:`ProposalAppearance`)."""
    with_context = FEATURE_NAMES + CONTEXT_FEATURE_NAMES
    if width == len(FEATURE_NAMES):
        return FEATURE_NAMES
    if width >= len(with_context):
        extra = width - len(with_context)
        return with_context + tuple(f"{APPEARANCE_PREFIX}{i}" for i in range(extra))
    raise ValueError(f"feature rows of {width} columns match no feature set")


def shrunk_frame(frame: LightFrame, factor: float) -> LightFrame:
    """``frame`` shrunk by ``factor`` (0–1; area interpolation), its boxes scaled with it and its key
    marked ``KEY@factor`` (:func:`frame_group` keeps it with the frame it came from)."""
    import cv2

    if not 0.0 < factor <= 1.0:
        raise ValueError(f"a shrink factor must lie in (0, 1], got {factor}")
    h, w = frame.image.shape[:2]
    size = (max(1, round(w * factor)), max(1, round(h * factor)))
    sx, sy = size[0] / w, size[1] / h
    shrink = np.array([sx, sy, sx, sy])
    return LightFrame(
        source=frame.source,
        key=f"{frame.key}@{factor:g}",
        image=cv2.resize(frame.image, size, interpolation=cv2.INTER_AREA),
        scale=frame.scale * factor,
        boxes=frame.boxes * shrink,
        negatives=frame.negatives * shrink,
        colours=list(frame.colours),
        vehicles=list(frame.vehicles),
    )


def verifier_rows(
    split: str,
    data_root: str | Path,
    *,
    label_positives: bool = False,
    vehicles: Callable[[np.ndarray], Vehicles] | None = None,
    extra_features: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
    scales: Sequence[float] = (1.0,),
    advance: Callable[[int], Any] | None = None,
) -> dict[str, Any]:
    """Feature rows of one split: ``x`` (n, F), ``y`` (n,) bool, ``frame`` (n,) frame index, and per
    frame ``frames`` (source, key, gt boxes, vehicles) and ``boxes`` of its proposals (module
    docstring; the extra label positives carry frame index -1 so they never enter an evaluation;
    ``origin`` (n,) is the frame every row came from, extra positives included). With ``vehicles``
    (a frame's BGR pixels → its vehicle boxes, e.g. the vehicle detector's ``detect_arrays``) every
    row also gets the vehicle-context columns (:func:`context_features`; an extra label positive is
    described among its frame's proposals). ``extra_features`` (a frame's BGR pixels and boxes ``(n, 4)`` →
    feature rows ``(n, k)``) appends ``k`` more columns to every row, after the context.

    ``scales`` other than 1 add a copy of every frame shrunk by that factor (area interpolation,
    boxes scaled with it; the frame key gains ``@scale``, so the copy stays in its frame's
    cross-validation group): the lamps of a vehicle farther away, or seen by a lens of shorter
    focal length (the rig's fisheyes see a lamp at about half the size a road camera does)."""
    from makeway.train.light_split import load_split

    if not scales or any(not 0.0 < s <= 1.0 for s in scales):
        raise ValueError(f"scales must lie in (0, 1], got {list(scales)}")
    loaded, _ = load_split(split, data_root, input_size=None)
    frames = [f if s == 1.0 else shrunk_frame(f, s) for f in loaded for s in scales]
    xs: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    fi: list[np.ndarray] = []
    origin: list[np.ndarray] = []
    info: list[tuple[str, str, np.ndarray, list[int]]] = []
    boxes: list[np.ndarray] = []
    colours: list[list[str]] = []
    for k, f in enumerate(frames):
        props = proposals(f.image, COLOURS)
        b = np.array([p["box"] for p in props], np.float64).reshape(-1, 4)
        pc = [p["colour"] for p in props]
        veh = vehicles(f.image) if vehicles is not None else None
        x = verifier_features(f.image, props)
        if veh is not None:
            x = np.concatenate([x, context_features(b, pc, veh)], axis=1)
        if extra_features is not None:
            x = np.concatenate([x, extra_features(f.image, b)], axis=1)
        y = np.zeros(len(props), bool)
        if len(f.boxes) and len(props):
            y = box_iou_matrix(b, f.boxes).max(axis=1) >= 0.5
        xs.append(x)
        ys.append(y)
        fi.append(np.full(len(props), k))
        origin.append(np.full(len(props), k))
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
            xe = verifier_features(f.image, extra)
            if veh is not None:
                ctx = context_features(f.boxes, list(f.colours), veh, peer_boxes=b, peer_colours=pc)
                xe = np.concatenate([xe, ctx], axis=1)
            if extra_features is not None:
                gt = np.asarray(f.boxes, np.float64).reshape(-1, 4)
                xe = np.concatenate([xe, extra_features(f.image, gt)], axis=1)
            xs.append(xe)
            ys.append(np.ones(len(extra), bool))
            fi.append(np.full(len(extra), -1))
            origin.append(np.full(len(extra), k))
        if advance is not None:
            advance(1)
    width = len(FEATURE_NAMES) + (len(CONTEXT_FEATURE_NAMES) if vehicles is not None else 0)
    return {
        "x": np.concatenate(xs) if xs else np.zeros((0, width), np.float32),
        "y": np.concatenate(ys) if ys else np.zeros(0, bool),
        "frame": np.concatenate(fi) if fi else np.zeros(0, np.int64),
        "origin": np.concatenate(origin) if origin else np.zeros(0, np.int64),
        "frames": info,
        "boxes": boxes,
        "colours": colours,
    }


def fit_verifier(
    x: np.ndarray,
    y: np.ndarray,
    *,
    seed: int = 0,
    threads: int = 2,
    negatives: float = 1.0,
    ignored: Sequence[str] = IGNORED_FEATURES,
) -> Any:
    """An :class:`xgboost.XGBClassifier` (:data:`XGB_PARAMS`) fitted to predict ``y`` from the
    features of ``x`` (rows of :func:`feature_names_for` its width) not in ``ignored``. With
    ``negatives`` < 1 only that random fraction of the negative rows is used, each weighted by its
    inverse (the same expected loss, several times faster; the cross-validation folds use it)."""
    import xgboost as xgb

    y = np.asarray(y, bool)
    x = np.array(x, np.float32)
    try:
        names = feature_names_for(x.shape[1]) if x.ndim == 2 else ()
    except ValueError:  # rows of another layout: nothing is known to ignore
        names = ()
    cols = [names.index(n) for n in ignored if n in names]
    if cols:
        x[:, cols] = 0.0  # constant: never split on
    if len(np.unique(y)) < 2:
        raise ValueError("the training proposals hold only one class")
    if not 0.0 < negatives <= 1.0:
        raise ValueError(f"negatives is a fraction in (0, 1], got {negatives}")
    weight = None
    if negatives < 1.0:
        keep = y | (np.random.default_rng(seed).random(len(y)) < negatives)
        x, y = x[keep], y[keep]
        weight = np.where(y, 1.0, 1.0 / negatives)
    clf = xgb.XGBClassifier(**XGB_PARAMS, random_state=seed, n_jobs=threads, eval_metric="logloss")
    return clf.fit(x, y, sample_weight=weight)


def detector_results(rows: dict[str, Any], prob: np.ndarray, threshold: float) -> list[FrameResult]:
    """What the full detector returns per frame when its verifier gives ``prob`` per row of
    ``rows`` and keeps those ≥ ``threshold`` (then NMS)."""
    out = []
    frame = np.asarray(rows["frame"])
    order = np.argsort(frame, kind="stable")
    bounds = np.searchsorted(frame[order], np.arange(len(rows["frames"]) + 1))
    for k, (source, key, gt, veh) in enumerate(rows["frames"]):
        sel = order[bounds[k] : bounds[k + 1]]
        p = prob[sel]
        b = rows["boxes"][k]
        keep = np.flatnonzero(p >= threshold)
        kept = keep[nms(b[keep], p[keep])] if len(keep) else keep
        out.append(FrameResult(source, key, gt, veh, b[kept], p[kept]))
    return out


def frame_group(source: str, key: str) -> str:
    """The cross-validation group of one labelled frame: its clip for a video source; for a photo of
    ``ambulance_yolo``, the photo's name before ``.rf.`` (the folder holds photometric copies of one
    photo under that name, which must stay in one fold)."""
    if source.startswith("ambulance_yolo"):
        return f"{source}:{Path(key).name.split('.rf.')[0]}"
    return source


def grouped_folds(groups: Sequence[str], n_folds: int) -> np.ndarray:
    """Fold index (0 … ``n_folds`` − 1) per item of ``groups``, a whole group in one fold: groups
    sorted by size (largest first, then by name) each go to the fold with the fewest items so far
    (deterministic, no randomness)."""
    if n_folds < 2:
        raise ValueError(f"need at least 2 folds, got {n_folds}")
    names, counts = np.unique(np.asarray(groups, dtype=object).astype(str), return_counts=True)
    if len(names) < n_folds:
        raise ValueError(f"{len(names)} groups cannot fill {n_folds} folds")
    order = sorted(range(len(names)), key=lambda i: (-counts[i], names[i]))
    load = np.zeros(n_folds, np.int64)
    fold_of: dict[str, int] = {}
    for i in order:
        f = int(np.argmin(load))
        fold_of[str(names[i])] = f
        load[f] += counts[i]
    return np.array([fold_of[str(g)] for g in groups], np.int64)


def out_of_fold(
    rows: dict[str, Any],
    n_folds: int = CV_FOLDS,
    *,
    seed: int = 0,
    threads: int = 1,
    ignored: Sequence[str] = IGNORED_FEATURES,
    advance: Callable[[int], Any] | None = None,
) -> np.ndarray:
    """Out-of-fold probabilities of every row of ``rows`` (a split of :func:`verifier_rows`): the rows
    of each frame group (:func:`frame_group`, folds by :func:`grouped_folds`) scored by a verifier
    fitted on the other folds' rows (extra label positives go with their frame's group). One thread
    by default: on a shared machine XGBoost's OpenMP workers spin-wait for each other, and a fold
    fitted on two threads under load took 4–9 min against 30 s on one."""
    frame_groups = [frame_group(src, key) for src, key, _, _ in rows["frames"]]
    fold_of_frame = grouped_folds(frame_groups, n_folds)
    fold = fold_of_frame[rows["origin"]]
    prob = np.zeros(len(rows["y"]), np.float64)
    for f in range(n_folds):
        test = fold == f
        clf = fit_verifier(
            rows["x"][~test],
            rows["y"][~test],
            seed=seed,
            threads=threads,
            negatives=CV_NEGATIVES,
            ignored=ignored,
        )
        prob[test] = clf.predict_proba(rows["x"][test])[:, 1]
        if advance is not None:
            advance(1)
    return prob


def choose_threshold(results_at: Callable[[float], list[FrameResult]]) -> tuple[float, float]:
    """``(threshold, min(P, R))``: the threshold of :data:`THRESHOLDS` that maximises the lower of array
    precision and recall over the frames ``results_at(threshold)`` returns (ties: the lowest)."""
    best: tuple[float, float] = (-1.0, THRESHOLDS[0])
    for t in THRESHOLDS:
        m = metrics(results_at(t))
        p, r = m.array_precision, m.array_recall
        val = min(p, r) if np.isfinite(p) and np.isfinite(r) else 0.0
        if val > best[0]:
            best = (val, t)
    return best[1], max(0.0, best[0])


def box_targets(rows: dict[str, Any], min_iou: float = REFINE_MIN_IOU) -> np.ndarray:
    """Per row of ``rows`` the corrections ``(n, 4)`` that move its proposal onto the labelled box it
    overlaps most — ``(gx1 − x1) / w, (gy1 − y1) / h, (gx2 − x2) / w, (gy2 − y2) / h`` with the
    proposal's width ``w`` and height ``h`` (the inverse of
    :func:`~makeway.perceive.vision.light_verify.refine_boxes`) — or NaN where that IoU is below
    ``min_iou`` (and for the extra label positives)."""
    frame = np.asarray(rows["frame"])
    out = np.full((len(frame), 4), np.nan)
    order = np.argsort(frame, kind="stable")
    bounds = np.searchsorted(frame[order], np.arange(len(rows["frames"]) + 1))
    for k, (_, _, gt, _) in enumerate(rows["frames"]):
        sel = order[bounds[k] : bounds[k + 1]]
        b = rows["boxes"][k]
        if not len(gt) or not len(sel):
            continue
        iou = box_iou_matrix(b, gt)
        g = gt[iou.argmax(axis=1)]
        w = np.maximum(1.0, b[:, 2] - b[:, 0])
        h = np.maximum(1.0, b[:, 3] - b[:, 1])
        off = np.stack(
            [
                (g[:, 0] - b[:, 0]) / w,
                (g[:, 1] - b[:, 1]) / h,
                (g[:, 2] - b[:, 2]) / w,
                (g[:, 3] - b[:, 3]) / h,
            ],
            1,
        )
        near = iou.max(axis=1) >= min_iou
        out[sel[near]] = off[near]
    return out


def fit_refiner(x: np.ndarray, targets: np.ndarray, *, seed: int = 0, threads: int = 1) -> list[Any]:
    """Four :class:`xgboost.XGBRegressor` (:data:`REFINE_PARAMS`), one per corner correction, fitted
    on the rows whose ``targets`` (:func:`box_targets`) are known; targets clipped to ±1.5."""
    import xgboost as xgb

    ok = ~np.isnan(np.asarray(targets)[:, 0])
    if ok.sum() < 10:
        raise ValueError(
            f"only {int(ok.sum())} proposals near a labelled light: cannot learn box corrections"
        )
    x = np.asarray(x, np.float32)[ok]
    t = np.clip(np.asarray(targets, np.float64)[ok], -1.5, 1.5)
    return [
        xgb.XGBRegressor(**REFINE_PARAMS, random_state=seed, n_jobs=threads).fit(x, t[:, c]) for c in range(4)
    ]


def predict_offsets(refiner: Sequence[Any], x: np.ndarray) -> np.ndarray:
    """The four regressors' corrections ``(n, 4)`` of feature rows ``x``."""
    if len(x) == 0:
        return np.zeros((0, 4))
    return np.stack([m.predict(np.asarray(x, np.float32)) for m in refiner], axis=1).astype(np.float64)


def refined_rows(rows: dict[str, Any], offsets: np.ndarray) -> dict[str, Any]:
    """A copy of ``rows`` whose proposal boxes are moved by ``offsets`` (one row each, extra label
    positives ignored) and whose ``y`` says whether the moved box has IoU ≥ 0.5 with a label."""
    from makeway.perceive.vision.light_verify import refine_boxes

    frame = np.asarray(rows["frame"])
    order = np.argsort(frame, kind="stable")
    bounds = np.searchsorted(frame[order], np.arange(len(rows["frames"]) + 1))
    y = np.asarray(rows["y"], bool).copy()
    boxes = []
    for k, (_, _, gt, _) in enumerate(rows["frames"]):
        sel = order[bounds[k] : bounds[k + 1]]
        b = rows["boxes"][k]
        size = (10**9, 10**9)  # clipping to the frame happens at run time; labels lie inside it anyway
        nb = refine_boxes(b, offsets[sel], size) if len(sel) else b
        boxes.append(nb)
        if len(sel):
            y[sel] = box_iou_matrix(nb, gt).max(axis=1) >= 0.5 if len(gt) else False
    return {**rows, "boxes": boxes, "y": y}


def _to_onnx(model: Any) -> Any:
    from onnxmltools import convert_xgboost
    from onnxmltools.convert.common.data_types import FloatTensorType

    return convert_xgboost(
        model,
        initial_types=[("features", FloatTensorType([None, int(model.n_features_in_)]))],
        target_opset=ONNX_OPSET,
    )


def _graft(graph: Any, model: Any, prefix: str) -> list[str]:
    """Copy the ONNX ``model``'s nodes and weights into ``graph``, names prefixed, its input wired to
    the graph's ``features``; returns the copied outputs' names."""
    import onnx

    sub = onnx.compose.add_prefix(model, prefix=prefix)
    inp = sub.graph.input[0].name
    for node in sub.graph.node:
        node.input[:] = ["features" if i == inp else i for i in node.input]
    graph.node.extend(sub.graph.node)
    graph.initializer.extend(sub.graph.initializer)
    return [o.name for o in sub.graph.output]


def _with_default_opset(onx: Any) -> None:
    """Declare the default ONNX domain (the converters' graphs import only ``ai.onnx.ml``)."""
    from onnx import helper

    if not any(op.domain in ("", "ai.onnx") for op in onx.opset_import):
        onx.opset_import.append(helper.make_opsetid("", ONNX_OPSET))


def _mean_of(models: Sequence[Any]) -> Any:
    """One ONNX graph reading ``features`` whose ``probabilities`` are the mean of the boosters'
    (XGBoost classifiers, bagged over seeds) and whose ``label`` is their arg-max."""
    import onnx
    from onnx import helper

    parts = [_to_onnx(m) for m in models]
    onx = onnx.ModelProto()
    onx.CopyFrom(parts[0])
    graph = onx.graph
    del graph.node[:], graph.initializer[:], graph.output[:]
    graph.input[0].name = "features"
    probs = [_graft(graph, sub, f"bag{i}_")[1] for i, sub in enumerate(parts)]
    graph.node.append(helper.make_node("Mean", probs, ["probabilities"], name="bag_mean"))
    graph.node.append(
        helper.make_node("ArgMax", ["probabilities"], ["label"], axis=1, keepdims=0, name="bag_label")
    )
    graph.output.extend(
        [
            helper.make_tensor_value_info("label", onnx.TensorProto.INT64, [None]),
            helper.make_tensor_value_info("probabilities", onnx.TensorProto.FLOAT, [None, 2]),
        ]
    )
    _with_default_opset(onx)
    onnx.checker.check_model(onx)
    return onx


def _export(clf: Any, path: Path, meta_extra: dict[str, Any], refiner: Sequence[Any] | None = None) -> None:
    """Write the classifier (an XGBoost model, a list of them whose probabilities are averaged, or
    an ONNX export) and the box refiner's four regressors (their outputs concatenated as
    ``box_offsets`` (n, 4)) as one ONNX graph reading ``features``, with the metadata."""
    import onnx
    from onnx import helper

    from makeway.atomic import atomic_path
    from makeway.perceive.vision.light_verify import BOX_OUTPUT

    if isinstance(clf, (list, tuple)):
        if len(clf) == 1:
            clf = clf[0]
        else:
            clf = _mean_of(clf)
    if isinstance(clf, onnx.ModelProto):  # an exported classifier (its old metadata is replaced)
        onx = onnx.ModelProto()
        onx.CopyFrom(clf)
        del onx.metadata_props[:]
        width = onx.graph.input[0].type.tensor_type.shape.dim[1].dim_value
    else:
        onx = _to_onnx(clf)
        width = int(clf.n_features_in_)
    if refiner:
        graph = onx.graph
        parts = [_graft(graph, _to_onnx(reg), f"refine{c}_")[0] for c, reg in enumerate(refiner)]
        graph.node.append(helper.make_node("Concat", parts, [BOX_OUTPUT], axis=1, name="box_offsets_concat"))
        _with_default_opset(onx)
        graph.output.append(helper.make_tensor_value_info(BOX_OUTPUT, onnx.TensorProto.FLOAT, [None, 4]))
        onnx.checker.check_model(onx)
    meta = {
        "makeway_model": "light_verifier",
        "format_version": "1",
        "feature_names": json.dumps(feature_names_for(width)),
    }
    meta.update({k: v if isinstance(v, str) else json.dumps(v) for k, v in meta_extra.items()})
    for k, v in meta.items():
        e = onx.metadata_props.add()
        e.key, e.value = k, v
    with atomic_path(path) as tmp:
        onnx.save(onx, str(tmp))


def _finite(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


def fit_from_rows(
    tr: dict[str, Any],
    va: dict[str, Any],
    *,
    seed: int = 0,
    bag: int = 1,
    refine: bool = False,
    threads: int = 1,
    ignored: Sequence[str] = IGNORED_FEATURES,
    progress: bool = False,
) -> dict[str, Any]:
    """Fit the verifier on train rows ``tr`` and choose its threshold (module docstring); with
    ``refine`` also fit the box refiner (:func:`fit_refiner` on :func:`box_targets`), whose grouped
    out-of-fold corrections move the train proposals (and the final refiner the validation ones)
    before the threshold is chosen. ``threads``: XGBoost threads of every fit (one by default: see
    :func:`out_of_fold`). With ``bag`` > 1 the verifier is the mean of ``bag`` boosters fitted with
    seeds ``seed`` … ``seed + bag − 1`` (out-of-fold scores averaged the same way): averaging
    over seeds steadies a model whose cross-validated figures move by 1–3 points from one seed to
    the next. Returns ``classifier`` (a list of ``bag`` boosters), ``refiner`` (None without
    ``refine``), ``threshold``, the train rows' out-of-fold probabilities ``oof`` and a JSON-able
    ``summary``."""
    from makeway.eval.lights import summarise
    from makeway.progress import progress_bar

    if bag < 1:
        raise ValueError(f"bag must be >= 1, got {bag}")
    seeds = list(range(seed, seed + bag))
    with progress_bar("cross-validation folds", CV_FOLDS * bag, enabled=progress, unit="fold") as advance:
        oof = np.mean(
            [
                out_of_fold(tr, CV_FOLDS, seed=s, threads=threads, ignored=ignored, advance=advance)
                for s in seeds
            ],
            axis=0,
        )
    clf = [fit_verifier(tr["x"], tr["y"], seed=s, threads=threads, ignored=ignored) for s in seeds]
    prob = np.mean([c.predict_proba(va["x"])[:, 1] for c in clf], axis=0)
    refiner = None
    tr_eval, va_eval = tr, va
    if refine:
        targets = box_targets(tr)
        keep = np.asarray(tr["frame"]) >= 0  # the extra label positives are their own box
        targets[~keep] = np.nan
        fold = grouped_folds([frame_group(s, k) for s, k, _, _ in tr["frames"]], CV_FOLDS)[tr["origin"]]
        oof_off = np.zeros((len(tr["y"]), 4))
        for f in range(CV_FOLDS):
            test = fold == f
            part = fit_refiner(tr["x"][~test], targets[~test], seed=seed, threads=threads)
            oof_off[test] = predict_offsets(part, tr["x"][test])
        refiner = fit_refiner(tr["x"], targets, seed=seed, threads=threads)
        tr_eval = refined_rows(tr, oof_off)
        va_eval = refined_rows(va, predict_offsets(refiner, va["x"]))
    threshold, _ = choose_threshold(
        lambda t: detector_results(tr_eval, oof, t) + detector_results(va_eval, prob, t)
    )
    keys = ("array_precision", "array_recall", "vehicle_precision", "vehicle_recall")
    cv_res = detector_results(tr_eval, oof, threshold)
    cv_summ = summarise(cv_res)["all"]
    # the same over the frames as recorded (no shrunk copies): comparable with a verifier trained
    # without ``scales``
    cv_orig = summarise([r for r in cv_res if "@" not in r.key])["all"]
    cv_orig_ap = metrics([r for r in detector_results(tr_eval, oof, THRESHOLDS[0]) if "@" not in r.key]).map50
    va_summ = summarise(detector_results(va_eval, prob, threshold))["all"]
    # the ranking over every proposal the lowest threshold keeps (AP50), out of fold and on validation
    cv_ap = metrics(detector_results(tr_eval, oof, THRESHOLDS[0])).map50
    va_ap = metrics(detector_results(va_eval, prob, THRESHOLDS[0])).map50
    summary = {
        "train_rows": len(tr["y"]),
        "train_positives": int(tr["y"].sum()),
        "train_proposal_positives": int(tr["y"][np.asarray(tr["frame"]) >= 0].sum()),
        "val_rows": len(va["y"]),
        "val_positives": int(va["y"].sum()),
        "threshold": threshold,
        "threshold_from": f"train {CV_FOLDS}-fold grouped CV (out-of-fold) + validation, max min(P, R)",
        "validation": {**{k: va_summ[k] for k in keys}, "ap50": _finite(va_ap)},
        "train_cv": {**{k: cv_summ[k] for k in keys}, "ap50": _finite(cv_ap)},
        "train_cv_recorded_frames": {**{k: cv_orig[k] for k in keys}, "ap50": _finite(cv_orig_ap)},
        "features": len(feature_names_for(tr["x"].shape[1])),
        "vehicle_context": tr["x"].shape[1] > len(FEATURE_NAMES),
        "appearance_components": max(0, tr["x"].shape[1] - len(FEATURE_NAMES + CONTEXT_FEATURE_NAMES)),
        "refine_boxes": refine,
        "params": XGB_PARAMS,
        "ignored_features": list(ignored),
        "refine_params": REFINE_PARAMS if refine else None,
        "seed": seed,
        "bag": bag,
    }
    return {"classifier": clf, "refiner": refiner, "threshold": threshold, "summary": summary, "oof": oof}


def train_light_verifier(
    out: str | Path | None = None,
    *,
    data_root: str | Path | None = None,
    label_positives: bool = True,
    seed: int = 0,
    refine: bool = False,
    vehicle_context: bool = True,
    appearance: int = 8,
    bag: int = 3,
    scales: Sequence[float] = (1.0,),
    applies_below_px: float | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Train the verifier on the train split, pick its threshold on the train split's grouped
    out-of-fold scores pooled with the validation split (module docstring) and write it as ONNX to
    ``out`` (default: the shipped ``models/lights_verifier.onnx``). With ``vehicle_context`` the
    rows also describe each proposal against the frame's vehicle boxes (YOLOX-nano,
    :func:`~makeway.perceive.vision.light_verify.context_features`); with ``appearance`` > 0
    (vehicle context needed) they end with that many appearance columns
    (:class:`~makeway.perceive.vision.light_verify.ProposalAppearance`, its standardisation and
    principal axes fitted on the train rows and stored in the model's metadata); the verifier
    averages ``bag`` boosters (:func:`fit_from_rows`); ``scales`` adds shrunk copies of the train
    frames (:func:`verifier_rows`; validation stays as it is). ``applies_below_px`` marks the model
    as the small-lamp verifier: the detector then scores with it only the proposals whose longer
    side is under that many pixels (metadata ``applies_below_px``;
    :class:`~makeway.perceive.vision.light_verify.VerifiedLightDetector`). Returns the
    counts, the threshold, the validation and train cross-validation figures and the seconds taken.

    Raises:
        InputError: no shared data folder, ``out``'s folder does not exist, or (with
            ``vehicle_context``) the vehicle detector's weights are missing.
    """
    from makeway.errors import InputError
    from makeway.paths import require_data_dir
    from makeway.perceive.vision.light_verify import vehicle_detector
    from makeway.progress import progress_bar
    from makeway.train.light_split import load_split

    target = Path(out) if out is not None else DEFAULT_VERIFIER_MODEL
    if not target.parent.is_dir():
        raise InputError(target, "its folder does not exist")
    root = require_data_dir(data_root)
    if appearance < 0 or (appearance and not vehicle_context):
        raise ValueError("appearance columns need the vehicle context and a count >= 0")
    if applies_below_px is not None and not applies_below_px > 0:
        raise ValueError(f"applies_below_px must be a positive size in pixels, got {applies_below_px}")
    if not scales or any(not 0.0 < v <= 1.0 for v in scales):
        raise ValueError(f"scales must lie in (0, 1], got {list(scales)}")
    t0 = time.perf_counter()
    vehicles = None
    if vehicle_context:
        vehicles = vehicle_detector(num_threads=1).detect_arrays
    app = ProposalAppearance(n_components=appearance) if appearance else None
    rows = {}
    for split in ("train", "val"):
        n = len(load_split(split, root, keep_images=False)[0])
        copies = tuple(scales) if split == "train" else (1.0,)
        with progress_bar(f"{split} proposals", n * len(copies), enabled=progress, unit="frame") as advance:
            rows[split] = verifier_rows(
                split,
                root,
                label_positives=label_positives and split == "train",
                vehicles=vehicles,
                extra_features=app.vectors if app is not None else None,
                scales=copies,
                advance=advance,
            )
    meta: dict[str, Any] = {}
    if applies_below_px is not None:
        meta["applies_below_px"] = repr(float(applies_below_px))
    if app is not None:  # the backbone's vectors → their coordinates on the train rows' principal axes
        width = len(FEATURE_NAMES + CONTEXT_FEATURE_NAMES)
        app.fit(rows["train"]["x"][:, width:], seed=0)
        for r in rows.values():
            r["x"] = np.concatenate([r["x"][:, :width], app.project(r["x"][:, width:])], axis=1)
        meta["appearance"] = app.to_json()
    ignored = IGNORED_FEATURES + (IGNORED_CONTEXT_FEATURES if vehicle_context else ())
    fitted = fit_from_rows(
        rows["train"], rows["val"], seed=seed, bag=bag, refine=refine, ignored=ignored, progress=progress
    )
    result = {
        "model": str(target),
        **fitted["summary"],
        "label_positives": label_positives,
        "train_scales": [float(v) for v in scales],
    }
    _export(
        fitted["classifier"],
        target,
        {
            "threshold": str(fitted["threshold"]),
            "training": {k: v for k, v in result.items() if k != "model"},
            **meta,
        },
        refiner=fitted["refiner"],
    )
    result["seconds"] = round(time.perf_counter() - t0, 1)
    result["size_bytes"] = target.stat().st_size
    return result
