"""Training of the siren network (issue 4, SPEC §3) — torch lives here only.

**Data.** :func:`build_dataset` auto-labels folders of recordings (0.5 s windows every 0.17 s,
sources beyond 100 m dropped, :func:`~makeway.eval.siren_labels.label_recording`) and turns
every window into the features of :class:`~makeway.perceive.audio.siren_features.SirenFeatures`.
With ``mirror=True`` each window is added a second time mirrored left↔right: the reference array is
symmetric about the vehicle's x axis, so swapping the two units (and each unit's left and right
capsules) is the same recording with every source at −θ — twice the data for no simulation.
Targets: siren present (any source ≤ 100 m), and θ / distance of the nearest present source.

**Network** (:class:`SirenNet`). SPEC §3's two streams plus makeway's bearing map:

* ``wave`` — 1-D CNN on the band-passed 8-channel waveform (8 kHz);
* ``spec`` — 2-D CNN on log-mel + MFCC;
* ``gcc`` — circular 1-D CNN over the bearing axis of the per-pair GCC-PHAT map; its last layer
  gives one logit per bearing, and the direction head is the softmax-weighted mean of the unit
  vectors (cos a, sin a) — so the output is SPEC §3's (sin θ, cos θ), normalised before taking θ;
* ``level`` — per-capsule in-band level.

The streams' embeddings are concatenated into an MLP trunk with the siren (logit) and distance (m)
heads. Losses as SPEC §3: BCE for the siren, squared error on (sin θ, cos θ) and on the distance,
both masked to windows with a siren, weighted sum with weights (10, 10, 0.008) by default. With
``TrainConfig.distance_loss = "log"`` the distance head predicts ln distance (the output stays in
metres) and the loss is the squared error of ln distance (weights 10, 10, 10 from the CLI): the
level cue's error is relative, so near sirens count as much as far ones. With
``TrainConfig.distance_sigma`` (log loss only) a fifth head predicts ln σ, the spread of the ln
distance error it expects for the window, trained by the Gaussian negative log-likelihood of the
(detached) ln distance error on the detached trunk features: the other heads train exactly as
without it, and the ONNX graph gains the output ``distance_log_sigma``. Inputs
are standardised inside the network (buffers fitted on the training data), so the exported ONNX
graph takes the raw features.

**Training.** Adam, reduce-on-plateau on the validation loss, early stop at a floor learning rate.
The validation part is split by recording (never by window: neighbouring windows overlap).
:func:`export_onnx` writes the network with the feature configuration and metadata in the ONNX
``metadata_props``, read back by :class:`~makeway.perceive.audio.siren_model.SirenModel`.
"""

from __future__ import annotations

import json
import math
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from makeway.eval.siren import calibrate_threshold
from makeway.eval.siren_labels import label_recording
from makeway.perceive.audio.features import window_batch
from makeway.perceive.audio.siren_features import MIRROR_CHANNELS, SirenFeatureConfig, SirenFeatures
from makeway.perceive.audio.siren_model import SIGMA_OUTPUT
from makeway.sense.recording import REFERENCE_FULL_SCALE_DB_SPL, calibration_gain, read_recording

__all__ = [
    "SirenDataset",
    "SirenNet",
    "TrainConfig",
    "build_dataset",
    "calibrate_threshold",
    "export_onnx",
    "train_siren_net",
    "train_siren_networks",
]

INPUT_NAMES = ("wave", "spec", "gcc", "level")
DISTANCE_LOSSES = ("squared", "log")
OUTPUT_NAMES = ("siren_logit", "direction", "distance", "bearing_logits")
LOG_SIGMA_RANGE = (-5.0, 3.0)


# ------------------------------------------------------------------------------------------- data


