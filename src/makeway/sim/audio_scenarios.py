"""Simulated siren recordings: seed 002's driving scenarios rendered through the array simulator.

Seed 002 is the Apollo paper on siren detection and localization with two 4-channel roof
microphones (``../shared/seeds/002_…``, digested in SPEC §3).

Scenarios (seed 002 Fig. 4, plus an emergency vehicle closing from behind), drawn at random per
recording; the ego drives along its lane at ``v0 + a·t`` (never backwards), everything is then
rotated and shifted by a random world pose so that world and vehicle frames differ:

=======================  ===================================================================
``crossing``             intersection: the EV crosses the ego's road on an orthogonal road
                         (8–20 m/s) 8–40 m ahead of the ego; the ego creeps or waits (0–12 m/s)
``same_direction``       parallel lanes, same direction: the EV 3–8 m to either side, −60…60 m
                         along the road at mid-recording, −6…+10 m/s faster than the ego
``opposite_direction``   parallel lanes, opposite directions: the EV 3–10 m to the left, 8–25
                         m/s, passing the ego somewhere in the recording
``from_behind``          the EV closes from 30–140 m behind in the ego's lane at +5…15 m/s,
                         moves to the left lane (over 2–3.5 s, starting 10–25 m behind the ego
                         or earlier when fast) and overtakes
=======================  ===================================================================

With ``far_start`` (opt-in, for ranging out to audible range, issue 25) the distances above are
drawn from wider ranges (:data:`FAR_START`): the EV crosses 8–250 m ahead, drives −250…250 m along
the road from the ego, passes anywhere from 0.8 recordings before its start to 0.8 after its end
(so it may stay a few hundred metres away the whole time), or closes from 30–300 m behind. Every
other draw of a seed is unchanged (the same random numbers are stretched over the wider ranges).
Over the four scenarios, 8 s recordings: without it half the windows hold a siren within 41 m,
3 % beyond 150 m, none beyond 300 m; with it 36 % within 100 m, 17 % at 100–150 m, 42 % at
150–300 m and 5 % farther.

**Levels** (drawn per recording; module constants below):

* siren: 110–120 dB SPL at 1 m (the issue's range; ratings of road sirens are higher on-axis —
  SAE J1849 asks ≥ ~118 dB(A) at 3 m forward — but fall off quickly to the sides and rear, so this is
  an all-round average), up to 6 dB less straight behind the EV; speaker 0.8–2.0 m above the
  ground; ground reflection coefficient 0.7–0.9;
* street noise: 60–75 dB(A) Leq at the array — the usual range by busy urban roads (EU noise maps
  put main roads at 65–75 dB(A) L_den), from 2–4 point sources 15–60 m away at random bearings,
  0.3–1.2 m high, each playing a different stretch of a real no-siren street recording (or
  generated street noise without data);
* wind: 60–72 dB SPL at 10 m/s air speed, 40·log10(U) law (see :mod:`makeway.sim.acoustics`),
  air speed = ego speed + 0.5–4 m/s ambient wind;
* capsule self-noise 30 dB SPL;
* non-siren street sounds (:mod:`makeway.sim.distractors`: horns, birds, brake squeal, air-brake
  hiss, revving engines) in 60 % of the recordings, with or without a siren: 1–3 of them at fixed
  points 5–40 m away (birds 2–10 m up), each 5 dB below to 15 dB above the street noise's A-weighted
  level while it sounds. Drawn from their own random stream, so switching them off
  (``distractors=False``) leaves every other draw of a seed unchanged.

The resulting in-band (500–1800 Hz) siren-to-noise ratio is written to ``meta.yaml`` (``snr_band_db``)
together with every other draw, so benchmarks can be broken down by it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from makeway.paths import data_dir
from makeway.sense.recording import (
    REFERENCE_SAMPLE_RATE,
    Recording,
    Trajectory,
    recording_folders,
    reference_mics,
    write_recording,
)
from makeway.sim.acoustics import (
    FULL_SCALE_DB_SPL,
    SPEED_OF_SOUND,
    PointSource,
    a_weighted_level_db,
    db_spl_to_pa,
    generated_street_noise,
    load_street_noise_sources,
    place_fixed_sources,
    self_noise,
    simulate_array,
    wind_noise,
)
from makeway.sim.distractors import synthesize_distractor
from makeway.sim.siren import (
    AudioSource,
    SirenParams,
    fit_length,
    load_siren_sources,
    pitch_shift,
    render_siren,
    split_sources,
    synthesize_siren,
)

AUDIO_SCENARIOS = ("crossing", "same_direction", "opposite_direction", "from_behind")
TRAJECTORY_RATE_HZ = 100.0
PRE_ROLL_S = 1.5
"""Sound emitted up to 1.5 s before t = 0 (515 m of travel) is simulated, so far sources are heard
from the first sample."""

SIREN_LEVEL_DB_1M = (110.0, 120.0)
SIREN_LEVEL_BOUNDS_DB = (80.0, 150.0)
"""The emitted siren levels a caller may ask for (dB SPL at 1 m): far beyond any road siren's
110–135 dB on either side, but no further (a typo like 1150 is refused, not simulated)."""
SIREN_REAR_ATTENUATION_DB = (0.0, 6.0)
SIREN_HEIGHT_M = (0.8, 2.0)
GROUND_REFLECTION = (0.7, 0.9)
STREET_NOISE_DBA = (60.0, 75.0)
N_NOISE_SOURCES = (2, 4)
NOISE_DISTANCE_M = (15.0, 60.0)
NOISE_HEIGHT_M = (0.3, 1.2)
WIND_LEVEL_10_DB = (60.0, 72.0)
AMBIENT_WIND_MPS = (0.5, 4.0)
REAL_SIREN_SHARE = 0.6
"""With ``siren="auto"`` and the data present, this share of sirens are real clips/tones."""
SNR_BAND_HZ = (500.0, 1800.0)
DISTRACTOR_SHARE = 0.6
N_DISTRACTORS = (1, 3)
DISTRACTOR_DISTANCE_M = (5.0, 40.0)
DISTRACTOR_HEIGHT_M = (0.5, 1.5)
BIRD_HEIGHT_M = (2.0, 10.0)
DISTRACTOR_REL_DBA = (-5.0, 15.0)
SIREN_VARIETY_SHARE = 0.5
"""With ``siren_pitch``: share of the sirens whose pitch (and, for synthesized wail/yelp, sweep shape)
is varied."""
SIREN_VARIETY_RISE = (0.15, 0.95)
"""With ``siren_pitch``: range of the rise fraction a varied synthesized wail or yelp is redrawn from
(0.95: a slow rise and a sudden drop, like a mechanical siren winding up)."""
"""A-weighted level of a distractor while it sounds, relative to the street noise's (dB)."""

