"""Read the sound track of a video file as one mono signal (PyAV / FFmpeg).

A road clip recorded by a dash or hand-held camera carries at most a mono or stereo track from one
microphone: enough to hear *whether* a siren sounds, never *where* (no array, no bearing). This
reader gives that track to the siren stack:

* :func:`has_audio` — does the file hold an audio stream at all (a clip without one keeps working
  with the sound off);
* :func:`read_clip_audio` — decode the first audio stream completely, convert every frame to 32-bit
  float (FFmpeg's resampler, format only), **downmix** to mono by averaging the channels, remove the
  mean, and **resample** to the rate asked for by polyphase filtering
  (:func:`scipy.signal.resample_poly` with the exact ratio of the two rates, e.g. 44.1 → 48 kHz is
  ×160/147) — the same downmix and resampling the real mono audio of the shared data gets.

Problems are :class:`~makeway.errors.InputError` naming the file: no such file, a file FFmpeg
cannot open, no audio stream (when one is required), or a stream that fails to decode or holds no
samples. The whole track is checked here, before any long work starts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from makeway.errors import InputError

__all__ = ["ClipAudio", "has_audio", "read_clip_audio"]

#: Decoded tracks shorter than this are refused (less than one analysis window of the siren stack).
MIN_SECONDS = 0.05


@dataclass(frozen=True)
class ClipAudio:
    """A clip's sound track as one mono signal.

    ``samples`` is float32 in the file's digital full scale (±1), mean removed, at ``sample_rate``
    Hz; ``source_rate`` and ``channels`` describe the stream as stored, ``codec`` its codec name.
    Time 0 is the first decoded sample (taken to be the first video frame's time).
    """

    path: Path
    samples: np.ndarray
    sample_rate: int
    source_rate: int
    channels: int
    codec: str

    @property
    def duration_s(self) -> float:
        """Length of the decoded track, s."""
        return len(self.samples) / self.sample_rate if self.sample_rate > 0 else 0.0

    def level_dbfs(self) -> float:
        """RMS level relative to digital full scale, dB (``-inf`` when silent)."""
        rms = float(np.sqrt(np.mean(np.square(self.samples, dtype=np.float64)))) if len(self.samples) else 0.0
        return 20.0 * math.log10(rms) if rms > 0 else -math.inf

    def to_dict(self) -> dict[str, object]:
        """The track's description for a run summary (no samples)."""
        level = self.level_dbfs()
        return {
            "codec": self.codec,
            "channels": self.channels,
            "source_rate_hz": self.source_rate,
            "sample_rate_hz": self.sample_rate,
            "duration_s": round(self.duration_s, 3),
            "level_dbfs": round(level, 1) if math.isfinite(level) else None,
        }


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _open(path: Path):  # type: ignore[no-untyped-def]
    import av

    if not path.exists():
        raise InputError(path, "no such file")
    if path.is_dir():
        raise InputError(path, "is a folder, not a video file")
    try:
        return av.open(str(path))
    except Exception as exc:  # FFmpeg's errors come as several classes
        raise InputError(path, f"cannot be opened as a media file ({_first_line(exc)})") from None


def has_audio(path: str | Path) -> bool:
    """Whether the file holds an audio stream (one that decodes or not).

    Raises:
        InputError: no such file, a folder, or a file FFmpeg cannot open.
    """
    p = Path(path)
    with _open(p) as container:
        return len(container.streams.audio) > 0


def read_clip_audio(path: str | Path, sample_rate: int) -> ClipAudio:
    """Decode the first audio stream of ``path``, downmix it to mono and resample it to
    ``sample_rate`` Hz (module docstring).

    Raises:
        InputError: no such file, not a media file, no audio stream, a stream that fails to decode
            (damaged packets, an unknown codec) or one that holds less than :data:`MIN_SECONDS`.
        ValueError: ``sample_rate`` is not positive.
    """
    import av
    from scipy.signal import resample_poly

    if sample_rate <= 0:
        raise ValueError(f"sample_rate must be positive, got {sample_rate}")
    p = Path(path)
    with _open(p) as container:
        if not container.streams.audio:
            raise InputError(p, "has no audio stream")
        stream = container.streams.audio[0]
        codec = stream.codec_context.name if stream.codec_context is not None else "unknown"
        # report damaged packets as errors instead of skipping them silently
        stream.codec_context.options = {"err_detect": "explode"}
        to_float = av.AudioResampler(format="fltp")  # sample format only: layout and rate kept
        pieces: list[np.ndarray] = []
        rate = 0
        channels = 0
        try:
            for frame in container.decode(stream):
                for f in to_float.resample(frame):
                    arr = f.to_ndarray()  # (channels, samples), float32 planar
                    rate = rate or int(f.sample_rate)
                    channels = channels or int(arr.shape[0])
                    pieces.append(arr.astype(np.float64).mean(axis=0))
            for f in to_float.resample(None):
                pieces.append(f.to_ndarray().astype(np.float64).mean(axis=0))
        except av.error.FFmpegError as exc:
            raise InputError(p, f"the audio stream cannot be decoded ({_first_line(exc)})") from None
    x = np.concatenate(pieces) if pieces else np.zeros(0)
    if rate <= 0 or len(x) < MIN_SECONDS * rate:
        raise InputError(p, "the audio stream holds no sound (no samples decode)")
    if not np.all(np.isfinite(x)):
        raise InputError(p, "the audio stream decodes to non-finite samples")
    if rate != sample_rate:
        g = math.gcd(rate, int(sample_rate))
        x = resample_poly(x, int(sample_rate) // g, rate // g)
    x = x - x.mean()
    return ClipAudio(p, x.astype(np.float32), int(sample_rate), rate, channels, codec)
