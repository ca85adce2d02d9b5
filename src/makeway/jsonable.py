"""Strict-JSON values from numpy-laden results: one converter for every summary and metrics file."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np


def to_jsonable(value: Any, digits: int | None = 6) -> Any:
    """NaN/inf → ``None``, floats rounded to ``digits`` (``None``: kept as they are), numpy scalars →
    Python, tuples → lists, paths → strings; recursive over dicts and sequences."""
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, float | np.floating):
        v = float(value)
        if not math.isfinite(v):
            return None
        return v if digits is None else round(v, digits)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, dict):
        return {str(k): to_jsonable(v, digits) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_jsonable(v, digits) for v in value]
    if isinstance(value, Path):
        return str(value)
    return value