FAR_START = {
    "crossing_gap_m": (8.0, 250.0),
    "same_direction_offset_m": (-250.0, 250.0),
    "opposite_pass_fraction": (-0.8, 1.8),
    "from_behind_gap_m": (30.0, 300.0),
}
"""With ``far_start``: the ranges that replace the scenario's own (module docstring); the default
ones are 8–40 m, −60…60 m, 0.1–0.9 of the recording and 30–140 m."""

Fn = Callable[[np.ndarray], np.ndarray]


@dataclass
class _Motion:
    """The ego's motion along its lane (before the random world pose)."""

    v0: float
    accel: float

    def x(self, t: np.ndarray) -> np.ndarray:
        """Distance along the lane at ``t`` (constant speed before t = 0, stopping rather than reversing)."""
        t = np.asarray(t, dtype=np.float64)
        tp = np.maximum(t, 0.0)
        if self.accel < 0 and self.v0 > 0:
            tp = np.minimum(tp, self.v0 / -self.accel)
        return self.v0 * np.minimum(t, 0.0) + self.v0 * tp + 0.5 * self.accel * tp**2

    def speed(self, t: np.ndarray) -> np.ndarray:
        dt = 1e-3
        return (self.x(np.asarray(t) + dt) - self.x(np.asarray(t) - dt)) / (2 * dt)