@dataclass
class SirenDataset:
    """Features and targets of labelled windows (``n`` windows)."""

    features: dict[str, np.ndarray]
    siren: np.ndarray  # (n,) float32 0/1
    theta: np.ndarray  # (n,) rad, NaN without a siren
    distance: np.ndarray  # (n,) m, NaN without a siren
    recording: np.ndarray  # (n,) int index into ``names``
    names: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.siren)

    def subset(self, idx: np.ndarray) -> SirenDataset:
        return SirenDataset(
            {k: v[idx] for k, v in self.features.items()},
            self.siren[idx],
            self.theta[idx],
            self.distance[idx],
            self.recording[idx],
            self.names,
        )

    @staticmethod
    def concat(parts: Sequence[SirenDataset]) -> SirenDataset:
        names: list[str] = []
        recs = []
        for p in parts:
            recs.append(p.recording + len(names))
            names.extend(p.names)
        return SirenDataset(
            {k: np.concatenate([p.features[k] for p in parts]) for k in parts[0].features},
            np.concatenate([p.siren for p in parts]),
            np.concatenate([p.theta for p in parts]),
            np.concatenate([p.distance for p in parts]),
            np.concatenate(recs),
            names,
        )

    def save(self, path: Path, key: str = "") -> Path:
        """Write as ``.npz`` (atomically; the waveform stream as float16); ``key`` identifies what
        the features were made from (see :func:`build_dataset`)."""
        from makeway.atomic import atomic_path

        arrays: dict[str, Any] = {
            f"f_{k}": (v.astype(np.float16) if k == "wave" else v) for k, v in self.features.items()
        }
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.savez(
                fh,
                key=np.array(key),
                siren=self.siren,
                theta=self.theta,
                distance=self.distance,
                recording=self.recording,
                names=np.array(self.names),
                **arrays,
            )
        return path

    @staticmethod
    def load(path: Path) -> SirenDataset:
        with np.load(path) as z:
            feats = {k[2:]: z[k].astype(np.float32) for k in z.files if k.startswith("f_")}
            return SirenDataset(
                feats, z["siren"], z["theta"], z["distance"], z["recording"], [str(s) for s in z["names"]]
            )


def _recording_dataset(folder: Path, feats: SirenFeatures, mirror: bool) -> SirenDataset:
    rec = read_recording(folder)
    labels = label_recording(rec, window_s=feats.config.window_s)
    kept = labels.kept  # windows whose sirens are all beyond 100 m are dropped (SPEC §3)
    # every network is trained at the reference calibration (makeway.sense.recording, Calibration)
    windows = window_batch(rec, labels)[kept] * calibration_gain(rec.full_scale_db_spl)
    theta, dist = labels.nearest()
    theta, dist = theta[kept], dist[kept]
    siren = labels.siren[kept].astype(np.float32)
    chunks = [feats.transform(windows[i : i + 32]) for i in range(0, len(windows), 32)]
    f = {k: np.concatenate([c[k] for c in chunks]) for k in chunks[0]} if chunks else {}
    parts = [SirenDataset(f, siren, theta, dist, np.zeros(len(siren), np.int64), [folder.name])]
    if mirror:
        mw = windows[:, list(MIRROR_CHANNELS)]
        mchunks = [feats.transform(mw[i : i + 32]) for i in range(0, len(mw), 32)]
        mf = {k: np.concatenate([c[k] for c in mchunks]) for k in mchunks[0]} if mchunks else {}
        parts.append(SirenDataset(mf, siren, -theta, dist, np.zeros(len(siren), np.int64), [folder.name]))
        merged = SirenDataset.concat(parts)
        merged.recording[:] = 0
        merged.names = [folder.name]
        return merged
    return parts[0]


def build_dataset(
    folders: Sequence[Path],
    feats: SirenFeatures,
    *,
    mirror: bool = False,
    cache: Path | None = None,
    workers: int = 1,
    advance: Callable[[int], Any] | None = None,
) -> SirenDataset:
    """Features and targets of every labelled window of ``folders`` (module docstring).

    With ``cache`` (a ``.npz`` path), a cache made from the same folders and feature configuration
    is reused, and a new one written otherwise. ``workers`` > 1 spreads the recordings over that
    many processes (the order of the result does not depend on it).
    """
    key = json.dumps({"folders": [str(f) for f in folders], "features": feats.config.to_dict(), "m": mirror})
    if cache is not None and cache.is_file():
        with np.load(cache) as z:
            same = "key" in z.files and str(z["key"]) == key
        if same:
            if advance is not None:
                advance(len(folders))
            return SirenDataset.load(cache)
    from concurrent.futures import ProcessPoolExecutor
    from contextlib import nullcontext

    parts: list[SirenDataset] = []
    pool = ProcessPoolExecutor(max_workers=workers) if workers > 1 and len(folders) > 1 else nullcontext()
    with pool as ex:
        jobs = (
            ex.map(
                _recording_dataset,
                [Path(f) for f in folders],
                [feats] * len(folders),
                [mirror] * len(folders),
            )
            if ex is not None
            else (_recording_dataset(Path(f), feats, mirror) for f in folders)
        )
        for part in jobs:  # in folder order either way
            parts.append(part)
            if advance is not None:
                advance(1)
    data = SirenDataset.concat(parts)
    if cache is not None:
        data.save(cache, key)
    return data


