"""Training of the far ranger (:mod:`makeway.perceive.audio.far_range`, issue 25) — torch lives here
only.

**Data** (:func:`far_dataset`). Every recording is run the way the listener runs it: the siren
networks (by default the shipped stack: detector, localizer and default rangers) on every 0.5 s
window (hop 0.17 s), and a :class:`~makeway.perceive.audio.far_range.FarTracker` fed each window in
order, which gives one feature row per window. Labels come from the trajectories out to
:data:`LABEL_MAX_DISTANCE_M` (400 m; :func:`~makeway.eval.siren_labels.label_recording`): the
nearest siren's distance; windows with no siren that near are not used.

**Network** (:class:`FarNet`). Inputs standardised inside the network (buffers fitted on the
training rows), two hidden layers of ``width`` (ReLU, dropout 0.5), three outputs: ln distance,
ln σ (clamped to [−4, 1.5]) and the far logit. Loss: the Gaussian negative log-likelihood of the
true ln distance under (ln distance, σ) — which fits the distance and a calibrated spread together
— plus ``far_weight`` × the binary cross-entropy of ``distance > far_boundary_m``.

**Training.** Adam with weight decay 0.01, reduce-on-plateau on the validation loss of a seeded 15 % of
the training recordings (split by recording), best epoch kept. :func:`export_far_onnx` writes the
ONNX file with the feature names, the far boundary, the networks that fed the rows and the training
description in its metadata.
"""

from __future__ import annotations

import json
import math
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from makeway.eval.siren_labels import label_recording
from makeway.perceive.audio.far_range import FAR_BOUNDARY_M, FarTracker, far_metadata
from makeway.perceive.audio.features import band_level_db, window_batch
from makeway.perceive.audio.siren_model import SirenModel
from makeway.sense.recording import REFERENCE_FULL_SCALE_DB_SPL, Recording, read_recording, recording_folders

__all__ = [
    "LABEL_MAX_DISTANCE_M",
    "FarNet",
    "export_far_onnx",
    "far_dataset",
    "far_rows",
    "train_far_net",
    "train_far_ranger",
]

LABEL_MAX_DISTANCE_M = 400.0
"""Windows whose nearest siren lies within this distance are labelled (module docstring)."""
LOG_SIGMA_RANGE = (-4.0, 1.5)
OUTPUT_NAMES = ("log_distance", "log_sigma", "far_logit")


def far_rows(rec: Recording, model: SirenModel, tracker: FarTracker | None = None) -> dict[str, np.ndarray]:
    """Per-window arrays of one recording, made as the listener makes them (module docstring):
    ``rows`` (the far tracker's feature rows), the networks' ``prob``, ``theta``, ``distance`` and
    ``sigma`` (NaN without one), the labelled nearest ``true_distance`` (m, NaN without a siren
    within :data:`LABEL_MAX_DISTANCE_M`), ``true_theta`` and ``source`` (the nearest siren's index,
    −1 without one), ``level_db_spl``, ``t_end``."""
    tracker = tracker if tracker is not None else FarTracker()
    tracker.reset()
    labels = label_recording(rec, max_distance_m=LABEL_MAX_DISTANCE_M)
    windows = window_batch(rec, labels)
    fs = rec.full_scale_db_spl if rec.full_scale_db_spl is not None else REFERENCE_FULL_SCALE_DB_SPL
    preds = [model.predict(windows[i : i + 64], fs) for i in range(0, len(windows), 64)]
    prob = np.concatenate([p.prob for p in preds]) if preds else np.zeros(0)
    theta = np.concatenate([p.theta for p in preds]) if preds else np.zeros(0)
    dist = np.concatenate([p.distance for p in preds]) if preds else np.zeros(0)
    sigma = (
        np.concatenate([p.distance_sigma for p in preds])
        if preds and all(p.distance_sigma is not None for p in preds)
        else np.full(len(windows), np.nan)
    )
    sr = int(rec.sample_rate)
    level = np.array([band_level_db(w, sr) + fs for w in windows])
    rows = [
        tracker.observe(
            windows[i],
            sr,
            float(labels.t_end[i]),
            level_db_spl=float(level[i]),
            distance_m=float(dist[i]),
            bearing_rad=float(theta[i]),
            siren_probability=float(prob[i]),
            sigma=None if math.isnan(sigma[i]) else float(sigma[i]),
        )
        for i in range(len(windows))
    ]
    true_theta, true_d = labels.nearest()
    source = labels.nearest_source()
    n_feat = len(tracker.feature_names)
    return {
        "rows": np.array(rows, dtype=np.float32).reshape(-1, n_feat),
        "prob": prob,
        "theta": theta,
        "distance": dist,
        "sigma": sigma,
        "true_distance": true_d,
        "true_theta": true_theta,
        "source": source,
        "level_db_spl": level,
        "t_end": np.asarray(labels.t_end, dtype=np.float64),
    }


