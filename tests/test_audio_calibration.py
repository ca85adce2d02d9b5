"""Issue 4, recording format: measuring an array's calibration from a calibrator tone
(``makeway audio calibrate``) and using it (``full_scale_db_spl`` → the siren networks' scale)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
from scipy.signal import resample_poly
from typer.testing import CliRunner

from makeway.cli.audio import audio_app
from makeway.errors import InputError
from makeway.eval.siren_labels import label_recording
from makeway.perceive.audio.features import window_batch
from makeway.perceive.audio.siren_model import SirenModel
from makeway.sense.calibration import measure_full_scale, write_full_scale
from makeway.sense.recording import read_recording, write_recording
from makeway.sim.acoustics import FULL_SCALE_PA, db_spl_to_pa, self_noise
from makeway.sim.audio_scenarios import simulate_recording, source_pools

SR = 48_000


def calibrator_take(
    data_root: Path, *, channel: int = 3, level: float = 94.0, freq: float = 1000.0, gain_db: float = 0.0
) -> np.ndarray:
    """2 s of the 8-capsule array at the simulator's scale (135 dB SPL full scale) with a
    calibrator on ``channel``: its tone, a real street recording at ~55 dB SPL on every capsule,
    capsule self-noise; then an array ``gain_db`` more sensitive."""
    rng = np.random.default_rng(0)
    n = 2 * SR
    street, rate = sf.read(str(data_root / "audio/street_recordings/traffic-5.flac"), dtype="float64")
    street = resample_poly(street if street.ndim == 1 else street[:, 0], SR // rate, 1)[:n]
    street *= db_spl_to_pa(55.0) / np.sqrt(np.mean(street**2))
    pa = self_noise(n, 8, rng) + street[:, None]
    t = np.arange(n) / SR
    pa[:, channel] += np.sqrt(2.0) * db_spl_to_pa(level) * np.sin(2 * np.pi * freq * t)
    return (pa / FULL_SCALE_PA * 10 ** (gain_db / 20)).astype(np.float32)


def test_measure_full_scale_of_a_calibrator_take(data_root: Path) -> None:
    found = measure_full_scale(calibrator_take(data_root), SR)
    assert found.channel == 3 and found.full_scale_db_spl == pytest.approx(135.0, abs=0.05)
    assert found.frequency_hz == pytest.approx(1000.0, abs=1.0) and found.snr_db > 30
    others = np.delete(found.channel_tone_dbfs, 3)
    assert found.tone_dbfs - others.max() > 30  # the calibrated capsule stands out
    # an array 10 dB more sensitive: 1.0 stands for 10 dB less; a 114 dB SPL / 250 Hz calibrator
    quieter = measure_full_scale(calibrator_take(data_root, gain_db=10.0), SR)
    assert quieter.full_scale_db_spl == pytest.approx(125.0, abs=0.05)
    other = calibrator_take(data_root, channel=6, level=114.0, freq=250.0)
    found = measure_full_scale(other, SR, level_db_spl=114.0, frequency_hz=250.0)
    assert found.channel == 6 and found.full_scale_db_spl == pytest.approx(135.0, abs=0.05)


def test_measure_full_scale_errors(data_root: Path) -> None:
    take = calibrator_take(data_root)
    with pytest.raises(InputError, match=r"strongest component is at 1000 Hz, not the calibrator's 250 Hz"):
        measure_full_scale(take, SR, frequency_hz=250.0, source="take.flac")
    with pytest.raises(InputError, match=r"channel 5: the strongest component"):
        measure_full_scale(take, SR, channel=5)  # street noise there, not the tone
    with pytest.raises(InputError, match="no channel 8"):
        measure_full_scale(take, SR, channel=8)
    with pytest.raises(InputError, match=r"at least 0\.5 s"):
        measure_full_scale(take[:1000], SR)
    loud = calibrator_take(data_root, level=133.0)  # peaks above full scale: a clipped take
    with pytest.raises(InputError, match="clipped"):
        measure_full_scale(np.clip(loud, -1, 1), SR)
    noisy = calibrator_take(data_root, level=60.0)  # a tone drowned in street noise
    with pytest.raises(InputError, match="stands only"):
        measure_full_scale(noisy, SR, channel=3)


def test_cli_calibrate_writes_the_array_and_eval_uses_it(data_root: Path, tmp_path: Path) -> None:
    """An array 10 dB more sensitive than the simulator's: its recordings state no calibration;
    `audio calibrate --write` measures and stores it, and the networks then see the windows
    exactly as at their own scale."""
    sirens, noise = source_pools("test", data_root)
    rec = simulate_recording(
        "opposite_direction",
        2.0,
        seed=3,
        siren="real",
        siren_pool=sirens,
        noise_pool=noise,
        data_root=data_root,
    )
    g = np.float32(10 ** (10 / 20))
    folder = write_recording(tmp_path / "rec", replace(rec, audio=rec.audio * g, full_scale_db_spl=None))
    take = tmp_path / "calibrator.flac"
    sf.write(str(take), calibrator_take(data_root, gain_db=10.0), SR, subtype="PCM_24")
    runner = CliRunner()
    res = runner.invoke(audio_app, ["calibrate", str(take), "--write", str(folder)])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert out["full_scale_db_spl"] == pytest.approx(125.0, abs=0.05) and out["channel"] == 3
    assert out["written"] == [str(folder / "array.yaml")]
    back = read_recording(folder)
    assert back.full_scale_db_spl == pytest.approx(125.0, abs=0.05)
    model = SirenModel(threads=1)
    lab = label_recording(rec)
    ref = model.predict(window_batch(rec, lab))
    got = model.predict(window_batch(back, lab), back.full_scale_db_spl)
    np.testing.assert_allclose(got.prob, ref.prob, atol=2e-3)
    np.testing.assert_allclose(got.distance, ref.distance, rtol=2e-3)
    # bad targets: nothing is written, one message names the file
    before = (folder / "array.yaml").read_text()
    bad = tmp_path / "bad.yaml"
    bad.write_text("just: text\n")
    res = runner.invoke(audio_app, ["calibrate", str(take), "--write", str(folder), "--write", str(bad)])
    assert res.exit_code == 2 and "bad.yaml" in res.stderr and "not an array description" in res.stderr
    assert (folder / "array.yaml").read_text() == before
    res = runner.invoke(audio_app, ["calibrate", str(tmp_path / "none.flac")])
    assert res.exit_code == 2 and "none.flac" in res.stderr
    with pytest.raises(InputError, match="no such file"):
        write_full_scale([tmp_path / "missing"], 120.0)


def test_training_reads_every_array_at_the_networks_scale(data_root: Path, tmp_path: Path) -> None:
    """The same scene simulated through an array 10 dB more sensitive yields the same training
    features once its array.yaml states it (makeway audio train rescales to 135 dB SPL)."""
    from makeway.perceive.audio.siren_features import SirenFeatures
    from makeway.train.siren import build_dataset

    sirens, noise = source_pools("train", data_root)
    kw = dict(siren="real", siren_pool=sirens, noise_pool=noise, data_root=data_root)
    plain = simulate_recording("same_direction", 1.5, seed=8, **kw)
    keen = simulate_recording("same_direction", 1.5, seed=8, full_scale_db_spl=125.0, **kw)
    assert np.abs(keen.audio).max() > 2.5 * np.abs(plain.audio).max()  # 10 dB louder samples
    folders = [write_recording(tmp_path / name, rec) for name, rec in (("plain", plain), ("keen", keen))]
    feats = SirenFeatures()
    a, b = (build_dataset([f], feats, mirror=False) for f in folders)
    for k in ("level", "spec", "wave", "gcc"):
        np.testing.assert_allclose(b.features[k], a.features[k], atol=2e-4, err_msg=k)