def _smoothstep(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def _ev_track(
    kind: str, ego: _Motion, duration_s: float, rng: np.random.Generator, far_start: bool = False
) -> tuple[Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], dict[str, float]]:
    """An EV path ``t → (x, y)`` in the ego's road frame for scenario ``kind``, and its parameters
    (``far_start``: the wider distances of :data:`FAR_START`)."""
    T = duration_s
    if kind == "crossing":
        t_c = float(rng.uniform(0.15, 0.85) * T)
        gap = float(rng.uniform(*(FAR_START["crossing_gap_m"] if far_start else (8.0, 40.0))))
        x_i = float(ego.x(np.array([t_c]))[0]) + gap
        side = float(rng.choice([-1.0, 1.0]))
        lane = float(rng.uniform(-4.0, 4.0))
        v = float(rng.uniform(8.0, 20.0))
        p = {"cross_time_s": t_c, "gap_m": gap, "ev_speed_mps": v, "direction": side}
        return (lambda t: (np.full_like(t, x_i + lane), side * v * (t - t_c))), p
    if kind == "opposite_direction":
        lateral = float(rng.uniform(3.0, 10.0))
        v = float(rng.uniform(8.0, 25.0))
        t_p = float(rng.uniform(*(FAR_START["opposite_pass_fraction"] if far_start else (0.1, 0.9))) * T)
        x_p = float(ego.x(np.array([t_p]))[0])
        p = {"lateral_m": lateral, "ev_speed_mps": v, "pass_time_s": t_p}
        return (lambda t: (x_p - v * (t - t_p), np.full_like(t, lateral))), p
    if kind == "same_direction":
        lateral = float(rng.uniform(3.0, 8.0) * rng.choice([-1.0, 1.0]))
        dv = float(rng.uniform(-6.0, 10.0))
        dx_mid = float(rng.uniform(*(FAR_START["same_direction_offset_m"] if far_start else (-60.0, 60.0))))
        p = {"lateral_m": lateral, "relative_speed_mps": dv, "offset_mid_m": dx_mid}
        return (lambda t: (ego.x(t) + dx_mid + dv * (t - 0.5 * T), np.full_like(t, lateral))), p
    if kind == "from_behind":
        gap0 = float(rng.uniform(*(FAR_START["from_behind_gap_m"] if far_start else (30.0, 140.0))))
        dv = float(rng.uniform(5.0, 15.0))
        dur = float(rng.uniform(2.0, 3.5))
        # the EV has moved most of the way over before it draws level with the ego
        pass_gap = max(float(rng.uniform(10.0, 25.0)), 0.7 * dv * dur)
        t_lc = (gap0 - pass_gap) / dv
        p = {"gap0_m": gap0, "relative_speed_mps": dv, "lane_change_time_s": t_lc}
        return (lambda t: (ego.x(t) - gap0 + dv * t, 3.5 * _smoothstep((t - t_lc) / dur))), p
    raise ValueError(f"unknown audio scenario {kind!r}; choose from {', '.join(AUDIO_SCENARIOS)}")


def _ego_motion(kind: str, rng: np.random.Generator) -> _Motion:
    if kind == "crossing":
        v0 = 0.0 if rng.random() < 0.3 else float(rng.uniform(1.0, 12.0))
    else:
        v0 = float(rng.uniform(5.0, 20.0))
    accel = float(rng.uniform(-0.8, 0.8)) if v0 > 0 else 0.0
    return _Motion(v0, accel)


@dataclass
class ScenarioTracks:
    """World trajectories of one simulated drive, covering ``[-PRE_ROLL_S, duration]`` at 100 Hz."""

    name: str
    ego: Trajectory
    evs: list[Trajectory]
    params: list[dict[str, Any]]
    ego_speed_mps: float


