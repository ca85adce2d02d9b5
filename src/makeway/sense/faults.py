"""Sensor faults injected into recordings and video frames (issue 29, item 2): what a degraded
sensor hands the perception stages, to measure how they cope (``benchmarks/bench_sensor_faults.py``).

Two registries, one per kind of data (:mod:`makeway.registry`'s convention): look a fault up by name
and call it with its data, a random generator and its parameters. Every fault returns new data and
leaves its input untouched.

:data:`AUDIO_FAULTS` — ``fault(recording, rng, **params) -> Recording`` on a multichannel
:class:`~makeway.sense.recording.Recording` (audio in full-scale units, channels in ``array.yaml``
order):

* ``dead_channel`` (``channel``) — the capsule gives nothing but the converter's hiss
  (:data:`DEAD_FLOOR_RMS`, white noise, about −100 dBFS);
* ``clipped_channel`` (``channel``, ``rms_dbfs`` = −6) — a preamp set far too hot: the channel
  amplified until its RMS reaches ``rms_dbfs`` (dB re full scale) and pinned at ±full scale;
* ``swapped_channels`` (``channel``, ``other``) — two channels wired the wrong way round;
* ``noisy_channel`` (``channel``, ``snr_db`` = 0) — a capsule full of its own noise (wind on one
  capsule, a broken shield): white noise at ``snr_db`` below the channel's own RMS;
* ``clock_skew`` (``offset_s`` = 0.05) — the ego pose log's clock runs ``offset_s`` ahead of the
  audio clock: the pose logged at ``t`` is the one at ``t + offset_s``;
* ``clock_jitter`` (``jitter_s`` = 0.05) — each ego pose timestamp off by a uniform random amount in
  ``±jitter_s`` (kept increasing).

:data:`VIDEO_FAULTS` — ``fault(frames, rng, **params) -> frames`` on a stream of
``(frame_index, time_s, image_bgr)`` as :class:`~makeway.sense.video.VideoReader` yields it (lazily:
a long clip is never held in memory):

* ``frame_drop`` (``fraction`` = 0.3) — each frame lost with that probability (the index and time of
  the frames that arrive are kept, so the consumer sees the gaps);
* ``frozen`` (``start_s`` = 0) — from ``start_s`` on the camera hands out the same image again and
  again (a stuck driver), with fresh indices and times;
* ``blackout`` (``start_s`` = 0, ``duration_s`` = inf) — the image is black (sensor dark, lens
  covered), with a little read noise;
* ``time_jitter`` (``jitter_s`` = 0.05) — each frame's timestamp off by a uniform random amount in
  ``±jitter_s`` (kept increasing).

:func:`apply_audio_fault` / :func:`apply_video_fault` look a name up and apply it with a seed.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator
from dataclasses import replace
from typing import Any

import numpy as np

from makeway.registry import Registry
from makeway.sense.recording import Recording, Trajectory

__all__ = [
    "AUDIO_FAULTS",
    "DEAD_FLOOR_RMS",
    "VIDEO_FAULTS",
    "Frame",
    "apply_audio_fault",
    "apply_video_fault",
]

Frame = tuple[int, float, np.ndarray]
"""One video frame: ``(frame_index, time_s, image_bgr)``."""

AudioFault = Callable[..., Recording]
VideoFault = Callable[..., Iterator[Frame]]

AUDIO_FAULTS: Registry[AudioFault] = Registry("audio fault")
VIDEO_FAULTS: Registry[VideoFault] = Registry("video fault")

DEAD_FLOOR_RMS = 1e-5
"""RMS of what a dead capsule still delivers (the converter's own noise, −100 dBFS)."""
BLACK_NOISE = 2.0
"""Standard deviation (8-bit grey levels) of the read noise in a blacked-out image."""


def _channel(rec: Recording, channel: int) -> int:
    if not -rec.n_channels <= channel < rec.n_channels:
        raise ValueError(f"channel {channel} does not exist: the recording has {rec.n_channels}")
    return channel % rec.n_channels


def _with_audio(rec: Recording, audio: np.ndarray, fault: str) -> Recording:
    meta = {**rec.meta, "faults": [*rec.meta.get("faults", []), fault]}
    return replace(rec, audio=audio.astype(np.float32, copy=False), meta=meta)


@AUDIO_FAULTS.register("dead_channel")
def dead_channel(rec: Recording, rng: np.random.Generator, channel: int = 0) -> Recording:
    """``channel`` dead: only :data:`DEAD_FLOOR_RMS` of white noise left."""
    k = _channel(rec, channel)
    audio = np.array(rec.audio, dtype=np.float64)
    audio[:, k] = DEAD_FLOOR_RMS * rng.standard_normal(rec.n_samples)
    return _with_audio(rec, audio, f"dead_channel:{k}")


@AUDIO_FAULTS.register("clipped_channel")
def clipped_channel(
    rec: Recording, rng: np.random.Generator, channel: int = 0, rms_dbfs: float = -6.0
) -> Recording:
    """``channel`` amplified to an RMS of ``rms_dbfs`` (dB re full scale) and clipped at ±1."""
    k = _channel(rec, channel)
    audio = np.array(rec.audio, dtype=np.float64)
    rms = float(np.sqrt(np.mean(audio[:, k] ** 2))) or DEAD_FLOOR_RMS
    audio[:, k] = np.clip(audio[:, k] * 10.0 ** (rms_dbfs / 20.0) / rms, -1.0, 1.0)
    return _with_audio(rec, audio, f"clipped_channel:{k}")


@AUDIO_FAULTS.register("swapped_channels")
def swapped_channels(rec: Recording, rng: np.random.Generator, channel: int = 0, other: int = 2) -> Recording:
    """Channels ``channel`` and ``other`` exchanged (by default the front and back capsules of the
    reference array's left unit)."""
    a, b = _channel(rec, channel), _channel(rec, other)
    audio = np.array(rec.audio, dtype=np.float64)
    audio[:, [a, b]] = audio[:, [b, a]]
    return _with_audio(rec, audio, f"swapped_channels:{a},{b}")


@AUDIO_FAULTS.register("noisy_channel")
def noisy_channel(
    rec: Recording, rng: np.random.Generator, channel: int = 0, snr_db: float = 0.0
) -> Recording:
    """White noise added to ``channel`` at ``snr_db`` below the channel's RMS."""
    k = _channel(rec, channel)
    audio = np.array(rec.audio, dtype=np.float64)
    rms = float(np.sqrt(np.mean(audio[:, k] ** 2))) or DEAD_FLOOR_RMS
    audio[:, k] += rms * 10.0 ** (-snr_db / 20.0) * rng.standard_normal(rec.n_samples)
    return _with_audio(rec, audio, f"noisy_channel:{k}")


def _increasing(t: np.ndarray) -> np.ndarray:
    """``t`` made strictly increasing (each value at least 1 µs above the one before)."""
    out = np.array(t, dtype=np.float64)
    for i in range(1, len(out)):
        out[i] = max(out[i], out[i - 1] + 1e-6)
    return out


def _with_ego(rec: Recording, ego: Trajectory, fault: str) -> Recording:
    meta = {**rec.meta, "faults": [*rec.meta.get("faults", []), fault]}
    return replace(rec, ego=ego, meta=meta)


@AUDIO_FAULTS.register("clock_skew")
def clock_skew(rec: Recording, rng: np.random.Generator, offset_s: float = 0.05) -> Recording:
    """The ego pose log ``offset_s`` ahead of the audio: the pose stamped ``t`` is the true pose at
    ``t + offset_s`` (the log keeps its timestamps, so it still spans the audio)."""
    e = rec.ego
    t = e.t
    x, y = e.position(t + offset_s)
    ego = Trajectory(t.copy(), x, y, e.heading(t + offset_s) if e.yaw is not None else None)
    return _with_ego(rec, ego, f"clock_skew:{offset_s:g}")


@AUDIO_FAULTS.register("clock_jitter")
def clock_jitter(rec: Recording, rng: np.random.Generator, jitter_s: float = 0.05) -> Recording:
    """Each ego pose's timestamp off by a uniform random amount in ``±jitter_s`` (the poses keep
    their values; timestamps kept strictly increasing)."""
    e = rec.ego
    t = _increasing(e.t + rng.uniform(-jitter_s, jitter_s, len(e.t)))
    ego = Trajectory(t, e.x.copy(), e.y.copy(), None if e.yaw is None else e.yaw.copy())
    return _with_ego(rec, ego, f"clock_jitter:{jitter_s:g}")


@VIDEO_FAULTS.register("frame_drop")
def frame_drop(frames: Iterable[Frame], rng: np.random.Generator, fraction: float = 0.3) -> Iterator[Frame]:
    """Each frame lost with probability ``fraction``; the others keep their index and time."""
    if not 0.0 <= fraction < 1.0:
        raise ValueError(f"fraction must be in [0, 1), got {fraction}")
    for frame in frames:
        if rng.random() >= fraction:
            yield frame


@VIDEO_FAULTS.register("frozen")
def frozen(frames: Iterable[Frame], rng: np.random.Generator, start_s: float = 0.0) -> Iterator[Frame]:
    """From ``start_s`` (s) on, every frame carries the image of the first frame at or after it."""
    stuck: np.ndarray | None = None
    for index, t, image in frames:
        if t >= start_s:
            if stuck is None:
                stuck = image.copy()
            yield index, t, stuck.copy()
        else:
            yield index, t, image


@VIDEO_FAULTS.register("blackout")
def blackout(
    frames: Iterable[Frame], rng: np.random.Generator, start_s: float = 0.0, duration_s: float = math.inf
) -> Iterator[Frame]:
    """Frames in ``[start_s, start_s + duration_s)`` black, with :data:`BLACK_NOISE` read noise."""
    for index, t, image in frames:
        if start_s <= t < start_s + duration_s:
            noise = np.abs(rng.normal(0.0, BLACK_NOISE, image.shape))
            yield index, t, np.clip(noise, 0, 255).astype(image.dtype)
        else:
            yield index, t, image


@VIDEO_FAULTS.register("time_jitter")
def time_jitter(frames: Iterable[Frame], rng: np.random.Generator, jitter_s: float = 0.05) -> Iterator[Frame]:
    """Each frame's timestamp off by a uniform random amount in ``±jitter_s``, kept increasing."""
    last = -math.inf
    for index, t, image in frames:
        stamp = max(t + float(rng.uniform(-jitter_s, jitter_s)), last + 1e-6)
        last = stamp
        yield index, stamp, image


def apply_audio_fault(rec: Recording, name: str, seed: int = 0, **params: Any) -> Recording:
    """``rec`` with the :data:`AUDIO_FAULTS` fault ``name`` (random parts drawn from ``seed``)."""
    return AUDIO_FAULTS[name](rec, np.random.default_rng(seed), **params)


def apply_video_fault(frames: Iterable[Frame], name: str, seed: int = 0, **params: Any) -> Iterator[Frame]:
    """``frames`` through the :data:`VIDEO_FAULTS` fault ``name`` (random parts from ``seed``)."""
    return VIDEO_FAULTS[name](frames, np.random.default_rng(seed), **params)
