"""``makeway lights-train``: train the lit-light detector (parses options, calls
:func:`makeway.apps.lights_train.train_lights`, prints). Registered by the main app."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from makeway.cli.common import console, friendly_errors, print_json_line


@friendly_errors
def lights_train(
    out: Annotated[
        Path, typer.Argument(help="ONNX file to write (the shipped one: src/makeway/models/lights_det.onnx).")
    ],
    no_attention: Annotated[
        bool, typer.Option("--no-attention", help="Train without the colour-attention block (the ablation).")
    ] = False,
    arch: Annotated[
        str,
        typer.Option(
            help="Network: yolox (early layers of the YOLOX-nano vehicle detector, fine-tuned) "
            "or small (a small network trained from scratch)."
        ),
    ] = "yolox",
    steps: Annotated[int, typer.Option(min=20, help="Optimiser steps.")] = 1500,
    crop: Annotated[int, typer.Option(min=32, help="Training crop side in pixels (multiple of 16).")] = 256,
    batch: Annotated[int, typer.Option(min=1, help="Crops per optimiser step.")] = 8,
    seed: Annotated[int, typer.Option(help="Random seed.")] = 0,
    threads: Annotated[int, typer.Option(min=1, help="CPU threads for training.")] = 2,
    paste: Annotated[
        float, typer.Option(help="Probability of pasting real lit-lamp patches into a crop.")
    ] = 0.5,
    night_lamps: Annotated[
        float,
        typer.Option(help="Probability of the day-to-night change (frame darkened, lamps kept bright)."),
    ] = 0.3,
    min_val_tp: Annotated[
        int,
        typer.Option(
            min=1,
            help="Lamps the validation clip must find before it may pick the kept step and "
            "threshold (else the last step and threshold 0.3).",
        ),
    ] = 10,
    swap_red_blue: Annotated[
        float, typer.Option(help="Probability of exchanging red and blue channels (red lamps become blue).")
    ] = 0.0,
    night: Annotated[float, typer.Option(help="Probability of the night gamma curve (γ 1.5-3).")] = 0.0,
    data: Annotated[
        Path | None,
        typer.Option("--data", help="Shared data folder (default: ../shared/data or MAKEWAY_DATA)."),
    ] = None,
    labels: Annotated[
        Path | None,
        typer.Option("--labels", help="Folder of label CSVs (default: the package's data/lights)."),
    ] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the summary as one JSON line.")] = False,
    verifier: Annotated[
        bool,
        typer.Option(
            "--verifier",
            help="Train the 'verified' detector's proposal verifier (boosted trees; the shipped one: "
            "src/makeway/models/lights_verifier.onnx) instead of the CNN; uses --seed, --data, "
            "--appearance, --bag, --scales and --small-below only.",
        ),
    ] = False,
    appearance: Annotated[
        int,
        typer.Option(
            min=0,
            help="With --verifier: appearance columns per proposal (a patch around it through "
            "YOLOX-nano's backbone, projected on this many principal axes); 0 for none.",
        ),
    ] = 8,
    bag: Annotated[
        int,
        typer.Option(
            min=1,
            help="With --verifier: boosters averaged (fitted with seeds --seed … --seed + BAG − 1).",
        ),
    ] = 3,
    scales: Annotated[
        str,
        typer.Option(
            help="With --verifier: comma-separated factors in (0, 1] at which each training frame is "
            "also shown, shrunk (farther lamps, wider lenses); 1 alone trains on the frames as they are.",
        ),
    ] = "1",
    small_below: Annotated[
        float | None,
        typer.Option(
            help="With --verifier: write a small-lamp verifier, used by the 'verified' detector beside "
            "the main one for proposals under this many pixels on their longer side (the shipped one: "
            "src/makeway/models/lights_verifier_small.onnx, --scales 1,0.5,0.35,0.25 --small-below 6).",
        ),
    ] = None,
) -> None:
    """Train a lit-light model (CNN or verifier) as ONNX.

    Uses the checked labels, split by source clip.

    Train: fire_trucks_red_lights, traffic_no_ev, ambulance_yolo (not held out); validation:
    intersection_cam_ambulance (picks the step when it has lit lights). See docs/model_card_lights.md.
    """
    if verifier:
        from makeway.train.light_verifier import train_light_verifier

        try:
            factors = tuple(float(t) for t in scales.split(",") if t.strip())
        except ValueError:
            raise typer.BadParameter(
                f"--scales must be numbers separated by commas, not {scales!r}"
            ) from None
        v = train_light_verifier(
            out,
            data_root=data,
            seed=seed,
            appearance=appearance,
            bag=bag,
            scales=factors,
            applies_below_px=small_below,
        )
        val = v["validation"]
        console.print(
            f"wrote {v['model']} ({v['size_bytes'] / 1e6:.2f} MB): {v['train_rows']} train proposals "
            f"({v['train_positives']} positive), threshold {v['threshold']:.2f}; validation array P "
            f"{val['array_precision']:.3f} R {val['array_recall']:.3f}; {v['seconds']:.0f} s"
        )
        if json_out:
            print_json_line(v)
        return
    from makeway.apps.lights_train import train_lights

    s = train_lights(
        out,
        attention=not no_attention,
        arch=arch,
        steps=steps,
        crop=crop,
        batch=batch,
        seed=seed,
        threads=threads,
        swap_red_blue=swap_red_blue,
        night=night,
        paste=paste,
        night_lamps=night_lamps,
        min_val_tp=min_val_tp,
        data=data,
        label_dir=labels,
    )
    console.print(
        f"wrote {s['model']} ({s['bytes'] / 1e6:.2f} MB, attention {'on' if s['attention'] else 'off'}): "
        f"{s['train_frames']} train frames ({s['train_positive_frames']} with lights, "
        f"{s['train_boxes']} boxes), "
        f"{s['val_frames']} val frames ({s['val_boxes']} boxes); step {s['chosen_step']} kept; "
        f"threshold {s['threshold']:.2f} ({s['threshold_from']}); "
        f"{s['train_seconds']:.0f} s training"
    )
    if s["left_out"]:
        console.print(f"left out (source not in the split table): {', '.join(s['left_out'])}")
    if json_out:
        print_json_line(s)
