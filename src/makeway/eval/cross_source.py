"""Cross-source evaluation of EV crop classifiers: leave one source out (issue 24, item 1).

A *source* is one labelled crop set with its own look (web photos, road photos, video frames of
one camera …). A classifier that is right on crops like those it learnt from can still fail on
another source, so every vision model is judged on each source it has not seen:

* :func:`leave_one_source_out` — for each named source, a *trainer* (a callable: training
  :class:`~makeway.sense.crops.CropSet` → classifier) is fitted on all the other sources together
  and the held-out source is scored alone;
* :func:`score_sources` — a fixed model (no training; e.g. a shipped one) scored on each source as
  given (the caller passes only the part the model did not learn from).

Each score (:class:`SourceScore`) is taken at the classifier's own decision threshold (a
probability at or above it is an EV): accuracy, precision, recall, F1, specificity, ``n`` and the
positive share. A source with one class only is still scored: accuracy, and recall (positives
only) or specificity (negatives only); precision and F1 are then ``None`` — not 0 — with
``classes`` saying why. :func:`worst_source` is the source of lowest accuracy, the protocol's
headline (target ≥ 0.90).

The training set of a held-out source joins the other sources' crops; each crop's ``group``
becomes ``<source>/<group>`` (``<source>/#<index>`` when the source has none), so a trainer that
keeps groups together (e.g. in its inner cross-validation) never mixes sources' groups.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from makeway.errors import InputError
from makeway.eval.classification import precision_recall_f1
from makeway.sense.crops import CropSet

__all__ = [
    "CropModel",
    "SourceScore",
    "check_sources",
    "leave_one_source_out",
    "merge_sources",
    "predict_crop_set",
    "score_crops",
    "score_sources",
    "worst_source",
]


class CropModel(Protocol):
    """What the protocol needs from a crop classifier: its decision ``threshold``, the crop size it
    wants (``input_size``) and ``predict_proba`` of ``uint8`` BGR crops ``(n, S, S, 3)`` → ``(n,)``.
    A model may also have ``predict_crop_set(crops) -> (n,)`` (e.g. from cached features); it is
    used instead when present."""

    threshold: float

    @property
    def input_size(self) -> int: ...

    def predict_proba(self, images: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class SourceScore:
    """One model scored on one source at its threshold (module docstring).

    ``trained_on`` names the sources the model was fitted on (``()`` for a fixed model);
    ``classes`` is ``"both"``, ``"positive only"`` or ``"negative only"``. Undefined figures are
    ``None``.
    """

    model: str
    source: str
    n: int
    n_positive: int
    accuracy: float
    precision: float | None
    recall: float | None
    f1: float | None
    specificity: float | None
    threshold: float
    classes: str
    trained_on: tuple[str, ...] = ()

    @property
    def positive_share(self) -> float:
        """Fraction of the source's crops that are EVs."""
        return self.n_positive / self.n if self.n else float("nan")

    def as_dict(self) -> dict[str, Any]:
        """A flat dict for one JSON line (figures rounded to 4 digits)."""

        def r(x: float | None) -> float | None:
            return None if x is None else round(float(x), 4)

        out: dict[str, Any] = {
            "model": self.model,
            "held_out": self.source,
            "accuracy": r(self.accuracy),
            "precision": r(self.precision),
            "recall": r(self.recall),
            "f1": r(self.f1),
            "specificity": r(self.specificity),
            "n": self.n,
            "positive_share": r(self.positive_share),
            "threshold": self.threshold,
            "classes": self.classes,
        }
        if self.trained_on:
            out["trained_on"] = list(self.trained_on)
        return out


def _defined(x: float) -> float | None:
    return None if np.isnan(x) else float(x)


def score_crops(
    probs: np.ndarray,
    labels: np.ndarray,
    threshold: float,
    *,
    model: str,
    source: str,
    trained_on: Sequence[str] = (),
) -> SourceScore:
    """Score probabilities ``(n,)`` against 0/1 ``labels`` at ``threshold`` (``p >= threshold`` is an
    EV); see :class:`SourceScore`.

    Raises:
        ValueError: lengths differ or there is nothing to score.
    """
    p = np.asarray(probs, dtype=np.float64).ravel()
    y = np.asarray(labels).astype(bool).ravel()
    if p.shape != y.shape:
        raise ValueError(f"{p.size} probabilities but {y.size} labels")
    if y.size == 0:
        raise ValueError(f"source {source!r}: nothing to score")
    pred = p >= threshold
    tp, fp = int(np.sum(pred & y)), int(np.sum(pred & ~y))
    fn, tn = int(np.sum(~pred & y)), int(np.sum(~pred & ~y))
    n_pos = int(y.sum())
    if 0 < n_pos < y.size:
        classes = "both"
        prf = precision_recall_f1(tp, fp, fn)
        precision, f1 = _defined(prf["precision"]), _defined(prf["f1"])
    else:
        classes = "positive only" if n_pos else "negative only"
        precision = f1 = None  # a one-class source cannot measure them
    return SourceScore(
        model=model,
        source=source,
        n=int(y.size),
        n_positive=n_pos,
        accuracy=(tp + tn) / y.size,
        precision=precision,
        recall=tp / n_pos if n_pos else None,
        f1=f1,
        specificity=tn / (tn + fp) if tn + fp else None,
        threshold=float(threshold),
        classes=classes,
        trained_on=tuple(trained_on),
    )


