"""Fuzzing of makeway's structured files (issue 29, item 1): a recording folder (``array.yaml``, the
ego and source trajectory CSVs, ``audio.flac``, ``meta.yaml``), audio files (FLAC and WAV), the rig
file, the roadside camera calibration, the V2X replay cache, and ``audio calibrate``'s rewrite of
``array.yaml`` (which must leave the file as it was when it refuses it). Each generated input ends in
a result or one ``InputError`` naming the file (:func:`fuzzing.check_reader`)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from hypothesis import example, given
from hypothesis import strategies as st

from fuzzing import budget, check_reader, file_contents
from makeway.roadside.transform import read_transform_calibration
from makeway.sense.calibration import write_full_scale
from makeway.sense.recording import read_audio, read_recording, write_recording
from makeway.sense.rig import default_rig_path, read_rig
from makeway.sim.audio_scenarios import simulate_recording
from makeway.v2x.security import ReplayCache

SHIPPED_CALIBRATION = default_rig_path().parent / "intersection_cam_ambulance.yaml"


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz_files")


@pytest.fixture(scope="module")
def recording(work: Path) -> Path:
    """A 0.6 s simulated recording of the roof array with one source (real files, makeway's writer)."""
    rec = simulate_recording("crossing", 0.6, seed=3, siren="synth", noise="generated")
    return write_recording(work / "rec_seed", rec)


def _write(folder: Path, name: str, data: bytes) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_bytes(data)
    return path


# ------------------------------------------------------------------------------- recording folder
_MEMBERS = ["array.yaml", "ego.csv", "source_0.csv", "audio.flac", "meta.yaml"]
_KINDS = {"array.yaml": "yaml", "meta.yaml": "yaml", "audio.flac": "binary"}


def test_fuzz_recording_folder(recording: Path, work: Path) -> None:
    """One file of a valid recording folder replaced by a mutation of itself per input."""
    assert {p.name for p in recording.iterdir()} >= set(_MEMBERS) - {"meta.yaml"}
    seeds = {
        m: (recording / m).read_bytes() if (recording / m).exists() else b"scene: crossing\n"
        for m in _MEMBERS
    }
    strategies = {m: file_contents(seeds[m], _KINDS.get(m, "text")) for m in _MEMBERS}
    folder = work / "rec"

    @budget(0.5)
    @given(member=st.sampled_from(_MEMBERS), data=st.data())
    def run(member: str, data: st.DataObject) -> None:
        shutil.rmtree(folder, ignore_errors=True)
        shutil.copytree(recording, folder)
        (folder / member).write_bytes(data.draw(strategies[member]))
        got = check_reader(f"recording folder ({member})", lambda: read_recording(folder), inside=folder)
        if got is not None:
            assert np.isfinite(got.audio).all() and got.audio.shape[1] == len(got.mics)

    run()


# -------------------------------------------------------------------------------------- audio files
def test_fuzz_audio_files(recording: Path, data_root: Path, work: Path) -> None:
    """FLAC (the recording's, and a real siren clip cut short) and WAV files, mutated byte-wise."""
    clip = sorted((data_root / "audio" / "siren_clips").glob("*.flac"))[0]
    real, rate = sf.read(str(clip), frames=4000, always_2d=True)
    wav = work / "seed.wav"
    sf.write(str(wav), real, rate, subtype="PCM_16")
    flac = work / "seed.flac"
    sf.write(str(flac), real, rate)
    seeds = [
        ("flac", (recording / "audio.flac").read_bytes()),
        ("flac", flac.read_bytes()),
        ("wav", wav.read_bytes()),
    ]

    @budget(0.5)
    @given(pick=st.integers(0, len(seeds) - 1), data=st.data())
    def run(pick: int, data: st.DataObject) -> None:
        suffix, seed = seeds[pick]
        path = _write(work / "audio", f"clip.{suffix}", data.draw(file_contents(seed, "binary")))
        got = check_reader(f"audio file ({suffix.upper()})", lambda: read_audio(path), inside=path)
        if got is not None:
            assert got[0].ndim == 2 and got[1] > 0

    run()


# -------------------------------------------------------------------------------------- YAML files
def test_fuzz_rig(work: Path) -> None:
    seed = default_rig_path().read_text(encoding="utf-8")

    @budget()
    @given(data=file_contents(seed, "yaml"))
    def run(data: bytes) -> None:
        path = _write(work / "rig", "rig.yaml", data)
        got = check_reader("rig file (YAML)", lambda: read_rig(path), inside=path)
        if got is not None:
            assert len(got.cameras) > 0

    run()


def test_fuzz_roadside_calibration(work: Path) -> None:
    seed = SHIPPED_CALIBRATION.read_text(encoding="utf-8")

    @budget()
    @given(data=file_contents(seed, "yaml"))
    def run(data: bytes) -> None:
        path = _write(work / "calibration", "camera.yaml", data)
        check_reader("roadside calibration (YAML)", lambda: read_transform_calibration(path), inside=path)

    run()


def test_fuzz_array_yaml_rewrite(recording: Path, work: Path) -> None:
    """``audio calibrate --set``: a refused array.yaml is left byte for byte as it was."""
    seed = (recording / "array.yaml").read_text(encoding="utf-8")

    @budget()
    @given(data=file_contents(seed, "yaml"))
    def run(data: bytes) -> None:
        path = _write(work / "calibrate", "array.yaml", data)
        got = check_reader("array.yaml rewrite", lambda: write_full_scale([path], 120.0), inside=path)
        if got is None:
            assert path.read_bytes() == data
        assert sorted(p.name for p in path.parent.iterdir()) == ["array.yaml"]  # no temporary left

    run()


def test_fuzz_replay_cache(work: Path) -> None:
    seed = '{"seen": [["00112233aabbccdd", 7, 1764000000000], ["8899aabbccddeeff", 1, 1764000000500]]}\n'

    @budget()
    @given(data=file_contents(seed))
    # found by fuzzing: a sequence of Infinity (JSON as Python writes it) raised OverflowError
    @example(data=b'{"seen": [["00112233aabbccdd", Infinity, 1764000000000]]}')
    @example(data=b'{"seen": [["00", 1.5, -3]]}')
    def run(data: bytes) -> None:
        path = _write(work / "replay", "replay.json", data)
        got = check_reader("V2X replay cache (JSON)", lambda: ReplayCache.load(path), inside=path)
        if got is not None:
            assert len(got) >= 0

    run()
