"""Several sirens in one window: bearings by time–frequency bin assignment (issue 4, SPEC §3).

The siren network reports the nearest siren (bearing and distance). Further sirens come from here.

**Why time–frequency bins.** A siren is narrowband at any instant and its pitch keeps moving, so in
a short STFT frame (1024 points, 21 ms at 48 kHz) two sirens almost never share a frequency bin.
Each strong bin therefore carries the inter-capsule phases of *one* source, and every source can be
read from the bins it owns.

**Method.**

1. STFT of the window (1024 points, hop 512, Hann) on every capsule.
2. Keep the bins in the siren band (500–1800 Hz) whose power, averaged over the capsules, stands
   :data:`SELECT_DB` above the window's median in-band power.
3. For every kept bin ``s`` and candidate bearing θ, the PHAT-weighted steered response over all
   capsule pairs, ``r_s(θ) = mean_pairs cos(φ_ij − ω τ_ij(θ))`` (far field, ground plane). It is 1
   when one source at θ explains the bin's phases exactly.
4. Greedy assignment. The bearing that explains the most bins (``r ≥`` :data:`COHERENCE`) is the
   first source; its bins are removed. The bearing explaining the most of the remaining bins is
   the next source if it explains at least :data:`MIN_SHARE` of the first source's bin count (and
   at least :data:`MIN_BINS` bins) and lies :data:`SEPARATION_DEG` from every source found so far.
   Repeat up to ``max_sources``.

Removing a source's bins also removes its grating lobes: the 0.9 m spacing between the two roof
units aliases every 20–40° at siren frequencies. This is why peak-picking on a summed SRP map finds
a spurious second siren in most one-siren windows, and why the network's own bearing map (trained
only through the nearest siren's direction) rarely shows the second siren.

**Used with the network.** :meth:`SourceSeparator.further` adds the bearings that lie away from
the network's nearest siren, but only when the assignment itself finds two or more sirens: in
one-siren windows the first bearing of the assignment is sometimes a lobe 30–40° off the true one,
and reporting it beside the network's (correct) bearing would be the commonest spurious second siren.

The constants (and that rule) were chosen on training-split recordings; the figures are in
docs/results.md, section "Two sirens at once".
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy.fft import rfft

from makeway.perceive.audio.features import BAND_HZ
from makeway.perceive.audio.geometry import capsule_pairs, pair_delays

__all__ = ["SourceSeparator"]

NFFT = 1024
HOP = 512
SELECT_DB = 10.0
"""A time–frequency bin enters when its power stands this far above the window's in-band median."""
COHERENCE = 0.8
"""A bin is explained by bearing θ when its steered response ``r_s(θ)`` reaches this value."""
MIN_SHARE = 0.3
"""A further source must explain at least this share of the first source's bin count."""
MIN_BINS = 6
SEPARATION_DEG = 30.0
N_AZIMUTH = 180