def far_dataset(
    folders: Sequence[str | Path],
    model: SirenModel,
    *,
    cache: Path | None = None,
    workers: int = 1,
    advance: Callable[[int], Any] | None = None,
) -> dict[str, np.ndarray]:
    """:func:`far_rows` of every recording under ``folders`` (each a recording folder or a folder of
    them), pooled, with ``recording`` (index) and ``names``. With ``cache`` (``.npz``) a cache made
    from the same folders and networks is reused and a new one written otherwise. ``workers`` > 1
    spreads the recordings over that many processes, each with its own copy of the networks (one
    thread each); the result does not depend on it."""
    recs = [r for f in folders for r in recording_folders(Path(f))]
    key = json.dumps({"recordings": [str(r) for r in recs], "model": repr(model)})
    if cache is not None and cache.is_file():
        with np.load(cache) as z:
            if "key" in z.files and str(z["key"]) == key:
                if advance is not None:
                    advance(len(recs))
                return {k: z[k] for k in z.files if k != "key"}
    parts = []
    if workers > 1 and len(recs) > 1:
        from concurrent.futures import ProcessPoolExecutor

        spec = _model_spec(model)
        with ProcessPoolExecutor(max_workers=workers) as ex:
            for part in ex.map(_rows_of, [str(r) for r in recs], [spec] * len(recs), chunksize=4):
                parts.append(part)
                if advance is not None:
                    advance(1)
    else:
        for folder in recs:
            parts.append(far_rows(read_recording(folder), model))
            if advance is not None:
                advance(1)
    for i, part in enumerate(parts):
        part["recording"] = np.full(len(part["rows"]), i)
    if not parts:
        raise ValueError(f"no recordings under {', '.join(str(f) for f in folders)}")
    out = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    out["names"] = np.array([str(r) for r in recs])
    if cache is not None:
        from makeway.atomic import atomic_path

        arrays: dict[str, Any] = {"key": np.array(key), **out}
        with atomic_path(cache) as tmp, open(tmp, "wb") as fh:
            np.savez(fh, **arrays)
    return out


def _model_spec(model: SirenModel) -> tuple[str, str | None, list[str], bool]:
    """What it takes to open ``model`` again in another process."""
    loc = None if model.localizer is None else str(model.localizer.path)
    return str(model.path), loc, [str(r.path) for r in model.rangers], model.localizer_distance


_WORKER_MODELS: dict[tuple[str, str | None, tuple[str, ...], bool], SirenModel] = {}


def _rows_of(folder: str, spec: tuple[str, str | None, list[str], bool]) -> dict[str, np.ndarray]:
    """:func:`far_rows` of one recording folder in a worker process (networks opened once each)."""
    path, loc, rangers, loc_d = spec
    key = (path, loc, tuple(rangers), loc_d)
    if key not in _WORKER_MODELS:
        _WORKER_MODELS[key] = SirenModel(
            path,
            threads=1,
            localizer=loc if loc is not None else False,
            ranger=rangers,
            localizer_distance=loc_d,
        )
    return far_rows(read_recording(folder), _WORKER_MODELS[key])


class FarNet(nn.Module):
    """The far ranger's network (module docstring)."""

    mean: torch.Tensor
    std: torch.Tensor

    def __init__(
        self,
        n_features: int,
        width: int = 64,
        dropout: float = 0.5,
        log_distance_offset: float = math.log(60.0),
    ) -> None:
        super().__init__()
        self.register_buffer("mean", torch.zeros(n_features))
        self.register_buffer("std", torch.ones(n_features))
        self.offset = float(log_distance_offset)
        self.body = nn.Sequential(
            nn.Linear(n_features, width),
            nn.ReLU(),
            nn.Dropout(dropout),
            nn.Linear(width, width),
            nn.ReLU(),
            nn.Dropout(dropout),
        )
        self.head = nn.Linear(width, 3)

    def fit_normalization(self, x: np.ndarray) -> None:
        with torch.no_grad():
            self.mean.copy_(torch.from_numpy(x.mean(axis=0).astype(np.float32)))
            self.std.copy_(torch.from_numpy(np.maximum(x.std(axis=0), 1e-3).astype(np.float32)))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        out = self.head(self.body((x - self.mean) / self.std))
        log_d = torch.clamp(out[:, 0] + self.offset, min=0.0, max=7.0)
        log_sigma = torch.clamp(out[:, 1], *LOG_SIGMA_RANGE)
        return log_d, log_sigma, out[:, 2]


