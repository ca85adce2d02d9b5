"""Multichannel siren recordings on disk: one folder per recording (issue 4, "recording format").

A recording folder holds

* ``audio.flac`` — ``N`` channels, one per microphone capsule, in the order of ``array.yaml``;
* ``array.yaml`` — ``sample_rate`` (Hz) and ``mics:`` (one ``[x, y, z]`` per channel, metres, in the
  vehicle frame: x forward, y left, z up, origin on the ground under the centre of the rear axle);
* ``ego.csv`` — columns ``t,x,y,yaw``: the vehicle-frame origin in the world frame (metres, radians),
  ≥ 10 Hz, ``t = 0`` at the first audio sample;
* ``source_<k>.csv`` — columns ``t,x,y`` for each siren source ``k = 0, 1, …`` (none: no siren);
  ``array.yaml`` may also state ``full_scale_db_spl``: the sound pressure level (dB re 20 µPa, RMS)
  that a digital RMS of 1.0 stands for, i.e. the array's calibration (see **Calibration** below);
* optionally ``meta.yaml`` — free-form facts about how the recording was made (the simulator writes
  the scenario, seed, siren and noise ingredients and levels there); readers may ignore it.

:func:`read_recording` checks everything and raises one :class:`~makeway.errors.InputError` per
problem, naming the file. :func:`write_recording` writes all-or-nothing.

**Clipping.** A recording counts as clipped when, in any channel, more than
:data:`CLIP_FRACTION` (0.1 %) of the samples sit at full scale (``|x| >= CLIP_LEVEL`` = 0.999). FLAC
stores integers, so a recorder that overloads leaves runs of samples pinned at ±full scale; a clean
signal that merely touches full scale now and then stays far below 0.1 %.

**Calibration.** The trained siren networks read absolute levels (the level stream, and the
distance they give leans on it), so they must know what pressure a sample value stands for.
``full_scale_db_spl`` in ``array.yaml`` says it: a 94 dB SPL tone reads as a digital RMS of
``10^((94 − full_scale_db_spl) / 20)``. A capsule whose datasheet sensitivity is ``S`` dBFS at 94 dB
SPL (AES17: a full-scale sine is 0 dBFS) has ``full_scale_db_spl = 97 − S``. The simulator writes
:data:`REFERENCE_FULL_SCALE_DB_SPL` (135 dB SPL), the scale every shipped network was trained at;
:func:`calibration_gain` is the factor that brings a recording's samples to a model's scale. A
recording without the key has ``full_scale_db_spl = None`` and is taken to be at the model's
scale (the tools say so). A wrong calibration costs: a level off by a few dB moves the given
distances and raises the distance error, and an array much quieter than stated loses recall (see
docs/results.md, section "Array calibration").

**Coverage.** Every trajectory must span the audio: first timestamp ≤ ``COVER_TOLERANCE_S`` (50 ms)
after 0 and last timestamp ≥ duration − 50 ms (a 10 Hz log may stop just short of the last sample;
positions in that gap are held at the end value).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from makeway.atomic import atomic_dir
from makeway.errors import InputError

AUDIO_FILE = "audio.flac"
ARRAY_FILE = "array.yaml"
EGO_FILE = "ego.csv"
META_FILE = "meta.yaml"
SOURCE_PATTERN = re.compile(r"^source_(\d+)\.csv$")

CLIP_LEVEL = 0.999
"""A sample with ``|x| >= CLIP_LEVEL`` (full scale = 1) is at full scale."""
CLIP_FRACTION = 1e-3
"""A channel with more than this share of its samples at full scale is clipped."""
COVER_TOLERANCE_S = 0.05
"""How far a trajectory may stop short of either end of the audio."""
MIN_TRAJECTORY_RATE_HZ = 10.0
"""The format asks for trajectories logged at ≥ 10 Hz (checked on the median step)."""

EGO_COLUMNS = ("t", "x", "y", "yaw")
SOURCE_COLUMNS = ("t", "x", "y")

REFERENCE_SAMPLE_RATE = 48_000
REFERENCE_FULL_SCALE_DB_SPL = 135.0
"""The calibration of the simulator's recordings and of every shipped siren network: a digital RMS of
1.0 stands for 135 dB SPL (module docstring, **Calibration**)."""
FULL_SCALE_KEY = "full_scale_db_spl"
FULL_SCALE_RANGE_DB = (60.0, 200.0)
"""Accepted ``full_scale_db_spl`` values: from a very sensitive capsule (1.0 = 60 dB SPL) to a
blast gauge; anything outside is taken for a mistake (a sensitivity in dBFS or mV/Pa, say)."""
REFERENCE_CHANNELS = ("L-front", "L-left", "L-back", "L-right", "R-front", "R-left", "R-back", "R-right")


def reference_mics() -> np.ndarray:
    """The issue's reference array, ``(8, 3)`` metres in the vehicle frame, in channel order.

    Two 4-capsule units on the rear roof, centred at (−0.9, ±0.45, 1.55) m (L at +y, R at −y); each
    unit's capsules at centre + (+0.03, 0, 0), (0, +0.03, 0), (−0.03, 0, 0), (0, −0.03, 0)
    (front, left, back, right). Channels: see :data:`REFERENCE_CHANNELS`.
    """
    offsets = np.array([[0.03, 0.0, 0.0], [0.0, 0.03, 0.0], [-0.03, 0.0, 0.0], [0.0, -0.03, 0.0]])
    centres = np.array([[-0.9, 0.45, 1.55], [-0.9, -0.45, 1.55]])
    return np.concatenate([c + offsets for c in centres], axis=0)


@dataclass
class Trajectory:
    """A planar trajectory in the world frame: times ``t`` (s, strictly increasing), ``x``, ``y`` (m).

    ``yaw`` (rad, counter-clockwise from the world x axis) is given for the ego vehicle and ``None``
    for siren sources. :meth:`at` interpolates linearly and holds the end values outside the span.
    """

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=np.float64).reshape(-1)
        self.x = np.asarray(self.x, dtype=np.float64).reshape(-1)
        self.y = np.asarray(self.y, dtype=np.float64).reshape(-1)
        if self.yaw is not None:
            self.yaw = np.asarray(self.yaw, dtype=np.float64).reshape(-1)
        n = len(self.t)
        if len(self.x) != n or len(self.y) != n or (self.yaw is not None and len(self.yaw) != n):
            raise ValueError("trajectory arrays t, x, y (and yaw) must have the same length")

    def __len__(self) -> int:
        return len(self.t)

    @property
    def span(self) -> tuple[float, float]:
        """``(first, last)`` timestamp."""
        return float(self.t[0]), float(self.t[-1])

    def position(self, times: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """World ``(x, y)`` at ``times`` (linear interpolation between timestamps)."""
        tt = np.asarray(times, dtype=np.float64)
        return np.interp(tt, self.t, self.x), np.interp(tt, self.t, self.y)

    def heading(self, times: np.ndarray | float) -> np.ndarray:
        """Yaw at ``times``; interpolated on the unwrapped angle. Needs ``yaw``."""
        if self.yaw is None:
            raise ValueError("this trajectory has no yaw")
        return np.interp(np.asarray(times, dtype=np.float64), self.t, np.unwrap(self.yaw))

    def velocity(self, times: np.ndarray | float, dt: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
        """World velocity ``(vx, vy)`` at ``times`` by central differences over ``±dt/2``."""
        tt = np.asarray(times, dtype=np.float64)
        x1, y1 = self.position(tt + 0.5 * dt)
        x0, y0 = self.position(tt - 0.5 * dt)
        return (x1 - x0) / dt, (y1 - y0) / dt


@dataclass
class Recording:
    """One recording (see the module docstring for the folder format).

    ``audio (n, channels)`` float32 in full-scale units, ``sample_rate`` Hz, ``mics (channels, 3)``
    vehicle-frame capsule positions, ``ego`` with yaw, ``sources`` one trajectory per siren (empty:
    no siren), ``path`` the folder it was read from or written to, ``meta`` the optional
    ``meta.yaml`` content, ``full_scale_db_spl`` the array's calibration from ``array.yaml``
    (``None``: not stated; module docstring, **Calibration**).
    """

    audio: np.ndarray
    sample_rate: int
    mics: np.ndarray
    ego: Trajectory
    sources: list[Trajectory] = field(default_factory=list)
    path: Path | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    full_scale_db_spl: float | None = None

    @property
    def n_samples(self) -> int:
        return int(self.audio.shape[0])

    @property
    def n_channels(self) -> int:
        return int(self.audio.shape[1])

    @property
    def duration_s(self) -> float:
        return self.n_samples / float(self.sample_rate)

    @property
    def has_siren(self) -> bool:
        return len(self.sources) > 0


# ------------------------------------------------------------------------------------------- reading


def recording_folders(folder: str | Path) -> list[Path]:
    """``folder`` itself when it is a recording, else its sub-folders that are recordings (holding
    ``array.yaml``), sorted.

    Raises:
        InputError: the folder does not exist, is a file, or holds no recording.
    """
    root = Path(folder)
    if not root.exists():
        raise InputError(root, "no such folder")
    if not root.is_dir():
        raise InputError(root, "is a file; expected a recording folder or a folder of recording folders")
    if (root / AUDIO_FILE).exists() or (root / ARRAY_FILE).exists():
        return [root]
    subs = sorted(p for p in root.iterdir() if p.is_dir() and (p / ARRAY_FILE).exists())
    if not subs:
        raise InputError(root, f"holds no recording (a folder with {AUDIO_FILE}, {ARRAY_FILE}, {EGO_FILE})")
    return subs


def read_recording(folder: str | Path) -> Recording:
    """Read and check a recording folder; every problem is one :class:`InputError` naming the file."""
    root = Path(folder)
    if not root.exists():
        raise InputError(root, "no such recording folder")
    if not root.is_dir():
        raise InputError(root, "is a file; a recording is a folder with audio.flac, array.yaml and ego.csv")
    for name in (AUDIO_FILE, ARRAY_FILE, EGO_FILE):
        if not (root / name).is_file():
            raise InputError(
                root / name, f"missing: a recording folder needs {AUDIO_FILE}, {ARRAY_FILE}, {EGO_FILE}"
            )

    sample_rate, mics, full_scale = _read_array_yaml(root / ARRAY_FILE)
    audio, audio_rate = read_audio(root / AUDIO_FILE)
    if audio.shape[1] != len(mics):
        raise InputError(
            root / AUDIO_FILE,
            f"has {audio.shape[1]} channel(s) but {ARRAY_FILE} lists {len(mics)} microphone(s)",
        )
    if audio_rate != sample_rate:
        raise InputError(
            root / AUDIO_FILE,
            f"sample rate is {audio_rate} Hz but {ARRAY_FILE} says sample_rate: {sample_rate}",
        )
    check_audio(audio, root / AUDIO_FILE)
    duration = audio.shape[0] / float(sample_rate)

    ego = _read_trajectory_csv(root / EGO_FILE, EGO_COLUMNS)
    _check_coverage(ego, duration, root / EGO_FILE)
    sources: list[Trajectory] = []
    for k, path in _source_files(root):
        src = _read_trajectory_csv(path, SOURCE_COLUMNS)
        _check_coverage(src, duration, path)
        if k != len(sources):
            raise InputError(
                path,
                f"source files must be numbered source_0.csv, source_1.csv, … "
                f"(missing source_{len(sources)}.csv)",
            )
        sources.append(src)

    meta: dict[str, Any] = {}
    if (root / META_FILE).is_file():
        try:
            loaded = yaml.safe_load((root / META_FILE).read_text(encoding="utf-8"))
        except (yaml.YAMLError, UnicodeDecodeError) as exc:
            raise InputError(root / META_FILE, f"is not valid YAML ({_first_line(exc)})") from None
        if isinstance(loaded, dict):
            meta = loaded
    return Recording(audio, sample_rate, mics, ego, sources, root, meta, full_scale)


def assume_calibration(rec: Recording, full_scale_db_spl: float | None) -> Recording:
    """``rec`` with ``full_scale_db_spl`` as its calibration when its ``array.yaml`` states none
    (a copy; ``rec`` itself when it states one or ``full_scale_db_spl`` is ``None``)."""
    if rec.full_scale_db_spl is not None or full_scale_db_spl is None:
        return rec
    return replace(rec, full_scale_db_spl=float(full_scale_db_spl))


def calibration_gain(
    full_scale_db_spl: float | None, reference_db_spl: float = REFERENCE_FULL_SCALE_DB_SPL
) -> float:
    """The factor that takes samples of an array whose full scale stands for ``full_scale_db_spl``
    to the scale ``reference_db_spl`` (a model's; module docstring, **Calibration**): a sound at
    ``L`` dB SPL sits at ``L − full_scale_db_spl`` dBFS in the recording and at
    ``L − reference_db_spl`` dBFS after the gain. ``None`` (not stated) gives 1.0."""
    if full_scale_db_spl is None:
        return 1.0
    return float(10.0 ** ((float(full_scale_db_spl) - float(reference_db_spl)) / 20.0))


def check_audio(audio: np.ndarray, path: str | Path) -> None:
    """Raise :class:`InputError` for NaN/inf samples or clipping (see the module docstring)."""
    finite = np.isfinite(audio)
    if not finite.all():
        bad = np.argwhere(~finite)[0]
        n_bad = int((~finite).sum())
        raise InputError(
            path,
            f"contains {n_bad} NaN/inf sample(s) (first at sample {int(bad[0])}, channel {int(bad[1])})",
        )
    if audio.size == 0:
        raise InputError(path, "has no samples")
    share = (np.abs(audio) >= CLIP_LEVEL).mean(axis=0)
    worst = int(np.argmax(share))
    if share[worst] > CLIP_FRACTION:
        raise InputError(
            path,
            f"is clipped: {100 * share[worst]:.2f}% of the samples of channel {worst} are at full scale "
            f"(limit {100 * CLIP_FRACTION:.1f}%); record with less gain",
        )


def _first_line(exc: BaseException) -> str:
    return str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__


def read_audio(path: Path) -> tuple[np.ndarray, int]:
    """``(samples (n, channels) float32 in full-scale units, sample rate)`` of an audio file, or
    one :class:`InputError` naming it."""
    import soundfile as sf

    try:
        data, rate = sf.read(str(path), dtype="float32", always_2d=True)
    except Exception as exc:  # soundfile raises LibsndfileError / RuntimeError / TypeError
        raise InputError(path, f"cannot be read as audio ({_first_line(exc)})") from None
    return np.ascontiguousarray(data, dtype=np.float32), int(rate)


def _read_array_yaml(path: Path) -> tuple[int, np.ndarray, float | None]:
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise InputError(path, f"is not valid YAML ({_first_line(exc)})") from None
    if not isinstance(doc, dict):
        raise InputError(path, "must be a YAML mapping with keys sample_rate and mics")
    missing = [k for k in ("sample_rate", "mics") if k not in doc]
    if missing:
        raise InputError(
            path, f"missing key(s) {', '.join(missing)} (found: {', '.join(map(str, doc)) or 'none'})"
        )
    rate = doc["sample_rate"]
    if isinstance(rate, bool) or not isinstance(rate, int | float) or rate <= 0 or float(rate) != int(rate):
        raise InputError(path, f"sample_rate must be a positive whole number of Hz, got {rate!r}")
    mics = doc["mics"]
    if not isinstance(mics, list) or not mics:
        raise InputError(path, "mics must be a non-empty list of [x, y, z] positions (one per channel)")
    rows: list[list[float]] = []
    for i, m in enumerate(mics):
        if (
            not isinstance(m, list | tuple)
            or len(m) != 3
            or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in m)
            or not all(math.isfinite(float(v)) for v in m)
        ):
            raise InputError(path, f"mics[{i}] must be [x, y, z] in metres, got {m!r}")
        rows.append([float(v) for v in m])
    full_scale = doc.get(FULL_SCALE_KEY)
    if full_scale is not None:
        lo, hi = FULL_SCALE_RANGE_DB
        if (
            isinstance(full_scale, bool)
            or not isinstance(full_scale, int | float)
            or not lo <= float(full_scale) <= hi
        ):
            raise InputError(
                path,
                f"{FULL_SCALE_KEY} must be the dB SPL that a digital RMS of 1.0 stands for, a number "
                f"from {lo:g} to {hi:g} (97 minus the capsules' sensitivity in dBFS at 94 dB SPL), "
                f"got {full_scale!r}",
            )
        full_scale = float(full_scale)
    return int(rate), np.asarray(rows, dtype=np.float64), full_scale


def _read_trajectory_csv(path: Path, columns: tuple[str, ...]) -> Trajectory:
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputError(path, "is not a text file (could not decode it as UTF-8)") from None
    except OSError as exc:
        raise InputError(path, f"cannot be read ({exc.strerror})") from None
    lines = text.splitlines()
    header_no = next((i for i, ln in enumerate(lines) if ln.strip()), None)
    if header_no is None:
        raise InputError(path, f"is empty; expected a header line {','.join(columns)} and rows")
    header = [h.strip() for h in lines[header_no].split(",")]
    missing = [c for c in columns if c not in header]
    if missing:
        raise InputError(
            path,
            f"missing column(s) {', '.join(missing)}; found {', '.join(h or '(blank)' for h in header)} "
            f"(needed: {','.join(columns)})",
        )
    idx = [header.index(c) for c in columns]
    rows: list[list[float]] = []
    for lineno in range(header_no + 1, len(lines)):
        line = lines[lineno]
        if not line.strip():
            continue
        cells = [c.strip() for c in line.split(",")]
        if len(cells) < len(header):
            raise InputError(
                path, f"line {lineno + 1}: {len(cells)} value(s), the header has {len(header)} columns"
            )
        row: list[float] = []
        for c, j in zip(columns, idx, strict=True):
            try:
                v = float(cells[j])
            except ValueError:
                raise InputError(
                    path, f"line {lineno + 1}: column {c} value {cells[j]!r} is not a number"
                ) from None
            if not math.isfinite(v):
                raise InputError(path, f"line {lineno + 1}: column {c} value {cells[j]!r} is not finite")
            row.append(v)
        rows.append(row)
    if len(rows) < 2:
        raise InputError(path, f"needs at least 2 rows, found {len(rows)}")
    arr = np.asarray(rows, dtype=np.float64)
    dt = np.diff(arr[:, 0])
    if (dt <= 0).any():
        k = int(np.argmax(dt <= 0))
        raise InputError(
            path, f"timestamps must increase strictly (t = {arr[k + 1, 0]:g} after {arr[k, 0]:g})"
        )
    med = float(np.median(dt))
    if med > 1.0 / MIN_TRAJECTORY_RATE_HZ * 1.05:
        raise InputError(
            path, f"logged at {1.0 / med:.1f} Hz; the format needs ≥ {MIN_TRAJECTORY_RATE_HZ:g} Hz"
        )
    yaw = arr[:, 3] if len(columns) > 3 else None
    return Trajectory(arr[:, 0], arr[:, 1], arr[:, 2], yaw)


def _check_coverage(traj: Trajectory, duration_s: float, path: Path) -> None:
    t0, t1 = traj.span
    if t0 > COVER_TOLERANCE_S or t1 < duration_s - COVER_TOLERANCE_S:
        raise InputError(
            path,
            f"trajectory covers {t0:.2f}–{t1:.2f} s but the audio needs 0.00–{duration_s:.2f} s",
        )


def _source_files(root: Path) -> list[tuple[int, Path]]:
    found: list[tuple[int, Path]] = []
    for p in root.iterdir():
        m = SOURCE_PATTERN.match(p.name)
        if m and p.is_file():
            found.append((int(m.group(1)), p))
    return sorted(found)


# ------------------------------------------------------------------------------------------- writing


def write_recording(folder: str | Path, rec: Recording, *, overwrite: bool = True) -> Path:
    """Write ``rec`` as a recording folder, all-or-nothing; returns the folder.

    Everything goes into a temporary sibling folder that is renamed onto ``folder`` at the end, so an
    error (or a crash) never leaves a half-written recording. An existing ``folder`` is replaced when
    ``overwrite`` (else :class:`FileExistsError`). Audio is stored as 24-bit FLAC. Raises
    :class:`ValueError` for an inconsistent ``rec`` (shape, NaN, clipping, trajectory lengths).
    """
    import soundfile as sf

    target = Path(folder)
    audio = np.asarray(rec.audio, dtype=np.float32)
    mics = np.asarray(rec.mics, dtype=np.float64)
    if audio.ndim != 2 or mics.ndim != 2 or mics.shape[1] != 3 or audio.shape[1] != mics.shape[0]:
        raise ValueError(f"audio {audio.shape} and mics {mics.shape} do not match (need (n, M) and (M, 3))")
    if rec.ego.yaw is None:
        raise ValueError("the ego trajectory needs yaw")
    try:
        check_audio(audio, target / AUDIO_FILE)
    except InputError as exc:
        raise ValueError(f"refusing to write: {exc}") from None
    if target.exists() and not overwrite:
        raise FileExistsError(target)

    with atomic_dir(target) as tmp:
        sf.write(str(tmp / AUDIO_FILE), audio, int(rec.sample_rate), format="FLAC", subtype="PCM_24")
        array_doc = {
            "sample_rate": int(rec.sample_rate),
            "mics": [[round(float(v), 6) for v in m] for m in mics],
        }
        if rec.full_scale_db_spl is not None:
            array_doc[FULL_SCALE_KEY] = round(float(rec.full_scale_db_spl), 3)
        (tmp / ARRAY_FILE).write_text(yaml.safe_dump(array_doc, sort_keys=False), encoding="utf-8")
        _write_csv(tmp / EGO_FILE, EGO_COLUMNS, (rec.ego.t, rec.ego.x, rec.ego.y, rec.ego.yaw))
        for k, src in enumerate(rec.sources):
            _write_csv(tmp / f"source_{k}.csv", SOURCE_COLUMNS, (src.t, src.x, src.y))
        if rec.meta:
            (tmp / META_FILE).write_text(yaml.safe_dump(_plain(rec.meta), sort_keys=False), encoding="utf-8")
    rec.path = target
    return target


def _write_csv(path: Path, columns: tuple[str, ...], arrays: tuple[np.ndarray | None, ...]) -> None:
    cols = [np.asarray(a, dtype=np.float64) for a in arrays if a is not None]
    if len(cols) != len(columns) or len({len(c) for c in cols}) != 1:
        raise ValueError(f"{path.name}: columns {columns} need equal-length arrays")
    data = np.stack(cols, axis=1)
    if not np.isfinite(data).all():
        raise ValueError(f"{path.name}: trajectory has NaN/inf values")
    lines = [",".join(columns)]
    lines += [",".join(f"{v:.6f}" for v in row) for row in data]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def _plain(obj: Any) -> Any:
    """Turn numpy scalars/arrays inside ``obj`` into plain Python for YAML."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    return obj
