"""Training of the EV crop classifier head (:class:`~makeway.perceive.vision.ev_classifier.EVCropClassifier`):
pooled detector-backbone features of each crop (and its mirror image) + standardised logistic
regression, written as ``.npz``. No torch needed.

:class:`FeatureCache` keeps the backbone features of crop files on disk, so that fitting a head
many times on overlapping crop sets (the cross-source protocol, :mod:`makeway.eval.cross_source`)
runs the backbones once per crop; :func:`head_trainer` is that protocol's trainer for the head and
:func:`cached_head` scores a fitted head from the same cache."""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from makeway.atomic import atomic_path
from makeway.eval.classification import operating_point_metrics
from makeway.perceive.vision.backbone import DEFAULT_BLOCKS, FeatureBlock
from makeway.perceive.vision.ev_classifier import DEFAULT_MODEL, EVCropClassifier
from makeway.progress import progress_bar
from makeway.sense.crops import CropSet, near_duplicate_groups, read_crop_folder, training_split

__all__ = ["CachedHead", "CropTrainingRun", "FeatureCache", "cached_head", "head_trainer", "train_ev_head"]


@dataclass(frozen=True)
class CropTrainingRun:
    """What a crop classifier training wrote (``model``; a CNN's ``checkpoint`` too) and its scores on
    the committed ev_crops holdout of each training folder that is ev_crops: ``held_out`` as
    ``(folder, metrics)`` pairs (:func:`~makeway.eval.classification.operating_point_metrics`)."""

    model: Path
    checkpoint: Path | None
    held_out: list[tuple[Path, dict[str, Any]]]


def train_ev_head(
    clf: EVCropClassifier,
    data: Sequence[str | Path],
    out: str | Path | None = None,
    *,
    match_quality: bool = False,
    log: Callable[[str], None] | None = None,
) -> CropTrainingRun:
    """Fit the head ``clf`` (its feature blocks, mirror and shrink settings as constructed) on the crop
    folders ``data`` and save it to ``out`` (default: the shipped head's path). On ev_crops only the
    training part is used (the committed holdout is left out) and the held-out part is scored
    afterwards. Near-duplicate crops stay in one fold of the inner cross-validation that picks the
    regularisation C. ``match_quality``: each folder's positive crops are first made as soft as its
    negatives (:func:`makeway.train.crop_quality.match_positive_quality`; each folder is one
    source). ``log`` receives a line per folder and one for the file written.

    Raises:
        InputError: a crop folder cannot be read (all are read before any work), or ``out`` cannot be
            written.
    """

    def say(line: str) -> None:
        if log is not None:
            log(line)

    target = Path(out) if out is not None else DEFAULT_MODEL
    sets = [(Path(folder), read_crop_folder(folder)) for folder in data]  # all read before any work
    xs: list[np.ndarray] = []
    xms: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    gs: list[np.ndarray] = []
    parts: list[str] = []
    held: list[tuple[Any, Path]] = []
    for folder, crops in sets:
        split = training_split(crops)
        if split is not None:
            train_idx, test_idx = split
            held.append((crops.subset(test_idx), folder))
            crops = crops.subset(train_idx)
            what = "training part (committed holdout excluded)"
        else:
            what = "all"
        say(f"{folder.name}: {what}, {len(crops)} crops ({crops.n_positive} positive)")
        parts.append(f"{folder.name}: {what}, {len(crops)} crops, {crops.n_positive} positive")
        images = crops.load_images(clf.input_size, cache=False)
        # near-duplicates stay in one inner-CV fold (as the holdout keeps them on one side)
        groups = np.char.add(f"{len(gs)}:", near_duplicate_groups(images).astype(str))
        if match_quality:
            from makeway.train.crop_quality import match_one_source

            images, note = match_one_source(images, crops.labels, seed=clf.seed)
            say(f"{folder.name}: {note}")
            parts[-1] += f", {note}"
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
    say(f"C = {clf.C:g}; head → {target} ({target.stat().st_size} bytes)")
    scores = []
    for test_set, folder in held:
        probs = clf.predict_proba(test_set.load_images(clf.input_size, cache=False))
        scores.append((folder, operating_point_metrics(probs, test_set.labels, clf.threshold)))
    return CropTrainingRun(model=target, checkpoint=None, held_out=scores)