def _loss(
    out: tuple[torch.Tensor, torch.Tensor, torch.Tensor],
    log_true: torch.Tensor,
    far: torch.Tensor,
    far_weight: float,
) -> tuple[torch.Tensor, float, float]:
    log_d, log_sigma, far_logit = out
    nll = (0.5 * (log_d - log_true) ** 2 * torch.exp(-2.0 * log_sigma) + log_sigma).mean()
    bce = nn.functional.binary_cross_entropy_with_logits(far_logit, far)
    return nll + far_weight * bce, float(nll.detach()), float(bce.detach())


def train_far_net(
    rows: np.ndarray,
    distance: np.ndarray,
    recording: np.ndarray,
    *,
    far_boundary_m: float = FAR_BOUNDARY_M,
    width: int = 64,
    epochs: int = 25,
    lr: float = 1e-3,
    weight_decay: float = 1e-2,
    far_weight: float = 1.0,
    batch_size: int = 256,
    seed: int = 0,
    threads: int = 1,
    on_epoch: Callable[[dict[str, float]], Any] | None = None,
) -> tuple[FarNet, list[dict[str, float]]]:
    """Train a :class:`FarNet` on feature ``rows`` with the true ``distance`` (m) of each, early
    stopping on a seeded 15 % of the ``recording`` ids (module docstring); returns the best network
    (eval mode) and the history."""
    torch.manual_seed(seed)
    torch.set_num_threads(max(1, int(threads)))
    rng = np.random.default_rng(seed)
    recs = np.unique(recording)
    val_recs = rng.choice(recs, size=max(1, round(0.15 * len(recs))), replace=False)
    is_val = np.isin(recording, val_recs)
    tr, va = np.flatnonzero(~is_val), np.flatnonzero(is_val)
    x = torch.from_numpy(np.asarray(rows, dtype=np.float32))
    log_true = torch.from_numpy(np.log(np.maximum(np.asarray(distance, dtype=np.float32), 1.0)))
    far = torch.from_numpy((np.asarray(distance) > far_boundary_m).astype(np.float32))
    net = FarNet(rows.shape[1], width)
    net.fit_normalization(np.asarray(rows, dtype=np.float32)[tr])
    opt = torch.optim.Adam(net.parameters(), lr=lr, weight_decay=weight_decay)
    sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, factor=0.3, patience=4)
    best: tuple[float, dict[str, torch.Tensor]] | None = None
    history: list[dict[str, float]] = []
    for epoch in range(epochs):
        t0 = time.perf_counter()
        net.train()
        order = rng.permutation(tr)
        total = 0.0
        for i in range(0, len(order), batch_size):
            idx = torch.from_numpy(order[i : i + batch_size])
            if len(idx) < 2:
                continue
            loss, _, _ = _loss(net(x[idx]), log_true[idx], far[idx], far_weight)
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += float(loss.detach()) * len(idx)
        net.eval()
        with torch.no_grad():
            vidx = torch.from_numpy(va)
            vloss, vnll, vbce = _loss(net(x[vidx]), log_true[vidx], far[vidx], far_weight)
            log_d = net(x[vidx])[0]
            rel = float(torch.median(torch.abs(torch.exp(log_d - log_true[vidx]) - 1.0)))
        row = {
            "epoch": epoch + 1,
            "lr": opt.param_groups[0]["lr"],
            "train_loss": total / max(len(tr), 1),
            "val_loss": float(vloss),
            "val_nll": vnll,
            "val_far_bce": vbce,
            "val_median_relative_error": rel,
            "seconds": time.perf_counter() - t0,
        }
        history.append(row)
        if on_epoch is not None:
            on_epoch(row)
        if best is None or float(vloss) < best[0]:
            best = (float(vloss), {k: v.detach().clone() for k, v in net.state_dict().items()})
        sched.step(float(vloss))
        if opt.param_groups[0]["lr"] < 1e-5:
            break
    if best is not None:
        net.load_state_dict(best[1])
    net.eval()
    return net, history


def export_far_onnx(net: FarNet, path: Path, feature_names: Sequence[str], meta: dict[str, Any]) -> Path:
    """Write ``net`` as ONNX (input ``features (n, n_features)``, outputs :data:`OUTPUT_NAMES`) with
    ``feature_names`` and ``meta`` in its metadata."""
    import onnx

    from makeway.atomic import atomic_path

    net.eval()
    props = far_metadata(
        {
            "makeway_model": "siren_far_ranger",
            "format_version": "1",
            "feature_names": json.dumps(list(feature_names)),
            **meta,
        }
    )
    with atomic_path(path) as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        torch.onnx.export(
            net,
            (torch.zeros((2, len(feature_names))),),
            str(tmp),
            dynamo=False,
            input_names=["features"],
            output_names=list(OUTPUT_NAMES),
            dynamic_axes={n: {0: "batch"} for n in ("features", *OUTPUT_NAMES)},
            opset_version=17,
        )
        model = onnx.load(str(tmp))
        for k, v in props.items():
            entry = model.metadata_props.add()
            entry.key, entry.value = k, v
        onnx.save(model, str(tmp))
    return path


