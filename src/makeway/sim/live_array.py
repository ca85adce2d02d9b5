"""The roof array's audio, rendered while the closed loop drives (SPEC §3 inside SPEC §7's loop).

The recordings of :mod:`makeway.sim.audio_scenarios` are rendered from trajectories known in
advance. In closed loop the ego's trajectory depends on what the car decides, so
:class:`LiveArraySimulator` renders the eight capsules hop by hop, from what has happened so far:

* :meth:`LiveArraySimulator.observe` is called every simulation step with the ego pose and each
  EV's true state (position, siren on or off); every EV sounds its own siren;
* :meth:`LiveArraySimulator.render` returns the audio heard between two instants up to the latest
  observed one, with the physics of :func:`~makeway.sim.acoustics.simulate_array` (per-capsule
  propagation delay with the emission time solved, Doppler, spherical spreading, air absorption, one
  ground reflection). The siren's emitted signal is gated by its on/off state at the emission time,
  with a 10 ms ramp, so the sound of a siren switched on reaches the car later the farther away it is.

Everything it renders at a time ``t`` depends only on states observed up to ``t`` (causal). Each
stretch is rendered with 2,048 samples of margin on both sides, then cut, so the block-wise air
absorption leaves no seams.

**Several EVs.** The first EV's siren is the scene's (below); each further EV ``k`` (1, 2, …) gets a
siren of its own, drawn with the same rules from a generator seeded ``(seed, k)``, so a scene with
one EV is the same whether or not more could have been drawn.

**The scene around the siren** is drawn once per run from ``seed``, with the recordings' ranges
(:mod:`makeway.sim.audio_scenarios`): the siren (synthesized, or a real held-out siren with
``siren="real"`` and the shared data), its level, speaker height, ground reflection and rear
attenuation; street noise of 2–4 fixed sources around the car at a level from ``street_dba``
(generated, or real held-out street recordings with ``noise="real"``); wind noise independent per
capsule; capsule self-noise. The noise is rendered in advance for the whole run. The wind's level
follows the ego's air speed as the car slows (40·log10 law, gain per sample); its spectrum keeps the
shape of the starting speed. Runs with the same seed, length, starting speed and array draw the
same scene, so the last two draws are kept and shared, read-only (a scenario run with other senses
or another scenario of the same length renders its noise once).
"""

from __future__ import annotations

import copy
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.fft import next_fast_len

from makeway.paths import data_dir
from makeway.sense.recording import REFERENCE_SAMPLE_RATE, Trajectory, reference_mics
from makeway.sim.acoustics import (
    FULL_SCALE_DB_SPL,
    PointSource,
    db_spl_to_pa,
    self_noise,
    simulate_array,
    wind_noise,
)
from makeway.sim.audio_scenarios import (
    AMBIENT_WIND_MPS,
    PRE_ROLL_S,
    SIREN_LEVEL_DB_1M,
    STREET_NOISE_DBA,
    WIND_LEVEL_10_DB,
    check_siren_level,
    pick_by_group,
    siren_point_source,
    source_pools,
    street_noise_field,
)
from makeway.sim.siren import fit_length, synthesize_siren

MARGIN_SAMPLES = 2048
"""Samples rendered beyond each end of a stretch and cut (the air-absorption blocks' length)."""
HISTORY_S = 2.0
"""The trajectories passed to a render reach this far back before its start (sound from ≤ 600 m)."""
GATE_RAMP_S = 0.01
"""The siren's switch-on/off ramp."""


@dataclass(frozen=True)
class LiveAudioConfig:
    """How :class:`LiveArraySimulator` draws the scene (module docstring).

    ``siren``: ``"synth"`` (procedural; needs no data) or ``"real"`` (a held-out siren of the shared
    data, ``split``); ``noise``: ``"generated"`` or ``"real"`` likewise; ``street_dba``: the range
    the street noise's A-weighted level is drawn from; ``siren_level_db``: the range the siren's
    emitted level is drawn from (dB SPL at 1 m; default the networks' training prior, real sirens
    span about 110–135 dB).
    """

    seed: int = 0
    siren: str = "synth"
    noise: str = "generated"
    split: str = "test"
    street_dba: tuple[float, float] = STREET_NOISE_DBA
    siren_level_db: tuple[float, float] = SIREN_LEVEL_DB_1M

    def __post_init__(self) -> None:
        check_siren_level(self.siren_level_db)
        if self.siren not in ("synth", "real"):
            raise ValueError(f"siren must be synth or real, not {self.siren!r}")
        if self.noise not in ("generated", "real"):
            raise ValueError(f"noise must be generated or real, not {self.noise!r}")


