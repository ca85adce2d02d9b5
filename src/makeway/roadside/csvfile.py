"""The data lines of the small CSV files the roadside commands read (points, pixels)."""

from __future__ import annotations

import csv
from pathlib import Path

from makeway.errors import InputError

__all__ = ["data_lines"]


def data_lines(path: Path, what: str) -> list[tuple[int, str, list[str]]]:
    """``(line number, stripped text, cells)`` of each line of ``path`` that is neither blank nor a
    ``#`` comment, cells stripped. ``what`` names the file's kind in the errors: a missing file raises
    ``InputError(path, "<what> file not found")``, an unreadable one ``"cannot be read as a <what>
    CSV (…)"``."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        raise InputError(path, f"{what} file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, f"cannot be read as a {what} CSV ({exc})") from None
    out = []
    for n, line in enumerate(lines, start=1):
        text = line.strip()
        if text and not text.startswith("#"):
            out.append((n, text, [c.strip() for c in next(csv.reader([text]))]))
    return out
