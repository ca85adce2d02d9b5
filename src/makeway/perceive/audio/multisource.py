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

**Is it a siren?** The assignment finds *sound sources*, not sirens: a point source of street
noise, a horn or birds owns bins as well, and the share rule (step 4) compares a source's bins
with the first siren's, so a loud street-noise source beside a distant siren easily passes it. A
further bearing is therefore reported only with two more checks:

* *not the known siren again*: fewer than :data:`KNOWN_SHARE` of its bins are also explained
  (``r ≥`` coherence) by a bearing within :data:`KNOWN_TOL_DEG` of a known siren — otherwise
  they are that siren's bins seen through a grating lobe;
* *a siren by the detector*: its bins alone, turned back into an array window (the STFT of every
  capsule masked to those bins, inverse STFT by overlap-add), are called a siren by ``judge``
  (by default the shipped siren network, :class:`~makeway.perceive.audio.siren_model.SirenModel`)
  at ``judge_threshold`` or above (by default the network's own decision threshold).

The checks need no new threshold on the network. :data:`KNOWN_TOL_DEG` and :data:`KNOWN_SHARE` were
set on training-split recordings (10 two-siren and 16 one-siren, ``audio simulate --split train``
with seeds 11 and 12) and on the one-siren recording of issue 21: most spurious further sources
that the network calls a siren have half or more of their bins explained by the known siren's
bearing too, and true second sirens almost never do.

The other constants (and the rules before the checks) were chosen on training-split recordings;
the held-out figures are in docs/results.md, section "Two sirens at once".
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import numpy as np
from scipy.fft import irfft, rfft

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
KNOWN_TOL_DEG = 8.0
"""A known siren's bearing is taken to explain a bin when a bearing this close to it does."""
KNOWN_SHARE = 0.5
"""A further source whose bins are this share or more explained by a known siren is that siren."""
JUDGE_THRESHOLD = 0.5
"""A further source is a siren when a given ``judge`` gives its masked window this probability or
more (the default judge uses its network's own decision threshold instead)."""

Judge = Callable[[np.ndarray], np.ndarray]
"""P(siren) of array windows ``(n, channels, samples)``, shape ``(n,)``."""


def default_judge() -> tuple[Judge, float]:
    """The shipped siren detector network (no localizer or rangers; windows taken at the network's
    own level scale) as a :data:`Judge`, and its decision threshold."""
    from makeway.perceive.audio.siren_model import SirenModel

    model = SirenModel(threads=2, localizer=False, ranger=False)
    return (lambda windows: model.predict(windows).prob), model.threshold


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
        judge: P(siren) of array windows, for :meth:`further` (module docstring; ``None``: the
            shipped siren network, :func:`default_judge`, loaded on first use).
        judge_threshold: a further source's masked window must reach this probability (``None``:
            the default judge's network threshold, or :data:`JUDGE_THRESHOLD` for a given judge).
        check_siren: ``False`` leaves out both siren checks of :meth:`further` (for comparison).
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
        judge: Judge | None = None,
        judge_threshold: float | None = None,
        check_siren: bool = True,
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
        self.judge = judge
        self.judge_threshold = judge_threshold
        self.check_siren = bool(check_siren)

    def __repr__(self) -> str:
        return (
            f"SourceSeparator({len(self.mics)} capsules, coherence={self.coherence:g}, "
            f"min_share={self.min_share:g}, separation={self.separation_deg:g}°)"
        )

    def responses(self, window: np.ndarray) -> np.ndarray:
        """``(kept bins, n_azimuth)`` steered responses ``r_s(θ)`` of the window's strong in-band
        time–frequency bins (module docstring, steps 1–3); ``window (channels, samples)``."""
        return self._analyse(window)[0]

    def _analyse(self, window: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(r, frame, bin, spectra)``: the responses of :meth:`responses`, each kept bin's frame
        index and its index into the full rfft, and the STFT ``(channels, frames, NFFT/2 + 1)``."""
        w = np.asarray(window, dtype=np.float64)
        if w.ndim != 2 or w.shape[0] != len(self.mics):
            raise ValueError(f"window must be ({len(self.mics)}, samples); got {w.shape}")
        pairs, bins, s_re, s_im, win = _plan(
            self.mics.tobytes(), len(self.mics), self.sample_rate, self.n_azimuth
        )
        empty = np.zeros(0, dtype=np.int64)
        if w.shape[1] < NFFT:
            return np.zeros((0, self.n_azimuth)), empty, empty, np.zeros((len(w), 0, NFFT // 2 + 1))
        frames = np.lib.stride_tricks.sliding_window_view(w, NFFT, axis=1)[:, ::HOP]  # (ch, T, NFFT)
        spectra = rfft(frames * win, axis=-1)  # (ch, T, NFFT/2 + 1)
        x = spectra[..., bins]  # (ch, T, F)
        power = (x.real**2 + x.imag**2).mean(axis=0)  # (T, F)
        keep = power > 10.0 ** (self.select_db / 10.0) * np.median(power)
        out, t_idx, f_idx = [], [], []
        for fi in np.flatnonzero(keep.any(axis=0)):
            ts = np.flatnonzero(keep[:, fi])
            xs = x[:, ts, fi]  # (ch, S_f)
            cross = xs[pairs[:, 0]] * np.conj(xs[pairs[:, 1]])  # (pairs, S_f)
            phat = cross / np.maximum(np.abs(cross), 1e-30)
            # Re(phat · e^{jωτ}) summed over pairs, for every bearing
            out.append(phat.real.T @ s_re[fi] - phat.imag.T @ s_im[fi])
            t_idx.append(ts)
            f_idx.append(np.full(len(ts), bins[fi]))
        if not out:
            return np.zeros((0, self.n_azimuth)), empty, empty, spectra
        r = np.concatenate(out, axis=0) / len(pairs)
        return r, np.concatenate(t_idx), np.concatenate(f_idx), spectra

    def _assign(self, r: np.ndarray, max_sources: int) -> list[tuple[float, np.ndarray]]:
        """Step 4 of the module docstring on responses ``r``: ``(bearing, indices of its bins in
        r)`` per source, the one owning the most bins first."""
        step = 2.0 * math.pi / self.n_azimuth
        sep = math.radians(self.separation_deg)
        found: list[tuple[float, np.ndarray]] = []
        idx = np.arange(len(r))
        n_first = 0
        while len(r) >= self.min_bins and len(found) < max_sources:
            hits = r >= self.coherence
            count = hits.sum(axis=0)
            k = int(np.argmax(count + 1e-3 * r.sum(axis=0)))  # ties: the stronger summed response
            n = int(count[k])
            if n < max(self.min_bins, self.min_share * n_first):
                break
            theta = math.atan2(math.sin(k * step), math.cos(k * step))
            if any(abs(math.remainder(theta - t, 2.0 * math.pi)) < sep for t, _ in found):
                break
            found.append((theta, idx[hits[:, k]]))
            n_first = n_first or n
            r, idx = r[~hits[:, k]], idx[~hits[:, k]]
        return found

    def bearings(self, window: np.ndarray, max_sources: int = 3) -> list[float]:
        """Bearings (rad, (−π, π], 0 ahead, positive left) of up to ``max_sources`` sound sources,
        the one owning the most bins first (module docstring, step 4). Empty when no bin stands
        out. No check here that a source is a siren (that is :meth:`further`'s)."""
        return [theta for theta, _ in self._assign(self.responses(window), max_sources)]

    def further(self, window: np.ndarray, known: list[float], max_sources: int = 3) -> list[float]:
        """Bearings of sirens other than ``known`` (rad), so that ``known`` plus the result holds at
        most ``max_sources``: the :meth:`bearings` that lie ``separation_deg`` from every known one
        and from each other — and only when :meth:`bearings` itself finds at least two sources. A lone
        bearing that disagrees with the network's is more often a lobe of the one siren than a second
        siren. Each such bearing must also pass the siren checks of the module docstring (unless
        ``check_siren`` is off): its bins are not mostly the known siren's, and ``judge`` calls
        its masked window a siren."""
        r, t_idx, f_idx, spectra = self._analyse(window)
        found = self._assign(r, max_sources)
        if len(found) < 2:
            return []
        sep = math.radians(self.separation_deg)
        taken = list(known)
        cand: list[tuple[float, np.ndarray]] = []
        for theta, own in found:
            if len(taken) >= max_sources:
                break
            if all(abs(math.remainder(theta - t, 2.0 * math.pi)) >= sep for t in taken):
                if self.check_siren and self._known_share(r[own], known) >= KNOWN_SHARE:
                    continue
                cand.append((theta, own))
                taken.append(theta)
        if not cand or not self.check_siren:
            return [theta for theta, _ in cand]
        masked = np.stack(
            [self._masked(np.asarray(window), spectra, t_idx[own], f_idx[own]) for _, own in cand]
        )
        judge, threshold = self._judge()
        prob = np.asarray(judge(masked), dtype=np.float64).reshape(-1)
        return [theta for (theta, _), p in zip(cand, prob, strict=True) if p >= threshold]

    def _known_share(self, r: np.ndarray, known: list[float]) -> float:
        """Share of the bins (rows of ``r``) that a bearing within :data:`KNOWN_TOL_DEG` of a known
        one explains (``r ≥`` coherence)."""
        if not len(r) or not known:
            return 0.0
        step = 2.0 * math.pi / self.n_azimuth
        half = int(math.ceil(math.radians(KNOWN_TOL_DEG) / step))
        near = np.concatenate([round(t / step) + np.arange(-half, half + 1) for t in known]) % self.n_azimuth
        return float(np.mean(r[:, near].max(axis=1) >= self.coherence))

    def _masked(
        self, window: np.ndarray, spectra: np.ndarray, t_idx: np.ndarray, f_idx: np.ndarray
    ) -> np.ndarray:
        """The window ``(channels, samples)`` with only the time–frequency bins ``(t_idx, f_idx)``
        left on every capsule: the masked STFT, inverted by overlap-add and divided by the summed
        analysis windows (samples that no frame covers stay 0)."""
        *_, win = _plan(self.mics.tobytes(), len(self.mics), self.sample_rate, self.n_azimuth)
        mask = np.zeros(spectra.shape[1:], dtype=bool)
        mask[t_idx, f_idx] = True
        frames = irfft(spectra * mask, n=NFFT, axis=-1)  # (ch, T, NFFT)
        out = np.zeros(window.shape, dtype=np.float64)
        wsum = np.zeros(window.shape[1])
        for k in range(spectra.shape[1]):
            out[:, k * HOP : k * HOP + NFFT] += frames[:, k]
            wsum[k * HOP : k * HOP + NFFT] += win
        return (out / np.maximum(wsum, 0.5)).astype(np.float32)

    def _judge(self) -> tuple[Judge, float]:
        """The judge and its threshold (class docstring); the default network is loaded once."""
        if self.judge is None:
            self.judge, shipped = default_judge()
            if self.judge_threshold is None:
                self.judge_threshold = shipped
        threshold = self.judge_threshold if self.judge_threshold is not None else JUDGE_THRESHOLD
        return self.judge, float(threshold)
