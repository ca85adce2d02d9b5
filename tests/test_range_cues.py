"""Level-independent siren range cues (issue 25): reflection geometry, the delay read from a
simulated array, and bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from makeway.errors import InputError
from makeway.perceive.audio.range_cues import (
    check_array_audio,
    distance_from_delay,
    reflection_delay,
    reflection_distance,
    reflection_tau,
    spectral_tilt,
)
from makeway.physics import SPEED_OF_SOUND
from makeway.sense.recording import Recording, Trajectory, read_recording, reference_mics, write_recording
from makeway.sim.acoustics import (
    PointSource,
    air_absorption_db_per_m,
    db_spl_to_pa,
    self_noise,
    simulate_array,
    wind_noise,
)
from makeway.sim.siren import synthesize_siren

SR = 48_000


def test_delay_geometry_round_trip() -> None:
    d = np.array([3.0, 10.0, 20.0, 50.0, 150.0])
    for hs in (0.8, 1.5, 2.0):
        tau = reflection_tau(d, hs, 1.55)
        assert np.all(np.diff(tau) < 0)  # farther: shorter delay
        np.testing.assert_allclose(distance_from_delay(tau, hs, 1.55), d, rtol=1e-9)
    # the figures: ≈ 0.7 ms at 20 m and ≈ 0.28 ms at 50 m (siren 1.5 m, roof array 1.6 m)
    assert float(reflection_tau(20.0, 1.5, 1.6)) == pytest.approx(0.7e-3, rel=0.05)
    assert float(reflection_tau(50.0, 1.5, 1.6)) == pytest.approx(0.28e-3, rel=0.05)
    # far field: τ ≈ 2·h_s·h_m / (c·d)
    assert float(reflection_tau(300.0, 1.5, 1.55)) == pytest.approx(
        2 * 1.5 * 1.55 / (SPEED_OF_SOUND * 300), rel=1e-3
    )
    # no distance gives a delay beyond the one straight below, nor a non-positive one
    assert np.isnan(distance_from_delay(2.5 * 1.5 / SPEED_OF_SOUND, 1.5, 1.55))
    assert np.isnan(distance_from_delay(0.0, 1.5, 1.55))
    # the height prior: distance ∝ siren height in the far field, so the interval brackets it
    mid, lo, hi = reflection_distance(float(reflection_tau(40.0, 1.5, 1.55)), 1.55, (1.0, 2.0))
    assert mid == pytest.approx(40.0, rel=1e-9)
    assert lo < 30.0 < 50.0 < hi


def _scene(mode: str, distance_m: float, seed: int = 0, reflection: float = 0.8) -> np.ndarray:
    """1.5 s of the reference array hearing a synthesized siren standing ``distance_m`` ahead
    (1.5 m high, road ``reflection``, air absorption), with wind and capsule noise; full scale."""
    rng = np.random.default_rng(seed)
    mics = reference_mics()
    t = np.linspace(-2.0, 4.0, 601)
    ego = Trajectory(t, np.zeros_like(t), np.zeros_like(t), np.zeros_like(t))
    centre = mics[:, :2].mean(axis=0)
    path = Trajectory(t, np.full_like(t, centre[0] + distance_m), np.full_like(t, centre[1]))
    sig, _ = synthesize_siren(mode, 4.0, SR, rng=rng)
    src = PointSource(sig * np.float32(db_spl_to_pa(120.0)), -1.5, path, height_m=1.5, reflection=reflection)
    n = round(1.5 * SR)
    pa = simulate_array([src], ego, mics, n, SR)
    pa += wind_noise(n, len(mics), SR, 5.0, 66.0, rng) + self_noise(n, len(mics), rng)
    return pa / db_spl_to_pa(135.0)


@pytest.mark.parametrize("mode", ["wail", "yelp", "hilo", "phaser"])
def test_reflection_delay_found_at_20_m(mode: str) -> None:
    h_array = float(reference_mics()[:, 2].mean())
    truth = float(reflection_tau(20.0, 1.5, h_array))  # 0.674 ms
    cue = reflection_delay(_scene(mode, 20.0), SR)
    assert cue.found and cue.score > 0.5
    # the best delay within 3 % (±20 µs, one sample is 21 µs) …
    assert cue.tau_s == pytest.approx(truth, rel=0.03)
    # … and so the distance, the siren's height being the prior's middle here
    assert reflection_distance(cue.tau_s, h_array, (1.0, 2.0))[0] == pytest.approx(20.0, rel=0.04)


def test_no_siren_no_confident_delay() -> None:
    rng = np.random.default_rng(3)
    n = round(1.5 * SR)
    pa = wind_noise(n, 8, SR, 8.0, 66.0, rng) + self_noise(n, 8, rng)
    cue = reflection_delay(pa / db_spl_to_pa(135.0), SR)
    assert cue.score < 0.5


def test_tilt_reads_air_absorption_for_one_siren() -> None:
    # the same siren (same seed) heard 10 m and 80 m away with no road reflection: the slope
    # distance differs by the 70 m between them (its offset is the siren's own spectrum)
    def tilt(d: float) -> float:
        audio = _scene("wail", d, seed=1, reflection=0.0)
        return spectral_tilt(audio, SR, air_absorption_db_per_m).distance_m

    assert tilt(80.0) - tilt(10.0) == pytest.approx(70.0, abs=15.0)


def _write(folder: Path, mics: np.ndarray) -> Path:
    t = np.linspace(0.0, 1.0, 11)
    ego = Trajectory(t, np.zeros_like(t), np.zeros_like(t), np.zeros_like(t))
    audio = (np.random.default_rng(0).standard_normal((SR, len(mics))) * 0.01).astype(np.float32)
    return write_recording(folder, Recording(audio, SR, mics, ego, [], None, {}, 135.0))


def test_bad_input(tmp_path: Path) -> None:
    mono = read_recording(_write(tmp_path / "mono", np.array([[0.0, 0.0, 1.5]])))
    with pytest.raises(InputError, match="mono") as err:
        check_array_audio(mono)
    assert "mono" in str(err.value) and str(tmp_path / "mono") in str(err.value)
    flat = reference_mics().copy()
    flat[:, 2] = 0.0
    no_height = read_recording(_write(tmp_path / "no_height", flat))
    with pytest.raises(InputError, match="array height") as err:
        check_array_audio(no_height)
    assert str(tmp_path / "no_height") in str(err.value)
    good = read_recording(_write(tmp_path / "good", reference_mics()))
    assert check_array_audio(good) == pytest.approx(1.55)


def test_scene_generator_level_range() -> None:
    from makeway.sim.audio_scenarios import SIREN_LEVEL_DB_1M, simulate_recording

    def level(**kw: object) -> float:
        rec = simulate_recording(
            "crossing",
            1.0,
            11,
            siren="synth",
            noise="generated",
            distractors=False,
            **kw,  # type: ignore[arg-type]
        )
        return float(rec.meta["sirens"][0]["level_db_1m"])

    default = level()
    assert SIREN_LEVEL_DB_1M[0] <= default <= SIREN_LEVEL_DB_1M[1]
    assert level(siren_level_db=SIREN_LEVEL_DB_1M) == default  # the default draws are unchanged
    assert 130.0 <= level(siren_level_db=(130.0, 135.0)) <= 135.0
    with pytest.raises(ValueError, match="siren_level_db"):
        level(siren_level_db=(135.0, 110.0))