def make_tracks(
    scenario: str,
    duration_s: float,
    rng: np.random.Generator,
    *,
    n_sirens: int = 1,
    far_start: bool = False,
) -> ScenarioTracks:
    """Ego and EV trajectories for ``scenario`` (``"none"``: an ego drive with no EV).

    The first EV follows ``scenario``; further EVs (``n_sirens > 1``) take random scenarios around
    the same ego drive. ``far_start``: EVs start farther away (module docstring).
    """
    if scenario not in (*AUDIO_SCENARIOS, "none"):
        raise ValueError(
            f"unknown audio scenario {scenario!r}; choose from {', '.join(AUDIO_SCENARIOS)}, none"
        )
    ego_kind = scenario if scenario != "none" else str(rng.choice(AUDIO_SCENARIOS))
    motion = _ego_motion(ego_kind, rng)
    t = np.arange(round((duration_s + PRE_ROLL_S) * TRAJECTORY_RATE_HZ) + 1) / TRAJECTORY_RATE_HZ - PRE_ROLL_S
    psi = float(rng.uniform(-math.pi, math.pi))
    ox, oy = (float(v) for v in rng.uniform(-1000.0, 1000.0, size=2))
    c, s = math.cos(psi), math.sin(psi)

    def world(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return ox + c * x - s * y, oy + s * x + c * y

    ex, ey = world(motion.x(t), np.zeros_like(t))
    ego = Trajectory(t, ex, ey, np.full_like(t, psi))
    kinds = (
        []
        if scenario == "none"
        else [scenario] + [str(rng.choice(AUDIO_SCENARIOS)) for _ in range(n_sirens - 1)]
    )
    evs: list[Trajectory] = []
    params: list[dict[str, Any]] = []
    for kind in kinds:
        path, p = _ev_track(kind, motion, duration_s, rng, far_start)
        vx, vy = path(t)
        wx, wy = world(vx, vy)
        evs.append(Trajectory(t, wx, wy))
        params.append({"scenario": kind, **{k: round(float(v), 3) for k, v in p.items()}})
    speed = float(np.mean(motion.speed(t[t >= 0])))
    return ScenarioTracks(scenario, ego, evs, params, speed)


def _clip_to_span(traj: Trajectory, duration_s: float) -> Trajectory:
    """The part of an internal trajectory that the recording stores: ``0 … duration`` at 100 Hz."""
    t = np.linspace(0.0, duration_s, round(duration_s * TRAJECTORY_RATE_HZ) + 1)
    x, y = traj.position(t)
    yaw = traj.heading(t) if traj.yaw is not None else None
    return Trajectory(t, x, y, yaw)


def pick_by_group(pool: Sequence[AudioSource], rng: np.random.Generator) -> AudioSource:
    """One source of ``pool``: a group drawn uniformly, then one of its members (so a group with many
    clips is not drawn more often than a single recording)."""
    groups = sorted({s.group for s in pool})
    g = groups[int(rng.integers(len(groups)))]
    members = [s for s in pool if s.group == g]
    return members[int(rng.integers(len(members)))]


def _band_power(x: np.ndarray, sample_rate: int, band: tuple[float, float]) -> float:
    spec = np.abs(np.fft.rfft(x, axis=0)) ** 2
    f = np.fft.rfftfreq(x.shape[0], 1.0 / sample_rate)
    sel = (f >= band[0]) & (f <= band[1])
    return float(spec[sel].sum())


def simulate_recording(
    scenario: str = "random",
    duration_s: float = 10.0,
    seed: int = 0,
    *,
    siren: str = "auto",
    noise: str = "auto",
    n_sirens: int = 1,
    data_root: str | Path | None = None,
    siren_pool: Sequence[AudioSource] | None = None,
    noise_pool: Sequence[AudioSource] | None = None,
    sample_rate: int = REFERENCE_SAMPLE_RATE,
    mics: np.ndarray | None = None,
    kernel: str = "sinc",
    distractors: bool = True,
    street_dba: tuple[float, float] = STREET_NOISE_DBA,
    siren_pitch: tuple[float, float] | None = None,
    full_scale_db_spl: float = FULL_SCALE_DB_SPL,
    siren_level_db: tuple[float, float] = SIREN_LEVEL_DB_1M,
    far_start: bool = False,
) -> Recording:
    """Simulate one recording of the reference array (not written; see :func:`generate_recordings`).

    Args:
        scenario: one of :data:`AUDIO_SCENARIOS`, ``"random"``, or ``"none"`` (no siren).
        duration_s: audio length.
        seed: everything random derives from it.
        siren: ``"synth"`` (procedural), ``"real"`` (clips/tones/recordings from the data),
            ``"auto"`` (real for :data:`REAL_SIREN_SHARE` of the sirens when the data exist), or
            ``"none"`` (no siren whatever ``scenario`` says).
        noise: ``"real"`` (street recordings), ``"generated"``, or ``"auto"`` (real when present).
        n_sirens: number of EVs (≥ 1) when there is a siren.
        data_root: the shared data folder; default :func:`makeway.paths.data_dir`.
        siren_pool, noise_pool: restrict the real ingredients (e.g. to a training split).
        mics: capsule positions (default: the reference array).
        kernel: fractional-delay interpolation (``"sinc"`` or ``"lagrange"``).
        distractors: add non-siren street sounds (module docstring) to a share of the recordings.
        street_dba: range of the street noise's A-weighted level at the array (dB(A)); wider than
            the default to teach a detector that loud traffic alone is no siren.
        siren_pitch: ``(low, high)`` pitch factors (e.g. ``(0.7, 1.25)``) for training-set variety:
            :data:`SIREN_VARIETY_SHARE` of the sirens are played at a factor drawn log-uniformly
            from it (real sirens resampled, so their tempo changes too; synthesized ones
            re-rendered with the sweep scaled and, for wail and yelp, a rise fraction redrawn from
            :data:`SIREN_VARIETY_RISE`). Drawn from its own random stream, so every other draw
            of a seed is unchanged; ``None`` (default) leaves the sirens as they are.
        full_scale_db_spl: the simulated array's calibration, the dB SPL that a digital RMS of
            1.0 stands for (default 135, the networks' scale); stated in the recording. A lower
            value is a more sensitive array: the same scene comes out louder.
        siren_level_db: ``(low, high)`` range the emitted siren level is drawn from, uniformly
            (dB SPL at 1 m; default :data:`SIREN_LEVEL_DB_1M`, the networks' training prior). Real
            sirens span about 110–135 dB: ``(110, 135)`` tests ranging beyond the prior (issue 25).
        far_start: EVs start and pass farther away, out to ~300 m (module docstring); off by
            default.
    """
    rng = np.random.default_rng(seed)
    vary_rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 0x517E]) if siren_pitch else None
    if siren_pitch is not None and not 0.25 <= siren_pitch[0] <= siren_pitch[1] <= 4.0:
        raise ValueError(f"siren_pitch must be (low, high), 0.25 <= low <= high <= 4, not {siren_pitch!r}")
    if siren not in ("auto", "synth", "real", "none"):
        raise ValueError(f"siren must be auto, synth, real or none, not {siren!r}")
    if noise not in ("auto", "real", "generated"):
        raise ValueError(f"noise must be auto, real or generated, not {noise!r}")
    if scenario == "random":
        scenario = str(rng.choice(AUDIO_SCENARIOS))
    if siren == "none":
        scenario = "none"
    root = Path(data_root) if data_root is not None else data_dir()
    if siren_pool is None:
        siren_pool = load_siren_sources(root) if root is not None and siren in ("auto", "real") else []
    if noise_pool is None:
        noise_pool = load_street_noise_sources(root) if root is not None and noise in ("auto", "real") else []
    if siren == "real" and not siren_pool:
        raise ValueError("siren='real' needs the shared data (audio/siren_clips, siren_tones); none found")
    if noise == "real" and not noise_pool:
        raise ValueError("noise='real' needs the shared data (audio/street_recordings); none found")

    mics = reference_mics() if mics is None else np.asarray(mics, dtype=np.float64)
    n = round(duration_s * sample_rate)
    tracks = make_tracks(scenario, duration_s, rng, n_sirens=max(1, n_sirens), far_start=far_start)
    meta: dict[str, Any] = {
        "simulator": "makeway.sim.audio_scenarios",
        "scenario": scenario,
        "seed": int(seed),
        "duration_s": float(duration_s),
        "ego_speed_mps": round(tracks.ego_speed_mps, 3),
    }
    if far_start:
        meta["far_start"] = True

    # --- sirens
    n_sig = round((duration_s + PRE_ROLL_S) * sample_rate) + 64
    sources: list[PointSource] = []
    siren_meta: list[dict[str, Any]] = []
    for ev, p in zip(tracks.evs, tracks.params, strict=True):
        use_real = siren == "real" or (
            siren == "auto" and bool(siren_pool) and rng.random() < REAL_SIREN_SHARE
        )
        info: dict[str, Any] = dict(p)
        sp: SirenParams | None = None
        if use_real:
            src = pick_by_group(siren_pool, rng)
            sig = fit_length(src.load(sample_rate), n_sig, rng, crossfade=0 if src.kind == "tone" else 2400)
            info.update(ingredient="real", name=src.name, group=src.group, kind=src.kind, mode=src.mode)
        else:
            sig, sp = synthesize_siren(None, n_sig / sample_rate, sample_rate, rng=rng)
        if vary_rng is not None and siren_pitch is not None and vary_rng.random() < SIREN_VARIETY_SHARE:
            sig, sp, info["variety"] = _vary_siren(sig, sp, siren_pitch, vary_rng, sample_rate)
        if sp is not None:
            info.update(
                ingredient="synth",
                mode=sp.mode,
                f_low_hz=round(sp.f_low, 1),
                f_high_hz=round(sp.f_high, 1),
                period_s=round(sp.period_s, 3),
            )
        ps, drawn = siren_point_source(sig, ev, rng, level_db=siren_level_db)
        info.update(drawn)
        sources.append(ps)
        siren_meta.append(info)
    siren_pa = simulate_array(sources, tracks.ego, mics, n, sample_rate, kernel=kernel) if sources else None

    # --- street noise: a few point sources fixed around the car
    pool = list(noise_pool) if noise in ("auto", "real") else []
    street, meta["street_noise"] = street_noise_field(n, sample_rate, mics, rng, pool, street_dba)

    # --- wind and self-noise
    wind_10 = float(rng.uniform(*WIND_LEVEL_10_DB))
    air = tracks.ego_speed_mps + float(rng.uniform(*AMBIENT_WIND_MPS))
    wind = wind_noise(n, len(mics), sample_rate, air, wind_10, rng)
    meta["wind"] = {"level_10_db": round(wind_10, 2), "air_speed_mps": round(air, 2)}
    noise_pa = street + wind + self_noise(n, len(mics), rng)
    if distractors:
        extra_pa, meta["distractors"] = _distractor_field(n, sample_rate, mics, street, seed)
        if extra_pa is not None:
            noise_pa = noise_pa + extra_pa

    total = noise_pa if siren_pa is None else siren_pa + noise_pa
    if siren_pa is not None:
        snr = _band_power(siren_pa, sample_rate, SNR_BAND_HZ) / max(
            _band_power(noise_pa, sample_rate, SNR_BAND_HZ), 1e-30
        )
        meta["snr_band_db"] = round(10 * math.log10(max(snr, 1e-30)), 2)
    audio = total / db_spl_to_pa(full_scale_db_spl)
    peak = float(np.max(np.abs(audio)))
    if peak > 0.95:  # a real capsule would overload; limit softly rather than clip
        audio = 0.95 * np.tanh(audio / 0.95)
        meta["limited"] = True
    meta["sirens"] = siren_meta
    ego_out = _clip_to_span(tracks.ego, duration_s)
    srcs_out = [_clip_to_span(ev, duration_s) for ev in tracks.evs]
    return Recording(
        audio.astype(np.float32), sample_rate, mics, ego_out, srcs_out, None, meta, float(full_scale_db_spl)
    )


