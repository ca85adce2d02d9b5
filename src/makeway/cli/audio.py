"""``makeway audio …``: simulated siren recordings and their labels (issue 4).

Registered by :mod:`makeway.cli.main` as ``app.add_typer(audio_app, name="audio")``; also runs on its
own (``python -m makeway.cli.audio``). Bad input ends with one red ``error:`` line naming the file,
exit code 2, and no half-written output.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Annotated

import typer

from makeway.cli.common import err_console, friendly_errors, new_app, print_json_line
from makeway.errors import InputError

audio_app = new_app(
    "audio", "Siren recordings from the car-roof microphone array: simulate, label, evaluate."
)


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
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as one JSON line.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Simulate recordings of the reference 8-capsule roof array (48 kHz) in seed 002's scenarios.

    Each recording is a folder: audio.flac, array.yaml, ego.csv, source_<k>.csv, meta.yaml. Uses the
    real siren clips/tones and street recordings from ../shared/data when present, the procedural
    siren synthesizer and generated noise otherwise.
    """
    from makeway.sim.audio_scenarios import AUDIO_SCENARIOS, generate_recordings

    scenarios = tuple(scenario) if scenario else AUDIO_SCENARIOS
    if siren not in ("auto", "synth", "real"):
        raise ValueError(f"--siren must be auto, synth or real, not {siren!r}")
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
        progress=not quiet,
    )
    wall = time.perf_counter() - t0
    summary = {
        "out": str(out),
        "recordings": len(paths),
        "duration_s": duration,
        "seconds": round(wall, 2),
        "seconds_per_audio_second": round(wall / max(len(paths) * duration, 1e-9), 3),
    }
    if as_json:
        print_json_line(summary)
    else:
        err_console.print(
            f"wrote {len(paths)} recordings of {duration:g} s to {out} in {wall:.1f} s",
            highlight=False,
        )


def _recording_folders(folder: Path) -> list[Path]:
    if not folder.exists():
        raise InputError(folder, "no such folder")
    if (folder / "audio.flac").exists() or (folder / "array.yaml").exists():
        return [folder]
    subs = sorted(p for p in folder.iterdir() if p.is_dir() and (p / "array.yaml").exists())
    if not subs:
        raise InputError(folder, "holds no recording (a folder with audio.flac, array.yaml, ego.csv)")
    return subs


