"""Measure a microphone array's calibration from a recorded calibrator tone (issue 4; recording
format, ``full_scale_db_spl``).

An acoustic calibrator clamped over a capsule plays a known tone — 94 dB SPL at 1 kHz for most
class-1 calibrators (IEC 60942), some 114 dB SPL or 250 Hz. Record it through the array's own
recorder, gains as they will be in use, and :func:`measure_full_scale` gives the value for
``array.yaml``: a tone at ``L`` dB SPL that reads as digital RMS ``r`` means full scale stands for
``full_scale_db_spl = L − 20·log10(r)`` (:mod:`makeway.sense.recording`, **Calibration**).

The tone's RMS is read from the spectrum, in ``±tolerance`` around the nominal frequency, so hum
and room noise do not count; the rest of the channel's power gives the tone-to-noise ratio, which
must reach :data:`MIN_TONE_SNR_DB` for the figure to be trusted. Capsules are calibrated one at a
time: the measured channel is ``channel``, or the loudest one (the calibrator's).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from makeway.errors import InputError
from makeway.sense.recording import (
    ARRAY_FILE,
    FULL_SCALE_KEY,
    FULL_SCALE_RANGE_DB,
    check_audio,
    read_audio,
)

CALIBRATOR_DB_SPL = 94.0
CALIBRATOR_HZ = 1000.0
MIN_TONE_SNR_DB = 20.0
"""The tone must stand this far above everything else in its channel."""
MIN_TONE_S = 0.5


@dataclass(frozen=True)
class ToneCalibration:
    """What :func:`measure_full_scale` found (JSON-ready via :meth:`to_dict`)."""

    full_scale_db_spl: float
    channel: int
    tone_dbfs: float
    """The tone's digital RMS, dB re 1.0 (so ``full_scale_db_spl = level − tone_dbfs``)."""
    frequency_hz: float
    """Where the tone's spectral peak is."""
    snr_db: float
    level_db_spl: float
    channel_tone_dbfs: list[float]
    """The tone's level in every channel (the calibrated capsule stands out)."""

    def to_dict(self) -> dict[str, Any]:
        return {k: (round(v, 3) if isinstance(v, float) else v) for k, v in asdict(self).items()} | {
            "channel_tone_dbfs": [round(v, 2) for v in self.channel_tone_dbfs]
        }


