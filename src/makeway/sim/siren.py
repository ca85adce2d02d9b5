"""Siren sounds for the array simulator: a procedural synthesizer and the real clips and tone loops.

**Synthesizer.** Four modes with their fundamental-frequency range and period drawn per siren from
:data:`MODE_RANGES`. The ranges follow the usual public descriptions of electronic sirens (wail: a
slow rise and fall over ~600–1500 Hz in a few seconds; yelp: the same sweep several times a second;
hi-lo: two alternating tones, e.g. ~450/600 Hz for the European DIN two-tone and ~600/800 to
800/1100 Hz for US/Nordic units; phaser/"hyper-yelp": a sweep of ~0.1 s), and were checked against
the 163 real tone loops in ``../shared/data/audio/siren_tones`` (STFT peak track, 5th–95th
percentile of the dominant component between 300 and 2500 Hz; period from the track's
autocorrelation). The synthesized ranges (:data:`MODE_RANGES`) cover the common part of each:

=======  =====================  =====================  =================================
mode     low end (Hz)           high end (Hz)          period
=======  =====================  =====================  =================================
wail     measured 520–880       measured 1120–1700     measured 3.4–5.7 s (median ≈ 4.5)
yelp     measured 520–860       measured 1100–1740     measured 0.21–0.34 s (median 0.27)
hi-lo    measured 390–1100      measured 540–1500      full cycle mostly 1.0–1.5 s
         (most 450–820)         (most 600–1140)        (some police hi-lo 0.25–0.35 s)
phaser   measured 500–950       measured 1180–1500     measured 0.06–0.10 s
=======  =====================  =====================  =================================

Synthesized: wail 550–850 → 1200–1700 Hz every 3.5–5.5 s; yelp 550–850 → 1150–1700 Hz every
0.2–0.35 s; hi-lo 430–820 Hz and 1.25–1.45× that, full cycle 0.9–1.5 s; phaser 550–900 → 1200–1550
Hz every 0.06–0.12 s.

Electronic sirens drive a horn speaker with a square-ish wave, so the tone is rich in harmonics:
harmonic ``k`` gets amplitude ``k**-decay`` (decay 0.8–1.6), even harmonics weighted 0.2–1 (a pure
square wave has none), harmonics fade out above :data:`MAX_HARMONIC_HZ`. The sweep shape is a
raised-cosine rise over ``rise_fraction`` of the period and a raised-cosine fall over the rest, a
little period jitter (±2 % per cycle) and a slight tremolo. Every draw is seedable.

**Real sirens.** :func:`load_siren_sources` lists the real clips, tone loops and longer recordings
with a ``group`` each, so train/test splits can be made by source: the 150 Kaggle clips in blocks of
10 consecutive numbers (neighbours are often cut from the same video), the tone loops by siren model
(``family__model__tone`` → model), each long recording on its own. :meth:`AudioSource.load` returns
mono audio resampled to 48 kHz with unit RMS (cached); for sirens it first undoes the recording's own
slow level changes and cuts its silences (:func:`flatten_envelope`), because the simulator applies
the distance itself and labels every window of a siren's track as "siren".

**Variety for training.** :func:`pitch_shift` plays a siren faster or slower (pitch and tempo
together); the simulator's ``siren_pitch`` option uses it to cover sirens pitched outside the
measured unit ranges (e.g. a low mechanical-style wail) in training sets.
"""

from __future__ import annotations

import functools
import hashlib
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

SAMPLE_RATE = 48_000
SIREN_MODES = ("wail", "yelp", "hilo", "phaser")
MAX_HARMONIC_HZ = 12_000.0
"""Harmonics fade to zero between MAX_HARMONIC_HZ − 1 kHz and MAX_HARMONIC_HZ."""

