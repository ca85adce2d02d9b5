"""The classical classifier study (SPEC §2): hand-made features × scikit-learn-style classifiers.

Seeds 001/003 (the thesis on two vision frameworks and its project report, SPEC §2) compared raw
pixels, HOG, a colour histogram and a custom HSV vector (:mod:`makeway.perceive.vision.features`)
under six classifiers; this module reruns that grid on our crops with an honest held-out split.
:data:`CLASSIFIERS` builds each with the seeds' settings:

=================  ==============================================================================
name               estimator
=================  ==============================================================================
svm                ``StandardScaler`` → ``SVC(kernel="poly", max_iter=50000)`` (scaling added: a
                   polynomial kernel on unscaled features is ill-conditioned)
adaboost           ``AdaBoostClassifier(n_estimators=100)`` (depth-1 trees, SAMME)
random_forest      ``RandomForestClassifier(n_estimators=10)``
gradient_boosting  ``GradientBoostingClassifier(n_estimators=100, learning_rate=1.0, max_depth=1)``
xgboost            ``XGBClassifier()`` with XGBoost's defaults (package ``xgboost-cpu``)
knn                ``KNeighborsClassifier(n_neighbors=3)``
logreg             ``StandardScaler`` → ``LogisticRegressionCV(Cs=10⁻⁴…10¹, cv=5, max_iter=2000)``:
                   L2 logistic regression whose C is chosen by a stratified 5-fold CV inside
                   ``fit``, i.e. on the training part only (added for the ``yolox`` features)
small_cnn          the seeds' small CNN (:class:`makeway.train.cnn.SmallCNNPixels`: 3 × conv+ReLU+
                   max-pool, dense ReLU, one sigmoid unit) on the ``pixels`` feature reshaped to
                   128×128 images; focal loss, Adam, plateau schedule, augmentation (needs torch,
                   extra ``train``; imported only when built). Runs with ``pixels`` only
                   (:data:`ONLY_FEATURES`); other pairs are left out.
=================  ==============================================================================

:func:`run_study` fits every pair on a training set and scores the test set: accuracy, precision,
recall, F1 at the estimator's own decision rule, max-F1 and precision at recall 0.8 over the
thresholds of its score (``decision_function``, else ``predict_proba``;
:mod:`makeway.eval.classification`), fit seconds, and milliseconds per 100 crops to predict and to
compute the feature. :func:`write_study` writes ``study.md`` and ``study.csv``.
No torch here; the small CNN of the study lives with the other networks (:mod:`makeway.train.cnn`).
"""

from __future__ import annotations

import csv
import io
import time
import warnings
from collections.abc import Callable, Collection, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from makeway.atomic import write_text_atomic
from makeway.eval.classification import precision_recall_f1, threshold_metrics
from makeway.perceive.vision.features import FEATURES, compute_features
from makeway.progress import progress_bar
from makeway.sense.crops import CropSet

__all__ = [
    "CLASSIFIERS",
    "ONLY_FEATURES",
    "StudyRow",
    "compatible",
    "make_classifier",
    "run_study",
    "write_study",
]


def _svm(n_jobs: int, seed: int) -> Any:
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler
    from sklearn.svm import SVC

    return make_pipeline(StandardScaler(), SVC(kernel="poly", max_iter=50000, random_state=seed))


def _adaboost(n_jobs: int, seed: int) -> Any:
    from sklearn.ensemble import AdaBoostClassifier

    return AdaBoostClassifier(n_estimators=100, random_state=seed)


def _random_forest(n_jobs: int, seed: int) -> Any:
    from sklearn.ensemble import RandomForestClassifier

    return RandomForestClassifier(n_estimators=10, n_jobs=n_jobs, random_state=seed)


def _gradient_boosting(n_jobs: int, seed: int) -> Any:
    from sklearn.ensemble import GradientBoostingClassifier

    return GradientBoostingClassifier(n_estimators=100, learning_rate=1.0, max_depth=1, random_state=seed)


def _xgboost(n_jobs: int, seed: int) -> Any:
    try:
        from xgboost import XGBClassifier
    except ImportError:
        raise ValueError(
            "the xgboost classifier needs the package xgboost-cpu (pip install xgboost-cpu)"
        ) from None
    return XGBClassifier(n_jobs=n_jobs, random_state=seed)


def _knn(n_jobs: int, seed: int) -> Any:
    from sklearn.neighbors import KNeighborsClassifier

    return KNeighborsClassifier(n_neighbors=3, n_jobs=n_jobs)