def predict_crop_set(model: CropModel, crops: CropSet) -> np.ndarray:
    """P(EV) ``(n,)`` of every crop: ``model.predict_crop_set`` when it has one, else its
    ``predict_proba`` on the crops loaded at its ``input_size``."""
    fn: Callable[[CropSet], np.ndarray] | None = getattr(model, "predict_crop_set", None)
    if fn is not None:
        return np.asarray(fn(crops), dtype=np.float64)
    images = crops.load_images(model.input_size, cache=False)
    return np.asarray(model.predict_proba(images), dtype=np.float64)


def check_sources(sources: Mapping[str, CropSet]) -> None:
    """Every source has a name and at least one crop.

    Raises:
        InputError: an empty source (named by its folder, or by its name).
    """
    if not sources:
        raise ValueError("no sources to evaluate on")
    for name, crops in sources.items():
        if not name:
            raise ValueError("a source needs a name")
        if len(crops) == 0:
            raise InputError(crops.root or Path(name), f"source {name!r} has no crops")


def merge_sources(sources: Mapping[str, CropSet]) -> CropSet:
    """All crops of ``sources`` as one set, in the order given; groups ``<source>/<group>`` (or
    ``<source>/#<index>`` where a source has none)."""
    paths: list[Path] = []
    labels: list[np.ndarray] = []
    groups: list[np.ndarray] = []
    for name, crops in sources.items():
        paths.extend(crops.paths)
        labels.append(np.asarray(crops.labels, dtype=np.int64))
        own = (
            crops.groups if crops.groups is not None else np.char.add("#", np.arange(len(crops)).astype(str))
        )
        groups.append(np.char.add(f"{name}/", np.asarray(own).astype(str)))
    return CropSet(
        paths=tuple(paths),
        labels=np.concatenate(labels) if labels else np.empty(0, dtype=np.int64),
        groups=np.concatenate(groups) if groups else None,
    )


def leave_one_source_out(
    sources: Mapping[str, CropSet],
    trainer: Callable[[CropSet], CropModel],
    *,
    model: str = "trained",
    held_out: Sequence[str] | None = None,
    on_score: Callable[[SourceScore], None] | None = None,
    log: Callable[[str], None] | None = None,
) -> list[SourceScore]:
    """For each source (or each of ``held_out``), fit ``trainer`` on all the other sources
    (:func:`merge_sources`) and score the held-out one alone (:func:`score_crops`). ``on_score``
    gets each score as soon as it is known; ``log`` a line per fit.

    Raises:
        InputError: an empty source.
        ValueError: fewer than two sources, or a ``held_out`` name that is not a source.
    """
    check_sources(sources)
    if len(sources) < 2:
        raise ValueError("leave-one-source-out needs at least two sources")
    names = list(held_out) if held_out is not None else list(sources)
    unknown = [n for n in names if n not in sources]
    if unknown:
        raise ValueError(f"unknown source {unknown[0]!r}; sources: {', '.join(sources)}")
    scores: list[SourceScore] = []
    for name in names:
        rest = {k: v for k, v in sources.items() if k != name}
        train_set = merge_sources(rest)
        if log is not None:
            log(
                f"{model}: training on {', '.join(rest)} ({len(train_set)} crops, "
                f"{train_set.n_positive} positive), holding out {name}"
            )
        clf = trainer(train_set)
        test = sources[name]
        score = score_crops(
            predict_crop_set(clf, test),
            test.labels,
            clf.threshold,
            model=model,
            source=name,
            trained_on=tuple(rest),
        )
        scores.append(score)
        if on_score is not None:
            on_score(score)
    return scores


def score_sources(
    clf: CropModel,
    sources: Mapping[str, CropSet],
    *,
    model: str,
    on_score: Callable[[SourceScore], None] | None = None,
) -> list[SourceScore]:
    """A fixed model scored on each source as given (:func:`score_crops` at its threshold).

    Raises:
        InputError: an empty source.
    """
    check_sources(sources)
    scores = []
    for name, crops in sources.items():
        score = score_crops(
            predict_crop_set(clf, crops), crops.labels, clf.threshold, model=model, source=name
        )
        scores.append(score)
        if on_score is not None:
            on_score(score)
    return scores


def worst_source(scores: Sequence[SourceScore]) -> SourceScore:
    """The score of lowest accuracy (the first such in order on a tie).

    Raises:
        ValueError: no scores.
    """
    if not scores:
        raise ValueError("no scores")
    return min(scores, key=lambda s: s.accuracy)