# ---------------------------------------------------------------------------------------- network


class _Standardize(nn.Module):
    """``(x − mean) / std`` with fixed buffers broadcast over the batch axis."""

    mean: torch.Tensor
    std: torch.Tensor

    def __init__(self, shape: tuple[int, ...]) -> None:
        super().__init__()
        self.register_buffer("mean", torch.zeros(shape))
        self.register_buffer("std", torch.ones(shape))

    def fit(self, x: np.ndarray, reduce_axes: tuple[int, ...]) -> None:
        m = x.mean(axis=reduce_axes, keepdims=True)[0]
        s = x.std(axis=reduce_axes, keepdims=True)[0]
        shape = tuple(self.mean.shape)
        self.mean.copy_(torch.from_numpy(np.broadcast_to(m, shape).astype(np.float32)))
        self.std.copy_(torch.from_numpy(np.broadcast_to(np.maximum(s, 1e-3), shape).astype(np.float32)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.mean) / self.std


def _conv1d(cin: int, cout: int, k: int, stride: int = 1, circular: bool = False) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv1d(
            cin,
            cout,
            k,
            stride=stride,
            padding=k // 2,
            padding_mode="circular" if circular else "zeros",
            bias=False,
        ),
        nn.BatchNorm1d(cout),
        nn.ReLU(inplace=True),
    )


def _conv2d(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True)
    )