# ------------------------------------------------------------------------------ feature cache


def _file_key(path: Path) -> str:
    """Identity of a crop file in the cache: absolute path, size and modification time (ns)."""
    st = path.stat()
    return f"{path.resolve()}|{st.st_size}|{st.st_mtime_ns}"


class FeatureCache:
    """Backbone features of crop files (and of their mirror images when the blocks are used with
    ``flip``), computed once per file.

    ``folder`` (``None``: in memory only) holds one ``features_<key>.npz`` per feature setting (the
    blocks and ``flip``); a file is known by its absolute path, size and modification time, so a
    changed crop is computed again. Crops are read at the blocks' largest input size, as
    :meth:`EVCropClassifier.predict_proba` would see them.
    """

    def __init__(
        self,
        blocks: Sequence[FeatureBlock | str] = DEFAULT_BLOCKS,
        *,
        flip: bool = True,
        folder: str | Path | None = None,
        num_threads: int | None = 1,
        batch: int = 64,
        progress: bool = True,
    ) -> None:
        self.extractor = EVCropClassifier(blocks=blocks, flip=flip, num_threads=num_threads)
        self.flip = bool(flip)
        self.batch = int(batch)
        self.progress = progress
        setting = "|".join([*(str(b) for b in self.extractor.blocks), f"flip={self.flip}"])
        self.setting = setting
        digest = hashlib.sha256(setting.encode()).hexdigest()[:12]
        self.path = None if folder is None else Path(folder) / f"features_{digest}.npz"
        self._rows: dict[str, tuple[np.ndarray, np.ndarray | None]] = {}
        if self.path is not None and self.path.is_file():
            self._load(self.path)

    def _load(self, path: Path) -> None:
        try:
            with np.load(path, allow_pickle=False) as npz:
                if str(npz["setting"]) != self.setting:
                    return
                keys, x = npz["keys"].tolist(), npz["x"]
                xm = npz["xm"] if self.flip else None
        except Exception:  # a damaged cache is recomputed, never trusted
            return
        for i, key in enumerate(keys):
            self._rows[str(key)] = (x[i], None if xm is None else xm[i])

    def _save(self) -> None:
        if self.path is None or not self._rows:
            return
        keys = list(self._rows)
        arrays: dict[str, Any] = {
            "setting": np.asarray(self.setting),
            "keys": np.asarray(keys, dtype=str),
            "x": np.stack([self._rows[k][0] for k in keys]),
        }
        if self.flip:
            arrays["xm"] = np.stack([self._rows[k][1] for k in keys])  # type: ignore[misc]
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_path(self.path) as tmp, tmp.open("wb") as fh:
            np.savez(fh, **arrays)

    @property
    def input_size(self) -> int:
        """Side at which crops are read."""
        return self.extractor.input_size

    def features(self, crops: CropSet) -> tuple[np.ndarray, np.ndarray | None]:
        """``(features (n, d), mirror-image features or None)`` of every crop, in order; the
        missing ones are computed (in batches, saved after each 512 crops and at the end).

        Raises:
            InputError: a crop cannot be read (names it).
        """
        keys = [_file_key(p) for p in crops.paths]
        todo = [i for i, k in enumerate(keys) if k not in self._rows]
        if todo:
            with progress_bar("backbone features", len(todo), enabled=self.progress, unit="crops") as adv:
                since_save = 0
                for start in range(0, len(todo), self.batch):
                    idx = todo[start : start + self.batch]
                    images = crops.subset(idx).load_images(self.input_size, cache=False)
                    x, xm = self.extractor.transform_pair(images)
                    for j, i in enumerate(idx):
                        self._rows[keys[i]] = (x[j], None if xm is None else xm[j])
                    adv(len(idx))
                    since_save += len(idx)
                    if since_save >= 512:
                        self._save()
                        since_save = 0
            self._save()
        x = np.stack([self._rows[k][0] for k in keys])
        xm = np.stack([self._rows[k][1] for k in keys]) if self.flip else None  # type: ignore[misc]
        return x, xm