MODE_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    # f_low, f_high: the bottom/top of the sweep (Hz); period_s: one full cycle (s);
    # rise_fraction: share of the cycle spent rising.
    "wail": {
        "f_low": (550.0, 850.0),
        "f_high": (1200.0, 1700.0),
        "period_s": (3.5, 5.5),
        "rise_fraction": (0.35, 0.6),
    },
    "yelp": {
        "f_low": (550.0, 850.0),
        "f_high": (1150.0, 1700.0),
        "period_s": (0.2, 0.35),
        "rise_fraction": (0.4, 0.6),
    },
    # hilo: f_high = f_low * ratio; the two tones alternate, each for half the period.
    "hilo": {
        "f_low": (430.0, 820.0),
        "ratio": (1.25, 1.45),
        "period_s": (0.9, 1.5),
        "rise_fraction": (0.5, 0.5),
    },
    "phaser": {
        "f_low": (550.0, 900.0),
        "f_high": (1200.0, 1550.0),
        "period_s": (0.06, 0.12),
        "rise_fraction": (0.7, 0.9),
    },
}


def mode_frequency_bounds(mode: str) -> tuple[float, float]:
    """The lowest and highest fundamental a synthesized ``mode`` siren can reach (Hz)."""
    r = MODE_RANGES[mode]
    if mode == "hilo":
        return r["f_low"][0], r["f_low"][1] * r["ratio"][1]
    return r["f_low"][0], r["f_high"][1]


@dataclass(frozen=True)
class SirenParams:
    """One synthesized siren: mode, sweep range (Hz), period (s) and timbre."""

    mode: str
    f_low: float
    f_high: float
    period_s: float
    rise_fraction: float
    harmonic_decay: float = 1.2
    even_weight: float = 0.5
    start_phase: float = 0.0
    """Where in its cycle the siren is at t = 0, as a fraction of the period."""
    tremolo_depth: float = 0.03
    tremolo_hz: float = 5.0


def random_siren_params(mode: str | None = None, rng: np.random.Generator | None = None) -> SirenParams:
    """Draw a siren from :data:`MODE_RANGES` (``mode=None``: a random mode)."""
    rng = np.random.default_rng() if rng is None else rng
    if mode is None:
        mode = str(rng.choice(SIREN_MODES))
    if mode not in MODE_RANGES:
        raise ValueError(f"unknown siren mode {mode!r}; choose from {', '.join(SIREN_MODES)}")
    r = MODE_RANGES[mode]

    def u(key: str) -> float:
        lo, hi = r[key]
        return float(rng.uniform(lo, hi))

    f_low = u("f_low")
    f_high = f_low * u("ratio") if mode == "hilo" else u("f_high")
    return SirenParams(
        mode=mode,
        f_low=f_low,
        f_high=f_high,
        period_s=u("period_s"),
        rise_fraction=u("rise_fraction"),
        harmonic_decay=float(rng.uniform(0.8, 1.6)),
        even_weight=float(rng.uniform(0.2, 1.0)),
        start_phase=float(rng.uniform(0.0, 1.0)),
        tremolo_depth=float(rng.uniform(0.0, 0.06)),
        tremolo_hz=float(rng.uniform(2.0, 8.0)),
    )


def _cycle_shape(frac: np.ndarray, rise: float, mode: str) -> np.ndarray:
    """Position within the sweep (0 = f_low, 1 = f_high) at cycle fraction ``frac`` ∈ [0, 1)."""
    if mode == "hilo":
        # two tones with a raised-cosine glide of 1.5 % of the cycle (≈ 15–20 ms) between them
        glide = 0.015
        up = np.clip((frac - 0.5) / glide, 0.0, 1.0) - np.clip((frac - 1.0 + glide) / glide, 0.0, 1.0)
        return 0.5 - 0.5 * np.cos(np.pi * up)
    rising = frac < rise
    out = np.empty_like(frac)
    out[rising] = 0.5 - 0.5 * np.cos(np.pi * frac[rising] / rise)
    out[~rising] = 0.5 + 0.5 * np.cos(np.pi * (frac[~rising] - rise) / (1.0 - rise))
    return out


