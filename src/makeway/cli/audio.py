"""``makeway audio …``: simulated siren recordings and their labels (issue 4).

Registered by :mod:`makeway.cli.main` as ``app.add_typer(audio_app, name="audio")``; also runs on its
own (``python -m makeway.cli.audio``). Bad input ends with one red ``error:`` line naming the file,
exit code 2, and no half-written output.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated

import typer

from makeway.cli.common import err_console, friendly_errors, new_app, print_json_line
from makeway.perceive.audio.windows import LISTEN_SMOOTH, SMOOTH_AVERAGE
from makeway.sense.recording import FULL_SCALE_RANGE_DB, REFERENCE_FULL_SCALE_DB_SPL

audio_app = new_app(
    "audio",
    "Sirens heard by the roof microphone array.\n\n"
    "Simulate and label recordings, train and score the siren networks, calibrate the array, listen.",
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
    siren_level: Annotated[
        str,
        typer.Option(
            help="Range the emitted siren level is drawn from, LOW,HIGH in dB SPL at 1 m "
            "(default 110,120; real sirens span about 110 to 135, e.g. 105,140 for training).",
        ),
    ] = "110,120",
    far_start: Annotated[
        bool,
        typer.Option(
            help="Let the emergency vehicles start and pass farther away, out to about 300 m "
            "(default: mostly within 60 m, at most about 180 m).",
        ),
    ] = False,
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
    """Simulate recordings of the roof microphone array.

    The reference array: 8 capsules on the car roof, 48 kHz, in four traffic scenarios (an EV crossing,
    driving the same way, the opposite way, or coming from behind). Each recording is a folder:
    audio.flac, array.yaml, ego.csv, source_<k>.csv, meta.yaml. Uses the real siren clips/tones and
    street recordings from ../shared/data when present, the procedural siren synthesizer and generated
    noise otherwise.
    """
    from makeway.apps.audio import simulate_recordings
    from makeway.sim.audio_scenarios import SIREN_LEVEL_BOUNDS_DB

    street_dba = _parse_range(street_level, "--street-level", (0.0, 120.0), "dB(A) like 60,75")
    level_db = _parse_range(siren_level, "--siren-level", SIREN_LEVEL_BOUNDS_DB, "dB SPL like 110,135")
    pitch = None
    if siren_pitch:
        pitch = _parse_range(siren_pitch, "--siren-pitch", (0.25, 4.0), "factors like 0.7,1.25")
    summary = simulate_recordings(
        out,
        n,
        scenarios=scenario,
        seed=seed,
        start=start,
        duration_s=duration,
        siren=siren,
        noise=noise,
        no_siren_fraction=no_siren_fraction,
        two_siren_fraction=two_siren_fraction,
        split=split,
        distractors=distractors,
        street_dba=street_dba,
        siren_pitch=pitch,
        siren_level_db=level_db,
        far_start=far_start,
        full_scale_db_spl=full_scale_db_spl,
        progress=not quiet,
    )
    if as_json:
        print_json_line(summary)
    else:
        err_console.print(
            f"wrote {summary['recordings']} recordings of {duration:g} s to {out} "
            f"in {summary['seconds']:.1f} s",
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
    """Label recordings from their trajectories.

    Writes one JSON line per window.
    Each line: recording, window, start_sample, n_samples, t_end, siren, and per source in range its
    theta (vehicle frame, 0 ahead, positive left), distance and range rate at the window end.
    """
    from makeway.apps.audio import label_recordings

    summary = label_recordings(folder, out, window_s=window, hop_s=hop, max_distance_m=max_distance)
    if as_json:
        print_json_line(summary)
    else:
        err_console.print(
            f"labelled {summary['recordings']} recording(s): {summary['windows']} windows, "
            f"{summary['positive']} with a siren within {max_distance:g} m, {summary['dropped']} dropped "
            f"(sirens only farther) → {summary['out']}",
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


def _log(line: str) -> None:
    """One progress line on stderr."""
    err_console.print(line, highlight=False)


def _calibration_note(n_without: int, baseline: str | None) -> None:
    """Say on stderr when recordings had no calibration and a network read their levels."""
    if n_without and baseline is None:
        err_console.print(
            f"note: {n_without} recording(s) state no full_scale_db_spl in array.yaml; taken at the "
            f"networks' {REFERENCE_FULL_SCALE_DB_SPL:g} dB SPL full scale (give --full-scale-db-spl "
            "if the array differs: 6 dB off moves the distances by a third or more)",
            highlight=False,
        )


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
            "'audio listen --smooth K' does live. The default is listen's own, so the score is that "
            "of the decision a user gets; --smooth 1 scores each window alone.",
        ),
    ] = LISTEN_SMOOTH,
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
    """Score siren detection and localization.

    Scores labelled recordings; prints one JSON line last.
    Runs the shipped siren network (or --model), or with --baseline a classical method. Keys:
    recall, false_alarm_rate (per window), accuracy, angle_median_deg, angle_mean_deg (wrapped),
    distance_median_m, distance_mean_m (null for the baselines), the same inside "range_10_50", and
    "by_distance" (10 m bins). With --approach, "approach": for the windows where the listener
    reports a siren moving by at least 1 m/s, the share called right (correct; undecided counts as
    wrong), decided, the two errors apart, and the same per scenario and per band of speed.
    """
    from makeway.apps.audio import evaluate_recordings

    result = evaluate_recordings(
        data,
        baseline=baseline,
        fit=fit,
        model=model,
        localizer=localizer,
        ranger=ranger,
        threads=threads,
        smooth=smooth,
        average=average,
        full_scale_db_spl=full_scale_db_spl,
        approach=approach,
        progress=not quiet,
    )
    name = result["method"]
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
            help="Distance loss: squared (squared error in m²) or log (squared error of ln "
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
    distance_sigma: Annotated[
        bool,
        typer.Option(
            help="Also learn how uncertain each distance is (needs --distance-loss log): the model "
            "then gives a spread with every distance.",
        ),
    ] = False,
) -> None:
    """Train the siren network and export it to ONNX.

    The network has detection, bearing and distance heads.
    Windows are auto-labelled from the trajectories; 15 % of the training recordings are held out
    for validation (by recording). Needs torch (pip install -e '.[train]').
    """
    try:
        from makeway.train.siren import train_siren_networks
    except ImportError as exc:
        raise ValueError(
            f"training needs torch ({exc}); install it with: pip install -e '.[train]'"
        ) from None

    weights = None
    if loss_weights is not None:
        try:
            weights = [float(v) for v in loss_weights.split(",")]
        except ValueError:
            weights = []
        if len(weights) != 3 or min(weights) < 0:
            raise ValueError(
                f"--loss-weights takes three non-negative numbers like 10,10,0.008, not {loss_weights!r}"
            )
    summary = train_siren_networks(
        data,
        out,
        test=test,
        streams=[x.strip() for x in streams.split(",") if x.strip()],
        distance_loss=distance_loss,
        loss_weights=weights,
        width=width,
        epochs=epochs,
        lr=lr,
        batch_size=batch_size,
        patience=patience,
        max_false_alarm=max_false_alarm,
        mirror=mirror,
        cache=cache,
        threads=threads,
        seed=seed,
        gain_augment_db=gain_augment,
        distance_sigma=distance_sigma,
        command=" ".join(["makeway audio train", *sys.argv[3:]])
        if len(sys.argv) > 3
        else "makeway audio train",
        log=_log,
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
    """Measure the array's calibration from a calibrator tone.

    Record a 94 dB SPL / 1 kHz calibrator (or give --level/--frequency) through the array's
    recorder at its working gain; prints one JSON line with full_scale_db_spl, the channel, the
    tone's level (dBFS) in every channel and its tone-to-noise ratio, and with --write stores the
    value where `audio eval` and `audio listen` read it."""
    from makeway.apps.audio import calibrate_from_tone

    found, out = calibrate_from_tone(
        tone, level_db_spl=level, frequency_hz=frequency, channel=channel, write=write or []
    )
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
        typer.Option(
            "--out", "-o", help="ONNX classifier to write (default: the shipped one for these rangers)."
        ),
    ] = None,
    model: ModelOption = None,
    localizer: LocalizerOption = None,
    ranger: RangerOption = None,
    seed: Annotated[int, typer.Option(help="Seed of the trees' row subsampling.")] = 0,
    depth: Annotated[
        int, typer.Option(min=1, help="Depth of each tree (4 for the shipped rangers, 6 for the wide ones).")
    ] = 4,
) -> None:
    """Train the approaching/receding classifier.

    On labelled recordings: the classifier 'audio listen' uses.
    Every recording runs as `audio listen` runs it (the siren networks, the listener's decision, the
    distance trend and the level/Doppler cues); the windows where a siren is reported and moves by
    at least 1 m/s relative to the car are the training rows, with the sign of the labelled range
    rate as the target. Gradient-boosted trees, written as ONNX. Each set of rangers has its own
    classifier: without --out, the one shipped for the rangers used is written. With --val, prints
    the validation scores of the new classifier and of the level/Doppler rule (JSON line last)."""
    from makeway.apps.audio import siren_networks
    from makeway.train.approach import train_approach_classifier

    result = train_approach_classifier(
        data, out, val=val or [], siren=siren_networks(model, localizer, ranger), seed=seed, max_depth=depth
    )
    err_console.print(
        f"approach classifier on {result['training']['windows']} windows → {result['model']}", highlight=False
    )
    print_json_line(result)


@audio_app.command("train-far")
@friendly_errors
def train_far(
    data: Annotated[
        list[Path],
        typer.Option(
            "--data",
            help="Training recordings with sirens out to 300 m and beyond (`audio simulate --far-start`): "
            "a folder of recording folders (repeatable).",
        ),
    ],
    out: Annotated[
        Path | None,
        typer.Option("--out", "-o", help="ONNX far ranger to write (default: the shipped one)."),
    ] = None,
    model: ModelOption = None,
    localizer: LocalizerOption = None,
    ranger: RangerOption = None,
    far_boundary: Annotated[
        float,
        typer.Option(
            min=10.0, max=350.0, help="The far/near boundary (m): far_probability is P(distance > this)."
        ),
    ] = 100.0,
    epochs: Annotated[int, typer.Option(min=1, help="Most epochs (the best on validation is kept).")] = 25,
    width: Annotated[int, typer.Option(min=4, help="Width of the two hidden layers.")] = 64,
    lr: Annotated[float, typer.Option(min=0.0, help="Adam learning rate.")] = 1e-3,
    far_weight: Annotated[
        float, typer.Option(min=0.0, help="Weight of the far/near loss beside the distance likelihood.")
    ] = 1.0,
    cache: Annotated[
        Path | None,
        typer.Option(help="Feature cache (.npz), reused when made from the same data and networks."),
    ] = None,
    threads: Annotated[int, typer.Option(min=1, help="torch and ONNX Runtime threads.")] = 1,
    seed: Annotated[int, typer.Option(help="Seed (weights, batches, early-stopping split).")] = 0,
) -> None:
    """Train the far ranger for sirens beyond 50 m.

    It gives a distance, its uncertainty and a far/near call. Every recording runs as
    `audio listen --far-ranger` runs it (the siren networks on every window, the spectral shape,
    level and bearing trends over the last 3 s); windows whose nearest siren lies within 400 m are
    the training rows, labelled from the trajectories. A small network learns ln distance with its
    σ (Gaussian likelihood) and P(distance > --far-boundary); 15 % of the recordings stop the
    training early. Written as ONNX (JSON line last). Needs torch."""
    try:
        from makeway.train.far_range import train_far_ranger
    except ImportError as exc:
        raise ValueError(
            f"training needs torch ({exc}); install it with: pip install -e '.[train]'"
        ) from None
    from makeway.apps.audio import siren_networks

    summary = train_far_ranger(
        data,
        out,
        siren=siren_networks(model, localizer, ranger, threads),
        far_boundary_m=far_boundary,
        width=width,
        epochs=epochs,
        lr=lr,
        far_weight=far_weight,
        seed=seed,
        threads=threads,
        cache=cache,
        command=" ".join(["makeway audio train-far", *sys.argv[3:]]),
        log=_log,
    )
    print_json_line(summary)


@audio_app.command()
@friendly_errors
def listen(
    path: Annotated[
        Path,
        typer.Argument(help="A recording folder, or a robotics log (MCAP file or ROS 2 bag folder)."),
    ],
    model: ModelOption = None,
    localizer: LocalizerOption = None,
    ranger: RangerOption = None,
    baseline: Annotated[
        str | None,
        typer.Option(help="Classical bearing + band-energy detector instead: gccphat, srp or normmusic."),
    ] = None,
    audio_topic: Annotated[
        str | None,
        typer.Option(
            help="Audio topic when PATH is a log: interleaved PCM blocks (Foxglove RawAudio or "
            "makeway_msgs/RawAudio) with the array on <topic>/array. Default: the only one."
        ),
    ] = None,
    pose_topic: Annotated[
        str | None,
        typer.Option(
            help="Ego pose topic when PATH is a log (Odometry, PoseStamped, Foxglove PoseInFrame). "
            "Default: the log's only pose topic, if it has one."
        ),
    ] = None,
    mcap: Annotated[
        Path | None,
        typer.Option(
            help="Also write the hops to an MCAP file that opens in Foxglove: the detections, an "
            "arrow per heard siren, the microphones and the vehicle pose."
        ),
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
    realtime: Annotated[
        bool,
        typer.Option(
            "--realtime",
            help="Play the recording as a live array: a window every hop; when the listener falls "
            "behind, the oldest waiting window is dropped, never the newest.",
        ),
    ] = False,
    far_ranger: Annotated[
        Path | None,
        typer.Option(
            help="Also run this far ranger (an ONNX file from `makeway audio train-far`; the shipped one is "
            "src/makeway/models/siren_far_ranger.onnx): it places sirens beyond 50 m, adds far_probability "
            "(P(distance > 100 m)) and distance_sigma to the nearest siren, and drops the approaching call "
            "of a far one. Off by default.",
        ),
    ] = None,
) -> None:
    """Listen to a recording for sirens, hop by hop.

    Prints one JSON line per hop (is_siren, probability, smoothed_probability,
    one entry per detected siren with bearing, distance — null for the baselines and for further
    sirens — and approaching/receding with its probability).

    is_siren is decided on the mean logit of the last --smooth windows (default 8, 1.36 s of audio:
    more recall at fewer false alarms than one window alone; --average probability averages the
    probabilities instead).

    PATH may be an MCAP file or a ROS 2 bag folder (--audio-topic, --pose-topic); --mcap writes
    the run for Foxglove."""
    from makeway.apps.audio import listen_recording

    run = listen_recording(
        path,
        model=model,
        localizer=localizer,
        ranger=ranger,
        baseline=baseline,
        window_s=window,
        hop_s=hop,
        smooth=smooth,
        average=average,
        full_scale_db_spl=full_scale_db_spl,
        approach=approach,
        plot=plot,
        jsonl=jsonl,
        audio_topic=audio_topic,
        pose_topic=pose_topic,
        mcap=mcap,
        # with --jsonl the messages go to a file: a progress bar on stderr instead (stdout stays JSON)
        on_message=print_json_line if jsonl is None else None,
        progress=jsonl is not None,
        realtime=realtime,
        far_ranger=far_ranger,
    )
    _calibration_note(int(run.uncalibrated), baseline)
    if jsonl is not None:
        print_json_line(run.summary)


if __name__ == "__main__":
    audio_app()
