"""``makeway detect``: the detector → tracker → crop classifier → smoother pipeline on a video."""

from __future__ import annotations

from pathlib import Path

from makeway.pipeline.video import VideoRunSummary, run_video

__all__ = ["detect"]


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
    classifier: str = "none",
    classify_every: int = 1,
    single_view: bool = False,
    progress: bool = True,
) -> VideoRunSummary:
    """Detect, track and (with a ``classifier``) judge the vehicles of ``video``; write the annotated
    video, ``tracks.jsonl`` and ``summary.json`` to ``out`` (default ``makeway_out/<video stem>``).

    ``classifier`` is a shipped crop classifier name (``default``, ``fast``, ``fastest``,
    ``imagenet``), a model file (``.npz`` head or ``.onnx`` CNN) or ``none``; it judges each track on
    every ``classify_every``-th frame, and ``single_view`` skips the mirror image for heads. The
    classifier and its feature extractors are built before the first frame, so bad weights fail early.
    Returns the run's summary (frames, timings in ms per frame, real-time factor, files written).

    Raises:
        InputError: the video, the detector weights or the classifier cannot be read (names the file;
            an unknown classifier name lists the shipped ones).
        UnknownNameError: an unknown detector (lists the known ones).
    """
    track_classifier = None
    if classifier.strip().lower() != "none":
        from makeway.perceive.vision.ev_classifier import EVTrackClassifier, load_crop_classifier

        crop_classifier = load_crop_classifier(classifier, single_view=single_view)
        track_classifier = EVTrackClassifier(crop_classifier, every=classify_every)
        getattr(track_classifier.classifier, "extractors", None)  # build them now: bad weights fail early
    out_dir = Path(out) if out is not None else Path("makeway_out") / Path(video).stem
    return run_video(
        video,
        out_dir,
        detector=detector,
        model=model,
        score_threshold=score_threshold,
        stride=stride,
        max_frames=max_frames,
        write_video=write_video,
        classifier=track_classifier,
        progress=progress,
    )