def check_siren_level(level_db: Sequence[float]) -> tuple[float, float]:
    """``level_db`` as ``(low, high)`` floats, or a ValueError unless it is two numbers with
    low ≤ high inside :data:`SIREN_LEVEL_BOUNDS_DB` (dB SPL at 1 m)."""
    try:
        lo, hi = (float(v) for v in level_db)
    except (TypeError, ValueError):
        raise ValueError(f"siren_level_db must be (low, high) in dB SPL at 1 m, not {level_db!r}") from None
    b = SIREN_LEVEL_BOUNDS_DB
    if not b[0] <= lo <= hi <= b[1]:
        raise ValueError(
            f"siren_level_db must be (low, high) with {b[0]:g} <= low <= high <= {b[1]:g} dB SPL at 1 m, "
            f"not {level_db!r}"
        )
    return lo, hi


def siren_point_source(
    signal: np.ndarray,
    trajectory: Trajectory,
    rng: np.random.Generator,
    *,
    level_db: tuple[float, float] = SIREN_LEVEL_DB_1M,
) -> tuple[PointSource, dict[str, float]]:
    """A siren as a :class:`~makeway.sim.acoustics.PointSource`: ``signal`` (unit RMS, its first
    sample emitted :data:`PRE_ROLL_S` before t = 0) played at a level drawn uniformly from
    ``level_db`` (dB SPL at 1 m; default :data:`SIREN_LEVEL_DB_1M`), from a speaker height, ground
    reflection and rear attenuation drawn from their ranges (module docstring). Returns the source
    and the drawn values."""
    lo, hi = check_siren_level(level_db)
    level = float(rng.uniform(lo, hi))
    ps = PointSource(
        signal=np.asarray(signal, dtype=np.float32) * np.float32(db_spl_to_pa(level)),
        t0=-PRE_ROLL_S,
        trajectory=trajectory,
        height_m=float(rng.uniform(*SIREN_HEIGHT_M)),
        reflection=float(rng.uniform(*GROUND_REFLECTION)),
        rear_attenuation_db=float(rng.uniform(*SIREN_REAR_ATTENUATION_DB)),
    )
    drawn = {
        "level_db_1m": round(level, 2),
        "height_m": round(ps.height_m, 3),
        "reflection": round(ps.reflection, 3),
        "rear_attenuation_db": round(ps.rear_attenuation_db, 2),
    }
    return ps, drawn


