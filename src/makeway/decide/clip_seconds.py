"""Per-second "active EV" decisions on a clip, under the duty to yield (issue 26 item 6).

The fused beliefs of a clip (:func:`makeway.fuse.clip_seconds.fuse_clip`: lights seen, siren
heard, at each frame and listener decision) are judged one by one under a
:class:`~makeway.decide.duty.DutyToYield` with :func:`~makeway.decide.duty.duty_of`, keeping, as
the yield state machine does, how long the lights have been seen without a break (lights alone
are acted on only after ``lights_only_min_s``). Each whole second ``[k, k + 1)`` then gets the
strongest duty reached in it — ``"yield"`` over ``"prepare"`` over ``"none"`` (the duty's
``"ignore"``): a car acts on a duty as soon as it arises. Under the default duty
(``audible_and_visual``): siren and lights → yield, siren alone → prepare, lights alone → yield
once seen for 2 s.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from makeway.decide.duty import DutyToYield, duty_of
from makeway.fuse.clip_seconds import FrameLights, SirenTimeline
from makeway.messages import EVBelief

__all__ = ["SECOND_DECISIONS", "SecondDecision", "decide_seconds", "whole_seconds"]

SECOND_DECISIONS = ("yield", "prepare", "none")
"""A second's decision, strongest first."""

_RANK = {"yield": 0, "prepare": 1, "ignore": 2}


def whole_seconds(covered_s: float) -> int:
    """How many whole seconds ``[k, k + 1)`` a run covering ``covered_s`` seconds holds."""
    if not math.isfinite(covered_s) or covered_s <= 0:
        return 0
    return int(math.floor(covered_s + 1e-6))


@dataclass(frozen=True)
class SecondDecision:
    """One whole second of a clip: ``second`` k covers ``[k, k + 1)`` s.

    ``frames`` processed in it, ``lights_frames`` of them with an active EV's lights seen, and
    ``lights`` whether any was; ``siren_probability`` the highest smoothed siren probability the
    listener decided in it and ``siren`` whether that reached the detector's threshold (both
    ``None`` when the clip ran without sound, or no decision fell in the second); ``decision`` the
    strongest duty reached in the second (:data:`SECOND_DECISIONS`).
    """

    second: int
    frames: int
    lights_frames: int
    siren_probability: float | None
    siren: bool | None
    decision: str

    @property
    def lights(self) -> bool:
        return self.lights_frames > 0

    def to_dict(self) -> dict[str, Any]:
        """One line of ``seconds.jsonl``."""
        return {
            "second": self.second,
            "start_s": float(self.second),
            "frames": self.frames,
            "lights_frames": self.lights_frames,
            "lights": self.lights,
            "siren_probability": None if self.siren_probability is None else round(self.siren_probability, 4),
            "siren": self.siren,
            "decision": self.decision,
        }


def decide_seconds(
    beliefs: Sequence[EVBelief],
    frames: Sequence[FrameLights],
    siren: SirenTimeline | None,
    n_seconds: int,
    duty: DutyToYield | None = None,
) -> list[SecondDecision]:
    """The decision of each whole second ``0 … n_seconds - 1`` (module docstring).

    ``beliefs`` are the clip's fused beliefs in time order, ``frames`` and ``siren`` the streams
    they were fused from (for the per-second counts; ``siren`` ``None`` without sound); ``duty``
    defaults to :class:`~makeway.decide.duty.DutyToYield` (``audible_and_visual``).

    Raises:
        ValueError: ``n_seconds`` is negative.
    """
    if n_seconds < 0:
        raise ValueError(f"n_seconds must be >= 0, got {n_seconds}")
    rule = duty if duty is not None else DutyToYield()
    best = ["ignore"] * n_seconds
    lights_since: float | None = None
    for b in beliefs:
        if b.detected and b.lights:
            lights_since = b.time_s if lights_since is None else lights_since
        else:
            lights_since = None
        k = int(math.floor(b.time_s + 1e-9))
        if not 0 <= k < n_seconds:
            continue
        lights_for = b.time_s - lights_since if lights_since is not None else 0.0
        d = duty_of(b, rule, lights_for)
        if _RANK[d] < _RANK[best[k]]:
            best[k] = d
    counts = [[0, 0] for _ in range(n_seconds)]
    for f in frames:
        k = int(math.floor(f.time_s + 1e-9))
        if 0 <= k < n_seconds:
            counts[k][0] += 1
            counts[k][1] += int(f.seen)
    out = []
    for k in range(n_seconds):
        p = siren.max_in(k, k + 1) if siren is not None else None
        out.append(
            SecondDecision(
                second=k,
                frames=counts[k][0],
                lights_frames=counts[k][1],
                siren_probability=p,
                siren=None if p is None or siren is None else p >= siren.threshold,
                decision="none" if best[k] == "ignore" else best[k],
            )
        )
    return out
