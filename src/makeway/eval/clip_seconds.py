"""Per-second "active EV" scores on the real clips with sound (issue 26 item 6).

The ground truth is ``src/makeway/data/clip_seconds.csv`` (data card
``docs/data_card_clip_seconds.md``): per whole second of each clip, whether a siren is audible,
whether lit emergency lights are visible, and ``active_ev`` (either). :func:`read_clip_seconds`
reads it; :func:`score_seconds` scores a per-second yes/no against a column of it (precision,
recall, F1 over the seconds whose truth is 0 or 1; ``unsure`` seconds are left out).
"""

from __future__ import annotations

import csv
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from makeway.errors import InputError

__all__ = ["CLIP_SECONDS", "SecondTruth", "pooled", "read_clip_seconds", "score_seconds"]

CLIP_SECONDS = Path(__file__).resolve().parents[1] / "data" / "clip_seconds.csv"
"""The shipped per-second ground truth."""

_HEADER = ["clip", "second", "siren", "lights", "active_ev", "checked_frames", "lit_frames", "siren_note"]
_VALUES = {"1": True, "0": False, "unsure": None}


@dataclass(frozen=True)
class SecondTruth:
    """One row of the ground truth: ``siren``, ``lights``, ``active_ev`` are ``True``/``False``, or
    ``None`` where the labeller was unsure."""

    clip: str
    second: int
    siren: bool | None
    lights: bool | None
    active_ev: bool | None
    note: str = ""


def read_clip_seconds(path: str | Path = CLIP_SECONDS) -> dict[str, list[SecondTruth]]:
    """The ground truth by clip, seconds in order.

    Raises:
        InputError: a missing file, a wrong header, a malformed value, or a clip whose seconds are
            not ``0, 1, 2, …`` (names ``file:line``).
    """
    p = Path(path)
    try:
        lines = p.read_text(encoding="utf-8").splitlines()
    except FileNotFoundError:
        raise InputError(p, "no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(p, f"cannot be read ({exc})") from None
    out: dict[str, list[SecondTruth]] = {}
    header_seen = False
    for lineno, line in enumerate(lines, 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        fields = next(csv.reader([line]))
        if not header_seen:
            if fields != _HEADER:
                raise InputError(f"{p}:{lineno}", f"header must be {','.join(_HEADER)}")
            header_seen = True
            continue
        if len(fields) != len(_HEADER):
            raise InputError(f"{p}:{lineno}", f"{len(fields)} fields, {len(_HEADER)} expected")
        clip, second, *flags = fields[:5]
        try:
            k = int(second)
            siren, lights, active = (_VALUES[v] for v in flags)
        except (ValueError, KeyError):
            raise InputError(f"{p}:{lineno}", "second must be an integer and flags 1, 0 or unsure") from None
        rows = out.setdefault(clip, [])
        if k != len(rows):
            raise InputError(f"{p}:{lineno}", f"second {k} of {clip} out of order (expected {len(rows)})")
        rows.append(SecondTruth(clip, k, siren, lights, active, fields[7]))
    if not header_seen:
        raise InputError(p, "no header row")
    return out


def score_seconds(predicted: Iterable[bool], truth: Iterable[bool | None]) -> dict[str, Any]:
    """Precision, recall and F1 of per-second yes/no ``predicted`` against ``truth`` (``None``
    seconds left out); also the counts and the false-positive seconds. Precision is ``None`` when
    nothing was predicted, recall when nothing is true.

    Raises:
        ValueError: the two have different lengths.
    """
    pred, true = list(predicted), list(truth)
    if len(pred) != len(true):
        raise ValueError(f"{len(pred)} predictions for {len(true)} seconds")
    tp = fp = fn = tn = skipped = 0
    for p, t in zip(pred, true, strict=True):
        if t is None:
            skipped += 1
        elif p and t:
            tp += 1
        elif p:
            fp += 1
        elif t:
            fn += 1
        else:
            tn += 1
    return _scores(tp, fp, fn, tn, skipped)


def _scores(tp: int, fp: int, fn: int, tn: int, unsure: int) -> dict[str, Any]:
    precision = tp / (tp + fp) if tp + fp else None
    recall = tp / (tp + fn) if tp + fn else None
    f1 = None
    if precision is not None and recall is not None:
        f1 = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    return {
        "tp": tp,
        "fp": fp,
        "fn": fn,
        "tn": tn,
        "unsure": unsure,
        "precision": None if precision is None else round(precision, 4),
        "recall": None if recall is None else round(recall, 4),
        "f1": None if f1 is None else round(f1, 4),
    }


def pooled(blocks: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """The scores of several clips' counts added up (the "all clips" row)."""
    counts = [sum(int(b[key]) for b in blocks.values()) for key in ("tp", "fp", "fn", "tn", "unsure")]
    return _scores(*counts)
