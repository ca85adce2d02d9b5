"""``makeway audio …``: simulated siren recordings and their labels (issue 4).

Registered by :mod:`makeway.cli.main` as ``app.add_typer(audio_app, name="audio")``; also runs on its
own (``python -m makeway.cli.audio``). Bad input ends with one red ``error:`` line naming the file,
exit code 2, and no half-written output.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from makeway.atomic import check_writable
from makeway.cli.common import err_console, friendly_errors, new_app, print_json_line
from makeway.errors import InputError
from makeway.perceive.audio.windows import LISTEN_SMOOTH, SMOOTH_AVERAGE
from makeway.sense.recording import FULL_SCALE_RANGE_DB, REFERENCE_FULL_SCALE_DB_SPL, recording_folders

if TYPE_CHECKING:
    from makeway.perceive.audio.siren_model import SirenModel

audio_app = new_app(
    "audio", "Siren recordings from the car-roof microphone array: simulate, label, evaluate."
)


def _parse_range(text: str, option: str, bounds: tuple[float, float], example: str) -> tuple[float, float]:
    """``"LOW,HIGH"`` → ``(low, high)`` within ``bounds``, or a ValueError naming ``option``."""
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"{option} takes LOW,HIGH in {example}, not {text!r}") from None
    if not bounds[0] <= lo <= hi <= bounds[1]:
        raise ValueError(f"{option} needs {bounds[0]:g} <= LOW <= HIGH <= {bounds[1]:g}, not {text!r}")
    return lo, hi


@audio_app.command()
@friendly_errors
def simulate(
    out: Annotated[
        Path, typer.Option("--out", "-o", help="Folder to write the recordings into (rec_00000, …).")
    ],
    n: Annotated[int, typer.Option("--n", min=1, help="Number of recordings.")] = 10,
    scenario: Annotated[
        list[str] | None,
        typer.Option(
            help="Scenario(s) to draw from: crossing, same_direction, opposite_direction, from_behind "
            "(repeat the option; default: all)."
        ),
    ] = None,
    seed: Annotated[int, typer.Option(help="Seed; recording i is fully determined by (seed, i).")] = 0,
    start: Annotated[
        int,
        typer.Option(
            min=0,
            help="Index of the first recording (rec_<start> …): commands with the same --seed and "
            "different --start fill one --out folder in parallel, as one command would.",
        ),
    ] = 0,
    duration: Annotated[float, typer.Option(min=0.6, help="Seconds of audio per recording.")] = 10.0,
    siren: Annotated[
        str, typer.Option(help="Siren sounds: auto, synth (procedural) or real (data).")
    ] = "auto",
    noise: Annotated[str, typer.Option(help="Street noise: auto, real (data) or generated.")] = "auto",
    no_siren_fraction: Annotated[
        float, typer.Option(min=0.0, max=1.0, help="Share of recordings with no siren (negatives).")
    ] = 0.25,
    two_siren_fraction: Annotated[
        float, typer.Option(min=0.0, max=1.0, help="Share of siren recordings with two EVs.")
    ] = 0.1,
    split: Annotated[
        str,
        typer.Option(
            help="Real ingredients to draw from: all, train or test (siren models, clip blocks and "
            "street recordings are split by a fixed hash of their group, 80/20)."
        ),
    ] = "all",
    distractors: Annotated[
        bool,
        typer.Option(
            help="Add non-siren street sounds (horns, birds, brake squeal, air-brake hiss, revving "
            "engines) to 60 % of the recordings."
        ),
    ] = True,
    street_level: Annotated[
        str,
        typer.Option(
            help="Range of the street noise's A-weighted level at the array, LOW,HIGH in dB(A) "
            "(e.g. 60,88 for loud no-siren training recordings: traffic alone is no siren)."
        ),
    ] = "60,75",
    siren_pitch: Annotated[
        str,
        typer.Option(
            help="Pitch variety for training sets, LOW,HIGH factors (e.g. 0.7,1.25): half the sirens "
            "are played at a factor drawn from this range (synthesized wails and yelps also get a "
            "new sweep shape). Empty: sirens as they are."
        ),
    ] = "",
    full_scale_db_spl: Annotated[
        float,
        typer.Option(
            "--full-scale-db-spl",
            min=FULL_SCALE_RANGE_DB[0],
            max=FULL_SCALE_RANGE_DB[1],
            help="The simulated array's calibration: the dB SPL that a digital RMS of 1.0 stands for, "
            "stated in each array.yaml (default: 135, the shipped networks' scale; lower = a more "
            "sensitive array).",
        ),
    ] = REFERENCE_FULL_SCALE_DB_SPL,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as one JSON line.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Simulate recordings of the reference 8-capsule roof array (48 kHz) in seed 002's scenarios.

    Each recording is a folder: audio.flac, array.yaml, ego.csv, source_<k>.csv, meta.yaml. Uses the
    real siren clips/tones and street recordings from ../shared/data when present, the procedural
    siren synthesizer and generated noise otherwise.
    """
    from makeway.sim.audio_scenarios import AUDIO_SCENARIOS, generate_recordings, source_pools

    check_writable(out, folder=True)
    scenarios = tuple(scenario) if scenario else AUDIO_SCENARIOS
    if siren not in ("auto", "synth", "real"):
        raise ValueError(f"--siren must be auto, synth or real, not {siren!r}")
    street_dba = _parse_range(street_level, "--street-level", (0.0, 120.0), "dB(A) like 60,75")
    pitch = None
    if siren_pitch:
        pitch = _parse_range(siren_pitch, "--siren-pitch", (0.25, 4.0), "factors like 0.7,1.25")
    siren_pool, noise_pool = source_pools(split)
    t0 = time.perf_counter()
    paths = generate_recordings(
        out,
        n,
        scenarios=scenarios,
        duration_s=duration,
        seed=seed,
        siren=siren,
        noise=noise,
        no_siren_fraction=no_siren_fraction,
        two_siren_fraction=two_siren_fraction,
        siren_pool=siren_pool if siren != "synth" else [],
        noise_pool=noise_pool if noise != "generated" else [],
        progress=not quiet,
        distractors=distractors,
        street_dba=street_dba,
        siren_pitch=pitch,
        start_index=start,
        full_scale_db_spl=full_scale_db_spl,
    )
    wall = time.perf_counter() - t0
    summary = {
        "out": str(out),
        "split": split,
        "recordings": len(paths),
        "duration_s": duration,
        "seconds": round(wall, 2),
        "seconds_per_audio_second": round(wall / max(len(paths) * duration, 1e-9), 3),
        "full_scale_db_spl": full_scale_db_spl,
    }
    if as_json:
        print_json_line(summary)
    else:
        err_console.print(
            f"wrote {len(paths)} recordings of {duration:g} s to {out} in {wall:.1f} s",
            highlight=False,
        )