class SirenNet(nn.Module):
    """The siren network (module docstring). ``shapes``: per-window input shapes by stream name."""

    unit: torch.Tensor

    def __init__(
        self,
        shapes: dict[str, tuple[int, ...]],
        streams: Sequence[str] = INPUT_NAMES,
        width: int = 32,
        n_azimuth: int = 120,
        log_distance: bool = False,
        distance_sigma: bool = False,
    ) -> None:
        super().__init__()
        self.log_distance = bool(log_distance)
        self.distance_sigma = bool(distance_sigma)
        if self.distance_sigma and not self.log_distance:
            raise ValueError("the distance uncertainty head needs the log distance loss")
        unknown = set(streams) - set(INPUT_NAMES)
        if unknown:
            raise ValueError(f"unknown streams {sorted(unknown)}; choose from {', '.join(INPUT_NAMES)}")
        self.streams = tuple(s for s in INPUT_NAMES if s in streams)
        self.shapes = {k: tuple(v) for k, v in shapes.items()}
        w = int(width)
        emb = 0
        self.norm = nn.ModuleDict({s: _Standardize(self.shapes[s]) for s in self.streams})
        if "wave" in self.streams:
            c = self.shapes["wave"][0]
            self.wave = nn.Sequential(
                _conv1d(c, w, 9, stride=4),
                _conv1d(w, 2 * w, 5, stride=2),
                nn.MaxPool1d(2),
                _conv1d(2 * w, 2 * w, 3),
                nn.MaxPool1d(2),
                _conv1d(2 * w, 2 * w, 3),
                nn.AdaptiveAvgPool1d(1),
                nn.Flatten(),
            )
            emb += 2 * w
        if "spec" in self.streams:
            c = self.shapes["spec"][0]
            self.spec = nn.Sequential(
                _conv2d(c, w // 2),
                nn.MaxPool2d(2),
                _conv2d(w // 2, w),
                nn.MaxPool2d(2),
                _conv2d(w, 2 * w),
                nn.MaxPool2d(2),
                _conv2d(2 * w, 2 * w),
                nn.AdaptiveAvgPool2d(1),
                nn.Flatten(),
            )
            emb += 2 * w
        if "gcc" in self.streams:
            c = self.shapes["gcc"][0]
            self.gcc = nn.Sequential(
                _conv1d(c, 2 * w, 5, circular=True),
                _conv1d(2 * w, 2 * w, 5, circular=True),
                _conv1d(2 * w, w, 5, circular=True),
            )
            self.bearing = nn.Conv1d(w, 1, 5, padding=2, padding_mode="circular")
            az = torch.arange(n_azimuth, dtype=torch.float32) * (2.0 * math.pi / n_azimuth)
            self.register_buffer("unit", torch.stack([torch.sin(az), torch.cos(az)], dim=0))  # (2, A)
            emb += 2 * w
        if "level" in self.streams:
            emb += self.shapes["level"][0]
        self.trunk = nn.Sequential(nn.Linear(emb, 4 * w), nn.ReLU(inplace=True), nn.Dropout(0.2))
        self.siren_head = nn.Linear(4 * w, 1)
        self.distance_head = nn.Linear(4 * w, 1)
        if "gcc" not in self.streams:
            self.direction_head = nn.Linear(4 * w, 2)
        if self.distance_sigma:  # made last: the other layers' initial weights stay as without it
            self.sigma_head = nn.Linear(4 * w, 1)

    def fit_normalization(self, features: dict[str, np.ndarray]) -> None:
        """Standardisation buffers from training features (per channel/row, over the rest)."""
        axes = {"wave": (0, 2), "spec": (0, 3), "gcc": (0, 1, 2), "level": (0,)}
        with torch.no_grad():
            for s in self.streams:
                norm = self.norm[s]
                assert isinstance(norm, _Standardize)
                norm.fit(features[s], axes[s])

    def forward(self, *inputs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """``(siren_logit, direction, distance, bearing_logits)``, plus ``distance_log_sigma``
        with ``distance_sigma`` (module docstring)."""
        x = dict(zip(self.streams, inputs, strict=True))
        parts = []
        bearing_logits = None
        if "wave" in x:
            parts.append(self.wave(self.norm["wave"](x["wave"])))
        if "spec" in x:
            parts.append(self.spec(self.norm["spec"](x["spec"])))
        if "gcc" in x:
            g = self.gcc(self.norm["gcc"](x["gcc"]))  # (n, w, A)
            parts.append(torch.cat([g.mean(dim=2), g.amax(dim=2)], dim=1))
            bearing_logits = self.bearing(g)[:, 0]  # (n, A)
        if "level" in x:
            parts.append(self.norm["level"](x["level"]))
        h = self.trunk(torch.cat(parts, dim=1))
        siren_logit = self.siren_head(h)[:, 0]
        if self.log_distance:  # the head predicts ln(distance); the output stays in metres
            distance = torch.exp(torch.clamp(self.distance_head(h)[:, 0] + math.log(30.0), max=8.0))
        else:
            distance = 50.0 * self.distance_head(h)[:, 0] + 40.0
        if bearing_logits is not None:
            weights = torch.softmax(bearing_logits, dim=1)
            direction = weights @ self.unit.T  # (n, 2) = (sin θ, cos θ), not normalised
        else:
            direction = self.direction_head(h)
            bearing_logits = torch.zeros((h.shape[0], 1), dtype=h.dtype)
        if self.distance_sigma:
            # on the detached trunk: the uncertainty never pulls on the features of the estimate
            log_sigma = torch.clamp(self.sigma_head(h.detach())[:, 0], *LOG_SIGMA_RANGE)
            return siren_logit, direction, distance, bearing_logits, log_sigma
        return siren_logit, direction, distance, bearing_logits


# --------------------------------------------------------------------------------------- training


@dataclass
class TrainConfig:
    """Training settings (SPEC §3 loss weights; Adam + reduce-on-plateau + floor stop)."""

    streams: tuple[str, ...] = INPUT_NAMES
    width: int = 32
    epochs: int = 30
    batch_size: int = 64
    lr: float = 1e-3
    weight_decay: float = 0.0
    loss_weights: tuple[float, float, float] = (10.0, 10.0, 0.008)
    distance_loss: str = "squared"
    """``"squared"`` (SPEC §3: squared error in m²) or ``"log"`` (squared error of ln distance)."""
    plateau_patience: int = 2
    plateau_factor: float = 0.3
    min_lr: float = 2e-5
    val_fraction: float = 0.15
    seed: int = 0
    threads: int = 2
    distance_sigma: bool = False
    """Add the distance uncertainty head (module docstring; needs ``distance_loss="log"``)."""
    gain_augment_db: float = 0.0
    """Each training window is shifted by a gain drawn uniformly from ±this many dB
    (:meth:`~makeway.perceive.audio.siren_features.SirenFeatures.shift_gain`), as if recorded by
    an array of another sensitivity: the network cannot lean on the absolute level. 0: off."""


def _targets(data: SirenDataset) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    siren = torch.from_numpy(data.siren.astype(np.float32))
    th = np.nan_to_num(data.theta.astype(np.float64))
    direction = torch.from_numpy(np.stack([np.sin(th), np.cos(th)], axis=1).astype(np.float32))
    dist = torch.from_numpy(np.nan_to_num(data.distance.astype(np.float32)))
    mask = siren > 0.5
    return siren, direction, dist, mask


def _loss(
    out: tuple[torch.Tensor, ...],
    tgt: tuple[torch.Tensor, ...],
    weights: tuple[float, float, float],
    distance_loss: str = "squared",
) -> tuple[torch.Tensor, list[float], torch.Tensor | None]:
    """The weighted loss of the siren, direction and distance heads, its three parts, and (with an
    uncertainty output) the Gaussian negative log-likelihood of the detached ln distance error
    under the predicted σ, to be added for the backward pass only."""
    siren_logit, direction, distance = out[:3]
    siren, direction_t, dist_t, mask = tgt
    bce = nn.functional.binary_cross_entropy_with_logits(siren_logit, siren)
    m = mask.float()
    n = torch.clamp(m.sum(), min=1.0)
    dir_l = (((direction - direction_t) ** 2).sum(dim=1) * m).sum() / n
    if distance_loss == "log":
        err = torch.log(torch.clamp(distance, min=0.5)) - torch.log(torch.clamp(dist_t, min=0.5))
    else:
        err = distance - dist_t
    dist_l = ((err**2) * m).sum() / n
    total = weights[0] * bce + weights[1] * dir_l + weights[2] * dist_l
    nll = None
    if len(out) > 4:
        log_sigma = out[4]
        e2 = err.detach() ** 2
        nll = ((0.5 * e2 * torch.exp(-2.0 * log_sigma) + log_sigma) * m).sum() / n
    return total, [float(bce.detach()), float(dir_l.detach()), float(dist_l.detach())], nll


def split_by_recording(data: SirenDataset, fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``(train_idx, val_idx)``: a seeded share ``fraction`` of the recordings is validation."""
    recs = np.unique(data.recording)
    rng = np.random.default_rng(seed)
    val_recs = rng.choice(recs, size=max(1, round(fraction * len(recs))), replace=False)
    is_val = np.isin(data.recording, val_recs)
    return np.flatnonzero(~is_val), np.flatnonzero(is_val)


def _batches(
    data: SirenDataset,
    idx: np.ndarray,
    streams: Sequence[str],
    shift: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]] | None = None,
) -> list[torch.Tensor]:
    feats = {s: data.features[s][idx] for s in streams}
    if shift is not None:
        feats = shift(feats)
    return [torch.from_numpy(np.ascontiguousarray(feats[s], dtype=np.float32)) for s in streams]


def evaluate_net(net: SirenNet, data: SirenDataset, batch_size: int = 256) -> dict[str, np.ndarray]:
    """Probabilities, bearings and distances of ``net`` on ``data`` (eval mode, no grad)."""
    net.eval()
    probs, thetas, dists = [], [], []
    with torch.no_grad():
        for i in range(0, len(data), batch_size):
            idx = np.arange(i, min(i + batch_size, len(data)))
            logit, direction, distance = net(*_batches(data, idx, net.streams))[:3]
            probs.append(torch.sigmoid(logit).numpy())
            thetas.append(torch.atan2(direction[:, 0], direction[:, 1]).numpy())
            dists.append(distance.numpy())
    return {"prob": np.concatenate(probs), "theta": np.concatenate(thetas), "distance": np.concatenate(dists)}


def train_siren_net(
    data: SirenDataset,
    shapes: dict[str, tuple[int, ...]],
    config: TrainConfig | None = None,
    *,
    n_azimuth: int = 120,
    on_epoch: Callable[[int, dict[str, float]], Any] | None = None,
    on_best: Callable[[SirenNet, dict[str, float]], Any] | None = None,
    features: SirenFeatures | None = None,
) -> tuple[SirenNet, list[dict[str, float]]]:
    """Train a :class:`SirenNet` on ``data`` (module docstring); returns the best-validation
    network (by validation loss) and the per-epoch history. ``on_best(net, row)`` is called (in eval
    mode) whenever the validation loss improves, e.g. to save a checkpoint of a long run.
    ``features`` (the extractor that made ``data``) is needed for ``config.gain_augment_db``; the
    validation windows are never shifted."""
    cfg = config if config is not None else TrainConfig()
    shift: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]] | None = None
    if cfg.gain_augment_db > 0:
        if features is None:
            raise ValueError("gain augmentation needs the feature extractor (features=)")
        extractor, span = features, float(cfg.gain_augment_db)

        def shift(feats: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
            n = len(next(iter(feats.values())))
            return extractor.shift_gain(feats, rng.uniform(-span, span, n).astype(np.float32))

    torch.manual_seed(cfg.seed)
    torch.set_num_threads(max(1, int(cfg.threads)))
    rng = np.random.default_rng(cfg.seed)
    if cfg.distance_loss not in DISTANCE_LOSSES:
        raise ValueError(
            f"distance_loss must be one of {', '.join(DISTANCE_LOSSES)}, not {cfg.distance_loss!r}"
        )
    train_idx, val_idx = split_by_recording(data, cfg.val_fraction, cfg.seed)
    net = SirenNet(
        shapes,
        cfg.streams,
        cfg.width,
        n_azimuth,
        log_distance=cfg.distance_loss == "log",
        distance_sigma=cfg.distance_sigma,
    )
    # standardisation statistics from at most 4000 training windows (a full copy of the waveform
    # stream would double the memory of a large training set)
    norm_idx = np.sort(rng.choice(train_idx, size=min(len(train_idx), 4000), replace=False))
    net.fit_normalization({s: data.features[s][norm_idx] for s in net.streams})
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.ReduceLROnPlateau(
        opt, mode="min", factor=cfg.plateau_factor, patience=cfg.plateau_patience
    )
    tgt_all = _targets(data)
    best: tuple[float, dict[str, Any]] | None = None
    history: list[dict[str, float]] = []
    for epoch in range(cfg.epochs):
        t0 = time.perf_counter()
        net.train()
        order = rng.permutation(train_idx)
        sums = np.zeros(4)
        nb = 0
        nll_sum = 0.0
        for i in range(0, len(order), cfg.batch_size):
            idx = order[i : i + cfg.batch_size]
            if len(idx) < 2:
                continue
            out = net(*_batches(data, idx, net.streams, shift))
            loss, parts, nll = _loss(out, tuple(t[idx] for t in tgt_all), cfg.loss_weights, cfg.distance_loss)
            opt.zero_grad()
            (loss if nll is None else loss + nll).backward()
            opt.step()
            sums += [float(loss.detach()), *parts]
            nb += 1
        net.eval()
        with torch.no_grad():
            vsum = np.zeros(4)
            vn = 0
            for i in range(0, len(val_idx), 256):
                idx = val_idx[i : i + 256]
                out = net(*_batches(data, idx, net.streams))
                loss, parts, nll = _loss(
                    out, tuple(t[idx] for t in tgt_all), cfg.loss_weights, cfg.distance_loss
                )
                vsum += np.array([float(loss), *parts]) * len(idx)
                vn += len(idx)
                if nll is not None:
                    nll_sum += float(nll) * len(idx)
            vsum /= max(vn, 1)
        row = {
            "epoch": epoch + 1,
            "lr": opt.param_groups[0]["lr"],
            "train_loss": sums[0] / max(nb, 1),
            "val_loss": vsum[0],
            "val_bce": vsum[1],
            "val_direction": vsum[2],
            "val_distance_mse": vsum[3],
            "seconds": time.perf_counter() - t0,
        }
        if net.distance_sigma:  # reported, not part of the checkpoint choice
            row["val_sigma_nll"] = nll_sum / max(vn, 1)
        history.append(row)
        if on_epoch is not None:
            on_epoch(epoch, row)
        if best is None or vsum[0] < best[0]:
            best = (float(vsum[0]), {k: v.detach().clone() for k, v in net.state_dict().items()})
            if on_best is not None:
                on_best(net, row)
        sched.step(vsum[0])
        if opt.param_groups[0]["lr"] < cfg.min_lr:
            break
    if best is not None:
        net.load_state_dict(best[1])
    net.eval()
    return net, history


def export_onnx(
    net: SirenNet,
    path: Path,
    feature_config: SirenFeatureConfig,
    *,
    threshold: float = 0.5,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Write ``net`` as ONNX (dynamic batch axis) with the feature configuration, the stream order,
    the decision threshold and ``extra`` (training description, metrics) in ``metadata_props``."""
    import onnx

    from makeway.atomic import atomic_path

    net.eval()
    dummy = tuple(torch.zeros((2, *net.shapes[s])) for s in net.streams)
    outputs = (*OUTPUT_NAMES, SIGMA_OUTPUT) if net.distance_sigma else OUTPUT_NAMES
    meta = {
        "makeway_model": "siren_net",
        "format_version": "1",
        "streams": json.dumps(list(net.streams)),
        "features": json.dumps(feature_config.to_dict()),
        "threshold": repr(float(threshold)),
        "full_scale_db_spl": repr(REFERENCE_FULL_SCALE_DB_SPL),
    }
    for k, v in (extra or {}).items():
        meta[k] = v if isinstance(v, str) else json.dumps(v)
    with atomic_path(path) as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # the TorchScript exporter is "legacy"
        torch.onnx.export(
            net,
            dummy,
            str(tmp),
            dynamo=False,
            input_names=list(net.streams),
            output_names=list(outputs),
            dynamic_axes={n: {0: "batch"} for n in (*net.streams, *outputs)},
            opset_version=17,
        )
        model = onnx.load(str(tmp))
        for k, v in meta.items():
            entry = model.metadata_props.add()
            entry.key, entry.value = k, v
        onnx.save(model, str(tmp))
    return path


def config_dict(cfg: TrainConfig) -> dict[str, Any]:
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(cfg).items()}


def train_siren_networks(
    data: Sequence[str | Path],
    out: str | Path | None = None,
    *,
    test: str | Path | None = None,
    streams: Sequence[str] = INPUT_NAMES,
    distance_loss: str = "squared",
    loss_weights: Sequence[float] | None = None,
    width: int = 24,
    epochs: int = 30,
    lr: float = 1e-3,
    batch_size: int = 64,
    patience: int = 2,
    max_false_alarm: float | None = None,
    mirror: bool = True,
    cache: str | Path | None = None,
    threads: int = 2,
    seed: int = 0,
    gain_augment_db: float = 0.0,
    distance_sigma: bool = False,
    command: str = "makeway audio train",
    log: Callable[[str], None] | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Train the siren network (detection, bearing and distance heads; module docstring) on the
    recordings under each folder of ``data`` and export it to ``out`` as ONNX (default: the shipped
    model's path). A checkpoint of the best network so far is written after every better epoch, so a
    run cut short still leaves a model.

    ``streams`` is a subset of :data:`~makeway.perceive.audio.siren_features.STREAMS`;
    ``distance_loss`` ``"squared"`` (m²) or ``"log"`` (ln distance); ``distance_sigma`` adds the
    distance uncertainty output (log loss only; module docstring); ``loss_weights`` weigh the siren,
    direction and distance losses (default ``(10, 10, 0.008)`` with the squared loss, ``(10, 10, 10)``
    with the log loss). ``lr`` is Adam's learning rate, ``patience`` the epochs without improvement
    before it drops; ``gain_augment_db`` shifts each training window by up to ± that many dB. With
    ``max_false_alarm`` the stored decision threshold is raised from 0.5 until the validation
    false-alarm rate per window is at most that fraction. ``cache`` is a feature cache (``.npz``);
    ``threads`` torch threads and feature-extraction processes; ``command`` is stored with the model.
    ``log`` receives one line per step worth reporting (data set size, every epoch, the threshold,
    the file written).

    Returns ``model`` (the file written), the training description stored in the model (data,
    configuration, ``history`` per epoch, ``train_seconds``, ``best_val_loss``) and, with ``test``,
    ``test``: :func:`makeway.eval.siren.evaluate` of the new model on the recordings under ``test``.

    Raises:
        ValueError: an unknown stream, distance loss, or bad loss weights (before any work).
        InputError: a recording folder cannot be read.
    """
    from makeway.perceive.audio.siren_features import STREAMS
    from makeway.perceive.audio.siren_model import DEFAULT_SIREN_MODEL
    from makeway.progress import progress_bar
    from makeway.sense.recording import recording_folders

    def say(line: str) -> None:
        if log is not None:
            log(line)

    if distance_sigma and distance_loss != "log":
        raise ValueError("--distance-sigma needs --distance-loss log (the spread is that of ln distance)")
    folders = [f for d in data for f in recording_folders(d)]
    test_folders = recording_folders(test) if test is not None else []
    target = Path(out) if out is not None else DEFAULT_SIREN_MODEL
    names = tuple(streams)
    unknown = sorted(set(names) - set(STREAMS))
    if unknown or not names:
        raise ValueError(
            f"unknown streams {unknown}; --streams takes a comma-separated subset of {', '.join(STREAMS)}"
        )
    if distance_loss not in DISTANCE_LOSSES:
        raise ValueError(f"--distance-loss must be {' or '.join(DISTANCE_LOSSES)}, not {distance_loss!r}")
    weights = (
        [10.0, 10.0, 0.008 if distance_loss == "squared" else 10.0]
        if loss_weights is None
        else [float(w) for w in loss_weights]
    )
    if len(weights) != 3 or min(weights) < 0:
        raise ValueError(f"--loss-weights takes three non-negative numbers like 10,10,0.008, not {weights!r}")
    cfg = TrainConfig(
        streams=names,
        distance_loss=distance_loss,
        loss_weights=(weights[0], weights[1], weights[2]),
        width=width,
        epochs=epochs,
        lr=lr,
        batch_size=batch_size,
        plateau_patience=patience,
        seed=seed,
        threads=threads,
        gain_augment_db=gain_augment_db,
        distance_sigma=distance_sigma,
    )
    feats = SirenFeatures()
    with progress_bar("features", len(folders), enabled=progress, unit="rec") as advance:
        dataset = build_dataset(
            folders,
            feats,
            mirror=mirror,
            cache=None if cache is None else Path(cache),
            workers=threads,
            advance=advance,
        )
    n_pos = int(dataset.siren.sum())
    say(
        f"{len(folders)} recordings → {len(dataset)} windows ({n_pos} with a siren ≤ 100 m)"
        + (" incl. mirrored copies" if mirror else "")
    )
    training: dict[str, Any] = {
        "command": command,
        "recordings": [str(d) for d in data],
        "n_recordings": len(folders),
        "windows": len(dataset),
        "positives": n_pos,
        "mirror": mirror,
        "config": config_dict(cfg),
    }
    t0 = time.perf_counter()
    with progress_bar("training", cfg.epochs, enabled=progress, unit="epoch") as advance:

        def on_epoch(epoch: int, row: dict[str, float]) -> None:
            distance = (
                f"distance rmse {row['val_distance_mse'] ** 0.5:.1f} m) "
                if distance_loss == "squared"
                else f"distance rms ln-error {row['val_distance_mse'] ** 0.5:.2f}) "
            )
            say(
                f"epoch {epoch + 1}: lr {row['lr']:.2g} train {row['train_loss']:.3f} "
                f"val {row['val_loss']:.3f} "
                f"(bce {row['val_bce']:.3f}, direction {row['val_direction']:.3f}, "
                + distance
                + (f"σ nll {row['val_sigma_nll']:.3f}, " if "val_sigma_nll" in row else "")
                + f"{row['seconds']:.0f} s"
            )
            advance(1)

        def on_best(best_net: Any, row: dict[str, float]) -> None:
            export_onnx(
                best_net,
                target,
                feats.config,
                extra={"training": {**training, "checkpoint_epoch": row["epoch"]}},
            )

        net, history = train_siren_net(
            dataset,
            feats.shapes(),
            cfg,
            n_azimuth=feats.config.n_azimuth,
            on_epoch=on_epoch,
            on_best=on_best,
            features=feats,
        )
    wall = time.perf_counter() - t0
    training.update(
        epochs_run=len(history),
        best_val_loss=round(min(h["val_loss"] for h in history), 5),
        history=[{k: round(float(v), 5) for k, v in h.items()} for h in history],
        train_seconds=round(wall, 1),
    )
    threshold = 0.5
    if max_false_alarm is not None:
        _, val_idx = split_by_recording(dataset, cfg.val_fraction, cfg.seed)  # the split training used
        val = dataset.subset(val_idx)
        threshold = calibrate_threshold(evaluate_net(net, val)["prob"], val.siren > 0.5, max_false_alarm)
        training["threshold_calibration"] = {
            "max_false_alarm": max_false_alarm,
            "validation_windows": len(val),
            "threshold": round(threshold, 6),
        }
        say(f"decision threshold {threshold:.4f} (validation false alarms ≤ {max_false_alarm:g})")
    export_onnx(net, target, feats.config, threshold=threshold, extra={"training": training})
    say(f"model → {target} ({target.stat().st_size / 1e6:.2f} MB)")
    summary: dict[str, Any] = {"model": str(target), **training}
    if test_folders:
        from makeway.eval.siren import evaluate, model_estimator
        from makeway.perceive.audio.siren_model import SirenModel

        with progress_bar("test", len(test_folders), enabled=progress, unit="rec") as advance:
            trained = SirenModel(target)
            summary["test"] = evaluate(
                test_folders,
                model_estimator(trained),
                on_recording=advance,
                name="model",
                threshold=trained.threshold,
            )
    return summary
