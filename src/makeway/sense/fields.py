"""Checked fields of the YAML calibration files (camera rig, roadside camera).

Each reader turns one field of a parsed YAML document into a number, a vector or a rotation, or
calls ``fail(problem)`` — the caller's function that raises an
:class:`~makeway.errors.InputError` naming the file (and the camera) — with a one-line problem.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from makeway.registry import UnknownNameError
from makeway.sense.camera import CAMERA_MODELS, Camera

__all__ = [
    "ORTHONORMAL_TOLERANCE",
    "camera_fields",
    "number_field",
    "rotation_field",
    "vector_field",
    "whole_field",
]

ORTHONORMAL_TOLERANCE = 1e-6
"""A rotation ``R`` is accepted when ``max|RᵀR − I|`` is at most this."""


def number_field(value: Any, key: str, fail: Any, *, positive: bool = False) -> float:
    """``value`` as a finite float (``positive``: also > 0)."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise fail(f"{key} must be a finite number, not {value!r}")
    if positive and value <= 0:
        raise fail(f"{key} must be positive, not {value!r}")
    return float(value)


def whole_field(value: Any, key: str, fail: Any) -> int:
    """``value`` as a positive whole number of pixels."""
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise fail(f"{key} must be a positive whole number of pixels, not {value!r}")
    return value


def vector_field(value: Any, key: str, n: int, fail: Any) -> np.ndarray:
    """``value`` as a list of ``n`` finite numbers."""
    if not isinstance(value, list) or len(value) != n:
        raise fail(f"{key} must be a list of {n} numbers, not {value!r}")
    return np.array([number_field(v, key, fail) for v in value])


def rotation_field(value: Any, fail: Any, key: str = "rotation") -> np.ndarray:
    """``value`` as a proper rotation matrix: 3 rows of 3 numbers, orthonormal within
    :data:`ORTHONORMAL_TOLERANCE`, determinant +1 (a reflection is refused)."""
    if not isinstance(value, list) or len(value) != 3 or not all(isinstance(r, list) for r in value):
        raise fail(f"{key} must be 3 rows of 3 numbers, not {value!r}")
    rot = np.stack([vector_field(row, key, 3, fail) for row in value])
    err = float(np.abs(rot.T @ rot - np.eye(3)).max())
    if err > ORTHONORMAL_TOLERANCE:
        raise fail(f"{key} is not orthonormal (max |RᵀR − I| = {err:.3g} > {ORTHONORMAL_TOLERANCE:g})")
    det = float(np.linalg.det(rot))
    if det < 0:
        raise fail(f"{key} is a reflection (det = {det:.6g}), not a rotation (det = +1)")
    return rot


def camera_fields(doc: dict[str, Any], fail: Any) -> Camera:
    """The camera of a calibration entry: ``model`` (a name of
    :data:`~makeway.sense.camera.CAMERA_MODELS`), ``width``, ``height`` (pixels), ``fx``, ``fy``,
    ``cx``, ``cy`` (pixels) and ``k`` (4 Kannala–Brandt coefficients; optional for ``pinhole``)."""
    model = doc["model"]
    if not isinstance(model, str):
        raise fail("model must be a string")
    try:
        factory = CAMERA_MODELS[model]
    except UnknownNameError as exc:
        raise fail(str(exc)) from None
    width, height = (whole_field(doc[key], key, fail) for key in ("width", "height"))
    fx, fy = (number_field(doc[key], key, fail, positive=True) for key in ("fx", "fy"))
    cx, cy = (number_field(doc[key], key, fail) for key in ("cx", "cy"))
    if "k" in doc:
        k = vector_field(doc["k"], "k", 4, fail)
    elif model == "pinhole":
        k = np.zeros(4)
    else:
        raise fail(f"missing field k (4 distortion coefficients k1..k4 for model {model})")
    k1, k2, k3, k4 = (float(c) for c in k)
    try:
        return factory(width, height, fx, fy, cx, cy, (k1, k2, k3, k4))
    except ValueError as exc:
        raise fail(str(exc)) from None