@audio_app.command()
@friendly_errors
def label(
    folder: Annotated[Path, typer.Argument(help="A recording folder, or a folder of recording folders.")],
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="JSONL output (default: FOLDER/labels.jsonl).")
    ] = None,
    window: Annotated[float, typer.Option(min=0.01, help="Window length (s).")] = 0.5,
    hop: Annotated[float, typer.Option(min=0.01, help="Hop between windows (s).")] = 0.17,
    max_distance: Annotated[float, typer.Option(min=0.0, help="Drop sources farther than this (m).")] = 100.0,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as one JSON line.")] = False,
) -> None:
    """Auto-label recordings from their trajectories: one JSON line per window.

    Each line: recording, window, start_sample, n_samples, t_end, siren, and per source in range its
    theta (vehicle frame, 0 ahead, positive left), distance and range rate at the window end.
    """
    from makeway.atomic import write_text_atomic
    from makeway.eval.siren_labels import label_recording
    from makeway.sense.recording import read_recording

    recs = recording_folders(folder)
    lines: list[str] = []
    n_windows = n_pos = n_dropped = 0
    for path in recs:  # read everything first: a bad recording leaves no output behind
        labels = label_recording(read_recording(path), window, hop, max_distance)
        for row in labels.records(path.name):
            lines.append(json.dumps(row, separators=(",", ":")))
        n_windows += len(labels)
        n_pos += int(labels.siren.sum())
        n_dropped += int(labels.dropped.sum())
    target = out if out is not None else folder / "labels.jsonl"
    write_text_atomic(target, "\n".join(lines) + ("\n" if lines else ""))
    summary = {
        "recordings": len(recs),
        "windows": n_windows,
        "positive": n_pos,
        "dropped": n_dropped,
        "out": str(target),
    }
    if as_json:
        print_json_line(summary)
    else:
        err_console.print(
            f"labelled {len(recs)} recording(s): {n_windows} windows, {n_pos} with a siren within "
            f"{max_distance:g} m, {n_dropped} dropped (sirens only farther) → {target}",
            highlight=False,
        )


