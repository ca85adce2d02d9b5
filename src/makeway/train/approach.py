"""Training of the approaching/receding classifier of :class:`~makeway.perceive.audio.motion.TrendApproach`
(issue 4, item 3) — XGBoost and onnxmltools live here only (``pip install makeway[train]``).

**Data.** :func:`approach_dataset` runs folders of labelled recordings through
:func:`~makeway.eval.siren_approach.approach_windows` — the shipped siren networks, the listener's
decision rule and the trend estimator's feature rows, exactly as ``makeway audio listen`` makes
them — and keeps the scored windows (a siren the listener reports, moving by ≥ 1 m/s relative to
the car). Target: approaching (the labelled range rate of the nearest siren is negative).

**Model.** Gradient-boosted trees (:data:`XGB_PARAMS`: 300 trees of depth 4, learning rate 0.05,
row subsampling 0.8; ``max_depth`` may be set per training: the wide rangers' classifier uses 6,
chosen on validation recordings). Trees take the has-slope flags and the saturation of the slopes as they
come, and were more accurate on validation recordings than a logistic regression on the same rows
(docs/journal.md, "Sirens: approaching or receding, from the trend of the network's distance").
:func:`export_approach_onnx` converts the booster to an ONNX ``TreeEnsembleClassifier``
(onnxmltools) with the feature names in the metadata, so the runtime needs only ONNX Runtime.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from makeway.eval.siren_approach import approach_recordings
from makeway.perceive.audio.motion import TrendApproach
from makeway.perceive.audio.siren_model import SirenModel
from makeway.sense.recording import recording_folders

XGB_PARAMS: dict[str, Any] = {
    "n_estimators": 300,
    "max_depth": 4,
    "learning_rate": 0.05,
    "subsample": 0.8,
}
"""The booster's settings (module docstring)."""
ONNX_OPSET = 15
"""The highest default-domain opset onnxmltools converts XGBoost to."""


def approach_dataset(
    folders: Sequence[str | Path],
    model: SirenModel,
    *,
    advance: Callable[[int], Any] | None = None,
) -> dict[str, np.ndarray]:
    """Per-window arrays of every recording under ``folders`` (:func:`~makeway.eval.siren_approach
    .approach_recordings`, the trend estimator making feature rows only), pooled."""
    recordings = [r for f in folders for r in recording_folders(Path(f))]
    return approach_recordings(recordings, model, TrendApproach(model=None), advance=advance)


def fit_approach(
    features: np.ndarray,
    approaching: np.ndarray,
    *,
    seed: int = 0,
    threads: int = 2,
    max_depth: int | None = None,
) -> Any:
    """An :class:`xgboost.XGBClassifier` (:data:`XGB_PARAMS`, with ``max_depth`` when given) fitted
    to predict ``approaching``."""
    import xgboost as xgb

    y = np.asarray(approaching, dtype=bool)
    if len(np.unique(y)) < 2:
        raise ValueError("the training windows hold only one class (need approaching and receding sirens)")
    params = approach_params(max_depth)
    clf = xgb.XGBClassifier(**params, random_state=seed, n_jobs=threads, eval_metric="logloss")
    return clf.fit(np.asarray(features, dtype=np.float32), y)


def approach_params(max_depth: int | None = None) -> dict[str, Any]:
    """:data:`XGB_PARAMS` with the trees' depth ``max_depth`` when given.

    Raises:
        ValueError: a depth below 1.
    """
    if max_depth is None:
        return dict(XGB_PARAMS)
    if max_depth < 1:
        raise ValueError(f"the trees' depth must be at least 1, got {max_depth}")
    return {**XGB_PARAMS, "max_depth": int(max_depth)}


def export_approach_onnx(
    clf: Any, path: str | Path, feature_names: Sequence[str], extra: dict[str, Any] | None = None
) -> Path:
    """Write the fitted booster as ONNX with ``feature_names`` and ``extra`` (training description,
    metrics) in the metadata read by :class:`~makeway.perceive.audio.motion.TrendApproach`."""
    import onnx
    from onnxmltools import convert_xgboost
    from onnxmltools.convert.common.data_types import FloatTensorType

    from makeway.atomic import atomic_path

    onx = convert_xgboost(
        clf,
        initial_types=[("features", FloatTensorType([None, len(feature_names)]))],
        target_opset=ONNX_OPSET,
    )
    meta = {
        "makeway_model": "siren_approach",
        "format_version": "1",
        "feature_names": json.dumps(list(feature_names)),
    }
    for k, v in (extra or {}).items():
        meta[k] = v if isinstance(v, str) else json.dumps(v)
    for k, v in meta.items():
        entry = onx.metadata_props.add()
        entry.key, entry.value = k, v
    with atomic_path(path) as tmp:
        onnx.save(onx, str(tmp))
    return Path(path)


def train_approach_classifier(
    data: Sequence[str | Path],
    out: str | Path | None = None,
    *,
    val: Sequence[str | Path] = (),
    siren: SirenModel | None = None,
    seed: int = 0,
    max_depth: int | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Train the approaching/receding classifier on the recordings under each folder of ``data`` and
    write it to ``out`` as ONNX (default: the shipped classifier paired with ``siren``'s rangers,
    :func:`~makeway.perceive.audio.motion.approach_model_for`: a classifier reads the distances of
    the rangers it was trained on). Every recording runs as ``audio listen`` runs it through
    ``siren`` (default: the shipped siren networks); the windows where a siren is reported and
    moves by at least 1 m/s relative to the car are the rows, the sign of the labelled range rate
    the target (module docstring).

    Returns ``model`` (the file written), ``training`` (recordings, windows, ``approaching_share``,
    the booster's params, seed, siren model, ranger files) and, with ``val``, ``validation``: the
    scores of the new classifier and of the level/Doppler rule on those recordings
    (:func:`~makeway.eval.siren_approach.approach_scores`).

    Raises:
        InputError: a recording folder or a model cannot be read (all folders listed first).
        ValueError: the training windows hold only one class.
    """
    from makeway.eval.siren_approach import approach_scores
    from makeway.perceive.audio.motion import approach_model_for
    from makeway.progress import progress_bar

    folders = [f for d in data for f in recording_folders(d)]
    val_folders = [f for d in val for f in recording_folders(d)]
    net = siren if siren is not None else SirenModel(None, localizer=True, ranger=True)
    rangers = [r.path for r in net.rangers]
    target = Path(out) if out is not None else approach_model_for(rangers)
    with progress_bar("training windows", len(folders), enabled=progress, unit="rec") as advance:
        train_set = approach_dataset(folders, net, advance=advance)
    rows = train_set["scored"]
    clf = fit_approach(
        train_set["features"][rows], train_set["approaching"][rows], seed=seed, max_depth=max_depth
    )
    training = {
        "recordings": len(folders),
        "windows": int(rows.sum()),
        "approaching_share": round(float(train_set["approaching"][rows].mean()), 4),
        "params": approach_params(max_depth),
        "seed": seed,
        "siren_model": repr(net),
        "rangers": [p.name for p in rangers],
    }
    export_approach_onnx(clf, target, TrendApproach(model=None).feature_names, extra={"training": training})
    result: dict[str, Any] = {"model": str(target), "training": training}
    if val_folders:
        trained = TrendApproach(target)
        with progress_bar("validation", len(val_folders), enabled=progress, unit="rec") as advance:
            val_set = approach_dataset(val_folders, net, advance=advance)
        result["validation"] = approach_scores(val_set, trained)
    return result