def train_far_ranger(
    data: Sequence[str | Path],
    out: str | Path | None = None,
    *,
    siren: SirenModel | None = None,
    far_boundary_m: float = FAR_BOUNDARY_M,
    width: int = 64,
    epochs: int = 25,
    lr: float = 1e-3,
    far_weight: float = 1.0,
    seed: int = 0,
    threads: int = 1,
    cache: str | Path | None = None,
    command: str = "makeway audio train-far",
    log: Callable[[str], None] | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Train the far ranger on the recordings under ``data`` (module docstring) and export it to
    ``out`` (default: the shipped file). ``siren``: the networks whose outputs feed it (default:
    the shipped stack, one thread). Returns the training description stored in the model.

    Raises:
        ValueError: a bad setting, or no windows with a siren within 400 m (before training).
        InputError: a recording folder cannot be read; ``out`` or ``cache`` cannot be written
            (checked first).
    """
    from makeway.atomic import check_writable
    from makeway.perceive.audio.far_range import DEFAULT_FAR_RANGER
    from makeway.progress import progress_bar

    if not 10.0 <= far_boundary_m <= 350.0:
        raise ValueError(f"--far-boundary must lie in 10–350 m (labels reach 400 m), not {far_boundary_m:g}")
    say = log if log is not None else (lambda _line: None)
    target = Path(out) if out is not None else DEFAULT_FAR_RANGER
    check_writable(target, folder=False)  # before hours of feature rows
    if cache is not None:
        check_writable(Path(cache), folder=False)
    model = siren if siren is not None else SirenModel(threads=threads)
    folders = [r for f in data for r in recording_folders(Path(f))]
    with progress_bar("far rows", len(folders), enabled=progress, unit="rec") as advance:
        ds = far_dataset(
            folders, model, cache=None if cache is None else Path(cache), workers=threads, advance=advance
        )
    use = np.isfinite(ds["true_distance"])
    if not use.any():
        raise ValueError("no window has a siren within 400 m: nothing to train the far ranger on")
    d = ds["true_distance"][use]
    say(
        f"{len(folders)} recordings → {int(use.sum())} windows with a siren ≤ {LABEL_MAX_DISTANCE_M:g} m "
        f"({100 * float((d > far_boundary_m).mean()):.0f} % beyond {far_boundary_m:g} m)"
    )
    t0 = time.perf_counter()

    def on_epoch(row: dict[str, float]) -> None:
        say(
            f"epoch {int(row['epoch'])}: lr {row['lr']:.2g} train {row['train_loss']:.3f} "
            f"val {row['val_loss']:.3f} "
            f"(nll {row['val_nll']:.3f}, far bce {row['val_far_bce']:.3f}, median relative error "
            f"{100 * row['val_median_relative_error']:.0f} %)"
        )

    net, history = train_far_net(
        ds["rows"][use],
        d,
        ds["recording"][use],
        far_boundary_m=far_boundary_m,
        width=width,
        epochs=epochs,
        lr=lr,
        far_weight=far_weight,
        seed=seed,
        threads=threads,
        on_epoch=on_epoch,
    )
    training = {
        "command": command,
        "recordings": [str(x) for x in data],
        "n_recordings": len(folders),
        "windows": int(use.sum()),
        "config": {"width": width, "epochs": epochs, "lr": lr, "far_weight": far_weight, "seed": seed},
        "epochs_run": len(history),
        "best_val_loss": round(min(h["val_loss"] for h in history), 5),
        "history": [{k: round(float(v), 5) for k, v in h.items()} for h in history],
        "train_seconds": round(time.perf_counter() - t0, 1),
    }
    networks = [model.path.name]
    if model.localizer is not None:
        networks.append(model.localizer.path.name)
    networks += [r.path.name for r in model.rangers]
    export_far_onnx(
        net,
        target,
        FarTracker().feature_names,
        {"far_boundary_m": repr(float(far_boundary_m)), "networks": networks, "training": training},
    )
    say(f"far ranger → {target} ({target.stat().st_size / 1e6:.2f} MB)")
    return {"model": str(target), **training}
