"""``makeway engine …``: the data engine — mine many videos, image folders and recordings for hard
samples on a Dask cluster, and feed the labels back into training (issue 28).

Each command parses its options, makes one call into :mod:`makeway.apps.engine` and prints.
Registered by the main app as ``app.add_typer(engine_app, name="engine")``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from makeway.cli.common import console, err_console, friendly_errors, new_app, print_json_line

engine_app = new_app(
    "engine",
    "Data engine: mine many inputs for samples to label.\n\n"
    "Mine road videos, image folders and siren recordings for the samples worth labelling, on this "
    "machine or a Dask cluster, and retrain with the labels.",
)


@engine_app.command()
@friendly_errors
def mine(
    inputs: Annotated[
        list[str],
        typer.Argument(
            help="Road videos (VIDEO, or VIDEO@START:END for frames START to END-1), folders of road "
            "images, recording folders (audio.flac + array.yaml), or robotics logs (MCAP files, "
            "ROS 2 bag folders)."
        ),
    ],
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder (a rerun resumes it).")],
    scheduler: Annotated[
        str | None,
        typer.Option(help="Address of a running Dask scheduler, tcp://HOST:PORT (default: start one here)."),
    ] = None,
    workers: Annotated[
        int | None,
        typer.Option(min=1, help="Worker processes of the local cluster (default: one per CPU core)."),
    ] = None,
    segment_frames: Annotated[
        int | None,
        typer.Option(min=1, help="Cut each whole video into tasks of this many frames."),
    ] = None,
    classifier: Annotated[
        str,
        typer.Option(
            help="Crop classifier: default, general, fast, fastest, imagenet, or a .npz/.onnx file."
        ),
    ] = "default",
    threshold: Annotated[
        float | None,
        typer.Option(min=0.0, max=1.0, help="EV probability that counts as active (default: the model's)."),
    ] = None,
    band: Annotated[
        float,
        typer.Option(min=0.0, max=1.0, help="Also keep near misses this far below the threshold."),
    ] = 0.2,
    stride: Annotated[int, typer.Option(min=1, help="Process every N-th video frame.")] = 1,
    every: Annotated[
        int, typer.Option(min=1, help="Keep at most one sample of a vehicle track per N frames.")
    ] = 10,
    top: Annotated[int, typer.Option(min=1, help="Thumbnails per contact sheet.")] = 64,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as one JSON line.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Mine inputs for hard samples to label.

    Each input is one task on the cluster: the vehicle detector, tracker and crop classifier run
    over videos and images, the siren network over recordings. Every sample the model calls an
    emergency vehicle or siren, and every near miss (--band), is kept with its context: the crop or
    audio snippet, time, input and track. Writes OUT/samples.csv (all, ranked), candidates.csv,
    contact_sheet*.png and labels_template.csv (fill the emergency column, then run `makeway engine
    feedback`), audio_candidates.csv, failures.csv and engine.json. Finished inputs are skipped when
    the command runs again. An input that cannot be read is listed and the rest completes; the exit
    code is then 2.
    """
    from makeway.engine.cluster import mine_inputs
    from makeway.engine.mine import MineConfig

    config = MineConfig(classifier=classifier, threshold=threshold, band=band, stride=stride, every=every)
    run = mine_inputs(
        inputs,
        out,
        config=config,
        scheduler=scheduler,
        workers=workers,
        segment_frames=segment_frames,
        top=top,
        progress=not quiet,
    )
    for failure in run.failures:
        err_console.print(f"[bold red]failed:[/] {failure['error']}", highlight=False, soft_wrap=True)
    if as_json:
        summary = run.to_json()
        summary.pop("tasks")
        print_json_line(summary)
    else:
        table = Table(title=f"makeway engine mine — {run.inputs} inputs", show_header=False)
        table.add_row("cluster", f"{run.scheduler}, {run.workers} workers")
        table.add_row("inputs", f"{run.done} mined, {run.skipped} done before, {run.failed} failed")
        table.add_row("samples", f"{run.vision_samples} crops, {run.audio_samples} audio snippets")
        table.add_row("time", f"{run.wall_s:.1f} s wall, {run.task_s:.1f} s in tasks")
        for name, path in run.outputs.items():
            table.add_row(f"→ {name}", path)
        console.print(table)
    if run.failed:
        raise typer.Exit(code=2)


@engine_app.command()
@friendly_errors
def feedback(
    mined: Annotated[Path, typer.Argument(help="Output folder of `makeway engine mine`.")],
    labels: Annotated[
        Path, typer.Option(help="Its labels_template.csv with the emergency column filled (1, 0 or blank).")
    ],
    out: Annotated[Path, typer.Option("--out", "-o", help="Where the crop folder and the report go.")],
    held_out: Annotated[
        list[str] | None,
        typer.Option(
            help="Held-out sources to report (repeat; default: ev_crops, ambulance_yolo, road_clips)."
        ),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the result as one JSON line.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress output.")] = False,
) -> None:
    """Retrain with the labelled samples and report the change.

    The labelled crops become a crop folder (OUT/mined_crops: images/ + labels.csv), which joins the
    training data of the default crop classifier's recipe. The recipe is trained with each labelled
    source left out in turn, without and with the mined crops, and scored on the source left out:
    OUT/feedback.md and OUT/feedback.json give accuracy, F1, recall and specificity before and after.
    """
    from makeway.apps.engine import engine_feedback

    def log(line: str) -> None:
        if not quiet:
            err_console.print(line, highlight=False)

    run = engine_feedback(mined, labels, out, held_out=held_out, progress=not quiet, log=log)
    if as_json:
        print_json_line(run.to_json())
        return
    table = Table(title="makeway engine feedback — before → after")
    for col in ("held-out source", "n", "accuracy", "F1"):
        table.add_column(col)
    for r in run.rows:
        f1b, f1a = r["f1_before"], r["f1_after"]
        table.add_row(
            r["held_out"],
            str(r["n"]),
            f"{r['accuracy_before']:.3f} → {r['accuracy_after']:.3f}",
            "—" if f1b is None or f1a is None else f"{f1b:.3f} → {f1a:.3f}",
        )
    console.print(table)
    for name, path in run.outputs.items():
        err_console.print(f"→ {name}: {path}", highlight=False)
