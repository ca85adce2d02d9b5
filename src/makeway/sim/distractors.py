"""Street sounds that are *not* sirens, for the simulator's negatives (issue 4, SPEC §3).

The twelve real no-siren street recordings are the only real negatives in the shared data, so a
network trained on them alone learns "tonal, frequency-modulated, in the 0.5–2 kHz band ⇒ siren" and
fires on the first bird or squeaking brake of a street it has not heard (docs/journal.md, "Siren
network, second model: cleaned negatives, street-sound distractors, loud traffic"). This
module synthesizes the common urban sounds that share some property of a siren but not its pattern,
placed by the simulator as extra point sources around the car:

===============  ====================================================================================
``horn``         a car horn: two tones at once (low 330–520 Hz, high 1.15–1.3× it — the usual
                 disc-horn pairs such as 420/500 Hz), square-ish (harmonics ∝ 1/k), 1–4 toots of
                 0.12–1.2 s. A siren never sounds two fundamentals together, and does not stop.
``birds``        song-bird chirps: 3–16 short (25–220 ms) near-pure tones sweeping up or down
                 0.2–2.5 kHz from 1.2–6 kHz, at irregular gaps of 40–600 ms. Sweeps like a yelp,
                 but short, high, irregular and without the siren's harmonic series.
``squeal``       brake squeal: a steady tone of 1.8–6 kHz with a weak 2nd harmonic and a 4–10 Hz
                 vibrato of 0.2–1 %, 0.4–3 s, swelling and fading.
``air_brake``    air-brake or door hiss: a burst of high-passed (≥ 0.8–2 kHz) noise, 0.15–1.2 s,
                 fast attack and exponential decay.
``engine_rev``   a revving engine: harmonic stack of a 20–70 Hz firing frequency (orders 1–40,
                 falling ∝ 1/k) that rises and falls 1.3–2.5× over 0.8–3 s, with rough broadband
                 noise. Rises and falls like a wail, but low and dense.
===============  ====================================================================================

:func:`synthesize_distractor` returns the mono pressure signal at 1 m (unit RMS over its active
part, silence elsewhere) and the activity mask, so the simulator can set its level against the
street noise over the time it sounds. Every draw comes from the generator passed in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

DISTRACTOR_KINDS = ("horn", "birds", "squeal", "air_brake", "engine_rev")


@dataclass
class Distractor:
    """One synthesized street sound: ``signal`` (unit RMS where ``active``) and its parameters."""

    kind: str
    signal: np.ndarray
    active: np.ndarray
    params: dict[str, Any] = field(default_factory=dict)


def _ramp(n: int, sample_rate: int, attack_s: float, release_s: float) -> np.ndarray:
    env = np.ones(n)
    a = min(n // 2, max(1, round(attack_s * sample_rate)))
    r = min(n // 2, max(1, round(release_s * sample_rate)))
    env[:a] = np.linspace(0.0, 1.0, a)
    env[n - r :] *= np.linspace(1.0, 0.0, r)
    return env


def _placed(n: int, start: int, segment: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(signal, active)`` of length ``n``: ``segment`` from sample ``start``, silence elsewhere."""
    x = np.zeros(n)
    x[start : start + len(segment)] = segment
    active = np.zeros(n, dtype=bool)
    active[start : start + len(segment)] = True
    return x, active


def _harmonic_tone(
    phase: np.ndarray, freq: np.ndarray, sample_rate: int, decay: float, max_k: int
) -> np.ndarray:
    """Sum of harmonics ``k`` (amplitude ``k**-decay``) of the running ``phase``, each faded out
    before it passes 0.45 × the sample rate."""
    out = np.zeros_like(phase)
    nyq = 0.45 * sample_rate
    for k in range(1, max_k + 1):
        gain = np.clip((nyq - k * freq) / (0.05 * sample_rate), 0.0, 1.0)
        if not gain.any():
            break
        out += gain * np.sin(k * phase) / k**decay
    return out


