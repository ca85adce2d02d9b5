"""Moving-source microphone-array simulator (issue 4): what the car-roof array hears.

pyroomacoustics has no moving sources, so propagation is done here, sample by sample.

**Propagation delay (Doppler).** For a capsule at world position ``m(t)`` (the vehicle-frame position
rotated and translated by the ego pose at ``t``) and a source moving along ``s(·)``, the sound heard at
``t`` left the source at the emission time ``t_e`` solving ``c·(t − t_e) = |m(t) − s(t_e)|``. It is
found by fixed-point iteration ``t_e ← t − |m(t) − s(t_e)|/c`` from ``t_e = t − |m(t) − s(t)|/c``;
each step shrinks the error by the source Mach number (< 0.1), so ≤ 8 iterations reach 1e-10 s.
Emission times are solved exactly on a grid every :data:`DELAY_GRID` samples (0.67 ms) and
interpolated linearly in between (the delay is smooth: the interpolation error stays < 0.01 sample
even for a source passing 3 m away at 30 m/s). Doppler shift, changing level and changing
inter-capsule delays all follow from ``t_e``.

**Fractional delay.** The received sample is the source signal read at ``t_e``: a 16-tap
Kaiser-windowed sinc (β = 6, rows normalised to unit DC gain) looked up in a table of 1024
fractional phases (quantisation ≤ 1/2048 sample ≈ 10 ns) — flat to about −0.1 dB up to ~15 kHz at
48 kHz. ``kernel="lagrange"`` uses 4-tap cubic Lagrange instead (4× cheaper, some high-frequency
droop).

**Level.** Spherical spreading ``1/r`` with ``r`` clamped at :data:`MIN_DISTANCE_M` (1 m, where the
source level is defined); an optional source directivity (sirens point forward: up to
``rear_attenuation_db`` lost straight behind, ``A·(1 − cos φ)/2`` dB at angle ``φ`` off the
source's direction of travel); the convective amplification of a moving source (≤ ±10 % at 30 m/s)
is neglected.

**Ground reflection.** One image source mirrored in the ground plane ``z = 0`` with a frequency-
independent reflection coefficient (asphalt is acoustically hard: 0.7–0.95; 0.8 default).

**Air absorption.** ISO 9613-1 pure-tone attenuation at 20 °C, 50 % RH, 101.325 kPa
(:func:`air_absorption_db_per_m`: ≈ 4.7 dB/km at 1 kHz, ≈ 30 dB/km at 4 kHz, ≈ 105 dB/km at 8 kHz),
applied per source as a zero-phase, distance-dependent gain in a 2048-sample STFT (hop 1024,
√Hann analysis and synthesis windows, i.e. a short zero-phase FIR updated every 21 ms). Being
zero-phase it adds no delay, so inter-capsule timing is untouched.

**Ambient street noise** is placed by :func:`place_fixed_sources` as a few point sources at fixed
positions relative to the car (the traffic around it moves with it); their delays are constant, so
they are applied exactly in the frequency domain together with spreading, ground reflection and
air absorption. The noise is thus coherent per source but, summed over a few sources, only partly
correlated across the capsules.

**Wind noise** (:func:`wind_noise`) is independent per capsule. The relative air speed is
``U = |ego speed| + ambient wind``. Following Strasberg's dimensional analysis of microphone wind
noise (pressure ∝ ρU², frequency ∝ U/D), the overall level is ``L_10 + 40·log10(U / 10 m/s)`` dB SPL
with a spectrum ``∝ 1/(1 + (f/f_c)²)``, ``f_c = 3 Hz·U/(m/s)`` — at a fixed frequency above ``f_c``
the level grows as ``50·log10 U``. ``L_10`` (level at 10 m/s) is 60–72 dB SPL for a windscreened
capsule on a car roof. A slow log-normal gust envelope (σ ≈ 3 dB, < 2 Hz) modulates it.

**Calibration.** Simulated pressures are in pascal; :data:`FULL_SCALE_PA` (digital 1.0 = 135 dB SPL
peak, a typical MEMS acoustic overload point) converts them to full-scale units: a digital RMS of
1.0 stands for 135 dB SPL, which the simulator states as ``full_scale_db_spl`` in ``array.yaml``
(:data:`makeway.sense.recording.REFERENCE_FULL_SCALE_DB_SPL`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from makeway.physics import P_REF_PA, SPEED_OF_SOUND
from makeway.sense.recording import REFERENCE_FULL_SCALE_DB_SPL, Trajectory
from makeway.sim.siren import AudioSource

P_REF = P_REF_PA
FULL_SCALE_DB_SPL = REFERENCE_FULL_SCALE_DB_SPL
FULL_SCALE_PA = P_REF * 10 ** (FULL_SCALE_DB_SPL / 20)
MIN_DISTANCE_M = 1.0
DELAY_GRID = 32
"""Emission times are solved exactly every DELAY_GRID samples and interpolated in between."""
SELF_NOISE_DB_SPL = 30.0
"""Capsule self-noise (white), as for a MEMS microphone with ~64 dB SNR."""


def db_spl_to_pa(level_db: float) -> float:
    """RMS pressure (Pa) of a sound pressure level (dB re 20 µPa)."""
    return P_REF * 10 ** (level_db / 20.0)


# ------------------------------------------------------------------------------------- air absorption


def air_absorption_db_per_m(
    freq_hz: np.ndarray | float,
    temp_c: float = 20.0,
    rel_humidity: float = 50.0,
    pressure_kpa: float = 101.325,
) -> np.ndarray:
    """Pure-tone atmospheric attenuation (dB per metre) following the ISO 9613-1 formulas."""
    f = np.asarray(freq_hz, dtype=np.float64)
    T = temp_c + 273.15
    T0 = 293.15
    T01 = 273.16
    pa = pressure_kpa / 101.325
    c_sat = -6.8346 * (T01 / T) ** 1.261 + 4.6151
    h = rel_humidity * 10**c_sat / pa  # molar concentration of water vapour, %
    fr_o = pa * (24.0 + 4.04e4 * h * (0.02 + h) / (0.391 + h))
    fr_n = pa * (T / T0) ** -0.5 * (9.0 + 280.0 * h * math.exp(-4.170 * ((T / T0) ** (-1.0 / 3.0) - 1.0)))
    relax = (T / T0) ** -2.5 * (
        0.01275 * math.exp(-2239.1 / T) / (fr_o + f**2 / fr_o)
        + 0.1068 * math.exp(-3352.0 / T) / (fr_n + f**2 / fr_n)
    )
    return 8.686 * f**2 * (1.84e-11 / pa * (T / T0) ** 0.5 + relax)


def apply_air_absorption(
    x: np.ndarray, distance_at: np.ndarray, sample_rate: int, *, frame: int = 2048
) -> np.ndarray:
    """Attenuate ``x (n, channels)`` by air absorption over the distance in ``distance_at (n,)``.

    A zero-phase gain per STFT frame (√Hann windows, hop ``frame/2``) for the distance at the
    frame centre; the gain is 1 at DC, so short distances leave the signal untouched.
    """
    x2 = x if x.ndim == 2 else x[:, None]
    n, channels = x2.shape
    hop = frame // 2
    window = np.sqrt(0.5 - 0.5 * np.cos(2 * np.pi * np.arange(frame) / frame))  # periodic √Hann
    alpha = air_absorption_db_per_m(np.fft.rfftfreq(frame, 1.0 / sample_rate))
    n_frames = (n + frame) // hop + 1
    padded_len = (n_frames - 1) * hop + frame
    starts = np.arange(n_frames) * hop - hop  # frame k covers [start, start + frame) in signal samples
    centres = np.clip(starts + frame // 2, 0, n - 1)
    gains = 10 ** (-np.outer(distance_at[centres], alpha) / 20.0)  # (frames, bins)
    out = np.zeros((padded_len, channels))
    for ch in range(channels):
        buf = np.zeros(padded_len)
        buf[hop : hop + n] = x2[:, ch]
        frames = np.lib.stride_tricks.sliding_window_view(buf, frame)[::hop][:n_frames] * window
        spec = np.fft.rfft(frames, axis=1) * gains
        y = np.fft.irfft(spec, n=frame, axis=1) * window
        acc = np.zeros((n_frames + 1, hop))  # overlap-add at 50 %: each frame is two half-frames
        acc[:n_frames] += y[:, :hop]
        acc[1:] += y[:, hop:]
        out[:, ch] = acc.reshape(-1)
    res = out[hop : hop + n]
    return res if x.ndim == 2 else res[:, 0]


# ---------------------------------------------------------------------------------- fractional delay


@functools.lru_cache(maxsize=8)
def _kernel_table(kernel: str, phases: int = 1024) -> tuple[np.ndarray, np.ndarray]:
    """``(offsets (taps,), table (taps, phases + 1))``: tap ``k`` weight for fractional part j/phases."""
    frac = np.arange(phases + 1) / phases
    if kernel == "sinc":
        taps, beta = 16, 6.0
        offsets = np.arange(-taps // 2 + 1, taps // 2 + 1)
        x = offsets[:, None] - frac[None, :]
        u = np.clip(x / (taps / 2), -1.0, 1.0)
        table = np.sinc(x) * np.i0(beta * np.sqrt(1.0 - u**2)) / np.i0(beta)
        table /= table.sum(axis=0, keepdims=True)
    elif kernel == "lagrange":
        offsets = np.array([-1, 0, 1, 2])
        d = frac
        table = np.stack(
            [
                -d * (d - 1) * (d - 2) / 6.0,
                (d + 1) * (d - 1) * (d - 2) / 2.0,
                -(d + 1) * d * (d - 2) / 2.0,
                (d + 1) * d * (d - 1) / 6.0,
            ]
        )
    else:
        raise ValueError(f"unknown interpolation kernel {kernel!r} (sinc or lagrange)")
    return offsets, np.ascontiguousarray(table, dtype=np.float32)


def read_fractional(signal: np.ndarray, positions: np.ndarray, kernel: str = "sinc") -> np.ndarray:
    """Band-limited read of ``signal`` at fractional sample ``positions`` (zero outside the signal).

    Only the stretch of ``signal`` the kernel's taps reach is copied, so reading a short hop of a
    long recording costs the hop, not the recording.
    """
    offsets, table = _kernel_table(kernel)
    phases = table.shape[1] - 1
    sig = np.asarray(signal, np.float32)
    pos = np.asarray(positions, dtype=np.float64)
    out = np.zeros(len(pos), dtype=np.float32)
    if not len(pos):
        return out
    i0 = np.floor(pos)
    ph = np.rint((pos - i0) * phases).astype(np.intp)
    # far outside the signal every tap lands in zeros, so the read is 0
    pad = len(offsets) + 2
    base = np.clip(i0, -pad - offsets.min(), len(sig) + pad - 1 - offsets.max()).astype(np.intp)
    lo = int(base.min()) + int(offsets.min())
    hi = int(base.max()) + int(offsets.max()) + 1
    window = np.zeros(hi - lo, dtype=np.float32)
    a, b = max(lo, 0), min(hi, len(sig))
    if b > a:
        window[a - lo : b - lo] = sig[a:b]
    idx = base - lo
    for m, k in enumerate(offsets):
        out += window[idx + k] * table[m][ph]
    return out


# ------------------------------------------------------------------------------- geometry and delays


def mic_world_positions(ego: Trajectory, mics: np.ndarray, times: np.ndarray) -> np.ndarray:
    """World positions ``(len(times), M, 3)`` of vehicle-frame capsules ``mics (M, 3)`` at ``times``."""
    ex, ey = ego.position(times)
    yaw = ego.heading(times)
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    mx, my, mz = mics[:, 0][None, :], mics[:, 1][None, :], mics[:, 2][None, :]
    out = np.empty((len(times), len(mics), 3))
    out[..., 0] = ex[:, None] + c * mx - s * my
    out[..., 1] = ey[:, None] + s * mx + c * my
    out[..., 2] = mz
    return out


def emission_times(
    times: np.ndarray,
    receiver: np.ndarray,
    source: Trajectory,
    source_z: float,
    c: float = SPEED_OF_SOUND,
    max_iter: int = 12,
    tol: float = 1e-10,
) -> tuple[np.ndarray, np.ndarray]:
    """Solve ``c·(t − t_e) = |receiver(t) − source(t_e)|`` for each time.

    Args:
        times: reception times ``(n,)``.
        receiver: receiver world positions ``(n, 3)`` at those times.
        source: the source's world trajectory (positions held beyond its span).
        source_z: source height (negative for the ground image).

    Returns:
        ``(t_e, path_length)`` both ``(n,)``.
    """
    t = np.asarray(times, dtype=np.float64)

    def dist(te: np.ndarray) -> np.ndarray:
        sx, sy = source.position(te)
        return np.sqrt(
            (receiver[:, 0] - sx) ** 2 + (receiver[:, 1] - sy) ** 2 + (receiver[:, 2] - source_z) ** 2
        )

    d = dist(t)
    te = t - d / c
    for _ in range(max_iter):
        d = dist(te)
        new = t - d / c
        done = float(np.max(np.abs(new - te))) < tol if len(t) else True
        te = new
        if done:
            break
    return te, dist(te)


@dataclass
class PointSource:
    """A moving sound source for :func:`simulate_array`.

    ``signal``: the emitted pressure (Pa) as heard 1 m from the source, sampled at the simulation
    rate, its first sample emitted at time ``t0`` (s; negative so that sound already on its way at
    t = 0 exists). ``trajectory``: world ``(x, y)`` over time, covering ``t0`` … end.
    """

    signal: np.ndarray
    t0: float
    trajectory: Trajectory
    height_m: float = 1.5
    reflection: float = 0.8
    rear_attenuation_db: float = 0.0
    air_absorption: bool = True


def propagation_delays(
    source: PointSource, ego: Trajectory, mics: np.ndarray, times: np.ndarray, c: float = SPEED_OF_SOUND
) -> np.ndarray:
    """Direct-path delays ``t − t_e`` (s), shape ``(len(times), M)``."""
    world = mic_world_positions(ego, np.asarray(mics, dtype=np.float64), np.asarray(times, dtype=np.float64))
    out = np.empty(world.shape[:2])
    for m in range(world.shape[1]):
        te, _ = emission_times(times, world[:, m], source.trajectory, source.height_m, c)
        out[:, m] = times - te
    return out


def _directivity_gain(source: PointSource, te: np.ndarray, receiver: np.ndarray) -> np.ndarray:
    if source.rear_attenuation_db <= 0:
        return np.ones(len(te))
    vx, vy = source.trajectory.velocity(te)
    sx, sy = source.trajectory.position(te)
    dx, dy = receiver[:, 0] - sx, receiver[:, 1] - sy
    speed = np.hypot(vx, vy)
    cos_phi = (vx * dx + vy * dy) / np.maximum(speed * np.hypot(dx, dy), 1e-9)
    cos_phi = np.where(speed > 0.5, cos_phi, 1.0)
    return 10 ** (-source.rear_attenuation_db * (1.0 - cos_phi) / 2.0 / 20.0)


def simulate_array(
    sources: Sequence[PointSource],
    ego: Trajectory,
    mics: np.ndarray,
    n_samples: int,
    sample_rate: int = 48_000,
    *,
    c: float = SPEED_OF_SOUND,
    kernel: str = "sinc",
    grid: int = DELAY_GRID,
    start_s: float = 0.0,
) -> np.ndarray:
    """Pressure (Pa) at each capsule, ``(n_samples, M)`` float64, from moving ``sources``.

    Sample ``i`` is heard at ``t = start_s + i / sample_rate``; ``mics (M, 3)`` are vehicle-frame
    positions moved with the ego pose. See the module docstring for the physics. A later
    ``start_s`` renders a stretch of a longer scene (the closed loop renders hop by hop:
    :class:`makeway.sim.live_array.LiveArraySimulator`).
    """
    mics = np.asarray(mics, dtype=np.float64)
    n_mics = len(mics)
    out = np.zeros((n_samples, n_mics))
    t = start_s + np.arange(n_samples) / sample_rate
    tg = start_s + np.arange(0, n_samples + grid, grid) / sample_rate
    world = mic_world_positions(ego, mics, tg)
    centre = world.mean(axis=1)
    for src in sources:
        sig = np.asarray(src.signal, dtype=np.float32)
        part = np.zeros((n_samples, n_mics))
        paths = [(src.height_m, 1.0)]
        if src.reflection > 0:
            paths.append((-src.height_m, float(src.reflection)))
        for m in range(n_mics):
            for z, coef in paths:
                te_g, r_g = emission_times(tg, world[:, m], src.trajectory, z, c)
                gain_g = coef / np.maximum(r_g, MIN_DISTANCE_M) * _directivity_gain(src, te_g, world[:, m])
                te = np.interp(t, tg, te_g)
                values = read_fractional(sig, (te - src.t0) * sample_rate, kernel)
                part[:, m] += values * np.interp(t, tg, gain_g)
        if src.air_absorption:
            _, r_c = emission_times(tg, centre, src.trajectory, src.height_m, c)
            part = apply_air_absorption(part, np.interp(t, tg, r_c), sample_rate)
        out += part
    return out


# ------------------------------------------------------------------------------------ ambient noise


def place_fixed_sources(
    signals: Sequence[np.ndarray],
    positions: np.ndarray,
    mics: np.ndarray,
    n_samples: int,
    sample_rate: int = 48_000,
    *,
    reflection: float = 0.8,
    c: float = SPEED_OF_SOUND,
) -> np.ndarray:
    """Pressure ``(n_samples, M)`` from sources at fixed vehicle-frame ``positions (K, 3)``.

    ``signals[k]`` is source k's pressure at 1 m, at least ``n_samples`` long plus a pre-roll: the
    last ``n_samples + pre`` samples are used, ``pre`` covering the longest delay (0.25 s of pre-roll
    covers sources up to ~80 m). Delays, ``1/r``
    spreading, the ground image and air absorption are applied exactly in the frequency domain.
    """
    mics = np.asarray(mics, dtype=np.float64)
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    images = positions * np.array([1.0, 1.0, -1.0])
    d_dir = np.linalg.norm(mics[None, :, :] - positions[:, None, :], axis=2)  # (K, M)
    d_img = np.linalg.norm(mics[None, :, :] - images[:, None, :], axis=2)
    pre = int(math.ceil(max(d_dir.max(initial=0.0), d_img.max(initial=0.0)) / c * sample_rate)) + 64
    nfft = _fast_len(n_samples + pre)
    f = np.fft.rfftfreq(nfft, 1.0 / sample_rate)
    alpha = air_absorption_db_per_m(f)
    acc = np.zeros((len(mics), len(f)), dtype=np.complex128)
    for k, sig in enumerate(signals):
        x = np.asarray(sig, dtype=np.float64)
        if len(x) < n_samples + pre:
            raise ValueError(f"fixed source signal has {len(x)} samples, needs {n_samples + pre}")
        spec = np.fft.rfft(x[-(n_samples + pre) :], nfft)
        for dists, coef in ((d_dir[k], 1.0), (d_img[k], reflection)):
            if coef == 0:
                continue
            # air absorption over the mean path (capsules lie within 1 m: < 0.1 dB apart at 8 kHz)
            shaped = spec * (coef * 10 ** (-alpha * float(dists.mean()) / 20))
            for m, d in enumerate(dists):
                acc[m] += shaped * (_phasor(len(f), f[1] * d / c) / max(float(d), MIN_DISTANCE_M))
    out = np.empty((n_samples, len(mics)))
    for m in range(len(mics)):
        out[:, m] = np.fft.irfft(acc[m], nfft)[pre : pre + n_samples]
    return out


def _phasor(n_bins: int, cycles_per_bin: float) -> np.ndarray:
    """``exp(−2πi·k·cycles_per_bin)`` for k = 0 … n_bins − 1 by repeated multiplication (float64:
    the accumulated error stays ~1e-11 over 10⁶ bins)."""
    out = np.full(n_bins, np.exp(-2j * np.pi * cycles_per_bin))
    out[0] = 1.0
    return np.cumprod(out)


def _fast_len(n: int) -> int:
    """The smallest 2^a·3^b·5^c ≥ n (fast FFT sizes)."""
    best = 1 << int(math.ceil(math.log2(max(n, 1))))
    p5 = 1
    while p5 < best:
        p35 = p5
        while p35 < best:
            v = p35
            while v < n:
                v *= 2
            best = min(best, v)
            p35 *= 3
        p5 *= 5
    return best


def a_weighting_db(freq_hz: np.ndarray) -> np.ndarray:
    """IEC 61672 A-weighting (dB) at ``freq_hz``."""
    f2 = np.asarray(freq_hz, dtype=np.float64) ** 2
    num = 12194.0**2 * f2**2
    den = (f2 + 20.6**2) * np.sqrt((f2 + 107.7**2) * (f2 + 737.9**2)) * (f2 + 12194.0**2)
    with np.errstate(divide="ignore"):
        return 20 * np.log10(np.maximum(num / den, 1e-30)) + 2.0


def a_weighted_level_db(x: np.ndarray, sample_rate: int) -> float:
    """Equivalent A-weighted level (dB(A) re 20 µPa) of pressure ``x`` (Pa), averaged over channels."""
    x2 = np.asarray(x, dtype=np.float64)
    x2 = x2[:, None] if x2.ndim == 1 else x2
    n = x2.shape[0]
    spec = np.abs(np.fft.rfft(x2, axis=0)) ** 2
    spec[1:] *= 2.0
    if n % 2 == 0:
        spec[-1] /= 2.0
    w = 10 ** (a_weighting_db(np.fft.rfftfreq(n, 1.0 / sample_rate)) / 10.0)
    power = float((spec * w[:, None]).sum() / n**2 / x2.shape[1])
    return 10 * math.log10(max(power, 1e-30) / P_REF**2)


def _shaped_noise(n: int, sample_rate: int, power_of_f: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Gaussian noise with power spectrum ∝ ``power_of_f`` (sampled on rfftfreq(n)), unit RMS."""
    spec = (rng.standard_normal(n // 2 + 1) + 1j * rng.standard_normal(n // 2 + 1)) * np.sqrt(power_of_f)
    spec[0] = 0.0
    y = np.fft.irfft(spec, n)
    return y / max(float(np.sqrt(np.mean(y**2))), 1e-12)


def _smooth_envelope(
    n: int, sample_rate: int, rng: np.random.Generator, sigma_db: float, max_hz: float
) -> np.ndarray:
    """A log-normal amplitude envelope (≈ ``sigma_db`` dB spread) varying slower than ``max_hz``."""
    step = max(1, int(sample_rate / (4 * max_hz)))
    knots = rng.standard_normal(n // step + 3)
    kt = np.arange(len(knots)) * step
    db = np.interp(np.arange(n), kt, knots) * sigma_db
    return 10 ** (db / 20.0)


def generated_street_noise(n: int, sample_rate: int, rng: np.random.Generator) -> np.ndarray:
    """Street-like noise with no data: unit RMS, used when the real recordings are absent.

    Broadband road-traffic noise (tyre/road: power ∝ 1/(1 + (f/800 Hz)²), high-passed below 40 Hz),
    a low engine hum (harmonics of 25–60 Hz) and slow level swells of passing vehicles.
    """
    f = np.fft.rfftfreq(n, 1.0 / sample_rate)
    fc = rng.uniform(500.0, 1200.0)
    power = 1.0 / (1.0 + (f / fc) ** 2) * (f / (f + 40.0)) ** 4
    x = _shaped_noise(n, sample_rate, power, rng)
    t = np.arange(n) / sample_rate
    f_eng = rng.uniform(25.0, 60.0)
    hum = sum(np.sin(2 * np.pi * k * f_eng * t + rng.uniform(0, 6.3)) / k for k in range(1, 6))
    x = x + rng.uniform(0.1, 0.4) * hum / max(float(np.std(hum)), 1e-12)
    x = x * _smooth_envelope(n, sample_rate, rng, 4.0, 0.3)
    return (x / max(float(np.sqrt(np.mean(x**2))), 1e-12)).astype(np.float32)


def wind_noise(
    n: int,
    n_mics: int,
    sample_rate: int,
    air_speed_mps: float,
    level_10_db: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """Wind noise pressure (Pa) ``(n, n_mics)``, independent per capsule (see the module docstring)."""
    u = max(float(air_speed_mps), 0.3)
    level = level_10_db + 40.0 * math.log10(u / 10.0)
    fc = 3.0 * u
    f = np.fft.rfftfreq(n, 1.0 / sample_rate)
    power = 1.0 / (1.0 + (f / fc) ** 2)
    out = np.empty((n, n_mics))
    for m in range(n_mics):
        out[:, m] = _shaped_noise(n, sample_rate, power, rng) * _smooth_envelope(
            n, sample_rate, rng, 3.0, 2.0
        )
    return out * db_spl_to_pa(level)


def self_noise(
    n: int, n_mics: int, rng: np.random.Generator, level_db: float = SELF_NOISE_DB_SPL
) -> np.ndarray:
    """White capsule self-noise (Pa), independent per capsule."""
    return rng.standard_normal((n, n_mics)) * db_spl_to_pa(level_db)


STREET_NOISE_SIRENS = Path(__file__).resolve().parents[1] / "data" / "street_noise_sirens.csv"
"""Spans of the no-siren street recordings that do hold a siren after all (found by looking at their
spectrograms; ``file,start_s,end_s,what``). They are cut out wherever the recordings serve as
negatives: as simulator noise and in the real-data check."""


def street_noise_siren_spans(
    path: str | Path = STREET_NOISE_SIRENS,
) -> dict[str, tuple[tuple[float, float], ...]]:
    """``{file stem: ((start_s, end_s), …)}`` from the annotation CSV (:data:`STREET_NOISE_SIRENS`).

    Raises :class:`~makeway.errors.InputError` naming the file and row on a malformed line."""
    import csv

    from makeway.errors import InputError

    spans: dict[str, list[tuple[float, float]]] = {}
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            missing = {"file", "start_s", "end_s"} - set(reader.fieldnames or ())
            if missing:
                raise InputError(
                    path, f"needs the columns file,start_s,end_s (missing {', '.join(sorted(missing))})"
                )
            for i, row in enumerate(reader, start=2):
                try:
                    start, end = float(row["start_s"]), float(row["end_s"])
                except (TypeError, ValueError):
                    raise InputError(path, f"line {i}: start_s/end_s must be numbers") from None
                if not (0.0 <= start < end):
                    raise InputError(path, f"line {i}: needs 0 <= start_s < end_s, got {start:g}, {end:g}")
                spans.setdefault(str(row["file"]).strip(), []).append((start, end))
    except OSError as exc:
        raise InputError(path, f"cannot be read ({exc.strerror or exc})") from None
    return {k: tuple(sorted(v)) for k, v in spans.items()}


def load_street_noise_sources(data_root: str | Path) -> list[AudioSource]:
    """The real street recordings with no siren (``traffic-*``, ``noise*`` under
    ``audio/street_recordings``), one group per file; the ``ambulance*`` files hold sirens and are left
    out, and so are the siren spans of :data:`STREET_NOISE_SIRENS` (``AudioSource.exclude``). 16 kHz
    material, so :meth:`AudioSource.load` upsamples it to 48 kHz (content < 8 kHz)."""
    folder = Path(data_root) / "audio" / "street_recordings"
    sirens = street_noise_siren_spans()
    out: list[AudioSource] = []
    for p in sorted(folder.glob("*.flac")):
        if p.stem.startswith(("traffic", "noise")):
            out.append(AudioSource(p.stem, f"street:{p.stem}", "street", "none", p, sirens.get(p.stem, ())))
    return out