class CachedHead:
    """A fitted :class:`EVCropClassifier` whose crop sets are scored from a :class:`FeatureCache`
    with the same blocks (:meth:`predict_crop_set`); ``predict_proba`` of images as the head's."""

    def __init__(self, clf: EVCropClassifier, cache: FeatureCache) -> None:
        if [str(b) for b in clf.blocks] != [str(b) for b in cache.extractor.blocks]:
            raise ValueError("the head's feature blocks differ from the cache's")
        if clf.flip and clf.mirror_at_test and not cache.flip:
            raise ValueError("the head judges mirror images too but the cache has no mirror-image features")
        self.clf = clf
        self.cache = cache
        self.threshold = clf.threshold

    @property
    def input_size(self) -> int:
        return self.clf.input_size

    def predict_proba(self, images: np.ndarray) -> np.ndarray:
        """P(EV) ``(n,)`` of ``uint8`` BGR crops (the head's own :meth:`~EVCropClassifier.predict_proba`)."""
        return self.clf.predict_proba(images)

    def predict_crop_set(self, crops: CropSet) -> np.ndarray:
        """P(EV) ``(n,)`` of every crop of ``crops``, from cached features."""
        x, xm = self.cache.features(crops)
        use_mirror = self.clf.flip and self.clf.mirror_at_test
        return self.clf.predict_proba_features(x, xm if use_mirror else None)


def cached_head(
    clf: EVCropClassifier, folder: str | Path | None, *, num_threads: int | None = 1, progress: bool = True
) -> CachedHead:
    """``clf`` scoring crop sets from a :class:`FeatureCache` of its blocks in ``folder``."""
    cache = FeatureCache(clf.blocks, flip=clf.flip, folder=folder, num_threads=num_threads, progress=progress)
    return CachedHead(clf, cache)


def head_trainer(
    blocks: Sequence[FeatureBlock | str] = DEFAULT_BLOCKS,
    *,
    flip: bool = True,
    threshold: float = 0.5,
    seed: int = 0,
    cache: FeatureCache | None = None,
    match_quality: bool = False,
) -> Callable[[CropSet], CachedHead]:
    """A trainer for :func:`makeway.eval.cross_source.leave_one_source_out`: fits a new
    :class:`EVCropClassifier` (``blocks``, ``flip``, ``threshold``, ``seed``; as the shipped
    ``default`` head with the defaults) on a crop set's features from ``cache`` (default: a new
    in-memory one), keeping each ``group`` in one fold of the inner cross-validation that picks C.
    ``match_quality``: each source's positive crops are first made as soft as its negatives
    (:func:`makeway.train.crop_quality.match_positive_quality`; the source is the group's prefix);
    the features of the crops it changes are computed afresh, not cached."""
    features = cache if cache is not None else FeatureCache(blocks, flip=flip, folder=None)
    wanted = [str(b) for b in EVCropClassifier(blocks=blocks).blocks]
    if [str(b) for b in features.extractor.blocks] != wanted or (flip and not features.flip):
        raise ValueError("the cache's feature blocks (or mirror setting) differ from the trainer's")

    def train(crops: CropSet) -> CachedHead:
        clf = EVCropClassifier(blocks=blocks, flip=flip, threshold=threshold, seed=seed)
        x, xm = features.features(crops)
        if match_quality:
            from makeway.train.crop_quality import match_positive_quality, source_of_groups

            images, shrunk = match_positive_quality(
                crops.load_images(features.input_size, cache=False),
                crops.labels,
                source_of_groups(crops.groups, len(crops)),
                seed=seed,
            )
            changed = np.flatnonzero(shrunk > 0)
            if len(changed):
                x, xm = x.copy(), None if xm is None else xm.copy()
                fx, fxm = features.extractor.transform_pair(images[changed])
                x[changed] = fx
                if xm is not None and fxm is not None:
                    xm[changed] = fxm
        clf.fit_features(
            x,
            crops.labels,
            x_mirrored=xm if flip else None,
            groups=crops.groups,
            training=f"{len(crops)} crops, {crops.n_positive} positive",
        )
        return CachedHead(clf, features)

    return train