@dataclass(frozen=True)
class _Scene:
    """What :class:`LiveArraySimulator` draws once per run (arrays read-only, shared between runs)."""

    siren_name: str
    siren_draws: dict[str, float]
    source: PointSource  # its signal is the siren as emitted when on; each run gates its own copy
    street_noise: dict[str, Any]
    wind_level_10_db: float
    ambient_wind_mps: float
    air_ref_mps: float
    wind: np.ndarray
    bed: np.ndarray


def _real_data_root(cfg: LiveAudioConfig) -> str:
    """The shared data folder ``cfg`` draws real sirens or streets from, "" when it draws none (or
    the data is missing)."""
    root = data_dir() if "real" in (cfg.siren, cfg.noise) else None
    return str(root) if root is not None else ""


@functools.lru_cache(maxsize=2)
def _draw_scene(
    duration_s: float,
    cfg: LiveAudioConfig,
    mics: tuple[tuple[float, ...], ...],
    sample_rate: int,
    initial_speed_mps: float,
    data: str,
) -> _Scene:
    """Draw the siren and render the noise bed of a run from ``cfg.seed`` (module docstring);
    ``data`` names the shared data folder real sirens and streets come from ("" when none is used).

    A function of its arguments alone, so runs that share them (the same seed, length and starting
    speed in another scenario or with other senses) share one draw instead of rendering it again.
    """
    sr = sample_rate
    mic_xyz = np.asarray(mics, dtype=np.float64)
    rng = np.random.default_rng(cfg.seed)
    sirens, noise = source_pools(cfg.split, data) if data else ([], [])
    if cfg.siren == "real" and not sirens:
        raise ValueError("siren='real' needs the shared data (audio/siren_clips, siren_tones); none found")
    if cfg.noise == "real" and not noise:
        raise ValueError("noise='real' needs the shared data (audio/street_recordings); none found")

    # the siren: its raw signal, and the emitted one (gated as the run goes)
    name, draws, source = _siren_source(rng, cfg, _siren_samples(duration_s, sr), sr, sirens)

    # the noise bed for the whole run, at a length the FFT factors well (the noise is shaped in
    # the frequency domain; an awkward length costs ten times the time)
    n = next_fast_len(round(duration_s * sr) + 2 * MARGIN_SAMPLES, real=True)
    street, street_meta = street_noise_field(n, sr, mic_xyz, rng, noise, cfg.street_dba)
    wind_10 = float(rng.uniform(*WIND_LEVEL_10_DB))
    ambient = float(rng.uniform(*AMBIENT_WIND_MPS))
    air_ref = max(initial_speed_mps + ambient, 0.3)
    wind = wind_noise(n, len(mic_xyz), sr, air_ref, wind_10, rng).astype(np.float32)
    bed = (street + self_noise(n, len(mic_xyz), rng)).astype(np.float32)
    for arr in (wind, bed):
        arr.setflags(write=False)
    return _Scene(name, draws, source, street_meta, wind_10, ambient, air_ref, wind, bed)


def _siren_source(
    rng: np.random.Generator, cfg: LiveAudioConfig, n_sig: int, sample_rate: int, sirens: list[Any]
) -> tuple[str, dict[str, float], PointSource]:
    """Draw one siren (``cfg.siren``: real from ``sirens`` or synthesized) as a point source at rest
    (the run sets its trajectory); its signal is read-only."""
    sr = sample_rate
    if cfg.siren == "real":
        src = pick_by_group(sirens, rng)
        raw = fit_length(src.load(sr), n_sig, rng, crossfade=0 if src.kind == "tone" else 2400)
        name = src.name
    else:
        raw, params = synthesize_siren(None, n_sig / sr, sr, rng=rng)
        name = f"synth:{params.mode}"
    source, draws = siren_point_source(
        raw, Trajectory(np.array([0.0, 1.0]), np.zeros(2), np.zeros(2)), rng, level_db=cfg.siren_level_db
    )
    source.signal.setflags(write=False)
    return name, draws, source


def _siren_samples(duration_s: float, sample_rate: int) -> int:
    """Samples of a run's emitted siren signal (pre-roll and render margins included)."""
    return round((duration_s + PRE_ROLL_S) * sample_rate) + 2 * MARGIN_SAMPLES + 64


@functools.lru_cache(maxsize=4)
def _draw_further_siren(
    duration_s: float, cfg: LiveAudioConfig, k: int, sample_rate: int, data: str
) -> tuple[str, dict[str, float], PointSource]:
    """The siren of the run's EV number ``k`` ≥ 1 (module docstring, "Several EVs")."""
    sirens, _ = source_pools(cfg.split, data) if data else ([], [])
    if cfg.siren == "real" and not sirens:
        raise ValueError("siren='real' needs the shared data (audio/siren_clips, siren_tones); none found")
    rng = np.random.default_rng((cfg.seed, k))
    return _siren_source(rng, cfg, _siren_samples(duration_s, sample_rate), sample_rate, sirens)