def _logreg(n_jobs: int, seed: int) -> Any:
    from sklearn.linear_model import LogisticRegressionCV
    from sklearn.model_selection import StratifiedKFold
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    inner = StratifiedKFold(n_splits=5, shuffle=True, random_state=seed)
    model = LogisticRegressionCV(Cs=np.logspace(-4, 1, 6), cv=inner, max_iter=2000, n_jobs=n_jobs)
    return make_pipeline(StandardScaler(), model)


def _small_cnn(n_jobs: int, seed: int) -> Any:
    try:
        from makeway.train.cnn import SmallCNNPixels  # torch, lazily
    except ImportError:
        raise ValueError("the small_cnn classifier needs torch (pip install 'makeway[train]')") from None
    return SmallCNNPixels(n_jobs=max(1, min(n_jobs, 2)), seed=seed)


#: Classifier factories by name: ``factory(n_jobs, seed)`` → an unfitted estimator (module docstring).
CLASSIFIERS: dict[str, Callable[[int, int], Any]] = {
    "svm": _svm,
    "adaboost": _adaboost,
    "random_forest": _random_forest,
    "gradient_boosting": _gradient_boosting,
    "xgboost": _xgboost,
    "knn": _knn,
    "logreg": _logreg,
    "small_cnn": _small_cnn,
}

#: Classifiers that take only some features (the small CNN needs images: the ``pixels`` feature).
ONLY_FEATURES: dict[str, tuple[str, ...]] = {"small_cnn": ("pixels",)}


def compatible(feature: str, classifier: str) -> bool:
    """Whether the study runs ``classifier`` on ``feature`` (see :data:`ONLY_FEATURES`)."""
    return feature in ONLY_FEATURES.get(classifier, (feature,))


def make_classifier(name: str, *, n_jobs: int = 1, seed: int = 0) -> Any:
    """A fresh estimator from :data:`CLASSIFIERS`; ``ValueError`` listing the names for an unknown one."""
    try:
        factory = CLASSIFIERS[name]
    except KeyError:
        raise ValueError(f"unknown classifier {name!r}; registered: {', '.join(CLASSIFIERS)}") from None
    return factory(n_jobs, seed)


@dataclass(frozen=True, slots=True)
class StudyRow:
    """One feature × classifier result on one split (times in seconds / milliseconds per 100 crops)."""

    feature: str
    classifier: str
    split: str
    n_train: int
    n_test: int
    accuracy: float
    precision: float
    recall: float
    f1: float
    max_f1: float
    p_at_r80: float
    fit_s: float
    predict_ms_per_100: float
    feature_ms_per_100: float
    note: str = ""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _scores(model: Any, x: np.ndarray) -> np.ndarray:
    if hasattr(model, "decision_function"):
        return np.asarray(model.decision_function(x), dtype=np.float64).ravel()
    proba = np.asarray(model.predict_proba(x), dtype=np.float64)
    return proba[:, -1]


def _check_names(chosen: Sequence[str], known: Sequence[str], what: str) -> list[str]:
    out = list(dict.fromkeys(chosen))
    bad = [n for n in out if n not in known]
    if bad or not out:
        raise ValueError(f"unknown {what} {', '.join(bad) or '(none given)'}; registered: {', '.join(known)}")
    return out