def street_noise_field(
    n: int,
    sample_rate: int,
    mics: np.ndarray,
    rng: np.random.Generator,
    noise_pool: Sequence[AudioSource] = (),
    street_dba: tuple[float, float] = STREET_NOISE_DBA,
) -> tuple[np.ndarray, dict[str, Any]]:
    """Street noise at the array, Pa ``(n, M)``: 2–4 point sources fixed around the car
    (:data:`N_NOISE_SOURCES`, :data:`NOISE_DISTANCE_M`, :data:`NOISE_HEIGHT_M`), each playing a
    stretch of a real recording of ``noise_pool`` (generated street noise when it is empty), scaled
    to an A-weighted level drawn from ``street_dba``. Returns the field and its description."""
    k = int(rng.integers(N_NOISE_SOURCES[0], N_NOISE_SOURCES[1] + 1))
    extra = round(0.25 * sample_rate)
    signals: list[np.ndarray] = []
    names: list[str] = []
    if noise_pool:
        pool = list(noise_pool)
        picks = rng.choice(len(pool), size=k, replace=len(pool) < k)
        for i in picks:
            signals.append(fit_length(pool[int(i)].load(sample_rate), n + extra, rng))
            names.append(pool[int(i)].name)
    else:
        signals = [generated_street_noise(n + extra, sample_rate, rng) for _ in range(k)]
    bearing = rng.uniform(-math.pi, math.pi, size=k)
    dist = rng.uniform(*NOISE_DISTANCE_M, size=k)
    pos = np.stack(
        [dist * np.cos(bearing), dist * np.sin(bearing), rng.uniform(*NOISE_HEIGHT_M, size=k)], axis=1
    )
    pos[:, :2] += mics[:, :2].mean(axis=0)
    street = place_fixed_sources(
        signals, pos, mics, n, sample_rate, reflection=float(rng.uniform(*GROUND_REFLECTION))
    )
    lo, hi = (float(v) for v in street_dba)
    if not lo <= hi:
        raise ValueError(f"street_dba must be (low, high) with low <= high, not {street_dba!r}")
    street_level = float(rng.uniform(lo, hi))
    street *= 10 ** ((street_level - a_weighted_level_db(street, sample_rate)) / 20.0)
    meta = {
        "ingredient": "real" if noise_pool else "generated",
        "names": names,
        "groups": [f"street:{nm}" for nm in names],
        "level_dba": round(street_level, 2),
        "positions_vehicle_m": np.round(pos, 2).tolist(),
    }
    return street, meta