class _Siren:
    """One EV's siren in a run: the emitted signal, gated as the run goes."""

    def __init__(self, name: str, draws: dict[str, float], source: PointSource) -> None:
        self.name, self.draws = name, copy.deepcopy(draws)
        self.raw = source.signal
        self.source = replace(source, signal=np.zeros_like(self.raw))
        self.gated_until = 0  # emitted samples [0, gated_until) are final


class LiveArraySimulator:
    """Renders the array's audio of one closed-loop run, hop by hop (module docstring).

    ``duration_s`` bounds the run; ``mics`` default to the reference array. Audio comes out as the
    array records it: digital samples where an RMS of 1.0 stands for ``full_scale_db_spl``.
    """

    def __init__(
        self,
        duration_s: float,
        config: LiveAudioConfig | None = None,
        *,
        mics: np.ndarray | None = None,
        sample_rate: int = REFERENCE_SAMPLE_RATE,
        full_scale_db_spl: float = FULL_SCALE_DB_SPL,
        initial_speed_mps: float = 0.0,
    ) -> None:
        self.config = config if config is not None else LiveAudioConfig()
        cfg = self.config
        self.mics = reference_mics() if mics is None else np.asarray(mics, dtype=np.float64)
        self.sample_rate = int(sample_rate)
        self.full_scale_db_spl = float(full_scale_db_spl)
        self.duration_s = float(duration_s)
        scene = _draw_scene(
            self.duration_s,
            cfg,
            tuple(map(tuple, self.mics.tolist())),
            self.sample_rate,
            float(initial_speed_mps),
            _real_data_root(cfg),
        )
        self.street_noise = copy.deepcopy(scene.street_noise)
        self.wind_level_10_db = scene.wind_level_10_db
        self._ambient_wind, self._air_ref = scene.ambient_wind_mps, scene.air_ref_mps
        self._wind, self._bed = scene.wind, scene.bed
        # each EV's emitted siren starts silent and is gated as the run goes; its trajectory is set
        # per render
        self._sirens = [_Siren(scene.siren_name, scene.siren_draws, scene.source)]
        self._data = _real_data_root(cfg)

        self._t: list[float] = []
        self._ego: list[tuple[float, float, float]] = []
        self._ev: list[list[tuple[float, float, float]]] = []  # per time, per EV: x, y, siren on (1/0)

    @property
    def siren_name(self) -> str:
        """The first EV's siren (a real recording's name, or ``synth:<mode>``)."""
        return self._sirens[0].name

    @property
    def siren_draws(self) -> dict[str, float]:
        """The first EV's siren's drawn level, height, ground reflection and rear attenuation."""
        return self._sirens[0].draws

    @property
    def siren_names(self) -> list[str]:
        """Every EV's siren so far, in EV order."""
        return [s.name for s in self._sirens]

    # ------------------------------------------------------------------------------------ inputs

    def observe(
        self,
        time_s: float,
        ego_x: float,
        ego_y: float,
        ego_yaw: float,
        ev: tuple[float, float, bool] | None,
        *,
        evs: Sequence[tuple[float, float, bool]] | None = None,
    ) -> None:
        """Record the state at ``time_s`` (not decreasing; the same time again replaces the state):
        the ego pose (world frame; its position is the vehicle frame's origin) and the EV's
        ``(x, y, siren on)``, ``None`` without an EV; or, with ``evs``, every EV's (``ev`` is then
        ignored; an EV keeps its place in the sequence from one call to the next)."""
        if self._t and time_s < self._t[-1]:
            raise ValueError(f"observe: time {time_s} is before the last one ({self._t[-1]})")
        if time_s > self.duration_s + 1e-9:
            raise ValueError(f"observe: time {time_s} is past the run's duration ({self.duration_s} s)")
        if self._t and time_s == self._t[-1]:
            self._t.pop(), self._ego.pop(), self._ev.pop()
        states = list(evs) if evs is not None else ([] if ev is None else [ev])
        while len(self._sirens) < len(states):
            k = len(self._sirens)
            self._sirens.append(
                _Siren(*_draw_further_siren(self.duration_s, self.config, k, self.sample_rate, self._data))
            )
        self._t.append(float(time_s))
        self._ego.append((float(ego_x), float(ego_y), float(ego_yaw)))
        self._ev.append([(float(x), float(y), float(on)) for x, y, on in states])

    @property
    def time_s(self) -> float:
        """The latest observed time (−inf before the first)."""
        return self._t[-1] if self._t else -math.inf

    # ----------------------------------------------------------------------------------- output

    def render(self, t_from: float, t_to: float) -> np.ndarray:
        """The digital audio ``(samples, channels)`` float32 heard in ``[t_from, t_to)``; needs
        ``t_to`` ≤ the latest observed time. Sample ``i`` is heard at ``t_from + i / sample_rate``,
        ``t_from`` a whole number of samples."""
        sr = self.sample_rate
        if not self._t or t_to > self._t[-1] + 1e-9:
            raise ValueError(f"render: audio up to {t_to} s needs states observed up to then")
        i0, i1 = round(t_from * sr), round(t_to * sr)
        n = i1 - i0
        if n <= 0:
            return np.zeros((0, len(self.mics)), dtype=np.float32)
        t = np.asarray(self._t)
        ego = np.asarray(self._ego)
        first = int(np.searchsorted(t, t_from - HISTORY_S, side="left"))  # the render's history only
        t, ego = t[first:], ego[first:]
        ev = np.full((len(t), len(self._sirens), 3), np.nan)
        ev[..., 2] = 0.0
        for j, states in enumerate(self._ev[first:]):
            if states:
                ev[j, : len(states)] = states
        if len(t) == 1:  # a one-point trajectory: hold it
            t, ego, ev = np.r_[t, t + 1.0], np.vstack([ego, ego]), np.concatenate([ev, ev])
        out = self._noise(i0, n, t, ego)
        sources = []
        for k, siren in enumerate(self._sirens):
            has_ev = np.isfinite(ev[:, k, 0])
            if not has_ev.any():
                continue
            self._gate_until(siren, t_to, t, ev[:, k, 2])
            siren.source.trajectory = Trajectory(t[has_ev], ev[has_ev, k, 0], ev[has_ev, k, 1])
            sources.append(siren.source)
        if sources:
            ego_traj = Trajectory(t, ego[:, 0], ego[:, 1], ego[:, 2])
            m = MARGIN_SAMPLES
            pa = simulate_array(sources, ego_traj, self.mics, n + 2 * m, sr, start_s=(i0 - m) / sr)[m : m + n]
            out += pa / db_spl_to_pa(self.full_scale_db_spl)
        return out.astype(np.float32)

    def _noise(self, i0: int, n: int, t: np.ndarray, ego: np.ndarray) -> np.ndarray:
        """Street noise, self-noise and wind (scaled to the ego's air speed) for samples i0 … i0+n."""
        sr = self.sample_rate
        a, b = MARGIN_SAMPLES + i0, MARGIN_SAMPLES + i0 + n
        if a < 0 or b > len(self._bed):
            raise ValueError(f"render: samples {i0}…{i0 + n} lie outside the run's {self.duration_s} s")
        ts = (i0 + np.arange(n)) / sr
        if len(t) >= 2:
            speed = np.hypot(np.gradient(ego[:, 0], t), np.gradient(ego[:, 1], t))
            air = np.maximum(np.interp(ts, t, speed) + self._ambient_wind, 0.3)
        else:
            air = np.full(n, self._air_ref)
        gain = (air / self._air_ref) ** 2  # 40·log10(U): amplitude ∝ U²
        pa = self._bed[a:b].astype(np.float64) + self._wind[a:b] * gain[:, None]
        return pa / db_spl_to_pa(self.full_scale_db_spl)

    def _gate_until(self, siren: _Siren, t_to: float, t: np.ndarray, on: np.ndarray) -> None:
        """Fix ``siren``'s emitted signal up to the emission time ``t_to`` from its states ``on``
        observed at times ``t`` (the render's history; later samples stay silent until then, only
        the cut margin of a render reads them)."""
        sr = self.sample_rate
        sig = siren.source.signal
        j1 = min(len(sig), round((t_to - siren.source.t0) * sr))
        j0 = siren.gated_until
        if j1 <= j0:
            return
        te = siren.source.t0 + np.arange(j0, j1) / sr
        # a step per observation, ramped over GATE_RAMP_S
        grid = np.arange(t[0] - GATE_RAMP_S, t[-1] + GATE_RAMP_S, GATE_RAMP_S)
        steps = on[np.clip(np.searchsorted(t, grid, side="right") - 1, 0, len(t) - 1)]
        steps[grid < t[0]] = on[0]
        gate = np.interp(te, grid, steps, left=on[0], right=on[-1]).astype(np.float32)
        sig[j0:j1] = siren.raw[j0:j1] * gate
        siren.gated_until = j1