ModelOption = Annotated[
    Path | None, typer.Option("--model", help="Siren model (.onnx) (default: the shipped one).")
]
LocalizerOption = Annotated[
    Path | None,
    typer.Option(
        help="A second siren model whose bearing and distance replace the model's "
        "(default: the shipped localizer, with the shipped model only)."
    ),
]
RangerOption = Annotated[
    list[Path] | None,
    typer.Option(
        help="A further siren model whose distance is averaged in (geometric mean); repeat the option "
        "for several (default: the shipped rangers, with the shipped model only)."
    ),
]

AverageOption = Annotated[
    str,
    typer.Option(
        help="How --smooth averages the windows: logit (the mean of their logits, each window "
        "weighed by its log-odds) or probability (the plain mean).",
    ),
]

FullScaleOption = Annotated[
    float | None,
    typer.Option(
        "--full-scale-db-spl",
        min=FULL_SCALE_RANGE_DB[0],
        max=FULL_SCALE_RANGE_DB[1],
        help="The array's calibration for recordings whose array.yaml states no full_scale_db_spl: "
        "the dB SPL that a digital RMS of 1.0 stands for (97 minus the capsules' sensitivity in dBFS "
        "at 94 dB SPL). Without it such recordings are taken at the networks' 135 dB SPL; 6 dB of "
        "error raises the median distance error by half, 12 dB too quiet costs 12 points of recall.",
    ),
]


def _calibration_note(n_without: int, baseline: str | None) -> None:
    """Say on stderr when recordings had no calibration and a network read their levels."""
    if n_without and baseline is None:
        err_console.print(
            f"note: {n_without} recording(s) state no full_scale_db_spl in array.yaml; taken at the "
            f"networks' {REFERENCE_FULL_SCALE_DB_SPL:g} dB SPL full scale (give --full-scale-db-spl "
            "if the array differs: 6 dB off moves the distances by a third or more)",
            highlight=False,
        )


def _check_baseline(baseline: str | None, *networks: Path | list[Path] | None) -> None:
    """``--baseline`` names a classical method and excludes ``--model/--localizer/--ranger``."""
    from makeway.perceive.audio.doa import DOA_METHODS

    if baseline is None:
        return
    if baseline not in DOA_METHODS:
        raise ValueError(f"--baseline must be one of {'|'.join(DOA_METHODS)}, not {baseline!r}")
    if any(n for n in networks):
        raise ValueError("give either --model/--localizer/--ranger or --baseline, not both")


def _siren_networks(
    model: Path | None, localizer: Path | None, ranger: list[Path] | None, threads: int | None
) -> SirenModel:
    """The siren network with its localizer and rangers (the shipped ones unless named)."""
    from makeway.perceive.audio.siren_model import SirenModel

    return SirenModel(
        model,
        threads=threads,
        localizer=localizer if localizer is not None else True,
        ranger=ranger if ranger else True,
    )


def _approach_estimator(name: str | None, net: SirenModel | None) -> Any:
    """The approach estimator named by ``--approach`` (None: :func:`~makeway.perceive.audio.stream
    .default_approach`); ``trend`` needs the network's distances."""
    from makeway.perceive.audio.motion import APPROACH_METHODS
    from makeway.perceive.audio.stream import default_approach

    if name is None:
        return default_approach(net)
    cls = APPROACH_METHODS[name]
    if name == "trend" and net is None:
        raise ValueError("--approach trend reads the network's distances; it cannot run with --baseline")
    return cls()