def _vary_siren(
    sig: np.ndarray,
    sp: SirenParams | None,
    pitch: tuple[float, float],
    rng: np.random.Generator,
    sample_rate: int,
) -> tuple[np.ndarray, SirenParams | None, dict[str, float]]:
    """One siren with its pitch (and a synthesized wail/yelp's sweep shape) varied; see
    :func:`simulate_recording`'s ``siren_pitch``. Returns the signal, the new synthesizer parameters
    (None for a real siren) and what was changed, for ``meta.yaml``."""
    factor = float(np.exp(rng.uniform(math.log(pitch[0]), math.log(pitch[1]))))
    if sp is None:
        return pitch_shift(sig, factor, len(sig)), None, {"pitch_factor": round(factor, 4)}
    rise = sp.rise_fraction
    if sp.mode in ("wail", "yelp"):
        rise = float(rng.uniform(*SIREN_VARIETY_RISE))
    new = replace(sp, f_low=sp.f_low * factor, f_high=sp.f_high * factor, rise_fraction=rise)
    out = render_siren(new, len(sig) / sample_rate, sample_rate, rng)[: len(sig)]
    return out, new, {"pitch_factor": round(factor, 4), "rise_fraction": round(rise, 3)}


def _distractor_field(
    n: int, sample_rate: int, mics: np.ndarray, street: np.ndarray, seed: int
) -> tuple[np.ndarray | None, list[dict[str, Any]]]:
    """Pressure of the non-siren street sounds of one recording (or None) and their description."""
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, 0xD157])
    if rng.random() >= DISTRACTOR_SHARE:
        return None, []
    street_dba = a_weighted_level_db(street, sample_rate)
    extra = round(0.25 * sample_rate)
    total = np.zeros((n, len(mics)))
    info: list[dict[str, Any]] = []
    centre = mics[:, :2].mean(axis=0)
    for _ in range(int(rng.integers(N_DISTRACTORS[0], N_DISTRACTORS[1] + 1))):
        d = synthesize_distractor(None, n + extra, sample_rate, rng)
        bearing = float(rng.uniform(-math.pi, math.pi))
        dist = float(rng.uniform(*DISTRACTOR_DISTANCE_M))
        height = float(rng.uniform(*(BIRD_HEIGHT_M if d.kind == "birds" else DISTRACTOR_HEIGHT_M)))
        pos = np.array([[centre[0] + dist * math.cos(bearing), centre[1] + dist * math.sin(bearing), height]])
        pa = place_fixed_sources([d.signal], pos, mics, n, sample_rate, reflection=0.8)
        # output sample j hears source sample extra + j − delay (place_fixed_sources' alignment)
        delay = round(float(np.linalg.norm(pos[0] - mics.mean(axis=0))) / SPEED_OF_SOUND * sample_rate)
        active = d.active[extra - delay : extra - delay + n]
        if not active.any():
            continue
        rel = float(rng.uniform(*DISTRACTOR_REL_DBA))
        pa *= 10 ** ((street_dba + rel - a_weighted_level_db(pa[active], sample_rate)) / 20.0)
        total += pa
        info.append(
            {
                "kind": d.kind,
                **d.params,
                "position_vehicle_m": np.round(pos[0], 2).tolist(),
                "relative_dba": round(rel, 2),
                "active_s": round(float(active.sum()) / sample_rate, 3),
            }
        )
    return (total if info else None), info


def source_pools(
    split: str, data_root: str | Path | None = None
) -> tuple[list[AudioSource], list[AudioSource]]:
    """The siren and street-noise ingredients of one source split (``"all"``, ``"train"`` or
    ``"test"``; :func:`makeway.sim.siren.group_split`) of the shared data at ``data_root`` (default:
    :func:`makeway.paths.data_dir`). Both empty without the data: the simulator then synthesizes
    sirens and noise."""
    root = Path(data_root) if data_root is not None else data_dir()
    if root is None:
        return [], []
    sirens = split_sources(load_siren_sources(root), split)
    noise = split_sources(load_street_noise_sources(root), split)
    return list(sirens), list(noise)