def frequency_track(params: SirenParams, t: np.ndarray, jitter: np.ndarray | None = None) -> np.ndarray:
    """The fundamental (Hz) at times ``t`` (s); ``jitter`` optionally scales each cycle's length."""
    cycles = np.asarray(t, dtype=np.float64) / params.period_s + params.start_phase
    if jitter is not None:
        # stretch each cycle by its own factor: map time → cycle count through a piecewise-linear warp
        n = len(jitter)
        edges = np.concatenate([[0.0], np.cumsum(jitter)])
        if cycles.size and cycles.max() > edges[-1]:
            raise ValueError("jitter covers fewer cycles than t spans")
        cycles = np.interp(cycles, edges, np.arange(n + 1))
    frac = np.mod(cycles, 1.0)
    pos = _cycle_shape(frac, params.rise_fraction, params.mode)
    return params.f_low + (params.f_high - params.f_low) * pos


def render_siren(
    params: SirenParams,
    duration_s: float,
    sample_rate: int = SAMPLE_RATE,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Render ``params`` for ``duration_s``: float32 mono with unit RMS."""
    rng = np.random.default_rng() if rng is None else rng
    n = max(1, round(duration_s * sample_rate))
    t = np.arange(n) / sample_rate
    n_cycles = int(1.1 * (duration_s / params.period_s + params.start_phase)) + 3
    jitter = 1.0 + rng.uniform(-0.02, 0.02, size=n_cycles)
    f0 = frequency_track(params, t, jitter)
    phase = 2.0 * np.pi * np.cumsum(f0) / sample_rate + rng.uniform(0, 2 * np.pi)
    out = np.zeros(n, dtype=np.float64)
    k_max = int(MAX_HARMONIC_HZ // max(params.f_low, 1.0))
    for k in range(1, max(k_max, 1) + 1):
        amp = k ** (-params.harmonic_decay) * (params.even_weight if k % 2 == 0 else 1.0)
        fade = np.clip((MAX_HARMONIC_HZ - k * f0) / 1000.0, 0.0, 1.0)
        if not fade.any():
            break
        out += amp * fade * np.sin(k * phase + rng.uniform(0, 2 * np.pi))
    if params.tremolo_depth > 0:
        out *= 1.0 + params.tremolo_depth * np.sin(
            2 * np.pi * params.tremolo_hz * t + rng.uniform(0, 2 * np.pi)
        )
    # 5 ms fade-in so that a siren starting at the first sample does not click
    ramp = min(n, int(0.005 * sample_rate))
    out[:ramp] *= np.linspace(0.0, 1.0, ramp, endpoint=False)
    rms = float(np.sqrt(np.mean(out**2)))
    return (out / max(rms, 1e-12)).astype(np.float32)


def synthesize_siren(
    mode: str | None = None,
    duration_s: float = 5.0,
    sample_rate: int = SAMPLE_RATE,
    seed: int | None = None,
    rng: np.random.Generator | None = None,
) -> tuple[np.ndarray, SirenParams]:
    """A random siren of ``mode`` (None: any): ``(unit-RMS float32 signal, its parameters)``."""
    rng = np.random.default_rng(seed) if rng is None else rng
    params = random_siren_params(mode, rng)
    return render_siren(params, duration_s, sample_rate, rng), params


def pitch_shift(x: np.ndarray, factor: float, n: int | None = None) -> np.ndarray:
    """``x`` played ``factor`` times faster (pitch and tempo both × ``factor``), ``n`` samples long.

    Polyphase resampling with the factor rounded to a fraction of denominator ≤ 100; where the result
    is shorter than ``n`` it is looped from its start (:func:`fit_length`, 50 ms crossfade). Used to
    widen the siren sounds a detector is trained on beyond the measured unit ranges (a mechanical or
    regional siren pitched lower or higher; :func:`makeway.sim.audio_scenarios.simulate_recording`'s
    ``siren_pitch``). ``n=None`` keeps the resampled length.
    """
    from fractions import Fraction

    from scipy.signal import resample_poly

    if not 0.25 <= factor <= 4.0:
        raise ValueError(f"pitch factor must be within 0.25–4, not {factor!r}")
    frac = Fraction(float(factor)).limit_denominator(100)
    y = np.asarray(x, dtype=np.float64)
    if frac != 1:
        y = resample_poly(y, frac.denominator, frac.numerator)
    y = y.astype(np.float32)
    if n is None:
        return y
    return y[:n].copy() if len(y) >= n else fit_length(y, n, random_start=False)


# ----------------------------------------------------------------------------------------- real audio


@functools.lru_cache(maxsize=256)
def _load_mono_cached(path: str, sample_rate: int) -> np.ndarray:
    import soundfile as sf
    from scipy.signal import resample_poly

    data, rate = sf.read(path, dtype="float32", always_2d=True)
    x = data.mean(axis=1).astype(np.float64)
    if int(rate) != sample_rate:
        g = math.gcd(int(rate), sample_rate)
        x = resample_poly(x, sample_rate // g, int(rate) // g)
    x = x - x.mean()
    out = np.asarray(x, dtype=np.float32)
    out.setflags(write=False)
    return out


def load_mono(path: str | Path, sample_rate: int = SAMPLE_RATE, *, unit_rms: bool = True) -> np.ndarray:
    """Read an audio file as mono float32 at ``sample_rate`` (polyphase resampling), cached.

    Channels are averaged and the mean removed; ``unit_rms`` scales to RMS 1. Returns a read-only
    array (copy it before changing it in place). Raises :class:`~makeway.errors.InputError` when the
    file cannot be read.
    """
    from makeway.errors import InputError

    try:
        x = _load_mono_cached(str(Path(path).resolve()), int(sample_rate))
    except Exception as exc:
        raise InputError(
            path, f"cannot be read as audio ({str(exc).strip().splitlines()[0] if str(exc) else exc!r})"
        ) from None
    return _unit_rms(x) if unit_rms else x


def _unit_rms(x: np.ndarray) -> np.ndarray:
    """``x`` scaled to RMS 1 as float32 (unchanged when silent or empty)."""
    rms = float(np.sqrt(np.mean(np.square(x, dtype=np.float64)))) if len(x) else 0.0
    return (x / rms).astype(np.float32) if rms > 0 else x


def cut_spans(
    x: np.ndarray, sample_rate: int, spans: Sequence[tuple[float, float]], *, unit_rms: bool = True
) -> np.ndarray:
    """``x`` without the samples of ``spans`` (seconds), the pieces joined end to end; unit RMS
    again when ``unit_rms``. Read-only like :func:`load_mono`."""
    keep = np.ones(len(x), dtype=bool)
    for start, end in spans:
        keep[max(0, round(start * sample_rate)) : max(0, round(end * sample_rate))] = False
    out = np.asarray(x, dtype=np.float32)[keep]
    if unit_rms:
        out = _unit_rms(out)
    out.setflags(write=False)
    return out


_TONE_MODES = (
    ("phaser", "phaser"),
    ("hyperyelp", "yelp"),
    ("yelp", "yelp"),
    ("wail", "wail"),
    ("hilo", "hilo"),
    ("twosound", "hilo"),
    ("_din", "hilo"),
    ("austria__hilo", "hilo"),
    ("kompressor", "hilo"),
    ("land", "hilo"),
    ("stadt", "hilo"),
    ("polizei", "hilo"),
    ("notarzt", "hilo"),
    ("fr_", "hilo"),
    ("it_", "hilo"),
)
HORN_TONES = ("horn", "bullhorn", "tmjingle")
"""Tone-loop names (last ``__`` part) that are air horns or jingles rather than sirens."""


@dataclass(frozen=True)
class AudioSource:
    """One real recording used as a simulator ingredient (a siren, or street noise).

    ``kind``: ``"clip"`` (3 s Kaggle siren clips), ``"tone"`` (clean siren-unit loops),
    ``"recording"`` (longer real siren recordings) or ``"street"`` (street noise without siren).
    ``group``: the unit to split train/test by (never put two sources of one group on both sides).
    ``mode``: wail/yelp/hilo/phaser when known from the name, else ``"unknown"``.
    """

    name: str
    group: str
    kind: str
    mode: str
    path: Path
    exclude: tuple[tuple[float, float], ...] = ()
    """Spans ``(start_s, end_s)`` cut out on loading (e.g. a siren heard in a no-siren recording)."""

    def load(self, sample_rate: int = SAMPLE_RATE) -> np.ndarray:
        """Mono float32 at ``sample_rate`` with unit RMS (cached, read-only), ``exclude`` cut out;
        a siren (every kind but ``"street"``) also through :func:`flatten_envelope`."""
        if self.kind != "street":
            return _flattened_siren(str(Path(self.path).resolve()), int(sample_rate), self.exclude)
        if not self.exclude:
            return load_mono(self.path, sample_rate)
        return cut_spans(load_mono(self.path, sample_rate, unit_rms=False), sample_rate, self.exclude)


@functools.lru_cache(maxsize=512)
def _flattened_siren(path: str, sample_rate: int, exclude: tuple[tuple[float, float], ...]) -> np.ndarray:
    x = load_mono(path, sample_rate, unit_rms=False)
    if exclude:
        x = cut_spans(x, sample_rate, exclude, unit_rms=False)
    out = flatten_envelope(x, sample_rate)
    out.setflags(write=False)
    return out


ENVELOPE_BAND_HZ = (300.0, 4000.0)
ENVELOPE_SMOOTH_S = 1.0
SILENCE_SMOOTH_S = 0.1
SILENCE_DB = -25.0
MAX_GAIN_DB = 20.0


def flatten_envelope(
    x: np.ndarray,
    sample_rate: int,
    *,
    smooth_s: float = ENVELOPE_SMOOTH_S,
    silence_db: float = SILENCE_DB,
    max_gain_db: float = MAX_GAIN_DB,
) -> np.ndarray:
    """A real siren recording with its slow level changes undone: unit RMS, float32.

    A recorded pass-by already carries the level changes of its own distance (``jap_amb``: half its
    0.5 s windows lie 12 dB or more below its RMS), and some clips fall silent for a while. Used as
    the emitted signal of a simulated siren, both would make the label ("a 110–120 dB siren at this
    distance") disagree with the audio: the simulator applies distance itself. So the in-band
    (:data:`ENVELOPE_BAND_HZ`) power is smoothed over ``smooth_s``; the signal is brought to that
    level's median with a gain of at most ``max_gain_db``, and stretches whose level over
    :data:`SILENCE_SMOOTH_S` lies more than ``-silence_db`` dB below the median are cut out
    (:func:`cut_spans`). Clean siren-unit loops pass nearly unchanged.
    """
    from scipy.ndimage import uniform_filter1d
    from scipy.signal import butter, sosfiltfilt

    x = np.asarray(x, dtype=np.float64)
    win = max(1, round(smooth_s * sample_rate))
    if len(x) < 2 * win:
        return _unit_rms(x.astype(np.float32))
    hi = min(ENVELOPE_BAND_HZ[1], 0.45 * sample_rate)
    sos = butter(4, [ENVELOPE_BAND_HZ[0], hi], btype="bandpass", fs=sample_rate, output="sos")
    band = sosfiltfilt(sos, x) ** 2
    level = 10.0 * np.log10(uniform_filter1d(band, win, mode="nearest") + 1e-20)
    ref = float(np.median(level))
    gain = 10.0 ** (np.clip(ref - level, -max_gain_db, max_gain_db) / 20.0)
    y = (x * gain).astype(np.float32)
    short = uniform_filter1d(band, max(1, round(SILENCE_SMOOTH_S * sample_rate)), mode="nearest")
    quiet = 10.0 * np.log10(short + 1e-20) < ref + silence_db
    if quiet.any() and not quiet.all():
        edges = np.flatnonzero(np.diff(np.concatenate([[0], quiet.astype(np.int8), [0]])))
        spans = [(a / sample_rate, b / sample_rate) for a, b in zip(edges[::2], edges[1::2], strict=True)]
        return np.array(cut_spans(y, sample_rate, spans), dtype=np.float32)
    return _unit_rms(y)


SirenSource = AudioSource


def _tone_mode(tone: str) -> str:
    low = tone.lower()
    for key, mode in _TONE_MODES:
        if key in low:
            return mode
    return "unknown"


def load_siren_sources(
    data_root: str | Path,
    *,
    kinds: tuple[str, ...] = ("clip", "tone", "recording"),
    include_horns: bool = False,
    clip_block: int = 10,
) -> list[AudioSource]:
    """The real siren ingredients under ``<data_root>/audio`` (empty list where a folder is absent).

    Audio is loaded lazily by :meth:`AudioSource.load` (48 kHz mono, unit RMS). Clips are grouped in
    blocks of ``clip_block`` consecutive numbers, tone loops by siren model, recordings singly. Air
    horns and jingles among the tone loops are left out unless ``include_horns``.
    """
    audio = Path(data_root) / "audio"
    out: list[AudioSource] = []
    if "clip" in kinds:
        for p in sorted((audio / "siren_clips").glob("*.flac")):
            m = re.search(r"(\d+)$", p.stem)
            num = int(m.group(1)) if m else 0
            out.append(AudioSource(p.stem, f"clips_{(num - 1) // clip_block:02d}", "clip", "unknown", p))
    if "tone" in kinds:
        for p in sorted((audio / "siren_tones").glob("*.flac")):
            parts = p.stem.split("__")
            tone = parts[-1]
            model = "__".join(parts[1:-1]) if len(parts) > 2 else parts[0]
            if not include_horns and any(tone.lower().endswith(h) for h in HORN_TONES):
                continue
            out.append(AudioSource(p.stem, f"tone:{model}", "tone", _tone_mode(tone), p))
    if "recording" in kinds:
        for p in sorted((audio / "siren_recordings").glob("*.flac")):
            out.append(AudioSource(p.stem, f"recording:{p.stem}", "recording", "unknown", p))
    return out


def fit_length(
    x: np.ndarray,
    n: int,
    rng: np.random.Generator | None = None,
    *,
    crossfade: int = 2400,
    random_start: bool = True,
) -> np.ndarray:
    """Loop ``x`` to exactly ``n`` samples from a random start, joining copies with a linear crossfade.

    Tone loops repeat seamlessly anyway; for clips the crossfade (50 ms at 48 kHz) hides the seam.
    """
    rng = np.random.default_rng() if rng is None else rng
    x = np.asarray(x, dtype=np.float32)
    if len(x) == 0:
        return np.zeros(n, dtype=np.float32)
    start = int(rng.integers(0, len(x))) if random_start else 0
    x = np.roll(x, -start)
    if len(x) >= n:
        return x[:n].copy()
    cf = min(crossfade, len(x) // 4)
    out = np.zeros(n + len(x), dtype=np.float32)
    pos = 0
    fade_in = np.linspace(0.0, 1.0, cf, dtype=np.float32) if cf else np.zeros(0, dtype=np.float32)
    while pos < n:
        seg = x.copy()
        if pos > 0 and cf:
            seg[:cf] *= fade_in
            out[pos : pos + cf] *= 1.0 - fade_in
        out[pos : pos + len(seg)] += seg
        pos += len(seg) - cf
    return out[:n]


SPLITS = ("all", "train", "test")
TEST_GROUP_FRACTION = 0.2
"""Share of the source groups (siren models, clip blocks, street recordings) held out for testing."""


def group_split(group: str, test_fraction: float = TEST_GROUP_FRACTION) -> str:
    """``"test"`` or ``"train"`` for a source group, fixed by a hash of its name.

    A group's side never depends on which other groups exist, so adding data never moves a test
    group into training. Every source of a group lands on one side (issue 4: held-out sirens and
    noise recordings).
    """
    digest = hashlib.sha256(f"makeway-audio-split:{group}".encode()).digest()
    return "test" if int.from_bytes(digest[:4], "big") / 2**32 < test_fraction else "train"


def split_sources(
    sources: Sequence[AudioSource], split: str, test_fraction: float = TEST_GROUP_FRACTION
) -> list[AudioSource]:
    """The sources of ``split`` (``"all"``, ``"train"`` or ``"test"``; see :func:`group_split`)."""
    if split not in SPLITS:
        raise ValueError(f"split must be one of {', '.join(SPLITS)}, not {split!r}")
    if split == "all":
        return list(sources)
    return [s for s in sources if group_split(s.group, test_fraction) == split]
