"""``makeway detect``: the detector → tracker → active-EV rule (lights and/or crop classifier) →
smoother pipeline on a video, with the siren detector on its sound track and both fused into
per-second decisions (:mod:`makeway.pipeline.clip_sound`)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from makeway.pipeline.clip_sound import run_clip
from makeway.pipeline.video import DEFAULT_LIGHTS, VideoRunSummary
from makeway.track.lights import ACTIVE_RULES

__all__ = ["DEFAULT_RULE", "FRAMEWORKS", "detect"]

#: ``b``: vehicle detector → SORT → crop classifier (the default); ``a``: one-stage EV detector → SORT.
FRAMEWORKS = ("a", "b")

#: The active-EV rule ``makeway detect`` uses when none is named (see :func:`detect`).
DEFAULT_RULE = "lights+crop"


def detect(
    video: str | Path,
    out: str | Path | None = None,
    *,
    detector: str = "yolox_nano",
    model: str | Path | None = None,
    score_threshold: float = 0.3,
    stride: int = 1,
    max_frames: int | None = None,
    write_video: bool = True,
    classifier: str = "default",
    classify_every: int = 1,
    single_view: bool = False,
    progress: bool = True,
    rule: str = DEFAULT_RULE,
    light_detector: str = DEFAULT_LIGHTS[0],
    colours: str = DEFAULT_LIGHTS[1],
    topic: str | None = None,
    mcap: str | Path | None = None,
    realtime: bool = False,
    audio: bool | None = None,
    duty: str = "audible_and_visual",
    framework: str = "b",
    detector_workers: int | None = None,
) -> VideoRunSummary:
    """Detect, track and judge the vehicles of ``video``; write the annotated video, ``tracks.jsonl``
    and ``summary.json`` to ``out`` (default ``makeway_out/<video stem>``).

    ``rule`` says what makes a vehicle track an active EV (:class:`makeway.pipeline.video.VisionPipeline`,
    :func:`makeway.track.lights.active_probability`), through the smoother: ``lights+crop``
    (default: a flashing emergency light on or above its box, and the crop classifier says it is an
    EV), ``lights`` (the flashing light alone; no classifier runs) or ``crop`` (the crop classifier
    alone, the earlier rule; without a classifier no track is judged). The lights rules use the
    light detector ``light_detector`` (registry name) with the colour set ``colours``, and each
    ``tracks.jsonl`` line then also lists the frame's ``lights``.

    ``classifier`` is a shipped crop classifier name (``default``, ``general``, ``fast``,
    ``fastest``, ``imagenet``), a model file (``.npz`` head or ``.onnx`` CNN) or ``none``; it judges
    each track on every ``classify_every``-th frame, and ``single_view`` skips the mirror image for heads. The
    classifier and its feature extractors are built before the first frame, so bad weights fail early.
    ``video`` may also be a robotics log (an MCAP file or a ROS 2 bag folder): its camera ``topic``
    is read (``None``: the log's only camera topic). With ``mcap`` the run is also written there as a
    Foxglove MCAP file (images, box annotations, tracks; :mod:`makeway.viz.foxglove`).
    Returns the run's summary (frames, timings in ms per frame, real-time factor, files written).
    ``realtime`` plays the video as a live camera would deliver it: when the pipeline falls behind,
    the oldest waiting frame is dropped, never the newest (``dropped_frames`` counts them).

    ``audio`` runs the siren detector on the clip's sound track (``None``, the default: when it has
    one) and each whole second is decided under the duty-to-yield preset ``duty``
    (:func:`makeway.pipeline.clip_sound.run_clip`): ``seconds.jsonl`` (per second: siren
    probability, lights seen, decision ``yield``/``prepare``/``none``) is written beside the other
    outputs, and the summary's ``seconds`` holds the per-second counts. Without sound the seconds
    are decided on the lights alone.

    ``framework="a"`` runs seed 001's Framework A instead of B: the one-stage EV detector
    (:class:`~makeway.perceive.vision.ev_detector.EVDetector`; ``model`` its file, default the
    shipped ``ev_det_yolox.onnx``; ``detector`` and ``classifier`` unused) → one SORT over all
    vehicles → the smoother fed by each track's per-box P(EV), under the same ``rule``.
    ``detector_workers``: frames detected at once (default: cores, at most 4).

    Raises:
        InputError: the video, the detector weights or the classifier cannot be read (names the file;
            an unknown classifier name lists the shipped ones); ``audio`` is asked for and the clip
            has no sound track, or its sound track cannot be decoded.
        UnknownNameError: an unknown detector or duty preset (lists the known ones).
    """
    if rule not in ACTIVE_RULES:
        raise ValueError(f"unknown rule {rule!r}; choose from: {', '.join(ACTIVE_RULES)}")
    if framework not in FRAMEWORKS:
        raise ValueError(f"unknown framework {framework!r}; choose from: {', '.join(FRAMEWORKS)}")
    out_dir = Path(out) if out is not None else Path("makeway_out") / Path(video).stem
    common: dict[str, Any] = {
        "audio": audio,
        "duty": duty,
        "stride": stride,
        "max_frames": max_frames,
        "write_video": write_video,
        "progress": progress,
        "rule": rule,
        "light_detector": light_detector,
        "light_colours": colours,
        "topic": topic,
        "mcap": mcap,
        "realtime": realtime,
    }
    if framework == "a":
        from makeway.perceive.vision.ev_detector import EVDetector

        workers = detector_workers if detector_workers is not None else min(os.cpu_count() or 1, 4)
        ev_detectors = [
            EVDetector(model, score_threshold=score_threshold, num_threads=None if workers == 1 else 1)
            for _ in range(max(1, workers))
        ]
        return run_clip(video, out_dir, ev_detectors=ev_detectors, **common).summary
    if rule == "lights+crop" and classifier.strip().lower() == "none":
        raise ValueError("the lights+crop rule needs a classifier; use --rule lights without one")
    track_classifier = None
    if classifier.strip().lower() != "none" and rule != "lights":
        from makeway.perceive.vision.ev_classifier import EVTrackClassifier, load_crop_classifier

        crop_classifier = load_crop_classifier(classifier, single_view=single_view)
        track_classifier = EVTrackClassifier(crop_classifier, every=classify_every)
        getattr(track_classifier.classifier, "extractors", None)  # build them now: bad weights fail early
    return run_clip(
        video,
        out_dir,
        detector=detector,
        model=model,
        score_threshold=score_threshold,
        classifier=track_classifier,
        detector_workers=detector_workers,
        **common,
    ).summary