@audio_app.command()
@friendly_errors
def label(
    folder: Annotated[Path, typer.Argument(help="A recording folder, or a folder of recording folders.")],
    out: Annotated[
        Path | None, typer.Option("--out", "-o", help="JSONL output [default: FOLDER/labels.jsonl].")
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
    from makeway.perceive.audio.labels import label_recording
    from makeway.sense.recording import read_recording

    recs = _recording_folders(folder)
    lines: list[str] = []
    n_windows = n_pos = 0
    for path in recs:  # read everything first: a bad recording leaves no output behind
        labels = label_recording(read_recording(path), window, hop, max_distance)
        for row in labels.records(path.name):
            lines.append(json.dumps(row, separators=(",", ":")))
        n_windows += len(labels)
        n_pos += int(labels.siren.sum())
    target = out if out is not None else folder / "labels.jsonl"
    write_text_atomic(target, "\n".join(lines) + ("\n" if lines else ""))
    summary = {"recordings": len(recs), "windows": n_windows, "positive": n_pos, "out": str(target)}
    if as_json:
        print_json_line(summary)
    else:
        err_console.print(
            f"labelled {len(recs)} recording(s): {n_windows} windows, {n_pos} with a siren within "
            f"{max_distance:g} m → {target}",
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
            "[default: the shipped constants]."
        ),
    ] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print only the JSON line.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar.")] = False,
) -> None:
    """Evaluate siren detection and localization on labelled recordings (one JSON line, last).

    Keys: recall, false_alarm_rate (per window), accuracy, angle_median_deg, angle_mean_deg (wrapped),
    distance_median_m, distance_mean_m (null for the baselines), the same inside "range_10_50", and
    "by_distance" (10 m bins).
    """
    from makeway.perceive.audio.doa import DOA_METHODS

    choices = "|".join(DOA_METHODS)
    if baseline is None:
        raise ValueError(f"no trained siren model yet; use --baseline {choices}")
    if baseline not in DOA_METHODS:
        raise ValueError(f"--baseline must be one of {choices}, not {baseline!r}")
    from makeway.perceive.audio.doa import SirenEnergyDetector
    from makeway.perceive.audio.evaluate import evaluate
    from makeway.perceive.audio.features import window_batch
    from makeway.perceive.audio.labels import label_recording
    from makeway.progress import progress_bar
    from makeway.sense.recording import read_recording

    recs = _recording_folders(data)
    detector = None
    if fit is not None:
        import numpy as np

        detector = SirenEnergyDetector()
        scores, ys = [], []
        for path in _recording_folders(fit):
            rec = read_recording(path)
            labels = label_recording(rec)
            detector.sample_rate = rec.sample_rate
            scores.append(detector.scores(window_batch(rec, labels)))
            ys.append(labels.siren)
        detector.fit_scores(np.concatenate(scores), np.concatenate(ys))
    t0 = time.perf_counter()
    with progress_bar(f"eval {baseline}", len(recs), enabled=not quiet, unit="rec") as advance:
        result = evaluate(recs, baseline, detector=detector, on_recording=advance)
    result["data"] = str(data)
    result["seconds"] = round(time.perf_counter() - t0, 2)
    if detector is not None:
        result["detector"] = {"slope": round(detector.slope, 6), "offset": round(detector.offset, 6)}
    if not as_json:
        r = result["range_10_50"]

        def pct(v: float | None) -> str:
            return "n/a" if v is None else f"{100 * v:.2f} %"

        err_console.print(
            f"{baseline}: {result['windows']} windows; recall {pct(result['recall'])}, false alarms "
            f"{pct(result['false_alarm_rate'])}; 10–50 m: recall {pct(r['recall'])}, angle error median "
            f"{r['angle_median_deg']}° mean {r['angle_mean_deg']}°",
            highlight=False,
        )
    print_json_line(result)


@audio_app.command()
@friendly_errors
def listen(
    path: Annotated[Path, typer.Argument(help="A recording folder.")],
    method: Annotated[str, typer.Option(help="Bearing method: gccphat, srp or normmusic.")] = "gccphat",
    plot: Annotated[
        Path | None, typer.Option("--plot", help="Write a spectrogram + polar bearing plot (PNG).")
    ] = None,
    jsonl: Annotated[
        Path | None,
        typer.Option("--jsonl", help="Write the messages to this JSONL file and print a summary instead."),
    ] = None,
    window: Annotated[float, typer.Option(min=0.05, help="Window length (s).")] = 0.5,
    hop: Annotated[float, typer.Option(min=0.01, help="Hop between windows (s).")] = 0.17,
) -> None:
    """Slide over a recording: one JSON line per hop (is_siren, probability, sources with bearing,
    distance — null without a trained model — and approaching/receding)."""
    from makeway.perceive.audio.doa import DOA_METHODS
    from makeway.perceive.audio.stream import listen as listen_stream
    from makeway.perceive.audio.stream import plot_listen
    from makeway.sense.recording import read_recording

    if method not in DOA_METHODS:
        raise ValueError(f"--method must be one of {'|'.join(DOA_METHODS)}, not {method!r}")
    if not path.exists():
        raise InputError(path, "no such folder")
    rec = read_recording(path)
    t0 = time.perf_counter()
    messages = []
    for msg in listen_stream(rec, window_s=window, hop_s=hop, method=method):
        messages.append(msg)
        if jsonl is None:
            print_json_line(msg)
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
