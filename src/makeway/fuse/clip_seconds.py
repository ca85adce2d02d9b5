"""Lights and siren of one clip fused into one belief over time (issue 26 item 6).

A road clip gives two senses on two clocks: the video pipeline's per-frame verdict (is some
vehicle track an active EV with its lights flashing?) and the siren listener's decisions (one every
hop of the sound track, from a mono microphone: *whether* a siren sounds, not where). Neither
places the EV, so the fused belief has no position: it says which signals are perceived now.

:func:`fuse_clip` merges the two streams in time order into one :class:`~makeway.messages.EVBelief`
per event (a frame or a listener decision): each sense holds its last value until its next one,
so a belief at a frame's time carries the last siren decision made by then, and one at a siren
decision the last frame's lights (for at most :data:`LIGHTS_HOLD_S`: a camera that has gone
quiet proves nothing). Times are seconds from the clip's start; the sound track is taken to start
with the first frame.

:class:`SirenTimeline` holds the listener's decisions; :meth:`SirenTimeline.max_in` is the
strongest siren probability of a span (the per-second figure of ``makeway detect``).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from makeway.messages import EVBelief

__all__ = ["LIGHTS_HOLD_S", "SOURCE", "FrameLights", "SirenTimeline", "fuse_clip"]

SOURCE = "clip"
"""The ``source`` of the beliefs :func:`fuse_clip` makes."""

LIGHTS_HOLD_S = 0.5
"""How long (s) a frame's lights verdict stands for a listener decision made after it, when no
newer frame came (frames dropped by a live feed, the end of the video)."""


@dataclass(frozen=True)
class FrameLights:
    """The video pipeline's verdict on one frame: ``time_s`` (s from the clip's start) and
    ``lights``, the strongest smoothed EV evidence among the frame's tracks that are active EVs
    (their lights seen flashing; ``TrackSmoother``'s positive fraction, in ``[0, 1]``), ``0.0`` when
    none is."""

    time_s: float
    lights: float = 0.0

    @property
    def seen(self) -> bool:
        """Whether an active EV's lights are seen in this frame."""
        return self.lights > 0.0


@dataclass(frozen=True)
class SirenTimeline:
    """The siren listener's decisions over a clip: at ``time_s`` (s, the end of each analysis
    window; increasing) the smoothed siren ``probability``; a siren is heard where it reaches
    ``threshold`` (the detector's own)."""

    time_s: np.ndarray
    probability: np.ndarray
    threshold: float

    def __post_init__(self) -> None:
        t = np.asarray(self.time_s, dtype=np.float64)
        p = np.asarray(self.probability, dtype=np.float64)
        if t.shape != p.shape or t.ndim != 1:
            raise ValueError("time_s and probability must be 1-D arrays of the same length")
        if len(t) > 1 and np.any(np.diff(t) <= 0):
            raise ValueError("time_s must increase")
        if not (np.all(np.isfinite(p)) and np.all((p >= 0) & (p <= 1))):
            raise ValueError("probabilities must be finite and within [0, 1]")
        object.__setattr__(self, "time_s", t)
        object.__setattr__(self, "probability", p)

    def __len__(self) -> int:
        return len(self.time_s)

    def max_in(self, start_s: float, end_s: float) -> float | None:
        """The highest probability decided in ``[start_s, end_s)``; ``None`` when no decision was."""
        sel = (self.time_s >= start_s) & (self.time_s < end_s)
        return float(self.probability[sel].max()) if np.any(sel) else None


def fuse_clip(frames: Sequence[FrameLights], siren: SirenTimeline | None = None) -> list[EVBelief]:
    """One belief per event of the two streams, in time order (module docstring).

    ``frames`` in time order; ``siren`` ``None`` when the clip is run without its sound. A belief is
    ``detected`` when the lights are seen or the siren is heard; ``lights`` and ``siren`` say which;
    ``confidence`` is the higher of the lights evidence and the siren probability (the latter only
    once a siren is heard); ``sources`` lists ``"light"`` and/or ``"siren"``. Before the listener's
    first decision the siren counts as not heard.

    Raises:
        ValueError: frame times that go backwards.
    """
    times = [f.time_s for f in frames]
    if any(b < a for a, b in itertools.pairwise(times)):
        raise ValueError("frame times must not decrease")
    events: list[tuple[float, int, int]] = [(f.time_s, 0, i) for i, f in enumerate(frames)]
    if siren is not None:
        events += [(float(t), 1, i) for i, t in enumerate(siren.time_s)]
    events.sort()
    lights = 0.0
    lights_at = -math.inf
    p_siren = 0.0
    out: list[EVBelief] = []
    for t, kind, i in events:
        if kind == 0:
            lights, lights_at = frames[i].lights, t
        else:
            assert siren is not None
            p_siren = float(siren.probability[i])
        seen = lights > 0.0 and t - lights_at <= LIGHTS_HOLD_S
        heard = siren is not None and p_siren >= siren.threshold
        sources = (("light",) if seen else ()) + (("siren",) if heard else ())
        confidence = max(lights if seen else 0.0, p_siren if heard else 0.0)
        out.append(
            EVBelief(
                time_s=t,
                detected=seen or heard,
                confidence=confidence,
                lights=seen,
                siren=heard,
                source=SOURCE,
                sources=sources,
            )
        )
    return out
