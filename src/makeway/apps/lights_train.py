"""``makeway lights-train``: train the lit-light detector on the committed labels and export it as ONNX.

One library call for the CLI and the benchmark: :func:`train_lights` loads the train and validation
splits (:mod:`makeway.train.lights`), trains, writes the ONNX file (and a JSON training log beside it,
``<out>.json``) and returns a summary.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from makeway.atomic import check_writable, write_text_atomic
from makeway.errors import InputError
from makeway.paths import require_data_dir

__all__ = ["train_lights"]


def train_lights(
    out: str | Path,
    *,
    attention: bool = True,
    arch: str = "yolox",
    steps: int = 1500,
    crop: int = 256,
    batch: int = 8,
    seed: int = 0,
    threads: int = 2,
    swap_red_blue: float = 0.0,
    night: float = 0.0,
    paste: float = 0.5,
    night_lamps: float = 0.3,
    min_val_tp: int = 10,
    data: str | Path | None = None,
    label_dir: str | Path | None = None,
    show_progress: bool = True,
) -> dict[str, Any]:
    """Train and export one detector to ``out`` (``.onnx``); ``arch`` the network (``yolox``: YOLOX-nano's
    COCO-pretrained early stages fine-tuned; ``small``: the from-scratch ``LightNet``); ``attention``
    False trains the ablation without the colour-attention block; ``steps`` of ``batch`` crops of
    ``crop`` px on ``threads`` torch threads; ``paste``, ``night_lamps``, ``swap_red_blue`` and
    ``night`` are the probabilities of those augmentations (:mod:`makeway.train.light_augment`);
    validation picks the step and threshold only when a check reaches ``min_val_tp`` true positives.
    Returns the summary: frames and boxes per split, the chosen step and operating threshold (and
    where it came from), seconds, model size (bytes), the label files left out (unknown source)."""
    from makeway.progress import progress_bar
    from makeway.train.lights import TrainConfig, export_onnx, load_split, log_json, train

    out = Path(out)
    if out.suffix.lower() != ".onnx":
        raise InputError(out, "the output must be an .onnx file")
    check_writable(out, folder=False)
    root = require_data_dir(data)
    from makeway.train.lights import ARCHS

    if arch not in ARCHS:
        raise ValueError(f"unknown network {arch!r}; choose from {', '.join(ARCHS)}")
    if steps < 20:
        raise ValueError(f"steps must be at least 20, got {steps}")
    if crop < 32 or crop % 16 or batch < 1 or threads < 1:
        raise ValueError(
            "crop must be a multiple of 16 of at least 32 px, batch and threads ≥ 1 "
            f"(got {crop}, {batch}, {threads})"
        )
    for name, p in (
        ("swap_red_blue", swap_red_blue),
        ("night", night),
        ("paste", paste),
        ("night_lamps", night_lamps),
    ):
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"{name} is a probability in [0, 1], got {p}")
    cfg = TrainConfig(
        arch=arch,
        steps=steps,
        crop=crop,
        batch=batch,
        attention=attention,
        seed=seed,
        threads=threads,
        swap_red_blue=swap_red_blue,
        night=night,
        paste=paste,
        night_lamps=night_lamps,
        min_val_tp=min_val_tp,
    )
    t0 = time.perf_counter()
    size = (cfg.input_width, cfg.input_height)
    train_frames, unknown = load_split("train", root, label_dir=label_dir, input_size=size)
    val_frames, _ = load_split("val", root, label_dir=label_dir, input_size=size)
    load_s = time.perf_counter() - t0
    with progress_bar("training lights detector", steps, enabled=show_progress, unit="steps") as advance:
        net, log = train(train_frames, val_frames, cfg, progress=lambda _s, _n, _l: advance())
    command = (
        f"makeway lights-train {out}"
        + ("" if attention else " --no-attention")
        + f" --arch {arch} --steps {steps} --crop {crop} --batch {batch} --threads {threads} --seed {seed}"
        + f" --paste {paste} --night-lamps {night_lamps} --min-val-tp {min_val_tp}"
        + f" --swap-red-blue {swap_red_blue} --night {night}"
    )
    export_onnx(net, out, cfg, training=command, threshold=float(log["threshold"]))
    summary: dict[str, Any] = {
        "model": str(out),
        "bytes": out.stat().st_size,
        "attention": attention,
        "train_frames": len(train_frames),
        "train_boxes": int(sum(len(f.boxes) for f in train_frames)),
        "train_positive_frames": int(sum(len(f.boxes) > 0 for f in train_frames)),
        "val_frames": len(val_frames),
        "val_boxes": int(sum(len(f.boxes) for f in val_frames)),
        "val_has_lights": bool(log["val_has_lights"]),
        "arch": arch,
        "chosen_step": int(log["chosen_step"]),
        "threshold": float(log["threshold"]),
        "threshold_from": str(log["threshold_from"]),
        "train_seconds": float(log["seconds"]),
        "load_seconds": round(load_s, 1),
        "left_out": unknown,
        "command": command,
    }
    log["summary"] = summary
    write_text_atomic(out.with_suffix(".json"), log_json(log) + "\n")
    return summary
