"""Write outputs all-or-nothing: a crash or bad input never leaves a half-written file behind."""

from __future__ import annotations

import contextlib
import itertools
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
def _naming(target: Path) -> Iterator[None]:
    """Turn an operating-system error while making room for ``target`` (its folder, the temporary
    beside it) into an :class:`InputError` naming ``target``, not the temporary."""
    try:
        yield
    except OSError as exc:
        raise InputError(target, f"cannot be written ({exc.strerror or exc})") from None


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; move it onto ``path`` only if the block succeeds.

    The temporary file lives in the same folder (so the final rename is atomic) and keeps the
    target's suffix (so writers that pick a format from it still work). On an exception it is
    deleted and the exception propagates.
    """
    target = Path(path)
    sfx = target.suffix if suffix is None else suffix
    with _naming(target):
        target.parent.mkdir(parents=True, exist_ok=True)
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


def check_writable(path: str | Path, *, folder: bool) -> Path:
    """Check, before any work starts, that the output ``path`` can be created; return it absolute.

    ``folder`` says whether ``path`` is an output folder (it may exist as a folder) or an output
    file (it may exist as a file). Folders missing on the way are not created: the nearest existing
    one must be a folder in which a file can be made (probed with a temporary file that is removed
    at once, so read-only file systems and ``/proc`` are caught even when running as root).

    Raises:
        InputError: ``path`` is a file where a folder is needed (or the reverse), a part of its
            parent chain is a file, or the nearest existing folder cannot be written.
    """
    target = Path(path).expanduser().absolute()
    if folder and target.exists() and not target.is_dir():
        raise InputError(target, "exists and is a file; an output folder is needed here")
    if not folder and target.is_dir():
        raise InputError(target, "is a folder; an output file is needed here")
    start = target if folder else target.parent
    existing = next(p for p in (start, *start.parents) if p.exists())
    if not existing.is_dir():
        raise InputError(target, f"cannot be created: {existing} is a file, not a folder")
    try:
        fd, probe = tempfile.mkstemp(prefix=".makeway-probe.", dir=existing)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise InputError(target, f"cannot be written: {existing}: {exc.strerror or exc}") from None
    return target


@contextlib.contextmanager
def removed_on_error(folder: str | Path) -> Iterator[None]:
    """Run a block that creates ``folder``; if the block fails, remove the folders of ``folder``'s
    chain that did not exist before it, where they are empty again, and re-raise."""
    target = Path(folder).expanduser().absolute()
    missing = list(itertools.takewhile(lambda p: not p.exists(), (target, *target.parents)))
    try:
        yield
    except BaseException:
        for made in missing:  # deepest first
            try:
                made.rmdir()
            except OSError:
                break
        raise


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
    with _naming(target):
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
