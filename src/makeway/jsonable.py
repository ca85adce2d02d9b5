"""Strict-JSON values from numpy-laden results: one converter for every summary and metrics file."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np


def to_jsonable(value: Any, digits: int = 6) -> Any:
    """NaN/inf → ``None``, floats rounded to ``digits``, numpy scalars → Python, tuples → lists,
    paths → strings; recursive over dicts and sequences."""
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, float | np.floating):
        v = float(value)
        return round(v, digits) if math.isfinite(v) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, dict):
        return {str(k): to_jsonable(v, digits) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_jsonable(v, digits) for v in value]
    if isinstance(value, Path):
        return str(value)
    return value