def measure_full_scale(
    audio: np.ndarray,
    sample_rate: int,
    *,
    level_db_spl: float = CALIBRATOR_DB_SPL,
    frequency_hz: float = CALIBRATOR_HZ,
    channel: int | None = None,
    tolerance: float = 0.05,
    source: str | Path = "calibration recording",
) -> ToneCalibration:
    """The array's ``full_scale_db_spl`` from ``audio (n, channels)`` holding a calibrator tone of
    ``level_db_spl`` at ``frequency_hz`` (module docstring). Raises :class:`InputError` naming
    ``source`` when the recording is too short, clipped or non-finite, when ``channel`` does not
    exist, when the strongest component of the channel is not the tone (off by more than
    ``tolerance``), or when the tone does not stand :data:`MIN_TONE_SNR_DB` above the rest."""
    x = np.asarray(audio, dtype=np.float64)
    if x.ndim == 1:
        x = x[:, None]
    if x.ndim != 2:
        raise InputError(source, f"expected (samples, channels) audio, got shape {x.shape}")
    if x.shape[0] < MIN_TONE_S * sample_rate:
        raise InputError(
            source,
            f"is {x.shape[0] / sample_rate:.2f} s long; record the calibrator for at least {MIN_TONE_S:g} s",
        )
    check_audio(x, source)
    if not 0 < frequency_hz < sample_rate / 2:
        raise ValueError(f"frequency_hz must lie between 0 and {sample_rate / 2:g} Hz")
    n = x.shape[0]
    win = np.hanning(n)
    spec = np.fft.rfft((x - x.mean(axis=0)) * win[:, None], axis=0)
    # one-sided power per bin, scaled so that the bins of a sine add up to its mean square
    power = np.abs(spec) ** 2 * (2.0 / (n * float(np.sum(win**2))))
    freqs = np.fft.rfftfreq(n, 1.0 / sample_rate)
    near = np.abs(freqs - frequency_hz) <= tolerance * frequency_hz
    if not near.any():
        raise ValueError("the tolerance band holds no frequency bin; record longer or widen it")
    tone_power = power[near].sum(axis=0)
    if channel is None:  # the calibrator, clamped on its capsule, is by far the loudest sound there
        channel = int(np.argmax(power.sum(axis=0)))
    elif not 0 <= channel < x.shape[1]:
        raise InputError(source, f"has {x.shape[1]} channel(s); there is no channel {channel}")
    p = power[:, channel]
    peak_hz = float(freqs[1:][np.argmax(p[1:])])  # skip DC
    if abs(peak_hz - frequency_hz) > tolerance * frequency_hz:
        raise InputError(
            source,
            f"channel {channel}: the strongest component is at {peak_hz:.0f} Hz, not the calibrator's "
            f"{frequency_hz:g} Hz (give --frequency for a 250 Hz calibrator, --channel for the "
            "capsule it sat on)",
        )
    rest = max(float(p.sum() - tone_power[channel]), 1e-30)
    snr = 10.0 * math.log10(max(float(tone_power[channel]), 1e-30) / rest)
    if snr < MIN_TONE_SNR_DB:
        raise InputError(
            source,
            f"channel {channel}: the {frequency_hz:g} Hz tone stands only {snr:.1f} dB above the rest "
            f"(need {MIN_TONE_SNR_DB:g} dB): seat the calibrator on the capsule, away from noise",
        )
    tone_dbfs = [10.0 * math.log10(max(float(v), 1e-30)) for v in tone_power]
    full_scale = level_db_spl - tone_dbfs[channel]
    lo, hi = FULL_SCALE_RANGE_DB
    if not lo <= full_scale <= hi:
        raise InputError(
            source,
            f"gives full_scale_db_spl {full_scale:.1f}, outside {lo:g}–{hi:g}: is the tone level "
            f"({level_db_spl:g} dB SPL) right?",
        )
    return ToneCalibration(
        full_scale_db_spl=full_scale,
        channel=channel,
        tone_dbfs=tone_dbfs[channel],
        frequency_hz=peak_hz,
        snr_db=snr,
        level_db_spl=level_db_spl,
        channel_tone_dbfs=tone_dbfs,
    )


def measure_file(path: str | Path, **kwargs: Any) -> ToneCalibration:
    """:func:`measure_full_scale` on an audio file (any format soundfile reads)."""
    audio, rate = read_audio(Path(path))
    return measure_full_scale(audio, rate, source=path, **kwargs)


def write_full_scale(targets: Sequence[str | Path], full_scale_db_spl: float) -> list[Path]:
    """Set ``full_scale_db_spl`` in every target (an ``array.yaml``, or a recording folder holding
    one), keeping their other keys. Every target is read and checked before any is written, and
    each is written atomically: a bad target leaves all of them as they were. Returns the files."""
    from makeway.atomic import write_text_atomic

    docs: list[tuple[Path, dict[str, Any]]] = []
    for target in targets:
        path = Path(target)
        if path.is_dir():
            path = path / ARRAY_FILE
        if not path.is_file():
            raise InputError(path, f"no such file (give an {ARRAY_FILE} or a recording folder)")
        try:
            doc = yaml.safe_load(path.read_text(encoding="utf-8"))
        except (yaml.YAMLError, UnicodeDecodeError) as exc:
            raise InputError(path, f"is not valid YAML ({str(exc).splitlines()[0]})") from None
        if not isinstance(doc, dict) or "mics" not in doc or "sample_rate" not in doc:
            raise InputError(path, "is not an array description (needs sample_rate and mics)")
        docs.append((path, doc))
    for path, doc in docs:
        doc[FULL_SCALE_KEY] = round(float(full_scale_db_spl), 3)
        write_text_atomic(path, yaml.safe_dump(doc, sort_keys=False))
    return [path for path, _ in docs]
