"""Where makeway looks for the shared data and the detector weights.

``MAKEWAY_DATA`` overrides the data folder; otherwise ``../shared/data`` next to the current
directory or next to the repository checkout is used when it exists. ``MAKEWAY_MODELS`` overrides the
folder of ONNX weights (default: ``<data>/models``).
"""

from __future__ import annotations

import os
from pathlib import Path

_REPO_ROOT = Path(__file__).resolve().parents[2]


def data_candidates() -> list[Path]:
    """The folders that may hold the shared data, in the order they are tried."""
    out: list[Path] = []
    env = os.environ.get("MAKEWAY_DATA")
    if env:
        out.append(Path(env).expanduser())
    for base in (Path.cwd(), _REPO_ROOT):
        cand = (base / ".." / "shared" / "data").resolve()
        if cand not in out:
            out.append(cand)
    return out


def data_dir() -> Path | None:
    """The shared data folder, or ``None`` when none of :func:`data_candidates` exists."""
    for cand in data_candidates():
        if cand.is_dir():
            return cand.resolve()
    return None


def require_data_dir(data: str | Path | None = None) -> Path:
    """``data``, or the shared data folder :func:`data_dir` finds when it is ``None``, checked to be
    a folder.

    Raises:
        InputError: no such folder (named, with how to point at one).
    """
    from makeway.errors import InputError

    path = Path(data) if data is not None else data_dir()
    if path is None or not path.is_dir():
        raise InputError(
            path if path is not None else "../shared/data",
            "shared data folder not found; pass --data or set MAKEWAY_DATA",
        )
    return path


def models_candidates() -> list[Path]:
    """The folders that may hold detector weights, in the order they are tried."""
    out: list[Path] = []
    env = os.environ.get("MAKEWAY_MODELS")
    if env:
        out.append(Path(env).expanduser())
    data = data_dir()
    if data is not None:
        out.append(data / "models")
    return out
