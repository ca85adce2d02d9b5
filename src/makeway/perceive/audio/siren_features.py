"""Input features of the siren network (issue 4, SPEC §3): three views of one multichannel window.

One 0.5 s window ``(channels, samples)`` of the roof array at 48 kHz becomes

* ``wave`` ``(channels, samples / decimation)`` — the waveform stream of SPEC §3: band-passed
  500–1800 Hz (zero phase, so inter-channel delays survive), decimated to 8 kHz (the band ends far
  below the new Nyquist frequency, so nothing aliases and no timing information is lost), divided by
  the window's RMS over all channels (the level travels separately, in ``level``);
* ``spec`` ``(1, n_mels + n_mfcc, frames)`` — the spectral stream of SPEC §3: log-mel power
  (``n_mels`` bands over ``mel_fmin``–``mel_fmax``; power averaged over the capsules, which averages
  the uncorrelated wind noise down) stacked over its MFCCs, 25 ms frames every 10 ms. The mel range
  reaches above the 1800 Hz band edge on purpose: siren harmonics up to 4 kHz are what tells a siren
  from a horn or a squealing brake, and the detection stream is not used for timing;
* ``gcc`` ``(2·pairs, azimuths)`` — makeway's addition: for every capsule pair, the GCC-PHAT of
  the band-passed window (cross-spectrum smoothed over ≈ 47 Hz) read at the delay each candidate bearing
  would give (far field, ground plane), on a grid of ``n_azimuth`` bearings over 360°. The first
  ``pairs`` rows use every in-band bin, the next ``pairs`` only the bins whose cross-power stands
  :data:`~makeway.perceive.audio.doa.GCC_SELECT_DB` above the band's median (the siren's harmonics;
  zero rows when none does). Summing the rows gives SRP-PHAT; the network learns a better
  combination, and the map keeps the bearing axis explicit (the model's bearing head works on it);
* ``level`` ``(channels + 1,)`` — in-band level of each capsule and of their mean, in dB re full
  scale, shifted by :data:`LEVEL_OFFSET_DB` to lie near 0…1. Level is the main distance cue.

**Gain.** ``wave`` (unit RMS) and ``gcc`` (PHAT) do not change when the window is scaled; ``level``
and ``spec`` move by a known constant. :meth:`SirenFeatures.shift_gain` applies that change to
computed features, as if the window had been recorded ``g`` dB louder (``makeway audio train
--gain-augment``: training that cannot lean on the absolute level).

Everything is numpy/scipy, so the runtime needs no torch. :class:`SirenFeatures` is configured by a
plain dict (:meth:`SirenFeatures.config`) that the trained model stores in its ONNX metadata, so the
features at inference are exactly those of training.
"""

from __future__ import annotations

import functools
import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy.fft import dct, irfft, next_fast_len, rfft
from scipy.signal import sosfreqz

from makeway.perceive.audio.doa import GCC_SELECT_DB
from makeway.perceive.audio.features import BAND_HZ, LOG_FLOOR, _band_sos, frame_params, mel_filterbank
from makeway.perceive.audio.geometry import capsule_pairs, pair_delays
from makeway.sense.recording import REFERENCE_SAMPLE_RATE, reference_mics

__all__ = ["LEVEL_OFFSET_DB", "MIRROR_CHANNELS", "STREAMS", "SirenFeatureConfig", "SirenFeatures"]

STREAMS = ("wave", "spec", "gcc", "level")
MIRROR_CHANNELS = (4, 7, 6, 5, 0, 3, 2, 1)
"""Channel permutation that mirrors the reference array about its x axis (L↔R units, each unit's
left↔right capsules): new channel k = old channel ``MIRROR_CHANNELS[k]``; a source at θ is then
heard at −θ."""
LEVEL_OFFSET_DB = 100.0
"""``level`` = (dB re full scale + 100) / 100: −100 dBFS → 0, 0 dBFS → 1."""


