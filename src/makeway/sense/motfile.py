"""MOTChallenge text files: detections, ground truth and tracker output (SPEC §2).

One row per box: ``frame, id, x, y, w, h, conf, …`` with 1-based frame numbers, the box's top-left
corner and size in pixels, ``id = -1`` for detections, and ``conf`` the detection score (in
ground-truth files a 0/1 "consider this box" flag). Comma- or whitespace-separated.
Tracker output is written as ``frame,id,x,y,w,h,1,-1,-1,-1``.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from makeway.atomic import atomic_path
from makeway.errors import InputError


@dataclass(frozen=True)
class MotData:
    """The rows of one MOTChallenge file, sorted by frame.

    ``frames (n,)`` 1-based frame numbers, ``ids (n,)`` object ids (-1 for detections),
    ``xywh (n, 4)`` boxes, ``conf (n,)`` the 7th column (1 where absent).
    """

    frames: np.ndarray
    ids: np.ndarray
    xywh: np.ndarray
    conf: np.ndarray

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def num_frames(self) -> int:
        """The last frame number (0 for an empty file)."""
        return int(self.frames.max()) if len(self.frames) else 0

    @property
    def xyxy(self) -> np.ndarray:
        out = self.xywh.copy()
        out[:, 2:] += out[:, :2]
        return out

    def by_frame(
        self, num_frames: int | None = None, *, only: np.ndarray | None = None
    ) -> Iterator[tuple[int, np.ndarray]]:
        """Yield ``(frame, row indices)`` for every frame 1…``num_frames``, empty ones included; with
        ``only`` (sorted 1-based frame numbers) for just those frames, so a sparse file with frame
        numbers in the billions costs its rows, not its frame range."""
        if only is None:
            last = self.num_frames if num_frames is None else num_frames
            only = np.arange(1, last + 1)
        lo = np.searchsorted(self.frames, only, side="left").tolist()
        hi = np.searchsorted(self.frames, only, side="right").tolist()
        for f, a, b in zip(np.asarray(only).tolist(), lo, hi, strict=True):
            yield int(f), np.arange(a, b)

    def frames_with_rows(self, num_frames: int | None = None) -> np.ndarray:
        """The sorted frame numbers that hold at least one row (up to ``num_frames``)."""
        frames = np.unique(self.frames)
        return frames if num_frames is None else frames[frames <= num_frames]

    def select(self, mask: np.ndarray) -> MotData:
        return MotData(self.frames[mask], self.ids[mask], self.xywh[mask], self.conf[mask])


#: the largest frame number or |id| a file may hold: every integer up to it is exact in a float64
MAX_INDEX = 2**53
#: the largest |x|, |y|, w or h of a box, pixels, and the smallest w or h
MAX_PIXELS = 1e6
MIN_SIZE_PX = 1e-3


def read_mot(path: str | Path, *, kind: str = "detection") -> MotData:
    """Read a MOTChallenge file; every problem is an :class:`InputError` naming file and line.

    Args:
        path: the ``det.txt`` / ``gt.txt`` / tracks file.
        kind: ``"detection"`` (ids may repeat), or ``"gt"``/``"tracks"`` (an id appears at most
            once per frame).
    """
    p = Path(path)
    if not p.exists():
        raise InputError(p, "no such file (expected a MOTChallenge text file: frame,id,x,y,w,h,conf,…)")
    if p.is_dir():
        raise InputError(p, "is a folder, expected a MOTChallenge text file (e.g. det/det.txt)")
    try:
        text = p.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputError(p, "is not a text file (could not decode it as UTF-8)") from None
    except OSError as exc:
        raise InputError(p, f"cannot be read ({exc.strerror})") from None

    rows: list[list[float]] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.replace(",", " ").split()
        if len(parts) < 6:
            raise InputError(
                p,
                f"line {lineno}: expected at least 6 values (frame,id,x,y,w,h), "
                f"found {len(parts)}: {s[:60]!r}",
            )
        try:
            vals = [float(v) for v in parts[:7]]
        except ValueError:
            raise InputError(p, f"line {lineno}: non-numeric value in {s[:60]!r}") from None
        if not all(np.isfinite(vals)):
            raise InputError(p, f"line {lineno}: NaN or infinite value in {s[:60]!r}")
        frame, ident, _, _, w, h = vals[:6]
        if frame < 1 or frame != int(frame) or frame > MAX_INDEX:
            raise InputError(
                p, f"line {lineno}: frame must be a positive integer up to 2**53, found {parts[0]}"
            )
        if ident != int(ident) or abs(ident) > MAX_INDEX:
            raise InputError(p, f"line {lineno}: id must be an integer up to ±2**53, found {parts[1]}")
        if w <= 0 or h <= 0:
            raise InputError(
                p, f"line {lineno}: box width and height must be positive, found w={w:g} h={h:g}"
            )
        if max(abs(v) for v in vals[2:6]) > MAX_PIXELS or min(w, h) < MIN_SIZE_PX:
            # beyond these a box's corners lose its size to rounding (x + w == x): no box at all
            raise InputError(
                p,
                f"line {lineno}: box outside ±{MAX_PIXELS:g} px or smaller than {MIN_SIZE_PX:g} px: "
                f"{s[:60]!r}",
            )
        if len(vals) == 6:
            vals.append(1.0)
        rows.append(vals)

    if not rows:
        arr = np.zeros((0, 7))
    else:
        arr = np.asarray(rows, dtype=np.float64)
        arr = arr[np.argsort(arr[:, 0], kind="stable")]
    data = MotData(
        frames=arr[:, 0].astype(np.int64),
        ids=arr[:, 1].astype(np.int64),
        xywh=arr[:, 2:6].copy(),
        conf=arr[:, 6].copy(),
    )
    if kind != "detection" and len(data):
        pairs = np.stack([data.frames, data.ids], axis=1)  # (frame, id) rows: no product to overflow
        uniq, counts = np.unique(pairs, axis=0, return_counts=True)
        if (counts > 1).any():
            frame, ident = uniq[int(np.flatnonzero(counts > 1)[0])]
            raise InputError(p, f"object id {ident} appears more than once in frame {frame}")
    return data


def write_mot_tracks(path: str | Path, rows: list[tuple[int, int, float, float, float, float]]) -> None:
    """Write tracker output ``(frame, id, x, y, w, h)`` rows as ``frame,id,x,y,w,h,1,-1,-1,-1``.

    The file appears only when complete.
    """
    with atomic_path(path) as tmp, tmp.open("w", encoding="utf-8") as fh:
        for f, i, x, y, w, h in rows:
            fh.write(f"{f},{i},{x:.2f},{y:.2f},{w:.2f},{h:.2f},1,-1,-1,-1\n")
