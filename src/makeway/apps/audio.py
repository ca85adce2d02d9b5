"""``makeway audio …``: simulated siren recordings, their labels, and the siren stack run over them.

Each function here is one command's work: it checks its outputs can be written and its options make
sense before the long part starts, and returns what the command prints.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from makeway.atomic import check_writable, write_text_atomic
from makeway.errors import InputError
from makeway.perceive.audio.windows import LISTEN_SMOOTH, SMOOTH_AVERAGE
from makeway.progress import progress_bar
from makeway.sense.recording import REFERENCE_FULL_SCALE_DB_SPL, recording_folders

if TYPE_CHECKING:
    from makeway.perceive.audio.doa import SirenEnergyDetector
    from makeway.perceive.audio.siren_model import SirenModel
    from makeway.sense.calibration import ToneCalibration

__all__ = [
    "ListenRun",
    "approach_estimator",
    "calibrate_from_tone",
    "check_baseline",
    "evaluate_recordings",
    "fit_energy_detector",
    "label_recordings",
    "listen_recording",
    "simulate_recordings",
    "siren_networks",
]


def simulate_recordings(
    out: str | Path,
    n: int,
    *,
    scenarios: Sequence[str] | None = None,
    seed: int = 0,
    start: int = 0,
    duration_s: float = 10.0,
    siren: str = "auto",
    noise: str = "auto",
    no_siren_fraction: float = 0.25,
    two_siren_fraction: float = 0.1,
    split: str = "all",
    distractors: bool = True,
    street_dba: tuple[float, float] = (60.0, 75.0),
    siren_pitch: tuple[float, float] | None = None,
    siren_level_db: tuple[float, float] = (110.0, 120.0),
    far_start: bool = False,
    full_scale_db_spl: float = REFERENCE_FULL_SCALE_DB_SPL,
    progress: bool = True,
) -> dict[str, Any]:
    """Write ``n`` simulated recordings of the reference roof array into ``out`` (``rec_<start>`` …),
    drawn from ``scenarios`` (default: all of :data:`~makeway.sim.audio_scenarios.AUDIO_SCENARIOS`)
    with the real ingredients of source ``split`` where the shared data is present
    (:func:`~makeway.sim.audio_scenarios.generate_recordings` explains every option; ``street_dba`` is
    the street noise's A-weighted level range at the array in dB(A), ``siren_pitch`` a range of pitch
    factors, ``siren_level_db`` the range the emitted siren level is drawn from in dB SPL at 1 m,
    ``far_start`` EVs that start and pass out to ~300 m away,
    ``full_scale_db_spl`` the dB SPL a digital RMS of 1.0 stands for).

    Returns a summary: ``out``, ``split``, ``recordings``, ``duration_s``, ``seconds`` (wall) and
    ``seconds_per_audio_second``, ``full_scale_db_spl``.

    Raises:
        InputError: ``out`` cannot be written (checked first).
        ValueError: ``siren`` is not auto, synth or real, or ``siren_level_db`` is out of range.
    """
    from makeway.sim.audio_scenarios import (
        AUDIO_SCENARIOS,
        check_siren_level,
        generate_recordings,
        source_pools,
    )

    check_writable(out, folder=True)
    siren_level_db = check_siren_level(siren_level_db)
    if siren not in ("auto", "synth", "real"):
        raise ValueError(f"--siren must be auto, synth or real, not {siren!r}")
    siren_pool, noise_pool = source_pools(split)
    t0 = time.perf_counter()
    paths = generate_recordings(
        out,
        n,
        scenarios=tuple(scenarios) if scenarios else AUDIO_SCENARIOS,
        duration_s=duration_s,
        seed=seed,
        siren=siren,
        noise=noise,
        no_siren_fraction=no_siren_fraction,
        two_siren_fraction=two_siren_fraction,
        siren_pool=siren_pool if siren != "synth" else [],
        noise_pool=noise_pool if noise != "generated" else [],
        progress=progress,
        distractors=distractors,
        street_dba=street_dba,
        siren_pitch=siren_pitch,
        siren_level_db=siren_level_db,
        far_start=far_start,
        start_index=start,
        full_scale_db_spl=full_scale_db_spl,
    )
    wall = time.perf_counter() - t0
    return {
        "out": str(out),
        "split": split,
        "recordings": len(paths),
        "duration_s": duration_s,
        "seconds": round(wall, 2),
        "seconds_per_audio_second": round(wall / max(len(paths) * duration_s, 1e-9), 3),
        "full_scale_db_spl": full_scale_db_spl,
        "siren_level_db": list(siren_level_db),
        "far_start": far_start,
    }


def label_recordings(
    folder: str | Path,
    out: str | Path | None = None,
    *,
    window_s: float = 0.5,
    hop_s: float = 0.17,
    max_distance_m: float = 100.0,
) -> dict[str, Any]:
    """Auto-label the recordings under ``folder`` from their logged trajectories
    (:func:`~makeway.eval.siren_labels.label_recording`) and write one JSON line per window to ``out``
    (default ``FOLDER/labels.jsonl``); sources farther than ``max_distance_m`` are dropped. Every
    recording is read before anything is written.

    Returns ``recordings``, ``windows``, ``positive`` (windows with a siren in range), ``dropped``
    (windows whose sirens are all farther) and ``out``.

    Raises:
        InputError: a recording cannot be read (nothing is written).
    """
    from makeway.eval.siren_labels import label_recording
    from makeway.sense.recording import read_recording

    recs = recording_folders(folder)
    lines: list[str] = []
    n_windows = n_pos = n_dropped = 0
    for path in recs:  # read everything first: a bad recording leaves no output behind
        labels = label_recording(read_recording(path), window_s, hop_s, max_distance_m)
        for row in labels.records(path.name):
            lines.append(json.dumps(row, separators=(",", ":")))
        n_windows += len(labels)
        n_pos += int(labels.siren.sum())
        n_dropped += int(labels.dropped.sum())
    target = Path(out) if out is not None else Path(folder) / "labels.jsonl"
    write_text_atomic(target, "\n".join(lines) + ("\n" if lines else ""))
    return {
        "recordings": len(recs),
        "windows": n_windows,
        "positive": n_pos,
        "dropped": n_dropped,
        "out": str(target),
    }


def siren_networks(
    model: str | Path | None = None,
    localizer: str | Path | None = None,
    ranger: Sequence[str | Path] | None = None,
    threads: int | None = None,
) -> SirenModel:
    """The siren network with its localizer and rangers: the shipped ones unless named (a named
    ``model`` alone runs without the shipped localizer and rangers, see
    :class:`~makeway.perceive.audio.siren_model.SirenModel`).

    Raises:
        InputError: a model file is missing or not a siren model.
    """
    from makeway.perceive.audio.siren_model import SirenModel

    return SirenModel(
        model,
        threads=threads,
        localizer=localizer if localizer is not None else True,
        ranger=list(ranger) if ranger else True,
    )


def check_baseline(baseline: str | None, *networks: object) -> None:
    """``baseline`` names a classical bearing method (:data:`~makeway.perceive.audio.doa.DOA_METHODS`)
    and comes without any of the siren networks in ``networks``.

    Raises:
        ValueError: an unknown method (lists the known ones), or a method and a network both given.
    """
    from makeway.perceive.audio.doa import DOA_METHODS

    if baseline is None:
        return
    if baseline not in DOA_METHODS:
        raise ValueError(f"--baseline must be one of {'|'.join(DOA_METHODS)}, not {baseline!r}")
    if any(n for n in networks):
        raise ValueError("give either --model/--localizer/--ranger or --baseline, not both")


def approach_estimator(name: str | None, net: SirenModel | None) -> Any:
    """The approaching/receding estimator named ``name``
    (:data:`~makeway.perceive.audio.motion.APPROACH_METHODS`; ``None``:
    :func:`~makeway.perceive.audio.stream.default_approach`). ``trend`` needs the network's distances.

    Raises:
        UnknownNameError: an unknown method (lists the known ones).
        ValueError: ``trend`` without a network.
    """
    from makeway.perceive.audio.motion import APPROACH_METHODS, TrendApproach, approach_model_for
    from makeway.perceive.audio.stream import default_approach

    if name is None:
        return default_approach(net)
    cls = APPROACH_METHODS[name]
    if name == "trend":
        if net is None:
            raise ValueError("--approach trend reads the network's distances; it cannot run with --baseline")
        return TrendApproach(approach_model_for([r.path for r in net.rangers]))
    return cls()


def fit_energy_detector(folder: str | Path) -> SirenEnergyDetector:
    """The band-energy siren detector with its two logistic constants (slope, offset) fitted on the
    auto-labelled windows of the recordings under ``folder``.

    Raises:
        InputError: a recording cannot be read.
    """
    import numpy as np

    from makeway.eval.siren_labels import label_recording
    from makeway.perceive.audio.doa import SirenEnergyDetector
    from makeway.perceive.audio.features import window_batch
    from makeway.sense.recording import read_recording

    detector = SirenEnergyDetector()
    scores, ys = [], []
    for path in recording_folders(folder):
        rec = read_recording(path)
        labels = label_recording(rec)
        detector.sample_rate = rec.sample_rate
        scores.append(detector.scores(window_batch(rec, labels)[labels.kept]))
        ys.append(labels.siren[labels.kept])
    detector.fit_scores(np.concatenate(scores), np.concatenate(ys))
    return detector


def _score_approach(
    recs: list[Path], net: SirenModel, full_scale_db_spl: float | None, progress: bool
) -> dict[str, Any]:
    """Each recording run as ``audio listen`` runs it; the approaching/receding call of the
    distance-trend classifier and of the level/Doppler rule scored against the labelled range rate
    (:mod:`makeway.eval.siren_approach`)."""
    from makeway.eval.siren_approach import MIN_RANGE_RATE_MPS, approach_recordings, approach_scores
    from makeway.perceive.audio.motion import TrendApproach, approach_model_for

    trend = TrendApproach(approach_model_for([r.path for r in net.rangers]))
    with progress_bar("approach", len(recs), enabled=progress, unit="rec") as advance:
        arrays = approach_recordings(recs, net, trend, full_scale_db_spl=full_scale_db_spl, advance=advance)
    return {"min_range_rate_mps": MIN_RANGE_RATE_MPS, **approach_scores(arrays, trend)}


def evaluate_recordings(
    data: str | Path,
    *,
    baseline: str | None = None,
    fit: str | Path | None = None,
    model: str | Path | None = None,
    localizer: str | Path | None = None,
    ranger: Sequence[str | Path] | None = None,
    threads: int | None = None,
    smooth: int = LISTEN_SMOOTH,
    average: str = SMOOTH_AVERAGE,
    full_scale_db_spl: float | None = None,
    approach: bool = False,
    progress: bool = True,
) -> dict[str, Any]:
    """Score siren detection and localization on the labelled recordings under ``data``
    (:func:`makeway.eval.siren.evaluate`): the siren networks (shipped unless named), or with
    ``baseline`` a classical bearing method with the band-energy detector (its constants fitted on
    the recordings under ``fit`` when given). ``smooth`` windows are averaged for each decision
    (``average``: their logits or probabilities; the default is ``audio listen``'s, so the score is
    that of the decision a user gets, and ``smooth=1`` scores each window alone);
    ``full_scale_db_spl`` is the calibration assumed for recordings whose ``array.yaml`` states
    none. With ``approach``, the approaching/receding call is scored too (the networks run a second
    time).

    Returns the scores of :func:`makeway.eval.siren.evaluate` with ``data``, ``seconds`` (wall), the
    localizer and rangers used, ``approach`` and the fitted ``detector`` constants where they apply.

    Raises:
        ValueError: contradictory options (a baseline with networks, ``fit`` or ``approach`` without
            the right method) — checked before any recording is read.
        InputError: a recording or a model cannot be read.
    """
    from makeway.eval.siren import evaluate, model_estimator

    check_baseline(baseline, model, localizer, ranger)
    if baseline is None and fit is not None:
        raise ValueError("--fit fits the baseline detector; it needs --baseline")
    if baseline is not None and approach:
        raise ValueError(
            "--approach scores the network's approaching/receding call; it needs the network, not --baseline"
        )
    recs = recording_folders(data)
    detector = fit_energy_detector(fit) if fit is not None else None
    method: Any = baseline
    name = baseline or "model"
    threshold = 0.5
    net: SirenModel | None = None
    if baseline is None:
        net = siren_networks(model, localizer, ranger, threads)
        method = model_estimator(net)
        name = f"model:{net.path.name}"
        threshold = net.threshold  # the decision threshold stored with the model
    t0 = time.perf_counter()
    with progress_bar(f"eval {name}", len(recs), enabled=progress, unit="rec") as advance:
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
            result["approach"] = _score_approach(recs, net, full_scale_db_spl, progress)
    result["seconds"] = round(time.perf_counter() - t0, 2)
    if detector is not None:
        result["detector"] = {"slope": round(detector.slope, 6), "offset": round(detector.offset, 6)}
    return result


def calibrate_from_tone(
    tone: str | Path,
    *,
    level_db_spl: float = 94.0,
    frequency_hz: float = 1000.0,
    channel: int | None = None,
    write: Sequence[str | Path] = (),
) -> tuple[ToneCalibration, dict[str, Any]]:
    """Measure the array's calibration (``full_scale_db_spl``: the dB SPL a digital RMS of 1.0 stands
    for) from a recorded calibrator tone of ``level_db_spl`` at ``frequency_hz`` on ``channel``
    (default: the loudest), and store it in each ``array.yaml`` (or recording folder) of ``write``
    (:mod:`makeway.sense.calibration`).

    Returns the measurement and its JSON form
    (:meth:`~makeway.sense.calibration.ToneCalibration.to_dict`) with ``file`` and ``written`` (the
    files updated).

    Raises:
        InputError: the tone cannot be read or holds no such tone; a target cannot be written.
    """
    from makeway.sense.calibration import measure_file, write_full_scale

    found = measure_file(tone, level_db_spl=level_db_spl, frequency_hz=frequency_hz, channel=channel)
    out = found.to_dict()
    out["file"] = str(tone)
    out["written"] = [str(p) for p in write_full_scale(list(write), found.full_scale_db_spl)]
    return found, out


@dataclass
class ListenRun:
    """What :func:`listen_recording` heard: the ``messages`` (one per hop), the wall time in
    ``seconds``, whether the recording had to be taken at the networks' full scale
    (``uncalibrated``), and a ``summary`` for runs that wrote the messages to a file."""

    messages: list[dict[str, Any]]
    seconds: float
    uncalibrated: bool
    summary: dict[str, Any] = field(default_factory=dict)


def listen_recording(
    path: str | Path,
    *,
    model: str | Path | None = None,
    localizer: str | Path | None = None,
    ranger: Sequence[str | Path] | None = None,
    baseline: str | None = None,
    window_s: float = 0.5,
    hop_s: float = 0.17,
    smooth: int = LISTEN_SMOOTH,
    average: str = SMOOTH_AVERAGE,
    full_scale_db_spl: float | None = None,
    approach: str | None = None,
    plot: str | Path | None = None,
    jsonl: str | Path | None = None,
    on_message: Callable[[dict[str, Any]], None] | None = None,
    progress: bool = False,
    audio_topic: str | None = None,
    pose_topic: str | None = None,
    mcap: str | Path | None = None,
    realtime: bool = False,
    far_ranger: str | Path | None = None,
) -> ListenRun:
    """Slide the siren listener (:func:`makeway.perceive.audio.stream.listen`) over the recording
    folder ``path``: the siren networks (shipped unless named; one thread), or a classical
    ``baseline`` bearing method with the band-energy detector. Each hop's message goes to
    ``on_message`` as it is made; with ``jsonl`` the messages are also written there (JSON lines),
    with ``plot`` a spectrogram + polar bearing plot (PNG). Windows are ``window_s`` long every
    ``hop_s`` seconds; ``smooth`` windows are averaged for each decision. ``approach`` names the
    approaching/receding method (:func:`approach_estimator`). ``realtime`` plays the recording as a
    live array (a window every ``hop_s`` of wall time; when the listener falls behind, the oldest
    waiting window is dropped, never the newest; the summary's ``dropped_windows`` counts them).

    ``path`` may also be a robotics log (an MCAP file or a ROS 2 bag folder,
    :mod:`makeway.sense.logs`): its ``audio_topic`` (default: its only audio topic) with the array
    description, and its ``pose_topic`` as the ego path (default: its only pose topic, if any), are
    listened to as a recording. With ``mcap`` the hops are also written there as a Foxglove MCAP file
    (:func:`makeway.viz.foxglove.write_listen_mcap`). ``far_ranger`` (an ONNX file written by
    ``makeway audio train-far``; opt-in) places sirens beyond 50 m (:mod:`makeway.perceive.audio
    .far_range`); it needs the siren networks (not a ``baseline``).

    Raises:
        ValueError: contradictory options, or a recording shorter than one window (before listening).
        InputError: the recording, the log (a missing topic, no array description, damaged) or a
            model cannot be read; ``plot``, ``jsonl`` or ``mcap`` cannot be written (checked first).
        UnknownNameError: an unknown ``approach`` method.
    """
    from makeway.perceive.audio.stream import listen as listen_stream
    from makeway.perceive.audio.stream import listen_windows
    from makeway.sense.logs import is_log, read_log_recording
    from makeway.sense.recording import assume_calibration, read_recording

    check_baseline(baseline, model, localizer, ranger)
    if not Path(path).exists():
        raise InputError(path, "no such folder")
    for target in (t for t in (plot, jsonl, mcap) if t is not None):
        check_writable(target, folder=False)
    if is_log(path):
        source = read_log_recording(path, audio_topic, pose_topic)
    elif audio_topic is not None or pose_topic is not None:
        raise InputError(path, "a topic was named, but this is not an MCAP file or a ROS 2 bag folder")
    else:
        source = read_recording(path)
    if far_ranger is not None and baseline is not None:
        raise ValueError("--far-ranger reads the siren networks' outputs; it cannot go with --baseline")
    net = siren_networks(model, localizer, ranger, 1) if baseline is None else None
    far = None
    if far_ranger is not None:
        from makeway.perceive.audio.far_range import FarRanger

        far = FarRanger(far_ranger, threads=1)
    estimator = approach_estimator(approach, net)
    rec = assume_calibration(source, full_scale_db_spl)
    t0 = time.perf_counter()
    messages: list[dict[str, Any]] = []
    hops = len(listen_windows(rec, window_s, hop_s))  # raises when shorter than one window
    with progress_bar("listening", hops, enabled=progress, unit="hop") as advance:
        for msg in listen_stream(
            rec,
            window_s=window_s,
            hop_s=hop_s,
            method=baseline or "gccphat",
            model=net,
            smooth=smooth,
            average=average,
            approach=estimator,
            realtime=realtime,
            far_ranger=far,
        ):
            messages.append(msg)
            if on_message is not None:
                on_message(msg)
            advance(1)
    wall = time.perf_counter() - t0
    if jsonl is not None:
        write_text_atomic(jsonl, "".join(json.dumps(m, separators=(",", ":")) + "\n" for m in messages))
    if plot is not None:
        from makeway.viz.listen_plot import plot_listen

        plot_listen(messages, rec, plot, window_s=window_s)
    if mcap is not None:
        from makeway.viz.foxglove import write_listen_mcap

        write_listen_mcap(mcap, messages, rec, start_ns=int(rec.meta.get("start_ns", 0)))
    run = ListenRun(messages, wall, uncalibrated=rec.full_scale_db_spl is None)
    if jsonl is not None:
        run.summary = {
            "recording": str(path),
            "messages": len(messages),
            "siren_messages": sum(1 for m in messages if m["is_siren"]),
            "dropped_windows": hops - len(messages),
            "ms_per_hop": round(1000.0 * wall / max(len(messages), 1), 2),
            "jsonl": str(jsonl),
            "plot": None if plot is None else str(plot),
            "mcap": None if mcap is None else str(mcap),
        }
    return run
