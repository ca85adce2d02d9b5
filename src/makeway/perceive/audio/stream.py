"""Streaming siren perception over a long recording (issue 4, item 6): ``makeway audio listen``.

:func:`listen` slides a window of ``window_s`` every ``hop_s`` over the recording (the windows of
:func:`~makeway.perceive.audio.windows.window_starts`, so message ``i`` matches label window ``i``)
and yields one message per hop::

    {"t_end": 1.17, "is_siren": true, "probability": 0.93, "smoothed_probability": 0.88,
     "level_db_spl": 78.4,
     "sources": [{"bearing_rad": 2.9, "bearing_deg": 166.2, "distance_m": 31.4, "approaching": true,
                  "approach_probability": 0.91}]}

With the trained siren network (``model``, :class:`~makeway.perceive.audio.siren_model.SirenModel`;
the CLI's default) ``probability`` is the network's, the first source is the nearest siren with
the network's bearing (vehicle frame, 0 ahead, positive left) and distance, and further sirens come
from the window's time–frequency bins (:mod:`~makeway.perceive.audio.multisource`; distance
``null``), each only when the network calls that source's own bins a siren. Without a model,
the band-energy :class:`~makeway.perceive.audio.doa.SirenEnergyDetector` and a classical bearing
(``method``) give at most one source and no distance. ``approaching`` comes from an approach estimator
(:data:`~makeway.perceive.audio.motion.APPROACH_METHODS`) that sees every window (so its history is
continuous) but is reported only in siren windows, for the nearest siren: with the network, by
default :class:`~makeway.perceive.audio.motion.TrendApproach` (the trend of the network's distance
and the level and Doppler cues, through a trained classifier; ``approach_probability`` is its
P(approaching)); without one, :class:`~makeway.perceive.audio.motion.ApproachEstimator` (level and
Doppler; ``approach_probability`` null). ``sources`` is empty when there is no siren.
``level_db_spl`` is the window's level in the siren band at the array (the recording's
calibration, or the networks' reference scale).

With the far ranger (opt-in, ``far_ranger=``; :mod:`~makeway.perceive.audio.far_range`) the nearest
siren also carries ``far_probability`` (P(distance > 100 m)) and ``distance_sigma`` (σ of ln
distance), its ``distance_m`` is the far ranger's, and a far one (``far_probability ≥``
:data:`~makeway.perceive.audio.far_range.FAR_CALL_PROBABILITY`) gets no approaching call.
Without it, the nearest siren carries ``distance_sigma`` when the networks state one (rangers
trained with ``--distance-sigma``, such as ``siren_ranger_wide.onnx``). The fusion weighs a
distance by the σ it comes with (:func:`makeway.fuse.kalman.range_sigma_m`).

``is_siren`` is decided on ``smoothed_probability``, the mean of this window and the ``smooth`` − 1
before it, taken over their logits unless ``average="probability"``
(:class:`~makeway.perceive.audio.windows.StreamSmoother`; with ``smooth = 1`` it is this window's
``probability``). The default is the logit mean of 8 windows (1.36 s of audio;
:data:`~makeway.perceive.audio.windows.LISTEN_SMOOTH`), chosen on validation recordings for its recall
at ≤ 1 % false alarms (see docs/results.md, section "Siren detection, bearing and distance").

:func:`makeway.viz.listen_plot.plot_listen` draws the messages.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from makeway.errors import InputError
from makeway.messages import SirenObservation, SirenSource
from makeway.perceive.audio.doa import DOA_METHODS, SirenEnergyDetector, detector_score
from makeway.perceive.audio.far_range import FAR_CALL_PROBABILITY, FAR_DISTANCE_PROBABILITY, FarRanger
from makeway.perceive.audio.features import band_level_db
from makeway.perceive.audio.motion import ApproachEstimator, TrendApproach, approach_model_for
from makeway.perceive.audio.multisource import SourceSeparator
from makeway.perceive.audio.siren_model import SirenModel
from makeway.perceive.audio.windows import (
    HOP_S,
    LISTEN_SMOOTH,
    SMOOTH_AVERAGE,
    WINDOW_S,
    StreamSmoother,
    window_starts,
)
from makeway.perceive.health import SwapCheck, audio_health, repair_window
from makeway.queues import live, paced
from makeway.sense.recording import AUDIO_FILE, REFERENCE_FULL_SCALE_DB_SPL, Recording


class SirenListener:
    """The listener's state and its per-window step (module docstring): one
    :class:`~makeway.messages.SirenObservation` per 0.5 s window of the array, in time order.

    :func:`listen` runs it over a recording; the closed loop runs it on audio rendered as the car
    drives (:class:`makeway.pipeline.siren_perception.SirenPerception`). ``mics`` and
    ``sample_rate`` are the array's, checked against the network's; ``full_scale_db_spl`` its
    calibration (``None``: the networks' scale). ``source`` names the stream in error messages.

    With ``health`` (the default) every window's capsules are checked first
    (:func:`~makeway.perceive.health.audio_health`: dead, clipped or uncorrelated; and, over the
    windows so far, two capsules swapped: :class:`~makeway.perceive.health.SwapCheck`, undone by
    re-ordering when the array's symmetry allows) and a distrusted one is rebuilt from its
    neighbours (:func:`~makeway.perceive.health.repair_window`) before anything else reads the
    window; the observation's ``health`` says which.
    """

    def __init__(
        self,
        mics: np.ndarray,
        sample_rate: int,
        *,
        model: SirenModel | None = None,
        method: str = "gccphat",
        detector: SirenEnergyDetector | None = None,
        approach: ApproachEstimator | TrendApproach | None = None,
        smooth: int = LISTEN_SMOOTH,
        average: str = SMOOTH_AVERAGE,
        window_s: float = WINDOW_S,
        full_scale_db_spl: float | None = None,
        source: str | Path = "recording",
        health: bool = True,
        far_ranger: FarRanger | None = None,
    ) -> None:
        self.check_health = bool(health)
        self.swap_check = SwapCheck(mics, int(sample_rate)) if self.check_health else None
        """Two capsules wired the wrong way round, found over the windows heard so far."""
        self.smoother = StreamSmoother(smooth, average)
        self.doa = DOA_METHODS[method]
        self.mics = np.asarray(mics, dtype=np.float64)
        self.sample_rate = int(sample_rate)
        if model is not None:
            model.check_array(self.mics, self.sample_rate, source)
            if abs(window_s - model.config.window_s) > 1e-9:
                raise ValueError(
                    f"the siren model works on {model.config.window_s:g} s windows, not {window_s:g} s"
                )
        if far_ranger is not None and model is None:
            raise ValueError("the far ranger reads the siren networks' outputs: it needs the siren model")
        self.model = model
        self.far_ranger = far_ranger
        """The far ranger (opt-in; :mod:`~makeway.perceive.audio.far_range`), fed every window."""
        self.window_s = float(window_s)
        self.full_scale_db_spl = full_scale_db_spl
        assumed = model.full_scale_db_spl if model is not None else REFERENCE_FULL_SCALE_DB_SPL
        self.full_scale = full_scale_db_spl if full_scale_db_spl is not None else assumed
        """The dB SPL of a digital RMS of 1.0 (when the array states none: the networks' scale, as
        :meth:`~makeway.perceive.audio.siren_model.SirenModel.predict` assumes)."""
        self.detector = detector if detector is not None else SirenEnergyDetector(self.sample_rate)
        self.approach = approach if approach is not None else default_approach(model)
        self.separator: SourceSeparator | None = None
        """Further sirens (with a network): judged by this listener's network at its calibration
        (:mod:`~makeway.perceive.audio.multisource`); handed to the network before each window."""
        if model is not None:
            gauge = self.full_scale_db_spl
            self.separator = SourceSeparator(
                self.mics,
                self.sample_rate,
                judge=lambda w: model.predict(w, gauge).prob,
                judge_threshold=model.threshold,
            )
        self.reset()

    @property
    def window_samples(self) -> int:
        """Samples per window."""
        return round(self.window_s * self.sample_rate)

    @property
    def threshold(self) -> float:
        """The decision threshold on the smoothed probability."""
        return self.model.threshold if self.model is not None else 0.5

    def reset(self) -> SirenListener:
        """Forget the history (decision smoothing, approach trend, what the swap check heard)."""
        self.smoother.reset()
        self.approach.reset()
        if self.far_ranger is not None:
            self.far_ranger.reset()
        if self.swap_check is not None:
            self.swap_check.reset()
        return self

    def step(self, window: np.ndarray, t_end: float) -> SirenObservation:
        """Judge one window ``(channels, samples)`` ending at ``t_end`` (s)."""
        window = np.asarray(window, dtype=np.float64)
        sr = self.sample_rate
        health = None
        if self.check_health:
            health = audio_health(window, self.mics, sr, t_end)
            if self.swap_check is not None:
                self.swap_check.update(window, t_end, self.window_s)
                window, health = self.swap_check.repair(window, health)
            if not health.ok:
                window, rebuilt = repair_window(window, self.mics, health)
                health = replace(health, repaired=tuple(sorted({*health.repaired, *rebuilt})))
        model = self.model
        pred = model.predict(window, self.full_scale_db_spl) if model is not None else None
        if pred is not None:
            p = float(pred.prob[0])
        else:
            p = float(self.detector.proba_from_scores(np.array([detector_score(window, sr)]))[0])
        p_smooth = self.smoother.update(p)
        is_siren = p_smooth >= self.threshold
        distance = float(pred.distance[0]) if pred is not None else None
        approaching, _ = self.approach.update(window, sr, t_end, distance_m=distance, is_siren=is_siren)
        p_approach = self.approach.probability_
        level = band_level_db(window, sr) + self.full_scale
        far = None
        if self.far_ranger is not None and pred is not None:
            far = self.far_ranger.update(
                window,
                sr,
                float(t_end),
                level_db_spl=level,
                distance_m=float(pred.distance[0]),
                bearing_rad=float(pred.theta[0]),
                siren_probability=p,
                sigma=None if pred.distance_sigma is None else float(pred.distance_sigma[0]),
            )
            if far.far_probability >= FAR_CALL_PROBABILITY:
                # beyond the trend classifier's training range (100 m): no approach call
                approaching, p_approach = None, None
        if model is not None and pred is not None:
            model.separator = self.separator
            found = model.sources(pred, 0, window, is_siren=is_siren)
        else:
            bearing = float(self.doa(window, self.mics, sr)) if is_siren else 0.0
            found = [{"bearing_rad": bearing, "distance_m": None}] if is_siren else []
        sources = tuple(
            SirenSource(
                bearing_rad=float(src["bearing_rad"]),
                distance_m=None if src["distance_m"] is None else float(src["distance_m"]),
                approaching=approaching if k == 0 else None,
                approach_probability=None if k or p_approach is None else float(p_approach),
            )
            for k, src in enumerate(found)
        )
        if sources and sources[0].distance_m is not None:
            # the σ of the distance reported: the far ranger's with its distance, else the networks'
            first = sources[0]
            if pred is not None and pred.distance_sigma is not None:
                first = replace(first, distance_sigma=float(pred.distance_sigma[0]))
            if far is not None:
                first = replace(first, far_probability=far.far_probability)
                if far.far_probability >= FAR_DISTANCE_PROBABILITY:
                    first = replace(first, distance_m=far.distance_m, distance_sigma=far.sigma)
            sources = (first, *sources[1:])
        return SirenObservation(float(t_end), bool(is_siren), p, float(p_smooth), sources, level, health)


def listen(
    recording: Recording,
    *,
    window_s: float = WINDOW_S,
    hop_s: float = HOP_S,
    method: str = "gccphat",
    detector: SirenEnergyDetector | None = None,
    approach: ApproachEstimator | TrendApproach | None = None,
    model: SirenModel | None = None,
    smooth: int = LISTEN_SMOOTH,
    average: str = SMOOTH_AVERAGE,
    realtime: bool = False,
    far_ranger: FarRanger | None = None,
) -> Iterator[dict[str, Any]]:
    """One JSON message per hop over ``recording`` (see the module docstring): a
    :class:`SirenListener` stepped over the windows of
    :func:`~makeway.perceive.audio.windows.window_starts`.

    With ``model`` (a :class:`~makeway.perceive.audio.siren_model.SirenModel`) the network gives
    the probability, the nearest siren's bearing and distance, and further sirens by time–frequency
    bin assignment (:meth:`~makeway.perceive.audio.siren_model.SirenModel.sources`); ``method`` and
    ``detector`` are then unused. ``approach`` (default :func:`default_approach`) says approaching or
    receding for the nearest siren. ``smooth`` windows are averaged for the decision, their logits
    or (``average``) probabilities (module docstring).

    ``realtime`` plays the recording as a live array delivers it: a window every ``hop_s`` seconds
    of wall time, handed over through a latest-wins queue of one window
    (:class:`makeway.queues.LiveSource`), so when the listener falls behind the oldest waiting
    window is dropped, never the newest, and each message is about the latest audio.

    ``far_ranger`` (opt-in, needs ``model``): the far ranger
    (:class:`~makeway.perceive.audio.far_range.FarRanger`) places the nearest siren beyond 50 m
    and adds ``far_probability`` and ``distance_sigma`` to it."""
    sr = int(recording.sample_rate)
    listener = SirenListener(
        recording.mics,
        sr,
        model=model,
        method=method,
        detector=detector,
        approach=approach,
        smooth=smooth,
        average=average,
        window_s=window_s,
        full_scale_db_spl=recording.full_scale_db_spl,
        source=recording.path or "recording",
        far_ranger=far_ranger,
    )
    audio = np.asarray(recording.audio)
    win = listener.window_samples
    starts = listen_windows(recording, window_s, hop_s)
    if realtime:
        for res in live(
            paced(starts.tolist(), 1.0 / hop_s), lambda s: listener.step(audio[s : s + win].T, (s + win) / sr)
        ):
            yield res.result.to_json()
        return
    for start in starts:
        yield listener.step(audio[start : start + win].T, (int(start) + win) / sr).to_json()


def listen_windows(recording: Recording, window_s: float = WINDOW_S, hop_s: float = HOP_S) -> np.ndarray:
    """The first sample of every window :func:`listen` steps over (``window_starts``).

    Raises:
        InputError: the recording is shorter than one window (names its audio file).
    """
    starts = window_starts(recording.n_samples, int(recording.sample_rate), window_s, hop_s)
    if len(starts) == 0:
        where = recording.path / AUDIO_FILE if recording.path is not None else Path("recording")
        raise InputError(
            where, f"is {recording.duration_s:.3g} s long, shorter than one {window_s:g} s listening window"
        )
    return starts


def default_approach(model: SirenModel | None) -> ApproachEstimator | TrendApproach:
    """The approach estimator :func:`listen` uses when none is given: :class:`TrendApproach` with
    the classifier trained on the distances of ``model``'s rangers
    (:func:`~makeway.perceive.audio.motion.approach_model_for`) when there is a network (it reads
    the network's distance) and that classifier is installed, :class:`ApproachEstimator`
    otherwise."""
    if model is not None:
        path = approach_model_for([r.path for r in model.rangers])
        if path.is_file():
            return TrendApproach(path)
    return ApproachEstimator()
