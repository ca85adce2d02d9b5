"""Lights and siren on the same road clip, fused into per-second "active EV" decisions (issue 26
item 6).

:func:`run_clip` runs the video pipeline (:func:`~makeway.pipeline.video.run_video`, its active-EV
rule per frame) and the siren detector on the clip's sound track, and combines them per second:

1. **Sound**: the first audio stream is decoded before the video runs (a damaged track fails
   before any long work), downmixed to mono (channel mean) and resampled to the siren network's rate
   (48 kHz; polyphase, exact ratio; :func:`~makeway.sense.clip_audio.read_clip_audio`). A phone or
   dash-camera microphone is one channel: it can tell *whether* a siren sounds, not where. The
   networks read the eight channels of the reference roof array, so the track is rendered as one
   static point source 25 m from the array, scaled to ``level_dba`` over the part of the track
   the video run covered (the whole clip unless frames were limited; 70 dB(A),
   as in the real mono check of :mod:`makeway.eval.siren_mono`; the camera's gain is unknown, so
   absolute levels mean nothing here), cut into 0.5 s windows every 0.17 s and decided as
   ``makeway audio listen`` decides (logit mean of the last 8 windows, the detector's own
   threshold), once every frame has been seen. Only the detector runs: no bearing or distance is
   asked of a mono track.
2. **Lights**: each processed frame's verdict, the strongest smoothed evidence among its tracks
   that the active-EV rule (default ``lights+crop``) turned active
   (:class:`~makeway.fuse.clip_seconds.FrameLights`).
3. **Fusion and decision**: :func:`~makeway.fuse.clip_seconds.fuse_clip` merges the two streams
   into beliefs; :func:`~makeway.decide.clip_seconds.decide_seconds` judges them under the duty to
   yield and gives each whole second its strongest duty: ``yield``, ``prepare`` or ``none``.

With an output folder, ``seconds.jsonl`` (one line per whole second:
:meth:`~makeway.decide.clip_seconds.SecondDecision.to_dict`) is written beside the video
pipeline's outputs, and ``summary.json`` gets the per-second counts under ``seconds``.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from makeway.atomic import check_writable, write_text_atomic
from makeway.decide.clip_seconds import SECOND_DECISIONS, SecondDecision, decide_seconds, whole_seconds
from makeway.decide.duty import DUTY_PRESETS, DutyToYield
from makeway.errors import InputError
from makeway.eval.siren_mono import LEVEL_DBA, render_static
from makeway.fuse.clip_seconds import FrameLights, SirenTimeline, fuse_clip
from makeway.messages import PerceptionFrame
from makeway.perceive.audio.siren_model import SirenModel
from makeway.perceive.audio.windows import (
    HOP_S,
    LISTEN_SMOOTH,
    SMOOTH_AVERAGE,
    WINDOW_S,
    smoothed_probability,
)
from makeway.perceive.audio.windows import window_starts as _window_starts
from makeway.pipeline.video import VideoRunSummary, run_video
from makeway.sense.clip_audio import ClipAudio, has_audio, read_clip_audio
from makeway.sense.logs import is_log
from makeway.sim.acoustics import FULL_SCALE_PA, self_noise

__all__ = ["ClipRun", "detection_model", "frame_lights", "listen_clip", "run_clip"]

BATCH = 32
"""Windows scored per network call."""


def detection_model(threads: int | None = 1) -> SirenModel:
    """The shipped siren detector alone (no localizer, no rangers: a mono track has no bearing)."""
    return SirenModel(threads=threads, localizer=False, ranger=False)


def listen_clip(
    audio: ClipAudio,
    model: SirenModel,
    *,
    level_dba: float = LEVEL_DBA,
    seed: int = 0,
    smooth: int = LISTEN_SMOOTH,
    average: str = SMOOTH_AVERAGE,
    until_s: float | None = None,
) -> SirenTimeline:
    """The siren listener's decisions over a clip's mono track (module docstring, step 1).

    ``audio`` must be at the model's sample rate. ``seed`` draws the rendered source's bearing and
    the capsules' self-noise. ``until_s`` listens to the track's first ``until_s`` seconds only
    (the part the video run covered; the level is then set over that part). A track shorter than
    one window gives an empty timeline.

    Raises:
        ValueError: ``audio`` is not at the model's sample rate.
    """
    cfg = model.config
    if audio.sample_rate != cfg.sample_rate:
        raise ValueError(f"audio at {audio.sample_rate} Hz; the siren model reads {cfg.sample_rate} Hz")
    x = audio.samples
    if until_s is not None:
        x = x[: max(0, round(until_s * cfg.sample_rate))]
    starts = _window_starts(len(x), cfg.sample_rate, WINDOW_S, HOP_S)
    win = cfg.n_samples
    if len(starts) == 0:
        return SirenTimeline(np.zeros(0), np.zeros(0), model.threshold)
    rng = np.random.default_rng(seed)
    n = int(starts[-1]) + win
    if np.any(x[:n]):
        array, _ = render_static(x[:n], model, rng, level_dba=level_dba)
    else:  # a digitally silent track: the capsules' own noise only
        array = (self_noise(n, len(model.mics), rng) / FULL_SCALE_PA).astype(np.float32)
    probs = []
    for i in range(0, len(starts), BATCH):
        chunk = np.stack([array[s : s + win].T for s in starts[i : i + BATCH]])
        probs.append(model.predict(chunk).prob)
    prob = smoothed_probability(np.concatenate(probs), smooth, average)
    times = (starts + win) / cfg.sample_rate
    return SirenTimeline(times, np.clip(prob, 0.0, 1.0), model.threshold)


def frame_lights(frame: PerceptionFrame) -> FrameLights:
    """A frame's lights verdict: the highest positive fraction among its active EV tracks (0 when
    none is active)."""
    active = [s.positive_fraction for s in frame.ev_states if s.active]
    return FrameLights(frame.time_s, max(active) if active else 0.0)


@dataclass
class ClipRun:
    """What :func:`run_clip` did: the video run's ``summary`` (with ``seconds``: the per-second
    counts), the per-second ``decisions``, the listener's ``siren`` decisions (``None`` without
    sound) and the sound track's description ``audio`` (``None`` without sound)."""

    summary: VideoRunSummary
    decisions: list[SecondDecision] = field(default_factory=list)
    siren: SirenTimeline | None = None
    audio: dict[str, Any] | None = None


