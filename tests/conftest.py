"""Shared fixtures. Tests run on the real data in ../shared/data (or $MAKEWAY_DATA).

Without it, data tests are skipped locally with a clear message but FAIL under CI (CI=true), so a
broken checkout can never pass by skipping everything.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from makeway.paths import data_candidates, data_dir
from makeway.sense.crops import CropSet


def _require_data() -> Path:
    found = data_dir()
    if found is not None:
        return found
    where = ", ".join(str(p) for p in data_candidates())
    msg = f"shared data folder not found (looked in: {where}); set MAKEWAY_DATA"
    if os.environ.get("CI"):
        pytest.fail(msg)
    pytest.skip(msg)


@pytest.fixture(scope="session")
def data_root() -> Path:
    """The shared data folder (``../shared/data``)."""
    return _require_data()


@pytest.fixture(scope="session")
def mot15_root(data_root: Path) -> Path:
    root = data_root / "mot15" / "train"
    if not root.is_dir():
        pytest.fail(f"{root} missing from the shared data")
    return root


@pytest.fixture(scope="session")
def video_dir(data_root: Path) -> Path:
    root = data_root / "video"
    if not root.is_dir():
        pytest.fail(f"{root} missing from the shared data")
    return root


@pytest.fixture(scope="session")
def ev_crops(data_root: Path) -> CropSet:
    """The labelled ev_crops folder (1246 crops), read once per test session."""
    from makeway.sense.crops import read_crop_folder

    root = data_root / "vision" / "ev_crops"
    if not root.is_dir():
        pytest.fail(f"{root} missing from the shared data")
    return read_crop_folder(root)