@dataclass(frozen=True)
class SirenFeatureConfig:
    """Feature parameters (stored with a trained model; see the module docstring)."""

    sample_rate: int = REFERENCE_SAMPLE_RATE
    window_s: float = 0.5
    band_low_hz: float = BAND_HZ[0]
    band_high_hz: float = BAND_HZ[1]
    decimation: int = 6
    n_mels: int = 48
    n_mfcc: int = 16
    mel_fmin: float = 300.0
    mel_fmax: float = 4000.0
    spec_channels: tuple[int, ...] = (0, 4)
    gcc_resolution_hz: float = 46.875
    n_azimuth: int = 120
    mics: tuple[tuple[float, ...], ...] = tuple(tuple(float(v) for v in m) for m in reference_mics())

    @property
    def n_channels(self) -> int:
        return len(self.mics)

    @property
    def n_samples(self) -> int:
        return round(self.window_s * self.sample_rate)

    @property
    def pairs(self) -> np.ndarray:
        n = self.n_channels
        return capsule_pairs(n)

    def azimuths(self) -> np.ndarray:
        """The bearing grid (rad), ``n_azimuth`` points from 0, counter-clockwise."""
        return np.arange(self.n_azimuth) * (2.0 * math.pi / self.n_azimuth)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["mics"] = [list(m) for m in self.mics]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> SirenFeatureConfig:
        known = {k: v for k, v in d.items() if k in cls.__dataclass_fields__}
        if "mics" in known:
            known["mics"] = tuple(tuple(float(v) for v in m) for m in known["mics"])
        if "spec_channels" in known:
            known["spec_channels"] = tuple(int(v) for v in known["spec_channels"])
        return cls(**known)


@functools.lru_cache(maxsize=8)
def _band_mask(sample_rate: int, low_hz: float, high_hz: float, n_fft: int) -> np.ndarray:
    """|H(f)|² of the order-4 Butterworth band-pass on the ``n_fft`` rfft grid: applying it to a
    spectrum is the zero-phase forward-backward filter of
    :func:`~makeway.perceive.audio.features.bandpass` (up to the edges), at a fraction of the cost."""
    sos = _band_sos(sample_rate, low_hz, high_hz, 4)
    _, h = sosfreqz(sos, worN=np.fft.rfftfreq(n_fft, 1.0 / sample_rate), fs=sample_rate)
    mask = (np.abs(h) ** 2).astype(np.float32)
    mask.setflags(write=False)
    return mask