def _horn(
    n: int, sample_rate: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    f_low = float(rng.uniform(330.0, 520.0))
    ratio = float(rng.uniform(1.15, 1.3))
    x = np.zeros(n)
    active = np.zeros(n, dtype=bool)
    toots = int(rng.integers(1, 5))
    pos = int(rng.integers(0, max(1, n // 3)))
    for _ in range(toots):
        dur = round(float(rng.uniform(0.12, 1.2)) * sample_rate)
        if pos + dur > n:
            break
        t = np.arange(dur) / sample_rate
        env = _ramp(dur, sample_rate, 0.01, 0.03)
        tone = np.zeros(dur)
        for f0 in (f_low, f_low * ratio):
            f = np.full(dur, f0 * (1 + 0.003 * np.sin(2 * np.pi * rng.uniform(3, 8) * t)))
            phase = 2 * np.pi * np.cumsum(f) / sample_rate + rng.uniform(0, 2 * np.pi)
            tone += _harmonic_tone(phase, f, sample_rate, 1.0, 30)
        x[pos : pos + dur] += env * tone
        active[pos : pos + dur] = True
        pos += dur + round(float(rng.uniform(0.1, 0.4)) * sample_rate)
    return x, active, {"f_low_hz": round(f_low, 1), "ratio": round(ratio, 3), "toots": toots}


def _birds(
    n: int, sample_rate: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    x = np.zeros(n)
    active = np.zeros(n, dtype=bool)
    chirps = int(rng.integers(3, 17))
    pos = int(rng.integers(0, max(1, n // 3)))
    f_centre = float(rng.uniform(1200.0, 6000.0))
    made = 0
    for _ in range(chirps):
        dur = round(float(rng.uniform(0.025, 0.22)) * sample_rate)
        if pos + dur > n:
            break
        f0 = f_centre * float(rng.uniform(0.8, 1.25))
        sweep = float(rng.uniform(200.0, 2500.0)) * float(rng.choice([-1.0, 1.0]))
        u = np.linspace(0.0, 1.0, dur)
        f = np.maximum(f0 + sweep * (u if rng.random() < 0.6 else np.sin(np.pi * u)), 300.0)
        phase = 2 * np.pi * np.cumsum(f) / sample_rate
        env = np.sin(np.pi * u) ** 2
        x[pos : pos + dur] += env * (np.sin(phase) + 0.18 * np.sin(2 * phase))
        active[pos : pos + dur] = True
        made += 1
        pos += dur + round(float(rng.uniform(0.04, 0.6)) * sample_rate)
    return x, active, {"f_centre_hz": round(f_centre, 1), "chirps": made}


def _squeal(
    n: int, sample_rate: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    f0 = float(rng.uniform(1800.0, 6000.0))
    dur = min(n, round(float(rng.uniform(0.4, 3.0)) * sample_rate))
    start = int(rng.integers(0, max(1, n - dur + 1)))
    t = np.arange(dur) / sample_rate
    depth = float(rng.uniform(0.002, 0.01))
    f = f0 * (1 + depth * np.sin(2 * np.pi * rng.uniform(4.0, 10.0) * t))
    phase = 2 * np.pi * np.cumsum(f) / sample_rate
    env = np.sin(np.pi * np.linspace(0.0, 1.0, dur)) ** 0.5
    x, active = _placed(n, start, env * (np.sin(phase) + 0.1 * np.sin(2 * phase)))
    return x, active, {"f_hz": round(f0, 1), "duration_s": round(dur / sample_rate, 3)}


def _air_brake(
    n: int, sample_rate: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    dur = min(n, round(float(rng.uniform(0.15, 1.2)) * sample_rate))
    start = int(rng.integers(0, max(1, n - dur + 1)))
    f_cut = float(rng.uniform(800.0, 2000.0))
    spec = rng.standard_normal(dur // 2 + 1) + 1j * rng.standard_normal(dur // 2 + 1)
    f = np.fft.rfftfreq(dur, 1.0 / sample_rate)
    spec *= (f / f_cut) ** 2 / (1 + (f / f_cut) ** 2)
    burst = np.fft.irfft(spec, dur)
    u = np.arange(dur) / sample_rate
    env = (1 - np.exp(-u / 0.005)) * np.exp(-u / (0.35 * dur / sample_rate))
    x, active = _placed(n, start, burst * env)
    return x, active, {"f_cut_hz": round(f_cut, 1), "duration_s": round(dur / sample_rate, 3)}


def _engine_rev(
    n: int, sample_rate: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    dur = min(n, round(float(rng.uniform(0.8, 3.0)) * sample_rate))
    start = int(rng.integers(0, max(1, n - dur + 1)))
    f_idle = float(rng.uniform(20.0, 70.0))
    rise = float(rng.uniform(1.3, 2.5))
    u = np.linspace(0.0, 1.0, dur)
    f = f_idle * (1 + (rise - 1) * np.sin(np.pi * u) ** 2)
    phase = 2 * np.pi * np.cumsum(f) / sample_rate
    tone = _harmonic_tone(phase, f, sample_rate, 1.0, 40)
    rough = rng.standard_normal(dur) * 0.3 * float(np.std(tone))
    env = _ramp(dur, sample_rate, 0.15, 0.3) * (0.6 + 0.4 * np.sin(np.pi * u))
    x, active = _placed(n, start, env * (tone + rough))
    return (
        x,
        active,
        {"f_idle_hz": round(f_idle, 1), "rise": round(rise, 3), "duration_s": round(dur / sample_rate, 3)},
    )


_MAKERS = {
    "horn": _horn,
    "birds": _birds,
    "squeal": _squeal,
    "air_brake": _air_brake,
    "engine_rev": _engine_rev,
}


def synthesize_distractor(kind: str | None, n: int, sample_rate: int, rng: np.random.Generator) -> Distractor:
    """One street sound of ``kind`` (None: any of :data:`DISTRACTOR_KINDS`) within ``n`` samples."""
    if kind is None:
        kind = str(rng.choice(DISTRACTOR_KINDS))
    if kind not in _MAKERS:
        raise ValueError(f"unknown distractor {kind!r}; choose from {', '.join(DISTRACTOR_KINDS)}")
    x, active, params = _MAKERS[kind](n, sample_rate, rng)
    if active.any():
        rms = math.sqrt(float(np.mean(x[active] ** 2)))
        x = x / max(rms, 1e-12)
    return Distractor(kind, x.astype(np.float32), active, params)
