"""Write outputs all-or-nothing: a crash or bad input never leaves a half-written file behind."""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from makeway.errors import InputError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; move it onto ``path`` only if the block succeeds.

    The temporary file lives in the same folder (so the final rename is atomic) and keeps the
    target's suffix (so writers that pick a format from it still work). On an exception it is
    deleted and the exception propagates.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    sfx = target.suffix if suffix is None else suffix
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.stem}.", suffix=f".partial{sfx}", dir=target.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600; outputs get the usual permissions
    try:
        yield tmp
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` all-or-nothing (UTF-8)."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def check_replaceable(path: str | Path, marker: str) -> None:
    """Refuse to replace ``path`` unless it is absent, empty, or an earlier output holding ``marker``.

    Raises:
        InputError: ``path`` is a file, or a non-empty folder without ``marker``.
    """
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise InputError(out, "exists and is not a folder; choose another output folder")
    if out.is_dir() and any(out.iterdir()) and not (out / marker).is_file():
        raise InputError(
            out, f"is a non-empty folder that is not a makeway output (no {marker}); choose another"
        )


@contextlib.contextmanager
def atomic_dir(path: str | Path, *, marker: str | None = None) -> Iterator[Path]:
    """Yield a temporary folder beside ``path``; it replaces ``path`` only if the block succeeds.

    An earlier folder at ``path`` is swapped out and removed after the new one is in place. With
    ``marker``, :func:`check_replaceable` runs first, so another program's folder is never replaced.
    On an exception the temporary folder is deleted and the exception propagates.
    """
    target = Path(path).expanduser().absolute()
    if marker is not None:
        check_replaceable(target, marker)
    target.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".partial", dir=target.parent))
    os.chmod(stage, 0o777 & ~_umask())  # mkdtemp makes it private; the published folder should not be
    try:
        yield stage
        if target.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=target.parent))
            os.replace(target, old / "x")
            os.replace(stage, target)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(stage, target)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
