"""Audio features of SPEC §3 (issue 4): band-pass, log-mel, MFCC, and the labelled window batch.

Everything is numpy/scipy (no librosa). Spectral features use frames of :data:`FRAME_S` (25 ms) every
:data:`HOP_S` (10 ms), a periodic Hann window and an FFT of the next power of two ≥ the frame
(2048 points at 48 kHz). The mel scale is the HTK one, ``mel = 2595·log10(1 + f/700)``, with
triangular filters normalised to unit area (Slaney style), so a white spectrum gives equal energy
per band.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy.fft import dct, rfft
from scipy.signal import butter, sosfiltfilt

from makeway.perceive.audio.windows import WindowGrid
from makeway.sense.recording import Recording

BAND_HZ = (500.0, 1800.0)
"""The siren band of SPEC §3: band-pass and DOA frequency range."""
FRAME_S = 0.025
HOP_S = 0.010
LOG_FLOOR = 1e-10
"""Power floor before the logarithm (−100 dB re full scale²)."""


@functools.lru_cache(maxsize=16)
def _band_sos(sample_rate: int, low_hz: float, high_hz: float, order: int) -> np.ndarray:
    return np.asarray(butter(order, [low_hz, high_hz], btype="bandpass", fs=sample_rate, output="sos"))


def band_level_db(window: np.ndarray, sample_rate: int, band: tuple[float, float] = BAND_HZ) -> float:
    """The in-band level of ``window (channels, samples)``: 10·log10 of its mean square within
    ``band`` (Hz; default the siren band), power-averaged over the channels, in dB re a digital RMS
    of 1.0. Add the array's ``full_scale_db_spl`` for dB SPL."""
    x = np.atleast_2d(np.asarray(window, dtype=np.float64))
    n = x.shape[-1]
    f = np.fft.rfftfreq(n, 1.0 / sample_rate)
    sel = (f >= band[0]) & (f <= band[1])
    power = np.abs(np.fft.rfft(x, axis=-1)[:, sel]) ** 2
    mean_square = 2.0 * float(power.sum(axis=-1).mean()) / n**2
    return 10.0 * math.log10(max(mean_square, 1e-30))


def bandpass(
    x: np.ndarray,
    sample_rate: int,
    low_hz: float = BAND_HZ[0],
    high_hz: float = BAND_HZ[1],
    order: int = 4,
    axis: int = -1,
) -> np.ndarray:
    """Zero-phase Butterworth band-pass (order ``order`` per pass, second-order sections).

    ``sosfiltfilt`` runs the filter forward and backward: no delay, so inter-channel time differences
    survive, and the magnitude response is the Butterworth one squared. Works along ``axis``
    (default: the last, i.e. ``(channels, samples)`` or ``(samples,)``).
    """
    if not 0 < low_hz < high_hz < sample_rate / 2:
        raise ValueError(f"band {low_hz:g}–{high_hz:g} Hz must lie inside (0, {sample_rate / 2:g}) Hz")
    sos = _band_sos(int(sample_rate), float(low_hz), float(high_hz), int(order))
    return np.asarray(sosfiltfilt(sos, np.asarray(x, dtype=np.float64), axis=axis))


def frame_params(sample_rate: int) -> tuple[int, int, int]:
    """``(frame_len, hop, n_fft)`` in samples for the 25 ms / 10 ms framing."""
    frame = round(FRAME_S * sample_rate)
    hop = round(HOP_S * sample_rate)
    n_fft = 1 << (frame - 1).bit_length()
    return frame, hop, n_fft