@functools.lru_cache(maxsize=8)
def _plan(
    mics_key: bytes, n_ch: int, sample_rate: int, n_azimuth: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(pairs, bins, steer_re, steer_im, window)``: ``steer (bins, pairs, azimuths)`` is
    ``exp(jωτ)`` for each in-band bin, pair and bearing."""
    mics = np.frombuffer(mics_key, dtype=np.float64).reshape(n_ch, 3)
    pairs = capsule_pairs(n_ch)
    f = np.fft.rfftfreq(NFFT, 1.0 / sample_rate)
    bins = np.flatnonzero((f >= BAND_HZ[0]) & (f <= BAND_HZ[1]))
    az = np.arange(n_azimuth) * (2.0 * math.pi / n_azimuth)
    tau = pair_delays(mics, pairs, az)  # (pairs, azimuths)
    phase = 2.0 * math.pi * f[bins][:, None, None] * tau[None]  # (bins, pairs, azimuths)
    win = np.hanning(NFFT + 1)[:-1]
    return pairs, bins, np.cos(phase), np.sin(phase), win


class SourceSeparator:
    """Bearings of the sirens in one window by time–frequency bin assignment (module docstring).

    Args:
        mics: ``(channels, 3)`` capsule positions, vehicle frame.
        sample_rate: Hz.
        coherence, min_share, min_bins, separation_deg, select_db: the assignment's constants.
        n_azimuth: bearing grid over 360°.
    """

    def __init__(
        self,
        mics: np.ndarray,
        sample_rate: int,
        *,
        coherence: float = COHERENCE,
        min_share: float = MIN_SHARE,
        min_bins: int = MIN_BINS,
        separation_deg: float = SEPARATION_DEG,
        select_db: float = SELECT_DB,
        n_azimuth: int = N_AZIMUTH,
    ) -> None:
        m = np.ascontiguousarray(mics, dtype=np.float64)
        if m.ndim != 2 or m.shape[1] != 3 or len(m) < 2:
            raise ValueError(f"mics must be (channels ≥ 2, 3); got {m.shape}")
        self.mics = m
        self.sample_rate = int(sample_rate)
        self.coherence = float(coherence)
        self.min_share = float(min_share)
        self.min_bins = int(min_bins)
        self.separation_deg = float(separation_deg)
        self.select_db = float(select_db)
        self.n_azimuth = int(n_azimuth)

    def __repr__(self) -> str:
        return (
            f"SourceSeparator({len(self.mics)} capsules, coherence={self.coherence:g}, "
            f"min_share={self.min_share:g}, separation={self.separation_deg:g}°)"
        )

    def responses(self, window: np.ndarray) -> np.ndarray:
        """``(kept bins, n_azimuth)`` steered responses ``r_s(θ)`` of the window's strong in-band
        time–frequency bins (module docstring, steps 1–3); ``window (channels, samples)``."""
        w = np.asarray(window, dtype=np.float64)
        if w.ndim != 2 or w.shape[0] != len(self.mics):
            raise ValueError(f"window must be ({len(self.mics)}, samples); got {w.shape}")
        pairs, bins, s_re, s_im, win = _plan(
            self.mics.tobytes(), len(self.mics), self.sample_rate, self.n_azimuth
        )
        if w.shape[1] < NFFT:
            return np.zeros((0, self.n_azimuth))
        frames = np.lib.stride_tricks.sliding_window_view(w, NFFT, axis=1)[:, ::HOP]  # (ch, T, NFFT)
        x = rfft(frames * win, axis=-1)[..., bins]  # (ch, T, F)
        power = (x.real**2 + x.imag**2).mean(axis=0)  # (T, F)
        keep = power > 10.0 ** (self.select_db / 10.0) * np.median(power)
        out = []
        for fi in np.flatnonzero(keep.any(axis=0)):
            xs = x[:, keep[:, fi], fi]  # (ch, S_f)
            cross = xs[pairs[:, 0]] * np.conj(xs[pairs[:, 1]])  # (pairs, S_f)
            phat = cross / np.maximum(np.abs(cross), 1e-30)
            # Re(phat · e^{jωτ}) summed over pairs, for every bearing
            out.append(phat.real.T @ s_re[fi] - phat.imag.T @ s_im[fi])
        if not out:
            return np.zeros((0, self.n_azimuth))
        return np.concatenate(out, axis=0) / len(pairs)

    def bearings(self, window: np.ndarray, max_sources: int = 3) -> list[float]:
        """Bearings (rad, (−π, π], 0 ahead, positive left) of up to ``max_sources`` sirens, the one
        owning the most bins first (module docstring, step 4). Empty when no bin stands out."""
        r = self.responses(window)
        step = 2.0 * math.pi / self.n_azimuth
        sep = math.radians(self.separation_deg)
        found: list[float] = []
        n_first = 0
        while len(r) >= self.min_bins and len(found) < max_sources:
            hits = r >= self.coherence
            count = hits.sum(axis=0)
            k = int(np.argmax(count + 1e-3 * r.sum(axis=0)))  # ties: the stronger summed response
            n = int(count[k])
            if n < max(self.min_bins, self.min_share * n_first):
                break
            theta = math.atan2(math.sin(k * step), math.cos(k * step))
            if any(abs(math.remainder(theta - t, 2.0 * math.pi)) < sep for t in found):
                break
            found.append(theta)
            n_first = n_first or n
            r = r[~hits[:, k]]
        return found

    def further(self, window: np.ndarray, known: list[float], max_sources: int = 3) -> list[float]:
        """Bearings of sirens other than ``known`` (rad), so that ``known`` plus the result holds at
        most ``max_sources``: the :meth:`bearings` that lie ``separation_deg`` from every known one
        and from each other — and only when :meth:`bearings` itself finds at least two sirens. A lone
        bearing that disagrees with the network's is more often a lobe of the one siren than a second
        siren (module docstring)."""
        found = self.bearings(window, max_sources)
        if len(found) < 2:
            return []
        sep = math.radians(self.separation_deg)
        taken = list(known)
        out: list[float] = []
        for theta in found:
            if len(taken) >= max_sources:
                break
            if all(abs(math.remainder(theta - t, 2.0 * math.pi)) >= sep for t in taken):
                out.append(theta)
                taken.append(theta)
        return out
