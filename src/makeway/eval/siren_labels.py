"""Auto-labelling of recordings from the logged trajectories (SPEC §3, seed 002 §II-C.1).

Seed 002 is the Apollo paper on siren detection and localization with two 4-channel roof
microphones (``../shared/seeds/002_…``, digested in SPEC §3).

The audio is cut into windows of ``window_s`` (0.5 s) every ``hop_s`` (0.17 s), starting at the first
sample; a window that would run past the end is not made. Each window is labelled at its **end**
time ``t_end``: the ego pose and each siren source's position are linearly interpolated between
their logged timestamps (yaw on the unwrapped angle), the source is moved into the vehicle frame
(x forward, y left, origin under the rear-axle centre) and

* ``theta = atan2(y, x)`` — bearing, 0 straight ahead, positive to the left, in (−π, π];
* ``distance = hypot(x, y)`` — in the ground plane, metres;
* ``range_rate`` — d(distance)/dt by a central difference over ±50 ms (one-sided at the ends of the
  logs; negative: approaching).

Sources farther than ``max_distance_m`` (100 m) are dropped, as in seed 002 (a siren is hardly
perceivable beyond); their entries hold NaN. A window whose every source is beyond that range is
**dropped** as a whole (``dropped`` true): it is neither a positive — no siren within 100 m — nor a
fair negative, since a 115 dB siren 120 m away is still plainly audible; seed 002 drops such samples
too. Training and evaluation skip dropped windows; a window of a recording without any siren is a
negative (``siren`` false).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from makeway.frames import to_vehicle_frame
from makeway.perceive.audio.windows import HOP_S, WINDOW_S, window_starts
from makeway.sense.recording import Recording, Trajectory

MAX_DISTANCE_M = 100.0
RATE_DT_S = 0.1


@dataclass(frozen=True)
class Labels:
    """Per-window labels of one recording (``W`` windows, ``K`` siren sources).

    ``start (W,)`` first sample of each window, ``window`` its length in samples, ``t_end (W,)`` the
    label time (s); ``present (W, K)`` source within range; ``theta``, ``distance``, ``range_rate``
    ``(W, K)`` (NaN where not present).
    """

    start: np.ndarray
    window: int
    sample_rate: int
    t_end: np.ndarray
    present: np.ndarray
    theta: np.ndarray
    distance: np.ndarray
    range_rate: np.ndarray
    window_s: float = WINDOW_S
    hop_s: float = HOP_S
    max_distance_m: float = MAX_DISTANCE_M
    far: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.start)

    @property
    def n_sources(self) -> int:
        return int(self.present.shape[1])

    @property
    def dropped(self) -> np.ndarray:
        """``(W,)`` bool: sources exist but all lie beyond ``max_distance_m`` (module docstring)."""
        if self.far is None:
            return np.zeros(len(self), dtype=bool)
        return np.asarray(self.far & ~self.present.any(axis=1), dtype=bool)

    @property
    def kept(self) -> np.ndarray:
        """``(W,)`` bool: the windows used for training and evaluation (not :attr:`dropped`)."""
        return ~self.dropped

    @property
    def siren(self) -> np.ndarray:
        """``(W,)`` bool: at least one siren within range at the window end."""
        return np.asarray(self.present.any(axis=1), dtype=bool)

    def nearest_source(self) -> np.ndarray:
        """``(W,)`` int: the index of the nearest present source per window (−1 when none)."""
        k = np.full(len(self), -1, dtype=np.int64)
        if self.n_sources and len(self):
            d = np.where(self.present, self.distance, np.inf)
            best = np.argmin(d, axis=1)
            ok = np.isfinite(d[np.arange(len(self)), best])
            k[ok] = best[ok]
        return k

    def _of_nearest(self, values: np.ndarray) -> np.ndarray:
        k = self.nearest_source()
        out = np.full(len(self), np.nan)
        ok = k >= 0
        out[ok] = values[np.flatnonzero(ok), k[ok]]
        return out

    def nearest(self) -> tuple[np.ndarray, np.ndarray]:
        """``(theta, distance)`` ``(W,)`` of the nearest present source per window (NaN when none)."""
        return self._of_nearest(self.theta), self._of_nearest(self.distance)

    def nearest_range_rate(self) -> np.ndarray:
        """``(W,)`` range rate (m/s, negative: approaching) of the nearest present source (NaN
        when none)."""
        return self._of_nearest(self.range_rate)

    def records(self, recording: str | None = None) -> list[dict[str, Any]]:
        """One JSON-ready dict per window (what ``makeway audio label`` writes as JSONL)."""
        out: list[dict[str, Any]] = []
        for w in range(len(self)):
            srcs = [
                {
                    "source": k,
                    "theta_rad": round(float(self.theta[w, k]), 6),
                    "theta_deg": round(math.degrees(float(self.theta[w, k])), 3),
                    "distance_m": round(float(self.distance[w, k]), 3),
                    "range_rate_mps": round(float(self.range_rate[w, k]), 3),
                }
                for k in range(self.n_sources)
                if self.present[w, k]
            ]
            row: dict[str, Any] = {}
            if recording is not None:
                row["recording"] = recording
            row.update(
                window=w,
                start_sample=int(self.start[w]),
                n_samples=int(self.window),
                t_end=round(float(self.t_end[w]), 6),
                siren=bool(srcs),
                dropped=bool(self.dropped[w]),
                sources=srcs,
            )
            out.append(row)
        return out


def relative_position(
    ego: Trajectory, source: Trajectory, times: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Source position ``(x, y)`` in the vehicle frame at ``times`` (linear interpolation)."""
    ex, ey = ego.position(times)
    yaw = ego.heading(times)
    sx, sy = source.position(times)
    return to_vehicle_frame(sx - ex, sy - ey, yaw)


def label_recording(
    rec: Recording,
    window_s: float = WINDOW_S,
    hop_s: float = HOP_S,
    max_distance_m: float = MAX_DISTANCE_M,
) -> Labels:
    """Label every window of ``rec`` from its trajectories (see the module docstring)."""
    sr = int(rec.sample_rate)
    start = window_starts(rec.n_samples, sr, window_s, hop_s)
    win = round(window_s * sr)
    t_end = (start + win) / sr
    k = len(rec.sources)
    shape = (len(start), k)
    theta = np.full(shape, np.nan)
    dist = np.full(shape, np.nan)
    rate = np.full(shape, np.nan)
    present = np.zeros(shape, dtype=bool)
    far = np.zeros(len(start), dtype=bool)
    for j, src in enumerate(rec.sources):
        x, y = relative_position(rec.ego, src, t_end)
        d = np.hypot(x, y)
        # central difference, made one-sided where the logs end
        lo_end = max(rec.ego.span[0], src.span[0])
        hi_end = min(rec.ego.span[1], src.span[1])
        t_hi = np.minimum(t_end + RATE_DT_S / 2, hi_end)
        t_lo = np.maximum(np.minimum(t_end - RATE_DT_S / 2, t_hi - RATE_DT_S / 2), lo_end)
        x1, y1 = relative_position(rec.ego, src, t_hi)
        x0, y0 = relative_position(rec.ego, src, t_lo)
        r = (np.hypot(x1, y1) - np.hypot(x0, y0)) / np.maximum(t_hi - t_lo, 1e-6)
        ok = d <= max_distance_m
        far |= ~ok
        present[:, j] = ok
        theta[ok, j] = np.arctan2(y, x)[ok]
        dist[ok, j] = d[ok]
        rate[ok, j] = r[ok]
    return Labels(start, win, sr, t_end, present, theta, dist, rate, window_s, hop_s, max_distance_m, far)
