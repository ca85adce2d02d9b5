"""Lights and siren of one clip fused into one belief over time (issue 26 item 6).

A road clip gives two senses on two clocks: the video pipeline's per-frame verdict (is some
vehicle track an active EV with its lights flashing?) and the siren listener's decisions (one every
hop of the sound track, from a mono microphone: *whether* a siren sounds, not where). Neither
places the EV, so the fused belief has no position: it says which signals are perceived now.

:func:`fuse_clip` merges the two streams in time order into one :class:`~makeway.messages.EVBelief`
per event (a frame or a listener decision). As in the multi-EV fusion
(:class:`~makeway.fuse.multi_ev.MultiEVFusion`'s ``sense_hold_s``), a sense supports the belief for
:data:`~makeway.fuse.multi_ev.SENSE_HOLD_S` (1 s) after its last positive observation: a frame with
an active EV's lights, a listener decision at or above the detector's threshold. The hold bridges
the moments where a vehicle track's active state drops out for a few frames (the track fragments,
the smoother dips) or the listener's probability dips below its threshold, so a belief says
"lights and siren" while both were perceived within the last second. Times are seconds from the
clip's start; the sound track is taken to start with the first frame.

:class:`SirenTimeline` holds the listener's decisions; :meth:`SirenTimeline.max_in` is the
strongest siren probability of a span (the per-second figure of ``makeway detect``).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from makeway.fuse.multi_ev import SENSE_HOLD_S
from makeway.messages import EVBelief

__all__ = ["SOURCE", "FrameLights", "SirenTimeline", "fuse_clip"]

SOURCE = "clip"
"""The ``source`` of the beliefs :func:`fuse_clip` makes."""


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


def fuse_clip(
    frames: Sequence[FrameLights], siren: SirenTimeline | None = None, *, hold_s: float = SENSE_HOLD_S
) -> list[EVBelief]:
    """One belief per event of the two streams, in time order (module docstring).

    ``frames`` in time order; ``siren`` ``None`` when the clip is run without its sound; ``hold_s``
    how long a sense supports the belief after its last positive observation. A belief is
    ``detected`` when the lights are seen or the siren is heard (within ``hold_s``); ``lights`` and
    ``siren`` say which; ``confidence`` is the higher of the last positive lights evidence and siren
    probability among the senses that support it; ``sources`` lists ``"light"`` and/or
    ``"siren"``.

    Raises:
        ValueError: frame times that go backwards, or a negative ``hold_s``.
    """
    if hold_s < 0:
        raise ValueError(f"hold_s must be >= 0, got {hold_s}")
    times = [f.time_s for f in frames]
    if any(b < a for a, b in itertools.pairwise(times)):
        raise ValueError("frame times must not decrease")
    events: list[tuple[float, int, int]] = [(f.time_s, 0, i) for i, f in enumerate(frames)]
    if siren is not None:
        events += [(float(t), 1, i) for i, t in enumerate(siren.time_s)]
    events.sort()
    lights, lights_at = 0.0, -math.inf  # the last positive observation of each sense
    p_siren, siren_at = 0.0, -math.inf
    out: list[EVBelief] = []
    for t, kind, i in events:
        if kind == 0 and frames[i].seen:
            lights, lights_at = frames[i].lights, t
        elif kind == 1:
            assert siren is not None
            if siren.probability[i] >= siren.threshold:
                p_siren, siren_at = float(siren.probability[i]), t
        seen = t - lights_at <= hold_s
        heard = t - siren_at <= hold_s
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