def generate_held_out(
    out_dir: str | Path,
    n: int,
    seeds: Sequence[int],
    duration_s: float = 8.0,
    split: str = "test",
    *,
    siren_level_db: tuple[float, float] = SIREN_LEVEL_DB_1M,
    far_start: bool = False,
) -> list[Path]:
    """The held-out sets of the audio benchmarks: ``n`` recordings per seed, into
    ``out_dir/seed_<seed>``, made of the test-split ingredients only (:func:`source_pools`), as
    ``makeway audio simulate --n N --duration D --seed S --split test`` makes them
    (``split="train"``: validation sets of training-split ingredients, for choices made before a
    held-out set is looked at). ``siren_level_db``: the emitted levels' range, ``far_start``: EVs out
    to ~300 m (:func:`simulate_recording`)."""
    sirens, noise = source_pools(split)
    folders: list[Path] = []
    for seed in seeds:
        folders += generate_recordings(
            Path(out_dir) / f"seed_{seed}",
            n,
            duration_s=duration_s,
            seed=seed,
            siren_pool=sirens,
            noise_pool=noise,
            siren_level_db=siren_level_db,
            far_start=far_start,
        )
    return folders


def held_out_folders(
    data: Sequence[str | Path] | None,
    out_dir: str | Path,
    n: int,
    seeds: Sequence[int],
    duration_s: float = 8.0,
    split: str = "test",
    *,
    siren_level_db: tuple[float, float] = SIREN_LEVEL_DB_1M,
    far_start: bool = False,
) -> list[Path]:
    """The recordings an audio benchmark runs on: those in the ``data`` folders
    (:func:`~makeway.sense.recording.recording_folders`), or, when none are given, the held-out
    sets simulated into ``out_dir`` (:func:`generate_held_out`, of ``split``'s ingredients, emitted
    levels drawn from ``siren_level_db``)."""
    if data:
        return [f for d in data for f in recording_folders(d)]
    return generate_held_out(
        out_dir, n, seeds, duration_s, split, siren_level_db=siren_level_db, far_start=far_start
    )


def generate_recordings(
    out_dir: str | Path,
    n: int,
    *,
    scenarios: Sequence[str] = AUDIO_SCENARIOS,
    duration_s: float = 10.0,
    seed: int = 0,
    siren: str = "auto",
    noise: str = "auto",
    no_siren_fraction: float = 0.25,
    two_siren_fraction: float = 0.1,
    data_root: str | Path | None = None,
    siren_pool: Sequence[AudioSource] | None = None,
    noise_pool: Sequence[AudioSource] | None = None,
    progress: bool = True,
    start_index: int = 0,
    distractors: bool = True,
    street_dba: tuple[float, float] = STREET_NOISE_DBA,
    siren_pitch: tuple[float, float] | None = None,
    full_scale_db_spl: float = FULL_SCALE_DB_SPL,
    siren_level_db: tuple[float, float] = SIREN_LEVEL_DB_1M,
    far_start: bool = False,
) -> list[Path]:
    """Simulate ``n`` recordings into ``out_dir/rec_00000`` … (each written all-or-nothing).

    A share ``no_siren_fraction`` has no siren (negatives), ``two_siren_fraction`` of the rest two
    EVs. Recording ``i`` uses a seed derived from ``(seed, i)``, so any one can be re-made alone.
    ``distractors``: non-siren street sounds in a share of the recordings (module docstring);
    ``street_dba``: the street noise's level range; ``siren_pitch``: pitch variety for training sets;
    ``full_scale_db_spl``: the array's calibration; ``siren_level_db``: the emitted levels' range;
    ``far_start``: EVs out to ~300 m (all: see :func:`simulate_recording`).
    """
    from makeway.progress import progress_bar

    for s in scenarios:
        if s not in AUDIO_SCENARIOS:
            raise ValueError(f"unknown audio scenario {s!r}; choose from {', '.join(AUDIO_SCENARIOS)}")
    siren_level_db = check_siren_level(siren_level_db)
    root = Path(data_root) if data_root is not None else data_dir()
    if siren_pool is None and root is not None and siren in ("auto", "real"):
        siren_pool = load_siren_sources(root)
    if noise_pool is None and root is not None and noise in ("auto", "real"):
        noise_pool = load_street_noise_sources(root)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    with progress_bar("simulating", n, enabled=progress, unit="rec") as advance:
        for i in range(start_index, start_index + n):
            rec_seed = int(np.random.SeedSequence([seed, i]).generate_state(1)[0])
            pick = np.random.default_rng(rec_seed ^ 0x5EED)
            negative = pick.random() < no_siren_fraction
            scen = "none" if negative else str(pick.choice(list(scenarios)))
            n_sir = 2 if (not negative and pick.random() < two_siren_fraction) else 1
            rec = simulate_recording(
                scen,
                duration_s,
                rec_seed,
                siren="none" if negative else siren,
                noise=noise,
                n_sirens=n_sir,
                data_root=root,
                siren_pool=siren_pool or [],
                noise_pool=noise_pool or [],
                distractors=distractors,
                street_dba=street_dba,
                siren_pitch=siren_pitch,
                full_scale_db_spl=full_scale_db_spl,
                siren_level_db=siren_level_db,
                far_start=far_start,
            )
            written.append(write_recording(out / f"rec_{i:05d}", rec))
            advance(1)
    return written
