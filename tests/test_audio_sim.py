"""Issue 4, simulation and labelling: recording format, synthesizer, moving-source array simulator,
scenarios, auto-labeller and the audio CLI."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
import yaml

from makeway.errors import InputError
from makeway.eval.siren_labels import label_recording
from makeway.perceive.audio.windows import window_starts
from makeway.sense.recording import (
    REFERENCE_FULL_SCALE_DB_SPL,
    REFERENCE_SAMPLE_RATE,
    Recording,
    Trajectory,
    calibration_gain,
    read_recording,
    reference_mics,
    write_recording,
)
from makeway.sim.acoustics import (
    SPEED_OF_SOUND,
    PointSource,
    a_weighted_level_db,
    db_spl_to_pa,
    generated_street_noise,
    mic_world_positions,
    place_fixed_sources,
    propagation_delays,
    read_fractional,
    simulate_array,
    wind_noise,
)
from makeway.sim.audio_scenarios import AUDIO_SCENARIOS, make_tracks, simulate_recording
from makeway.sim.siren import (
    MODE_RANGES,
    SIREN_MODES,
    fit_length,
    flatten_envelope,
    load_siren_sources,
    mode_frequency_bounds,
    pitch_shift,
    synthesize_siren,
)

SR = REFERENCE_SAMPLE_RATE
C = SPEED_OF_SOUND


def _line(
    t0: float,
    t1: float,
    x0: float,
    y0: float,
    vx: float = 0.0,
    vy: float = 0.0,
    yaw: float | None = None,
    rate: float = 100.0,
) -> Trajectory:
    t = np.linspace(t0, t1, round((t1 - t0) * rate) + 1)
    return Trajectory(
        t, x0 + vx * (t - 0.0), y0 + vy * (t - 0.0), None if yaw is None else np.full_like(t, yaw)
    )


def _small_recording(duration: float = 1.0, seed: int = 0) -> Recording:
    rng = np.random.default_rng(seed)
    n = round(duration * SR)
    audio = (0.05 * rng.standard_normal((n, 8))).astype(np.float32)
    ego = _line(0.0, duration, 3.0, -2.0, vx=5.0, yaw=0.0)
    src = _line(0.0, duration, 40.0, 10.0, vx=-8.0)
    return Recording(audio, SR, reference_mics(), ego, [src], meta={"note": "test", "level": 1.5})


# ------------------------------------------------------------------------------------ recording format


def test_reference_array_matches_issue() -> None:
    mics = reference_mics()
    assert mics.shape == (8, 3)
    np.testing.assert_allclose(mics[0], [-0.87, 0.45, 1.55])  # L-front
    np.testing.assert_allclose(mics[1], [-0.90, 0.48, 1.55])  # L-left
    np.testing.assert_allclose(mics[6], [-0.93, -0.45, 1.55])  # R-back
    np.testing.assert_allclose(mics[7], [-0.90, -0.48, 1.55])  # R-right


def test_recording_round_trip(tmp_path: Path) -> None:
    rec = _small_recording()
    folder = write_recording(tmp_path / "rec", rec)
    back = read_recording(folder)
    assert back.sample_rate == SR and back.audio.dtype == np.float32 and back.audio.shape == rec.audio.shape
    np.testing.assert_allclose(back.audio, rec.audio, atol=2e-7)
    np.testing.assert_allclose(back.mics, rec.mics)
    for a, b in ((back.ego, rec.ego), (back.sources[0], rec.sources[0])):
        for name in ("t", "x", "y"):
            np.testing.assert_allclose(getattr(a, name), getattr(b, name), atol=1e-6)
    assert back.ego.yaw is not None and back.sources[0].yaw is None
    assert back.meta == {"note": "test", "level": 1.5}
    # overwriting replaces the folder whole and leaves no temporary siblings behind
    rec2 = _small_recording(seed=1)
    rec2.sources = []
    write_recording(folder, rec2)
    assert not (folder / "source_0.csv").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec"]


def test_write_refuses_bad_audio(tmp_path: Path) -> None:
    rec = _small_recording()
    rec.audio[10, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        write_recording(tmp_path / "bad", rec)
    assert not any(tmp_path.iterdir())


def _expect(folder: Path, file_name: str, *fragments: str) -> None:
    with pytest.raises(InputError) as info:
        read_recording(folder)
    assert info.value.path.name == file_name, str(info.value)
    for frag in fragments:
        assert frag in info.value.problem, str(info.value)


@pytest.fixture
def good_folder(tmp_path: Path) -> Path:
    return write_recording(tmp_path / "rec", _small_recording())


def test_error_missing_file(good_folder: Path) -> None:
    (good_folder / "ego.csv").unlink()
    _expect(good_folder, "ego.csv", "missing")


def test_error_unreadable_audio(good_folder: Path) -> None:
    (good_folder / "audio.flac").write_bytes(b"not a flac file at all")
    _expect(good_folder, "audio.flac", "cannot be read as audio")


def test_error_channel_count(good_folder: Path) -> None:
    doc = yaml.safe_load((good_folder / "array.yaml").read_text())
    doc["mics"] = doc["mics"][:7]
    (good_folder / "array.yaml").write_text(yaml.safe_dump(doc))
    _expect(good_folder, "audio.flac", "8 channel(s)", "7 microphone(s)")


def test_error_sample_rate_mismatch(good_folder: Path) -> None:
    doc = yaml.safe_load((good_folder / "array.yaml").read_text())
    doc["sample_rate"] = 44100
    (good_folder / "array.yaml").write_text(yaml.safe_dump(doc))
    _expect(good_folder, "audio.flac", "48000 Hz", "44100")


def test_error_nan_audio(good_folder: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    real_read = sf.read

    def fake_read(*args: object, **kwargs: object) -> tuple[np.ndarray, int]:
        data, rate = real_read(*args, **kwargs)
        data[100, 2] = np.inf
        return data, rate

    monkeypatch.setattr(sf, "read", fake_read)
    _expect(good_folder, "audio.flac", "NaN/inf", "sample 100, channel 2")


def test_error_clipped_audio(good_folder: Path) -> None:
    audio = 0.05 * np.random.default_rng(3).standard_normal((SR, 8))
    audio[1000:1500, 5] = 1.0  # 1 % of channel 5 pinned at full scale
    sf.write(good_folder / "audio.flac", audio, SR, subtype="PCM_24")
    _expect(good_folder, "audio.flac", "clipped", "channel 5")


def test_error_malformed_yaml(good_folder: Path) -> None:
    (good_folder / "array.yaml").write_text("sample_rate: [48000\nmics: {")
    _expect(good_folder, "array.yaml", "not valid YAML")


def test_error_missing_yaml_key(good_folder: Path) -> None:
    (good_folder / "array.yaml").write_text("sample_rate: 48000\n")
    _expect(good_folder, "array.yaml", "missing key(s) mics")


def test_calibration_round_trip_and_gain(tmp_path: Path) -> None:
    """``full_scale_db_spl`` in array.yaml: optional, written and read back, and the gain it implies
    (a sound at L dB SPL is at L − full scale dBFS)."""
    rec = _small_recording()
    assert rec.full_scale_db_spl is None
    back = read_recording(write_recording(tmp_path / "plain", rec))
    assert (
        back.full_scale_db_spl is None
        and "full_scale_db_spl" not in (tmp_path / "plain/array.yaml").read_text()
    )
    rec.full_scale_db_spl = 120.5
    back = read_recording(write_recording(tmp_path / "cal", rec))
    assert back.full_scale_db_spl == 120.5
    assert calibration_gain(None) == 1.0 and calibration_gain(135.0) == pytest.approx(1.0)
    # an array whose full scale is 120 dB SPL records a 100 dB SPL tone at -20 dBFS; at the
    # networks' 135 dB SPL scale the same tone is at -35 dBFS
    assert 20 * np.log10(calibration_gain(120.0)) == pytest.approx(-15.0)
    assert calibration_gain(140.0, reference_db_spl=120.0) == pytest.approx(10.0)
    assert REFERENCE_FULL_SCALE_DB_SPL == 135.0


@pytest.mark.parametrize("value", ["'loud'", "-41", "true", "300", "[135]"])
def test_error_bad_calibration(good_folder: Path, value: str) -> None:
    doc = (good_folder / "array.yaml").read_text()
    (good_folder / "array.yaml").write_text(doc + f"full_scale_db_spl: {value}\n")
    _expect(good_folder, "array.yaml", "full_scale_db_spl must be the dB SPL", "from 60 to 200")


def test_error_csv_missing_column(good_folder: Path) -> None:
    (good_folder / "ego.csv").write_text("t,x,y\n0,0,0\n1,1,0\n")
    _expect(good_folder, "ego.csv", "missing column(s) yaw", "found t, x, y")


def test_error_csv_not_numeric(good_folder: Path) -> None:
    lines = (good_folder / "source_0.csv").read_text().splitlines()
    lines[3] = "0.020000,abc,1.0"
    (good_folder / "source_0.csv").write_text("\n".join(lines) + "\n")
    _expect(good_folder, "source_0.csv", "line 4", "'abc'")


def test_error_trajectory_too_short(good_folder: Path) -> None:
    lines = (good_folder / "source_0.csv").read_text().splitlines()
    (good_folder / "source_0.csv").write_text("\n".join(lines[:52]) + "\n")  # header + 0.00 … 0.50 s
    _expect(good_folder, "source_0.csv", "covers 0.00–0.50 s", "needs 0.00–1.00 s")


# ----------------------------------------------------------------------------------------- synthesizer


def _peak_track(x: np.ndarray, lo: float = 200.0, hi: float = 3000.0) -> np.ndarray:
    from scipy.signal import stft

    f, _, z = stft(x, SR, nperseg=4096, noverlap=4096 - 512)
    band = (f >= lo) & (f <= hi)
    return f[band][np.abs(z[band]).argmax(axis=0)][4:-4]


@pytest.mark.parametrize("mode", SIREN_MODES)
def test_synth_frequency_range(mode: str) -> None:
    lo, hi = mode_frequency_bounds(mode)
    for seed in (1, 2):
        x, p = synthesize_siren(mode, 8.0, SR, seed=seed)
        assert x.dtype == np.float32 and len(x) == 8 * SR
        assert abs(float(np.sqrt(np.mean(x.astype(np.float64) ** 2))) - 1.0) < 1e-3
        r = MODE_RANGES[mode]
        assert r["period_s"][0] <= p.period_s <= r["period_s"][1]
        track = _peak_track(x)
        bin_hz = SR / 4096
        # the fundamental stays inside the documented range …
        assert np.percentile(track, 2) >= lo - 2 * bin_hz, (mode, seed, np.percentile(track, 2))
        assert np.percentile(track, 98) <= hi + 2 * bin_hz, (mode, seed, np.percentile(track, 98))
        # … and sweeps most of this siren's own range (phaser sweeps too fast for a 4096-point STFT)
        if mode != "phaser":
            span = np.percentile(track, 98) - np.percentile(track, 2)
            assert span >= 0.8 * (p.f_high - p.f_low) - 2 * bin_hz, (mode, seed, span)
    a, _ = synthesize_siren(mode, 1.0, SR, seed=7)
    b, _ = synthesize_siren(mode, 1.0, SR, seed=7)
    np.testing.assert_array_equal(a, b)


def test_fit_length_loops() -> None:
    x = np.arange(1000, dtype=np.float32)
    y = fit_length(x, 2500, np.random.default_rng(0), crossfade=0, random_start=False)
    assert len(y) == 2500 and y[1000] == 0 and y[2499] == 499


def test_pitch_shift_moves_the_tone() -> None:
    t = np.arange(SR) / SR
    x = np.sin(2 * np.pi * 1000.0 * t).astype(np.float32)
    for factor in (0.7, 1.25):
        y = pitch_shift(x, factor, SR)
        assert len(y) == SR and y.dtype == np.float32
        assert abs(float(np.median(_peak_track(y))) - 1000.0 * factor) <= SR / 4096
    assert len(pitch_shift(x, 0.5)) == 2 * SR  # n=None keeps the resampled length
    with pytest.raises(ValueError, match="pitch factor"):
        pitch_shift(x, 10.0)


def _window_levels_db(x: np.ndarray, win: int = SR // 2) -> np.ndarray:
    k = len(x) // win
    p = np.mean(np.asarray(x[: k * win], dtype=np.float64).reshape(k, win) ** 2, axis=1)
    return 10 * np.log10(p + 1e-20)


def test_flatten_envelope_undoes_level_changes_and_cuts_silence() -> None:
    x, _ = synthesize_siren("yelp", 6.0, SR, seed=3)
    fade = np.concatenate([np.linspace(0.0, -20.0, 4 * SR), np.full(2 * SR, -20.0)])  # a pass-by's fall
    y = x * 10 ** (fade / 20)
    y[5 * SR : int(5.5 * SR)] = 0.0  # a silent gap
    out = flatten_envelope(y, SR)
    assert out.dtype == np.float32 and abs(len(out) / SR - 5.5) < 0.15  # the gap is cut out
    levels = _window_levels_db(out)
    assert levels.max() - levels.min() < 4.0, levels  # was 20 dB
    assert abs(float(np.sqrt(np.mean(out.astype(np.float64) ** 2))) - 1.0) < 1e-3
    clean = flatten_envelope(x, SR)  # a steady siren passes nearly unchanged
    assert len(clean) == len(x) and np.corrcoef(clean, x)[0, 1] > 0.99


def test_real_siren_recordings_are_flattened(data_root: Path) -> None:
    src = next(s for s in load_siren_sources(data_root) if s.name == "jap_amb")
    from makeway.sim.siren import load_mono

    raw, flat = load_mono(src.path), src.load()
    assert np.median(_window_levels_db(raw)) < -8.0  # a pass-by: most windows well below its RMS
    assert np.median(_window_levels_db(flat)) > -2.0


def test_siren_pitch_variety_uses_its_own_stream(monkeypatch: pytest.MonkeyPatch) -> None:
    import makeway.sim.audio_scenarios as scen

    monkeypatch.setattr(scen, "data_dir", lambda: None)  # synthesized sirens, generated noise
    varied = None
    for seed in range(8):
        plain = simulate_recording("crossing", 1.0, seed=seed, distractors=False)
        rec = simulate_recording("crossing", 1.0, seed=seed, distractors=False, siren_pitch=(0.7, 0.75))
        for key in ("street_noise", "wind", "ego_speed_mps", "scenario"):  # every other draw is unchanged
            assert rec.meta[key] == plain.meta[key]
        s, p = rec.meta["sirens"][0], plain.meta["sirens"][0]
        assert s["level_db_1m"] == p["level_db_1m"] and s["period_s"] == p["period_s"]
        if "variety" in s:
            varied = (s, p)
        else:  # not drawn for variety: the very same siren
            np.testing.assert_array_equal(rec.audio, plain.audio)
    assert varied is not None, "no siren of 8 was varied (share 0.5)"
    s, p = varied
    assert 0.7 <= s["variety"]["pitch_factor"] <= 0.75
    assert s["f_low_hz"] == pytest.approx(p["f_low_hz"] * s["variety"]["pitch_factor"], abs=0.2)
    with pytest.raises(ValueError, match="siren_pitch"):
        simulate_recording("crossing", 1.0, seed=0, siren_pitch=(1.3, 0.7))


# ----------------------------------------------------------------------------------------- simulator


@pytest.mark.parametrize("kernel", ["sinc", "lagrange"])
def test_fractional_read_is_the_signal_padded_with_silence(kernel: str) -> None:
    """A read needs only the stretch its taps reach; outside the signal it reads silence."""
    rng = np.random.default_rng(3)
    sig = rng.normal(size=5_000).astype(np.float32)
    padded = np.concatenate([np.zeros(300, np.float32), sig, np.zeros(300, np.float32)])
    for pos in (
        np.linspace(-40.0, 60.0, 777),  # across the start
        np.linspace(4_950.0, 5_030.0, 333),  # across the end
        np.linspace(1_000.3, 1_500.9, 2_000),  # inside, a short hop of a long signal
        rng.uniform(-200.0, 5_200.0, 1_000),  # anywhere, in any order
    ):
        got = read_fractional(sig, pos, kernel)
        assert got.dtype == np.float32 and got.shape == pos.shape
        np.testing.assert_array_equal(got, read_fractional(padded, pos + 300.0, kernel))
    whole = np.arange(len(sig), dtype=np.float64)
    np.testing.assert_array_equal(read_fractional(sig, whole, kernel), sig)  # whole samples: exact
    assert not read_fractional(sig, np.array([-1e7, -30.0, 5_030.0, 1e9]), kernel).any()
    assert read_fractional(sig, np.array([]), kernel).shape == (0,)
    # a slow sine read between its samples
    tone = np.sin(2 * np.pi * 0.01 * np.arange(4_000)).astype(np.float32)
    pos = np.linspace(100.25, 3_900.75, 1_500)
    np.testing.assert_allclose(read_fractional(tone, pos, kernel), np.sin(2 * np.pi * 0.01 * pos), atol=2e-3)


def test_static_delays_match_geometry() -> None:
    ego = _line(-1.0, 2.0, 12.0, -4.0, yaw=0.4)
    src_xy = np.array([12.0 + 30 * math.cos(1.1), -4.0 + 30 * math.sin(1.1)])
    source = PointSource(np.zeros(10), -1.0, _line(-1.0, 2.0, *src_xy), height_m=1.2, reflection=0.0)
    times = np.array([0.3, 1.0])
    delays = propagation_delays(source, ego, reference_mics(), times)
    world = mic_world_positions(ego, reference_mics(), times)
    geo = np.linalg.norm(world - np.array([*src_xy, 1.2]), axis=2) / C
    np.testing.assert_allclose(delays, geo, atol=1e-12)
    # inter-capsule delays L-front − R-front from the vehicle-frame geometry directly
    rel = np.array([30 * math.cos(1.1 - 0.4), 30 * math.sin(1.1 - 0.4), 1.2])
    m = reference_mics()
    expect = (np.linalg.norm(m[0] - rel) - np.linalg.norm(m[4] - rel)) / C
    assert abs((delays[0, 0] - delays[0, 4]) - expect) < 1e-12


def test_simulated_tone_phase_matches_geometry() -> None:
    """A static 1 kHz tone: the phase difference between capsules equals 2π·f·Δτ(geometry)."""
    f0, dur = 1000.0, 1.0
    t_sig = np.arange(round((dur + 0.5) * SR)) / SR - 0.5
    ego = _line(-0.5, dur, 0.0, 0.0, yaw=-0.7)
    src_xy = (25 * math.cos(0.2), 25 * math.sin(0.2))
    source = PointSource(
        np.sin(2 * np.pi * f0 * t_sig),
        -0.5,
        _line(-0.5, dur, *src_xy),
        1.55,
        reflection=0.0,
        air_absorption=False,
    )
    y = simulate_array([source], ego, reference_mics(), round(dur * SR), SR)
    t = np.arange(len(y)) / SR
    sel = slice(SR // 4, SR - SR // 8)
    demod = (y[sel] * np.exp(-2j * np.pi * f0 * t[sel])[:, None]).mean(axis=0)
    delays = propagation_delays(source, ego, reference_mics(), np.array([0.5]))[0]
    for m in range(1, 8):
        measured = np.angle(demod[m] / demod[0])
        expected = -2 * np.pi * f0 * (delays[m] - delays[0])
        assert abs(np.angle(np.exp(1j * (measured - expected)))) < 2e-3, (m, measured, expected)
    # level: 1/r spreading (amplitude 1 at 1 m → 1/25 at 25 m)
    assert abs(np.abs(demod[0]) * 2 - 1 / 25.0) < 0.002


def test_fixed_sources_agree_with_moving_source_engine() -> None:
    """The frequency-domain placement of ambient sources matches the time-domain engine for a
    source that happens to stand still."""
    n, pre = SR // 2, SR // 4
    sig = generated_street_noise(n + pre, SR, np.random.default_rng(2))
    pos = np.array([20.0, 10.0, 1.0])
    fixed = place_fixed_sources([sig], pos[None], reference_mics(), n, SR, reflection=0.8)
    ego = _line(-0.5, 1.0, 0.0, 0.0, yaw=0.0)
    moving = simulate_array(
        [PointSource(sig, -pre / SR, _line(-0.5, 1.0, pos[0], pos[1]), height_m=pos[2], reflection=0.8)],
        ego,
        reference_mics(),
        n,
        SR,
    )
    sel = slice(SR // 10, n)
    for m in (0, 5):
        a, b = fixed[sel, m], moving[sel, m]
        assert np.corrcoef(a, b)[0, 1] > 0.999
        assert abs(a.std() / b.std() - 1.0) < 0.01


def _inst_frequency(x: np.ndarray, sel: slice) -> float:
    from scipy.signal import hilbert

    phase = np.unwrap(np.angle(hilbert(x)))[sel]
    t = np.arange(len(x))[sel] / SR
    return float(np.polyfit(t, phase, 1)[0] / (2 * np.pi))


@pytest.mark.parametrize(
    ("case", "src_v", "ego_v"),
    [("source approaching", -30.0, 0.0), ("source receding", 25.0, 0.0), ("ego approaching", 0.0, 20.0)],
)
def test_doppler_shift(case: str, src_v: float, ego_v: float) -> None:
    f0, dur, pre = 800.0, 2.0, 1.5
    t_sig = np.arange(round((dur + pre) * SR)) / SR - pre
    ego = _line(-pre, dur, 0.0, 0.0, vx=ego_v, yaw=0.0)
    source = PointSource(
        np.sin(2 * np.pi * f0 * t_sig).astype(np.float32),
        -pre,
        _line(-pre, dur, 120.0, 0.0, vx=src_v),
        height_m=1.0,
        reflection=0.0,
        air_absorption=False,
    )
    y = simulate_array([source], ego, np.array([[0.0, 0.0, 1.0]]), round(dur * SR), SR)[:, 0]
    measured = _inst_frequency(y, slice(SR // 4, 7 * SR // 4))
    # closed form: moving source f0 / (1 − v_s,toward/c); moving observer f0 · (1 + v_o,toward/c)
    expected = f0 / (1.0 - (-src_v) / C) * (1.0 + ego_v / C)
    assert abs(measured / expected - 1.0) < 0.01, (case, measured, expected)
    assert abs(measured / f0 - 1.0) > 0.05  # the shift is really there


def _gcc_phat_tdoa(a: np.ndarray, b: np.ndarray, band: tuple[float, float] = (400.0, 4000.0)) -> float:
    """Delay of ``a`` relative to ``b`` (s) by GCC-PHAT with parabolic peak interpolation.

    Only bins whose cross-power stands 10 dB above the band's median enter (the siren's harmonics):
    plain PHAT would give the many noise-only bins as much weight as the narrow-band siren.
    """
    n = 2 * len(a)
    spec = np.fft.rfft(a, n) * np.conj(np.fft.rfft(b, n))
    f = np.fft.rfftfreq(n, 1 / SR)
    in_band = (f >= band[0]) & (f <= band[1])
    strong = np.abs(spec) > 10.0 * np.median(np.abs(spec[in_band]))
    spec = np.where(in_band & strong, spec / np.maximum(np.abs(spec), 1e-20), 0)
    cc = np.fft.irfft(spec, n)
    max_lag = 200
    cc = np.concatenate([cc[-max_lag:], cc[: max_lag + 1]])
    k = int(np.argmax(cc))
    y0, y1, y2 = cc[k - 1], cc[k], cc[k + 1]
    frac = 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)
    return (k - max_lag + frac) / SR


def test_gcc_phat_on_simulated_array_matches_bearing() -> None:
    """Whole chain: siren + street noise + wind on the 8-capsule array, ego and EV moving together;
    GCC-PHAT between the L and R front capsules gives the TDOA of the labelled bearing."""
    rng = np.random.default_rng(5)
    dur, pre = 1.0, 0.5
    n = round(dur * SR)
    yaw, v = 0.9, 8.0
    vx, vy = v * math.cos(yaw), v * math.sin(yaw)
    ego = _line(-pre, dur, 100.0, 50.0, vx, vy, yaw=yaw)
    theta_true, dist_true = math.radians(50.0), 30.0
    ox = dist_true * math.cos(theta_true + yaw)
    oy = dist_true * math.sin(theta_true + yaw)
    src = _line(-pre, dur, 100.0 + ox, 50.0 + oy, vx, vy)
    sig, _ = synthesize_siren("wail", dur + pre, SR, seed=3)
    siren = PointSource(sig * db_spl_to_pa(115.0), -pre, src, height_m=1.5, reflection=0.8)
    y = simulate_array([siren], ego, reference_mics(), n, SR)
    noise = place_fixed_sources(
        [generated_street_noise(n + SR // 4, SR, rng) for _ in range(3)],
        np.array([[30.0, -20.0, 1.0], [-40.0, 10.0, 1.0], [5.0, 35.0, 1.0]]),
        reference_mics(),
        n,
        SR,
    )
    noise *= 10 ** ((70.0 - a_weighted_level_db(noise, SR)) / 20)  # street noise at 70 dB(A)
    y = y + noise + wind_noise(n, 8, SR, v + 2.0, 66.0, rng)
    rec = Recording(y.astype(np.float32), SR, reference_mics(), ego, [src])
    labels = label_recording(rec)
    assert np.allclose(labels.theta[:, 0], theta_true, atol=1e-9)
    assert np.allclose(labels.distance[:, 0], dist_true, atol=1e-9)
    w = len(labels) - 1
    a = y[labels.start[w] : labels.start[w] + labels.window, 0]
    b = y[labels.start[w] : labels.start[w] + labels.window, 4]
    tdoa = _gcc_phat_tdoa(a, b)
    m = reference_mics()
    rel = np.array([dist_true * math.cos(theta_true), dist_true * math.sin(theta_true), 1.5])
    # EV and ego move together, so the relative geometry is fixed (up to the 0.7 m the EV moves while
    # the sound travels)
    expected = (np.linalg.norm(m[0] - rel) - np.linalg.norm(m[4] - rel)) / C
    assert abs(tdoa - expected) < 2.0 / SR, (tdoa * SR, expected * SR)
    bearing = math.asin(float(np.clip(-tdoa * C / 0.9, -1, 1)))  # far field, front/back ambiguous
    assert abs(math.degrees(bearing - theta_true)) < 5.0


# ----------------------------------------------------------------------------------------- labeller


def test_labeller_angles_and_distances() -> None:
    dur = 2.0
    n = round(dur * SR)
    ego = _line(0.0, dur, 10.0, 5.0, vy=10.0, yaw=math.pi / 2, rate=10.0)  # facing world +y
    ahead = _line(0.0, dur, 10.0, 35.0, vy=10.0, rate=10.0)  # 30 m straight ahead, same speed
    left = _line(0.0, dur, -10.0, 5.0, vy=10.0, rate=10.0)  # 20 m to the left (world −x)
    far = _line(0.0, dur, 10.0, 5.0 - 150.0, vy=10.0, rate=10.0)  # 150 m behind
    closing = _line(0.0, dur, 10.0, 65.0, vy=0.0, rate=10.0)  # static, ego drives at it
    rec = Recording(np.zeros((n, 8), np.float32), SR, reference_mics(), ego, [ahead, left, far, closing])
    labels = label_recording(rec)
    assert len(labels) == 9 and labels.window == SR // 2
    np.testing.assert_allclose(labels.t_end[:3], [0.5, 0.67, 0.84])
    np.testing.assert_allclose(labels.theta[:, 0], 0.0, atol=1e-9)
    np.testing.assert_allclose(labels.distance[:, 0], 30.0, atol=1e-9)
    np.testing.assert_allclose(labels.theta[:, 1], math.pi / 2, atol=1e-9)
    np.testing.assert_allclose(labels.distance[:, 1], 20.0, atol=1e-9)
    assert not labels.present[:, 2].any() and np.isnan(labels.theta[:, 2]).all()
    # linear interpolation between 10 Hz samples: distance 60 − 10·t_end, closing at 10 m/s
    np.testing.assert_allclose(labels.distance[:, 3], 60.0 - 10.0 * labels.t_end, atol=1e-9)
    np.testing.assert_allclose(labels.range_rate[:, 3], -10.0, atol=1e-6)
    np.testing.assert_allclose(labels.range_rate[:, 0], 0.0, atol=1e-6)
    theta, dist = labels.nearest()
    np.testing.assert_allclose(dist, 20.0)
    np.testing.assert_allclose(theta, math.pi / 2)
    # with only the far source the windows are negatives
    neg = label_recording(Recording(rec.audio, SR, rec.mics, ego, [far]))
    assert not neg.siren.any()
    row = neg.records("x")[0]
    assert row["siren"] is False and row["sources"] == []
    assert len(window_starts(SR // 4, SR)) == 0


# ----------------------------------------------------------------------------------------- scenarios


def test_scenario_geometry() -> None:
    rng = np.random.default_rng(11)
    for name in AUDIO_SCENARIOS:
        tr = make_tracks(name, 10.0, rng)
        assert len(tr.evs) == 1 and tr.ego.span[0] < 0 <= 10.0 <= tr.ego.span[1]
    for seed in range(5):
        tr = make_tracks("from_behind", 10.0, np.random.default_rng(seed))
        rec = Recording(np.zeros((10 * SR, 1), np.float32), SR, np.zeros((1, 3)), tr.ego, tr.evs)
        lab = label_recording(rec, max_distance_m=1e9)
        assert abs(lab.theta[0, 0]) > math.radians(170)  # starts right behind in the ego's lane
        assert (lab.range_rate[:, 0] < 0).any()


def test_simulate_recording_without_data(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import makeway.sim.audio_scenarios as scen

    monkeypatch.setattr(scen, "data_dir", lambda: None)  # as on a machine without ../shared/data
    rec = simulate_recording("opposite_direction", 2.0, seed=4)
    assert rec.meta["street_noise"]["ingredient"] == "generated"
    assert rec.audio.shape == (2 * SR, 8) and rec.audio.dtype == np.float32
    assert np.isfinite(rec.audio).all() and 1e-4 < np.abs(rec.audio).max() < 0.9
    assert rec.meta["sirens"][0]["ingredient"] == "synth" and "snr_band_db" in rec.meta
    assert len(rec.sources) == 1 and rec.sources[0].span == (0.0, 2.0)
    back = read_recording(write_recording(tmp_path / "r", rec))
    assert back.meta["scenario"] == "opposite_direction"
    # the same scene through an array 10 dB more sensitive: 10 dB louder samples, and it says so
    keen = simulate_recording("opposite_direction", 2.0, seed=4, full_scale_db_spl=125.0)
    assert keen.full_scale_db_spl == 125.0 and "limited" not in keen.meta
    np.testing.assert_allclose(keen.audio, rec.audio * 10 ** (10 / 20), rtol=1e-4, atol=1e-7)
    assert rec.full_scale_db_spl == back.full_scale_db_spl == REFERENCE_FULL_SCALE_DB_SPL  # stated
    neg = simulate_recording("crossing", 1.0, seed=4, siren="none", noise="generated")
    assert neg.sources == [] and "sirens" in neg.meta and neg.meta["sirens"] == []


def test_simulate_with_real_ingredients(data_root: Path) -> None:
    pool = load_siren_sources(data_root)
    kinds = {s.kind for s in pool}
    assert kinds == {"clip", "tone", "recording"}
    groups = {s.name: s.group for s in pool}
    assert groups["ambulance_001"] == groups["ambulance_010"] != groups["ambulance_011"]
    assert groups["sirens__federal_sig_80k__emv_wail"] == groups["sirens__federal_sig_80k__emv_yelp"]
    assert not any(name.endswith("horn") for name in groups)
    x = next(s for s in pool if s.name == "sirens__chp__emv_yelp").load()
    assert (
        abs(len(x) / SR - sf.info(data_root / "audio/siren_tones/sirens__chp__emv_yelp.flac").duration) < 1e-3
    )
    rec = simulate_recording("same_direction", 2.0, seed=2, siren="real", noise="real", data_root=data_root)
    assert rec.meta["sirens"][0]["ingredient"] == "real"
    assert rec.meta["street_noise"]["ingredient"] == "real"
    assert all(nm.startswith(("traffic", "noise")) for nm in rec.meta["street_noise"]["names"])
    assert np.isfinite(rec.audio).all() and np.abs(rec.audio).max() < 0.9


# ----------------------------------------------------------------------------------------------- CLI


def test_cli_simulate_and_label(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from makeway.cli.audio import audio_app

    runner = CliRunner()
    out = tmp_path / "sim"
    res = runner.invoke(
        audio_app,
        [
            "simulate",
            "--out",
            str(out),
            "--n",
            "2",
            "--duration",
            "1",
            "--siren",
            "synth",
            "--noise",
            "generated",
            "--no-siren-fraction",
            "0.5",
            "--quiet",
            "--json",
            "--full-scale-db-spl",
            "128.5",
        ],
    )
    assert res.exit_code == 0, res.output
    assert sorted(p.name for p in out.iterdir()) == ["rec_00000", "rec_00001"]
    assert json.loads(res.stdout.strip().splitlines()[-1])["full_scale_db_spl"] == 128.5
    assert read_recording(out / "rec_00000").full_scale_db_spl == 128.5
    # --start: recording 1 alone, made by a second command, is the same recording
    part = tmp_path / "part"
    args = ["--duration", "1", "--siren", "synth", "--noise", "generated", "--no-siren-fraction", "0.5"]
    args += ["--full-scale-db-spl", "128.5"]
    res = runner.invoke(audio_app, ["simulate", "--out", str(part), "--n", "1", "--start", "1", *args, "-q"])
    assert res.exit_code == 0, res.output
    assert [p.name for p in part.iterdir()] == ["rec_00001"]
    assert (part / "rec_00001" / "audio.flac").read_bytes() == (out / "rec_00001" / "audio.flac").read_bytes()
    res = runner.invoke(audio_app, ["label", str(out), "--json"])
    assert res.exit_code == 0, res.output
    rows = [json.loads(ln) for ln in (out / "labels.jsonl").read_text().splitlines()]
    assert len(rows) == 2 * 3 and {r["recording"] for r in rows} == {"rec_00000", "rec_00001"}
    (out / "rec_00001" / "ego.csv").write_text("t,x\n0,0\n")
    res = runner.invoke(audio_app, ["label", str(out / "rec_00001")])
    assert res.exit_code == 2 and "missing column(s) y, yaw" in res.output
