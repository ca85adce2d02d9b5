"""Per-track output smoother for per-frame probabilities (SPEC §1, seed 000).

Seed 000 is the Aurora paper on a per-frame EV crop CNN with a per-track output smoother
(``../shared/seeds/000_…``, digested in SPEC §1).

A per-frame classifier flickers: glare, occlusion and the off phase of a flashing light all produce
single-frame mistakes. The smoother keeps, per track id, a ring buffer of the last ``window`` valid
per-frame probabilities. A frame counts as positive when its probability is at least
``prob_threshold``. The track is an **active EV** when the buffer holds at least ``min_frames``
valid judgements and the positive fraction is **strictly greater** than ``threshold`` (T); before
``min_frames`` it is *warming up*. Frames without a valid judgement (``probability is None`` or NaN)
are skipped, not counted as negative. Buffers of tracks that died are forgotten.

Defaults are the paper's: ``window = 25``, ``min_frames = 6``, ``T = 0.5``. It is generic over any
per-frame probability (vision crop classifier, a simulated perception, an audio detector).

    smoother = TrackSmoother(window=25, min_frames=6, threshold=0.5)
    states = smoother.update(observations, alive_track_ids=tracker.live_ids)
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable

from makeway.messages import EVObservation, EVState, EVTrackState


class TrackSmoother:
    """Ring-buffer vote per track id; see the module docstring (SPEC §1).

    Args:
        window: N, the number of most recent valid probabilities kept per track (default 25).
        min_frames: valid judgements needed before a decision (default 6).
        threshold: T, the positive fraction that must be exceeded (default 0.5).
        prob_threshold: a frame is positive when its probability is at least this (default 0.5).
    """

    def __init__(
        self, window: int = 25, min_frames: int = 6, threshold: float = 0.5, prob_threshold: float = 0.5
    ) -> None:
        if window < 1:
            raise ValueError(f"window must be >= 1, got {window}")
        if not 1 <= min_frames <= window:
            raise ValueError(f"min_frames must lie in [1, window={window}], got {min_frames}")
        if not 0.0 <= threshold < 1.0:
            raise ValueError(f"threshold T must lie in [0, 1), got {threshold}")
        if not 0.0 <= prob_threshold <= 1.0:
            raise ValueError(f"prob_threshold must lie in [0, 1], got {prob_threshold}")
        self.window = window
        self.min_frames = min_frames
        self.threshold = threshold
        self.prob_threshold = prob_threshold
        self._buffers: dict[int, deque[float]] = {}

    def reset(self) -> None:
        """Forget every track."""
        self._buffers.clear()

    @property
    def track_ids(self) -> list[int]:
        """Ids that currently have a buffer."""
        return list(self._buffers)

    def update(
        self, observations: Iterable[EVObservation], alive_track_ids: Iterable[int] | None = None
    ) -> list[EVTrackState]:
        """Add this frame's observations; return the state of every live track.

        Args:
            observations: per-frame judgements (any number per call, any tracks).
            alive_track_ids: the tracker's live ids. Buffers of other ids are dropped, and tracks
                alive but not observed yet are reported as warming up. When ``None``, every track
                with a buffer is kept and reported.
        """
        for obs in observations:
            buf = self._buffers.get(obs.track_id)
            if buf is None:
                buf = self._buffers[obs.track_id] = deque(maxlen=self.window)
            p = obs.probability
            if p is not None and not math.isnan(p):
                buf.append(float(p))
        if alive_track_ids is None:
            ids = list(self._buffers)
        else:
            ids = list(dict.fromkeys(alive_track_ids))
            alive = set(ids)
            for dead in [k for k in self._buffers if k not in alive]:
                del self._buffers[dead]
        return [self.state(k) for k in ids]

    def state(self, track_id: int) -> EVTrackState:
        """The current smoothed state of one track (warming up when unknown)."""
        buf = self._buffers.get(track_id)
        n = len(buf) if buf is not None else 0
        if buf is None or n == 0:
            return EVTrackState(track_id, EVState.WARMING_UP, 0.0, 0, 0.0)
        positives = sum(1 for p in buf if p >= self.prob_threshold)
        fraction = positives / n
        if n < self.min_frames:
            state = EVState.WARMING_UP
        elif fraction > self.threshold:
            state = EVState.ACTIVE
        else:
            state = EVState.INACTIVE
        return EVTrackState(track_id, state, fraction, n, sum(buf) / n)