def _resolve_audio(video: Path, audio: bool | None) -> bool:
    """Whether to listen: ``audio`` ``None`` means "when the clip has a sound track"."""
    if is_log(video):
        if audio:
            raise InputError(video, "sound is read from video files only, not from robotics logs")
        return False
    if audio is False:
        return False
    try:
        present = has_audio(video)
    except InputError:
        if audio:
            raise
        return False  # not a media file FFmpeg opens: the video reader names the problem
    if audio and not present:
        raise InputError(video, "has no audio stream (run without sound: --no-audio)")
    return present


def run_clip(
    video: str | Path,
    out_dir: str | Path | None,
    *,
    audio: bool | None = None,
    duty: str | DutyToYield = "audible_and_visual",
    siren_model: SirenModel | None = None,
    level_dba: float = LEVEL_DBA,
    on_frame: Callable[[PerceptionFrame], None] | None = None,
    **video_options: Any,
) -> ClipRun:
    """Run the video pipeline and the siren detector on ``video`` and decide each whole second
    (module docstring); ``video_options`` go to :func:`~makeway.pipeline.video.run_video` (its
    ``rule`` decides which tracks count as active EVs with lights; ``realtime`` drops frames, and
    a second then holds fewer).

    ``audio``: ``True`` listens (the clip must have sound), ``False`` does not, ``None`` (default)
    listens when the clip has an audio stream. ``duty`` is a preset name of
    :data:`~makeway.decide.duty.DUTY_PRESETS` or a ready duty. ``siren_model`` defaults to
    :func:`detection_model`.

    Raises:
        InputError: the sound track is asked for but missing, or damaged; sound asked of a log;
            anything :func:`run_video` raises. Checked before the video runs: nothing is written.
        UnknownNameError: an unknown duty preset.
    """
    rule = DUTY_PRESETS[duty] if isinstance(duty, str) else duty
    if out_dir is not None:
        check_writable(out_dir, folder=True)
    src = Path(video)
    clip: ClipAudio | None = None
    model: SirenModel | None = None
    listen = _resolve_audio(src, audio) if src.exists() else False  # a missing file: run_video says so
    if listen:  # decode the whole track now: a damaged one fails before the video runs
        model = siren_model if siren_model is not None else detection_model()
        clip = read_clip_audio(src, model.config.sample_rate)
    frames: list[FrameLights] = []
    decisions: list[SecondDecision] = []
    heard: list[SirenTimeline] = []

    def collect(frame: PerceptionFrame) -> None:
        frames.append(frame_lights(frame))
        if on_frame is not None:
            on_frame(frame)

    def finish(out: Path | None, covered_s: float) -> tuple[dict[str, Any], dict[str, str]]:
        siren = None
        if clip is not None and model is not None:
            siren = listen_clip(clip, model, level_dba=level_dba, until_s=covered_s)
            heard.append(siren)
        beliefs = fuse_clip(frames, siren)
        decisions.extend(decide_seconds(beliefs, frames, siren, whole_seconds(covered_s), rule))
        counts = {d: sum(1 for s in decisions if s.decision == d) for d in SECOND_DECISIONS}
        per_second: dict[str, Any] = {
            "duty": rule.name,
            "audio": clip.to_dict() if clip is not None else None,
            "siren_level_dba": level_dba if clip is not None else None,
            "siren_threshold": round(siren.threshold, 6) if siren is not None else None,
            "seconds": len(decisions),
            "lights_seconds": sum(1 for s in decisions if s.lights),
            "siren_seconds": sum(1 for s in decisions if s.siren) if siren is not None else None,
            "decisions": counts,
        }
        written: dict[str, str] = {}
        if out is not None:
            path = out / "seconds.jsonl"
            write_text_atomic(
                path, "".join(json.dumps(s.to_dict(), separators=(",", ":")) + "\n" for s in decisions)
            )
            written["seconds"] = str(path)
        return per_second, written

    summary = run_video(video, out_dir, on_frame=collect, finish=finish, **video_options)
    return ClipRun(
        summary, decisions, heard[0] if heard else None, clip.to_dict() if clip is not None else None
    )