def _score_approach(
    recs: list[Path], net: SirenModel, full_scale_db_spl: float | None, quiet: bool
) -> dict[str, Any]:
    """``eval --approach``: each recording run as ``listen`` runs it, the approaching/receding call
    of the distance-trend classifier and of the level/Doppler rule scored against the labelled
    range rate (:mod:`makeway.eval.siren_approach`)."""
    from makeway.eval.siren_approach import MIN_RANGE_RATE_MPS, approach_recordings, approach_scores
    from makeway.perceive.audio.motion import TrendApproach
    from makeway.progress import progress_bar

    trend = TrendApproach()
    with progress_bar("approach", len(recs), enabled=not quiet, unit="rec") as advance:
        arrays = approach_recordings(recs, net, trend, full_scale_db_spl=full_scale_db_spl, advance=advance)
    return {"min_range_rate_mps": MIN_RANGE_RATE_MPS, **approach_scores(arrays, trend)}


@audio_app.command("eval")
@friendly_errors
def eval_cmd(
    data: Annotated[
        Path, typer.Option("--data", help="A recording folder, or a folder of recording folders.")
    ],
    baseline: Annotated[
        str | None,
        typer.Option(
            help="Classical method instead of the trained model: gccphat, srp or normmusic "
            "(with the band-energy siren detector)."
        ),
    ] = None,
    fit: Annotated[
        Path | None,
        typer.Option(
            help="Fit the baseline detector's two logistic constants on these recordings first "
            "(default: the shipped constants)."
        ),
    ] = None,
    model: ModelOption = None,
    localizer: LocalizerOption = None,
    ranger: RangerOption = None,
    threads: Annotated[int | None, typer.Option(min=1, help="ONNX Runtime threads (default: all).")] = None,
    smooth: Annotated[
        int,
        typer.Option(
            min=1,
            help="Decide on the mean of each window and the K-1 before it, as "
            "'audio listen --smooth K' does live (default: 1, seed 002's per-window decision).",
        ),
    ] = 1,
    average: AverageOption = SMOOTH_AVERAGE,
    full_scale_db_spl: FullScaleOption = None,
    approach: Annotated[
        bool,
        typer.Option(
            "--approach",
            help="Also score approaching/receding as 'audio listen' calls it (the distance-trend "
            'classifier and the level/Doppler rule) against the labelled range rate: an "approach" key. '
            "Runs the networks a second time.",
        ),
    ] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print only the JSON line.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Evaluate siren detection and localization on labelled recordings (one JSON line, last).

    Runs the shipped siren network (or --model), or with --baseline a classical method. Keys:
    recall, false_alarm_rate (per window), accuracy, angle_median_deg, angle_mean_deg (wrapped),
    distance_median_m, distance_mean_m (null for the baselines), the same inside "range_10_50", and
    "by_distance" (10 m bins). With --approach, "approach": for the windows where the listener
    reports a siren moving by at least 1 m/s, the share called right (correct; undecided counts as
    wrong), decided, the two errors apart, and the same per scenario and per band of speed.
    """
    _check_baseline(baseline, model, localizer, ranger)
    if baseline is None and fit is not None:
        raise ValueError("--fit fits the baseline detector; it needs --baseline")
    if baseline is not None and approach:
        raise ValueError(
            "--approach scores the network's approaching/receding call; it needs the network, not --baseline"
        )
    from makeway.eval.siren import evaluate, model_estimator
    from makeway.eval.siren_labels import label_recording
    from makeway.perceive.audio.doa import SirenEnergyDetector
    from makeway.perceive.audio.features import window_batch
    from makeway.progress import progress_bar
    from makeway.sense.recording import read_recording

    recs = recording_folders(data)
    detector = None
    if fit is not None:
        import numpy as np

        detector = SirenEnergyDetector()
        scores, ys = [], []
        for path in recording_folders(fit):
            rec = read_recording(path)
            labels = label_recording(rec)
            detector.sample_rate = rec.sample_rate
            scores.append(detector.scores(window_batch(rec, labels)[labels.kept]))
            ys.append(labels.siren[labels.kept])
        detector.fit_scores(np.concatenate(scores), np.concatenate(ys))
    method: Any = baseline
    name = baseline or "model"
    threshold = 0.5
    net: Any = None
    if baseline is None:
        net = _siren_networks(model, localizer, ranger, threads)
        method = model_estimator(net)
        name = f"model:{net.path.name}"
        threshold = net.threshold  # the decision threshold stored with the model
    t0 = time.perf_counter()
    with progress_bar(f"eval {name}", len(recs), enabled=not quiet, unit="rec") as advance:
        result = evaluate(
            recs,
            method,
            detector=detector,
            on_recording=advance,
            name=name,
            threshold=threshold,
            smooth=smooth,
            average=average,
            full_scale_db_spl=full_scale_db_spl,
        )
    result["data"] = str(data)
    if net is not None:
        result["localizer"] = net.localizer.path.name if net.localizer is not None else None
        result["ranger"] = [r.path.name for r in net.rangers]
    if approach:
        result["approach"] = _score_approach(recs, net, full_scale_db_spl, quiet)
    result["seconds"] = round(time.perf_counter() - t0, 2)
    if detector is not None:
        result["detector"] = {"slope": round(detector.slope, 6), "offset": round(detector.offset, 6)}
    if not as_json:
        _calibration_note(result["recordings_without_calibration"], baseline)
        r = result["range_10_50"]

        def pct(v: float | None) -> str:
            return "n/a" if v is None else f"{100 * v:.2f} %"

        err_console.print(
            f"{name}: {result['windows']} windows; recall {pct(result['recall'])}, false alarms "
            f"{pct(result['false_alarm_rate'])}; 10–50 m: recall {pct(r['recall'])}, angle error median "
            f"{r['angle_median_deg']}° mean {r['angle_mean_deg']}°",
            highlight=False,
        )
    print_json_line(result)


@audio_app.command()
@friendly_errors
def train(
    data: Annotated[
        list[Path],
        typer.Option("--data", help="Training recordings: a folder of recording folders (repeatable)."),
    ],
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="ONNX model to write (default: the shipped model).")
    ] = None,
    test: Annotated[
        Path | None,
        typer.Option(help="Held-out recordings to evaluate the trained model on (JSON line last)."),
    ] = None,
    epochs: Annotated[int, typer.Option(min=1, help="Most epochs (training stops at the floor lr).")] = 30,
    width: Annotated[int, typer.Option(min=4, help="Channel width of the network.")] = 24,
    streams: Annotated[
        str, typer.Option(help="Comma-separated input streams: wave, spec, gcc, level.")
    ] = "wave,spec,gcc,level",
    lr: Annotated[float, typer.Option(min=0.0, help="Adam learning rate.")] = 1e-3,
    batch_size: Annotated[int, typer.Option(min=2, help="Windows per batch.")] = 64,
    max_false_alarm: Annotated[
        float | None,
        typer.Option(
            min=0.0,
            max=1.0,
            help="Raise the stored decision threshold (from 0.5) until the validation false-alarm rate "
            "per window is at most this (default: keep 0.5).",
        ),
    ] = None,
    patience: Annotated[
        int, typer.Option(min=0, help="Epochs without improvement before the learning rate drops (×0.3).")
    ] = 2,
    distance_loss: Annotated[
        str,
        typer.Option(
            help="Distance loss: squared (SPEC §3, squared error in m²) or log (squared error of ln "
            "distance: the level cue's error is relative, so near sources count as much as far ones)."
        ),
    ] = "squared",
    loss_weights: Annotated[
        str | None,
        typer.Option(
            help="Weights of the siren, direction and distance losses, e.g. 10,10,0.008 "
            "(default: 10,10,0.008 with --distance-loss squared, 10,10,10 with log)."
        ),
    ] = None,
    mirror: Annotated[bool, typer.Option(help="Add every window mirrored left/right.")] = True,
    cache: Annotated[
        Path | None, typer.Option(help="Feature cache (.npz), reused when made from the same data.")
    ] = None,
    threads: Annotated[
        int, typer.Option(min=1, help="torch threads; also feature-extraction processes.")
    ] = 2,
    seed: Annotated[int, typer.Option(help="Seed (weights, batches, validation split).")] = 0,
    gain_augment: Annotated[
        float,
        typer.Option(
            min=0.0,
            max=40.0,
            help="Shift every training window by a random gain of up to ± this many dB, as if another "
            "array had recorded it, so the network cannot lean on the absolute level (0: off).",
        ),
    ] = 0.0,
) -> None:
    """Train the siren network (SPEC §3): detection, bearing and distance heads, exported to ONNX.

    Windows are auto-labelled from the trajectories; 15 % of the training recordings are held out
    for validation (by recording). Needs torch (`pip install -e ".\\[train]"`).
    """
    import sys

    from makeway.perceive.audio.siren_features import STREAMS, SirenFeatures
    from makeway.perceive.audio.siren_model import DEFAULT_SIREN_MODEL
    from makeway.progress import progress_bar

    try:
        from makeway.train.siren import (
            DISTANCE_LOSSES,
            TrainConfig,
            build_dataset,
            calibrate_threshold,
            config_dict,
            evaluate_net,
            export_onnx,
            split_by_recording,
            train_siren_net,
        )
    except ImportError as exc:
        raise ValueError(
            f"training needs torch ({exc}); install it with: pip install -e '.[train]'"
        ) from None

    folders = [f for d in data for f in recording_folders(d)]
    test_folders = recording_folders(test) if test is not None else []
    target = out if out is not None else DEFAULT_SIREN_MODEL
    names = tuple(x.strip() for x in streams.split(",") if x.strip())
    unknown = sorted(set(names) - set(STREAMS))
    if unknown or not names:
        raise ValueError(
            f"unknown streams {unknown}; --streams takes a comma-separated subset of {', '.join(STREAMS)}"
        )
    if distance_loss not in DISTANCE_LOSSES:
        raise ValueError(f"--distance-loss must be {' or '.join(DISTANCE_LOSSES)}, not {distance_loss!r}")
    weights: list[float] = [10.0, 10.0, 0.008 if distance_loss == "squared" else 10.0]
    if loss_weights is not None:
        try:
            weights = [float(v) for v in loss_weights.split(",")]
        except ValueError:
            weights = []
        if len(weights) != 3 or min(weights) < 0:
            raise ValueError(
                f"--loss-weights takes three non-negative numbers like 10,10,0.008, not {loss_weights!r}"
            )
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
        gain_augment_db=gain_augment,
    )
    feats = SirenFeatures()
    with progress_bar("features", len(folders), unit="rec") as advance:
        dataset = build_dataset(folders, feats, mirror=mirror, cache=cache, workers=threads, advance=advance)
    n_pos = int(dataset.siren.sum())
    err_console.print(
        f"{len(folders)} recordings → {len(dataset)} windows ({n_pos} with a siren ≤ 100 m)"
        + (" incl. mirrored copies" if mirror else ""),
        highlight=False,
    )
    command = " ".join(["makeway audio train", *sys.argv[3:]]) if len(sys.argv) > 3 else "makeway audio train"
    t0 = time.perf_counter()
    with progress_bar("training", cfg.epochs, unit="epoch") as advance:

        def on_epoch(epoch: int, row: dict[str, float]) -> None:
            err_console.print(
                f"epoch {epoch + 1}: lr {row['lr']:.2g} train {row['train_loss']:.3f} "
                f"val {row['val_loss']:.3f} "
                f"(bce {row['val_bce']:.3f}, direction {row['val_direction']:.3f}, "
                + (
                    f"distance rmse {row['val_distance_mse'] ** 0.5:.1f} m) "
                    if distance_loss == "squared"
                    else f"distance rms ln-error {row['val_distance_mse'] ** 0.5:.2f}) "
                )
                + f"{row['seconds']:.0f} s",
                highlight=False,
            )
            advance(1)

        def on_best(best_net: Any, row: dict[str, float]) -> None:
            # a checkpoint of the best network so far, so a long run cut short still leaves a model
            export_onnx(
                best_net,
                target,
                feats.config,
                extra={"training": {**training, "checkpoint_epoch": row["epoch"]}},
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
        err_console.print(
            f"decision threshold {threshold:.4f} (validation false alarms ≤ {max_false_alarm:g})"
        )
    export_onnx(net, target, feats.config, threshold=threshold, extra={"training": training})
    err_console.print(f"model → {target} ({target.stat().st_size / 1e6:.2f} MB)", highlight=False)
    summary: dict[str, Any] = {"model": str(target), **training}
    if test_folders:
        from makeway.eval.siren import evaluate, model_estimator
        from makeway.perceive.audio.siren_model import SirenModel

        with progress_bar("test", len(test_folders), unit="rec") as advance:
            trained = SirenModel(target)
            summary["test"] = evaluate(
                test_folders,
                model_estimator(trained),
                on_recording=advance,
                name="model",
                threshold=trained.threshold,
            )
    print_json_line(summary)


@audio_app.command()
@friendly_errors
def calibrate(
    tone: Annotated[
        Path, typer.Argument(help="A recording of an acoustic calibrator on one capsule (any audio format).")
    ],
    level: Annotated[float, typer.Option(min=60.0, max=160.0, help="The calibrator's level, dB SPL.")] = 94.0,
    frequency: Annotated[float, typer.Option(min=1.0, help="The calibrator's frequency, Hz.")] = 1000.0,
    channel: Annotated[
        int | None,
        typer.Option(min=0, help="The channel of the capsule it sat on (default: the loudest channel)."),
    ] = None,
    write: Annotated[
        list[Path] | None,
        typer.Option(
            "--write",
            help="Set full_scale_db_spl in this array.yaml, or in the array.yaml of this recording "
            "folder (repeatable).",
        ),
    ] = None,
) -> None:
    """Measure the array's calibration (full_scale_db_spl) from a recorded calibrator tone.

    Record a 94 dB SPL / 1 kHz calibrator (or give --level/--frequency) through the array's
    recorder at its working gain; prints one JSON line with full_scale_db_spl, the channel, the
    tone's level (dBFS) in every channel and its tone-to-noise ratio, and with --write stores the
    value where `audio eval` and `audio listen` read it."""
    from makeway.sense.calibration import measure_file, write_full_scale

    found = measure_file(tone, level_db_spl=level, frequency_hz=frequency, channel=channel)
    out = found.to_dict()
    out["file"] = str(tone)
    out["written"] = [str(p) for p in write_full_scale(write or [], found.full_scale_db_spl)]
    err_console.print(
        f"full_scale_db_spl {found.full_scale_db_spl:.2f} (channel {found.channel}: tone at "
        f"{found.tone_dbfs:.2f} dBFS, {found.frequency_hz:.0f} Hz, {found.snr_db:.0f} dB above the rest)",
        highlight=False,
    )
    print_json_line(out)


@audio_app.command("train-approach")
@friendly_errors
def train_approach(
    data: Annotated[
        list[Path],
        typer.Option("--data", help="Training recordings: a folder of recording folders (repeatable)."),
    ],
    val: Annotated[
        list[Path] | None,
        typer.Option("--val", help="Validation recordings, scored after training (repeatable)."),
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="ONNX classifier to write (default: the shipped one)."),
    ] = None,
    model: ModelOption = None,
    localizer: LocalizerOption = None,
    ranger: RangerOption = None,
    seed: Annotated[int, typer.Option(help="Seed of the trees' row subsampling.")] = 0,
) -> None:
    """Train the approaching/receding classifier of `audio listen` on labelled recordings.

    Every recording runs as `audio listen` runs it (the siren networks, the listener's decision, the
    distance trend and the level/Doppler cues); the windows where a siren is reported and moves by
    at least 1 m/s relative to the car are the training rows, with the sign of the labelled range
    rate as the target. Gradient-boosted trees, written as ONNX. With --val, prints the validation
    scores of the new classifier and of the level/Doppler rule (JSON line last)."""
    from makeway.eval.siren_approach import approach_scores
    from makeway.perceive.audio.motion import DEFAULT_APPROACH_MODEL, TrendApproach
    from makeway.progress import progress_bar
    from makeway.train.approach import XGB_PARAMS, approach_dataset, export_approach_onnx, fit_approach

    target = out if out is not None else DEFAULT_APPROACH_MODEL
    folders = [f for d in data for f in recording_folders(d)]
    val_folders = [f for d in (val or []) for f in recording_folders(d)]
    net = _siren_networks(model, localizer, ranger, None)
    with progress_bar("training windows", len(folders), unit="rec") as advance:
        train_set = approach_dataset(folders, net, advance=advance)
    rows = train_set["scored"]
    clf = fit_approach(train_set["features"][rows], train_set["approaching"][rows], seed=seed)
    training = {
        "recordings": len(folders),
        "windows": int(rows.sum()),
        "approaching_share": round(float(train_set["approaching"][rows].mean()), 4),
        "params": XGB_PARAMS,
        "seed": seed,
        "siren_model": repr(net),
    }
    export_approach_onnx(clf, target, TrendApproach(model=None).feature_names, extra={"training": training})
    result: dict[str, Any] = {"model": str(target), "training": training}
    if val_folders:
        trained = TrendApproach(target)
        with progress_bar("validation", len(val_folders), unit="rec") as advance:
            val_set = approach_dataset(val_folders, net, advance=advance)
        result["validation"] = approach_scores(val_set, trained)
    err_console.print(f"approach classifier on {int(rows.sum())} windows → {target}", highlight=False)
    print_json_line(result)


@audio_app.command()
@friendly_errors
def listen(
    path: Annotated[Path, typer.Argument(help="A recording folder.")],
    model: ModelOption = None,
    localizer: LocalizerOption = None,
    ranger: RangerOption = None,
    baseline: Annotated[
        str | None,
        typer.Option(help="Classical bearing + band-energy detector instead: gccphat, srp or normmusic."),
    ] = None,
    plot: Annotated[
        Path | None, typer.Option("--plot", help="Write a spectrogram + polar bearing plot (PNG).")
    ] = None,
    jsonl: Annotated[
        Path | None,
        typer.Option("--jsonl", help="Write the messages to this JSONL file and print a summary instead."),
    ] = None,
    window: Annotated[float, typer.Option(min=0.05, help="Window length (s).")] = 0.5,
    hop: Annotated[float, typer.Option(min=0.01, help="Hop between windows (s).")] = 0.17,
    smooth: Annotated[
        int,
        typer.Option(
            min=1,
            help="Decide on the mean of the last K windows (1: each window alone).",
        ),
    ] = LISTEN_SMOOTH,
    average: AverageOption = SMOOTH_AVERAGE,
    full_scale_db_spl: FullScaleOption = None,
    approach: Annotated[
        str | None,
        typer.Option(
            help="How approaching/receding is told: trend (the trend of the network's distance with the "
            "level and Doppler cues, through the shipped classifier; the default with the network) or "
            "level (level slope and Doppler only; the default, and the only choice, with --baseline).",
        ),
    ] = None,
) -> None:
    """Slide over a recording: one JSON line per hop (is_siren, probability, smoothed_probability,
    one entry per detected siren with bearing, distance — null for the baselines and for further
    sirens — and approaching/receding with its probability).

    is_siren is decided on the mean logit of the last --smooth windows (default 8, 1.36 s of audio:
    more recall at fewer false alarms than one window alone; --average probability averages the
    probabilities instead)."""
    from makeway.perceive.audio.stream import listen as listen_stream
    from makeway.perceive.audio.stream import listen_windows
    from makeway.progress import progress_bar
    from makeway.sense.recording import assume_calibration, read_recording
    from makeway.viz.listen_plot import plot_listen

    _check_baseline(baseline, model, localizer, ranger)
    if not path.exists():
        raise InputError(path, "no such folder")
    for target in (t for t in (plot, jsonl) if t is not None):
        check_writable(target, folder=False)
    net = _siren_networks(model, localizer, ranger, 1) if baseline is None else None
    estimator = _approach_estimator(approach, net)
    rec = assume_calibration(read_recording(path), full_scale_db_spl)
    _calibration_note(int(rec.full_scale_db_spl is None), baseline)
    t0 = time.perf_counter()
    messages = []
    method = baseline or "gccphat"
    hops = len(listen_windows(rec, window, hop))  # raises when shorter than one window
    # with --jsonl the messages go to a file: a progress bar on stderr instead (stdout stays JSON)
    with progress_bar("listening", hops, enabled=jsonl is not None, unit="hop") as advance:
        for msg in listen_stream(
            rec,
            window_s=window,
            hop_s=hop,
            method=method,
            model=net,
            smooth=smooth,
            average=average,
            approach=estimator,
        ):
            messages.append(msg)
            if jsonl is None:
                print_json_line(msg)
            advance(1)
    wall = time.perf_counter() - t0
    if jsonl is not None:
        from makeway.atomic import write_text_atomic

        write_text_atomic(jsonl, "".join(json.dumps(m, separators=(",", ":")) + "\n" for m in messages))
    if plot is not None:
        plot_listen(messages, rec, plot, window_s=window)
    if jsonl is not None:
        n_siren = sum(1 for m in messages if m["is_siren"])
        print_json_line(
            {
                "recording": str(path),
                "messages": len(messages),
                "siren_messages": n_siren,
                "ms_per_hop": round(1000.0 * wall / max(len(messages), 1), 2),
                "jsonl": str(jsonl),
                "plot": None if plot is None else str(plot),
            }
        )


if __name__ == "__main__":
    audio_app()