@functools.lru_cache(maxsize=8)
def _gcc_plan(config: SirenFeatureConfig, n_fft: int) -> tuple[int, int, int, np.ndarray]:
    """``(first_bin, block, n_blocks, steering)`` of the GCC map on the ``n_fft``-point spectrum:
    the in-band bins are averaged in blocks of ``block`` bins (≈ ``gcc_resolution_hz``), and
    ``steering`` ``(pairs, azimuths, n_blocks)`` (complex64) is ``exp(jωτ)`` at the block centres."""
    df = config.sample_rate / n_fft
    first = int(math.ceil(config.band_low_hz / df))
    last = int(math.floor(config.band_high_hz / df))
    block = max(1, round(config.gcc_resolution_hz / df))
    n_blocks = max(1, (last - first + 1) // block)
    centres = (first + block * np.arange(n_blocks) + (block - 1) / 2.0) * df
    mics = np.asarray(config.mics, dtype=np.float64)
    pairs = config.pairs
    az = config.azimuths()
    tau = pair_delays(mics, pairs, az)  # (pairs, azimuths) seconds
    steer = np.exp(1j * 2.0 * math.pi * tau[:, :, None] * centres[None, None, :]).astype(np.complex64)
    steer = np.concatenate([steer, steer], axis=0)  # the all-bin rows, then the selected-bin rows
    steer.setflags(write=False)
    return first, block, n_blocks, steer


class SirenFeatures:
    """Window → ``{"wave", "spec", "gcc", "level"}`` arrays (see the module docstring).

    ``transform(windows)`` takes ``(n, channels, samples)`` (or one ``(channels, samples)``
    window) at ``config.sample_rate`` and returns float32 arrays with a leading batch axis.
    """

    def __init__(self, config: SirenFeatureConfig | None = None) -> None:
        self.config = config if config is not None else SirenFeatureConfig()

    def __repr__(self) -> str:
        c = self.config
        return (
            f"SirenFeatures({c.n_channels} ch, {c.sample_rate} Hz, {c.window_s:g} s, "
            f"band {c.band_low_hz:g}–{c.band_high_hz:g} Hz, {c.n_azimuth} bearings)"
        )

    def shapes(self) -> dict[str, tuple[int, ...]]:
        """Per-window shape of each stream."""
        c = self.config
        frame, hop, _ = frame_params(c.sample_rate)
        n_frames = 1 + (c.n_samples - frame) // hop
        n_wave = -(-c.n_samples // c.decimation)
        return {
            "wave": (c.n_channels, n_wave),
            "spec": (1, c.n_mels + c.n_mfcc, n_frames),
            "gcc": (2 * len(c.pairs), c.n_azimuth),
            "level": (c.n_channels + 1,),
        }

    def _check(self, windows: np.ndarray) -> np.ndarray:
        w = np.asarray(windows, dtype=np.float64)
        if w.ndim == 2:
            w = w[None]
        c = self.config
        if w.ndim != 3 or w.shape[1] != c.n_channels or w.shape[2] != c.n_samples:
            raise ValueError(
                f"windows must be (n, {c.n_channels}, {c.n_samples}) "
                f"({c.n_channels} channels × {c.window_s:g} s at {c.sample_rate} Hz); got {w.shape}"
            )
        if not np.all(np.isfinite(w)):
            raise ValueError("windows contain NaN or infinite samples")
        return w

    def transform(self, windows: np.ndarray) -> dict[str, np.ndarray]:
        c = self.config
        w = self._check(windows)
        n = w.shape[-1]
        n_fft = next_fast_len(n + 1024, real=True)  # 1024 samples of padding against circular wrap
        mask = _band_mask(c.sample_rate, c.band_low_hz, c.band_high_hz, n_fft)
        spectrum = rfft(w, n=n_fft, axis=-1) * mask
        band = irfft(spectrum, n=n_fft, axis=-1)[..., :n]
        out: dict[str, np.ndarray] = {}

        # level: in-band mean power per capsule and over all capsules
        power = np.mean(band**2, axis=-1)  # (n, ch)
        all_power = power.mean(axis=1, keepdims=True)
        db = 10.0 * np.log10(np.maximum(np.concatenate([power, all_power], axis=1), LOG_FLOOR))
        out["level"] = ((db + LEVEL_OFFSET_DB) / 100.0).astype(np.float32)

        # wave: band-passed, decimated, unit RMS over the window
        dec = band[:, :, :: c.decimation]
        rms = np.sqrt(np.maximum(all_power, LOG_FLOOR))[:, :, None]
        out["wave"] = (dec / rms).astype(np.float32)

        out["spec"] = self._spectral(w).astype(np.float32)[:, None]
        out["gcc"] = self._gcc(spectrum, n_fft).astype(np.float32)
        return out

    def shift_gain(self, feats: dict[str, np.ndarray], gain_db: np.ndarray | float) -> dict[str, np.ndarray]:
        """The features of the same windows recorded ``gain_db`` louder (one value, or one per
        window), from already computed ``feats`` (module docstring, **Gain**): ``level`` moves by
        ``g / 100``; the log-mel rows of ``spec`` by ``g·ln(10)/10`` natural-log units (scaled like
        :meth:`transform`), and of the MFCCs only c0, by ``√n_mels`` times that (orthonormal DCT
        of a constant). ``wave`` and ``gcc`` are returned as they are. Exact while every power stays
        above the log floor (−100 dB re full scale)."""
        c = self.config
        out = dict(feats)
        first = next(iter(feats.values()))
        g = np.broadcast_to(np.asarray(gain_db, dtype=np.float32), (len(first),))
        if "level" in feats:
            out["level"] = (feats["level"] + g[:, None] / 100.0).astype(np.float32)
        if "spec" in feats:
            d_ln = g * np.float32(math.log(10.0) / 10.0)  # ln power per window
            spec = feats["spec"].copy()
            spec[:, :, : c.n_mels] += (d_ln / 10.0)[:, None, None, None]  # (n, 1, mels, frames)
            spec[:, :, c.n_mels] += (d_ln * math.sqrt(c.n_mels) / 50.0)[:, None, None]  # c0: (n, 1, frames)
            out["spec"] = spec.astype(np.float32)
        return out

    def _spectral(self, w: np.ndarray) -> np.ndarray:
        c = self.config
        frame, hop, n_fft = frame_params(c.sample_rate)
        n_frames = 1 + (w.shape[-1] - frame) // hop
        x = w[:, list(c.spec_channels)].astype(np.float32)
        frames = np.lib.stride_tricks.sliding_window_view(x, frame, axis=-1)[..., ::hop, :][..., :n_frames, :]
        win = np.hanning(frame + 1)[:-1].astype(np.float32)
        spec = rfft(frames * win, n=n_fft, axis=-1)
        power = (spec.real**2 + spec.imag**2).mean(axis=1)  # mean over capsules: (n, frames, bins)
        fb = mel_filterbank(c.sample_rate, n_fft, c.n_mels, c.mel_fmin, c.mel_fmax)
        mel = np.log(np.maximum(np.einsum("mf,ntf->nmt", fb, power), LOG_FLOOR))
        mfcc = dct(mel, type=2, axis=1, norm="ortho")[:, : c.n_mfcc]
        # log-mel in natural-log units is ~ −23…0 for full-scale audio; bring it near 0…1
        return np.concatenate([(mel + 23.0) / 10.0, mfcc / 50.0], axis=1)

    def _gcc(self, spectrum: np.ndarray, n_fft: int) -> np.ndarray:
        """The bearing map from the band-passed window's spectrum ``(n, channels, n_fft // 2 + 1)``.

        Cross-spectra of every pair are averaged over blocks of neighbouring bins (frequency
        smoothing, ≈ ``gcc_resolution_hz``), PHAT-weighted, and steered to every bearing of the grid.
        Over one block the phase of even the widest pair (0.96 m, 2.8 ms) turns by < 0.9 rad, so the
        averaging loses < 4 % coherence, as Welch averaging with a 21 ms frame would."""
        c = self.config
        first, block, n_blocks, steer = _gcc_plan(c, n_fft)
        x = spectrum[..., first : first + block * n_blocks].astype(np.complex64)
        pairs = c.pairs
        cross = (x[:, pairs[:, 0]] * np.conj(x[:, pairs[:, 1]])).reshape(len(x), len(pairs), n_blocks, block)
        cross = cross.mean(axis=3)  # (n, pairs, blocks)
        mag = np.abs(cross)
        phat = cross / np.maximum(mag, 1e-30)
        keep = mag > 10.0 ** (GCC_SELECT_DB / 10.0) * np.median(mag, axis=2, keepdims=True)
        n_keep = np.maximum(keep.sum(axis=2, keepdims=True), 1)
        sel_phat = np.where(keep, phat, 0.0) * (n_blocks / n_keep)
        both = np.concatenate([phat, sel_phat], axis=1).astype(np.complex64)  # (n, 2P, blocks)
        gcc = np.matmul(steer[None], both[:, :, :, None])[..., 0].real / n_blocks  # (n, 2P, A)
        return np.asarray(gcc)