def power_spectrogram(x: np.ndarray, sample_rate: int) -> np.ndarray:
    """``|STFT|²`` of ``x (..., samples)``: ``(..., n_fft // 2 + 1, frames)``.

    Frames start at sample 0 every hop; a signal shorter than one frame is zero-padded to one frame.
    """
    x = np.asarray(x, dtype=np.float64)
    frame, hop, n_fft = frame_params(sample_rate)
    n = x.shape[-1]
    if n < frame:
        x = np.concatenate([x, np.zeros((*x.shape[:-1], frame - n))], axis=-1)
        n = frame
    n_frames = 1 + (n - frame) // hop
    frames = np.lib.stride_tricks.sliding_window_view(x, frame, axis=-1)[..., ::hop, :][..., :n_frames, :]
    win = np.hanning(frame + 1)[:-1]  # periodic Hann
    spec = rfft(frames * win, n=n_fft, axis=-1)
    power = spec.real**2 + spec.imag**2
    return np.swapaxes(power, -1, -2)


def _hz_to_mel(f: np.ndarray | float) -> np.ndarray:
    return 2595.0 * np.log10(1.0 + np.asarray(f, dtype=np.float64) / 700.0)


def _mel_to_hz(m: np.ndarray) -> np.ndarray:
    return 700.0 * (10.0 ** (np.asarray(m) / 2595.0) - 1.0)


@functools.lru_cache(maxsize=16)
def mel_filterbank(
    sample_rate: int, n_fft: int, n_mels: int = 64, fmin: float = 0.0, fmax: float | None = None
) -> np.ndarray:
    """``(n_mels, n_fft // 2 + 1)`` triangular filters, equally spaced in mel, unit area."""
    top = sample_rate / 2.0 if fmax is None else float(fmax)
    edges = _mel_to_hz(np.linspace(_hz_to_mel(fmin), _hz_to_mel(top), n_mels + 2))
    freqs = np.fft.rfftfreq(n_fft, 1.0 / sample_rate)
    lo, mid, hi = edges[:-2, None], edges[1:-1, None], edges[2:, None]
    rise = (freqs[None, :] - lo) / np.maximum(mid - lo, 1e-9)
    fall = (hi - freqs[None, :]) / np.maximum(hi - mid, 1e-9)
    tri = np.maximum(0.0, np.minimum(rise, fall))
    tri *= 2.0 / np.maximum(hi - lo, 1e-9)  # Slaney area normalisation
    tri.setflags(write=False)
    return tri


def log_mel(
    x: np.ndarray, sample_rate: int, n_mels: int = 64, fmin: float = 0.0, fmax: float | None = None
) -> np.ndarray:
    """Log-mel power (natural log) of ``x (..., samples)``: ``(..., n_mels, frames)``."""
    power = power_spectrogram(x, sample_rate)
    _, _, n_fft = frame_params(sample_rate)
    fb = mel_filterbank(int(sample_rate), n_fft, int(n_mels), float(fmin), fmax)
    mel = np.einsum("mf,...ft->...mt", fb, power)
    return np.log(np.maximum(mel, LOG_FLOOR))


def mfcc(x: np.ndarray, sample_rate: int, n_mfcc: int = 20, n_mels: int = 64) -> np.ndarray:
    """MFCCs of ``x (..., samples)``: orthonormal DCT-II of the log-mel over mel bands,
    ``(..., n_mfcc, frames)``."""
    if not 1 <= n_mfcc <= n_mels:
        raise ValueError(f"n_mfcc must be in 1..{n_mels}")
    lm = log_mel(x, sample_rate, n_mels)
    return np.asarray(dct(lm, type=2, axis=-2, norm="ortho"))[..., :n_mfcc, :]


def window_batch(rec: Recording, labels: WindowGrid) -> np.ndarray:
    """The labelled windows of ``rec``: ``(n_windows, channels, window)`` float32 (a copy)."""
    if labels.sample_rate != rec.sample_rate:
        raise ValueError("labels and recording have different sample rates")
    audio = np.asarray(rec.audio, dtype=np.float32)
    if len(labels) == 0:
        return np.zeros((0, audio.shape[1], labels.window), dtype=np.float32)
    if int(labels.start[-1]) + labels.window > audio.shape[0]:
        raise ValueError("labels run past the end of the recording")
    idx = labels.start[:, None] + np.arange(labels.window)[None, :]
    return np.ascontiguousarray(np.transpose(audio[idx], (0, 2, 1)))
