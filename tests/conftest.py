"""Shared fixtures. Tests run on the real data in ../shared/data (or $MAKEWAY_DATA).

Without it, data tests are skipped locally with a clear message but FAIL under CI (CI=true), so a
broken checkout can never pass by skipping everything. The same holds for the pieces the dev extra
installs (torch): :func:`require_module`. Under CI the session also prints how many tests were
skipped and fails when any was.
"""

from __future__ import annotations

import importlib
import os
import shutil
import subprocess
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from makeway.paths import data_candidates, data_dir
from makeway.sense.crops import CropSet


def under_ci() -> bool:
    """Whether the suite runs under CI (``CI`` set to anything but empty, 0 or false)."""
    return os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")


def skip_or_fail(msg: str) -> None:
    """Skip locally, fail under CI: CI installs every piece the project needs (``make test``)."""
    if under_ci():
        pytest.fail(msg, pytrace=False)
    pytest.skip(msg, allow_module_level=True)


def require_module(name: str) -> ModuleType:
    """Import ``name`` (a dev-extra package such as torch); skipped locally when missing, a
    failure under CI. Works at module level as well as inside a test."""
    try:
        return importlib.import_module(name)
    except ImportError as exc:
        skip_or_fail(f"{name} is not installed ({exc}); `pip install -e '.[dev]'` installs it")
        raise  # not reached: skip_or_fail raises


def _require_data() -> Path:
    found = data_dir()
    if found is not None:
        return found
    where = ", ".join(str(p) for p in data_candidates())
    skip_or_fail(f"shared data folder not found (looked in: {where}); set MAKEWAY_DATA")
    raise AssertionError("not reached")


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if under_ci():
        skipped = len(terminalreporter.stats.get("skipped", []))
        terminalreporter.write_line(
            f"CI: {skipped} test(s) skipped" + (" — CI fails on any skip" if skipped else "")
        )


def start_car_listener(
    trust: Path, segment: str, endpoint: str, *, count: int, duration_s: float, ego_lat: float, ego_lon: float
) -> subprocess.Popen[str]:
    """Start a car process, ``makeway vehicle listen``, on loopback ``endpoint`` (``tcp/127.0.0.1:PORT``):
    it verifies alerts on ``segment`` against the trust store ``trust`` and prints one JSON line each,
    stopping after ``count`` alerts or ``duration_s`` seconds; the ego sits at WGS84 ``ego_lat``,
    ``ego_lon`` (degrees) and holds a belief 30 s. stdout/stderr are pipes (text); kill it when done."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1] / "src")}
    args = ["vehicle", "listen", "--trust", str(trust), "--segment", segment, "--count", str(count)]
    args += ["--duration", f"{duration_s:g}", "--listen", endpoint, "--hold-s", "30"]
    args += ["--ego-lat", repr(ego_lat), "--ego-lon", repr(ego_lon)]
    return subprocess.Popen(
        [sys.executable, "-m", "makeway", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )


def yolo_subset(yolo_dir: Path, out: Path, stems: list[str]) -> Path:
    """Copy the named images (``STEM.jpg``) and their YOLO label files of ``yolo_dir`` into a new
    YOLO folder ``out`` (``images/``, ``labels/``); return ``out``."""
    for sub in ("images", "labels"):
        (out / sub).mkdir(parents=True)
    for stem in stems:
        shutil.copy(yolo_dir / "images" / f"{stem}.jpg", out / "images")
        shutil.copy(yolo_dir / "labels" / f"{stem}.txt", out / "labels")
    return out


@pytest.hookimpl(trylast=True)
def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """Under CI a skipped test fails the run: nothing the project installs may be missing there."""
    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    if under_ci() and reporter is not None and reporter.stats.get("skipped") and exitstatus == 0:
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


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
def ambulance_dir(data_root: Path) -> Path:
    """The ambulance YOLO photo folder (``images/``, ``labels/``)."""
    root = data_root / "vision" / "ambulance_yolo" / "valid"
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


# ------------------------------------------------------------------- fuzzing (issue 29, item 1)
def _register_fuzz_profiles() -> None:
    """Register the hypothesis profiles of ``tests/test_fuzz_*.py`` and load the one that
    ``MAKEWAY_FUZZ_PROFILE`` names: ``ci`` (the default: a fixed budget of about a minute) or ``long``
    (``make fuzz``: over 100,000 inputs across the readers)."""
    from hypothesis import settings

    from fuzzing import PROFILE_ENV, PROFILES

    for name, profile in PROFILES.items():
        settings.register_profile(name, profile)
    chosen = os.environ.get(PROFILE_ENV, "ci")
    if chosen not in PROFILES:
        raise pytest.UsageError(f"{PROFILE_ENV}={chosen!r}: expected one of {', '.join(PROFILES)}")
    settings.load_profile(chosen)


_register_fuzz_profiles()


@pytest.fixture(scope="session")
def short_train_recordings(data_root: Path) -> Any:
    """``make(folder, scenarios, seed)``: 1.5 s roof-array recordings of training-split sirens, one
    per scenario (seeds ``seed``, ``seed + 1``, …), written as ``folder/rec_00000`` …; returns
    their folders in order."""
    from makeway.sense.recording import write_recording
    from makeway.sim.audio_scenarios import simulate_recording
    from makeway.sim.siren import load_siren_sources, split_sources

    sirens = split_sources(load_siren_sources(data_root), "train")

    def make(folder: Path, scenarios: tuple[str, ...], seed: int) -> list[Path]:
        for i, scen in enumerate(scenarios):
            rec = simulate_recording(scen, 1.5, seed=seed + i, siren_pool=sirens, data_root=data_root)
            write_recording(folder / f"rec_{i:05d}", rec)
        return sorted(folder.iterdir())

    return make