def run_study(
    train_set: CropSet,
    test_set: CropSet,
    features: Sequence[str] = tuple(FEATURES),
    classifiers: Sequence[str] = tuple(CLASSIFIERS),
    *,
    split: str = "test",
    image_size: int = 224,
    n_jobs: int = 1,
    seed: int = 0,
    progress: bool = True,
    on_row: Callable[[StudyRow], Any] | None = None,
    skip: Collection[tuple[str, str]] = (),
) -> list[StudyRow]:
    """Fit every ``features`` × ``classifiers`` pair on ``train_set`` and score it on ``test_set``.

    Crops are loaded at ``image_size`` (then each feature resizes as it needs). ``split`` names the
    test split in the rows (e.g. ``"ev_crops holdout"``). ``on_row`` is called with each finished row
    (to write partial results). ``skip`` lists ``(feature, classifier)`` pairs not to run (too slow on
    small machines). A classifier that stops at its iteration cap gets a ``note``.
    """
    feats = _check_names(features, list(FEATURES), "features")
    clfs = _check_names(classifiers, list(CLASSIFIERS), "classifiers")
    skipped = {(f, c) for f, c in skip}
    pairs = {f: [c for c in clfs if (f, c) not in skipped and compatible(f, c)] for f in feats}
    pairs = {f: c for f, c in pairs.items() if c}  # a feature no chosen classifier takes is not computed
    feats = list(pairs)
    y_train = np.asarray(train_set.labels, dtype=np.int64)
    y_test = np.asarray(test_set.labels, dtype=np.int64)
    if len(np.unique(y_train)) < 2:
        raise ValueError("the training set needs both labels")
    with progress_bar("loading crops", len(train_set) + len(test_set), enabled=progress, unit="crops") as adv:
        x_train_img = train_set.load_images(image_size, advance=adv)
        x_test_img = test_set.load_images(image_size, advance=adv)
    rows: list[StudyRow] = []
    n_test = len(test_set)
    with progress_bar(
        "feature × classifier", sum(1 + len(c) for c in pairs.values()), enabled=progress, unit="steps"
    ) as adv:
        for feat in feats:
            x_train = compute_features(feat, x_train_img)
            t0 = time.perf_counter()
            x_test = compute_features(feat, x_test_img)
            feature_ms = (time.perf_counter() - t0) * 1e5 / max(n_test, 1)
            adv(1)
            for name in pairs[feat]:
                model = make_classifier(name, n_jobs=n_jobs, seed=seed)
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    t0 = time.perf_counter()
                    model.fit(x_train, y_train)
                    fit_s = time.perf_counter() - t0
                note = ""
                if any("terminated early" in str(w.message) or "max_iter" in str(w.message) for w in caught):
                    note = "stopped at max_iter"
                t0 = time.perf_counter()
                pred = np.asarray(model.predict(x_test)).astype(np.int64).ravel()
                predict_ms = (time.perf_counter() - t0) * 1e5 / max(n_test, 1)
                scores = _scores(model, x_test)
                tp = int(np.sum((pred == 1) & (y_test == 1)))
                fp = int(np.sum((pred == 1) & (y_test == 0)))
                fn = int(np.sum((pred == 0) & (y_test == 1)))
                prf = precision_recall_f1(tp, fp, fn)
                thr = threshold_metrics(scores, y_test, recall_at=0.8)
                row = StudyRow(
                    feature=feat,
                    classifier=name,
                    split=split,
                    n_train=len(train_set),
                    n_test=n_test,
                    accuracy=float(np.mean(pred == y_test)) if n_test else float("nan"),
                    precision=float(prf["precision"]),
                    recall=float(prf["recall"]),
                    f1=float(prf["f1"]),
                    max_f1=thr["max_f1"],
                    p_at_r80=thr["precision_at_recall_0.8"],
                    fit_s=fit_s,
                    predict_ms_per_100=predict_ms,
                    feature_ms_per_100=feature_ms,
                    note=note,
                )
                rows.append(row)
                if on_row is not None:
                    on_row(row)
                adv(1)
    return rows


def _sort_key(row: StudyRow) -> tuple[float, float]:
    acc = row.accuracy if np.isfinite(row.accuracy) else -1.0
    f1 = row.f1 if np.isfinite(row.f1) else -1.0
    return (-acc, -f1)


def _fmt(value: float, digits: int = 3) -> str:
    return "–" if not np.isfinite(value) else f"{value:.{digits}f}"


def write_study(
    rows: Sequence[StudyRow],
    out_dir: str | Path,
    *,
    title: str = "Classical classifier study (SPEC §2)",
    notes: Sequence[str] = (),
) -> tuple[Path, Path]:
    """Write ``study.md`` (rows sorted by accuracy, then F1) and ``study.csv``; returns both paths.

    ``notes`` are Markdown lines printed above the table (data, split, command, machine). Each row
    names the split it was evaluated on. Both files are written atomically.
    """
    out = Path(out_dir)
    ordered = sorted(rows, key=_sort_key)
    md = [f"# {title}", ""]
    if notes:
        md += [*notes, ""]
    md += [
        "| # | feature | classifier | accuracy | precision | recall | F1 | max-F1 | P@R0.8 "
        "| fit s | predict ms/100 | feature ms/100 | split (n train / n test) | note |",
        "|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---|",
    ]
    for k, r in enumerate(ordered, start=1):
        md.append(
            f"| {k} | {r.feature} | {r.classifier} | {_fmt(r.accuracy)} | {_fmt(r.precision)} "
            f"| {_fmt(r.recall)} | {_fmt(r.f1)} | {_fmt(r.max_f1)} | {_fmt(r.p_at_r80)} | {_fmt(r.fit_s, 2)} "
            f"| {_fmt(r.predict_ms_per_100, 1)} | {_fmt(r.feature_ms_per_100, 1)} "
            f"| {r.split} ({r.n_train} / {r.n_test}) | {r.note} |"
        )
    md_path, csv_path = out / "study.md", out / "study.csv"
    write_text_atomic(md_path, "\n".join(md) + "\n")
    buf = io.StringIO()
    names = [f.name for f in fields(StudyRow)]
    writer = csv.DictWriter(buf, fieldnames=names, lineterminator="\n")
    writer.writeheader()
    for r in ordered:
        d = r.to_dict()
        writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in d.items()})
    write_text_atomic(csv_path, buf.getvalue())
    return md_path, csv_path
